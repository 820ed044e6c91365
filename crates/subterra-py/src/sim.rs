//! Bindings of `subterra-sim`: worlds, sensors, the step loop. Conversions only.

use glam::DVec3;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};
use subterra::Isometry3;
use subterra_sim::noise::{DepthNoiseModel, LidarNoiseModel};
use subterra_sim::scenarios;
use subterra_sim::sensors::{depth_to_millimetres, DepthCamera, DepthCameraConfig, DepthRender, Lidar, LidarConfig, LidarScan};
use subterra_sim::simulation::{Goal, RunStatus, Simulation, Vehicle};
use subterra_sim::vehicles::{BodyVelocityCommand, GroundRobotConfig, GroundRobotState, QuadrotorConfig, QuadrotorState};
use subterra_sim::world::World;
use subterra_sim::SimError;
use xoshiro::Xoshiro256PlusPlus;
use rand::SeedableRng;

use crate::shared::Shared;
use crate::convert::{arg, isometry, vec3};
use crate::errors::{input_error, sim_err, SimPyResult};
use crate::PyPinholeCamera;

mod xoshiro {
    pub use rand_xoshiro::Xoshiro256PlusPlus;
}

/// A lidar scan as arrays: points `(N, 3)` float32 in the sensor frame, ring `(N,)` uint16.
type LidarArrays<'py> = (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray1<u16>>);

fn matrix<'py>(py: Python<'py>, t: &Isometry3) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let rows: Vec<Vec<f64>> = t.to_matrix_rows().iter().map(|r| r.to_vec()).collect();
    PyArray2::from_vec2(py, &rows).map_err(|e| input_error(py, e.to_string()))
}

fn vec3_array<'py>(py: Python<'py>, v: DVec3) -> Bound<'py, PyArray1<f64>> {
    vec![v.x, v.y, v.z].into_pyarray(py)
}

fn image<'py>(py: Python<'py>, data: Vec<f32>, width: u32, height: u32) -> PyResult<Bound<'py, PyArray2<f32>>> {
    data.into_pyarray(py).reshape([height as usize, width as usize])
}

/// Which encoding a depth image is returned in.
#[derive(Clone, Copy, PartialEq, Eq)]
enum DepthDtype {
    /// float32 metres.
    F32,
    /// uint16 millimetres (ROS / RealSense `16UC1`).
    U16,
}

fn depth_dtype(py: Python<'_>, argument: &str, dtype: &str) -> PyResult<DepthDtype> {
    match dtype {
        "float32" => Ok(DepthDtype::F32),
        "uint16" => Ok(DepthDtype::U16),
        _ => Err(input_error(py, format!("argument `{argument}` must be \"float32\" (metres) or \"uint16\" (millimetres), got {dtype:?}"))),
    }
}

fn depth_image<'py>(py: Python<'py>, data: Vec<f32>, width: u32, height: u32, dtype: DepthDtype) -> PyResult<Bound<'py, PyAny>> {
    Ok(match dtype {
        DepthDtype::F32 => image(py, data, width, height)?.into_any(),
        DepthDtype::U16 => {
            let mm = py.detach(|| depth_to_millimetres(&data));
            mm.into_pyarray(py).reshape([height as usize, width as usize])?.into_any()
        }
    })
}

fn points<'py>(py: Python<'py>, pts: &[[f32; 3]]) -> PyResult<Bound<'py, PyArray2<f32>>> {
    points_array(py, flat_points(pts))
}

/// `(x, y, z)` points as one flat list (the data of an `(N, 3)` array).
fn flat_points(pts: &[[f32; 3]]) -> Vec<f32> {
    pts.iter().flatten().copied().collect()
}

/// The `(N, 3)` array of a [`flat_points`] list.
fn points_array(py: Python<'_>, flat: Vec<f32>) -> PyResult<Bound<'_, PyArray2<f32>>> {
    let n = flat.len() / 3;
    flat.into_pyarray(py).reshape([n, 3])
}

/// A simulated world: primitives, terrain, regions, routes.
#[pyclass(name = "World", module = "subterra._core.sim", frozen)]
pub struct PyWorld {
    pub inner: World,
}

#[pymethods]
impl PyWorld {
    /// Parses a world file's text (TOML, see docs/world-format.md).
    #[staticmethod]
    fn from_toml(py: Python<'_>, #[pyo3(from_py_with = arg::s_text)] text: String) -> PyResult<Self> {
        Ok(Self { inner: World::from_toml_str(&text).sim_err(py)? })
    }

    /// A built-in scenario (`scenario_names()`: `highbay`, `cable`, `tunnel`, `mine`, `subway`,
    /// `slopes`, `rough`, `ledge`, `cave`, `warehouse`) generated with `seed`.
    #[staticmethod]
    #[pyo3(signature = (name, seed = 0))]
    fn scenario(py: Python<'_>, #[pyo3(from_py_with = arg::s_name)] name: String, #[pyo3(from_py_with = arg::seed_u64)] seed: u64) -> PyResult<Self> {
        let spec = scenarios::generate(&name, seed).sim_err(py)?;
        Ok(Self { inner: py.detach(|| World::from_spec(spec)).sim_err(py)? })
    }

    /// Name of the world.
    #[getter]
    fn name(&self) -> String {
        self.inner.spec().name.clone()
    }

    /// Regions: `{name: (centre [m], radius [m])}`.
    #[getter]
    fn regions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for r in &self.inner.spec().regions {
            d.set_item(&r.name, (r.centre.to_vec(), r.radius))?;
        }
        Ok(d)
    }

    /// Routes: `[(name, from, to)]`.
    #[getter]
    fn routes(&self) -> Vec<(String, String, String)> {
        self.inner.spec().routes.iter().map(|r| (r.name.clone(), r.from.clone(), r.to.clone())).collect()
    }

    /// Axis-aligned bounds of the bounded geometry `(min, max)` [m].
    #[getter]
    fn bounds<'py>(&self, py: Python<'py>) -> (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>) {
        let (lo, hi) = self.inner.bounds();
        (vec3_array(py, lo), vec3_array(py, hi))
    }

    /// Number of primitives.
    #[getter]
    fn primitive_count(&self) -> usize {
        self.inner.primitive_count()
    }

    /// Tag, kind and width of primitive `id`: `(tag, kind, width_m, dark)`.
    fn primitive(&self, py: Python<'_>, #[pyo3(from_py_with = arg::id_u32)] id: u32) -> PyResult<(String, String, f64, bool)> {
        let p = self.inner.primitive(id).ok_or_else(|| input_error(py, format!("argument `id` must be < {}, got {id}", self.inner.primitive_count())))?;
        Ok((p.tag.clone(), format!("{:?}", p.kind).to_lowercase(), p.width_m, p.dark))
    }

    /// Nearest hit along a ray: `{"distance_m", "point", "normal", "primitive"}` or None.
    #[pyo3(signature = (origin, direction, max_range_m = 100.0))]
    fn cast_ray<'py>(&self, py: Python<'py>, origin: &Bound<'py, PyAny>, direction: &Bound<'py, PyAny>, #[pyo3(from_py_with = arg::max_range_m)] max_range_m: f64) -> PyResult<Option<Bound<'py, PyDict>>> {
        let o = vec3(py, "origin", origin)?;
        let d = vec3(py, "direction", direction)?;
        if d.length() == 0.0 {
            return Err(input_error(py, "argument `direction` must not be zero"));
        }
        if !(max_range_m.is_finite() && max_range_m > 0.0) {
            return Err(input_error(py, format!("argument `max_range_m` must be finite and > 0, got {max_range_m}")));
        }
        let Some(hit) = self.inner.cast_ray(o, d.normalize(), max_range_m) else { return Ok(None) };
        let out = PyDict::new(py);
        out.set_item("distance_m", hit.distance_m)?;
        out.set_item("point", vec3_array(py, hit.point))?;
        out.set_item("normal", vec3_array(py, hit.normal))?;
        out.set_item("primitive", hit.primitive)?;
        Ok(Some(out))
    }

    /// Distance from `point` to the nearest solid surface [m] (<= 0 inside).
    fn clearance(&self, py: Python<'_>, point: &Bound<'_, PyAny>) -> PyResult<f64> {
        Ok(self.inner.clearance(vec3(py, "point", point)?))
    }

    /// Terrain height at `(x, y)` [m], None over a hole or where nothing is below.
    fn ground_height(&self, py: Python<'_>, #[pyo3(from_py_with = arg::x)] x: f64, #[pyo3(from_py_with = arg::y)] y: f64) -> PyResult<Option<f64>> {
        // Beyond the limit of poses: a point no robot of the library can stand at.
        let far = subterra::frames::MAX_TRANSLATION_M;
        if !(x.is_finite() && y.is_finite() && x.abs() <= far && y.abs() <= far) {
            return Err(input_error(py, format!("arguments `x`, `y` must be finite and within {far:e} m of the origin, got ({x}, {y})")));
        }
        Ok(self.inner.ground_height(x, y))
    }

    /// The world description as TOML text.
    fn to_toml(&self, py: Python<'_>) -> PyResult<String> {
        toml::to_string(self.inner.spec()).map_err(|e| input_error(py, format!("world cannot be written as TOML: {e}")))
    }

    fn __repr__(&self) -> String {
        format!("World(name={:?}, primitives={}, regions={})", self.inner.spec().name, self.inner.primitive_count(), self.inner.spec().regions.len())
    }
}

fn depth_noise(py: Python<'_>, name: &str) -> PyResult<DepthNoiseModel> {
    DepthNoiseModel::preset(name).sim_err(py)
}

fn lidar_noise(py: Python<'_>, name: &str) -> PyResult<LidarNoiseModel> {
    LidarNoiseModel::preset(name).sim_err(py)
}

/// A sensor's noise-free frame, kept between calls and rendered into again: a frame's
/// megabytes then reuse the last frame's pages instead of fresh ones mapped and cleared by
/// the kernel. A call made while another thread holds it renders into a new one.
#[derive(Default)]
struct Scratch<T: Default>(std::sync::Mutex<T>);

impl<T: Default> Scratch<T> {
    fn with<R>(&self, f: impl FnOnce(&mut T) -> R) -> R {
        match self.0.try_lock() {
            Ok(mut kept) => f(&mut kept),
            // A call that panicked left it half written: every call overwrites it whole.
            Err(std::sync::TryLockError::Poisoned(poisoned)) => f(&mut poisoned.into_inner()),
            Err(std::sync::TryLockError::WouldBlock) => f(&mut T::default()),
        }
    }
}

/// A simulated pinhole depth camera.
#[pyclass(name = "DepthCamera", module = "subterra._core.sim", frozen)]
pub struct PyDepthCamera {
    inner: DepthCamera,
    truth: Scratch<DepthRender>,
}

#[pymethods]
impl PyDepthCamera {
    #[new]
    #[pyo3(signature = (camera = None, min_range_m = 0.1, max_range_m = 10.0))]
    fn new(py: Python<'_>, #[pyo3(from_py_with = arg::opt_camera)] camera: Option<Bound<'_, PyPinholeCamera>>, #[pyo3(from_py_with = arg::min_range_m)] min_range_m: f64, #[pyo3(from_py_with = arg::max_range_m)] max_range_m: f64) -> PyResult<Self> {
        let mut config = DepthCameraConfig::d435();
        if let Some(c) = camera {
            config.camera = c.get().inner;
        }
        config.min_range_m = min_range_m;
        config.max_range_m = max_range_m;
        Ok(Self { inner: DepthCamera::new(config).sim_err(py)?, truth: Scratch::default() })
    }

    /// The RealSense D435 preset: 640x480, fx = fy = 385 px, 0.1-10 m.
    #[staticmethod]
    fn d435(py: Python<'_>) -> PyResult<Self> {
        Ok(Self { inner: DepthCamera::new(DepthCameraConfig::d435()).sim_err(py)?, truth: Scratch::default() })
    }

    /// The intrinsics.
    #[getter]
    fn camera(&self) -> PyPinholeCamera {
        PyPinholeCamera { inner: self.inner.config().camera }
    }

    /// Renders an `(H, W)` depth image from `world_from_camera` (4x4, optical frame), with
    /// the named noise preset seeded by `seed`, on `threads` threads (the image is the same
    /// for any count): `dtype="float32"` metres or `"uint16"` millimetres, 0 = no return.
    /// Releases the GIL.
    #[pyo3(
        signature = (world, world_from_camera, noise = "none".to_owned(), seed = 0, threads = 1, *, dtype = "float32".to_owned()),
        text_signature = "($self, world, world_from_camera, noise='none', seed=0, threads=1, *, dtype='float32')"
    )]
    #[allow(clippy::too_many_arguments)]
    fn render<'py>(&self, py: Python<'py>, #[pyo3(from_py_with = arg::world)] world: Bound<'py, PyWorld>, world_from_camera: &Bound<'py, PyAny>, #[pyo3(from_py_with = arg::s_noise)] noise: String, #[pyo3(from_py_with = arg::seed_u64)] seed: u64, #[pyo3(from_py_with = arg::threads_usize)] threads: usize, #[pyo3(from_py_with = arg::s_dtype)] dtype: String) -> PyResult<Bound<'py, PyAny>> {
        let dtype = depth_dtype(py, "dtype", &dtype)?;
        let noise = noise.as_str();
        if threads == 0 || threads > 256 {
            return Err(input_error(py, format!("argument `threads` must be in 1..=256, got {threads}")));
        }
        let pose = isometry(py, "world_from_camera", world_from_camera)?;
        let model = depth_noise(py, noise)?;
        let (cam, w) = (&self.inner, &world.get().inner);
        let depth = py
            .detach(|| {
                self.truth.with(|truth| {
                    if threads > 1 {
                        cam.render_parallel_into(w, &pose, threads, truth);
                    } else {
                        cam.render_into(w, &pose, truth);
                    }
                    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
                    model.try_apply(truth, w, cam.config(), &mut rng)
                })
            })
            .sim_err(py)?;
        let c = self.inner.config().camera;
        depth_image(py, depth, c.width, c.height, dtype)
    }
}

/// A simulated spinning lidar.
#[pyclass(name = "Lidar", module = "subterra._core.sim", frozen)]
pub struct PyLidar {
    inner: Lidar,
    truth: Scratch<LidarScan>,
}

#[pymethods]
impl PyLidar {
    /// A preset: `vlp16` or `os1_64`.
    #[new]
    #[pyo3(signature = (preset = "os1_64".to_owned()), text_signature = "(preset='os1_64')")]
    fn new(py: Python<'_>, #[pyo3(from_py_with = arg::s_preset)] preset: String) -> PyResult<Self> {
        let preset = preset.as_str();
        let config = match preset {
            "vlp16" => LidarConfig::vlp16(),
            "os1_64" => LidarConfig::os1_64(),
            _ => return Err(sim_err(py, SimError::Unknown { what: "lidar preset".into(), name: preset.into(), known: "vlp16, os1_64".into() })),
        };
        Ok(Self { inner: Lidar::new(config).sim_err(py)?, truth: Scratch::default() })
    }

    /// Rays per scan.
    #[getter]
    fn ray_count(&self) -> usize {
        self.inner.config().ray_count()
    }

    /// One scan from `world_from_sensor` (4x4): `(points (N, 3) float32 in the sensor frame, ring (N,) uint16)`.
    #[pyo3(signature = (world, world_from_sensor, noise = "none".to_owned(), seed = 0), text_signature = "($self, world, world_from_sensor, noise='none', seed=0)")]
    fn scan<'py>(&self, py: Python<'py>, #[pyo3(from_py_with = arg::world)] world: Bound<'py, PyWorld>, world_from_sensor: &Bound<'py, PyAny>, #[pyo3(from_py_with = arg::s_noise)] noise: String, #[pyo3(from_py_with = arg::seed_u64)] seed: u64) -> PyResult<LidarArrays<'py>> {
        let pose = isometry(py, "world_from_sensor", world_from_sensor)?;
        let model = lidar_noise(py, &noise)?;
        let (lidar, w) = (&self.inner, &world.get().inner);
        let (flat, ring) = py
            .detach(|| {
                self.truth.with(|truth| {
                    lidar.scan_into(w, &pose, truth);
                    if model.stages.is_empty() {
                        // No noise: the arrays straight from the kept scan.
                        return Ok((flat_points(&truth.points_sensor), truth.ring.clone()));
                    }
                    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
                    let scan = model.try_apply(truth, &mut rng)?;
                    Ok((flat_points(&scan.points_sensor), scan.ring))
                })
            })
            .sim_err(py)?;
        Ok((points_array(py, flat)?, ring.into_pyarray(py)))
    }
}

fn status_name(status: &RunStatus) -> &'static str {
    match status {
        RunStatus::Running => "running",
        RunStatus::GoalReached => "goal_reached",
        RunStatus::Failed(_) => "failed",
        RunStatus::TimedOut => "timed_out",
        RunStatus::Aborted(_) => "aborted",
    }
}

/// How far outside the world's bounded geometry a vehicle may start [m].
const START_MARGIN_M: f64 = 100.0;

/// A closed-loop simulation: one vehicle, its sensors, a goal, metrics.
#[pyclass(name = "Simulation", module = "subterra._core.sim", frozen)]
pub struct PySimulation {
    inner: Shared<Simulation>,
}

#[pymethods]
impl PySimulation {
    /// `vehicle`: "quadrotor" (start = x, y, z) or "ground" (start = x, y; z ignored);
    /// `sensors`: `{name: sensor}` or `{name: (sensor, body_from_sensor, noise)}` with a
    /// `DepthCamera` or `Lidar` (see `add_depth_camera` / `add_lidar` for the defaults);
    /// `yaw` [rad]; every noise stream is seeded from `seed`.
    #[new]
    #[pyo3(
        signature = (world, vehicle = "quadrotor".to_owned(), sensors = None, seed = 0, *, start = None, yaw = 0.0),
        text_signature = "(world, vehicle='quadrotor', sensors=None, seed=0, *, start=None, yaw=0.0)"
    )]
    fn new(
        py: Python<'_>,
        #[pyo3(from_py_with = arg::world)] world: Bound<'_, PyWorld>,
        #[pyo3(from_py_with = arg::s_vehicle)] vehicle: String,
        sensors: Option<&Bound<'_, PyAny>>,
        #[pyo3(from_py_with = arg::seed_u64)] seed: u64,
        start: Option<&Bound<'_, PyAny>>,
        #[pyo3(from_py_with = arg::yaw)] yaw: f64,
    ) -> PyResult<Self> {
        let vehicle = vehicle.as_str();
        let start = match start {
            Some(s) => vec3(py, "start", s)?,
            None => DVec3::ZERO,
        };
        if !yaw.is_finite() {
            return Err(input_error(py, format!("argument `yaw` must be finite, got {yaw}")));
        }
        // A start far off the world's geometry is a mistake (a typo, or a unit error), not a flight.
        let (lo, hi) = world.get().inner.bounds();
        let margin = DVec3::splat(START_MARGIN_M);
        if !(start.cmpge(lo - margin).all() && start.cmple(hi + margin).all()) {
            return Err(input_error(
                py,
                format!("argument `start` {:?} m is more than {START_MARGIN_M} m outside the world (its geometry spans {:?} to {:?} m)", start.to_array(), lo.to_array(), hi.to_array()),
            ));
        }
        let v = match vehicle {
            "quadrotor" => Vehicle::quadrotor(QuadrotorConfig::default(), QuadrotorState::at_rest(start, yaw)),
            "ground" => Vehicle::ground(
                GroundRobotConfig::default(),
                GroundRobotState { x_m: start.x, y_m: start.y, yaw_rad: yaw, v_m_s: 0.0, yaw_rate_rad_s: 0.0 },
            ),
            _ => Err(SimError::Unknown { what: "vehicle".into(), name: vehicle.into(), known: "quadrotor, ground".into() }),
        }
        .sim_err(py)?;
        let w = world.get().inner.clone();
        // The Rust constructor names its `vehicle` argument when the vehicle cannot start
        // where it stands; from Python that place is `start` (and `yaw`).
        let created = Simulation::new(w, v, seed).map_err(|e| match e {
            SimError::InvalidInput { argument, reason } if argument == "vehicle" => SimError::InvalidInput { argument: "start".into(), reason },
            other => other,
        });
        let sim = Self { inner: Shared::new(created.sim_err(py)?) };
        let sensors = match sensors {
            Some(s) if !s.is_none() => Some(s.cast::<PyDict>().map_err(|_| {
                input_error(py, format!("argument `sensors` must be a dict {{name: sensor}} or {{name: (sensor, body_from_sensor, noise)}}, got {}", crate::convert::type_name(s)))
            })?),
            _ => None,
        };
        if let Some(sensors) = sensors {
            for (name, mount) in sensors.iter() {
                let name: String = name.extract().map_err(|_| input_error(py, "argument `sensors` must map names (str) to sensors"))?;
                let (sensor, pose, noise) = if let Ok(t) = mount.cast::<pyo3::types::PyTuple>() {
                    let get = |i: usize| t.get_item(i).ok();
                    let noise: String = match get(2) {
                        Some(n) => n.extract().map_err(|_| input_error(py, format!("argument `sensors[{name:?}]`: noise must be a preset name")))?,
                        None => "none".into(),
                    };
                    let sensor = get(0).ok_or_else(|| input_error(py, format!("argument `sensors[{name:?}]` is an empty tuple")))?;
                    (sensor, get(1).filter(|p| !p.is_none()), noise)
                } else {
                    (mount.clone(), None, "none".to_owned())
                };
                if let Ok(cam) = sensor.cast::<PyDepthCamera>() {
                    sim.add_depth_camera(py, name.clone(), cam.clone(), pose.as_ref(), noise)?;
                } else if let Ok(lidar) = sensor.cast::<PyLidar>() {
                    sim.add_lidar(py, name.clone(), lidar.clone(), pose.as_ref(), noise)?;
                } else {
                    return Err(input_error(py, format!("argument `sensors[{name:?}]` must be a DepthCamera or a Lidar, or a tuple (sensor, body_from_sensor, noise)")));
                }
            }
        }
        Ok(sim)
    }

    /// Mounts a depth camera (default pose: looking forward from the body origin).
    #[pyo3(signature = (name, camera, body_from_camera = None, noise = "none".to_owned()), text_signature = "($self, name, camera, body_from_camera=None, noise='none')")]
    fn add_depth_camera(&self, py: Python<'_>, #[pyo3(from_py_with = arg::s_name)] name: String, #[pyo3(from_py_with = arg::depth_camera)] camera: Bound<'_, PyDepthCamera>, body_from_camera: Option<&Bound<'_, PyAny>>, #[pyo3(from_py_with = arg::s_noise)] noise: String) -> PyResult<()> {
        let (name, noise) = (name.as_str(), noise.as_str());
        let pose = match body_from_camera {
            Some(m) => isometry(py, "body_from_camera", m)?,
            None => Isometry3::body_from_forward_optical(),
        };
        let model = depth_noise(py, noise)?;
        self.inner.lock().add_depth_camera(name, *camera.get().inner.config(), pose, model).sim_err(py)
    }

    /// Mounts a lidar (default pose: at the body origin, axes aligned).
    #[pyo3(signature = (name, lidar, body_from_sensor = None, noise = "none".to_owned()), text_signature = "($self, name, lidar, body_from_sensor=None, noise='none')")]
    fn add_lidar(&self, py: Python<'_>, #[pyo3(from_py_with = arg::s_name)] name: String, #[pyo3(from_py_with = arg::lidar)] lidar: Bound<'_, PyLidar>, body_from_sensor: Option<&Bound<'_, PyAny>>, #[pyo3(from_py_with = arg::s_noise)] noise: String) -> PyResult<()> {
        let (name, noise) = (name.as_str(), noise.as_str());
        let pose = match body_from_sensor {
            Some(m) => isometry(py, "body_from_sensor", m)?,
            None => Isometry3::IDENTITY,
        };
        let model = lidar_noise(py, noise)?;
        self.inner.lock().add_lidar(name, lidar.get().inner.config().clone(), pose, model).sim_err(py)
    }

    /// The goal: a region of the world by name, or a point with a radius [m].
    #[pyo3(signature = (region = None, point = None, radius_m = 0.5))]
    fn set_goal(&self, py: Python<'_>, #[pyo3(from_py_with = arg::opt_region)] region: Option<String>, point: Option<&Bound<'_, PyAny>>, #[pyo3(from_py_with = arg::radius_m)] radius_m: f64) -> PyResult<()> {
        let goal = match (region, point) {
            (Some(r), None) => Goal::Region(r),
            (None, Some(p)) => Goal::Point { centre: vec3(py, "point", p)?, radius_m },
            _ => return Err(input_error(py, "give exactly one of `region` and `point`")),
        };
        self.inner.lock().set_goal(goal).sim_err(py)
    }

    /// Ends the run as timed out after `limit_s` simulated seconds (None: no limit).
    fn set_time_limit(&self, py: Python<'_>, #[pyo3(from_py_with = arg::opt_limit_s)] limit_s: Option<f64>) -> PyResult<()> {
        self.inner.lock().set_time_limit(limit_s).sim_err(py)
    }

    /// Ends the run with the caller's cause (e.g. "local_minimum").
    fn abort(&self, #[pyo3(from_py_with = arg::s_cause)] cause: String) {
        self.inner.lock().abort(&cause);
    }

    /// Renders every sensor at the true pose: a dict with `time_s`, `depth` ({name: (H, W)
    /// noisy depth, float32 [m] or, with `depth_dtype="uint16"`, uint16 [mm]),
    /// `depth_truth` ({name: (H, W) float32 [m], noise-free}), `depth_truth_min` ({name:
    /// closest noise-free depth [m] or None}), `scans` ({name: (N, 3) float32}),
    /// `world_from_body` and `odometry` (4x4), `velocity_world`, `world_from_sensor` ({name: 4x4}).
    #[pyo3(signature = (*, depth_dtype = "float32".to_owned()), text_signature = "($self, *, depth_dtype='float32')")]
    fn observe<'py>(&self, py: Python<'py>, #[pyo3(from_py_with = arg::s_depth_dtype)] depth_dtype: String) -> PyResult<Bound<'py, PyDict>> {
        let dtype = self::depth_dtype(py, "depth_dtype", &depth_dtype)?;
        let mut this = self.inner.lock();
        let sim = &mut *this;
        let obs = py.detach(|| sim.observe());
        let d = PyDict::new(py);
        d.set_item("time_s", obs.time_s)?;
        let depth = PyDict::new(py);
        let truth = PyDict::new(py);
        let truth_min = PyDict::new(py);
        let poses = PyDict::new(py);
        for o in obs.depth {
            let closest = o.truth.depth_m.iter().copied().filter(|&z| z > 0.0).reduce(f32::min).map(f64::from);
            truth_min.set_item(&o.name, closest)?;
            truth.set_item(&o.name, image(py, o.truth.depth_m, o.width, o.height)?)?;
            poses.set_item(&o.name, matrix(py, &o.world_from_camera)?)?;
            depth.set_item(o.name, depth_image(py, o.depth_m, o.width, o.height, dtype)?)?;
        }
        let scans = PyDict::new(py);
        for s in obs.scans {
            poses.set_item(&s.name, matrix(py, &s.world_from_sensor)?)?;
            scans.set_item(s.name, points(py, &s.scan.points_sensor)?)?;
        }
        d.set_item("depth", depth)?;
        d.set_item("depth_truth", truth)?;
        d.set_item("depth_truth_min", truth_min)?;
        d.set_item("scans", scans)?;
        d.set_item("world_from_sensor", poses)?;
        d.set_item("world_from_body", matrix(py, &obs.world_from_body)?)?;
        d.set_item("odometry", matrix(py, &obs.odometry.world_from_body)?)?;
        d.set_item("velocity_world", vec3_array(py, obs.velocity_world))?;
        Ok(d)
    }

    /// Advances by `dt` [s] under a body-frame `command`: a `subterra.Command` (from
    /// `ApfController.command`) or `[v_x, v_y, v_z, yaw_rate]` (m/s, rad/s; a ground robot
    /// uses v_x and yaw_rate). `compute_time_s` is the controller's time for this step (for
    /// the metrics). Returns `{time_s, status, collided, clearance_m, failure}`.
    #[pyo3(signature = (command, dt = 0.1, *, compute_time_s = 0.0))]
    fn step<'py>(&self, py: Python<'py>, command: &Bound<'py, PyAny>, #[pyo3(from_py_with = arg::dt)] dt: f64, #[pyo3(from_py_with = arg::compute_time_s)] compute_time_s: f64) -> PyResult<Bound<'py, PyDict>> {
        let cmd = if let Ok(c) = command.cast::<crate::PyCommand>() {
            let c = c.get();
            BodyVelocityCommand::new(c.inner.v_x_m_s, c.inner.v_y_m_s, c.inner.v_z_m_s, c.inner.yaw_rate_rad_s)
        } else {
            // Through NumPy's dtype check: pyo3's float() of a complex element drops its imaginary
            // part. A NaN goes on to the command's own check, which names the component.
            let v = crate::convert::real_vector(py, "command", command, 4, "a Command or [v_x, v_y, v_z, yaw_rate]")?;
            BodyVelocityCommand::new(v[0], v[1], v[2], v[3])
        };
        let mut this = self.inner.lock();
        let sim = &mut *this;
        let out = py.detach(|| sim.step(&cmd, dt, compute_time_s)).map_err(|e| e.renamed("dt_s", "dt")).sim_err(py)?;
        let d = PyDict::new(py);
        d.set_item("time_s", out.time_s)?;
        d.set_item("status", status_name(&out.status))?;
        d.set_item("collided", out.collided)?;
        d.set_item("clearance_m", out.clearance_m)?;
        d.set_item("failure", out.status.failure_cause().or(out.failure.map(|f| f.as_str().to_owned())))?;
        Ok(d)
    }

    /// Run metrics so far: success, failure, collisions, min clearance, path length, time, compute time.
    fn metrics<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let this = self.inner.lock();
        let m = this.metrics();
        let d = PyDict::new(py);
        d.set_item("success", m.success)?;
        d.set_item("failure", m.failure)?;
        d.set_item("collisions", m.collisions)?;
        d.set_item("min_clearance_m", m.min_clearance_m)?;
        d.set_item("path_length_m", m.path_length_m)?;
        d.set_item("time_s", m.time_s)?;
        d.set_item("compute_ms_median", m.compute_ms_median)?;
        d.set_item("compute_ms_p99", m.compute_ms_p99)?;
        d.set_item("steps", m.steps)?;
        Ok(d)
    }

    /// `running`, `goal_reached`, `failed`, `timed_out` or `aborted`.
    #[getter]
    fn status(&self) -> &'static str {
        status_name(self.inner.lock().status())
    }

    /// Simulation time [s].
    #[getter]
    fn time_s(&self) -> f64 {
        self.inner.lock().time_s()
    }

    /// True pose of the body (4x4).
    #[getter]
    fn world_from_body<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let this = self.inner.lock();
        matrix(py, &this.vehicle().world_from_body())
    }
}

/// Names of the built-in scenarios.
#[pyfunction]
pub fn scenario_names() -> Vec<&'static str> {
    scenarios::SCENARIOS.to_vec()
}

/// Registers `subterra._core.sim`.
pub fn register(parent: &Bound<'_, PyModule>) -> PyResult<()> {
    let m = PyModule::new(parent.py(), "sim")?;
    m.add_class::<PyWorld>()?;
    m.add_class::<PyDepthCamera>()?;
    m.add_class::<PyLidar>()?;
    m.add_class::<PySimulation>()?;
    m.add_function(wrap_pyfunction!(scenario_names, &m)?)?;
    m.add("DEPTH_NOISE_PRESETS", PyTuple::new(parent.py(), subterra_sim::noise::DEPTH_NOISE_PRESETS)?)?;
    m.add("LIDAR_NOISE_PRESETS", PyTuple::new(parent.py(), subterra_sim::noise::LIDAR_NOISE_PRESETS)?)?;
    parent.add_submodule(&m)?;
    Ok(())
}
