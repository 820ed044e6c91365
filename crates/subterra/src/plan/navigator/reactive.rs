//! The reactive behaviours (`rotate`, `back_out`) and the check every one of them passes
//! before it moves: the **swept footprint** of its next motion against the current map and
//! the memories ([`SafetyView::sweep`]). A motion that would put any part of the footprint on
//! a cell that is blocking (at or above the planner's threshold in force, or lethal) or
//! **unknown** (unobserved by the map, not remembered by the near memory, never stood on) is
//! not made: the behaviour tries its other way (the other turning direction, turning in place
//! instead of reversing) and stops, with the reason, when none is safe. Recoveries run when the
//! map is least trusted, beside what stopped the robot, often in the lidar's blind ring: they
//! must not move where the robot cannot know the ground holds.

use std::f64::consts::PI;
use std::cmp::Ordering;

use glam::DVec2;

use super::memory::{for_cells_within, for_footprint_cells, DrivenMemory, HazardMemory, NearMemory, WorldCell};
use super::NavigatorSettings;
use crate::error::Result;
use crate::plan::astar::{EntryPrices, PlanOutcome, RiskAStar};
use crate::plan::grid::RiskGrid;
use crate::plan::recovery::wrap_angle;
use crate::terrain::{GridGeometry, RobotConfig};

/// Why a cell may not be swept.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Blocked {
    /// The cell's risk is at or above the blocking level.
    Risky {
        /// Its centre [m, world].
        at: DVec2,
        /// Its risk.
        risk: f32,
    },
    /// Nothing is known of the cell.
    Unknown {
        /// Its centre [m, world].
        at: DVec2,
    },
}

impl Blocked {
    /// In words, for the event log.
    pub(super) fn describe(&self) -> String {
        match *self {
            Blocked::Risky { at, risk } => format!("the footprint would sweep a cell of risk {risk:.2} at ({:.2}, {:.2})", at.x, at.y),
            Blocked::Unknown { at } => format!("the footprint would sweep an unknown cell at ({:.2}, {:.2})", at.x, at.y),
        }
    }
}

/// What a sweep is checked against.
pub(crate) struct SafetyView<'a> {
    /// The navigator's grid: the map's ratings where observed, raised by the hazard memory,
    /// the near memory's where unobserved near the robot (NaN elsewhere).
    pub grid: RiskGrid<'a>,
    /// The hazard memory (for cells off the map).
    pub hazards: &'a HazardMemory,
    /// The near memory: a cell it holds was observed.
    pub near: &'a NearMemory,
    /// The cells the robot stood on: known to carry it.
    pub driven: &'a DrivenMemory,
    /// Cells at or above this risk block \[1\].
    pub blocking: f32,
    /// The lethal level \[1\].
    pub lethal: f32,
    /// Whether an unknown cell (unobserved, not remembered, never stood on) blocks. If not,
    /// it still blocks within `unknown_near_lethal_m` of a lethal cell (a hazard's unseen
    /// part: its shadow, its far rim).
    pub unknown_blocks: bool,
    /// See `unknown_blocks` \[m\].
    pub unknown_near_lethal_m: f64,
    /// The robot.
    pub robot: RobotConfig,
    /// Added to the footprint on every side \[m\].
    pub margin_m: f64,
    /// Whether a cell counts when any part of it is under the footprint (its centre within
    /// half a cell of it), or only when its centre is: the recoveries take the first, the
    /// tracker the second, which is what the A* plans with (lethal cells inflated by the
    /// inscribed radius between cell centres).
    pub cell_overlap: bool,
}

impl SafetyView<'_> {
    /// The grid's value at `cell` (the hazard memory's off the map; NaN: unknown).
    fn value(&self, cell: WorldCell) -> f32 {
        match self.grid.map_geometry().and_then(|g| cell.flat_on(g)) {
            Some(c) => self.grid.risk()[c],
            None => self.hazards.get(cell).unwrap_or(f32::NAN),
        }
    }

    /// Why `cell` may not be swept, if it may not.
    fn check(&self, cell: WorldCell) -> Option<Blocked> {
        let res = self.grid.resolution_m();
        let at = (DVec2::new(cell.x as f64, cell.y as f64) + 0.5) * res;
        let value = self.value(cell);
        // The near memory's rating counts too, as in the grid: below lethal only (lethal
        // cells are remembered by the hazard memory, which keeps patches, not speckles).
        let remembered = self.near.below_lethal(cell, self.lethal);
        let worst = remembered.map_or(value, |r| if value >= r { value } else { r });
        if worst >= self.blocking {
            return Some(Blocked::Risky { at, risk: worst });
        }
        if !value.is_nan() || self.near.get(cell).is_some() {
            return None;
        }
        if self.driven.contains(cell) {
            return None;
        }
        if self.unknown_blocks {
            return Some(Blocked::Unknown { at });
        }
        let reach = (self.unknown_near_lethal_m / res).floor() as i64;
        let r2 = (self.unknown_near_lethal_m / res).powi(2) * (1.0 + 1e-9);
        for dy in -reach..=reach {
            for dx in -reach..=reach {
                if (dx * dx + dy * dy) as f64 <= r2 && self.value(WorldCell { x: cell.x + dx, y: cell.y + dy }) >= self.lethal {
                    return Some(Blocked::Unknown { at });
                }
            }
        }
        None
    }

    /// The cells (centres within half a cell of it) of the footprint plus the margin at a pose.
    fn footprint_cells(&self, position: DVec2, heading: f64, mut f: impl FnMut(WorldCell)) {
        let res = self.grid.resolution_m();
        let grow = 2.0 * self.margin_m + if self.cell_overlap { res } else { 0.0 };
        for_footprint_cells(position, heading, self.robot.length_m + grow, self.robot.width_m + grow, res, &mut f);
    }

    /// The first cell that may not be swept among those the footprint (plus the margin) would
    /// newly cover at any of `poses` (`(position, heading)`) starting from `from`: the cells it
    /// covers at `from` already are where the robot is, and a motion away from them is allowed.
    pub(super) fn sweep(&self, from: (DVec2, f64), poses: impl IntoIterator<Item = (DVec2, f64)>) -> Option<Blocked> {
        self.first_blocked(from, poses).map(|(_, blocked)| blocked)
    }

    /// [`SafetyView::sweep`], with the index among `poses` of the first pose that is blocked.
    pub(super) fn first_blocked(&self, from: (DVec2, f64), poses: impl IntoIterator<Item = (DVec2, f64)>) -> Option<(usize, Blocked)> {
        let mut here = Vec::new();
        self.footprint_cells(from.0, from.1, |cell| here.push(cell));
        here.sort_unstable();
        let mut found = None;
        for (k, (position, heading)) in poses.into_iter().enumerate() {
            self.footprint_cells(position, heading, |cell| {
                if found.is_none() && here.binary_search(&cell).is_err() {
                    found = self.check(cell);
                }
            });
            if let Some(blocked) = found {
                return Some((k, blocked));
            }
        }
        None
    }

    /// The poses of a turn in place at `position` from `from_rad` by `angle_rad` (signed), so
    /// spaced that no corner moves more than half a cell between two.
    pub(super) fn turn_poses(&self, position: DVec2, from_rad: f64, angle_rad: f64) -> impl Iterator<Item = (DVec2, f64)> {
        let reach = 0.5 * self.robot.length_m.hypot(self.robot.width_m) + self.margin_m;
        let step = 0.5 * self.grid.resolution_m() / reach;
        let n = (angle_rad.abs() / step).ceil().max(1.0) as usize;
        (1..=n).map(move |k| (position, from_rad + angle_rad * k as f64 / n as f64))
    }
}

/// The poses of a unicycle from `(position, heading)` at speed `v` and yaw rate `w` over
/// `duration_s`, so spaced that the footprint moves at most half a cell between two.
pub(crate) fn arc_poses(position: DVec2, heading: f64, v: f64, w: f64, duration_s: f64, view: &SafetyView<'_>) -> Vec<(DVec2, f64)> {
    let reach = 0.5 * view.robot.length_m.hypot(view.robot.width_m) + view.margin_m;
    let per_s = v.abs() + w.abs() * reach;
    let n = ((per_s * duration_s) / (0.5 * view.grid.resolution_m())).ceil().clamp(1.0, 400.0) as usize;
    let dt = duration_s / n as f64;
    let (mut p, mut psi) = (position, heading);
    (0..n)
        .map(|_| {
            p += DVec2::from_angle(psi + 0.5 * w * dt) * (v * dt);
            psi += w * dt;
            (p, psi)
        })
        .collect()
}

/// The poses of a robot following the polyline `path` (world, at least two points): points
/// every `spacing_m` of arc length after the first, each with the heading of the chord from
/// `half_window_m` behind it to `half_window_m` ahead of it along the path (the tangent the
/// tracker steers to, [`crate::plan::mpc`]'s `tangent_half_window_m`).
pub(crate) fn path_poses(path: &[DVec2], spacing_m: f64, half_window_m: f64) -> Vec<(DVec2, f64)> {
    let mut along = Vec::with_capacity(path.len());
    let mut total = 0.0;
    for (k, p) in path.iter().enumerate() {
        if k > 0 {
            total += p.distance(path[k - 1]);
        }
        along.push(total);
    }
    let at = |s: f64| -> DVec2 {
        let s = s.clamp(0.0, total);
        let k = along.partition_point(|&a| a < s).clamp(1, path.len() - 1);
        let (a, b) = (along[k - 1], along[k]);
        let t = if b > a { (s - a) / (b - a) } else { 0.0 };
        path[k - 1].lerp(path[k], t)
    };
    let n = (total / spacing_m.max(1e-6)).ceil().min(100_000.0) as usize;
    (1..=n)
        .map(|k| {
            let s = (k as f64 * spacing_m).min(total);
            let chord = at(s + half_window_m) - at(s - half_window_m);
            (at(s), chord.y.atan2(chord.x))
        })
        .collect()
}

/// What [`footprint_checked`] checks a plan with.
pub(crate) struct FootprintReplan<'a> {
    /// The tracker's footprint test.
    pub view: &'a SafetyView<'a>,
    /// The robot's pose `(position, heading)`: the cells under it now do not block.
    pub from: (DVec2, f64),
    /// The goal the A* plans to [m, world].
    pub goal: DVec2,
    /// At most this many new searches.
    pub replans: u32,
    /// Half the window of the path's tangent \[m\].
    pub half_window_m: f64,
}

/// The footprint-checked plan (`NavigatorSettings::footprint_replans`): `outcome`, the A*'s
/// plan on `astar` (geometry `g`), if the footprint along its path ([`path_poses`], every half
/// cell, the heading that of the chord over the robot's length or the tracker's tangent
/// window if longer; poses whose closing would reach the start or the goal left out) passes
/// `replan.view`; else, at most `replan.replans` times, the cells within the
/// difference of the circumscribed and the inscribed radius (at least a cell) of the first
/// pose that fails are closed (set to `lethal`) and the A* plans again, until a path passes.
/// If none does (or a search finds no path), the last path found.
pub(crate) fn footprint_checked(
    planner: &mut RiskAStar,
    astar: &[f32],
    g: &GridGeometry,
    lethal: f32,
    entry: Option<&EntryPrices<'_>>,
    replan: &FootprintReplan<'_>,
    mut outcome: PlanOutcome,
) -> Result<PlanOutcome> {
    let robot = replan.view.robot;
    let close_m = (0.5 * robot.length_m.hypot(robot.width_m) - 0.5 * robot.width_m).max(g.resolution_m);
    let mut closed: Option<Vec<f32>> = None;
    for _ in 0..replan.replans {
        let Some(path) = outcome.found() else { break };
        let Some(((at, _), _)) = first_blocked_along(replan, &path.points_world, g.resolution_m) else { break };
        let closed = closed.get_or_insert_with(|| astar.to_vec());
        for_cells_within(g, at, close_m, |_, c| closed[c] = lethal);
        let retry = planner.plan_with(&RiskGrid::on_geometry(closed, g)?, replan.from.0, replan.goal, entry)?;
        if retry.found().is_none() {
            break;
        }
        outcome = retry;
    }
    Ok(outcome)
}

/// The first pose along `path` (from `replan.from` to `replan.goal`) whose footprint
/// `replan.view` refuses, with why ([`footprint_checked`]'s test: poses every half cell of
/// side `resolution_m`, the heading that of the chord over the robot's length or the
/// tracker's tangent window if longer, poses whose closing would reach the start or the goal
/// left out); `None` if the robot can follow the whole path.
pub(crate) fn first_blocked_along(replan: &FootprintReplan<'_>, path: &[DVec2], resolution_m: f64) -> Option<((DVec2, f64), Blocked)> {
    if path.len() < 2 {
        return None;
    }
    let robot = replan.view.robot;
    let close_m = (0.5 * robot.length_m.hypot(robot.width_m) - 0.5 * robot.width_m).max(resolution_m);
    // Poses whose closing would close the start or the goal are not checked: the robot has
    // to leave where it stands and reach where it goes whatever the footprint says.
    let keep_off = close_m + resolution_m;
    let poses: Vec<(DVec2, f64)> = path_poses(path, 0.5 * resolution_m, replan.half_window_m.max(0.5 * robot.length_m))
        .into_iter()
        .filter(|(p, _)| p.distance(replan.from.0) > keep_off && p.distance(replan.goal) > keep_off)
        .collect();
    replan.view.first_blocked(replan.from, poses.iter().copied()).map(|(k, why)| (poses[k], why))
}

/// A reactive command, or why none is safe.
pub(crate) type Reaction = Result<(f64, f64), String>;

/// `rotate` toward `target_rad`: `v = 0`, `ω = clamp(k·e, ±ω_max)` with `e` the heading error
/// the short way round, if the whole remaining turn is safe; else none. (The long way round is
/// no way out: a footprint symmetric under a half turn sweeps, turning more than half a turn,
/// every cell the short way would.)
pub(crate) fn rotate(view: &SafetyView<'_>, position: DVec2, heading: f64, target_rad: f64, s: &NavigatorSettings) -> Reaction {
    let angle = wrap_angle(target_rad - heading);
    match view.sweep((position, heading), view.turn_poses(position, heading, angle)) {
        None => Ok((0.0, (s.turn_gain_per_s * angle).clamp(-s.max_turn_rate_rad_s, s.max_turn_rate_rad_s))),
        Some(blocked) => Err(format!("no safe turn to {target_rad:.2} rad ({angle:+.2} rad): {}", blocked.describe())),
    }
}

/// `back_out` toward `carrot` (world): with `e = wrap(bearing of the carrot in the body frame
/// - π)`, `ω = clamp(k·e, ±ω_max)`, `v = -v_back·max(cos e, 0)`, if the motion is safe until
/// some part of the footprint has moved `backout_clearance_m` (at least one control period);
/// else the turn in place alone (`v = 0`), checked the same way, if that is safe; else none.
pub(crate) fn back_out(view: &SafetyView<'_>, position: DVec2, heading: f64, carrot: DVec2, period_s: f64, s: &NavigatorSettings) -> Reaction {
    let body = DVec2::from_angle(-heading).rotate(carrot - position);
    let e = wrap_angle(body.y.atan2(body.x) - PI);
    let w = (s.turn_gain_per_s * e).clamp(-s.max_turn_rate_rad_s, s.max_turn_rate_rad_s);
    let v = -s.backout_speed_m_s * e.cos().max(0.0);
    let reach = 0.5 * view.robot.length_m.hypot(view.robot.width_m) + view.margin_m;
    let look = |v: f64, w: f64| (s.backout_clearance_m / (v.abs() + w.abs() * reach).max(1e-9)).max(period_s);
    let Some(reverse_blocked) = view.sweep((position, heading), arc_poses(position, heading, v, w, look(v, w), view)) else { return Ok((v, w)) };
    if w == 0.0 {
        return Err(format!("no safe way back: reversing, {}", reverse_blocked.describe()));
    }
    match view.sweep((position, heading), arc_poses(position, heading, 0.0, w, look(0.0, w), view)) {
        None => Ok((0.0, w)),
        Some(turn_blocked) => {
            Err(format!("no safe way back: reversing, {}; turning in place, {}", reverse_blocked.describe(), turn_blocked.describe()))
        }
    }
}

/// The tracker's command `(v, w)` if the motion is safe (checked as `back_out`'s: until some
/// part of the footprint has moved `backout_clearance_m`, at least one control period), else
/// the first safe of: turning in place, driving straight on, stopping. `Err` carries why the
/// command was changed, with what it became.
pub(crate) fn filter_track(view: &SafetyView<'_>, position: DVec2, heading: f64, command: (f64, f64), period_s: f64, s: &NavigatorSettings) -> Result<(f64, f64), ((f64, f64), String)> {
    let reach = 0.5 * view.robot.length_m.hypot(view.robot.width_m) + view.margin_m;
    let look = |v: f64, w: f64| (s.backout_clearance_m / (v.abs() + w.abs() * reach).max(1e-9)).max(period_s);
    let blocked = |(v, w): (f64, f64)| view.sweep((position, heading), arc_poses(position, heading, v, w, look(v, w), view));
    let Some(first) = blocked(command) else { return Ok(command) };
    let (v, w) = command;
    for alternative in [(0.0, w), (v, 0.0)] {
        if alternative != (0.0, 0.0) && blocked(alternative).is_none() {
            return Err((alternative, format!("tracker command ({v:.2} m/s, {w:.2} rad/s) not safe: {}", first.describe())));
        }
    }
    Err(((0.0, 0.0), format!("tracker command ({v:.2} m/s, {w:.2} rad/s) not safe, stopped: {}", first.describe())))
}

/// The heading of the longest ray below `r_inst` from `from` (`Navigator`'s docs, step 6): over
/// `clearance_headings` evenly spaced headings, the distance the grid stays below `r_inst`
/// (cell steps, up to `clearance_range_m`); the longest wins, ties to the heading nearest
/// `toward`.
pub(crate) fn clearance_heading(grid: &RiskGrid<'_>, from: DVec2, r_inst: f64, toward: f64, s: &NavigatorSettings) -> f64 {
    let step = grid.resolution_m();
    let n = s.clearance_headings as usize;
    let steps = (s.clearance_range_m / step).ceil() as usize;
    let mut best = (f64::NEG_INFINITY, f64::INFINITY, toward);
    for k in 0..n {
        let angle = wrap_angle(2.0 * PI * k as f64 / n as f64);
        let dir = DVec2::from_angle(angle);
        let mut free = 0.0;
        for i in 1..=steps {
            let q = from + dir * (i as f64 * step);
            match grid.value_at(q) {
                Some(r) if f64::from(r).partial_cmp(&r_inst).is_none_or(Ordering::is_lt) => free = i as f64 * step,
                _ => break,
            }
        }
        let off = wrap_angle(angle - toward).abs();
        if free > best.0 || (free == best.0 && off < best.1) {
            best = (free, off, angle);
        }
    }
    best.2
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::terrain::GridGeometry;

    /// A 60 x 60 grid of 0.1 m cells over [0, 6) m, every cell observed safe (0.05) but a
    /// hole: cells with x in [3.6, 4.6) and y in [2.0, 4.0) lethal (risk 1).
    fn hole_grid() -> (GridGeometry, Vec<f32>) {
        let g = GridGeometry { resolution_m: 0.1, nx: 60, ny: 60, origin_cell: (0, 0) };
        let mut risk = vec![0.05f32; g.cells()];
        for iy in 20..40 {
            for ix in 36..46 {
                risk[iy * 60 + ix] = 1.0;
            }
        }
        (g, risk)
    }

    fn view<'a>(grid: RiskGrid<'a>, hazards: &'a HazardMemory, near: &'a NearMemory, driven: &'a DrivenMemory) -> SafetyView<'a> {
        SafetyView {
            grid,
            hazards,
            near,
            driven,
            blocking: 0.6,
            lethal: 0.9,
            unknown_blocks: true,
            unknown_near_lethal_m: 0.3,
            robot: RobotConfig::default(),
            margin_m: 0.05,
            cell_overlap: true,
        }
    }

    #[test]
    fn a_back_out_beside_a_hole_stops_instead_of_swinging_a_corner_over_it() {
        // The robot (0.99 x 0.67 m) at (3.05, 3.0) facing +y, its right side 0.215 m from the
        // hole's rim at x = 3.6. Its carrot lies behind it to the left: reversing toward it
        // means turning clockwise, which swings the front-right corner over the hole.
        let (g, risk) = hole_grid();
        let grid = RiskGrid::on_geometry(&risk, &g).unwrap();
        let (hazards, near, driven) = (HazardMemory::default(), NearMemory::default(), DrivenMemory::default());
        let v = view(grid, &hazards, &near, &driven);
        let s = NavigatorSettings::default();
        let position = DVec2::new(3.05, 3.0);
        let heading = std::f64::consts::FRAC_PI_2;
        let carrot = DVec2::new(2.25, 2.9);
        let reason = back_out(&v, position, heading, carrot, 0.1, &s).expect_err("every way back sweeps the hole");
        assert!(reason.contains("reversing") && reason.contains("turning in place") && reason.contains("risk 1.00"), "{reason}");
        // The same motion with the hole filled in is made: a clockwise turn, reversing slowly.
        let safe = vec![0.05f32; g.cells()];
        let grid = RiskGrid::on_geometry(&safe, &g).unwrap();
        let v = view(grid, &hazards, &near, &driven);
        let (speed, w) = back_out(&v, position, heading, carrot, 0.1, &s).unwrap();
        assert!(w < 0.0 && speed < 0.0, "{speed} {w}");
    }

    #[test]
    fn a_back_out_along_a_safe_trail_reverses() {
        let (g, risk) = hole_grid();
        let grid = RiskGrid::on_geometry(&risk, &g).unwrap();
        let (hazards, near, driven) = (HazardMemory::default(), NearMemory::default(), DrivenMemory::default());
        let v = view(grid, &hazards, &near, &driven);
        let s = NavigatorSettings::default();
        // Facing +y at (1.5, 3.0), far from the hole, the carrot straight behind.
        let (speed, w) = back_out(&v, DVec2::new(1.5, 3.0), std::f64::consts::FRAC_PI_2, DVec2::new(1.5, 2.4), 0.1, &s).unwrap();
        assert!((speed + s.backout_speed_m_s).abs() < 1e-12 && w.abs() < 1e-9, "{speed} {w}");
    }

    #[test]
    fn unknown_ground_blocks_unless_remembered_or_driven() {
        // Nothing observed: every cell NaN.
        let g = GridGeometry { resolution_m: 0.1, nx: 60, ny: 60, origin_cell: (0, 0) };
        let risk = vec![f32::NAN; g.cells()];
        let grid = RiskGrid::on_geometry(&risk, &g).unwrap();
        let s = NavigatorSettings::default();
        let (hazards, near, mut driven) = (HazardMemory::default(), NearMemory::default(), DrivenMemory::default());
        let position = DVec2::new(3.0, 3.0);
        {
            let v = view(grid, &hazards, &near, &driven);
            let reason = rotate(&v, position, 0.0, 1.5, &s).unwrap_err();
            assert!(reason.contains("unknown cell"), "{reason}");
        }
        // The robot has driven over a disc 1.5 m across around its position: the turn is safe.
        for k in 0..72 {
            let a = k as f64 * 5f64.to_radians();
            driven.stamp(position + DVec2::from_angle(a) * 0.25, a, 1.6, 1.6, 0.1, 20.0);
        }
        let v = view(grid, &hazards, &near, &driven);
        let (speed, w) = rotate(&v, position, 0.0, 1.5, &s).unwrap();
        assert!(speed == 0.0 && w > 0.0, "{speed} {w}");
    }

    #[test]
    fn a_turn_that_would_sweep_a_lethal_cell_is_not_made() {
        // Lethal cells ahead-left of a robot at (2.0, 3.0) facing +x, 0.64 m from its centre:
        // beyond its corners at rest (0.60 m), within what they sweep turning left.
        let g = GridGeometry { resolution_m: 0.1, nx: 60, ny: 60, origin_cell: (0, 0) };
        let mut risk = vec![0.05f32; g.cells()];
        for iy in 34..37 {
            for ix in 24..27 {
                risk[iy * 60 + ix] = 1.0;
            }
        }
        let grid = RiskGrid::on_geometry(&risk, &g).unwrap();
        let (hazards, near, driven) = (HazardMemory::default(), NearMemory::default(), DrivenMemory::default());
        let v = view(grid, &hazards, &near, &driven);
        let s = NavigatorSettings::default();
        let reason = rotate(&v, DVec2::new(2.0, 3.0), 0.0, 1.2, &s).unwrap_err();
        assert!(reason.contains("risk 1.00"), "{reason}");
        // Far from them the same turn is made.
        let (speed, w) = rotate(&v, DVec2::new(1.0, 1.0), 0.0, 1.2, &s).unwrap();
        assert!(speed == 0.0 && w > 0.0);
    }

    #[test]
    fn path_poses_follow_the_path_with_its_tangent() {
        let path = [DVec2::new(0.0, 0.0), DVec2::new(1.0, 0.0), DVec2::new(1.0, 1.0)];
        let poses = path_poses(&path, 0.05, 0.3);
        assert_eq!(poses.len(), 40);
        assert!(poses[0].0.distance(DVec2::new(0.05, 0.0)) < 1e-12 && poses[0].1.abs() < 1e-12);
        assert!(poses[39].0.distance(DVec2::new(1.0, 1.0)) < 1e-12);
        assert!((poses[39].1 - std::f64::consts::FRAC_PI_2).abs() < 1e-12, "the last chord runs up the second leg");
        // At the corner the chord from 0.3 m before to 0.3 m after is at 45 degrees.
        assert!((poses[19].1 - std::f64::consts::FRAC_PI_4).abs() < 1e-12, "{}", poses[19].1);
    }

    /// An 8 x 6.6 m grid, lethal but for two rooms joined by a 0.8 m corridor with two right
    /// angles (the short way) and by a 1.6 m passage along the top (the long way).
    fn corner_world() -> (GridGeometry, Vec<f32>) {
        let g = GridGeometry { resolution_m: 0.1, nx: 80, ny: 66, origin_cell: (0, 0) };
        let within = |x: f64, y: f64, (x0, x1, y0, y1): (f64, f64, f64, f64)| x >= x0 && x < x1 && y >= y0 && y < y1;
        let free = [
            (0.4, 2.4, 0.4, 6.2), // the start's room
            (5.6, 7.6, 0.4, 6.2), // the goal's room
            (0.4, 7.6, 4.6, 6.2), // the wide way along the top
            (2.4, 4.4, 0.8, 1.6), // the corridor: east,
            (3.6, 4.4, 0.8, 3.0), // north,
            (3.6, 5.6, 2.2, 3.0), // east again
        ];
        let risk = (0..g.cells())
            .map(|c| {
                let (x, y) = ((c % g.nx) as f64 * 0.1 + 0.05, (c / g.nx) as f64 * 0.1 + 0.05);
                if free.iter().any(|&r| within(x, y, r)) { 0.05 } else { 1.0 }
            })
            .collect();
        (g, risk)
    }

    #[test]
    fn a_plan_whose_turn_the_footprint_cannot_make_is_replaced_by_one_it_can() {
        let (g, risk) = corner_world();
        let grid = RiskGrid::on_geometry(&risk, &g).unwrap();
        let robot = RobotConfig::default();
        let (start, goal) = (DVec2::new(1.45, 1.25), DVec2::new(6.55, 2.65));
        let mut astar = Vec::new();
        crate::plan::navigator::morphology::inflate_lethal(&risk, &mut astar, &g, 0.9, 0, 0.5 * robot.width_m, start);
        let astar_grid = RiskGrid::on_geometry(&astar, &g).unwrap();
        let mut planner = RiskAStar::new(crate::plan::astar::RiskAStarConfig::default()).unwrap();
        let first = planner.plan_with(&astar_grid, start, goal, None).unwrap();
        let first_path = first.found().expect("the inscribed disc fits the corridor").clone();
        assert!(first_path.length_m < 7.5, "the A* takes the short way, through the corridor: {} m", first_path.length_m);

        let (hazards, near, driven) = (HazardMemory::default(), NearMemory::default(), DrivenMemory::default());
        let tracker_view = SafetyView { blocking: 0.9, unknown_blocks: false, unknown_near_lethal_m: 0.15, margin_m: 0.0, cell_overlap: false, ..view(grid, &hazards, &near, &driven) };
        let poses = path_poses(&first_path.points_world, 0.05, 0.5 * robot.length_m);
        let (k, _) = tracker_view.first_blocked((start, 0.0), poses.iter().copied()).expect("the rectangle cannot take the corner");
        assert!((3.4..4.6).contains(&poses[k].0.x) && poses[k].0.y < 3.2, "blocked in the corridor: {:?}", poses[k].0);

        let replan = FootprintReplan { view: &tracker_view, from: (start, 0.0), goal, replans: 4, half_window_m: 0.3 };
        let checked = footprint_checked(&mut planner, &astar, &g, 0.9, None, &replan, first.clone()).unwrap();
        let path = checked.found().expect("the wide way round");
        assert!(path.length_m > 9.0, "the checked plan goes the wide way: {} m", path.length_m);
        let poses = path_poses(&path.points_world, 0.05, 0.5 * robot.length_m);
        assert_eq!(tracker_view.first_blocked((start, 0.0), poses.iter().copied()), None);
        // Off (no replans): the first plan as it was.
        let off = FootprintReplan { replans: 0, ..replan };
        assert_eq!(footprint_checked(&mut planner, &astar, &g, 0.9, None, &off, first.clone()).unwrap().found().unwrap().length_m, first_path.length_m);
    }
}
