//! Perception-aware planning: where the robot's sensor will see the ground from along a path,
//! and which unknown cells a path would enter unseen.
//!
//! Documented on [`SensorCoverage`].

use glam::DVec2;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::plan::grid::RiskGrid;

/// The A*'s 8 moves `(dx, dy)`, in its order (E, N, W, S, NE, NW, SW, SE).
pub(super) const MOVES: [(i32, i32); 8] = [(1, 0), (0, 1), (-1, 0), (0, -1), (1, 1), (-1, 1), (-1, -1), (1, -1)];

/// Where a sensor on the robot sees the ground from a pose.
///
/// The draft of STEP (§VII) treats each map cell as a random variable and plans on the map
/// *predicted* along a candidate path: cells the sensor will observe from the path's poses
/// have their variance reduced as a measurement would, the rest keep theirs, and risk is
/// priced with the predicted variance. This module makes that prediction for the one thing a
/// grid A* can price edge by edge: whether an **unknown** cell is seen before the robot enters
/// it. A cell seen on the way gets measured and, if it is a hazard, replanned around before
/// the robot is on it; a cell entered unseen carries its prior risk for real.
///
/// # The prediction, exactly
/// The A* enters cell `c` by one of its 8 moves `d` (unit step `(dx, dy)`, length `|d|·res`).
/// The robot is taken to approach `c` along `d` facing its motion (the planner plans forward
/// driving). The sensor ([`SensorCoverage`]) sees a ground cell at distance `s` straight ahead
/// when `min_range_m <= s <= max_range_m` (a forward camera's field of view holds the
/// direction of motion; a spinning lidar's holds everything). With `n = ceil(min_range_m /
/// (|d|·res))` moves, `c` is **seen before entry along `d`** when the `n` cells `c - j·d`,
/// `j = 1..n`, hold no occluder (a cell at or above the occluding risk: walls, boxes, drops;
/// cells off the grid do not occlude): the robot can stand at `c - n·d` and the ray from
/// there to `c` is clear. An unknown cell nearer the robot than `min_range_m` is not priced:
/// it is too near to be seen from any path, the same for all of them. So the entry mask marks,
/// per unknown cell, the moves that would enter it unseen; [`crate::plan::RiskAStar`] prices
/// those entries at `unseen_risk` instead of its `unknown_risk`.
///
/// Each direction is one pass over the grid in an order where `c - d` comes before `c`,
/// carrying the length of the clear run behind each cell: O(8·cells).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SensorCoverage {
    /// Horizontal field of view centred on the robot's heading \[deg\]; 360 for a spinning lidar.
    pub fov_deg: f64,
    /// Nearest ground the sensor sees \[m\]: the blind ring of a lidar (its height over the
    /// tangent of its lowest beam's depression), a camera's nearest visible ground.
    pub min_range_m: f64,
    /// Farthest ground it rates reliably \[m\].
    pub max_range_m: f64,
}

impl Default for SensorCoverage {
    /// An Ouster OS1-64 0.7 m above the ground: 360°, lowest beam 16.6° down (the data
    /// sheet's ±16.6° vertical field), blind within 0.7 / tan 16.6° = 2.35 m; ground rated
    /// out to 15 m.
    fn default() -> Self {
        Self::lidar(2.35, 15.0)
    }
}

impl SensorCoverage {
    /// A spinning lidar: all round, blind within `min_range_m`.
    pub fn lidar(min_range_m: f64, max_range_m: f64) -> Self {
        Self { fov_deg: 360.0, min_range_m, max_range_m }
    }

    /// A forward depth camera of horizontal field of view `fov_deg`.
    pub fn forward_camera(fov_deg: f64, min_range_m: f64, max_range_m: f64) -> Self {
        Self { fov_deg, min_range_m, max_range_m }
    }

    /// Checks every field, naming it (`<prefix>.<field>`).
    pub fn validate(&self, prefix: &str) -> Result<()> {
        if !(self.fov_deg.is_finite() && self.fov_deg > 0.0 && self.fov_deg <= 360.0) {
            return Err(Error::config(format!("{prefix}.fov_deg"), "must be in (0, 360]", self.fov_deg));
        }
        if !(self.min_range_m.is_finite() && (0.0..=100.0).contains(&self.min_range_m)) {
            return Err(Error::config(format!("{prefix}.min_range_m"), "must be in [0, 100] m", self.min_range_m));
        }
        if !(self.max_range_m.is_finite() && self.max_range_m > self.min_range_m && self.max_range_m <= 1000.0) {
            return Err(Error::config(format!("{prefix}.max_range_m"), format!("must be in ({}, 1000] m (above min_range_m)", self.min_range_m), self.max_range_m));
        }
        Ok(())
    }

    /// Whether the sensor at a pose sees a ground point `distance_m` away at `bearing_rad`
    /// from its heading.
    pub fn sees(&self, bearing_rad: f64, distance_m: f64) -> bool {
        bearing_rad.abs().to_degrees() <= 0.5 * self.fov_deg && distance_m >= self.min_range_m && distance_m <= self.max_range_m
    }
}

/// Marks in `out` (one byte per cell, bit `k` for move `k` of [`MOVES`]) the moves that would
/// enter an unknown cell unseen (`SensorCoverage`'s docs). `known[c]`: whether cell `c` is known (observed
/// or remembered); `occluding`: the risk at or above which a cell blocks the view; `robot`: the
/// robot's position [m, world]. `run`: scratch.
pub(super) fn unseen_entries(grid: &RiskGrid<'_>, known: &[bool], robot: DVec2, coverage: &SensorCoverage, occluding: f32, out: &mut Vec<u8>, run: &mut Vec<u16>) {
    let (nx, ny) = (grid.nx(), grid.ny());
    let res = grid.resolution_m();
    out.clear();
    out.resize(nx * ny, 0);
    let risk = grid.risk();
    let occludes = |i: usize| risk[i] >= occluding;
    // Moving straight ahead the robot sees the cell entered (bearing 0); a sensor that does
    // not see straight ahead sees nothing on the way.
    let ahead = coverage.sees(0.0, coverage.min_range_m.max(res));
    let near2 = coverage.min_range_m * coverage.min_range_m;
    for (k, &(dx, dy)) in MOVES.iter().enumerate() {
        let step_m = res * if dx != 0 && dy != 0 { std::f64::consts::SQRT_2 } else { 1.0 };
        let need = (coverage.min_range_m / step_m).ceil().clamp(1.0, f64::from(u16::MAX)) as u16;
        run.clear();
        run.resize(nx * ny, 0);
        let xs: Vec<usize> = if dx >= 0 { (0..nx).collect() } else { (0..nx).rev().collect() };
        let ys: Vec<usize> = if dy >= 0 { (0..ny).collect() } else { (0..ny).rev().collect() };
        for &iy in &ys {
            for &ix in &xs {
                let c = iy * nx + ix;
                // The clear run behind c along -d: c - d first.
                let (px, py) = (ix as i64 - i64::from(dx), iy as i64 - i64::from(dy));
                let behind = if px < 0 || py < 0 || px >= nx as i64 || py >= ny as i64 {
                    need
                } else {
                    let p = py as usize * nx + px as usize;
                    if occludes(p) { 0 } else { run[p].saturating_add(1).min(need) }
                };
                run[c] = behind;
                if known[c] || !risk[c].is_nan() {
                    continue;
                }
                let centre = grid.centre_of(grid.cell_at(c));
                if centre.distance_squared(robot) < near2 {
                    continue;
                }
                if !ahead || behind < need {
                    out[c] |= 1 << k;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unknown_cell_behind_a_wall_is_entered_unseen_from_the_wall_side_only() {
        // 30 x 30 cells of 0.1 m, all observed safe but an unknown cell at (15, 15) and a wall
        // (lethal) along column 14 from row 10 to 20, right beside it on its west.
        let (nx, ny) = (30, 30);
        let mut risk = vec![0.1f32; nx * ny];
        risk[15 * nx + 15] = f32::NAN;
        for iy in 10..=20 {
            risk[iy * nx + 14] = 1.0;
        }
        let grid = RiskGrid::new(&risk, nx, ny, 0.1, DVec2::ZERO).unwrap();
        let known = vec![false; nx * ny];
        let (mut out, mut run) = (Vec::new(), Vec::new());
        let lidar = SensorCoverage::lidar(0.5, 10.0);
        unseen_entries(&grid, &known, DVec2::new(-10.0, -10.0), &lidar, 0.9, &mut out, &mut run);
        // Entering eastward (move 0) comes from behind the wall: unseen. Northward (1),
        // westward (2), southward (3) have 5 clear cells behind them: seen. NE (4) crosses the
        // wall's column too (from (14 - j..., ...)), SE (7) as well; NW (5) and SW (6) come
        // from the east: seen.
        assert_eq!(out[15 * nx + 15], (1 << 0) | (1 << 4) | (1 << 7), "{:08b}", out[15 * nx + 15]);
        // Observed cells are never marked.
        assert!(out.iter().enumerate().all(|(c, &m)| c == 15 * nx + 15 || m == 0));
        // Known (remembered) cells neither.
        let mut known = known;
        known[15 * nx + 15] = true;
        unseen_entries(&grid, &known, DVec2::new(-10.0, -10.0), &lidar, 0.9, &mut out, &mut run);
        assert!(out.iter().all(|&m| m == 0));
    }

    #[test]
    fn cells_too_near_the_robot_and_a_blind_sensor() {
        let (nx, ny) = (20, 20);
        let risk = vec![f32::NAN; nx * ny];
        let grid = RiskGrid::new(&risk, nx, ny, 0.1, DVec2::ZERO).unwrap();
        let known = vec![false; nx * ny];
        let (mut out, mut run) = (Vec::new(), Vec::new());
        // Nothing occludes: every unknown cell is seen on the way.
        unseen_entries(&grid, &known, DVec2::new(1.0, 1.0), &SensorCoverage::lidar(0.3, 10.0), 0.9, &mut out, &mut run);
        assert!(out.iter().all(|&m| m == 0));
        assert!(!SensorCoverage::forward_camera(60.0, 0.3, 5.0).sees(1.0, 1.0));
        assert!(SensorCoverage::forward_camera(60.0, 0.3, 5.0).sees(0.4, 1.0));
        // A wall along column 7; the robot at (0.65, 1.0), in cell (6, 10) west of it.
        let walls: Vec<f32> = (0..nx * ny).map(|c| if c % nx == 7 { 1.0 } else { f32::NAN }).collect();
        let grid = RiskGrid::new(&walls, nx, ny, 0.1, DVec2::ZERO).unwrap();
        unseen_entries(&grid, &known, DVec2::new(0.65, 1.0), &SensorCoverage::lidar(0.3, 10.0), 0.9, &mut out, &mut run);
        assert_eq!(out[10 * nx + 8], 0, "0.2 m from the robot: too near to be priced");
        assert_ne!(out[10 * nx + 9] & 1, 0, "entered eastward, the wall 2 cells behind: unseen");
        assert_eq!(out[10 * nx + 9] & (1 << 2), 0, "entered westward, 3 clear cells behind: seen");
        assert_eq!(out[10 * nx + 11] & 1, 0, "entered eastward, 3 clear cells behind: seen");
    }

    /// The moves of `path` (cells) that enter a cell unseen by `mask`.
    fn unseen_moves(path: &[crate::terrain::CellIndex], mask: &[u8], nx: usize) -> usize {
        path.windows(2)
            .filter(|w| {
                let d = (w[1].ix as i32 - w[0].ix as i32, w[1].iy as i32 - w[0].iy as i32);
                let k = MOVES.iter().position(|&m| m == d).unwrap();
                mask[w[1].iy as usize * nx + w[1].ix as usize] & (1 << k) != 0
            })
            .count()
    }

    #[test]
    fn perception_aware_prices_change_the_plan_to_enter_the_unknown_in_view() {
        use crate::plan::astar::{EntryPrices, PlanStatus, RiskAStar, RiskAStarConfig};
        use crate::terrain::CellIndex;
        // 40 x 21 cells of 0.1 m: observed safe ground west of x = 2.0 m, unknown east of it;
        // a pillar (lethal, 3 x 3 cells) at x 1.4-1.7 m on the straight line y = 1.05 m from
        // the start (0.55, 1.05) to the goal (3.05, 1.05) in the unknown. Entering the unknown
        // eastward on that line, the pillar hides the cells just past x = 2 m from the sensor
        // (blind within 0.6 m); entering it diagonally, they are seen on the way.
        let (nx, ny) = (40, 21);
        let mut risk = vec![0.0f32; nx * ny];
        for iy in 0..ny {
            for ix in 20..nx {
                risk[iy * nx + ix] = f32::NAN;
            }
        }
        for iy in 9..12 {
            for ix in 14..17 {
                risk[iy * nx + ix] = 1.0;
            }
        }
        let grid = RiskGrid::new(&risk, nx, ny, 0.1, DVec2::ZERO).unwrap();
        let known = vec![false; nx * ny];
        let (mut mask, mut run) = (Vec::new(), Vec::new());
        let start = DVec2::new(0.55, 1.05);
        unseen_entries(&grid, &known, start, &SensorCoverage::lidar(0.6, 10.0), 0.9, &mut mask, &mut run);
        let mut planner = RiskAStar::new(RiskAStarConfig { r_total: 1.0, unknown_risk: 0.03, ..RiskAStarConfig::default() }).unwrap();
        let (s, g) = (CellIndex { ix: 5, iy: 10 }, CellIndex { ix: 30, iy: 10 });
        let plain = planner.plan_cells(&grid, s, g).unwrap();
        let prices = EntryPrices { unseen: &mask, unseen_risk: 0.15, clearance: &[] };
        let aware = planner.plan_cells_with(&grid, s, g, Some(&prices)).unwrap();
        assert_eq!((plain.status, aware.status), (PlanStatus::Found, PlanStatus::Found));
        let (plain, aware) = (plain.path.unwrap(), aware.path.unwrap());
        assert!(unseen_moves(&plain.cells, &mask, nx) > 0, "the plain plan enters the unknown behind the pillar");
        assert_eq!(unseen_moves(&aware.cells, &mask, nx), 0, "the perception-aware plan enters it in view");
        assert_ne!(plain.cells, aware.cells);
        // It pays for that with at most a little length.
        assert!(aware.length_m <= plain.length_m + 0.5, "{} vs {}", aware.length_m, plain.length_m);
    }

    #[test]
    fn coverage_is_checked() {
        assert!(SensorCoverage::lidar(2.0, 1.0).validate("c").unwrap_err().to_string().contains("c.max_range_m"));
        assert!(SensorCoverage::forward_camera(0.0, 0.3, 5.0).validate("c").unwrap_err().to_string().contains("c.fov_deg"));
        assert!(SensorCoverage::lidar(f64::NAN, 5.0).validate("c").unwrap_err().to_string().contains("c.min_range_m"));
        assert!(SensorCoverage::default().validate("c").is_ok());
    }
}
