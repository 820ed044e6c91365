//! The navigator's configuration: the planner, tracker and recovery sections and the
//! settings of the wiring itself. The defaults are committed as `configs/navigator.toml` (a
//! test keeps the two equal).

use std::cmp::Ordering;

use serde::{Deserialize, Serialize};

use crate::error::{require_non_negative, require_positive, Error, Result};
use crate::plan::astar::RiskAStarConfig;
use crate::plan::coverage::SensorCoverage;
use crate::plan::mpc::MpcConfig;
use crate::plan::recovery::RecoveryConfig;
use crate::terrain::RobotConfig;

/// Risk per metre the navigator's planner gives an unobserved cell. Smaller than the map's
/// display value `risk.unknown` (0.15): with the per-metre budget, 0.15 would spend
/// `R_total` = 0.5 on 4.3 m of unseen ground, and the goal is usually beyond what the
/// sensor has seen. subterra.
pub const UNSEEN_RISK_PER_M: f64 = 0.03;

/// Settings of the wiring itself.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NavigatorSettings {
    /// Least time between two plans while tracking \[s\].
    pub replan_period_s: f64,
    /// `None`: plan on the mean risk; `Some(α)`: on its `CVaR_α`, α in (0, 1).
    pub cvar_alpha: Option<f64>,
    /// Proportional gain of the heading loops of `rotate` and `back_out` [1/s].
    pub turn_gain_per_s: f64,
    /// Yaw-rate limit of those loops [rad/s].
    pub max_turn_rate_rad_s: f64,
    /// Reversing speed of `back_out` [m/s].
    pub backout_speed_m_s: f64,
    /// `back_out` checks the footprint swept over this much reversing ahead of each step \[m\].
    pub backout_clearance_m: f64,
    /// Added on every side of the footprint when a recovery checks the cells its motion
    /// sweeps \[m\] (a cell counts when any part of it is within it): a corner that swings 5 cm
    /// over a hole's rim drops a wheel. A corridor too narrow to turn in is then backed out of
    /// until there is room (`recovery.backout_max_distance_m`).
    pub sweep_margin_m: f64,
    /// The tracker's command is also checked against the footprint it sweeps: an unknown
    /// cell this near a lethal one blocks it like the lethal cell \[m\]. About one cell, its
    /// diagonal included: the unseen rim of a hole whose inside was seen.
    pub track_unknown_fringe_m: f64,
    /// Headings tried for the clearance heading.
    pub clearance_headings: u32,
    /// Longest clearance ray \[m\].
    pub clearance_range_m: f64,
    /// How far from a target off the map its stand-in on the map edge may move to reach a
    /// traversable cell \[m\].
    pub standin_search_m: f64,
    /// Remember hazards in the world frame beyond the mapper's fusion window (step 2).
    pub hazard_memory: bool,
    /// A lethal cell is remembered and inflated only with at least this many of its 8
    /// neighbours lethal too, in [0, 2]: real hazards are patches, while single cells rated
    /// lethal by sensor noise would each close a disc the robot's width across.
    pub lethal_min_neighbours: u32,
    /// Inflate lethal cells by half the robot's width plus `inflation_margin_m` for the
    /// planner (step 3): the A* plans the robot's centre.
    pub inflate_lethal: bool,
    /// Added to half the robot's width for the inflation and for where the robot fits \[m\].
    /// 0: the inscribed radius exactly; a margin narrows every passage by twice as much.
    pub inflation_margin_m: f64,
    /// Price of planning the robot's centre where it could not turn in place without its
    /// footprint touching a lethal cell (step 3), as a multiple of the least cost of a metre
    /// (λ, or 1 with the additive model) \[1\]; 0: off. A cell nearer a lethal patch than the
    /// footprint's circumscribed radius (plus `inflation_margin_m`) costs up to this much more
    /// per metre, falling linearly from the inscribed radius, where the cell becomes
    /// untraversable, to the circumscribed one. The price is about room, not risk: it never
    /// adds to a path's accumulated risk. Without it the cheapest path through a bend hugs
    /// the inner wall at exactly the inscribed radius, where a rectangle cannot swing its
    /// corners round; with it the path keeps the room to turn wherever the passage has it,
    /// and still squeezes through where it does not. Off by default: at 1 it helps in narrow
    /// winding passages, and in the mine it turned more drives into stops than it saved
    /// (docs/drive.md measures both).
    pub turn_room_price: f64,
    /// Unobserved cells within this distance of a lethal patch are taken as part of it on
    /// the A*'s grid (step 2) \[m\]; 0: off. A hazard's far side and corners lie in its own
    /// shadow (a pit's tip beyond its near rim gets no return): what the lidar could not see
    /// next to a drop is more likely the drop than ground.
    pub unseen_growth_m: f64,
    /// No growth into unobserved cells nearer than this to the robot \[m\] (about the
    /// footprint's half-length): the cells under and beside the robot are unobserved because
    /// the lidar cannot look down so steeply, not because a hazard shadows them; grown there,
    /// a corridor's walls would close it around the robot.
    pub unseen_growth_min_range_m: f64,
    /// `clear_map` keeps the remembered cells this near the robot \[m\]: the lidar cannot see
    /// them again from where it stands (its blind ring), the rest it sees again at once.
    pub hazard_memory_keep_m: f64,
    /// A remembered cell is forgotten once the map holds at least this many ground points in
    /// it and rates it below the lethal level: seen ground, not a grazing ray.
    pub hazard_memory_forget_points: u32,
    /// Only cells this near the robot are remembered \[m\]: the memory must bridge the blind
    /// ring, and far cells, on few points and grazing rays, are rated least reliably.
    pub hazard_memory_record_m: f64,
    /// Remembered cells farther than this from the robot are forgotten \[m\].
    pub hazard_memory_range_m: f64,
    /// **Near memory** (step 2): an unobserved cell within this distance of the robot takes
    /// the rating it had when last observed within it (with `near_memory_highest` its highest
    /// there), if that is above the planner's `unknown_risk` \[m\]; 0: off. The lidar's blind
    /// ring (~2.3 m for one 0.7 m up) hides the ground the robot is about to drive on:
    /// without it a slope seen from afar turns into cheap unseen ground once the robot
    /// stands at its foot. The recoveries' sweep check also counts a cell it holds as known.
    pub near_memory_m: f64,
    /// The near memory keeps each cell's highest rating while near instead of its newest.
    /// Seen from close by, a slope's plane fit rests on fewer cells and rates lower; the
    /// highest keeps the rating from afar. Off by default: the newest rating follows a map
    /// that corrects an early false alarm.
    pub near_memory_highest: bool,
    /// The cells the robot's footprint stood on are remembered this far \[m\] (the **driven
    /// memory**): ground that carried the robot is known, for the recoveries' sweep check,
    /// however little of it the sensor sees from there.
    pub driven_memory_m: f64,
    /// **Unseen-near rule** (step 2): with an all-round sensor (`coverage.fov_deg` 360) whose
    /// blind ring (`coverage.min_range_m`) lies inside `near_memory_m`, every patch of ground
    /// that comes within the blind ring passed through the ring between the two, where the
    /// sensor sees it and the near memory records it. A cell within the blind ring that the
    /// near memory never held below the lethal level as shown ground (a point of its own, or a
    /// rating from outside the blind ring: inside it a ground line is drawn on into ground the
    /// sensor cannot see), that the robot never stood on, not
    /// within the blind ring of where the robot started, with its 8 neighbours the same, is
    /// therefore not ground the sensor missed by chance: it returned nothing (a hole's mouth,
    /// a drop), and it is lethal on the navigator's grid. The tracker then stops short of it
    /// and the A* plans around it.
    pub unseen_near_lethal: bool,
    /// **Void rim** (step 2): cells within this distance of a void (a cell the map rated as
    /// missing ground, held by the map or the hazard memory) are lethal on the navigator's
    /// grid, unless the robot stood on them \[m\]; 0: off. The map places a void's edge where
    /// a ray's ground returns stop, to within the ground segmentation's radial bin
    /// (`ground.bin_m`, 0.2 m): the cells holding the last returns are rated ground although
    /// part of them overhangs the drop. Without the rim the A*'s inflation and the tracker's
    /// footprint check keep the robot clear of the rated void, not of the real edge.
    pub void_rim_m: f64,
    /// **Stale sensor** (step 1): once a map exists, with no scan for longer than this the
    /// robot stops, whatever the plan, until scans come again \[s\] (`safety` says why). A
    /// tracker with no new scans drives on a map that no longer shows what is ahead: a lidar
    /// that stopped publishing, or a driver that hangs. Odometry confidence 0 (no usable
    /// odometry source: `subterra.OdometryMux`) stops the robot the same way.
    pub scan_timeout_s: f64,
    /// **Footprint-checked plans** (step 3): the A*'s path is checked with the tracker's own
    /// footprint test (the rectangle along the path's tangent against lethal cells and the
    /// unknown beside them); where it fails, the cells within the difference between the
    /// circumscribed and the inscribed radius of that point are closed and the A* plans
    /// again, at most this many times; 0: off. The A* plans the centre of a disc the robot's
    /// width across; the rectangle cannot take every turn that disc can, and a path it cannot
    /// follow only stops the tracker beside an obstacle. If no checked path is found the last
    /// path found is used.
    pub footprint_replans: u32,
    /// **Plan hysteresis** (step 3), a fraction in [0, 1]: a new plan replaces the path being
    /// followed only when that path's rest, priced on the current grid as the A* prices a
    /// path, has become untraversable, over the risk budget or footprint-blocked, or costs
    /// more than `1 + plan_hysteresis` times the new one; 0: every plan replaces the path.
    /// Each scan re-rates the ground ahead, and two routes of nearly equal cost would
    /// otherwise take turns, the robot turning back and forth between them. Only a clearly
    /// better route is worth turning for.
    pub plan_hysteresis: f64,
    /// **Targets beyond the map** (step 3): plan toward them with the A*'s exit search, which
    /// may leave the map by any border cell, the straight line on priced at λ a metre
    /// ([`crate::plan::astar::RiskAStar::plan_toward`]); `false`: plan to one stand-in, the
    /// traversable cell nearest where the segment to the target leaves the map. A detour
    /// round a wall that runs past the map's edge (a ridge's walled flank) leaves by another
    /// border than the segment does.
    pub leave_by_any_border: bool,
    /// **Perception-aware planning** (step 3): price the unknown cells the A* enters by
    /// whether the sensor will have seen them from the path before the robot gets there.
    pub perception_aware: bool,
    /// Where the robot's sensor sees the ground from a pose (its field of view, blind zone and
    /// range), for perception-aware planning.
    pub coverage: SensorCoverage,
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
            sweep_margin_m: 0.05,
            track_unknown_fringe_m: 0.15,
            clearance_headings: 16,
            clearance_range_m: 5.0,
            standin_search_m: 3.0,
            hazard_memory: true,
            lethal_min_neighbours: 2,
            inflate_lethal: true,
            inflation_margin_m: 0.0,
            turn_room_price: 0.0,
            unseen_growth_m: 0.3,
            unseen_growth_min_range_m: 0.5,
            hazard_memory_keep_m: 3.0,
            hazard_memory_forget_points: 5,
            hazard_memory_record_m: 6.0,
            hazard_memory_range_m: 15.0,
            near_memory_m: 3.0,
            near_memory_highest: false,
            driven_memory_m: 15.0,
            unseen_near_lethal: true,
            void_rim_m: 0.2,
            scan_timeout_s: 0.5,
            footprint_replans: 4,
            plan_hysteresis: 0.2,
            leave_by_any_border: true,
            perception_aware: true,
            coverage: SensorCoverage::default(),
        }
    }
}

/// Largest search or memory range accepted \[m\]: the navigator works on a local map (20 m by
/// default); searches and memories kilometres wide are a mistake and would take seconds a step.
pub(crate) const MAX_RANGE_SETTING_M: f64 = 100.0;
/// Largest inflation, growth or sweep margin accepted \[m\]: each lethal cell stamps a disc of
/// this radius; metres of margin close every passage of a mine anyway.
pub(crate) const MAX_MORPHOLOGY_M: f64 = 2.0;

/// Largest `turn_room_price` accepted \[1\]: at 100 a metre hugging a wall costs as much as
/// 100 m in the open; anything above that is a wall of its own.
pub(super) const MAX_TURN_ROOM_PRICE: f64 = 100.0;

/// Most footprint replans accepted (`footprint_replans`): each is a whole A* search.
pub(super) const MAX_FOOTPRINT_REPLANS: u32 = 16;

impl NavigatorSettings {
    /// Checks every field, naming it (`navigator.<field>`).
    pub fn validate(&self) -> Result<()> {
        require_positive("navigator.replan_period_s", self.replan_period_s)?;
        require_positive("navigator.turn_gain_per_s", self.turn_gain_per_s)?;
        require_positive("navigator.max_turn_rate_rad_s", self.max_turn_rate_rad_s)?;
        require_positive("navigator.backout_speed_m_s", self.backout_speed_m_s)?;
        require_positive("navigator.backout_clearance_m", self.backout_clearance_m)?;
        require_non_negative("navigator.sweep_margin_m", self.sweep_margin_m)?;
        require_non_negative("navigator.track_unknown_fringe_m", self.track_unknown_fringe_m)?;
        require_positive("navigator.clearance_range_m", self.clearance_range_m)?;
        require_positive("navigator.standin_search_m", self.standin_search_m)?;
        require_positive("navigator.hazard_memory_record_m", self.hazard_memory_record_m)?;
        require_positive("navigator.hazard_memory_range_m", self.hazard_memory_range_m)?;
        require_non_negative("navigator.hazard_memory_keep_m", self.hazard_memory_keep_m)?;
        require_non_negative("navigator.inflation_margin_m", self.inflation_margin_m)?;
        if !(self.turn_room_price.is_finite() && (0.0..=MAX_TURN_ROOM_PRICE).contains(&self.turn_room_price)) {
            return Err(Error::config("navigator.turn_room_price", format!("must be in [0, {MAX_TURN_ROOM_PRICE}]"), self.turn_room_price));
        }
        require_non_negative("navigator.unseen_growth_m", self.unseen_growth_m)?;
        require_non_negative("navigator.unseen_growth_min_range_m", self.unseen_growth_min_range_m)?;
        require_non_negative("navigator.near_memory_m", self.near_memory_m)?;
        require_non_negative("navigator.driven_memory_m", self.driven_memory_m)?;
        require_non_negative("navigator.void_rim_m", self.void_rim_m)?;
        if !(self.scan_timeout_s.is_finite() && self.scan_timeout_s > 0.0 && self.scan_timeout_s <= 3600.0) {
            return Err(Error::config("navigator.scan_timeout_s", "must be in (0, 3600] s", self.scan_timeout_s));
        }
        // Bounds on the work and memory a setting implies: a disc per lethal cell for the
        // morphology radii, a search or a memory over the area of the others.
        let limited = [
            ("backout_clearance_m", self.backout_clearance_m, MAX_MORPHOLOGY_M),
            ("sweep_margin_m", self.sweep_margin_m, MAX_MORPHOLOGY_M),
            ("track_unknown_fringe_m", self.track_unknown_fringe_m, MAX_MORPHOLOGY_M),
            ("inflation_margin_m", self.inflation_margin_m, MAX_MORPHOLOGY_M),
            ("unseen_growth_m", self.unseen_growth_m, MAX_MORPHOLOGY_M),
            ("void_rim_m", self.void_rim_m, MAX_MORPHOLOGY_M),
            ("clearance_range_m", self.clearance_range_m, MAX_RANGE_SETTING_M),
            ("standin_search_m", self.standin_search_m, MAX_RANGE_SETTING_M),
            ("unseen_growth_min_range_m", self.unseen_growth_min_range_m, MAX_RANGE_SETTING_M),
            ("hazard_memory_keep_m", self.hazard_memory_keep_m, MAX_RANGE_SETTING_M),
            ("hazard_memory_record_m", self.hazard_memory_record_m, MAX_RANGE_SETTING_M),
            ("hazard_memory_range_m", self.hazard_memory_range_m, MAX_RANGE_SETTING_M),
            ("near_memory_m", self.near_memory_m, MAX_RANGE_SETTING_M),
            ("driven_memory_m", self.driven_memory_m, MAX_RANGE_SETTING_M),
        ];
        if !(0.0..=1.0).contains(&self.plan_hysteresis) {
            return Err(Error::config("navigator.plan_hysteresis", "must be in [0, 1]", self.plan_hysteresis));
        }
        if self.footprint_replans > MAX_FOOTPRINT_REPLANS {
            return Err(Error::config("navigator.footprint_replans", format!("must be at most {MAX_FOOTPRINT_REPLANS} (each is one more A* search a plan)"), self.footprint_replans));
        }
        for (name, value, limit) in limited {
            if value > limit {
                return Err(Error::config(format!("navigator.{name}"), format!("must be at most {limit} m"), value));
            }
        }
        if self.unseen_near_lethal {
            if self.coverage.fov_deg < 360.0 {
                return Err(Error::config("navigator.unseen_near_lethal", "needs an all-round sensor (navigator.coverage.fov_deg = 360): set it false for a forward sensor", self.coverage.fov_deg));
            }
            if self.near_memory_m.partial_cmp(&self.coverage.min_range_m).is_none_or(Ordering::is_le) {
                return Err(Error::config(
                    "navigator.unseen_near_lethal",
                    format!("needs navigator.near_memory_m above the blind ring navigator.coverage.min_range_m = {} m: set it false or widen the near memory", self.coverage.min_range_m),
                    self.near_memory_m,
                ));
            }
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
        self.coverage.validate("navigator.coverage")
    }
}

/// Everything a [`Navigator`](super::Navigator) is configured by.
///
/// [`Default`] is [`NavigatorConfig::for_robot`] of the default (Husky-like) robot; a TOML
/// document's missing fields keep those values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NavigatorConfig {
    /// The planner (its `r_inst`/`r_total` are replaced by the recovery machine's, its
    /// `lethal_risk` by the terrain map's).
    pub planner: RiskAStarConfig,
    /// The MPC tracker (its `risk.lethal_risk` is replaced by the terrain map's).
    pub tracker: MpcConfig,
    /// The recovery ladder and the nominal thresholds.
    pub recovery: RecoveryConfig,
    /// The wiring.
    pub navigator: NavigatorSettings,
}

impl Default for NavigatorConfig {
    fn default() -> Self {
        Self::for_robot(&RobotConfig::default())
    }
}

impl NavigatorConfig {
    /// The defaults for `robot`: the MPC's footprint and limits follow the robot; the
    /// planner prices unobserved cells at [`UNSEEN_RISK_PER_M`].
    pub fn for_robot(robot: &RobotConfig) -> Self {
        Self {
            planner: RiskAStarConfig { unknown_risk: UNSEEN_RISK_PER_M, ..RiskAStarConfig::default() },
            tracker: MpcConfig::for_robot(robot),
            recovery: RecoveryConfig::default(),
            navigator: NavigatorSettings::default(),
        }
    }

    /// Checks every section.
    pub fn validate(&self) -> Result<()> {
        // Each section's errors name the field as the navigator's file spells it
        // (`planner.lam`, not the A* file's `astar.lam`).
        self.planner.validate().map_err(|e| e.in_section("astar.", "planner"))?;
        self.tracker.validate().map_err(|e| e.in_section("", "tracker"))?;
        self.recovery.validate()?;
        self.navigator.validate()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_is_the_default_robots() {
        assert_eq!(NavigatorConfig::default(), NavigatorConfig::for_robot(&RobotConfig::default()));
    }

    #[test]
    fn section_errors_name_the_navigators_field() {
        let mut c = NavigatorConfig::default();
        c.planner.lam = 2f64.powi(64);
        assert!(c.validate().unwrap_err().to_string().contains("`planner.lam`"));
        let mut c = NavigatorConfig::default();
        c.tracker.dt_s = 2f64.powi(64);
        assert!(c.validate().unwrap_err().to_string().contains("`tracker.dt_s`"));
    }

    #[test]
    fn settings_are_checked_naming_the_field() {
        let bad = |f: fn(&mut NavigatorSettings)| {
            let mut s = NavigatorSettings::default();
            f(&mut s);
            s.validate().unwrap_err().to_string()
        };
        assert!(bad(|s| s.lethal_min_neighbours = 3).contains("lethal_min_neighbours"));
        assert!(bad(|s| s.hazard_memory_forget_points = 0).contains("hazard_memory_forget_points"));
        assert!(bad(|s| s.hazard_memory_range_m = f64::NAN).contains("hazard_memory_range_m"));
        assert!(bad(|s| s.unseen_growth_m = -0.1).contains("unseen_growth_m"));
        // Work and memory they imply are bounded: a 1 km growth or search is refused.
        assert!(bad(|s| s.unseen_growth_m = 1000.0).contains("at most"));
        assert!(bad(|s| s.standin_search_m = 1e5).contains("navigator.standin_search_m"));
        assert!(bad(|s| s.inflation_margin_m = 1000.0).contains("navigator.inflation_margin_m"));
        assert!(bad(|s| s.sweep_margin_m = -1.0).contains("sweep_margin_m"));
    }
}
