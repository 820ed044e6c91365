//! Bindings of the core's risk-aware A*: `subterra::plan::RiskAStar` and its `PlanOutcome`.
//!
//! Conversions, error mapping and GIL release only; the search lives in the core crate.

use std::borrow::Cow;

use glam::DVec2;
use numpy::{IntoPyArray, PyArray2, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods};
use pyo3::prelude::*;
use subterra::plan::{PlanOutcome, RiskAStar, RiskAStarConfig, RiskGrid};
use subterra::terrain::{CellIndex, RiskMap};

use crate::shared::Shared;
use crate::convert::{check_elements, real, small_vector, type_name, MAX_GRID_CELLS};
use crate::config::{resolve, PyRiskAStarConfig};
use crate::errors::{input_error, IntoPyResult};
use crate::terrain::PyRiskMap;

/// Two numbers `(x, y)` from any sequence or array; finiteness is checked by the core.
fn point2(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>) -> PyResult<DVec2> {
    let v = small_vector(py, argument, value, 2, "two numbers (x, y) [m]")?;
    Ok(DVec2::new(v[0], v[1]))
}

/// A cell `(ix, iy)` from two non-negative integers; the grid bounds are checked by the core.
fn cell2(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>) -> PyResult<CellIndex> {
    let bad = || input_error(py, format!("argument `{argument}` must be two non-negative integers (ix, iy), got {}", type_name(value)));
    let v: Vec<i64> = value
        .extract()
        .or_else(|_| {
            let np = py.import("numpy")?;
            let a = np.call_method1("asarray", (value,))?;
            let kind: String = a.getattr("dtype")?.getattr("kind")?.extract()?;
            if !matches!(kind.as_str(), "i" | "u") {
                return Err(bad());
            }
            a.call_method0("ravel")?.call_method0("tolist")?.extract()
        })
        .map_err(|_| bad())?;
    match v[..] {
        [ix, iy] => match (u32::try_from(ix), u32::try_from(iy)) {
            (Ok(ix), Ok(iy)) => Ok(CellIndex { ix, iy }),
            _ => Err(input_error(py, format!("argument `{argument}` must be non-negative, got ({ix}, {iy})"))),
        },
        _ => Err(input_error(py, format!("argument `{argument}` must have 2 elements (ix, iy), got {}", v.len()))),
    }
}

/// A risk grid's parts, borrowed from a `RiskMap` or a NumPy array (copied only when the array
/// is not C-ordered `float32`).
enum GridParts<'a> {
    Map(&'a RiskMap),
    Array { risk: Cow<'a, [f32]>, nx: usize, ny: usize, resolution_m: f64, origin_m: DVec2 },
}

impl GridParts<'_> {
    /// The core's grid (checks every value: O(cells)).
    fn grid(&self) -> subterra::Result<RiskGrid<'_>> {
        match self {
            GridParts::Map(m) => RiskGrid::from_map(m),
            GridParts::Array { risk, nx, ny, resolution_m, origin_m } => RiskGrid::new(risk, *nx, *ny, *resolution_m, *origin_m),
        }
    }
}

/// Calls `f` with the grid given as `risk` (+ `resolution`, `origin` for an array).
fn with_grid<T>(
    py: Python<'_>,
    risk: &Bound<'_, PyAny>,
    resolution: Option<&Bound<'_, PyAny>>,
    origin: Option<&Bound<'_, PyAny>>,
    f: impl FnOnce(GridParts<'_>) -> T,
) -> PyResult<T> {
    if let Ok(map) = risk.cast::<PyRiskMap>() {
        for (name, value) in [("resolution", resolution), ("origin", origin)] {
            if value.is_some_and(|v| !v.is_none()) {
                return Err(input_error(py, format!("argument `{name}` must be None when `risk` is a RiskMap (the map carries its geometry)")));
            }
        }
        return Ok(f(GridParts::Map(map.get().map())));
    }
    let Ok(untyped) = risk.cast::<PyUntypedArray>() else {
        return Err(input_error(py, format!("argument `risk` must be a 2-D float array (ny, nx) or a subterra.RiskMap, got {}", type_name(risk))));
    };
    if untyped.ndim() != 2 {
        return Err(input_error(py, format!("argument `risk` must be 2-D (ny, nx), got shape {:?}", untyped.shape())));
    }
    check_elements(py, "risk", untyped.shape(), MAX_GRID_CELLS, "cells")?;
    let kind: String = untyped.dtype().getattr("kind")?.extract()?;
    if kind != "f" {
        return Err(input_error(py, format!("argument `risk` must be a float array (float32 preferred), got {}", type_name(risk))));
    }
    let resolution_m = match resolution {
        Some(v) if !v.is_none() => {
            // `real` refuses a complex or bool value (extract::<f64> took np.complex128(1) as 1.0).
            real(py, "resolution", v)?
        }
        _ => return Err(input_error(py, "argument `resolution` is required when `risk` is an array (cell side in metres)")),
    };
    let origin_m = match origin {
        Some(v) if !v.is_none() => point2(py, "origin", v)?,
        _ => DVec2::ZERO,
    };
    let converted;
    let array = match risk.cast::<PyArray2<f32>>() {
        Ok(a) => a.clone(),
        Err(_) => {
            converted = risk.call_method1("astype", ("float32",))?;
            converted.cast::<PyArray2<f32>>().map_err(|_| input_error(py, format!("argument `risk` cannot be read as float32, got {}", type_name(risk))))?.clone()
        }
    };
    let view = array.readonly();
    let (ny, nx) = (view.shape()[0], view.shape()[1]);
    // Borrow only a C-ordered buffer; anything else is copied in logical row-major order.
    let values = match view.as_array().to_slice() {
        Some(s) => Cow::Borrowed(s),
        None => Cow::Owned(view.as_array().iter().copied().collect()),
    };
    Ok(f(GridParts::Array { risk: values, nx, ny, resolution_m, origin_m }))
}

/// Where the plan should start and end.
enum Endpoints {
    World(DVec2, DVec2),
    Cells(CellIndex, CellIndex),
    Toward(DVec2, DVec2),
}

/// Risk-aware A* on an 8-connected grid (STEP, Fan et al. 2021); holds its search buffers between plans.
#[pyclass(name = "RiskAStar", module = "subterra._core", frozen)]
pub struct PyRiskAStar {
    inner: Shared<RiskAStar>,
}

impl PyRiskAStar {
    fn run(&self, py: Python<'_>, risk: &Bound<'_, PyAny>, ends: Endpoints, resolution: Option<&Bound<'_, PyAny>>, origin: Option<&Bound<'_, PyAny>>) -> PyResult<PyPlanOutcome> {
        let mut this = self.inner.lock();
        let planner = &mut *this;
        let outcome = with_grid(py, risk, resolution, origin, |parts| {
            py.detach(|| {
                let grid = parts.grid()?;
                match ends {
                    Endpoints::World(s, g) => planner.plan(&grid, s, g),
                    Endpoints::Cells(s, g) => planner.plan_cells(&grid, s, g),
                    Endpoints::Toward(s, t) => planner.plan_toward(&grid, s, t, None),
                }
            })
        })?;
        Ok(PyPlanOutcome { inner: outcome.py_err(py)? })
    }
}

#[pymethods]
impl PyRiskAStar {
    /// `config`: None (the `configs/astar.toml` defaults), a (partial) dict laid over them
    /// (`{"lam": 0.5, "cost_model": "additive"}`), a `RiskAStarConfig` or a TOML path.
    #[new]
    #[pyo3(signature = (config = None))]
    fn new(py: Python<'_>, config: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        let config = resolve::<PyRiskAStarConfig>(py, "config", config, || Ok(RiskAStarConfig::default()))?;
        Ok(Self { inner: Shared::new(RiskAStar::new(config).py_err(py)?) })
    }

    /// Plans from the world position `start` = (x, y) [m] to `goal`. `risk`: a
    /// `subterra.RiskMap` (its `risk` layer and geometry) or a 2-D float array `(ny, nx)` of
    /// per-metre risks (row iy along world y, column ix along world x; converted to float32;
    /// NaN = unknown) with `resolution` [m/cell] and `origin` (x, y) of cell (0, 0)'s lower-left
    /// corner [m], default (0, 0). Releases the GIL while it runs.
    #[pyo3(signature = (risk, start, goal, *, resolution = None, origin = None))]
    fn plan(
        &self,
        py: Python<'_>,
        risk: &Bound<'_, PyAny>,
        start: &Bound<'_, PyAny>,
        goal: &Bound<'_, PyAny>,
        resolution: Option<&Bound<'_, PyAny>>,
        origin: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyPlanOutcome> {
        let ends = Endpoints::World(point2(py, "start", start)?, point2(py, "goal", goal)?);
        self.run(py, risk, ends, resolution, origin)
    }

    /// Like `plan`, toward a `target` (x, y) [m] that may lie beyond the grid: the path leaves
    /// by the border cell whose cost to reach plus λ per metre of straight line on to the
    /// target is least (one search; docs/planning.md, "Toward a target off the grid"). The
    /// result's `goal_cell` is that border cell; a target on the grid is planned to as by
    /// `plan`.
    #[pyo3(signature = (risk, start, target, *, resolution = None, origin = None))]
    fn plan_toward(
        &self,
        py: Python<'_>,
        risk: &Bound<'_, PyAny>,
        start: &Bound<'_, PyAny>,
        target: &Bound<'_, PyAny>,
        resolution: Option<&Bound<'_, PyAny>>,
        origin: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyPlanOutcome> {
        let ends = Endpoints::Toward(point2(py, "start", start)?, point2(py, "target", target)?);
        self.run(py, risk, ends, resolution, origin)
    }

    /// Like `plan`, with the start and goal given as cells `(ix, iy)` (`risk[iy, ix]`).
    #[pyo3(signature = (risk, start_cell, goal_cell, *, resolution = None, origin = None))]
    fn plan_cells(
        &self,
        py: Python<'_>,
        risk: &Bound<'_, PyAny>,
        start_cell: &Bound<'_, PyAny>,
        goal_cell: &Bound<'_, PyAny>,
        resolution: Option<&Bound<'_, PyAny>>,
        origin: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyPlanOutcome> {
        let ends = Endpoints::Cells(cell2(py, "start", start_cell)?, cell2(py, "goal", goal_cell)?);
        self.run(py, risk, ends, resolution, origin)
    }

    /// λ, the length weight [1/m].
    /// The config in use.
    #[getter]
    fn config(&self) -> PyRiskAStarConfig {
        PyRiskAStarConfig::from_core(*self.inner.lock().config())
    }

    #[getter]
    fn lam(&self) -> f64 {
        self.inner.lock().config().lam
    }
    /// Cells with risk >= r_inst are untraversable.
    #[getter]
    fn r_inst(&self) -> f64 {
        self.inner.lock().config().r_inst
    }
    /// Largest accumulated risk of an accepted path.
    #[getter]
    fn r_total(&self) -> f64 {
        self.inner.lock().config().r_total
    }
    /// Path length from the start to the carrot [m].
    #[getter]
    fn carrot_m(&self) -> f64 {
        self.inner.lock().config().carrot_m
    }
    /// Risk of NaN (unknown) cells.
    #[getter]
    fn unknown_risk(&self) -> f64 {
        self.inner.lock().config().unknown_risk
    }
    /// Whether diagonal moves may pass an untraversable corner.
    #[getter]
    fn allow_corner_cutting(&self) -> bool {
        self.inner.lock().config().allow_corner_cutting
    }

    fn __repr__(&self) -> String {
        let this = self.inner.lock();
        let c = this.config();
        format!(
            "RiskAStar(lam={}, r_inst={}, r_total={}, carrot_m={}, unknown_risk={}, allow_corner_cutting={})",
            c.lam,
            c.r_inst,
            c.r_total,
            c.carrot_m,
            c.unknown_risk,
            if c.allow_corner_cutting { "True" } else { "False" }
        )
    }
}

/// The outcome of one `RiskAStar.plan`.
#[pyclass(name = "PlanOutcome", module = "subterra._core", frozen)]
pub struct PyPlanOutcome {
    inner: PlanOutcome,
}

#[pymethods]
impl PyPlanOutcome {
    /// "found", "start_blocked", "goal_blocked", "no_path" or "budget_exceeded".
    #[getter]
    fn status(&self) -> &'static str {
        self.inner.status.name()
    }
    /// True iff the status is "found".
    #[getter]
    fn found(&self) -> bool {
        self.inner.found().is_some()
    }
    /// Cell centres of the least-cost path, start first, float64 (N, 2) [m]; (0, 2) without one.
    /// Also given with "budget_exceeded" (the rejected path).
    #[getter]
    fn path_world<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let pts = self.inner.path.as_ref().map_or(&[][..], |p| &p.points_world[..]);
        let flat: Vec<f64> = pts.iter().flat_map(|p| [p.x, p.y]).collect();
        flat.into_pyarray(py).reshape([pts.len(), 2])
    }
    /// Cells `(ix, iy)` of the path, int64 (N, 2); index a risk array as `risk[iy, ix]`.
    #[getter]
    fn path_cells<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<i64>>> {
        let cells = self.inner.path.as_ref().map_or(&[][..], |p| &p.cells[..]);
        let flat: Vec<i64> = cells.iter().flat_map(|c| [c.ix as i64, c.iy as i64]).collect();
        flat.into_pyarray(py).reshape([cells.len(), 2])
    }
    /// `1 - exp(-S)` of the path, or None without a path.
    #[getter]
    fn accumulated_risk(&self) -> Option<f64> {
        self.inner.path.as_ref().map(|p| p.accumulated_risk)
    }
    /// `S = Σ d·(ρ(a) + ρ(b))/2`, the path's risk integral, or None.
    #[getter]
    fn risk_integral(&self) -> Option<f64> {
        self.inner.path.as_ref().map(|p| p.risk_integral)
    }
    /// Path length through the cell centres [m], or None.
    #[getter]
    fn length_m(&self) -> Option<f64> {
        self.inner.path.as_ref().map(|p| p.length_m)
    }
    /// Path cost `λ·length + S`, or None.
    #[getter]
    fn cost(&self) -> Option<f64> {
        self.inner.path.as_ref().map(|p| p.cost)
    }
    /// Cells expanded by the search (the goal included).
    #[getter]
    fn expanded(&self) -> usize {
        self.inner.expanded
    }
    /// The point `carrot_m` of path length from the start (x, y) [m]; None unless "found".
    #[getter]
    fn carrot(&self) -> Option<(f64, f64)> {
        self.inner.carrot_world.map(|p| (p.x, p.y))
    }
    /// The start cell (ix, iy).
    #[getter]
    fn start_cell(&self) -> (u32, u32) {
        (self.inner.start_cell.ix, self.inner.start_cell.iy)
    }
    /// The goal cell (ix, iy).
    #[getter]
    fn goal_cell(&self) -> (u32, u32) {
        (self.inner.goal_cell.ix, self.inner.goal_cell.iy)
    }
    /// Time of the search and the path tracing in the core [s]; not the conversions or the grid check.
    #[getter]
    fn time_s(&self) -> f64 {
        self.inner.time_s
    }

    fn __repr__(&self) -> String {
        let o = &self.inner;
        match &o.path {
            Some(p) => format!(
                "PlanOutcome(status={:?}, cells={}, length_m={:.3}, cost={:.4}, accumulated_risk={:.4}, expanded={})",
                o.status.name(),
                p.cells.len(),
                p.length_m,
                p.cost,
                p.accumulated_risk,
                o.expanded
            ),
            None => format!("PlanOutcome(status={:?}, expanded={})", o.status.name(), o.expanded),
        }
    }
}

/// Adds the A* classes to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyRiskAStar>()?;
    m.add_class::<PyPlanOutcome>()?;
    Ok(())
}
