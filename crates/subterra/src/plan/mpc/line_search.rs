//! Step 5 of `MpcTracker`'s docs: the merit of a trajectory and the filtered line search along
//! the QP's step, and the tightened speed bounds after a refused one.

use super::assemble::iu;
use super::clearance::obstacle_slack;
use super::linearise::{reachable_bounds, speed_bounds};
use super::{rollout, ConvexPolygon, MpcConfig, RiskGrid, StageTarget, UnicycleInput, UnicycleState, Workspace};

/// A line-search step may not raise `max(largest speed-limit excess [m/s], largest intrusion
/// into an obstacle margin \[m\])` by more than this.
const FILTER_M: f64 = 1e-4;
/// Sufficient-decrease fraction of the line search (Armijo).
const ARMIJO: f64 = 1e-4;
/// A predicted decrease of the QP model smaller than this means the nominal is optimal.
const MIN_PREDICTED_DECREASE: f64 = 1e-12;

/// The merit of a trajectory (`MpcTracker`'s docs, step 5).
#[derive(Debug, Clone, Copy)]
struct Merit {
    /// `φ`: the cost with the current targets and the exact penalties.
    cost: f64,
    /// Largest excess of a speed over its widened bounds [m/s].
    speed_excess_m_s: f64,
    /// Largest intrusion of a footprint into an obstacle's margin \[m\].
    obstacle_intrusion_m: f64,
}

impl Merit {
    /// The filter's measure: `max(speed excess [m/s], margin intrusion [m])`.
    fn violation(&self) -> f64 {
        self.speed_excess_m_s.max(self.obstacle_intrusion_m)
    }
}

/// Cost of a trajectory with the current targets, slacks at their smallest for the
/// trajectory's own speed bounds and clearances (`MpcTracker`'s docs, step 5).
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
pub(super) enum Step {
    /// A step was taken; `go_on`: it was not below `step_tolerance`.
    Accepted { go_on: bool },
    /// Every trial step was refused.
    Refused,
    /// The QP predicts no decrease: the nominal is optimal for it.
    Converged,
}

/// After a refused line search: each stage's speed bounds also hold along the full QP
/// step's rollout (`MpcTracker`'s docs, step 5), for a second QP from the same nominal.
pub(super) fn tighten_speed_bounds(c: &MpcConfig, ws: &mut Workspace, state: &UnicycleState, risk: Option<&RiskGrid<'_>>) {
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

/// Step 5 of `MpcTracker`'s docs. Updates `ws.u` (and `ws.x` to its rollout) when a step is
/// accepted.
pub(super) fn line_search(c: &MpcConfig, ws: &mut Workspace, state: &UnicycleState, risk: Option<&RiskGrid<'_>>, previous_input: Option<UnicycleInput>) -> Step {
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
