//! Bindings of `subterra::terrain`: configs, `TerrainMapper`, `RiskMap`, `segment_ground`.
//!
//! Conversions, error mapping and GIL release only; every algorithm lives in the core crate.
//! The one per-cell loop here, [`PyRiskMap::to_image`], is a colour lookup for display.

use std::borrow::Cow;

use glam::DVec2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use subterra::terrain::{segment_ground as core_segment_ground, GroundConfig, Layer, MissionItem, RiskMap, RobotConfig, TerrainConfig, TerrainMapper, MAX_MISSION_ITEMS, TerrainStats, TerrainTimings};
use subterra::Isometry3;

use crate::shared::Shared;
use crate::convert::{arg, check_rows, isometry, real_array, type_name, MAX_POINTS};
use crate::config::{resolve, PyRobotConfig, PyTerrainConfig};
use crate::errors::{input_error, IntoPyResult};

/// Time between scans when `update` is not given a stamp [s] (a 10 Hz lidar).
const DEFAULT_SCAN_PERIOD_S: f64 = 0.1;
/// Colour of a risk-0 cell in [`PyRiskMap::to_image`] (green).
const SAFE_RGB: [f64; 3] = [0.0, 200.0, 0.0];
/// Colour of a lethal (risk-1) cell (red).
const LETHAL_RGB: [f64; 3] = [220.0, 0.0, 0.0];
/// Colour of an unobserved cell (grey).
const UNKNOWN_RGB: [u8; 3] = [128, 128, 128];

/// The robot of argument `robot` (any of the four forms; `None` is the Husky-like default).
pub(crate) fn resolve_robot(py: Python<'_>, robot: Option<&Bound<'_, PyAny>>) -> PyResult<RobotConfig> {
    resolve::<PyRobotConfig>(py, "robot", robot, || Ok(RobotConfig::husky()))
}

/// The terrain config of argument `argument` (any of the four forms).
pub(crate) fn resolve_config(py: Python<'_>, argument: &str, config: Option<&Bound<'_, PyAny>>) -> PyResult<TerrainConfig> {
    resolve::<PyTerrainConfig>(py, argument, config, || Ok(TerrainConfig::default()))
}

// ---------------------------------------------------------------- points

/// Calls `f` with the row-major coordinates of an `(N, 3)` numeric array (N >= 1). `float32`
/// C-ordered arrays are borrowed; other numeric dtypes are converted and non-contiguous
/// arrays copied.
pub(crate) fn with_points<T>(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>, f: impl FnOnce(&[f32]) -> T) -> PyResult<T> {
    let converted;
    let array = match value.cast::<PyArray2<f32>>() {
        Ok(a) => a.clone(),
        Err(_) => {
            let np = py.import("numpy")?;
            let raw = np
                .call_method1("asarray", (value,))
                .map_err(|_| input_error(py, format!("argument `{argument}` must be an (N, 3) array of numbers, got {}", type_name(value))))?;
            let kind: String = raw.getattr("dtype")?.getattr("kind")?.extract()?;
            if !matches!(kind.as_str(), "f" | "i" | "u") {
                return Err(input_error(py, format!("argument `{argument}` must be an (N, 3) array of real numbers (float32 preferred), got {}", type_name(&raw))));
            }
            let shape: Vec<usize> = raw.getattr("shape")?.extract()?;
            if shape.len() != 2 || shape[1] != 3 {
                return Err(input_error(py, format!("argument `{argument}` must have shape (N, 3), got {shape:?}")));
            }
            check_rows(py, argument, &shape, MAX_POINTS, "points")?;
            converted = raw.call_method1("astype", ("float32",))?;
            converted
                .cast::<PyArray2<f32>>()
                .map_err(|_| input_error(py, format!("argument `{argument}` must have shape (N, 3), got {}", type_name(&raw))))?
                .clone()
        }
    };
    let view = array.readonly();
    let shape = view.shape();
    if shape[1] != 3 {
        return Err(input_error(py, format!("argument `{argument}` must have shape (N, 3), got {shape:?}")));
    }
    if shape[0] == 0 {
        return Err(input_error(py, format!("argument `{argument}` is empty (shape {shape:?}); a scan needs at least one point")));
    }
    check_rows(py, argument, shape, MAX_POINTS, "points")?;
    let flat = match view.as_array().to_slice() {
        Some(s) => Cow::Borrowed(s),
        None => Cow::Owned(view.as_array().iter().copied().collect()),
    };
    Ok(f(&flat))
}

fn finite(py: Python<'_>, argument: &str, value: f64) -> PyResult<f64> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(input_error(py, format!("argument `{argument}` must be finite, got {value}")))
    }
}

// ---------------------------------------------------------------- RiskMap

/// A robot-centred, world-axis-aligned grid map with named layers (row-major `(ny, nx)`:
/// row `iy` along world y, column `ix` along world x; plot with `origin="lower"`).
#[pyclass(name = "RiskMap", module = "subterra._core", frozen)]
pub struct PyRiskMap {
    inner: RiskMap,
    kind: &'static str,
    stats: TerrainStats,
    timings: TerrainTimings,
}

impl PyRiskMap {
    /// The core map (the planner bindings read its `risk` layer in place).
    /// A Python map around a core map.
    pub(crate) fn from_core(inner: RiskMap, kind: &'static str, stats: TerrainStats, timings: TerrainTimings) -> Self {
        Self { inner, kind, stats, timings }
    }

    pub(crate) fn map(&self) -> &RiskMap {
        &self.inner
    }

    fn dims(&self) -> [usize; 2] {
        let g = self.inner.geometry();
        [g.ny, g.nx]
    }

    fn grid<'py>(&self, py: Python<'py>, data: Vec<f32>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        data.into_pyarray(py).reshape(self.dims())
    }
}

#[pymethods]
impl PyRiskMap {
    /// A copy of the layer `name` as a `float32` `(ny, nx)` array (see `layer_names`).
    fn layer<'py>(&self, py: Python<'py>, #[pyo3(from_py_with = arg::s_name)] name: String) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let data = self.inner.layer(&name).py_err(py)?.to_vec();
        self.grid(py, data)
    }

    /// Every layer's name, in storage order.
    #[getter]
    fn layer_names(&self) -> Vec<&'static str> {
        RiskMap::layer_names().to_vec()
    }

    /// The combined risk at the world position `(x, y)` [m]; `None` outside the map.
    fn risk_at(&self, py: Python<'_>, #[pyo3(from_py_with = arg::x)] x: f64, #[pyo3(from_py_with = arg::y)] y: f64) -> PyResult<Option<f32>> {
        Ok(self.inner.risk_at(finite(py, "x", x)?, finite(py, "y", y)?))
    }

    /// The value of layer `name` at the world position `(x, y)` [m]; `None` outside the map.
    fn value_at(&self, py: Python<'_>, #[pyo3(from_py_with = arg::s_name)] name: String, #[pyo3(from_py_with = arg::x)] x: f64, #[pyo3(from_py_with = arg::y)] y: f64) -> PyResult<Option<f32>> {
        let layer = Layer::from_name(&name).ok_or_else(|| {
            input_error(py, format!("argument `name`: unknown layer `{name}`; known layers: {}", RiskMap::layer_names().join(", ")))
        })?;
        Ok(self.inner.value_at(layer, finite(py, "x", x)?, finite(py, "y", y)?))
    }

    /// `CVaR_alpha` of each cell's risk (normal approximation), `float32` `(ny, nx)` in [0, 1].
    fn cvar<'py>(&self, py: Python<'py>, #[pyo3(from_py_with = arg::alpha)] alpha: f64) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let data = self.inner.cvar(alpha).py_err(py)?;
        self.grid(py, data)
    }

    /// Risk at or above which a cell is lethal (the mapper's `risk.lethal_risk`): the one
    /// definition of a lethal cell for every output.
    #[getter]
    fn lethal_risk(&self) -> f32 {
        self.inner.lethal_risk
    }

    /// A `bool` `(ny, nx)` array: the lethal cells (combined risk at or above `lethal_risk`,
    /// observed or not).
    fn lethal<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<bool>>> {
        let lethal: Vec<bool> = (0..self.inner.geometry().cells()).map(|c| self.inner.is_lethal(c)).collect();
        lethal.into_pyarray(py).reshape(self.dims())
    }

    /// The number of lethal cells.
    fn lethal_count(&self) -> usize {
        self.inner.lethal_count()
    }

    /// An RGB `uint8` `(ny, nx, 3)` image of a risk layer (default the combined `risk`):
    /// green (0) to red (1) linearly, grey where the cell was not observed; a lethal cell
    /// (combined risk at or above `lethal_risk`) is red whatever the layer. Row 0 is the
    /// lowest y: show it with `origin="lower"`.
    #[pyo3(signature = (layer = "risk".to_owned()), text_signature = "($self, layer='risk')")]
    fn to_image<'py>(&self, py: Python<'py>, #[pyo3(from_py_with = arg::s_layer)] layer: String) -> PyResult<Bound<'py, PyArray3<u8>>> {
        let values = self.inner.layer(&layer).py_err(py)?;
        let observed = self.inner.get(Layer::Observed);
        let mut rgb = Vec::with_capacity(values.len() * 3);
        for (c, (&v, &seen)) in values.iter().zip(observed).enumerate() {
            if self.inner.is_lethal(c) {
                rgb.extend(LETHAL_RGB.map(|x| x.round() as u8));
            } else if seen > 0.0 {
                let t = if v.is_nan() { 0.0 } else { (v as f64).clamp(0.0, 1.0) };
                rgb.extend((0..3).map(|c| (SAFE_RGB[c] + t * (LETHAL_RGB[c] - SAFE_RGB[c])).round() as u8));
            } else {
                rgb.extend(UNKNOWN_RGB);
            }
        }
        let [ny, nx] = self.dims();
        rgb.into_pyarray(py).reshape([ny, nx, 3])
    }

    /// `"coarse"` (the fused long-range map) or `"fine"` (the newest scan, short range).
    #[getter]
    fn kind(&self) -> &'static str {
        self.kind
    }
    /// Cell side [m].
    #[getter]
    fn resolution(&self) -> f64 {
        self.inner.geometry().resolution_m
    }
    /// Cells along world x.
    #[getter]
    fn nx(&self) -> usize {
        self.inner.geometry().nx
    }
    /// Cells along world y.
    #[getter]
    fn ny(&self) -> usize {
        self.inner.geometry().ny
    }
    /// `(ny, nx)`, the shape of every layer.
    #[getter]
    fn shape(&self) -> (usize, usize) {
        let [ny, nx] = self.dims();
        (ny, nx)
    }
    /// World position `(x, y)` of the map's lower corner [m].
    #[getter]
    fn origin(&self) -> (f64, f64) {
        let o = self.inner.geometry().origin_m();
        (o.x, o.y)
    }
    /// Global cell index `(gx, gy)` of cell (0, 0): it covers `[gx·res, (gx+1)·res) x [gy·res, (gy+1)·res)`.
    #[getter]
    fn origin_cell(&self) -> (i64, i64) {
        self.inner.geometry().origin_cell
    }
    /// `(x_min, x_max, y_min, y_max)` [m], for `imshow(..., extent=..., origin="lower")`.
    #[getter]
    fn extent(&self) -> (f64, f64, f64, f64) {
        let g = self.inner.geometry();
        let o = g.origin_m();
        (o.x, o.x + g.nx as f64 * g.resolution_m, o.y, o.y + g.ny as f64 * g.resolution_m)
    }
    /// `(ix, iy)` of the cell holding the world position `(x, y)` [m]; `None` outside.
    fn cell_of(&self, py: Python<'_>, #[pyo3(from_py_with = arg::x)] x: f64, #[pyo3(from_py_with = arg::y)] y: f64) -> PyResult<Option<(u32, u32)>> {
        Ok(self.inner.geometry().cell_of(finite(py, "x", x)?, finite(py, "y", y)?).map(|c| (c.ix, c.iy)))
    }
    /// World x of the cell centres, `(nx,)` [m].
    #[getter]
    fn x_centres<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let g = self.inner.geometry();
        (0..g.nx).map(|i| (g.origin_cell.0 as f64 + i as f64 + 0.5) * g.resolution_m).collect::<Vec<_>>().into_pyarray(py)
    }
    /// World y of the cell centres, `(ny,)` [m].
    #[getter]
    fn y_centres<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let g = self.inner.geometry();
        (0..g.ny).map(|i| (g.origin_cell.1 as f64 + i as f64 + 0.5) * g.resolution_m).collect::<Vec<_>>().into_pyarray(py)
    }
    /// Time of the newest scan in the map [s].
    #[getter]
    fn stamp(&self) -> f64 {
        self.inner.stamp_s
    }
    /// Scans fused into this map.
    #[getter]
    fn scans(&self) -> usize {
        self.inner.scans
    }
    /// Points binned into this map (inside its extent).
    #[getter]
    fn points(&self) -> usize {
        self.inner.points
    }
    /// Counts of the update that made this map.
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = &self.stats;
        let p = &s.prefilter;
        let d = PyDict::new(py);
        for (k, v) in [
            ("input_points", p.input),
            ("non_finite", p.non_finite),
            ("out_of_range", p.out_of_range),
            ("self_hits", p.self_hits),
            ("downsampled", p.downsampled),
            ("outliers", p.outliers),
            ("kept", p.kept),
            ("ground_points", s.ground_points),
            ("obstacle_points", s.obstacle_points),
            ("fused_scans", s.fused_scans),
            ("fused_points", s.fused_points),
            ("map_points", self.inner.points),
        ] {
            d.set_item(k, v)?;
        }
        Ok(d)
    }
    /// Seconds per stage of the update that made this map.
    #[getter]
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let t = &self.timings;
        let d = PyDict::new(py);
        for (k, v) in [("prefilter_s", t.prefilter_s), ("segment_s", t.segment_s), ("coarse_s", t.coarse_s), ("fine_s", t.fine_s), ("total_s", t.total_s)] {
            d.set_item(k, v)?;
        }
        Ok(d)
    }

    fn __repr__(&self) -> String {
        let g = self.inner.geometry();
        let o = g.origin_m();
        format!(
            "RiskMap(kind={:?}, shape=({}, {}), resolution={}, origin=({:.3}, {:.3}), scans={}, stamp={})",
            self.kind, g.ny, g.nx, g.resolution_m, o.x, o.y, self.inner.scans, self.inner.stamp_s
        )
    }
}

// ---------------------------------------------------------------- TerrainMapper

/// Points `(N, 3)` and their heights above ground `(N,)`.
type PointsAndHeights<'py> = (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray1<f32>>);

/// Terrain risk mapping for one ground robot and one sensor stream.
#[pyclass(name = "TerrainMapper", module = "subterra._core", frozen)]
pub struct PyTerrainMapper {
    inner: Shared<TerrainMapper>,
    last_stamp: Shared<Option<f64>>,
    last_coarse: Shared<Option<Py<PyRiskMap>>>,
    last_fine: Shared<Option<Py<PyRiskMap>>>,
}

#[pymethods]
impl PyTerrainMapper {
    #[new]
    #[pyo3(signature = (robot = None, config = None))]
    fn new(py: Python<'_>, robot: Option<&Bound<'_, PyAny>>, config: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        let robot = resolve_robot(py, robot)?;
        let config = resolve_config(py, "config", config)?;
        let inner = TerrainMapper::new(robot, config).py_err(py)?;
        Ok(Self { inner: Shared::new(inner), last_stamp: Shared::new(None), last_coarse: Shared::new(None), last_fine: Shared::new(None) })
    }

    /// Adds one scan and returns the coarse (fused) map; the fine map is `last_fine`.
    ///
    /// `points`: `(N, 3)` in the sensor frame [m] (float32; other real dtypes are converted);
    /// NaN points are dropped and counted. `stamp` [s]: default 0.1 s after the previous
    /// scan (0 for the first). Poses are 4x4 rigid matrices, default identity.
    /// `confidence` in [0, 1] shrinks the fusion window (0: the newest scan alone).
    /// Releases the GIL while it runs.
    #[pyo3(signature = (points, *, stamp = None, world_from_body = None, body_from_sensor = None, confidence = 1.0))]
    fn update(
        &self,
        py: Python<'_>,
        points: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = arg::opt_stamp)] stamp: Option<f64>,
        world_from_body: Option<&Bound<'_, PyAny>>,
        body_from_sensor: Option<&Bound<'_, PyAny>>,
        #[pyo3(from_py_with = arg::confidence)] confidence: f64,
    ) -> PyResult<Py<PyRiskMap>> {
        let world_from_body = match world_from_body {
            Some(m) => isometry(py, "world_from_body", m)?,
            None => Isometry3::IDENTITY,
        };
        let body_from_sensor = match body_from_sensor {
            Some(m) => isometry(py, "body_from_sensor", m)?,
            None => Isometry3::IDENTITY,
        };
        // The mapper's lock is held from the default stamp to its update, so that threads
        // sharing the mapper never compute the same default.
        let mut this = self.inner.lock();
        let stamp_s = match stamp {
            Some(s) => s,
            None => self.last_stamp.lock().map_or(0.0, |t| t + DEFAULT_SCAN_PERIOD_S),
        };
        let inner = &mut *this;
        let result = with_points(py, "points", points, |flat| py.detach(|| inner.update(flat, stamp_s, &world_from_body, &body_from_sensor, confidence)))?;
        let out = result.map_err(|e| e.renamed(&["stamp_s"], "stamp")).py_err(py)?;
        *self.last_stamp.lock() = Some(stamp_s);
        let coarse = Py::new(py, PyRiskMap { inner: out.coarse, kind: "coarse", stats: out.stats, timings: out.timings })?;
        *self.last_fine.lock() = match out.fine {
            Some(fine) => Some(Py::new(py, PyRiskMap { inner: fine, kind: "fine", stats: out.stats, timings: out.timings })?),
            None => None,
        };
        *self.last_coarse.lock() = Some(coarse.clone_ref(py));
        Ok(coarse)
    }

    /// The coarse map of the last update, or None before the first.
    #[getter]
    fn last_coarse(&self, py: Python<'_>) -> Option<Py<PyRiskMap>> {
        self.last_coarse.lock().as_ref().map(|m| m.clone_ref(py))
    }

    /// The fine map of the last update, or None (before the first, or `fine_enabled = false`).
    #[getter]
    fn last_fine(&self, py: Python<'_>) -> Option<Py<PyRiskMap>> {
        self.last_fine.lock().as_ref().map(|m| m.clone_ref(py))
    }

    /// Replaces the keep-out circles of the `mission` layer. Each item is `(x, y, radius)`
    /// [m, world frame] or a dict `{"position": (x, y), "radius": r}`; an empty list clears them.
    fn set_mission_items(&self, py: Python<'_>, items: &Bound<'_, PyAny>) -> PyResult<()> {
        let np = py.import("numpy")?;
        // The count is checked on the sequence (a broadcast view of 10^8 rows costs nothing to
        // refuse); a sequence without a length stops at the limit.
        let too_many = |n: usize| input_error(py, format!("argument `items` has {n} items: more than {MAX_MISSION_ITEMS}, the most accepted"));
        if let Ok(n) = items.len() {
            if n > MAX_MISSION_ITEMS {
                return Err(too_many(n));
            }
        }
        let mut parsed = Vec::new();
        let iter = items.try_iter().map_err(|_| input_error(py, format!("argument `items` must be a sequence, got {}", type_name(items))))?;
        for (i, item) in iter.enumerate() {
            if i >= MAX_MISSION_ITEMS {
                return Err(too_many(i + 1));
            }
            let item = item?;
            // Real numbers only: a complex value is refused, not cast (real_array checks the dtype).
            let numbers = |v: &Bound<'_, PyAny>| -> Option<Vec<f64>> {
                let raw = real_array(py, "items", v, "numbers").ok()?;
                np.call_method1("asarray", (raw, "float64")).ok()?.call_method0("ravel").ok()?.call_method0("tolist").ok()?.extract().ok()
            };
            let values = if let Ok(d) = item.cast::<PyDict>() {
                let position = d.get_item("position")?.and_then(|p| numbers(&p));
                let radius = d.get_item("radius")?.and_then(|r| numbers(&r));
                match (position, radius) {
                    (Some(p), Some(r)) if p.len() == 2 && r.len() == 1 => Some(vec![p[0], p[1], r[0]]),
                    _ => None,
                }
            } else {
                numbers(&item).filter(|v| v.len() == 3)
            };
            let v = values.ok_or_else(|| {
                input_error(py, format!("argument `items[{i}]` must be (x, y, radius) or {{\"position\": (x, y), \"radius\": r}}, got {}", type_name(&item)))
            })?;
            parsed.push(MissionItem { position_world: DVec2::new(v[0], v[1]), radius_m: v[2] });
        }
        self.inner.lock().set_mission_items(&parsed).py_err(py)
    }

    /// Forgets every scan (the recovery behaviour "clear the map"); the next stamp may be any.
    fn reset(&self) {
        self.inner.lock().reset();
        *self.last_stamp.lock() = None;
    }

    /// Scans held in the fusion window.
    #[getter]
    fn window_len(&self) -> usize {
        self.inner.lock().window_len()
    }

    /// The robot model.
    #[getter]
    fn robot(&self) -> PyRobotConfig {
        PyRobotConfig::from_core(*self.inner.lock().robot())
    }

    /// The config.
    #[getter]
    fn config(&self) -> PyTerrainConfig {
        PyTerrainConfig::from_core(*self.inner.lock().config())
    }

    /// The newest scan's kept points relative to the body origin, world-aligned axes
    /// (`float32` `(N, 3)` [m]; add the body's world position for world coordinates), and
    /// each one's height above its ground line (`float32` `(N,)` [m]; NaN: no line).
    /// A point is ground iff `|height| <= config.ground.max_dist_to_line_m`. None before
    /// the first update.
    fn newest_points<'py>(&self, py: Python<'py>) -> PyResult<Option<PointsAndHeights<'py>>> {
        let this = self.inner.lock();
        let Some((points, heights)) = this.newest_points_level() else { return Ok(None) };
        let n = points.len();
        let flat: Vec<f32> = points.into_iter().flatten().collect();
        Ok(Some((flat.into_pyarray(py).reshape([n, 3])?, heights.to_vec().into_pyarray(py))))
    }

    fn __repr__(&self) -> String {
        format!("TerrainMapper(window_len={}, last_stamp={:?})", self.inner.lock().window_len(), self.last_stamp)
    }
}

/// Labels each point of `points` (`(N, 3)` [m], sensor-centred, z up) ground (True) or
/// obstacle (False) by line fits in cylindrical coordinates (Himmelsbach et al. 2010).
/// `sensor_height` [m]: the sensor's height above the ground near it. `config`: a terrain
/// config (None, a dict, a `TerrainConfig` or a TOML path) whose `ground` section is used.
/// Releases the GIL while it runs.
#[pyfunction]
#[pyo3(signature = (points, *, sensor_height, config = None))]
fn segment_ground<'py>(py: Python<'py>, points: &Bound<'_, PyAny>, #[pyo3(from_py_with = arg::sensor_height)] sensor_height: f64, config: Option<&Bound<'_, PyAny>>) -> PyResult<Bound<'py, PyArray1<bool>>> {
    let ground: GroundConfig = resolve_config(py, "config", config)?.ground;
    let sensor_height = finite(py, "sensor_height", sensor_height)?;
    let labels = with_points(py, "points", points, |flat| py.detach(|| core_segment_ground(flat, &ground, sensor_height)))?.map_err(|e| e.renamed(&["sensor_height_m"], "sensor_height")).py_err(py)?;
    Ok(labels.into_pyarray(py))
}

/// Adds the terrain classes and functions to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyRiskMap>()?;
    m.add_class::<PyTerrainMapper>()?;
    m.add_function(wrap_pyfunction!(segment_ground, m)?)?;
    Ok(())
}
