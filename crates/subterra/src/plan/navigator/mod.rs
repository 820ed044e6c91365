//! The navigator: terrain mapper + risk-aware A* + MPC tracker + recovery machine, wired
//! for a robot's own control loop (STEP; the JPL CoSTAR draft "Risk-aware Traversability in
//! Extreme Environments"). One [`Navigator::step`] per control tick.
//!
//! - [`config`]: the settings and their committed defaults (`configs/navigator.toml`);
//! - [`memory`]: the hazard, near and driven memories, by [`WorldCell`];
//! - [`morphology`]: lethal patches, their growth into their own shadow, the inflation;
//! - [`target`]: stand-ins for targets off the map or on blocked cells;
//! - [`reactive`]: `rotate` and `back_out`, and the swept-footprint check of every recovery.
//!
//! # One step, exactly
//! 1. **Map.** With a scan, [`TerrainMapper::update`] at the odometry pose; the coarse map is
//!    kept (the navigator plans and tracks on it: the mapper's fine map is not computed).
//!    Without a scan, the last map stands; once a map exists, no scan for longer than
//!    `scan_timeout_s`, or an odometry confidence of 0 (no usable odometry source), stops the
//!    robot here, with the reason in `safety` (steps 2-5 wait for the sensor).
//! 2. **Grids.** The navigator's grid is the coarse map's `risk` layer, or with
//!    `navigator.cvar_alpha` its `CVaR_α`, where the map observed the cell (holes and
//!    drop-offs rated by ray reasoning are observed and lethal: a cell whose ground is missing
//!    where the sensor should have seen it); NaN where it did not. Then, in the world frame:
//!    the **near memory** records the newest (or highest) rating of every cell observed within
//!    `near_memory_m`; the **hazard memory** forgets remembered cells beyond
//!    `hazard_memory_range_m` or seen again as ground (at least `hazard_memory_forget_points`
//!    ground points and a rating below lethal), remembers every lethal cell within
//!    `hazard_memory_record_m` in a patch (`lethal_min_neighbours`), and raises every
//!    remembered cell on the grid to its rating. A copy for the A* only is grown into the
//!    unseen: unobserved cells within `unseen_growth_m` of a lethal patch and at least
//!    `unseen_growth_min_range_m` from the robot take its rating (a hazard's far side lies in
//!    its own shadow). Last, on both, each cell still unobserved within `near_memory_m` takes
//!    its near-memory rating if that is above the planner's `unknown_risk`. With
//!    `unseen_near_lethal`, the **unseen-near rule** marks lethal on both each cell within the
//!    sensor's blind ring (`coverage.min_range_m`) that is unobserved, never held by the near
//!    memory below lethal as shown ground (a point of its own, or rated from outside the
//!    blind ring), never stood on, not within the blind ring of the robot's first
//!    pose, with its 8 neighbours the same: ground the all-round sensor had in view on its way
//!    in and never got a return from (a hole's mouth; [`memory::mark_unseen_near`]). With
//!    `void_rim_m` > 0, every cell within it of a void (a cell whose `negative` layer is
//!    lethal, on this map in a patch or remembered by the hazard memory) is lethal on both
//!    unless the robot stood on it: the map places a void's edge only to within one radial
//!    ground bin ([`memory::mark_void_rims`]). The **driven
//!    memory** adds the cells under the robot's footprint every step. **Lethal** is the map's
//!    one definition ([`RiskMap::lethal_risk`]): the A* never enters a lethal cell whatever its
//!    thresholds, the MPC keeps the footprint off them.
//! 3. **Plan** (only while tracking, and at most every `replan_period_s` unless the last plan
//!    failed, the thresholds or the target changed): with `inflate_lethal`, the lethal patch
//!    cells of the navigator's grid inflated by half the robot's width (plus
//!    `inflation_margin_m`) except around the robot, and the cells grown into the unseen laid
//!    over them as they are (a guess: they block, they are not inflated); a target off the map
//!    is planned toward with the A*'s exit search (`leave_by_any_border`: the path leaves by
//!    the border cell that makes the whole way cheapest, the straight line on priced at λ a
//!    metre, [`RiskAStar::plan_toward`]; when it finds no way out within the thresholds, and
//!    without it, the target is replaced by the map cell on the segment robot→target nearest
//!    it); a target on a cell the robot may not enter by the
//!    nearest cell where the robot fits and that the A* reaches ([`target`]); with `perception_aware`, the moves that would enter an unknown cell (not
//!    observed, not remembered, not driven) the sensor will not have seen on the way are priced
//!    at the map's `risk.unknown` instead of the planner's `unknown_risk`
//!    ([`crate::plan::coverage`]); then the A* with the recovery machine's `R_inst`/`R_total`.
//!    With `footprint_replans` > 0 the path found is checked with the tracker's footprint test
//!    (below, step 5) at poses every half cell along it, each with the heading of the path's
//!    chord over the robot's length; where the rectangle fails, a disc of the circumscribed
//!    less the inscribed radius around that pose is closed and the A* runs again, up to
//!    `footprint_replans` times ([`reactive::footprint_checked`]): the disc the A* plans for
//!    takes turns the rectangle cannot, and such a path only stops the tracker beside an
//!    obstacle. With `plan_hysteresis` > 0, a plan that takes another route than the path
//!    being followed (a vertex of the path's rest farther than the robot's width from it)
//!    replaces it only if that rest crosses an unknown cell, or, priced alike ([`RiskAStar::price_polyline`], the
//!    perception-aware entry prices included, plus λ per metre on to the target), is untraversable, over budget, footprint-blocked or more
//!    than `1 + plan_hysteresis` times the plan's price; else the rest is kept. A plan that
//!    lengthens the way to the target by more than the recovery's `progress_min_m` is
//!    reported as a reroute ([`RecoveryInput::route_switched`]): the recovery machine then
//!    measures progress along the new route (once a window).
//!    The distance to the target the recovery machine measures progress by is the path's
//!    length plus the straight remainder beyond the map when a path was found, else the
//!    straight-line distance.
//! 4. **Recovery.** [`RecoveryMachine::step`] with the plan's outcome and the heading of most
//!    clearance ([`reactive::clearance_heading`]) gives the behaviour for this tick.
//! 5. **Act.** `track`: the MPC on the last path, on the navigator's grid (ungrown,
//!    uninflated: its speed limits and lethal obstacle polygons), its command checked
//!    ([`reactive::filter_track`]): if the footprint it would sweep newly covers the centre of
//!    a lethal cell or of an unknown one within `track_unknown_fringe_m` of a lethal cell (a
//!    hazard's unseen rim), a turn in place, a straight drive or a stop instead
//!    (`NavigatorOutput::safety` says why); no path yet: stop.
//!    `clear_map`: drop the mapper's window and the remembered hazards and near cells farther
//!    than `hazard_memory_keep_m`, stop. `rotate` and `back_out` ([`reactive`]) move only if
//!    the footprint their next motion sweeps covers no cell at or above the nominal `R_inst`
//!    (raised thresholds are for the planner) or lethal, and no unknown cell; when no motion is safe the behaviour ends
//!    ([`RecoveryMachine::abort`], with the reason) and the robot stops.
//!    `raise_thresholds` and the final behaviours: stop.
//!
//! Every stage's wall time is reported.

mod config;
mod memory;
mod morphology;
mod reactive;
mod target;

use std::time::Instant;

use glam::DVec2;

pub use config::{NavigatorConfig, NavigatorSettings, MAX_MORPHOLOGY_M, MAX_RANGE_SETTING_M, UNSEEN_RISK_PER_M};
pub use memory::WorldCell;

use self::memory::{mark_unseen_near, mark_void_rims, DrivenMemory, HazardMemory, HazardRules, NearMemory, UnseenNear};
use self::morphology::{clustered, grow_into_unseen, inflate_lethal, turn_room_prices, Growth};
use self::reactive::{FootprintReplan, SafetyView};
use self::target::{nearest_traversable, nearest_traversable_to, on_map, path_length_from, reachable_from, Search};
use crate::error::{Error, Result};
use crate::frames::Isometry3;
use crate::plan::astar::{EntryPrices, PlanOutcome, PlanStatus, RiskAStar, RiskAStarConfig};
use crate::plan::coverage::unseen_entries;
use crate::plan::grid::RiskGrid;
use crate::plan::mpc::{MpcOutput, MpcTracker, UnicycleState};
use crate::plan::recovery::{wrap_angle, Behaviour, PlanFeedback, RecoveryInput, RecoveryMachine, Target, Transition};
use crate::terrain::{RiskMap, RobotConfig, TerrainConfig, TerrainMapper, TerrainStats, TerrainTimings};

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
    /// Why the command is not the behaviour's own, when the motion it asked for was not safe
    /// (the footprint it would sweep): the tracker's command replaced by a turn, a straight
    /// drive or a stop, or a recovery stopped.
    pub safety: Option<String>,
}

/// The scratch of a plan.
#[derive(Debug, Default)]
struct PlanScratch {
    /// The navigator's grid grown into the unseen (step 2): the A*'s grid before inflation.
    grown: Vec<f32>,
    /// The A*'s grid.
    astar: Vec<f32>,
    /// The cells the planner can reach from the robot (stand-ins must be).
    reachable: Vec<bool>,
    flood: Vec<usize>,
    /// Which cells are known (observed or remembered) for perception-aware planning.
    known: Vec<bool>,
    /// The perception-aware entry mask and its scratch.
    unseen: Vec<u8>,
    run: Vec<u16>,
    /// The A*'s clearance prices (`turn_room_price`).
    turn_room: Vec<f32>,
}

/// The ground robot's navigation stack (see the module docs).
#[derive(Debug)]
pub struct Navigator {
    config: NavigatorConfig,
    robot: RobotConfig,
    /// The map's prior risk of an unobserved cell: the price of an unknown cell entered unseen.
    unseen_risk: f64,
    mapper: TerrainMapper,
    planner: RiskAStar,
    tracker: MpcTracker,
    recovery: RecoveryMachine,
    goal: DVec2,
    map: Option<RiskMap>,
    /// The navigator's grid (step 2).
    grid: Vec<f32>,
    hazards: HazardMemory,
    near: NearMemory,
    driven: DrivenMemory,
    /// Where the robot stood at its first map: its blind ring there was never in view.
    start: Option<DVec2>,
    scratch: PlanScratch,
    path: Vec<DVec2>,
    remainder_m: f64,
    /// The distance to the target the recovery machine was last told [m].
    last_distance_m: Option<f64>,
    last_plan_s: Option<f64>,
    last_plan_ok: bool,
    planned_for: Option<(f64, f64, Target)>,
    last_stamp_s: Option<f64>,
    /// The stamp of the last scan mapped [s].
    last_scan_s: Option<f64>,
    transitions_seen: usize,
    home_pending: bool,
    terrain_stats: (TerrainStats, TerrainTimings),
}

/// The control period assumed before two steps have been seen [s].
const DEFAULT_PERIOD_S: f64 = 0.1;

impl Navigator {
    /// A navigator for `robot` on `terrain` settings, driving to `goal` and back to `home`
    /// when it gives up (world frame [m]; `None`: where the robot is at its first step). The
    /// planner's `lethal_risk` and the tracker's `risk.lethal_risk` are set to the terrain's
    /// `risk.lethal_risk`: one definition of lethal.
    pub fn new(robot: RobotConfig, terrain: TerrainConfig, config: NavigatorConfig, goal: DVec2, home: Option<DVec2>) -> Result<Self> {
        config.validate()?;
        if !goal.is_finite() {
            return Err(Error::input("goal", format!("must be finite, got ({}, {})", goal.x, goal.y)));
        }
        let mut config = config;
        let lethal = terrain.risk.lethal_risk;
        config.planner.lethal_risk = lethal;
        config.tracker.risk.lethal_risk = lethal;
        let terrain = TerrainConfig { fine_enabled: false, ..terrain };
        let mapper = TerrainMapper::new(robot, terrain)?;
        let planner = RiskAStar::new(config.planner)?;
        let tracker = MpcTracker::new(config.tracker)?;
        let recovery = RecoveryMachine::new(config.recovery, home.unwrap_or(DVec2::ZERO))?;
        Ok(Self {
            config,
            robot,
            unseen_risk: terrain.risk.unknown,
            mapper,
            planner,
            tracker,
            recovery,
            goal,
            map: None,
            grid: Vec::new(),
            hazards: HazardMemory::default(),
            near: NearMemory::default(),
            driven: DrivenMemory::default(),
            start: None,
            scratch: PlanScratch::default(),
            path: Vec::new(),
            remainder_m: 0.0,
            last_distance_m: None,
            last_plan_s: None,
            last_plan_ok: false,
            planned_for: None,
            last_stamp_s: None,
            last_scan_s: None,
            transitions_seen: 0,
            home_pending: home.is_none(),
            terrain_stats: (TerrainStats::default(), TerrainTimings::default()),
        })
    }

    /// The configuration (with the lethal level of the terrain's).
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

    /// The navigator's grid on the last map's geometry (step 2: risk or CVaR where observed,
    /// raised by the hazard memory; near the robot the near memory's rating where it is
    /// unobserved; NaN elsewhere unobserved), row-major `ny x nx`; empty before the first scan.
    pub fn plan_grid(&self) -> &[f32] {
        &self.grid
    }

    /// Cells in the hazard memory.
    pub fn remembered_hazards(&self) -> usize {
        self.hazards.len()
    }

    /// Cells in the driven memory.
    pub fn driven_cells(&self) -> usize {
        self.driven.len()
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

    /// Drives to a new `goal` (world frame [m]) from the next step: the map, the remembered
    /// hazards, the driven cells and home stay; the plan, the tracker's warm start and the
    /// recovery ladder (behaviour, thresholds, transitions, trail) start again, as for a
    /// navigator that has just been made. A goal that is not finite is an `InputError`
    /// naming `goal`, and nothing changes.
    pub fn set_goal(&mut self, goal: DVec2) -> Result<()> {
        if !goal.is_finite() {
            return Err(Error::input("goal", format!("must be finite, got ({}, {})", goal.x, goal.y)));
        }
        self.recovery = RecoveryMachine::new(self.config.recovery, self.recovery.home())?;
        self.tracker.reset();
        self.goal = goal;
        self.path.clear();
        self.remainder_m = 0.0;
        self.last_distance_m = None;
        self.last_plan_s = None;
        self.last_plan_ok = false;
        self.planned_for = None;
        self.transitions_seen = 0;
        Ok(())
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
        let period_s = self.last_stamp_s.map_or(DEFAULT_PERIOD_S, |t| (input.stamp_s - t).max(0.0));

        // 1 and 2. Map, grids.
        if let Some(points) = input.points_sensor {
            let out = self.mapper.update(points, input.stamp_s, &input.world_from_body, &input.body_from_sensor, input.confidence)?;
            self.terrain_stats = (out.stats, out.timings);
            self.grids(out.coarse, position)?;
            self.last_scan_s = Some(input.stamp_s);
        }
        self.last_stamp_s = Some(input.stamp_s);
        if let Some(map) = &self.map {
            let nav = &self.config.navigator;
            self.driven.stamp(position, heading, self.robot.length_m, self.robot.width_m, map.geometry().resolution_m, nav.driven_memory_m);
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
        // A stale sensor or no odometry: stop where the robot is, and say why.
        let stale = self.last_scan_s.map_or(0.0, |t| input.stamp_s - t);
        let halt = if stale > self.config.navigator.scan_timeout_s {
            Some(format!("stale scan: none for over navigator.scan_timeout_s = {} s", self.config.navigator.scan_timeout_s))
        } else if input.confidence <= 0.0 {
            Some("no odometry: confidence 0".to_string())
        } else {
            None
        };
        if let Some(reason) = halt {
            self.tracker.reset();
            timings.total_s = started.elapsed().as_secs_f64();
            let unknown = self.config.planner.unknown_risk;
            let mut output = self.output(0.0, 0.0, None, None, unknown, timings);
            output.safety = Some(reason);
            return Ok(output);
        }
        let g = *map.geometry();
        let lethal = map.lethal_risk;
        // The grid is read by every stage below while the planner and the memories change:
        // held out of `self` for the rest of the step.
        let values = std::mem::take(&mut self.grid);
        let result = self.act(input, &values, &g, lethal, position, heading, straight, target_point, period_s, started, timings);
        self.grid = values;
        result
    }

    /// Steps 3 to 5, on the navigator's grid `values` of geometry `g`.
    #[allow(clippy::too_many_arguments)]
    fn act(
        &mut self,
        input: &NavigatorInput<'_>,
        values: &[f32],
        g: &crate::terrain::GridGeometry,
        lethal: f32,
        position: DVec2,
        heading: f64,
        straight: f64,
        target_point: DVec2,
        period_s: f64,
        started: Instant,
        mut timings: NavigatorTimings,
    ) -> Result<NavigatorOutput> {
        let unknown = self.config.planner.unknown_risk;
        let grid = RiskGrid::on_geometry(values, g)?;
        let local_risk = grid.value_at(position).map_or(unknown, |r| if r.is_nan() { unknown } else { f64::from(r) });

        // 3. Plan.
        let mut plan = None;
        let mut feedback = PlanFeedback::NotRun;
        let mut distance = straight;
        if self.recovery.behaviour() == Behaviour::Track {
            let key = (self.recovery.thresholds().0, self.recovery.thresholds().1, self.recovery.target());
            let due = self.last_plan_s.is_none_or(|t| input.stamp_s - t >= self.config.navigator.replan_period_s);
            if due || !self.last_plan_ok || self.planned_for != Some(key) {
                let t_plan = Instant::now();
                let outcome = self.plan(&grid, lethal, (position, heading), target_point, key)?;
                self.last_plan_s = Some(input.stamp_s);
                self.planned_for = Some(key);
                self.last_plan_ok = outcome.status == PlanStatus::Found;
                feedback = match outcome.status {
                    PlanStatus::Found => PlanFeedback::Found,
                    PlanStatus::BudgetExceeded => PlanFeedback::BudgetExceeded,
                    _ => PlanFeedback::NoPath,
                };
                plan = Some(outcome);
                timings.plan_s = t_plan.elapsed().as_secs_f64();
            }
            if !self.path.is_empty() {
                distance = path_length_from(&self.path, position) + self.remainder_m;
            }
        }

        // 4. Clearance heading, recovery.
        let r_inst_now = self.recovery.thresholds().0;
        let clearance_heading = reactive::clearance_heading(&grid, position, r_inst_now.min(f64::from(lethal)), (target_point - position).to_angle(), &self.config.navigator);
        let directive = self.recovery.step(&RecoveryInput {
            time_s: input.stamp_s,
            position,
            yaw_rad: heading,
            distance_to_target_m: distance,
            straight_distance_m: straight,
            plan: feedback,
            clearance_heading_rad: Some(clearance_heading),
            room_to_turn: self.recovery.behaviour() != Behaviour::BackOut || self.room_to_turn(grid, position, heading, lethal),
            // A plan of this tick lengthened the way by more than counts as progress: a
            // reroute, not the robot going backwards.
            route_switched: plan.as_ref().is_some_and(|o| o.found().is_some())
                && self.last_distance_m.is_some_and(|last| distance - last > self.recovery.config().progress_min_m),
        })?;
        self.last_distance_m = Some(distance);
        if directive.target != self.planned_for.map_or(Target::Goal, |k| k.2) {
            self.path.clear();
            self.last_plan_ok = false;
        }

        // 5. Act.
        let nav = self.config.navigator;
        // Recoveries keep to the nominal threshold: raised thresholds let the planner cross
        // riskier ground, not turn or reverse blind over it.
        let blocking = (self.config.recovery.r_inst as f32).min(lethal);
        let mut mpc = None;
        let mut abort = None;
        let mut safety = None;
        let (v, w) = match directive.behaviour {
            Behaviour::Track if self.path.len() >= 2 => {
                let t_track = Instant::now();
                let state = UnicycleState { x_m: position.x, y_m: position.y, heading_rad: heading, speed_m_s: input.speed_m_s };
                let out = self.tracker.solve(&state, &self.path, Some(&grid), None)?;
                let command = (out.command.speed_m_s, out.command.yaw_rate_rad_s);
                mpc = Some(out);
                let command = match reactive::filter_track(&self.safety_view(grid, blocking, lethal, false), position, heading, command, period_s, &nav) {
                    Ok(command) => command,
                    Err((safe, reason)) => {
                        safety = Some(reason);
                        safe
                    }
                };
                timings.track_s = t_track.elapsed().as_secs_f64();
                command
            }
            Behaviour::ClearMap => {
                self.mapper.reset();
                self.hazards.forget_beyond(position, g.resolution_m, nav.hazard_memory_keep_m);
                self.near.forget_beyond(position, g.resolution_m, nav.hazard_memory_keep_m);
                self.tracker.reset();
                self.path.clear();
                self.last_plan_ok = false;
                (0.0, 0.0)
            }
            Behaviour::Rotate => {
                self.tracker.reset();
                let target = directive.rotate_to_rad.unwrap_or(heading);
                reactive::rotate(&self.safety_view(grid, blocking, lethal, true), position, heading, target, &nav).unwrap_or_else(|reason| {
                    abort = Some(reason);
                    (0.0, 0.0)
                })
            }
            Behaviour::BackOut => {
                self.tracker.reset();
                let carrot = directive.backout_carrot.unwrap_or(position);
                reactive::back_out(&self.safety_view(grid, blocking, lethal, true), position, heading, carrot, period_s, &nav).unwrap_or_else(|reason| {
                    abort = Some(reason);
                    (0.0, 0.0)
                })
            }
            _ => (0.0, 0.0),
        };
        if let Some(reason) = &abort {
            self.recovery.abort(input.stamp_s, reason);
        }
        timings.total_s = started.elapsed().as_secs_f64();
        let mut output = self.output(v, w, plan, mpc, local_risk, timings);
        output.safety = safety.or(abort);
        Ok(output)
    }

    /// Whether a full turn in place is safe here (`BackOut` goes on until it is).
    fn room_to_turn(&self, grid: RiskGrid<'_>, position: DVec2, heading: f64, lethal: f32) -> bool {
        let blocking = (self.config.recovery.r_inst as f32).min(lethal);
        let view = self.safety_view(grid, blocking, lethal, true);
        view.sweep((position, heading), view.turn_poses(position, heading, 2.0 * std::f64::consts::PI)).is_none()
    }

    /// What a motion is checked against: for the recoveries (`recovery`) every cell at or
    /// above `blocking` and every unknown cell blocks, and any part of a cell within
    /// `sweep_margin_m` of the footprint counts; for tracking, lethal cells and unknown ones
    /// within `track_unknown_fringe_m` of a lethal cell count when the footprint covers their
    /// centres, as the A*'s inflation by the inscribed radius counts them.
    fn safety_view<'a>(&'a self, grid: RiskGrid<'a>, blocking: f32, lethal: f32, recovery: bool) -> SafetyView<'a> {
        safety_view(&self.config.navigator, self.robot, (&self.hazards, &self.near, &self.driven), grid, blocking, lethal, recovery)
    }

    /// Step 2: the navigator's grid from a new map, through the memories.
    fn grids(&mut self, map: RiskMap, position: DVec2) -> Result<()> {
        let nav = self.config.navigator;
        // Risk (or its CVaR) where observed, NaN elsewhere so that the planner's own
        // `unknown_risk` prices the unseen.
        let risk = match nav.cvar_alpha {
            Some(alpha) => map.cvar(alpha)?,
            None => map.layer("risk")?.to_vec(),
        };
        let observed = map.layer("observed")?;
        self.grid.clear();
        self.grid.extend(risk.iter().zip(observed).map(|(&r, &o)| if o > 0.0 { r } else { f32::NAN }));
        let g = *map.geometry();
        let lethal = map.lethal_risk;
        if nav.near_memory_m > 0.0 {
            self.near.record(&self.grid, map.layer("count")?, &g, position, nav.near_memory_m, nav.coverage.min_range_m, nav.near_memory_highest);
        }
        if nav.hazard_memory {
            let rules = HazardRules {
                lethal,
                min_neighbours: nav.lethal_min_neighbours,
                forget_points: nav.hazard_memory_forget_points as f32,
                record_m: nav.hazard_memory_record_m,
                range_m: nav.hazard_memory_range_m,
            };
            self.hazards.update(&mut self.grid, map.layer("ground_count")?, map.layer("negative")?, &g, position, &rules);
        }
        let s = &mut self.scratch;
        s.grown.clone_from(&self.grid);
        if nav.unseen_growth_m > 0.0 {
            let growth = Growth { lethal, min_neighbours: nav.lethal_min_neighbours, radius_m: nav.unseen_growth_m, robot: position, min_range_m: nav.unseen_growth_min_range_m };
            grow_into_unseen(&mut s.grown, &mut s.astar, &g, &growth);
        }
        if nav.near_memory_m > 0.0 {
            let above = self.config.planner.unknown_risk as f32;
            self.near.recall(&mut self.grid, &g, position, nav.near_memory_m, above, lethal);
            self.near.recall(&mut s.grown, &g, position, nav.near_memory_m, above, lethal);
        }
        let start = *self.start.get_or_insert(position);
        if nav.unseen_near_lethal {
            let rule = UnseenNear { robot: position, start, blind_m: nav.coverage.min_range_m, lethal };
            mark_unseen_near(&mut self.grid, &mut s.grown, &g, &self.near, &self.driven, &rule);
        }
        if nav.void_rim_m > 0.0 {
            // The voids of this map (patches, as the hazard memory keeps them) the memory does
            // not already hold, and the remembered ones, which the blind ring hides once the
            // robot is beside them.
            let negative = map.layer("negative")?;
            let on_map: Vec<WorldCell> = (0..g.cells())
                .filter(|&c| negative[c] >= lethal && clustered(&self.grid, g.nx, g.ny, c, lethal, nav.lethal_min_neighbours))
                .map(|c| WorldCell::of_flat(&g, c))
                .filter(|&cell| !self.hazards.is_void(cell))
                .collect();
            let remembered = self.hazards.voids().collect::<Vec<_>>();
            mark_void_rims(&mut self.grid, &mut s.grown, &g, on_map.into_iter().chain(remembered), &self.driven, nav.void_rim_m, lethal);
        }
        self.map = Some(map);
        Ok(())
    }

    /// Step 3: the A*'s grid, the stand-in, the entry prices and the plan; keeps the path.
    fn plan(&mut self, grid: &RiskGrid<'_>, lethal: f32, pose: (DVec2, f64), target_point: DVec2, key: (f64, f64, Target)) -> Result<PlanOutcome> {
        let position = pose.0;
        let nav = self.config.navigator;
        let g = *grid.map_geometry().ok_or_else(|| Error::input("grid", "must lie on a map geometry"))?;
        let fit_radius = 0.5 * self.robot.width_m + nav.inflation_margin_m;
        let unknown = self.config.planner.unknown_risk;
        let s = &mut self.scratch;
        if nav.inflate_lethal {
            // The lethal cells of the map and the memories are inflated by the inscribed
            // radius; the cells grown into the unseen, a guess, only block where they are.
            inflate_lethal(grid.risk(), &mut s.astar, &g, lethal, nav.lethal_min_neighbours, fit_radius, position);
            for (a, &grown) in s.astar.iter_mut().zip(&s.grown) {
                if grown >= lethal && !(*a >= grown) {
                    *a = grown;
                }
            }
        } else {
            s.astar.clone_from(&s.grown);
        }
        let astar_grid = RiskGrid::on_geometry(&s.astar, &g)?;
        let (mut goal_on_map, mut remainder) = on_map(grid, position, target_point);
        let off_map = remainder > 0.0;
        let exit_search = off_map && nav.leave_by_any_border;
        if self.planner.config().r_inst != key.0 || self.planner.config().r_total != key.1 {
            self.planner = RiskAStar::new(RiskAStarConfig { r_inst: key.0, r_total: key.1, ..self.config.planner })?;
        }
        if nav.perception_aware {
            s.known.clear();
            s.known.extend((0..g.cells()).map(|c| {
                let cell = WorldCell::of_flat(&g, c);
                !s.astar[c].is_nan() || self.near.get(cell).is_some() || self.driven.contains(cell)
            }));
            unseen_entries(&astar_grid, &s.known, position, &nav.coverage, lethal, &mut s.unseen, &mut s.run);
        } else {
            s.unseen.clear();
        }
        let turn_room = nav.inflate_lethal && nav.turn_room_price > 0.0;
        if turn_room {
            // Room to turn: the ground between the inscribed and the circumscribed radius of
            // the same lethal cells the inflation grows, priced (it stays traversable).
            let circumscribed = (0.5 * self.robot.length_m).hypot(0.5 * self.robot.width_m) + nav.inflation_margin_m;
            turn_room_prices(grid.risk(), &mut s.turn_room, &g, lethal, nav.lethal_min_neighbours, fit_radius, circumscribed, nav.turn_room_price as f32);
        } else {
            s.turn_room.clear();
        }
        let entry = (nav.perception_aware || turn_room).then(|| EntryPrices { unseen: &s.unseen, unseen_risk: self.unseen_risk, clearance: &s.turn_room });
        // Toward a target beyond the map: leave by whichever border cell makes the whole way
        // cheapest (the A*'s "toward a target off the grid"); when no way out within the
        // thresholds exists (the border walled off or over them), the stand-in still gets
        // the robot as near as the map allows.
        let toward = if exit_search { Some(self.planner.plan_toward(&astar_grid, position, target_point, entry.as_ref())?) } else { None };
        let mut outcome = match toward {
            Some(out) if out.status == PlanStatus::Found => {
                goal_on_map = astar_grid.centre_of(out.goal_cell);
                remainder = goal_on_map.distance(target_point);
                out
            }
            _ => {
                // A stand-in for a target off the map, or on a cell the robot may not enter,
                // must be a cell where it fits and that the planner can reach.
                let blocking = key.0.min(f64::from(lethal));
                reachable_from(&astar_grid, position, blocking, unknown, self.config.planner.allow_corner_cutting, &mut s.reachable, &mut s.flood);
                let search = Search { r_inst: blocking, unknown, fit_radius_m: fit_radius, reachable: &s.reachable };
                let standin = nearest_traversable(grid, goal_on_map, nav.standin_search_m, &search)
                    .or_else(|| off_map.then(|| nearest_traversable_to(grid, target_point, &search)).flatten());
                if let Some(p) = standin {
                    goal_on_map = p;
                    remainder = p.distance(target_point);
                }
                self.planner.plan_with(&astar_grid, position, goal_on_map, entry.as_ref())?
            }
        };
        if nav.footprint_replans > 0 && outcome.found().is_some() {
            // The path checked with the tracker's own footprint test (the rectangle along the
            // path's tangent, lethal cells and the unknown next to them): where it fails, a
            // disc around that point of the path is closed and the A* plans again.
            let view = safety_view(&nav, self.robot, (&self.hazards, &self.near, &self.driven), *grid, lethal, lethal, false);
            let replan = FootprintReplan {
                view: &view,
                from: pose,
                goal: goal_on_map,
                replans: nav.footprint_replans,
                half_window_m: self.config.tracker.tracking.tangent_half_window_m,
            };
            outcome = reactive::footprint_checked(&mut self.planner, &s.astar, &g, lethal, entry.as_ref(), &replan, outcome)?;
        }
        let followed = self.last_plan_ok && self.planned_for == Some(key) && self.path.len() >= 2;
        if let Some(path) = outcome.found() {
            let view = safety_view(&nav, self.robot, (&self.hazards, &self.near, &self.driven), *grid, lethal, lethal, false);
            let check = FootprintReplan { view: &view, from: pose, goal: goal_on_map, replans: 0, half_window_m: self.config.tracker.tracking.tangent_half_window_m };
            let rest = if followed { rest_of_path(&self.path, position, 0.5 * self.robot.width_m) } else { None };
            let planner = &self.planner;
            // Both priced alike, as the A* prices a path (its perception-aware entry prices
            // included: a path kept through ground the sensor will not have seen costs what
            // the search would charge for it), then λ per metre of straight line on to the
            // target (the heuristic's price of the unmapped remainder).
            let price = |points: &[DVec2]| {
                let end = *points.last()?;
                let (cost, _) = planner.price_polyline(&astar_grid, points, entry.as_ref()).ok()??;
                Some(cost + planner.config().min_cell_cost() * end.distance(target_point))
            };
            // Only over ground the map has rated: a path kept through unknown ground would
            // take the robot where the planner no longer goes (a pit whose floor its rim
            // hides), on the strength of an old guess.
            let passable = |rest: &[DVec2]| {
                let check = FootprintReplan { goal: *rest.last().unwrap_or(&goal_on_map), ..check };
                rest.iter().skip(1).all(|p| astar_grid.value_at(*p).is_some_and(|v| !v.is_nan()))
                    && reactive::first_blocked_along(&check, rest, g.resolution_m).is_none()
            };
            let decision = choose_route(rest, &path.points_world, self.robot.width_m, nav.plan_hysteresis, price, passable);
            match decision {
                Route::Kept(rest) => {
                    self.remainder_m = rest.last().map_or(0.0, |e| e.distance(target_point));
                    self.path = rest;
                }
                _ => {
                    self.path.clone_from(&path.points_world);
                    self.remainder_m = remainder;
                }
            }
        } else {
            self.path.clear();
        }
        Ok(outcome)
    }

    fn output(&mut self, v: f64, w: f64, plan: Option<PlanOutcome>, mpc: Option<MpcOutput>, local_risk: f64, timings: NavigatorTimings) -> NavigatorOutput {
        let transitions = self.recovery.transitions()[self.transitions_seen..].to_vec();
        self.transitions_seen = self.recovery.transitions().len();
        let (r_inst, r_total) = self.recovery.thresholds();
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
            safety: None,
        }
    }
}

/// What step 3 does with a new plan while a path is being followed.
#[derive(Debug, PartialEq)]
enum Route {
    /// No path was being followed: the plan is the path.
    New,
    /// The plan runs along the path being followed (within the robot's width): it replaces
    /// it, as a refreshed copy of the same route.
    Same,
    /// The plan takes another route, and the rest of the path being followed is still
    /// traversable, within the budget, passable for the footprint and at most
    /// `1 + plan_hysteresis` times the plan's price: the rest is kept.
    Kept(Vec<DVec2>),
    /// The plan takes another route, clearly better or the only one left: it replaces the path.
    Switched,
}

/// Step 3's choice between `rest`, the rest of the path being followed (if any), and `new`,
/// the plan just found: the same route if every vertex of `rest` lies within `width_m` of
/// `new`; else `rest` is kept if `price` prices both, `rest` at most `1 + hysteresis` times
/// `new`, and the footprint can follow it (`passable`).
fn choose_route(
    rest: Option<Vec<DVec2>>,
    new: &[DVec2],
    width_m: f64,
    hysteresis: f64,
    price: impl Fn(&[DVec2]) -> Option<f64>,
    passable: impl Fn(&[DVec2]) -> bool,
) -> Route {
    let Some(rest) = rest else { return Route::New };
    if max_deviation(&rest, new) <= width_m {
        return Route::Same;
    }
    let cheap_enough = matches!((price(&rest), price(new)), (Some(old), Some(new)) if old <= (1.0 + hysteresis) * new);
    if hysteresis > 0.0 && cheap_enough && passable(&rest) { Route::Kept(rest) } else { Route::Switched }
}

/// The rest of `path` from the robot at `position`: the robot, then the path from its vertex
/// nearest the robot; `None` if that vertex is farther than `within_m` (the robot is not
/// following the path) or is the path's end.
fn rest_of_path(path: &[DVec2], position: DVec2, within_m: f64) -> Option<Vec<DVec2>> {
    let (nearest, d2) = path.iter().enumerate().map(|(i, p)| (i, p.distance_squared(position))).min_by(|a, b| a.1.total_cmp(&b.1))?;
    if d2 > within_m * within_m || nearest + 1 >= path.len() {
        return None;
    }
    let mut rest = Vec::with_capacity(path.len() - nearest + 1);
    rest.push(position);
    rest.extend_from_slice(&path[nearest..]);
    Some(rest)
}

/// The largest distance from a vertex of `a` to the nearest vertex of `b` [m].
fn max_deviation(a: &[DVec2], b: &[DVec2]) -> f64 {
    a.iter().map(|p| b.iter().map(|q| p.distance_squared(*q)).fold(f64::INFINITY, f64::min)).fold(0.0, f64::max).sqrt()
}

/// What a motion is checked against ([`Navigator::safety_view`]), from the navigator's
/// settings, the robot and its `(hazard, near, driven)` memories: for the recoveries
/// (`recovery`) every cell at or above `blocking` and every unknown cell blocks, with the
/// footprint grown by `sweep_margin_m` and any cell it touches counted; for tracking (and
/// the footprint check of plans) lethal cells and unknown ones within
/// `track_unknown_fringe_m` of a lethal cell, counted when the footprint covers their
/// centres.
fn safety_view<'a>(
    nav: &NavigatorSettings,
    robot: RobotConfig,
    (hazards, near, driven): (&'a HazardMemory, &'a NearMemory, &'a DrivenMemory),
    grid: RiskGrid<'a>,
    blocking: f32,
    lethal: f32,
    recovery: bool,
) -> SafetyView<'a> {
    SafetyView {
        grid,
        hazards,
        near,
        driven,
        blocking: if recovery { blocking } else { lethal },
        lethal,
        unknown_blocks: recovery,
        unknown_near_lethal_m: nav.track_unknown_fringe_m,
        robot,
        margin_m: if recovery { nav.sweep_margin_m } else { 0.0 },
        cell_overlap: recovery,
    }
}

/// Heading of the body's x axis in the world's x-y plane [rad].
fn yaw_of(pose: &Isometry3) -> f64 {
    let x = pose.rotation * glam::DVec3::X;
    wrap_angle(x.y.atan2(x.x))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 30 x 15 cells of 0.2 m with a block across the middle (x 10-19, y 4-10): two routes
    /// round it, over (rows 11-14) and under (rows 0-3); `top_risk` on the upper band.
    fn two_routes(top_risk: f32) -> Vec<f32> {
        let mut risk = vec![0.0f32; 30 * 15];
        for y in 0..15 {
            for x in 0..30 {
                if (10..20).contains(&x) && (4..11).contains(&y) {
                    risk[y * 30 + x] = 0.95;
                } else if y >= 11 && (8..22).contains(&x) {
                    risk[y * 30 + x] = top_risk;
                }
            }
        }
        risk
    }

    fn plan(risk: &[f32]) -> (RiskAStarConfig, Vec<DVec2>) {
        let grid = RiskGrid::new(risk, 30, 15, 0.2, DVec2::ZERO).unwrap();
        let config = RiskAStarConfig { r_total: 1.0, ..RiskAStarConfig::default() };
        let out = RiskAStar::new(config).unwrap().plan(&grid, DVec2::new(0.5, 1.5), DVec2::new(5.7, 1.5)).unwrap();
        (config, out.found().expect("a path").points_world.clone())
    }

    #[test]
    fn a_route_is_kept_unless_the_new_one_is_clearly_better() {
        // The robot follows the route over the block (planned when the under route was risky).
        let mut under_risky = two_routes(0.0);
        for y in 0..4 {
            for x in 8..22 {
                under_risky[y * 30 + x] = 0.3;
            }
        }
        let (config, over) = plan(&under_risky);
        assert!(over.iter().any(|p| p.y > 2.2), "the first plan goes over the block");
        let rest = rest_of_path(&over, over[3], 0.3).unwrap();
        let judge = |risk: &[f32], hysteresis: f64| {
            let (_, new) = plan(risk);
            let grid = RiskGrid::new(risk, 30, 15, 0.2, DVec2::ZERO).unwrap();
            let price = |points: &[DVec2]| config.polyline_cost(&grid, points).map(|(c, _)| c);
            (choose_route(Some(rest.clone()), &new, 0.67, hysteresis, price, |_| true), new)
        };
        // Now the under route is clear and the over one slightly risky: the new plan goes
        // under, a little cheaper; the route over is kept.
        let (route, new) = judge(&two_routes(0.02), 0.2);
        assert!(new.iter().all(|p| p.y < 2.2), "the new plan goes under");
        assert!(matches!(route, Route::Kept(_)), "{route:?}");
        // Without hysteresis, or when the route over became clearly worse, it switches.
        assert_eq!(judge(&two_routes(0.02), 0.0).0, Route::Switched);
        assert_eq!(judge(&two_routes(0.4), 0.2).0, Route::Switched);
        // A route the footprint cannot follow any more is not kept.
        let grid = RiskGrid::new(&under_risky, 30, 15, 0.2, DVec2::ZERO).unwrap();
        let price = |points: &[DVec2]| config.polyline_cost(&grid, points).map(|(c, _)| c);
        assert_eq!(choose_route(Some(rest.clone()), &plan(&two_routes(0.02)).1, 0.67, 0.2, price, |_| false), Route::Switched);
        // The same route found again replaces the old path; no path followed: the plan.
        assert_eq!(choose_route(Some(rest.clone()), &over, 0.67, 0.2, price, |_| true), Route::Same);
        assert_eq!(choose_route(None, &over, 0.67, 0.2, price, |_| true), Route::New);
    }

    #[test]
    fn the_rest_of_a_path_starts_at_the_robot_and_needs_it_near() {
        let path = [DVec2::new(0.0, 0.0), DVec2::new(1.0, 0.0), DVec2::new(2.0, 0.0)];
        assert_eq!(rest_of_path(&path, DVec2::new(1.1, 0.1), 0.3).unwrap(), vec![DVec2::new(1.1, 0.1), DVec2::new(1.0, 0.0), DVec2::new(2.0, 0.0)]);
        assert_eq!(rest_of_path(&path, DVec2::new(1.0, 1.0), 0.3), None, "off the path");
        assert_eq!(rest_of_path(&path, DVec2::new(2.0, 0.0), 0.3), None, "at its end");
        assert!((max_deviation(&path, &[DVec2::new(0.0, 0.5), DVec2::new(2.0, 0.5)]) - 1.0f64.hypot(0.5)).abs() < 1e-12);
    }
}
