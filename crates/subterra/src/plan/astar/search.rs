//! One A* search over the grid: the per-cell nodes, the moves of the 8-connected grid, the
//! heuristic, the relaxation of a move and the expansion of interior and border cells.

use super::open_list::{key_flat, open_key, OpenList};
use super::{PlanStatus, RiskAStarConfig};

/// The 8 moves `(dx, dy)`: orthogonal first (E, N, W, S), then diagonal (NE, NW, SW, SE).
pub(super) const MOVES: [(i32, i32); 8] = [(1, 0), (0, 1), (-1, 0), (0, -1), (1, 1), (-1, 1), (-1, -1), (1, -1)];
/// For diagonal move `4 + k`, the two orthogonal moves whose cells share its corner.
const CORNERS: [(usize, usize); 4] = [(0, 1), (2, 1), (2, 3), (0, 3)];
/// Parent of the start cell.
const NO_PARENT: u8 = u8::MAX;

/// Search state of one cell; valid only when `stamp` is the planner's current stamp.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Node {
    /// Cost from the start: `+inf` not reached, [`CLOSED`] expanded (the goal keeps its cost).
    pub(super) g: f64,
    /// Cell cost `λ + ρ` (`+inf`: untraversable).
    pub(super) cost: f64,
    pub(super) stamp: u32,
    /// The move (index into `MOVES`) that reached this cell.
    pub(super) parent: u8,
}

/// `g` of an expanded cell: no new cost is below it, so a closed cell is never improved, and an
/// untraversable neighbour's `+inf` cost never improves anything either (one comparison tests
/// all three).
const CLOSED: f64 = f64::NEG_INFINITY;

/// One search: the node array, the open list and what every expansion reads.
pub(super) struct Search<'a> {
    pub(super) nodes: &'a mut [Node],
    pub(super) open: &'a mut OpenList,
    pub(super) risk: &'a [f32],
    pub(super) config: &'a RiskAStarConfig,
    pub(super) stamp: u32,
    /// Move lengths \[m\]: orthogonal, diagonal.
    pub(super) step: [f64; 2],
    /// The goal cell `(x, y)`.
    pub(super) goal: (usize, usize),
    /// Toward a target off the grid: its position in cell coordinates (cell `(x, y)`'s centre
    /// at `(x, y)`); the goal is then the virtual node past the last cell (`RiskAStar`'s docs,
    /// "Toward a target off the grid").
    pub(super) exit: Option<(f64, f64)>,
    /// The border cell the virtual node was last improved from, and that cell's `g`.
    pub(super) exit_from: (usize, f64),
    /// `λ·res` (or `res` with the additive model): the heuristic per cell of octile distance.
    pub(super) h_scale: f64,
    /// Per cell, the moves that enter it unseen (bit `k` for move `k`); empty: none.
    pub(super) unseen: &'a [u8],
    /// What such an entry adds to a cell's cost [1/m].
    pub(super) unseen_extra: f64,
    /// The clearance prices (empty: none) and what one unit costs [1/m].
    pub(super) clearance: &'a [f32],
    pub(super) clearance_unit: f64,
}

impl Search<'_> {
    /// The node of cell `i`, initialised (cost computed, not reached, open) on first touch.
    #[inline(always)]
    pub(super) fn touch(&mut self, i: usize) -> &mut Node {
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
    pub(super) fn heuristic(&self, x: usize, y: usize) -> f64 {
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
    pub(super) fn run<const CUT: bool>(&mut self, nx: usize, ny: usize) -> (PlanStatus, usize) {
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
