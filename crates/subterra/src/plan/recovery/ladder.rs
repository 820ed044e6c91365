//! The ladder itself (`RecoveryMachine`'s docs): what makes a trigger, the rung each trigger climbs to, the
//! relaxation of raised thresholds and of the ladder, and the progress window.

use std::f64::consts::PI;

use super::{wrap_angle, Behaviour, PlanFeedback, RecoveryInput, RecoveryMachine, Target, Transition};

/// Thresholds within this of their ceiling count as at the ceiling (sums of steps such
/// as 0.6 + 3 x 0.1 land a rounding error below 0.9).
const RAISE_EPS: f64 = 1e-9;

impl RecoveryMachine {
    /// The reason for a trigger this tick, if there is one.
    pub(super) fn trigger(&mut self, input: &RecoveryInput) -> Option<String> {
        match input.plan {
            PlanFeedback::NoPath | PlanFeedback::BudgetExceeded => self.plan_failures += 1,
            PlanFeedback::Found => self.plan_failures = 0,
            PlanFeedback::NotRun => {}
        }
        if self.plan_failures >= self.config.stuck_plan_failures {
            let what = if input.plan == PlanFeedback::BudgetExceeded { "no path within the risk budget" } else { "no path" };
            return Some(format!("{what} for {} ticks (R_inst {:.2}, R_total {:.2})", self.plan_failures, self.r_inst, self.r_total));
        }
        let window = self.config.progress_window_s;
        if input.time_s - self.entered_s < window {
            return None;
        }
        // The oldest sample at least a window old.
        let (_, then) = self.progress.iter().rev().find(|(ts, _)| input.time_s - ts >= window).copied()?;
        let gained = then - input.distance_to_target_m;
        (gained < self.config.progress_min_m)
            .then(|| format!("no progress: {gained:.2} m closer in {window:.1} s (< {:.2} m)", self.config.progress_min_m))
    }

    /// Climbs one rung after a trigger; returns whether to clear the map.
    pub(super) fn climb(&mut self, t: f64, input: &RecoveryInput, reason: String) -> bool {
        self.last_trigger_s = t;
        self.plan_failures = 0;
        if self.rung == 0 {
            self.stuck_distance = self.best_distance.min(input.straight_distance_m);
        }
        self.rung += 1;
        let can_raise = self.r_inst < self.config.r_inst_ceiling - RAISE_EPS || self.r_total < self.config.r_total_ceiling - RAISE_EPS;
        match self.rung {
            1 => {
                self.enter(t, Behaviour::ClearMap, reason);
                return true;
            }
            2 => {
                let heading = input.clearance_heading_rad.unwrap_or_else(|| wrap_angle(input.yaw_rad + PI));
                self.rotate_to = Some(heading);
                self.enter(t, Behaviour::Rotate, format!("{reason}; turning to {heading:.2} rad"));
            }
            // Backed out already and still stuck: give up (thresholds that relaxed while
            // backing out must not restart the raises).
            _ if self.backout_start.is_some() => match self.target {
                Target::Goal => {
                    self.target = Target::Home;
                    self.reset_ladder();
                    (self.r_inst, self.r_total) = (self.config.r_inst, self.config.r_total);
                    self.enter(t, Behaviour::Track, format!("{reason}; every behaviour tried: giving up the goal, returning home"));
                }
                Target::Home => self.enter(t, Behaviour::Failed, format!("{reason}; every behaviour tried on the way home")),
            },
            _ if can_raise => {
                let was = (self.r_inst, self.r_total);
                self.r_inst = raise(self.r_inst, self.config.r_inst_step, self.config.r_inst_ceiling);
                self.r_total = raise(self.r_total, self.config.r_total_step, self.config.r_total_ceiling);
                self.enter(t, Behaviour::RaiseThresholds, format!(
                    "{reason}; R_inst {:.2} -> {:.2}, R_total {:.2} -> {:.2}", was.0, self.r_inst, was.1, self.r_total,
                ));
            }
            _ => {
                self.backout_start = Some(input.position);
                self.backout_index = self.trail.len().saturating_sub(1);
                self.enter(t, Behaviour::BackOut, format!("{reason}; thresholds at their ceilings, reversing along the trail"));
            }
        }
        false
    }

    /// The adaptive part: raised thresholds go back to nominal after `relax_after_s` of
    /// tracking without a trigger; the ladder itself (the way to back-out and giving up)
    /// starts again only once the robot is `progress_min_m` closer to the target than it
    /// ever was before it got stuck.
    pub(super) fn relax(&mut self, t: f64, distance: f64) {
        let nominal = (self.config.r_inst, self.config.r_total);
        if (self.r_inst, self.r_total) != nominal && t - self.last_trigger_s >= self.config.relax_after_s {
            let was = (self.r_inst, self.r_total);
            (self.r_inst, self.r_total) = nominal;
            self.log(t, Behaviour::Track, Behaviour::Track, format!(
                "no trigger for {:.1} s: thresholds back to nominal (R_inst {:.2} -> {:.2}, R_total {:.2} -> {:.2})",
                self.config.relax_after_s, was.0, self.r_inst, was.1, self.r_total,
            ));
        }
        if self.rung > 0 && distance < self.stuck_distance - self.config.progress_min_m {
            let stuck = self.stuck_distance;
            self.reset_ladder();
            self.log(t, Behaviour::Track, Behaviour::Track, format!(
                "{distance:.2} m from the target, past where it got stuck ({stuck:.2} m): recovery ladder reset"
            ));
        }
    }

    /// Back to rung 0 (thresholds stay: they relax with time, see [`Self::relax`]).
    fn reset_ladder(&mut self) {
        self.rung = 0;
        self.stuck_distance = f64::INFINITY;
        self.best_distance = f64::INFINITY;
        self.backout_start = None;
        self.rotate_to = None;
        self.progress.clear();
    }

    pub(super) fn enter(&mut self, t: f64, to: Behaviour, reason: String) {
        let from = self.behaviour;
        self.behaviour = to;
        self.entered_s = t;
        self.progress.clear();
        self.plan_failures = 0;
        self.log(t, from, to, reason);
    }

    fn log(&mut self, time_s: f64, from: Behaviour, to: Behaviour, reason: String) {
        self.transitions.push(Transition { time_s, from, to, reason, r_inst: self.r_inst, r_total: self.r_total });
    }

    pub(super) fn record_progress(&mut self, t: f64, distance: f64, route_switched: bool) {
        // A switch to a longer route: the samples of the window are measured along the new
        // route from now on (shifted by the jump), once a window, so that choosing a longer,
        // safer way is not a stall but two switches in one window still are.
        if let Some(&(_, last)) = self.progress.back() {
            let jump = distance - last;
            if route_switched && jump > 0.0 && self.last_rebase_s.is_none_or(|r| t - r >= self.config.progress_window_s) {
                for sample in &mut self.progress {
                    sample.1 += jump;
                }
                self.last_rebase_s = Some(t);
            }
        }
        self.progress.push_back((t, distance));
        // Keep one sample older than the window, drop the rest.
        while self.progress.len() > 2 && t - self.progress[1].0 >= self.config.progress_window_s {
            self.progress.pop_front();
        }
    }
}

/// `value + step`, snapped to `ceiling` when within [`RAISE_EPS`] of it or above.
fn raise(value: f64, step: f64, ceiling: f64) -> f64 {
    let raised = value + step;
    if raised >= ceiling - RAISE_EPS { ceiling } else { raised }
}
