"""The MPC tracker from Python (STEP, Fan et al. 2021; docs/mpc.md).

The closed loops below drive a velocity-commanded unicycle simulated in NumPy: each step
the robot takes the returned command ``(v, ω)`` and holds it for ``dt`` (exact arc
integration), which is not the tracker's own model (that one ramps the speed with ``a``),
so the loops also check that the tracker copes with a model mismatch.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tomllib

import subterra
from subterra.bench.reference.mpc import arc_step as plant_step
from subterra.errors import ConfigError, FileFormatError, InputError

REPO = Path(__file__).resolve().parents[2]
RES = 0.1
#: Husky footprint and the default margin (configs/mpc.toml).
LENGTH, WIDTH, MARGIN = 0.99, 0.67, 0.1


def cross_track(p: np.ndarray, path: np.ndarray) -> float:
    """Distance from ``p`` to the polyline ``path`` [m]."""
    a, b = path[:-1], path[1:]
    e = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, e) / np.einsum("ij,ij->i", e, e), 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + t[:, None] * e - p, axis=1)))


def grid(nx: int, ny: int, origin: tuple[float, float], value: float = 0.0) -> np.ndarray:
    return np.full((ny, nx), value, np.float32)


def paint(risk: np.ndarray, origin, box, value: float) -> None:
    """Sets the cells whose centres lie in ``box = (x0, x1, y0, y1)`` to ``value``."""
    ny, nx = risk.shape
    xc = origin[0] + RES * (np.arange(nx) + 0.5)
    yc = origin[1] + RES * (np.arange(ny) + 0.5)
    x0, x1, y0, y1 = box
    risk[np.ix_((yc >= y0) & (yc <= y1), (xc >= x0) & (xc <= x1))] = value


def risk_at(risk: np.ndarray, origin, p) -> float:
    ix = int(np.floor((p[0] - origin[0]) / RES))
    iy = int(np.floor((p[1] - origin[1]) / RES))
    return float(risk[iy, ix])


def footprint_clearance(state: np.ndarray, risk: np.ndarray, origin, lethal: float = 0.9) -> float:
    """Smallest distance from the robot's rectangle to a lethal cell [m] (0 if they touch
    or a cell lies inside): its outline sampled every 5 mm against the cells' squares."""
    x, y, th, _ = state
    c, s = np.cos(th), np.sin(th)
    hl, hw = LENGTH / 2, WIDTH / 2
    corners = np.array([[hl, -hw], [hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
    outline = []
    for a, b in zip(corners[:-1], corners[1:]):
        n = int(np.ceil(np.linalg.norm(b - a) / 0.005)) + 1
        outline.append(a + np.linspace(0, 1, n)[:, None] * (b - a))
    body = np.concatenate(outline)
    world = np.column_stack([x + c * body[:, 0] - s * body[:, 1], y + s * body[:, 0] + c * body[:, 1]])
    iy, ix = np.nonzero(risk >= lethal)
    lo = np.column_stack([origin[0] + RES * ix, origin[1] + RES * iy])
    # Distance from every outline point to every lethal square.
    d = np.maximum(np.maximum(lo[None, :, :] - world[:, None, :], world[:, None, :] - (lo[None, :, :] + RES)), 0.0)
    dist = float(np.min(np.linalg.norm(d, axis=2)))
    # A cell wholly inside the rectangle does not touch its outline.
    centres = lo + RES / 2 - [x, y]
    along, across = centres @ [c, s], centres @ [-s, c]
    if np.any((np.abs(along) <= hl) & (np.abs(across) <= hw)):
        return 0.0
    return dist


def test_committed_config_is_the_default():
    """configs/mpc.toml is MpcConfig::default(); a changed default must change the file."""
    with open(REPO / "configs" / "mpc.toml", "rb") as f:
        committed = tomllib.load(f)
    assert subterra.MpcConfig().to_dict() == committed
    assert subterra.MpcTracker(REPO / "configs" / "mpc.toml").config == subterra.MpcConfig()


def test_result_fields_and_shapes():
    tracker = subterra.MpcTracker()
    out = tracker.solve([0.0, 0.1, 0.0, 0.5], [[0, 0], [5, 0]])
    n = tracker.horizon
    assert (n, tracker.dt) == (20, 0.1)
    assert out.predicted.shape == (n + 1, 4) and out.predicted.dtype == np.float64
    assert out.inputs.shape == (n, 2)
    assert out.speed_limits.shape == (n,) and out.reference_points.shape == (n, 2)
    assert out.status == "solved" and not out.is_backup
    assert out.iterations >= 1 and out.qp_iterations >= out.iterations and out.solve_time_s > 0
    assert out.polygons == [] and out.min_clearance == np.inf
    np.testing.assert_array_equal(out.predicted[0], [0.0, 0.1, 0.0, 0.5])
    v, w = out.command
    assert v == out.predicted[1, 3] and w == out.inputs[0, 1]
    assert "MpcOutput(status=\"solved\"" in repr(out)


def test_closed_loop_tracks_a_curved_reference():
    """An S-bend (two arcs of radius 4 m); the robot starts 0.4 m off it, turned 0.3 rad away.
    After 6 s the cross-track error stays below 2 cm (about 5 mm when this was written) and
    the speed near the desired 0.8 m/s."""
    phi = np.linspace(0, 1.2, 60)
    first = np.column_stack([4 * np.sin(phi), 4 * (1 - np.cos(phi))])
    end, heading = first[-1], 1.2
    centre = end + 4 * np.array([np.sin(heading), -np.cos(heading)])
    second = centre + 4 * np.column_stack([-np.sin(heading - phi[1:]), np.cos(heading - phi[1:])])
    path = np.concatenate([first, second, second[-1] + [[2.0, 0.0]]])
    tracker = subterra.MpcTracker()
    state = np.array([0.0, -0.4, -0.3, 0.0])
    errors, speeds = [], []
    for _ in range(110):
        out = tracker.solve(state, path)
        assert out.status == "solved", out
        state = plant_step(state, out.command, tracker.dt)
        errors.append(cross_track(state[:2], path))
        speeds.append(state[3])
    assert max(errors[60:]) < 0.02, max(errors[60:])
    assert 0.7 < np.median(speeds[60:]) <= 0.8 + 1e-9
    assert errors[0] > 0.3  # it did start off the path


def test_speed_drops_in_a_risky_band():
    """A band of risk 0.6 across the path: inside it the robot drives at most 1.0·(1 - 0.6)
    m/s, and every predicted state keeps v_k <= v_max·(1 - r(p_k))."""
    origin = (-2.0, -3.0)
    risk = grid(160, 60, origin, 0.05)
    paint(risk, origin, (3.0, 4.5, -10, 10), 0.6)
    tracker = subterra.MpcTracker({"tracking": {"desired_speed_m_s": 1.0}})
    state = np.array([0.0, 0.0, 0.0, 1.0])
    in_band = []
    for _ in range(90):
        out = tracker.solve(state, [[-1, 0], [14, 0]], risk=risk, resolution=RES, origin=origin)
        assert not out.is_backup, out
        for p in out.predicted[1:]:
            assert p[3] <= 1.0 * (1 - risk_at(risk, origin, p)) + 1e-3, (p, out)
        state = plant_step(state, out.command, tracker.dt)
        if risk_at(risk, origin, state) == np.float32(0.6):
            in_band.append(state[3])
    assert len(in_band) > 10
    assert max(in_band) <= 0.4 + 1e-3, max(in_band)
    assert min(in_band) > 0.3, "it does not crawl"
    assert state[0] > 6 and state[3] > 0.8, "it speeds up after the band"


def test_obstacle_next_to_the_path_is_not_touched():
    """A 0.6 m block whose edge is 0.2 m from the path, inside the robot's half-width: the
    robot steers around it; its footprint never touches a lethal cell and keeps the 0.1 m
    margin (to 1 cm), and it comes back to the path."""
    origin = (-2.0, -3.0)
    risk = grid(140, 60, origin)
    paint(risk, origin, (4.0, 4.6, 0.2, 0.8), 1.0)
    tracker = subterra.MpcTracker()
    state = np.array([0.0, 0.0, 0.0, 0.8])
    clearances, widest = [], 0.0
    for _ in range(130):
        out = tracker.solve(state, [[-1, 0], [20, 0]], risk=risk, resolution=RES, origin=origin)
        assert out.status == "solved", out
        state = plant_step(state, out.command, tracker.dt)
        if 2.5 < state[0] < 6.5:
            clearances.append(footprint_clearance(state, risk, origin))
        widest = max(widest, -state[1])
    assert clearances and min(clearances) > 0.0
    assert min(clearances) > MARGIN - 0.01, min(clearances)
    assert widest > 0.2
    assert state[0] > 8 and abs(state[1]) < 0.05


def test_backup_stop_when_boxed_in():
    """Full speed into a dead end whose wall is 0.3 m ahead (braking needs 0.5 m): no safe
    plan, so the output is the backup stop — brake at a_max along the heading, ω = 0."""
    origin = (-3.0, -3.0)
    risk = grid(60, 60, origin)
    paint(risk, origin, (0.8, 1.5, -3, 3), 1.0)  # the wall ahead
    paint(risk, origin, (-3, 1.5, 0.5, 1.0), 1.0)  # left side
    paint(risk, origin, (-3, 1.5, -1.0, -0.5), 1.0)  # right side
    out = subterra.MpcTracker().solve([0, 0, 0, 1.0], [[0, 0], [5, 0]], risk=risk, resolution=RES, origin=origin)
    assert out.status == "infeasible_backup" and out.is_backup
    assert out.command == pytest.approx((0.9, 0.0))
    np.testing.assert_array_equal(out.inputs[:, 1], 0.0)
    np.testing.assert_allclose(out.inputs[:10, 0], -1.0)
    np.testing.assert_allclose(out.predicted[10:, 3], 0.0, atol=1e-12)
    np.testing.assert_array_equal(out.predicted[:, 1:3], 0.0)
    assert out.max_obstacle_slack > 0 and len(out.polygons) >= 3


def test_risk_map_gives_the_same_plan_as_its_risk_layer():
    from subterra.terrain import translation

    xy = np.mgrid[-8:8:0.1, -8:8:0.1].reshape(2, -1).T
    ground = np.column_stack([xy, np.full(len(xy), -0.5)]).astype(np.float32)
    box = np.mgrid[2:2.5:0.05, -0.6:-0.1:0.05, -0.5:0.3:0.05].reshape(3, -1).T.astype(np.float32)
    risk_map = subterra.TerrainMapper().update(np.concatenate([ground, box]), stamp=0.0, body_from_sensor=translation(z=0.5))
    path = [[0, 0], [6, 0]]
    a = subterra.MpcTracker().solve([0, 0, 0, 0.5], path, risk_map=risk_map)
    b = subterra.MpcTracker().solve(
        [0, 0, 0, 0.5], path, risk=risk_map.layer("risk"), resolution=risk_map.resolution, origin=risk_map.origin
    )
    assert a.polygons, "the box is lethal"
    np.testing.assert_array_equal(a.predicted, b.predicted)
    assert a.status == b.status


def test_same_calls_give_the_same_bits():
    origin = (-2.0, -3.0)
    risk = grid(100, 60, origin, 0.1)
    paint(risk, origin, (2.0, 2.5, 0.1, 0.6), 1.0)
    path = np.array([[0, 0], [3, 0.4], [7, -0.4]])

    def run():
        tracker, state, outs = subterra.MpcTracker(), np.array([0, 0, 0, 0.3]), []
        for _ in range(12):
            out = tracker.solve(state, path, risk=risk, resolution=RES, origin=origin)
            outs.append((out.predicted.tobytes(), out.inputs.tobytes(), out.command, out.status, out.max_slack))
            state = plant_step(state, out.command, 0.1)
        return outs

    assert run() == run()


@pytest.mark.parametrize(
    ("kwargs", "error", "argument"),
    [
        ({"state": [0, 0, np.nan, 0]}, InputError, "`state`"),
        ({"state": [0, 0, 0]}, InputError, "`state`"),
        ({"state": [0, 0, 0, 1e9]}, InputError, "`state`"),
        ({"state": "fast"}, InputError, "`state`"),
        ({"reference_path": [[0, 0]]}, InputError, "`reference_path`"),
        ({"reference_path": [[0, 0], [0, 0]]}, InputError, "`reference_path`"),
        ({"reference_path": [0, 1, 2]}, InputError, "`reference_path`"),
        ({"reference_path": [[0, 0], [np.inf, 0]]}, InputError, "`reference_path`"),
        ({"risk": np.zeros((4, 4), np.float32)}, InputError, "`resolution`"),
        ({"risk": np.zeros((4, 4)), "resolution": 0.1}, InputError, "`origin`"),
        ({"risk": np.zeros(4), "resolution": 0.1, "origin": (0, 0)}, InputError, "`risk`"),
        ({"risk": np.full((4, 4), 2.0), "resolution": 0.1, "origin": (0, 0)}, InputError, "`risk`"),
        ({"risk": np.zeros((4, 4)), "resolution": -1.0, "origin": (0, 0)}, InputError, "`resolution`"),
        ({"risk": np.zeros((4, 4)), "resolution": 0.1, "origin": (0, np.nan)}, InputError, "`origin`"),
        ({"resolution": 0.1}, InputError, "`resolution`"),
        ({"risk_map": np.zeros((4, 4))}, InputError, "`risk_map`"),
        ({"desired_speed": -0.5}, InputError, "`desired_speed`"),
        ({"desired_speed": 9.0}, InputError, "`desired_speed`"),
    ],
)
def test_bad_inputs_name_the_argument(kwargs, error, argument):
    call = {"state": [0, 0, 0, 0], "reference_path": [[0, 0], [5, 0]]} | kwargs
    tracker = subterra.MpcTracker()
    with pytest.raises(error, match=argument):
        tracker.solve(call.pop("state"), call.pop("reference_path"), **call)
    # The tracker still works, and the failed call left no trace.
    fresh = subterra.MpcTracker()
    a = tracker.solve([0, 0, 0, 0], [[0, 0], [5, 0]])
    b = fresh.solve([0, 0, 0, 0], [[0, 0], [5, 0]])
    np.testing.assert_array_equal(a.predicted, b.predicted)


@pytest.mark.parametrize(
    ("config", "field"),
    [
        ({"dt_s": 0.0}, "dt_s"),
        ({"horizon": 100000}, "horizon"),
        ({"limits": {"max_accel_m_s2": -1.0}}, "limits.max_accel_m_s2"),
        ({"limits": {"min_speed_m_s": 0.5}}, "limits.min_speed_m_s"),
        ({"weights": {"contour": float("nan")}}, "weights.contour"),
        ({"obstacles": {"margin_m": 1e6}}, "obstacles.margin_m"),
        ({"risk": {"lethal_risk": 1.5}}, "risk.lethal_risk"),
        ({"limits": {"max_speed": 1.0}}, "max_speed"),
    ],
)
def test_absurd_configs_name_the_field(config, field):
    with pytest.raises(ConfigError, match=field):
        subterra.MpcTracker(config)


def test_config_of_the_wrong_type_is_a_config_error():
    with pytest.raises(ConfigError, match="`config`"):
        subterra.MpcTracker(42)
    with pytest.raises(FileFormatError, match="nope.toml"):
        subterra.MpcTracker(REPO / "nope.toml")


def _blocks_case():
    """A curved path with a lethal block reaching into it (obstacle rows in the QP)."""
    s = np.linspace(0.0, 6.0, 61)
    path = np.column_stack([s, 0.4 * np.sin(0.5 * s)])
    origin = (-2.0, -3.0)
    risk = grid(100, 60, origin, 0.1)
    paint(risk, origin, (2.0, 2.5, -0.6, 0.1), 1.0)
    return path, risk, origin


def test_both_qp_solvers_drive_the_same_closed_loop():
    path, risk, origin = _blocks_case()
    runs = {}
    for solver in ("banded", "clarabel"):
        tracker = subterra.MpcTracker({"solver": {"qp_solver": solver}})
        assert tracker.config.to_dict()["solver"]["qp_solver"] == solver
        state = np.array([0.0, 0.0, 0.0, 0.4])
        states = []
        for _ in range(40):
            out = tracker.solve(state, path, risk=risk, resolution=0.1, origin=origin)
            assert not out.is_backup, out
            state = plant_step(state, out.command, tracker.dt)
            states.append(state.copy())
        runs[solver] = np.array(states)
    # Two solvers to 1e-6 on every QP: the same closed loop up to millimetres.
    assert np.max(np.abs(runs["banded"] - runs["clarabel"])) < 5e-3


def test_the_last_qp_can_be_solved_again_by_either_solver():
    path, risk, origin = _blocks_case()
    tracker = subterra.MpcTracker()
    assert tracker.last_qp() is None
    tracker.solve([1.5, 0.0, 0.0, 0.5], path, risk=risk, resolution=0.1, origin=origin)
    qp = tracker.last_qp()
    n = 7 * tracker.horizon
    assert qp["q"].shape == (n,) and qp["p_colptr"].shape == (n + 1,) and qp["equalities"] == 4 * tracker.horizon
    banded = subterra.MpcTracker.solve_qp(qp)
    clarabel = subterra.MpcTracker.solve_qp(qp, solver="clarabel")
    assert banded["status"] == clarabel["status"] == "solved"
    assert np.max(np.abs(banded["z"] - clarabel["z"])) < 1e-3
    assert banded["time_s"] > 0 and banded["iterations"] > 0
    # The dynamics hold at the solution: the first `equalities` rows of A z equal b.
    from scipy import sparse

    a = sparse.csc_matrix((qp["a_nzval"], qp["a_rowval"], qp["a_colptr"]), shape=(len(qp["b"]), n))
    residual = a @ banded["z"] - qp["b"]
    assert np.max(np.abs(residual[: qp["equalities"]])) < 1e-6
    assert np.max(residual[qp["equalities"]:]) < 1e-6


@pytest.mark.parametrize(
    ("change", "argument"),
    [
        (lambda qp: qp.pop("b"), "qp"),
        (lambda qp: qp.__setitem__("b", qp["b"][:-1]), "A` is invalid: column 139: row indices must be increasing and below 219 (the length of `b`)"),
        (lambda qp: qp.__setitem__("p_colptr", qp["p_colptr"][:-1]), "P"),
        (lambda qp: qp.__setitem__("a_rowval", qp["a_rowval"].astype(np.float64)), 'qp["a_rowval"]'),
        (lambda qp: qp.__setitem__("q", np.full_like(qp["q"], np.nan)), "q"),
        (lambda qp: qp.__setitem__("equalities", -1), 'qp["equalities"]'),
        (lambda qp: qp.__setitem__("q", np.broadcast_to(np.zeros(1), (10**9,))), 'qp["q"]'),
    ],
)
def test_a_bad_qp_names_its_part(change, argument):
    tracker = subterra.MpcTracker()
    tracker.solve([0.0, 0.0, 0.0, 0.5], np.array([[0.0, 0.0], [5.0, 0.0]]))
    qp = tracker.last_qp()
    change(qp)
    with pytest.raises(InputError) as error:
        subterra.MpcTracker.solve_qp(qp)
    assert f"argument `{argument}" in str(error.value)


def test_bad_solver_names_are_errors():
    tracker = subterra.MpcTracker()
    tracker.solve([0.0, 0.0, 0.0, 0.5], np.array([[0.0, 0.0], [5.0, 0.0]]))
    with pytest.raises(InputError, match="`solver`"):
        subterra.MpcTracker.solve_qp(tracker.last_qp(), solver="osqp")
    with pytest.raises(InputError, match="`qp`"):
        subterra.MpcTracker.solve_qp([1, 2])
    with pytest.raises(ConfigError, match="qp_solver"):
        subterra.MpcTracker({"solver": {"qp_solver": "osqp"}})


def test_osqp_warm_started_on_the_trackers_qps_finds_the_same_solutions():
    pytest.importorskip("osqp")
    from subterra.bench import mpc as bench_mpc

    qps = bench_mpc.closed_loop_qps()[:4]
    banded = [subterra.MpcTracker.solve_qp(qp)["z"] for qp in qps]
    times, solutions, statuses, fresh = bench_mpc._osqp_run(qps, bench_mpc.OSQP_VARIANTS["osqp_eps1e-5_polished"])
    assert fresh[0] and len(times) == 4 and all(t > 0 for t in times)
    assert all(s.startswith("solved") for s in statuses), statuses
    assert max(float(np.max(np.abs(x - z))) for x, z in zip(solutions, banded)) < 1e-2
