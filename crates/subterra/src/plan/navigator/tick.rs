//! One control tick's input ([`NavigatorInput`]: time, scan, odometry) and output
//! ([`NavigatorOutput`]: the command, the behaviour, the plan and the tracker's output, and
//! the [`NavigatorTimings`] of each stage).

use glam::DVec2;

use crate::frames::Isometry3;
use crate::plan::astar::PlanOutcome;
use crate::plan::mpc::MpcOutput;
use crate::plan::recovery::{Behaviour, Target, Transition};

/// One control tick's inputs.
#[derive(Debug, Clone, Copy)]
pub struct NavigatorInput<'a> {
    /// Time \[s\]; must not go backwards.
    pub stamp_s: f64,
    /// A new scan, `(N, 3)` flat, sensor frame \[m\], or `None`.
    pub points_sensor: Option<&'a [f32]>,
    /// Odometry pose.
    pub world_from_body: Isometry3,
    /// Sensor mounting.
    pub body_from_sensor: Isometry3,
    /// Odometry confidence in [0, 1] (fusion window).
    pub confidence: f64,
    /// Measured forward speed [m/s].
    pub speed_m_s: f64,
}

/// Wall time of each stage of one step \[s\].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct NavigatorTimings {
    /// Map update.
    pub map_s: f64,
    /// Planning (0 when it did not run).
    pub plan_s: f64,
    /// MPC (0 when it did not run).
    pub track_s: f64,
    /// The whole step.
    pub total_s: f64,
}

/// One control tick's outputs.
#[derive(Debug, Clone)]
pub struct NavigatorOutput {
    /// Forward speed to command [m/s].
    pub speed_m_s: f64,
    /// Yaw rate to command [rad/s].
    pub yaw_rate_rad_s: f64,
    /// The behaviour that produced the command.
    pub behaviour: Behaviour,
    /// The target being driven to.
    pub target: Target,
    /// The plan made this tick, if one was made.
    pub plan: Option<PlanOutcome>,
    /// The path being tracked (the last found), world \[m\].
    pub path_world: Vec<DVec2>,
    /// The MPC's output, when it ran.
    pub mpc: Option<MpcOutput>,
    /// Risk under the robot [0-1].
    pub local_risk: f64,
    /// `v_max·(1 - local_risk)` [m/s].
    pub speed_limit_m_s: f64,
    /// Planner thresholds in force.
    pub r_inst: f64,
    /// Planner budget in force.
    pub r_total: f64,
    /// Transitions of the recovery machine during this tick.
    pub transitions: Vec<Transition>,
    /// Stage times.
    pub timings: NavigatorTimings,
    /// Why the command is not the behaviour's own, when the motion it asked for was not safe
    /// (the footprint it would sweep): the tracker's command replaced by a turn, a straight
    /// drive or a stop, or a recovery stopped.
    pub safety: Option<String>,
}
