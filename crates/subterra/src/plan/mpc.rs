//! Kinodynamic MPC that tracks a reference path with risk-limited speed and obstacle
//! half-planes (STEP's MPC tracker).
//!
//! In: the robot's state `x0 = [x, y, θ, v]`, a reference polyline in world coordinates,
//! optionally a risk grid ([`RiskGrid`]) and a desired speed. Out: an [`MpcOutput`] — the
//! command `(v, ω)` to send now, the predicted trajectory, the status, and diagnostics.
//!
//! # Model
//! Unicycle, state `[x, y, θ, v]`, input `u = [a, ω]` constant over steps of `T = dt_s`,
//! horizon `N` steps; the exact discrete dynamics `x_{k+1} = f(x_k, u_k)` are in
//! [`unicycle`] (closed-form integral, no Euler error). The command sent is
//! `(v0 + a_0·T, ω_0)`: the speed at the end of the first step, and its yaw rate. The robot
//! is a `length x width` rectangle centred on `(x, y)` (not a cover of discs: a disc cover
//! of the Husky overhangs its ends by 0.2 m).
//!
//! # One solve (sequential QP)
//! 0. **Obstacles.** The lethal cells (`risk >= lethal_risk`) within `N·T·max(v_max, |v0|)`
//!    plus the footprint's half-diagonal, the margin and the activation distance of `x0`
//!    become convex polygons ([`geometry`]: 8-connected regions, cut until each convex hull
//!    hardly overhangs its cells).
//! 1. **Nominal.** `ū` = the previous solve's inputs shifted by one step (the last one
//!    repeated), or zeros on the first solve or after [`MpcTracker::reset`]; clamped to the
//!    input limits. `x̄` = its exact rollout from `x0`, with the Jacobians `A_k, B_k`.
//! 2. **Targets** (fixed for the iteration). `s0` = arc length of the path point closest
//!    to `x0`; stage `k = 1..N` gets the path point at `s_k = clamp(s0 + Σ_{j<k}
//!    ½(v̄_j + v̄_{j+1})·T, 0, L)` — spaced by the nominal's predicted travel — and the speed
//!    `vr_k = min(v_des, sqrt(2·d_end·(L - s_k)))` (stops at the end). The path's direction
//!    `t(s)` is the chord over `±tangent_half_window_m` (corners of a grid path turn
//!    smoothly). **Moving the path around obstacles:** the path is sampled every 0.1 m from
//!    `s0 - ramp` to `s0 + N·T·max(v_max, |v0|) + ramp` (`ramp = path_shift_ramp_m`); at each
//!    sample, each polygon forbids the interval of sideways offsets `o` (along `perp(t)`) at
//!    which the footprint, with the path's heading, is within `path_clearance_m` of it (the
//!    line of centres against the polygon grown by the rectangle and the clearance — exact up
//!    to corners taken square), and the nearest free offsets on the right (`o <= 0`) and
//!    left (`o >= 0`) within `max_path_shift_m` are kept. Each run of samples where `o = 0`
//!    is not free goes round on one side — the side whose largest offset over the run is
//!    smaller (right on a tie); a run blocked on both sides keeps 0 and is left to the
//!    obstacle rows (the robot stops in front of it). `o(s)` is the largest-magnitude sample
//!    offset scaled by the tent `1 - |s - s_i|/ramp`, so the moved path leaves the path
//!    before an obstacle and comes back after it. The target is `r_k = path(s_k) +
//!    o(s_k)·perp(t)`, with the moved path's unit tangent `t_k = (t + o'·perp(t))/|...|`
//!    (`o'` by central differences over 0.1 m) and heading `θr_k = atan2(t_k)` unwrapped to
//!    within π of `θ̄_k`. So the robot steers around an obstacle that reaches into its path
//!    before it gets there, instead of stopping in front of it. **Speed bounds:** `r_k` =
//!    the largest risk met along the nominal from `p̄_{k-1}` through `p̄_k` to `p̄_{k+1}`
//!    (sampled every half cell, ends included; NaN and outside the grid = `unknown_risk`;
//!    no grid = 0), `vhi_k = v_max·(1 - r_k)`, `vlo_k = max(v_min, -vhi_k)`: the risk limit
//!    `|v_k| <= v_max·(1 - r(p_k))` taken constant from the nominal's positions,
//!    conservative by a step either side so a risky band thinner than a step is not jumped
//!    over; then widened to what braking at `a_max` from `v0` can reach,
//!    `vhi'_k = max(vhi_k, v0 - a_max·k·T + 10⁻³)`, `vlo'_k = min(vlo_k, v0 + a_max·k·T -
//!    10⁻³)`, so the speed rows are always feasible.
//! 3. **Obstacle rows.** For each stage, the polygons whose exact signed distance `d̄` to the
//!    footprint rectangle at `(p̄_k, θ̄_k)` is below `margin + activation_m`, nearest first, at
//!    most `max_per_stage`; each gives two rows, one per robot corner `c` of the two deepest
//!    along the unit normal `n̄` from the polygon to the robot (at the nearest points, or the
//!    axis of least penetration):
//!    `n̄·c̄ - h + n̄·δp_k + n̄·perp(c̄ - p̄_k)·δθ_k >= margin - σo_k`, `h = max over the
//!    polygon's vertices of n̄·vertex`. In the translation `δp` this is a supporting
//!    half-plane of the polygon pushed out by the margin, so for a fixed heading it never
//!    lets the rectangle closer than `margin`; the heading enters to first order, through
//!    both corners (a heading change turns one in and the other out).
//! 4. **QP** in `z = [δa_k, δω_k, δx_{k+1}, δy_{k+1}, δθ_{k+1}, δv_{k+1}, σo_{k+1}]_{k<N}`
//!    (`7N` variables, `δ· = · - ·̄`; stage by stage, so the KKT system is banded):
//!    ```text
//!    min  Σ_{k=1..N} f_k·[ w_c(n_k·(p_k - r_k))² + w_l(t_k·(p_k - r_k))²
//!                          + w_θ(θ_k - θr_k)² + w_v(v_k - vr_k)² ]
//!       + Σ_{k<N} [ w_a a_k² + w_ω ω_k² + w_Δa(a_k - a_{k-1})² + w_Δω(ω_k - ω_{k-1})² ]
//!       + Σ_{k=1..N} [ w_s1·σo_k + w_s2·σo_k² ]
//!    s.t. δx_{k+1} = A_k δx_k + B_k δu_k,  δx_0 = 0     (Jacobians of f at the nominal)
//!         |a_k| <= a_max,  |ω_k| <= ω_max                (hard)
//!         vlo'_k <= v_k <= vhi'_k                        (speed and risk, hard; step 2)
//!         the obstacle rows of step 3,  σo_k >= 0       (soft)
//!    ```
//!    with `n_k = perp(t_k)`, `f_k = 1`, `f_N = terminal_factor`, and `(a_{-1}, ω_{-1})` the
//!    previous solve's first input (no such term on the first solve). The obstacle slack
//!    keeps the QP feasible when the start already violates a margin; its linear weight
//!    makes the penalty exact (zero slack whenever the rows can hold and `w_s1` exceeds
//!    their multipliers). Solved by Clarabel (interior point).
//! 5. **Line search.** Merit `φ(u)` = the cost above on the exact rollout of `u`, targets of
//!    step 2 held fixed, plus the exact penalties of the nonlinear constraints:
//!    `w_s1·(σv_k + σo_k) + w_s2·(σv_k² + σo_k²)` with `σv_k` the excess of `v_k` over the
//!    widened bounds recomputed along the rollout and `σo_k = max(0, margin - min over all
//!    polygons of the exact distance)`. Steps `α = 1, ½, ¼, ...` (`line_search_steps` tries)
//!    until `φ(ū + αδu) <= φ(ū) + 10⁻⁴·α·Δm` (`Δm < 0` the QP's predicted change) and the
//!    violation `max(largest σv_k [m/s], largest σo_k [m])` has not grown by more than 10⁻⁴
//!    (a filter: a step that carries a predicted state into cells riskier than the nominal
//!    saw, or closer to an obstacle than the rows promised, is refused whatever it gains in
//!    tracking, so a plan that starts within its limits stays within them; one violation may
//!    shrink at the price of a smaller other); the first acceptable step updates `ū`. The
//!    loop re-linearises (step 1 with the new `ū`) up to `sqp_iterations` QPs in all, and
//!    stops early when the accepted step is below `step_tolerance` in every input or the QP
//!    predicts no decrease. When no step is acceptable, the next QP starts from the same
//!    nominal with each stage's speed bounds tightened to those along the refused full
//!    step's rollout too (the step had carried states into cells riskier than the nominal
//!    saw); when that one is refused as well, the loop stops.
//! 6. **Check and backup.** On the final exact rollout, `c_k` = the smallest signed distance
//!    from the footprint to any polygon. The plan is unsafe when some `c_k <
//!    min(margin, c_0) - clearance_tolerance_m`: it would bring the robot closer to a lethal
//!    region than both the margin and where it stands now (a start inside a margin may stay
//!    there or back out, never go deeper). An unsafe plan, or a failed first QP, is replaced
//!    by the **backup stop**: `ω = 0`, `a_k = clamp(-v_k/T, -a_max, a_max)` (brake along the
//!    current heading to a standstill, no reversing); the status says which.
//!
//! Everything is deterministic: a fresh tracker (or one after [`MpcTracker::reset`]) given
//! the same calls returns bit-identical outputs (only `solve_time_s` differs). The QP's
//! sparsity depends only on how many obstacle rows each stage has; while it stays the same
//! the Clarabel solver is kept and only its values are overwritten (no new ordering or
//! symbolic factorisation), and every buffer of the solve is reused.

mod config;
pub mod geometry;
mod qp;
mod reference;
pub mod unicycle;

use std::time::Instant;

use glam::DVec2;

pub use config::{MpcConfig, MpcFootprint, MpcLimits, MpcObstacles, MpcRisk, MpcSolver, MpcTracking, MpcWeights};
pub use geometry::{ConvexPolygon, RiskGrid};
pub use unicycle::{step, step_with_jacobians, StepJacobians, UnicycleInput, UnicycleState};

use crate::error::{Error, Result};
use geometry::{blocked_offsets, lethal_polygons, separation, supporting_corners, Footprint, PolygonScratch};
use qp::{CscBuilder, QpOutcome, QpProblem, QpSolver};
use reference::Reference;

/// Spacing of the path samples whose sideways offsets are worked out [m].
const PATH_SAMPLE_M: f64 = 0.1;
/// A state's speed beyond this is a broken estimate, not a robot [m/s].
const MAX_STATE_SPEED_M_S: f64 = 100.0;
/// [`free_offsets`] steps this far past the end of a blocked interval [m] (rounding).
const PUSH_TOLERANCE_M: f64 = 1e-6;
/// QP variables per stage: `[a_k, ω_k, x, y, θ, v (of state k+1), σo_{k+1}]`.
const STAGE_VARS: usize = 7;
/// The braking envelope of the speed bounds is widened by this [m/s], so that braking at
/// exactly `a_max` is inside the feasible set rather than on its edge.
const ENVELOPE_SLACK_M_S: f64 = 1e-3;
/// A line-search step may not raise `max(largest speed-limit excess [m/s], largest intrusion
/// into an obstacle margin [m])` by more than this.
const FILTER_M: f64 = 1e-4;
/// Right-hand side of an unused obstacle row, `-σo <= this` [m]: never binding.
const UNUSED_ROW_RHS_M: f64 = 1e3;
/// Sufficient-decrease fraction of the line search (Armijo).
const ARMIJO: f64 = 1e-4;
/// A predicted decrease of the QP model smaller than this means the nominal is optimal.
const MIN_PREDICTED_DECREASE: f64 = 1e-12;

/// How a solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum MpcStatus {
    /// Every QP solved to tolerance; the plan is safe.
    Solved,
    /// The plan is safe but a QP stopped at reduced accuracy or failed after the first
    /// iteration (the last good iterate is used).
    SolvedInexact,
    /// No safe plan (the best plan goes deeper into a lethal region's margin than the robot
    /// is now): the output is the backup stop.
    InfeasibleBackup,
    /// The first QP failed (numerical trouble): the output is the backup stop.
    SolverFailedBackup,
}

impl MpcStatus {
    /// `solved`, `solved_inexact`, `infeasible_backup`, `solver_failed_backup`.
    pub fn name(self) -> &'static str {
        match self {
            MpcStatus::Solved => "solved",
            MpcStatus::SolvedInexact => "solved_inexact",
            MpcStatus::InfeasibleBackup => "infeasible_backup",
            MpcStatus::SolverFailedBackup => "solver_failed_backup",
        }
    }

    /// Whether the output is the backup stop.
    pub fn is_backup(self) -> bool {
        matches!(self, MpcStatus::InfeasibleBackup | MpcStatus::SolverFailedBackup)
    }
}

/// The command to send now.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MpcCommand {
    /// Forward speed at the end of the first step, `v0 + a_0·dt` [m/s].
    pub speed_m_s: f64,
    /// Yaw rate over the first step [rad/s].
    pub yaw_rate_rad_s: f64,
}

/// What one solve gives. Slacks, clearances and speed limits describe the returned
/// `predicted` trajectory (the backup stop when the status is a backup).
#[derive(Debug, Clone, PartialEq)]
pub struct MpcOutput {
    /// The command to send now.
    pub command: MpcCommand,
    /// Predicted states `x_0..x_N` (`x_0` the given state), exact rollout of `inputs`.
    pub predicted: Vec<UnicycleState>,
    /// Planned inputs `u_0..u_{N-1}`.
    pub inputs: Vec<UnicycleInput>,
    /// How the solve ended.
    pub status: MpcStatus,
    /// QPs solved (re-linearisations), 0 when the first one failed.
    pub sqp_iterations: u32,
    /// Interior-point iterations over all QPs.
    pub qp_iterations: u32,
    /// Wall time of the solve [s].
    pub solve_time_s: f64,
    /// `max(max_speed_slack_m_s, max_obstacle_slack_m)` [m/s or m].
    pub max_slack: f64,
    /// Largest excess of `|v_k|` over its risk and speed limits, `k = 1..N` [m/s].
    pub max_speed_slack_m_s: f64,
    /// Largest intrusion of a predicted footprint into a polygon's margin, `k = 1..N` [m].
    pub max_obstacle_slack_m: f64,
    /// Smallest signed distance from a predicted footprint (`k = 1..N`) to a lethal polygon
    /// [m]; infinite when there is none.
    pub min_clearance_m: f64,
    /// Upper speed limit `vhi_k` at the predicted states `k = 1..N` [m/s] (module notes, step 2).
    pub speed_limits_m_s: Vec<f64>,
    /// Reference points `r_1..r_N` of the last iteration [m].
    pub reference_points: Vec<DVec2>,
    /// The lethal polygons considered.
    pub polygons: Vec<ConvexPolygon>,
}

/// Targets of one stage, fixed during one SQP iteration (module notes, step 2).
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

/// One obstacle half-plane of a stage (module notes, step 3).
#[derive(Debug, Clone, Copy, Default)]
struct ObstacleRow {
    /// Whether the row constrains anything (else it is a placeholder of the fixed sparsity).
    used: bool,
    /// The corner's distance beyond the polygon's supporting line at the nominal [m].
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

/// The MPC tracker (module notes). Keeps the last plan to warm-start the next solve.
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
        Ok(Self { config, warm: None, ws: Workspace::default(), solver: QpSolver::new(config.solver.qp_max_iterations) })
    }

    /// The config.
    pub fn config(&self) -> &MpcConfig {
        &self.config
    }

    /// Forgets the last plan and the QP solver: the next solve starts from zero inputs.
    pub fn reset(&mut self) {
        self.warm = None;
        self.solver.reset();
    }

    /// One solve (module notes). `reference_path`: at least two finite world points with a
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
                QpOutcome::Failed if sqp_iterations == 0 => {
                    status = MpcStatus::SolverFailedBackup;
                    break;
                }
                QpOutcome::Failed => {
                    status = MpcStatus::SolvedInexact;
                    break;
                }
                QpOutcome::Inexact => status = MpcStatus::SolvedInexact,
                QpOutcome::Solved => {}
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

/// The backup stop (module notes, step 6) into `u` and `x`.
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

/// Footprint of a state.
fn footprint(c: &MpcConfig, s: &UnicycleState) -> Footprint {
    Footprint::at(s.position(), s.heading_rad, c.footprint.length_m, c.footprint.width_m)
}

/// The smallest signed distance from the footprint at `s` to any polygon [m]; infinite if none.
fn clearance(c: &MpcConfig, polygons: &[ConvexPolygon], s: &UnicycleState) -> f64 {
    let half_diagonal = 0.5 * c.footprint.length_m.hypot(c.footprint.width_m);
    let fp = footprint(c, s);
    let mut best = f64::INFINITY;
    for p in polygons {
        // The bounding circles' gap is a lower bound of the distance.
        if s.position().distance(p.centre) - half_diagonal - p.radius_m < best {
            best = best.min(separation(&fp, p).distance_m);
        }
    }
    best
}

/// Smallest obstacle slack of the footprint at `s` (>= 0) [m]: its largest intrusion into
/// the margin of any polygon.
fn obstacle_slack(c: &MpcConfig, polygons: &[ConvexPolygon], s: &UnicycleState) -> f64 {
    let half_diagonal = 0.5 * c.footprint.length_m.hypot(c.footprint.width_m);
    let margin = c.obstacles.margin_m;
    let fp = footprint(c, s);
    let mut worst = 0.0f64;
    for p in polygons {
        if s.position().distance(p.centre) - half_diagonal - p.radius_m < margin - worst {
            worst = worst.max(margin - separation(&fp, p).distance_m);
        }
    }
    worst
}

/// The nearest free sideways offsets of a path sample, `(right <= 0, left >= 0)` [m].
type SideOffsets = (Option<f64>, Option<f64>);

/// The sideways offsets (along the path normal) of a reference point nearest to zero on
/// either side, `(right <= 0, left >= 0)`, at which the footprint, with the path's heading,
/// clears every polygon by `path_clearance_m` (module notes, step 2): each polygon forbids an
/// interval of offsets ([`blocked_offsets`]), and the candidates are 0 and the points just
/// past each interval's ends. `None` on a side with no free offset within `max_path_shift_m`.
fn free_offsets(c: &MpcConfig, intervals: &mut Vec<(f64, f64)>, polygons: &[ConvexPolygon], point: DVec2, tangent: DVec2) -> SideOffsets {
    let half_diagonal = 0.5 * c.footprint.length_m.hypot(c.footprint.width_m);
    let want = c.obstacles.path_clearance_m;
    let max_shift = c.obstacles.max_path_shift_m;
    let robot = Footprint::at(DVec2::ZERO, tangent.y.atan2(tangent.x), c.footprint.length_m, c.footprint.width_m);
    let normal = tangent.perp();
    intervals.clear();
    for p in polygons {
        if point.distance(p.centre) - half_diagonal - p.radius_m < want + max_shift {
            if let Some(interval) = blocked_offsets(&robot, p, point, normal, want) {
                intervals.push(interval);
            }
        }
    }
    let free = |o: f64| o.abs() <= max_shift && intervals.iter().all(|&(lo, hi)| o <= lo || o >= hi);
    if free(0.0) {
        return (Some(0.0), Some(0.0));
    }
    let (mut right, mut left): (Option<f64>, Option<f64>) = (None, None);
    for &(lo, hi) in intervals.iter() {
        for o in [lo - PUSH_TOLERANCE_M, hi + PUSH_TOLERANCE_M] {
            if !free(o) {
                continue;
            }
            if o < 0.0 && right.is_none_or(|r| o > r) {
                right = Some(o);
            }
            if o > 0.0 && left.is_none_or(|l| o < l) {
                left = Some(o);
            }
        }
    }
    (right, left)
}

/// The sideways offsets of the path samples around the robot (module notes, step 2): each
/// run of consecutive samples where the path itself is blocked goes round on one side, the
/// one whose largest offset over the run is smaller (right on a tie); a run blocked on both
/// sides keeps offset 0 (the obstacle rows stop the robot).
fn path_offsets(c: &MpcConfig, ws: &mut Workspace, s0: f64, reach_m: f64) {
    let ramp = c.obstacles.path_shift_ramp_m;
    ws.path_offsets.clear();
    ws.path_offsets_start = s0 - ramp;
    if ws.polygons.is_empty() {
        return;
    }
    let samples = ((reach_m + 2.0 * ramp) / PATH_SAMPLE_M).ceil() as usize + 1;
    ws.side_offsets.clear();
    for i in 0..samples {
        let at = ws.reference.at_smoothed(ws.path_offsets_start + i as f64 * PATH_SAMPLE_M, c.tracking.tangent_half_window_m);
        let sides = free_offsets(c, &mut ws.intervals, &ws.polygons, at.position, at.tangent);
        ws.side_offsets.push(sides);
    }
    let mut i = 0;
    while i < samples {
        let blocked = |(r, l): SideOffsets| !(r == Some(0.0) && l == Some(0.0));
        if !blocked(ws.side_offsets[i]) {
            ws.path_offsets.push(0.0);
            i += 1;
            continue;
        }
        let end = i + ws.side_offsets[i..].iter().take_while(|&&o| blocked(o)).count();
        let run = &ws.side_offsets[i..end];
        let worst = |side: fn(&SideOffsets) -> Option<f64>| run.iter().map(side).try_fold(0.0f64, |acc, o| o.map(|o| acc.max(o.abs())));
        let (right, left) = (worst(|o| o.0), worst(|o| o.1));
        let use_left = match (right, left) {
            (Some(r), Some(l)) => l < r,
            (None, Some(_)) => true,
            _ => false,
        };
        let both_blocked = right.is_none() && left.is_none();
        for o in run {
            let offset = if both_blocked { 0.0 } else if use_left { o.1.unwrap_or(0.0) } else { o.0.unwrap_or(0.0) };
            ws.path_offsets.push(offset);
        }
        i = end;
    }
}

/// The offset at arc length `s`: of the samples within `path_shift_ramp_m`, the one with the
/// largest magnitude after scaling by `1 - distance/ramp` (a tent), so the reference leaves
/// the path gradually before an obstacle and comes back gradually after it.
fn offset_at(c: &MpcConfig, ws: &Workspace, s: f64) -> f64 {
    let ramp = c.obstacles.path_shift_ramp_m;
    let mut best = 0.0f64;
    for (i, &offset) in ws.path_offsets.iter().enumerate() {
        let distance = (ws.path_offsets_start + i as f64 * PATH_SAMPLE_M - s).abs();
        let scaled = if ramp > 0.0 { offset * (1.0 - distance / ramp) } else if distance < 0.5 * PATH_SAMPLE_M { offset } else { 0.0 };
        if distance <= ramp && scaled.abs() > best.abs() {
            best = scaled;
        }
    }
    best
}

/// `(vhi_k, vlo_k)` widened to what braking from `v0` at `a_max` can reach by step `k`
/// (plus [`ENVELOPE_SLACK_M_S`]), so the QP's hard speed rows always have a strict interior.
fn reachable_bounds(c: &MpcConfig, v0: f64, k: usize, (hi, lo): (f64, f64)) -> (f64, f64) {
    let change = c.limits.max_accel_m_s2 * c.dt_s * k as f64;
    (hi.max(v0 - change + ENVELOPE_SLACK_M_S), lo.min(v0 + change - ENVELOPE_SLACK_M_S))
}

/// `(vhi_k, vlo_k)` from the risk along `x[k-1] -> x[k] -> x[k+1]` (module notes, step 2).
fn speed_bounds(c: &MpcConfig, x: &[UnicycleState], k: usize, risk: Option<&RiskGrid<'_>>) -> (f64, f64) {
    let r = match risk {
        None => 0.0,
        Some(grid) => {
            let lookup = |p: DVec2| grid.risk_at(p).unwrap_or(c.risk.unknown_risk);
            let spacing = 0.5 * grid.resolution_m();
            let mut worst = lookup(x[k].position());
            for (a, b) in [(k - 1, k), (k, k + 1)] {
                if b >= x.len() {
                    continue;
                }
                let (pa, pb) = (x[a].position(), x[b].position());
                // Both ends included. A straight step crosses at most nx + ny cells: four
                // samples per cell it can cross bound the work on a fine grid (a tiny
                // resolution) without thinning the half-cell spacing on any real one.
                let budget = (4 * (grid.nx + grid.ny) + 16) as f64;
                let samples = ((pa.distance(pb) / spacing).ceil().min(budget) as usize).max(1);
                for i in 0..=samples {
                    worst = worst.max(lookup(pa + (pb - pa) * (i as f64 / samples as f64)));
                }
            }
            worst
        }
    };
    let hi = c.limits.max_speed_m_s * (1.0 - r);
    (hi, c.limits.min_speed_m_s.max(-hi))
}

/// Steps 1-3 of the module notes: rollout with Jacobians, targets, speed bounds, obstacle rows.
fn linearise(c: &MpcConfig, ws: &mut Workspace, state: &UnicycleState, s0: f64, desired: f64, risk: Option<&RiskGrid<'_>>) {
    let n = c.horizon;
    let t = c.dt_s;
    ws.x.clear();
    ws.x.push(*state);
    ws.jacobians.clear();
    for k in 0..n {
        let (next, jac) = step_with_jacobians(&ws.x[k], &ws.u[k], t);
        ws.x.push(next);
        ws.jacobians.push(jac);
    }
    let length = ws.reference.length();
    ws.targets.clear();
    let mut travel = 0.0;
    for k in 1..=n {
        travel += 0.5 * (ws.x[k - 1].speed_m_s + ws.x[k].speed_m_s) * t;
        let s = (s0 + travel).clamp(0.0, length);
        let at = ws.reference.at_smoothed(s, c.tracking.tangent_half_window_m);
        // The moved path: its point, and its direction from the offset's slope.
        let offset = offset_at(c, ws, s);
        let slope = (offset_at(c, ws, s + PATH_SAMPLE_M) - offset_at(c, ws, s - PATH_SAMPLE_M)) / (2.0 * PATH_SAMPLE_M);
        let tangent = (at.tangent + at.tangent.perp() * slope).normalize();
        let heading = tangent.y.atan2(tangent.x);
        let turns = ((ws.x[k].heading_rad - heading) / std::f64::consts::TAU).round();
        let (speed_hi, speed_lo) = reachable_bounds(c, state.speed_m_s, k, speed_bounds(c, &ws.x, k, risk));
        ws.targets.push(StageTarget {
            point: at.position + at.tangent.perp() * offset,
            tangent,
            heading_rad: heading + turns * std::f64::consts::TAU,
            speed_m_s: desired.min((2.0 * c.tracking.end_decel_m_s2 * (length - s)).sqrt()),
            factor: if k == n { c.weights.terminal_factor } else { 1.0 },
            speed_hi,
            speed_lo,
        });
    }

    let per_stage = c.obstacles.max_per_stage;
    let rows_per_stage = 2 * per_stage;
    ws.rows.clear();
    ws.rows.resize(n * rows_per_stage, ObstacleRow::default());
    if ws.polygons.is_empty() || per_stage == 0 {
        return;
    }
    let half_diagonal = 0.5 * c.footprint.length_m.hypot(c.footprint.width_m);
    let reach = c.obstacles.margin_m + c.obstacles.activation_m;
    for k in 1..=n {
        let s = ws.x[k];
        let fp = footprint(c, &s);
        ws.candidates.clear();
        for (i, p) in ws.polygons.iter().enumerate() {
            if s.position().distance(p.centre) - half_diagonal - p.radius_m >= reach {
                continue;
            }
            let d = separation(&fp, p).distance_m;
            if d < reach {
                ws.candidates.push((d, i));
            }
        }
        ws.candidates.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        for (j, &(_, i)) in ws.candidates.iter().take(per_stage).enumerate() {
            let p = &ws.polygons[i];
            let normal = separation(&fp, p).normal;
            for (r, (distance_m, corner)) in supporting_corners(&fp, p, normal).into_iter().enumerate() {
                let lever_m = normal.dot((corner - s.position()).perp());
                ws.rows[(k - 1) * rows_per_stage + 2 * j + r] = ObstacleRow { used: true, distance_m, normal, lever_m };
            }
        }
    }
}

/// Index of input `ch` (0: a, 1: ω) of step `k` in `z`.
#[inline]
fn iu(k: usize, ch: usize) -> usize {
    STAGE_VARS * k + ch
}

/// Index of component `i` of state `k >= 1` (`[x, y, θ, v]`) in `z`.
#[inline]
fn ix(k: usize, i: usize) -> usize {
    STAGE_VARS * (k - 1) + 2 + i
}

/// Index of the obstacle slack of state `k >= 1`.
#[inline]
fn iso(k: usize) -> usize {
    STAGE_VARS * (k - 1) + 6
}

/// Step 4 of the module notes: the QP around the nominal, into `ws.qp`. Variables stage by
/// stage, `z = [δa_k, δω_k, δx_{k+1}, δy_{k+1}, δθ_{k+1}, δv_{k+1}, σv_{k+1}, σo_{k+1}]_{k<N}`,
/// so `P` is block diagonal (plus the input-rate couplings) and the KKT system banded; only
/// used obstacle rows enter `A`.
fn build_qp(c: &MpcConfig, ws: &mut Workspace, previous_input: Option<UnicycleInput>) {
    let n = c.horizon;
    let nz = STAGE_VARS * n;
    let w = &c.weights;
    let qp = &mut ws.qp;
    // P (upper triangle) as its diagonal and three kinds of off-diagonal entries.
    let diag = &mut ws.p_diag;
    diag.clear();
    diag.resize(nz, 0.0);
    let off = &mut ws.p_off;
    off.clear();
    // Per stage k: P[a_{k-1}, a_k], P[ω_{k-1}, ω_k], P[x_{k+1}, y_{k+1}].
    off.resize(n, [0.0; 3]);
    qp.q.clear();
    qp.q.resize(nz, 0.0);
    let q = &mut qp.q;

    for (k, &u) in ws.u.iter().enumerate() {
        for (ch, value, effort, rate) in [(0, u.accel_m_s2, w.accel, w.accel_rate), (1, u.yaw_rate_rad_s, w.yaw_rate, w.yaw_rate_rate)] {
            let i = iu(k, ch);
            diag[i] += 2.0 * effort;
            q[i] += 2.0 * effort * value;
            let before = if k > 0 {
                let b = ws.u[k - 1];
                Some((if ch == 0 { b.accel_m_s2 } else { b.yaw_rate_rad_s }, Some(iu(k - 1, ch))))
            } else {
                previous_input.map(|b| (if ch == 0 { b.accel_m_s2 } else { b.yaw_rate_rad_s }, None))
            };
            if let Some((prev, prev_index)) = before {
                let e = value - prev;
                diag[i] += 2.0 * rate;
                q[i] += 2.0 * rate * e;
                if let Some(j) = prev_index {
                    diag[j] += 2.0 * rate;
                    q[j] -= 2.0 * rate * e;
                    off[k][ch] = -2.0 * rate;
                }
            }
        }
    }
    for k in 1..=n {
        let t = ws.targets[k - 1];
        let s = ws.x[k];
        let f = t.factor;
        let nrm = t.tangent.perp();
        let e = s.position() - t.point;
        let (ec, el) = (nrm.dot(e), t.tangent.dot(e));
        let (px, py) = (ix(k, 0), ix(k, 1));
        diag[px] += 2.0 * f * (w.contour * nrm.x * nrm.x + w.lag * t.tangent.x * t.tangent.x);
        diag[py] += 2.0 * f * (w.contour * nrm.y * nrm.y + w.lag * t.tangent.y * t.tangent.y);
        off[k - 1][2] = 2.0 * f * (w.contour * nrm.x * nrm.y + w.lag * t.tangent.x * t.tangent.y);
        q[px] += 2.0 * f * (w.contour * ec * nrm.x + w.lag * el * t.tangent.x);
        q[py] += 2.0 * f * (w.contour * ec * nrm.y + w.lag * el * t.tangent.y);
        diag[ix(k, 2)] += 2.0 * f * w.heading;
        q[ix(k, 2)] += 2.0 * f * w.heading * (s.heading_rad - t.heading_rad);
        diag[ix(k, 3)] += 2.0 * f * w.speed;
        q[ix(k, 3)] += 2.0 * f * w.speed * (s.speed_m_s - t.speed_m_s);
        diag[iso(k)] += 2.0 * w.slack_quadratic;
        q[iso(k)] += w.slack_linear;
    }
    // P in compressed columns; rows increase within each column.
    let p = &mut qp.p;
    p.rows = nz;
    p.cols = nz;
    p.colptr.clear();
    p.rowval.clear();
    p.nzval.clear();
    for (col, &d) in diag.iter().enumerate() {
        p.colptr.push(p.rowval.len());
        let k = col / STAGE_VARS;
        match col % STAGE_VARS {
            ch @ (0 | 1) if k > 0 => {
                p.rowval.push(col - STAGE_VARS);
                p.nzval.push(off[k][ch]);
            }
            3 => {
                p.rowval.push(col - 1);
                p.nzval.push(off[k][2]);
            }
            _ => {}
        }
        p.rowval.push(col);
        p.nzval.push(d);
    }
    p.colptr.push(p.rowval.len());

    // A and b: the dynamics (equalities) first, then every inequality.
    let b = &mut qp.b;
    b.clear();
    let a = &mut ws.builder;
    a.clear();
    let mut row = 0;
    for k in 0..n {
        let jac = &ws.jacobians[k];
        for i in 0..4 {
            // δx_{k+1} - A_k δx_k - B_k δu_k = 0 over the Jacobians' structural entries
            // (δx_0 = 0: the start is given).
            if k > 0 {
                for j in 0..4 {
                    if i == j || (i < 2 && j >= 2) {
                        a.push(row, ix(k, j), -jac.a[i][j]);
                    }
                }
            }
            for ch in 0..2 {
                if i < 2 || (i == 2 && ch == 1) || (i == 3 && ch == 0) {
                    a.push(row, iu(k, ch), -jac.b[i][ch]);
                }
            }
            a.push(row, ix(k + 1, i), 1.0);
            b.push(0.0);
            row += 1;
        }
    }
    qp.equalities = row;
    let lim = &c.limits;
    for k in 0..n {
        let u = ws.u[k];
        for (ch, value, max) in [(0, u.accel_m_s2, lim.max_accel_m_s2), (1, u.yaw_rate_rad_s, lim.max_yaw_rate_rad_s)] {
            a.push(row, iu(k, ch), 1.0);
            b.push(max - value);
            a.push(row + 1, iu(k, ch), -1.0);
            b.push(max + value);
            row += 2;
        }
    }
    let rows_per_stage = 2 * c.obstacles.max_per_stage;
    let uniform_rows = ws.rows.chunks(rows_per_stage.max(1)).map(|stage| stage.iter().take_while(|r| r.used).count()).max().unwrap_or(0);
    for k in 1..=n {
        let t = ws.targets[k - 1];
        let v = ws.x[k].speed_m_s;
        // vlo_k <= v_k <= vhi_k (hard, widened to the braking envelope);  σo >= 0.
        a.push(row, ix(k, 3), 1.0);
        b.push(t.speed_hi - v);
        a.push(row + 1, ix(k, 3), -1.0);
        b.push(v - t.speed_lo);
        a.push(row + 2, iso(k), -1.0);
        b.push(0.0);
        row += 3;
        // Every stage gets `uniform_rows` obstacle rows, the most any stage uses: the pattern
        // then depends on that one number and the cached solvers are reused.
        for r in ws.rows[(k - 1) * rows_per_stage..(k - 1) * rows_per_stage + uniform_rows].iter() {
            // -(n·δp + lever·δθ) - σo <= d̄ - margin; an unused row only bounds σo below by
            // -UNUSED_ROW_RHS_M.
            a.push(row, ix(k, 0), -r.normal.x);
            a.push(row, ix(k, 1), -r.normal.y);
            a.push(row, ix(k, 2), -r.lever_m);
            a.push(row, iso(k), -1.0);
            b.push(if r.used { r.distance_m - c.obstacles.margin_m } else { UNUSED_ROW_RHS_M });
            row += 1;
        }
    }
    a.finish(row, nz, &mut qp.a);
}

/// The merit of a trajectory (module notes, step 5).
#[derive(Debug, Clone, Copy)]
struct Merit {
    /// `φ`: the cost with the current targets and the exact penalties.
    cost: f64,
    /// Largest excess of a speed over its widened bounds [m/s].
    speed_excess_m_s: f64,
    /// Largest intrusion of a footprint into an obstacle's margin [m].
    obstacle_intrusion_m: f64,
}

impl Merit {
    /// The filter's measure: `max(speed excess [m/s], margin intrusion [m])`.
    fn violation(&self) -> f64 {
        self.speed_excess_m_s.max(self.obstacle_intrusion_m)
    }
}

/// Cost of a trajectory with the current targets, slacks at their smallest for the
/// trajectory's own speed bounds and clearances (module notes, step 5).
fn merit(
    c: &MpcConfig,
    targets: &[StageTarget],
    polygons: &[ConvexPolygon],
    risk: Option<&RiskGrid<'_>>,
    x: &[UnicycleState],
    u: &[UnicycleInput],
    previous_input: Option<UnicycleInput>,
) -> Merit {
    let w = &c.weights;
    let mut cost = 0.0;
    let (mut speed, mut obstacle) = (0.0f64, 0.0f64);
    for (k, input) in u.iter().enumerate() {
        cost += w.accel * input.accel_m_s2 * input.accel_m_s2 + w.yaw_rate * input.yaw_rate_rad_s * input.yaw_rate_rad_s;
        let before = if k > 0 { Some(u[k - 1]) } else { previous_input };
        if let Some(b) = before {
            let (da, dw) = (input.accel_m_s2 - b.accel_m_s2, input.yaw_rate_rad_s - b.yaw_rate_rad_s);
            cost += w.accel_rate * da * da + w.yaw_rate_rate * dw * dw;
        }
    }
    for (k, t) in targets.iter().enumerate() {
        let s = &x[k + 1];
        let e = s.position() - t.point;
        let (ec, el) = (t.tangent.perp().dot(e), t.tangent.dot(e));
        let (eh, ev) = (s.heading_rad - t.heading_rad, s.speed_m_s - t.speed_m_s);
        cost += t.factor * (w.contour * ec * ec + w.lag * el * el + w.heading * eh * eh + w.speed * ev * ev);
        let (hi, lo) = reachable_bounds(c, x[0].speed_m_s, k + 1, speed_bounds(c, x, k + 1, risk));
        let sv = (s.speed_m_s - hi).max(lo - s.speed_m_s).max(0.0);
        let so = obstacle_slack(c, polygons, s);
        cost += w.slack_linear * (sv + so) + w.slack_quadratic * (sv * sv + so * so);
        speed = speed.max(sv);
        obstacle = obstacle.max(so);
    }
    Merit { cost, speed_excess_m_s: speed, obstacle_intrusion_m: obstacle }
}

/// What the line search did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    /// A step was taken; `go_on`: it was not below `step_tolerance`.
    Accepted { go_on: bool },
    /// Every trial step was refused.
    Refused,
    /// The QP predicts no decrease: the nominal is optimal for it.
    Converged,
}

/// After a refused line search: each stage's speed bounds also hold along the full QP
/// step's rollout (module notes, step 5), for a second QP from the same nominal.
fn tighten_speed_bounds(c: &MpcConfig, ws: &mut Workspace, state: &UnicycleState, risk: Option<&RiskGrid<'_>>) {
    ws.trial_u.clear();
    for (k, u) in ws.u.iter().enumerate() {
        ws.trial_u.push(UnicycleInput {
            accel_m_s2: (u.accel_m_s2 + ws.z[iu(k, 0)]).clamp(-c.limits.max_accel_m_s2, c.limits.max_accel_m_s2),
            yaw_rate_rad_s: (u.yaw_rate_rad_s + ws.z[iu(k, 1)]).clamp(-c.limits.max_yaw_rate_rad_s, c.limits.max_yaw_rate_rad_s),
        });
    }
    rollout(state, &ws.trial_u, c.dt_s, &mut ws.trial_x);
    for k in 1..=c.horizon {
        let (hi, lo) = reachable_bounds(c, state.speed_m_s, k, speed_bounds(c, &ws.trial_x, k, risk));
        let t = &mut ws.targets[k - 1];
        t.speed_hi = t.speed_hi.min(hi);
        t.speed_lo = t.speed_lo.max(lo);
    }
}

/// Step 5 of the module notes. Updates `ws.u` (and `ws.x` to its rollout) when a step is
/// accepted.
fn line_search(c: &MpcConfig, ws: &mut Workspace, state: &UnicycleState, risk: Option<&RiskGrid<'_>>, previous_input: Option<UnicycleInput>) -> Step {
    let n = c.horizon;
    // Model change from δ = 0 (slacks at their smallest) to the QP's solution.
    let z = &ws.z;
    let p = &ws.qp.p;
    let mut model = 0.0;
    for col in 0..p.cols {
        for idx in p.colptr[col]..p.colptr[col + 1] {
            let r = p.rowval[idx];
            let scale = if r == col { 0.5 } else { 1.0 };
            model += scale * p.nzval[idx] * z[r] * z[col];
        }
        model += ws.qp.q[col] * z[col];
    }
    let w = &c.weights;
    let rows_per_stage = 2 * c.obstacles.max_per_stage;
    let mut model_at_zero = 0.0;
    for k in 1..=n {
        let t = ws.targets[k - 1];
        let v = ws.x[k].speed_m_s;
        let sv = (v - t.speed_hi).max(t.speed_lo - v).max(0.0);
        let so = ws.rows[(k - 1) * rows_per_stage..k * rows_per_stage]
            .iter()
            .filter(|r| r.used)
            .fold(0.0f64, |acc, r| acc.max(c.obstacles.margin_m - r.distance_m));
        // The QP's speed rows are hard: its solution has no speed excess left.
        model_at_zero += w.slack_linear * (sv + so) + w.slack_quadratic * (sv * sv + so * so);
    }
    let predicted = model - model_at_zero;
    if predicted > -MIN_PREDICTED_DECREASE {
        return Step::Converged;
    }
    let merit0 = merit(c, &ws.targets, &ws.polygons, risk, &ws.x, &ws.u, previous_input);
    let mut alpha = 1.0;
    for _ in 0..c.solver.line_search_steps {
        ws.trial_u.clear();
        let mut largest_step = 0.0f64;
        for k in 0..n {
            let (da, dw) = (alpha * ws.z[iu(k, 0)], alpha * ws.z[iu(k, 1)]);
            largest_step = largest_step.max(da.abs()).max(dw.abs());
            let u = ws.u[k];
            ws.trial_u.push(UnicycleInput {
                accel_m_s2: (u.accel_m_s2 + da).clamp(-c.limits.max_accel_m_s2, c.limits.max_accel_m_s2),
                yaw_rate_rad_s: (u.yaw_rate_rad_s + dw).clamp(-c.limits.max_yaw_rate_rad_s, c.limits.max_yaw_rate_rad_s),
            });
        }
        rollout(state, &ws.trial_u, c.dt_s, &mut ws.trial_x);
        let trial = merit(c, &ws.targets, &ws.polygons, risk, &ws.trial_x, &ws.trial_u, previous_input);
        let decreases = trial.cost <= merit0.cost + ARMIJO * alpha * predicted;
        let no_worse = trial.violation() <= merit0.violation() + FILTER_M;
        if decreases && no_worse {
            std::mem::swap(&mut ws.u, &mut ws.trial_u);
            std::mem::swap(&mut ws.x, &mut ws.trial_x);
            return Step::Accepted { go_on: largest_step > c.solver.step_tolerance };
        }
        alpha *= 0.5;
    }
    Step::Refused
}

#[cfg(test)]
mod tests;
