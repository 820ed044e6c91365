//! Bindings of `subterra::plan::Navigator` (the wired ground-robot stack) and the recovery
//! machine's records. Conversions, error mapping and GIL release only.

use glam::DVec2;
use numpy::{IntoPyArray, PyArray2};
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use subterra::plan::{Navigator, NavigatorConfig, NavigatorOutput, Transition};
use subterra::Isometry3;

use crate::shared::Shared;
use crate::convert::{arg, isometry, small_vector};
use crate::errors::IntoPyResult;
use crate::config::{resolve, PyNavigatorConfig, PyRobotConfig};
use crate::terrain::{resolve_config, resolve_robot, with_points, PyRiskMap};

/// Two finite numbers `(x, y)`.
fn xy(py: Python<'_>, argument: &str, value: &Bound<'_, PyAny>) -> PyResult<DVec2> {
    let v = small_vector(py, argument, value, 2, "two numbers (x, y) [m]")?;
    Ok(DVec2::new(v[0], v[1]))
}

fn transition_dict<'py>(py: Python<'py>, t: &Transition) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("time_s", t.time_s)?;
    d.set_item("from", t.from.name())?;
    d.set_item("to", t.to.name())?;
    d.set_item("reason", &t.reason)?;
    d.set_item("r_inst", t.r_inst)?;
    d.set_item("r_total", t.r_total)?;
    Ok(d)
}

fn points_array<'py>(py: Python<'py>, points: &[DVec2]) -> Bound<'py, PyArray2<f64>> {
    let flat: Vec<f64> = points.iter().flat_map(|p| [p.x, p.y]).collect();
    numpy::ndarray::Array2::from_shape_vec((points.len(), 2), flat).expect("n x 2 values").into_pyarray(py)
}

/// What one `Navigator.step` decided.
#[pyclass(name = "NavigatorOutput", module = "subterra._core", frozen)]
pub struct PyNavigatorOutput {
    inner: NavigatorOutput,
}

#[pymethods]
impl PyNavigatorOutput {
    /// `(v, ω)`: forward speed [m/s] and yaw rate [rad/s] to command.
    #[getter]
    fn command(&self) -> (f64, f64) {
        (self.inner.speed_m_s, self.inner.yaw_rate_rad_s)
    }

    /// The behaviour that produced the command: `track`, `clear_map`, `rotate`,
    /// `raise_thresholds`, `back_out`, `goal_reached`, `home` or `failed`.
    #[getter]
    fn behaviour(&self) -> &'static str {
        self.inner.behaviour.name()
    }

    /// `goal`, or `home` after the goal was given up.
    #[getter]
    fn target(&self) -> &'static str {
        match self.inner.target {
            subterra::plan::Target::Goal => "goal",
            subterra::plan::Target::Home => "home",
        }
    }

    /// Status of the plan made this step (`found`, `no_path`, `budget_exceeded`, ...), or None.
    #[getter]
    fn plan_status(&self) -> Option<&'static str> {
        self.inner.plan.as_ref().map(|p| p.status.name())
    }

    /// The path being tracked, `(N, 2)` world [m] (empty without one).
    #[getter]
    fn path_world<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        points_array(py, &self.inner.path_world)
    }

    /// Status of the MPC solve this step (`solved`, `solved_inexact`, `infeasible_backup`,
    /// `solver_failed_backup`), or None when it did not run.
    #[getter]
    fn mpc_status(&self) -> Option<&'static str> {
        self.inner.mpc.as_ref().map(|m| m.status.name())
    }

    /// The MPC's predicted states `(N + 1, 4)` `[x, y, θ, v]`, or None.
    #[getter]
    fn predicted<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f64>>> {
        self.inner.mpc.as_ref().map(|m| {
            let flat: Vec<f64> = m.predicted.iter().flat_map(|s| s.to_array()).collect();
            numpy::ndarray::Array2::from_shape_vec((m.predicted.len(), 4), flat).expect("n x 4 values").into_pyarray(py)
        })
    }

    /// Risk under the robot [0-1].
    #[getter]
    fn local_risk(&self) -> f64 {
        self.inner.local_risk
    }

    /// `v_max·(1 - local_risk)` [m/s].
    #[getter]
    fn speed_limit_m_s(&self) -> f64 {
        self.inner.speed_limit_m_s
    }

    /// `(R_inst, R_total)` in force.
    #[getter]
    fn thresholds(&self) -> (f64, f64) {
        (self.inner.r_inst, self.inner.r_total)
    }

    /// The recovery machine's transitions during this step: dicts with `time_s`, `from`,
    /// `to`, `reason`, `r_inst`, `r_total`.
    #[getter]
    fn transitions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let items = self.inner.transitions.iter().map(|t| transition_dict(py, t)).collect::<PyResult<Vec<_>>>()?;
        PyList::new(py, items)
    }

    /// Wall time per stage [s]: `map_s`, `plan_s`, `track_s`, `total_s`.
    /// Why the command is not the behaviour's own (the motion it asked for would have swept
    /// the footprint over a lethal or unknown cell), or `None`.
    #[getter]
    fn safety(&self) -> Option<String> {
        self.inner.safety.clone()
    }

    #[getter]
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let t = self.inner.timings;
        let d = PyDict::new(py);
        d.set_item("map_s", t.map_s)?;
        d.set_item("plan_s", t.plan_s)?;
        d.set_item("track_s", t.track_s)?;
        d.set_item("total_s", t.total_s)?;
        Ok(d)
    }

    fn __repr__(&self) -> String {
        format!(
            "NavigatorOutput(command=({:.3}, {:.3}), behaviour={:?}, plan={:?}, local_risk={:.3})",
            self.inner.speed_m_s,
            self.inner.yaw_rate_rad_s,
            self.inner.behaviour.name(),
            self.inner.plan.as_ref().map(|p| p.status.name()),
            self.inner.local_risk
        )
    }
}

/// The ground robot's navigation stack (STEP, Fan et al. 2021): terrain mapper, risk-aware A*, MPC
/// tracker and recovery behaviours, one `step` per control tick.
#[pyclass(name = "Navigator", module = "subterra._core", frozen)]
pub struct PyNavigator {
    inner: Shared<Navigator>,
    last_stamp: Shared<Option<f64>>,
}

#[pymethods]
impl PyNavigator {
    /// `goal`, `home`: world (x, y) [m]; `home` (where the robot returns when it gives up
    /// the goal) defaults to its position at the first step. `robot`: None (Husky), a dict or a
    /// `RobotConfig` or a TOML path. `terrain`: None, a dict, a `TerrainConfig` or a TOML path.
    /// `config`: None (the defaults for the robot), a (partial) dict with sections `planner`,
    /// `tracker`, `recovery`, `navigator` laid over them, a `NavigatorConfig` or a TOML path.
    #[new]
    #[pyo3(signature = (goal, *, home = None, robot = None, terrain = None, config = None))]
    fn new(
        py: Python<'_>,
        goal: &Bound<'_, PyAny>,
        home: Option<&Bound<'_, PyAny>>,
        robot: Option<&Bound<'_, PyAny>>,
        terrain: Option<&Bound<'_, PyAny>>,
        config: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let goal = xy(py, "goal", goal)?;
        let home = match home {
            Some(h) if !h.is_none() => Some(xy(py, "home", h)?),
            _ => None,
        };
        let robot = resolve_robot(py, robot)?;
        let terrain = resolve_config(py, "terrain", terrain)?;
        let config = resolve::<PyNavigatorConfig>(py, "config", config, || Ok(NavigatorConfig::for_robot(&robot)))?;
        let inner = Navigator::new(robot, terrain, config, goal, home).py_err(py)?;
        Ok(Self { inner: Shared::new(inner), last_stamp: Shared::new(None) })
    }

    /// One control tick. `points`: a new scan `(N, 3)` in the sensor frame [m], or None.
    /// `stamp` [s] (default 0.1 s after the previous step), `world_from_body` (4x4 odometry
    /// pose, required), `body_from_sensor` (default identity), `confidence` in [0, 1],
    /// `speed`: measured forward speed [m/s]. Releases the GIL while it runs.
    #[pyo3(signature = (points, *, stamp = None, world_from_body, body_from_sensor = None, confidence = 1.0, speed = 0.0))]
    #[allow(clippy::too_many_arguments)]
    fn step(
        &self,
        py: Python<'_>,
        points: Option<&Bound<'_, PyAny>>,
        #[pyo3(from_py_with = arg::opt_stamp)] stamp: Option<f64>,
        world_from_body: &Bound<'_, PyAny>,
        body_from_sensor: Option<&Bound<'_, PyAny>>,
        #[pyo3(from_py_with = arg::confidence)] confidence: f64,
        #[pyo3(from_py_with = arg::speed)] speed: f64,
    ) -> PyResult<PyNavigatorOutput> {
        let world_from_body = isometry(py, "world_from_body", world_from_body)?;
        let body_from_sensor = match body_from_sensor {
            Some(m) if !m.is_none() => isometry(py, "body_from_sensor", m)?,
            _ => Isometry3::IDENTITY,
        };
        // The navigator's lock is held from the default stamp to its step (threads sharing it
        // never compute the same default).
        let mut this = self.inner.lock();
        let stamp_s = stamp.unwrap_or_else(|| self.last_stamp.lock().map_or(0.0, |t| t + 0.1));
        let nav = &mut *this;
        let mut run = |points: Option<&[f32]>| {
            py.detach(|| {
                nav.step(&subterra::plan::NavigatorInput {
                    stamp_s,
                    points_sensor: points,
                    world_from_body,
                    body_from_sensor,
                    confidence,
                    speed_m_s: speed,
                })
            })
        };
        let out = match points {
            Some(p) if !p.is_none() => with_points(py, "points", p, |flat| run(Some(flat)))?,
            _ => run(None),
        }
        .map_err(|e| e.renamed(&["stamp_s", "time_s"], "stamp"))
        .py_err(py)?;
        *self.last_stamp.lock() = Some(stamp_s);
        Ok(PyNavigatorOutput { inner: out })
    }

    /// The last coarse risk map (None before the first scan).
    #[getter]
    fn risk_map(&self, py: Python<'_>) -> PyResult<Option<Py<PyRiskMap>>> {
        let this = self.inner.lock();
        match this.risk_map() {
            Some(m) => {
                let (stats, timings) = this.last_terrain_stats();
                Ok(Some(Py::new(py, PyRiskMap::from_core(m.clone(), "coarse", stats, timings))?))
            }
            None => Ok(None),
        }
    }

    /// The planner's grid `(ny, nx)` float32 on `risk_map`'s geometry: the risk where
    /// observed, raised by the hazard memory, NaN where unobserved (None before the first scan).
    #[getter]
    fn plan_grid<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray2<f32>>>> {
        let this = self.inner.lock();
        let Some(map) = this.risk_map() else { return Ok(None) };
        let g = map.geometry();
        let grid = numpy::ndarray::Array2::from_shape_vec((g.ny, g.nx), this.plan_grid().to_vec())
            .map_err(|e| PyRuntimeError::new_err(format!("plan grid: {e}")))?;
        Ok(Some(grid.into_pyarray(py)))
    }

    /// Cells in the hazard memory (`navigator.hazard_memory`).
    /// Cells the robot's footprint has stood on (the driven memory).
    #[getter]
    fn driven_cells(&self) -> usize {
        self.inner.lock().driven_cells()
    }

    #[getter]
    fn remembered_hazards(&self) -> usize {
        self.inner.lock().remembered_hazards()
    }

    /// The robot.
    #[getter]
    fn robot(&self) -> PyRobotConfig {
        PyRobotConfig::from_core(*self.inner.lock().robot())
    }

    /// The configuration in use (sections `planner`, `tracker`, `recovery`, `navigator`).
    #[getter]
    fn config(&self) -> PyNavigatorConfig {
        PyNavigatorConfig::from_core(self.inner.lock().config().clone())
    }

    /// Every transition of the recovery machine so far (dicts, oldest first).
    #[getter]
    fn transitions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let items = self.inner.lock().recovery().transitions().iter().map(|t| transition_dict(py, t)).collect::<PyResult<Vec<_>>>()?;
        PyList::new(py, items)
    }

    /// The goal (x, y) [m].
    #[getter]
    fn goal(&self) -> (f64, f64) {
        let this = self.inner.lock();
        let goal = this.goal();
        (goal.x, goal.y)
    }

    /// Drives to a new `goal` (x, y) [m, world] from the next step, keeping the map, the
    /// remembered hazards and home; the plan and the recovery ladder start again (so
    /// `transitions` starts empty). A goal that is not 2 finite numbers is an `InputError`.
    fn set_goal(&self, py: Python<'_>, goal: &Bound<'_, PyAny>) -> PyResult<()> {
        let goal = xy(py, "goal", goal)?;
        self.inner.lock().set_goal(goal).py_err(py)
    }

    /// Home (x, y) [m].
    #[getter]
    fn home(&self) -> (f64, f64) {
        let h = self.inner.lock().recovery().home();
        (h.x, h.y)
    }

    fn __repr__(&self) -> String {
        let this = self.inner.lock();
        let g = this.goal();
        format!("Navigator(goal=({:.2}, {:.2}), behaviour={:?})", g.x, g.y, this.recovery().behaviour().name())
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyNavigator>()?;
    m.add_class::<PyNavigatorOutput>()?;
    Ok(())
}
