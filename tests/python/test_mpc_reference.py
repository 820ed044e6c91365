"""``MpcTracker`` against the SLSQP reference of the same optimal control problem
(``subterra.bench.reference.mpc``), and the MPC case of ``subterra bench plan``.

Tolerances. The reference solves its NLP with SLSQP (``ftol`` 1e-13) and iterates the
targets until no input moves by 1e-6; the tracker, allowed 10 QPs with a 1e-6 step
tolerance (``CONVERGED_SOLVER``), solves each QP with Clarabel to 1e-6. Both then sit at the
same fixed point up to about 1e-4 (inputs) and 1e-5 m (positions); the asserted 1e-2 m,
1e-2 m/s and 2e-2 rad/s leave room for the Gauss-Newton SQP's slower last iterations, and
are still far below what a changed weight, bound or reference rule moves the plan (the
``test_a_changed_*`` tests show that each moves it by more than the tolerance).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import subterra
from subterra.bench import mpc as bench_mpc
from subterra.bench.reference import mpc as reference

POSITION_TOL_M = 1e-2
SPEED_TOL_M_S = 1e-2
YAW_RATE_TOL_RAD_S = 2e-2
HEADING_TOL_RAD = 2e-2


def assert_agree(tracker_result, reference_result, name: str) -> dict[str, float]:
    d = bench_mpc.compare(tracker_result, reference_result)
    assert reference_result.converged, f"{name}: the reference did not reach its fixed point"
    assert d["predicted_position_m"] <= POSITION_TOL_M, (name, d)
    assert d["predicted_speed_m_s"] <= SPEED_TOL_M_S, (name, d)
    assert d["predicted_heading_rad"] <= HEADING_TOL_RAD, (name, d)
    assert d["command_speed_m_s"] <= SPEED_TOL_M_S, (name, d)
    assert d["command_yaw_rate_rad_s"] <= YAW_RATE_TOL_RAD_S, (name, d)
    return d


@pytest.fixture(scope="module")
def reference_solutions():
    """The reference's solutions of the seeded cases (seeds 0 and 1), computed once."""
    out = {}
    for seed in (0, 1):
        for name, kwargs in bench_mpc.agreement_cases(seed).items():
            out[(seed, name)] = (kwargs, reference.solve(**kwargs))
    return out


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("name", ["straight", "curved", "risk_band", "off_path"])
def test_converged_tracker_agrees_with_the_reference(reference_solutions, seed, name):
    kwargs, ref = reference_solutions[(seed, name)]
    out = subterra.MpcTracker(bench_mpc.CONVERGED_SOLVER).solve(**kwargs)
    assert out.status == "solved"
    assert_agree(out, ref, f"{name}, seed {seed}")
    # Both keep the hard bounds.
    assert np.all(np.abs(ref.inputs) <= [1.0 + 1e-9, 1.5 + 1e-9])
    np.testing.assert_allclose(ref.reference_points, out.reference_points, atol=POSITION_TOL_M)


def test_the_risk_band_binds_and_both_keep_the_widened_bound(reference_solutions):
    kwargs, ref = reference_solutions[(0, "risk_band")]
    out = subterra.MpcTracker(bench_mpc.CONVERGED_SOLVER).solve(**kwargs)
    # Risk 0.6 -> limit 0.4 m/s; from 0.8 m/s braking at 1 m/s² the bound is max(0.4, 0.8 - 0.1k + 1e-3).
    k = np.arange(1, 21)
    widened = np.maximum(0.4, 0.8 - 0.1 * k + 1e-3)
    np.testing.assert_allclose(ref.speed_limits, 0.4, atol=1e-6)
    np.testing.assert_allclose(out.speed_limits, 0.4, atol=1e-6)
    for v in (ref.predicted[1:, 3], out.predicted[1:, 3]):
        assert np.all(v <= widened + 1e-5)
    # The bound is active: the first steps brake at a_max.
    assert ref.inputs[0, 0] == pytest.approx(-1.0, abs=1e-6) and out.inputs[0][0] == pytest.approx(-1.0, abs=1e-4)


def test_default_tracker_is_near_the_fixed_point_after_warm_steps():
    """The real-time tracker (2 QPs per solve) on the straight case: a few solves along the
    closed loop carry its plan to within a few cm of the converged optimum."""
    kwargs = bench_mpc.agreement_cases(0)["straight"]
    tracker = subterra.MpcTracker()
    state = np.asarray(kwargs["state"], dtype=np.float64)
    last = None
    for _ in range(15):
        out = tracker.solve(state, kwargs["reference_path"])
        last, state = out, reference.step(state, *out.inputs[0], tracker.dt)
    out = tracker.solve(state, kwargs["reference_path"])
    nominal = np.vstack([last.inputs[1:], last.inputs[-1:]])
    ref = reference.solve(state, kwargs["reference_path"], previous_input=last.inputs[0], initial_inputs=nominal)
    d = bench_mpc.compare(out, ref)
    assert d["predicted_position_m"] < 0.05 and d["command_speed_m_s"] < 0.05, d


@pytest.mark.parametrize(
    "config, what",
    [
        ({"weights": {"contour": 5.0}}, "contour weight"),
        ({"weights": {"lag": 3.0}}, "lag weight"),
        ({"weights": {"heading": 0.5}}, "heading weight"),
        ({"weights": {"accel": 1.0}}, "acceleration weight"),
        ({"weights": {"yaw_rate_rate": 2.0}}, "input-rate weight"),
        ({"weights": {"terminal_factor": 1.0}}, "terminal factor"),
        ({"limits": {"max_yaw_rate_rad_s": 0.5}}, "yaw-rate bound"),
        ({"tracking": {"desired_speed_m_s": 0.5}}, "desired speed"),
        ({"tracking": {"tangent_half_window_m": 1.0}}, "tangent window"),
    ],
)
def test_a_changed_problem_is_detected(reference_solutions, config, what):
    """The agreement test has teeth: the reference with one parameter changed is outside the
    tolerances from the tracker with the committed config (on the start beside the S-bend,
    which exercises every term; the smallest miss, the terminal factor, is 1.7x the tolerance)."""
    kwargs, _ = reference_solutions[(0, "off_path")]
    changed = reference.solve(**kwargs, config=config)
    out = subterra.MpcTracker(bench_mpc.CONVERGED_SOLVER).solve(**kwargs)
    d = bench_mpc.compare(out, changed)
    worst = max(d["predicted_position_m"] / POSITION_TOL_M, d["command_yaw_rate_rad_s"] / YAW_RATE_TOL_RAD_S, d["predicted_speed_m_s"] / SPEED_TOL_M_S)
    assert worst > 1.0, f"a changed {what} went unnoticed ({worst:.2f} of the tolerance)"


def test_the_speed_bound_is_detected(reference_solutions):
    kwargs, _ = reference_solutions[(0, "risk_band")]
    changed = reference.solve(**kwargs, config={"limits": {"max_accel_m_s2": 2.0}})
    out = subterra.MpcTracker(bench_mpc.CONVERGED_SOLVER).solve(**kwargs)
    assert bench_mpc.compare(out, changed)["predicted_speed_m_s"] > SPEED_TOL_M_S


def test_reference_gradient_and_step():
    """The adjoint gradient against central differences; the quadrature step against the
    closed form of a straight step and of a constant-speed arc."""
    kwargs = bench_mpc.agreement_cases(3)["curved"]
    ref = reference.solve(**kwargs)
    rng = np.random.default_rng(3)
    for prev in (None, np.array([0.3, -0.2])):
        ref.problem.previous_input = prev
        z = rng.uniform(-1.0, 1.0, 40)
        g = ref.problem.cost(z)[1]
        h = 1e-6
        fd = np.array([(ref.problem.cost(z + h * e, gradient=False) - ref.problem.cost(z - h * e, gradient=False)) / (2 * h) for e in np.eye(40)])
        np.testing.assert_allclose(g, fd, atol=1e-6 * max(1.0, np.abs(fd).max()))
    s = reference.step(np.array([1.0, 2.0, 0.3, 0.5]), 0.7, 0.0, 0.1)
    d = 0.5 * 0.1 + 0.5 * 0.7 * 0.01
    np.testing.assert_allclose(s, [1.0 + d * np.cos(0.3), 2.0 + d * np.sin(0.3), 0.3, 0.57], atol=1e-15)
    v, w, th = 0.8, 1.2, -0.4
    s = reference.step(np.array([0.0, 0.0, th, v]), 0.0, w, 0.1)
    np.testing.assert_allclose(s[:2], [v / w * (np.sin(th + 0.12) - np.sin(th)), v / w * (np.cos(th) - np.cos(th + 0.12))], atol=1e-15)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"state": [0.0, 0.0, 0.0]}, "state must have shape"),
        ({"state": [0.0, np.nan, 0.0, 0.5]}, "state must be finite"),
        ({"reference_path": [[0.0, 0.0]]}, "reference_path must have shape"),
        ({"reference_path": [[1.0, 1.0], [1.0, 1.0]]}, "reference_path has zero length"),
        ({"reference_path": [[0.0, 0.0], [np.inf, 0.0]]}, "reference_path must be finite"),
        ({"desired_speed": 1.5}, "desired_speed must be in"),
        ({"risk": np.zeros((4, 4))}, "risk needs resolution and origin"),
        ({"resolution": 0.1}, "resolution and origin need risk"),
        ({"risk": np.zeros(4), "resolution": 0.1, "origin": (0, 0)}, r"risk must be a non-empty \(ny, nx\)"),
        ({"risk": np.full((4, 4), 1.5), "resolution": 0.1, "origin": (0, 0)}, r"risk values must be in \[0, 1\]"),
        ({"risk": np.eye(4), "resolution": 0.1, "origin": (0, 0)}, "risk has lethal cells"),
        ({"risk": np.zeros((4, 4)), "resolution": -0.1, "origin": (0, 0)}, "resolution must be > 0"),
        ({"risk": np.zeros((4, 4)), "resolution": 0.1, "origin": (0, 0, 0)}, "origin must have shape"),
        ({"previous_input": [0.0]}, "previous_input must have shape"),
        ({"initial_inputs": np.zeros((19, 2))}, "initial_inputs must have shape"),
        ({"config": {"weights": {"contuor": 1.0}}}, "unknown key `weights.contuor`"),
        ({"config": {"weights": 1.0}}, "`weights` must be a table"),
        ({"config": "mpc.toml"}, "config must be a dict"),
    ],
)
def test_reference_bad_inputs_name_the_argument(kwargs, match):
    args = {"state": [0.0, 0.0, 0.0, 0.5], "reference_path": [[0.0, 0.0], [5.0, 0.0]], **kwargs}
    with pytest.raises(ValueError, match=match):
        reference.solve(**args)


def test_bench_scene_matches_the_rust_bench():
    risk = bench_mpc.bench_risk()
    assert risk.shape == (200, 200) and risk.dtype == np.float32
    def cell(x: float, y: float) -> tuple[int, int]:
        return int((y - bench_mpc.ORIGIN[1]) / 0.1), int((x - bench_mpc.ORIGIN[0]) / 0.1)

    # (3.05, 0.05) lies in the band (2.8 <= x < 3.3), (2.25, -1.0) in the first block, (2.05, 0.05) in neither.
    assert risk[cell(3.05, 0.05)] == 0.5 and risk[cell(2.25, -1.0)] == 1.0 and risk[cell(2.05, 0.05)] < 0.25
    assert not np.any(bench_mpc.bench_risk(lethal=False) >= 0.9)
    path = bench_mpc.bench_path()
    assert path.shape == (79, 2) and np.allclose(np.hypot(*np.diff(path, axis=0).T), 0.1, atol=1e-4)


def test_bench_case_reports_the_fields():
    case = bench_mpc.mpc_case(1, 0)
    for variant in ("no_lethal", "with_lethal"):
        v = case[variant]
        assert v["python_wall"]["runs"] == bench_mpc.RUN_STEPS and v["python_wall"]["median_ms"] > 0
        assert sum(v["statuses"].values()) == bench_mpc.RUN_STEPS and 1 <= v["qps_per_solve_mean"] <= 2
    assert case["no_lethal"]["statuses"].get("solved", 0) >= bench_mpc.RUN_STEPS - 2
    ref = case["reference_slsqp_no_lethal"]
    assert ref["wall"]["runs"] == 1 and ref["converged"] == 1
    assert case["speedup_vs_reference_median"] > 1.0
    assert case["target_ms"] == 2.0 and isinstance(case["target_met"], bool)
    assert set(case["agreement_converged"]) == {"straight", "curved", "risk_band", "off_path"}
    m = case["agreement_converged_max"]
    assert m["predicted_position_m"] <= POSITION_TOL_M and m["predicted_speed_m_s"] <= SPEED_TOL_M_S
    solvers = case["qp_solvers"]
    assert solvers["qps"] == bench_mpc.RUN_STEPS and solvers["banded"]["statuses"] == ["solved"]
    assert solvers["clarabel"]["max_difference_from_banded"] < 1e-3
    if "osqp_default" in solvers:
        assert solvers["osqp_default"]["per_qp"]["runs"] == bench_mpc.RUN_STEPS
        assert set(solvers["banded_faster_than_warm_osqp"]) == set(bench_mpc.OSQP_VARIANTS)
    json.dumps(case)


def test_bench_plan_prints_the_mpc_case(tmp_path, monkeypatch, capsys):
    from subterra import cli
    from subterra.bench import plan as bench

    monkeypatch.setattr(bench, "GRID_SIZES", (20,))
    monkeypatch.setattr(bench, "_mine_case", lambda repeats, seed: {"skipped": True})
    # One agreement case keeps this test short (all four run in the test above).
    cases = bench_mpc.agreement_cases
    monkeypatch.setattr(bench_mpc, "agreement_cases", lambda seed: {"risk_band": cases(seed)["risk_band"]})
    out = tmp_path / "plan.json"
    assert cli.main(["bench", "plan", "--repeats", "1", "--out", str(out)]) == 0
    printed = json.loads(capsys.readouterr().out)
    case = printed["extra"]["mpc_h20_200x200"]
    assert case["no_lethal"]["python_wall"]["runs"] == bench_mpc.RUN_STEPS and list(case["agreement_converged"]) == ["risk_band"]
    assert json.loads(out.read_text())["extra"]["mpc_h20_200x200"]["target_ms"] == 2.0
