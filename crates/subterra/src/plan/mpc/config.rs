//! Typed configuration of the MPC tracker (layout of `configs/mpc.toml`).
//!
//! Each field documents its unit and source. "Husky" means the default robot (Clearpath Husky A200)
//! ([`RobotConfig::husky`](crate::terrain::RobotConfig::husky)); "subterra" an engineering
//! choice of this library, not a published value.

use serde::{Deserialize, Serialize};

use crate::error::{require_non_negative, require_positive, Error, Result};
use crate::terrain::RobotConfig;

/// Longest step accepted \[s\].
const MAX_DT_S: f64 = 1.0;
/// Longest horizon accepted \[steps\]: the QP grows linearly, and 200 steps of 0.1 s is 20 s.
const MAX_HORIZON: usize = 200;
/// Largest speed accepted [m/s]: a ground robot in a mine does not go faster.
const MAX_SPEED_M_S: f64 = 30.0;
/// Largest acceleration accepted [m/s²].
const MAX_ACCEL_M_S2: f64 = 50.0;
/// Largest yaw rate accepted [rad/s].
const MAX_YAW_RATE_RAD_S: f64 = 50.0;
/// Largest footprint side, margin, block or activation distance accepted \[m\].
const MAX_LENGTH_M: f64 = 20.0;
/// Largest weight accepted (anything larger wrecks the QP's conditioning).
const MAX_WEIGHT: f64 = 1e7;
/// Most obstacle rows per stage accepted.
const MAX_OBSTACLES_PER_STAGE: usize = 64;

/// Actuator and speed limits.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MpcLimits {
    /// Top forward speed `v_max` [m/s]; also the scale of the risk limit `v_max·(1 - r)`.
    /// Husky: 1.0.
    pub max_speed_m_s: f64,
    /// Lowest speed `v_min` [m/s], <= 0; negative lets the plan back up. subterra: -0.2
    /// (a slow reverse, so the tracker can back off a margin it has entered).
    pub min_speed_m_s: f64,
    /// `|a| <= a_max` [m/s²]; also the braking of the backup stop. subterra: 1.0 (the Husky's
    /// controller allows 3; 1 keeps the ride smooth on rubble).
    pub max_accel_m_s2: f64,
    /// `|ω| <= ω_max` [rad/s]. subterra: 1.5 (the Husky's controller allows 2).
    pub max_yaw_rate_rad_s: f64,
}

/// What the tracker aims for.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MpcTracking {
    /// Speed along the path when `solve` is not given one [m/s], in `[0, v_max]`. subterra: 0.8.
    pub desired_speed_m_s: f64,
    /// The speed reference falls as `sqrt(2·d·(remaining path))` so that the robot stops at
    /// the path's end; this is `d` [m/s²]. subterra: 0.5 (half of `a_max`).
    pub end_decel_m_s2: f64,
    /// The path's direction at a reference point is that of the chord from this far behind
    /// it to this far ahead, so headings turn smoothly through the corners of a grid path
    /// \[m\]. subterra: 0.3 (three cells of the coarse map).
    pub tangent_half_window_m: f64,
}

/// Weights of the cost (see [`MpcTracker`](super::MpcTracker) and `docs/mpc.md`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MpcWeights {
    /// Cross-track (contour) error, across the path [1/m²]. subterra: 20.
    pub contour: f64,
    /// Along-track (lag) error [1/m²]. subterra: 1.
    pub lag: f64,
    /// Heading error [1/rad²]. subterra: 2.
    pub heading: f64,
    /// Speed error against the speed reference [s²/m²]. subterra: 2.
    pub speed: f64,
    /// Acceleration effort [s⁴/m²]. subterra: 0.1.
    pub accel: f64,
    /// Yaw-rate effort [s²/rad²]. subterra: 0.1.
    pub yaw_rate: f64,
    /// Change of acceleration between steps [s⁴/m²]. subterra: 0.5.
    pub accel_rate: f64,
    /// Change of yaw rate between steps [s²/rad²]. subterra: 0.5.
    pub yaw_rate_rate: f64,
    /// The last state's tracking terms are multiplied by this \[1\]. subterra: 5.
    pub terminal_factor: f64,
    /// Linear penalty of a slack (speed [m/s] or obstacle margin \[m\]) [1/unit]; above the
    /// constraints' multipliers, so a soft constraint holds whenever it can (an exact
    /// penalty; the tracking terms above give multipliers of a few tens). subterra: 300.
    pub slack_linear: f64,
    /// Quadratic penalty of a slack [1/unit²]. subterra: 1000.
    pub slack_quadratic: f64,
}

/// The robot's footprint: a `length x width` rectangle centred on the state's position.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MpcFootprint {
    /// Along body x \[m\]. Husky: 0.99.
    pub length_m: f64,
    /// Along body y \[m\]. Husky: 0.67.
    pub width_m: f64,
}

/// How the risk grid limits speed and makes obstacles.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MpcRisk {
    /// Risk taken outside the grid and where it is NaN, in [0, 1] \[1\]. subterra: 0.15 (the
    /// terrain map's `unknown` risk).
    pub unknown_risk: f64,
    /// Cells with `risk >= lethal_risk` are obstacles, in (0, 1] \[1\]. subterra: 0.9.
    pub lethal_risk: f64,
}

/// Obstacle half-planes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MpcObstacles {
    /// The footprint keeps this signed distance from every lethal polygon \[m\]. subterra: 0.1.
    pub margin_m: f64,
    /// A lethal region is cut into pieces until each piece's convex hull overhangs its cells
    /// by at most this much on average (free area over the longer side) \[m\]. subterra: 0.1
    /// (a cell of the coarse map).
    pub max_overhang_m: f64,
    /// A polygon constrains a predicted state when their distance at the linearisation point
    /// is below `margin_m + activation_m` \[m\]. subterra: 0.5.
    pub activation_m: f64,
    /// Reference points are moved sideways until the footprint at them clears every
    /// polygon beside the path by this much, so the robot steers around an obstacle that
    /// reaches into its path instead of stopping in front of it \[m\], >= `margin_m`.
    /// subterra: 0.15.
    pub path_clearance_m: f64,
    /// Largest such sideways move; a point that needs more stays where it is \[m\].
    /// subterra: 1.0.
    pub max_path_shift_m: f64,
    /// The move fades in over this much path before the obstacle and out after it, so the
    /// robot starts to steer early \[m\]. subterra: 1.0.
    pub path_shift_ramp_m: f64,
    /// Most polygons constraining one predicted state (the nearest); 0 disables obstacles.
    /// subterra: 6.
    pub max_per_stage: usize,
}

/// The sequential QP.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MpcSolver {
    /// Most QPs (re-linearisations) per solve. STEP: 1-3; subterra: 2 (each solve goes
    /// on from the previous plan, so the iterations continue across solves; docs/mpc.md has
    /// what a third QP changes on the benchmark run, and costs).
    pub sqp_iterations: u32,
    /// Most trial step lengths `1, ½, ¼, ...` of the backtracking line search. subterra: 4.
    pub line_search_steps: u32,
    /// The iterations stop once the accepted input step is below this in every component
    /// [m/s² or rad/s] (0.1 m/s² is 1 cm/s of commanded speed); the next solve goes on from
    /// there. subterra: 0.1.
    pub step_tolerance: f64,
    /// Interior-point iterations per QP. subterra: 50 (typical QPs take 10-20).
    pub qp_max_iterations: u32,
    /// Which interior-point solver solves the QPs. subterra: `banded`.
    #[serde(default)]
    pub qp_solver: QpSolverKind,
    /// A plan is unsafe (backup stop) when a predicted footprint comes closer to a lethal
    /// polygon than `min(margin, clearance now) - this` \[m\]. subterra: 0.02.
    pub clearance_tolerance_m: f64,
}

/// The QP solver of the tracker's SQP iterations.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum QpSolverKind {
    /// The tracker's own interior-point method, whose Newton systems use the QP's band
    /// structure (`MpcTracker`'s docs, step 4); a QP it does not solve to full accuracy is
    /// solved again by Clarabel.
    #[default]
    Banded,
    /// Clarabel (a general conic interior-point solver) for every QP.
    Clarabel,
}

/// Everything the MPC tracker needs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MpcConfig {
    /// Step of the discrete dynamics \[s\]. STEP: 0.1.
    pub dt_s: f64,
    /// Number of steps N of the horizon \[steps\]. STEP: 20.
    pub horizon: usize,
    /// Actuator and speed limits.
    pub limits: MpcLimits,
    /// Speed aims.
    pub tracking: MpcTracking,
    /// Cost weights.
    pub weights: MpcWeights,
    /// The robot's rectangle.
    pub footprint: MpcFootprint,
    /// Risk look-ups.
    pub risk: MpcRisk,
    /// Obstacle constraints.
    pub obstacles: MpcObstacles,
    /// The sequential QP.
    pub solver: MpcSolver,
}

impl Default for MpcConfig {
    fn default() -> Self {
        Self::for_robot(&RobotConfig::husky())
    }
}

impl MpcConfig {
    /// The defaults with the footprint and top speed of `robot`.
    pub fn for_robot(robot: &RobotConfig) -> Self {
        Self {
            dt_s: 0.1,
            horizon: 20,
            limits: MpcLimits { max_speed_m_s: robot.max_speed_m_s, min_speed_m_s: -0.2, max_accel_m_s2: 1.0, max_yaw_rate_rad_s: 1.5 },
            tracking: MpcTracking { desired_speed_m_s: 0.8 * robot.max_speed_m_s, end_decel_m_s2: 0.5, tangent_half_window_m: 0.3 },
            weights: MpcWeights {
                contour: 20.0,
                lag: 1.0,
                heading: 2.0,
                speed: 2.0,
                accel: 0.1,
                yaw_rate: 0.1,
                accel_rate: 0.5,
                yaw_rate_rate: 0.5,
                terminal_factor: 5.0,
                slack_linear: 300.0,
                slack_quadratic: 1000.0,
            },
            footprint: MpcFootprint { length_m: robot.length_m, width_m: robot.width_m },
            risk: MpcRisk { unknown_risk: 0.15, lethal_risk: 0.9 },
            obstacles: MpcObstacles { margin_m: 0.1, max_overhang_m: 0.1, activation_m: 0.5, path_clearance_m: 0.15, max_path_shift_m: 1.0, path_shift_ramp_m: 1.0, max_per_stage: 4 },
            solver: MpcSolver { sqp_iterations: 2, line_search_steps: 4, step_tolerance: 0.1, qp_max_iterations: 50, qp_solver: QpSolverKind::Banded, clearance_tolerance_m: 0.02 },
        }
    }


    /// Checks every field, naming it on error (`limits.max_speed_m_s`, `weights.contour`, ...).
    pub fn validate(&self) -> Result<()> {
        let in_range = |field: &str, value: f64, lo: f64, hi: f64, what: &str| {
            if value.is_finite() && value >= lo && value <= hi {
                Ok(())
            } else {
                Err(Error::config(field, what.to_owned(), value))
            }
        };
        require_positive("dt_s", self.dt_s)?;
        in_range("dt_s", self.dt_s, 0.0, MAX_DT_S, &format!("must be in (0, {MAX_DT_S}] s"))?;
        if self.horizon == 0 || self.horizon > MAX_HORIZON {
            return Err(Error::config("horizon", format!("must be in 1..={MAX_HORIZON} steps"), self.horizon));
        }
        let l = &self.limits;
        require_positive("limits.max_speed_m_s", l.max_speed_m_s)?;
        in_range("limits.max_speed_m_s", l.max_speed_m_s, 0.0, MAX_SPEED_M_S, &format!("must be in (0, {MAX_SPEED_M_S}] m/s"))?;
        in_range("limits.min_speed_m_s", l.min_speed_m_s, -l.max_speed_m_s, 0.0, &format!("must be in [-limits.max_speed_m_s, 0] = [{}, 0] m/s", -l.max_speed_m_s))?;
        require_positive("limits.max_accel_m_s2", l.max_accel_m_s2)?;
        in_range("limits.max_accel_m_s2", l.max_accel_m_s2, 0.0, MAX_ACCEL_M_S2, &format!("must be in (0, {MAX_ACCEL_M_S2}] m/s²"))?;
        require_positive("limits.max_yaw_rate_rad_s", l.max_yaw_rate_rad_s)?;
        in_range("limits.max_yaw_rate_rad_s", l.max_yaw_rate_rad_s, 0.0, MAX_YAW_RATE_RAD_S, &format!("must be in (0, {MAX_YAW_RATE_RAD_S}] rad/s"))?;
        let t = &self.tracking;
        in_range("tracking.desired_speed_m_s", t.desired_speed_m_s, 0.0, l.max_speed_m_s, &format!("must be in [0, limits.max_speed_m_s = {}] m/s", l.max_speed_m_s))?;
        require_positive("tracking.end_decel_m_s2", t.end_decel_m_s2)?;
        in_range("tracking.tangent_half_window_m", t.tangent_half_window_m, 0.0, MAX_LENGTH_M, &format!("must be in [0, {MAX_LENGTH_M}] m"))?;
        let w = &self.weights;
        for (name, value) in [
            ("weights.contour", w.contour),
            ("weights.lag", w.lag),
            ("weights.heading", w.heading),
            ("weights.speed", w.speed),
            ("weights.accel_rate", w.accel_rate),
            ("weights.yaw_rate_rate", w.yaw_rate_rate),
            ("weights.terminal_factor", w.terminal_factor),
            ("weights.slack_quadratic", w.slack_quadratic),
        ] {
            in_range(name, value, 0.0, MAX_WEIGHT, &format!("must be in [0, {MAX_WEIGHT:e}]"))?;
        }
        // Strictly positive input and slack weights keep every QP strictly convex in the
        // inputs (a unique, hence reproducible, solution) and the slack penalty exact.
        for (name, value) in [("weights.accel", w.accel), ("weights.yaw_rate", w.yaw_rate), ("weights.slack_linear", w.slack_linear)] {
            require_positive(name, value)?;
            in_range(name, value, 0.0, MAX_WEIGHT, &format!("must be in (0, {MAX_WEIGHT:e}]"))?;
        }
        for (name, value) in [("footprint.length_m", self.footprint.length_m), ("footprint.width_m", self.footprint.width_m)] {
            require_positive(name, value)?;
            in_range(name, value, 0.0, MAX_LENGTH_M, &format!("must be in (0, {MAX_LENGTH_M}] m"))?;
        }
        in_range("risk.unknown_risk", self.risk.unknown_risk, 0.0, 1.0, "must be in [0, 1]")?;
        require_positive("risk.lethal_risk", self.risk.lethal_risk)?;
        in_range("risk.lethal_risk", self.risk.lethal_risk, 0.0, 1.0, "must be in (0, 1]")?;
        let o = &self.obstacles;
        require_non_negative("obstacles.margin_m", o.margin_m)?;
        in_range("obstacles.margin_m", o.margin_m, 0.0, MAX_LENGTH_M, &format!("must be in [0, {MAX_LENGTH_M}] m"))?;
        require_non_negative("obstacles.max_overhang_m", o.max_overhang_m)?;
        in_range("obstacles.max_overhang_m", o.max_overhang_m, 0.0, MAX_LENGTH_M, &format!("must be in [0, {MAX_LENGTH_M}] m"))?;
        in_range("obstacles.activation_m", o.activation_m, 0.0, MAX_LENGTH_M, &format!("must be in [0, {MAX_LENGTH_M}] m"))?;
        in_range("obstacles.path_clearance_m", o.path_clearance_m, o.margin_m, MAX_LENGTH_M, &format!("must be in [obstacles.margin_m = {}, {MAX_LENGTH_M}] m", o.margin_m))?;
        in_range("obstacles.max_path_shift_m", o.max_path_shift_m, 0.0, MAX_LENGTH_M, &format!("must be in [0, {MAX_LENGTH_M}] m"))?;
        in_range("obstacles.path_shift_ramp_m", o.path_shift_ramp_m, 0.0, MAX_LENGTH_M, &format!("must be in [0, {MAX_LENGTH_M}] m"))?;
        if o.max_per_stage > MAX_OBSTACLES_PER_STAGE {
            return Err(Error::config("obstacles.max_per_stage", format!("must be in 0..={MAX_OBSTACLES_PER_STAGE}"), o.max_per_stage));
        }
        let s = &self.solver;
        if !(1..=10).contains(&s.sqp_iterations) {
            return Err(Error::config("solver.sqp_iterations", "must be in 1..=10", s.sqp_iterations));
        }
        if !(1..=30).contains(&s.line_search_steps) {
            return Err(Error::config("solver.line_search_steps", "must be in 1..=30", s.line_search_steps));
        }
        require_positive("solver.step_tolerance", s.step_tolerance)?;
        if !(1..=1000).contains(&s.qp_max_iterations) {
            return Err(Error::config("solver.qp_max_iterations", "must be in 1..=1000", s.qp_max_iterations));
        }
        require_non_negative("solver.clearance_tolerance_m", s.clearance_tolerance_m)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Config;

    #[test]
    fn defaults_hold_the_design_values() {
        let c = MpcConfig::default();
        c.validate().unwrap();
        assert_eq!((c.dt_s, c.horizon), (0.1, 20));
        assert_eq!((c.footprint.length_m, c.footprint.width_m, c.limits.max_speed_m_s), (0.99, 0.67, 1.0));
    }

    #[test]
    fn toml_round_trip_and_unknown_keys() {
        let c = MpcConfig::default();
        let text = c.to_toml_string();
        assert_eq!(MpcConfig::from_toml_str(&text).unwrap(), c);
        let bad = text.replace("horizon = 20", "horizon = 20\nhorizon_s = 2.0");
        assert!(MpcConfig::from_toml_str(&bad).unwrap_err().to_string().contains("horizon_s"));
    }

    #[test]
    fn bad_values_name_their_field() {
        let field_of = |c: MpcConfig| c.validate().unwrap_err().to_string();
        assert!(field_of(MpcConfig { dt_s: 0.0, ..MpcConfig::default() }).contains("`dt_s`"));
        assert!(field_of(MpcConfig { horizon: 0, ..MpcConfig::default() }).contains("`horizon`"));
        let mut c = MpcConfig::default();
        c.limits.min_speed_m_s = 0.5;
        assert!(field_of(c).contains("limits.min_speed_m_s"));
        let mut c = MpcConfig::default();
        c.limits.max_accel_m_s2 = f64::NAN;
        assert!(field_of(c).contains("limits.max_accel_m_s2"));
        let mut c = MpcConfig::default();
        c.tracking.desired_speed_m_s = 2.0;
        assert!(field_of(c).contains("tracking.desired_speed_m_s"));
        let mut c = MpcConfig::default();
        c.weights.contour = -1.0;
        assert!(field_of(c).contains("weights.contour"));
        let mut c = MpcConfig::default();
        c.weights.accel = 0.0;
        assert!(field_of(c).contains("weights.accel"));
        let mut c = MpcConfig::default();
        c.risk.lethal_risk = 0.0;
        assert!(field_of(c).contains("risk.lethal_risk"));
        let mut c = MpcConfig::default();
        c.obstacles.max_overhang_m = 1e9;
        assert!(field_of(c).contains("obstacles.max_overhang_m"));
        let mut c = MpcConfig::default();
        c.solver.sqp_iterations = 0;
        assert!(field_of(c).contains("solver.sqp_iterations"));
    }
}
