//! The unicycle ground robot: its configuration (Husky-like defaults), state, failures, and
//! the stepping that settles it on the terrain and checks it after every sub-step.

use std::f64::consts::PI;

use glam::{DMat3, DVec2, DVec3};
use rand::Rng;
use serde::{Deserialize, Serialize};
use subterra::Isometry3;

use super::collision::CollisionProbes;
use super::dynamics::{ramp, require_non_negative, require_positive, step_is_valid, unicycle_arc, wrap_angle};
use super::odometry::{OdometryDrift, OdometryNoise};
use super::settle::{convex_hull, hull_contains, resting_plane, ContactPlane, Settle};
use crate::error::{SimError, SimResult};
use crate::world::World;

#[cfg(doc)]
use super::dynamics::MAX_STEP_S;

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
/// Footprint samples along body x (rear edge, quarter, centre, quarter, front edge).
const FOOTPRINT_SAMPLES_X: usize = 5;
/// Footprint samples along body y (right edge, centre line, left edge).
const FOOTPRINT_SAMPLES_Y: usize = 3;
/// A footprint sample within this of the contact plane supports the robot [m].
const SUPPORT_TOLERANCE_M: f64 = 1e-6;
/// Horizontal rays of the ground robot's clearance probe (one every 10°).
const CLEARANCE_PROBE_RAYS: usize = 36;
/// Range of the ground robot's clearance probe [m]; the reported clearance is capped here.
pub const CLEARANCE_PROBE_RANGE_M: f64 = 5.0;
/// A ray hit whose normal has a z component above this is ground, not an obstacle.
const GROUND_NORMAL_Z: f64 = 0.7;

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
