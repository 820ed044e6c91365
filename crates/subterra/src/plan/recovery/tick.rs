//! What the recovery machine is told each tick and what it answers: the [`RecoveryInput`] and
//! [`PlanFeedback`] in, the [`Directive`] with its [`Behaviour`] and [`Target`] out, and the
//! [`Transition`]s it records.

use std::fmt;

use glam::DVec2;
use serde::{Deserialize, Serialize};

/// What the robot is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Behaviour {
    /// Plan to the target and track the plan.
    Track,
    /// Drop the fused map (one tick).
    ClearMap,
    /// Turn in place toward the heading of most clearance.
    Rotate,
    /// Raise the planner's thresholds one step (one tick).
    RaiseThresholds,
    /// Reverse along the driven path.
    BackOut,
    /// The goal was reached: stop.
    GoalReached,
    /// Home was reached after giving up the goal: stop.
    Home,
    /// Every behaviour was tried on the way home too: stop.
    Failed,
}

impl Behaviour {
    /// The snake_case name used in logs and files.
    pub fn name(self) -> &'static str {
        match self {
            Self::Track => "track",
            Self::ClearMap => "clear_map",
            Self::Rotate => "rotate",
            Self::RaiseThresholds => "raise_thresholds",
            Self::BackOut => "back_out",
            Self::GoalReached => "goal_reached",
            Self::Home => "home",
            Self::Failed => "failed",
        }
    }

    /// Whether the run is over.
    pub fn is_final(self) -> bool {
        matches!(self, Self::GoalReached | Self::Home | Self::Failed)
    }
}

impl fmt::Display for Behaviour {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// How the planner's last call went, as the recovery machine needs to know it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlanFeedback {
    /// A path within the thresholds was found.
    Found,
    /// No path (unreachable, or the start or target is untraversable).
    NoPath,
    /// The least-risk path exceeds the accumulated-risk budget.
    BudgetExceeded,
    /// The planner did not run this tick.
    NotRun,
}

/// One tick's facts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecoveryInput {
    /// Time \[s\]; must not go backwards.
    pub time_s: f64,
    /// Robot position, world frame \[m\].
    pub position: DVec2,
    /// Robot heading, world frame \[rad\].
    pub yaw_rad: f64,
    /// Distance from the robot to the current target \[m\] (path length if known, else
    /// straight line).
    pub distance_to_target_m: f64,
    /// Straight-line distance from the robot to the target \[m\] (decides when the robot got
    /// past where it was stuck; the path-based distance above jumps when a replan finds
    /// another way).
    pub straight_distance_m: f64,
    /// How the planner's last call went.
    pub plan: PlanFeedback,
    /// Heading of most clearance around the robot, world frame \[rad\], if the navigator
    /// computed one (used when entering `Rotate`).
    pub clearance_heading_rad: Option<f64>,
    /// Whether the robot could turn in place here (the navigator checked the footprint a full
    /// turn sweeps): `BackOut` goes on past `backout_distance_m` while it could not.
    pub room_to_turn: bool,
    /// Whether this tick's plan rerouted the robot (the navigator sets it when a new plan
    /// lengthens the way by more than `progress_min_m`): that jump in
    /// `distance_to_target_m` is then not lost progress (`RecoveryMachine`'s docs), at most once a
    /// progress window.
    pub route_switched: bool,
}

/// Which target to drive to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Target {
    /// The goal given to the navigator.
    Goal,
    /// The home position (where the robot started, or as given).
    Home,
}

/// What to do this tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Directive {
    /// The behaviour to run.
    pub behaviour: Behaviour,
    /// Planner threshold `R_inst` to use [0-1].
    pub r_inst: f64,
    /// Planner budget `R_total` to use [0-1].
    pub r_total: f64,
    /// The target to plan to.
    pub target: Target,
    /// Drop the fused map before the next update.
    pub clear_map: bool,
    /// `Rotate`: the heading to turn to, world frame \[rad\].
    pub rotate_to_rad: Option<f64>,
    /// `BackOut`: the point on the trail to reverse toward, world frame \[m\].
    pub backout_carrot: Option<DVec2>,
}

/// One recorded change of behaviour.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Transition {
    /// When \[s\].
    pub time_s: f64,
    /// Behaviour before.
    pub from: Behaviour,
    /// Behaviour after.
    pub to: Behaviour,
    /// Why, in words with the numbers that decided it.
    pub reason: String,
    /// `R_inst` after the transition.
    pub r_inst: f64,
    /// `R_total` after the transition.
    pub r_total: f64,
}
