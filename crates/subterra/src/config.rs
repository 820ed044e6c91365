//! Typed configuration of the APF-PF pipeline and its named presets.
//!
//! Defaults are the paper's values; each field documents its unit and source. The
//! committed files `configs/<preset>.toml` are the same values as text, and a test
//! keeps the two equal so that a paper default never changes silently.

use serde::{Deserialize, Serialize};

use crate::error::{require_non_negative, require_positive, Error, Result};

/// Names of the built-in presets, the default first.
pub const PRESET_NAMES: [&str; 5] = ["flight", "cable", "flight-memory", "acc2021", "flight-escape"];

/// Largest number of states (voxels + free) accepted; past this the grid is a mistake.
const MAX_STATES: usize = 4_000_000;
/// Largest memory the transition model's tables may take [bytes].
const MAX_TRANSITION_BYTES: usize = 1 << 30;
/// Bytes of transition tables per (state, depth bin): the class tables hold about
/// `(MAX_CLASSES + 1)² = 25` offsets and alias slots of 8 bytes each per entry (measured
/// 175-195 on the D435 with 11-150 bins).
const TRANSITION_BYTES_PER_STATE_BIN: usize = 200;
/// Largest particle count accepted.
const MAX_PARTICLES: usize = 50_000_000;
/// Largest block side \[px\].
const MAX_BLOCK_PX: u32 = 4096;
/// Largest number of depth bins accepted.
const MAX_DEPTH_BINS: f64 = 10_000.0;
/// Largest repulsive force magnitude a config may produce \[N\]; past this forces overflow
/// to infinity once weighted and summed.
const MAX_REPULSION: f64 = 1e12;
/// How close `(d_max - d_min) / k_d` must be to a whole number of bins.
const BIN_COUNT_TOLERANCE: f64 = 1e-6;

/// How the 2.5D voxel grid cuts the image and the depth range.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridConfig {
    /// Block width k_w \[px\]. Paper §V: 50.
    pub block_width_px: u32,
    /// Block height k_h \[px\]. Paper §V: 50.
    pub block_height_px: u32,
    /// Depth bin k_d \[m\]. Paper §V: 0.1.
    pub depth_bin_m: f64,
    /// Near end of the depth range d_min \[m\]. Paper §V: 0.1.
    pub depth_min_m: f64,
    /// Far end of the depth range d_max \[m\], the sensing horizon. Paper §V: 1.2.
    pub depth_max_m: f64,
}

/// Where the transition model puts the free state along the depth axis, i.e. the depth
/// `z(s_free)` of its bias factor `hn(z(s_free); σ_z)`. The paper does not say.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FreeStateDepth {
    /// At depth 0, factor 1: the authors' code stores `s_free` as the point (0, 0, 0)
    /// (apf_pf, `discretize_image`). The free state is then about as reachable as the
    /// nearest voxels (`flight`: voxel -> free ~4e-3 per frame).
    Zero,
    /// At the sensing horizon `d_max`, factor `e^{-d_max²/2σ_z²}` (e^-4.5 at `flight`;
    /// subterra's first reading: "no obstacle inside the horizon"). Free transitions are
    /// ~80x rarer (~6e-5 per frame at `flight`). Kept as an option; the default of a
    /// config file that does not name the field, so older files keep their meaning.
    #[default]
    Horizon,
}

/// Transition model `T(s -> s') ∝ hn(L1; σ_s)·hn(z(s'); σ_z)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransitionConfig {
    /// σ_s \[voxels\]: spread of the Manhattan-distance kernel. Paper §V: 8.
    pub sigma_s_voxels: f64,
    /// σ_z \[m\]: spread of the bias toward near target voxels. Paper §V: 0.4.
    pub sigma_z_m: f64,
    /// Depth of the free state in the depth bias (`zero`: the authors' code; `horizon`:
    /// subterra's earlier convention, the default when a file leaves it out).
    #[serde(default)]
    pub free_state_depth: FreeStateDepth,
}

/// Observation model: normal pdfs over per-voxel point counts.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObservationConfig {
    /// σ_o \[points\]: spread of an occupied voxel's count. Paper §V-B: 170 (§V-A: 300).
    pub sigma_o_points: f64,
    /// σ_n \[points\]: spread of the largest count under "free". Paper §V-B: 60 (§V-A: 1).
    pub sigma_n_points: f64,
}

/// Which Bayes filter runs over the voxel states.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FilterMode {
    /// Particle filter, as in the paper.
    Particle,
    /// Exact histogram Bayes filter over the same model (no sampling noise; subterra).
    Histogram,
    /// No filter: the baseline APF-PF argues against ("raw APF"). The belief is this
    /// frame's empirical histogram of in-range points, `b(s) = n_s / Σ n`, and
    /// `b(s_free) = 1` only when no point is in range. No transition model is built.
    Raw,
}

/// How particles are resampled after weighting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Resampling {
    /// One uniform draw, N evenly spaced pointers: lower variance (subterra default).
    Systematic,
    /// N independent draws, as in the paper.
    Multinomial,
}

/// Filter settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FilterConfig {
    /// Particle filter, exact histogram filter, or none (`raw`: the baseline).
    pub mode: FilterMode,
    /// Number of particles N. Paper §V: 20000.
    pub particles: usize,
    /// Resampling scheme.
    pub resampling: Resampling,
    /// Smallest probability with which the particle filter *proposes* the free state
    /// (subterra; 0 = the paper's plain bootstrap proposal). Under the model a particle
    /// reaches `s_free` with probability ~3e-5 per frame at `flight`, so 20000 particles
    /// put 0 or 1 particle there and P(free) flips between 0 and 1 on an empty frame.
    /// Proposing it more often and weighting by `T/q` keeps the estimate unbiased.
    pub free_proposal_min: f64,
}

/// How the net force becomes a velocity command.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CommandMode {
    /// Forward speed, vertical speed and yaw rate (paper eq. 10).
    Nonholonomic,
    /// A body-frame velocity along the force direction, no yaw.
    Holonomic,
}

/// Which point of a voxel its repulsive force comes from. The paper does not say.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum VoxelPosition {
    /// The block's top-left corner pixel `(i·k_w, j·k_h)` back-projected at the bin's near
    /// edge `d_min + k·k_d`: the authors' code (apf_pf, `discretize_image`). The conservative
    /// distance: at `flight` the repulsion of a voxel 1 m ahead is ~38% stronger than from
    /// its centre.
    NearCorner,
    /// The block's centre pixel at the bin's centre depth (subterra's earlier convention;
    /// the default when a file leaves it out).
    #[default]
    Centre,
}

/// Artificial potential fields and command limits.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ApfConfig {
    /// ρ_0 \[m\]: voxels farther than this do not repel. Authors' apf_acc.yaml: 1.4.
    pub rho_0_m: f64,
    /// η [N·m]: repulsive gain. apf_acc.yaml: 1.1.
    pub eta: f64,
    /// ξ [1/s]: attractive gain. apf_acc.yaml: 0.4.
    pub xi: f64,
    /// ρ_r \[m\]: beyond this goal distance the attraction is conic (constant magnitude). apf_acc.yaml: 0.5.
    pub rho_r_m: f64,
    /// Forward speed limit v_x,max [m/s]. Paper §V-B: 0.6.
    pub v_x_max_m_s: f64,
    /// Vertical speed limit v_z,max [m/s]. Paper §V-B: 0.6.
    pub v_z_max_m_s: f64,
    /// Yaw-rate limit ψ̇_max [rad/s]. Paper §V-B: 1.0.
    pub yaw_rate_max_rad_s: f64,
    /// Command mapping.
    pub mode: CommandMode,
    /// The robot stops within this distance of the goal \[m\] (subterra).
    pub success_radius_m: f64,
    /// `|x|` is clamped below at this in the repulsion, so it stays finite \[m\] (subterra).
    pub min_distance_m: f64,
    /// The point of a voxel its repulsion comes from (`near-corner`: the authors' code;
    /// `centre`: subterra's earlier convention, the default when a file leaves it out).
    #[serde(default)]
    pub voxel_position: VoxelPosition,
}

/// The obstacle memory ([`ObstacleMemory`](crate::apf::ObstacleMemory); subterra, not in the
/// paper): where the belief put obstacles, kept in the odometry frame so that they still repel
/// once out of view.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MemoryConfig {
    /// Whether a flight builds the memory. Off in the paper's presets.
    pub enabled: bool,
    /// Side of the world-frame cells in which remembered obstacles merge \[m\] (the depth bin).
    pub cell_m: f64,
    /// Belief a voxel needs to be remembered (a thin pole's belief spreads over its column's
    /// voxels, ~0.1-0.2 each).
    pub min_belief: f64,
    /// A remembered cell in the camera's view that the belief has not put an obstacle in for
    /// this long is forgotten \[s\]: the filter sees the place.
    pub in_view_timeout_s: f64,
    /// Any remembered cell is forgotten this long after the belief last put an obstacle in it
    /// \[s\] (odometry drifts; a hovering robot must not forget what is beside it sooner).
    pub timeout_s: f64,
    /// Cut-off ρ_m of the memory's repulsion \[m\]: short, so that it acts near contact only.
    pub rho_0_m: f64,
    /// At most this many cells are kept; the oldest go first.
    pub max_cells: u32,
    /// Near-field guard (0 = off): a voxel whose point lies within `rho_0_m` and whose count
    /// is at least `guard_sigmas · σ_n` is remembered with weight 1 whatever the belief
    /// holds. Under the free hypothesis the largest count is `N(0, σ_n)`, so such a count is
    /// not noise at `guard_sigmas` standard deviations; the belief over one obstacle can
    /// still sit on a wall behind a thin cable (docs/flight.md). The threshold scales with
    /// the preset's σ_n: 180 points in `flight-escape` (σ_n = 60), but 3 points with the
    /// `cable` preset's σ_n = 1, where it would fire on speckle.
    pub guard_sigmas: f64,
}

impl Default for MemoryConfig {
    fn default() -> Self {
        Self { enabled: false, cell_m: 0.1, min_belief: 0.01, in_view_timeout_s: 1.0, timeout_s: 10.0, rho_0_m: 0.6, max_cells: 4096, guard_sigmas: 0.0 }
    }
}

/// Largest number of memory cells accepted.
const MAX_MEMORY_CELLS: u32 = 1_000_000;

impl MemoryConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<()> {
        require_positive("memory.cell_m", self.cell_m)?;
        if !(self.min_belief > 0.0 && self.min_belief <= 1.0) {
            return Err(Error::config("memory.min_belief", "must be in (0, 1]", self.min_belief));
        }
        require_non_negative("memory.in_view_timeout_s", self.in_view_timeout_s)?;
        require_non_negative("memory.timeout_s", self.timeout_s)?;
        if self.in_view_timeout_s > self.timeout_s {
            return Err(Error::config("memory.in_view_timeout_s", format!("must not exceed memory.timeout_s = {}", self.timeout_s), self.in_view_timeout_s));
        }
        require_positive("memory.rho_0_m", self.rho_0_m)?;
        if self.max_cells == 0 || self.max_cells > MAX_MEMORY_CELLS {
            return Err(Error::config("memory.max_cells", format!("must be in 1..={MAX_MEMORY_CELLS}"), self.max_cells));
        }
        if !(self.guard_sigmas == 0.0 || (self.guard_sigmas >= 1.0 && self.guard_sigmas <= 100.0)) {
            return Err(Error::config("memory.guard_sigmas", "must be 0 (off) or in [1, 100]", self.guard_sigmas));
        }
        Ok(())
    }
}

/// Escape from local minima by boundary following ([`Escape`](crate::apf::Escape); subterra,
/// not in the paper).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EscapeConfig {
    /// Whether a flight runs the escape. Off in the paper's presets.
    pub enabled: bool,
    /// No progress for this long engages the escape \[s\] (well below the 10 s after which a
    /// flight counts as stuck).
    pub stall_s: f64,
    /// Progress: the remaining distance falling by at least this much \[m\].
    pub progress_m: f64,
    /// Remembered points within this horizontal distance are the boundary followed \[m\].
    pub follow_range_m: f64,
    /// ... and within this height of the robot \[m\].
    pub z_band_m: f64,
    /// Smallest distance kept from the boundary while following \[m\].
    pub min_standoff_m: f64,
    /// Largest distance kept from the boundary while following \[m\].
    pub max_standoff_m: f64,
    /// How hard the following turns toward the standoff, per metre off it [1/m].
    pub gain_per_m: f64,
    /// Released when the remaining distance is this much below that at the hit point \[m\].
    pub release_m: f64,
    /// Following one side this long without release flips the side \[s\].
    pub side_timeout_s: f64,
    /// A side that takes the remaining distance this much above where it began is flipped \[m\].
    pub max_detour_m: f64,
    /// Flips after which following stops and the stall must be detected afresh.
    pub max_flips: u32,
    /// While following, the repulsion is capped at this times the attraction's full
    /// strength `ρ_r·ξ` (the boundary term keeps the distance instead).
    pub follow_repulsion_ratio: f64,
    /// A way round a wall ahead is turned toward the goal only when, over the next 0.5 m,
    /// it keeps the remembered points at least `min(d₀, lookahead_keep_m)` away, `d₀` being
    /// the nearest one's distance now \[m\]: a collision margin (the quadrotor's 0.27 m
    /// radius and 0.13 m), not the standoff, so that a way between obstacles 1 m apart is
    /// still clear (`escape.rs`, steps 4-5).
    pub lookahead_keep_m: f64,
}

impl Default for EscapeConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            stall_s: 3.0,
            progress_m: 0.2,
            follow_range_m: 1.5,
            z_band_m: 0.6,
            min_standoff_m: 0.55,
            max_standoff_m: 0.8,
            gain_per_m: 3.0,
            release_m: 0.3,
            side_timeout_s: 25.0,
            max_detour_m: 3.0,
            max_flips: 1,
            follow_repulsion_ratio: 0.5,
            lookahead_keep_m: 0.4,
        }
    }
}

impl EscapeConfig {
    /// Checks every field.
    pub fn validate(&self) -> Result<()> {
        require_positive("escape.stall_s", self.stall_s)?;
        require_non_negative("escape.progress_m", self.progress_m)?;
        require_positive("escape.follow_range_m", self.follow_range_m)?;
        require_positive("escape.z_band_m", self.z_band_m)?;
        require_positive("escape.min_standoff_m", self.min_standoff_m)?;
        if !(self.max_standoff_m >= self.min_standoff_m && self.max_standoff_m <= self.follow_range_m) {
            return Err(Error::config(
                "escape.max_standoff_m",
                format!("must be in [escape.min_standoff_m = {}, escape.follow_range_m = {}]", self.min_standoff_m, self.follow_range_m),
                self.max_standoff_m,
            ));
        }
        require_non_negative("escape.gain_per_m", self.gain_per_m)?;
        require_non_negative("escape.release_m", self.release_m)?;
        require_positive("escape.side_timeout_s", self.side_timeout_s)?;
        require_positive("escape.max_detour_m", self.max_detour_m)?;
        require_non_negative("escape.follow_repulsion_ratio", self.follow_repulsion_ratio)?;
        if !(self.lookahead_keep_m.is_finite() && self.lookahead_keep_m > 0.0 && self.lookahead_keep_m <= self.min_standoff_m) {
            return Err(Error::config(
                "escape.lookahead_keep_m",
                format!("must be in (0, escape.min_standoff_m = {}]", self.min_standoff_m),
                self.lookahead_keep_m,
            ));
        }
        Ok(())
    }
}

/// Everything APF-PF needs besides the camera: one preset.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PerceptionConfig {
    /// Voxel grid.
    pub grid: GridConfig,
    /// Transition model.
    pub transition: TransitionConfig,
    /// Observation model.
    pub observation: ObservationConfig,
    /// Filter.
    pub filter: FilterConfig,
    /// Potential fields and command limits.
    pub apf: ApfConfig,
    /// Obstacle memory (subterra); absent from a file = the defaults, off.
    #[serde(default)]
    pub memory: MemoryConfig,
    /// Escape from local minima (subterra); absent from a file = the defaults, off.
    #[serde(default)]
    pub escape: EscapeConfig,
}

impl Default for PerceptionConfig {
    fn default() -> Self {
        Self::flight()
    }
}

impl PerceptionConfig {
    /// Preset `flight`: the paper's flight experiments (§V-B, authors' apf_acc.yaml).
    pub fn flight() -> Self {
        Self {
            grid: GridConfig {
                block_width_px: 50,
                block_height_px: 50,
                depth_bin_m: 0.1,
                depth_min_m: 0.1,
                depth_max_m: 1.2,
            },
            transition: TransitionConfig { sigma_s_voxels: 8.0, sigma_z_m: 0.4, free_state_depth: FreeStateDepth::Horizon },
            observation: ObservationConfig { sigma_o_points: 170.0, sigma_n_points: 60.0 },
            filter: FilterConfig { mode: FilterMode::Particle, particles: 20_000, resampling: Resampling::Systematic, free_proposal_min: 0.05 },
            apf: ApfConfig {
                rho_0_m: 1.4,
                eta: 1.1,
                xi: 0.4,
                rho_r_m: 0.5,
                v_x_max_m_s: 0.6,
                v_z_max_m_s: 0.6,
                yaw_rate_max_rad_s: 1.0,
                mode: CommandMode::Nonholonomic,
                success_radius_m: 0.3,
                min_distance_m: 0.05,
                voxel_position: VoxelPosition::Centre,
            },
            memory: MemoryConfig::default(),
            escape: EscapeConfig::default(),
        }
    }

    /// Preset `cable`: the static thin-cable test (§V-A): σ_o = 300, σ_n = 1.
    pub fn cable() -> Self {
        let mut config = Self::flight();
        config.observation = ObservationConfig { sigma_o_points: 300.0, sigma_n_points: 1.0 };
        config
    }

    /// Preset `flight-memory` (subterra): `flight` with the §V-A occupied spread σ_o = 300
    /// (a 22 mm pole is believed from ~1 m instead of ~0.65 m; σ_n = 60 still rejects
    /// speckle) and the obstacle memory on. The paper's `flight` grazes 22 mm poles
    /// (docs/flight.md); this is what `fly-batch` reaches 0 collisions with.
    pub fn flight_memory() -> Self {
        let mut config = Self::flight();
        config.observation.sigma_o_points = 300.0;
        config.memory.enabled = true;
        config
    }

    /// Preset `acc2021`: the paper (ACC 2021, §V-B) as the authors' code runs it: the
    /// `flight` values with the free state at depth 0 in the transition model, each
    /// voxel's repulsion from its block's corner pixel at its bin's near edge, the plain
    /// bootstrap proposal (`free_proposal_min = 0`) and multinomial resampling.
    pub fn acc2021() -> Self {
        let mut config = Self::flight();
        config.transition.free_state_depth = FreeStateDepth::Zero;
        config.apf.voxel_position = VoxelPosition::NearCorner;
        config.filter.free_proposal_min = 0.0;
        config.filter.resampling = Resampling::Multinomial;
        config
    }

    /// Preset `flight-escape` (subterra, the default of `subterra fly`): `flight-memory`
    /// with the escape from local minima on ([`Escape`](crate::apf::Escape)) and the memory's
    /// near-field guard at 3 σ_n ([`MemoryConfig::guard_sigmas`]). With the waypoint
    /// carrot of `subterra fly` it is the configuration measured best (docs/flight.md).
    pub fn flight_escape() -> Self {
        let mut config = Self::flight_memory();
        config.escape.enabled = true;
        config.memory.guard_sigmas = 3.0;
        config
    }

    /// A preset by name (see [`PRESET_NAMES`]).
    pub fn preset(name: &str) -> Result<Self> {
        match name {
            "flight" => Ok(Self::flight()),
            "cable" => Ok(Self::cable()),
            "flight-memory" => Ok(Self::flight_memory()),
            "acc2021" => Ok(Self::acc2021()),
            "flight-escape" => Ok(Self::flight_escape()),
            _ => Err(Error::UnknownPreset { name: name.to_owned(), known: PRESET_NAMES.join(", ") }),
        }
    }


    /// Number of depth bins `N_d = round((d_max - d_min)/k_d)`.
    pub fn depth_bins(&self) -> usize {
        let g = &self.grid;
        ((g.depth_max_m - g.depth_min_m) / g.depth_bin_m).round() as usize
    }

    /// Checks every field; the stack trusts a validated config.
    pub fn validate(&self) -> Result<()> {
        let g = &self.grid;
        for (field, px) in [("grid.block_width_px", g.block_width_px), ("grid.block_height_px", g.block_height_px)] {
            if px == 0 || px > MAX_BLOCK_PX {
                return Err(Error::config(field, format!("must be in 1..={MAX_BLOCK_PX} px"), px));
            }
        }
        require_positive("grid.depth_bin_m", g.depth_bin_m)?;
        require_non_negative("grid.depth_min_m", g.depth_min_m)?;
        require_positive("grid.depth_max_m", g.depth_max_m)?;
        if g.depth_max_m <= g.depth_min_m {
            return Err(Error::config("grid.depth_max_m", format!("must exceed grid.depth_min_m = {}", g.depth_min_m), g.depth_max_m));
        }
        let bins = (g.depth_max_m - g.depth_min_m) / g.depth_bin_m;
        if !(1.0..=MAX_DEPTH_BINS).contains(&bins.round()) {
            return Err(Error::config(
                "grid.depth_bin_m",
                format!("gives {bins:.0} depth bins over [{}, {}] m; must give 1..={MAX_DEPTH_BINS}", g.depth_min_m, g.depth_max_m),
                g.depth_bin_m,
            ));
        }
        if (bins - bins.round()).abs() > BIN_COUNT_TOLERANCE * bins.max(1.0) {
            return Err(Error::config(
                "grid.depth_bin_m",
                format!("must divide the depth range [{}, {}] m into a whole number of bins", g.depth_min_m, g.depth_max_m),
                g.depth_bin_m,
            ));
        }
        require_positive("transition.sigma_s_voxels", self.transition.sigma_s_voxels)?;
        require_positive("transition.sigma_z_m", self.transition.sigma_z_m)?;
        require_positive("observation.sigma_o_points", self.observation.sigma_o_points)?;
        require_positive("observation.sigma_n_points", self.observation.sigma_n_points)?;
        let n = self.filter.particles;
        if n == 0 || n > MAX_PARTICLES {
            return Err(Error::config("filter.particles", format!("must be in 1..={MAX_PARTICLES}"), n));
        }
        let q = self.filter.free_proposal_min;
        if !(0.0..1.0).contains(&q) {
            return Err(Error::config("filter.free_proposal_min", "must be in [0, 1)", q));
        }
        let a = &self.apf;
        require_positive("apf.rho_0_m", a.rho_0_m)?;
        require_non_negative("apf.eta", a.eta)?;
        require_non_negative("apf.xi", a.xi)?;
        require_positive("apf.rho_r_m", a.rho_r_m)?;
        require_non_negative("apf.v_x_max_m_s", a.v_x_max_m_s)?;
        require_non_negative("apf.v_z_max_m_s", a.v_z_max_m_s)?;
        require_non_negative("apf.yaw_rate_max_rad_s", a.yaw_rate_max_rad_s)?;
        require_non_negative("apf.success_radius_m", a.success_radius_m)?;
        require_positive("apf.min_distance_m", a.min_distance_m)?;
        let strongest = a.eta * (1.0 / a.min_distance_m - 1.0 / a.rho_0_m).max(0.0) / (a.min_distance_m * a.min_distance_m);
        self.memory.validate()?;
        self.escape.validate()?;
        if !(strongest.is_finite() && strongest <= MAX_REPULSION) {
            return Err(Error::config(
                "apf.eta",
                format!("with apf.min_distance_m = {} the repulsion reaches {strongest:.3e} N; at most {MAX_REPULSION:.0e}", a.min_distance_m),
                a.eta,
            ));
        }
        Ok(())
    }

    /// Validates the config together with the image size it will be used on.
    pub fn validate_for_image(&self, width: u32, height: u32) -> Result<()> {
        self.validate()?;
        let states = (width.div_ceil(self.grid.block_width_px) as usize)
            .checked_mul(height.div_ceil(self.grid.block_height_px) as usize)
            .and_then(|blocks| blocks.checked_mul(self.depth_bins()))
            .map_or(usize::MAX, |voxels| voxels.saturating_add(1));
        if states > MAX_STATES {
            return Err(Error::config("grid", format!("gives {states} states for a {width}x{height} image; at most {MAX_STATES}"), states));
        }
        let bytes = states.saturating_mul(self.depth_bins()).saturating_mul(TRANSITION_BYTES_PER_STATE_BIN);
        if bytes > MAX_TRANSITION_BYTES {
            return Err(Error::config(
                "grid.depth_bin_m",
                format!(
                    "gives {states} states in {} depth bins for a {width}x{height} image: the transition model would take about {:.1} GB, at most {:.1} GB (use wider depth bins or larger blocks)",
                    self.depth_bins(),
                    bytes as f64 / 1e9,
                    MAX_TRANSITION_BYTES as f64 / 1e9
                ),
                self.grid.depth_bin_m,
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Config;

    fn committed(name: &str) -> String {
        let path = format!("{}/../../configs/{name}.toml", env!("CARGO_MANIFEST_DIR"));
        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
    }

    #[test]
    fn builtin_presets_equal_the_committed_files() {
        for name in PRESET_NAMES {
            let from_file = PerceptionConfig::from_toml_str(&committed(name)).unwrap();
            assert_eq!(PerceptionConfig::preset(name).unwrap(), from_file, "preset {name} drifted from configs/{name}.toml");
        }
        assert_eq!(PerceptionConfig::default(), PerceptionConfig::flight());
    }

    #[test]
    fn presets_hold_the_paper_values() {
        let f = PerceptionConfig::flight();
        assert_eq!((f.observation.sigma_o_points, f.observation.sigma_n_points), (170.0, 60.0));
        assert_eq!(f.filter.particles, 20_000);
        assert_eq!(f.depth_bins(), 11);
        let c = PerceptionConfig::cable();
        assert_eq!((c.observation.sigma_o_points, c.observation.sigma_n_points), (300.0, 1.0));
        assert_eq!(c.grid, f.grid);
    }

    #[test]
    fn toml_round_trip() {
        let c = PerceptionConfig::cable();
        assert_eq!(PerceptionConfig::from_toml_str(&c.to_toml_string()).unwrap(), c);
    }

    #[test]
    fn bad_values_name_their_field() {
        let mut c = PerceptionConfig::flight();
        c.transition.sigma_s_voxels = -1.0;
        assert!(c.validate().unwrap_err().to_string().contains("transition.sigma_s_voxels"));
        let mut c = PerceptionConfig::flight();
        c.grid.depth_bin_m = 0.3;
        assert!(c.validate().unwrap_err().to_string().contains("grid.depth_bin_m"));
        let mut c = PerceptionConfig::flight();
        c.filter.particles = 0;
        assert!(c.validate().unwrap_err().to_string().contains("filter.particles"));
        let mut c = PerceptionConfig::flight();
        c.grid.depth_max_m = 0.05;
        assert!(c.validate().unwrap_err().to_string().contains("grid.depth_max_m"));
        assert!(matches!(PerceptionConfig::preset("hover"), Err(Error::UnknownPreset { .. })));
        let err = PerceptionConfig::from_toml_str("[grid]\nblock_width_px = 'x'").unwrap_err();
        assert!(matches!(err, Error::ConfigParse { .. }));
        let mut c = PerceptionConfig::flight();
        c.grid.depth_max_m = 1e300;
        assert!(c.validate().unwrap_err().to_string().contains("grid.depth_bin_m"));
        let mut c = PerceptionConfig::flight();
        c.apf.eta = 1e308;
        assert!(c.validate().unwrap_err().to_string().contains("apf.eta"));
        let mut c = PerceptionConfig::flight();
        c.grid.block_width_px = 1;
        c.grid.block_height_px = 1;
        assert!(c.validate_for_image(4000, 4000).unwrap_err().to_string().contains("states"));
        // 1000 bins of 1 cm over 0.1-10.1 m: 130k states would need about 26 GB of tables.
        let mut c = PerceptionConfig::flight();
        (c.grid.depth_bin_m, c.grid.depth_min_m, c.grid.depth_max_m) = (0.01, 0.1, 10.1);
        c.validate().unwrap();
        let err = c.validate_for_image(640, 480).unwrap_err().to_string();
        assert!(err.contains("grid.depth_bin_m") && err.contains("GB"), "{err}");
        // The guard is off (0) or 1-100 σ_n: under 1 σ_n it would fire on noise.
        for bad in [0.5, -1.0, f64::NAN, 101.0, f64::INFINITY] {
            let mut c = PerceptionConfig::flight_escape();
            c.memory.guard_sigmas = bad;
            assert!(c.validate().unwrap_err().to_string().contains("memory.guard_sigmas"), "{bad}");
        }
        for good in [0.0, 1.0, 100.0] {
            let mut c = PerceptionConfig::flight_escape();
            c.memory.guard_sigmas = good;
            c.validate().unwrap();
        }
    }

    #[test]
    fn unknown_keys_are_rejected() {
        let text = committed("flight").replace("eta = 1.1", "eta = 1.1\netaa = 2.0");
        assert!(PerceptionConfig::from_toml_str(&text).unwrap_err().to_string().contains("etaa"));
    }
}
