//! Moving the reference path around obstacles (`MpcTracker`'s docs, step 2): the free sideways
//! offsets of path samples, the side each blocked run goes round on, and the tent-shaped
//! offset at any arc length.

use glam::DVec2;

use super::geometry::{blocked_offsets, Footprint};
use super::{ConvexPolygon, MpcConfig, Workspace};

/// Spacing of the path samples whose sideways offsets are worked out \[m\].
pub(super) const PATH_SAMPLE_M: f64 = 0.1;
/// [`free_offsets`] steps this far past the end of a blocked interval \[m\] (rounding).
const PUSH_TOLERANCE_M: f64 = 1e-6;

/// The nearest free sideways offsets of a path sample, `(right <= 0, left >= 0)` \[m\].
pub(super) type SideOffsets = (Option<f64>, Option<f64>);

/// The sideways offsets (along the path normal) of a reference point nearest to zero on
/// either side, `(right <= 0, left >= 0)`, at which the footprint, with the path's heading,
/// clears every polygon by `path_clearance_m` (`MpcTracker`'s docs, step 2): each polygon forbids an
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

/// The sideways offsets of the path samples around the robot (`MpcTracker`'s docs, step 2): each
/// run of consecutive samples where the path itself is blocked goes round on one side, the
/// one whose largest offset over the run is smaller (right on a tie); a run blocked on both
/// sides keeps offset 0 (the obstacle rows stop the robot).
pub(super) fn path_offsets(c: &MpcConfig, ws: &mut Workspace, s0: f64, reach_m: f64) {
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
pub(super) fn offset_at(c: &MpcConfig, ws: &Workspace, s: f64) -> f64 {
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
