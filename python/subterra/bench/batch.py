"""`subterra bench batch`: what the batch engines cost. Per engine: its start (a local Ray
is started for the batch), the overhead per job (jobs that do nothing, so the time is the
engine's: sending the job, running it, the row back into the log), and real flights
(``fly-batch`` settings: `highbay`, every route, both controllers, `d435-phantom`, 15 Hz).

Flights are measured two ways. Wall time: flights per minute on this machine as it is
(on a shared machine that depends on the others' load, so the engines take turns, a seed
at a time, to see the same load). CPU time: each flight's own CPU seconds (its thread's,
where it ran), which the load barely changes: ``60 x cores / (cpu_s + overhead)`` is the
rate an idle machine reaches, and ``cpu_s`` the cost of a flight per core.

The flights are the same on every engine, so their rows are compared too: the report says
whether every engine gave every flight the same outcome (wall-clock timings aside).
"""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np

from subterra.batch import Job, ThreadsEngine, run_batch
from subterra.errors import InputError
from subterra.sim import DEFAULT_DEPTH_NOISE

__all__ = ["bench_batch", "noop_job", "timed_flight"]

#: Row fields that measure time (wall-clock or CPU).
TIMING_FIELDS = ("wall_s", "compute_ms_median", "compute_ms_p99", "cpu_s")


class _Noop:
    def __init__(self, i: int) -> None:
        self.i = i

    def summary(self) -> dict[str, Any]:
        return {"i": self.i, "success": True, "failure": None}


def noop_job(i: int) -> _Noop:
    """A job that does nothing (the engine's overhead alone)."""
    return _Noop(i)


class _Timed:
    def __init__(self, record: Any, cpu_s: float) -> None:
        self.record, self.cpu_s = record, cpu_s

    def summary(self) -> dict[str, Any]:
        return {**self.record.summary(), "cpu_s": round(self.cpu_s, 3)}


def timed_flight(**params: Any) -> _Timed:
    """A batch flight (:func:`subterra.flight.batch.fly_job`) with its CPU seconds."""
    from subterra.flight.batch import fly_job

    t0 = time.thread_time()
    record = fly_job(**params)
    return _Timed(record, time.thread_time() - t0)


def bench_batch(*, flights: int = 20, noop_jobs: int = 200, workers: int | None = None,
                engines: tuple[str, ...] = ("threads", "ray"), seed: int = 0) -> dict[str, Any]:
    """Runs the measurement; ``flights`` rounds up to whole seeds of 10 flights (5 routes x
    2 controllers). ``workers``: threads, or CPUs of the local Ray (default: the CPU count)."""
    if flights < 1 or noop_jobs < 1:
        raise InputError(f"arguments `flights` and `noop_jobs` must be >= 1, got {flights} and {noop_jobs}")
    workers = workers or os.cpu_count() or 1
    seeds = list(range(seed, seed + max(1, -(-flights // 10))))
    routes = ("A-B", "B-C", "C-D", "D-C", "D-B")
    settings = {"scenario": "highbay", "noise": DEFAULT_DEPTH_NOISE, "rate_hz": 15.0, "time_limit_s": None, "preset": "flight"}
    report: dict[str, Any] = {"workers": workers, "cpu_count": os.cpu_count(), "load_average_1min_start": os.getloadavg()[0],
                              "flights": {**settings, "routes": list(routes), "seeds": seeds,
                                          "controllers": ["apf-pf", "raw-apf"]}, "engines": {}}
    running: dict[str, Any] = {}
    try:
        for name in engines:
            started = time.perf_counter()
            if name == "ray":
                from subterra.batch.ray_engine import RayEngine

                running[name] = RayEngine(workers=workers)
            else:
                running[name] = ThreadsEngine(workers)
            start_s = time.perf_counter() - started
            jobs = [Job("subterra.bench.batch:noop_job", {"i": i}) for i in range(noop_jobs)]
            t0 = time.perf_counter()
            run_batch(jobs, engine=running[name], progress=False)
            overhead_s = (time.perf_counter() - t0) / noop_jobs
            report["engines"][name] = {"start_s": round(start_s, 2), "overhead_ms_per_job": round(1000 * overhead_s, 2),
                                       "rows": [], "wall_s": 0.0}
        for s in seeds:  # the engines take turns, a seed each
            jobs = [Job("subterra.bench.batch:timed_flight", {**settings, "route": route, "controller": c, "seed": s})
                    for route in routes for c in ("apf-pf", "raw-apf")]
            for name, engine in running.items():
                t0 = time.perf_counter()
                run = run_batch(jobs, engine=engine, progress=False)
                report["engines"][name]["wall_s"] += time.perf_counter() - t0
                report["engines"][name]["rows"] += run.rows
    finally:
        for engine in running.values():
            engine.close()
    report["load_average_1min_end"] = os.getloadavg()[0]
    outcomes = []
    for e in report["engines"].values():
        rows = e.pop("rows")
        outcomes.append({r["job"]: {k: v for k, v in r.items() if k not in TIMING_FIELDS} for r in rows})
        cpu = [r["cpu_s"] for r in rows]
        n, wall = len(rows), e.pop("wall_s")
        overhead = e["overhead_ms_per_job"] / 1000.0
        e.update({
            "flights": n, "successes": sum(bool(r["success"]) for r in rows), "wall_s": round(wall, 1),
            "flights_per_minute_here": round(60 * n / wall, 2),
            "simulated_s_per_flight_mean": round(float(np.mean([r["time_s"] for r in rows])), 1),
            "cpu_s_per_flight_mean": round(float(np.mean(cpu)), 2), "cpu_s_per_flight_median": round(float(np.median(cpu)), 2),
            "flights_per_minute_idle": round(60 * workers / (float(np.mean(cpu)) + overhead), 2),
        })
    report["same_outcomes_on_every_engine"] = all(o == outcomes[0] for o in outcomes)
    return report
