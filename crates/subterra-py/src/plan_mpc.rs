//! Bindings of the core's MPC tracker: `subterra::plan::MpcTracker` and `MpcOutput`.
//!
//! Conversions, error mapping and GIL release only; every algorithm lives in the core crate.

use std::borrow::Cow;

use glam::DVec2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use subterra::plan::{ConvexPolygon, MpcConfig, MpcOutput, MpcQp, MpcTracker, QpSolverKind, RiskGrid, UnicycleState};

use crate::shared::Shared;
use crate::convert::{arg, check_elements, real_array, small_vector, text, type_name, MAX_GRID_CELLS, MAX_PATH_POINTS};
use crate::errors::{input_error, IntoPyResult};
use crate::config::{resolve, PyMpcConfig};
use crate::terrain::PyRiskMap;

// ---------------------------------------------------------------- config

// ---------------------------------------------------------------- inputs

/// A finite float array of `value` with `ndim` dimensions (any real dtype is converted).
use real_array as float_array;

fn state_of(py: Python<'_>, state: &Bound<'_, PyAny>) -> PyResult<UnicycleState> {
    let v = small_vector(py, "state", state, 4, "4 numbers [x, y, heading, speed]")?;
    Ok(UnicycleState::from_array([v[0], v[1], v[2], v[3]]))
}

fn path_of(py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<Vec<DVec2>> {
    let what = "an (M, 2) array of world points [m], M >= 2";
    let raw = float_array(py, "reference_path", path, what)?;
    let shape: Vec<usize> = raw.getattr("shape")?.extract()?;
    if shape.len() != 2 || shape[1] != 2 {
        return Err(input_error(py, format!("argument `reference_path` must be {what}, got shape {shape:?}")));
    }
    check_elements(py, "reference_path", &shape[..1], MAX_PATH_POINTS, "points")?;
    let flat: Vec<f64> = raw.call_method1("astype", ("float64",))?.call_method0("ravel")?.call_method0("tolist")?.extract()?;
    Ok(flat.chunks_exact(2).map(|p| DVec2::new(p[0], p[1])).collect())
}

/// A risk grid held for the duration of one call: row-major `(ny, nx)` values and geometry.
struct RiskInput<'a> {
    values: Cow<'a, [f32]>,
    nx: usize,
    ny: usize,
    resolution_m: f64,
    origin_m: DVec2,
}

fn origin_of(py: Python<'_>, origin: &Bound<'_, PyAny>) -> PyResult<DVec2> {
    let v = small_vector(py, "origin", origin, 2, "2 numbers (x, y) [m]")?;
    Ok(DVec2::new(v[0], v[1]))
}

/// Calls `f` with the risk grid of `risk` (+ `resolution`, `origin`) or `risk_map`, if any.
fn with_risk<T>(
    py: Python<'_>,
    risk: Option<&Bound<'_, PyAny>>,
    resolution: Option<f64>,
    origin: Option<&Bound<'_, PyAny>>,
    risk_map: Option<&Bound<'_, PyAny>>,
    f: impl FnOnce(Option<&RiskInput<'_>>) -> T,
) -> PyResult<T> {
    match (risk, risk_map) {
        (Some(_), Some(_)) => Err(input_error(py, "arguments `risk` and `risk_map` are exclusive: give the array with `resolution` and `origin`, or a RiskMap")),
        (None, None) => {
            if resolution.is_some() || origin.is_some() {
                return Err(input_error(py, "arguments `resolution` and `origin` describe `risk`, which was not given"));
            }
            Ok(f(None))
        }
        (None, Some(map)) => {
            if resolution.is_some() || origin.is_some() {
                return Err(input_error(py, "arguments `resolution` and `origin` are taken from `risk_map`; do not pass them with it"));
            }
            let map = map.cast::<PyRiskMap>().map_err(|_| input_error(py, format!("argument `risk_map` must be a subterra.RiskMap, got {}", type_name(map))))?;
            let layer = map.call_method1("layer", ("risk",))?;
            let layer = layer.cast::<PyArray2<f32>>().map_err(|_| input_error(py, "argument `risk_map`: its risk layer is not a float32 array"))?;
            let view = layer.readonly();
            let (ny, nx) = (view.shape()[0], view.shape()[1]);
            let resolution_m: f64 = map.getattr("resolution")?.extract()?;
            let (ox, oy): (f64, f64) = map.getattr("origin")?.extract()?;
            let values = match view.as_array().to_slice() {
                Some(s) => Cow::Borrowed(s),
                None => Cow::Owned(view.as_array().iter().copied().collect()),
            };
            Ok(f(Some(&RiskInput { values, nx, ny, resolution_m, origin_m: DVec2::new(ox, oy) })))
        }
        (Some(risk), None) => {
            let resolution_m = resolution.ok_or_else(|| input_error(py, "argument `resolution` [m/cell] is required with `risk`"))?;
            let origin_m = match origin {
                Some(o) => origin_of(py, o)?,
                None => return Err(input_error(py, "argument `origin` (world x, y of the lower-left corner of cell (0, 0)) [m] is required with `risk`")),
            };
            let what = "a 2-D (ny, nx) array of risks in [0, 1] (float32 preferred)";
            let converted;
            let array = match risk.cast::<PyArray2<f32>>() {
                Ok(a) => {
                    check_elements(py, "risk", a.shape(), MAX_GRID_CELLS, "cells")?;
                    a.clone()
                }
                Err(_) => {
                    let raw = float_array(py, "risk", risk, what)?;
                    let ndim: usize = raw.getattr("ndim")?.extract()?;
                    if ndim != 2 {
                        return Err(input_error(py, format!("argument `risk` must be {what}, got {}", type_name(&raw))));
                    }
                    let shape: Vec<usize> = raw.getattr("shape")?.extract()?;
                    check_elements(py, "risk", &shape, MAX_GRID_CELLS, "cells")?;
                    converted = raw.call_method1("astype", ("float32",))?;
                    converted.cast::<PyArray2<f32>>().map_err(|_| input_error(py, format!("argument `risk` must be {what}")))?.clone()
                }
            };
            let view = array.readonly();
            let (ny, nx) = (view.shape()[0], view.shape()[1]);
            let values = match view.as_array().to_slice() {
                Some(s) => Cow::Borrowed(s),
                None => Cow::Owned(view.as_array().iter().copied().collect()),
            };
            Ok(f(Some(&RiskInput { values, nx, ny, resolution_m, origin_m })))
        }
    }
}

// ---------------------------------------------------------------- MpcOutput

fn rows_array<'py, const W: usize>(py: Python<'py>, rows: impl Iterator<Item = [f64; W]>) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let flat: Vec<f64> = rows.flatten().collect();
    let n = flat.len() / W;
    flat.into_pyarray(py).reshape([n, W])
}

fn polygon_array<'py>(py: Python<'py>, p: &ConvexPolygon) -> PyResult<Bound<'py, PyArray2<f64>>> {
    rows_array(py, p.vertices.iter().map(|v| [v.x, v.y]))
}

/// What one `MpcTracker.solve` gives.
#[pyclass(name = "MpcOutput", module = "subterra._core", frozen)]
pub struct PyMpcOutput {
    inner: MpcOutput,
}

#[pymethods]
impl PyMpcOutput {
    /// `(v, ω)` to send now: the speed at the end of the first step [m/s] and the yaw rate
    /// over it [rad/s].
    #[getter]
    fn command(&self) -> (f64, f64) {
        (self.inner.command.speed_m_s, self.inner.command.yaw_rate_rad_s)
    }
    /// Predicted states `[x, y, heading, speed]`, `(N+1, 4)` float64; row 0 is the given state.
    #[getter]
    fn predicted<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        rows_array(py, self.inner.predicted.iter().map(|s| s.to_array()))
    }
    /// Planned inputs `[accel, yaw_rate]`, `(N, 2)` float64 [m/s², rad/s].
    #[getter]
    fn inputs<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        rows_array(py, self.inner.inputs.iter().map(|u| [u.accel_m_s2, u.yaw_rate_rad_s]))
    }
    /// `"solved"`, `"solved_inexact"`, `"infeasible_backup"` or `"solver_failed_backup"`.
    #[getter]
    fn status(&self) -> &'static str {
        self.inner.status.name()
    }
    /// Whether `predicted` is the backup stop.
    #[getter]
    fn is_backup(&self) -> bool {
        self.inner.status.is_backup()
    }
    /// QPs solved (re-linearisations).
    #[getter]
    fn iterations(&self) -> u32 {
        self.inner.sqp_iterations
    }
    /// Interior-point iterations over all QPs.
    #[getter]
    fn qp_iterations(&self) -> u32 {
        self.inner.qp_iterations
    }
    /// Wall time of the solve [s].
    #[getter]
    fn solve_time_s(&self) -> f64 {
        self.inner.solve_time_s
    }
    /// `max(max_speed_slack, max_obstacle_slack)` of `predicted`.
    #[getter]
    fn max_slack(&self) -> f64 {
        self.inner.max_slack
    }
    /// Largest excess of a predicted speed over its limits [m/s].
    #[getter]
    fn max_speed_slack(&self) -> f64 {
        self.inner.max_speed_slack_m_s
    }
    /// Largest intrusion of a predicted footprint into an obstacle's margin [m].
    #[getter]
    fn max_obstacle_slack(&self) -> f64 {
        self.inner.max_obstacle_slack_m
    }
    /// Smallest signed distance from a predicted footprint to a lethal polygon [m]; inf if none.
    #[getter]
    fn min_clearance(&self) -> f64 {
        self.inner.min_clearance_m
    }
    /// Speed limit `v_max·(1 - r)` at predicted states 1..N, `(N,)` float64 [m/s].
    #[getter]
    fn speed_limits<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.speed_limits_m_s.clone().into_pyarray(py)
    }
    /// Reference points of predicted states 1..N, `(N, 2)` float64 [m].
    #[getter]
    fn reference_points<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        rows_array(py, self.inner.reference_points.iter().map(|p| [p.x, p.y]))
    }
    /// The lethal polygons considered: a list of `(K, 2)` float64 arrays, counter-clockwise [m].
    #[getter]
    fn polygons<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyArray2<f64>>>> {
        self.inner.polygons.iter().map(|p| polygon_array(py, p)).collect()
    }
    fn __repr__(&self) -> String {
        let o = &self.inner;
        format!(
            "MpcOutput(status={:?}, command=({:.3}, {:.3}), iterations={}, max_slack={:.4}, solve_time_s={:.6})",
            o.status.name(),
            o.command.speed_m_s,
            o.command.yaw_rate_rad_s,
            o.sqp_iterations,
            o.max_slack,
            o.solve_time_s
        )
    }
}

// ---------------------------------------------------------------- MpcTracker

/// The MPC path tracker of a ground robot (STEP, Fan et al. 2021): keeps its last plan to warm-start
/// the next solve.
/// Most entries of one array of a QP given to `MpcTracker.solve_qp`.
const MAX_QP_ENTRIES: usize = 1 << 22;

/// One 1-D array of the QP dict `qp`, key `key`, as real numbers.
fn qp_array<'py>(py: Python<'py>, qp: &Bound<'py, PyDict>, key: &str) -> PyResult<Bound<'py, PyAny>> {
    let argument = format!("qp[{key:?}]");
    let Some(value) = qp.get_item(key)? else {
        return Err(input_error(py, format!("argument `qp` must have the key {key:?} (see MpcTracker.last_qp)")));
    };
    let raw = real_array(py, &argument, &value, "a 1-D array")?;
    let shape: Vec<usize> = raw.getattr("shape")?.extract()?;
    if shape.len() != 1 {
        return Err(input_error(py, format!("argument `{argument}` must be a 1-D array, got shape {shape:?}")));
    }
    check_elements(py, &argument, &shape, MAX_QP_ENTRIES, "entries")?;
    Ok(raw)
}

fn qp_floats(py: Python<'_>, qp: &Bound<'_, PyDict>, key: &str) -> PyResult<Vec<f64>> {
    qp_array(py, qp, key)?.call_method1("astype", ("float64",))?.call_method0("tolist")?.extract()
}

fn qp_indices(py: Python<'_>, qp: &Bound<'_, PyDict>, key: &str) -> PyResult<Vec<usize>> {
    let raw = qp_array(py, qp, key)?;
    let kind: String = raw.getattr("dtype")?.getattr("kind")?.extract()?;
    let values: Vec<f64> = raw.call_method1("astype", ("float64",))?.call_method0("tolist")?.extract()?;
    if !matches!(kind.as_str(), "i" | "u") || values.iter().any(|&v| v < 0.0 || v > MAX_QP_ENTRIES as f64) {
        return Err(input_error(py, format!("argument `qp[{key:?}]` must hold integer indices in [0, {MAX_QP_ENTRIES}], got dtype kind {kind:?}")));
    }
    Ok(values.into_iter().map(|v| v as usize).collect())
}

#[pyclass(name = "MpcTracker", module = "subterra._core", frozen)]
pub struct PyMpcTracker {
    inner: Shared<MpcTracker>,
}

#[pymethods]
impl PyMpcTracker {
    /// `config`: None (the `configs/mpc.toml` defaults), a partial nested dict laid over
    /// them (`{"limits": {"max_speed_m_s": 0.5}}`), an `MpcConfig` or a TOML path.
    #[new]
    #[pyo3(signature = (config = None))]
    fn new(py: Python<'_>, config: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        let config = resolve::<PyMpcConfig>(py, "config", config, || Ok(MpcConfig::default()))?;
        Ok(Self { inner: Shared::new(MpcTracker::new(config).py_err(py)?) })
    }

    /// One solve from `state` `[x, y, heading, speed]` along `reference_path` `(M, 2)`
    /// (world [m], M >= 2). Risk: either `risk` (a `(ny, nx)` array, row `iy` along world
    /// y) with `resolution` [m/cell] and `origin` (world x, y of the lower-left corner of
    /// cell (0, 0)) [m], or `risk_map` (a `RiskMap`, its `risk` layer); neither means no
    /// risk and no obstacles. `desired_speed` [m/s]: None takes the config's. Releases the
    /// GIL while it runs.
    #[pyo3(signature = (state, reference_path, *, risk = None, resolution = None, origin = None, risk_map = None, desired_speed = None))]
    #[allow(clippy::too_many_arguments)]
    fn solve(
        &self,
        py: Python<'_>,
        state: &Bound<'_, PyAny>,
        reference_path: &Bound<'_, PyAny>,
        risk: Option<&Bound<'_, PyAny>>,
        #[pyo3(from_py_with = arg::opt_resolution)] resolution: Option<f64>,
        origin: Option<&Bound<'_, PyAny>>,
        risk_map: Option<&Bound<'_, PyAny>>,
        #[pyo3(from_py_with = arg::opt_desired_speed)] desired_speed: Option<f64>,
    ) -> PyResult<PyMpcOutput> {
        let state = state_of(py, state)?;
        let path = path_of(py, reference_path)?;
        let mut this = self.inner.lock();
        let tracker = &mut *this;
        let result = with_risk(py, risk, resolution, origin, risk_map, |grid| {
            let grid = match grid {
                None => None,
                Some(g) => match RiskGrid::new(&g.values, g.nx, g.ny, g.resolution_m, g.origin_m) {
                    Ok(grid) => Some(grid),
                    Err(e) => return Err(e),
                },
            };
            py.detach(|| tracker.solve(&state, &path, grid.as_ref(), desired_speed))
        })?;
        Ok(PyMpcOutput { inner: result.py_err(py)? })
    }

    /// The QP of the last SQP iteration of the last solve (None before the first): a dict of
    /// 1-D arrays `p_colptr`, `p_rowval`, `p_nzval` (`P`'s upper triangle in compressed
    /// columns: SciPy's `indptr`, `indices`, `data`), `q`, `a_colptr`, `a_rowval`, `a_nzval`,
    /// `b`, and the int `equalities`: `min ½zᵀPz + qᵀz` s.t. `A z = b` in the first
    /// `equalities` rows, `A z <= b` in the rest.
    fn last_qp<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(qp) = self.inner.lock().last_qp() else { return Ok(None) };
        let d = PyDict::new(py);
        let index = |v: Vec<usize>| v.into_iter().map(|i| i as i64).collect::<Vec<i64>>().into_pyarray(py);
        d.set_item("p_colptr", index(qp.p_colptr))?;
        d.set_item("p_rowval", index(qp.p_rowval))?;
        d.set_item("p_nzval", qp.p_nzval.into_pyarray(py))?;
        d.set_item("q", qp.q.into_pyarray(py))?;
        d.set_item("a_colptr", index(qp.a_colptr))?;
        d.set_item("a_rowval", index(qp.a_rowval))?;
        d.set_item("a_nzval", qp.a_nzval.into_pyarray(py))?;
        d.set_item("b", qp.b.into_pyarray(py))?;
        d.set_item("equalities", qp.equalities)?;
        Ok(Some(d))
    }

    /// Solves a QP laid out as `last_qp` returns it with the tracker's `solver` (`"banded"`,
    /// its own, or `"clarabel"`), at most `max_iterations` interior-point iterations (None: the default config's). Returns
    /// a dict: `z` (the solution; empty if the status is `"failed"`), `status` (`"solved"`,
    /// `"inexact"`, `"failed"`), `iterations`, `time_s` (in the solver). Releases the GIL.
    #[staticmethod]
    #[pyo3(signature = (qp, *, solver = None, max_iterations = None))]
    fn solve_qp<'py>(py: Python<'py>, qp: &Bound<'py, PyAny>, solver: Option<&Bound<'py, PyAny>>, max_iterations: Option<&Bound<'py, PyAny>>) -> PyResult<Bound<'py, PyDict>> {
        let d = qp.cast::<PyDict>().map_err(|_| input_error(py, format!("argument `qp` must be a dict as MpcTracker.last_qp returns, got {}", type_name(qp))))?;
        let kind = match solver.map(|s| text(py, "solver", s)).transpose()?.as_deref() {
            None | Some("banded") => QpSolverKind::Banded,
            Some("clarabel") => QpSolverKind::Clarabel,
            Some(other) => return Err(input_error(py, format!("argument `solver` must be \"banded\" or \"clarabel\", got {other:?}"))),
        };
        let max_iterations: u32 = match max_iterations {
            None => MpcConfig::default().solver.qp_max_iterations,
            Some(v) => v.extract().map_err(|_| input_error(py, format!("argument `max_iterations` must be an int in 1..=1000, got {}", type_name(v))))?,
        };
        let equalities = match d.get_item("equalities")? {
            Some(v) => v.extract::<usize>().map_err(|_| input_error(py, format!("argument `qp[\"equalities\"]` must be a non-negative int, got {}", type_name(&v))))?,
            None => return Err(input_error(py, "argument `qp` must have the key \"equalities\" (see MpcTracker.last_qp)")),
        };
        let problem = MpcQp {
            p_colptr: qp_indices(py, d, "p_colptr")?,
            p_rowval: qp_indices(py, d, "p_rowval")?,
            p_nzval: qp_floats(py, d, "p_nzval")?,
            q: qp_floats(py, d, "q")?,
            a_colptr: qp_indices(py, d, "a_colptr")?,
            a_rowval: qp_indices(py, d, "a_rowval")?,
            a_nzval: qp_floats(py, d, "a_nzval")?,
            b: qp_floats(py, d, "b")?,
            equalities,
        };
        let solution = py.detach(|| problem.solve(kind, max_iterations)).py_err(py)?;
        let out = PyDict::new(py);
        out.set_item("z", solution.z.into_pyarray(py))?;
        out.set_item("status", solution.status.as_str())?;
        out.set_item("iterations", solution.iterations)?;
        out.set_item("time_s", solution.time_s)?;
        Ok(out)
    }

    /// Forgets the last plan: the next solve starts from zero inputs.
    fn reset(&self) {
        self.inner.lock().reset();
    }

    /// The config in use.
    #[getter]
    fn config(&self) -> PyMpcConfig {
        PyMpcConfig::from_core(*self.inner.lock().config())
    }

    /// Steps N of the horizon.
    #[getter]
    fn horizon(&self) -> usize {
        self.inner.lock().config().horizon
    }

    /// Step [s].
    #[getter]
    fn dt(&self) -> f64 {
        self.inner.lock().config().dt_s
    }

    fn __repr__(&self) -> String {
        let this = self.inner.lock();
        let c = this.config();
        format!("MpcTracker(horizon={}, dt={}, max_speed_m_s={})", c.horizon, c.dt_s, c.limits.max_speed_m_s)
    }
}

/// Adds the MPC classes to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyMpcTracker>()?;
    m.add_class::<PyMpcOutput>()?;
    Ok(())
}
