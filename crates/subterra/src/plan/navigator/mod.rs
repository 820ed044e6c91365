//! The navigator: terrain mapper + risk-aware A* + MPC tracker + recovery machine, wired
//! for a robot's own control loop (STEP; the JPL CoSTAR draft "Risk-aware Traversability in
//! Extreme Environments"). One [`Navigator::step`] per control tick.
//!
//! Documented on [`Navigator`]. The files:
//!
//! - `tick`: one control tick's input and output ([`NavigatorInput`], [`NavigatorOutput`]);
//! - `grids`: step 2, the navigator's grid from a new map, through the memories;
//! - `planning`: step 3, the A*'s grid, the stand-in, the entry prices and the plan;
//! - `route`: step 3's choice between the route being followed and a new plan;
//! - [`config`]: the settings and their committed defaults (`configs/navigator.toml`);
//! - [`memory`]: the hazard, near and driven memories, by [`WorldCell`];
//! - [`morphology`]: lethal patches, their growth into their own shadow, the inflation;
//! - [`target`]: stand-ins for targets off the map or on blocked cells;
//! - [`reactive`]: `rotate` and `back_out`, and the swept-footprint check of every recovery.

mod config;
mod grids;
mod memory;
mod morphology;
mod planning;
mod reactive;
mod route;
mod target;
mod tick;

use std::time::Instant;

use glam::DVec2;

pub use config::{NavigatorConfig, NavigatorSettings, UNSEEN_RISK_PER_M};
pub use tick::{NavigatorInput, NavigatorOutput, NavigatorTimings};

use self::memory::{DrivenMemory, HazardMemory, NearMemory};
use self::reactive::SafetyView;
use self::target::path_length_from;
use crate::error::{Error, Result};
use crate::frames::{check_position, check_stamp, Isometry3};
use crate::plan::astar::{PlanOutcome, PlanStatus, RiskAStar};
use crate::plan::grid::RiskGrid;
use crate::plan::mpc::{MpcOutput, MpcTracker, UnicycleState, MAX_STATE_SPEED_M_S};
use crate::plan::recovery::{wrap_angle, Behaviour, PlanFeedback, RecoveryInput, RecoveryMachine, Target};
use crate::terrain::{RiskMap, RobotConfig, TerrainConfig, TerrainMapper, TerrainStats, TerrainTimings};

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

/// The ground robot's navigation stack.
///
/// # One step, exactly
/// 1. **Map.** With a scan, [`TerrainMapper::update`] at the odometry pose; the coarse map is
///    kept (the navigator plans and tracks on it: the mapper's fine map is not computed).
///    Without a scan, the last map stands; once a map exists, no scan for longer than
///    `scan_timeout_s`, or an odometry confidence of 0 (no usable odometry source), stops the
///    robot here, with the reason in `safety` (steps 2-5 wait for the sensor).
/// 2. **Grids.** The navigator's grid is the coarse map's `risk` layer, or with
///    `navigator.cvar_alpha` its `CVaR_α`, where the map observed the cell (holes and
///    drop-offs rated by ray reasoning are observed and lethal: a cell whose ground is missing
///    where the sensor should have seen it); NaN where it did not. Then, in the world frame:
///    the **near memory** records the newest (or highest) rating of every cell observed within
///    `near_memory_m`; the **hazard memory** forgets remembered cells beyond
///    `hazard_memory_range_m` or seen again as ground (at least `hazard_memory_forget_points`
///    ground points and a rating below lethal), remembers every lethal cell within
///    `hazard_memory_record_m` in a patch (`lethal_min_neighbours`), and raises every
///    remembered cell on the grid to its rating. A copy for the A* only is grown into the
///    unseen: unobserved cells within `unseen_growth_m` of a lethal patch and at least
///    `unseen_growth_min_range_m` from the robot take its rating (a hazard's far side lies in
///    its own shadow). Last, on both, each cell still unobserved within `near_memory_m` takes
///    its near-memory rating if that is above the planner's `unknown_risk`. With
///    `unseen_near_lethal`, the **unseen-near rule** marks lethal on both each cell within the
///    sensor's blind ring (`coverage.min_range_m`) that is unobserved, never held by the near
///    memory below lethal as shown ground (a point of its own, or rated from outside the
///    blind ring), never stood on, not within the blind ring of the robot's first
///    pose, with its 8 neighbours the same: ground the all-round sensor had in view on its way
///    in and never got a return from (a hole's mouth; `memory::mark_unseen_near`). With
///    `void_rim_m` > 0, every cell within it of a void (a cell whose `negative` layer is
///    lethal, on this map in a patch or remembered by the hazard memory) is lethal on both
///    unless the robot stood on it: the map places a void's edge only to within one radial
///    ground bin (`memory::mark_void_rims`). The **driven
///    memory** adds the cells under the robot's footprint every step. **Lethal** is the map's
///    one definition ([`RiskMap::lethal_risk`]): the A* never enters a lethal cell whatever its
///    thresholds, the MPC keeps the footprint off them.
/// 3. **Plan** (only while tracking, and at most every `replan_period_s` unless the last plan
///    failed, the thresholds or the target changed): with `inflate_lethal`, the lethal patch
///    cells of the navigator's grid inflated by half the robot's width (plus
///    `inflation_margin_m`) except around the robot, and the cells grown into the unseen laid
///    over them as they are (a guess: they block, they are not inflated); a target off the map
///    is planned toward with the A*'s exit search (`leave_by_any_border`: the path leaves by
///    the border cell that makes the whole way cheapest, the straight line on priced at λ a
///    metre, [`RiskAStar::plan_toward`]; when it finds no way out within the thresholds, and
///    without it, the target is replaced by the map cell on the segment robot→target nearest
///    it); a target on a cell the robot may not enter by the
///    nearest cell where the robot fits and that the A* reaches (`target`); with `perception_aware`, the moves that would enter an unknown cell (not
///    observed, not remembered, not driven) the sensor will not have seen on the way are priced
///    at the map's `risk.unknown` instead of the planner's `unknown_risk`
///    ([`SensorCoverage`](crate::plan::SensorCoverage)); then the A* with the recovery machine's `R_inst`/`R_total`.
///    With `footprint_replans` > 0 the path found is checked with the tracker's footprint test
///    (below, step 5) at poses every half cell along it, each with the heading of the path's
///    chord over the robot's length; where the rectangle fails, a disc of the circumscribed
///    less the inscribed radius around that pose is closed and the A* runs again, up to
///    `footprint_replans` times (`reactive::footprint_checked`): the disc the A* plans for
///    takes turns the rectangle cannot, and such a path only stops the tracker beside an
///    obstacle. With `plan_hysteresis` > 0, a plan that takes another route than the path
///    being followed (a vertex of the path's rest farther than the robot's width from it)
///    replaces it only if that rest crosses an unknown cell, or, priced alike ([`RiskAStar::price_polyline`], the
///    perception-aware entry prices included, plus λ per metre on to the target), is untraversable, over budget, footprint-blocked or more
///    than `1 + plan_hysteresis` times the plan's price; else the rest is kept. A plan that
///    lengthens the way to the target by more than the recovery's `progress_min_m` is
///    reported as a reroute ([`RecoveryInput::route_switched`]): the recovery machine then
///    measures progress along the new route (once a window).
///    The distance to the target the recovery machine measures progress by is the path's
///    length plus the straight remainder beyond the map when a path was found, else the
///    straight-line distance.
/// 4. **Recovery.** [`RecoveryMachine::step`] with the plan's outcome and the heading of most
///    clearance (`reactive::clearance_heading`) gives the behaviour for this tick.
/// 5. **Act.** `track`: the MPC on the last path, on the navigator's grid (ungrown,
///    uninflated: its speed limits and lethal obstacle polygons), its command checked
///    (`reactive::filter_track`): if the footprint it would sweep newly covers the centre of
///    a lethal cell or of an unknown one within `track_unknown_fringe_m` of a lethal cell (a
///    hazard's unseen rim), a turn in place, a straight drive or a stop instead
///    (`NavigatorOutput::safety` says why); no path yet: stop.
///    `clear_map`: drop the mapper's window and the remembered hazards and near cells farther
///    than `hazard_memory_keep_m`, stop. `rotate` and `back_out` (`reactive`) move only if
///    the footprint their next motion sweeps covers no cell at or above the nominal `R_inst`
///    (raised thresholds are for the planner) or lethal, and no unknown cell; when no motion is safe the behaviour ends
///    ([`RecoveryMachine::abort`], with the reason) and the robot stops.
///    `raise_thresholds` and the final behaviours: stop.
///
/// Every stage's wall time is reported.
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
    /// The distance to the target the recovery machine was last told \[m\].
    last_distance_m: Option<f64>,
    last_plan_s: Option<f64>,
    last_plan_ok: bool,
    planned_for: Option<(f64, f64, Target)>,
    last_stamp_s: Option<f64>,
    /// The stamp of the last scan mapped \[s\].
    last_scan_s: Option<f64>,
    transitions_seen: usize,
    home_pending: bool,
    terrain_stats: (TerrainStats, TerrainTimings),
}

/// The control period assumed before two steps have been seen \[s\].
const DEFAULT_PERIOD_S: f64 = 0.1;

impl Navigator {
    /// A navigator for `robot` on `terrain` settings, driving to `goal` and back to `home`
    /// when it gives up (world frame \[m\]; `None`: where the robot is at its first step). The
    /// planner's `lethal_risk` and the tracker's `risk.lethal_risk` are set to the terrain's
    /// `risk.lethal_risk`: one definition of lethal.
    pub fn new(robot: RobotConfig, terrain: TerrainConfig, config: NavigatorConfig, goal: DVec2, home: Option<DVec2>) -> Result<Self> {
        config.validate()?;
        check_position("goal", &[goal.x, goal.y])?;
        if let Some(home) = home {
            check_position("home", &[home.x, home.y])?;
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

    /// Drives to a new `goal` (world frame \[m\]) from the next step: the map, the remembered
    /// hazards, the driven cells and home stay; the plan, the tracker's warm start and the
    /// recovery ladder (behaviour, thresholds, transitions, trail) start again, as for a
    /// navigator that has just been made. A goal that is not finite is an `InputError`
    /// naming `goal`, and nothing changes.
    pub fn set_goal(&mut self, goal: DVec2) -> Result<()> {
        check_position("goal", &[goal.x, goal.y])?;
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

    /// One control tick (see [`Navigator`]).
    pub fn step(&mut self, input: &NavigatorInput<'_>) -> Result<NavigatorOutput> {
        let started = Instant::now();
        if !(input.speed_m_s.is_finite() && input.speed_m_s.abs() <= MAX_STATE_SPEED_M_S) {
            return Err(Error::input("speed", format!("must be finite and within {MAX_STATE_SPEED_M_S} m/s of zero (any ground robot), got {}", input.speed_m_s)));
        }
        check_stamp("stamp_s", input.stamp_s)?;
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

/// Heading of the body's x axis in the world's x-y plane \[rad\].
fn yaw_of(pose: &Isometry3) -> f64 {
    let x = pose.rotation * glam::DVec3::X;
    wrap_angle(x.y.atan2(x.x))
}
