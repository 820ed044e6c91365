//! Kinodynamic MPC that tracks a reference path with risk-limited speed and obstacle
//! half-planes (STEP's MPC tracker).
//!
//! Documented on [`MpcTracker`].

mod assemble;
mod clearance;
mod config;
mod geometry;
mod ipm;
mod line_search;
mod linearise;
mod output;
mod path_shift;
mod qp;
mod reference;
mod unicycle;

use std::time::Instant;

use glam::DVec2;

pub use config::{MpcConfig, MpcFootprint, MpcLimits, MpcObstacles, MpcRisk, MpcSolver, MpcTracking, MpcWeights, QpSolverKind};
pub use geometry::ConvexPolygon;
use crate::plan::grid::RiskGrid;
pub use output::{MpcCommand, MpcOutput, MpcStatus};
pub use unicycle::{step, UnicycleInput, UnicycleState};
use unicycle::{step_with_jacobians, StepJacobians};

use crate::error::{Error, Result};
use assemble::build_qp;
use clearance::clearance;
use geometry::{lethal_polygons, PolygonScratch};
use line_search::{line_search, tighten_speed_bounds, Step};
use linearise::{linearise, speed_bounds};
use path_shift::{path_offsets, SideOffsets};
use qp::{CscBuilder, QpProblem, QpSolver};
pub use qp::{MpcQp, MpcQpSolution, QpStatus};
use reference::Reference;

/// A state's speed beyond this is a broken estimate, not a robot [m/s].
pub(crate) const MAX_STATE_SPEED_M_S: f64 = 100.0;
/// A state's |heading| beyond this is a broken estimate [rad] (headings are not wrapped, but
/// a robot that turned 10^6 rad has spun for days; `f64` keeps 10^-10 rad at this size).
pub(crate) const MAX_STATE_HEADING_RAD: f64 = 1e6;

/// Targets of one stage, fixed during one SQP iteration (`MpcTracker`'s docs, step 2).
#[derive(Debug, Clone, Copy, Default)]
struct StageTarget {
    point: DVec2,
    tangent: DVec2,
    heading_rad: f64,
    speed_m_s: f64,
    factor: f64,
    /// Speed bounds of the QP: `vhi_k`, `vlo_k` widened to the braking envelope.
    speed_hi: f64,
    speed_lo: f64,
}

/// One obstacle half-plane of a stage (`MpcTracker`'s docs, step 3).
#[derive(Debug, Clone, Copy, Default)]
struct ObstacleRow {
    /// Whether the row constrains anything (else it is a placeholder of the fixed sparsity).
    used: bool,
    /// The corner's distance beyond the polygon's supporting line at the nominal \[m\].
    distance_m: f64,
    /// Unit normal from the obstacle to the robot.
    normal: DVec2,
    /// `n̄·perp(corner - p̄)`: the distance's derivative in the heading [m/rad].
    lever_m: f64,
}

/// Buffers reused between solves.
#[derive(Debug, Default)]
struct Workspace {
    reference: Reference,
    polygons: Vec<ConvexPolygon>,
    polygon_scratch: PolygonScratch,
    /// Nominal inputs `ū` and states `x̄`, Jacobians of each step.
    u: Vec<UnicycleInput>,
    x: Vec<UnicycleState>,
    jacobians: Vec<StepJacobians>,
    /// Line-search trial.
    trial_u: Vec<UnicycleInput>,
    trial_x: Vec<UnicycleState>,
    /// Stage `k = 1..N` at index `k - 1`.
    targets: Vec<StageTarget>,
    /// `N·2K` rows, stage-major: two per polygon (the two deepest corners).
    rows: Vec<ObstacleRow>,
    candidates: Vec<(f64, usize)>,
    /// Sideways offsets of the path at arc lengths `path_offsets_start + i·PATH_SAMPLE_M`.
    path_offsets: Vec<f64>,
    path_offsets_start: f64,
    intervals: Vec<(f64, f64)>,
    /// Per path sample: the nearest free offsets `(right, left)`.
    side_offsets: Vec<SideOffsets>,
    /// The diagonal of `P` and its off-diagonal entries per stage (see [`build_qp`]).
    p_diag: Vec<f64>,
    p_off: Vec<[f64; 3]>,
    builder: CscBuilder,
    qp: QpProblem,
    z: Vec<f64>,
}

/// The MPC tracker. Keeps the last plan to warm-start the next solve.
///
/// In: the robot's state `x0 = [x, y, θ, v]`, a reference polyline in world coordinates,
/// optionally a risk grid ([`RiskGrid`]) and a desired speed. Out: an [`MpcOutput`] — the
/// command `(v, ω)` to send now, the predicted trajectory, the status, and diagnostics.
///
/// # Model
/// Unicycle, state `[x, y, θ, v]`, input `u = [a, ω]` constant over steps of `T = dt_s`,
/// horizon `N` steps; the exact discrete dynamics `x_{k+1} = f(x_k, u_k)` are in
/// `unicycle` (closed-form integral, no Euler error). The command sent is
/// `(v0 + a_0·T, ω_0)`: the speed at the end of the first step, and its yaw rate. The robot
/// is a `length x width` rectangle centred on `(x, y)` (not a cover of discs: a disc cover
/// of the Husky overhangs its ends by 0.2 m).
///
/// # One solve (sequential QP)
/// 0. **Obstacles.** The lethal cells (`risk >= lethal_risk`) within `N·T·max(v_max, |v0|)`
///    plus the footprint's half-diagonal, the margin and the activation distance of `x0`
///    become convex polygons (`geometry`: 8-connected regions, cut until each convex hull
///    hardly overhangs its cells).
/// 1. **Nominal.** `ū` = the previous solve's inputs shifted by one step (the last one
///    repeated), or zeros on the first solve or after [`MpcTracker::reset`]; clamped to the
///    input limits. `x̄` = its exact rollout from `x0`, with the Jacobians `A_k, B_k`.
/// 2. **Targets** (fixed for the iteration). `s0` = arc length of the path point closest
///    to `x0`; stage `k = 1..N` gets the path point at `s_k = clamp(s0 + Σ_{j<k}
///    ½(v̄_j + v̄_{j+1})·T, 0, L)` — spaced by the nominal's predicted travel — and the speed
///    `vr_k = min(v_des, sqrt(2·d_end·(L - s_k)))` (stops at the end). The path's direction
///    `t(s)` is the chord over `±tangent_half_window_m` (corners of a grid path turn
///    smoothly). **Moving the path around obstacles:** the path is sampled every 0.1 m from
///    `s0 - ramp` to `s0 + N·T·max(v_max, |v0|) + ramp` (`ramp = path_shift_ramp_m`); at each
///    sample, each polygon forbids the interval of sideways offsets `o` (along `perp(t)`) at
///    which the footprint, with the path's heading, is within `path_clearance_m` of it (the
///    line of centres against the polygon grown by the rectangle and the clearance — exact up
///    to corners taken square), and the nearest free offsets on the right (`o <= 0`) and
///    left (`o >= 0`) within `max_path_shift_m` are kept. Each run of samples where `o = 0`
///    is not free goes round on one side — the side whose largest offset over the run is
///    smaller (right on a tie); a run blocked on both sides keeps 0 and is left to the
///    obstacle rows (the robot stops in front of it). `o(s)` is the largest-magnitude sample
///    offset scaled by the tent `1 - |s - s_i|/ramp`, so the moved path leaves the path
///    before an obstacle and comes back after it. The target is `r_k = path(s_k) +
///    o(s_k)·perp(t)`, with the moved path's unit tangent `t_k = (t + o'·perp(t))/|...|`
///    (`o'` by central differences over 0.1 m) and heading `θr_k = atan2(t_k)` unwrapped to
///    within π of `θ̄_k`. So the robot steers around an obstacle that reaches into its path
///    before it gets there, instead of stopping in front of it. **Speed bounds:** `r_k` =
///    the largest risk met along the nominal from `p̄_{k-1}` through `p̄_k` to `p̄_{k+1}`
///    (sampled every half cell, ends included; NaN and outside the grid = `unknown_risk`;
///    no grid = 0), `vhi_k = v_max·(1 - r_k)`, `vlo_k = max(v_min, -vhi_k)`: the risk limit
///    `|v_k| <= v_max·(1 - r(p_k))` taken constant from the nominal's positions,
///    conservative by a step either side so a risky band thinner than a step is not jumped
///    over; then widened to what braking at `a_max` from `v0` can reach,
///    `vhi'_k = max(vhi_k, v0 - a_max·k·T + 10⁻³)`, `vlo'_k = min(vlo_k, v0 + a_max·k·T -
///    10⁻³)`, so the speed rows are always feasible.
/// 3. **Obstacle rows.** For each stage, the polygons whose exact signed distance `d̄` to the
///    footprint rectangle at `(p̄_k, θ̄_k)` is below `margin + activation_m`, nearest first, at
///    most `max_per_stage`; each gives two rows, one per robot corner `c` of the two deepest
///    along the unit normal `n̄` from the polygon to the robot (at the nearest points, or the
///    axis of least penetration):
///    `n̄·c̄ - h + n̄·δp_k + n̄·perp(c̄ - p̄_k)·δθ_k >= margin - σo_k`, `h = max over the
///    polygon's vertices of n̄·vertex`. In the translation `δp` this is a supporting
///    half-plane of the polygon pushed out by the margin, so for a fixed heading it never
///    lets the rectangle closer than `margin`; the heading enters to first order, through
///    both corners (a heading change turns one in and the other out).
/// 4. **QP** in `z = [δa_k, δω_k, δx_{k+1}, δy_{k+1}, δθ_{k+1}, δv_{k+1}, σo_{k+1}]_{k<N}`
///    (`7N` variables, `δ· = · - ·̄`; stage by stage, so the KKT system is banded):
///    ```text
///    min  Σ_{k=1..N} f_k·[ w_c(n_k·(p_k - r_k))² + w_l(t_k·(p_k - r_k))²
///                          + w_θ(θ_k - θr_k)² + w_v(v_k - vr_k)² ]
///       + Σ_{k<N} [ w_a a_k² + w_ω ω_k² + w_Δa(a_k - a_{k-1})² + w_Δω(ω_k - ω_{k-1})² ]
///       + Σ_{k=1..N} [ w_s1·σo_k + w_s2·σo_k² ]
///    s.t. δx_{k+1} = A_k δx_k + B_k δu_k,  δx_0 = 0     (Jacobians of f at the nominal)
///         |a_k| <= a_max,  |ω_k| <= ω_max                (hard)
///         vlo'_k <= v_k <= vhi'_k                        (speed and risk, hard; step 2)
///         the obstacle rows of step 3,  σo_k >= 0       (soft)
///    ```
///    with `n_k = perp(t_k)`, `f_k = 1`, `f_N = terminal_factor`, and `(a_{-1}, ω_{-1})` the
///    previous solve's first input (no such term on the first solve). The obstacle slack
///    keeps the QP feasible when the start already violates a margin; its linear weight
///    makes the penalty exact (zero slack whenever the rows can hold and `w_s1` exceeds
///    their multipliers). Solved by the tracker's own primal-dual interior-point method
///    (`solver.qp_solver = banded`: Mehrotra's predictor-corrector, each Newton system a
///    quasi-definite `LDLᵀ` over the band the stage-by-stage layout gives, about one stage
///    wide); a QP it does not solve to full accuracy goes to Clarabel, which can also solve
///    every QP (`clarabel`). [`MpcTracker::last_qp`] gives the QP for inspection.
/// 5. **Line search.** Merit `φ(u)` = the cost above on the exact rollout of `u`, targets of
///    step 2 held fixed, plus the exact penalties of the nonlinear constraints:
///    `w_s1·(σv_k + σo_k) + w_s2·(σv_k² + σo_k²)` with `σv_k` the excess of `v_k` over the
///    widened bounds recomputed along the rollout and `σo_k = max(0, margin - min over all
///    polygons of the exact distance)`. Steps `α = 1, ½, ¼, ...` (`line_search_steps` tries)
///    until `φ(ū + αδu) <= φ(ū) + 10⁻⁴·α·Δm` (`Δm < 0` the QP's predicted change) and the
///    violation `max(largest σv_k [m/s], largest σo_k [m])` has not grown by more than 10⁻⁴
///    (a filter: a step that carries a predicted state into cells riskier than the nominal
///    saw, or closer to an obstacle than the rows promised, is refused whatever it gains in
///    tracking, so a plan that starts within its limits stays within them; one violation may
///    shrink at the price of a smaller other); the first acceptable step updates `ū`. The
///    loop re-linearises (step 1 with the new `ū`) up to `sqp_iterations` QPs in all, and
///    stops early when the accepted step is below `step_tolerance` in every input or the QP
///    predicts no decrease. When no step is acceptable, the next QP starts from the same
///    nominal with each stage's speed bounds tightened to those along the refused full
///    step's rollout too (the step had carried states into cells riskier than the nominal
///    saw); when that one is refused as well, the loop stops.
/// 6. **Check and backup.** On the final exact rollout, `c_k` = the smallest signed distance
///    from the footprint to any polygon. The plan is unsafe when some `c_k <
///    min(margin, c_0) - clearance_tolerance_m`: it would bring the robot closer to a lethal
///    region than both the margin and where it stands now (a start inside a margin may stay
///    there or back out, never go deeper). An unsafe plan, or a failed first QP, is replaced
///    by the **backup stop**: `ω = 0`, `a_k = clamp(-v_k/T, -a_max, a_max)` (brake along the
///    current heading to a standstill, no reversing); the status says which.
///
/// Everything is deterministic: a fresh tracker (or one after [`MpcTracker::reset`]) given
/// the same calls returns bit-identical outputs (only `solve_time_s` differs). The QP's
/// sparsity depends only on how many obstacle rows each stage has; while it stays the same
/// the solver keeps its layout (the banded solver its order and envelope, Clarabel its
/// ordering and symbolic factorisation) and only the values change, and every buffer of the
/// solve is reused.
#[derive(Debug)]
pub struct MpcTracker {
    config: MpcConfig,
    /// The last plan's inputs, if any.
    warm: Option<Vec<UnicycleInput>>,
    ws: Workspace,
    solver: QpSolver,
}

impl MpcTracker {
    /// A tracker with a validated config.
    pub fn new(config: MpcConfig) -> Result<Self> {
        config.validate()?;
        Ok(Self { config, warm: None, ws: Workspace::default(), solver: QpSolver::new(config.solver.qp_max_iterations, config.solver.qp_solver) })
    }

    /// The config.
    pub fn config(&self) -> &MpcConfig {
        &self.config
    }

    /// The QP of the last SQP iteration of the last solve (`None` before the first solve), as
    /// the solver got it: to inspect what the tracker solved, or to time another solver on it
    /// ([`MpcQp::solve`]).
    pub fn last_qp(&self) -> Option<MpcQp> {
        (!self.ws.qp.q.is_empty()).then(|| MpcQp::of(&self.ws.qp))
    }

    /// Forgets the last plan, the last QP and the QP solver: the next solve starts from zero
    /// inputs.
    pub fn reset(&mut self) {
        self.warm = None;
        self.ws.qp.q.clear();
        self.solver.reset();
    }

    /// One solve (see [`MpcTracker`]). `reference_path`: at least two finite world points with a
    /// positive length. `desired_speed_m_s`: `None` takes the config's; else in `[0, v_max]`.
    /// Errors (naming `state`, `reference_path` or `desired_speed`) leave the tracker as it was.
    pub fn solve(
        &mut self,
        state: &UnicycleState,
        reference_path: &[DVec2],
        risk: Option<&RiskGrid<'_>>,
        desired_speed_m_s: Option<f64>,
    ) -> Result<MpcOutput> {
        let started = Instant::now();
        let c = self.config;
        if !state.is_finite() {
            return Err(Error::input("state", format!("must be 4 finite numbers [x, y, θ, v], got {:?}", state.to_array())));
        }
        crate::frames::check_position("state", &[state.x_m, state.y_m])?;
        if state.heading_rad.abs() > MAX_STATE_HEADING_RAD {
            return Err(Error::input("state", format!("heading {} rad is beyond |θ| <= {MAX_STATE_HEADING_RAD:e} rad (a broken estimate)", state.heading_rad)));
        }
        if state.speed_m_s.abs() > MAX_STATE_SPEED_M_S {
            return Err(Error::input("state", format!("speed {} m/s is beyond any ground robot (|v| <= {MAX_STATE_SPEED_M_S} m/s)", state.speed_m_s)));
        }
        let desired = desired_speed_m_s.unwrap_or(c.tracking.desired_speed_m_s);
        if !(desired.is_finite() && desired >= 0.0 && desired <= c.limits.max_speed_m_s) {
            return Err(Error::input("desired_speed", format!("must be in [0, max_speed_m_s = {}] m/s, got {desired}", c.limits.max_speed_m_s)));
        }
        self.ws.reference.set(reference_path)?;

        let n = c.horizon;
        let half_diagonal = 0.5 * c.footprint.length_m.hypot(c.footprint.width_m);
        self.ws.polygons.clear();
        if let (Some(grid), true) = (risk, c.obstacles.max_per_stage > 0) {
            let reach = n as f64 * c.dt_s * c.limits.max_speed_m_s.max(state.speed_m_s.abs());
            let radius = reach + half_diagonal + c.obstacles.margin_m + c.obstacles.activation_m;
            let overhang_cells = c.obstacles.max_overhang_m / grid.resolution_m();
            lethal_polygons(grid, state.position(), radius, c.risk.lethal_risk as f32, overhang_cells, &mut self.ws.polygon_scratch, &mut self.ws.polygons);
        }

        // Step 1: the nominal.
        let ws = &mut self.ws;
        ws.u.clear();
        match &self.warm {
            Some(prev) if prev.len() == n => {
                ws.u.extend_from_slice(&prev[1..]);
                ws.u.push(prev[n - 1]);
            }
            _ => ws.u.resize(n, UnicycleInput::default()),
        }
        let previous_input = self.warm.as_ref().map(|p| p[0]);
        for u in &mut ws.u {
            u.accel_m_s2 = u.accel_m_s2.clamp(-c.limits.max_accel_m_s2, c.limits.max_accel_m_s2);
            u.yaw_rate_rad_s = u.yaw_rate_rad_s.clamp(-c.limits.max_yaw_rate_rad_s, c.limits.max_yaw_rate_rad_s);
        }
        let s0 = ws.reference.project(state.position());
        let reach = n as f64 * c.dt_s * c.limits.max_speed_m_s.max(state.speed_m_s.abs());
        path_offsets(&c, ws, s0, reach);

        let mut status = MpcStatus::Solved;
        let mut sqp_iterations = 0;
        let mut qp_iterations = 0;
        // Whether the QP is to be solved again from the same nominal with tightened bounds.
        let mut tightened = false;
        for _ in 0..c.solver.sqp_iterations {
            if !tightened {
                linearise(&c, ws, state, s0, desired, risk);
            }
            build_qp(&c, ws, previous_input);
            let (outcome, iterations) = self.solver.solve(&ws.qp, &mut ws.z);
            qp_iterations += iterations;
            match outcome {
                QpStatus::Failed if sqp_iterations == 0 => {
                    status = MpcStatus::SolverFailedBackup;
                    break;
                }
                QpStatus::Failed => {
                    status = MpcStatus::SolvedInexact;
                    break;
                }
                QpStatus::Inexact => status = MpcStatus::SolvedInexact,
                QpStatus::Solved => {}
            }
            sqp_iterations += 1;
            match line_search(&c, ws, state, risk, previous_input) {
                Step::Accepted { go_on: true } => tightened = false,
                Step::Refused if !tightened => {
                    tighten_speed_bounds(&c, ws, state, risk);
                    tightened = true;
                }
                _ => break,
            }
        }

        // Step 6: check the plan on its exact rollout; else the backup stop.
        if status != MpcStatus::SolverFailedBackup {
            rollout(state, &ws.u, c.dt_s, &mut ws.x);
            let start = clearance(&c, &ws.polygons, state);
            let limit = c.obstacles.margin_m.min(start) - c.solver.clearance_tolerance_m;
            if ws.x[1..].iter().any(|s| clearance(&c, &ws.polygons, s) < limit) {
                status = MpcStatus::InfeasibleBackup;
            }
        }
        if status.is_backup() {
            backup_stop(&c, state, &mut ws.u, &mut ws.x);
        }
        self.warm = Some(ws.u.clone());

        // Diagnostics of the returned trajectory.
        let mut speed_limits_m_s = Vec::with_capacity(n);
        let (mut max_speed_slack, mut max_obstacle_slack, mut min_clearance) = (0.0f64, 0.0f64, f64::INFINITY);
        for k in 1..=n {
            let (hi, lo) = speed_bounds(&c, &ws.x, k, risk);
            speed_limits_m_s.push(hi);
            let v = ws.x[k].speed_m_s;
            max_speed_slack = max_speed_slack.max(v - hi).max(lo - v);
            let d = clearance(&c, &ws.polygons, &ws.x[k]);
            min_clearance = min_clearance.min(d);
            max_obstacle_slack = max_obstacle_slack.max(c.obstacles.margin_m - d);
        }
        Ok(MpcOutput {
            command: MpcCommand { speed_m_s: ws.x[1].speed_m_s, yaw_rate_rad_s: ws.u[0].yaw_rate_rad_s },
            predicted: ws.x.clone(),
            inputs: ws.u.clone(),
            status,
            sqp_iterations,
            qp_iterations,
            solve_time_s: started.elapsed().as_secs_f64(),
            max_slack: max_speed_slack.max(max_obstacle_slack),
            max_speed_slack_m_s: max_speed_slack,
            max_obstacle_slack_m: max_obstacle_slack,
            min_clearance_m: min_clearance,
            speed_limits_m_s,
            reference_points: ws.targets.iter().map(|t| t.point).collect(),
            polygons: ws.polygons.clone(),
        })
    }
}

/// `x[0] = start`, `x[k+1] = f(x[k], u[k])`.
fn rollout(start: &UnicycleState, u: &[UnicycleInput], dt_s: f64, x: &mut Vec<UnicycleState>) {
    x.clear();
    x.push(*start);
    for input in u {
        let next = step(&x[x.len() - 1], input, dt_s);
        x.push(next);
    }
}

/// The backup stop (`MpcTracker`'s docs, step 6) into `u` and `x`.
fn backup_stop(c: &MpcConfig, start: &UnicycleState, u: &mut Vec<UnicycleInput>, x: &mut Vec<UnicycleState>) {
    u.clear();
    x.clear();
    x.push(*start);
    for _ in 0..c.horizon {
        let s = x[x.len() - 1];
        let a = (-s.speed_m_s / c.dt_s).clamp(-c.limits.max_accel_m_s2, c.limits.max_accel_m_s2);
        let input = UnicycleInput { accel_m_s2: a, yaw_rate_rad_s: 0.0 };
        u.push(input);
        x.push(step(&s, &input, c.dt_s));
    }
}

#[cfg(test)]
mod tests;
