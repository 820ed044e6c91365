"""`subterra bench plan`: planning time, subterra against scikit-image / SciPy in the same run.

Risk-aware A* (:class:`subterra.RiskAStar`) on seeded random risk grids
(:func:`random_risk_grid`) of 200x200 and 1000x1000 cells at 0.1 m, from cell (0, 0) to the
opposite corner, against scikit-image's ``MCP_Geometric`` (``find_costs`` to the goal, then
``traceback``) on the same grid: the same cost model (:mod:`subterra.bench.reference.plan`),
so the optimal costs must agree (asserted to 1e-9 relative) and the time ratio is reported.
MCP lets diagonals cut corners, so the compared A* runs with ``allow_corner_cutting=True``;
the default A* (no corner cutting) is timed beside it. ``r_total = 1`` so that every run
returns its path (the search is the same whatever the budget). The random grids carry risk
almost everywhere (about 1% of cells are exactly 0), so the heuristic ``lam * octile`` is weak
and A* expands about half the grid: a hard case. A terrain map is easier: the last case plans
on the coarse map of a simulated ``mine`` scan, to 8 goals 8 m around the robot.

Other planning benchmarks plug in through :data:`EXTRA_CASES`: each is a callable
``(repeats, seed) -> dict`` whose JSON-ready result appears under ``report["extra"][name]``.
The MPC solve benchmark (:func:`subterra.bench.mpc.mpc_case`: ``MpcTracker.solve`` in a
closed loop against the SLSQP reference of :mod:`subterra.bench.reference.mpc`) is
registered there as ``mpc_h20_200x200``.
"""

from __future__ import annotations

import math
import os
import platform
import time
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["EXTRA_CASES", "GRID_SIZES", "RESOLUTION_M", "SplitMix64", "bench_plan", "random_risk_grid"]

#: Sides of the square benchmark grids [cells].
GRID_SIZES = (200, 1000)
#: Cell side of the benchmark grids [m] (the terrain mapper's coarse map).
RESOLUTION_M = 0.1
#: Smooth risk blobs per grid.
BLOBS = 40
#: Lethal rectangles per grid.
OBSTACLES = 30

#: Hook for more planning benchmarks: name -> ``callable(repeats, seed) -> JSON-ready dict``.
#: ``bench_plan`` runs each after the A* cases and reports it under ``report["extra"][name]``.
EXTRA_CASES: dict[str, Callable[[int, int], dict[str, Any]]] = {}


def _mpc_case(repeats: int, seed: int) -> dict[str, Any]:
    from subterra.bench.mpc import mpc_case

    return mpc_case(repeats, seed)


EXTRA_CASES["mpc_h20_200x200"] = _mpc_case


class SplitMix64:
    """SplitMix64 (Steele, Lea, Flood 2014): the few random numbers of :func:`random_risk_grid`,
    drawn identically by ``crates/subterra/benches/astar.rs``, so both benchmarks plan on the
    same grids."""

    MASK = (1 << 64) - 1

    def __init__(self, seed: int) -> None:
        self.state = seed & self.MASK

    def next(self) -> int:
        self.state = (self.state + 0x9E3779B97F4A7C15) & self.MASK
        z = self.state
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & self.MASK
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & self.MASK
        return z ^ (z >> 31)

    def uniform(self, lo: float, hi: float) -> float:
        """Uniform in [lo, hi): the top 53 bits as a fraction."""
        return lo + (hi - lo) * ((self.next() >> 11) * 2.0**-53)


def random_risk_grid(n: int, seed: int = 0) -> np.ndarray:
    """A seeded ``n x n`` float32 risk grid, the same as ``crates/subterra/benches/astar.rs``
    makes (same :class:`SplitMix64` draws in the same order; values equal up to the last bit
    of ``exp``): the hazard ``s = sum a * exp(-|p - c|^2 / 2 sigma^2)`` of :data:`BLOBS`
    Gaussian blobs (centre ``(cx, cy)`` uniform over the grid, sigma in [0.02 n, 0.08 n] cells,
    a in [0.1, 1.5] per metre, cut at 4 sigma; cell centres at ``i + 0.5``), risk
    ``1 - exp(-s)``; then :data:`OBSTACLES` lethal rectangles (risk 1; lower corner
    ``floor(uniform(0, n))``, sides ``floor(uniform(max(1, 0.01 n), max(2, 0.06 n)))`` cells);
    then the ``max(2, floor(0.02 n))``-cell squares at the corners (0, 0) and (n-1, n-1)
    cleared to 0."""
    rng = SplitMix64(seed)
    hazard = np.zeros((n, n))
    for _ in range(BLOBS):
        cx, cy = rng.uniform(0.0, n), rng.uniform(0.0, n)
        sigma = rng.uniform(0.02 * n, 0.08 * n)
        a = rng.uniform(0.1, 1.5)
        x0, x1 = max(0, math.floor(cx - 4 * sigma)), min(n - 1, math.ceil(cx + 4 * sigma))
        y0, y1 = max(0, math.floor(cy - 4 * sigma)), min(n - 1, math.ceil(cy + 4 * sigma))
        x = np.arange(x0, x1 + 1) + 0.5 - cx
        y = np.arange(y0, y1 + 1) + 0.5 - cy
        d2 = x[None, :] * x[None, :] + y[:, None] * y[:, None]
        hazard[y0 : y1 + 1, x0 : x1 + 1] += a * np.exp(-d2 / (2.0 * sigma * sigma))
    risk = (-np.expm1(-hazard)).astype(np.float32)
    lo, hi = max(1.0, 0.01 * n), max(2.0, 0.06 * n)
    for _ in range(OBSTACLES):
        x0, y0 = math.floor(rng.uniform(0.0, n)), math.floor(rng.uniform(0.0, n))
        w, h = math.floor(rng.uniform(lo, hi)), math.floor(rng.uniform(lo, hi))
        risk[y0 : y0 + h, x0 : x0 + w] = 1.0
    clear = min(n, max(2, math.floor(0.02 * n)))
    risk[:clear, :clear] = 0.0
    risk[n - clear :, n - clear :] = 0.0
    return risk


def _summary(seconds: list[float]) -> dict[str, float]:
    ms = np.asarray(seconds, dtype=np.float64) * 1e3
    return {"median_ms": float(np.median(ms)), "min_ms": float(ms.min()), "max_ms": float(ms.max()), "runs": int(ms.size)}


def _time(fn: Callable[[], Any], repeats: int) -> tuple[list[float], Any]:
    """Wall times of ``repeats`` calls after one warm-up call, and the last result."""
    out = fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return times, out


def _astar_case(n: int, repeats: int, seed: int) -> dict[str, Any]:
    from skimage.graph import MCP_Geometric

    import subterra
    from subterra.bench.reference.plan import cell_costs

    risk = random_risk_grid(n, seed)
    start, goal = (0, 0), (n - 1, n - 1)
    params = {"lam": 0.1, "r_inst": 0.8, "unknown_risk": 0.15}
    cutting = subterra.RiskAStar({**params, "r_total": 1.0, "allow_corner_cutting": True})
    default = subterra.RiskAStar({**params, "r_total": 1.0})

    def plan(planner):
        return lambda: planner.plan_cells(risk, start, goal, resolution=RESOLUTION_M)

    t_cut, res_cut = _time(plan(cutting), repeats)
    t_def, res_def = _time(plan(default), repeats)
    core_cut = [plan(cutting)().time_s for _ in range(repeats)]

    # The reference: the cost array, MCP_Geometric's set-up, find_costs to the goal, traceback.
    t0 = time.perf_counter()
    costs, _ = cell_costs(risk, **params)
    costs_s = time.perf_counter() - t0
    sy, sx, gy, gx = start[1], start[0], goal[1], goal[0]

    def mcp():
        t0 = time.perf_counter()
        m = MCP_Geometric(costs, fully_connected=True)
        t1 = time.perf_counter()
        cumulative, _ = m.find_costs([(sy, sx)], [(gy, gx)])
        path = m.traceback((gy, gx))
        return t1 - t0, time.perf_counter() - t1, float(cumulative[gy, gx]) * RESOLUTION_M, len(path)

    mcp()
    runs = [mcp() for _ in range(repeats)]
    mcp_init, mcp_search = [r[0] for r in runs], [r[1] for r in runs]
    mcp_total = [a + b for a, b in zip(mcp_init, mcp_search)]
    mcp_cost = runs[-1][2]
    if not (res_cut.status == "found" and math.isclose(res_cut.cost, mcp_cost, rel_tol=1e-9)):
        raise AssertionError(f"{n}x{n}: A* ({res_cut.status}, cost {res_cut.cost}) disagrees with MCP_Geometric (cost {mcp_cost})")
    astar_ms = _summary(t_cut)["median_ms"]
    lethal = float((risk >= params["r_inst"]).mean())
    return {
        "grid": {"shape": [n, n], "resolution_m": RESOLUTION_M, "seed": seed, "untraversable_fraction": lethal, "start_cell": start, "goal_cell": goal},
        "config": {**params, "r_total": 1.0},
        "astar_corner_cutting": {
            "wall": _summary(t_cut),
            "core_time_s_median_ms": float(np.median(core_cut) * 1e3),
            "cost": res_cut.cost,
            "length_m": res_cut.length_m,
            "accumulated_risk": res_cut.accumulated_risk,
            "path_cells": int(len(res_cut.path_cells)),
            "expanded": res_cut.expanded,
            "expanded_fraction": res_cut.expanded / (n * n),
        },
        "astar_default_no_corner_cutting": {
            "wall": _summary(t_def),
            "cost": res_def.cost,
            "accumulated_risk": res_def.accumulated_risk,
            "expanded": res_def.expanded,
            "expanded_fraction": res_def.expanded / (n * n),
        },
        "mcp_geometric": {
            "cost_array_ms": costs_s * 1e3,
            "init_ms": _summary(mcp_init)["median_ms"],
            "find_costs_and_traceback": _summary(mcp_search),
            "total": _summary(mcp_total),
            "cost": mcp_cost,
            "path_cells": runs[-1][3],
        },
        "same_optimal_cost": True,
        "speedup_vs_mcp_find_costs_and_traceback_median": _summary(mcp_search)["median_ms"] / astar_ms,
        "speedup_vs_mcp_total_median": _summary(mcp_total)["median_ms"] / astar_ms,
    }


def _mine_case(repeats: int, seed: int) -> dict[str, Any]:
    """A* on a terrain map: the coarse map (200x200, 0.1 m) of one simulated OS1-64 scan of the
    ``mine`` scenario (seed ``seed``, sensor 0.7 m up), from the robot to 8 goals on a ring of
    8 m around it (every 45 degrees from its heading). Default config (no corner cutting,
    ``r_total`` 0.5) timed on all 8; the corner-cutting A* (``r_total`` 1) is checked against
    MCP_Geometric (set-up + ``find_costs`` + ``traceback``, one run per goal) and timed on
    every goal it reaches."""
    from skimage.graph import MCP_Geometric

    import subterra
    from subterra.bench.reference.plan import cell_costs
    from subterra.sim import Lidar, World
    from subterra.sim.render import pose_matrix, start_pose
    from subterra.terrain import translation

    world = World.scenario("mine", seed)
    position, yaw, _ = start_pose(world)
    ground = world.ground_height(position[0], position[1]) or 0.0
    world_from_body = pose_matrix(np.array([position[0], position[1], ground]), yaw)
    body_from_sensor = translation(z=0.7)
    points, _ = Lidar("os1_64").scan(world, world_from_body @ body_from_sensor)
    risk_map = subterra.TerrainMapper().update(points, world_from_body=world_from_body, body_from_sensor=body_from_sensor)
    start = (float(position[0]), float(position[1]))
    goals = [(start[0] + 8.0 * math.cos(yaw + a), start[1] + 8.0 * math.sin(yaw + a)) for a in np.radians(np.arange(0, 360, 45))]
    planner = subterra.RiskAStar()
    cutting = subterra.RiskAStar({"r_total": 1.0, "allow_corner_cutting": True})
    times, statuses, expanded = [], [], []
    for goal in goals:
        t, result = _time(lambda goal=goal: planner.plan(risk_map, start, goal), repeats)
        times += t
        statuses.append(result.status)
        expanded.append(result.expanded)
    costs, _ = cell_costs(risk_map.layer("risk"), lam=0.1, r_inst=0.8, unknown_risk=0.15)
    checked = 0
    cut_times, mcp_times = [], []
    for goal in goals:
        t, result = _time(lambda goal=goal: cutting.plan(risk_map, start, goal), repeats)
        if not result.found:
            continue
        cut_times += t
        (sx, sy), (gx, gy) = result.start_cell, result.goal_cell
        t0 = time.perf_counter()
        mcp = MCP_Geometric(costs, fully_connected=True)
        cumulative, _ = mcp.find_costs([(sy, sx)], [(gy, gx)])
        mcp.traceback((gy, gx))
        mcp_times.append(time.perf_counter() - t0)
        reference = float(cumulative[gy, gx]) * risk_map.resolution
        if not math.isclose(result.cost, reference, rel_tol=1e-9):
            raise AssertionError(f"mine goal {goal}: A* cost {result.cost} vs MCP_Geometric {reference}")
        checked += 1
    return {
        "map": {"scenario": "mine", "seed": seed, "shape": list(risk_map.shape), "resolution_m": risk_map.resolution, "points": int(len(points))},
        "start": start,
        "goals": [list(g) for g in goals],
        "statuses": statuses,
        "expanded": expanded,
        "astar_default_per_plan": _summary(times),
        "astar_corner_cutting_per_plan_on_the_checked_goals": _summary(cut_times) if cut_times else None,
        "mcp_geometric_per_plan_on_the_checked_goals": _summary(mcp_times) if mcp_times else None,
        "same_optimal_cost_goals": checked,
        "speedup_vs_mcp_total_median": _summary(mcp_times)["median_ms"] / _summary(cut_times)["median_ms"] if cut_times else None,
    }


def bench_plan(sizes: tuple[int, ...] | None = None, repeats: int = 20, seed: int = 0, mine: bool = True) -> dict[str, Any]:
    """Times the planners on one thread and returns a JSON-ready report: per grid size
    ``astar_<n>x<n>`` for each size (default :data:`GRID_SIZES`): A* with and without corner
    cutting, ``MCP_Geometric`` on the same costs, the speed-ups; with ``mine``,
    ``astar_mine_200x200``: plans on a simulated terrain map (:func:`_mine_case`); and ``extra``
    (:data:`EXTRA_CASES`). Wall times are medians of
    ``repeats`` runs after one warm-up run; the A* wall time includes the Python call and the
    grid's O(cells) check, ``core_time_s`` only the search."""
    import subterra

    sizes = GRID_SIZES if sizes is None else tuple(sizes)
    if repeats < 1 or not sizes or min(sizes) < 2:
        raise ValueError("repeats must be >= 1 and every size >= 2")
    report: dict[str, Any] = {
        "benchmark": "plan",
        "subterra_version": subterra.__version__,
        "machine": {"python": platform.python_version(), "processor": platform.processor() or platform.machine(), "cpus": os.cpu_count()},
        "load_average_before": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "targets_ms": {"astar_200x200": 2.0, "astar_1000x1000": 100.0, "mpc_solve_h20": 2.0},
        "blas_threads_env": {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")},
    }
    for n in sizes:
        report[f"astar_{n}x{n}"] = _astar_case(n, repeats, seed)
    if mine:
        report["astar_mine_200x200"] = _mine_case(repeats, seed)
    report["extra"] = {name: case(repeats, seed) for name, case in EXTRA_CASES.items()}
    report["load_average_after"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    return report
