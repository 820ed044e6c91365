//! Typed configuration of the terrain-risk pipeline (STEP, Fan et al. 2021): the robot model and
//! every stage's settings.
//!
//! Each field documents its unit and source. "subterra" as a source means an
//! engineering choice of this library, not a published value.

use std::cmp::Ordering;

use serde::{Deserialize, Serialize};

use crate::error::{require_non_negative, require_positive, Error, Result};

/// Largest number of cells of the coarse and the fine map together (a 200 m square at 0.1 m).
/// A cell takes about 300 bytes while a map is built and handed over (its 21 layers, the
/// builder's per-cell state, a copy for the caller): 4 M cells is about 1.2 GB.
const MAX_MAP_CELLS: f64 = 4_000_000.0;
/// Cell sides of a map accepted \[m\]: no range sensor resolves less than 1 mm, and a cell
/// wider than 10 m averages away every step and slope a wheel meets.
const MAP_RESOLUTION_RANGE_M: (f64, f64) = (1e-3, 10.0);
/// Largest number of polar bins (sectors x radial bins) of the ground segmentation.
const MAX_POLAR_BINS: f64 = 4_000_000.0;
/// Largest sensor range accepted \[m\].
const MAX_RANGE_M: f64 = 1_000.0;
/// Largest fusion window accepted \[s\].
const MAX_WINDOW_S: f64 = 60.0;
/// Largest number of scans kept in the fusion window.
const MAX_SCANS: usize = 1_000;
/// Largest number of headings the tilt layer settles the footprint at.
const MAX_TILT_HEADINGS: u32 = 64;
/// Largest robot side (length, width, height) accepted \[m\]: a mining haul truck is 15 m long.
const MAX_ROBOT_SIDE_M: f64 = 30.0;
/// Fastest robot accepted [m/s] (108 km/h).
const MAX_ROBOT_SPEED_M_S: f64 = 30.0;

/// The ground robot (a Clearpath Husky by default; Husky A200 data sheet).
///
/// The body frame is FLU with its origin at the centre of the footprint on the ground
/// (REP 120 `base_footprint`): the robot occupies `|x| <= length/2`, `|y| <= width/2`,
/// `0 <= z <= height`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotConfig {
    /// Footprint length along body x \[m\]. Husky: 0.99.
    pub length_m: f64,
    /// Footprint width along body y \[m\]. Husky: 0.67.
    pub width_m: f64,
    /// Height of the body's top above the ground \[m\]. Husky: 0.4.
    pub height_m: f64,
    /// Ground clearance: the belly's height above flat ground \[m\]. Husky: 0.13.
    pub ground_clearance_m: f64,
    /// Top speed [m/s]. Husky: 1.0.
    pub max_speed_m_s: f64,
    /// Tilt (angle of the settled body's z axis from vertical) below which the `tilt`
    /// risk is 0 \[deg\]. STEP: 10.
    pub tilt_safe_deg: f64,
    /// Tilt at and beyond which the `tilt` risk is 1 (lethal) \[deg\]. STEP: 25.
    pub tilt_lethal_deg: f64,
}

impl Default for RobotConfig {
    fn default() -> Self {
        Self::husky()
    }
}

impl RobotConfig {
    /// The Husky-like default robot (Clearpath Husky A200).
    pub fn husky() -> Self {
        Self {
            length_m: 0.99,
            width_m: 0.67,
            height_m: 0.4,
            ground_clearance_m: 0.13,
            max_speed_m_s: 1.0,
            tilt_safe_deg: 10.0,
            tilt_lethal_deg: 25.0,
        }
    }

    /// Checks every field, naming it (`robot.<field>`) on error.
    pub fn validate(&self) -> Result<()> {
        require_positive("robot.length_m", self.length_m)?;
        require_positive("robot.width_m", self.width_m)?;
        require_positive("robot.height_m", self.height_m)?;
        require_non_negative("robot.ground_clearance_m", self.ground_clearance_m)?;
        if self.ground_clearance_m >= self.height_m {
            return Err(Error::config(
                "robot.ground_clearance_m",
                format!("must be below robot.height_m = {}", self.height_m),
                self.ground_clearance_m,
            ));
        }
        require_positive("robot.max_speed_m_s", self.max_speed_m_s)?;
        for (field, side) in [("robot.length_m", self.length_m), ("robot.width_m", self.width_m), ("robot.height_m", self.height_m)] {
            if side > MAX_ROBOT_SIDE_M {
                return Err(Error::config(field, format!("must be at most {MAX_ROBOT_SIDE_M} m"), side));
            }
        }
        if self.max_speed_m_s > MAX_ROBOT_SPEED_M_S {
            return Err(Error::config("robot.max_speed_m_s", format!("must be at most {MAX_ROBOT_SPEED_M_S} m/s"), self.max_speed_m_s));
        }
        require_non_negative("robot.tilt_safe_deg", self.tilt_safe_deg)?;
        if !(self.tilt_lethal_deg.is_finite() && self.tilt_lethal_deg > self.tilt_safe_deg && self.tilt_lethal_deg < 90.0) {
            return Err(Error::config(
                "robot.tilt_lethal_deg",
                format!("must be in (robot.tilt_safe_deg = {}, 90)", self.tilt_safe_deg),
                self.tilt_lethal_deg,
            ));
        }
        Ok(())
    }

    /// The tilt ramp in radians.
    pub fn tilt_ramp_rad(&self) -> Ramp {
        Ramp { safe: self.tilt_safe_deg.to_radians(), lethal: self.tilt_lethal_deg.to_radians() }
    }
}

/// A linear risk ramp: 0 at and below `safe`, 1 at and beyond `lethal`, linear between.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ramp {
    /// Value of the quantity below which the risk is 0 (the quantity's unit).
    pub safe: f64,
    /// Value of the quantity at and beyond which the risk is 1 (the quantity's unit).
    pub lethal: f64,
}

impl Ramp {
    /// `clamp((x - safe)/(lethal - safe), 0, 1)`; NaN gives 0.
    #[inline]
    pub fn eval(&self, x: f64) -> f64 {
        // At or below `safe` (or NaN) the quotient is <= 0 (or NaN): no division needed.
        if x.partial_cmp(&self.safe).is_none_or(Ordering::is_le) {
            return 0.0;
        }
        let r = (x - self.safe) / (self.lethal - self.safe);
        if r > 0.0 {
            r.min(1.0)
        } else {
            0.0
        }
    }

    fn validate(&self, field: &str) -> Result<()> {
        require_non_negative(&format!("{field}.safe"), self.safe)?;
        if !(self.lethal.is_finite() && self.lethal > self.safe) {
            return Err(Error::config(format!("{field}.lethal"), format!("must be finite and > {field}.safe = {}", self.safe), self.lethal));
        }
        Ok(())
    }
}

/// Prefilter of the raw cloud.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PrefilterConfig {
    /// Points nearer the sensor than this are dropped \[m\]. subterra (lidar blind zone).
    pub min_range_m: f64,
    /// Points farther from the sensor than this are dropped \[m\]. subterra (VLP-16/OS1 ~100 m, but
    /// returns beyond 40 m are too sparse to map a 20 m grid).
    pub max_range_m: f64,
    /// Margin around the robot's box (body frame) inside which points are the robot's own \[m\].
    /// subterra.
    pub self_margin_m: f64,
    /// Voxel side for downsampling (first point of each voxel kept, in input order) \[m\];
    /// 0 disables it. subterra default: off (the grid already aggregates).
    pub voxel_m: f64,
    /// Side of the cubes used to count neighbours for sparse-outlier removal \[m\]. subterra.
    pub outlier_cell_m: f64,
    /// A point with fewer than this many other points in its cube and the 26 around it is
    /// an outlier; 0 disables the removal. subterra default: off (costs ~2 ms per 100k points).
    pub outlier_min_neighbors: u32,
}

/// Temporal fusion window.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FusionConfig {
    /// Window at full odometry confidence \[s\]; at confidence c only scans at most
    /// `c·window_s` older than the newest are fused (c = 0: the newest alone). STEP: 2 (1-5).
    pub window_s: f64,
    /// Most scans kept, newest first \[scans\]. subterra: 20 (2 s of a 10 Hz lidar).
    pub max_scans: usize,
}

/// Ground segmentation by line fits in cylindrical coordinates (Himmelsbach et al. 2010).
/// See [`segment_ground`](super::ground::segment_ground) for the exact algorithm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroundConfig {
    /// Number of angular sectors over 360° \[sectors\]. subterra: 360 (1°; Himmelsbach: 0.5-2°).
    pub sectors: u32,
    /// Radial bin width \[m\]. subterra: 0.2.
    pub bin_m: f64,
    /// Points at or beyond this horizontal range from the origin get no bin and are
    /// labelled obstacle \[m\]. subterra: 40.
    pub max_range_m: f64,
    /// Largest |slope| (rise over run) of a ground line \[1\]. subterra: 0.7 (35°, above the
    /// robot's lethal tilt so steep ground is still ground and the tilt layer rates it).
    pub max_slope: f64,
    /// Largest root-mean-square residual of a ground line's fit \[m\]. Himmelsbach T_RMSE; subterra: 0.05.
    pub max_rmse_m: f64,
    /// Largest distance of a new prototype from the line fitted so far (prediction) \[m\]. subterra: 0.1.
    pub max_prediction_error_m: f64,
    /// A line may only start at a prototype within this height of the current ground
    /// estimate \[m\]. Himmelsbach T_b; subterra: 0.2.
    pub max_start_height_m: f64,
    /// A radial gap between consecutive prototypes longer than this ends a line \[m\]. subterra: 3.
    pub max_gap_m: f64,
    /// Fewest prototypes of an accepted ground line \[points\]. subterra: 3.
    pub min_line_points: u32,
    /// A point is ground if its height above its sector's ground line is within ±this \[m\].
    /// Himmelsbach T_dground; subterra: 0.1.
    pub max_dist_to_line_m: f64,
    /// Void (missing ground, the STEP `negative` layer): the empty bins between two returns of a
    /// sector are *void* when the rays between them span more than this depression angle
    /// \[deg\]: beams must have crossed the expected ground there and none came back (a hole
    /// with no floor in range). 0 (the default) turns void detection off. It reads the
    /// absence of returns as evidence, so it suits a spinning lidar, whose beams are evenly
    /// spaced in elevation: set it above the sensor's vertical beam spacing (2.5 for the
    /// VLP-16's 2.0°, the coarsest supported lidar; OS1-64: 0.53°). On clouds without that
    /// structure (depth cameras with dropouts, sparse or merged clouds) empty bins near the
    /// robot are common and would be marked lethal. subterra.
    #[serde(default)]
    pub void_min_gap_deg: f64,
    /// Rises over unseen ground: a sector's first line, whose first prototype lies *above*
    /// the ground under the robot by more than `max_start_height_m`, with nothing seen before
    /// it lower than that (the blind ring around the robot), starts on the ground if a ramp
    /// no steeper than `max_slope` could climb there over that stretch and the line is level
    /// (rising at most `max_start_height_m` over this length) and spans at least this many
    /// metres: the plateau at the top of a ramp
    /// whose foot the robot stands on. A box top seen beyond its hidden face looks the same,
    /// so the span is long (a plateau, not a rock). 0 (the default) turns it off. subterra.
    #[serde(default)]
    pub unseen_rise_min_length_m: f64,
    /// Shadows of drops (the STEP `negative` layer): where rays passed below the expected
    /// ground beyond a return, the floor is missing somewhere between that return and them;
    /// the positions in between take the deepest such evidence as their `negative_depth`
    /// (the docs of [`segment_ground`](crate::terrain::segment_ground), *Shadow*). A pit's near edge hides its floor from the
    /// sensor: without this the cells just past the edge read as ground, rated only by rays
    /// that graze them. On (the default) for every sensor: it needs rays that passed below
    /// the ground, which dropouts do not make. subterra.
    #[serde(default = "enabled")]
    pub drop_shadows: bool,
    /// A run is a drop's shadow only behind a return whose ray descends at least this steeply
    /// \[deg\]: the robot's safe tilt. The ground hidden behind a return falls away at least as
    /// steeply as the ray that grazed it; seen more steeply than the robot's safe tilt, no
    /// reading of it is safe, seen shallower (far off, past a gentle crest) it may be a slope
    /// the robot could drive, and the sensor sees it again from closer. The Husky's 10° puts
    /// the limit 4 m out for a lidar 0.7 m up. subterra.
    #[serde(default = "default_min_grazing_deg")]
    pub drop_shadow_min_grazing_deg: f64,
}

/// `ground.drop_shadow_min_grazing_deg` by default: the Husky's safe tilt \[deg\].
fn default_min_grazing_deg() -> f64 {
    10.0
}

/// `true`, for `#[serde(default = "enabled")]`.
fn enabled() -> bool {
    true
}

/// `ground.void_min_gap_deg` for the simulated spinning lidars (VLP-16, OS1-64): above the
/// VLP-16's 2.0° ring spacing \[deg\].
#[cfg(test)]
pub(super) const SPINNING_LIDAR_VOID_MIN_GAP_DEG: f64 = 2.5;

/// Geometry of one robot-centred, world-axis-aligned map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapConfig {
    /// Cell side [m/cell]. STEP: 0.1 (coarse), subterra: 0.05 (fine).
    pub resolution_m: f64,
    /// Extent along world x \[m\]; rounded to whole cells. STEP: 20 (coarse), subterra: 8 (fine).
    pub size_x_m: f64,
    /// Extent along world y \[m\]; rounded to whole cells. STEP: 20 (coarse), subterra: 8 (fine).
    pub size_y_m: f64,
}

/// How the geometric layers are computed from the cells' points.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LayerConfig {
    /// Side of the square window of the ground-plane fit (slope, roughness) \[m\]; rounded to
    /// an odd number of cells. subterra: 0.7 (the Husky's width).
    pub plane_window_m: f64,
    /// Fewest cells with a ground height in the window for a plane fit \[cells\]. subterra: 4.
    pub plane_min_cells: u32,
    /// Side of the square patch under each wheel whose highest ground the wheel rests on
    /// (settling) \[m\]. subterra: 0.3 (about a Husky wheel's contact length).
    pub wheel_patch_m: f64,
    /// Headings the footprint is settled at, evenly spaced over [0°, 180°) from world x;
    /// the tilt layer is the worst of them \[headings\]. subterra: 4.
    pub tilt_headings: u32,
    /// Obstacle points up to this much above the robot's top still count for `collision` \[m\].
    /// subterra: 0.1.
    pub head_margin_m: f64,
    /// Obstacle points from this much *below* the ground clearance count for `collision` \[m\]:
    /// the clearance is the belly's height over flat ground, and over ground that curves
    /// under the footprint (a rock on a hump, a dip's rim) the belly rides lower than that
    /// above the ground next to the rock; a point's height above the ground also carries the
    /// lidar's range noise. subterra: 0.03 (2 σ of a 1.5 cm range noise; a 0.12 m rock meets
    /// a Husky's 0.13 m belly where the ground curves, mine seed 252).
    pub clearance_margin_m: f64,
}

/// Ramps (safe -> lethal) of the risk layers; the tilt ramp is in [`RobotConfig`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RiskConfig {
    /// `collision`: obstacle points in the cell between the clearance and the robot's top
    /// \[points\]. subterra: 0 -> 2.
    pub collision_points: Ramp,
    /// `step`: largest ground-height difference to an 8-neighbour \[m\]. subterra: 0.05 -> 0.15
    /// (about the Husky's wheel radius, 0.165).
    pub step_m: Ramp,
    /// `negative`: depth of missing ground below where it should have been seen \[m\].
    /// subterra: 0.07 -> 0.13 (lethal beyond the Husky's clearance).
    pub negative_m: Ramp,
    /// `roughness`: RMS residual of the ground-plane fit \[m\]. subterra: 0.02 -> 0.1.
    pub roughness_m: Ramp,
    /// `unknown`: risk of an unobserved cell, in [0, 1) \[1\]. subterra: 0.15 (small, non-lethal).
    pub unknown: f64,
    /// `mission`: the risk falls from 1 at an item's radius to 0 this much farther out \[m\];
    /// 0 gives a hard circle. subterra: 0.
    pub mission_margin_m: f64,
    /// Combined risk at or above which a cell is lethal, in (0, 1] \[1\]: the one definition of
    /// a lethal cell for every output (the planners never enter one, the MPC keeps off it,
    /// counts, pictures and exported grids mark it). subterra: 0.9.
    #[serde(default = "default_lethal_risk")]
    pub lethal_risk: f64,
}

fn default_lethal_risk() -> f64 {
    super::grid::DEFAULT_LETHAL_RISK
}

/// Per-cell uncertainty of the risk (STEP's CVaR needs a mean and a spread).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UncertaintyConfig {
    /// Range noise of the sensor, 1σ \[m\]. VLP-16 / OS1 data sheets: 0.03.
    pub range_sigma_m: f64,
    /// Growth of the height error with a cell's age in the fusion window (odometry drift) [m/s].
    /// subterra: 0.05.
    pub drift_m_per_s: f64,
    /// Height error that makes a 1σ risk error of 1 (the span of the step ramp) \[m\]. subterra: 0.1.
    pub height_span_m: f64,
    /// Risk spread (1σ) of an unobserved cell, and the cap of every cell's \[1\]. subterra: 0.3.
    pub max_sigma: f64,
}

/// Everything the terrain mapper needs besides the robot model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TerrainConfig {
    /// Prefilter.
    pub prefilter: PrefilterConfig,
    /// Temporal fusion.
    pub fusion: FusionConfig,
    /// Ground segmentation.
    pub ground: GroundConfig,
    /// The coarse, long-range map from the fused window (for the path planner).
    pub coarse: MapConfig,
    /// Whether the fine map is made.
    pub fine_enabled: bool,
    /// The fine, short-range map from the newest scan alone (for the tracker).
    pub fine: MapConfig,
    /// Geometric layers.
    pub layers: LayerConfig,
    /// Risk ramps.
    pub risk: RiskConfig,
    /// Uncertainty.
    pub uncertainty: UncertaintyConfig,
}

impl Default for GroundConfig {
    fn default() -> Self {
        Self {
            sectors: 360,
            bin_m: 0.2,
            max_range_m: 40.0,
            max_slope: 0.7,
            max_rmse_m: 0.05,
            max_prediction_error_m: 0.1,
            max_start_height_m: 0.2,
            max_gap_m: 3.0,
            min_line_points: 3,
            max_dist_to_line_m: 0.1,
            void_min_gap_deg: 0.0,
            unseen_rise_min_length_m: 0.0,
            drop_shadows: true,
            drop_shadow_min_grazing_deg: 10.0,
        }
    }
}

impl Default for TerrainConfig {
    fn default() -> Self {
        Self {
            prefilter: PrefilterConfig {
                min_range_m: 0.3,
                max_range_m: 40.0,
                self_margin_m: 0.1,
                voxel_m: 0.0,
                outlier_cell_m: 0.5,
                outlier_min_neighbors: 0,
            },
            fusion: FusionConfig { window_s: 2.0, max_scans: 20 },
            ground: GroundConfig::default(),
            coarse: MapConfig { resolution_m: 0.1, size_x_m: 20.0, size_y_m: 20.0 },
            fine_enabled: true,
            fine: MapConfig { resolution_m: 0.05, size_x_m: 8.0, size_y_m: 8.0 },
            layers: LayerConfig {
                plane_window_m: 0.7,
                plane_min_cells: 4,
                wheel_patch_m: 0.3,
                tilt_headings: 4,
                head_margin_m: 0.1,
                clearance_margin_m: 0.03,
            },
            risk: RiskConfig {
                collision_points: Ramp { safe: 0.0, lethal: 2.0 },
                step_m: Ramp { safe: 0.05, lethal: 0.15 },
                negative_m: Ramp { safe: 0.07, lethal: 0.13 },
                roughness_m: Ramp { safe: 0.02, lethal: 0.1 },
                unknown: 0.15,
                mission_margin_m: 0.0,
                lethal_risk: default_lethal_risk(),
            },
            uncertainty: UncertaintyConfig { range_sigma_m: 0.03, drift_m_per_s: 0.05, height_span_m: 0.1, max_sigma: 0.3 },
        }
    }
}

impl GroundConfig {
    /// Number of radial bins, `ceil(max_range_m / bin_m)`.
    pub fn bins(&self) -> usize {
        (self.max_range_m / self.bin_m).ceil() as usize
    }

    /// Checks every field, naming it (`ground.<field>`) on error.
    pub fn validate(&self) -> Result<()> {
        if self.sectors == 0 || self.sectors > 100_000 {
            return Err(Error::config("ground.sectors", "must be in 1..=100000", self.sectors));
        }
        require_positive("ground.bin_m", self.bin_m)?;
        require_positive("ground.max_range_m", self.max_range_m)?;
        if self.max_range_m > MAX_RANGE_M {
            return Err(Error::config("ground.max_range_m", format!("must be <= {MAX_RANGE_M} m"), self.max_range_m));
        }
        let polar = self.sectors as f64 * (self.max_range_m / self.bin_m).ceil();
        if polar > MAX_POLAR_BINS {
            return Err(Error::config(
                "ground.bin_m",
                format!("gives {polar:.0} polar bins with ground.sectors = {}; at most {MAX_POLAR_BINS:.0}", self.sectors),
                self.bin_m,
            ));
        }
        require_positive("ground.max_slope", self.max_slope)?;
        require_positive("ground.max_rmse_m", self.max_rmse_m)?;
        require_positive("ground.max_prediction_error_m", self.max_prediction_error_m)?;
        require_positive("ground.max_start_height_m", self.max_start_height_m)?;
        require_positive("ground.max_gap_m", self.max_gap_m)?;
        if self.min_line_points < 2 {
            return Err(Error::config("ground.min_line_points", "must be >= 2 (a line needs two points)", self.min_line_points));
        }
        require_positive("ground.max_dist_to_line_m", self.max_dist_to_line_m)?;
        if !(self.drop_shadow_min_grazing_deg.is_finite() && self.drop_shadow_min_grazing_deg >= 0.0 && self.drop_shadow_min_grazing_deg < 90.0) {
            return Err(Error::config("ground.drop_shadow_min_grazing_deg", "must be in [0, 90) deg", self.drop_shadow_min_grazing_deg));
        }
        if !(self.void_min_gap_deg.is_finite() && self.void_min_gap_deg >= 0.0 && self.void_min_gap_deg < 90.0) {
            return Err(Error::config("ground.void_min_gap_deg", "must be 0 (off) or in (0, 90) deg", self.void_min_gap_deg));
        }
        if !(self.unseen_rise_min_length_m.is_finite() && self.unseen_rise_min_length_m >= 0.0) {
            return Err(Error::config("ground.unseen_rise_min_length_m", "must be 0 (off) or a finite length > 0 m", self.unseen_rise_min_length_m));
        }
        Ok(())
    }
}

impl MapConfig {
    /// Cells along x and y: `max(1, round(size / resolution))`.
    pub fn cells(&self) -> (usize, usize) {
        let n = |size: f64| ((size / self.resolution_m).round() as usize).max(1);
        (n(self.size_x_m), n(self.size_y_m))
    }

    fn validate(&self, prefix: &str) -> Result<()> {
        require_positive(&format!("{prefix}.resolution_m"), self.resolution_m)?;
        let (lo, hi) = MAP_RESOLUTION_RANGE_M;
        if !(lo..=hi).contains(&self.resolution_m) {
            return Err(Error::config(format!("{prefix}.resolution_m"), format!("must be in [{lo}, {hi}] m (a cell side)"), self.resolution_m));
        }
        require_positive(&format!("{prefix}.size_x_m"), self.size_x_m)?;
        require_positive(&format!("{prefix}.size_y_m"), self.size_y_m)?;
        let cells = (self.size_x_m / self.resolution_m).round() * (self.size_y_m / self.resolution_m).round();
        if cells > MAX_MAP_CELLS {
            return Err(Error::config(
                format!("{prefix}.resolution_m"),
                format!("gives {cells:.0} cells over {} x {} m; at most {MAX_MAP_CELLS:.0}", self.size_x_m, self.size_y_m),
                self.resolution_m,
            ));
        }
        Ok(())
    }
}

impl TerrainConfig {

    /// Checks every field, naming it on error (`ground.bin_m`, `risk.step_m.lethal`, ...).
    pub fn validate(&self) -> Result<()> {
        let p = &self.prefilter;
        require_non_negative("prefilter.min_range_m", p.min_range_m)?;
        if !(p.max_range_m.is_finite() && p.max_range_m > p.min_range_m && p.max_range_m <= MAX_RANGE_M) {
            return Err(Error::config(
                "prefilter.max_range_m",
                format!("must be in (prefilter.min_range_m = {}, {MAX_RANGE_M}] m", p.min_range_m),
                p.max_range_m,
            ));
        }
        require_non_negative("prefilter.self_margin_m", p.self_margin_m)?;
        require_non_negative("prefilter.voxel_m", p.voxel_m)?;
        if p.voxel_m > 0.0 && p.voxel_m < 1e-3 {
            return Err(Error::config("prefilter.voxel_m", "must be 0 (off) or >= 0.001 m", p.voxel_m));
        }
        require_positive("prefilter.outlier_cell_m", p.outlier_cell_m)?;
        if p.outlier_cell_m < 1e-3 {
            return Err(Error::config("prefilter.outlier_cell_m", "must be >= 0.001 m", p.outlier_cell_m));
        }
        let f = &self.fusion;
        if !(f.window_s.is_finite() && f.window_s >= 0.0 && f.window_s <= MAX_WINDOW_S) {
            return Err(Error::config("fusion.window_s", format!("must be in [0, {MAX_WINDOW_S}] s"), f.window_s));
        }
        if f.max_scans == 0 || f.max_scans > MAX_SCANS {
            return Err(Error::config("fusion.max_scans", format!("must be in 1..={MAX_SCANS}"), f.max_scans));
        }
        self.ground.validate()?;
        self.coarse.validate("coarse")?;
        self.fine.validate("fine")?;
        if self.fine_enabled {
            let ((cx, cy), (fx, fy)) = (self.coarse.cells(), self.fine.cells());
            let cells = (cx * cy + fx * fy) as f64;
            if cells > MAX_MAP_CELLS {
                return Err(Error::config(
                    "fine.resolution_m",
                    format!("the coarse and the fine map together have {cells:.0} cells; at most {MAX_MAP_CELLS:.0}"),
                    self.fine.resolution_m,
                ));
            }
        }
        let l = &self.layers;
        require_positive("layers.plane_window_m", l.plane_window_m)?;
        if l.plane_min_cells < 3 {
            return Err(Error::config("layers.plane_min_cells", "must be >= 3 (a plane needs three cells)", l.plane_min_cells));
        }
        require_positive("layers.wheel_patch_m", l.wheel_patch_m)?;
        if l.tilt_headings == 0 || l.tilt_headings > MAX_TILT_HEADINGS {
            return Err(Error::config("layers.tilt_headings", format!("must be in 1..={MAX_TILT_HEADINGS}"), l.tilt_headings));
        }
        require_non_negative("layers.head_margin_m", l.head_margin_m)?;
        // Points the ground segmentation rated ground never count, whatever the margin: a
        // margin past the clearance counts every point off the ground up to the robot's top.
        if !(l.clearance_margin_m.is_finite() && (0.0..=1.0).contains(&l.clearance_margin_m)) {
            return Err(Error::config("layers.clearance_margin_m", "must be in [0, 1] m", l.clearance_margin_m));
        }
        for (map, prefix) in [(&self.coarse, "coarse"), (&self.fine, "fine")] {
            for (field, size) in [("layers.plane_window_m", l.plane_window_m), ("layers.wheel_patch_m", l.wheel_patch_m)] {
                if size / map.resolution_m > 101.0 {
                    return Err(Error::config(field, format!("spans more than 101 cells of {prefix}.resolution_m = {}", map.resolution_m), size));
                }
            }
        }
        let r = &self.risk;
        r.collision_points.validate("risk.collision_points")?;
        r.step_m.validate("risk.step_m")?;
        r.negative_m.validate("risk.negative_m")?;
        r.roughness_m.validate("risk.roughness_m")?;
        if !(0.0..1.0).contains(&r.unknown) {
            return Err(Error::config("risk.unknown", "must be in [0, 1) (unknown is never lethal)", r.unknown));
        }
        require_non_negative("risk.mission_margin_m", r.mission_margin_m)?;
        if !(r.lethal_risk > 0.0 && r.lethal_risk <= 1.0) {
            return Err(Error::config("risk.lethal_risk", "must be in (0, 1]", r.lethal_risk));
        }
        let u = &self.uncertainty;
        require_non_negative("uncertainty.range_sigma_m", u.range_sigma_m)?;
        require_non_negative("uncertainty.drift_m_per_s", u.drift_m_per_s)?;
        require_positive("uncertainty.height_span_m", u.height_span_m)?;
        if !(u.max_sigma.is_finite() && u.max_sigma > 0.0 && u.max_sigma <= 1.0) {
            return Err(Error::config("uncertainty.max_sigma", "must be in (0, 1]", u.max_sigma));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Config;

    #[test]
    fn defaults_hold_the_design_values() {
        let r = RobotConfig::default();
        assert_eq!((r.length_m, r.width_m, r.height_m, r.ground_clearance_m), (0.99, 0.67, 0.4, 0.13));
        assert_eq!((r.max_speed_m_s, r.tilt_safe_deg, r.tilt_lethal_deg), (1.0, 10.0, 25.0));
        r.validate().unwrap();
        let c = TerrainConfig::default();
        c.validate().unwrap();
        assert_eq!(c.fusion.window_s, 2.0);
        assert_eq!((c.coarse.resolution_m, c.coarse.cells()), (0.1, (200, 200)));
        assert_eq!(c.ground.bins(), 200);
    }

    #[test]
    fn maps_past_the_cell_budget_are_refused_before_anything_is_allocated() {
        // A strip 24.6 km long at 0.1 m: 9.8 M cells, which took 3 GB (a fuzzing finding).
        let mut c = TerrainConfig::default();
        c.coarse.size_x_m = 24_568.0;
        c.coarse.size_y_m = 4.0;
        let err = c.validate().unwrap_err().to_string();
        assert!(err.contains("coarse.resolution_m") && err.contains("at most 4000000"), "{err}");
        // Each map within the budget, both together over it.
        let mut c = TerrainConfig::default();
        c.coarse.size_x_m = 150.0;
        c.coarse.size_y_m = 150.0;
        c.fine.size_x_m = 150.0;
        c.fine.size_y_m = 150.0;
        c.fine.resolution_m = 0.1;
        c.fine_enabled = false;
        c.validate().unwrap();
        c.fine_enabled = true;
        let err = c.validate().unwrap_err().to_string();
        assert!(err.contains("fine.resolution_m") && err.contains("4500000 cells"), "{err}");
    }

    #[test]
    fn ramp_by_hand() {
        let ramp = Ramp { safe: 10.0, lethal: 25.0 };
        assert_eq!(ramp.eval(5.0), 0.0);
        assert!((ramp.eval(15.0) - 1.0 / 3.0).abs() < 1e-12);
        assert_eq!(ramp.eval(30.0), 1.0);
        assert_eq!(ramp.eval(f64::NAN), 0.0);
    }

    #[test]
    fn toml_round_trip_and_unknown_keys() {
        let c = TerrainConfig::default();
        let text = c.to_toml_string();
        assert_eq!(TerrainConfig::from_toml_str(&text).unwrap(), c);
        let bad = text.replace("window_s = 2.0", "window_s = 2.0\nwindow_ss = 1.0");
        assert!(TerrainConfig::from_toml_str(&bad).unwrap_err().to_string().contains("window_ss"));
    }

    #[test]
    fn bad_values_name_their_field() {
        let field_of = |c: TerrainConfig| c.validate().unwrap_err().to_string();
        let mut c = TerrainConfig::default();
        c.ground.bin_m = -0.2;
        assert!(field_of(c).contains("ground.bin_m"));
        let mut c = TerrainConfig::default();
        c.coarse.resolution_m = 1e-5;
        assert!(field_of(c).contains("coarse.resolution_m"));
        // A probe finding: one cell of 1e308 m passed the cell budget (one cell).
        let mut c = TerrainConfig::default();
        c.coarse.resolution_m = 1e308;
        let err = field_of(c);
        assert!(err.contains("coarse.resolution_m") && err.contains("[0.001, 10] m"), "{err}");
        let mut c = TerrainConfig::default();
        c.fine.resolution_m = 11.0;
        assert!(field_of(c).contains("fine.resolution_m"));
        let mut c = TerrainConfig::default();
        c.risk.step_m.lethal = 0.01;
        assert!(field_of(c).contains("risk.step_m.lethal"));
        let mut c = TerrainConfig::default();
        c.risk.unknown = 1.0;
        assert!(field_of(c).contains("risk.unknown"));
        let mut c = TerrainConfig::default();
        c.fusion.window_s = f64::NAN;
        assert!(field_of(c).contains("fusion.window_s"));
        let mut c = TerrainConfig::default();
        c.prefilter.max_range_m = 0.1;
        assert!(field_of(c).contains("prefilter.max_range_m"));
        let r = RobotConfig { tilt_lethal_deg: 5.0, ..RobotConfig::default() };
        assert!(r.validate().unwrap_err().to_string().contains("robot.tilt_lethal_deg"));
        let r = RobotConfig { ground_clearance_m: 1.0, ..RobotConfig::default() };
        assert!(r.validate().unwrap_err().to_string().contains("robot.ground_clearance_m"));
        // Sizes and speeds no ground robot has (1e9 m/s once overflowed a capacity).
        let r = RobotConfig { max_speed_m_s: 1e9, ..RobotConfig::default() };
        assert!(r.validate().unwrap_err().to_string().contains("robot.max_speed_m_s"));
        let r = RobotConfig { length_m: 1e9, ..RobotConfig::default() };
        assert!(r.validate().unwrap_err().to_string().contains("robot.length_m"));
    }

    #[test]
    fn a_window_too_long_for_the_speed_is_refused_before_the_scratch_map_is_allocated() {
        let robot = RobotConfig { max_speed_m_s: 30.0, ..RobotConfig::default() };
        let mut c = TerrainConfig::default();
        c.fusion.window_s = 60.0;
        let err = crate::terrain::TerrainMapper::new(robot, c).expect_err("refused").to_string();
        assert!(err.contains("fusion.window_s") && err.contains("robot.max_speed_m_s"), "{err}");
    }
}
