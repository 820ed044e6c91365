//! From labelled points to a [`RiskMap`]: binning, geometric layers, risk layers and
//! their uncertainty (pipeline steps 4-6).
//!
//! Every pass is O(points) or O(cells): points are binned into cells once (a fused scan
//! once in its life, see [`super::fusion`]); the plane fits use summed-area tables, so their
//! cost does not grow with the window.
//!
//! The layers are set out exactly on [`Layer`](super::Layer).

mod binning;
mod combine;
mod geometry;
mod tilt;
#[cfg(test)]
mod tests;

use std::sync::Arc;

use glam::{DVec2, DVec3, Vec3};

use super::config::{LayerConfig, MapConfig, RiskConfig, RobotConfig, UncertaintyConfig};
use super::grid::{GridGeometry, RiskMap};
use super::ground::GroundSegmenter;
use tilt::{heading_stencil, HeadingStencil};

/// A keep-out circle around a mission item (a dropped comm node, another robot).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MissionItem {
    /// Centre, world frame \[m\].
    pub position_world: DVec2,
    /// Radius of the lethal circle \[m\].
    pub radius_m: f64,
}

/// One scan's points as the map sees them.
pub(crate) struct ScanSource<'a> {
    /// Points relative to the scan's own body position, world axes \[m\].
    pub points_level: &'a [[f32; 3]],
    /// Each point's height above its ground line \[m\] (NaN: no ground line).
    pub heights: &'a [f32],
    /// The scan's body position minus the current body position, world axes \[m\].
    pub offset: Vec3,
    /// Age of the scan \[s\].
    pub age_s: f32,
}

/// One non-empty cell of a scan binned once when it arrived: its global cell index and the
/// sums of its points, heights relative to that scan's body origin.
#[derive(Debug, Clone, Copy)]
pub(super) struct BinnedCell {
    /// Global cell index along x (`floor(x_world / res)`).
    pub gx: i64,
    /// Global cell index along y.
    pub gy: i64,
    acc: CellAccumulator,
}

/// A pre-binned scan as the coarse map sees it.
pub(crate) struct BinnedSource<'a> {
    pub cells: &'a [BinnedCell],
    /// The scan's body z minus the current body z \[m\].
    pub dz: f32,
    /// Age of the scan \[s\].
    pub age_s: f32,
}

/// The newest scan's polar ground knowledge and where its sensor was.
pub(crate) struct NewestPolar<'a> {
    pub segmenter: &'a GroundSegmenter,
    /// Sensor position relative to the current body origin, world axes \[m\].
    pub sensor_level: DVec3,
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
    /// Adds a point at height `z` \[m\] whose height above its ground line is `h` \[m\].
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
    /// Cell-centre x relative to the newest sensor, by column \[m\].
    xs: Vec<f64>,
    /// Scratch cells [`bin_scan`](Self::bin_scan) has hit, in order of the first hit (its
    /// first entries; the rest is room to write one more without a test).
    touched: Vec<u32>,
}

impl MapBuilder {
    /// The scratch map the scans of one fusion window are binned into: the map grown by the
    /// distance the robot can drive within the window (plus 1 m of slack for odometry).
    pub(super) fn scratch_map(map: &MapConfig, robot: &RobotConfig, window_s: f64) -> MapConfig {
        let margin = robot.max_speed_m_s * window_s + 1.0;
        MapConfig { size_x_m: map.size_x_m + 2.0 * margin, size_y_m: map.size_y_m + 2.0 * margin, ..*map }
    }

    /// Configs are trusted (validated by the mapper).
    pub(super) fn new(map: MapConfig, robot: RobotConfig, layers: LayerConfig, risk: RiskConfig, uncertainty: UncertaintyConfig, ground_threshold: f64, window_s: f64) -> Self {
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
    pub(super) fn build(
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
}

/// `if c { a } else { b }`, as an integer select on the bits: a plain `f32` select on a
/// condition that is not itself a float comparison compiles to a branch on x86-64 (SSE2 has
/// no scalar float `cmov`), and where the condition depends on the data that branch is
/// mispredicted often.
#[inline(always)]
fn select_f32(c: bool, a: f32, b: f32) -> f32 {
    f32::from_bits(std::hint::select_unpredictable(c, a.to_bits(), b.to_bits()))
}
