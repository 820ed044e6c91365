//! Steps 1-3 of `MpcTracker`'s docs: the nominal's rollout with its Jacobians, each stage's
//! targets and risk-limited speed bounds, and the obstacle rows.

use glam::DVec2;

use super::clearance::footprint;
use super::geometry::{separation, supporting_corners};
use super::path_shift::{offset_at, PATH_SAMPLE_M};
use super::{step_with_jacobians, MpcConfig, ObstacleRow, RiskGrid, StageTarget, UnicycleState, Workspace};

/// The braking envelope of the speed bounds is widened by this [m/s], so that braking at
/// exactly `a_max` is inside the feasible set rather than on its edge.
const ENVELOPE_SLACK_M_S: f64 = 1e-3;

/// `(vhi_k, vlo_k)` widened to what braking from `v0` at `a_max` can reach by step `k`
/// (plus [`ENVELOPE_SLACK_M_S`]), so the QP's hard speed rows always have a strict interior.
pub(super) fn reachable_bounds(c: &MpcConfig, v0: f64, k: usize, (hi, lo): (f64, f64)) -> (f64, f64) {
    let change = c.limits.max_accel_m_s2 * c.dt_s * k as f64;
    (hi.max(v0 - change + ENVELOPE_SLACK_M_S), lo.min(v0 + change - ENVELOPE_SLACK_M_S))
}

/// `(vhi_k, vlo_k)` from the risk along `x[k-1] -> x[k] -> x[k+1]` (`MpcTracker`'s docs, step 2).
pub(super) fn speed_bounds(c: &MpcConfig, x: &[UnicycleState], k: usize, risk: Option<&RiskGrid<'_>>) -> (f64, f64) {
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

/// Steps 1-3 of `MpcTracker`'s docs: rollout with Jacobians, targets, speed bounds, obstacle rows.
pub(super) fn linearise(c: &MpcConfig, ws: &mut Workspace, state: &UnicycleState, s0: f64, desired: f64, risk: Option<&RiskGrid<'_>>) {
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
