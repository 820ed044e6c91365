//! The quadrotor: a first-order lag on the clipped body-velocity command, integrated exactly,
//! with a collision sphere (see the module documentation of `vehicles`).

use glam::{DMat3, DVec3};
use rand::Rng;
use serde::{Deserialize, Serialize};
use subterra::Isometry3;

use super::command::BodyVelocityCommand;
use super::dynamics::{lag_decay, lag_integral, require_non_negative, require_positive, step_is_valid, wrap_angle};
use super::odometry::{OdometryDrift, OdometryNoise};
use crate::error::{SimError, SimResult};
use crate::world::World;

#[cfg(doc)]
use super::dynamics::MAX_STEP_S;

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
