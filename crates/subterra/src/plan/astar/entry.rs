//! Perception-aware and clearance prices for the search ([`EntryPrices`]), and their checked
//! per-metre form the search and the path pricing use.

#[cfg(doc)]
use super::RiskAStar;

/// Perception-aware prices for [`RiskAStar::plan_with`]
/// ([`SensorCoverage`](crate::plan::SensorCoverage)): the moves that would enter an unknown
/// cell before the sensor has seen it cost as if the cell's risk were `unseen_risk` instead of
/// the planner's `unknown_risk` (in the cost and in the accumulated risk).
#[derive(Debug, Clone, Copy)]
pub struct EntryPrices<'a> {
    /// One byte per cell, row-major: bit `k` set when move `k` (E, N, W, S, NE, NW, SW, SE)
    /// into the cell enters it unseen (as the navigator marks them from its
    /// [`SensorCoverage`](crate::plan::SensorCoverage)).
    pub unseen: &'a [u8],
    /// The risk of an unknown cell entered unseen, in [0, 1] [1/m].
    pub unseen_risk: f64,
    /// Per cell, row-major, the clearance price `k >= 0` (finite): the cell's cost grows by `k`
    /// times the least cell cost ([`RiskAStar`], step 7). Empty: none.
    pub clearance: &'a [f32],
}

impl EntryPrices<'_> {
    /// No prices: no unseen entries, no clearance prices.
    pub const NONE: EntryPrices<'static> = EntryPrices { unseen: &[], unseen_risk: 0.0, clearance: &[] };
}

/// [`EntryPrices`] checked against a grid and turned into per-metre additions.
#[derive(Debug, Clone, Copy)]
pub(super) struct Entry<'a> {
    pub(super) unseen: &'a [u8],
    pub(super) cost_extra: f64,
    pub(super) hazard_extra: f64,
    /// Clearance prices per cell (empty: none) and what one unit of price costs [1/m].
    pub(super) clearance: &'a [f32],
    pub(super) clearance_unit: f64,
}

impl Entry<'_> {
    pub(super) const NONE: Entry<'static> = Entry { unseen: &[], cost_extra: 0.0, hazard_extra: 0.0, clearance: &[], clearance_unit: 0.0 };

    /// What cell `i`'s clearance price adds to its cost [1/m].
    #[inline(always)]
    pub(super) fn clearance_cost(&self, i: usize) -> f64 {
        if self.clearance.is_empty() { 0.0 } else { f64::from(self.clearance[i]) * self.clearance_unit }
    }
}
