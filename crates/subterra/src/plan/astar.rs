//! Risk-aware A* on an 8-connected grid (STEP, Fan et al. 2021).
//!
//! Documented on [`RiskAStar`].

mod config;
mod entry;
mod open_list;
mod outcome;
mod search;
#[cfg(test)]
mod tests;

use std::time::Instant;

use glam::DVec2;

use crate::error::{Error, Result};
use crate::plan::grid::RiskGrid;
use crate::terrain::CellIndex;

pub use config::{CostModel, RiskAStarConfig};
pub use entry::EntryPrices;
pub use outcome::{PlanOutcome, PlanStatus, PlannedPath};

use entry::Entry;
use open_list::{open_key, OpenList};
use search::{Node, Search, MOVES};

/// The risk-aware A* planner.
///
/// In: a [`RiskGrid`] ([`RiskGrid`]: row-major `(ny, nx)` risks, row `iy` along world y, column `ix` along
/// world x, the layout of the terrain [`RiskMap`] layers), a start and a goal. Out: a
/// [`PlanOutcome`]: the least-cost path, its cost, length and accumulated risk, the carrot point,
/// or the reason there is no path.
///
/// # Cost model
///
/// A cell's risk `r` is the probability of failing per metre travelled in it.
/// 1. NaN (unknown) is replaced by [`RiskAStarConfig::unknown_risk`].
/// 2. A cell is **untraversable** iff `r >= min(r_inst, lethal_risk)`: a lethal cell (the
///    terrain map's `risk.lethal_risk`) stays untraversable however far the recovery raises
///    `r_inst`.
/// 3. Traversable cells have the hazard `ρ = -ln(1 - r)` [1/m], computed in `f64` as
///    `-ln_1p(-r)` with `r` clamped to at most `MAX_RISK` `= 1 - 2^-24` (the largest `f32`
///    below 1, so the clamp changes no `f32` risk and `ρ <= 16.64`), and the cost
///    `c = λ + ρ` [1/m].
/// 4. A move between 8-neighbours `a`, `b` whose centres are `d` apart (`d = res` or
///    `res·√2`) costs `d·(c(a) + c(b))/2`. This is scikit-image's `MCP_Geometric` on the costs
///    `c` (unit sampling) times `res`, so optimal costs are comparable.
/// 5. Diagonal moves. With `allow_corner_cutting = false` (the default) a diagonal move from
///    `a` to `a + (dx, dy)` is allowed only if both cells sharing that corner, `a + (dx, 0)` and
///    `a + (0, dy)`, are traversable (their risk does not enter the move's cost): the robot never
///    squeezes between two untraversable cells or brushes an untraversable corner. With
///    `allow_corner_cutting = true` every traversable 8-neighbour is reachable
///    (`MCP_Geometric`'s rule).
///
/// 6. Perception-aware prices (optional, [`EntryPrices`]): a move that enters an unknown
///    cell the sensor will not have seen on the way ([`SensorCoverage`](crate::plan::SensorCoverage)) adds
///    `d·(c(unseen_risk) - c(unknown_risk))` to the cost and `d·(ρ(unseen_risk) -
///    ρ(unknown_risk))` to `S`.
/// 7. Clearance prices (optional, [`EntryPrices::clearance`]): cell `i`'s cost gains
///    `k_i·c_min`, with `c_min` the least cell cost ([`RiskAStarConfig::min_cell_cost`]: `λ`,
///    or 1 with the additive model) and `k_i >= 0` given per cell. The navigator can price
///    the ground where the robot could not turn in place without touching an obstacle this
///    way (`navigator.turn_room_price`); it adds to the cost only, never to `S`: it is about
///    room, not risk.
///
/// Without clearance prices a path's cost is therefore `λ·L + S`, with `L = Σ d` its length \[m\] and
/// `S = Σ d·(ρ(a) + ρ(b))/2` its risk integral; its **accumulated risk** is `1 - exp(-S)`
/// (computed as `-expm1(-S)`), STEP's `1 - exp(-Σ d·(-ln(1 - r̄)))` with the same
/// cell averaging as the cost.
///
/// # Search
///
/// A* from the start cell to the goal cell. `g` is the cost from the start; the heuristic is
/// `h = λ·res·octile(n, goal)` with `octile = max(|Δx|, |Δy|) + (√2 - 1)·min(|Δx|, |Δy|)` cells,
/// the length of the shortest 8-connected path, so `h` is admissible and consistent (every move
/// costs at least `λ·d` because `ρ >= 0`): the first time the goal is popped its `g` is the
/// optimal cost, and a closed cell is never reopened. It is never smaller than the paper's
/// `λ·euclid` bound (a better-informed heuristic: up to ties, A* with it expands a subset of
/// the cells it would expand with `λ·euclid`). An expanded cell's `g` is set to `-inf`, so one
/// comparison `g_new < g` skips closed and untraversable neighbours. The open list is an
/// indexed binary heap holding each open cell once, ordered by `f = g + h`, ties broken by the
/// smaller `h` (as `f32`) and then the smaller flat index `iy·nx + ix` (a total order: the pops
/// do not depend on the heap's shape), so a plan is deterministic; an improved cell's key is
/// lowered in place. A cell's `g` improves only when strictly smaller, so among equal-cost
/// predecessors the first one found is kept. Moves are tried in the order E, N, W, S, NE, NW,
/// SW, SE (unrolled away from the grid's border).
///
/// # Toward a target off the grid
///
/// A robot-centred map holds only part of a long route. [`RiskAStar::plan_toward`] plans to
/// a target beyond the grid's border: the path may leave the grid from any border cell `b`,
/// and the leg from `b` on is priced `λ·|b - target|` (the least cost per metre times the
/// straight line: what the heuristic assumes of ground nobody has mapped). One search does
/// it: `h` becomes `λ·euclid(n, target)` (admissible and consistent: every route from `n` on
/// is at least that long and costs at least `λ` a metre), and expanding a border cell `b`
/// offers a virtual goal node the cost `g(b) + h(b)`; the search ends when that node is
/// popped. The path is the one to the `b` that offered its final cost: the least over every
/// border cell of the cost to reach it plus the straight leg on (a test checks this against
/// a search to each border cell). A detour whose way out lies elsewhere on the border is
/// found, where a single stand-in on the segment toward the target would not be.
///
/// # Outcome
///
/// In this order: the start cell untraversable -> [`PlanStatus::StartBlocked`]; the goal cell
/// untraversable -> [`PlanStatus::GoalBlocked`]; the open list empties before the goal is
/// popped -> [`PlanStatus::NoPath`]; otherwise the least-cost path `P` is found and its
/// accumulated risk `R(P)` is compared with `r_total`: `R(P) > r_total` ->
/// [`PlanStatus::BudgetExceeded`] (with `P`, so the caller sees what was rejected), else
/// [`PlanStatus::Found`]. Only the least-cost path's risk is checked: a costlier path whose risk
/// would fit the budget is not searched for (that is a constrained shortest-path problem).
///
/// The planner holds its search buffers between calls: a node array indexed by cell, reused
/// through a per-call stamp (no clearing), and the heap's storage with its slot per cell. A
/// cell's cost is computed the first time the search touches it.
///
/// [`RiskMap`]: crate::terrain::RiskMap
#[derive(Debug, Clone)]
pub struct RiskAStar {
    config: RiskAStarConfig,
    nodes: Vec<Node>,
    open: OpenList,
    stamp: u32,
    /// The border cell the last search toward a target off the grid left by, and its `g`.
    exit_from: (usize, f64),
}

impl RiskAStar {
    /// A planner; fails if the config is invalid.
    pub fn new(config: RiskAStarConfig) -> Result<Self> {
        config.validate()?;
        Ok(Self { config, nodes: Vec::new(), open: OpenList::default(), stamp: 0, exit_from: (0, f64::INFINITY) })
    }

    /// The config.
    pub fn config(&self) -> &RiskAStarConfig {
        &self.config
    }

    /// [`RiskAStarConfig::polyline_cost`] with the perception-aware entry prices the search
    /// would use (`entry`): a path priced so costs what the A* would charge for it. Errors as
    /// [`RiskAStar::plan_with`] on a bad `entry`.
    pub fn price_polyline(&self, grid: &RiskGrid<'_>, points_world: &[DVec2], entry: Option<&EntryPrices<'_>>) -> Result<Option<(f64, f64)>> {
        let entry = self.checked_entry(grid, entry)?;
        Ok(self.config.polyline_cost_with(grid, points_world, entry))
    }

    /// Plans from the cell holding the world position `start_world` to the one holding
    /// `goal_world` \[m\]. Errors (naming `start` or `goal`) if a position is not finite or lies
    /// outside the grid; "no path" is an outcome.
    pub fn plan(&mut self, grid: &RiskGrid<'_>, start_world: DVec2, goal_world: DVec2) -> Result<PlanOutcome> {
        self.plan_with(grid, start_world, goal_world, None)
    }

    /// [`RiskAStar::plan`] with perception-aware entry prices (see [`EntryPrices`]).
    pub fn plan_with(&mut self, grid: &RiskGrid<'_>, start_world: DVec2, goal_world: DVec2, entry: Option<&EntryPrices<'_>>) -> Result<PlanOutcome> {
        let start = grid.locate("start", start_world)?;
        let goal = grid.locate("goal", goal_world)?;
        self.plan_cells_with(grid, start, goal, entry)
    }

    /// Plans from the cell holding `start_world` toward `target_world` \[m\], which may lie off
    /// the grid: to the border cell `b` whose path cost plus `λ·|b - target|` (the heuristic's
    /// price of the straight line on, [`RiskAStarConfig::min_cell_cost`] per metre) is least
    /// (`RiskAStar`'s docs, "Toward a target off the grid"). The path ends at `b`
    /// ([`PlanOutcome::goal_cell`]); its cost, length and risk are those of the path on the
    /// grid. A target on the grid is planned to as by [`RiskAStar::plan_with`]. Errors (naming
    /// `start` or `target`) if a position is not finite or the start lies off the grid.
    pub fn plan_toward(&mut self, grid: &RiskGrid<'_>, start_world: DVec2, target_world: DVec2, entry: Option<&EntryPrices<'_>>) -> Result<PlanOutcome> {
        crate::frames::check_position("target", &target_world.to_array())?;
        if grid.cell_of(target_world).is_some() {
            return self.plan_with(grid, start_world, target_world, entry);
        }
        let started = Instant::now();
        let start = grid.locate("start", start_world)?;
        let entry = self.checked_entry(grid, entry)?;
        // The target in cell coordinates: cell (x, y)'s centre at (x, y).
        let c0 = grid.centre_of(grid.cell_at(0));
        let exit = ((target_world.x - c0.x) / grid.resolution_m, (target_world.y - c0.y) / grid.resolution_m);
        let (status, expanded) = self.search(grid, grid.flat(start), grid.flat(start), Some(exit), entry);
        let (exit_cell, exit_g) = self.exit_from;
        let goal = grid.cell_at(exit_cell);
        let path = match status {
            PlanStatus::Found => Some(self.trace(grid, exit_cell, exit_g, entry)),
            _ => None,
        };
        Ok(self.outcome(status, path, (start, goal), expanded, started))
    }

    /// Plans from cell `start` to cell `goal`. Errors (naming `start` or `goal`) if a cell is
    /// outside the grid.
    pub fn plan_cells(&mut self, grid: &RiskGrid<'_>, start: CellIndex, goal: CellIndex) -> Result<PlanOutcome> {
        self.plan_cells_with(grid, start, goal, None)
    }

    /// [`RiskAStar::plan_cells`] with perception-aware entry prices.
    pub fn plan_cells_with(&mut self, grid: &RiskGrid<'_>, start: CellIndex, goal: CellIndex, entry: Option<&EntryPrices<'_>>) -> Result<PlanOutcome> {
        let started = Instant::now();
        grid.check_cell("start", start)?;
        grid.check_cell("goal", goal)?;
        let entry = self.checked_entry(grid, entry)?;
        let (status, expanded) = self.search(grid, grid.flat(start), grid.flat(goal), None, entry);
        let path = match status {
            PlanStatus::Found | PlanStatus::BudgetExceeded => Some(self.trace(grid, grid.flat(goal), self.nodes[grid.flat(goal)].g, entry)),
            _ => None,
        };
        Ok(self.outcome(status, path, (start, goal), expanded, started))
    }

    /// The outcome of a search that ended with `status` and traced `path`: the budget check
    /// (with the `risk` model) and the carrot.
    fn outcome(&self, status: PlanStatus, path: Option<PlannedPath>, (start, goal): (CellIndex, CellIndex), expanded: usize, started: Instant) -> PlanOutcome {
        let status = match &path {
            Some(p) if self.config.cost_model == CostModel::Risk && p.accumulated_risk > self.config.r_total => PlanStatus::BudgetExceeded,
            _ => status,
        };
        let carrot_world = match (&path, status) {
            (Some(p), PlanStatus::Found) => Some(carrot(&p.points_world, self.config.carrot_m)),
            _ => None,
        };
        PlanOutcome { status, path, carrot_world, start_cell: start, goal_cell: goal, expanded, time_s: started.elapsed().as_secs_f64() }
    }

    /// Starts a new search over `cells` cells: grows the node array, moves to a fresh stamp and
    /// empties the open list.
    fn begin(&mut self, cells: usize) {
        if self.nodes.len() < cells {
            self.nodes.resize(cells, Node::default());
        }
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            // Wrapped: forget every old stamp.
            self.nodes.iter_mut().for_each(|n| n.stamp = 0);
            self.stamp = 1;
        }
        self.open.begin(cells);
    }

    /// A* from `start` to `goal` (flat indices). Returns `Found` (the goal's `g` and parents are
    /// set; the budget is checked by the caller), `StartBlocked`, `GoalBlocked` or `NoPath`, and
    /// the number of expanded cells.
    /// The entry mask and what an unseen entry adds to the cost and to the hazard [1/m], and
    /// the clearance prices, checked against the grid; empty without prices.
    fn checked_entry<'e>(&self, grid: &RiskGrid<'_>, entry: Option<&EntryPrices<'e>>) -> Result<Entry<'e>> {
        let Some(e) = entry else { return Ok(Entry::NONE) };
        let cells = grid.nx * grid.ny;
        if !e.unseen.is_empty() && e.unseen.len() != cells {
            return Err(Error::input("unseen", format!("has {} values, the grid {cells} cells", e.unseen.len())));
        }
        if !e.clearance.is_empty() && e.clearance.len() != cells {
            return Err(Error::input("clearance", format!("has {} values, the grid {cells} cells", e.clearance.len())));
        }
        if let Some(bad) = e.clearance.iter().find(|k| !(k.is_finite() && **k >= 0.0)) {
            return Err(Error::input("clearance", format!("prices must be finite and >= 0, got {bad}")));
        }
        if !(0.0..=1.0).contains(&e.unseen_risk) {
            return Err(Error::input("unseen_risk", format!("must be in [0, 1], got {}", e.unseen_risk)));
        }
        let unseen = e.unseen_risk as f32;
        let cost_extra = (self.config.cell_cost(unseen) - self.config.cell_cost(f32::NAN)).max(0.0);
        let hazard = |r: f32| self.config.hazard(r).unwrap_or(f64::INFINITY);
        let hazard_extra = (hazard(unseen) - hazard(f32::NAN)).max(0.0);
        Ok(Entry { unseen: e.unseen, cost_extra, hazard_extra, clearance: e.clearance, clearance_unit: self.config.min_cell_cost() })
    }

    fn search(&mut self, grid: &RiskGrid<'_>, start: usize, goal: usize, exit: Option<(f64, f64)>, entry: Entry<'_>) -> (PlanStatus, usize) {
        let (nx, ny) = (grid.nx, grid.ny);
        // One node more than the cells: the virtual goal toward a target off the grid.
        self.begin(nx * ny + 1);
        let res = grid.resolution_m;
        let mut search = Search {
            nodes: &mut self.nodes[..nx * ny + 1],
            open: &mut self.open,
            risk: grid.risk,
            config: &self.config,
            stamp: self.stamp,
            step: [res, res * std::f64::consts::SQRT_2],
            goal: (goal % nx, goal / nx),
            exit,
            exit_from: (goal, f64::INFINITY),
            h_scale: self.config.min_cell_cost() * res,
            unseen: entry.unseen,
            unseen_extra: entry.cost_extra,
            clearance: entry.clearance,
            clearance_unit: entry.clearance_unit,
        };
        if search.touch(start).cost.is_infinite() {
            return (PlanStatus::StartBlocked, 0);
        }
        if exit.is_none() && search.touch(goal).cost.is_infinite() {
            return (PlanStatus::GoalBlocked, 0);
        }
        search.nodes[start].g = 0.0;
        let (sx, sy) = (start % nx, start / nx);
        let h0 = search.heuristic(sx, sy);
        search.open.push(open_key(h0, h0, start));
        let out = if self.config.allow_corner_cutting { search.run::<true>(nx, ny) } else { search.run::<false>(nx, ny) };
        self.exit_from = search.exit_from;
        out
    }

    /// The path to `goal` through the parents of the last search, with its cost, length, risk
    /// integral and accumulated risk.
    fn trace(&self, grid: &RiskGrid<'_>, goal: usize, cost: f64, entry: Entry<'_>) -> PlannedPath {
        let mut flat = vec![goal];
        let mut i = goal;
        while let Some(&(dx, dy)) = MOVES.get(self.nodes[i].parent as usize) {
            let (x, y) = ((i % grid.nx) as i64 - dx as i64, (i / grid.nx) as i64 - dy as i64);
            i = (y * grid.nx as i64 + x) as usize;
            flat.push(i);
        }
        flat.reverse();
        let cells: Vec<CellIndex> = flat.iter().map(|&i| grid.cell_at(i)).collect();
        let points_world: Vec<DVec2> = cells.iter().map(|&c| grid.centre_of(c)).collect();
        let hazard = |i: usize| self.config.hazard(grid.risk[i]).unwrap_or(f64::INFINITY);
        let (mut length_m, mut risk_integral) = (0.0, 0.0);
        for w in flat.windows(2) {
            let diagonal = w[0] % grid.nx != w[1] % grid.nx && w[0] / grid.nx != w[1] / grid.nx;
            let d = if diagonal { grid.resolution_m * std::f64::consts::SQRT_2 } else { grid.resolution_m };
            length_m += d;
            let unseen = !entry.unseen.is_empty() && entry.unseen[w[1]] & (1 << self.nodes[w[1]].parent) != 0;
            risk_integral += d * ((hazard(w[0]) + hazard(w[1])) * 0.5 + if unseen { entry.hazard_extra } else { 0.0 });
        }
        PlannedPath { cells, points_world, cost, length_m, risk_integral, accumulated_risk: -(-risk_integral).exp_m1() }
    }
}

/// The point `distance_m` along the polyline `points` from its first point; its last point if
/// the polyline is shorter.
fn carrot(points: &[DVec2], distance_m: f64) -> DVec2 {
    let mut left = distance_m;
    for w in points.windows(2) {
        let seg = w[0].distance(w[1]);
        if seg >= left {
            return w[0] + (w[1] - w[0]) * (left / seg);
        }
        left -= seg;
    }
    points.last().copied().unwrap_or(DVec2::NAN)
}
