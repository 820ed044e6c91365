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
//!
//! Layout: `quadrotor.rs` and `ground_robot.rs` hold the two vehicles, `settle.rs` the
//! resting plane and `collision.rs` the body-box probes of the ground robot, `dynamics.rs`
//! the shared motion helpers, `command.rs` the velocity command, `odometry.rs` the drift.

#[cfg(doc)]
use crate::world::World;

mod collision;
mod command;
mod dynamics;
mod ground_robot;
mod odometry;
mod quadrotor;
mod settle;
#[cfg(test)]
mod tests;

pub use command::BodyVelocityCommand;
pub use dynamics::{unicycle_arc, wrap_angle, MAX_STEP_S};
pub use ground_robot::{
    Failure, GroundRobot, GroundRobotConfig, GroundRobotState, CLEARANCE_PROBE_RANGE_M, HUSKY_CLEARANCE_M, HUSKY_HEIGHT_M, HUSKY_LENGTH_M,
    HUSKY_V_MAX_M_S, HUSKY_WIDTH_M, HUSKY_YAW_RATE_MAX_RAD_S, ROLLOVER_LIMIT_DEG,
};
pub use odometry::{OdometryDrift, OdometryNoise};
pub use quadrotor::{
    Quadrotor, QuadrotorConfig, QuadrotorState, QUADROTOR_RADIUS_M, QUADROTOR_TIME_CONSTANT_S, QUADROTOR_V_XY_MAX_M_S, QUADROTOR_V_Z_MAX_M_S,
    QUADROTOR_YAW_RATE_MAX_RAD_S,
};
pub use settle::Settle;
