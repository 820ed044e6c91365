"""The MPC solve benchmark of ``subterra bench plan`` (Project target: one solve, horizon 20,
<= 2 ms), registered in :data:`subterra.bench.plan.EXTRA_CASES` as ``mpc_h20_200x200``.

The scene is ``crates/subterra/benches/mpc.rs``'s: a 200 x 200 risk grid at 0.1 m (origin
(-5, -10) m), background risk ``0.125 + 0.075·sin(1.3x)·cos(0.7y)``, a band of risk 0.5 for
``2.8 <= x < 3.3`` m across a reference arc of radius 6 m turning left from the origin
(1.3 rad, points 0.1 m apart), and four lethal blocks (risk 1), one reaching into the path.
The tracker (``configs/mpc.toml`` defaults) runs the closed loop from ``(0, -0.2)`` m, heading
0, 0.5 m/s: each solve warm-started by the last, the robot moved by the exact unicycle step
of the first planned input (as the Rust bench does), restarted (``reset()``) every
:data:`RUN_STEPS` steps. ``repeats`` such runs are timed per variant: ``no_lethal`` (the
blocks removed) and ``with_lethal`` (the full scene).

The reference (:mod:`subterra.bench.reference.mpc`, SLSQP to the fixed point of the same
problem, obstacle-free only) solves at :func:`reference_states` of the first ``no_lethal``
run, from the nominal the tracker started from there (its last plan shifted) and with the
tracker's previous first input, so both solve the same problem. Reported: both median
times and their ratio, and how far the tracker's plan (at most 2 QPs per solve) is from the
reference's converged one: at the first step of the run (``cold_start``: from zero inputs,
where 2 QPs are far from converged), and at the warm-started steps, split by whether the
reference found a true fixed point or had to hold the risk bounds (a stage at the edge of
the risk band: see the reference's notes). ``agreement_converged`` repeats that on the seeded cases of
:func:`agreement_cases` against a tracker allowed to converge (:data:`CONVERGED_SOLVER`):
the same optimum up to the solvers' tolerances.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

__all__ = [
    "CONVERGED_SOLVER",
    "NX",
    "ORIGIN",
    "RESOLUTION_M",
    "RUN_STEPS",
    "START",
    "TARGET_MS",
    "agreement_cases",
    "bench_path",
    "bench_risk",
    "compare",
    "mpc_case",
    "reference_states",
]

#: Cells per side of the benchmark grid, its resolution [m] and origin [m] (benches/mpc.rs).
NX = 200
RESOLUTION_M = 0.1
ORIGIN = (-5.0, -10.0)
#: Closed-loop steps before the run starts again (benches/mpc.rs ``RUN_STEPS``).
RUN_STEPS = 60
#: Start state ``[x, y, θ, v]`` of each run.
START = (0.0, -0.2, 0.0, 0.5)
#: Project target: one MPC solve, horizon 20 [ms].
TARGET_MS = 2.0
#: Lethal blocks ``(x0, x1, y0, y1)`` [m] (benches/mpc.rs).
BLOCKS = ((2.0, 2.5, -1.3, -0.7), (4.0, 4.5, 1.6, 2.1), (5.0, 5.6, 0.6, 1.1), (1.5, 2.0, 0.8, 1.3))
#: A tracker that runs its SQP to convergence: the most QPs the config allows, a step
#: tolerance far below the agreement asked for, and a long line search.
CONVERGED_SOLVER = {"solver": {"sqp_iterations": 10, "step_tolerance": 1e-6, "line_search_steps": 30}}


def bench_path() -> np.ndarray:
    """The reference arc: radius 6 m turning left from the origin along +x, 79 points 0.1 m apart."""
    phi = np.arange(79) * 0.1 / 6.0
    return np.column_stack([6.0 * np.sin(phi), 6.0 * (1.0 - np.cos(phi))])


def bench_risk(lethal: bool = True) -> np.ndarray:
    """The benchmark risk grid ``(200, 200)`` float32 (row ``iy`` along world y); without
    ``lethal`` the four blocks are left out."""
    xc = ORIGIN[0] + RESOLUTION_M * (np.arange(NX) + 0.5)
    yc = ORIGIN[1] + RESOLUTION_M * (np.arange(NX) + 0.5)
    x, y = np.meshgrid(xc, yc)
    risk = 0.125 + 0.075 * np.sin(1.3 * x) * np.cos(0.7 * y)
    risk[(x >= 2.8) & (x < 3.3)] = 0.5
    if lethal:
        for x0, x1, y0, y1 in BLOCKS:
            risk[(x >= x0) & (x < x1) & (y >= y0) & (y < y1)] = 1.0
    return risk.astype(np.float32)


def compare(tracker_result, reference_result) -> dict[str, float]:
    """How far a tracker's plan is from the reference's: first command ``|Δv|`` [m/s] and
    ``|Δω|`` [rad/s], the largest predicted position [m], heading [rad] and speed [m/s]
    differences over the horizon."""
    p, q = np.asarray(tracker_result.predicted), np.asarray(reference_result.predicted)
    (v, w), (rv, rw) = tracker_result.command, reference_result.command
    return {
        "command_speed_m_s": abs(v - rv),
        "command_yaw_rate_rad_s": abs(w - rw),
        "predicted_position_m": float(np.max(np.hypot(*(p[:, :2] - q[:, :2]).T))),
        "predicted_heading_rad": float(np.max(np.abs(p[:, 2] - q[:, 2]))),
        "predicted_speed_m_s": float(np.max(np.abs(p[:, 3] - q[:, 3]))),
    }


def agreement_cases(seed: int = 0) -> dict[str, dict[str, Any]]:
    """Seeded obstacle-free cases: keyword arguments shared by ``MpcTracker.solve`` and
    :func:`subterra.bench.reference.mpc.solve` (a fresh tracker: no previous input).

    ``straight``: a straight path along +x, starting on it at 0.3-0.7 m/s. ``curved``: an
    S-bend, starting near its start. ``risk_band``: the straight path through a band of
    risk 0.6 (limit 0.4 m/s) that the robot, at 0.8 m/s, is in from the start: the widened
    braking bounds bind. ``off_path``: the curved path from 0.4-0.6 m beside it, heading
    off by up to 0.3 rad. The random draws (``numpy.random.default_rng(seed)``) perturb the
    starts."""
    rng = np.random.default_rng(seed)
    straight = np.array([[0.0, 0.0], [8.0, 0.0]])
    s = np.linspace(0.0, 6.0, 61)
    curved = np.column_stack([s, 0.6 * np.sin(s)])
    band = np.full((40, 120), 0.05, np.float32)  # 12 x 4 m from (-2, -2)
    xc = -2.0 + RESOLUTION_M * (np.arange(120) + 0.5)
    band[:, (xc >= -1.0) & (xc < 6.0)] = 0.6
    side = rng.choice([-1.0, 1.0])
    return {
        "straight": {"state": [0.0, rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(0.3, 0.7)], "reference_path": straight},
        "curved": {"state": [0.1, rng.uniform(-0.05, 0.05), rng.uniform(0.4, 0.6), rng.uniform(0.3, 0.6)], "reference_path": curved},
        "risk_band": {"state": [0.0, rng.uniform(-0.05, 0.05), 0.0, 0.8], "reference_path": straight,
                      "risk": band, "resolution": RESOLUTION_M, "origin": (-2.0, -2.0)},
        "off_path": {"state": [0.5, side * rng.uniform(0.4, 0.6), -side * rng.uniform(0.0, 0.3), rng.uniform(0.2, 0.5)], "reference_path": curved},
    }


def reference_states(repeats: int) -> list[int]:
    """Steps of the first ``no_lethal`` run at which the reference solves: ``min(repeats,
    RUN_STEPS)`` steps spread evenly over the run (SLSQP to the fixed point takes about
    a second each on the development machine)."""
    count = min(max(repeats, 1), RUN_STEPS)
    return sorted({int(i) for i in np.linspace(0, RUN_STEPS - 1, count).round()})


_MEASURES = ("command_speed_m_s", "command_yaw_rate_rad_s", "predicted_position_m", "predicted_heading_rad", "predicted_speed_m_s")


def _spread(diffs: list[dict[str, float]]) -> dict[str, Any]:
    """Median and largest of each :func:`compare` measure over ``diffs`` (and the step of the
    largest position difference)."""
    if not diffs:
        return {"states": 0}
    out: dict[str, Any] = {"states": len(diffs), "steps": [d["step"] for d in diffs]}
    for key in _MEASURES:
        values = [d[key] for d in diffs]
        out[key] = {"median": float(np.median(values)), "max": float(max(values))}
    out["worst_position_step"] = max(diffs, key=lambda d: d["predicted_position_m"])["step"]
    return out


def _summary(ms: list[float]) -> dict[str, float]:
    a = np.asarray(ms, dtype=np.float64)
    return {"median_ms": float(np.median(a)), "p90_ms": float(np.percentile(a, 90)), "min_ms": float(a.min()), "max_ms": float(a.max()), "runs": int(a.size)}


def _closed_loop(risk: np.ndarray, repeats: int, at: list[int] | None = None) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """``repeats`` timed closed-loop runs; with ``at``, the first run's problems at those steps
    (state, tracker result, previous first input, the nominal it started from)."""
    import subterra
    from subterra.bench.reference.mpc import step

    path = bench_path()
    tracker = subterra.MpcTracker()
    dt = tracker.dt
    wall, core, qps, ipm, statuses, slack = [], [], [], [], {}, 0.0
    captured = []
    for run in range(repeats + 1):  # run 0 warms up (not timed)
        tracker.reset()
        state = np.array(START, dtype=np.float64)
        last = None
        for k in range(RUN_STEPS):
            t0 = time.perf_counter()
            out = tracker.solve(state, path, risk=risk, resolution=RESOLUTION_M, origin=ORIGIN)
            elapsed = time.perf_counter() - t0
            if run > 0:
                wall.append(elapsed * 1e3)
                core.append(out.solve_time_s * 1e3)
                qps.append(out.iterations)
                ipm.append(out.qp_iterations)
                statuses[out.status] = statuses.get(out.status, 0) + 1
                slack = max(slack, out.max_speed_slack)
            if run == 1 and at is not None and k in at:
                nominal = None if last is None else np.vstack([last.inputs[1:], last.inputs[-1:]])
                captured.append({"step": k, "state": state.copy(), "result": out,
                                 "previous_input": None if last is None else last.inputs[0].copy(), "nominal": nominal})
            state = step(state, *out.inputs[0], dt)
            last = out
    report = {
        "python_wall": _summary(wall),
        "core_solve_time": _summary(core),
        "qps_per_solve_mean": float(np.mean(qps)),
        "interior_point_iterations_per_solve_mean": float(np.mean(ipm)),
        "statuses": statuses,
        "max_speed_slack_m_s": slack,
    }
    return report, captured


#: OSQP settings compared: its defaults (ε = 1e-3), and tolerances near the tracker's (1e-6)
#: with solution polishing. Both warm-started from the previous QP's solution.
OSQP_VARIANTS = {
    "osqp_default": {"eps_abs": 1e-3, "eps_rel": 1e-3, "polishing": False},
    "osqp_eps1e-5_polished": {"eps_abs": 1e-5, "eps_rel": 1e-5, "polishing": True},
}


def closed_loop_qps() -> list[dict[str, Any]]:
    """The QP of the last SQP iteration of every solve of one closed-loop run on the full scene
    (``MpcTracker.last_qp``), in order."""
    import subterra
    from subterra.bench.reference.mpc import step

    tracker = subterra.MpcTracker()
    path, risk = bench_path(), bench_risk(lethal=True)
    state = np.array(START, dtype=np.float64)
    qps = []
    for _ in range(RUN_STEPS):
        out = tracker.solve(state, path, risk=risk, resolution=RESOLUTION_M, origin=ORIGIN)
        qps.append(tracker.last_qp())
        state = step(state, *out.inputs[0], tracker.dt)
    return qps


def _osqp_run(qps: list[dict[str, Any]], settings: dict[str, Any]) -> tuple[list[float], list[np.ndarray], list[str], list[bool]]:
    """One pass of OSQP over ``qps`` in order: a solver set up once per sparsity pattern, then
    updated (``Px``, ``Ax``, ``q``, ``l``, ``u``) and warm-started from the previous solution.
    Per QP: OSQP's own update + solve (+ polish) time [ms] (setup time added when the pattern
    changed), the solution, the status, and whether it needed a new setup."""
    import osqp
    from scipy import sparse

    times, solutions, statuses, fresh = [], [], [], []
    solver, pattern = None, None
    for qp in qps:
        n, m, me = len(qp["q"]), len(qp["b"]), int(qp["equalities"])
        lower = np.concatenate([qp["b"][:me], np.full(m - me, -np.inf)])
        key = (qp["p_colptr"].tobytes(), qp["p_rowval"].tobytes(), qp["a_colptr"].tobytes(), qp["a_rowval"].tobytes(), me)
        extra = 0.0
        if key != pattern:
            solver, pattern = osqp.OSQP(), key
            p = sparse.csc_matrix((qp["p_nzval"], qp["p_rowval"], qp["p_colptr"]), shape=(n, n))
            a = sparse.csc_matrix((qp["a_nzval"], qp["a_rowval"], qp["a_colptr"]), shape=(m, n))
            solver.setup(p, qp["q"], a, lower, qp["b"], verbose=False, warm_starting=True, **settings)
            extra = solver.solve(raise_error=False).info.setup_time  # the setup's own solve is not timed
            solver.warm_start(x=np.zeros(n), y=np.zeros(m))
        else:
            solver.update(Px=qp["p_nzval"], Ax=qp["a_nzval"], q=qp["q"], l=lower, u=qp["b"])
        result = solver.solve(raise_error=False)
        info = result.info
        times.append((extra + info.update_time + info.solve_time + info.polish_time) * 1e3)
        solutions.append(np.array(result.x))
        statuses.append(str(info.status))
        fresh.append(extra > 0.0)
    return times, solutions, statuses, fresh


def qp_solvers(repeats: int) -> dict[str, Any]:
    """The tracker's QP solvers and OSQP on the same QPs (:func:`closed_loop_qps`), each
    time the solver's own (no Python conversions), the fastest of ``repeats`` passes per QP;
    medians over the QPs, and each solution's largest difference from the banded solver's."""
    import subterra

    qps = closed_loop_qps()
    report: dict[str, Any] = {"qps": len(qps), "passes": repeats}
    ours: dict[str, list[dict[str, Any]]] = {}
    for solver in ("banded", "clarabel"):
        best = [np.inf] * len(qps)
        for _ in range(repeats):
            results = [subterra.MpcTracker.solve_qp(qp, solver=solver) for qp in qps]
            best = [min(b, r["time_s"] * 1e3) for b, r in zip(best, results)]
        ours[solver] = results
        report[solver] = {"per_qp": _summary(best), "iterations_mean": float(np.mean([r["iterations"] for r in results])),
                          "statuses": sorted({r["status"] for r in results})}
    reference = [r["z"] for r in ours["banded"]]
    report["clarabel"]["max_difference_from_banded"] = float(max(np.max(np.abs(r["z"] - z)) for r, z in zip(ours["clarabel"], reference)))
    try:
        import osqp  # noqa: F401
    except ImportError:
        report["osqp"] = "not installed (pip install osqp)"
        return report
    for name, settings in OSQP_VARIANTS.items():
        best = [np.inf] * len(qps)
        for _ in range(repeats):
            times, solutions, statuses, fresh = _osqp_run(qps, settings)
            best = [min(b, t) for b, t in zip(best, times)]
        warm = [t for t, new in zip(best, fresh) if not new]
        report[name] = {"settings": settings, "per_qp": _summary(best), "per_qp_warm_updates_only": _summary(warm),
                        "setups": int(sum(fresh)), "statuses": sorted(set(statuses)),
                        "max_difference_from_banded": float(max(np.max(np.abs(x - z)) for x, z in zip(solutions, reference)))}
    banded = report["banded"]["per_qp"]["median_ms"]
    report["banded_faster_than_warm_osqp"] = {name: bool(banded < report[name]["per_qp_warm_updates_only"]["median_ms"]) for name in OSQP_VARIANTS}
    return report


def mpc_case(repeats: int, seed: int) -> dict[str, Any]:
    """The ``mpc_h20_200x200`` case of ``subterra bench plan`` (module notes): JSON-ready."""
    import subterra
    from subterra.bench.reference import mpc as reference

    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    path = bench_path()
    free = bench_risk(lethal=False)
    at = reference_states(repeats)
    no_lethal, captured = _closed_loop(free, repeats, at)
    with_lethal, _ = _closed_loop(bench_risk(lethal=True), repeats)

    ref_ms, ref_outer, ref_converged = [], [], 0
    diffs: dict[str, list[dict[str, float]]] = {"cold_start": [], "warm_fixed_point": [], "warm_bounds_held": []}
    for c in captured:
        r = reference.solve(c["state"], path, risk=free, resolution=RESOLUTION_M, origin=ORIGIN,
                            previous_input=c["previous_input"], initial_inputs=c["nominal"])
        ref_ms.append(r.solve_time_s * 1e3)
        ref_outer.append(r.outer_iterations)
        ref_converged += int(r.converged)
        kind = "cold_start" if c["nominal"] is None else "warm_bounds_held" if r.bounds_held else "warm_fixed_point"
        diffs[kind].append({"step": c["step"], **compare(c["result"], r)})
    closed_loop = {kind: _spread(d) for kind, d in diffs.items()}

    converged = {}
    for name, kwargs in agreement_cases(seed).items():
        r = reference.solve(**kwargs)
        tracker = subterra.MpcTracker(CONVERGED_SOLVER)
        converged[name] = {**compare(tracker.solve(**kwargs), r), "reference_converged": r.converged}

    solvers = qp_solvers(min(repeats, 10))

    tracker_ms = no_lethal["python_wall"]["median_ms"]
    worst_ms = max(no_lethal["python_wall"]["median_ms"], with_lethal["python_wall"]["median_ms"])
    return {
        "scene": {"grid": [NX, NX], "resolution_m": RESOLUTION_M, "origin": list(ORIGIN), "start": list(START), "run_steps": RUN_STEPS,
                  "runs": repeats, "source": "crates/subterra/benches/mpc.rs"},
        "no_lethal": no_lethal,
        "with_lethal": with_lethal,
        "reference_slsqp_no_lethal": {
            "steps": at,
            "wall": _summary(ref_ms),
            "outer_iterations_mean": float(np.mean(ref_outer)),
            "converged": ref_converged,
        },
        "speedup_vs_reference_median": float(np.median(ref_ms)) / tracker_ms,
        "qp_solvers": solvers,
        "agreement_closed_loop_default_tracker": closed_loop,
        "agreement_converged": converged,
        "agreement_converged_max": {key: float(max(v[key] for v in converged.values())) for key in _MEASURES},
        "target_ms": TARGET_MS,
        "target_met": bool(worst_ms <= TARGET_MS),
        "target_note": "median Python wall time per solve (call and conversions included), the worse of the two variants",
    }

