//! The navigator: terrain mapper + risk-aware A* + MPC tracker + recovery machine, wired
//! for a robot's own control loop (DESIGN §3). One [`Navigator::step`] per control tick.
//!
//! # One step, exactly
//! 1. **Map.** With a scan, [`TerrainMapper::update`] at the odometry pose; the coarse
//!    map is kept. Without one, the last map stands.
//! 2. **Risk grid.** The coarse map's `risk` layer, or with `navigator.cvar_alpha` its
//!    `CVaR_α` (risk-averse planning on the uncertainty of DESIGN §2), where the map has
//!    observed the cell; NaN (priced by the planner's `unknown_risk`, default
//!    [`UNSEEN_RISK_PER_M`]) where it has not. The local risk is the grid's value under the
//!    robot (`unknown_risk` when NaN or off the map).
//! 3. **Plan** (only while tracking, and at most every `replan_period_s` unless the last
//!    plan failed, the thresholds or the target changed): A* with the recovery machine's
//!    current `R_inst`/`R_total` from the robot's cell to the target — the goal, or home
//!    after the goal was given up. A target off the map is replaced by the map cell on
//!    the segment robot→target nearest to it, one cell inside the edge, moved to the
//!    nearest cell below `R_inst` within `standin_search_m` if it is not one (the planner
//!    sees only the local map; the rest of the way counts as straight). The distance to the
//!    target the recovery machine measures progress by is the path's length plus that
//!    straight remainder when a path was found, else the straight-line distance.
//! 4. **Recovery.** [`RecoveryMachine::step`] with the plan's outcome (a path within
//!    thresholds, none, or none within the budget) and the heading of most clearance
//!    (step 6) gives the behaviour for this tick.
//! 5. **Act.** `track`: the MPC on the last path (the risk grid gives its speed limits and
//!    obstacle polygons); no path yet: stop. `clear_map`: drop the mapper's window, stop.
//!    `rotate`: `v = 0`, `ω = clamp(k_rot·wrap(ψ* - ψ), ±ω_max)`. `back_out`: reverse toward
//!    the machine's carrot: with `e = wrap(bearing of the carrot in the body frame - π)`,
//!    `ω = clamp(k_rot·e, ±ω_max)`, `v = -v_back·max(cos e, 0)`, and `v = 0` while a cell
//!    `backout_clearance_m` behind the footprint's rear corners or centre is at or above
//!    `R_inst` (the robot cannot see behind it well; it must not back into what it mapped). `raise_thresholds` and the
//!    final behaviours: stop.
//! 6. **Clearance heading.** Over `clearance_headings` evenly spaced headings, the distance
//!    the grid stays below `R_inst` along a ray from the robot (cell steps, up to
//!    `clearance_range_m`); the longest wins, ties to the heading nearest the target's
//!    bearing.
//!
//! Every stage's wall time is reported; nothing here allocates per step beyond the
//! outputs it returns.

use std::f64::consts::PI;
use std::time::Instant;

use glam::DVec2;
use serde::{Deserialize, Serialize};

use crate::error::{require_positive, Error, Result};
use crate::frames::Isometry3;
use crate::plan::astar::{PlanOutcome, PlanStatus, RiskAStar, RiskAStarConfig, RiskGrid};
use crate::plan::mpc::{MpcConfig, MpcOutput, MpcTracker, RiskGrid as MpcRiskGrid, UnicycleState};
use crate::plan::recovery::{wrap_angle, Behaviour, PlanFeedback, RecoveryConfig, RecoveryInput, RecoveryMachine, Target, Transition};
use crate::terrain::{RiskMap, RobotConfig, TerrainConfig, TerrainMapper, TerrainStats, TerrainTimings};

/// Risk per metre the navigator's planner gives an unobserved cell. Smaller than the map's
/// display value `risk.unknown` (0.15): with the per-metre budget, 0.15 would spend
/// `R_total` = 0.5 on 4.3 m of unseen ground, and the goal is usually beyond what the
/// sensor has seen. subterra.
pub const UNSEEN_RISK_PER_M: f64 = 0.03;

/// Settings of the wiring itself.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NavigatorSettings {
    /// Least time between two plans while tracking [s].
    pub replan_period_s: f64,
    /// `None`: plan on the mean risk; `Some(α)`: on its `CVaR_α`, α in (0, 1).
    pub cvar_alpha: Option<f64>,
    /// Proportional gain of the heading loops of `rotate` and `back_out` [1/s].
    pub turn_gain_per_s: f64,
    /// Yaw-rate limit of those loops [rad/s].
    pub max_turn_rate_rad_s: f64,
    /// Reversing speed of `back_out` [m/s].
    pub backout_speed_m_s: f64,
    /// `back_out` stops reversing while a cell this far behind the footprint's rear edge
    /// (at its corners or centre) is at or above `R_inst` [m].
    pub backout_clearance_m: f64,
    /// Headings tried for the clearance heading.
    pub clearance_headings: u32,
    /// Longest clearance ray [m].
    pub clearance_range_m: f64,
    /// How far from a target off the map its stand-in on the map edge may move to reach a
    /// traversable cell [m].
    pub standin_search_m: f64,
}

impl Default for NavigatorSettings {
    fn default() -> Self {
        Self {
            replan_period_s: 0.5,
            cvar_alpha: None,
            turn_gain_per_s: 1.5,
            max_turn_rate_rad_s: 1.0,
            backout_speed_m_s: 0.3,
            backout_clearance_m: 0.3,
            clearance_headings: 16,
            clearance_range_m: 5.0,
            standin_search_m: 3.0,
        }
    }
}

impl NavigatorSettings {
    /// Checks every field, naming it (`navigator.<field>`).
    pub fn validate(&self) -> Result<()> {
        require_positive("navigator.replan_period_s", self.replan_period_s)?;
        require_positive("navigator.turn_gain_per_s", self.turn_gain_per_s)?;
        require_positive("navigator.max_turn_rate_rad_s", self.max_turn_rate_rad_s)?;
        require_positive("navigator.backout_speed_m_s", self.backout_speed_m_s)?;
        require_positive("navigator.backout_clearance_m", self.backout_clearance_m)?;
        require_positive("navigator.clearance_range_m", self.clearance_range_m)?;
        require_positive("navigator.standin_search_m", self.standin_search_m)?;
        if !(4..=360).contains(&self.clearance_headings) {
            return Err(Error::config("navigator.clearance_headings", "must be in [4, 360]", self.clearance_headings));
        }
        if let Some(a) = self.cvar_alpha {
            if !(a.is_finite() && a > 0.0 && a < 1.0) {
                return Err(Error::config("navigator.cvar_alpha", "must be in (0, 1) or absent", a));
            }
        }
        Ok(())
    }
}

/// Everything a [`Navigator`] is configured by.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct NavigatorConfig {
    /// The planner (its `r_inst`/`r_total` are replaced by the recovery machine's).
    pub planner: RiskAStarConfig,
    /// The MPC tracker.
    pub tracker: MpcConfig,
    /// The recovery ladder and the nominal thresholds.
    pub recovery: RecoveryConfig,
    /// The wiring.
    pub navigator: NavigatorSettings,
}

impl NavigatorConfig {
    /// The defaults for `robot`: the MPC's footprint and limits follow the robot; the
    /// planner prices unobserved cells at [`UNSEEN_RISK_PER_M`].
    pub fn for_robot(robot: &RobotConfig) -> Self {
        Self {
            planner: RiskAStarConfig { unknown_risk: UNSEEN_RISK_PER_M, ..RiskAStarConfig::default() },
            tracker: MpcConfig::for_robot(robot),
            ..Self::default()
        }
    }

    /// Checks every section.
    pub fn validate(&self) -> Result<()> {
        self.planner.validate()?;
        self.tracker.validate()?;
        self.recovery.validate()?;
        self.navigator.validate()
    }
}

/// One control tick's inputs.
#[derive(Debug, Clone, Copy)]
pub struct NavigatorInput<'a> {
    /// Time [s]; must not go backwards.
    pub stamp_s: f64,
    /// A new scan, `(N, 3)` flat, sensor frame [m], or `None`.
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

/// Wall time of each stage of one step [s].
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
    /// The path being tracked (the last found), world [m].
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
}

/// The ground robot's navigation stack (see the module docs).
#[derive(Debug)]
pub struct Navigator {
    config: NavigatorConfig,
    robot: RobotConfig,
    mapper: TerrainMapper,
    planner: RiskAStar,
    tracker: MpcTracker,
    recovery: RecoveryMachine,
    goal: DVec2,
    map: Option<RiskMap>,
    plan_risk: Vec<f32>,
    path: Vec<DVec2>,
    remainder_m: f64,
    last_plan_s: Option<f64>,
    last_plan_ok: bool,
    planned_for: Option<(f64, f64, Target)>,
    transitions_seen: usize,
    home_pending: bool,
    terrain_stats: (TerrainStats, TerrainTimings),
}

impl Navigator {
    /// A navigator for `robot` on `terrain` settings, driving to `goal` and back to `home`
    /// when it gives up (world frame [m]; `None`: where the robot is at its first step).
    pub fn new(robot: RobotConfig, terrain: TerrainConfig, config: NavigatorConfig, goal: DVec2, home: Option<DVec2>) -> Result<Self> {
        config.validate()?;
        if !goal.is_finite() {
            return Err(Error::input("goal", format!("must be finite, got ({}, {})", goal.x, goal.y)));
        }
        let mapper = TerrainMapper::new(robot, terrain)?;
        let planner = RiskAStar::new(config.planner)?;
        let tracker = MpcTracker::new(config.tracker)?;
        let recovery = RecoveryMachine::new(config.recovery, home.unwrap_or(DVec2::ZERO))?;
        Ok(Self {
            config,
            robot,
            mapper,
            planner,
            tracker,
            recovery,
            goal,
            map: None,
            plan_risk: Vec::new(),
            path: Vec::new(),
            remainder_m: 0.0,
            last_plan_s: None,
            last_plan_ok: false,
            planned_for: None,
            transitions_seen: 0,
            home_pending: home.is_none(),
            terrain_stats: (TerrainStats::default(), TerrainTimings::default()),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &NavigatorConfig {
        &self.config
    }

    /// The robot.
    pub fn robot(&self) -> &RobotConfig {
        &self.robot
    }

    /// The last coarse risk map, if a scan has arrived.
    pub fn risk_map(&self) -> Option<&RiskMap> {
        self.map.as_ref()
    }

    /// Counts and stage times of the last map update.
    pub fn last_terrain_stats(&self) -> (TerrainStats, TerrainTimings) {
        self.terrain_stats
    }

    /// The recovery machine (behaviour, transitions, trail).
    pub fn recovery(&self) -> &RecoveryMachine {
        &self.recovery
    }

    /// The goal [m, world].
    pub fn goal(&self) -> DVec2 {
        self.goal
    }

    /// One control tick (module docs).
    pub fn step(&mut self, input: &NavigatorInput<'_>) -> Result<NavigatorOutput> {
        let started = Instant::now();
        if !(input.speed_m_s.is_finite()) {
            return Err(Error::input("speed", format!("must be finite, got {}", input.speed_m_s)));
        }
        let pose = &input.world_from_body;
        let position = DVec2::new(pose.translation.x, pose.translation.y);
        let heading = yaw_of(pose);
        if self.home_pending {
            self.recovery.set_home(position)?;
            self.home_pending = false;
        }

        // 1. Map.
        if let Some(points) = input.points_sensor {
            let out = self.mapper.update(points, input.stamp_s, &input.world_from_body, &input.body_from_sensor, input.confidence)?;
            self.terrain_stats = (out.stats, out.timings);
            let map = out.coarse;
            // The planner's grid: risk (or its CVaR) where observed, NaN elsewhere so that
            // the planner's own `unknown_risk` prices the unseen.
            let risk = match self.config.navigator.cvar_alpha {
                Some(alpha) => map.cvar(alpha)?,
                None => map.layer("risk")?.to_vec(),
            };
            let observed = map.layer("observed")?;
            self.plan_risk.clear();
            self.plan_risk.extend(risk.iter().zip(observed).map(|(&r, &o)| if o > 0.0 { r } else { f32::NAN }));
            self.map = Some(map);
        }
        let t_map = Instant::now();
        let mut timings = NavigatorTimings { map_s: (t_map - started).as_secs_f64(), ..NavigatorTimings::default() };

        let unknown = self.config.planner.unknown_risk;
        let target_point = match self.recovery.target() {
            Target::Goal => self.goal,
            Target::Home => self.recovery.home(),
        };
        let straight = position.distance(target_point);
        let Some(map) = self.map.as_ref() else {
            // No map yet: stop and wait, the machine's clock starts with the first map.
            timings.total_s = started.elapsed().as_secs_f64();
            return Ok(self.output(0.0, 0.0, None, None, unknown, timings));
        };
        let g = map.geometry();
        let grid = RiskGrid::new(&self.plan_risk, g.nx, g.ny, g.resolution_m, g.origin_m())?;
        let local_risk = risk_at(&grid, position).map_or(unknown, |r| if r.is_nan() { unknown } else { f64::from(r) });

        // 3. Plan.
        let behaviour = self.recovery.behaviour();
        let mut plan = None;
        let mut feedback = PlanFeedback::NotRun;
        let mut distance = straight;
        if behaviour == Behaviour::Track {
            let key = (self.recovery_thresholds().0, self.recovery_thresholds().1, self.recovery.target());
            let due = self.last_plan_s.is_none_or(|t| input.stamp_s - t >= self.config.navigator.replan_period_s);
            if due || !self.last_plan_ok || self.planned_for != Some(key) {
                let t_plan = Instant::now();
                let (mut goal_on_map, mut remainder) = on_map(&grid, position, target_point);
                if remainder > 0.0 {
                    // A stand-in for a target off the map must be a cell the robot may enter.
                    let unknown = self.config.planner.unknown_risk;
                    if let Some(p) = nearest_traversable(&grid, goal_on_map, key.0, unknown, self.config.navigator.standin_search_m) {
                        goal_on_map = p;
                        remainder = p.distance(target_point);
                    }
                }
                if self.planner.config().r_inst != key.0 || self.planner.config().r_total != key.1 {
                    self.planner = RiskAStar::new(RiskAStarConfig { r_inst: key.0, r_total: key.1, ..self.config.planner })?;
                }
                let outcome = self.planner.plan(&grid, position, goal_on_map)?;
                self.last_plan_s = Some(input.stamp_s);
                self.planned_for = Some(key);
                self.last_plan_ok = outcome.status == PlanStatus::Found;
                feedback = match outcome.status {
                    PlanStatus::Found => PlanFeedback::Found,
                    PlanStatus::BudgetExceeded => PlanFeedback::BudgetExceeded,
                    _ => PlanFeedback::NoPath,
                };
                if let Some(path) = outcome.found() {
                    self.path.clone_from(&path.points_world);
                    self.remainder_m = remainder;
                } else {
                    self.path.clear();
                }
                plan = Some(outcome);
                timings.plan_s = t_plan.elapsed().as_secs_f64();
            }
            if !self.path.is_empty() {
                distance = path_length_from(&self.path, position) + self.remainder_m;
            }
        }

        // 6 and 4. Clearance heading, recovery.
        let r_inst_now = self.recovery_thresholds().0;
        let clearance_heading = clearance_heading(&grid, position, r_inst_now, (target_point - position).to_angle(), &self.config.navigator);
        let directive = self.recovery.step(&RecoveryInput {
            time_s: input.stamp_s,
            position,
            yaw_rad: heading,
            distance_to_target_m: distance,
            straight_distance_m: straight,
            plan: feedback,
            clearance_heading_rad: Some(clearance_heading),
        })?;
        if directive.target != key_target(self.planned_for) {
            self.path.clear();
            self.last_plan_ok = false;
        }

        // 5. Act.
        let nav = self.config.navigator;
        let turn = |error: f64| (nav.turn_gain_per_s * error).clamp(-nav.max_turn_rate_rad_s, nav.max_turn_rate_rad_s);
        let mut mpc = None;
        let (v, w) = match directive.behaviour {
            Behaviour::Track if !self.path.is_empty() && self.path.len() >= 2 => {
                let t_track = Instant::now();
                let state = UnicycleState { x_m: position.x, y_m: position.y, heading_rad: heading, speed_m_s: input.speed_m_s };
                let g = map.geometry();
                let mpc_grid = MpcRiskGrid::new(&self.plan_risk, g.nx, g.ny, g.resolution_m, g.origin_m())?;
                let out = self.tracker.solve(&state, &self.path, Some(&mpc_grid), None)?;
                timings.track_s = t_track.elapsed().as_secs_f64();
                let command = (out.command.speed_m_s, out.command.yaw_rate_rad_s);
                mpc = Some(out);
                command
            }
            Behaviour::ClearMap => {
                self.mapper.reset();
                self.tracker.reset();
                self.path.clear();
                self.last_plan_ok = false;
                (0.0, 0.0)
            }
            Behaviour::Rotate => {
                self.tracker.reset();
                let target = directive.rotate_to_rad.unwrap_or(heading);
                (0.0, turn(wrap_angle(target - heading)))
            }
            Behaviour::BackOut => {
                self.tracker.reset();
                let carrot = directive.backout_carrot.unwrap_or(position);
                let body = DVec2::from_angle(-heading).rotate(carrot - position);
                let e = wrap_angle(body.y.atan2(body.x) - PI);
                // Reverse only while the ground behind the footprint is below R_inst.
                let behind = |lateral: f64| {
                    let local = DVec2::new(-0.5 * self.robot.length_m - nav.backout_clearance_m, lateral);
                    position + DVec2::from_angle(heading).rotate(local)
                };
                let half_width = 0.5 * self.robot.width_m;
                let blocked = [-half_width, 0.0, half_width].into_iter().any(|lateral| {
                    risk_at(&grid, behind(lateral)).is_some_and(|r| f64::from(r) >= directive.r_inst)
                });
                let v = if blocked { 0.0 } else { -nav.backout_speed_m_s * e.cos().max(0.0) };
                (v, turn(e))
            }
            _ => (0.0, 0.0),
        };
        timings.total_s = started.elapsed().as_secs_f64();
        Ok(self.output(v, w, plan, mpc, local_risk, timings))
    }

    fn recovery_thresholds(&self) -> (f64, f64) {
        self.recovery.thresholds()
    }

    fn output(&mut self, v: f64, w: f64, plan: Option<PlanOutcome>, mpc: Option<MpcOutput>, local_risk: f64, timings: NavigatorTimings) -> NavigatorOutput {
        let transitions = self.recovery.transitions()[self.transitions_seen..].to_vec();
        self.transitions_seen = self.recovery.transitions().len();
        let (r_inst, r_total) = self.recovery_thresholds();
        NavigatorOutput {
            speed_m_s: v,
            yaw_rate_rad_s: w,
            behaviour: self.recovery.behaviour(),
            target: self.recovery.target(),
            plan,
            path_world: self.path.clone(),
            mpc,
            local_risk,
            speed_limit_m_s: self.config.tracker.limits.max_speed_m_s * (1.0 - local_risk.clamp(0.0, 1.0)),
            r_inst,
            r_total,
            transitions,
            timings,
        }
    }
}

/// Heading of the body's x axis in the world's x-y plane [rad].
fn yaw_of(pose: &Isometry3) -> f64 {
    let x = pose.rotation * glam::DVec3::X;
    x.y.atan2(x.x)
}

/// The grid's risk at a world position, if on the grid (NaN stays NaN).
fn risk_at(grid: &RiskGrid<'_>, p: DVec2) -> Option<f32> {
    grid.cell_of(p).map(|c| grid.risk()[c.iy as usize * grid.nx() + c.ix as usize])
}

fn key_target(planned_for: Option<(f64, f64, Target)>) -> Target {
    planned_for.map_or(Target::Goal, |k| k.2)
}

/// `target` if it is on the grid (one cell inside its edge), else the point of the segment
/// `from -> target` nearest to `target` that is; and the straight distance left from there.
fn on_map(grid: &RiskGrid<'_>, from: DVec2, target: DVec2) -> (DVec2, f64) {
    let res = grid.resolution_m();
    let lo = grid.origin_m() + DVec2::splat(1.5 * res);
    let hi = grid.origin_m() + DVec2::new(grid.nx() as f64, grid.ny() as f64) * res - DVec2::splat(1.5 * res);
    let inside = |p: DVec2| p.x >= lo.x && p.y >= lo.y && p.x <= hi.x && p.y <= hi.y;
    if inside(target) {
        return (target, 0.0);
    }
    // Largest t in [0, 1] with from + t·(target - from) inside the shrunk box (slab clipping).
    let d = target - from;
    let mut t_max: f64 = 1.0;
    for (o, dd, l, h) in [(from.x, d.x, lo.x, hi.x), (from.y, d.y, lo.y, hi.y)] {
        if dd > 0.0 {
            t_max = t_max.min((h - o) / dd);
        } else if dd < 0.0 {
            t_max = t_max.min((l - o) / dd);
        }
    }
    let p = from + d * t_max.clamp(0.0, 1.0);
    let p = p.clamp(lo, hi);
    (p, p.distance(target))
}

/// The centre of the cell nearest `p` (within `radius_m`) whose risk (NaN: `unknown`) is
/// below `r_inst`, if any.
fn nearest_traversable(grid: &RiskGrid<'_>, p: DVec2, r_inst: f64, unknown: f64, radius_m: f64) -> Option<DVec2> {
    let centre = grid.cell_of(p)?;
    let reach = (radius_m / grid.resolution_m()).ceil() as i64;
    let mut best: Option<(f64, DVec2)> = None;
    for dy in -reach..=reach {
        for dx in -reach..=reach {
            let (ix, iy) = (centre.ix as i64 + dx, centre.iy as i64 + dy);
            if ix < 0 || iy < 0 || ix >= grid.nx() as i64 || iy >= grid.ny() as i64 {
                continue;
            }
            let r = grid.risk()[iy as usize * grid.nx() + ix as usize];
            let r = if r.is_nan() { unknown } else { f64::from(r) };
            if r >= r_inst {
                continue;
            }
            let q = grid.origin_m() + (DVec2::new(ix as f64, iy as f64) + 0.5) * grid.resolution_m();
            let d = q.distance_squared(p);
            if d <= radius_m * radius_m && best.is_none_or(|(bd, _)| d < bd) {
                best = Some((d, q));
            }
        }
    }
    best.map(|(_, q)| q)
}

/// Length of `path` from its point nearest `p` to its end, plus the gap to that point [m].
fn path_length_from(path: &[DVec2], p: DVec2) -> f64 {
    let nearest = path
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.distance_squared(p).total_cmp(&b.1.distance_squared(p)))
        .map_or(0, |(i, _)| i);
    let rest: f64 = path[nearest..].windows(2).map(|w| w[0].distance(w[1])).sum();
    rest + path.get(nearest).map_or(0.0, |q| q.distance(p))
}

/// The heading of the longest ray below `r_inst` (module docs, step 6).
fn clearance_heading(grid: &RiskGrid<'_>, from: DVec2, r_inst: f64, toward: f64, s: &NavigatorSettings) -> f64 {
    let step = grid.resolution_m();
    let n = s.clearance_headings as usize;
    let steps = (s.clearance_range_m / step).ceil() as usize;
    let mut best = (f64::NEG_INFINITY, f64::INFINITY, toward);
    for k in 0..n {
        let angle = wrap_angle(2.0 * PI * k as f64 / n as f64);
        let dir = DVec2::from_angle(angle);
        let mut free = 0.0;
        for i in 1..=steps {
            let q = from + dir * (i as f64 * step);
            match risk_at(grid, q) {
                Some(r) if !(f64::from(r) >= r_inst) => free = i as f64 * step,
                _ => break,
            }
        }
        let off = wrap_angle(angle - toward).abs();
        if free > best.0 || (free == best.0 && off < best.1) {
            best = (free, off, angle);
        }
    }
    best.2
}
