//! Risk-aware A* on an 8-connected grid (STEP, Fan et al. 2021).
//!
//! In: a [`RiskGrid`] ([`crate::plan::grid`]: row-major `(ny, nx)` risks, row `iy` along world y, column `ix` along
//! world x, the layout of the terrain [`RiskMap`] layers), a start and a goal. Out: a
//! [`PlanOutcome`]: the least-cost path, its cost, length and accumulated risk, the carrot point,
//! or the reason there is no path.
//!
//! # Cost model
//!
//! A cell's risk `r` is the probability of failing per metre travelled in it.
//! 1. NaN (unknown) is replaced by [`RiskAStarConfig::unknown_risk`].
//! 2. A cell is **untraversable** iff `r >= min(r_inst, lethal_risk)`: a lethal cell (the
//!    terrain map's `risk.lethal_risk`) stays untraversable however far the recovery raises
//!    `r_inst`.
//! 3. Traversable cells have the hazard `ρ = -ln(1 - r)` [1/m], computed in `f64` as
//!    `-ln_1p(-r)` with `r` clamped to at most [`MAX_RISK`] `= 1 - 2^-24` (the largest `f32`
//!    below 1, so the clamp changes no `f32` risk and `ρ <= 16.64`), and the cost
//!    `c = λ + ρ` [1/m].
//! 4. A move between 8-neighbours `a`, `b` whose centres are `d` apart (`d = res` or
//!    `res·√2`) costs `d·(c(a) + c(b))/2`. This is scikit-image's `MCP_Geometric` on the costs
//!    `c` (unit sampling) times `res`, so optimal costs are comparable.
//! 5. Diagonal moves. With `allow_corner_cutting = false` (the default) a diagonal move from
//!    `a` to `a + (dx, dy)` is allowed only if both cells sharing that corner, `a + (dx, 0)` and
//!    `a + (0, dy)`, are traversable (their risk does not enter the move's cost): the robot never
//!    squeezes between two untraversable cells or brushes an untraversable corner. With
//!    `allow_corner_cutting = true` every traversable 8-neighbour is reachable
//!    (`MCP_Geometric`'s rule).
//!
//! 6. Perception-aware prices (optional, [`EntryPrices`]): a move that enters an unknown
//!    cell the sensor will not have seen on the way ([`crate::plan::coverage`]) adds
//!    `d·(c(unseen_risk) - c(unknown_risk))` to the cost and `d·(ρ(unseen_risk) -
//!    ρ(unknown_risk))` to `S`.
//! 7. Clearance prices (optional, [`EntryPrices::clearance`]): cell `i`'s cost gains
//!    `k_i·c_min`, with `c_min` the least cell cost ([`RiskAStarConfig::min_cell_cost`]: `λ`,
//!    or 1 with the additive model) and `k_i >= 0` given per cell. The navigator can price
//!    the ground where the robot could not turn in place without touching an obstacle this
//!    way (`navigator.turn_room_price`); it adds to the cost only, never to `S`: it is about
//!    room, not risk.
//!
//! Without clearance prices a path's cost is therefore `λ·L + S`, with `L = Σ d` its length [m] and
//! `S = Σ d·(ρ(a) + ρ(b))/2` its risk integral; its **accumulated risk** is `1 - exp(-S)`
//! (computed as `-expm1(-S)`), STEP's `1 - exp(-Σ d·(-ln(1 - r̄)))` with the same
//! cell averaging as the cost.
//!
//! # Search
//!
//! A* from the start cell to the goal cell. `g` is the cost from the start; the heuristic is
//! `h = λ·res·octile(n, goal)` with `octile = max(|Δx|, |Δy|) + (√2 - 1)·min(|Δx|, |Δy|)` cells,
//! the length of the shortest 8-connected path, so `h` is admissible and consistent (every move
//! costs at least `λ·d` because `ρ >= 0`): the first time the goal is popped its `g` is the
//! optimal cost, and a closed cell is never reopened. It is never smaller than the paper's
//! `λ·euclid` bound (a better-informed heuristic: up to ties, A* with it expands a subset of
//! the cells it would expand with `λ·euclid`). An expanded cell's `g` is set to `-inf`, so one
//! comparison `g_new < g` skips closed and untraversable neighbours. The open list is an
//! indexed binary heap holding each open cell once, ordered by `f = g + h`, ties broken by the
//! smaller `h` (as `f32`) and then the smaller flat index `iy·nx + ix` (a total order: the pops
//! do not depend on the heap's shape), so a plan is deterministic; an improved cell's key is
//! lowered in place. A cell's `g` improves only when strictly smaller, so among equal-cost
//! predecessors the first one found is kept. Moves are tried in the order E, N, W, S, NE, NW,
//! SW, SE (unrolled away from the grid's border).
//!
//! # Toward a target off the grid
//!
//! A robot-centred map holds only part of a long route. [`RiskAStar::plan_toward`] plans to
//! a target beyond the grid's border: the path may leave the grid from any border cell `b`,
//! and the leg from `b` on is priced `λ·|b - target|` (the least cost per metre times the
//! straight line: what the heuristic assumes of ground nobody has mapped). One search does
//! it: `h` becomes `λ·euclid(n, target)` (admissible and consistent: every route from `n` on
//! is at least that long and costs at least `λ` a metre), and expanding a border cell `b`
//! offers a virtual goal node the cost `g(b) + h(b)`; the search ends when that node is
//! popped. The path is the one to the `b` that offered its final cost: the least over every
//! border cell of the cost to reach it plus the straight leg on (a test checks this against
//! a search to each border cell). A detour whose way out lies elsewhere on the border is
//! found, where a single stand-in on the segment toward the target would not be.
//!
//! # Outcome
//!
//! In this order: the start cell untraversable -> [`PlanStatus::StartBlocked`]; the goal cell
//! untraversable -> [`PlanStatus::GoalBlocked`]; the open list empties before the goal is
//! popped -> [`PlanStatus::NoPath`]; otherwise the least-cost path `P` is found and its
//! accumulated risk `R(P)` is compared with `r_total`: `R(P) > r_total` ->
//! [`PlanStatus::BudgetExceeded`] (with `P`, so the caller sees what was rejected), else
//! [`PlanStatus::Found`]. Only the least-cost path's risk is checked: a costlier path whose risk
//! would fit the budget is not searched for (that is a constrained shortest-path problem).
//!
//! The planner holds its search buffers between calls: a node array indexed by cell, reused
//! through a per-call stamp (no clearing), and the heap's storage with its slot per cell. A
//! cell's cost is computed the first time the search touches it.
//!
//! [`RiskMap`]: crate::terrain::RiskMap

use std::time::Instant;

use glam::DVec2;
use serde::{Deserialize, Serialize};

use crate::error::{require_positive, Error, Result};
pub use crate::plan::grid::{RiskGrid, MAX_GRID_CELLS, MAX_SIDE};
use crate::terrain::CellIndex;

/// Largest risk used in `-ln(1 - r)`: `1 - 2^-24`, the largest `f32` below 1. Keeps the hazard
/// finite (at most `24·ln 2 = 16.64` per metre).
pub const MAX_RISK: f64 = 1.0 - 1.0 / 16_777_216.0;
/// Largest length weight λ accepted [1/m]; keeps every path cost finite.
pub const MAX_LAMBDA_PER_M: f64 = 1.0e6;

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
    /// `R_inst`: cells with risk `>= r_inst` are untraversable, in (0, 1] [1]. subterra: 0.8.
    pub r_inst: f64,
    /// `R_total`: the largest accumulated risk of an accepted path, in (0, 1] [1]. subterra: 0.5.
    pub r_total: f64,
    /// Path length from the start to the carrot point [m]. STEP: 1.
    pub carrot_m: f64,
    /// Risk of a cell whose risk is NaN (unknown), in [0, 1] [1/m]; `>= r_inst` makes unknown
    /// cells untraversable. subterra: 0.15, the terrain mapper's `risk.unknown`.
    pub unknown_risk: f64,
    /// Whether a diagonal move may pass an untraversable cell at the corner it crosses (see the
    /// module docs). subterra: false.
    pub allow_corner_cutting: bool,
    /// The cost model: `risk` (STEP, Fan et al. 2021) or `additive` (the baseline). subterra: risk.
    #[serde(default)]
    pub cost_model: CostModel,
    /// `k` of the additive model `1 + k·r` [1]. Nav2 Smac planner's `cost_penalty`: 2.0.
    #[serde(default = "default_additive_weight")]
    pub additive_weight: f64,
    /// Cells at or above this risk are lethal and untraversable whatever `r_inst` is, in
    /// (0, 1] [1]. The navigator sets it to the terrain map's `risk.lethal_risk`, so that
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

    /// Parses and validates a TOML document laid out like `configs/astar.toml`.
    pub fn from_toml_str(text: &str) -> Result<Self> {
        let config: Self = crate::error::parse_toml(text)?;
        config.validate()?;
        Ok(config)
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
    fn polyline_cost_with(&self, grid: &RiskGrid<'_>, points_world: &[DVec2], entry: Entry<'_>) -> Option<(f64, f64)> {
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
    /// The cells' centres in the world frame [m].
    pub points_world: Vec<DVec2>,
    /// `λ·L + S`, the sum of the move costs (the A* `g` of the goal) [1].
    pub cost: f64,
    /// `L`, the length of the polyline through the cell centres [m].
    pub length_m: f64,
    /// `S = Σ d·(ρ(a) + ρ(b))/2`, the risk integral [1].
    pub risk_integral: f64,
    /// `1 - exp(-S)`, the accumulated risk [1].
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
    /// Wall time of the plan [s].
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

/// The 8 moves `(dx, dy)`: orthogonal first (E, N, W, S), then diagonal (NE, NW, SW, SE).
const MOVES: [(i32, i32); 8] = [(1, 0), (0, 1), (-1, 0), (0, -1), (1, 1), (-1, 1), (-1, -1), (1, -1)];
/// For diagonal move `4 + k`, the two orthogonal moves whose cells share its corner.
const CORNERS: [(usize, usize); 4] = [(0, 1), (2, 1), (2, 3), (0, 3)];
/// Parent of the start cell.
const NO_PARENT: u8 = u8::MAX;

/// Search state of one cell; valid only when `stamp` is the planner's current stamp.
#[derive(Debug, Clone, Copy, Default)]
struct Node {
    /// Cost from the start: `+inf` not reached, [`CLOSED`] expanded (the goal keeps its cost).
    g: f64,
    /// Cell cost `λ + ρ` (`+inf`: untraversable).
    cost: f64,
    stamp: u32,
    /// The move (index into `MOVES`) that reached this cell.
    parent: u8,
}

/// `g` of an expanded cell: no new cost is below it, so a closed cell is never improved, and an
/// untraversable neighbour's `+inf` cost never improves anything either (one comparison tests
/// all three).
const CLOSED: f64 = f64::NEG_INFINITY;

/// The open-list key of the cell of flat index `flat`: `f.to_bits() << 64 | (h as f32).to_bits() << 32 | flat`
/// as one integer. `f, h >= 0`, so their bits order as their values: the smallest key is the
/// entry of smallest `(f, h, flat index)`. Grids have at most [`MAX_GRID_CELLS`] `<= 2^32` cells.
#[inline]
fn open_key(f: f64, h: f64, flat: usize) -> u128 {
    let tie = (((h as f32).to_bits() as u64) << 32) | flat as u64;
    ((f.to_bits() as u128) << 64) | tie as u128
}

/// The flat index of an open-list key's cell.
#[inline]
fn key_flat(key: u128) -> usize {
    key as u32 as usize
}

/// The open list: an indexed binary min-heap of [`open_key`]s, one per open cell (the children
/// of slot `i` are the slots `2i + 1` and `2i + 2`). Each open cell's slot is recorded, so an
/// improved cell's key is lowered in place: no stale entries.
#[derive(Debug, Clone, Default)]
struct OpenList {
    keys: Vec<u128>,
    /// The slot of each open cell's key, by flat index (meaningless for other cells).
    slots: Vec<u32>,
}

impl OpenList {
    /// Empties the list for a search over `cells` cells.
    fn begin(&mut self, cells: usize) {
        self.keys.clear();
        if self.slots.len() < cells {
            self.slots.resize(cells, 0);
        }
    }

    /// Puts `key` into slot `i` and records the slot.
    #[inline(always)]
    fn place(&mut self, i: usize, key: u128) {
        self.keys[i] = key;
        self.slots[key_flat(key)] = i as u32;
    }

    /// Moves the hole at slot `hole` up while its parent's key is above `key`, then puts `key`
    /// there.
    #[inline(always)]
    fn sift_up(&mut self, mut hole: usize, key: u128) {
        while hole > 0 {
            let parent = (hole - 1) / 2;
            let above = self.keys[parent];
            if above < key {
                break;
            }
            self.place(hole, above);
            hole = parent;
        }
        self.place(hole, key);
    }

    /// Adds the key of a cell not in the list.
    #[inline]
    fn push(&mut self, key: u128) {
        let hole = self.keys.len();
        self.keys.push(key);
        self.sift_up(hole, key);
    }

    /// Lowers the key of a cell in the list to `key` (at most its old key: same cell and `h`,
    /// `f` not larger).
    #[inline]
    fn decrease(&mut self, key: u128) {
        let hole = self.slots[key_flat(key)] as usize;
        self.sift_up(hole, key);
    }

    /// The smallest key, removed. Floyd's deletion: the root's hole moves down along the smaller
    /// children to the bottom, then the last key sifts up from there (it usually belongs near
    /// the bottom: one comparison per level on the way down instead of two).
    #[inline]
    fn pop(&mut self) -> Option<u128> {
        let last = self.keys.pop()?;
        let Some(&top) = self.keys.first() else {
            return Some(last);
        };
        let mut hole = 0;
        let mut child = 1;
        while let Some(pair) = self.keys.get(child..child + 2) {
            let smaller = child + (pair[1] < pair[0]) as usize;
            self.place(hole, self.keys[smaller]);
            hole = smaller;
            child = 2 * hole + 1;
        }
        if let Some(&key) = self.keys.get(child) {
            self.place(hole, key);
            hole = child;
        }
        self.sift_up(hole, last);
        Some(top)
    }
}

/// One search: the node array, the open list and what every expansion reads.
struct Search<'a> {
    nodes: &'a mut [Node],
    open: &'a mut OpenList,
    risk: &'a [f32],
    config: &'a RiskAStarConfig,
    stamp: u32,
    /// Move lengths [m]: orthogonal, diagonal.
    step: [f64; 2],
    /// The goal cell `(x, y)`.
    goal: (usize, usize),
    /// Toward a target off the grid: its position in cell coordinates (cell `(x, y)`'s centre
    /// at `(x, y)`); the goal is then the virtual node past the last cell (module docs,
    /// "Toward a target off the grid").
    exit: Option<(f64, f64)>,
    /// The border cell the virtual node was last improved from, and that cell's `g`.
    exit_from: (usize, f64),
    /// `λ·res` (or `res` with the additive model): the heuristic per cell of octile distance.
    h_scale: f64,
    /// Per cell, the moves that enter it unseen (bit `k` for move `k`); empty: none.
    unseen: &'a [u8],
    /// What such an entry adds to a cell's cost [1/m].
    unseen_extra: f64,
    /// The clearance prices (empty: none) and what one unit costs [1/m].
    clearance: &'a [f32],
    clearance_unit: f64,
}

impl Search<'_> {
    /// The node of cell `i`, initialised (cost computed, not reached, open) on first touch.
    #[inline(always)]
    fn touch(&mut self, i: usize) -> &mut Node {
        let node = &mut self.nodes[i];
        if node.stamp != self.stamp {
            let extra = if self.clearance.is_empty() { 0.0 } else { f64::from(self.clearance[i]) * self.clearance_unit };
            *node = Node { g: f64::INFINITY, cost: self.config.cell_cost(self.risk[i]) + extra, stamp: self.stamp, parent: NO_PARENT };
        }
        node
    }

    /// `h` of cell `(x, y)`: `h_scale·octile`, from integer distances (exact in `f64`); toward
    /// a target off the grid, `h_scale·euclid` to the target.
    #[inline(always)]
    fn heuristic(&self, x: usize, y: usize) -> f64 {
        if let Some((tx, ty)) = self.exit {
            return self.h_scale * (x as f64 - tx).hypot(y as f64 - ty);
        }
        // Sides are at most MAX_SIDE = 2^16 cells: the distances fit a u32.
        let (dx, dy) = (x.abs_diff(self.goal.0) as u32, y.abs_diff(self.goal.1) as u32);
        self.h_scale * (f64::from(dx.max(dy)) + (std::f64::consts::SQRT_2 - 1.0) * f64::from(dx.min(dy)))
    }

    /// Tries move `k` from a cell of cost `g_a` and cell cost `cost_a` to cell `b` = `(bx, by)`
    /// (inside the grid): if the move lowers `b`'s `g`, improves `b` and adds its key to the open
    /// list or lowers the key there. Returns whether
    /// `b` is traversable.
    #[inline(always)]
    fn relax(&mut self, g_a: f64, cost_a: f64, k: usize, b: usize, bx: usize, by: usize) -> bool {
        let step = self.step[(k >= 4) as usize];
        let extra = if !self.unseen.is_empty() && self.unseen[b] & (1 << k) != 0 { self.unseen_extra } else { 0.0 };
        let node = self.touch(b);
        let cost_b = node.cost;
        // `+inf` for an untraversable `b`; never below a closed `b`'s CLOSED.
        let g = g_a + step * ((cost_a + cost_b) * 0.5 + extra);
        if g < node.g {
            let open = node.g < f64::INFINITY;
            node.g = g;
            node.parent = k as u8;
            let h = self.heuristic(bx, by);
            let key = open_key(g + h, h, b);
            if open {
                self.open.decrease(key);
            } else {
                self.open.push(key);
            }
        }
        cost_b < f64::INFINITY
    }

    /// A* until the goal is popped or the open list empties; `CUT`: corner cutting allowed.
    fn run<const CUT: bool>(&mut self, nx: usize, ny: usize) -> (PlanStatus, usize) {
        let goal = if self.exit.is_some() { nx * ny } else { self.goal.1 * nx + self.goal.0 };
        let mut expanded = 0;
        while let Some(key) = self.open.pop() {
            let a = key_flat(key);
            // u32 division: cells fit a u32 (MAX_GRID_CELLS).
            let (ax, ay) = ((a as u32 % nx as u32) as usize, (a as u32 / nx as u32) as usize);
            let node = &mut self.nodes[a];
            let (g_a, cost_a) = (node.g, node.cost);
            expanded += 1;
            if a == goal {
                return (PlanStatus::Found, expanded);
            }
            node.g = CLOSED;
            if ax > 0 && ay > 0 && ax + 1 < nx && ay + 1 < ny {
                self.expand_interior::<CUT>(g_a, cost_a, a, ax, ay, nx);
            } else {
                if self.exit.is_some() {
                    self.offer_exit(g_a, a, ax, ay, goal);
                }
                self.expand_border::<CUT>(g_a, cost_a, ax, ay, nx, ny);
            }
        }
        (PlanStatus::NoPath, expanded)
    }

    /// From border cell `a` = `(ax, ay)` of cost `g_a`, the move off the grid straight to the
    /// target: the virtual node `goal` gets `g_a + h(a)` (λ per metre on, the heuristic's own
    /// price) if that is lower, with `h = 0`.
    #[inline(never)]
    fn offer_exit(&mut self, g_a: f64, a: usize, ax: usize, ay: usize, goal: usize) {
        let g = g_a + self.heuristic(ax, ay);
        let node = &mut self.nodes[goal];
        if node.stamp != self.stamp {
            *node = Node { g: f64::INFINITY, cost: 0.0, stamp: self.stamp, parent: NO_PARENT };
        }
        if g < node.g {
            let open = node.g < f64::INFINITY;
            node.g = g;
            self.exit_from = (a, g_a);
            let key = open_key(g, 0.0, goal);
            if open {
                self.open.decrease(key);
            } else {
                self.open.push(key);
            }
        }
    }

    /// Expands cell `a` = `(ax, ay)` away from the border (every neighbour inside the grid): the
    /// moves of [`MOVES`] in order, unrolled.
    #[inline(always)]
    fn expand_interior<const CUT: bool>(&mut self, g_a: f64, cost_a: f64, a: usize, ax: usize, ay: usize, nx: usize) {
        let e = self.relax(g_a, cost_a, 0, a + 1, ax + 1, ay);
        let n = self.relax(g_a, cost_a, 1, a + nx, ax, ay + 1);
        let w = self.relax(g_a, cost_a, 2, a - 1, ax - 1, ay);
        let s = self.relax(g_a, cost_a, 3, a - nx, ax, ay - 1);
        if CUT || (e && n) {
            self.relax(g_a, cost_a, 4, a + nx + 1, ax + 1, ay + 1);
        }
        if CUT || (w && n) {
            self.relax(g_a, cost_a, 5, a + nx - 1, ax - 1, ay + 1);
        }
        if CUT || (w && s) {
            self.relax(g_a, cost_a, 6, a - nx - 1, ax - 1, ay - 1);
        }
        if CUT || (e && s) {
            self.relax(g_a, cost_a, 7, a - nx + 1, ax + 1, ay - 1);
        }
    }

    /// Expands cell `(ax, ay)` on the border: the moves of [`MOVES`] in order, those leaving
    /// the grid skipped.
    #[inline(never)]
    fn expand_border<const CUT: bool>(&mut self, g_a: f64, cost_a: f64, ax: usize, ay: usize, nx: usize, ny: usize) {
        let mut orthogonal_open = [false; 4];
        for (k, &(dx, dy)) in MOVES.iter().enumerate() {
            let (bx, by) = (ax.wrapping_add_signed(dx as isize), ay.wrapping_add_signed(dy as isize));
            // Off the grid, a coordinate wraps to a huge value.
            if bx >= nx || by >= ny {
                continue;
            }
            if k >= 4 && !CUT {
                let (p, q) = CORNERS[k - 4];
                if !(orthogonal_open[p] && orthogonal_open[q]) {
                    continue;
                }
            }
            let traversable = self.relax(g_a, cost_a, k, by * nx + bx, bx, by);
            if k < 4 {
                orthogonal_open[k] = traversable;
            }
        }
    }
}

/// Perception-aware prices for [`RiskAStar::plan_with`] ([`crate::plan::coverage`]): the
/// moves that would enter an unknown cell before the sensor has seen it cost as if the cell's
/// risk were `unseen_risk` instead of the planner's `unknown_risk` (in the cost and in the
/// accumulated risk).
#[derive(Debug, Clone, Copy)]
pub struct EntryPrices<'a> {
    /// One byte per cell, row-major: bit `k` set when move `k` (E, N, W, S, NE, NW, SW, SE)
    /// into the cell enters it unseen ([`crate::plan::coverage::unseen_entries`]).
    pub unseen: &'a [u8],
    /// The risk of an unknown cell entered unseen, in [0, 1] [1/m].
    pub unseen_risk: f64,
    /// Per cell, row-major, the clearance price `k >= 0` (finite): the cell's cost grows by `k`
    /// times the least cell cost (module docs, step 7). Empty: none.
    pub clearance: &'a [f32],
}

impl EntryPrices<'_> {
    /// No prices: no unseen entries, no clearance prices.
    pub const NONE: EntryPrices<'static> = EntryPrices { unseen: &[], unseen_risk: 0.0, clearance: &[] };
}

/// [`EntryPrices`] checked against a grid and turned into per-metre additions.
#[derive(Debug, Clone, Copy)]
struct Entry<'a> {
    unseen: &'a [u8],
    cost_extra: f64,
    hazard_extra: f64,
    /// Clearance prices per cell (empty: none) and what one unit of price costs [1/m].
    clearance: &'a [f32],
    clearance_unit: f64,
}

impl Entry<'_> {
    const NONE: Entry<'static> = Entry { unseen: &[], cost_extra: 0.0, hazard_extra: 0.0, clearance: &[], clearance_unit: 0.0 };

    /// What cell `i`'s clearance price adds to its cost [1/m].
    #[inline(always)]
    fn clearance_cost(&self, i: usize) -> f64 {
        if self.clearance.is_empty() { 0.0 } else { f64::from(self.clearance[i]) * self.clearance_unit }
    }
}

/// The risk-aware A* planner (see the module docs for the exact algorithm).
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
    /// `goal_world` [m]. Errors (naming `start` or `goal`) if a position is not finite or lies
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

    /// Plans from the cell holding `start_world` toward `target_world` [m], which may lie off
    /// the grid: to the border cell `b` whose path cost plus `λ·|b - target|` (the heuristic's
    /// price of the straight line on, [`RiskAStarConfig::min_cell_cost`] per metre) is least
    /// (module docs, "Toward a target off the grid"). The path ends at `b`
    /// ([`PlanOutcome::goal_cell`]); its cost, length and risk are those of the path on the
    /// grid. A target on the grid is planned to as by [`RiskAStar::plan_with`]. Errors (naming
    /// `start` or `target`) if a position is not finite or the start lies off the grid.
    pub fn plan_toward(&mut self, grid: &RiskGrid<'_>, start_world: DVec2, target_world: DVec2, entry: Option<&EntryPrices<'_>>) -> Result<PlanOutcome> {
        let far = crate::frames::MAX_TRANSLATION_M;
        if !(target_world.is_finite() && target_world.x.abs() <= far && target_world.y.abs() <= far) {
            return Err(Error::input("target", format!("must be finite and within {far:e} m of the origin, got ({}, {})", target_world.x, target_world.y)));
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn planner(f: impl FnOnce(&mut RiskAStarConfig)) -> RiskAStar {
        let mut c = RiskAStarConfig::default();
        f(&mut c);
        RiskAStar::new(c).unwrap()
    }

    fn cell(ix: u32, iy: u32) -> CellIndex {
        CellIndex { ix, iy }
    }

    #[test]
    fn toward_a_target_off_the_grid_the_path_leaves_where_the_whole_way_is_cheapest() {
        // 20 x 10 cells of 1 m; a lethal wall across the whole grid at column 15. The target
        // lies beyond the east border at (30, 8): the way on leaves by the north or the south
        // border before the wall, where a stand-in on the segment toward the target is walled
        // off.
        let mut risk = vec![0.0f32; 200];
        for y in 0..10 {
            risk[y * 20 + 15] = 1.0;
        }
        let grid = RiskGrid::new(&risk, 20, 10, 1.0, DVec2::ZERO).unwrap();
        let mut p = planner(|c| c.r_total = 1.0);
        let (start, target) = (DVec2::new(2.5, 2.5), DVec2::new(30.5, 8.5));
        let out = p.plan_toward(&grid, start, target, None).unwrap();
        assert_eq!(out.status, PlanStatus::Found);
        let exit = out.goal_cell;
        assert!(exit.ix < 15 && (exit.iy == 0 || exit.iy == 9), "a border cell before the wall: {exit:?}");
        let path = out.path.as_ref().unwrap();
        assert_eq!(*path.cells.last().unwrap(), exit);
        let on_segment = p.plan(&grid, start, DVec2::new(19.5, 8.5)).unwrap();
        assert_eq!(on_segment.status, PlanStatus::NoPath);
        // A target on the grid is planned to as usual.
        let inside = p.plan_toward(&grid, start, DVec2::new(10.5, 5.5), None).unwrap();
        assert_eq!(inside.goal_cell, cell(10, 5));
        assert!(p.plan_toward(&grid, start, DVec2::new(f64::NAN, 0.0), None).unwrap_err().to_string().contains("`target`"));
        assert!(p.plan_toward(&grid, start, DVec2::new(1e300, 0.0), None).unwrap_err().to_string().contains("`target`"));
    }

    #[test]
    fn the_way_out_is_the_least_over_every_border_cell() {
        // Random risks (some untraversable) on 13 x 9 cells of 0.5 m; targets round the grid.
        // The search's cost to its exit plus λ·|exit - target| equals the least, over every
        // border cell reachable, of a plain search's cost plus the same leg.
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (nx, ny, res) = (13usize, 9usize, 0.5);
        for case in 0..12 {
            let risk: Vec<f32> = (0..nx * ny).map(|_| { let u = next(); if u < 0.15 { 1.0 } else { (u * 0.6) as f32 } }).collect();
            let grid = RiskGrid::new(&risk, nx, ny, res, DVec2::new(-1.0, 2.0)).unwrap();
            let mut p = planner(|c| c.r_total = 1.0);
            let lam = p.config().min_cell_cost();
            let start_cell = cell(6, 4);
            if risk[4 * nx + 6] >= 0.8 {
                continue;
            }
            let start = grid.centre_of(start_cell);
            let angle = case as f64 * 0.53;
            let target = start + 9.0 * DVec2::new(angle.cos(), angle.sin());
            let out = p.plan_toward(&grid, start, target, None).unwrap();
            let mut best = f64::INFINITY;
            for iy in 0..ny as u32 {
                for ix in 0..nx as u32 {
                    if ix != 0 && iy != 0 && ix + 1 != nx as u32 && iy + 1 != ny as u32 {
                        continue;
                    }
                    if let Some(path) = p.plan_cells(&grid, start_cell, cell(ix, iy)).unwrap().path {
                        best = best.min(path.cost + lam * grid.centre_of(cell(ix, iy)).distance(target));
                    }
                }
            }
            match out.path {
                Some(path) => {
                    let got = path.cost + lam * grid.centre_of(out.goal_cell).distance(target);
                    assert!((got - best).abs() < 1e-9, "case {case}: {got} vs {best}");
                    let (cost, _) = p.config().polyline_cost(&grid, &path.points_world).unwrap();
                    assert!((cost - path.cost).abs() < 1e-9);
                }
                None => assert!(best.is_infinite(), "case {case}: no way out found, but {best}"),
            }
        }
    }

    #[test]
    fn defaults_equal_the_committed_config() {
        let text = include_str!("../../../../configs/astar.toml");
        assert_eq!(RiskAStarConfig::from_toml_str(text).unwrap(), RiskAStarConfig::default());
    }

    #[test]
    fn one_diagonal_and_one_straight_move_by_hand() {
        // 3 x 2 grid, res 0.5, λ = 0.1: path (0,0) -> (1,1) -> (2,1) with risks 0.2, 0.5, 0.
        // Costs c = 0.1 - ln(0.8) = 0.3231435513, 0.1 - ln(0.5) = 0.7931471806, 0.1.
        // Diagonal: 0.5·√2·(0.3231435513 + 0.7931471806)/2 = 0.3946683731;
        // straight: 0.5·(0.7931471806 + 0.1)/2 = 0.2232867951; total 0.6179551683.
        let risk = [0.2, 0.9, 0.9, 0.9, 0.5, 0.0];
        let grid = RiskGrid::new(&risk, 3, 2, 0.5, DVec2::new(-1.0, 2.0)).unwrap();
        let mut p = planner(|c| {
            c.lam = 0.1;
            c.r_total = 1.0;
            c.allow_corner_cutting = true;
        });
        let out = p.plan_cells(&grid, cell(0, 0), cell(2, 1)).unwrap();
        assert_eq!(out.status, PlanStatus::Found);
        let path = out.path.unwrap();
        assert_eq!(path.cells, vec![cell(0, 0), cell(1, 1), cell(2, 1)]);
        assert!((path.cost - 0.617_955_168_3).abs() < 1e-8, "{}", path.cost);
        assert!((path.length_m - (0.5 * 2f64.sqrt() + 0.5)).abs() < 1e-12);
        // S = cost - λ·L = 0.6179551683 - 0.1·1.2071067812 = 0.4972444902; R = 1 - e^-S.
        // (Risks are f32: 0.2f32 = 0.2000000030, hence the 1e-8 tolerances.)
        assert!((path.risk_integral - 0.497_244_490_2).abs() < 1e-8);
        assert!((path.accumulated_risk - (1.0 - (-0.497_244_490_2f64).exp())).abs() < 1e-8);
        assert_eq!(path.points_world[0], DVec2::new(-0.75, 2.25));
        assert_eq!(path.points_world[2], DVec2::new(0.25, 2.75));
        // The same polyline priced outside the search: the same cost and risk integral.
        let (cost, integral) = p.config().polyline_cost(&grid, &path.points_world).unwrap();
        assert!((cost - path.cost).abs() < 1e-12 && (integral - path.risk_integral).abs() < 1e-12);
        // Through an untraversable cell (0.9 >= r_inst 0.8), off the grid, or over budget: none.
        assert_eq!(p.config().polyline_cost(&grid, &[DVec2::new(-0.75, 2.25), DVec2::new(-0.25, 2.25)]), None);
        assert_eq!(p.config().polyline_cost(&grid, &[DVec2::new(-0.75, 2.25), DVec2::new(-5.0, 2.25)]), None);
        let tight = RiskAStarConfig { r_total: 0.1, ..*p.config() };
        assert_eq!(tight.polyline_cost(&grid, &path.points_world), None);
        // With entry prices: the move into the last cell (E, from (1, 1) to (2, 1)) entered
        // unseen pays the search's extra, as the search would.
        let mut unseen = vec![0u8; 6];
        unseen[5] = 1 << 0;
        let entry = EntryPrices { unseen: &unseen, unseen_risk: 0.5, clearance: &[] };
        let (priced, _) = p.price_polyline(&grid, &path.points_world, Some(&entry)).unwrap().unwrap();
        let extra = p.config().cell_cost(0.5) - p.config().cell_cost(f32::NAN);
        assert!((priced - (path.cost + 0.5 * extra)).abs() < 1e-9, "{priced} vs {}", path.cost + 0.5 * extra);
        let searched = p.plan_cells_with(&grid, cell(0, 0), cell(2, 1), Some(&entry)).unwrap();
        if searched.path.as_ref().map(|q| &q.cells) == Some(&path.cells) {
            assert!((searched.path.unwrap().cost - priced).abs() < 1e-9);
        }
    }

    #[test]
    fn clearance_prices_move_a_path_off_a_wall_without_adding_risk() {
        // A 30 x 8 grid of 0.1 m cells, row 0 a wall, the start and goal next to it (row 1):
        // without prices the path runs straight along row 1; with a price of 4
        // on rows 1-2 and 2 on row 3 it moves to row 4 and back (a detour of a few cells is
        // cheaper than 2.5 m at up to 5x the cost), its risk unchanged (0), its cost the
        // prices' search cost, and `price_polyline` prices it alike.
        let (nx, ny) = (30, 8);
        let risk: Vec<f32> = (0..nx * ny).map(|i| if i < nx { 1.0 } else { 0.0 }).collect();
        let grid = RiskGrid::new(&risk, nx, ny, 0.1, DVec2::ZERO).unwrap();
        for model in [CostModel::Risk, CostModel::Additive] {
            let mut p = planner(|c| c.cost_model = model);
            let plain = p.plan_cells(&grid, cell(1, 1), cell(28, 1)).unwrap().path.unwrap();
            assert!(plain.cells.iter().all(|c| c.iy == 1), "{model:?}");
            let clearance: Vec<f32> = (0..nx * ny).map(|i| match i / nx { 1 | 2 => 4.0, 3 => 2.0, _ => 0.0 }).collect();
            let entry = EntryPrices { clearance: &clearance, ..EntryPrices::NONE };
            let priced = p.plan_cells_with(&grid, cell(1, 1), cell(28, 1), Some(&entry)).unwrap().path.unwrap();
            assert!(priced.cells.iter().any(|c| c.iy >= 4), "{model:?}: {:?}", priced.cells);
            assert_eq!(priced.risk_integral, 0.0);
            assert!(priced.length_m > plain.length_m);
            let (again, _) = p.price_polyline(&grid, &priced.points_world, Some(&entry)).unwrap().unwrap();
            assert!((again - priced.cost).abs() < 1e-9, "{model:?}: {again} vs {}", priced.cost);
            // A price that is not finite and >= 0, or of the wrong length, is refused by name.
            for bad in [vec![-1.0f32; nx * ny], vec![f32::NAN; nx * ny], vec![0.0f32; 3]] {
                let e = EntryPrices { clearance: &bad, ..EntryPrices::NONE };
                let err = p.plan_cells_with(&grid, cell(1, 1), cell(28, 1), Some(&e)).unwrap_err().to_string();
                assert!(err.contains("clearance"), "{err}");
            }
        }
    }

    #[test]
    fn corner_cutting_rule() {
        // Row 1:  . .   Start S = (0, 0), goal (1, 1), lethal X at (1, 0): without corner
        // Row 0:  S X   cutting the diagonal is refused and the path goes round by (0, 1).
        let risk = [0.0, 1.0, 0.0, 0.0];
        let grid = RiskGrid::new(&risk, 2, 2, 1.0, DVec2::ZERO).unwrap();
        let out = planner(|_| {}).plan_cells(&grid, cell(0, 0), cell(1, 1)).unwrap();
        assert_eq!(out.path.unwrap().cells, vec![cell(0, 0), cell(0, 1), cell(1, 1)]);
        let out = planner(|c| c.allow_corner_cutting = true).plan_cells(&grid, cell(0, 0), cell(1, 1)).unwrap();
        assert_eq!(out.path.unwrap().cells, vec![cell(0, 0), cell(1, 1)]);
        // Both corner cells lethal: no path without corner cutting.
        let risk = [0.0, 1.0, 1.0, 0.0];
        let grid = RiskGrid::new(&risk, 2, 2, 1.0, DVec2::ZERO).unwrap();
        assert_eq!(planner(|_| {}).plan_cells(&grid, cell(0, 0), cell(1, 1)).unwrap().status, PlanStatus::NoPath);
    }

    #[test]
    fn blocked_and_unreachable_are_told_apart() {
        let risk = [0.0, 0.9, 0.0, 0.0, 0.9, 0.0];
        let grid = RiskGrid::new(&risk, 3, 2, 1.0, DVec2::ZERO).unwrap();
        let mut p = planner(|_| {});
        assert_eq!(p.plan_cells(&grid, cell(1, 0), cell(2, 0)).unwrap().status, PlanStatus::StartBlocked);
        assert_eq!(p.plan_cells(&grid, cell(0, 0), cell(1, 1)).unwrap().status, PlanStatus::GoalBlocked);
        let out = p.plan_cells(&grid, cell(0, 0), cell(2, 1)).unwrap();
        assert_eq!((out.status, out.path, out.carrot_world, out.expanded), (PlanStatus::NoPath, None, None, 2));
        // Unknown cells take `unknown_risk`: untraversable when it reaches r_inst.
        let risk = [0.0, f32::NAN, 0.0];
        let grid = RiskGrid::new(&risk, 3, 1, 1.0, DVec2::ZERO).unwrap();
        assert_eq!(p.plan_cells(&grid, cell(0, 0), cell(2, 0)).unwrap().status, PlanStatus::Found);
        let mut q = planner(|c| c.unknown_risk = 0.8);
        assert_eq!(q.plan_cells(&grid, cell(0, 0), cell(2, 0)).unwrap().status, PlanStatus::NoPath);
    }

    #[test]
    fn start_equals_goal() {
        let risk = [0.3; 4];
        let grid = RiskGrid::new(&risk, 2, 2, 1.0, DVec2::new(1.0, 1.0)).unwrap();
        let out = planner(|_| {}).plan(&grid, DVec2::new(1.2, 1.7), DVec2::new(1.9, 1.1)).unwrap();
        let path = out.path.as_ref().unwrap();
        assert_eq!((out.status, path.cells.len(), path.cost, path.length_m, path.accumulated_risk), (PlanStatus::Found, 1, 0.0, 0.0, 0.0));
        assert_eq!(out.carrot_world, Some(DVec2::new(1.5, 1.5)));
    }

    #[test]
    fn carrot_by_hand() {
        let pts = [DVec2::new(0.0, 0.0), DVec2::new(0.5, 0.0), DVec2::new(1.0, 0.5)];
        // 0.5 along the first segment, then 0.5 of the 0.7071 diagonal.
        let c = carrot(&pts, 1.0);
        let t = 0.5 / 0.5f64.hypot(0.5);
        assert!((c - DVec2::new(0.5 + 0.5 * t, 0.5 * t)).length() < 1e-12);
        assert_eq!(carrot(&pts, 5.0), DVec2::new(1.0, 0.5));
        assert_eq!(carrot(&pts[..1], 1.0), DVec2::ZERO);
    }

    #[test]
    fn budget_boundary_is_inclusive() {
        let risk = [0.1f32; 10];
        let grid = RiskGrid::new(&risk, 10, 1, 0.5, DVec2::ZERO).unwrap();
        let probe = planner(|c| c.r_total = 1.0).plan_cells(&grid, cell(0, 0), cell(9, 0)).unwrap();
        let r = probe.path.unwrap().accumulated_risk;
        // 4.5 m at -ln(0.9)/m: R = 1 - 0.9^4.5.
        assert!((r - (1.0 - (1.0 - 0.1f32 as f64).powf(4.5))).abs() < 1e-12, "{r}");
        let at = planner(|c| c.r_total = r).plan_cells(&grid, cell(0, 0), cell(9, 0)).unwrap();
        assert_eq!(at.status, PlanStatus::Found);
        let below = planner(|c| c.r_total = f64::from_bits(r.to_bits() - 1)).plan_cells(&grid, cell(0, 0), cell(9, 0)).unwrap();
        assert_eq!(below.status, PlanStatus::BudgetExceeded);
        assert_eq!(below.path.unwrap().accumulated_risk, r);
        assert_eq!(below.carrot_world, None);
    }

    #[test]
    fn bad_config_and_input_name_the_field() {
        let err = |f: fn(&mut RiskAStarConfig)| {
            let mut c = RiskAStarConfig::default();
            f(&mut c);
            RiskAStar::new(c).unwrap_err().to_string()
        };
        assert!(err(|c| c.lam = 0.0).contains("astar.lam"));
        assert!(err(|c| c.lam = f64::NAN).contains("astar.lam"));
        assert!(err(|c| c.r_inst = 1.5).contains("astar.r_inst"));
        assert!(err(|c| c.r_total = 0.0).contains("astar.r_total"));
        assert!(err(|c| c.carrot_m = -1.0).contains("astar.carrot_m"));
        assert!(err(|c| c.unknown_risk = f64::NAN).contains("astar.unknown_risk"));
        let risk = [0.0f32; 6];
        assert!(RiskGrid::new(&risk, 3, 3, 1.0, DVec2::ZERO).unwrap_err().to_string().contains("`risk`"));
        assert!(RiskGrid::new(&risk[..0], 0, 3, 1.0, DVec2::ZERO).unwrap_err().to_string().contains("empty"));
        assert!(RiskGrid::new(&risk, 3, 2, 0.0, DVec2::ZERO).unwrap_err().to_string().contains("`resolution`"));
        assert!(RiskGrid::new(&risk, 3, 2, 1.0, DVec2::new(f64::NAN, 0.0)).unwrap_err().to_string().contains("`origin`"));
        let negative = [0.0, 0.0, 0.0, 0.0, -0.5, 0.0];
        assert!(RiskGrid::new(&negative, 3, 2, 1.0, DVec2::ZERO).unwrap_err().to_string().contains("row 1, column 1"));
        let grid = RiskGrid::new(&risk, 3, 2, 1.0, DVec2::ZERO).unwrap();
        let mut p = planner(|_| {});
        assert!(p.plan(&grid, DVec2::new(f64::NAN, 0.0), DVec2::ZERO).unwrap_err().to_string().contains("`start`"));
        assert!(p.plan(&grid, DVec2::ZERO, DVec2::new(3.0, 0.5)).unwrap_err().to_string().contains("`goal`"));
        assert!(p.plan(&grid, DVec2::new(-1e-9, 0.5), DVec2::ZERO).unwrap_err().to_string().contains("`start`"));
        assert!(p.plan_cells(&grid, cell(0, 2), cell(0, 0)).unwrap_err().to_string().contains("`start`"));
    }

    #[test]
    fn a_terrain_map_is_planned_on_its_own_cells() {
        use crate::terrain::{GridGeometry, Layer, MapConfig, RiskMap};
        let config = MapConfig { resolution_m: 0.1, size_x_m: 2.0, size_y_m: 1.0 };
        let mut map = RiskMap::zeros(GridGeometry::centred_on(&config, 0.37, -0.21), 0.0);
        let geometry = *map.geometry();
        // A lethal column through the map but for its top row.
        for iy in 0..geometry.ny - 1 {
            map.get_mut(Layer::Risk)[geometry.flat(CellIndex { ix: 12, iy: iy as u32 })] = 1.0;
        }
        let grid = RiskGrid::from_map(&map).unwrap();
        let (start, goal) = (DVec2::new(-0.3, -0.5), DVec2::new(1.05, -0.55));
        let out = planner(|c| c.r_total = 1.0).plan(&grid, start, goal).unwrap();
        assert_eq!(out.status, PlanStatus::Found);
        assert_eq!(Some(out.start_cell), geometry.cell_of(start.x, start.y));
        assert_eq!(Some(out.goal_cell), geometry.cell_of(goal.x, goal.y));
        let path = out.path.unwrap();
        assert!(path.cells.iter().all(|&c| map.get(Layer::Risk)[geometry.flat(c)] < 0.8));
        assert!(path.cells.iter().any(|c| c.iy as usize == geometry.ny - 1), "goes over the wall's top");
        for (c, p) in path.cells.iter().zip(&path.points_world) {
            assert_eq!(*p, geometry.centre_of(*c));
        }
    }

    #[test]
    fn stamps_reuse_the_buffers_across_grids() {
        // A big grid, then a small one, then the big one again: same answers as fresh planners.
        let big: Vec<f32> = (0..400).map(|i| ((i * 37) % 100) as f32 / 120.0).collect();
        let small = [0.0f32, 0.5, 0.2, 0.0];
        let gb = RiskGrid::new(&big, 20, 20, 0.1, DVec2::ZERO).unwrap();
        let gs = RiskGrid::new(&small, 2, 2, 0.1, DVec2::ZERO).unwrap();
        let mut p = planner(|c| c.r_total = 1.0);
        let first = p.plan_cells(&gb, cell(0, 0), cell(19, 19)).unwrap();
        let s = p.plan_cells(&gs, cell(0, 0), cell(1, 1)).unwrap();
        let again = p.plan_cells(&gb, cell(0, 0), cell(19, 19)).unwrap();
        assert_eq!((&first.path, first.expanded), (&again.path, again.expanded));
        let fresh = planner(|c| c.r_total = 1.0).plan_cells(&gs, cell(0, 0), cell(1, 1)).unwrap();
        assert_eq!(s.path, fresh.path);
        // Force the stamp to wrap.
        p.stamp = u32::MAX;
        let wrapped = p.plan_cells(&gb, cell(0, 0), cell(19, 19)).unwrap();
        assert_eq!(wrapped.path, again.path);
    }
}
