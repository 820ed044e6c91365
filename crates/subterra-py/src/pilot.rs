//! `subterra.Pilot`: the drone's loop of the core (`subterra::apf::Pilot`), one call per
//! control step.

use std::borrow::Cow;

use numpy::{IntoPyArray, PyArray2, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
use subterra::apf::{controller_named, Pilot, PilotCamera, PilotController, PilotOutput, QmdpConfig, CONTROLLER_NAMES, MAX_CAMERAS};
use subterra::depth::{DepthImage, TransitionModel};
use subterra::Isometry3;

use crate::convert::{arg, isometry, type_name, vec3, with_depth, DepthPixels};
use crate::errors::{input_error, IntoPyResult};
use crate::shared::Shared;
use crate::config::PyPerceptionConfig;
use crate::{array3, resolve_config, voxel_centres_array, PyCommand, PyEscapeOutput, PyPerceptionOutput, PyPinholeCamera};

/// What one `Pilot.step` gives.
#[pyclass(name = "PilotOutput", module = "subterra._core", frozen)]
struct PyPilotOutput {
    inner: PilotOutput,
}

#[pymethods]
impl PyPilotOutput {
    /// The velocity command.
    #[getter]
    fn command(&self) -> PyCommand {
        PyCommand { inner: self.inner.command }
    }
    /// Each camera's `PerceptionOutput`, in camera order.
    #[getter]
    fn perceptions(&self) -> Vec<PyPerceptionOutput> {
        self.inner
            .perceptions
            .iter()
            .zip(&self.inner.belief_repulsive_body)
            .map(|(o, f)| PyPerceptionOutput { inner: o.clone(), repulsive_body: *f })
            .collect()
    }
    /// The point the attraction pulled toward before the escape (goal or carrot), world [m].
    #[getter]
    fn target_world<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        array3(py, self.inner.target_world)
    }
    /// Distance still to go, straight or along the path [m].
    #[getter]
    fn remaining_m(&self) -> f64 {
        self.inner.remaining_m
    }
    /// The belief's push, body frame: the summed repulsion [N], or the QMDP velocity [m/s].
    #[getter]
    fn belief_push_body<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        array3(py, self.inner.belief_push_body)
    }
    /// The obstacle memories' repulsion, body frame [N] (zero without a memory).
    #[getter]
    fn memory_repulsive_body<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        array3(py, self.inner.memory_repulsive_body)
    }
    /// Cells the memories hold (0 without a memory).
    #[getter]
    fn memory_cells(&self) -> usize {
        self.inner.memory_cells
    }
    /// The escape's output, or None when the config leaves the escape off.
    #[getter]
    fn escape(&self) -> Option<PyEscapeOutput> {
        self.inner.escape.map(|inner| PyEscapeOutput { inner })
    }
    /// Whether the escape is following an obstacle's boundary.
    #[getter]
    fn escape_active(&self) -> bool {
        self.inner.escape.is_some_and(|e| e.mode != subterra::apf::EscapeMode::Goal)
    }
    /// The goal the command pulled toward, body frame [m].
    #[getter]
    fn goal_body<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        array3(py, self.inner.goal_body)
    }
    /// The repulsion the command used, body frame [N].
    #[getter]
    fn repulsive_body<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        array3(py, self.inner.repulsive_body)
    }
    /// Seconds: `perception_s` (the filters), `control_s` (forces, memory, escape,
    /// command), `total_s`.
    #[getter]
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let t = self.inner.timings;
        let d = PyDict::new(py);
        d.set_item("perception_s", t.perception_s)?;
        d.set_item("control_s", t.control_s)?;
        d.set_item("total_s", t.total_s)?;
        Ok(d)
    }
    fn __repr__(&self) -> String {
        let c = self.inner.command;
        format!(
            "PilotOutput(command=[{:.3}, {:.3}, {:.3}, {:.3}], remaining_m={:.3}, memory_cells={}, escape_active={})",
            c.v_x_m_s,
            c.v_y_m_s,
            c.v_z_m_s,
            c.yaw_rate_rad_s,
            self.inner.remaining_m,
            self.inner.memory_cells,
            if self.escape_active() { "True" } else { "False" }
        )
    }
}

/// The drone's perception and control in one object: each camera's APF-PF filter, the
/// obstacle memory and the escape when the preset turns them on, and the controller.
/// `step(frames, stamp=, world_from_body=)` per control step gives the command.
#[pyclass(name = "Pilot", module = "subterra._core", frozen)]
struct PyPilot {
    inner: Shared<Pilot>,
    /// `(width, height)` of each camera.
    sizes: Vec<(u32, u32)>,
    cameras: Vec<PilotCamera>,
    controller: String,
}

fn camera_of(py: Python<'_>, n: usize, item: &Bound<'_, PyAny>) -> PyResult<PilotCamera> {
    if let Ok(c) = item.cast::<PyPinholeCamera>() {
        return Ok(PilotCamera { camera: c.get().inner, body_from_camera: Isometry3::body_from_forward_optical() });
    }
    if let Ok(pair) = item.cast::<PyTuple>() {
        if pair.len() == 2 {
            if let Ok(c) = pair.get_item(0)?.cast::<PyPinholeCamera>() {
                let mount = isometry(py, &format!("cameras[{n}][1]"), &pair.get_item(1)?)?;
                return Ok(PilotCamera { camera: c.get().inner, body_from_camera: mount });
            }
        }
    }
    Err(input_error(
        py,
        format!("argument `cameras[{n}]` must be a PinholeCamera or a (PinholeCamera, body_from_camera 4x4) pair, got {}", type_name(item)),
    ))
}

fn cameras_of(py: Python<'_>, cameras: &Bound<'_, PyAny>) -> PyResult<Vec<PilotCamera>> {
    if cameras.cast::<PyPinholeCamera>().is_ok() || cameras.cast::<PyTuple>().is_ok_and(|t| t.len() == 2 && t.get_item(0).is_ok_and(|c| c.cast::<PyPinholeCamera>().is_ok())) {
        return Ok(vec![camera_of(py, 0, cameras)?]);
    }
    let Ok(list) = cameras.cast::<PyList>() else {
        return Err(input_error(py, format!("argument `cameras` must be a PinholeCamera, a (camera, body_from_camera) pair or a list of them, got {}", type_name(cameras))));
    };
    if list.is_empty() || list.len() > MAX_CAMERAS {
        return Err(input_error(py, format!("argument `cameras` must hold 1 to {MAX_CAMERAS} cameras, got {}", list.len())));
    }
    list.iter().enumerate().map(|(n, item)| camera_of(py, n, &item)).collect()
}

/// An owned copy of one frame's pixels (several cameras: each frame is borrowed in turn).
fn owned(pixels: &DepthPixels<'_>) -> DepthPixels<'static> {
    match pixels {
        DepthPixels::U16(p, s) => DepthPixels::U16(Cow::Owned(p.to_vec()), *s),
        DepthPixels::F32(p) => DepthPixels::F32(Cow::Owned(p.to_vec())),
    }
}

#[pymethods]
impl PyPilot {
    /// `cameras`: a `PinholeCamera` (looking forward from the body origin), a
    /// `(camera, body_from_camera)` pair, or a list of them. `preset` / `config`: the
    /// perception settings (`memory.enabled` and `escape.enabled` switch those parts on).
    /// `controller`: `"apf-pf"`, `"apf-pf-histogram"`, `"apf-pf-qmdp"` or `"raw-apf"`.
    /// Camera `n`'s filter is seeded with `seed + n`. `qmdp`: a dict over
    /// `Qmdp.default_config()` for `apf-pf-qmdp`.
    #[new]
    #[pyo3(
        signature = (cameras, preset = "flight-escape".to_owned(), *, config = None, controller = "apf-pf".to_owned(), seed = 0, qmdp = None),
        text_signature = "(cameras, preset='flight-escape', *, config=None, controller='apf-pf', seed=0, qmdp=None)"
    )]
    fn new(
        py: Python<'_>,
        cameras: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = arg::s_preset)] preset: String,
        config: Option<&Bound<'_, PyAny>>,
        #[pyo3(from_py_with = arg::s_controller)] controller: String,
        #[pyo3(from_py_with = arg::seed_u64)] seed: u64,
        qmdp: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let cameras = cameras_of(py, cameras)?;
        let mut config = resolve_config(py, &preset, config)?;
        let (mode, kind) = controller_named(&controller).py_err(py)?;
        config.filter.mode = mode;
        let qmdp = match (kind, qmdp) {
            (PilotController::Qmdp, q) => crate::qmdp::resolve_config(py, q)?,
            (PilotController::Apf, None) => QmdpConfig::default(),
            (PilotController::Apf, Some(_)) => {
                return Err(input_error(py, format!("argument `qmdp` applies to controller \"apf-pf-qmdp\" only, not {controller:?}")));
            }
        };
        let list = cameras.clone();
        let pilot = py.detach(move || Pilot::new(config, &list, kind, qmdp, seed)).py_err(py)?;
        let sizes = cameras.iter().map(|c| (c.camera.width, c.camera.height)).collect();
        Ok(Self { inner: Shared::new(pilot), sizes, cameras, controller })
    }

    /// The controllers a pilot runs.
    #[staticmethod]
    fn controllers() -> Vec<&'static str> {
        CONTROLLER_NAMES.to_vec()
    }

    /// Flies to `goal_world` (3 numbers [m], world frame); drops a path.
    fn set_goal(&self, py: Python<'_>, goal_world: &Bound<'_, PyAny>) -> PyResult<()> {
        let goal = vec3(py, "goal_world", goal_world)?;
        self.inner.lock().set_goal(goal).py_err(py)
    }

    /// Follows `path` (at least two 3-vectors [m, world], the last the goal) with a carrot
    /// `lookahead_m` ahead.
    #[pyo3(signature = (path, *, lookahead_m = subterra::apf::DEFAULT_LOOKAHEAD_M))]
    fn set_path(&self, py: Python<'_>, path: &Bound<'_, PyAny>, #[pyo3(from_py_with = arg::lookahead_m)] lookahead_m: f64) -> PyResult<()> {
        let points = crate::convert::path3(py, "path", path)?;
        self.inner.lock().set_path(&points, lookahead_m).py_err(py)
    }

    /// One control step: `frames` is one `(H, W)` depth image (`uint16` with `scale`
    /// metres per unit, default 0.001, or `float32` metres) or a list with one per camera,
    /// taken at `stamp` [s] with the odometry pose `world_from_body` (4x4) and its
    /// `confidence` in [0, 1] (an `OdometryMux`'s: the obstacle memories' timeouts are
    /// scaled by it, at 0 they keep only this frame). Releases the GIL while it runs.
    #[pyo3(signature = (frames, *, stamp, world_from_body, scale = None, confidence = 1.0))]
    fn step(
        &self,
        py: Python<'_>,
        frames: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = arg::stamp)] stamp: f64,
        world_from_body: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = arg::opt_scale)] scale: Option<f64>,
        #[pyo3(from_py_with = arg::confidence)] confidence: f64,
    ) -> PyResult<PyPilotOutput> {
        let pose = isometry(py, "world_from_body", world_from_body)?;
        let list: Vec<Bound<'_, PyAny>> = match frames.cast::<PyList>() {
            Ok(l) => l.iter().collect(),
            Err(_) => vec![frames.clone()],
        };
        if list.len() != self.sizes.len() {
            return Err(input_error(py, format!("argument `frames` must hold one depth image per camera ({}), got {}", self.sizes.len(), list.len())));
        }
        let mut this = self.inner.lock();
        let pilot = &mut *this;
        pilot.set_odometry_confidence(confidence).py_err(py)?;
        let result = if list.len() == 1 {
            with_depth(py, &list[0], scale, self.sizes[0], |pixels, _, _| py.detach(|| pilot.step(&[pixels.image()], stamp, &pose)))?
        } else {
            let mut copies = Vec::with_capacity(list.len());
            for (frame, &size) in list.iter().zip(&self.sizes) {
                copies.push(with_depth(py, frame, scale, size, |pixels, _, _| owned(pixels))?);
            }
            py.detach(|| {
                let images: Vec<DepthImage<'_>> = copies.iter().map(DepthPixels::image).collect();
                pilot.step(&images, stamp, &pose)
            })
        };
        Ok(PyPilotOutput { inner: result.py_err(py)? })
    }

    /// Forgets the obstacle memories and the escape's progress (odometry that jumped, a
    /// new flight); the filters keep their belief.
    fn reset(&self) {
        self.inner.lock().reset();
    }

    /// The perception settings in force (with the controller's filter mode).
    #[getter]
    fn config(&self) -> PyPerceptionConfig {
        PyPerceptionConfig::from_core(*self.inner.lock().config())
    }

    /// The controller's name.
    #[getter]
    fn controller(&self) -> String {
        self.controller.clone()
    }

    /// How many cameras.
    #[getter]
    fn camera_count(&self) -> usize {
        self.cameras.len()
    }

    /// Camera `n`'s intrinsics.
    #[pyo3(signature = (n = 0))]
    fn camera(&self, py: Python<'_>, #[pyo3(from_py_with = arg::n_usize)] n: usize) -> PyResult<PyPinholeCamera> {
        self.cameras.get(n).map(|c| PyPinholeCamera { inner: c.camera }).ok_or_else(|| input_error(py, format!("argument `n` must be below {}, got {n}", self.cameras.len())))
    }

    /// Whether the settings run an obstacle memory.
    #[getter]
    fn has_memory(&self) -> bool {
        self.inner.lock().has_memory()
    }

    /// The free state's id (the same for every camera of one config: the last state).
    #[pyo3(signature = (n = 0))]
    fn free_state(&self, py: Python<'_>, #[pyo3(from_py_with = arg::n_usize)] n: usize) -> PyResult<u32> {
        let this = self.inner.lock();
        let p = self.perception(py, &this, n)?;
        Ok(p.grid().free_state().0)
    }

    /// Camera `n`'s perception: `grid_shape` `(N_w, N_h, N_d)`, `state_count`,
    /// `free_state`, `frames`, `transition_build_s`, `transition_memory_bytes`.
    #[pyo3(signature = (n = 0))]
    fn perception_info<'py>(&self, py: Python<'py>, #[pyo3(from_py_with = arg::n_usize)] n: usize) -> PyResult<Bound<'py, PyDict>> {
        let this = self.inner.lock();
        let p = self.perception(py, &this, n)?;
        let d = PyDict::new(py);
        d.set_item("grid_shape", p.grid().shape())?;
        d.set_item("state_count", p.grid().state_count())?;
        d.set_item("free_state", p.grid().free_state().0)?;
        d.set_item("frames", p.frames())?;
        d.set_item("transition_build_s", p.transition_build_s())?;
        d.set_item("transition_memory_bytes", p.transition().map_or(0, TransitionModel::memory_bytes))?;
        Ok(d)
    }

    /// Centres of camera `n`'s voxels, shape `(S-1, 3)` [m], in the `frame` "camera" or "body".
    #[pyo3(signature = (frame = "camera".to_owned(), n = 0), text_signature = "($self, frame='camera', n=0)")]
    fn voxel_centres<'py>(&self, py: Python<'py>, #[pyo3(from_py_with = arg::s_frame)] frame: String, #[pyo3(from_py_with = arg::n_usize)] n: usize) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let this = self.inner.lock();
        let p = self.perception(py, &this, n)?;
        voxel_centres_array(py, p, &frame)
    }

    /// The remembered obstacle points, shape `(N, 3)` [m, world], camera by camera.
    fn memory_points_world<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let points = self.inner.lock().memory_points_world();
        let flat: Vec<f64> = points.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
        flat.into_pyarray(py).reshape([points.len(), 3])
    }

    /// The path's length [m], or None for a point goal (or none yet).
    #[getter]
    fn path_length_m(&self) -> Option<f64> {
        self.inner.lock().path_length_m()
    }

    /// Steps taken.
    #[getter]
    fn steps(&self) -> u64 {
        self.inner.lock().steps()
    }

    fn __repr__(&self) -> String {
        format!("Pilot(cameras={}, controller={:?}, steps={})", self.cameras.len(), self.controller, self.inner.lock().steps())
    }
}

impl PyPilot {
    /// Camera `n`'s perception, or an error naming `n`.
    fn perception<'a>(&self, py: Python<'_>, pilot: &'a Pilot, n: usize) -> PyResult<&'a subterra::depth::DepthPerception> {
        pilot.perceptions().nth(n).ok_or_else(|| input_error(py, format!("argument `n` must be below {}, got {n}", self.cameras.len())))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyPilot>()?;
    m.add_class::<PyPilotOutput>()?;
    Ok(())
}
