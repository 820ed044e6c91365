//! `subterra._core`: the Python face of the `subterra` crate.
//!
//! Conversions, error mapping and GIL release only; every algorithm lives in the core crate.

mod codec;
mod config;
mod convert;
mod errors;
mod hero;
mod pilot;
mod plan_astar;
mod plan_nav;
mod plan_mpc;
mod qmdp;
mod shared;
mod sim;
mod terrain;

use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use subterra::config::{FilterMode, PerceptionConfig};
use subterra::depth::{DepthPerception, MostProbableVoxel, PerceptionOutput, StateId, TransitionModel, VoxelIndex};
use subterra::apf::{BeliefForces, CarrotOutput, Escape, EscapeMode, EscapeOutput, MemoryOutput, ObstacleMemory, PathFollower};
use subterra::{ApfController, Command, Isometry3, PinholeCamera};

use crate::config::PyPerceptionConfig;
use crate::shared::Shared;
use crate::convert::{arg, integer, isometry, real, vec3, with_depth};
use crate::errors::{config_error, input_error, IntoPyResult};

fn array3<'py>(py: Python<'py>, v: glam::DVec3) -> Bound<'py, PyArray1<f64>> {
    vec![v.x, v.y, v.z].into_pyarray(py)
}

/// Pinhole intrinsics of a depth camera (optical frame: x right, y down, z forward).
#[pyclass(name = "PinholeCamera", module = "subterra._core", frozen, eq)]
#[derive(Clone, PartialEq)]
pub struct PyPinholeCamera {
    /// The core camera.
    pub inner: PinholeCamera,
}

#[pymethods]
impl PyPinholeCamera {
    #[new]
    #[pyo3(signature = (fx, fy, cx, cy, width, height))]
    fn new(
        py: Python<'_>,
        fx: &Bound<'_, PyAny>,
        fy: &Bound<'_, PyAny>,
        cx: &Bound<'_, PyAny>,
        cy: &Bound<'_, PyAny>,
        width: &Bound<'_, PyAny>,
        height: &Bound<'_, PyAny>,
    ) -> PyResult<Self> {
        // A whole number of any size is an image side to validate (a `camera.*` ConfigError
        // when out of range); anything else is an InputError naming the argument.
        let side = |name: &str, v: &Bound<'_, PyAny>| {
            let n = integer(py, name, v, i128::MIN, i128::MAX)?;
            u32::try_from(n).map_err(|_| config_error(py, format!("config field `camera.{name}` is invalid: must be in 1..=16384 px (got {n})")))
        };
        let inner =
            PinholeCamera::new(real(py, "fx", fx)?, real(py, "fy", fy)?, real(py, "cx", cx)?, real(py, "cy", cy)?, side("width", width)?, side("height", height)?)
                .py_err(py)?;
        Ok(Self { inner })
    }

    /// The simulated RealSense D435 depth stream: 640x480, fx = fy = 385 px.
    #[staticmethod]
    fn d435() -> Self {
        Self { inner: PinholeCamera::d435() }
    }

    #[getter]
    fn fx(&self) -> f64 {
        self.inner.fx
    }
    #[getter]
    fn fy(&self) -> f64 {
        self.inner.fy
    }
    #[getter]
    fn cx(&self) -> f64 {
        self.inner.cx
    }
    #[getter]
    fn cy(&self) -> f64 {
        self.inner.cy
    }
    #[getter]
    fn width(&self) -> u32 {
        self.inner.width
    }
    #[getter]
    fn height(&self) -> u32 {
        self.inner.height
    }

    fn __repr__(&self) -> String {
        let c = &self.inner;
        format!("PinholeCamera(fx={}, fy={}, cx={}, cy={}, width={}, height={})", c.fx, c.fy, c.cx, c.cy, c.width, c.height)
    }
}

/// The most probable voxel of a belief.
#[pyclass(name = "MostProbableVoxel", module = "subterra._core", frozen)]
struct PyMostProbableVoxel {
    inner: MostProbableVoxel,
}

#[pymethods]
impl PyMostProbableVoxel {
    /// `(i, j, k)`: column block, row block, depth bin.
    #[getter]
    fn voxel(&self) -> (u32, u32, u32) {
        let v = self.inner.voxel;
        (v.i, v.j, v.k)
    }
    /// Flat state id.
    #[getter]
    fn state(&self) -> u32 {
        self.inner.state.0
    }
    /// Belief of this voxel.
    #[getter]
    fn probability(&self) -> f64 {
        self.inner.probability
    }
    /// Depth of the voxel's centre along the optical axis [m].
    #[getter]
    fn depth_m(&self) -> f64 {
        self.inner.centre_camera.z
    }
    /// Centre in the camera optical frame [m].
    #[getter]
    fn centre_camera<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array3(py, self.inner.centre_camera)
    }
    /// Centre in the body frame [m].
    #[getter]
    fn centre_body<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array3(py, self.inner.centre_body)
    }
    fn __repr__(&self) -> String {
        let v = self.inner.voxel;
        format!("MostProbableVoxel(voxel=({}, {}, {}), probability={:.4}, depth_m={:.3})", v.i, v.j, v.k, self.inner.probability, self.inner.centre_camera.z)
    }
}

/// What one depth frame gives: belief, P(free), most probable voxel, forces, timings.
#[pyclass(name = "PerceptionOutput", module = "subterra._core", frozen)]
struct PyPerceptionOutput {
    inner: PerceptionOutput,
    /// The belief's repulsion, `Σ_s b(s)·F_rep(s)` (`apf::forces`), body frame [N].
    repulsive_body: glam::DVec3,
}

#[pymethods]
impl PyPerceptionOutput {
    /// State ids with belief (ascending; the free state is the last id).
    #[getter]
    fn belief_states<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u32>> {
        self.inner.belief_states.iter().map(|s| s.0).collect::<Vec<_>>().into_pyarray(py)
    }
    /// Their probabilities.
    #[getter]
    fn belief_probabilities<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.belief_probabilities.clone().into_pyarray(py)
    }
    /// Belief that no obstacle is inside the sensing horizon.
    #[getter]
    fn p_free(&self) -> f64 {
        self.inner.p_free
    }
    /// The most probable voxel, or None.
    #[getter]
    fn most_probable(&self) -> Option<PyMostProbableVoxel> {
        self.inner.most_probable.map(|inner| PyMostProbableVoxel { inner })
    }
    /// Smallest valid raw depth of the frame [m], or None.
    #[getter]
    fn closest_depth_m(&self) -> Option<f64> {
        self.inner.closest_depth_m
    }
    /// Pixels with a valid depth.
    #[getter]
    fn valid_pixels(&self) -> u64 {
        self.inner.valid_pixels
    }
    /// Pixels with a valid depth inside the horizon.
    #[getter]
    fn in_range_pixels(&self) -> u64 {
        self.inner.in_range_pixels
    }
    /// Largest per-voxel count.
    #[getter]
    fn max_count(&self) -> u32 {
        self.inner.max_count
    }
    /// Belief-weighted repulsive force in the body frame [N].
    #[getter]
    fn repulsive_body<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array3(py, self.repulsive_body)
    }
    /// Seconds per stage: count, predict, update, belief, total.
    #[getter]
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let t = self.inner.timings;
        let d = PyDict::new(py);
        d.set_item("count_s", t.count_s)?;
        d.set_item("predict_s", t.predict_s)?;
        d.set_item("update_s", t.update_s)?;
        d.set_item("belief_s", t.belief_s)?;
        d.set_item("total_s", t.total_s)?;
        Ok(d)
    }
    fn __repr__(&self) -> String {
        let o = &self.inner;
        let map = o.most_probable.map_or("None".to_owned(), |m| format!("{:.3} m (p={:.3})", m.centre_camera.z, m.probability));
        let closest = o.closest_depth_m.map_or("None".to_owned(), |d| format!("{d:.3}"));
        format!("PerceptionOutput(p_free={:.4}, most_probable={map}, closest_depth_m={closest}, in_range_pixels={})", o.p_free, o.in_range_pixels)
    }
}

/// The perception config of argument `config` (any of the four forms): a dict is laid over
/// the preset `preset`, `None` is the preset.
fn resolve_config(py: Python<'_>, preset: &str, config: Option<&Bound<'_, PyAny>>) -> PyResult<PerceptionConfig> {
    config::resolve::<PyPerceptionConfig>(py, "config", config, || PerceptionConfig::preset(preset).py_err(py))
}

/// APF-PF perception of one depth camera: `update(depth)` per frame.
#[pyclass(name = "DepthPerception", module = "subterra._core", frozen)]
struct PyDepthPerception {
    inner: Shared<DepthPerception>,
    camera: PinholeCamera,
    /// Its belief's forces (fixed at construction).
    forces: BeliefForces,
}

#[pymethods]
impl PyDepthPerception {
    #[new]
    #[pyo3(
        signature = (camera, preset = "flight".to_owned(), *, config = None, body_from_camera = None, seed = None, mode = None),
        text_signature = "(camera, preset='flight', *, config=None, body_from_camera=None, seed=None, mode=None)"
    )]
    fn new(
        py: Python<'_>,
        #[pyo3(from_py_with = arg::camera)] camera: Bound<'_, PyPinholeCamera>,
        #[pyo3(from_py_with = arg::s_preset)] preset: String,
        config: Option<&Bound<'_, PyAny>>,
        body_from_camera: Option<&Bound<'_, PyAny>>,
        seed: Option<&Bound<'_, PyAny>>,
        #[pyo3(from_py_with = arg::opt_mode)] mode: Option<String>,
    ) -> PyResult<Self> {
        let mut config = resolve_config(py, &preset, config)?;
        if let Some(mode) = mode {
            config.filter.mode = match mode.as_str() {
                "particle" => FilterMode::Particle,
                "histogram" => FilterMode::Histogram,
                "raw" => FilterMode::Raw,
                _ => return Err(config_error(py, format!("argument `mode` must be \"particle\", \"histogram\" or \"raw\", got {mode:?}"))),
            };
        }
        let body_from_camera = match body_from_camera {
            Some(m) => isometry(py, "body_from_camera", m)?,
            None => Isometry3::body_from_forward_optical(),
        };
        let seed: u64 = match seed {
            None => 0,
            Some(s) => s.extract().map_err(|_| {
                input_error(py, format!("argument `seed` must be an integer in 0..2**64, got {}", s.repr().map(|r| r.to_string()).unwrap_or_default()))
            })?,
        };
        let cam = camera.get().inner;
        let inner = py.detach(move || DepthPerception::new(cam, body_from_camera, config, seed)).py_err(py)?;
        let forces = BeliefForces::new(&inner);
        Ok(Self { inner: Shared::new(inner), camera: cam, forces })
    }

    /// Processes one `(H, W)` depth frame (`uint16` with `scale` metres per unit, default
    /// 0.001, or `float32` metres). Releases the GIL while it runs.
    #[pyo3(signature = (depth, scale = None))]
    fn update(&self, py: Python<'_>, depth: &Bound<'_, PyAny>, #[pyo3(from_py_with = arg::opt_scale)] scale: Option<f64>) -> PyResult<PyPerceptionOutput> {
        let expected = (self.camera.width, self.camera.height);
        let mut this = self.inner.lock();
        let inner = &mut *this;
        let result = with_depth(py, depth, scale, expected, |pixels, w, h| py.detach(|| inner.update(pixels.image(), w, h)))?;
        let output = result.py_err(py)?;
        Ok(PyPerceptionOutput { inner: output, repulsive_body: self.forces.repulsive(inner.belief()) })
    }

    /// The camera.
    #[getter]
    fn camera(&self) -> PyPinholeCamera {
        PyPinholeCamera { inner: self.camera }
    }
    /// The config.
    #[getter]
    fn config(&self) -> PyPerceptionConfig {
        PyPerceptionConfig::from_core(*self.inner.lock().config())
    }
    /// `body_from_camera` as a 4x4 matrix.
    #[getter]
    fn body_from_camera<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let rows: Vec<Vec<f64>> = self.inner.lock().body_from_camera().to_matrix_rows().iter().map(|r| r.to_vec()).collect();
        PyArray2::from_vec2(py, &rows).map_err(|e| input_error(py, e.to_string()))
    }
    /// `(N_w, N_h, N_d)`: column blocks, row blocks, depth bins.
    #[getter]
    fn grid_shape(&self) -> (usize, usize, usize) {
        self.inner.lock().grid().shape()
    }
    /// Number of states (voxels + free).
    #[getter]
    fn state_count(&self) -> usize {
        self.inner.lock().grid().state_count()
    }
    /// The free state's id (the last).
    #[getter]
    fn free_state(&self) -> u32 {
        self.inner.lock().grid().free_state().0
    }
    /// Frames processed.
    #[getter]
    fn frames(&self) -> u64 {
        self.inner.lock().frames()
    }
    /// Seconds spent building the transition model.
    #[getter]
    fn transition_build_s(&self) -> f64 {
        self.inner.lock().transition_build_s()
    }
    /// Bytes held by the transition model.
    #[getter]
    fn transition_memory_bytes(&self) -> usize {
        self.inner.lock().transition().map_or(0, TransitionModel::memory_bytes)
    }
    /// The dense belief over all states, shape `(S,)`.
    fn belief<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.lock().belief().to_vec().into_pyarray(py)
    }
    /// Per-voxel counts of the last frame, shape `(N_h, N_w, N_d)`, or None before the first.
    fn counts<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray3<u32>>>> {
        let this = self.inner.lock();
        let (n_w, n_h, n_d) = this.grid().shape();
        let Some(c) = this.last_counts() else { return Ok(None) };
        Ok(Some(c.counts.clone().into_pyarray(py).reshape([n_h, n_w, n_d])?))
    }
    /// Centres of all voxels, shape `(S-1, 3)` [m], in the `frame` "camera" or "body".
    #[pyo3(signature = (frame = "camera".to_owned()), text_signature = "($self, frame='camera')")]
    fn voxel_centres<'py>(&self, py: Python<'py>, #[pyo3(from_py_with = arg::s_frame)] frame: String) -> PyResult<Bound<'py, PyArray2<f64>>> {
        voxel_centres_array(py, &self.inner.lock(), &frame)
    }
    /// Per-state repulsive force in the body frame, shape `(S, 3)` [N].
    fn forces_body<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let f: Vec<f64> = self.forces.forces_body().iter().flat_map(|v| [v.x, v.y, v.z]).collect();
        let n = f.len() / 3;
        f.into_pyarray(py).reshape([n, 3])
    }
    /// The transition row `T(state -> ·)`, shape `(S,)`.
    fn transition_row<'py>(&self, py: Python<'py>, #[pyo3(from_py_with = arg::state_i64)] state: i64) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let s = self.check_state(py, state)?;
        let this = self.inner.lock();
        let t = this.transition().ok_or_else(|| input_error(py, "argument `state`: filter mode `raw` has no transition model"))?;
        Ok(t.row(StateId(s)).into_pyarray(py))
    }
    /// Flat id of voxel `(i, j, k)`.
    fn state_of(&self, py: Python<'_>, #[pyo3(from_py_with = arg::i_i64)] i: i64, #[pyo3(from_py_with = arg::j_i64)] j: i64, #[pyo3(from_py_with = arg::k_i64)] k: i64) -> PyResult<u32> {
        let this = self.inner.lock();
        let (n_w, n_h, n_d) = this.grid().shape();
        let inside = |x: i64, n: usize| x >= 0 && (x as usize) < n;
        if !(inside(i, n_w) && inside(j, n_h) && inside(k, n_d)) {
            return Err(input_error(py, format!("voxel ({i}, {j}, {k}) is outside the grid of shape (N_w, N_h, N_d) = ({n_w}, {n_h}, {n_d})")));
        }
        Ok(this.grid().state_of(VoxelIndex { i: i as u32, j: j as u32, k: k as u32 }).0)
    }
    /// `(i, j, k)` of a state, or None for the free state.
    fn voxel_of(&self, py: Python<'_>, #[pyo3(from_py_with = arg::state_i64)] state: i64) -> PyResult<Option<(u32, u32, u32)>> {
        let s = self.check_state(py, state)?;
        Ok(self.inner.lock().grid().voxel_of(StateId(s)).map(|v| (v.i, v.j, v.k)))
    }
    fn __repr__(&self) -> String {
        let this = self.inner.lock();
        let (w, h, d) = this.grid().shape();
        format!("DepthPerception(grid=({w}, {h}, {d}), states={}, frames={})", w * h * d + 1, this.frames())
    }
}

/// Centres of `perception`'s voxels, shape `(S-1, 3)` [m], in the `frame` "camera" or "body".
fn voxel_centres_array<'py>(py: Python<'py>, perception: &DepthPerception, frame: &str) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let body = match frame {
        "camera" => false,
        "body" => true,
        _ => return Err(input_error(py, format!("argument `frame` must be \"camera\" or \"body\", got {frame:?}"))),
    };
    let g = perception.grid();
    let mut flat = Vec::with_capacity(g.voxel_count() * 3);
    for s in 0..g.voxel_count() as u32 {
        let Some(v) = g.voxel_of(StateId(s)) else { continue };
        let mut p = g.voxel_centre_camera(v);
        if body {
            p = perception.body_from_camera().transform_point(p);
        }
        flat.extend([p.x, p.y, p.z]);
    }
    flat.into_pyarray(py).reshape([g.voxel_count(), 3])
}

impl PyDepthPerception {
    fn check_state(&self, py: Python<'_>, state: i64) -> PyResult<u32> {
        let n = self.inner.lock().grid().state_count() as i64;
        if !(0..n).contains(&state) {
            return Err(input_error(py, format!("argument `state` must be in 0..{n}, got {state}")));
        }
        Ok(state as u32)
    }
}

/// What one `ObstacleMemory.update` gives.
#[pyclass(name = "MemoryOutput", module = "subterra._core", frozen)]
struct PyMemoryOutput {
    inner: MemoryOutput,
}

#[pymethods]
impl PyMemoryOutput {
    /// The memory's repulsive force in the body frame [N].
    #[getter]
    fn repulsive_body<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array3(py, self.inner.repulsive_body)
    }
    /// Cells remembered after the update.
    #[getter]
    fn cells(&self) -> usize {
        self.inner.cells
    }
    /// Distance from the body origin to the nearest remembered point [m], or None.
    #[getter]
    fn nearest_m(&self) -> Option<f64> {
        self.inner.nearest_m
    }
    fn __repr__(&self) -> String {
        let o = &self.inner;
        let f = o.repulsive_body;
        let nearest = o.nearest_m.map_or("None".to_owned(), |d| format!("{d:.3}"));
        format!("MemoryOutput(cells={}, nearest_m={nearest}, repulsive_body=[{:.4}, {:.4}, {:.4}])", o.cells, f.x, f.y, f.z)
    }
}

/// Where a camera's belief put obstacles, kept in the odometry frame so that they still
/// repel out of view: `update(output, stamp=..., world_from_body=...)` per frame.
#[pyclass(name = "ObstacleMemory", module = "subterra._core", frozen)]
struct PyObstacleMemory {
    inner: Shared<ObstacleMemory>,
}

#[pymethods]
impl PyObstacleMemory {
    /// A memory for `perception`'s camera, grid and mounting, with its config's `memory` settings.
    #[new]
    fn new(py: Python<'_>, #[pyo3(from_py_with = arg::perception)] perception: Bound<'_, PyDepthPerception>) -> PyResult<Self> {
        Ok(Self { inner: Shared::new(ObstacleMemory::new(&perception.get().inner.lock()).py_err(py)?) })
    }

    /// Records `output` (a `PerceptionOutput` of that perception) taken at `stamp` [s] with
    /// the odometry pose `world_from_body` (4x4), forgets, and returns the memory's force.
    /// `perception`, the one that gave `output`, lends its frame's voxel counts to the
    /// near-field guard (`memory.guard_sigmas`); without it there is no guard.
    #[pyo3(signature = (output, *, stamp, world_from_body, perception = None))]
    fn update(
        &self,
        py: Python<'_>,
        #[pyo3(from_py_with = arg::output)] output: Bound<'_, PyPerceptionOutput>,
        #[pyo3(from_py_with = arg::stamp)] stamp: f64,
        world_from_body: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = arg::opt_perception)] perception: Option<Bound<'_, PyDepthPerception>>,
    ) -> PyResult<PyMemoryOutput> {
        let (output, perception) = (output.get(), perception.as_ref().map(Bound::get));
        let pose = isometry(py, "world_from_body", world_from_body)?;
        let counts = match perception {
            Some(p) => {
                let p = p.inner.lock();
                if p.fingerprint() != output.inner.fingerprint {
                    return Err(input_error(
                        py,
                        "argument `perception` is not the perception that gave `output` (its camera, mounting or grid differ): pass the one whose update() returned it",
                    ));
                }
                p.last_counts().cloned()
            }
            None => None,
        };
        let mut this = self.inner.lock();
        let (inner, out) = (&mut *this, &output.inner);
        Ok(PyMemoryOutput { inner: py.detach(|| inner.update(out, counts.as_ref(), stamp, &pose)).py_err(py)? })
    }

    /// Forgets everything.
    fn reset(&self) {
        self.inner.lock().reset();
    }

    /// The remembered points, shape `(N, 3)` [m, world].
    fn points_world<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let this = self.inner.lock();
        let flat: Vec<f64> = this.obstacles().flat_map(|c| [c.point_world.x, c.point_world.y, c.point_world.z]).collect();
        flat.into_pyarray(py).reshape([this.len(), 3])
    }

    /// Their weights (the belief that recorded them), shape `(N,)`.
    fn weights<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.inner.lock().obstacles().map(|c| c.weight).collect::<Vec<_>>().into_pyarray(py)
    }

    fn __len__(&self) -> usize {
        self.inner.lock().len()
    }

    fn __repr__(&self) -> String {
        let this = self.inner.lock();
        let c = this.config();
        format!("ObstacleMemory(cells={}, rho_0_m={}, timeout_s={}, in_view_timeout_s={})", this.len(), c.rho_0_m, c.timeout_s, c.in_view_timeout_s)
    }
}

/// A velocity command in the body frame (FLU).
#[pyclass(name = "Command", module = "subterra._core", frozen)]
pub struct PyCommand {
    /// The core command.
    pub inner: Command,
}

#[pymethods]
impl PyCommand {
    /// Forward speed [m/s].
    #[getter]
    fn v_x_m_s(&self) -> f64 {
        self.inner.v_x_m_s
    }
    /// Lateral speed [m/s] (holonomic mode only).
    #[getter]
    fn v_y_m_s(&self) -> f64 {
        self.inner.v_y_m_s
    }
    /// Vertical speed [m/s].
    #[getter]
    fn v_z_m_s(&self) -> f64 {
        self.inner.v_z_m_s
    }
    /// Yaw rate [rad/s].
    #[getter]
    fn yaw_rate_rad_s(&self) -> f64 {
        self.inner.yaw_rate_rad_s
    }
    /// The goal is within the success radius.
    #[getter]
    fn reached(&self) -> bool {
        self.inner.reached
    }
    /// Attractive force used [N], body frame.
    #[getter]
    fn attractive_body<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array3(py, self.inner.attractive_body)
    }
    /// Summed repulsive force used [N], body frame.
    #[getter]
    fn repulsive_body<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array3(py, self.inner.repulsive_body)
    }
    /// `[v_x, v_y, v_z, yaw_rate]`.
    fn as_array<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let c = &self.inner;
        vec![c.v_x_m_s, c.v_y_m_s, c.v_z_m_s, c.yaw_rate_rad_s].into_pyarray(py)
    }
    fn __repr__(&self) -> String {
        let c = &self.inner;
        format!("Command(v_x_m_s={:.3}, v_y_m_s={:.3}, v_z_m_s={:.3}, yaw_rate_rad_s={:.3}, reached={})", c.v_x_m_s, c.v_y_m_s, c.v_z_m_s, c.yaw_rate_rad_s, if c.reached { "True" } else { "False" })
    }
}

/// Potential-field controller: attraction to the goal plus the cameras' repulsion.
#[pyclass(name = "ApfController", module = "subterra._core", frozen)]
struct PyApfController {
    inner: ApfController,
}

#[pymethods]
impl PyApfController {
    #[new]
    #[pyo3(signature = (preset = "flight".to_owned(), *, config = None), text_signature = "(preset='flight', *, config=None)")]
    fn new(py: Python<'_>, #[pyo3(from_py_with = arg::s_preset)] preset: String, config: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        let config = resolve_config(py, &preset, config)?;
        config.validate().py_err(py)?;
        Ok(Self { inner: ApfController::new(config.apf) })
    }

    /// The command toward `goal_body` (3 numbers, body frame [m]) under the repulsion of
    /// `perception` (one `PerceptionOutput` or a list, one per camera) plus an optional
    /// extra `repulsive_body` force.
    #[pyo3(signature = (goal_body, perception = None, *, repulsive_body = None))]
    fn command(
        &self,
        py: Python<'_>,
        goal_body: &Bound<'_, PyAny>,
        perception: Option<&Bound<'_, PyAny>>,
        repulsive_body: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyCommand> {
        let goal = vec3(py, "goal_body", goal_body)?;
        let mut repulsion = match repulsive_body {
            Some(r) => vec3(py, "repulsive_body", r)?,
            None => glam::DVec3::ZERO,
        };
        if let Some(p) = perception {
            if let Ok(one) = p.cast::<PyPerceptionOutput>() {
                repulsion += one.get().repulsive_body;
            } else if let Ok(items) = p.try_iter() {
                for (n, item) in items.enumerate() {
                    let item = item?;
                    let out = item.cast::<PyPerceptionOutput>().map_err(|_| {
                        input_error(py, format!("argument `perception[{n}]` must be a PerceptionOutput, got {}", convert::type_name(&item)))
                    })?;
                    repulsion += out.get().repulsive_body;
                }
            } else {
                return Err(input_error(py, format!("argument `perception` must be a PerceptionOutput or a sequence of them, got {}", convert::type_name(p))));
            }
        }
        Ok(PyCommand { inner: self.inner.command(goal, repulsion).py_err(py)? })
    }
}

/// What one `Escape.step` gives.
#[pyclass(name = "EscapeOutput", module = "subterra._core", frozen)]
struct PyEscapeOutput {
    inner: EscapeOutput,
}

#[pymethods]
impl PyEscapeOutput {
    /// The goal to attract toward, body frame [m]: the real goal, or the boundary target.
    #[getter]
    fn goal_body<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array3(py, self.inner.goal_body)
    }
    /// `"goal"`, `"follow-left"` or `"follow-right"`.
    #[getter]
    fn mode(&self) -> &'static str {
        match self.inner.mode {
            EscapeMode::Goal => "goal",
            EscapeMode::FollowLeft => "follow-left",
            EscapeMode::FollowRight => "follow-right",
        }
    }
    /// Whether the boundary is being followed.
    #[getter]
    fn active(&self) -> bool {
        self.inner.mode != EscapeMode::Goal
    }
    /// The boundary point followed, world frame [m], or None.
    #[getter]
    fn boundary_world<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.inner.boundary_world.map(|p| array3(py, p))
    }
    /// The repulsion the command should use, body frame [N] (capped while following).
    #[getter]
    fn repulsive_body<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array3(py, self.inner.repulsive_body)
    }
    /// How many times following has engaged so far.
    #[getter]
    fn engagements(&self) -> u32 {
        self.inner.engagements
    }
    fn __repr__(&self) -> String {
        format!("EscapeOutput(mode={:?}, engagements={})", self.mode(), self.inner.engagements)
    }
}

/// Escape from local minima by boundary following: `step(...)` per control step.
#[pyclass(name = "Escape", module = "subterra._core", frozen)]
struct PyEscape {
    inner: Shared<Escape>,
}

#[pymethods]
impl PyEscape {
    /// An escape with the `escape` settings of `preset` (or of `config`).
    #[new]
    #[pyo3(signature = (preset = "flight".to_owned(), *, config = None), text_signature = "(preset='flight', *, config=None)")]
    fn new(py: Python<'_>, #[pyo3(from_py_with = arg::s_preset)] preset: String, config: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        let config = resolve_config(py, &preset, config)?;
        Ok(Self { inner: Shared::new(Escape::new(config.escape, &config.apf).py_err(py)?) })
    }

    /// One step at `stamp` [s] with the odometry pose `world_from_body` (4x4), the goal (or
    /// carrot) `goal_world` [m], the distance still to go `remaining_m`, the obstacle
    /// `memory` (its points are the boundary; None: only `repulsive_body` tells where the
    /// obstacle is) and the repulsion the command will use, body frame [N].
    #[pyo3(signature = (*, stamp, world_from_body, goal_world, remaining_m, memory = None, repulsive_body = None))]
    #[allow(clippy::too_many_arguments)]
    fn step(
        &self,
        py: Python<'_>,
        #[pyo3(from_py_with = arg::stamp)] stamp: f64,
        world_from_body: &Bound<'_, PyAny>,
        goal_world: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = arg::remaining_m)] remaining_m: f64,
        #[pyo3(from_py_with = arg::opt_memory)] memory: Option<Bound<'_, PyObstacleMemory>>,
        repulsive_body: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyEscapeOutput> {
        let memory = memory.as_ref().map(Bound::get);
        let pose = isometry(py, "world_from_body", world_from_body)?;
        let goal = vec3(py, "goal_world", goal_world)?;
        let repulsion = match repulsive_body {
            Some(r) => vec3(py, "repulsive_body", r)?,
            None => glam::DVec3::ZERO,
        };
        let points: Vec<glam::DVec3> = memory.map_or_else(Vec::new, |m| m.inner.lock().obstacles().map(|c| c.point_world).collect());
        Ok(PyEscapeOutput { inner: self.inner.lock().step(stamp, &pose, goal, remaining_m, &points, repulsion).py_err(py)? })
    }

    /// Starts afresh.
    fn reset(&self) {
        self.inner.lock().reset();
    }

    fn __repr__(&self) -> String {
        let this = self.inner.lock();
        let c = this.config();
        format!("Escape(enabled={}, stall_s={}, release_m={})", if c.enabled { "True" } else { "False" }, c.stall_s, c.release_m)
    }
}

/// What one `PathFollower.update` gives.
#[pyclass(name = "CarrotOutput", module = "subterra._core", frozen)]
struct PyCarrotOutput {
    inner: CarrotOutput,
}

#[pymethods]
impl PyCarrotOutput {
    /// The point to pull toward, world frame [m].
    #[getter]
    fn carrot_world<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array3(py, self.inner.carrot_world)
    }
    /// Arc length reached along the path [m].
    #[getter]
    fn progress_m(&self) -> f64 {
        self.inner.progress_m
    }
    /// Distance still to go along the path [m].
    #[getter]
    fn remaining_m(&self) -> f64 {
        self.inner.remaining_m
    }
    fn __repr__(&self) -> String {
        let c = self.inner.carrot_world;
        format!("CarrotOutput(carrot_world=[{:.3}, {:.3}, {:.3}], progress_m={:.3}, remaining_m={:.3})", c.x, c.y, c.z, self.inner.progress_m, self.inner.remaining_m)
    }
}

/// A carrot `lookahead_m` ahead along a path of waypoints: `update(position_world)` per step.
#[pyclass(name = "PathFollower", module = "subterra._core", frozen)]
struct PyPathFollower {
    inner: Shared<PathFollower>,
}

#[pymethods]
impl PyPathFollower {
    /// `path`: at least two points, shape `(N, 3)` [m, world].
    #[new]
    #[pyo3(signature = (path, *, lookahead_m = subterra::apf::DEFAULT_LOOKAHEAD_M))]
    fn new(py: Python<'_>, path: &Bound<'_, PyAny>, #[pyo3(from_py_with = arg::lookahead_m)] lookahead_m: f64) -> PyResult<Self> {
        let points = convert::path3(py, "path", path)?;
        Ok(Self { inner: Shared::new(PathFollower::new(&points, lookahead_m).py_err(py)?) })
    }

    /// The carrot for the robot at `position_world` (3 numbers [m]).
    fn update(&self, py: Python<'_>, position_world: &Bound<'_, PyAny>) -> PyResult<PyCarrotOutput> {
        let p = vec3(py, "position_world", position_world)?;
        Ok(PyCarrotOutput { inner: self.inner.lock().update(p).py_err(py)? })
    }

    /// The path's points, shape `(N, 3)`.
    fn points<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let this = self.inner.lock();
        let flat: Vec<f64> = this.points().iter().flat_map(|p| [p.x, p.y, p.z]).collect();
        flat.into_pyarray(py).reshape([this.points().len(), 3])
    }

    /// The path's length [m].
    #[getter]
    fn length_m(&self) -> f64 {
        self.inner.lock().length_m()
    }

    /// Starts again from the first point.
    fn reset(&self) {
        self.inner.lock().reset();
    }

    fn __repr__(&self) -> String {
        let f = self.inner.lock();
        format!("PathFollower(points={}, length_m={:.3}, lookahead_m={})", f.points().len(), f.length_m(), f.lookahead_m())
    }
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    // Bounds shared with the CLI (`terrain --sensor-height`).
    m.add("MIN_SENSOR_HEIGHT_M", subterra::terrain::MIN_SENSOR_HEIGHT_M)?;
    m.add("MAX_SENSOR_HEIGHT_M", subterra::terrain::MAX_SENSOR_HEIGHT_M)?;
    m.add_class::<PyPinholeCamera>()?;
    config::register(m)?;
    m.add_class::<PyDepthPerception>()?;
    m.add_class::<PyPerceptionOutput>()?;
    m.add_class::<PyMostProbableVoxel>()?;
    m.add_class::<PyApfController>()?;
    m.add_class::<PyCommand>()?;
    m.add_class::<PyObstacleMemory>()?;
    m.add_class::<PyMemoryOutput>()?;
    m.add_class::<PyEscape>()?;
    m.add_class::<PyEscapeOutput>()?;
    m.add_class::<PyPathFollower>()?;
    m.add_class::<PyCarrotOutput>()?;
    sim::register(m)?;
    terrain::register(m)?;
    plan_astar::register(m)?;
    plan_nav::register(m)?;
    plan_mpc::register(m)?;
    qmdp::register(m)?;
    hero::register(m)?;
    pilot::register(m)?;
    codec::register(m)?;
    Ok(())
}
