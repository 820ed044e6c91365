"""Risk-aware A*'s optimal cost by off-the-shelf shortest-path codes: the reference for parity
tests and benchmarks.

The Rust planner (``crates/subterra/src/plan/astar.rs``) documents its cost model exactly;
this module rebuilds it from that documentation:

* :func:`cell_costs`: per-cell cost ``c = lam - ln(1 - r)`` [1/m] in float64 from the float32
  risks (NaN -> ``unknown_risk``; ``r >= r_inst`` -> ``inf``, untraversable; ``r`` clamped to
  at most ``1 - 2**-24``), and the hazard ``rho = -ln(1 - r)``.
* :func:`mcp_plan`: scikit-image's ``MCP_Geometric`` (8-connected, ``fully_connected=True``)
  on those costs: its move cost ``0.5 * (c(a) + c(b)) * |offset|`` times the resolution is the
  planner's move cost, and it lets a diagonal pass any corner — the planner's
  ``allow_corner_cutting=True``. Returns the optimal cost and a least-cost path.
* :func:`graph_plan`: the grid as an undirected graph with exactly the planner's rules
  (including the default no-corner-cutting rule: a diagonal edge only where both cells at its
  corner are traversable), solved by SciPy's ``scipy.sparse.csgraph.dijkstra``.
* :func:`path_metrics`: cost, length, risk integral and accumulated risk along a given path.

NumPy is imported at module import; SciPy and scikit-image only inside the functions that use
them, so the module imports without them.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["MAX_RISK", "cell_costs", "graph_plan", "mcp_plan", "path_metrics"]

#: Largest risk used in ``-ln(1 - r)``: the largest float32 below 1 (as the Rust planner).
MAX_RISK = 1.0 - 2.0**-24


def cell_costs(risk: np.ndarray, *, lam: float, r_inst: float, unknown_risk: float) -> tuple[np.ndarray, np.ndarray]:
    """``(cost, rho)``, float64 arrays of the risk's shape: ``cost = lam + rho`` [1/m], ``inf``
    where the cell is untraversable (``r >= r_inst`` after NaN -> ``unknown_risk``), and the
    hazard ``rho = -ln(1 - min(r, MAX_RISK))`` (``inf`` where untraversable)."""
    r = np.asarray(risk, dtype=np.float32).astype(np.float64)
    r = np.where(np.isnan(r), unknown_risk, r)
    blocked = r >= r_inst
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = -np.log1p(-np.minimum(r, MAX_RISK))
    rho = np.where(blocked, np.inf, rho)
    return np.where(blocked, np.inf, lam + rho), rho


def mcp_plan(
    risk: np.ndarray,
    start_cell: tuple[int, int],
    goal_cell: tuple[int, int],
    *,
    resolution: float,
    lam: float,
    r_inst: float,
    unknown_risk: float,
) -> dict[str, Any]:
    """Least-cost path by ``skimage.graph.MCP_Geometric`` with corner cutting (its rule).

    Cells are ``(ix, iy)``. Returns ``{"cost": float (inf if unreachable), "cells": (N, 2)
    int array of (ix, iy) or None}``. The start and goal must be traversable.
    """
    from skimage.graph import MCP_Geometric

    cost, _ = cell_costs(risk, lam=lam, r_inst=r_inst, unknown_risk=unknown_risk)
    start, goal = (start_cell[1], start_cell[0]), (goal_cell[1], goal_cell[0])
    mcp = MCP_Geometric(cost, fully_connected=True)
    cumulative, _ = mcp.find_costs([start], [goal])
    total = float(cumulative[goal]) * resolution
    if not math.isfinite(total):
        return {"cost": math.inf, "cells": None}
    path = np.asarray(mcp.traceback(goal), dtype=np.int64)[:, ::-1]
    return {"cost": total, "cells": path}


def _edges(cost: np.ndarray, allow_corner_cutting: bool, resolution: float):
    """Rows, columns and weights of the undirected edges (each once) between traversable cells."""
    ny, nx = cost.shape
    ok = np.isfinite(cost)
    flat = np.arange(nx * ny).reshape(ny, nx)
    rows, cols, weights = [], [], []
    # E, N, NE, NW: every undirected 8-neighbour pair once.
    for dx, dy in ((1, 0), (0, 1), (1, 1), (-1, 1)):
        ys = slice(0, ny - dy)
        xs = slice(max(0, -dx), nx - max(0, dx))
        ys_b = slice(dy, ny)
        xs_b = slice(max(0, dx), nx - max(0, -dx))
        a_ok, b_ok = ok[ys, xs], ok[ys_b, xs_b]
        mask = a_ok & b_ok
        d = resolution * (math.sqrt(2.0) if dx and dy else 1.0)
        if dx and dy and not allow_corner_cutting:
            # The cells at the corner: a + (dx, 0) and a + (0, dy).
            side_x = ok[ys, xs_b]
            side_y = ok[ys_b, xs]
            mask &= side_x & side_y
        rows.append(flat[ys, xs][mask])
        cols.append(flat[ys_b, xs_b][mask])
        weights.append(d * (cost[ys, xs][mask] + cost[ys_b, xs_b][mask]) * 0.5)
    return np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)


def graph_plan(
    risk: np.ndarray,
    start_cell: tuple[int, int],
    goal_cell: tuple[int, int],
    *,
    resolution: float,
    lam: float,
    r_inst: float,
    unknown_risk: float,
    allow_corner_cutting: bool,
) -> dict[str, Any]:
    """Optimal cost by ``scipy.sparse.csgraph.dijkstra`` on the grid graph built to the planner's
    exact rules. Returns ``{"cost": float (inf if unreachable or an end is untraversable)}``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    cost, _ = cell_costs(risk, lam=lam, r_inst=r_inst, unknown_risk=unknown_risk)
    ny, nx = cost.shape
    s, g = start_cell[1] * nx + start_cell[0], goal_cell[1] * nx + goal_cell[0]
    if not (np.isfinite(cost.flat[s]) and np.isfinite(cost.flat[g])):
        return {"cost": math.inf}
    if s == g:
        return {"cost": 0.0}
    rows, cols, weights = _edges(cost, allow_corner_cutting, resolution)
    graph = coo_matrix((weights, (rows, cols)), shape=(nx * ny, nx * ny)).tocsr()
    dist = dijkstra(graph, directed=False, indices=s)
    return {"cost": float(dist[g])}


def path_metrics(
    risk: np.ndarray, cells: np.ndarray, *, resolution: float, lam: float, r_inst: float, unknown_risk: float
) -> dict[str, float]:
    """Cost, length [m], risk integral and accumulated risk along ``cells`` ((N, 2) of (ix, iy))
    by the documented formulas (``inf`` cost if the path enters an untraversable cell)."""
    cost, rho = cell_costs(risk, lam=lam, r_inst=r_inst, unknown_risk=unknown_risk)
    cells = np.asarray(cells, dtype=np.int64)
    c = cost[cells[:, 1], cells[:, 0]]
    h = rho[cells[:, 1], cells[:, 0]]
    step = np.abs(np.diff(cells, axis=0))
    d = resolution * np.where(step.sum(axis=1) == 2, math.sqrt(2.0), 1.0)
    integral = float(np.sum(d * (h[:-1] + h[1:]) * 0.5))
    return {
        "cost": float(np.sum(d * (c[:-1] + c[1:]) * 0.5)),
        "length_m": float(d.sum()),
        "risk_integral": integral,
        "accumulated_risk": float(-np.expm1(-integral)),
    }
