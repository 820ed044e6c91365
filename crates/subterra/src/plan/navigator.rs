//! The navigator: terrain mapper + risk-aware A* + MPC tracker + recovery machine, wired
//! for a robot's own control loop (DESIGN §3). One [`Navigator::step`] per control tick.
//!
//! # One step, exactly
//! 1. **Map.** With a scan, [`TerrainMapper::update`] at the odometry pose; the coarse
//!    map is kept. Without one, the last map stands.
//! 2. **Risk grid.** The coarse map's `risk` layer, or with `navigator.cvar_alpha` its
//!    `CVaR_α` (risk-averse planning on the uncertainty of DESIGN §2), where the map has
//!    observed the cell; NaN (priced by the planner's `unknown_risk`, default
//!    [`UNSEEN_RISK_PER_M`]) where it has not. With `near_memory_m` > 0, a **near memory**
//!    (world frame, by global cell index) then records the newest rating of every cell
//!    observed within `near_memory_m` of the robot (with `near_memory_highest`, the highest
//!    since it came that near: seen from close by, a slope's plane fit rests on fewer cells
//!    and rates lower), and forgets cells beyond it; it is recalled last (below). With `hazard_memory`, each new map then
//!    passes through a **hazard memory** kept in the world frame, by global cell index:
//!    remembered cells farther than `hazard_memory_range_m` from the robot, and those the map
//!    now rates below `lethal_risk` on at least `hazard_memory_forget_points` ground
//!    points, are forgotten; every cell within `hazard_memory_record_m` of the robot rated
//!    at or above `lethal_risk`, with at least `lethal_min_neighbours` of its 8 neighbours
//!    rated so too (a patch, not a noise speckle), is remembered
//!    (with its newest rating); every remembered cell on the grid is raised to its rating
//!    (unobserved ones set to it). The mapper fuses only its window (2 s by default), and a
//!    lidar 0.7 m up sees no ground within ~2.3 m: without the memory a hole seen from afar
//!    leaves the map before the robot has passed it. A bottomless hole never gets ground
//!    points, so it is never forgotten while the robot is near. Then, on a copy for the A*
//!    only, with `unseen_growth_m` > 0, every unobserved cell within that distance of a
//!    lethal patch (as for the memory) and at least `unseen_growth_min_range_m` from the
//!    robot takes its rating: a hazard's corners and far side lie in its own shadow (mine
//!    seed 11: a pit's tip beyond its near rim never got a return, and the footprint went
//!    over it). The grown cells are a guess, so they steer the plan but are not the MPC's
//!    hard obstacles: in its grid they boxed in the robot's current state (mine seed 0: the
//!    backup stop on 11 of 307 ticks). Last, on both grids, each cell still unobserved
//!    within `near_memory_m` of the robot takes its rating from the near memory if that is
//!    above the planner's `unknown_risk` (the unseen is never priced below it): the ground
//!    under and just ahead of the robot, in the lidar's blind ring, keeps what was seen of
//!    it (risky-slope: the ramp from its foot). The
//!    local risk is the grid's value under the robot (`unknown_risk` when NaN or off the map).
//! 3. **Plan** (only while tracking, and at most every `replan_period_s` unless the last
//!    plan failed, the thresholds or the target changed): A* with the recovery machine's
//!    current `R_inst`/`R_total` from the robot's cell to the target — the goal, or home
//!    after the goal was given up. A target off the map is replaced by the map cell on
//!    the segment robot→target nearest to it, one cell inside the edge, moved to the
//!    nearest cell within `standin_search_m` where the robot fits (every cell within half
//!    its width plus `inflation_margin_m` below `R_inst`) and that the A* reaches from the
//!    robot (a flood fill with its moves over the grid it plans on), if it is not one; with
//!    none there, the cell of the whole map nearest the target that is one (the planner
//!    sees only the local map; the rest of the way counts as straight). A target on the
//!    map where the robot does not fit is moved the same way, within `standin_search_m`. With
//!    `inflate_lethal`, the A* plans on the grid with every cell within half the robot's
//!    width (its inscribed radius) plus `inflation_margin_m` of a lethal cell (at or above `lethal_risk`, in a patch as
//!    for the memory) raised to that level,
//!    except within that radius of the robot (so that it can plan its way out); the A*
//!    plans the robot's centre, and a centre there would put the footprint on the hazard.
//!    The MPC, the local risk and `back_out` use the grid uninflated and ungrown (the MPC keeps the
//!    footprint off lethal polygons itself). The distance to the
//!    target the recovery machine measures progress by is the path's length plus that
//!    straight remainder when a path was found, else the straight-line distance.
//! 4. **Recovery.** [`RecoveryMachine::step`] with the plan's outcome (a path within
//!    thresholds, none, or none within the budget) and the heading of most clearance
//!    (step 6) gives the behaviour for this tick.
//! 5. **Act.** `track`: the MPC on the last path (the risk grid gives its speed limits and
//!    obstacle polygons); no path yet: stop. `clear_map`: drop the mapper's window and the
//!    remembered hazards and near-memory cells farther than `hazard_memory_keep_m` from the robot, stop.
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

use std::collections::HashMap;
use std::f64::consts::PI;
use std::time::Instant;

use glam::DVec2;
use serde::{Deserialize, Serialize};

use crate::error::{require_non_negative, require_positive, Error, Result};
use crate::frames::Isometry3;
use crate::plan::astar::{PlanOutcome, PlanStatus, RiskAStar, RiskAStarConfig, RiskGrid};
use crate::plan::mpc::{MpcConfig, MpcOutput, MpcTracker, RiskGrid as MpcRiskGrid, UnicycleState};
use crate::plan::recovery::{wrap_angle, Behaviour, PlanFeedback, RecoveryConfig, RecoveryInput, RecoveryMachine, Target, Transition};
use crate::terrain::{GridGeometry, RiskMap, RobotConfig, TerrainConfig, TerrainMapper, TerrainStats, TerrainTimings};

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
    /// Remember hazards in the world frame beyond the mapper's fusion window (step 2).
    pub hazard_memory: bool,
    /// Risk at or above which a cell is lethal: remembered by the hazard memory, and
    /// inflated by half the robot's width for the planner [0-1].
    pub lethal_risk: f64,
    /// A lethal cell is remembered and inflated only with at least this many of its 8
    /// neighbours lethal too, in [0, 2]: real hazards are patches, while single cells rated
    /// lethal by sensor noise would each close a disc the robot's width across.
    pub lethal_min_neighbours: u32,
    /// Inflate lethal cells by half the robot's width plus `inflation_margin_m` for the
    /// planner (step 3).
    pub inflate_lethal: bool,
    /// Added to half the robot's width for the inflation and for where the robot fits [m].
    /// A hazard's rim is mapped less sharply than its middle, but on `mine` seeds 0-19 a
    /// 0.1 m margin closed passages: 12 of 20 reached the goal (16 without), 2 fell (1).
    pub inflation_margin_m: f64,
    /// Unobserved cells within this distance of a lethal patch are taken as part of it on
    /// the A*'s grid (step 2) [m]; 0: off. A hazard's far side and corners lie in its own shadow (a pit's
    /// tip beyond its near rim gets no return): what the lidar could not see next to a drop
    /// is more likely the drop than ground.
    pub unseen_growth_m: f64,
    /// No growth into unobserved cells nearer than this to the robot [m] (default about
    /// the Husky footprint's half-length, 0.5 m): the cells under and beside the robot are
    /// unobserved because the lidar cannot look down so steeply, not because a hazard
    /// shadows them, and grown there a corridor's walls closed it around the robot
    /// (`dead-end` gave up on the way home with 0 and 0.35 m). Farther out the growth stays,
    /// blind ring or not: mine seed 11 fell with 0.6 m, and on mine seeds 0-99 a 2.5 m range
    /// gave 3 falls (docs/drive.md).
    pub unseen_growth_min_range_m: f64,
    /// `clear_map` keeps the remembered cells this near the robot [m]: the lidar cannot see
    /// them again from where it stands (its blind ring), the rest it sees again at once.
    pub hazard_memory_keep_m: f64,
    /// A remembered cell is forgotten once the map holds at least this many ground points in
    /// it and rates it below `lethal_risk`.
    pub hazard_memory_forget_points: u32,
    /// Only cells this near the robot are remembered [m]: the memory must bridge the blind
    /// ring, and far cells, on few points and grazing rays, are rated least reliably.
    pub hazard_memory_record_m: f64,
    /// Remembered cells farther than this from the robot are forgotten [m].
    pub hazard_memory_range_m: f64,
    /// **Near memory** (step 2): an unobserved cell within this distance of the robot takes
    /// the rating it had when last observed within it (with `near_memory_highest` its highest
    /// there), if that is above the planner's `unknown_risk` [m]; 0: off. The lidar's blind ring
    /// (~2.3 m for one 0.7 m up) hides the ground the robot is about to drive on: without
    /// it a slope seen from afar turns into cheap unseen ground (`UNSEEN_RISK_PER_M`) once
    /// the robot stands at its foot, and is climbed on nominal thresholds (risky-slope).
    pub near_memory_m: f64,
    /// The near memory keeps each cell's highest rating while near instead of its newest.
    /// Seen from close by, a slope's plane fit rests on fewer cells and rates it lower (the
    /// risky-slope ramp: ~0.62 from afar, ~0.37 from its foot), so the newest rating lets
    /// the robot climb it on nominal thresholds; the highest keeps it. Off by default: on
    /// `mine` it flipped seed 11 (the pit tip never seen) into a fall (docs/drive.md).
    pub near_memory_highest: bool,
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
            hazard_memory: true,
            lethal_risk: 0.9,
            lethal_min_neighbours: 2,
            inflate_lethal: true,
            inflation_margin_m: 0.0,
            unseen_growth_m: 0.3,
            unseen_growth_min_range_m: 0.5,
            hazard_memory_keep_m: 3.0,
            hazard_memory_forget_points: 5,
            hazard_memory_record_m: 6.0,
            hazard_memory_range_m: 15.0,
            near_memory_m: 3.0,
            near_memory_highest: false,
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
        require_positive("navigator.hazard_memory_record_m", self.hazard_memory_record_m)?;
        require_positive("navigator.hazard_memory_range_m", self.hazard_memory_range_m)?;
        require_non_negative("navigator.hazard_memory_keep_m", self.hazard_memory_keep_m)?;
        require_non_negative("navigator.inflation_margin_m", self.inflation_margin_m)?;
        require_non_negative("navigator.unseen_growth_m", self.unseen_growth_m)?;
        require_non_negative("navigator.unseen_growth_min_range_m", self.unseen_growth_min_range_m)?;
        require_non_negative("navigator.near_memory_m", self.near_memory_m)?;
        if !(self.lethal_risk > 0.0 && self.lethal_risk <= 1.0) {
            return Err(Error::config("navigator.lethal_risk", "must be in (0, 1]", self.lethal_risk));
        }
        if self.lethal_min_neighbours > 2 {
            return Err(Error::config("navigator.lethal_min_neighbours", "must be in [0, 2]", self.lethal_min_neighbours));
        }
        if self.hazard_memory_forget_points == 0 {
            return Err(Error::config("navigator.hazard_memory_forget_points", "must be >= 1", self.hazard_memory_forget_points));
        }
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
    hazards: HashMap<(i64, i64), f32>,
    /// Step 2's near memory: the last rating of observed cells near the robot, by global cell.
    near: HashMap<(i64, i64), f32>,
    /// `plan_risk` grown into the unseen (step 2): the A*'s grid before its inflation.
    grown_risk: Vec<f32>,
    astar_risk: Vec<f32>,
    /// Scratch: the cells the planner can reach from the robot (stand-ins must be).
    reachable: Vec<bool>,
    /// Scratch of the flood fill.
    flood: Vec<usize>,
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
            hazards: HashMap::new(),
            near: HashMap::new(),
            grown_risk: Vec::new(),
            astar_risk: Vec::new(),
            reachable: Vec::new(),
            flood: Vec::new(),
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

    /// The planner's grid on the last map's geometry (step 2: risk or CVaR where observed,
    /// raised by the hazard memory; near the robot the near memory's rating where it is
    /// unobserved; NaN elsewhere unobserved), row-major `ny x nx`; empty before
    /// the first scan.
    pub fn plan_grid(&self) -> &[f32] {
        &self.plan_risk
    }

    /// Cells in the hazard memory.
    pub fn remembered_hazards(&self) -> usize {
        self.hazards.len()
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
            let near_m = self.config.navigator.near_memory_m;
            if near_m > 0.0 {
                remember_near(&mut self.near, &self.plan_risk, map.geometry(), position, near_m, self.config.navigator.near_memory_highest);
            }
            if self.config.navigator.hazard_memory {
                let ground_points = map.layer("ground_count")?;
                remember_hazards(&mut self.hazards, &mut self.plan_risk, ground_points, map.geometry(), position, &self.config.navigator);
            }
            let nav = &self.config.navigator;
            self.grown_risk.clone_from(&self.plan_risk);
            if nav.unseen_growth_m > 0.0 {
                let growth = Growth { lethal: nav.lethal_risk as f32, min_neighbours: nav.lethal_min_neighbours, radius_m: nav.unseen_growth_m, robot: position, min_range_m: nav.unseen_growth_min_range_m };
                grow_into_unseen(&mut self.grown_risk, &mut self.astar_risk, map.geometry(), &growth);
            }
            if near_m > 0.0 {
                let above = self.config.planner.unknown_risk as f32;
                recall_near(&self.near, &mut self.plan_risk, map.geometry(), position, near_m, above);
                recall_near(&self.near, &mut self.grown_risk, map.geometry(), position, near_m, above);
            }
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
                let nav = &self.config.navigator;
                let fit_radius = 0.5 * self.robot.width_m + nav.inflation_margin_m;
                let unknown = self.config.planner.unknown_risk;
                if nav.inflate_lethal {
                    inflate_lethal(&self.grown_risk, &mut self.astar_risk, g, nav.lethal_risk as f32, nav.lethal_min_neighbours, fit_radius, position);
                } else {
                    self.astar_risk.clone_from(&self.grown_risk);
                }
                let astar_grid = RiskGrid::new(&self.astar_risk, g.nx, g.ny, g.resolution_m, g.origin_m())?;
                // A stand-in for a target off the map, or on a cell the robot may not enter,
                // must be a cell where it fits and that the planner can reach.
                reachable_from(&astar_grid, position, key.0, unknown, self.config.planner.allow_corner_cutting, &mut self.reachable, &mut self.flood);
                let (mut goal_on_map, mut remainder) = on_map(&grid, position, target_point);
                let off_map = remainder > 0.0;
                let search = Search { r_inst: key.0, unknown, fit_radius_m: fit_radius, reachable: &self.reachable };
                let standin = nearest_traversable(&grid, goal_on_map, nav.standin_search_m, &search)
                    .or_else(|| off_map.then(|| nearest_traversable_to(&grid, target_point, &search)).flatten());
                if let Some(p) = standin {
                    goal_on_map = p;
                    remainder = p.distance(target_point);
                }
                if self.planner.config().r_inst != key.0 || self.planner.config().r_total != key.1 {
                    self.planner = RiskAStar::new(RiskAStarConfig { r_inst: key.0, r_total: key.1, ..self.config.planner })?;
                }
                let outcome = self.planner.plan(&astar_grid, position, goal_on_map)?;
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
                forget_beyond(&mut self.hazards, position, map.geometry().resolution_m, self.config.navigator.hazard_memory_keep_m);
                forget_beyond(&mut self.near, position, map.geometry().resolution_m, self.config.navigator.hazard_memory_keep_m);
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
/// Step 2's hazard memory, on the planner's grid `risk` (NaN: unobserved) of geometry `g`:
/// forgets remembered cells beyond `hazard_memory_range_m` of `position` and those the map
/// now holds `hazard_memory_forget_points` ground points in and rates below
/// `lethal_risk`; remembers every cell within `hazard_memory_record_m` rated at or above it
/// (its newest rating);
/// then raises each remembered cell on the grid to its remembered rating.
fn remember_hazards(memory: &mut HashMap<(i64, i64), f32>, risk: &mut [f32], ground_points: &[f32], g: &GridGeometry, position: DVec2, s: &NavigatorSettings) {
    let (ox, oy) = g.origin_cell;
    let threshold = s.lethal_risk as f32;
    let forget_points = s.hazard_memory_forget_points as f32;
    let range_cells = s.hazard_memory_range_m / g.resolution_m;
    let here = position / g.resolution_m - 0.5;
    let flat = |(wx, wy): (i64, i64)| {
        let (ix, iy) = (wx - ox, wy - oy);
        (ix >= 0 && iy >= 0 && ix < g.nx as i64 && iy < g.ny as i64).then(|| iy as usize * g.nx + ix as usize)
    };
    memory.retain(|&key, _| {
        let near = DVec2::new(key.0 as f64, key.1 as f64).distance_squared(here) <= range_cells * range_cells;
        near && flat(key).is_none_or(|c| !(ground_points[c] >= forget_points && risk[c] < threshold))
    });
    let record_cells = s.hazard_memory_record_m / g.resolution_m;
    for (c, &r) in risk.iter().enumerate() {
        let key = (ox + (c % g.nx) as i64, oy + (c / g.nx) as i64);
        // NaN (unobserved) compares false.
        let near = DVec2::new(key.0 as f64, key.1 as f64).distance_squared(here) <= record_cells * record_cells;
        if r >= threshold && near && clustered(risk, g.nx, g.ny, c, threshold, s.lethal_min_neighbours) {
            memory.insert(key, r);
        }
    }
    for (&key, &remembered) in memory.iter() {
        if let Some(c) = flat(key) {
            risk[c] = if risk[c].is_nan() { remembered } else { risk[c].max(remembered) };
        }
    }
}

/// The cells of geometry `g` whose centres lie within `radius_m` of `position`: `f(global
/// cell, flat index)` for each.
fn for_cells_within(g: &GridGeometry, position: DVec2, radius_m: f64, mut f: impl FnMut((i64, i64), usize)) {
    let (ox, oy) = g.origin_cell;
    let radius = radius_m / g.resolution_m;
    let here = position / g.resolution_m - 0.5;
    let (lo_x, hi_x) = ((here.x - radius).floor() as i64, (here.x + radius).ceil() as i64);
    let (lo_y, hi_y) = ((here.y - radius).floor() as i64, (here.y + radius).ceil() as i64);
    for wy in lo_y.max(oy)..=hi_y.min(oy + g.ny as i64 - 1) {
        for wx in lo_x.max(ox)..=hi_x.min(ox + g.nx as i64 - 1) {
            if DVec2::new(wx as f64, wy as f64).distance_squared(here) <= radius * radius {
                f((wx, wy), (wy - oy) as usize * g.nx + (wx - ox) as usize);
            }
        }
    }
}

/// Step 2's near memory, recording: forgets remembered cells farther than `radius_m` from
/// `position`, and remembers for each cell within it that the map observed (`risk` not NaN;
/// the map's ratings only, before the hazard memory) its newest rating, or with `highest`
/// the highest it got while near.
fn remember_near(memory: &mut HashMap<(i64, i64), f32>, risk: &[f32], g: &GridGeometry, position: DVec2, radius_m: f64, highest: bool) {
    let radius = radius_m / g.resolution_m;
    let here = position / g.resolution_m - 0.5;
    memory.retain(|&key, _| DVec2::new(key.0 as f64, key.1 as f64).distance_squared(here) <= radius * radius);
    for_cells_within(g, position, radius_m, |key, c| {
        if !risk[c].is_nan() {
            let r = memory.entry(key).or_insert(risk[c]);
            *r = if highest { r.max(risk[c]) } else { risk[c] };
        }
    });
}

/// Step 2's near memory, recalling: each cell of `risk` still unobserved (NaN: after the
/// hazard memory and the growth into the unseen) within `radius_m` of `position` whose
/// remembered rating is above `above` (the planner's price of the unseen) takes it.
fn recall_near(memory: &HashMap<(i64, i64), f32>, risk: &mut [f32], g: &GridGeometry, position: DVec2, radius_m: f64, above: f32) {
    for_cells_within(g, position, radius_m, |key, c| {
        if risk[c].is_nan() {
            if let Some(&r) = memory.get(&key).filter(|&&r| r > above) {
                risk[c] = r;
            }
        }
    });
}

/// Step 2's growth into the unseen, its settings.
#[derive(Debug, Clone, Copy)]
struct Growth {
    /// The lethal level.
    lethal: f32,
    /// Lethal neighbours a lethal cell needs to spread (a patch, not a speckle).
    min_neighbours: u32,
    /// How far a patch spreads [m].
    radius_m: f64,
    /// The robot [m, world].
    robot: DVec2,
    /// No cell whose centre is nearer the robot than this takes a rating [m].
    min_range_m: f64,
}

/// Step 2's growth into the unseen: every unobserved (NaN) cell of `risk` within
/// `radius_m` of a lethal cell (at or above `lethal`, with `min_neighbours` lethal
/// neighbours), and at least `min_range_m` from the robot, takes the highest such rating.
/// Only cells lethal before the growth spread it. `scratch`: a buffer for the grid as it was.
fn grow_into_unseen(risk: &mut [f32], scratch: &mut Vec<f32>, g: &GridGeometry, growth: &Growth) {
    let Growth { lethal, min_neighbours, radius_m, robot, min_range_m } = *growth;
    // The robot in cell units, relative to cell centres.
    let rc = (robot - g.origin_m()) / g.resolution_m - 0.5;
    let near2 = (min_range_m / g.resolution_m).powi(2);
    scratch.clear();
    scratch.extend_from_slice(risk);
    let src = &scratch[..];
    let (nx, ny) = (g.nx as i64, g.ny as i64);
    // In cells, a hair wide: 0.3 m / 0.1 m is 2.9999999999999996.
    let cells = radius_m / g.resolution_m * (1.0 + 1e-9);
    let reach = cells.floor() as i64;
    let disc: Vec<(i64, i64)> = (-reach..=reach).flat_map(|dy| (-reach..=reach).map(move |dx| (dx, dy))).filter(|&(dx, dy)| (dx * dx + dy * dy) as f64 <= cells * cells).collect();
    for iy in 0..ny {
        for ix in 0..nx {
            let c = (iy * nx + ix) as usize;
            let r = src[c];
            if !(r >= lethal) || !clustered(src, g.nx, g.ny, c, lethal, min_neighbours) {
                continue;
            }
            for &(dx, dy) in &disc {
                let (jx, jy) = (ix + dx, iy + dy);
                if jx < 0 || jy < 0 || jx >= nx || jy >= ny {
                    continue;
                }
                let j = (jy * nx + jx) as usize;
                if src[j].is_nan() && !(risk[j] >= r) && DVec2::new(jx as f64, jy as f64).distance_squared(rc) >= near2 {
                    risk[j] = r;
                }
            }
        }
    }
}

/// Whether cell `c` of the `nx x ny` grid `risk` has at least `min` of its 8 neighbours at or
/// above `lethal` (cells off the grid do not count).
fn clustered(risk: &[f32], nx: usize, ny: usize, c: usize, lethal: f32, min: u32) -> bool {
    if min == 0 {
        return true;
    }
    let (ix, iy) = ((c % nx) as i64, (c / nx) as i64);
    let mut n = 0;
    for (dx, dy) in [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
        let (jx, jy) = (ix + dx, iy + dy);
        if jx >= 0 && jy >= 0 && jx < nx as i64 && jy < ny as i64 && risk[jy as usize * nx + jx as usize] >= lethal {
            n += 1;
        }
    }
    n >= min
}

/// Forgets the remembered cells whose centres are farther than `keep_m` from `position`.
fn forget_beyond(memory: &mut HashMap<(i64, i64), f32>, position: DVec2, resolution_m: f64, keep_m: f64) {
    let here = position / resolution_m - 0.5;
    let keep = keep_m / resolution_m;
    memory.retain(|&(wx, wy), _| DVec2::new(wx as f64, wy as f64).distance_squared(here) <= keep * keep);
}

/// Step 3's planner grid: `risk` with every cell whose centre lies within `radius_m` of a
/// cell at or above `lethal` with at least `min_neighbours` such neighbours ([`clustered`])
/// raised to at least `lethal` (the robot's centre there
/// would put its footprint on it; `radius_m` is half its width, the inscribed radius), except
/// cells within `radius_m` of `robot`: a robot already that close must be able to plan its
/// way out.
fn inflate_lethal(risk: &[f32], out: &mut Vec<f32>, g: &GridGeometry, lethal: f32, min_neighbours: u32, radius_m: f64, robot: DVec2) {
    out.clear();
    out.extend_from_slice(risk);
    let res = g.resolution_m;
    let (nx, ny) = (g.nx as i64, g.ny as i64);
    let reach = (radius_m / res).floor() as i64;
    let r2 = (radius_m / res) * (radius_m / res);
    let disc: Vec<(i64, i64)> =
        (-reach..=reach).flat_map(|dy| (-reach..=reach).map(move |dx| (dx, dy))).filter(|&(dx, dy)| (dx * dx + dy * dy) as f64 <= r2).collect();
    // The robot in cell units, relative to cell centres.
    let rc = (robot - g.origin_m()) / res - 0.5;
    let is_lethal = |ix: i64, iy: i64| ix < 0 || iy < 0 || ix >= nx || iy >= ny || risk[(iy * nx + ix) as usize] >= lethal;
    for iy in 0..ny {
        for ix in 0..nx {
            let r = risk[(iy * nx + ix) as usize];
            // NaN compares false. An interior cell's disc is covered by its neighbours' (a
            // cell within reach of it is nearer one of its four neighbours).
            // With `min_neighbours` <= 2 those neighbours are clustered themselves.
            let interior = is_lethal(ix - 1, iy) && is_lethal(ix + 1, iy) && is_lethal(ix, iy - 1) && is_lethal(ix, iy + 1);
            if !(r >= lethal) || interior || !clustered(risk, g.nx, g.ny, (iy * nx + ix) as usize, lethal, min_neighbours) {
                continue;
            }
            for &(dx, dy) in &disc {
                let (jx, jy) = (ix + dx, iy + dy);
                if jx < 0 || jy < 0 || jx >= nx || jy >= ny || DVec2::new(jx as f64, jy as f64).distance_squared(rc) <= r2 {
                    continue;
                }
                let v = &mut out[(jy * nx + jx) as usize];
                if !(*v >= r) {
                    *v = r;
                }
            }
        }
    }
}

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

/// What a stand-in must satisfy (step 3): the robot fits there (every cell within
/// `fit_radius_m` of it, itself included, has a risk (NaN: `unknown`) below `r_inst`) and the
/// planner reaches it from the robot (`reachable`, by cell; empty: not checked). A lone
/// traversable cell in a lethal patch, or a pocket walled in by one, would do as a target
/// for the planner, but no path reaches it.
struct Search<'a> {
    r_inst: f64,
    unknown: f64,
    fit_radius_m: f64,
    reachable: &'a [bool],
}

impl Search<'_> {
    fn accepts(&self, grid: &RiskGrid<'_>, ix: i64, iy: i64) -> bool {
        let (nx, ny) = (grid.nx() as i64, grid.ny() as i64);
        let res = grid.resolution_m();
        let blocked = |ix: i64, iy: i64| {
            let inside = ix >= 0 && iy >= 0 && ix < nx && iy < ny;
            !inside || {
                let r = grid.risk()[(iy * nx + ix) as usize];
                (if r.is_nan() { self.unknown } else { f64::from(r) }) >= self.r_inst
            }
        };
        let fit = (self.fit_radius_m / res).floor() as i64;
        let r2 = self.fit_radius_m * self.fit_radius_m;
        let inside = ix >= 0 && iy >= 0 && ix < nx && iy < ny;
        inside
            && (self.reachable.is_empty() || self.reachable[(iy * nx + ix) as usize])
            && (-fit..=fit).all(|dy| (-fit..=fit).all(|dx| ((dx * dx + dy * dy) as f64 * res * res > r2) || !blocked(ix + dx, iy + dy)))
    }
}

/// The centre of the cell nearest `p` (within `radius_m`) that `search` accepts.
fn nearest_traversable(grid: &RiskGrid<'_>, p: DVec2, radius_m: f64, search: &Search<'_>) -> Option<DVec2> {
    let centre = grid.cell_of(p)?;
    let res = grid.resolution_m();
    let reach = (radius_m / res).ceil() as i64;
    let mut best: Option<(f64, DVec2)> = None;
    for dy in -reach..=reach {
        for dx in -reach..=reach {
            let (ix, iy) = (centre.ix as i64 + dx, centre.iy as i64 + dy);
            let q = grid.origin_m() + (DVec2::new(ix as f64, iy as f64) + 0.5) * res;
            let d = q.distance_squared(p);
            if d <= radius_m * radius_m && best.is_none_or(|(bd, _)| d < bd) && search.accepts(grid, ix, iy) {
                best = Some((d, q));
            }
        }
    }
    best.map(|(_, q)| q)
}

/// The centre of the cell of the whole grid nearest `p` that `search` accepts: for a target
/// off the map whose stand-in on the edge has none near it, the way on goes through the
/// reachable cell nearest the target (the map grows as the robot gets there).
fn nearest_traversable_to(grid: &RiskGrid<'_>, p: DVec2, search: &Search<'_>) -> Option<DVec2> {
    let res = grid.resolution_m();
    let mut best: Option<(f64, DVec2)> = None;
    for iy in 0..grid.ny() as i64 {
        for ix in 0..grid.nx() as i64 {
            if !search.reachable.is_empty() && !search.reachable[iy as usize * grid.nx() + ix as usize] {
                continue;
            }
            let q = grid.origin_m() + (DVec2::new(ix as f64, iy as f64) + 0.5) * res;
            let d = q.distance_squared(p);
            if best.is_none_or(|(bd, _)| d < bd) && search.accepts(grid, ix, iy) {
                best = Some((d, q));
            }
        }
    }
    best.map(|(_, q)| q)
}

/// Marks in `out` (one flag per cell) the cells the A* can reach from `start`'s cell: its
/// moves (8-connected; a diagonal needs both cells at its corner traversable unless
/// `allow_corner_cutting`) over cells with a risk (NaN: `unknown`) below `r_inst`. The start
/// cell counts as reached even when blocked (the A* then reports it). `out` is left empty
/// when `start` is off the grid (nothing is checked then). `stack`: scratch.
fn reachable_from(grid: &RiskGrid<'_>, start: DVec2, r_inst: f64, unknown: f64, allow_corner_cutting: bool, out: &mut Vec<bool>, stack: &mut Vec<usize>) {
    out.clear();
    let Some(c) = grid.cell_of(start) else { return };
    let (nx, ny) = (grid.nx(), grid.ny());
    out.resize(nx * ny, false);
    let risk = grid.risk();
    let free = |i: usize| {
        let r = risk[i];
        (if r.is_nan() { unknown } else { f64::from(r) }) < r_inst
    };
    stack.clear();
    let s = c.iy as usize * nx + c.ix as usize;
    out[s] = true;
    stack.push(s);
    while let Some(i) = stack.pop() {
        let (x, y) = ((i % nx) as i64, (i / nx) as i64);
        for (dx, dy) in [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)] {
            let (jx, jy) = (x + dx, y + dy);
            if jx < 0 || jy < 0 || jx >= nx as i64 || jy >= ny as i64 {
                continue;
            }
            let j = jy as usize * nx + jx as usize;
            if out[j] || !free(j) {
                continue;
            }
            if dx != 0 && dy != 0 && !allow_corner_cutting && !(free(y as usize * nx + jx as usize) && free(jy as usize * nx + x as usize)) {
                continue;
            }
            out[j] = true;
            stack.push(j);
        }
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    const N: usize = 10;

    fn geometry(origin_cell: (i64, i64)) -> GridGeometry {
        GridGeometry { resolution_m: 0.1, nx: N, ny: N, origin_cell }
    }

    /// One memory step on a 10x10 grid at `origin_cell`: `cells` lists (ix, iy, risk,
    /// ground points), every other cell unobserved. Returns the grid after the step.
    fn step(memory: &mut HashMap<(i64, i64), f32>, origin_cell: (i64, i64), cells: &[(usize, usize, f32, f32)], position: DVec2) -> Vec<f32> {
        step_with(memory, origin_cell, cells, position, 0)
    }

    #[test]
    fn near_memory_keeps_what_was_seen_near_the_robot_in_the_world_frame() {
        let mut memory = HashMap::new();
        let near_with = |memory: &mut HashMap<(i64, i64), f32>, origin_cell: (i64, i64), cells: &[(usize, usize, f32)], position: DVec2, highest: bool| {
            let mut risk = vec![f32::NAN; N * N];
            for &(ix, iy, r) in cells {
                risk[iy * N + ix] = r;
            }
            remember_near(memory, &risk, &geometry(origin_cell), position, 0.3, highest);
            recall_near(memory, &mut risk, &geometry(origin_cell), position, 0.3, 0.05);
            risk
        };
        let near = |memory: &mut HashMap<(i64, i64), f32>, origin_cell: (i64, i64), cells: &[(usize, usize, f32)], position: DVec2| {
            near_with(memory, origin_cell, cells, position, true)
        };
        // Grid at origin cell (0, 0): cell (5, 5) is at (0.55, 0.55) m. The robot at its centre.
        let robot = DVec2::new(0.55, 0.55);
        let risk = near(&mut memory, (0, 0), &[(5, 5, 0.6), (6, 5, 0.2), (9, 9, 0.7)], robot);
        assert_eq!((risk[5 * N + 5], risk[5 * N + 6]), (0.6, 0.2));
        // (9, 9) is 0.57 m away, beyond 0.3 m: not remembered.
        assert_eq!(memory.len(), 2);
        // Next map, shifted by one cell (origin (1, 0)): nothing observed; the same world
        // cells get their ratings back at their new indices, the rest stay unobserved.
        let risk = near(&mut memory, (1, 0), &[], robot);
        assert_eq!((risk[5 * N + 4], risk[5 * N + 5]), (0.6, 0.2));
        assert_eq!(risk.iter().filter(|r| !r.is_nan()).count(), 2);
        // A new observation rates the cell on the grid; the memory keeps the highest rating.
        let risk = near(&mut memory, (1, 0), &[(4, 5, 0.01), (5, 5, 0.9)], robot);
        assert_eq!((risk[5 * N + 4], risk[5 * N + 5]), (0.01, 0.9));
        assert_eq!((memory[&(5, 5)], memory[&(6, 5)]), (0.6, 0.9));
        // Without `highest`, the newest rating.
        let mut newest = HashMap::new();
        near_with(&mut newest, (0, 0), &[(5, 5, 0.6)], robot, false);
        near_with(&mut newest, (0, 0), &[(5, 5, 0.3)], robot, false);
        assert_eq!(newest[&(5, 5)], 0.3);
        // A rating at or below the price of the unseen (0.05 here) is not recalled.
        let mut low = HashMap::new();
        near(&mut low, (0, 0), &[(5, 5, 0.01)], robot);
        assert!(near(&mut low, (0, 0), &[], robot)[5 * N + 5].is_nan());
        // The robot moves 1 m away: everything is forgotten.
        near(&mut memory, (1, 0), &[], robot + DVec2::new(0.0, 1.0));
        assert!(memory.is_empty());
    }

    fn step_with(memory: &mut HashMap<(i64, i64), f32>, origin_cell: (i64, i64), cells: &[(usize, usize, f32, f32)], position: DVec2, min_neighbours: u32) -> Vec<f32> {
        let mut risk = vec![f32::NAN; N * N];
        let mut ground = vec![0.0; N * N];
        for &(ix, iy, r, n) in cells {
            risk[iy * N + ix] = r;
            ground[iy * N + ix] = n;
        }
        let settings = NavigatorSettings { lethal_min_neighbours: min_neighbours, ..NavigatorSettings::default() };
        remember_hazards(memory, &mut risk, &ground, &geometry(origin_cell), position, &settings);
        risk
    }

    #[test]
    fn a_hazard_stays_on_the_grid_until_ground_is_seen_there() {
        let mut memory = HashMap::new();
        let p = DVec2::new(0.5, 0.5);
        // Seen lethal (a hole's void), with a safe neighbour.
        let r = step(&mut memory, (0, 0), &[(4, 4, 1.0, 0.0), (5, 4, 0.1, 20.0)], p);
        assert_eq!((r[44], r[45]), (1.0, 0.1));
        // Out of view (the blind ring): still lethal; the unobserved rest stays NaN.
        let r = step(&mut memory, (0, 0), &[], p);
        assert_eq!(r[44], 1.0);
        assert!(r.iter().enumerate().all(|(c, v)| c == 44 || v.is_nan()));
        // Rated safe on too few ground points: the memory wins.
        let r = step(&mut memory, (0, 0), &[(4, 4, 0.2, 4.0)], p);
        assert_eq!(r[44], 1.0);
        // Rated safe on enough ground points: forgotten, now and later.
        let r = step(&mut memory, (0, 0), &[(4, 4, 0.2, 5.0)], p);
        assert_eq!(r[44], 0.2);
        assert!(step(&mut memory, (0, 0), &[], p)[44].is_nan());
        assert!(memory.is_empty());
    }

    #[test]
    fn only_clustered_lethal_cells_and_near_ones_are_remembered() {
        let mut memory = HashMap::new();
        // A lone lethal cell (noise) and an L of three (each with two lethal neighbours).
        step_with(&mut memory, (0, 0), &[(1, 1, 1.0, 0.0), (5, 5, 1.0, 0.0), (6, 5, 1.0, 0.0), (5, 6, 1.0, 0.0)], DVec2::ZERO, 2);
        let mut kept: Vec<_> = memory.keys().copied().collect();
        kept.sort_unstable();
        assert_eq!(kept, vec![(5, 5), (5, 6), (6, 5)]);
        // Beyond hazard_memory_record_m (6 m = 60 cells), nothing new is remembered.
        memory.clear();
        step_with(&mut memory, (0, 0), &[(5, 5, 1.0, 0.0)], DVec2::new(-6.0, 0.0), 0);
        assert!(memory.is_empty());
    }

    #[test]
    fn a_hazard_is_kept_in_the_world_frame_as_the_map_moves() {
        let mut memory = HashMap::new();
        // World cell (7, 2): on the first map at (7, 2), on a map whose origin moved by
        // (3, -1) cells at (4, 3); a cell below the memory's risk is not remembered.
        step(&mut memory, (0, 0), &[(7, 2, 0.95, 30.0), (1, 1, 0.89, 0.0)], DVec2::ZERO);
        let r = step(&mut memory, (3, -1), &[], DVec2::ZERO);
        assert_eq!(r[3 * N + 4], 0.95);
        assert_eq!(r.iter().filter(|v| !v.is_nan()).count(), 1);
        // Off this map it is kept; beyond the range it is forgotten.
        step(&mut memory, (100, 100), &[], DVec2::ZERO);
        assert_eq!(memory.len(), 1);
        step(&mut memory, (200, 0), &[], DVec2::new(20.0, 0.0));
        assert!(memory.is_empty());
    }

    #[test]
    fn a_stand_in_is_where_the_robot_fits_not_a_lone_cell_in_a_lethal_patch() {
        // 20 x 20 cells of 0.1 m: a lethal 9 x 9 patch at cells 6..=14 with one safe cell
        // (10, 10) in it.
        let mut risk = vec![0.0f32; 400];
        for iy in 6..=14 {
            for ix in 6..=14 {
                risk[iy * 20 + ix] = 1.0;
            }
        }
        risk[10 * 20 + 10] = 0.0;
        let grid = RiskGrid::new(&risk, 20, 20, 0.1, DVec2::ZERO).unwrap();
        let p = DVec2::new(1.05, 1.05);
        let search = |fit_radius_m: f64| Search { r_inst: 0.6, unknown: 0.03, fit_radius_m, reachable: &[] };
        // Without room to fit, the lone cell itself.
        assert_eq!(nearest_traversable(&grid, p, 1.0, &search(0.0)), Some(p));
        // A robot 0.2 m wide: the nearest cell at least 0.1 m clear of the patch, 5 cells
        // away along an axis (cell 4 or 16).
        let q = nearest_traversable(&grid, p, 1.0, &search(0.1)).unwrap();
        assert!((q.distance(p) - 0.6).abs() < 1e-9, "{q}");
        // None within reach.
        assert_eq!(nearest_traversable(&grid, p, 0.4, &search(0.1)), None);
    }

    #[test]
    fn a_stand_in_is_one_the_planner_reaches_not_a_walled_in_pocket() {
        // Regression (mine seed 4): the stand-in on the map's edge was a pocket of free cells
        // walled in by lethal ones, and the A* reported "no path" although the robot could
        // drive to the edge elsewhere. 40 x 20 cells of 0.1 m; the robot at (0.5, 1.0); a
        // lethal ring around the pocket centred on (3.5, 1.0) (cells 30..=40 x 5..=15, its
        // inside 32..=38 x 7..=13 free).
        let (nx, ny) = (40usize, 20usize);
        let mut risk = vec![0.0f32; nx * ny];
        for iy in 5..=15 {
            for ix in 30..nx {
                let inner = (32..=38).contains(&ix) && (7..=13).contains(&iy);
                if !inner {
                    risk[iy * nx + ix] = 1.0;
                }
            }
        }
        let grid = RiskGrid::new(&risk, nx, ny, 0.1, DVec2::ZERO).unwrap();
        let (mut reachable, mut stack) = (Vec::new(), Vec::new());
        reachable_from(&grid, DVec2::new(0.5, 1.0), 0.6, 0.03, false, &mut reachable, &mut stack);
        assert!(!reachable[10 * nx + 35] && reachable[10 * nx + 10] && reachable[2 * nx + 35], "pocket walled in, the rest reached");
        let target = DVec2::new(3.55, 1.05);
        let blind = Search { r_inst: 0.6, unknown: 0.03, fit_radius_m: 0.15, reachable: &[] };
        assert!(nearest_traversable(&grid, target, 1.0, &blind).is_some_and(|q| q.distance(target) < 0.2), "without reachability: the pocket");
        let seeing = Search { reachable: &reachable, ..blind };
        // Within 0.5 m of the target, nothing reachable fits; over the whole grid, the
        // reachable cells nearest the target with room for the robot are 0.7 m from it,
        // beside the ring (left of it or below it).
        assert_eq!(nearest_traversable(&grid, target, 0.5, &seeing), None);
        let q = nearest_traversable_to(&grid, target, &seeing).unwrap();
        assert!((q.distance(target) - 0.7).abs() < 1e-9 && (q.x < 2.9 || q.y < 0.4), "{q}");
        // A diagonal gap between two blocked cells is no way in without corner cutting.
        let mut diag = vec![0.0f32; 9];
        diag[1] = 1.0;
        diag[3] = 1.0;
        let g3 = RiskGrid::new(&diag, 3, 3, 0.1, DVec2::ZERO).unwrap();
        reachable_from(&g3, DVec2::new(0.05, 0.05), 0.6, 0.03, false, &mut reachable, &mut stack);
        assert_eq!(reachable.iter().filter(|&&r| r).count(), 1);
        reachable_from(&g3, DVec2::new(0.05, 0.05), 0.6, 0.03, true, &mut reachable, &mut stack);
        assert_eq!(reachable.iter().filter(|&&r| r).count(), 7);
    }

    /// `inflate_lethal` without its shortcut: every lethal cell stamps its disc.
    fn inflate_naive(risk: &[f32], g: &GridGeometry, lethal: f32, min: u32, radius_m: f64, robot: DVec2) -> Vec<f32> {
        let mut out = risk.to_vec();
        let centre = |i: usize| g.origin_m() + (DVec2::new((i % g.nx) as f64, (i / g.nx) as f64) + 0.5) * g.resolution_m;
        for (i, &r) in risk.iter().enumerate() {
            for j in 0..risk.len() {
                let near = |a: DVec2, b: DVec2| a.distance_squared(b) <= radius_m * radius_m * (1.0 + 1e-12);
                if r >= lethal && clustered(risk, g.nx, g.ny, i, lethal, min) && near(centre(i), centre(j)) && !near(centre(j), robot) && !(out[j] >= r) {
                    out[j] = r;
                }
            }
        }
        out
    }

    #[test]
    fn a_lethal_cell_is_inflated_by_the_inscribed_radius_except_around_the_robot() {
        let g = GridGeometry { resolution_m: 0.1, nx: 21, ny: 21, origin_cell: (0, 0) };
        let mut risk = vec![0.1f32; 21 * 21];
        risk[10 * 21 + 10] = 1.0;
        risk[10 * 21 + 12] = f32::NAN;
        let mut out = Vec::new();
        // 0.25 m = 2.5 cells: 21 cells within, the unobserved one among them raised too.
        inflate_lethal(&risk, &mut out, &g, 0.9, 0, 0.25, DVec2::ZERO);
        assert_eq!(out.iter().filter(|&&v| v >= 0.9).count(), 21);
        assert_eq!(out[10 * 21 + 12], 1.0);
        assert_eq!((out[12 * 21 + 12], out[10 * 21 + 13]), (0.1, 0.1));
        // The robot at cell (12, 10): cells within 0.25 m of it keep their risk.
        inflate_lethal(&risk, &mut out, &g, 0.9, 0, 0.25, DVec2::new(1.25, 1.05));
        assert!(out[10 * 21 + 12].is_nan());
        assert_eq!((out[10 * 21 + 10], out[10 * 21 + 9]), (1.0, 1.0));
    }

    #[test]
    fn lethal_inflation_equals_stamping_every_lethal_cell() {
        // Seeded random grids: blobs of lethal cells (values 0.9-1), NaN and safe cells.
        let g = GridGeometry { resolution_m: 0.1, nx: 23, ny: 17, origin_cell: (-5, 3) };
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut out = Vec::new();
        for case in 0..20 {
            let risk: Vec<f32> = (0..g.cells())
                .map(|_| match next() {
                    u if u < 0.15 => 0.9 + 0.1 * next() as f32,
                    u if u < 0.25 => f32::NAN,
                    _ => 0.8 * next() as f32,
                })
                .collect();
            let robot = g.origin_m() + DVec2::new(next() * 2.3, next() * 1.7);
            let radius = 0.05 + 0.3 * next();
            let min = (case % 3) as u32;
            inflate_lethal(&risk, &mut out, &g, 0.9, min, radius, robot);
            let want = inflate_naive(&risk, &g, 0.9, min, radius, robot);
            for (c, (a, b)) in out.iter().zip(&want).enumerate() {
                // Lethal values may come from a different lethal neighbour; both block.
                let same = a.to_bits() == b.to_bits() || (*a >= 0.9 && *b >= 0.9);
                assert!(same, "case {case} cell {c}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn clear_map_keeps_the_hazards_the_lidar_cannot_see_again() {
        let mut memory: HashMap<(i64, i64), f32> = [((10, 0), 1.0), ((40, 0), 1.0)].into_iter().collect();
        forget_beyond(&mut memory, DVec2::ZERO, 0.1, 3.0);
        assert_eq!(memory.keys().copied().collect::<Vec<_>>(), vec![(10, 0)]);
    }

    #[test]
    fn hazard_memory_settings_are_checked() {
        let bad = |f: fn(&mut NavigatorSettings)| {
            let mut s = NavigatorSettings::default();
            f(&mut s);
            s.validate().unwrap_err().to_string()
        };
        assert!(bad(|s| s.lethal_risk = 0.0).contains("lethal_risk"));
        assert!(bad(|s| s.lethal_risk = 1.5).contains("lethal_risk"));
        assert!(bad(|s| s.lethal_min_neighbours = 3).contains("lethal_min_neighbours"));
        assert!(bad(|s| s.hazard_memory_forget_points = 0).contains("hazard_memory_forget_points"));
        assert!(bad(|s| s.hazard_memory_range_m = f64::NAN).contains("hazard_memory_range_m"));
        assert!(bad(|s| s.unseen_growth_m = -0.1).contains("unseen_growth_m"));
    }

    #[test]
    fn lethal_patches_grow_into_unobserved_cells_only() {
        // 12 x 12 cells of 0.1 m: a lethal 3 x 3 patch at cells 2..=4, unobserved cells to
        // its right (columns 5..=11 of rows 2..=4), observed ground elsewhere.
        let g = GridGeometry { resolution_m: 0.1, nx: 12, ny: 12, origin_cell: (0, 0) };
        let mut risk = vec![0.1f32; 144];
        for iy in 2..=4 {
            for ix in 2..=4 {
                risk[iy * 12 + ix] = 1.0;
            }
            for ix in 5..12 {
                risk[iy * 12 + ix] = f32::NAN;
            }
        }
        risk[8 * 12 + 8] = 0.95; // a lone lethal speckle: no patch, no growth
        risk[8 * 12 + 9] = f32::NAN;
        let mut scratch = Vec::new();
        // The robot far off the grid: nothing is too near it to grow into.
        let growth = Growth { lethal: 0.9, min_neighbours: 2, radius_m: 0.3, robot: DVec2::new(-50.0, -50.0), min_range_m: 2.5 };
        grow_into_unseen(&mut risk, &mut scratch, &g, &growth);
        for iy in 2..=4 {
            // 0.3 m = 3 cells: columns 5..=7 taken, not 8 and beyond (no chain reaction).
            assert_eq!(&risk[iy * 12 + 5..iy * 12 + 8], &[1.0, 1.0, 1.0], "row {iy}");
            assert!(risk[iy * 12 + 8..iy * 12 + 12].iter().all(|v| v.is_nan()), "row {iy}");
        }
        // Observed cells keep their rating; the speckle spreads nothing.
        assert_eq!((risk[12 + 3], risk[5 * 12 + 3]), (0.1, 0.1));
        assert!(risk[8 * 12 + 9].is_nan());
    }

    #[test]
    fn no_growth_next_to_the_robot() {
        // A lethal band at x = 0.1-0.3 m, unobserved cells right of it; the robot at
        // (0.78, 0.64) m. Within 0.5 m of it nothing grows, beyond it the growth stays.
        let g = GridGeometry { resolution_m: 0.1, nx: 12, ny: 12, origin_cell: (0, 0) };
        let mut risk = vec![f32::NAN; 144];
        for iy in 0..12 {
            risk[iy * 12 + 1] = 1.0;
            risk[iy * 12 + 2] = 1.0;
        }
        let growth = Growth { lethal: 0.9, min_neighbours: 2, radius_m: 0.3, robot: DVec2::new(0.78, 0.64), min_range_m: 0.5 };
        grow_into_unseen(&mut risk, &mut Vec::new(), &g, &growth);
        for iy in 0..12usize {
            for ix in 3..=5usize {
                let centre = DVec2::new(ix as f64 + 0.5, iy as f64 + 0.5) * 0.1;
                let grown = risk[iy * 12 + ix] == 1.0;
                assert_eq!(grown, centre.distance(growth.robot) >= 0.5, "cell ({ix}, {iy})");
            }
        }
    }
}
