//! The planner's settings ([`RiskAStarConfig`], [`CostModel`]) and the cost model they define:
//! a cell's hazard and cost per metre, and the price of a polyline as the search prices it.

use glam::DVec2;
use serde::{Deserialize, Serialize};

#[cfg(doc)]
use super::RiskAStar;
use super::entry::Entry;
use super::search::MOVES;
use crate::error::{require_positive, Error, Result};
use crate::plan::grid::RiskGrid;
use crate::terrain::CellIndex;

/// Largest risk used in `-ln(1 - r)`: `1 - 2^-24`, the largest `f32` below 1. Keeps the hazard
/// finite (at most `24·ln 2 = 16.64` per metre).
pub(crate) const MAX_RISK: f64 = 1.0 - 1.0 / 16_777_216.0;
/// Largest length weight λ accepted [1/m]; keeps every path cost finite.
pub(crate) const MAX_LAMBDA_PER_M: f64 = 1.0e6;

/// How a cell's risk becomes a cost per metre.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum CostModel {
    /// STEP: `c = λ - ln(1 - r)`; the accumulated-risk budget `R_total` applies.
    #[default]
    Risk,
    /// The conventional baseline (Nav2 Smac-style): `c = 1 + k·r` with `k` =
    /// `additive_weight`; cells at or above `R_inst` blocked; **no** budget (a path is
    /// `Found` whatever its accumulated risk, which is still reported).
    Additive,
}

/// Settings of [`RiskAStar`]. "subterra" as a source means an engineering choice of this
/// library, not a published value.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RiskAStarConfig {
    /// λ, the weight of path length in the cost `d·(λ - ln(1 - r̄))` [1/m]: a detour of `x`
    /// metres is worth avoiding a risk integral of `λ·x`. Small, so that risk dominates and
    /// among riskless paths the shortest wins (STEP, Fan et al. 2021). subterra: 0.1.
    pub lam: f64,
    /// `R_inst`: cells with risk `>= r_inst` are untraversable, in (0, 1] \[1\]. subterra: 0.8.
    pub r_inst: f64,
    /// `R_total`: the largest accumulated risk of an accepted path, in (0, 1] \[1\]. subterra: 0.5.
    pub r_total: f64,
    /// Path length from the start to the carrot point \[m\]. STEP: 1.
    pub carrot_m: f64,
    /// Risk of a cell whose risk is NaN (unknown), in [0, 1] [1/m]; `>= r_inst` makes unknown
    /// cells untraversable. subterra: 0.15, the terrain mapper's `risk.unknown`.
    pub unknown_risk: f64,
    /// Whether a diagonal move may pass an untraversable cell at the corner it crosses (see the
    /// `RiskAStar`'s docs). subterra: false.
    pub allow_corner_cutting: bool,
    /// The cost model: `risk` (STEP, Fan et al. 2021) or `additive` (the baseline). subterra: risk.
    #[serde(default)]
    pub cost_model: CostModel,
    /// `k` of the additive model `1 + k·r` \[1\]. Nav2 Smac planner's `cost_penalty`: 2.0.
    #[serde(default = "default_additive_weight")]
    pub additive_weight: f64,
    /// Cells at or above this risk are lethal and untraversable whatever `r_inst` is, in
    /// (0, 1] \[1\]. The navigator sets it to the terrain map's `risk.lethal_risk`, so that
    /// raised thresholds never open a hole or a wall. subterra: 1.0 (only certain failure).
    #[serde(default = "default_lethal_risk")]
    pub lethal_risk: f64,
}

fn default_lethal_risk() -> f64 {
    1.0
}

fn default_additive_weight() -> f64 {
    2.0
}

impl Default for RiskAStarConfig {
    fn default() -> Self {
        Self {
            lam: 0.1,
            r_inst: 0.8,
            r_total: 0.5,
            carrot_m: 1.0,
            unknown_risk: 0.15,
            allow_corner_cutting: false,
            cost_model: CostModel::Risk,
            additive_weight: default_additive_weight(),
            lethal_risk: default_lethal_risk(),
        }
    }
}

impl RiskAStarConfig {
    /// Checks every field, naming it (`astar.<field>`) on error.
    pub fn validate(&self) -> Result<()> {
        if !(self.lam.is_finite() && self.lam > 0.0 && self.lam <= MAX_LAMBDA_PER_M) {
            return Err(Error::config("astar.lam", format!("must be in (0, {MAX_LAMBDA_PER_M:e}] 1/m"), self.lam));
        }
        let unit = |field: &str, value: f64| {
            if value.is_finite() && value > 0.0 && value <= 1.0 {
                Ok(())
            } else {
                Err(Error::config(field, "must be in (0, 1]", value))
            }
        };
        unit("astar.r_inst", self.r_inst)?;
        unit("astar.r_total", self.r_total)?;
        unit("astar.lethal_risk", self.lethal_risk)?;
        require_positive("astar.carrot_m", self.carrot_m)?;
        if !(0.0..=1.0).contains(&self.unknown_risk) {
            return Err(Error::config("astar.unknown_risk", "must be in [0, 1]", self.unknown_risk));
        }
        if !(self.additive_weight.is_finite() && self.additive_weight >= 0.0 && self.additive_weight <= MAX_LAMBDA_PER_M) {
            return Err(Error::config("astar.additive_weight", format!("must be in [0, {MAX_LAMBDA_PER_M:e}]"), self.additive_weight));
        }
        Ok(())
    }

    /// The hazard `-ln(1 - r)` [1/m] of a cell of risk `r`, or `None` if it is untraversable.
    #[inline]
    pub fn hazard(&self, risk: f32) -> Option<f64> {
        let r = if risk.is_nan() { self.unknown_risk } else { risk as f64 };
        if r >= self.r_inst || r >= self.lethal_risk {
            None
        } else {
            Some(-(-r.min(MAX_RISK)).ln_1p())
        }
    }

    /// The cost [1/m] of a cell of risk `r`: `λ - ln(1 - r)`, or `1 + k·r` with the additive
    /// model; `+inf` if it is untraversable.
    #[inline]
    pub fn cell_cost(&self, risk: f32) -> f64 {
        match self.cost_model {
            CostModel::Risk => self.hazard(risk).map_or(f64::INFINITY, |rho| self.lam + rho),
            CostModel::Additive => {
                let r = if risk.is_nan() { self.unknown_risk } else { risk as f64 };
                if r >= self.r_inst || r >= self.lethal_risk { f64::INFINITY } else { 1.0 + self.additive_weight * r.max(0.0) }
            }
        }
    }

    /// Prices the polyline `points_world` on `grid` as the search prices its moves: each
    /// segment `a -> b` costs `d·(c(a) + c(b))/2` and adds `d·(ρ(a) + ρ(b))/2` to the risk
    /// integral, with `c` and `ρ` of the cells holding its ends (no entry prices). `None`
    /// when a point lies off the grid or in an untraversable cell, or when the accumulated
    /// risk exceeds `r_total` (with the `risk` model). For a path of 8-neighbour cell centres
    /// this is the path's `cost` and `risk_integral`; the navigator uses it to price the path
    /// it follows and a new one alike (plan hysteresis).
    pub fn polyline_cost(&self, grid: &RiskGrid<'_>, points_world: &[DVec2]) -> Option<(f64, f64)> {
        self.polyline_cost_with(grid, points_world, Entry::NONE)
    }

    /// [`Self::polyline_cost`] with the search's entry prices: a segment between 8-neighbour
    /// cells whose move enters its cell unseen pays the extra, and a cell's clearance price
    /// adds to its cost, as in the search.
    pub(super) fn polyline_cost_with(&self, grid: &RiskGrid<'_>, points_world: &[DVec2], entry: Entry<'_>) -> Option<(f64, f64)> {
        let mut prev: Option<(CellIndex, f64, f64, DVec2)> = None;
        let (mut cost, mut integral) = (0.0, 0.0);
        for &p in points_world {
            let cell = grid.cell_of(p)?;
            let flat = grid.flat(cell);
            let risk = grid.risk[flat];
            let (c, rho) = (self.cell_cost(risk) + entry.clearance_cost(flat), self.hazard(risk)?);
            if !c.is_finite() {
                return None;
            }
            if let Some((qc, cq, rq, q)) = prev {
                let d = p.distance(q);
                let step = (i64::from(cell.ix) - i64::from(qc.ix), i64::from(cell.iy) - i64::from(qc.iy));
                let unseen = !entry.unseen.is_empty()
                    && MOVES.iter().position(|&(dx, dy)| (i64::from(dx), i64::from(dy)) == step).is_some_and(|k| entry.unseen[flat] & (1 << k) != 0);
                let (ce, he) = if unseen { (entry.cost_extra, entry.hazard_extra) } else { (0.0, 0.0) };
                cost += d * (0.5 * (c + cq) + ce);
                integral += d * (0.5 * (rho + rq) + he);
            }
            prev = Some((cell, c, rho, p));
        }
        let over_budget = self.cost_model == CostModel::Risk && -(-integral).exp_m1() > self.r_total;
        (!over_budget).then_some((cost, integral))
    }

    /// The least cost per metre of any cell: the heuristic's scale [1/m].
    #[inline]
    pub fn min_cell_cost(&self) -> f64 {
        match self.cost_model {
            CostModel::Risk => self.lam,
            CostModel::Additive => 1.0,
        }
    }
}
