//! Adaptive thresholds and recovery behaviours (STEP, Fan et al. 2021): what a ground robot does
//! when the planner finds no path or the robot stops making progress.
//!
//! Documented on [`RecoveryMachine`].

mod config;
mod ladder;
mod tick;
#[cfg(test)]
mod tests;

use std::collections::VecDeque;
use std::f64::consts::PI;

use glam::DVec2;

use crate::error::{Error, Result};

pub use config::RecoveryConfig;
pub use tick::{Behaviour, Directive, PlanFeedback, RecoveryInput, Target, Transition};

/// The recovery state machine.
///
/// [`RecoveryMachine`] is a pure state machine: each control tick the navigator tells it
/// the time, the robot's pose, its distance to the current target and how the last plan
/// went ([`RecoveryInput`]); it answers with a [`Directive`]: which behaviour to run, the
/// planner thresholds to use, which target to drive to, and whether to clear the map.
/// It does no planning and sends no command itself.
///
/// # The machine, exactly
/// A **trigger** is either (a) the planner reporting no path (or none within the risk
/// budget) on `stuck_plan_failures` consecutive ticks, or (b) *no progress*: over the
/// last `progress_window_s` seconds the distance to the target shrank by less than
/// `progress_min_m` (checked only once that much time has passed since the last
/// transition, so each behaviour gets a fair window). When the navigator switches to a
/// longer route ([`RecoveryInput::route_switched`]), the window's samples are shifted by the
/// jump, so progress is measured along the new route; at most once a window, so a robot
/// whose plans keep switching still triggers. While tracking, each trigger
/// climbs one rung of the **ladder**; the rung reached decides the next behaviour:
///
/// 1. `ClearMap`: drop the fused map (stale or smeared scans can close a passage); one
///    tick, then back to `Track`.
/// 2. `Rotate`: turn in place to the heading of most clearance (given by the navigator
///    in [`RecoveryInput::clearance_heading_rad`]; without one, a half turn), until
///    within `rotate_tolerance_rad` of it or after `rotate_timeout_s`; then `Track`.
/// 3. `RaiseThresholds`: `R_inst += r_inst_step`, `R_total += r_total_step`, each capped
///    at its ceiling; then `Track` with the new thresholds. Repeated while a raise is
///    still possible (each further trigger raises one more step).
/// 4. `BackOut`: with both thresholds at their ceilings, reverse along the driven path
///    (the breadcrumb trail, one crumb every `crumb_spacing_m`) for `backout_distance_m`,
///    steering at a carrot `backout_carrot_m` back along the trail; ends when that far
///    from where it started and there is room to turn in place
///    ([`RecoveryInput::room_to_turn`]; without, at `backout_max_distance_m`), at the trail's
///    end, or after `backout_timeout_s`; then `Track`.
/// 5. A trigger after `BackOut` abandons the goal and turns for home: the target becomes
///    [`Target::Home`] (the home position given at construction) and the thresholds and the
///    ladder start again from the bottom. The same ladder runs on the way home; a trigger after its `BackOut` ends in
///    `Failed` (the robot stops).
///
/// **Progress relaxes the thresholds**: after `relax_after_s` seconds of tracking
/// without a trigger, the thresholds go back to their nominal values (the adaptive part:
/// raised thresholds are a temporary permission); the ladder itself goes back to rung 0
/// only when the robot is `progress_min_m` closer to the target (straight line) than the
/// least distance it had reached before the ladder's first trigger (it got past where it was stuck), so
/// a robot that keeps failing at the same place does reach back-out and giving up. Reaching the
/// target (distance `<= goal_tolerance_m`) ends in `GoalReached` (or `Home` on the way
/// back). Every transition is recorded as a [`Transition`] with its time and reason
/// (a relaxation too, as `track -> track`). The navigator may end a `Rotate` or a `BackOut`
/// early ([`RecoveryMachine::abort`]) when its next motion is not safe; that is an end like
/// any other, with its reason.
#[derive(Debug, Clone)]
pub struct RecoveryMachine {
    config: RecoveryConfig,
    home: DVec2,
    behaviour: Behaviour,
    target: Target,
    /// Rungs climbed since the ladder was last reset (0 = none).
    rung: u32,
    r_inst: f64,
    r_total: f64,
    entered_s: f64,
    last_trigger_s: f64,
    plan_failures: u32,
    /// (time, distance to target) samples of the current progress window.
    progress: VecDeque<(f64, f64)>,
    /// When the progress window was last shifted for a route switch.
    last_rebase_s: Option<f64>,
    /// Breadcrumbs, oldest first.
    trail: VecDeque<DVec2>,
    rotate_to: Option<f64>,
    /// Least distance to the target while tracking since the ladder was last reset \[m\].
    best_distance: f64,
    /// `best_distance` when the ladder's first rung was climbed \[m\].
    stuck_distance: f64,
    backout_start: Option<DVec2>,
    backout_index: usize,
    last_time_s: Option<f64>,
    transitions: Vec<Transition>,
}

impl RecoveryMachine {
    /// A machine that starts tracking toward the goal; `home` is where the robot drives once
    /// it gives the goal up ([`Target::Home`], world frame \[m\]).
    pub fn new(config: RecoveryConfig, home: DVec2) -> Result<Self> {
        config.validate()?;
        if !home.is_finite() {
            return Err(Error::input("home", format!("must be finite, got ({}, {})", home.x, home.y)));
        }
        Ok(Self {
            config,
            home,
            behaviour: Behaviour::Track,
            target: Target::Goal,
            rung: 0,
            r_inst: config.r_inst,
            r_total: config.r_total,
            entered_s: f64::NAN,
            last_trigger_s: f64::NAN,
            plan_failures: 0,
            progress: VecDeque::new(),
            last_rebase_s: None,
            trail: VecDeque::new(),
            rotate_to: None,
            best_distance: f64::INFINITY,
            stuck_distance: f64::INFINITY,
            backout_start: None,
            backout_index: 0,
            last_time_s: None,
            transitions: Vec::new(),
        })
    }

    /// The settings.
    pub fn config(&self) -> &RecoveryConfig {
        &self.config
    }

    /// The current behaviour.
    pub fn behaviour(&self) -> Behaviour {
        self.behaviour
    }

    /// The current target.
    pub fn target(&self) -> Target {
        self.target
    }

    /// Where the robot drives once it gives the goal up ([`Target::Home`]).
    pub fn home(&self) -> DVec2 {
        self.home
    }

    /// Moves home (world frame \[m\]).
    pub fn set_home(&mut self, home: DVec2) -> Result<()> {
        if !home.is_finite() {
            return Err(Error::input("home", format!("must be finite, got ({}, {})", home.x, home.y)));
        }
        self.home = home;
        Ok(())
    }

    /// The planner thresholds `(R_inst, R_total)` in force.
    pub fn thresholds(&self) -> (f64, f64) {
        (self.r_inst, self.r_total)
    }

    /// Every transition so far, oldest first.
    pub fn transitions(&self) -> &[Transition] {
        &self.transitions
    }

    /// The breadcrumb trail, oldest first (world frame \[m\]).
    pub fn trail(&self) -> impl Iterator<Item = DVec2> + '_ {
        self.trail.iter().copied()
    }

    /// Ends the current `Rotate` or `BackOut` at time `time_s` because its motion is not safe
    /// (the navigator checked the footprint it would sweep): back to `Track`, with `reason`
    /// in the transition. The robot stops; the ladder climbs on at the next trigger as after
    /// any other end of the behaviour. Other behaviours are left as they are.
    pub fn abort(&mut self, time_s: f64, reason: &str) {
        if matches!(self.behaviour, Behaviour::Rotate | Behaviour::BackOut) {
            let what = self.behaviour.name();
            self.enter(time_s, Behaviour::Track, format!("{what} stopped, no safe motion: {reason}"));
        }
    }

    /// Advances one tick and says what to do.
    pub fn step(&mut self, input: &RecoveryInput) -> Result<Directive> {
        self.check(input)?;
        let t = input.time_s;
        if self.entered_s.is_nan() {
            self.entered_s = t;
            self.last_trigger_s = t;
        }
        self.last_time_s = Some(t);
        if self.behaviour != Behaviour::BackOut {
            self.drop_crumb(input.position);
        }
        let mut clear_map = false;

        match self.behaviour {
            Behaviour::GoalReached | Behaviour::Home | Behaviour::Failed => {}
            Behaviour::ClearMap | Behaviour::RaiseThresholds => {
                // One-tick behaviours: their effect was handed out last tick.
                self.enter(t, Behaviour::Track, "done".to_owned());
            }
            Behaviour::Rotate => {
                let target = self.rotate_to.unwrap_or(input.yaw_rad);
                let error = wrap_angle(target - input.yaw_rad).abs();
                if error <= self.config.rotate_tolerance_rad {
                    self.enter(t, Behaviour::Track, format!("heading reached ({error:.2} rad off)"));
                } else if t - self.entered_s >= self.config.rotate_timeout_s {
                    self.enter(t, Behaviour::Track, format!("rotate timed out after {:.1} s, {error:.2} rad off", t - self.entered_s));
                }
            }
            Behaviour::BackOut => {
                let start = self.backout_start.unwrap_or(input.position);
                let moved = input.position.distance(start);
                if moved >= self.config.backout_distance_m && (input.room_to_turn || moved >= self.config.backout_max_distance_m) {
                    let room = if input.room_to_turn { "room to turn" } else { "no room to turn yet, the longest back-out" };
                    self.enter(t, Behaviour::Track, format!("backed out {moved:.2} m ({room})"));
                } else if self.backout_index == 0 && input.position.distance(self.trail.front().copied().unwrap_or(input.position)) < self.config.crumb_spacing_m {
                    self.enter(t, Behaviour::Track, format!("end of the trail after {moved:.2} m"));
                } else if t - self.entered_s >= self.config.backout_timeout_s {
                    self.enter(t, Behaviour::Track, format!("back-out timed out after {:.1} s, {moved:.2} m", t - self.entered_s));
                }
            }
            Behaviour::Track => {}
        }

        if self.behaviour == Behaviour::Track {
            if input.distance_to_target_m <= self.config.goal_tolerance_m {
                let (to, what) = match self.target {
                    Target::Goal => (Behaviour::GoalReached, "goal"),
                    Target::Home => (Behaviour::Home, "home"),
                };
                self.enter(t, to, format!("{what} reached ({:.2} m away)", input.distance_to_target_m));
            } else if let Some(reason) = self.trigger(input) {
                clear_map = self.climb(t, input, reason);
            } else {
                self.relax(t, input.straight_distance_m);
            }
        }
        if self.behaviour == Behaviour::Track {
            self.best_distance = self.best_distance.min(input.straight_distance_m);
        }
        self.record_progress(t, input.distance_to_target_m, input.route_switched);

        let backout_carrot = (self.behaviour == Behaviour::BackOut).then(|| self.backout_carrot(input.position));
        Ok(Directive {
            behaviour: self.behaviour,
            r_inst: self.r_inst,
            r_total: self.r_total,
            target: self.target,
            clear_map,
            rotate_to_rad: if self.behaviour == Behaviour::Rotate { self.rotate_to } else { None },
            backout_carrot,
        })
    }

    fn check(&self, input: &RecoveryInput) -> Result<()> {
        if !input.time_s.is_finite() {
            return Err(Error::input("time_s", format!("must be finite, got {}", input.time_s)));
        }
        if let Some(last) = self.last_time_s {
            if input.time_s < last {
                return Err(Error::input("time_s", format!("went backwards: {} after {last}", input.time_s)));
            }
        }
        if !input.position.is_finite() || !input.yaw_rad.is_finite() {
            return Err(Error::input("position", "position and yaw must be finite"));
        }
        if !(input.distance_to_target_m.is_finite() && input.distance_to_target_m >= 0.0) {
            return Err(Error::input("distance_to_target_m", format!("must be finite and >= 0, got {}", input.distance_to_target_m)));
        }
        if !(input.straight_distance_m.is_finite() && input.straight_distance_m >= 0.0) {
            return Err(Error::input("straight_distance_m", format!("must be finite and >= 0, got {}", input.straight_distance_m)));
        }
        if let Some(h) = input.clearance_heading_rad {
            if !h.is_finite() {
                return Err(Error::input("clearance_heading_rad", format!("must be finite, got {h}")));
            }
        }
        Ok(())
    }

    fn drop_crumb(&mut self, position: DVec2) {
        if self.trail.back().is_none_or(|last| last.distance(position) >= self.config.crumb_spacing_m) {
            self.trail.push_back(position);
            let max = (self.config.trail_length_m / self.config.crumb_spacing_m).ceil() as usize + 1;
            while self.trail.len() > max {
                self.trail.pop_front();
            }
        }
    }

    /// The carrot `backout_carrot_m` back along the trail from the crumb nearest behind.
    fn backout_carrot(&mut self, position: DVec2) -> DVec2 {
        if self.trail.is_empty() {
            return position;
        }
        // Move the index past crumbs already reached.
        while self.backout_index > 0 && position.distance(self.trail[self.backout_index]) < self.config.backout_carrot_m {
            self.backout_index -= 1;
        }
        self.trail[self.backout_index]
    }
}

/// `a` wrapped into (-π, π].
pub(super) fn wrap_angle(a: f64) -> f64 {
    let w = a.rem_euclid(2.0 * PI);
    if w > PI { w - 2.0 * PI } else { w }
}
