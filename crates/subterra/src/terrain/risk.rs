//! From labelled points to a [`RiskMap`]: binning, geometric layers, risk layers and
//! their uncertainty (pipeline steps 4-6).
//!
//! Every pass is O(points) or O(cells): points are binned into cells once (a fused scan
//! once in its life, see [`super::fusion`]); the plane fits use summed-area tables, so their
//! cost does not grow with the window.
//!
//! # The layers, exactly
//! Heights below are relative to the current body origin, world axes (the *level frame*);
//! the height layers add the body's world z. `thr = ground.max_dist_to_line_m`; a point's
//! `h` is its height above its scan's ground line ([`GroundSegmenter`]).
//! - `count`, `min_height`, `max_height`, `age`: over all points in the cell.
//! - `ground_count`: points with `|h| <= thr`; `ground_height` = their mean z, else (no
//!   ground point) the newest scan's ground line at the cell centre if a line covers the
//!   cell's polar bin, else NaN. `observed` = 1 if the cell has a point or is so covered.
//! - `slope`, `plane_residual`: least-squares plane `z = a·x + b·y + c` through the ground
//!   heights of the cells with one in the `w x w` window centred on the cell (`w` = the odd
//!   cell count nearest `layers.plane_window_m / res`, clipped at the map's edge), needing
//!   `layers.plane_min_cells` of them; slope `atan(sqrt(a² + b²))`, residual
//!   `sqrt(SSE / n)`. NaN for cells without a ground height.
//! - `step_height`: `max |H(n) - H(c)|` over the 8 neighbours n with a ground height.
//! - `negative_depth`: at the cell centre, in the newest scan's polar bin: the bin's ground
//!   line height minus the floor bound (the lower of the bin's lowest point and the
//!   lowest ray that passed over the cell's radius), floored at 0; 0 without evidence. On
//!   a cell with ground points of its own it is instead how far its lowest point lies
//!   below their mean height, where that exceeds `thr`, else 0: seen ground is no hole
//!   (the bin's line, carried across a hole, overestimates a lower floor seen beyond it),
//!   but a rim cell holding part of the drop's wall or floor is as deep as they reach.
//!   A cell without ground points in a drop's shadow (`ground.drop_shadows`: beyond the
//!   bin's last return, in a run of bins that returned nothing, where rays passed below the
//!   expected ground farther on) is at least as deep as the deepest such ray or point.
//! - `tilt_angle`: *settling*. Each wheel rests on the highest ground in a square patch
//!   (`layers.wheel_patch_m`) around its corner of the footprint (`robot.length_m x
//!   robot.width_m`, corners rounded to cell centres) at heading ψ; the rigid body rests on
//!   three of the four corners whose plane passes at or above the fourth (for four corners
//!   two such triangles exist: the robot can rock between them), and its tilt is the angle
//!   of that plane from horizontal, `atan |∇z|`. The layer is the worst over both rocking
//!   poses and the `layers.tilt_headings` headings `ψ = j·180°/J`. Where some corner patch
//!   has no ground at every heading, the plane-fit slope stands in; else NaN.
//! - risks: `collision` = ramp(number of points with `clearance - clearance_margin < h <= height + head_margin`),
//!   `step` = ramp(`step_height`), `negative` = ramp(`negative_depth`), `tilt` =
//!   ramp(`tilt_angle`) with the robot's tilt ramp, `roughness` = ramp(`plane_residual`),
//!   `unknown` = `risk.unknown` where not observed, `mission` = 1 within an item's radius of
//!   its centre, falling linearly to 0 over `risk.mission_margin_m` (NaN inputs give 0).
//!   `risk = 1 - Π(1 - r_k)`. A cell whose `negative` risk is above 0 is `observed` (its
//!   rating comes from ray reasoning: beams passed below where its ground should have been),
//!   so that a hole's inside is a known hazard, not unknown ground.
//! - `risk_variance` = σ², `σ = min(sqrt(σ_range²/max(n, 1) + (drift·age)²) / height_span,
//!   max_sigma)` for observed cells (n = `count`, age = `age` or 0), `max_sigma` otherwise.

use std::sync::Arc;

use glam::{DVec2, DVec3, Vec3};

use super::config::{LayerConfig, MapConfig, RiskConfig, RobotConfig, UncertaintyConfig};
use super::grid::{GridGeometry, Layer, RiskMap};
use super::ground::GroundSegmenter;

/// A keep-out circle around a mission item (a dropped comm node, another robot).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MissionItem {
    /// Centre, world frame [m].
    pub position_world: DVec2,
    /// Radius of the lethal circle [m].
    pub radius_m: f64,
}

/// One scan's points as the map sees them.
pub(crate) struct ScanSource<'a> {
    /// Points relative to the scan's own body position, world axes [m].
    pub points_level: &'a [[f32; 3]],
    /// Each point's height above its ground line [m] (NaN: no ground line).
    pub heights: &'a [f32],
    /// The scan's body position minus the current body position, world axes [m].
    pub offset: Vec3,
    /// Age of the scan [s].
    pub age_s: f32,
}

/// One non-empty cell of a scan binned once when it arrived: its global cell index and the
/// sums of its points, heights relative to that scan's body origin.
#[derive(Debug, Clone, Copy)]
pub struct BinnedCell {
    /// Global cell index along x (`floor(x_world / res)`).
    pub gx: i64,
    /// Global cell index along y.
    pub gy: i64,
    acc: CellAccumulator,
}

/// A pre-binned scan as the coarse map sees it.
pub(crate) struct BinnedSource<'a> {
    pub cells: &'a [BinnedCell],
    /// The scan's body z minus the current body z [m].
    pub dz: f32,
    /// Age of the scan [s].
    pub age_s: f32,
}

/// The newest scan's polar ground knowledge and where its sensor was.
pub(crate) struct NewestPolar<'a> {
    pub segmenter: &'a GroundSegmenter,
    /// Sensor position relative to the current body origin, world axes [m].
    pub sensor_level: DVec3,
}

/// One settling triangle: corners `i, j, k` bear the body, the fourth is lifted.
#[derive(Debug, Clone, Copy)]
struct Triangle {
    i: usize,
    j: usize,
    k: usize,
    /// `A⁻¹` with `A = [[p_j - p_i], [p_k - p_i]]` (rows), so `∇z = A⁻¹ [Δ_j, Δ_k]`.
    inv: [[f64; 2]; 2],
}

/// The footprint's four corner cells at one heading. Rounding is symmetric, so the corners
/// are `±u, ±v` (FL = -RR, FR = -RL): a parallelogram centred on the cell.
#[derive(Debug, Clone)]
struct HeadingStencil {
    offsets: [(i64, i64); 4],
    /// The triangle lifting each corner (index = the lifted corner); `None` if degenerate.
    triangles: [Option<Triangle>; 4],
}

/// What the points of one cell add up to (one cache line per cell while binning).
#[derive(Debug, Clone, Copy)]
struct CellAccumulator {
    count: u32,
    ground_n: u32,
    collision_n: u32,
    ground_sum: f32,
    min_z: f32,
    max_z: f32,
    min_age: f32,
    /// Void samples of the scan(s) in the cell: the floor was found missing there.
    void_n: u32,
}

impl CellAccumulator {
    /// Adds a point at height `z` [m] whose height above its ground line is `h` [m].
    #[inline]
    fn add(&mut self, z: f32, h: f32, ground_threshold: f32, collision_lo: f32, collision_hi: f32) {
        // Every field is written with a select instead of behind a branch: whether a point is
        // ground, or the cell's lowest, depends on the data (real scans mix ground and
        // obstacles point by point), so branches here are mispredicted often.
        self.count += 1;
        // `min_z`/`max_z` are never NaN (they start infinite and only take points' z), so these
        // are `min`/`max` without the NaN handling.
        self.min_z = if z < self.min_z { z } else { self.min_z };
        self.max_z = if z > self.max_z { z } else { self.max_z };
        let ground = h.abs() <= ground_threshold;
        let collision = !ground && h > collision_lo && h <= collision_hi;
        self.ground_n += ground as u32;
        // The sum is formed either way and kept only for ground: exactly `+= z` or nothing.
        let ground_sum = self.ground_sum + z;
        self.ground_sum = if ground { ground_sum } else { self.ground_sum };
        self.collision_n += collision as u32;
    }

    const EMPTY: Self = Self { count: 0, ground_n: 0, collision_n: 0, ground_sum: 0.0, min_z: f32::INFINITY, max_z: f32::NEG_INFINITY, min_age: f32::INFINITY, void_n: 0 };
}

/// Builds maps of one geometry with reusable buffers.
#[derive(Debug, Clone)]
pub(crate) struct MapBuilder {
    map: MapConfig,
    robot: RobotConfig,
    layers: LayerConfig,
    risk: RiskConfig,
    uncertainty: UncertaintyConfig,
    ground_threshold: f32,
    plane_half: usize,
    patch_half: usize,
    stencils: Vec<HeadingStencil>,
    /// The map's cells, kept all-empty between calls of [`build`](Self::build).
    cells: Vec<CellAccumulator>,
    /// The storage of the previous map, for the next one (see [`RiskMap::reusing`]): every
    /// pass writes each of its layers completely.
    recycled: Option<Arc<Vec<f32>>>,
    /// Dense scratch of [`bin_scan`](Self::bin_scan), kept all-empty between calls.
    scratch: Vec<CellAccumulator>,
    /// Extent of that scratch around a scan: the map plus the farthest the robot can drive
    /// within the fusion window.
    scratch_map: MapConfig,
    height: Vec<f32>,
    patch_tmp: Vec<f32>,
    patch_max: Vec<f32>,
    patch_f64: Vec<f64>,
    tilt_worst: Vec<f64>,
    /// The runs of cells with ground in the inner span of a row, in [`tilt`](Self::tilt).
    tilt_runs: Vec<(usize, usize)>,
    integral: Vec<[f64; 10]>,
    /// Cell-centre x relative to the newest sensor, by column [m].
    xs: Vec<f64>,
    /// Scratch cells [`bin_scan`](Self::bin_scan) has hit, in order of the first hit (its
    /// first entries; the rest is room to write one more without a test).
    touched: Vec<u32>,
}

impl MapBuilder {
    /// The scratch map the scans of one fusion window are binned into: the map grown by the
    /// distance the robot can drive within the window (plus 1 m of slack for odometry).
    pub fn scratch_map(map: &MapConfig, robot: &RobotConfig, window_s: f64) -> MapConfig {
        let margin = robot.max_speed_m_s * window_s + 1.0;
        MapConfig { size_x_m: map.size_x_m + 2.0 * margin, size_y_m: map.size_y_m + 2.0 * margin, ..*map }
    }

    /// Configs are trusted (validated by the mapper).
    pub fn new(map: MapConfig, robot: RobotConfig, layers: LayerConfig, risk: RiskConfig, uncertainty: UncertaintyConfig, ground_threshold: f64, window_s: f64) -> Self {
        let scratch_map = Self::scratch_map(&map, &robot, window_s);
        let res = map.resolution_m;
        let odd_half = |size: f64| ((size / res).round() as usize).max(1) / 2;
        let stencils = (0..layers.tilt_headings).map(|j| heading_stencil(&robot, res, j as f64 * std::f64::consts::PI / layers.tilt_headings as f64)).collect();
        Self {
            map,
            robot,
            layers,
            risk,
            uncertainty,
            ground_threshold: ground_threshold as f32,
            plane_half: odd_half(layers.plane_window_m),
            patch_half: odd_half(layers.wheel_patch_m),
            stencils,
            cells: Vec::new(),
            recycled: None,
            scratch: Vec::new(),
            scratch_map,
            height: Vec::new(),
            patch_tmp: Vec::new(),
            patch_max: Vec::new(),
            patch_f64: Vec::new(),
            tilt_worst: Vec::new(),
            tilt_runs: Vec::new(),
            integral: Vec::new(),
            xs: Vec::new(),
            touched: Vec::new(),
        }
    }

    /// The map centred on `body_world` from `sources`, with the newest scan's polar ground.
    /// Bins one scan's points once, into the global cells around `origin_world` (the scan's
    /// sensor, world frame): `out` gets the non-empty cells. `sensor_above_body_m` lifts the
    /// sensor-centred heights to the scan's body origin. `voids`: the scan's void samples
    /// (sensor-centred `(x, y)`, [`GroundSegmenter::void_samples`]), counted per cell.
    pub fn bin_scan(&mut self, points: &[[f32; 3]], heights: &[f32], voids: &[[f32; 2]], origin_world: DVec3, sensor_above_body_m: f64, out: &mut Vec<BinnedCell>) {
        let g = GridGeometry::centred_on(&self.scratch_map, origin_world.x, origin_world.y);
        let n = g.cells();
        if self.scratch.len() != n {
            self.scratch.clear();
            self.scratch.resize(n, CellAccumulator::EMPTY);
        }
        let res = g.resolution_m;
        let (nx, ny) = (g.nx as i64, g.ny as i64);
        let thr = self.ground_threshold;
        let lo = (self.robot.ground_clearance_m - self.layers.clearance_margin_m) as f32;
        let hi = (self.robot.height_m + self.layers.head_margin_m) as f32;
        let dz = sensor_above_body_m as f32;
        // Each point writes its cell to `touched[hits]` and counts it only if the cell was
        // empty: no branch on "first hit", which real scans mispredict often. At most
        // min(points + voids, cells) distinct cells, plus the slot the last write may use.
        let room = (points.len() + voids.len()).min(n) + 1;
        if self.touched.len() < room {
            self.touched.resize(room, 0);
        }
        let touched = &mut self.touched[..room];
        let mut hits = 0;
        // The cells are [origin, origin + n) along each axis: floor(q) - origin is in [0, n)
        // iff q is in [origin, origin + n) (integer bounds), tested on q itself; then
        // floor_small gives floor(q) exactly. Points are finite (prefiltered), so q is too.
        let (x_lo, y_lo) = (g.origin_cell.0 as f64, g.origin_cell.1 as f64);
        let (x_hi, y_hi) = ((g.origin_cell.0 + nx) as f64, (g.origin_cell.1 + ny) as f64);
        let small = [x_lo, x_hi, y_lo, y_hi].iter().all(|b| b.abs() < FLOOR_SMALL_LIMIT);
        // A local slice: its pointer and length stay in registers (the writes to `touched`
        // could otherwise alias `self.scratch`).
        let scratch = &mut self.scratch[..n];
        for (p, &h) in points.iter().zip(heights) {
            // The same formula as GridGeometry::cell_of, so every scan agrees on the cells.
            let qx = (p[0] as f64 + origin_world.x) / res;
            let qy = (p[1] as f64 + origin_world.y) / res;
            let (ix, iy) = if small {
                if !(qx >= x_lo && qx < x_hi && qy >= y_lo && qy < y_hi) {
                    continue;
                }
                (floor_small(qx) - g.origin_cell.0, floor_small(qy) - g.origin_cell.1)
            } else {
                let (ix, iy) = (floor_i64(qx) - g.origin_cell.0, floor_i64(qy) - g.origin_cell.1);
                if ix < 0 || iy < 0 || ix >= nx || iy >= ny {
                    continue;
                }
                (ix, iy)
            };
            let c = (iy * nx + ix) as usize;
            let cell = &mut scratch[c];
            touched[hits] = c as u32;
            hits += (cell.count == 0) as usize;
            cell.add(p[2] + dz, h, thr, lo, hi);
        }
        for v in voids {
            let (ix, iy) = (floor_i64((v[0] as f64 + origin_world.x) / res) - g.origin_cell.0, floor_i64((v[1] as f64 + origin_world.y) / res) - g.origin_cell.1);
            if ix < 0 || iy < 0 || ix >= nx || iy >= ny {
                continue;
            }
            let c = (iy * nx + ix) as usize;
            let cell = &mut scratch[c];
            touched[hits] = c as u32;
            hits += (cell.count == 0 && cell.void_n == 0) as usize;
            cell.void_n += 1;
        }
        // The non-empty cells in the order they were first hit (each global cell once, so
        // the order does not change any sum the map makes of them).
        out.clear();
        let touched = &touched[..hits];
        out.reserve(touched.len());
        let scratch = &mut self.scratch[..n];
        for &c in touched.iter() {
            let c = c as usize;
            let cell = std::mem::replace(&mut scratch[c], CellAccumulator::EMPTY);
            let (ix, iy) = ((c % g.nx) as i64, (c / g.nx) as i64);
            out.push(BinnedCell { gx: g.origin_cell.0 + ix, gy: g.origin_cell.1 + iy, acc: cell });
        }
    }

    pub fn build(
        &mut self,
        body_world: DVec3,
        stamp_s: f64,
        sources: &[ScanSource<'_>],
        binned: &[BinnedSource<'_>],
        polar: Option<&NewestPolar<'_>>,
        missions: &[MissionItem],
    ) -> RiskMap {
        let geometry = GridGeometry::centred_on(&self.map, body_world.x, body_world.y);
        let mut map = RiskMap::reusing(self.recycled.take(), geometry, stamp_s);
        map.scans = sources.len() + binned.len();
        let n = geometry.cells();
        if self.cells.len() != n {
            self.cells.clear();
            self.cells.resize(n, CellAccumulator::EMPTY);
        }
        // Map corner relative to the body, level frame.
        let corner = geometry.origin_m() - body_world.truncate();
        map.points = self.bin_points(&geometry, corner, sources) + self.merge_binned(&geometry, binned);
        self.ground_heights(&geometry, corner, polar, &mut map);
        self.plane_fits(&geometry, &mut map);
        self.steps(&geometry, &mut map);
        self.tilt(&geometry, &mut map);
        self.risks(&geometry, body_world, missions, &mut map);
        map.lethal_risk = self.risk.lethal_risk as f32;
        self.recycled = Some(map.storage());
        map
    }

    #[inline(never)]
    fn bin_points(&mut self, g: &GridGeometry, corner: DVec2, sources: &[ScanSource<'_>]) -> usize {
        let inv = (1.0 / g.resolution_m) as f32;
        let (nx, ny) = (g.nx as f32, g.ny as f32);
        let nxu = g.nx;
        let thr = self.ground_threshold;
        let lo = (self.robot.ground_clearance_m - self.layers.clearance_margin_m) as f32;
        let hi = (self.robot.height_m + self.layers.head_margin_m) as f32;
        let mut binned = 0;
        for src in sources {
            // u = (x + offset - corner) / res.
            let ox = (src.offset.x as f64 - corner.x) as f32;
            let oy = (src.offset.y as f64 - corner.y) as f32;
            let oz = src.offset.z;
            let age = src.age_s;
            for (p, &h) in src.points_level.iter().zip(src.heights) {
                let u = (p[0] + ox) * inv;
                let v = (p[1] + oy) * inv;
                if !(u >= 0.0 && u < nx && v >= 0.0 && v < ny) {
                    continue;
                }
                let cell = &mut self.cells[v as usize * nxu + u as usize];
                binned += 1;
                cell.add(p[2] + oz, h, thr, lo, hi);
                cell.min_age = cell.min_age.min(age);
            }
        }
        binned
    }

    #[inline(never)]
    fn merge_binned(&mut self, g: &GridGeometry, binned: &[BinnedSource<'_>]) -> usize {
        let (nx, ny) = (g.nx as i64, g.ny as i64);
        let mut points = 0;
        for src in binned {
            let dz = src.dz;
            for b in src.cells {
                let (ix, iy) = (b.gx - g.origin_cell.0, b.gy - g.origin_cell.1);
                if ix < 0 || iy < 0 || ix >= nx || iy >= ny {
                    continue;
                }
                let a = &b.acc;
                let cell = &mut self.cells[(iy * nx + ix) as usize];
                points += a.count as usize;
                cell.count += a.count;
                cell.ground_n += a.ground_n;
                cell.collision_n += a.collision_n;
                cell.ground_sum += a.ground_sum + a.ground_n as f32 * dz;
                cell.min_z = cell.min_z.min(a.min_z + dz);
                cell.max_z = cell.max_z.max(a.max_z + dz);
                cell.min_age = cell.min_age.min(src.age_s);
                cell.void_n += a.void_n;
            }
        }
        points
    }

    #[inline(never)]
    fn ground_heights(&mut self, g: &GridGeometry, corner: DVec2, polar: Option<&NewestPolar<'_>>, map: &mut RiskMap) {
        let n = g.cells();
        let res = g.resolution_m;
        self.height.resize(n, f32::NAN);
        let Ok([.., negative_depth, _tilt, observed, _age, _collision, _step, _negative, _tilt_risk, _rough, _unknown, _mission, _risk, _variance]) = <[&mut [f32]; 21]>::try_from(map.layers_mut()) else {
            unreachable!("a RiskMap holds Layer::ALL.len() layers")
        };
        let (depth, observed, height) = (&mut negative_depth[..n], &mut observed[..n], &mut self.height[..n]);
        // Every cell: its own points' ground and observation, no depth unless the floor was
        // found missing and no scan of the window saw ground here (the polar queries below
        // add to that). Selects, not branches: real scans mix empty, ground and obstacle
        // cells unpredictably.
        let thr = self.ground_threshold;
        for (c, cell) in self.cells[..n].iter().enumerate() {
            let mean = cell.ground_sum / cell.ground_n as f32;
            height[c] = select_f32(cell.ground_n > 0, mean, f32::NAN);
            let void = (cell.void_n > 0) & (cell.ground_n == 0);
            observed[c] = select_f32((cell.count > 0) | void, 1.0, 0.0);
            // A cell with ground of its own is as deep as its points reach below that ground,
            // if deeper than the ground band (a rim with the drop's wall or floor in it).
            let drop = mean - cell.min_z;
            let own = select_f32((cell.ground_n > 0) & (drop > thr), drop, 0.0);
            depth[c] = select_f32(void, f32::INFINITY, own);
        }
        if let Some(polar) = polar {
            let s = polar.sensor_level;
            // Cell centres relative to the sensor: x by column, y by row.
            self.xs.clear();
            self.xs.extend((0..g.nx).map(|ix| corner.x + (ix as f64 + 0.5) * res - s.x));
            let cells = &self.cells[..n];
            for iy in 0..g.ny {
                let y = corner.y + (iy as f64 + 0.5) * res - s.y;
                let row = iy * g.nx;
                polar.segmenter.query_row(&self.xs, y, |ix, bin| {
                    let c = row + ix;
                    // Selects again: coverage and evidence vary cell by cell. A void cell
                    // without ground points is observed, infinitely deep, and keeps no line.
                    let cell = &cells[c];
                    let void = (cell.ground_n == 0) & (bin.void | (cell.void_n > 0));
                    observed[c] = select_f32(bin.covered | void, 1.0, observed[c]);
                    let line_height = (bin.ground_z + s.z) as f32;
                    height[c] = select_f32(bin.covered & (cell.ground_n == 0) & !void, line_height, height[c]);
                    let below = (bin.ground_z - bin.floor_bound_z).max(0.0) as f32;
                    let below = select_f32(bin.floor_bound_z.is_finite(), below, depth[c]);
                    // In a drop's shadow the drop may begin anywhere: as deep as it gets.
                    let below = below.max(bin.shadow_depth as f32);
                    let below = select_f32(cell.ground_n > 0, depth[c], below);
                    depth[c] = select_f32(void, f32::INFINITY, below);
                });
            }
        }
    }

    /// Slope and residual of the plane through the ground heights under the window.
    #[inline(never)]
    fn plane_fits(&mut self, g: &GridGeometry, map: &mut RiskMap) {
        let (nx, ny) = (g.nx, g.ny);
        let res = g.resolution_m;
        let w = nx + 1;
        let hw = self.plane_half;
        // The summed-area table, row r (0..=ny, row 0 all zeros) in slot r % slots: map row
        // iy reads rows iy - hw and iy + hw + 1 (clipped), so 2·hw + 2 slots hold every row
        // still needed.
        let slots = (2 * hw + 2).min(ny + 1);
        self.integral.clear();
        self.integral.resize(slots * w, [0.0; 10]);
        let min_cells = self.layers.plane_min_cells as f64;
        let Ok([_count, _ground_count, _ground_height, _min, _max, slope, residual, ..]) = <[&mut [f32]; 21]>::try_from(map.layers_mut()) else {
            unreachable!("a RiskMap holds Layer::ALL.len() layers")
        };
        slope.fill(f32::NAN);
        residual.fill(f32::NAN);
        let height = &self.height[..nx * ny];
        let mut built = 0;
        for iy in 0..ny {
            let (y0, y1) = (iy.saturating_sub(hw), (iy + hw + 1).min(ny));
            while built < y1 {
                // Row built + 1 = row built + the running sums along map row `built`.
                let (a, b) = (built % slots, (built + 1) % slots);
                let (above, cur) = if a < b {
                    let (lo, hi) = self.integral.split_at_mut(b * w);
                    (&lo[a * w..(a + 1) * w], &mut hi[..w])
                } else {
                    let (lo, hi) = self.integral.split_at_mut(a * w);
                    (&hi[..w], &mut lo[b * w..(b + 1) * w])
                };
                let mut row = [0.0f64; 10];
                let y = built as f64 * res;
                for (ix, (&z, (cell, above))) in height[built * nx..(built + 1) * nx].iter().zip(cur[1..].iter_mut().zip(&above[1..])).enumerate() {
                    if z.is_finite() {
                        let (x, z) = (ix as f64 * res, z as f64);
                        let m = [1.0, x, y, z, x * x, x * y, y * y, x * z, y * z, z * z];
                        for k in 0..10 {
                            row[k] += m[k];
                        }
                    }
                    for k in 0..10 {
                        cell[k] = above[k] + row[k];
                    }
                }
                built += 1;
            }
            let (top, bottom) = (&self.integral[(y0 % slots) * w..][..w], &self.integral[(y1 % slots) * w..][..w]);
            let hrow = &height[iy * nx..(iy + 1) * nx];
            for (ix, h) in hrow.iter().enumerate() {
                if !h.is_finite() {
                    continue;
                }
                let (x0, x1) = (ix.saturating_sub(hw), (ix + hw + 1).min(nx));
                let (a, b, cc, d) = (&bottom[x1], &top[x1], &bottom[x0], &top[x0]);
                let mut s = [0.0f64; 10];
                for k in 0..10 {
                    s[k] = a[k] - b[k] - cc[k] + d[k];
                }
                let n = s[0];
                if n < min_cells {
                    continue;
                }
                if let Some((grad, rms)) = fit_plane(&s, ix as f64 * res, iy as f64 * res) {
                    let c = iy * nx + ix;
                    slope[c] = grad.atan() as f32;
                    residual[c] = rms as f32;
                }
            }
        }
    }

    #[inline(never)]
    fn steps(&mut self, g: &GridGeometry, map: &mut RiskMap) {
        let (nx, ny) = (g.nx, g.ny);
        let out = map.get_mut(Layer::StepHeight);
        let height = &self.height[..nx * ny];
        // max |H(n) - H(c)| over the 3x3 block clipped to the map, visited in the same
        // row-major order everywhere (the cell itself adds 0; NaN neighbours never compare
        // greater).
        let block = |ix: usize, iy: usize, h: f32| {
            let mut worst = 0.0f32;
            for jy in iy.saturating_sub(1)..(iy + 2).min(ny) {
                for jx in ix.saturating_sub(1)..(ix + 2).min(nx) {
                    let d = (height[jy * nx + jx] - h).abs();
                    if d > worst {
                        worst = d;
                    }
                }
            }
            worst
        };
        for iy in 0..ny {
            let row = iy * nx;
            if iy == 0 || iy + 1 == ny || nx < 3 {
                for ix in 0..nx {
                    let h = height[row + ix];
                    out[row + ix] = if h.is_finite() { block(ix, iy, h) } else { f32::NAN };
                }
                continue;
            }
            // Inner row: the three rows as slices, no clipping between the edge columns.
            let (above, mid, below) = (&height[row - nx..row], &height[row..row + nx], &height[row + nx..row + 2 * nx]);
            let out = &mut out[row..row + nx];
            for ix in [0, nx - 1] {
                let h = mid[ix];
                out[ix] = if h.is_finite() { block(ix, iy, h) } else { f32::NAN };
            }
            // Branch-free over the inner cells, so that the loop vectorises: every candidate
            // `|v - h|` is +0 or positive (abs), NaN ones never win, so the largest does
            // whatever the order, the same as the block order above; the cell itself (0) is
            // left out, and a cell without ground gives NaN.
            let m = nx - 2;
            let (a0, a1, a2) = (&above[..m], &above[1..m + 1], &above[2..m + 2]);
            let (m0, m1, m2) = (&mid[..m], &mid[1..m + 1], &mid[2..m + 2]);
            let (b0, b1, b2) = (&below[..m], &below[1..m + 1], &below[2..m + 2]);
            let out_inner = &mut out[1..m + 1];
            for i in 0..m {
                let h = m1[i];
                let mut worst = 0.0f32;
                for v in [a0[i], a1[i], a2[i], m0[i], m2[i], b0[i], b1[i], b2[i]] {
                    let d = (v - h).abs();
                    worst = if d > worst { d } else { worst };
                }
                out_inner[i] = if h.is_finite() { worst } else { f32::NAN };
            }
        }
    }

    #[inline(never)]
    fn tilt(&mut self, g: &GridGeometry, map: &mut RiskMap) {
        let (nx, ny) = (g.nx, g.ny);
        let n = nx * ny;
        // Highest ground in the wheel patch around each cell (separable max, NaN ignored).
        let p = self.patch_half;
        self.patch_tmp.clear();
        self.patch_tmp.resize(n, f32::NAN);
        self.patch_max.clear();
        self.patch_max.resize(n, f32::NAN);
        // Row by row, offset by offset in increasing order: each cell folds the same values
        // in the same order as a per-cell loop would.
        let nan_max = |m: f32, v: f32| if v > m || m.is_nan() { v } else { m };
        for iy in 0..ny {
            let row = &self.height[iy * nx..(iy + 1) * nx];
            let tmp = &mut self.patch_tmp[iy * nx..(iy + 1) * nx];
            for d in -(p as isize)..=p as isize {
                // Cells ix with 0 <= ix + d < nx.
                let (lo, hi) = ((-d).max(0) as usize, (nx as isize - d).min(nx as isize).max(0) as usize);
                if lo >= hi {
                    continue;
                }
                let src = &row[(lo as isize + d) as usize..(hi as isize + d) as usize];
                for (m, &v) in tmp[lo..hi].iter_mut().zip(src) {
                    *m = nan_max(*m, v);
                }
            }
        }
        for iy in 0..ny {
            let out = &mut self.patch_max[iy * nx..(iy + 1) * nx];
            for jy in iy.saturating_sub(p)..(iy + p + 1).min(ny) {
                for (m, &v) in out.iter_mut().zip(&self.patch_tmp[jy * nx..(jy + 1) * nx]) {
                    *m = nan_max(*m, v);
                }
            }
        }
        let Ok([_count, _ground_count, _ground_height, _min, _max, slope, _residual, _step, _depth, out, ..]) = <[&mut [f32]; 21]>::try_from(map.layers_mut()) else {
            unreachable!("a RiskMap holds Layer::ALL.len() layers")
        };
        // Cells at least `reach` from every edge have all their corners inside the map:
        // their corners are flat offsets from the cell, no bounds to test.
        let reach_x = self.stencils.iter().flat_map(|s| s.offsets).map(|(dx, _)| dx.unsigned_abs() as usize).max().unwrap_or(0);
        let reach_y = self.stencils.iter().flat_map(|s| s.offsets).map(|(_, dy)| dy.unsigned_abs() as usize).max().unwrap_or(0);
        // The patch maxima as f64 (NaN stays NaN), converted once instead of per corner.
        self.patch_f64.clear();
        self.patch_f64.extend(self.patch_max.iter().map(|&v| v as f64));
        let patch = &self.patch_f64[..n];
        let height = &self.height[..n];
        let (slope, out) = (&slope[..n], &mut out[..n]);
        // Per heading, its corner offsets in the flat layer and the two settling poses of
        // each diagonal, hoisted out of the cell loop.
        let headings: Vec<HeadingKernel> = self.stencils.iter().map(|s| HeadingKernel::new(s, nx)).collect();
        // The inner cells of a row: their worst tan² so far.
        let worst = &mut self.tilt_worst;
        let (x0, x1) = (reach_x.min(nx), nx.saturating_sub(reach_x).max(reach_x.min(nx)));
        for iy in 0..ny {
            let row = iy * nx;
            let inner = iy >= reach_y && iy + reach_y < ny && x0 < x1;
            // Near the edge (corners may be off the map): cell by cell. The whole row, or
            // the columns outside the inner span.
            let (edge_a, edge_b) = if inner { (0..x0, x1..nx) } else { (0..nx, nx..nx) };
            for ix in edge_a.chain(edge_b) {
                let c = row + ix;
                if !height[c].is_finite() {
                    out[c] = f32::NAN;
                    continue;
                }
                let mut worst_tan2 = -1.0f64;
                for stencil in &self.stencils {
                    if let Some(h) = corner_heights(&self.patch_max, nx, ny, ix, iy, &stencil.offsets) {
                        worst_tan2 = worst_tan2.max(settle_tan2(&stencil.triangles, &h));
                    }
                }
                out[c] = if worst_tan2 >= 0.0 { worst_tan2.sqrt().atan() as f32 } else { slope[c] };
            }
            if !inner {
                continue;
            }
            // Heading by heading over the row's inner cells: each cell still folds its
            // headings in order, with the same values.
            worst.clear();
            worst.resize(x1 - x0, -1.0);
            let has = &height[row + x0..row + x1];
            // Only the runs of cells with ground (a cell without keeps -1 and gets NaN
            // below): real scans leave long stretches without ground (out of range, behind
            // walls). Gaps shorter than `MIN_GAP` are settled with the runs, at less cost than
            // a call.
            const MIN_GAP: usize = 8;
            let runs = &mut self.tilt_runs;
            runs.clear();
            let mut at = 0;
            while let Some(a) = has[at..].iter().position(|h| h.is_finite()).map(|a| at + a) {
                let b = has[a..].iter().position(|h| !h.is_finite()).map_or(has.len(), |b| a + b);
                match runs.last_mut() {
                    Some(last) if a - last.1 < MIN_GAP => last.1 = b,
                    _ => runs.push((a, b)),
                }
                at = b;
            }
            for k in &headings {
                for &(a, b) in runs.iter() {
                    k.settle_row(patch, row + x0 + a, &has[a..b], &mut worst[a..b]);
                }
            }
            let (out_inner, slope_inner) = (&mut out[row + x0..row + x1], &slope[row + x0..row + x1]);
            for (i, &w) in worst.iter().enumerate() {
                out_inner[i] = if !has[i].is_finite() {
                    f32::NAN
                } else if w >= 0.0 {
                    w.sqrt().atan() as f32
                } else {
                    slope_inner[i]
                };
            }
        }
    }

    #[inline(never)]
    fn risks(&mut self, g: &GridGeometry, body_world: DVec3, missions: &[MissionItem], map: &mut RiskMap) {
        let n = g.cells();
        let r = self.risk;
        let tilt_ramp = self.robot.tilt_ramp_rad();
        let u = self.uncertainty;
        let z0 = body_world.z as f32;
        // One slice per layer, in `Layer::ALL` order, each exactly `n` long.
        let Ok([count_l, ground_count, ground_height, min_height, max_height, _slope, residual, step_height, negative_depth, tilt_angle, observed_l, age_l, collision_l, step_l, negative_l, tilt_l, rough_l, unknown_l, mission_l, risk_l, variance_l]) =
            <[&mut [f32]; 21]>::try_from(map.layers_mut())
        else {
            unreachable!("a RiskMap holds Layer::ALL.len() layers")
        };
        mission_l.fill(0.0);
        for item in missions {
            stamp_mission(g, item, r.mission_margin_m, mission_l);
        }
        let cells = &mut self.cells[..n];
        let height = &self.height[..n];
        // Re-sliced to `n` so that the loops index without bounds checks.
        let (count_l, ground_count, ground_height, min_height, max_height, age_l) =
            (&mut count_l[..n], &mut ground_count[..n], &mut ground_height[..n], &mut min_height[..n], &mut max_height[..n], &mut age_l[..n]);
        for c in 0..n {
            let cell = &cells[c];
            let count = cell.count;
            count_l[c] = count as f32;
            ground_count[c] = cell.ground_n as f32;
            ground_height[c] = height[c] + z0;
            // Whether the cell has points, as a float comparison (an empty cell's bounds are
            // +inf and -inf, a non-empty one's finite): selects on it compile without a
            // branch, which real scans, mixing empty and non-empty cells, mispredicted.
            let has = cell.min_z <= cell.max_z;
            min_height[c] = select_f32(has, cell.min_z + z0, f32::NAN);
            max_height[c] = select_f32(has, cell.max_z + z0, f32::NAN);
            age_l[c] = select_f32(has, cell.min_age, f32::NAN);
        }
        let (residual, step_height, negative_depth, tilt_angle, observed_l) =
            (&residual[..n], &step_height[..n], &negative_depth[..n], &tilt_angle[..n], &mut observed_l[..n]);
        let (collision_l, step_l, negative_l, tilt_l, rough_l, unknown_l, mission_l, risk_l, variance_l) = (
            &mut collision_l[..n],
            &mut step_l[..n],
            &mut negative_l[..n],
            &mut tilt_l[..n],
            &mut rough_l[..n],
            &mut unknown_l[..n],
            &mut mission_l[..n],
            &mut risk_l[..n],
            &mut variance_l[..n],
        );
        // σ² of an observed cell with `count` points (0 counts as 1), the newest `age` s old.
        let variance = |count: u32, age: f64| {
            let var_h = u.range_sigma_m * u.range_sigma_m / (count.max(1) as f64) + (u.drift_m_per_s * age).powi(2);
            let sigma = (var_h.sqrt() / u.height_span_m).min(u.max_sigma);
            (sigma * sigma) as f32
        };
        let var_unobserved = (u.max_sigma * u.max_sigma) as f32;
        // The same at age 0, by count (most cells of a fresh scan).
        let mut var_fresh = [0.0f32; 64];
        for (k, v) in var_fresh.iter_mut().enumerate() {
            *v = variance(k as u32, 0.0);
        }
        for c in 0..n {
            // The last reader of the cell: it is left empty for the next map.
            let cell = &std::mem::replace(&mut cells[c], CellAccumulator::EMPTY);
            let count = cell.count;
            let has = cell.min_z <= cell.max_z;
            let negative = r.negative_m.eval(negative_depth[c] as f64);
            // A cell rated by ray reasoning (beams passed below where its ground should have
            // been) is observed: what it says is known, not guessed.
            let observed = observed_l[c] > 0.0 || negative > 0.0;
            observed_l[c] = select_f32(observed, 1.0, 0.0);
            let collision = r.collision_points.eval(cell.collision_n as f64);
            let step = r.step_m.eval(step_height[c] as f64);
            let tilt = tilt_ramp.eval(tilt_angle[c] as f64);
            let rough = r.roughness_m.eval(residual[c] as f64);
            let unknown = if observed { 0.0 } else { r.unknown };
            let m = mission_l[c] as f64;
            // Same order as Layer::RISKS. A cell with every risk 0 (ramps give +0, never -0)
            // gets +0 in each, and combined risk 1 - 1 = +0.
            if collision != 0.0 || step != 0.0 || negative != 0.0 || tilt != 0.0 || rough != 0.0 || unknown != 0.0 || m != 0.0 {
                collision_l[c] = collision as f32;
                step_l[c] = step as f32;
                negative_l[c] = negative as f32;
                tilt_l[c] = tilt as f32;
                rough_l[c] = rough as f32;
                unknown_l[c] = unknown as f32;
                let keep = 1.0 * (1.0 - collision) * (1.0 - step) * (1.0 - negative) * (1.0 - tilt) * (1.0 - rough) * (1.0 - unknown) * (1.0 - m);
                risk_l[c] = (1.0 - keep).clamp(0.0, 1.0) as f32;
            } else {
                for layer in [&mut collision_l[c], &mut step_l[c], &mut negative_l[c], &mut tilt_l[c], &mut rough_l[c], &mut unknown_l[c], &mut risk_l[c]] {
                    *layer = 0.0;
                }
            }
            // No points: count 0 (the same as 1) and age 0. Selects again, as `has` above.
            let age = if has { cell.min_age } else { 0.0 };
            let var = if age == 0.0 && (count as usize) < var_fresh.len() {
                // Age ±0 adds exactly 0 (drift·age squared): the value of `count` alone.
                var_fresh[count as usize]
            } else {
                variance(count, age as f64)
            };
            variance_l[c] = if observed { var } else { var_unobserved };
        }
    }
}

/// One heading's settling, for cells whose four corners are inside the map: the corners'
/// flat offsets and the `A⁻¹` of the triangles [`settle_tan2`] uses.
struct HeadingKernel {
    offsets: [isize; 4],
    /// Triangles lifting corners 1, 2 (the body on FL-RR), then 0, 3 (on FR-RL).
    tri: [Option<[[f64; 2]; 2]>; 4],
}

impl HeadingKernel {
    fn new(s: &HeadingStencil, nx: usize) -> Self {
        let t = |o: usize| s.triangles[o].map(|t| t.inv);
        Self { offsets: s.offsets.map(|(dx, dy)| dy as isize * nx as isize + dx as isize), tri: [t(1), t(2), t(0), t(3)] }
    }

    /// For the cells `c = start..start + worst.len()` of one row whose four corners are inside
    /// the map: `worst[i] = max(worst[i], settle_tan2(corners))` where `has[i]` (the cell has
    /// ground) and all four corners have ground, as the per-cell loop does (`worst` starts
    /// at -1 and never holds NaN).
    #[inline(never)]
    fn settle_row(&self, patch: &[f64], start: usize, has: &[f32], worst: &mut [f64]) {
        let len = worst.len();
        let corner = |o: isize| &patch[(start as isize + o) as usize..][..len];
        let (s0, s1, s2, s3) = (corner(self.offsets[0]), corner(self.offsets[1]), corner(self.offsets[2]), corner(self.offsets[3]));
        let has = &has[..len];
        if let [Some(t0), Some(t1), Some(t2), Some(t3)] = self.tri {
            // `t0`, `t1` lift corners 1, 2 (the body on FL-RR), `t2`, `t3` lift 0, 3 (on FR-RL).
            // Both diagonals' poses are computed and the result selected, with no branch:
            // which diagonal bears the body, and which cells have ground, vary cell by cell
            // on real terrain, and those branches were mispredicted often. The selected
            // values are the ones the branches would have computed.
            for i in 0..len {
                let h = [s0[i], s1[i], s2[i], s3[i]];
                // Finite iff all four corners are (f32 values: the sum cannot overflow).
                let d = h[0] + h[3] - h[1] - h[2];
                let on_main = support(&t1, h[0], h[1], h[3], support(&t0, h[0], h[2], h[3], -1.0));
                let on_cross = support(&t3, h[0], h[1], h[2], support(&t2, h[1], h[2], h[3], -1.0));
                let tan2 = if d >= 0.0 { on_main } else { on_cross };
                let counts = has[i].is_finite() & d.is_finite() & (tan2 > worst[i]);
                worst[i] = if counts { tan2 } else { worst[i] };
            }
        } else {
            for i in 0..len {
                if !has[i].is_finite() {
                    continue;
                }
                let h = [s0[i], s1[i], s2[i], s3[i]];
                // Finite iff all four corners are (f32 values: the sum cannot overflow).
                let d = h[0] + h[3] - h[1] - h[2];
                if !d.is_finite() {
                    continue;
                }
                let tan2 = if d >= 0.0 {
                    let w = support_opt(&self.tri[0], h[0], h[2], h[3], -1.0);
                    support_opt(&self.tri[1], h[0], h[1], h[3], w)
                } else {
                    let w = support_opt(&self.tri[2], h[1], h[2], h[3], -1.0);
                    support_opt(&self.tri[3], h[0], h[1], h[2], w)
                };
                if tan2 > worst[i] {
                    worst[i] = tan2;
                }
            }
        }
    }
}

/// `if c { a } else { b }`, as an integer select on the bits: a plain `f32` select on a
/// condition that is not itself a float comparison compiles to a branch on x86-64 (SSE2 has
/// no scalar float `cmov`), and where the condition depends on the data that branch is
/// mispredicted often.
#[inline(always)]
fn select_f32(c: bool, a: f32, b: f32) -> f32 {
    f32::from_bits(std::hint::select_unpredictable(c, a.to_bits(), b.to_bits()))
}

/// One settling pose of [`settle_tan2`]: the body on corners `i, j, k` (heights `hi, hj,
/// hk`), `worst` folded in as there.
#[inline(always)]
fn support(inv: &[[f64; 2]; 2], hi: f64, hj: f64, hk: f64, worst: f64) -> f64 {
    let (dj, dk) = (hj - hi, hk - hi);
    let gx = inv[0][0] * dj + inv[0][1] * dk;
    let gy = inv[1][0] * dj + inv[1][1] * dk;
    let tan2 = gx * gx + gy * gy;
    if tan2 > worst {
        tan2
    } else {
        worst
    }
}

#[inline(always)]
fn support_opt(t: &Option<[[f64; 2]; 2]>, hi: f64, hj: f64, hk: f64, worst: f64) -> f64 {
    match t {
        Some(inv) => support(inv, hi, hj, hk, worst),
        None => worst,
    }
}

/// Inputs of [`floor_small`] stay below this in magnitude.
const FLOOR_SMALL_LIMIT: f64 = (1u64 << 50) as f64;

/// `floor(x)` for `|x| < 2^50`, exactly, without a libm call or saturation code: adding
/// 1.5·2^52 rounds x to the nearest integer, held in the low mantissa bits; one comparison
/// turns the rounding into a floor.
#[inline]
fn floor_small(x: f64) -> i64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5·2^52
    let t = x + MAGIC;
    let rounded = (t.to_bits() as i64) - (MAGIC.to_bits() as i64);
    rounded - ((t - MAGIC) > x) as i64
}

/// `floor(x)` as an integer without a libm call (x86-64 without SSE4.1 has no inline
/// floor); saturates like `as` for huge or NaN inputs (NaN gives 0).
#[inline]
fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t - 1
    } else {
        t
    }
}

/// The patch heights under the four corners at `offsets` from cell `(ix, iy)`; `None` if a
/// corner is off the map or has no ground.
fn corner_heights(patch_max: &[f32], nx: usize, ny: usize, ix: usize, iy: usize, offsets: &[(i64, i64); 4]) -> Option<[f64; 4]> {
    let mut h = [0.0f64; 4];
    for (corner, &(dx, dy)) in offsets.iter().enumerate() {
        let (jx, jy) = (ix as i64 + dx, iy as i64 + dy);
        if jx < 0 || jy < 0 || jx >= nx as i64 || jy >= ny as i64 {
            return None;
        }
        let v = patch_max[jy as usize * nx + jx as usize];
        if !v.is_finite() {
            return None;
        }
        h[corner] = v as f64;
    }
    Some(h)
}

/// The footprint corners at heading `yaw` as cell offsets, and the four settling triangles.
fn heading_stencil(robot: &RobotConfig, res: f64, yaw: f64) -> HeadingStencil {
    let (a, b) = (robot.length_m / 2.0, robot.width_m / 2.0);
    let (s, c) = yaw.sin_cos();
    // Front-left, front-right, rear-left, rear-right.
    let corners = [(a, b), (a, -b), (-a, b), (-a, -b)];
    let offsets = corners.map(|(x, y)| (((c * x - s * y) / res).round() as i64, ((s * x + c * y) / res).round() as i64));
    let pos = offsets.map(|(i, j)| DVec2::new(i as f64 * res, j as f64 * res));
    debug_assert!(offsets[0] == (-offsets[3].0, -offsets[3].1) && offsets[1] == (-offsets[2].0, -offsets[2].1));
    let mut triangles = [None; 4];
    for o in 0..4 {
        let rest: Vec<usize> = (0..4).filter(|&q| q != o).collect();
        let (i, j, k) = (rest[0], rest[1], rest[2]);
        let (dj, dk) = (pos[j] - pos[i], pos[k] - pos[i]);
        let det = dj.x * dk.y - dj.y * dk.x;
        if det.abs() < 1e-9 {
            continue;
        }
        // A = [[dj.x, dj.y], [dk.x, dk.y]]; ∇z solves A ∇z = [Δj, Δk].
        let inv = [[dk.y / det, -dj.y / det], [-dk.x / det, dj.x / det]];
        triangles[o] = Some(Triangle { i, j, k, inv });
    }
    HeadingStencil { offsets, triangles }
}

/// The worst `tan²(tilt)` over the poses the body can rest in. On the parallelogram of
/// corners FL, FR, RL, RR (heights `h`), the body rests on the higher diagonal: with
/// `d = h_FL + h_RR - h_FR - h_RL >= 0` on FL-RR and either FR or RL (lifting RL or FR),
/// else on FR-RL and either FL or RR. Both poses of the pair are stable (it rocks).
fn settle_tan2(triangles: &[Option<Triangle>; 4], h: &[f64; 4]) -> f64 {
    // The corners bearing the body when corner `o` is lifted are the other three in order
    // (see heading_stencil): spelled out per lifted corner so the indices are constants.
    #[inline(always)]
    fn support(t: &Option<Triangle>, h: &[f64; 4], i: usize, j: usize, k: usize, worst: f64) -> f64 {
        let Some(t) = t else { return worst };
        debug_assert!((t.i, t.j, t.k) == (i, j, k));
        let (dj, dk) = (h[j] - h[i], h[k] - h[i]);
        let gx = t.inv[0][0] * dj + t.inv[0][1] * dk;
        let gy = t.inv[1][0] * dj + t.inv[1][1] * dk;
        // Both finite and >= 0 (never -0), `worst` >= -1: the same as `worst.max(..)`.
        let tan2 = gx * gx + gy * gy;
        if tan2 > worst {
            tan2
        } else {
            worst
        }
    }
    let d = h[0] + h[3] - h[1] - h[2];
    if d >= 0.0 {
        // Lift RL (1) or FR (2): the body rests on FL-RR.
        let worst = support(&triangles[1], h, 0, 2, 3, -1.0);
        support(&triangles[2], h, 0, 1, 3, worst)
    } else {
        let worst = support(&triangles[0], h, 1, 2, 3, -1.0);
        support(&triangles[3], h, 0, 1, 2, worst)
    }
}

/// Least-squares plane through window sums `s = [n, Σx, Σy, Σz, Σxx, Σxy, Σyy, Σxz, Σyz, Σzz]`,
/// centred at `(xc, yc)`; returns `(|∇z|, rms residual)`.
/// Below this eigenvalue ratio of the cells' spread, a window's cells count as collinear.
const COLLINEAR_RATIO: f64 = 1e-6;

fn fit_plane(s: &[f64; 10], xc: f64, yc: f64) -> Option<(f64, f64)> {
    let [n, sx, sy, sz, sxx, sxy, syy, sxz, syz, szz] = *s;
    let x = sx - n * xc;
    let y = sy - n * yc;
    let xx = sxx - 2.0 * xc * sx + n * xc * xc;
    let yy = syy - 2.0 * yc * sy + n * yc * yc;
    let xy = sxy - xc * sy - yc * sx + n * xc * yc;
    let xz = sxz - xc * sz;
    let yz = syz - yc * sz;
    // Normal equations [xx xy x; xy yy y; x y n] [a b c] = [xz yz sz], by Cramer's rule.
    let det = xx * (yy * n - y * y) - xy * (xy * n - y * x) + x * (xy * y - yy * x);
    // Collinear cells have no plane. The spread of the cells about their mean, `C`, has
    // `det C = det / n`; its eigenvalue ratio `λ_min/λ_max ≈ det C / (tr C)²` is >= ~1e-3 for
    // any non-collinear set of cells in a window (cells lie on a lattice) and ~1e-10 for
    // collinear ones (rounding of the window sums), so the test is scale-free. (Comparing
    // `det` with `xx·yy·n` instead passes on noise when the cells lie in one row or column:
    // `xx` or `yy` is then itself ~0. Regression test `collinear_ground_cells_have_no_plane`.)
    let trace = (xx - x * x / n) + (yy - y * y / n);
    if !(det / n > COLLINEAR_RATIO * trace * trace) {
        return None;
    }
    let a = (xz * (yy * n - y * y) - xy * (yz * n - y * sz) + x * (yz * y - yy * sz)) / det;
    let b = (xx * (yz * n - y * sz) - xz * (xy * n - y * x) + x * (xy * sz - yz * x)) / det;
    let c = (xx * (yy * sz - y * yz) - xy * (xy * sz - yz * x) + xz * (xy * y - yy * x)) / det;
    let sse = szz - a * xz - b * yz - c * sz;
    Some(((a * a + b * b).sqrt(), (sse.max(0.0) / n).sqrt()))
}

fn stamp_mission(g: &GridGeometry, item: &MissionItem, margin_m: f64, out: &mut [f32]) {
    let reach = item.radius_m + margin_m;
    if !(reach.is_finite() && item.position_world.is_finite() && item.radius_m >= 0.0) {
        return;
    }
    let res = g.resolution_m;
    let origin = g.origin_m();
    let lo = ((item.position_world - reach - origin) / res).floor();
    let hi = ((item.position_world + reach - origin) / res).ceil();
    let (x0, x1) = (lo.x.max(0.0) as usize, (hi.x.max(0.0) as usize).min(g.nx));
    let (y0, y1) = (lo.y.max(0.0) as usize, (hi.y.max(0.0) as usize).min(g.ny));
    for iy in y0..y1 {
        for ix in x0..x1 {
            let centre = origin + (DVec2::new(ix as f64, iy as f64) + 0.5) * res;
            let d = (centre - item.position_world).length();
            let value = if d <= item.radius_m {
                1.0
            } else if margin_m > 0.0 {
                (1.0 - (d - item.radius_m) / margin_m).max(0.0)
            } else {
                0.0
            };
            let c = iy * g.nx + ix;
            out[c] = out[c].max(value as f32);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_without_libm() {
        for x in [-2.5, -2.0, -1e-300, 0.0, 0.3, 1.0, 1.9999999999999998, 7.5e15] {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
        }
    }

    #[test]
    fn floor_small_is_floor() {
        let mut xs = vec![-2.5, -2.0, -1.5, -0.5, -1e-300, -0.0, 0.0, 0.3, 0.5, 1.0, 1.5, 2.5, 1.9999999999999998, -1.0000000000000002, 1e15 + 0.5, -1e15 - 0.5];
        let mut state = 5u64;
        for i in 0..200_000 {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let u = (state >> 11) as f64 / (1u64 << 53) as f64;
            let scale = [1.0, 100.0, 1e6, 1e12, 1e15][i % 5];
            let x = (u - 0.5) * 2.0 * scale;
            // Also integers, halves and their neighbours.
            let k = x.round();
            xs.extend([x, k, k + 0.5, f64::from_bits(k.to_bits() + 1), f64::from_bits(k.to_bits().wrapping_sub(1))]);
        }
        for x in xs {
            if x.abs() < FLOOR_SMALL_LIMIT {
                assert_eq!(floor_small(x), x.floor() as i64, "{x}");
                assert_eq!(floor_small(x), floor_i64(x), "{x}");
            }
        }
    }

    #[test]
    fn plane_fit_by_hand() {
        // z = 0.1 x - 0.2 y + 1 on a 3x3 grid of unit cells: slope sqrt(0.05), no residual.
        let mut s = [0.0; 10];
        for i in 0..3 {
            for j in 0..3 {
                let (x, y) = (i as f64, j as f64);
                let z = 0.1 * x - 0.2 * y + 1.0;
                let m = [1.0, x, y, z, x * x, x * y, y * y, x * z, y * z, z * z];
                for k in 0..10 {
                    s[k] += m[k];
                }
            }
        }
        let (grad, rms) = fit_plane(&s, 1.0, 1.0).unwrap();
        assert!((grad - 0.05f64.sqrt()).abs() < 1e-9 && rms < 1e-6, "{grad} {rms}");
    }

    #[test]
    fn collinear_ground_cells_have_no_plane() {
        // Window sums of cells at absolute positions far from the origin (as the map's
        // summed-area tables give them), centred at (xc, yc).
        fn sums(cells: &[(f64, f64, f64)]) -> [f64; 10] {
            let mut s = [0.0; 10];
            for &(x, y, z) in cells {
                for (k, v) in [1.0, x, y, z, x * x, x * y, y * y, x * z, y * z, z * z].into_iter().enumerate() {
                    s[k] += v;
                }
            }
            s
        }
        let (x0, y0) = (123.45, -678.95);
        // One column of cells 0.1 m apart, rising 3 cm/m: no plane.
        let column: Vec<_> = (0..9).map(|k| (x0, y0 + 0.1 * k as f64, 0.03 * 0.1 * k as f64)).collect();
        assert_eq!(fit_plane(&sums(&column), x0, y0 + 0.4), None);
        let row: Vec<_> = (0..9).map(|k| (x0 + 0.1 * k as f64, y0, 0.01 * k as f64)).collect();
        assert_eq!(fit_plane(&sums(&row), x0 + 0.4, y0), None);
        // The same column plus one cell beside its end: a plane, with the column's slope.
        let mut l_shape = column.clone();
        l_shape.push((x0 + 0.1, y0, 0.0));
        let (grad, rms) = fit_plane(&sums(&l_shape), x0, y0 + 0.4).expect("an L of cells spans a plane");
        assert!((grad - 0.03).abs() < 1e-6 && rms < 1e-9, "{grad} {rms}");
    }

    #[test]
    fn settling_on_a_plane_and_on_a_bump() {
        let robot = RobotConfig::default();
        let stencil = heading_stencil(&robot, 0.1, 0.0);
        assert_eq!(stencil.offsets, [(5, 3), (5, -3), (-5, 3), (-5, -3)]);
        // A plane rising 0.2 per metre along x: every support has that slope.
        let h = stencil.offsets.map(|(i, _)| 0.2 * i as f64 * 0.1);
        assert!((settle_tan2(&stencil.triangles, &h) - 0.04).abs() < 1e-12);
        // Front-left wheel on a 0.1 m block: the body rocks on the FL-RR diagonal, resting
        // either on FL, FR, RR (rolled: ∇ = (0, 0.1/0.6)) or on FL, RL, RR (pitched:
        // ∇ = (0.1/1.0, 0)); FL, FR, RL would leave RR in the air. The worst is the roll.
        let h = [0.1, 0.0, 0.0, 0.0];
        let tan2 = settle_tan2(&stencil.triangles, &h);
        assert!((tan2 - (0.1f64 / 0.6).powi(2)).abs() < 1e-12, "{tan2}");
    }
}
