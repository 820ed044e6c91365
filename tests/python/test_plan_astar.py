"""The risk-aware A* from Python (STEP, Fan et al. 2021): optimal costs against scikit-image's
``MCP_Geometric`` and SciPy's ``csgraph.dijkstra`` (the reference in
``subterra.bench.reference.plan``), paths that never enter untraversable cells, the exact
budget check, shortest paths on riskless grids, the carrot, the outcomes, bad input, a
``RiskMap`` from ``TerrainMapper``, and ``subterra bench plan``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import subterra
from subterra.bench.plan import random_risk_grid
from subterra.bench.reference.plan import cell_costs, graph_plan, mcp_plan, path_metrics
from subterra.errors import ConfigError, InputError, SubterraError
from subterra.terrain import translation

DEFAULTS = {"lam": 0.1, "r_inst": 0.8, "r_total": 0.5, "carrot_m": 1.0, "unknown_risk": 0.15, "allow_corner_cutting": False}


def mixed_grid(rng: np.random.Generator, ny: int, nx: int) -> np.ndarray:
    """float32 risks: zeros, smooth-ish values, lethal cells, unknown (NaN) cells."""
    kind = rng.choice(5, size=(ny, nx), p=[0.35, 0.35, 0.15, 0.05, 0.10])
    values = np.select(
        [kind == 0, kind == 1, kind == 2, kind == 3],
        [0.0, rng.uniform(0.0, 0.6, (ny, nx)), 1.0, np.nan],
        rng.uniform(0.5, 1.0, (ny, nx)),
    )
    return values.astype(np.float32)


def traversable_cells(risk: np.ndarray, r_inst: float, unknown_risk: float) -> np.ndarray:
    """(k, 2) array of (ix, iy) of the traversable cells."""
    cost, _ = cell_costs(risk, lam=1.0, r_inst=r_inst, unknown_risk=unknown_risk)
    iy, ix = np.nonzero(np.isfinite(cost))
    return np.column_stack([ix, iy])


def check_legal(result, risk: np.ndarray, *, r_inst: float, unknown_risk: float, allow_corner_cutting: bool) -> None:
    """Every path cell traversable; moves between 8-neighbours; no forbidden corner cuts."""
    cells = result.path_cells
    r = np.where(np.isnan(risk), unknown_risk, risk.astype(np.float64))
    assert np.all(r[cells[:, 1], cells[:, 0]] < r_inst), "the path enters an untraversable cell"
    steps = np.diff(cells, axis=0)
    assert np.all(np.abs(steps).max(axis=1) == 1)
    if not allow_corner_cutting:
        diagonal = np.abs(steps).sum(axis=1) == 2
        a, b = cells[:-1][diagonal], cells[1:][diagonal]
        assert np.all(r[a[:, 1], b[:, 0]] < r_inst) and np.all(r[b[:, 1], a[:, 0]] < r_inst), "a diagonal cuts a corner"


# ------------------------------------------------------------------ optimality against references


@pytest.mark.parametrize("seed", range(8))
def test_cost_equals_mcp_geometric_with_corner_cutting(seed):
    rng = np.random.default_rng(seed)
    ny, nx = rng.integers(5, 60, 2)
    risk = mixed_grid(rng, ny, nx) if seed % 2 else random_risk_grid(int(nx), seed)
    res = float(rng.uniform(0.05, 0.5))
    params = {"lam": float(rng.uniform(0.02, 1.0)), "r_inst": float(rng.uniform(0.6, 1.0)), "unknown_risk": 0.2}
    planner = subterra.RiskAStar({**params, "r_total": 1.0, "allow_corner_cutting": True})
    cells = traversable_cells(risk, params["r_inst"], params["unknown_risk"])
    found = 0
    for _ in range(6):
        s, g = (tuple(int(v) for v in cells[i]) for i in rng.integers(0, len(cells), 2))
        result = planner.plan_cells(risk, s, g, resolution=res)
        ref = mcp_plan(risk, s, g, resolution=res, **params)
        if math.isinf(ref["cost"]):
            assert result.status == "no_path" and result.cost is None
            continue
        found += 1
        assert result.status == "found"
        assert result.cost == pytest.approx(ref["cost"], rel=1e-9, abs=1e-12)
        # The path's own cost by the documented formulas is the reported cost.
        m = path_metrics(risk, result.path_cells, resolution=res, **params)
        assert m["cost"] == pytest.approx(result.cost, rel=1e-9, abs=1e-12)
        assert m["length_m"] == pytest.approx(result.length_m, rel=1e-12)
        assert m["accumulated_risk"] == pytest.approx(result.accumulated_risk, rel=1e-9, abs=1e-15)
        check_legal(result, risk, r_inst=params["r_inst"], unknown_risk=0.2, allow_corner_cutting=True)
    assert found > 0


@pytest.mark.parametrize("allow_corner_cutting", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_cost_equals_scipy_dijkstra_on_the_exact_rules(seed, allow_corner_cutting):
    rng = np.random.default_rng(100 + seed)
    ny, nx = rng.integers(3, 50, 2)
    risk = mixed_grid(rng, ny, nx)
    res = float(rng.uniform(0.05, 1.0))
    params = {"lam": float(rng.uniform(0.01, 2.0)), "r_inst": float(rng.uniform(0.5, 1.0)), "unknown_risk": float(rng.uniform(0.0, 0.5))}
    planner = subterra.RiskAStar({**params, "r_total": 1.0, "allow_corner_cutting": allow_corner_cutting})
    origin = tuple(rng.uniform(-50, 50, 2))
    outcomes = set()
    for _ in range(8):
        s, g = (tuple(int(v) for v in (rng.integers(0, nx), rng.integers(0, ny))) for _ in range(2))
        result = planner.plan_cells(risk, s, g, resolution=res, origin=origin)
        ref = graph_plan(risk, s, g, resolution=res, allow_corner_cutting=allow_corner_cutting, **params)
        outcomes.add(result.status)
        if result.status in ("start_blocked", "goal_blocked"):
            r = np.where(np.isnan(risk), params["unknown_risk"], risk)
            blocked = s if result.status == "start_blocked" else g
            assert r[blocked[1], blocked[0]] >= params["r_inst"]
            assert math.isinf(ref["cost"])
        elif result.status == "no_path":
            assert math.isinf(ref["cost"])
            assert result.path_world.shape == (0, 2) and result.carrot is None and result.accumulated_risk is None
        else:
            assert result.status == "found"
            assert result.cost == pytest.approx(ref["cost"], rel=1e-9, abs=1e-12)
            check_legal(result, risk, allow_corner_cutting=allow_corner_cutting, **{k: params[k] for k in ("r_inst", "unknown_risk")})
            # World points are the cell centres under the origin.
            centres = np.asarray(origin) + (result.path_cells + 0.5) * res
            np.testing.assert_allclose(result.path_world, centres, rtol=0, atol=1e-9)
    assert "found" in outcomes


@pytest.mark.parametrize("seed", range(3))
def test_plan_toward_leaves_by_the_cheapest_border_cell(seed):
    # Against the SciPy reference: the least over every border cell of the cost to reach it
    # plus λ per metre of straight line on to a target beyond the grid.
    rng = np.random.default_rng(300 + seed)
    ny, nx, res, origin = 12, 15, 0.4, (-2.0, 1.0)
    risk = mixed_grid(rng, ny, nx)
    params = {"lam": 0.1, "r_inst": 0.8, "unknown_risk": 0.15}
    planner = subterra.RiskAStar({**params, "r_total": 1.0})
    s = next((x, y) for x, y in zip(rng.integers(0, nx, 50), rng.integers(0, ny, 50)) if np.isfinite(risk[y, x]) and risk[y, x] < 0.8)
    start = np.asarray(origin) + (np.asarray(s) + 0.5) * res
    target = start + 12.0 * np.array([math.cos(seed * 2.1), math.sin(seed * 2.1)])
    result = planner.plan_toward(risk, start, target, resolution=res, origin=origin)
    border = [(x, y) for y in range(ny) for x in range(nx) if x in (0, nx - 1) or y in (0, ny - 1)]
    centre = lambda c: np.asarray(origin) + (np.asarray(c) + 0.5) * res  # noqa: E731
    best = min(graph_plan(risk, (int(s[0]), int(s[1])), b, resolution=res, allow_corner_cutting=False, **params)["cost"]
               + params["lam"] * float(np.linalg.norm(centre(b) - target)) for b in border)
    if math.isinf(best):
        assert result.status == "no_path"
        return
    assert result.status == "found"
    b = result.goal_cell
    assert b[0] in (0, nx - 1) or b[1] in (0, ny - 1)
    assert result.cost + params["lam"] * float(np.linalg.norm(centre(b) - target)) == pytest.approx(best, rel=1e-9)
    np.testing.assert_array_equal(result.path_cells[-1], b)
    # A target on the grid: the plain plan.
    inside = planner.plan_toward(risk, start, start, resolution=res, origin=origin)
    assert inside.status == "found" and inside.length_m == 0.0
    with pytest.raises(InputError, match="target"):
        planner.plan_toward(risk, start, (math.nan, 0.0), resolution=res, origin=origin)


def test_corner_cutting_rule_by_hand():
    # Row 1: . .   From (0, 0) to (1, 1) past the lethal (1, 0): round by (0, 1) unless
    # Row 0: S X   corner cutting is allowed.
    risk = np.array([[0.0, 1.0], [0.0, 0.0]], np.float32)
    strict = subterra.RiskAStar().plan_cells(risk, (0, 0), (1, 1), resolution=1.0)
    assert strict.path_cells.tolist() == [[0, 0], [0, 1], [1, 1]]
    assert strict.length_m == pytest.approx(2.0)
    cutting = subterra.RiskAStar({"allow_corner_cutting": True}).plan_cells(risk, (0, 0), (1, 1), resolution=1.0)
    assert cutting.path_cells.tolist() == [[0, 0], [1, 1]]
    assert cutting.length_m == pytest.approx(math.sqrt(2.0))


def test_cost_by_hand():
    # Two cells 0.5 m apart with risks 0.2 and 0.5, lam 0.1: 0.5 * (0.1 - ln 0.8 + 0.1 - ln 0.5) / 2.
    risk = np.array([[0.2, 0.5]], np.float32)
    result = subterra.RiskAStar({"r_total": 1.0}).plan(risk, (0.1, 0.2), (0.9, 0.4), resolution=0.5)
    r0, r1 = float(np.float32(0.2)), float(np.float32(0.5))
    assert result.cost == pytest.approx(0.5 * (0.2 - math.log(1 - r0) - math.log(1 - r1)) / 2, rel=1e-12)
    integral = 0.5 * (-math.log(1 - r0) - math.log(1 - r1)) / 2
    assert result.risk_integral == pytest.approx(integral, rel=1e-12)
    assert result.accumulated_risk == pytest.approx(1 - math.exp(-integral), rel=1e-12)
    assert result.length_m == 0.5 and result.start_cell == (0, 0) and result.goal_cell == (1, 0)


# ------------------------------------------------------------------ invariants


def test_paths_never_enter_untraversable_cells_on_benchmark_grids():
    risk = random_risk_grid(150, 3)
    for r_inst in (0.3, 0.6, 0.9, 1.0):
        result = subterra.RiskAStar({"r_inst": r_inst, "r_total": 1.0}).plan_cells(risk, (0, 0), (149, 149), resolution=0.1)
        assert result.status in ("found", "no_path")
        if result.found:
            check_legal(result, risk, r_inst=r_inst, unknown_risk=0.15, allow_corner_cutting=False)


def test_budget_rejection_is_exact_at_the_boundary():
    rng = np.random.default_rng(7)
    risk = (rng.uniform(0.0, 0.3, (30, 40))).astype(np.float32)
    probe = subterra.RiskAStar({"r_total": 1.0}).plan(risk, (0.05, 0.05), (3.9, 2.9), resolution=0.1)
    r = probe.accumulated_risk
    assert 0.0 < r < 1.0
    at = subterra.RiskAStar({"r_total": r}).plan(risk, (0.05, 0.05), (3.9, 2.9), resolution=0.1)
    assert at.status == "found" and at.carrot is not None
    below = subterra.RiskAStar({"r_total": float(np.nextafter(r, 0.0))}).plan(risk, (0.05, 0.05), (3.9, 2.9), resolution=0.1)
    assert below.status == "budget_exceeded" and not below.found
    # The rejected least-cost path is still reported; no carrot to follow.
    assert below.accumulated_risk == r and below.cost == probe.cost and below.carrot is None
    np.testing.assert_array_equal(below.path_cells, probe.path_cells)


@pytest.mark.parametrize("lam", [1e-3, 0.1, 5.0])
@pytest.mark.parametrize("allow_corner_cutting", [False, True])
def test_zero_risk_grids_give_shortest_paths(lam, allow_corner_cutting):
    rng = np.random.default_rng(int(lam * 1000))
    planner = subterra.RiskAStar({"lam": lam, "allow_corner_cutting": allow_corner_cutting})
    risk = np.zeros((40, 70), np.float32)
    for _ in range(10):
        (sx, gx), (sy, gy) = rng.integers(0, 70, 2), rng.integers(0, 40, 2)
        result = planner.plan_cells(risk, (sx, sy), (gx, gy), resolution=0.2)
        dx, dy = abs(int(gx) - int(sx)), abs(int(gy) - int(sy))
        octile = 0.2 * (max(dx, dy) + (math.sqrt(2) - 1) * min(dx, dy))
        assert result.status == "found" and result.accumulated_risk == 0.0
        assert result.length_m == pytest.approx(octile, rel=1e-12, abs=1e-12)
        assert result.cost == pytest.approx(lam * octile, rel=1e-12, abs=1e-15)
    # Walls on a riskless grid: the length is the geodesic (the graph's with lam = 1 and r = 0).
    walls = np.zeros((40, 70), np.float32)
    walls[5:40, 20] = 1.0
    walls[0:35, 45] = 1.0
    result = planner.plan_cells(walls, (2, 20), (68, 20), resolution=0.2)
    ref = graph_plan(walls, (2, 20), (68, 20), resolution=0.2, lam=1.0, r_inst=0.8, unknown_risk=0.15, allow_corner_cutting=allow_corner_cutting)
    assert result.length_m == pytest.approx(ref["cost"], rel=1e-12)
    assert result.cost == pytest.approx(lam * ref["cost"], rel=1e-12)


def test_small_lam_trades_length_for_risk_and_large_lam_the_reverse():
    # A risky band across the straight line, with a riskless detour around its end.
    risk = np.zeros((30, 60), np.float32)
    risk[0:25, 28:32] = 0.3
    short = subterra.RiskAStar({"lam": 100.0, "r_total": 1.0}).plan_cells(risk, (5, 5), (55, 5), resolution=0.1)
    safe = subterra.RiskAStar({"lam": 0.01, "r_total": 1.0}).plan_cells(risk, (5, 5), (55, 5), resolution=0.1)
    assert short.length_m == pytest.approx(5.0) and short.accumulated_risk > 0
    assert safe.accumulated_risk == 0.0 and safe.length_m > short.length_m


def test_carrot_along_the_path():
    risk = np.zeros((5, 40), np.float32)
    planner = subterra.RiskAStar({"carrot_m": 1.0})
    # Straight along x from the centre of (0, 2) to (30, 2): carrot 1 m ahead.
    result = planner.plan(risk, (0.05, 0.25), (3.05, 0.25), resolution=0.1)
    assert result.carrot == pytest.approx((1.05, 0.25))
    # Interpolated between centres, and the goal when the path is shorter than carrot_m.
    assert subterra.RiskAStar({"carrot_m": 0.37}).plan(risk, (0.05, 0.25), (3.05, 0.25), resolution=0.1).carrot == pytest.approx((0.42, 0.25))
    assert subterra.RiskAStar({"carrot_m": 10.0}).plan(risk, (0.05, 0.25), (3.05, 0.25), resolution=0.1).carrot == pytest.approx((3.05, 0.25))
    # A pure diagonal: the carrot lies on it, 1 m from the start centre.
    square = np.zeros((30, 30), np.float32)
    diag = planner.plan(square, (0.05, 0.05), (2.95, 2.95), resolution=0.1)
    assert diag.carrot == pytest.approx((0.05 + 1 / math.sqrt(2), 0.05 + 1 / math.sqrt(2)))
    # Start == goal: the carrot is that cell's centre.
    same = planner.plan(square, (1.01, 1.01), (1.09, 1.02), resolution=0.1)
    assert same.found and same.length_m == 0.0 and same.carrot == pytest.approx((1.05, 1.05))
    assert same.path_cells.tolist() == [[10, 10]]


def test_outcomes_are_told_apart():
    risk = np.zeros((10, 10), np.float32)
    risk[:, 5] = 1.0  # a wall
    risk[2, 2] = np.nan
    planner = subterra.RiskAStar()
    assert planner.plan_cells(risk, (5, 3), (0, 0), resolution=0.1).status == "start_blocked"
    assert planner.plan_cells(risk, (0, 0), (5, 3), resolution=0.1).status == "goal_blocked"
    blocked = planner.plan_cells(risk, (0, 0), (9, 9), resolution=0.1)
    assert blocked.status == "no_path" and blocked.expanded == 50
    assert blocked.path_cells.shape == (0, 2) and blocked.length_m is None and blocked.cost is None
    # NaN is unknown: traversable at unknown_risk < r_inst, untraversable at >= r_inst.
    assert planner.plan_cells(risk, (2, 2), (0, 0), resolution=0.1).status == "found"
    assert subterra.RiskAStar({"unknown_risk": 0.8}).plan_cells(risk, (2, 2), (0, 0), resolution=0.1).status == "start_blocked"
    assert "no_path" in repr(blocked)


def test_deterministic_and_buffers_reused_across_grid_sizes():
    big, small = random_risk_grid(120, 1), random_risk_grid(30, 2)
    planner = subterra.RiskAStar({"r_total": 1.0})
    first = planner.plan_cells(big, (0, 0), (119, 119), resolution=0.1)
    planner.plan_cells(small, (0, 0), (29, 29), resolution=0.1)
    again = planner.plan_cells(big, (0, 0), (119, 119), resolution=0.1)
    fresh = subterra.RiskAStar({"r_total": 1.0}).plan_cells(big, (0, 0), (119, 119), resolution=0.1)
    for other in (again, fresh):
        np.testing.assert_array_equal(other.path_cells, first.path_cells)
        assert (other.cost, other.expanded) == (first.cost, first.expanded)


def test_array_layouts_and_dtypes_give_the_same_plan():
    risk = random_risk_grid(50, 4)
    planner = subterra.RiskAStar({"r_total": 1.0})
    base = planner.plan_cells(risk, (0, 0), (49, 49), resolution=0.1)
    for variant in (risk.astype(np.float64), np.asfortranarray(risk), risk.T.copy().T, risk[::1, ::1]):
        other = planner.plan_cells(variant, (0, 0), (49, 49), resolution=0.1)
        assert other.cost == base.cost
    strided = np.zeros((50, 100), np.float32)
    strided[:, ::2] = risk
    assert planner.plan_cells(strided[:, ::2], (0, 0), (49, 49), resolution=0.1).cost == base.cost


# ------------------------------------------------------------------ bad input


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"lam": 0.0}, "lam"),
        ({"lam": -1.0}, "lam"),
        ({"lam": math.nan}, "lam"),
        ({"lam": math.inf}, "lam"),
        ({"lam": 1e300}, "lam"),
        ({"lam": "small"}, "lam"),
        ({"r_inst": 0.0}, "r_inst"),
        ({"r_inst": 1.5}, "r_inst"),
        ({"r_total": 0.0}, "r_total"),
        ({"r_total": 2.0}, "r_total"),
        ({"r_total": math.nan}, "r_total"),
        ({"carrot_m": 0.0}, "carrot_m"),
        ({"carrot_m": -1.0}, "carrot_m"),
        ({"unknown_risk": -0.1}, "unknown_risk"),
        ({"unknown_risk": 1.1}, "unknown_risk"),
        ({"unknown_risk": math.nan}, "unknown_risk"),
        ({"allow_corner_cutting": "yes"}, "allow_corner_cutting"),
    ],
)
def test_bad_config_raises_config_error_naming_it(kwargs, name):
    with pytest.raises(ConfigError, match=name) as info:
        subterra.RiskAStar(kwargs)
    assert isinstance(info.value, SubterraError) and isinstance(info.value, ValueError)


def test_config_getters_and_defaults():
    planner = subterra.RiskAStar()
    assert {k: getattr(planner, k) for k in DEFAULTS} == DEFAULTS
    assert "lam=0.1" in repr(planner)


GOOD = np.zeros((10, 20), np.float32)


@pytest.mark.parametrize(
    ("risk", "start", "goal", "kwargs", "name"),
    [
        (GOOD.astype(np.int32), (0.05, 0.05), (1.0, 0.5), {"resolution": 0.1}, "risk"),
        (GOOD.astype(complex), (0.05, 0.05), (1.0, 0.5), {"resolution": 0.1}, "risk"),
        (np.zeros((2, 3, 4), np.float32), (0.05, 0.05), (0.1, 0.1), {"resolution": 0.1}, "risk"),
        (np.zeros(10, np.float32), (0.05, 0.05), (0.1, 0.1), {"resolution": 0.1}, "risk"),
        (np.zeros((0, 5), np.float32), (0.05, 0.05), (0.1, 0.1), {"resolution": 0.1}, "risk"),
        ([[0.0, 0.1]], (0.05, 0.05), (0.1, 0.1), {"resolution": 0.1}, "risk"),
        ("risk", (0.05, 0.05), (0.1, 0.1), {"resolution": 0.1}, "risk"),
        (np.where(np.arange(200).reshape(10, 20) == 57, -0.5, 0.0).astype(np.float32), (0.05, 0.05), (1.0, 0.5), {"resolution": 0.1}, "risk"),
        (GOOD, (0.05, 0.05), (1.0, 0.5), {}, "resolution"),
        (GOOD, (0.05, 0.05), (1.0, 0.5), {"resolution": 0.0}, "resolution"),
        (GOOD, (0.05, 0.05), (1.0, 0.5), {"resolution": -0.1}, "resolution"),
        (GOOD, (0.05, 0.05), (1.0, 0.5), {"resolution": math.nan}, "resolution"),
        (GOOD, (0.05, 0.05), (1.0, 0.5), {"resolution": "fine"}, "resolution"),
        (GOOD, (0.05, 0.05), (1.0, 0.5), {"resolution": 0.1, "origin": (math.nan, 0.0)}, "origin"),
        (GOOD, (0.05, 0.05), (1.0, 0.5), {"resolution": 0.1, "origin": (0.0, 0.0, 0.0)}, "origin"),
        (GOOD, (math.nan, 0.05), (1.0, 0.5), {"resolution": 0.1}, "start"),
        (GOOD, (0.05, math.inf), (1.0, 0.5), {"resolution": 0.1}, "start"),
        (GOOD, (-0.01, 0.05), (1.0, 0.5), {"resolution": 0.1}, "start"),
        (GOOD, (0.05, 0.05, 0.0), (1.0, 0.5), {"resolution": 0.1}, "start"),
        (GOOD, "here", (1.0, 0.5), {"resolution": 0.1}, "start"),
        (GOOD, (0.05, 0.05), (2.0, 0.5), {"resolution": 0.1}, "goal"),
        (GOOD, (0.05, 0.05), (1.0, 1.0), {"resolution": 0.1}, "goal"),
        (GOOD, (0.05, 0.05), None, {"resolution": 0.1}, "goal"),
    ],
)
def test_bad_input_raises_input_error_naming_it(risk, start, goal, kwargs, name):
    with pytest.raises(InputError, match=f"`{name}`") as info:
        subterra.RiskAStar().plan(risk, start, goal, **kwargs)
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize(("start", "goal", "name"), [((-1, 0), (1, 1), "start"), ((0, 0), (20, 0), "goal"), ((0, 0), (0.5, 1), "goal"), ((0, 0, 0), (1, 1), "start")])
def test_bad_cells_raise_input_error_naming_them(start, goal, name):
    with pytest.raises(InputError, match=f"`{name}`"):
        subterra.RiskAStar().plan_cells(GOOD, start, goal, resolution=0.1)


# ------------------------------------------------------------------ a RiskMap from the terrain mapper

SENSOR_HEIGHT_M = 0.7
#: A 0.4 m wall-like box across the straight line from START to GOAL [m, world = body].
BOX_X, BOX_Y, BOX_H = (3.0, 3.6), (-1.0, 1.0), 0.4
START, GOAL = (0.5, 0.0), (5.5, 0.0)


@pytest.fixture(scope="module")
def box_map():
    step = 0.05
    g = np.arange(-7.0, 7.0 + 1e-9, step)
    x, y = np.meshgrid(g, g)
    ground = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    under = (ground[:, 0] >= BOX_X[0]) & (ground[:, 0] <= BOX_X[1]) & (ground[:, 1] >= BOX_Y[0]) & (ground[:, 1] <= BOX_Y[1])
    xs, ys = np.arange(BOX_X[0], BOX_X[1] + 1e-9, 0.02), np.arange(BOX_Y[0], BOX_Y[1] + 1e-9, 0.02)
    top = np.array([(bx, by, BOX_H) for bx in xs for by in ys])
    points = np.vstack([ground[~under], top]) - [0.0, 0.0, SENSOR_HEIGHT_M]
    return subterra.TerrainMapper().update(points.astype(np.float32), stamp=0.0, body_from_sensor=translation(z=SENSOR_HEIGHT_M))


def test_plans_around_the_lethal_box_of_a_terrain_map(box_map):
    m = box_map
    risk = m.layer("risk")
    assert m.risk_at(3.3, 0.0) == 1.0  # the box is lethal
    planner = subterra.RiskAStar()
    result = planner.plan(m, START, GOAL)
    assert result.status == "found", result
    assert result.start_cell == m.cell_of(*START) and result.goal_cell == m.cell_of(*GOAL)
    # Never in a cell at or above r_inst, and around the box: somewhere beside it |y| > 1 m.
    check_legal(result, risk, r_inst=0.8, unknown_risk=0.15, allow_corner_cutting=False)
    beside = (result.path_world[:, 0] > BOX_X[0]) & (result.path_world[:, 0] < BOX_X[1])
    assert beside.any() and np.all(np.abs(result.path_world[beside, 1]) > BOX_Y[1])
    assert result.length_m > GOAL[0] - START[0] + 0.5  # the detour (straight: 5 m)
    # The same plan from the layer as an array with the map's geometry, and the reference's cost.
    as_array = planner.plan(risk, START, GOAL, resolution=m.resolution, origin=m.origin)
    np.testing.assert_array_equal(as_array.path_cells, result.path_cells)
    np.testing.assert_allclose(as_array.path_world, result.path_world, atol=1e-9)
    ref = graph_plan(risk, result.start_cell, result.goal_cell, resolution=m.resolution, lam=0.1, r_inst=0.8, unknown_risk=0.15, allow_corner_cutting=False)
    assert result.cost == pytest.approx(ref["cost"], rel=1e-9)
    # The carrot is 1 m of path ahead of the start cell's centre, on the path.
    first = result.path_world[0]
    assert result.carrot is not None and math.dist(result.carrot, first) <= 1.0 + 1e-9
    with pytest.raises(InputError, match="`resolution`"):
        planner.plan(m, START, GOAL, resolution=0.1)
    with pytest.raises(InputError, match="`goal`"):
        planner.plan(m, START, (50.0, 0.0))


# ------------------------------------------------------------------ subterra bench plan


def test_bench_plan_reports_the_same_cost_and_runs_extra_cases(tmp_path, monkeypatch):
    from subterra import cli
    from subterra.bench import plan as bench

    monkeypatch.setattr(bench, "GRID_SIZES", (40, 60))
    # Only a stand-in extra case (the MPC case has its own test, tests/python/test_mpc_reference.py).
    monkeypatch.setattr(bench, "EXTRA_CASES", {"dummy": lambda repeats, seed: {"repeats": repeats, "seed": seed}})
    out = tmp_path / "plan.json"
    assert cli.main(["bench", "plan", "--repeats", "2", "--seed", "1", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["benchmark"] == "plan" and report["extra"] == {"dummy": {"repeats": 2, "seed": 1}}
    for n in (40, 60):
        case = report[f"astar_{n}x{n}"]
        assert case["same_optimal_cost"] and case["astar_corner_cutting"]["cost"] == pytest.approx(case["mcp_geometric"]["cost"], rel=1e-9)
        assert case["astar_corner_cutting"]["wall"]["runs"] == 2 and case["speedup_vs_mcp_total_median"] > 0
        assert case["astar_default_no_corner_cutting"]["cost"] >= case["astar_corner_cutting"]["cost"] - 1e-12
    mine = report["astar_mine_200x200"]
    assert len(mine["statuses"]) == 8 and "found" in mine["statuses"] and mine["same_optimal_cost_goals"] >= 1


def test_benchmark_grid_is_seeded():
    a, b = random_risk_grid(80, 5), random_risk_grid(80, 5)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, random_risk_grid(80, 6))
    assert a.dtype == np.float32 and a.min() >= 0.0 and a.max() == 1.0
    assert np.all(a[:2, :2] == 0.0) and np.all(a[-2:, -2:] == 0.0)


def test_additive_baseline_cost_model():
    """The Nav2-style baseline: cost 1 + k·r per metre, R_inst cells blocked, no budget.
    A 0.88-risk band across the grid with a gap at the far side: the risk-aware planner
    (λ = 0.1) walks round through the gap (crossing: 0.4 m x -ln(0.12) = 0.85 > the
    detour's 7.6 m x λ = 0.76), the additive one (k = 2: crossing costs 0.70 extra, the
    detour 7.6) crosses the band, and is not stopped by the budget."""
    risk = np.zeros((40, 40), np.float32)
    risk[:, 19:23] = 0.88
    risk[38:, 19:23] = 0.0  # the gap at the top
    aware = subterra.RiskAStar({"r_inst": 0.9, "r_total": 0.99}).plan(risk, (0.5, 0.5), (3.5, 0.5), resolution=0.1)
    additive = subterra.RiskAStar({"r_inst": 0.9, "r_total": 0.01, "cost_model": "additive"}).plan(risk, (0.5, 0.5), (3.5, 0.5), resolution=0.1)
    assert aware.status == "found" and additive.status == "found"
    assert aware.length_m > 6.0 and additive.length_m < 3.5
    assert additive.accumulated_risk > 0.01  # over the budget, yet found: the baseline has none
    rows = additive.path_cells[:, 1]
    assert (rows == 5).all()  # straight across, on the start's row
    expected = 3.0 + 2.0 * float(np.float32(0.88)) * 0.4  # 3 m of length plus k·r over the band's 0.4 m
    assert additive.cost == pytest.approx(expected, rel=1e-12)
    with pytest.raises(subterra.errors.ConfigError, match="cost_model"):
        subterra.RiskAStar({"cost_model": "nav2"})
    with pytest.raises(subterra.errors.ConfigError, match="additive_weight"):
        subterra.RiskAStar({"cost_model": "additive", "additive_weight": -1.0})
