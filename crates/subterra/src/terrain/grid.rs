//! The map geometry (robot-centred, world-axis-aligned cells) and the named layers over it.
//!
//! Cells are aligned to whole multiples of the resolution in the world frame: the cell with
//! global index `(gx, gy)` covers `[gx·res, (gx+1)·res) x [gy·res, (gy+1)·res)`, so a wall
//! lands in the same cells whatever the robot's pose. A map is the `nx x ny` block of cells
//! whose lower corner is `origin_cell = (floor(x_body/res) - nx/2, floor(y_body/res) - ny/2)`.
//! Layers are row-major `(ny, nx)` arrays: layer`[iy·nx + ix]` is [`CellIndex`] `{ix, iy}`.

use std::sync::Arc;

use glam::DVec2;

use super::config::MapConfig;
use crate::error::{Error, Result};

/// A cell of a map: column `ix` (along world x) and row `iy` (along world y).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CellIndex {
    /// Column, along world x, from the map's lower corner.
    pub ix: u32,
    /// Row, along world y, from the map's lower corner.
    pub iy: u32,
}

/// The default of `risk.lethal_risk`: a cell at or above this risk is lethal \[1\]. subterra:
/// 0.9, where the ramps of the risk layers are all but at their lethal end.
pub const DEFAULT_LETHAL_RISK: f64 = 0.9;

/// Where a map's cells are.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridGeometry {
    /// Cell side [m/cell].
    pub resolution_m: f64,
    /// Cells along world x.
    pub nx: usize,
    /// Cells along world y.
    pub ny: usize,
    /// Global index of cell `(0, 0)`: it covers `[gx·res, (gx+1)·res) x [gy·res, (gy+1)·res)`.
    pub origin_cell: (i64, i64),
}

impl GridGeometry {
    /// The map of `config` centred on the world position `(x_m, y_m)` (the robot).
    pub fn centred_on(config: &MapConfig, x_m: f64, y_m: f64) -> Self {
        let (nx, ny) = config.cells();
        let res = config.resolution_m;
        let gx = (x_m / res).floor() as i64 - (nx / 2) as i64;
        let gy = (y_m / res).floor() as i64 - (ny / 2) as i64;
        Self { resolution_m: res, nx, ny, origin_cell: (gx, gy) }
    }

    /// Number of cells.
    pub fn cells(&self) -> usize {
        self.nx * self.ny
    }

    /// World position of the map's lower corner (cell `(0, 0)`'s lower corner) \[m\].
    pub fn origin_m(&self) -> DVec2 {
        DVec2::new(self.origin_cell.0 as f64, self.origin_cell.1 as f64) * self.resolution_m
    }

    /// The cell containing the world position `(x_m, y_m)`, if inside the map.
    pub fn cell_of(&self, x_m: f64, y_m: f64) -> Option<CellIndex> {
        let gx = (x_m / self.resolution_m).floor() as i64 - self.origin_cell.0;
        let gy = (y_m / self.resolution_m).floor() as i64 - self.origin_cell.1;
        if (0..self.nx as i64).contains(&gx) && (0..self.ny as i64).contains(&gy) {
            Some(CellIndex { ix: gx as u32, iy: gy as u32 })
        } else {
            None
        }
    }

    /// World position of a cell's centre \[m\].
    pub fn centre_of(&self, cell: CellIndex) -> DVec2 {
        let g = DVec2::new((self.origin_cell.0 + cell.ix as i64) as f64, (self.origin_cell.1 + cell.iy as i64) as f64);
        (g + 0.5) * self.resolution_m
    }

    /// Position of a cell in a layer array: `iy·nx + ix`.
    pub fn flat(&self, cell: CellIndex) -> usize {
        cell.iy as usize * self.nx + cell.ix as usize
    }

    /// The cell at a position in a layer array.
    pub fn cell_at(&self, flat: usize) -> CellIndex {
        CellIndex { ix: (flat % self.nx) as u32, iy: (flat / self.nx) as u32 }
    }
}

/// The layers of a [`RiskMap`]. Heights are world z \[m\]; NaN marks "no value".
///
/// # The layers, exactly
/// Heights below are relative to the current body origin, world axes (the *level frame*);
/// the height layers add the body's world z. `thr = ground.max_dist_to_line_m`; a point's
/// `h` is its height above its scan's ground line ([`segment_ground`](super::segment_ground)).
/// - `count`, `min_height`, `max_height`, `age`: over all points in the cell.
/// - `ground_count`: points with `|h| <= thr`; `ground_height` = their mean z, else (no
///   ground point) the newest scan's ground line at the cell centre if a line covers the
///   cell's polar bin, else NaN. `observed` = 1 if the cell has a point or is so covered.
/// - `slope`, `plane_residual`: least-squares plane `z = a·x + b·y + c` through the ground
///   heights of the cells with one in the `w x w` window centred on the cell (`w` = the odd
///   cell count nearest `layers.plane_window_m / res`, clipped at the map's edge), needing
///   `layers.plane_min_cells` of them; slope `atan(sqrt(a² + b²))`, residual
///   `sqrt(SSE / n)`. NaN for cells without a ground height.
/// - `step_height`: `max |H(n) - H(c)|` over the 8 neighbours n with a ground height.
/// - `negative_depth`: at the cell centre, in the newest scan's polar bin: the bin's ground
///   line height minus the floor bound (the lower of the bin's lowest point and the
///   lowest ray that passed over the cell's radius), floored at 0; 0 without evidence. On
///   a cell with ground points of its own it is instead how far its lowest point lies
///   below their mean height, where that exceeds `thr`, else 0: seen ground is no hole
///   (the bin's line, carried across a hole, overestimates a lower floor seen beyond it),
///   but a rim cell holding part of the drop's wall or floor is as deep as they reach.
///   A cell without ground points in a drop's shadow (`ground.drop_shadows`: beyond the
///   bin's last return, in a run of bins that returned nothing, where rays passed below the
///   expected ground farther on) is at least as deep as the deepest such ray or point.
/// - `tilt_angle`: *settling*. Each wheel rests on the highest ground in a square patch
///   (`layers.wheel_patch_m`) around its corner of the footprint (`robot.length_m x
///   robot.width_m`, corners rounded to cell centres) at heading ψ; the rigid body rests on
///   three of the four corners whose plane passes at or above the fourth (for four corners
///   two such triangles exist: the robot can rock between them), and its tilt is the angle
///   of that plane from horizontal, `atan |∇z|`. The layer is the worst over both rocking
///   poses and the `layers.tilt_headings` headings `ψ = j·180°/J`. Where some corner patch
///   has no ground at every heading, the plane-fit slope stands in; else NaN.
/// - risks: `collision` = ramp(number of points with `clearance - clearance_margin < h <= height + head_margin`),
///   `step` = ramp(`step_height`), `negative` = ramp(`negative_depth`), `tilt` =
///   ramp(`tilt_angle`) with the robot's tilt ramp, `roughness` = ramp(`plane_residual`),
///   `unknown` = `risk.unknown` where not observed, `mission` = 1 within an item's radius of
///   its centre, falling linearly to 0 over `risk.mission_margin_m` (NaN inputs give 0).
///   `risk = 1 - Π(1 - r_k)`. A cell whose `negative` risk is above 0 is `observed` (its
///   rating comes from ray reasoning: beams passed below where its ground should have been),
///   so that a hole's inside is a known hazard, not unknown ground.
/// - `risk_variance` = σ², `σ = min(sqrt(σ_range²/max(n, 1) + (drift·age)²) / height_span,
///   max_sigma)` for observed cells (n = `count`, age = `age` or 0), `max_sigma` otherwise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(usize)]
pub enum Layer {
    /// Points in the cell (all scans fused into this map) \[points\].
    Count,
    /// Ground-labelled points in the cell \[points\].
    GroundCount,
    /// Ground height: mean z of the cell's ground points, else the newest scan's ground line
    /// where a line covers the cell, else NaN \[m\].
    GroundHeight,
    /// Lowest point's z \[m\].
    MinHeight,
    /// Highest point's z \[m\].
    MaxHeight,
    /// Slope of the ground plane fitted under the footprint-sized window \[rad\].
    Slope,
    /// Roughness: RMS residual of that plane fit \[m\].
    PlaneResidual,
    /// Largest ground-height difference to an 8-neighbour \[m\].
    StepHeight,
    /// Depth of the floor below where ground was expected (negative obstacles) \[m\].
    NegativeDepth,
    /// Worst tilt of the footprint settled on the ground, over the headings \[rad\].
    TiltAngle,
    /// 1 if the cell was observed (has points, or the newest scan's ground line covers it), else 0.
    Observed,
    /// Age of the newest scan that put a point in the cell \[s\]; NaN if none.
    Age,
    /// Risk: obstacle points between the clearance and the robot's top.
    Collision,
    /// Risk: steps.
    Step,
    /// Risk: drop-offs and holes.
    Negative,
    /// Risk: tilt of the settled footprint.
    Tilt,
    /// Risk: roughness.
    Roughness,
    /// Risk: unobserved cells (small, non-lethal).
    Unknown,
    /// Risk: keep-out circles around mission items.
    Mission,
    /// Combined risk `1 - Π(1 - r_k)` over the seven risk layers (the mean of the cell's risk).
    Risk,
    /// Variance of the cell's risk.
    RiskVariance,
}

impl Layer {
    /// Every layer, in storage order.
    pub const ALL: [Layer; 21] = [
        Layer::Count,
        Layer::GroundCount,
        Layer::GroundHeight,
        Layer::MinHeight,
        Layer::MaxHeight,
        Layer::Slope,
        Layer::PlaneResidual,
        Layer::StepHeight,
        Layer::NegativeDepth,
        Layer::TiltAngle,
        Layer::Observed,
        Layer::Age,
        Layer::Collision,
        Layer::Step,
        Layer::Negative,
        Layer::Tilt,
        Layer::Roughness,
        Layer::Unknown,
        Layer::Mission,
        Layer::Risk,
        Layer::RiskVariance,
    ];

    /// The seven risk layers combined into [`Layer::Risk`].
    pub const RISKS: [Layer; 7] =
        [Layer::Collision, Layer::Step, Layer::Negative, Layer::Tilt, Layer::Roughness, Layer::Unknown, Layer::Mission];

    /// The layer's name, as [`RiskMap::layer`] takes it.
    pub fn name(self) -> &'static str {
        match self {
            Layer::Count => "count",
            Layer::GroundCount => "ground_count",
            Layer::GroundHeight => "ground_height",
            Layer::MinHeight => "min_height",
            Layer::MaxHeight => "max_height",
            Layer::Slope => "slope",
            Layer::PlaneResidual => "plane_residual",
            Layer::StepHeight => "step_height",
            Layer::NegativeDepth => "negative_depth",
            Layer::TiltAngle => "tilt_angle",
            Layer::Observed => "observed",
            Layer::Age => "age",
            Layer::Collision => "collision",
            Layer::Step => "step",
            Layer::Negative => "negative",
            Layer::Tilt => "tilt",
            Layer::Roughness => "roughness",
            Layer::Unknown => "unknown",
            Layer::Mission => "mission",
            Layer::Risk => "risk",
            Layer::RiskVariance => "risk_variance",
        }
    }

    /// The layer of a name.
    pub fn from_name(name: &str) -> Option<Layer> {
        Self::ALL.iter().copied().find(|l| l.name() == name)
    }
}

/// A map: its geometry and every [`Layer`] as a contiguous `f32` array.
#[derive(Debug, Clone, PartialEq)]
pub struct RiskMap {
    geometry: GridGeometry,
    /// `Layer::ALL.len()` arrays of `geometry.cells()` values, in `Layer::ALL` order. Shared
    /// with the builder that made the map: once every copy of the map is dropped, the
    /// builder writes its next map into the same storage (no allocation and zero fill of
    /// megabytes per update). Nothing outside this crate mutates a map.
    data: Arc<Vec<f32>>,
    /// Time of the newest scan in the map \[s\].
    pub stamp_s: f64,
    /// Scans fused into the map.
    pub scans: usize,
    /// Points binned into the map (inside its extent).
    pub points: usize,
    /// Risk at or above which a cell is lethal (the mapper's `risk.lethal_risk`) \[1\]: the one
    /// definition of a lethal cell for the planners, the counts, the pictures and the
    /// exported grids ([`RiskMap::is_lethal`]).
    pub lethal_risk: f32,
}

impl RiskMap {
    /// A map with every layer zero.
    pub(crate) fn zeros(geometry: GridGeometry, stamp_s: f64) -> Self {
        Self { geometry, data: Arc::new(vec![0.0; Layer::ALL.len() * geometry.cells()]), stamp_s, scans: 0, points: 0, lethal_risk: DEFAULT_LETHAL_RISK as f32 }
    }

    /// A map in `storage` (a previous map's, see [`storage`](Self::storage)) if no copy of
    /// that map is alive and it has the size, its layers then holding stale values that the
    /// caller must overwrite; else [`zeros`](Self::zeros).
    pub(crate) fn reusing(storage: Option<Arc<Vec<f32>>>, geometry: GridGeometry, stamp_s: f64) -> Self {
        let len = Layer::ALL.len() * geometry.cells();
        match storage.and_then(|data| Arc::try_unwrap(data).ok()).filter(|data| data.len() == len) {
            Some(data) => Self { geometry, data: Arc::new(data), stamp_s, scans: 0, points: 0, lethal_risk: DEFAULT_LETHAL_RISK as f32 },
            None => Self::zeros(geometry, stamp_s),
        }
    }

    /// A handle on the map's storage, for [`reusing`](Self::reusing) once the map is dropped.
    pub(crate) fn storage(&self) -> Arc<Vec<f32>> {
        Arc::clone(&self.data)
    }

    /// Where the cells are.
    pub fn geometry(&self) -> &GridGeometry {
        &self.geometry
    }

    /// A layer, row-major `(ny, nx)`.
    pub fn get(&self, layer: Layer) -> &[f32] {
        let n = self.geometry.cells();
        &self.data[layer as usize * n..(layer as usize + 1) * n]
    }

    /// A layer, mutable.
    pub(crate) fn get_mut(&mut self, layer: Layer) -> &mut [f32] {
        let n = self.geometry.cells();
        &mut Arc::make_mut(&mut self.data)[layer as usize * n..(layer as usize + 1) * n]
    }

    /// Every layer, mutable, in `Layer::ALL` order.
    pub(crate) fn layers_mut(&mut self) -> Vec<&mut [f32]> {
        let n = self.geometry.cells();
        Arc::make_mut(&mut self.data).chunks_mut(n).collect()
    }

    /// A layer by name (see [`Layer::name`]), row-major `(ny, nx)`.
    pub fn layer(&self, name: &str) -> Result<&[f32]> {
        match Layer::from_name(name) {
            Some(layer) => Ok(self.get(layer)),
            None => Err(Error::input(
                "name",
                format!("unknown layer `{name}`; known layers: {}", Layer::ALL.map(Layer::name).join(", ")),
            )),
        }
    }

    /// The names of the layers, in storage order.
    pub fn layer_names() -> [&'static str; 21] {
        Layer::ALL.map(Layer::name)
    }

    /// Whether cell `flat` is lethal: its combined risk is at or above [`RiskMap::lethal_risk`].
    /// Observed or not: a lethal cell is never unknown.
    pub fn is_lethal(&self, flat: usize) -> bool {
        self.get(Layer::Risk)[flat] >= self.lethal_risk
    }

    /// The number of lethal cells ([`RiskMap::is_lethal`]).
    pub fn lethal_count(&self) -> usize {
        self.get(Layer::Risk).iter().filter(|&&r| r >= self.lethal_risk).count()
    }

    /// Combined risk at the world position `(x_m, y_m)`; `None` outside the map.
    pub fn risk_at(&self, x_m: f64, y_m: f64) -> Option<f32> {
        self.value_at(Layer::Risk, x_m, y_m)
    }

    /// A layer's value at the world position `(x_m, y_m)`; `None` outside the map.
    pub fn value_at(&self, layer: Layer, x_m: f64, y_m: f64) -> Option<f32> {
        let cell = self.geometry.cell_of(x_m, y_m)?;
        Some(self.get(layer)[self.geometry.flat(cell)])
    }

    /// `CVaR_α` of each cell's risk under a normal approximation (STEP):
    /// `clip(μ + σ·φ(Φ⁻¹(α))/(1 - α), 0, 1)` with μ = `risk`, σ² = `risk_variance`.
    pub fn cvar(&self, alpha: f64) -> Result<Vec<f32>> {
        let k = cvar_factor(alpha)?;
        Ok(self
            .get(Layer::Risk)
            .iter()
            .zip(self.get(Layer::RiskVariance))
            .map(|(&mean, &var)| (mean as f64 + var.max(0.0).sqrt() as f64 * k).clamp(0.0, 1.0) as f32)
            .collect())
    }
}

/// `φ(Φ⁻¹(α))/(1 - α)`, the CVaR of a standard normal at level α.
pub(super) fn cvar_factor(alpha: f64) -> Result<f64> {
    if !(alpha.is_finite() && alpha > 0.0 && alpha < 1.0) {
        return Err(Error::input("alpha", format!("must be in (0, 1), got {alpha}")));
    }
    let z = inverse_normal_cdf(alpha);
    let pdf = (-0.5 * z * z).exp() / (std::f64::consts::TAU).sqrt();
    Ok(pdf / (1.0 - alpha))
}

/// Φ⁻¹(p) for p in (0, 1): Acklam's rational approximation (relative error < 1.2e-9).
pub(super) fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] = [-3.969683028665376e1, 2.209460984245205e2, -2.759285104469687e2, 1.38357751867269e2, -3.066479806614716e1, 2.506628277459239];
    const B: [f64; 5] = [-5.447609879822406e1, 1.615858368580409e2, -1.556989798598866e2, 6.680131188771972e1, -1.328068155288572e1];
    const C: [f64; 6] = [-7.784894002430293e-3, -3.223964580411365e-1, -2.400758277161838, -2.549732539343734, 4.374664141464968, 2.938163982698783];
    const D: [f64; 4] = [7.784695709041462e-3, 3.224671290700398e-1, 2.445134137142996, 3.754408661907416];
    const P_LOW: f64 = 0.02425;
    if p < P_LOW {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5]) / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - P_LOW {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        let q = (-2.0 * (1.0 - p).ln()).sqrt();
        -(((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5]) / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_are_aligned_to_the_world() {
        let config = MapConfig { resolution_m: 0.1, size_x_m: 2.0, size_y_m: 1.0 };
        let a = GridGeometry::centred_on(&config, 0.04, 0.0);
        let b = GridGeometry::centred_on(&config, 0.37, -0.21);
        assert_eq!((a.nx, a.ny), (20, 10));
        assert_eq!(a.origin_cell, (-10, -5));
        assert_eq!(b.origin_cell, (-7, -8));
        // The same world point is the same global cell in both maps.
        let (p, q) = (a.cell_of(0.55, -0.25).unwrap(), b.cell_of(0.55, -0.25).unwrap());
        assert_eq!((p.ix as i64 + a.origin_cell.0, p.iy as i64 + a.origin_cell.1), (5, -3));
        assert_eq!((q.ix as i64 + b.origin_cell.0, q.iy as i64 + b.origin_cell.1), (5, -3));
        assert!((a.centre_of(p) - DVec2::new(0.55, -0.25)).length() < 1e-12);
        assert_eq!(a.cell_of(5.0, 0.0), None);
        assert_eq!(a.cell_at(a.flat(p)), p);
    }

    #[test]
    fn layers_by_name() {
        let config = MapConfig { resolution_m: 0.5, size_x_m: 2.0, size_y_m: 2.0 };
        let mut map = RiskMap::zeros(GridGeometry::centred_on(&config, 0.0, 0.0), 0.0);
        map.get_mut(Layer::Tilt)[5] = 0.25;
        assert_eq!(map.layer("tilt").unwrap()[5], 0.25);
        assert_eq!(map.layer("tilt").unwrap().len(), 16);
        assert!(map.layer("tilts").unwrap_err().to_string().contains("tilts"));
        for layer in Layer::ALL {
            assert_eq!(Layer::from_name(layer.name()), Some(layer));
        }
    }

    #[test]
    fn cvar_by_hand() {
        // α = 0.5: φ(0)/(0.5) = 0.7978845608.
        assert!((cvar_factor(0.5).unwrap() - 0.797_884_560_8).abs() < 1e-8);
        // α = 0.95: Φ⁻¹ = 1.644853627, φ = 0.103135624, / 0.05 = 2.06271.
        assert!((inverse_normal_cdf(0.95) - 1.644_853_627).abs() < 1e-8);
        assert!((cvar_factor(0.95).unwrap() - 2.062_712_5).abs() < 1e-5);
        assert!((inverse_normal_cdf(0.001) + 3.090_232_306).abs() < 1e-8);
        assert!(cvar_factor(1.0).unwrap_err().to_string().contains("alpha"));
    }
}
