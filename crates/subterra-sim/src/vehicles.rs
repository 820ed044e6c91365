//! Vehicles: a quadrotor that tracks body-frame velocity commands, and a unicycle ground
//! robot settled on the terrain every step.
//!
//! In: a [`BodyVelocityCommand`] (FLU body frame: x forward, y left, z up; yaw about the
//! world z axis) and a time step; for the ground robot also the [`World`] it drives on.
//! Out: the true state, its `world_from_body` pose, odometry (optionally drifting, see
//! [`OdometryNoise`]) and, for the ground robot, a [`Failure`] when it collides, rolls
//! over, falls or leaves the world.
//!
//! **Quadrotor.** Velocity and yaw rate follow the clipped command with a first-order lag
//! of time constant τ, integrated exactly over a step of length `dt`:
//! `v(t + dt) = u + (v(t) - u)·e^{-dt/τ}`, `p(t + dt) = p(t) + u·dt + (v(t) - u)·τ·(1 - e^{-dt/τ})`
//! (same for the yaw rate and the yaw). The body command is rotated into the world by the
//! yaw at the middle of the step and held over the step. Roll and pitch are not simulated:
//! the body frame is gravity-aligned, rotated by the yaw only. The collision shape is a
//! sphere of radius 0.27 m (540 mm frame) around the body origin.
//!
//! **Ground robot.** A unicycle `(x, y, ψ)` driven by `(v, ω)` (limits, optional
//! acceleration limits), integrated exactly for constant `(v, ω)` over sub-steps of at
//! most 5 cm / 0.05 rad. After each sub-step the footprint is **settled** on the terrain
//! (see [`GroundRobot::settle`]): the ground height under a 5 x 3 grid of footprint points
//! (corners, edge midpoints, centre, quarter points) comes from [`World::ground_height`],
//! and the contact plane is the **resting plane** — the plane on or above every sample
//! that is lowest under the footprint's centre (the facet of the samples' upper convex
//! hull above the centre: the chassis rests on its three highest supports around its
//! centre of mass). It gives the height `z`, roll and pitch (ZYX Euler angles, REP 103:
//! **nose up is negative pitch**, left side up is positive roll). Failures, checked in
//! this order: [`Failure::OutOfWorld`] (no ground under any sample), [`Failure::Fall`]
//! (a sample over a hole, or an **overhanging** sample more than `max_drop_m` below both
//! the contact plane and the lowest supporting sample: part of the footprint sticks out over
//! a drop deeper than the clearance; a low sample inside the convex hull of the supporting
//! samples is bridged — the robot spans a valley or a ditch — and is not a fall, nor is a
//! wheel lifted off ground no lower than the supports, as when one front corner climbs the
//! foot of a ramp first), [`Failure::Rollover`] (|roll| or |pitch|
//! beyond the limits), [`Failure::Collision`] (the terrain under a sample rose more than
//! `max_step_m` above the previous contact plane in one sub-step — the body ran into a
//! ledge — or a solid lies inside the body box above the ground clearance, see
//! [`GroundRobot::body_collision`]).
//!
//! Collisions are detected, not resolved: the vehicle moves on; the simulation decides
//! whether a collision ends the run.

use std::f64::consts::PI;

use glam::{DMat3, DVec2, DVec3};
use rand::Rng;
use serde::{Deserialize, Serialize};
use subterra::Isometry3;

use crate::error::{SimError, SimResult};
use crate::world::World;

/// Quadrotor velocity time constant τ [s]: a velocity-controlled multirotor reaches 63 %
/// of a commanded velocity step in about 0.2 s (typical PX4 velocity-loop response).
pub const QUADROTOR_TIME_CONSTANT_S: f64 = 0.2;
/// Quadrotor horizontal speed limit per axis [m/s]: APF-PF `flight` preset v_x,max
/// (paper §V-B, authors' apf_acc.yaml); v_y is limited like v_x.
pub const QUADROTOR_V_XY_MAX_M_S: f64 = 0.6;
/// Quadrotor vertical speed limit [m/s]: APF-PF `flight` preset v_z,max.
pub const QUADROTOR_V_Z_MAX_M_S: f64 = 0.6;
/// Quadrotor yaw-rate limit [rad/s]: APF-PF `flight` preset ψ̇_max.
pub const QUADROTOR_YAW_RATE_MAX_RAD_S: f64 = 1.0;
/// Quadrotor collision-sphere radius [m]: half the 540 mm frame (issue 3).
pub const QUADROTOR_RADIUS_M: f64 = 0.27;

/// Ground robot footprint length along body x [m] (Clearpath Husky).
pub const HUSKY_LENGTH_M: f64 = 0.99;
/// Ground robot footprint width along body y [m] (Husky).
pub const HUSKY_WIDTH_M: f64 = 0.67;
/// Ground robot height above the contact plane [m] (Husky).
pub const HUSKY_HEIGHT_M: f64 = 0.4;
/// Ground robot ground clearance [m] (Husky).
pub const HUSKY_CLEARANCE_M: f64 = 0.13;
/// Ground robot speed limit [m/s] (Husky data sheet).
pub const HUSKY_V_MAX_M_S: f64 = 1.0;
/// Ground robot yaw-rate limit [rad/s] (Husky's `husky_control` angular velocity limit).
pub const HUSKY_YAW_RATE_MAX_RAD_S: f64 = 2.0;
/// Rollover limit on |roll| and |pitch| [deg]. The static tip-over angle of a Husky-like
/// base (track ≈ 0.55 m, centre of mass ≈ 0.25 m above the contact plane) is about 45-50°;
/// 35° keeps a margin for bumps and wheel slip, and lies above the mapper's lethal tilt
/// (25°), so a mapper that works never lets the robot get there.
pub const ROLLOVER_LIMIT_DEG: f64 = 35.0;

/// Longest ground-robot sub-step travel [m]: settle and failure checks run at least this often.
const SUBSTEP_MAX_TRAVEL_M: f64 = 0.05;
/// Largest ground-robot sub-step rotation [rad] (corners move at most ~3 cm).
const SUBSTEP_MAX_TURN_RAD: f64 = 0.05;
/// Longest step accepted by the vehicles [s]; longer (or non-positive) steps are ignored.
pub const MAX_STEP_S: f64 = 60.0;
/// Footprint samples along body x (rear edge, quarter, centre, quarter, front edge).
const FOOTPRINT_SAMPLES_X: usize = 5;
/// Footprint samples along body y (right edge, centre line, left edge).
const FOOTPRINT_SAMPLES_Y: usize = 3;
/// Tolerance of the resting-plane test "every sample on or below the plane" [m].
const PLANE_TOLERANCE_M: f64 = 1e-9;
/// A footprint sample within this of the contact plane supports the robot [m].
const SUPPORT_TOLERANCE_M: f64 = 1e-6;
/// Largest side of a coarse collision cell [m]; small enough that the cell's
/// circumscribed sphere stays clear of the ground on level terrain.
const COLLISION_COARSE_CELL_M: f64 = 0.25;
/// Largest radius of a fine collision probe ball [m].
const COLLISION_FINE_RADIUS_MAX_M: f64 = 0.075;
/// Horizontal rays of the ground robot's clearance probe (one every 10°).
const CLEARANCE_PROBE_RAYS: usize = 36;
/// Range of the ground robot's clearance probe [m]; the reported clearance is capped here.
pub const CLEARANCE_PROBE_RANGE_M: f64 = 5.0;
/// A ray hit whose normal has a z component above this is ground, not an obstacle.
const GROUND_NORMAL_Z: f64 = 0.7;

/// A velocity command in the body frame (FLU) with a yaw rate about the world z axis.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct BodyVelocityCommand {
    /// Forward velocity [m/s].
    pub v_x_m_s: f64,
    /// Leftward velocity [m/s] (holonomic mode; a ground robot ignores it).
    pub v_y_m_s: f64,
    /// Upward velocity [m/s] (a ground robot ignores it).
    pub v_z_m_s: f64,
    /// Yaw rate, counter-clockwise seen from above [rad/s].
    pub yaw_rate_rad_s: f64,
}

impl BodyVelocityCommand {
    /// Zero velocity: hover / stand still.
    pub const ZERO: Self = Self { v_x_m_s: 0.0, v_y_m_s: 0.0, v_z_m_s: 0.0, yaw_rate_rad_s: 0.0 };

    /// A command from its four components [m/s, m/s, m/s, rad/s].
    pub fn new(v_x_m_s: f64, v_y_m_s: f64, v_z_m_s: f64, yaw_rate_rad_s: f64) -> Self {
        Self { v_x_m_s, v_y_m_s, v_z_m_s, yaw_rate_rad_s }
    }

    /// Checks that every component is finite; the error names `argument.component`.
    pub fn validate(&self, argument: &str) -> SimResult<()> {
        for (name, value) in self.components() {
            if !value.is_finite() {
                return Err(SimError::input(format!("{argument}.{name}"), format!("must be finite, got {value}")));
            }
        }
        Ok(())
    }

    /// The components with their field names.
    fn components(&self) -> [(&'static str, f64); 4] {
        [
            ("v_x_m_s", self.v_x_m_s),
            ("v_y_m_s", self.v_y_m_s),
            ("v_z_m_s", self.v_z_m_s),
            ("yaw_rate_rad_s", self.yaw_rate_rad_s),
        ]
    }

    /// Non-finite components replaced by zero (a vehicle never integrates a NaN).
    fn sanitised(&self) -> Self {
        let f = |x: f64| if x.is_finite() { x } else { 0.0 };
        Self::new(f(self.v_x_m_s), f(self.v_y_m_s), f(self.v_z_m_s), f(self.yaw_rate_rad_s))
    }
}

/// Why a ground robot's run ended (or, for [`Failure::Collision`], what it hit).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Failure {
    /// A solid (an obstacle, or terrain rising above the ground clearance) intersects the body.
    Collision,
    /// |roll| or |pitch| beyond the rollover limit.
    Rollover,
    /// Part of the footprint over a hole or a drop deeper than the clearance.
    Fall,
    /// No ground under the footprint at all.
    OutOfWorld,
}

impl Failure {
    /// Lower-case name used in metrics: `collision`, `rollover`, `fall`, `out_of_world`.
    pub fn as_str(&self) -> &'static str {
        match self {
            Self::Collision => "collision",
            Self::Rollover => "rollover",
            Self::Fall => "fall",
            Self::OutOfWorld => "out_of_world",
        }
    }
}

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Odometry drift: a random-walk bias added to the true position (each axis) and yaw.
/// After `t` seconds the bias has standard deviation `walk·√t` per axis.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OdometryNoise {
    /// Position random-walk intensity [m/√s] (per axis).
    pub position_walk_m_per_sqrt_s: f64,
    /// Yaw random-walk intensity [rad/√s].
    pub yaw_walk_rad_per_sqrt_s: f64,
}

impl OdometryNoise {
    /// Checks both intensities are finite and >= 0; errors name `prefix.field`.
    pub fn validate(&self, prefix: &str) -> SimResult<()> {
        require_non_negative(&format!("{prefix}.position_walk_m_per_sqrt_s"), self.position_walk_m_per_sqrt_s)?;
        require_non_negative(&format!("{prefix}.yaw_walk_rad_per_sqrt_s"), self.yaw_walk_rad_per_sqrt_s)
    }
}

/// The drifting odometry of one vehicle: the bias of [`OdometryNoise`] and the time not
/// yet folded into it. Odometry = truth with `bias_position_m` added to the position,
/// the body rotated by `bias_yaw_rad` about world z and the velocity rotated likewise.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct OdometryDrift {
    /// The noise intensities; `None`: odometry equals the truth and draws nothing.
    pub noise: Option<OdometryNoise>,
    /// Current position bias [m].
    pub bias_position_m: DVec3,
    /// Current yaw bias [rad].
    pub bias_yaw_rad: f64,
    /// Time elapsed since the bias was last drawn [s].
    pending_s: f64,
}

impl OdometryDrift {
    /// A drift with zero bias.
    pub fn new(noise: Option<OdometryNoise>) -> Self {
        Self { noise, ..Self::default() }
    }

    /// Lets `dt_s` seconds pass (the bias walks over them at the next [`Self::advance`]).
    pub fn elapse(&mut self, dt_s: f64) {
        if dt_s.is_finite() && dt_s > 0.0 {
            self.pending_s += dt_s;
        }
    }

    /// Draws the random walk over the elapsed time: each bias component gets a Gaussian
    /// increment of standard deviation `walk·√elapsed`. Draws nothing without noise or
    /// when no time has passed.
    pub fn advance<R: Rng + ?Sized>(&mut self, rng: &mut R) {
        let Some(noise) = self.noise else { return };
        if self.pending_s <= 0.0 {
            return;
        }
        let scale = self.pending_s.sqrt();
        self.pending_s = 0.0;
        let sp = noise.position_walk_m_per_sqrt_s * scale;
        self.bias_position_m += DVec3::new(standard_normal(rng), standard_normal(rng), standard_normal(rng)) * sp;
        self.bias_yaw_rad += standard_normal(rng) * noise.yaw_walk_rad_per_sqrt_s * scale;
    }

    /// The odometry `(world_from_body, velocity_world)` of a true pose and velocity.
    pub fn apply(&self, world_from_body: &Isometry3, velocity_world: DVec3) -> (Isometry3, DVec3) {
        let r = DMat3::from_rotation_z(self.bias_yaw_rad);
        let pose = Isometry3 { rotation: r * world_from_body.rotation, translation: world_from_body.translation + self.bias_position_m };
        (pose, r * velocity_world)
    }
}

/// A standard normal draw (Box-Muller, one of the pair; 53-bit uniforms).
pub(crate) fn standard_normal<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    // u1 in (0, 1], u2 in [0, 1).
    let u1 = ((rng.next_u64() >> 11) as f64 + 1.0) * (1.0 / (1u64 << 53) as f64);
    let u2 = (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
    (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
}

/// Wraps an angle to (-π, π] [rad].
pub fn wrap_angle(angle_rad: f64) -> f64 {
    let a = (angle_rad + PI).rem_euclid(2.0 * PI) - PI;
    if a <= -PI {
        a + 2.0 * PI
    } else {
        a
    }
}

fn require_positive(field: &str, value: f64) -> SimResult<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(SimError::config(field, "must be finite and > 0", value))
    }
}

fn require_non_negative(field: &str, value: f64) -> SimResult<()> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(SimError::config(field, "must be finite and >= 0", value))
    }
}

fn step_is_valid(dt_s: f64) -> bool {
    dt_s.is_finite() && dt_s > 0.0 && dt_s <= MAX_STEP_S
}

/// `∫_0^t e^{-s/τ} ds = τ·(1 - e^{-t/τ})` [s]; `0` lag (τ = 0) gives 0.
fn lag_integral(t_s: f64, tau_s: f64) -> f64 {
    if tau_s > 0.0 {
        -tau_s * (-t_s / tau_s).exp_m1()
    } else {
        0.0
    }
}

/// `e^{-t/τ}`; 0 for τ = 0 (no lag).
fn lag_decay(t_s: f64, tau_s: f64) -> f64 {
    if tau_s > 0.0 {
        (-t_s / tau_s).exp()
    } else {
        0.0
    }
}

// ---------------------------------------------------------------------------------------
// Quadrotor
// ---------------------------------------------------------------------------------------

/// Quadrotor dynamics and shape.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct QuadrotorConfig {
    /// Time constant τ of the first-order lag of velocity and yaw rate [s]; 0 = no lag.
    pub time_constant_s: f64,
    /// Limit on |v_x| and |v_y| (each axis) [m/s].
    pub v_xy_max_m_s: f64,
    /// Limit on |v_z| [m/s].
    pub v_z_max_m_s: f64,
    /// Limit on |yaw rate| [rad/s].
    pub yaw_rate_max_rad_s: f64,
    /// Collision-sphere radius [m].
    pub radius_m: f64,
    /// Odometry drift; `None`: odometry is the truth.
    pub odometry_noise: Option<OdometryNoise>,
}

impl Default for QuadrotorConfig {
    fn default() -> Self {
        Self {
            time_constant_s: QUADROTOR_TIME_CONSTANT_S,
            v_xy_max_m_s: QUADROTOR_V_XY_MAX_M_S,
            v_z_max_m_s: QUADROTOR_V_Z_MAX_M_S,
            yaw_rate_max_rad_s: QUADROTOR_YAW_RATE_MAX_RAD_S,
            radius_m: QUADROTOR_RADIUS_M,
            odometry_noise: None,
        }
    }
}

impl QuadrotorConfig {
    /// Checks every field; errors name `quadrotor.<field>`.
    pub fn validate(&self) -> SimResult<()> {
        require_non_negative("quadrotor.time_constant_s", self.time_constant_s)?;
        require_positive("quadrotor.v_xy_max_m_s", self.v_xy_max_m_s)?;
        require_positive("quadrotor.v_z_max_m_s", self.v_z_max_m_s)?;
        require_positive("quadrotor.yaw_rate_max_rad_s", self.yaw_rate_max_rad_s)?;
        require_positive("quadrotor.radius_m", self.radius_m)?;
        if let Some(noise) = &self.odometry_noise {
            noise.validate("quadrotor.odometry_noise")?;
        }
        Ok(())
    }
}

/// The true state of a quadrotor (world frame ENU).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct QuadrotorState {
    /// Position of the body origin [m].
    pub position: DVec3,
    /// Yaw about world z, in (-π, π] [rad].
    pub yaw_rad: f64,
    /// Velocity in the world frame [m/s].
    pub velocity_world: DVec3,
    /// Yaw rate [rad/s].
    pub yaw_rate_rad_s: f64,
}

impl QuadrotorState {
    /// At rest at `position` [m] with heading `yaw_rad` [rad].
    pub fn at_rest(position: DVec3, yaw_rad: f64) -> Self {
        Self { position, yaw_rad, velocity_world: DVec3::ZERO, yaw_rate_rad_s: 0.0 }
    }

    /// Checks that every value is finite; errors name `argument.field`.
    pub fn validate(&self, argument: &str) -> SimResult<()> {
        let finite = |v: DVec3| v.is_finite();
        if !finite(self.position) {
            return Err(SimError::input(format!("{argument}.position"), "must be finite"));
        }
        if !self.yaw_rad.is_finite() {
            return Err(SimError::input(format!("{argument}.yaw_rad"), "must be finite"));
        }
        if !finite(self.velocity_world) {
            return Err(SimError::input(format!("{argument}.velocity_world"), "must be finite"));
        }
        if !self.yaw_rate_rad_s.is_finite() {
            return Err(SimError::input(format!("{argument}.yaw_rate_rad_s"), "must be finite"));
        }
        Ok(())
    }
}

/// A quadrotor tracking body-frame velocity commands (see the module documentation).
#[derive(Debug, Clone, PartialEq)]
pub struct Quadrotor {
    config: QuadrotorConfig,
    state: QuadrotorState,
    drift: OdometryDrift,
}

impl Quadrotor {
    /// A quadrotor in state `initial` (its yaw wrapped to (-π, π]).
    pub fn new(config: QuadrotorConfig, initial: QuadrotorState) -> SimResult<Self> {
        config.validate()?;
        initial.validate("initial")?;
        let mut state = initial;
        state.yaw_rad = wrap_angle(state.yaw_rad);
        Ok(Self { config, state, drift: OdometryDrift::new(config.odometry_noise) })
    }

    /// The configuration.
    pub fn config(&self) -> &QuadrotorConfig {
        &self.config
    }

    /// The true state.
    pub fn state(&self) -> &QuadrotorState {
        &self.state
    }

    /// The command after the limits: each component clipped to its limit; non-finite
    /// components become 0.
    pub fn limited(&self, cmd: &BodyVelocityCommand) -> BodyVelocityCommand {
        let c = cmd.sanitised();
        let clip = |x: f64, m: f64| x.clamp(-m, m);
        BodyVelocityCommand::new(
            clip(c.v_x_m_s, self.config.v_xy_max_m_s),
            clip(c.v_y_m_s, self.config.v_xy_max_m_s),
            clip(c.v_z_m_s, self.config.v_z_max_m_s),
            clip(c.yaw_rate_rad_s, self.config.yaw_rate_max_rad_s),
        )
    }

    /// Advances by `dt_s` seconds toward the (limited) command with the first-order lag,
    /// integrated exactly (module documentation). A `dt_s` that is not finite, not > 0 or
    /// beyond [`MAX_STEP_S`] leaves the state unchanged ([`crate::simulation::Simulation`]
    /// reports it as an error); non-finite command components count as 0.
    pub fn step(&mut self, cmd: &BodyVelocityCommand, dt_s: f64) {
        if !step_is_valid(dt_s) {
            return;
        }
        let cmd = self.limited(cmd);
        let tau = self.config.time_constant_s;
        let s = self.state;
        let r_cmd = cmd.yaw_rate_rad_s;
        let yaw_at = |t: f64| s.yaw_rad + r_cmd * t + (s.yaw_rate_rad_s - r_cmd) * lag_integral(t, tau);
        let yaw_mid = yaw_at(0.5 * dt_s);
        let target = DMat3::from_rotation_z(yaw_mid) * DVec3::new(cmd.v_x_m_s, cmd.v_y_m_s, cmd.v_z_m_s);
        let decay = lag_decay(dt_s, tau);
        let integral = lag_integral(dt_s, tau);
        self.state = QuadrotorState {
            position: s.position + target * dt_s + (s.velocity_world - target) * integral,
            yaw_rad: wrap_angle(yaw_at(dt_s)),
            velocity_world: target + (s.velocity_world - target) * decay,
            yaw_rate_rad_s: r_cmd + (s.yaw_rate_rad_s - r_cmd) * decay,
        };
        self.drift.elapse(dt_s);
    }

    /// The true pose: translation = position, rotation = yaw about world z.
    pub fn world_from_body(&self) -> Isometry3 {
        Isometry3 { rotation: DMat3::from_rotation_z(self.state.yaw_rad), translation: self.state.position }
    }

    /// Distance from the collision sphere to the nearest solid [m]: `world.clearance(position) - radius`
    /// (negative when penetrating; floors and walls count).
    pub fn clearance_m(&self, world: &World) -> f64 {
        world.clearance(self.state.position) - self.config.radius_m
    }

    /// Whether the collision sphere intersects a solid: `world.clearance(position) < radius`.
    pub fn collided(&self, world: &World) -> bool {
        world.clearance(self.state.position) < self.config.radius_m
    }

    /// Odometry `(world_from_body, velocity_world)`: the truth, or with the drift of
    /// [`QuadrotorConfig::odometry_noise`] walked over the time since the last call
    /// (draws from `rng` only when drift is configured).
    pub fn odometry<R: Rng + ?Sized>(&mut self, rng: &mut R) -> (Isometry3, DVec3) {
        self.drift.advance(rng);
        self.drift.apply(&self.world_from_body(), self.state.velocity_world)
    }

    /// The drift state of the odometry.
    pub fn odometry_drift(&self) -> &OdometryDrift {
        &self.drift
    }
}

// ---------------------------------------------------------------------------------------
// Ground robot
// ---------------------------------------------------------------------------------------

/// Ground robot geometry, limits and failure thresholds (defaults: Clearpath Husky-like).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GroundRobotConfig {
    /// Footprint length along body x [m].
    pub length_m: f64,
    /// Footprint width along body y [m].
    pub width_m: f64,
    /// Height of the body top above the contact plane [m].
    pub height_m: f64,
    /// Ground clearance: the body box spans `ground_clearance_m..height_m` above the contact plane [m].
    pub ground_clearance_m: f64,
    /// Limit on |v| [m/s].
    pub v_max_m_s: f64,
    /// Limit on |ω| [rad/s].
    pub yaw_rate_max_rad_s: f64,
    /// Limit on |dv/dt| [m/s²]; `None`: the speed follows the command at once.
    pub accel_max_m_s2: Option<f64>,
    /// Limit on |dω/dt| [rad/s²]; `None`: the yaw rate follows the command at once.
    pub yaw_accel_max_rad_s2: Option<f64>,
    /// Rollover when |roll| exceeds this [rad] (default 35°, see [`ROLLOVER_LIMIT_DEG`]).
    pub rollover_roll_rad: f64,
    /// Rollover when |pitch| exceeds this [rad] (default 35°).
    pub rollover_pitch_rad: f64,
    /// Fall when a footprint sample lies more than this below the contact plane [m] (= clearance).
    pub max_drop_m: f64,
    /// Collision when the terrain under a sample rises more than this above the previous
    /// contact plane within one sub-step (a ledge) [m] (= clearance).
    pub max_step_m: f64,
    /// Odometry drift; `None`: odometry is the truth.
    pub odometry_noise: Option<OdometryNoise>,
}

impl Default for GroundRobotConfig {
    fn default() -> Self {
        Self {
            length_m: HUSKY_LENGTH_M,
            width_m: HUSKY_WIDTH_M,
            height_m: HUSKY_HEIGHT_M,
            ground_clearance_m: HUSKY_CLEARANCE_M,
            v_max_m_s: HUSKY_V_MAX_M_S,
            yaw_rate_max_rad_s: HUSKY_YAW_RATE_MAX_RAD_S,
            accel_max_m_s2: None,
            yaw_accel_max_rad_s2: None,
            rollover_roll_rad: ROLLOVER_LIMIT_DEG.to_radians(),
            rollover_pitch_rad: ROLLOVER_LIMIT_DEG.to_radians(),
            max_drop_m: HUSKY_CLEARANCE_M,
            max_step_m: HUSKY_CLEARANCE_M,
            odometry_noise: None,
        }
    }
}

impl GroundRobotConfig {
    /// Checks every field; errors name `ground_robot.<field>`.
    pub fn validate(&self) -> SimResult<()> {
        require_positive("ground_robot.length_m", self.length_m)?;
        require_positive("ground_robot.width_m", self.width_m)?;
        require_positive("ground_robot.height_m", self.height_m)?;
        require_non_negative("ground_robot.ground_clearance_m", self.ground_clearance_m)?;
        if self.ground_clearance_m >= self.height_m {
            return Err(SimError::config("ground_robot.ground_clearance_m", format!("must be < height_m = {}", self.height_m), self.ground_clearance_m));
        }
        require_positive("ground_robot.v_max_m_s", self.v_max_m_s)?;
        require_positive("ground_robot.yaw_rate_max_rad_s", self.yaw_rate_max_rad_s)?;
        if let Some(a) = self.accel_max_m_s2 {
            require_positive("ground_robot.accel_max_m_s2", a)?;
        }
        if let Some(a) = self.yaw_accel_max_rad_s2 {
            require_positive("ground_robot.yaw_accel_max_rad_s2", a)?;
        }
        for (field, value) in [("ground_robot.rollover_roll_rad", self.rollover_roll_rad), ("ground_robot.rollover_pitch_rad", self.rollover_pitch_rad)] {
            if !(value.is_finite() && value > 0.0 && value < 0.5 * PI) {
                return Err(SimError::config(field, "must be in (0, π/2) rad", value));
            }
        }
        require_positive("ground_robot.max_drop_m", self.max_drop_m)?;
        require_positive("ground_robot.max_step_m", self.max_step_m)?;
        if let Some(noise) = &self.odometry_noise {
            noise.validate("ground_robot.odometry_noise")?;
        }
        Ok(())
    }
}

/// The planar state of a ground robot (its height, roll and pitch come from [`Settle`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct GroundRobotState {
    /// World x of the footprint centre [m].
    pub x_m: f64,
    /// World y of the footprint centre [m].
    pub y_m: f64,
    /// Heading about world z, in (-π, π] [rad].
    pub yaw_rad: f64,
    /// Forward speed [m/s].
    pub v_m_s: f64,
    /// Yaw rate [rad/s].
    pub yaw_rate_rad_s: f64,
}

impl GroundRobotState {
    /// At rest at `(x_m, y_m)` [m] heading `yaw_rad` [rad].
    pub fn at_rest(x_m: f64, y_m: f64, yaw_rad: f64) -> Self {
        Self { x_m, y_m, yaw_rad, v_m_s: 0.0, yaw_rate_rad_s: 0.0 }
    }

    /// Checks that every value is finite; errors name `argument.field`.
    pub fn validate(&self, argument: &str) -> SimResult<()> {
        for (name, value) in [("x_m", self.x_m), ("y_m", self.y_m), ("yaw_rad", self.yaw_rad), ("v_m_s", self.v_m_s), ("yaw_rate_rad_s", self.yaw_rate_rad_s)] {
            if !value.is_finite() {
                return Err(SimError::input(format!("{argument}.{name}"), format!("must be finite, got {value}")));
            }
        }
        Ok(())
    }
}

/// The footprint settled on the terrain: the contact plane under the robot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settle {
    /// Height of the contact plane under the footprint centre: the body origin's z [m].
    pub z_m: f64,
    /// Roll (rotation about body x; left side up is positive) [rad].
    pub roll_rad: f64,
    /// Pitch (rotation about body y; REP 103: nose **down** is positive) [rad].
    pub pitch_rad: f64,
    /// Slope of the contact plane `(dz/dx, dz/dy)` in the world frame [m/m].
    pub gradient: DVec2,
    /// Deepest footprint sample below the contact plane [m] (0 on a plane).
    pub max_gap_m: f64,
    /// Deepest drop under an overhanging sample [m]: over the samples outside the convex
    /// hull (in x-y) of the supporting samples (those on the plane), the largest of
    /// `min(gap below the plane, lowest support's height - sample's ground height)`. Low
    /// samples inside that hull are bridged (a valley, a ditch under the belly) and do not
    /// count; a lifted wheel over ground as high as the lowest support (one corner on the
    /// foot of a ramp, the other three on the floor) gives 0.
    pub overhang_gap_m: f64,
    /// Footprint samples with ground under them.
    pub samples_on_ground: usize,
    /// Footprint samples over a hole (no ground).
    pub samples_over_hole: usize,
}

impl Settle {
    /// The unit normal of the contact plane (world frame, pointing up).
    pub fn normal(&self) -> DVec3 {
        DVec3::new(-self.gradient.x, -self.gradient.y, 1.0).normalize()
    }

    /// The body rotation `world_from_body` for heading `yaw_rad`: body x along the plane
    /// in the heading direction, body z along the plane normal.
    pub fn rotation(&self, yaw_rad: f64) -> DMat3 {
        let (s, c) = yaw_rad.sin_cos();
        let forward = DVec2::new(c, s);
        let x_b = DVec3::new(c, s, self.gradient.dot(forward)).normalize();
        let z_b = self.normal();
        let y_b = z_b.cross(x_b);
        DMat3::from_cols(x_b, y_b, z_b)
    }

    /// The terrain failure this contact implies, if any: out of world, fall (hole, or an
    /// overhang deeper than `max_drop_m`), rollover — in that order.
    pub fn failure(&self, config: &GroundRobotConfig) -> Option<Failure> {
        if self.samples_on_ground == 0 {
            Some(Failure::OutOfWorld)
        } else if self.samples_over_hole > 0 || self.overhang_gap_m > config.max_drop_m {
            Some(Failure::Fall)
        } else if self.roll_rad.abs() > config.rollover_roll_rad || self.pitch_rad.abs() > config.rollover_pitch_rad {
            Some(Failure::Rollover)
        } else {
            None
        }
    }
}

/// A plane `z = a + b·(x - x0) + c·(y - y0)` around a reference point `(x0, y0)`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ContactPlane {
    origin: DVec2,
    z0: f64,
    gradient: DVec2,
}

impl ContactPlane {
    fn height(&self, xy: DVec2) -> f64 {
        self.z0 + self.gradient.dot(xy - self.origin)
    }
}

/// The resting plane of points `(dx, dy, z)` given relative to the footprint centre: the
/// plane on or above every point whose height at `(0, 0)` is lowest — a linear programme
/// whose optimum is the plane through three of the points (the facet of their upper
/// convex hull above the centre), found by trying every non-collinear triple (15 points:
/// 455 triples). Ties (a centre on a hull edge) go to the least tilted plane. Returns
/// `(z at the centre, gradient)`, or `None` with fewer than three non-collinear points.
pub(crate) fn resting_plane(points: &[DVec3]) -> Option<(f64, DVec2)> {
    let scale = points.iter().map(|p| p.x.abs().max(p.y.abs())).fold(0.0_f64, f64::max).max(1e-9);
    let min_det = 1e-9 * scale * scale;
    let mut best: Option<(f64, DVec2)> = None;
    let n = points.len();
    for i in 0..n {
        for j in (i + 1)..n {
            for k in (j + 1)..n {
                let (p, q, r) = (points[i], points[j], points[k]);
                // Solve z = a + b x + c y through p, q, r.
                let (ux, uy, uz) = (q.x - p.x, q.y - p.y, q.z - p.z);
                let (vx, vy, vz) = (r.x - p.x, r.y - p.y, r.z - p.z);
                let det = ux * vy - uy * vx;
                if det.abs() < min_det {
                    continue;
                }
                let b = (uz * vy - uy * vz) / det;
                let c = (ux * vz - uz * vx) / det;
                let a = p.z - b * p.x - c * p.y;
                let above_all = points.iter().all(|s| s.z <= a + b * s.x + c * s.y + PLANE_TOLERANCE_M);
                if !above_all {
                    continue;
                }
                let g = DVec2::new(b, c);
                let better = match best {
                    None => true,
                    Some((a_best, g_best)) => {
                        a < a_best - PLANE_TOLERANCE_M || (a <= a_best + PLANE_TOLERANCE_M && g.length_squared() < g_best.length_squared())
                    }
                };
                if better {
                    best = Some((a, g));
                }
            }
        }
    }
    best
}

/// The convex hull of 2-D points, counter-clockwise, without collinear vertices
/// (Andrew's monotone chain). Fewer than three distinct points give them back as they are.
pub(crate) fn convex_hull(points: &[DVec2]) -> Vec<DVec2> {
    let mut pts: Vec<DVec2> = points.to_vec();
    pts.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    pts.dedup();
    if pts.len() < 3 {
        return pts;
    }
    let cross = |o: DVec2, a: DVec2, b: DVec2| (a - o).perp_dot(b - o);
    let mut hull: Vec<DVec2> = Vec::with_capacity(2 * pts.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &DVec2>> = if pass == 0 { Box::new(pts.iter()) } else { Box::new(pts.iter().rev()) };
        for &p in iter {
            while hull.len() >= start + 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0 {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    hull
}

/// Whether `p` lies inside or on the boundary of a counter-clockwise convex hull
/// (within 1e-9 m); a hull of fewer than three vertices contains nothing.
pub(crate) fn hull_contains(hull: &[DVec2], p: DVec2) -> bool {
    const TOLERANCE_M: f64 = 1e-9;
    if hull.len() < 3 {
        return false;
    }
    (0..hull.len()).all(|i| {
        let a = hull[i];
        let b = hull[(i + 1) % hull.len()];
        let edge = b - a;
        // Signed distance of p to the left of edge a -> b.
        edge.perp_dot(p - a) / edge.length() >= -TOLERANCE_M
    })
}

/// One cell of the body box above the clearance (body frame): a coarse test sphere and
/// the fine probe balls inside it.
#[derive(Debug, Clone, PartialEq)]
struct CollisionCell {
    centre_body: DVec3,
    half_diagonal_m: f64,
    fine_body: Vec<DVec3>,
}

/// The body box's collision probes: coarse cells, each with fine balls of one radius.
#[derive(Debug, Clone, PartialEq)]
struct CollisionProbes {
    cells: Vec<CollisionCell>,
    fine_radius_m: f64,
}

impl CollisionProbes {
    fn new(config: &GroundRobotConfig) -> Self {
        let (l, w) = (config.length_m, config.width_m);
        let (c, h) = (config.ground_clearance_m, config.height_m);
        let nx = (l / COLLISION_COARSE_CELL_M).ceil().max(1.0) as usize;
        let ny = (w / COLLISION_COARSE_CELL_M).ceil().max(1.0) as usize;
        let (sx, sy) = (l / nx as f64, w / ny as f64);
        let z_mid = 0.5 * (c + h);
        let half_diagonal_m = DVec3::new(0.5 * sx, 0.5 * sy, 0.5 * (h - c)).length();
        let mut cells: Vec<CollisionCell> = Vec::with_capacity(nx * ny);
        for i in 0..nx {
            for j in 0..ny {
                let centre_body = DVec3::new(-0.5 * l + (i as f64 + 0.5) * sx, -0.5 * w + (j as f64 + 0.5) * sy, z_mid);
                cells.push(CollisionCell { centre_body, half_diagonal_m, fine_body: Vec::new() });
            }
        }
        // Fine balls inside the box: centres on a grid at most √2·r apart along each axis
        // (their discs cover the inset footprint), from r inside every face.
        let r = (0.25 * (h - c)).min(COLLISION_FINE_RADIUS_MAX_M).min(0.5 * l).min(0.5 * w);
        let spacing = std::f64::consts::SQRT_2 * r;
        let count = |span: f64| ((span / spacing).ceil().max(0.0) as usize) + 1;
        let axis = |half: f64, n: usize| -> Vec<f64> {
            if n <= 1 {
                vec![0.0]
            } else {
                (0..n).map(|k| -half + r + (2.0 * (half - r)) * k as f64 / (n - 1) as f64).collect()
            }
        };
        let xs = axis(0.5 * l, count(l - 2.0 * r));
        let ys = axis(0.5 * w, count(w - 2.0 * r));
        let nz = count(h - c - 2.0 * r).max(2);
        let zs: Vec<f64> = (0..nz).map(|k| c + r + (h - c - 2.0 * r) * k as f64 / (nz - 1) as f64).collect();
        for &x in &xs {
            for &y in &ys {
                let i = (((x + 0.5 * l) / sx).floor().max(0.0) as usize).min(nx - 1);
                let j = (((y + 0.5 * w) / sy).floor().max(0.0) as usize).min(ny - 1);
                if let Some(cell) = cells.get_mut(i * ny + j) {
                    for &z in &zs {
                        cell.fine_body.push(DVec3::new(x, y, z));
                    }
                }
            }
        }
        Self { cells, fine_radius_m: r }
    }
}

/// A unicycle ground robot settled on the terrain (see the module documentation).
#[derive(Debug, Clone, PartialEq)]
pub struct GroundRobot {
    config: GroundRobotConfig,
    state: GroundRobotState,
    /// The last settle, with its contact plane; `None` until placed.
    contact: Option<(Settle, ContactPlane)>,
    probes: CollisionProbes,
    drift: OdometryDrift,
}

impl GroundRobot {
    /// A robot at `initial` (yaw wrapped to (-π, π]), not yet settled: call [`Self::place`]
    /// (the simulation does) before reading its height or tilt.
    pub fn new(config: GroundRobotConfig, initial: GroundRobotState) -> SimResult<Self> {
        config.validate()?;
        initial.validate("initial")?;
        let mut state = initial;
        state.yaw_rad = wrap_angle(state.yaw_rad);
        Ok(Self { config, state, contact: None, probes: CollisionProbes::new(&config), drift: OdometryDrift::new(config.odometry_noise) })
    }

    /// The configuration.
    pub fn config(&self) -> &GroundRobotConfig {
        &self.config
    }

    /// The planar state.
    pub fn state(&self) -> &GroundRobotState {
        &self.state
    }

    /// The last settle (`None` before [`Self::place`] or the first step).
    pub fn last_settle(&self) -> Option<&Settle> {
        self.contact.as_ref().map(|(s, _)| s)
    }

    /// The footprint sample points `(x, y)` in the world at a pose (5 x 3 grid over the
    /// footprint rotated by the heading; horizontal projection).
    pub fn footprint_samples(&self, x_m: f64, y_m: f64, yaw_rad: f64) -> Vec<DVec2> {
        let (s, c) = yaw_rad.sin_cos();
        let (l, w) = (self.config.length_m, self.config.width_m);
        let mut out = Vec::with_capacity(FOOTPRINT_SAMPLES_X * FOOTPRINT_SAMPLES_Y);
        for i in 0..FOOTPRINT_SAMPLES_X {
            let bx = -0.5 * l + l * i as f64 / (FOOTPRINT_SAMPLES_X - 1) as f64;
            for j in 0..FOOTPRINT_SAMPLES_Y {
                let by = -0.5 * w + w * j as f64 / (FOOTPRINT_SAMPLES_Y - 1) as f64;
                out.push(DVec2::new(x_m + c * bx - s * by, y_m + s * bx + c * by));
            }
        }
        out
    }

    /// Settles the footprint at the current pose (module documentation): height, roll
    /// and pitch of the resting plane on the ground under the 15 footprint samples.
    pub fn settle(&self, world: &World) -> Settle {
        self.settle_at(world, self.state.x_m, self.state.y_m, self.state.yaw_rad).0
    }

    fn settle_at(&self, world: &World, x_m: f64, y_m: f64, yaw_rad: f64) -> (Settle, ContactPlane) {
        let centre = DVec2::new(x_m, y_m);
        let samples = self.footprint_samples(x_m, y_m, yaw_rad);
        let mut points = Vec::with_capacity(samples.len());
        let mut holes = 0;
        for xy in &samples {
            match world.ground_height(xy.x, xy.y) {
                Some(z) if z.is_finite() => points.push(DVec3::new(xy.x - x_m, xy.y - y_m, z)),
                _ => holes += 1,
            }
        }
        let fallback_z = self.contact.as_ref().map_or(0.0, |(s, _)| s.z_m);
        let (z0, gradient) = match resting_plane(&points) {
            Some(plane) => plane,
            // Too few supports for a plane: level at the highest sample (or stay put).
            None => (points.iter().map(|p| p.z).reduce(f64::max).unwrap_or(fallback_z), DVec2::ZERO),
        };
        let plane = ContactPlane { origin: centre, z0, gradient };
        let gaps: Vec<f64> = points.iter().map(|p| plane.height(DVec2::new(p.x, p.y) + centre) - p.z).collect();
        let max_gap_m = gaps.iter().copied().fold(0.0_f64, f64::max);
        let supports: Vec<DVec2> = points.iter().zip(&gaps).filter(|(_, g)| **g <= SUPPORT_TOLERANCE_M).map(|(p, _)| p.truncate()).collect();
        let hull = convex_hull(&supports);
        let lowest_support_z = points.iter().zip(&gaps).filter(|(_, g)| **g <= SUPPORT_TOLERANCE_M).map(|(p, _)| p.z).fold(f64::INFINITY, f64::min);
        let overhang_gap_m = points
            .iter()
            .zip(&gaps)
            .filter(|(p, g)| **g > SUPPORT_TOLERANCE_M && !hull_contains(&hull, p.truncate()))
            .map(|(p, g)| g.min(lowest_support_z - p.z))
            .fold(0.0_f64, f64::max);
        let mut settle = Settle {
            z_m: z0,
            roll_rad: 0.0,
            pitch_rad: 0.0,
            gradient,
            max_gap_m,
            overhang_gap_m,
            samples_on_ground: points.len(),
            samples_over_hole: holes,
        };
        let r = settle.rotation(yaw_rad);
        // ZYX Euler angles of R = Rz(yaw)·Ry(pitch)·Rx(roll).
        settle.pitch_rad = -r.x_axis.z.clamp(-1.0, 1.0).asin();
        settle.roll_rad = r.y_axis.z.atan2(r.z_axis.z);
        (settle, plane)
    }

    /// The true pose: the footprint centre on the contact plane, body x along the plane in
    /// the heading direction, body z along its normal. Before the robot is placed, the
    /// pose is level at z = 0.
    pub fn world_from_body(&self) -> Isometry3 {
        let (z, rotation) = match &self.contact {
            Some((s, _)) => (s.z_m, s.rotation(self.state.yaw_rad)),
            None => (0.0, DMat3::from_rotation_z(self.state.yaw_rad)),
        };
        Isometry3 { rotation, translation: DVec3::new(self.state.x_m, self.state.y_m, z) }
    }

    /// The true velocity in the world frame [m/s]: the speed along body x.
    pub fn velocity_world(&self) -> DVec3 {
        self.world_from_body().rotation.x_axis * self.state.v_m_s
    }

    /// Whether a solid lies inside the body box above the ground clearance
    /// (`ground_clearance_m..height_m` above the contact plane, the full footprint) at
    /// pose `world_from_body`. Coarse cells (at most 25 cm square, the box's height) are
    /// cleared with one [`World::clearance`] query at their centre when the clearance
    /// exceeds the cell's half diagonal (no surface inside the cell). An unresolved cell
    /// is probed with balls of radius r = min((height - clearance)/4, 7.5 cm) lying inside
    /// the box (a grid of centres at most √2·r apart along each axis, from r inside the
    /// faces; 10 x 7 x 3 for the Husky box): a collision is
    /// reported when `clearance < r` at a ball centre, i.e. a solid surface is certainly
    /// inside the box. No false alarms; a penetration shallower than about r at the box's
    /// faces, or a solid thinner than the gaps between the balls, can go unnoticed until
    /// it reaches deeper. The terrain counts: ground rising into the belly is a collision.
    pub fn body_collision(&self, world: &World, world_from_body: &Isometry3) -> bool {
        let r = self.probes.fine_radius_m;
        for cell in &self.probes.cells {
            let centre = world_from_body.transform_point(cell.centre_body);
            if world.clearance(centre) > cell.half_diagonal_m {
                continue;
            }
            if cell.fine_body.iter().any(|p| world.clearance(world_from_body.transform_point(*p)) < r) {
                return true;
            }
        }
        false
    }

    /// Distance from the body box to the nearest obstacle [m], probed by 36 rays in the
    /// body's x-y plane at mid-body height from the footprint centre, each minus the
    /// distance from the centre to the box side along the ray. Hits on ground (normal
    /// z > 0.7) do not count. Capped at [`CLEARANCE_PROBE_RANGE_M`]; 0 when the body
    /// box collides.
    pub fn clearance_m(&self, world: &World) -> f64 {
        let pose = self.world_from_body();
        if self.body_collision(world, &pose) {
            return 0.0;
        }
        let (hl, hw) = (0.5 * self.config.length_m, 0.5 * self.config.width_m);
        let origin = pose.transform_point(DVec3::new(0.0, 0.0, 0.5 * (self.config.ground_clearance_m + self.config.height_m)));
        let mut best = CLEARANCE_PROBE_RANGE_M;
        for k in 0..CLEARANCE_PROBE_RAYS {
            let angle = 2.0 * PI * k as f64 / CLEARANCE_PROBE_RAYS as f64;
            let (s, c) = angle.sin_cos();
            // Distance from the centre to the box side along (c, s).
            let exit = (if c.abs() > 1e-12 { hl / c.abs() } else { f64::INFINITY }).min(if s.abs() > 1e-12 { hw / s.abs() } else { f64::INFINITY });
            let dir = pose.transform_vector(DVec3::new(c, s, 0.0));
            if let Some(hit) = world.cast_ray(origin, dir, CLEARANCE_PROBE_RANGE_M + exit) {
                if hit.normal.z > GROUND_NORMAL_Z {
                    continue;
                }
                best = best.min((hit.distance_m - exit).max(0.0));
            }
        }
        best
    }

    /// Settles the robot at its current pose (no ledge test: there is no previous contact)
    /// and returns the failure of that placement, if any: terrain failures first, then a
    /// body collision.
    pub fn place(&mut self, world: &World) -> Option<Failure> {
        let (settle, plane) = self.settle_at(world, self.state.x_m, self.state.y_m, self.state.yaw_rad);
        self.contact = Some((settle, plane));
        if let Some(f) = settle.failure(&self.config) {
            return Some(f);
        }
        self.body_collision(world, &self.world_from_body()).then_some(Failure::Collision)
    }

    /// Drives with commanded speed `v_m_s` [m/s] and yaw rate `omega_rad_s` [rad/s] for
    /// `dt_s` seconds: limits and optional acceleration limits, then exact unicycle arcs
    /// over sub-steps of at most 5 cm / 0.05 rad, each followed by a settle and the
    /// failure checks. A fall, rollover or leaving the world stops the robot at the
    /// sub-step where it happened and is returned; a collision is detected, not resolved:
    /// the robot drives on through the step and [`Failure::Collision`] is returned. An
    /// invalid `dt_s` (not finite, <= 0 or beyond [`MAX_STEP_S`]) does nothing;
    /// non-finite commands count as 0.
    pub fn step(&mut self, v_m_s: f64, omega_rad_s: f64, dt_s: f64, world: &World) -> Option<Failure> {
        if !step_is_valid(dt_s) {
            return None;
        }
        self.drift.elapse(dt_s);
        let finite_or_zero = |x: f64| if x.is_finite() { x } else { 0.0 };
        let v_cmd = finite_or_zero(v_m_s).clamp(-self.config.v_max_m_s, self.config.v_max_m_s);
        let w_cmd = finite_or_zero(omega_rad_s).clamp(-self.config.yaw_rate_max_rad_s, self.config.yaw_rate_max_rad_s);
        let v_peak = v_cmd.abs().max(self.state.v_m_s.abs());
        let w_peak = w_cmd.abs().max(self.state.yaw_rate_rad_s.abs());
        let n = ((v_peak * dt_s / SUBSTEP_MAX_TRAVEL_M).ceil().max((w_peak * dt_s / SUBSTEP_MAX_TURN_RAD).ceil()).max(1.0)) as usize;
        let h = dt_s / n as f64;
        let mut collided = false;
        for _ in 0..n {
            let (v1, v) = ramp(self.state.v_m_s, v_cmd, self.config.accel_max_m_s2, h);
            let (w1, w) = ramp(self.state.yaw_rate_rad_s, w_cmd, self.config.yaw_accel_max_rad_s2, h);
            let (x, y, yaw) = unicycle_arc(self.state.x_m, self.state.y_m, self.state.yaw_rad, v, w, h);
            self.state = GroundRobotState { x_m: x, y_m: y, yaw_rad: yaw, v_m_s: v1, yaw_rate_rad_s: w1 };
            match self.settle_and_check(world) {
                Some(Failure::Collision) => collided = true,
                Some(failure) => return Some(failure),
                None => {}
            }
        }
        collided.then_some(Failure::Collision)
    }

    /// Settles at the current pose; checks the terrain failures, the ledge test against
    /// the previous contact plane, and the body box.
    fn settle_and_check(&mut self, world: &World) -> Option<Failure> {
        let (settle, plane) = self.settle_at(world, self.state.x_m, self.state.y_m, self.state.yaw_rad);
        let previous = self.contact.map(|(_, p)| p);
        self.contact = Some((settle, plane));
        if let Some(f) = settle.failure(&self.config) {
            return Some(f);
        }
        if let Some(prev) = previous {
            let ledge = self.footprint_samples(self.state.x_m, self.state.y_m, self.state.yaw_rad).iter().any(|xy| {
                world.ground_height(xy.x, xy.y).is_some_and(|z| z - prev.height(*xy) > self.config.max_step_m)
            });
            if ledge {
                return Some(Failure::Collision);
            }
        }
        self.body_collision(world, &self.world_from_body()).then_some(Failure::Collision)
    }

    /// Odometry `(world_from_body, velocity_world)`: the truth, or with the drift of
    /// [`GroundRobotConfig::odometry_noise`] walked over the time since the last call.
    pub fn odometry<R: Rng + ?Sized>(&mut self, rng: &mut R) -> (Isometry3, DVec3) {
        self.drift.advance(rng);
        self.drift.apply(&self.world_from_body(), self.velocity_world())
    }

    /// The drift state of the odometry.
    pub fn odometry_drift(&self) -> &OdometryDrift {
        &self.drift
    }
}

/// A rate moving from `from` toward `to` at most `max_rate` per second (`None`: jumps to
/// `to` at once) over `h` seconds: `(value at the end, mean value over the interval)`.
/// The mean is exact for the linear ramp, also when it reaches `to` within the interval.
fn ramp(from: f64, to: f64, max_rate: Option<f64>, h: f64) -> (f64, f64) {
    let Some(rate) = max_rate else { return (to, to) };
    let change = to - from;
    let t_reach = change.abs() / rate;
    if t_reach >= h {
        let end = from + rate * h * change.signum();
        (end, 0.5 * (from + end))
    } else {
        // Ramp for t_reach, then hold `to`.
        let mean = (0.5 * (from + to) * t_reach + to * (h - t_reach)) / h;
        (to, mean)
    }
}

/// Exact unicycle motion for constant `(v, ω)` over `dt`: a straight segment for ω = 0,
/// else a circular arc. Returns `(x, y, yaw)` with the yaw wrapped to (-π, π].
pub fn unicycle_arc(x_m: f64, y_m: f64, yaw_rad: f64, v_m_s: f64, omega_rad_s: f64, dt_s: f64) -> (f64, f64, f64) {
    let dyaw = omega_rad_s * dt_s;
    // Chord of the arc: length v·dt·sinc(dψ/2) along the mid heading.
    let half = 0.5 * dyaw;
    let sinc = if half.abs() < 1e-6 { 1.0 - half * half / 6.0 } else { half.sin() / half };
    let chord = v_m_s * dt_s * sinc;
    let mid = yaw_rad + half;
    (x_m + chord * mid.cos(), y_m + chord * mid.sin(), wrap_angle(yaw_rad + dyaw))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn wrap_angle_maps_into_half_open_interval() {
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(-PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(0.5) - 0.5).abs() < 1e-15);
        assert!((wrap_angle(2.0 * PI + 0.25) - 0.25).abs() < 1e-12);
        assert!((wrap_angle(-0.75 * PI) + 0.75 * PI).abs() < 1e-12);
    }

    #[test]
    fn unicycle_arc_quarter_circle() {
        // v = 1, ω = π/2 for 1 s: a quarter circle of radius 2/π, from heading 0 turning left.
        let (x, y, yaw) = unicycle_arc(0.0, 0.0, 0.0, 1.0, 0.5 * PI, 1.0);
        let r = 2.0 / PI;
        assert!((x - r).abs() < 1e-12, "x = {x}");
        assert!((y - r).abs() < 1e-12, "y = {y}");
        assert!((yaw - 0.5 * PI).abs() < 1e-12);
        // Two half steps compose exactly to the same arc.
        let (x1, y1, yaw1) = unicycle_arc(0.0, 0.0, 0.0, 1.0, 0.5 * PI, 0.5);
        let (x2, y2, yaw2) = unicycle_arc(x1, y1, yaw1, 1.0, 0.5 * PI, 0.5);
        assert!((x2 - x).abs() < 1e-12 && (y2 - y).abs() < 1e-12 && (yaw2 - yaw).abs() < 1e-12);
        // Straight line.
        let (x, y, _) = unicycle_arc(1.0, 2.0, 0.5 * PI, 0.5, 0.0, 2.0);
        assert!((x - 1.0).abs() < 1e-12 && (y - 3.0).abs() < 1e-12);
    }

    #[test]
    fn ramp_means_are_exact() {
        assert_eq!(ramp(0.0, 1.0, None, 0.1), (1.0, 1.0));
        // 0.5 m/s² over 0.1 s from 0: 0.05 at the end, mean 0.025.
        let (end, mean) = ramp(0.0, 1.0, Some(0.5), 0.1);
        assert!((end - 0.05).abs() < 1e-15 && (mean - 0.025).abs() < 1e-15);
        // Reaches 0.2 from 0 at 4 m/s² after 0.05 s of 0.1: distance 0.005 + 0.01 -> mean 0.15.
        let (end, mean) = ramp(0.0, 0.2, Some(4.0), 0.1);
        assert_eq!(end, 0.2);
        assert!((mean - 0.15).abs() < 1e-15);
        // Braking: from 1 toward -1 at 2 m/s² for 0.1 s: 0.8, mean 0.9.
        let (end, mean) = ramp(1.0, -1.0, Some(2.0), 0.1);
        assert!((end - 0.8).abs() < 1e-15 && (mean - 0.9).abs() < 1e-15);
    }

    #[test]
    fn resting_plane_on_a_plane_is_the_plane() {
        // z = 1 + 0.2 x - 0.1 y sampled on a 3 x 3 grid: every triple is coplanar.
        let pts: Vec<DVec3> =
            (-1..=1).flat_map(|i| (-1..=1).map(move |j| DVec3::new(i as f64, j as f64, 1.0 + 0.2 * i as f64 - 0.1 * j as f64))).collect();
        let (a, g) = resting_plane(&pts).unwrap();
        assert!((a - 1.0).abs() < 1e-12);
        assert!((g.x - 0.2).abs() < 1e-12 && (g.y + 0.1).abs() < 1e-12);
    }

    #[test]
    fn resting_plane_rests_on_the_highest_supports() {
        // Square corners at z = 0 and a bump of 0.1 at the centre: the body rests on the
        // bump and tips onto two corners; the centre height is the bump's 0.1.
        let mut pts = vec![
            DVec3::new(-1.0, -1.0, 0.0),
            DVec3::new(1.0, -1.0, 0.0),
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::new(-1.0, 1.0, 0.0),
            DVec3::new(0.0, 0.0, 0.1),
        ];
        let (a, _) = resting_plane(&pts).unwrap();
        assert!((a - 0.1).abs() < 1e-12);
        // A raised corner (0.2 at (1, 1)): every plane on or above the samples that is
        // lowest at the centre passes 0.1 there (the centre lies on the hull ridge from
        // (-1, -1, 0) through the bump to (1, 1, 0.2)); the planes through three samples
        // on that ridge's sides all tilt by 0.1 (e.g. z = 0.1 + 0.1 y through (1, 1),
        // (1, -1), (-1, -1)), and every sample stays on or below the chosen plane.
        pts[2].z = 0.2;
        let (a, g) = resting_plane(&pts).unwrap();
        assert!((a - 0.1).abs() < 1e-12, "a = {a}");
        assert!((g.length() - 0.1).abs() < 1e-12, "g = {g}");
        assert!(pts.iter().all(|p| p.z <= a + g.x * p.x + g.y * p.y + 1e-12));
        // Collinear points give no plane.
        assert!(resting_plane(&[DVec3::ZERO, DVec3::X, DVec3::new(2.0, 0.0, 1.0)]).is_none());
    }

    #[test]
    fn hull_of_a_grid_and_containment() {
        // 3 x 3 grid: hull is the 4 corners; the centre and edge midpoints are inside/on it.
        let pts: Vec<DVec2> = (0..3).flat_map(|i| (0..3).map(move |j| DVec2::new(i as f64, j as f64))).collect();
        let hull = convex_hull(&pts);
        assert_eq!(hull, vec![DVec2::new(0.0, 0.0), DVec2::new(2.0, 0.0), DVec2::new(2.0, 2.0), DVec2::new(0.0, 2.0)]);
        assert!(hull_contains(&hull, DVec2::new(1.0, 1.0)));
        assert!(hull_contains(&hull, DVec2::new(2.0, 1.0)));
        assert!(!hull_contains(&hull, DVec2::new(2.0 + 1e-6, 1.0)));
        // Rear and front rows only (a valley under the middle): the middle row is bridged.
        let rows: Vec<DVec2> = pts.iter().copied().filter(|p| p.x != 1.0).collect();
        let hull = convex_hull(&rows);
        assert!(hull_contains(&hull, DVec2::new(1.0, 0.0)) && hull_contains(&hull, DVec2::new(1.0, 2.0)));
        // Rear and middle rows only (a cliff ahead): the front row overhangs.
        let back: Vec<DVec2> = pts.iter().copied().filter(|p| p.x != 2.0).collect();
        assert!(!hull_contains(&convex_hull(&back), DVec2::new(2.0, 1.0)));
        // Degenerate support (collinear) contains nothing.
        assert!(!hull_contains(&convex_hull(&[DVec2::ZERO, DVec2::X, DVec2::new(2.0, 0.0)]), DVec2::X));
    }

    #[test]
    fn quadrotor_step_is_exact_first_order_lag() {
        let mut q = Quadrotor::new(QuadrotorConfig::default(), QuadrotorState::at_rest(DVec3::ZERO, 0.0)).unwrap();
        q.step(&BodyVelocityCommand::new(0.5, 0.0, 0.0, 0.0), 0.2);
        // One step of τ: v = 0.5 (1 - e^-1), x = 0.5 (τ - τ (1 - e^-1)) = 0.5·0.2·e^-1.
        let e = (-1.0_f64).exp();
        assert!((q.state().velocity_world.x - 0.5 * (1.0 - e)).abs() < 1e-15);
        assert!((q.state().position.x - 0.5 * 0.2 * e).abs() < 1e-15);
        // Invalid steps do nothing.
        let before = *q.state();
        q.step(&BodyVelocityCommand::new(0.5, 0.0, 0.0, 0.0), f64::NAN);
        q.step(&BodyVelocityCommand::new(0.5, 0.0, 0.0, 0.0), -0.1);
        assert_eq!(*q.state(), before);
        // NaN commands count as zero.
        let limited = q.limited(&BodyVelocityCommand::new(f64::NAN, 2.0, -2.0, f64::INFINITY));
        assert_eq!(limited, BodyVelocityCommand::new(0.0, 0.6, -0.6, 0.0));
    }

    #[test]
    fn odometry_drift_variance_grows_with_time() {
        let noise = OdometryNoise { position_walk_m_per_sqrt_s: 0.1, yaw_walk_rad_per_sqrt_s: 0.02 };
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(7);
        let n = 4000;
        let (mut sum_x2, mut sum_yaw2) = (0.0, 0.0);
        for _ in 0..n {
            let mut drift = OdometryDrift::new(Some(noise));
            for _ in 0..4 {
                drift.elapse(1.0);
                drift.advance(&mut rng);
            }
            sum_x2 += drift.bias_position_m.x.powi(2);
            sum_yaw2 += drift.bias_yaw_rad.powi(2);
        }
        // After 4 s: variance 0.1² · 4 = 0.04 and 0.02² · 4 = 0.0016 (5 % tolerance at n = 4000 ~ 2.2 σ).
        let var_x = sum_x2 / n as f64;
        let var_yaw = sum_yaw2 / n as f64;
        assert!((var_x / 0.04 - 1.0).abs() < 0.05, "var_x = {var_x}");
        assert!((var_yaw / 0.0016 - 1.0).abs() < 0.05, "var_yaw = {var_yaw}");
        // Without noise nothing is drawn and odometry is the truth.
        let mut drift = OdometryDrift::new(None);
        drift.elapse(1.0);
        let mut a = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(1);
        drift.advance(&mut a);
        let mut b = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(1);
        assert_eq!(a.next_u64(), b.next_u64());
        assert_eq!(drift.bias_position_m, DVec3::ZERO);
    }

    #[test]
    fn configs_reject_bad_values() {
        let c = QuadrotorConfig { radius_m: 0.0, ..QuadrotorConfig::default() };
        assert!(matches!(c.validate(), Err(SimError::InvalidConfig { field, .. }) if field == "quadrotor.radius_m"));
        let g = GroundRobotConfig { ground_clearance_m: 0.5, ..GroundRobotConfig::default() };
        assert!(matches!(g.validate(), Err(SimError::InvalidConfig { field, .. }) if field == "ground_robot.ground_clearance_m"));
        let g = GroundRobotConfig { rollover_pitch_rad: 2.0, ..GroundRobotConfig::default() };
        assert!(matches!(g.validate(), Err(SimError::InvalidConfig { field, .. }) if field == "ground_robot.rollover_pitch_rad"));
        assert!(matches!(
            Quadrotor::new(QuadrotorConfig::default(), QuadrotorState::at_rest(DVec3::new(f64::NAN, 0.0, 0.0), 0.0)),
            Err(SimError::InvalidInput { argument, .. }) if argument == "initial.position"
        ));
    }

    #[test]
    fn collision_probes_cover_the_husky_box() {
        let probes = CollisionProbes::new(&GroundRobotConfig::default());
        // 4 x 3 coarse cells of 0.2475 x 0.2233 x 0.27 m.
        assert_eq!(probes.cells.len(), 12);
        let hd = DVec3::new(0.12375, 0.67 / 6.0, 0.135).length();
        assert!((probes.cells[0].half_diagonal_m - hd).abs() < 1e-12);
        // The half diagonal stays below the cell centre's height above the contact plane
        // (0.265 m), so level ground never blocks the coarse test.
        assert!(hd < 0.265);
        // Fine balls: r = 0.27 / 4, spacing √2·r = 0.0955: along x ceil(0.855 / 0.0955) + 1 = 10,
        // along y ceil(0.535 / 0.0955) + 1 = 7, along z ceil(0.135 / 0.0955) + 1 = 3; all inside the box.
        let r = probes.fine_radius_m;
        assert!((r - 0.0675).abs() < 1e-12);
        let all: Vec<DVec3> = probes.cells.iter().flat_map(|c| c.fine_body.iter().copied()).collect();
        assert_eq!(all.len(), 10 * 7 * 3);
        for p in &all {
            assert!(p.x.abs() + r <= 0.495 + 1e-12 && p.y.abs() + r <= 0.335 + 1e-12);
            assert!(p.z - r >= 0.13 - 1e-12 && p.z + r <= 0.4 + 1e-12);
        }
    }
}
