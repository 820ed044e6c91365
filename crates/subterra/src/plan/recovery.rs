//! Adaptive thresholds and recovery behaviours (STEP, Fan et al. 2021): what a ground robot does
//! when the planner finds no path or the robot stops making progress.
//!
//! [`RecoveryMachine`] is a pure state machine: each control tick the navigator tells it
//! the time, the robot's pose, its distance to the current target and how the last plan
//! went ([`RecoveryInput`]); it answers with a [`Directive`]: which behaviour to run, the
//! planner thresholds to use, which target to drive to, and whether to clear the map.
//! It does no planning and sends no command itself.
//!
//! # The machine, exactly
//! A **trigger** is either (a) the planner reporting no path (or none within the risk
//! budget) on `stuck_plan_failures` consecutive ticks, or (b) *no progress*: over the
//! last `progress_window_s` seconds the distance to the target shrank by less than
//! `progress_min_m` (checked only once that much time has passed since the last
//! transition, so each behaviour gets a fair window). When the navigator switches to a
//! longer route ([`RecoveryInput::route_switched`]), the window's samples are shifted by the
//! jump, so progress is measured along the new route; at most once a window, so a robot
//! whose plans keep switching still triggers. While tracking, each trigger
//! climbs one rung of the **ladder**; the rung reached decides the next behaviour:
//!
//! 1. `ClearMap`: drop the fused map (stale or smeared scans can close a passage); one
//!    tick, then back to `Track`.
//! 2. `Rotate`: turn in place to the heading of most clearance (given by the navigator
//!    in [`RecoveryInput::clearance_heading_rad`]; without one, a half turn), until
//!    within `rotate_tolerance_rad` of it or after `rotate_timeout_s`; then `Track`.
//! 3. `RaiseThresholds`: `R_inst += r_inst_step`, `R_total += r_total_step`, each capped
//!    at its ceiling; then `Track` with the new thresholds. Repeated while a raise is
//!    still possible (each further trigger raises one more step).
//! 4. `BackOut`: with both thresholds at their ceilings, reverse along the driven path
//!    (the breadcrumb trail, one crumb every `crumb_spacing_m`) for `backout_distance_m`,
//!    steering at a carrot `backout_carrot_m` back along the trail; ends when that far
//!    from where it started and there is room to turn in place
//!    ([`RecoveryInput::room_to_turn`]; without, at `backout_max_distance_m`), at the trail's
//!    end, or after `backout_timeout_s`; then `Track`.
//! 5. A trigger after `BackOut` abandons the goal: `ReturnHome` (the target becomes the
//!    home position given at construction; thresholds and ladder start again from the
//!    bottom). The same ladder runs on the way home; a trigger after its `BackOut` ends in
//!    `Failed` (the robot stops).
//!
//! **Progress relaxes the thresholds**: after `relax_after_s` seconds of tracking
//! without a trigger, the thresholds go back to their nominal values (the adaptive part:
//! raised thresholds are a temporary permission); the ladder itself goes back to rung 0
//! only when the robot is `progress_min_m` closer to the target (straight line) than the
//! least distance it had reached before the ladder's first trigger (it got past where it was stuck), so
//! a robot that keeps failing at the same place does reach back-out and giving up. Reaching the
//! target (distance `<= goal_tolerance_m`) ends in `GoalReached` (or `Home` on the way
//! back). Every transition is recorded as a [`Transition`] with its time and reason
//! (a relaxation too, as `track -> track`). The navigator may end a `Rotate` or a `BackOut`
//! early ([`RecoveryMachine::abort`]) when its next motion is not safe; that is an end like
//! any other, with its reason.

use std::collections::VecDeque;
use std::f64::consts::PI;
use std::fmt;

use glam::DVec2;
use serde::{Deserialize, Serialize};

use crate::error::{require_positive, Error, Result};

/// Thresholds within this of their ceiling count as at the ceiling (sums of steps such
/// as 0.6 + 3 x 0.1 land a rounding error below 0.9).
const RAISE_EPS: f64 = 1e-9;

/// Settings of the recovery ladder. Defaults: values that suit a Husky-sized robot at
/// 1 m/s in a mine (chosen for the `mine` scenario; STEP gives no numbers).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecoveryConfig {
    /// Window over which progress toward the target is measured [s].
    pub progress_window_s: f64,
    /// Least decrease of the distance to the target over the window that counts as
    /// progress [m].
    pub progress_min_m: f64,
    /// Consecutive ticks without a plan that make a trigger [ticks].
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
    /// Heading error at which `Rotate` is done [rad].
    pub rotate_tolerance_rad: f64,
    /// Longest `Rotate` [s].
    pub rotate_timeout_s: f64,
    /// Distance `BackOut` reverses along the trail [m].
    pub backout_distance_m: f64,
    /// How far back along the trail the `BackOut` carrot is [m].
    pub backout_carrot_m: f64,
    /// Longest `BackOut` [s].
    pub backout_timeout_s: f64,
    /// `BackOut` goes on past `backout_distance_m` while the robot has no room to turn in
    /// place (a corridor it drove into), up to this distance [m].
    #[serde(default = "default_backout_max_distance_m")]
    pub backout_max_distance_m: f64,
    /// Spacing of the breadcrumb trail [m].
    pub crumb_spacing_m: f64,
    /// Longest trail kept [m] (older crumbs are dropped).
    pub trail_length_m: f64,
    /// Tracking time without a trigger after which the ladder and thresholds reset [s].
    pub relax_after_s: f64,
    /// Distance to the target that counts as reached [m].
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
    /// Time [s]; must not go backwards.
    pub time_s: f64,
    /// Robot position, world frame [m].
    pub position: DVec2,
    /// Robot heading, world frame [rad].
    pub yaw_rad: f64,
    /// Distance from the robot to the current target [m] (path length if known, else
    /// straight line).
    pub distance_to_target_m: f64,
    /// Straight-line distance from the robot to the target [m] (decides when the robot got
    /// past where it was stuck; the path-based distance above jumps when a replan finds
    /// another way).
    pub straight_distance_m: f64,
    /// How the planner's last call went.
    pub plan: PlanFeedback,
    /// Heading of most clearance around the robot, world frame [rad], if the navigator
    /// computed one (used when entering `Rotate`).
    pub clearance_heading_rad: Option<f64>,
    /// Whether the robot could turn in place here (the navigator checked the footprint a full
    /// turn sweeps): `BackOut` goes on past `backout_distance_m` while it could not.
    pub room_to_turn: bool,
    /// Whether this tick's plan rerouted the robot (the navigator sets it when a new plan
    /// lengthens the way by more than `progress_min_m`): that jump in
    /// `distance_to_target_m` is then not lost progress (module docs), at most once a
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
    /// `Rotate`: the heading to turn to, world frame [rad].
    pub rotate_to_rad: Option<f64>,
    /// `BackOut`: the point on the trail to reverse toward, world frame [m].
    pub backout_carrot: Option<DVec2>,
}

/// One recorded change of behaviour.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Transition {
    /// When [s].
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

/// The recovery state machine (see the module docs for its exact rules).
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
    /// Least distance to the target while tracking since the ladder was last reset [m].
    best_distance: f64,
    /// `best_distance` when the ladder's first rung was climbed [m].
    stuck_distance: f64,
    backout_start: Option<DVec2>,
    backout_index: usize,
    last_time_s: Option<f64>,
    transitions: Vec<Transition>,
}

impl RecoveryMachine {
    /// A machine that starts tracking toward the goal; `home` is where `ReturnHome`
    /// drives to (world frame [m]).
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

    /// Where `ReturnHome` drives to.
    pub fn home(&self) -> DVec2 {
        self.home
    }

    /// Moves home (world frame [m]).
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

    /// The breadcrumb trail, oldest first (world frame [m]).
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

    /// The reason for a trigger this tick, if there is one.
    fn trigger(&mut self, input: &RecoveryInput) -> Option<String> {
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
    fn climb(&mut self, t: f64, input: &RecoveryInput, reason: String) -> bool {
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
    fn relax(&mut self, t: f64, distance: f64) {
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

    fn enter(&mut self, t: f64, to: Behaviour, reason: String) {
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

    fn record_progress(&mut self, t: f64, distance: f64, route_switched: bool) {
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

/// `value + step`, snapped to `ceiling` when within [`RAISE_EPS`] of it or above.
fn raise(value: f64, step: f64, ceiling: f64) -> f64 {
    let raised = value + step;
    if raised >= ceiling - RAISE_EPS { ceiling } else { raised }
}

/// `a` wrapped into (-π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let w = a.rem_euclid(2.0 * PI);
    if w > PI { w - 2.0 * PI } else { w }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input(t: f64, x: f64, d: f64, plan: PlanFeedback) -> RecoveryInput {
        RecoveryInput {
            time_s: t,
            position: DVec2::new(x, 0.0),
            yaw_rad: 0.0,
            distance_to_target_m: d,
            straight_distance_m: d,
            plan,
            clearance_heading_rad: Some(1.0),
            room_to_turn: true,
            route_switched: false,
        }
    }

    fn machine() -> RecoveryMachine {
        RecoveryMachine::new(RecoveryConfig::default(), DVec2::ZERO).unwrap()
    }

    #[test]
    fn progress_keeps_tracking_and_goal_ends_the_run() {
        let mut m = machine();
        for k in 0..350 {
            let t = k as f64 * 0.1;
            let d = 15.0 - t * 0.5; // 0.5 m/s toward the goal
            let out = m.step(&input(t, t * 0.5, d.max(0.0), PlanFeedback::Found)).unwrap();
            if d > 0.5 {
                assert_eq!(out.behaviour, Behaviour::Track, "t = {t}");
            }
        }
        assert_eq!(m.behaviour(), Behaviour::GoalReached);
        assert_eq!(m.transitions().len(), 1);
        assert!(m.transitions()[0].reason.contains("goal reached"));
    }

    #[test]
    fn plan_failures_climb_the_whole_ladder_in_order() {
        let mut m = machine();
        let mut seen = Vec::new();
        let mut t = 0.0;
        let mut x = 0.0;
        for _ in 0..400 {
            let out = m.step(&input(t, x, 10.0, PlanFeedback::NoPath)).unwrap();
            if seen.last() != Some(&out.behaviour) {
                seen.push(out.behaviour);
            }
            match out.behaviour {
                // Rotating: report the heading as reached at once.
                Behaviour::BackOut => x -= 0.05,
                Behaviour::Failed => break,
                _ => {}
            }
            t += 0.1;
            if out.behaviour == Behaviour::Rotate {
                // The robot turns to the asked heading.
                let out = m.step(&RecoveryInput { time_s: t, yaw_rad: 1.0, ..input(t, x, 10.0, PlanFeedback::NoPath) }).unwrap();
                assert_eq!(out.behaviour, Behaviour::Track);
                t += 0.1;
            }
        }
        use Behaviour::*;
        // Goal: clear, rotate, raise x3 (0.6 -> 0.9), back out; then home: the same, then failed.
        let ladder = [ClearMap, Track, Rotate, Track, RaiseThresholds, Track, RaiseThresholds, Track, RaiseThresholds, Track, BackOut, Track];
        // The switch to home is track -> track, so it does not show in `seen`.
        let mut expected = vec![Track];
        expected.extend_from_slice(&ladder);
        expected.extend_from_slice(&ladder);
        expected.push(Failed);
        assert_eq!(seen, expected);
        let home_switch = m.transitions().iter().position(|tr| tr.reason.contains("returning home")).unwrap();
        assert!(m.transitions()[..home_switch].iter().any(|tr| (tr.r_inst - 0.9).abs() < 1e-12));
        assert_eq!(m.transitions()[home_switch].r_inst, 0.6, "thresholds reset for the way home");
        assert_eq!(m.target(), Target::Home);
        assert!(m.transitions().iter().all(|tr| !tr.reason.is_empty()));
    }

    #[test]
    fn clear_map_is_asked_once_on_the_first_trigger() {
        let mut m = machine();
        let mut clears = 0;
        for k in 0..5 {
            let out = m.step(&input(k as f64 * 0.1, 0.0, 10.0, PlanFeedback::NoPath)).unwrap();
            clears += out.clear_map as u32;
            if k == 4 {
                assert!(out.clear_map);
                assert_eq!(out.behaviour, Behaviour::ClearMap);
            }
        }
        assert_eq!(clears, 1);
    }

    #[test]
    fn no_progress_triggers_after_a_full_window_only() {
        let mut m = machine();
        let mut first = None;
        for k in 0..200 {
            let t = k as f64 * 0.1;
            let d = 10.0 - 0.02 * t; // 0.16 m per 8 s window: too slow
            let out = m.step(&input(t, 0.0, d, PlanFeedback::Found)).unwrap();
            if out.behaviour == Behaviour::ClearMap {
                first = Some(t);
                break;
            }
        }
        let t = first.expect("no trigger");
        assert!((8.0..=8.15).contains(&t), "triggered at {t}");
        assert!(m.transitions()[0].reason.starts_with("no progress: 0.16 m"));
    }

    /// Drives at 0.5 m/s toward a target 10 m off; at `t = 3 s` the plan switches to a route
    /// 4 m longer (and, with `again`, at 6 s back to one 4 m longer still). The first switch
    /// is progress along the new route; a second within the window is not.
    fn drive_with_switches(again: bool) -> Option<f64> {
        let mut m = machine();
        for k in 0..160 {
            let t = k as f64 * 0.1;
            let extra = if t >= 6.0 && again { 8.0 } else if t >= 3.0 { 4.0 } else { 0.0 };
            let switched = (k == 30) || (again && k == 60);
            let d = 10.0 - 0.5 * t + extra;
            let out = m.step(&RecoveryInput { route_switched: switched, ..input(t, 0.0, d, PlanFeedback::Found) }).unwrap();
            if out.behaviour != Behaviour::Track {
                return Some(t);
            }
        }
        None
    }

    #[test]
    fn a_switch_to_a_longer_route_is_not_lost_progress_but_dithering_is() {
        assert_eq!(drive_with_switches(false), None, "one switch: progress along the new route");
        let t = drive_with_switches(true).expect("two switches in one window: no progress");
        assert!((8.0..=9.0).contains(&t), "triggered at {t}");
        // Without the flag, the same jump is a stall.
        let mut m = machine();
        let stalled = (0..160).map(|k| k as f64 * 0.1).find(|&t| {
            let d = 10.0 - 0.5 * t + if t >= 3.0 { 4.0 } else { 0.0 };
            m.step(&input(t, 0.0, d, PlanFeedback::Found)).unwrap().behaviour != Behaviour::Track
        });
        assert!(stalled.is_some());
    }

    #[test]
    fn sustained_progress_relaxes_raised_thresholds() {
        let cfg = RecoveryConfig::default();
        let mut m = machine();
        let mut t = 0.0;
        // Three triggers: clear, rotate (reached at once), raise.
        while m.transitions().iter().filter(|tr| tr.to == Behaviour::RaiseThresholds).count() == 0 {
            let yaw = if m.behaviour() == Behaviour::Rotate { 1.0 } else { 0.0 };
            m.step(&RecoveryInput { yaw_rad: yaw, ..input(t, 0.0, 10.0, PlanFeedback::NoPath) }).unwrap();
            t += 0.1;
        }
        let out = m.step(&input(t, 0.0, 10.0, PlanFeedback::Found)).unwrap();
        assert!((out.r_inst - (cfg.r_inst + cfg.r_inst_step)).abs() < 1e-12);
        let raised_at = t;
        let mut d = 10.0;
        while t < raised_at + cfg.relax_after_s + 0.5 {
            t += 0.1;
            d -= 0.05;
            m.step(&input(t, 0.0, d, PlanFeedback::Found)).unwrap();
        }
        let out = m.step(&input(t + 0.1, 0.0, d - 0.05, PlanFeedback::Found)).unwrap();
        assert_eq!((out.r_inst, out.r_total), (cfg.r_inst, cfg.r_total));
        assert!(m.transitions().iter().any(|tr| tr.reason.contains("past where it got stuck")), "{:?}", m.transitions().last());
    }

    /// Drives 5 m along +x, gets stuck, and backs out with `room_to_turn(x)`; the distance
    /// backed out.
    fn back_out_until(room_to_turn: impl Fn(f64) -> bool) -> f64 {
        let mut m = machine();
        let mut t = 0.0;
        for k in 0..100 {
            t = k as f64 * 0.1;
            m.step(&input(t, 0.05 * k as f64, 10.0 - 0.05 * k as f64, PlanFeedback::Found)).unwrap();
        }
        let mut x = 4.95;
        let mut started = None;
        for _ in 0..2000 {
            t += 0.1;
            let yaw = if m.behaviour() == Behaviour::Rotate { 1.0 } else { 0.0 };
            let out = m.step(&RecoveryInput { yaw_rad: yaw, room_to_turn: room_to_turn(x), ..input(t, x, 5.05, PlanFeedback::NoPath) }).unwrap();
            if out.behaviour == Behaviour::BackOut {
                started.get_or_insert(x);
                x -= 0.02;
            } else if let Some(x0) = started {
                return x0 - x;
            }
        }
        panic!("never backed out");
    }

    #[test]
    fn backout_goes_on_until_there_is_room_to_turn() {
        // Room everywhere: the nominal 2 m.
        assert!((back_out_until(|_| true) - 2.0).abs() < 0.05);
        // A corridor: no room to turn until x < 1.5 (3.45 m back).
        let d = back_out_until(|x| x < 1.5);
        assert!((d - 3.45).abs() < 0.05, "{d}");
        // Never room (the trail is 5 m long): at the trail's end, before the 8 m limit.
        assert!(back_out_until(|_| false) <= 5.0);
    }

    #[test]
    fn backout_follows_the_trail_backwards() {
        let mut m = machine();
        // Drive 5 m along +x, then get stuck for good.
        let mut t = 0.0;
        for k in 0..100 {
            t = k as f64 * 0.1;
            m.step(&input(t, 0.05 * k as f64, 10.0 - 0.05 * k as f64, PlanFeedback::Found)).unwrap();
        }
        let mut x = 4.95;
        let mut carrots = Vec::new();
        for _ in 0..400 {
            t += 0.1;
            let yaw = if m.behaviour() == Behaviour::Rotate { 1.0 } else { 0.0 };
            let out = m.step(&RecoveryInput { yaw_rad: yaw, ..input(t, x, 5.05, PlanFeedback::NoPath) }).unwrap();
            if out.behaviour == Behaviour::BackOut {
                let c = out.backout_carrot.unwrap();
                assert!(c.x < x && c.x >= x - 1.0, "carrot {c} behind the robot at x = {x}");
                carrots.push(c.x);
                x -= 0.05;
            } else if !carrots.is_empty() {
                break;
            }
        }
        assert!(carrots.windows(2).all(|w| w[1] <= w[0]), "carrots move back along the trail");
        let done = m.transitions().iter().find(|tr| tr.from == Behaviour::BackOut).unwrap();
        assert!(done.reason.starts_with("backed out 2.0"), "{}", done.reason);
    }

    #[test]
    fn bad_inputs_and_configs_name_the_field() {
        let mut m = machine();
        m.step(&input(1.0, 0.0, 5.0, PlanFeedback::Found)).unwrap();
        let err = m.step(&input(0.5, 0.0, 5.0, PlanFeedback::Found)).unwrap_err();
        assert!(err.to_string().contains("time_s"));
        let err = m.step(&input(2.0, f64::NAN, 5.0, PlanFeedback::Found)).unwrap_err();
        assert!(err.to_string().contains("position"));
        let err = m.step(&input(2.0, 0.0, -1.0, PlanFeedback::Found)).unwrap_err();
        assert!(err.to_string().contains("distance_to_target_m"));
        let bad = RecoveryConfig { r_inst_ceiling: 0.5, ..RecoveryConfig::default() };
        assert!(RecoveryMachine::new(bad, DVec2::ZERO).unwrap_err().to_string().contains("recovery.r_inst_ceiling"));
        let bad = RecoveryConfig { progress_window_s: f64::NAN, ..RecoveryConfig::default() };
        assert!(RecoveryMachine::new(bad, DVec2::ZERO).unwrap_err().to_string().contains("recovery.progress_window_s"));
        assert!(RecoveryMachine::new(RecoveryConfig::default(), DVec2::NAN).is_err());
    }

    #[test]
    fn wrap_angle_stays_in_range() {
        for a in [-7.0, -PI, -1.0, 0.0, 1.0, PI, 4.0, 100.0] {
            let w = wrap_angle(a);
            assert!(w > -PI - 1e-12 && w <= PI + 1e-12);
            assert!(((a - w) / (2.0 * PI)).fract().abs() < 1e-9 || ((a - w) / (2.0 * PI)).fract().abs() > 1.0 - 1e-9);
        }
    }
}
