//! The step loop: one world, one vehicle, mounted sensors, a goal, metrics.
//!
//! ```text
//! let mut sim = Simulation::new(world, vehicle, seed)?;
//! sim.add_depth_camera("front", DepthCameraConfig::d435(), body_from_camera, DepthNoiseModel::preset("d435")?)?;
//! sim.set_goal(Goal::Region("B".into()))?;
//! while sim.status().is_running() {
//!     let obs = sim.observe();                 // sensors at the true pose, noisy + truth
//!     let (cmd, compute_s) = controller(&obs); // the code under test, timed by the caller
//!     sim.step(&cmd, 0.1, compute_s)?;         // vehicle, collisions, failures, goal, metrics
//! }
//! let metrics = sim.metrics();
//! ```
//!
//! Randomness: the seed feeds one xoshiro256++ stream that hands out one sub-stream for
//! the odometry drift (at construction) and one per sensor (when it is added, in order):
//! the same seed and the same calls give bit-identical observations, and adding a sensor
//! does not change what the others see.

use glam::{DMat3, DVec3};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use subterra::Isometry3;

use crate::error::{SimError, SimResult};
use crate::metrics::{MetricsRecorder, RunMetrics};
use crate::noise::{DepthNoiseModel, LidarNoiseModel};
use crate::sensors::{DepthCamera, DepthCameraConfig, DepthRender, Lidar, LidarConfig, LidarScan};
use crate::vehicles::{
    BodyVelocityCommand, Failure, GroundRobot, GroundRobotConfig, GroundRobotState, Quadrotor, QuadrotorConfig, QuadrotorState, MAX_STEP_S,
};
use crate::world::World;

/// Tolerance on `RᵀR = I` and `det R = 1` of a sensor mounting.
const ROTATION_TOLERANCE: f64 = 1e-6;

/// The simulated vehicle with its state.
#[derive(Debug, Clone, PartialEq)]
pub enum Vehicle {
    /// An aerial robot ([`Quadrotor`]).
    Quadrotor(Quadrotor),
    /// A ground robot ([`GroundRobot`]); the simulation settles it on the terrain at start.
    Ground(GroundRobot),
}

impl Vehicle {
    /// A quadrotor (validated).
    pub fn quadrotor(config: QuadrotorConfig, initial: QuadrotorState) -> SimResult<Self> {
        Ok(Self::Quadrotor(Quadrotor::new(config, initial)?))
    }

    /// A ground robot (validated).
    pub fn ground(config: GroundRobotConfig, initial: GroundRobotState) -> SimResult<Self> {
        Ok(Self::Ground(GroundRobot::new(config, initial)?))
    }

    /// The true pose of the body.
    pub fn world_from_body(&self) -> Isometry3 {
        match self {
            Self::Quadrotor(q) => q.world_from_body(),
            Self::Ground(g) => g.world_from_body(),
        }
    }

    /// The true position of the body origin [m].
    pub fn position(&self) -> DVec3 {
        self.world_from_body().translation
    }

    /// The true velocity in the world frame [m/s].
    pub fn velocity_world(&self) -> DVec3 {
        match self {
            Self::Quadrotor(q) => q.state().velocity_world,
            Self::Ground(g) => g.velocity_world(),
        }
    }

    /// Clearance [m]: the quadrotor's sphere clearance ([`Quadrotor::clearance_m`]) or
    /// the ground robot's probe ([`GroundRobot::clearance_m`]).
    fn clearance_m(&self, world: &World) -> f64 {
        match self {
            Self::Quadrotor(q) => q.clearance_m(world),
            Self::Ground(g) => g.clearance_m(world),
        }
    }

    fn odometry<R: Rng + ?Sized>(&mut self, rng: &mut R) -> Odometry {
        let (world_from_body, velocity_world) = match self {
            Self::Quadrotor(q) => q.odometry(rng),
            Self::Ground(g) => g.odometry(rng),
        };
        Odometry { world_from_body, velocity_world }
    }
}

/// Where the run succeeds.
#[derive(Debug, Clone, PartialEq)]
pub enum Goal {
    /// A named region of the world: a vertical cylinder (horizontal distance to its
    /// centre <= its radius, any height).
    Region(String),
    /// A ball around a point: distance to `centre` [m] <= `radius_m` [m].
    Point {
        /// Centre [m].
        centre: DVec3,
        /// Radius [m].
        radius_m: f64,
    },
}

/// A goal resolved to its geometry.
#[derive(Debug, Clone, Copy, PartialEq)]
struct GoalArea {
    centre: DVec3,
    radius_m: f64,
    /// Vertical cylinder (ignore z) or ball.
    cylinder: bool,
}

impl GoalArea {
    fn contains(&self, p: DVec3) -> bool {
        let d = p - self.centre;
        let d = if self.cylinder { d.truncate().length() } else { d.length() };
        d <= self.radius_m
    }
}

/// Where a run stands.
#[derive(Debug, Clone, PartialEq)]
pub enum RunStatus {
    /// Still going.
    Running,
    /// The vehicle reached the goal.
    GoalReached,
    /// A failure ended the run (a collision only when collisions stop the run).
    Failed(Failure),
    /// The time limit passed.
    TimedOut,
    /// The caller ended the run with this cause ([`Simulation::abort`]).
    Aborted(String),
}

impl RunStatus {
    /// Whether the run goes on.
    pub fn is_running(&self) -> bool {
        matches!(self, Self::Running)
    }

    /// The failure cause for [`RunMetrics::failure`]: `collision`, `rollover`, `fall`,
    /// `out_of_world`, `timeout` or the caller's cause; `None` when running or successful.
    pub fn failure_cause(&self) -> Option<String> {
        match self {
            Self::Running | Self::GoalReached => None,
            Self::Failed(f) => Some(f.as_str().to_owned()),
            Self::TimedOut => Some("timeout".to_owned()),
            Self::Aborted(cause) => Some(cause.clone()),
        }
    }
}

/// What one step did.
#[derive(Debug, Clone, PartialEq)]
pub struct StepOutcome {
    /// Simulation time after the step [s].
    pub time_s: f64,
    /// Where the run stands after the step.
    pub status: RunStatus,
    /// The vehicle is in collision at the end of the step (ground robot: at some sub-step of it).
    pub collided: bool,
    /// The vehicle's clearance after the step [m] (see [`Simulation::step`]).
    pub clearance_m: f64,
    /// The failure detected during this step, terminal or not.
    pub failure: Option<Failure>,
}

/// Odometry as the robot's estimator would report it (the truth plus optional drift).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Odometry {
    /// Estimated pose of the body.
    pub world_from_body: Isometry3,
    /// Estimated velocity in the world frame [m/s].
    pub velocity_world: DVec3,
}

/// One depth camera's frame.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthObservation {
    /// The camera's name.
    pub name: String,
    /// Image width [px].
    pub width: u32,
    /// Image height [px].
    pub height: u32,
    /// Noisy depth along the optical axis [m], row-major, 0 = no return.
    pub depth_m: Vec<f32>,
    /// The noise-free render (ground truth: depth, primitive hit, incidence).
    pub truth: DepthRender,
    /// The camera's true pose (optical frame).
    pub world_from_camera: Isometry3,
}

/// One lidar's scan.
#[derive(Debug, Clone, PartialEq)]
pub struct LidarObservation {
    /// The lidar's name.
    pub name: String,
    /// Noisy returns in the sensor frame.
    pub scan: LidarScan,
    /// Noise-free returns (ground truth).
    pub truth: LidarScan,
    /// The sensor's true pose.
    pub world_from_sensor: Isometry3,
}

/// Everything the robot senses at one instant, plus the ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    /// Simulation time [s].
    pub time_s: f64,
    /// Depth cameras, in the order they were added.
    pub depth: Vec<DepthObservation>,
    /// Lidars, in the order they were added.
    pub scans: Vec<LidarObservation>,
    /// True pose of the body.
    pub world_from_body: Isometry3,
    /// True velocity in the world frame [m/s].
    pub velocity_world: DVec3,
    /// Odometry (the truth plus the vehicle's configured drift).
    pub odometry: Odometry,
}

struct MountedCamera {
    name: String,
    camera: DepthCamera,
    body_from_camera: Isometry3,
    noise: DepthNoiseModel,
    rng: Xoshiro256PlusPlus,
}

struct MountedLidar {
    name: String,
    lidar: Lidar,
    body_from_sensor: Isometry3,
    noise: LidarNoiseModel,
    rng: Xoshiro256PlusPlus,
}

/// A closed-loop simulation (see the module documentation).
pub struct Simulation {
    world: World,
    vehicle: Vehicle,
    seed: u64,
    streams: Xoshiro256PlusPlus,
    odometry_rng: Xoshiro256PlusPlus,
    cameras: Vec<MountedCamera>,
    lidars: Vec<MountedLidar>,
    render_threads: usize,
    goal: Option<GoalArea>,
    time_s: f64,
    time_limit_s: Option<f64>,
    stop_on_collision: bool,
    status: RunStatus,
    metrics: MetricsRecorder,
}

impl Simulation {
    /// A simulation of `vehicle` in `world` with every random stream derived from `seed`.
    /// A ground robot is settled on the terrain first. Errors
    /// ([`SimError::InvalidInput`], argument `vehicle`) when the vehicle starts in a failed
    /// state: a quadrotor sphere touching a solid, a ground robot over a hole, off the
    /// terrain, tipped over or inside an obstacle.
    pub fn new(world: World, vehicle: Vehicle, seed: u64) -> SimResult<Self> {
        let mut vehicle = vehicle;
        match &mut vehicle {
            Vehicle::Quadrotor(q) => {
                if q.collided(&world) {
                    let p = q.state().position;
                    return Err(SimError::input(
                        "vehicle",
                        format!("the quadrotor starts in collision at ({:.3}, {:.3}, {:.3}) (clearance {:.3} m)", p.x, p.y, p.z, q.clearance_m(&world)),
                    ));
                }
            }
            Vehicle::Ground(g) => {
                if let Some(failure) = g.place(&world) {
                    let s = g.state();
                    return Err(SimError::input(
                        "vehicle",
                        format!("the ground robot cannot start at ({:.3}, {:.3}) heading {:.3} rad: {failure}", s.x_m, s.y_m, s.yaw_rad),
                    ));
                }
            }
        }
        let mut streams = Xoshiro256PlusPlus::seed_from_u64(seed);
        let odometry_rng = Xoshiro256PlusPlus::seed_from_u64(streams.next_u64());
        let clearance = vehicle.clearance_m(&world);
        let metrics = MetricsRecorder::new(0.0, vehicle.position(), clearance, false);
        Ok(Self {
            world,
            vehicle,
            seed,
            streams,
            odometry_rng,
            cameras: Vec::new(),
            lidars: Vec::new(),
            render_threads: 1,
            goal: None,
            time_s: 0.0,
            time_limit_s: None,
            stop_on_collision: true,
            status: RunStatus::Running,
            metrics,
        })
    }

    fn check_sensor_name(&self, name: &str) -> SimResult<()> {
        if name.trim().is_empty() {
            return Err(SimError::input("name", "must not be empty"));
        }
        if self.cameras.iter().any(|c| c.name == name) || self.lidars.iter().any(|l| l.name == name) {
            return Err(SimError::input("name", format!("a sensor named `{name}` is already mounted")));
        }
        Ok(())
    }

    /// Mounts a depth camera at `body_from_camera` (optical frame: x right, y down, z
    /// forward) with its noise model. Errors name `name`, `config.*`, `body_from_camera`
    /// or `noise.*`.
    pub fn add_depth_camera(&mut self, name: &str, config: DepthCameraConfig, body_from_camera: Isometry3, noise: DepthNoiseModel) -> SimResult<()> {
        self.check_sensor_name(name)?;
        validate_mounting("body_from_camera", &body_from_camera)?;
        noise.validate()?;
        let camera = DepthCamera::new(config)?;
        let rng = Xoshiro256PlusPlus::seed_from_u64(self.streams.next_u64());
        self.cameras.push(MountedCamera { name: name.to_owned(), camera, body_from_camera, noise, rng });
        Ok(())
    }

    /// Mounts a spinning lidar at `body_from_sensor` (sensor frame FLU) with its noise model.
    pub fn add_lidar(&mut self, name: &str, config: LidarConfig, body_from_sensor: Isometry3, noise: LidarNoiseModel) -> SimResult<()> {
        self.check_sensor_name(name)?;
        validate_mounting("body_from_sensor", &body_from_sensor)?;
        noise.validate()?;
        let lidar = Lidar::new(config)?;
        let rng = Xoshiro256PlusPlus::seed_from_u64(self.streams.next_u64());
        self.lidars.push(MountedLidar { name: name.to_owned(), lidar, body_from_sensor, noise, rng });
        Ok(())
    }

    /// Renders depth frames on this many threads (0 or 1: the calling thread). The
    /// frames are identical whatever the count.
    pub fn set_render_threads(&mut self, threads: usize) {
        self.render_threads = threads;
    }

    /// Sets where the run succeeds. A region must exist in the world
    /// ([`SimError::Unknown`] lists the known ones); a point goal needs a finite centre
    /// and a radius > 0.
    pub fn set_goal(&mut self, goal: Goal) -> SimResult<()> {
        let area = match &goal {
            Goal::Region(name) => {
                let region = self.world.region(name).ok_or_else(|| {
                    let known: Vec<&str> = self.world.spec().regions.iter().map(|r| r.name.as_str()).collect();
                    SimError::Unknown { what: "region".into(), name: name.clone(), known: if known.is_empty() { "(none)".into() } else { known.join(", ") } }
                })?;
                GoalArea { centre: DVec3::from_array(region.centre), radius_m: region.radius, cylinder: true }
            }
            Goal::Point { centre, radius_m } => {
                if !centre.is_finite() {
                    return Err(SimError::input("goal.centre", "must be finite"));
                }
                if !(radius_m.is_finite() && *radius_m > 0.0) {
                    return Err(SimError::input("goal.radius_m", format!("must be finite and > 0, got {radius_m}")));
                }
                GoalArea { centre: *centre, radius_m: *radius_m, cylinder: false }
            }
        };
        self.goal = Some(area);
        Ok(())
    }

    /// Ends the run with a timeout once the time reaches `limit_s` [s] (`None`: no limit).
    pub fn set_time_limit(&mut self, limit_s: Option<f64>) -> SimResult<()> {
        if let Some(t) = limit_s {
            if !(t.is_finite() && t > 0.0) {
                return Err(SimError::input("limit_s", format!("must be finite and > 0, got {t}")));
            }
        }
        self.time_limit_s = limit_s;
        Ok(())
    }

    /// Whether a collision ends the run (default `true`). With `false` the vehicle goes
    /// on through the obstacle and every new contact counts in [`RunMetrics::collisions`].
    pub fn set_stop_on_collision(&mut self, stop: bool) {
        self.stop_on_collision = stop;
    }

    /// Ends a running run with the caller's cause (`local_minimum`, ...), which becomes
    /// [`RunMetrics::failure`]. No effect on a run already over.
    pub fn abort(&mut self, cause: &str) {
        if self.status.is_running() {
            self.status = RunStatus::Aborted(cause.to_owned());
        }
    }

    /// Renders every sensor at the current true pose and applies its noise with its own
    /// seeded stream; adds the odometry (with its drift, if configured) and the truth.
    pub fn observe(&mut self) -> Observation {
        let world_from_body = self.vehicle.world_from_body();
        let mut depth = Vec::with_capacity(self.cameras.len());
        for mounted in &mut self.cameras {
            let world_from_camera = world_from_body.compose(&mounted.body_from_camera);
            let truth = if self.render_threads > 1 {
                mounted.camera.render_parallel(&self.world, &world_from_camera, self.render_threads)
            } else {
                mounted.camera.render(&self.world, &world_from_camera)
            };
            let depth_m = mounted.noise.apply(&truth, &self.world, mounted.camera.config(), &mut mounted.rng);
            let c = mounted.camera.config().camera;
            depth.push(DepthObservation { name: mounted.name.clone(), width: c.width, height: c.height, depth_m, truth, world_from_camera });
        }
        let mut scans = Vec::with_capacity(self.lidars.len());
        for mounted in &mut self.lidars {
            let world_from_sensor = world_from_body.compose(&mounted.body_from_sensor);
            let truth = mounted.lidar.scan(&self.world, &world_from_sensor);
            let scan = mounted.noise.apply(&truth, &mut mounted.rng);
            scans.push(LidarObservation { name: mounted.name.clone(), scan, truth, world_from_sensor });
        }
        let odometry = self.vehicle.odometry(&mut self.odometry_rng);
        Observation { time_s: self.time_s, depth, scans, world_from_body, velocity_world: self.vehicle.velocity_world(), odometry }
    }

    /// Advances the vehicle by `dt_s` [s] under `cmd` and records the step with the
    /// controller's compute time `compute_time_s` [s]. A quadrotor uses every component;
    /// a ground robot drives with `v = cmd.v_x_m_s`, `ω = cmd.yaw_rate_rad_s` and ignores
    /// `v_y`, `v_z`. Then: collision and failures (a collision ends the run unless
    /// [`Self::set_stop_on_collision`] says otherwise; fall, rollover and leaving the
    /// world always do), the goal, the time limit.
    ///
    /// Clearance: quadrotor — distance from its sphere to the nearest solid, floor
    /// included (negative when penetrating); ground robot — distance from its body box to
    /// the nearest obstacle in its body plane, ground excluded, capped at 5 m, 0 in collision.
    ///
    /// Errors ([`SimError::InvalidInput`]): a non-finite command component (`cmd.v_x_m_s`,
    /// ...), `dt_s` not finite, not > 0 or beyond 60 s, `compute_time_s` not finite or < 0,
    /// or a run that has already ended (`step`).
    pub fn step(&mut self, cmd: &BodyVelocityCommand, dt_s: f64, compute_time_s: f64) -> SimResult<StepOutcome> {
        cmd.validate("cmd")?;
        if !(dt_s.is_finite() && dt_s > 0.0 && dt_s <= MAX_STEP_S) {
            return Err(SimError::input("dt_s", format!("must be finite, > 0 and <= {MAX_STEP_S} s, got {dt_s}")));
        }
        if !(compute_time_s.is_finite() && compute_time_s >= 0.0) {
            return Err(SimError::input("compute_time_s", format!("must be finite and >= 0, got {compute_time_s}")));
        }
        if !self.status.is_running() {
            return Err(SimError::input("step", format!("the run has already ended ({:?}); read metrics() or start a new simulation", self.status)));
        }
        let (failure, collided) = match &mut self.vehicle {
            Vehicle::Quadrotor(q) => {
                q.step(cmd, dt_s);
                let collided = q.collided(&self.world);
                (collided.then_some(Failure::Collision), collided)
            }
            Vehicle::Ground(g) => {
                let failure = g.step(cmd.v_x_m_s, cmd.yaw_rate_rad_s, dt_s, &self.world);
                (failure, failure == Some(Failure::Collision))
            }
        };
        self.time_s += dt_s;
        let clearance_m = if collided { self.vehicle.clearance_m(&self.world).min(0.0) } else { self.vehicle.clearance_m(&self.world) };
        let position = self.vehicle.position();
        self.status = match failure {
            Some(Failure::Collision) if self.stop_on_collision => RunStatus::Failed(Failure::Collision),
            Some(f @ (Failure::Fall | Failure::Rollover | Failure::OutOfWorld)) => RunStatus::Failed(f),
            _ if self.goal.is_some_and(|g| g.contains(position)) => RunStatus::GoalReached,
            _ if self.time_limit_s.is_some_and(|t| self.time_s >= t) => RunStatus::TimedOut,
            _ => RunStatus::Running,
        };
        self.metrics.record(self.time_s, position, clearance_m, collided, Some(compute_time_s));
        Ok(StepOutcome { time_s: self.time_s, status: self.status.clone(), collided, clearance_m, failure })
    }

    /// The run's metrics so far (success = goal reached; failure = the status's cause).
    pub fn metrics(&self) -> RunMetrics {
        self.metrics.finish(self.status == RunStatus::GoalReached, self.status.failure_cause())
    }

    /// Simulation time [s].
    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    /// Where the run stands.
    pub fn status(&self) -> &RunStatus {
        &self.status
    }

    /// The world.
    pub fn world(&self) -> &World {
        &self.world
    }

    /// The vehicle and its true state.
    pub fn vehicle(&self) -> &Vehicle {
        &self.vehicle
    }

    /// The seed of the run.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Names of the mounted depth cameras, then of the lidars, in the order they were added.
    pub fn sensor_names(&self) -> Vec<&str> {
        self.cameras.iter().map(|c| c.name.as_str()).chain(self.lidars.iter().map(|l| l.name.as_str())).collect()
    }
}

/// Checks a sensor mounting: finite, and a proper rotation.
fn validate_mounting(argument: &str, t: &Isometry3) -> SimResult<()> {
    let m = t.rotation;
    if !(m.is_finite() && t.translation.is_finite()) {
        return Err(SimError::input(argument, "contains NaN or infinity"));
    }
    let err = (m.transpose() * m - DMat3::IDENTITY).abs().to_cols_array().into_iter().fold(0.0_f64, f64::max);
    if err > ROTATION_TOLERANCE || (m.determinant() - 1.0).abs() > ROTATION_TOLERANCE {
        return Err(SimError::input(argument, format!("rotation is not proper (|RᵀR - I| = {err:.2e}, det = {:.6})", m.determinant())));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mounting_validation() {
        assert!(validate_mounting("body_from_camera", &Isometry3::body_from_forward_optical()).is_ok());
        let mut t = Isometry3::IDENTITY;
        t.rotation.x_axis.x = 2.0;
        assert!(matches!(validate_mounting("body_from_camera", &t), Err(SimError::InvalidInput { argument, .. }) if argument == "body_from_camera"));
        let mut t = Isometry3::IDENTITY;
        t.translation.y = f64::NAN;
        assert!(validate_mounting("body_from_sensor", &t).is_err());
    }

    #[test]
    fn goal_areas() {
        let cyl = GoalArea { centre: DVec3::new(1.0, 1.0, 0.0), radius_m: 0.5, cylinder: true };
        assert!(cyl.contains(DVec3::new(1.3, 1.4, 7.0)));
        assert!(!cyl.contains(DVec3::new(1.3, 1.41, 0.0)));
        let ball = GoalArea { centre: DVec3::ZERO, radius_m: 1.0, cylinder: false };
        assert!(ball.contains(DVec3::new(0.6, 0.0, 0.8)));
        assert!(!ball.contains(DVec3::new(0.0, 0.0, 1.01)));
    }

    #[test]
    fn status_causes() {
        assert_eq!(RunStatus::Failed(Failure::OutOfWorld).failure_cause().as_deref(), Some("out_of_world"));
        assert_eq!(RunStatus::TimedOut.failure_cause().as_deref(), Some("timeout"));
        assert_eq!(RunStatus::GoalReached.failure_cause(), None);
        assert!(!RunStatus::Aborted("local_minimum".into()).is_running());
    }
}
