//! What a plan returns: its [`PlanStatus`], the [`PlannedPath`] found and the whole
//! [`PlanOutcome`] with the carrot point, the cells expanded and the time taken.

use glam::DVec2;

#[cfg(doc)]
use super::RiskAStar;
use crate::terrain::CellIndex;

/// Why a plan has or has no path.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum PlanStatus {
    /// The least-cost path is within the risk budget.
    Found,
    /// The start cell is untraversable (`r >= r_inst`).
    StartBlocked,
    /// The goal cell is untraversable (`r >= r_inst`).
    GoalBlocked,
    /// No traversable path joins start and goal.
    NoPath,
    /// The least-cost path's accumulated risk exceeds `r_total` (the path is reported).
    BudgetExceeded,
}

impl PlanStatus {
    /// `found`, `start_blocked`, `goal_blocked`, `no_path` or `budget_exceeded`.
    pub fn name(self) -> &'static str {
        match self {
            PlanStatus::Found => "found",
            PlanStatus::StartBlocked => "start_blocked",
            PlanStatus::GoalBlocked => "goal_blocked",
            PlanStatus::NoPath => "no_path",
            PlanStatus::BudgetExceeded => "budget_exceeded",
        }
    }
}

/// A least-cost path from the start cell to the goal cell.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedPath {
    /// The cells, start first, goal last; consecutive cells are 8-neighbours.
    pub cells: Vec<CellIndex>,
    /// The cells' centres in the world frame \[m\].
    pub points_world: Vec<DVec2>,
    /// `λ·L + S`, the sum of the move costs (the A* `g` of the goal) \[1\].
    pub cost: f64,
    /// `L`, the length of the polyline through the cell centres \[m\].
    pub length_m: f64,
    /// `S = Σ d·(ρ(a) + ρ(b))/2`, the risk integral \[1\].
    pub risk_integral: f64,
    /// `1 - exp(-S)`, the accumulated risk \[1\].
    pub accumulated_risk: f64,
}

/// The result of one [`RiskAStar::plan`].
#[derive(Debug, Clone, PartialEq)]
pub struct PlanOutcome {
    /// Whether a path was found, and if not why.
    pub status: PlanStatus,
    /// The least-cost path: with [`PlanStatus::Found`] and [`PlanStatus::BudgetExceeded`].
    pub path: Option<PlannedPath>,
    /// The point `carrot_m` of path length from the start along the path's polyline (the goal's
    /// centre if the path is shorter) [m, world]: with [`PlanStatus::Found`] only.
    pub carrot_world: Option<DVec2>,
    /// The start cell.
    pub start_cell: CellIndex,
    /// The goal cell.
    pub goal_cell: CellIndex,
    /// Cells popped from the open list and expanded (the goal included).
    pub expanded: usize,
    /// Wall time of the plan \[s\].
    pub time_s: f64,
}

impl PlanOutcome {
    /// The path when the status is [`PlanStatus::Found`].
    pub fn found(&self) -> Option<&PlannedPath> {
        if self.status == PlanStatus::Found {
            self.path.as_ref()
        } else {
            None
        }
    }
}
