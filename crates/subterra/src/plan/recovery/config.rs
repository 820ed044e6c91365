//! The recovery ladder's settings ([`RecoveryConfig`]): progress window, thresholds and their
//! raises, rotate and back-out limits, the breadcrumb trail; with their defaults and checks.

use serde::{Deserialize, Serialize};

use crate::error::{require_positive, Error, Result};

/// Settings of the recovery ladder. Defaults: values that suit a Husky-sized robot at
/// 1 m/s in a mine (chosen for the `mine` scenario; STEP gives no numbers).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecoveryConfig {
    /// Window over which progress toward the target is measured \[s\].
    pub progress_window_s: f64,
    /// Least decrease of the distance to the target over the window that counts as
    /// progress \[m\].
    pub progress_min_m: f64,
    /// Consecutive ticks without a plan that make a trigger \[ticks\].
    pub stuck_plan_failures: u32,
    /// Nominal untraversable-cell threshold `R_inst` of the planner [0-1].
    pub r_inst: f64,
    /// Raise of `R_inst` per `RaiseThresholds` step [0-1].
    pub r_inst_step: f64,
    /// Ceiling of `R_inst` [0-1].
    pub r_inst_ceiling: f64,
    /// Nominal accumulated-risk budget `R_total` of the planner [0-1].
    pub r_total: f64,
    /// Raise of `R_total` per step [0-1].
    pub r_total_step: f64,
    /// Ceiling of `R_total` [0-1].
    pub r_total_ceiling: f64,
    /// Heading error at which `Rotate` is done \[rad\].
    pub rotate_tolerance_rad: f64,
    /// Longest `Rotate` \[s\].
    pub rotate_timeout_s: f64,
    /// Distance `BackOut` reverses along the trail \[m\].
    pub backout_distance_m: f64,
    /// How far back along the trail the `BackOut` carrot is \[m\].
    pub backout_carrot_m: f64,
    /// Longest `BackOut` \[s\].
    pub backout_timeout_s: f64,
    /// `BackOut` goes on past `backout_distance_m` while the robot has no room to turn in
    /// place (a corridor it drove into), up to this distance \[m\].
    #[serde(default = "default_backout_max_distance_m")]
    pub backout_max_distance_m: f64,
    /// Spacing of the breadcrumb trail \[m\].
    pub crumb_spacing_m: f64,
    /// Longest trail kept \[m\] (older crumbs are dropped).
    pub trail_length_m: f64,
    /// Tracking time without a trigger after which the ladder and thresholds reset \[s\].
    pub relax_after_s: f64,
    /// Distance to the target that counts as reached \[m\].
    pub goal_tolerance_m: f64,
}

fn default_backout_max_distance_m() -> f64 {
    8.0
}

impl Default for RecoveryConfig {
    fn default() -> Self {
        Self {
            progress_window_s: 8.0,
            progress_min_m: 0.3,
            stuck_plan_failures: 5,
            r_inst: 0.6,
            r_inst_step: 0.1,
            r_inst_ceiling: 0.9,
            r_total: 0.5,
            r_total_step: 0.15,
            r_total_ceiling: 0.95,
            rotate_tolerance_rad: 0.15,
            rotate_timeout_s: 8.0,
            backout_distance_m: 2.0,
            backout_carrot_m: 0.6,
            backout_timeout_s: 40.0,
            backout_max_distance_m: default_backout_max_distance_m(),
            crumb_spacing_m: 0.2,
            trail_length_m: 20.0,
            relax_after_s: 15.0,
            goal_tolerance_m: 0.5,
        }
    }
}

impl RecoveryConfig {
    /// Checks every field, naming it (`recovery.<field>`) on error.
    pub fn validate(&self) -> Result<()> {
        for (name, value) in [
            ("progress_window_s", self.progress_window_s),
            ("progress_min_m", self.progress_min_m),
            ("rotate_tolerance_rad", self.rotate_tolerance_rad),
            ("rotate_timeout_s", self.rotate_timeout_s),
            ("backout_distance_m", self.backout_distance_m),
            ("backout_carrot_m", self.backout_carrot_m),
            ("backout_timeout_s", self.backout_timeout_s),
            ("backout_max_distance_m", self.backout_max_distance_m),
            ("crumb_spacing_m", self.crumb_spacing_m),
            ("trail_length_m", self.trail_length_m),
            ("relax_after_s", self.relax_after_s),
            ("goal_tolerance_m", self.goal_tolerance_m),
        ] {
            require_positive(&format!("recovery.{name}"), value)?;
        }
        if self.stuck_plan_failures == 0 {
            return Err(Error::config("recovery.stuck_plan_failures", "must be >= 1", 0));
        }
        for (name, value) in [("r_inst", self.r_inst), ("r_total", self.r_total)] {
            if !(value.is_finite() && value > 0.0 && value <= 1.0) {
                return Err(Error::config(format!("recovery.{name}"), "must be in (0, 1]", value));
            }
        }
        for (name, value, nominal) in [
            ("r_inst_ceiling", self.r_inst_ceiling, self.r_inst),
            ("r_total_ceiling", self.r_total_ceiling, self.r_total),
        ] {
            if !(value.is_finite() && value >= nominal && value <= 1.0) {
                return Err(Error::config(format!("recovery.{name}"), format!("must be in [{nominal}, 1] (nominal .. 1)"), value));
            }
        }
        for (name, value) in [("r_inst_step", self.r_inst_step), ("r_total_step", self.r_total_step)] {
            if !(value.is_finite() && value > 0.0 && value <= 1.0) {
                return Err(Error::config(format!("recovery.{name}"), "must be in (0, 1]", value));
            }
        }
        if self.backout_max_distance_m < self.backout_distance_m {
            return Err(Error::config("recovery.backout_max_distance_m", "must be >= recovery.backout_distance_m", self.backout_max_distance_m));
        }
        if self.trail_length_m < self.backout_distance_m {
            return Err(Error::config("recovery.trail_length_m", "must be >= recovery.backout_distance_m", self.trail_length_m));
        }
        Ok(())
    }
}
