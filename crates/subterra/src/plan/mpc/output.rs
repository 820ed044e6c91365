//! What one solve gives: the [`MpcStatus`] it ended with, the [`MpcCommand`] to send now and
//! the whole [`MpcOutput`] with the predicted trajectory and its diagnostics.

use glam::DVec2;

use super::{ConvexPolygon, UnicycleInput, UnicycleState};

/// How a solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum MpcStatus {
    /// Every QP solved to tolerance; the plan is safe.
    Solved,
    /// The plan is safe but a QP stopped at reduced accuracy or failed after the first
    /// iteration (the last good iterate is used).
    SolvedInexact,
    /// No safe plan (the best plan goes deeper into a lethal region's margin than the robot
    /// is now): the output is the backup stop.
    InfeasibleBackup,
    /// The first QP failed (numerical trouble): the output is the backup stop.
    SolverFailedBackup,
}

impl MpcStatus {
    /// `solved`, `solved_inexact`, `infeasible_backup`, `solver_failed_backup`.
    pub fn name(self) -> &'static str {
        match self {
            MpcStatus::Solved => "solved",
            MpcStatus::SolvedInexact => "solved_inexact",
            MpcStatus::InfeasibleBackup => "infeasible_backup",
            MpcStatus::SolverFailedBackup => "solver_failed_backup",
        }
    }

    /// Whether the output is the backup stop.
    pub fn is_backup(self) -> bool {
        matches!(self, MpcStatus::InfeasibleBackup | MpcStatus::SolverFailedBackup)
    }
}

/// The command to send now.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MpcCommand {
    /// Forward speed at the end of the first step, `v0 + a_0·dt` [m/s].
    pub speed_m_s: f64,
    /// Yaw rate over the first step [rad/s].
    pub yaw_rate_rad_s: f64,
}

/// What one solve gives. Slacks, clearances and speed limits describe the returned
/// `predicted` trajectory (the backup stop when the status is a backup).
#[derive(Debug, Clone, PartialEq)]
pub struct MpcOutput {
    /// The command to send now.
    pub command: MpcCommand,
    /// Predicted states `x_0..x_N` (`x_0` the given state), exact rollout of `inputs`.
    pub predicted: Vec<UnicycleState>,
    /// Planned inputs `u_0..u_{N-1}`.
    pub inputs: Vec<UnicycleInput>,
    /// How the solve ended.
    pub status: MpcStatus,
    /// QPs solved (re-linearisations), 0 when the first one failed.
    pub sqp_iterations: u32,
    /// Interior-point iterations over all QPs.
    pub qp_iterations: u32,
    /// Wall time of the solve \[s\].
    pub solve_time_s: f64,
    /// `max(max_speed_slack_m_s, max_obstacle_slack_m)` [m/s or m].
    pub max_slack: f64,
    /// Largest excess of `|v_k|` over its risk and speed limits, `k = 1..N` [m/s].
    pub max_speed_slack_m_s: f64,
    /// Largest intrusion of a predicted footprint into a polygon's margin, `k = 1..N` \[m\].
    pub max_obstacle_slack_m: f64,
    /// Smallest signed distance from a predicted footprint (`k = 1..N`) to a lethal polygon
    /// \[m\]; infinite when there is none.
    pub min_clearance_m: f64,
    /// Upper speed limit `vhi_k` at the predicted states `k = 1..N` [m/s] (`MpcTracker`'s docs, step 2).
    pub speed_limits_m_s: Vec<f64>,
    /// Reference points `r_1..r_N` of the last iteration \[m\].
    pub reference_points: Vec<DVec2>,
    /// The lethal polygons considered.
    pub polygons: Vec<ConvexPolygon>,
}
