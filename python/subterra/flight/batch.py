"""Many randomized flights (`subterra fly-batch`): every route x seed x noise model x
perception preset, flown by APF-PF and by the raw-APF baseline on the same worlds, seeds
and noise.

Each seed is a new obstacle layout (the built-in generators are seeded), a new noise
stream and a new particle-filter stream. Every flight is one job of the batch engine
(:mod:`subterra.batch`: threads here or a Ray cluster); results depend on neither the
engine nor the number of workers.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from subterra.batch import BatchReport, Engine, Job, ProgressArg, check_workers, markdown_table, run_batch, seed_list
from subterra.errors import InputError
from subterra.flight.run import CONTROLLERS, FlightResult, fly, resolve_route
from subterra.sim import DEFAULT_DEPTH_NOISE, DEPTH_NOISE_PRESETS, World

__all__ = ["FLY_JOB", "BatchResult", "fly_batch", "fly_job", "perception_config", "summarise_rows"]

#: The job function of a flight (:func:`fly_job`).
FLY_JOB = "subterra.flight.batch:fly_job"


def _laid_over(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in over.items():
        out[key] = _laid_over(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def perception_config(preset: str, overrides: dict[str, Any] | None) -> Any:
    """The perception config of ``preset`` with ``overrides`` (a partial dict of sections,
    e.g. ``{"observation": {"sigma_o_points": 120}}``) laid over it; None without overrides."""
    if not overrides:
        return None
    from subterra._core import PerceptionConfig

    return PerceptionConfig.from_dict(_laid_over(PerceptionConfig.preset(preset).to_dict(), overrides))


def fly_job(*, perception: dict[str, Any] | None = None, preset: str = "flight-escape", **params: Any) -> FlightResult:
    """One flight of a batch: :func:`subterra.flight.fly` with ``params``, the perception
    config of ``preset`` with the ``perception`` overrides laid over it (a sweep's fields)."""
    return fly(preset=preset, config=perception_config(preset, perception), **params)

#: Failure causes reported per flight; anything else is counted as "other".
FAILURE_CAUSES = ("collision", "local_minimum", "timeout")


@dataclass
class BatchResult(BatchReport):
    """Per-flight rows (``FlightResult.summary()`` dicts), the summary table and the full
    records of the flights kept for plotting (the first seed of each route)."""

    ROWS = "flights"

    def markdown(self) -> str:
        """The results table (one line per controller x preset x noise x route, then the totals)."""
        head = ("controller", "preset", "noise", "route", "flights", "success", "collisions", "local minima", "timeouts",
                "other failures", "min clearance [m] (worst / median)", "time to goal [s] (median)", "compute [ms] (median / p99)")
        lines = []
        for r in self.table:
            clear = "-" if r["min_clearance_m"] is None else f"{r['min_clearance_m']:.3f} / {r['median_min_clearance_m']:.3f}"
            t = "-" if r["median_time_s"] is None else f"{r['median_time_s']:.1f}"
            c = "-" if r["compute_ms_median"] is None else f"{r['compute_ms_median']:.2f} / {r['compute_ms_p99']:.2f}"
            lines.append((r["controller"], r["preset"], r["noise"], r["route"], r["flights"],
                          f"{r['successes']} ({100 * r['success_rate']:.0f}%)", r["collisions"], r["local_minima"],
                          r["timeouts"], r["other_failures"], clear, t, c))
        return markdown_table(head, lines)

    def figures(self, out: Path) -> dict[str, Path]:
        """``paths-seed<N>-<noise>[-<preset>].png``: every kept route, both controllers, over
        the world of that seed (the preset in the name when the batch flew several)."""
        if not self.kept:
            return {}
        from subterra.viz.flight import plot_flight_path

        groups: dict[tuple[str, str], list[FlightResult]] = {}
        for r in self.kept:
            groups.setdefault((r.noise, r.preset), []).append(r)
        several = len({preset for _, preset in groups}) > 1
        written = {}
        for (noise, preset), results in groups.items():
            seed = results[0].seed
            suffix = f"{noise}-{preset}" if several else noise
            written[f"paths_{suffix}"] = plot_flight_path(
                results, out / f"paths-seed{seed}-{suffix}.png",
                title=f"{self.scenario}, seed {seed}, noise {noise}, preset {preset}: every route, both controllers")
        return written


def summarise_rows(rows: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """Groups flight rows by (controller, preset, noise, route) and by (controller, preset,
    noise) over all routes (route "all"); counts successes and failure causes."""
    groups: dict[tuple[str, str, str, str], list[dict[str, Any]]] = {}
    for r in rows:
        preset = r.get("preset", "flight")
        # With faults injected, a line per fault (the route column names it).
        group = ",".join(r["faults"]) if r.get("faults") else r["route"]
        groups.setdefault((r["controller"], preset, r["noise"], group), []).append(r)
        groups.setdefault((r["controller"], preset, r["noise"], "all"), []).append(r)
    table = []
    order = lambda kv: (kv[0][2], kv[0][0], kv[0][1], kv[0][3] == "all", kv[0][3])  # noqa: E731
    for (controller, preset, noise, route), rs in sorted(groups.items(), key=order):
        clear = [r["min_clearance_m"] for r in rs if r["min_clearance_m"] is not None]
        times = [r["time_s"] for r in rs if r["success"]]
        compute = [r["compute_ms_median"] for r in rs if r["compute_ms_median"] is not None]
        p99 = [r["compute_ms_p99"] for r in rs if r["compute_ms_p99"] is not None]
        failures = [r["failure"] for r in rs if not r["success"]]
        n = len(rs)
        successes = sum(bool(r["success"]) for r in rs)
        table.append({
            "controller": controller, "preset": preset, "noise": noise, "route": route, "flights": n,
            "successes": successes, "success_rate": successes / n if n else 0.0,
            "collisions": failures.count("collision"), "local_minima": failures.count("local_minimum"),
            "timeouts": failures.count("timeout"),
            "other_failures": sum(1 for f in failures if f not in FAILURE_CAUSES),
            "min_clearance_m": min(clear) if clear else None,
            "median_min_clearance_m": float(np.median(clear)) if clear else None,
            "median_time_s": float(np.median(times)) if times else None,
            "compute_ms_median": float(np.median(compute)) if compute else None,
            "compute_ms_p99": float(np.max(p99)) if p99 else None,
            "failed_flights": [f"{r['route']} seed {r['seed']}: {r['failure']}" for r in rs if not r["success"]],
            "hovers": sum(int(r.get("hovers") or 0) for r in rs),
            "odometry_switches": sum(int(r.get("odometry_switches") or 0) for r in rs),
        })
    return table


def _routes(scenario: str, routes: str | Sequence[str]) -> list[str]:
    world = World.scenario(scenario, 0)
    if isinstance(routes, str):
        if routes == "all":
            names = [f"{a}-{b}" for _, a, b in world.routes]
            if not names:
                raise InputError(f"argument `routes`: scenario {scenario!r} defines no routes")
            return names
        routes = [r.strip() for r in routes.split(",") if r.strip()]
    if not routes:
        raise InputError("argument `routes` must name at least one route, or be 'all'")
    return [resolve_route(world, r)[0] for r in routes]


def fly_batch(
    scenario: str = "highbay",
    routes: str | Sequence[str] = "all",
    seeds: int | Sequence[int] = 50,
    *,
    controllers: Sequence[str] = ("apf-pf", "raw-apf@flight"),
    noises: Sequence[str] = (DEFAULT_DEPTH_NOISE,),
    preset: str | Sequence[str] = "flight-escape",
    rate_hz: float = 15.0,
    time_limit_s: float | None = None,
    workers: int | None = None,
    keep_seed: int | None = None,
    keep_records: bool = True,
    progress: ProgressArg = True,
    log_path: str | os.PathLike[str] | None = None,
    engine: str | Engine = "threads",
    address: str | None = None,
    resume: bool = False,
    faults: str | Sequence[str] | None = None,
    faults_config: dict[str, Any] | None = None,
) -> BatchResult:
    """Flies every (preset, noise, seed, route, controller) combination and summarises them.

    ``faults``: fault names (:data:`subterra.sim.faults.FAULT_NAMES`, ``"all"`` for every one):
    the flights take them in turn, one each (seeded by the flight's seed), and the table has a
    line per fault instead of per route; ``faults_config``: their settings.

    ``preset``: a perception preset name, a comma-separated list or a sequence of names
    (e.g. ``"flight,flight-memory"``: the paper's and the obstacle memory's side by side).
    A controller written ``name@preset`` (the default ``raw-apf@flight``: the paper's
    baseline, whose unfiltered belief would fill an obstacle memory with speckle) flies
    with that preset only, whatever ``preset`` says.

    ``seeds``: a count (seeds ``0..n-1``) or explicit seeds. ``time_limit_s``: per flight
    (default: :func:`~subterra.flight.fly`'s, from the route length). ``keep_seed``: keep the
    full records of this seed for plotting (default: the first seed; ``keep_records=False``:
    none, rows only, so every flight may run on a remote engine). ``progress``: a
    progress bar on stderr, or a callback ``(done, total, row)``. ``log_path``: the
    JSON-lines log, a row per flight as it lands (a fresh file; ``resume``: continue it and
    fly only the flights it does not hold). ``engine``: ``"threads"`` or ``"ray"``
    (``address``: an existing Ray cluster); ``workers``: parallel flights (default: the
    CPU count). See :func:`subterra.batch.run_batch`.
    """
    seed_values = seed_list(seeds)
    from subterra._core import preset_names
    from subterra.sim.faults import parse_faults

    fault_list = parse_faults(faults)

    pinned: list[tuple[str, str | None]] = []
    for c in controllers:
        name, _, own = str(c).partition("@")
        if name not in CONTROLLERS:
            raise InputError(f"argument `controllers`: unknown controller {name!r} (known: {', '.join(CONTROLLERS)})")
        if own and own not in preset_names():
            raise InputError(f"argument `controllers`: unknown perception preset {own!r} in {c!r} (known: {', '.join(preset_names())})")
        pinned.append((name, own or None))
    if not controllers:
        raise InputError("argument `controllers` must not be empty")
    for n in noises:
        if n not in DEPTH_NOISE_PRESETS:
            raise InputError(f"argument `noises`: unknown noise model {n!r} (known: {', '.join(DEPTH_NOISE_PRESETS)})")
    if not noises:
        raise InputError("argument `noises` must not be empty")
    check_workers(workers)
    presets = [p.strip() for p in preset.split(",") if p.strip()] if isinstance(preset, str) else [str(p) for p in preset]
    if not presets:
        raise InputError("argument `preset` must name at least one perception preset")
    for p in presets:
        if p not in preset_names():
            raise InputError(f"argument `preset`: unknown perception preset {p!r} (known: {', '.join(preset_names())})")
    route_list = _routes(scenario, routes)
    keep = (seed_values[0] if keep_seed is None else keep_seed) if keep_records else None
    # (controller, preset) pairs in order, each once: a pinned controller flies its own preset.
    pairs: list[tuple[str, str]] = []
    for p in presets:
        for name, own in pinned:
            if (name, own or p) not in pairs:
                pairs.append((name, own or p))
    jobs = [Job(FLY_JOB, {"scenario": scenario, "route": route, "controller": controller, "noise": noise, "preset": p,
                          "seed": seed, "rate_hz": rate_hz, "time_limit_s": time_limit_s}, keep=seed == keep)
            for noise in noises for seed in seed_values for route in route_list for controller, p in pairs]
    if fault_list:
        # One fault per flight, in turn (the same fault for every controller of a flight).
        per_flight = len(pairs)
        jobs = [Job(FLY_JOB, {**job.params, "faults": [fault_list[(k // per_flight) % len(fault_list)]],
                              "faults_config": faults_config}, keep=job.keep) for k, job in enumerate(jobs)]
    several = len({p for _, p in pairs}) > 1
    label = (lambda c, p: f"{c}@{p}") if several else (lambda c, p: c)

    def status(rows: list[dict[str, Any]]) -> str:
        counts = {label(c, p): [0, 0] for c, p in pairs}
        for r in rows:
            c = counts[label(r["controller"], r["preset"])]
            c[0] += int(bool(r["success"]))
            c[1] += int(r["failure"] == "collision")
        return ", ".join(f"{k}: {ok} ok, {coll} coll." for k, (ok, coll) in counts.items())

    run = run_batch(jobs, engine=engine, workers=workers, address=address, progress=progress,
                    desc=f"fly-batch {scenario}", unit="flight", status=status, log_path=log_path, resume=resume)
    kept = [run.records[job.id] for job in jobs if job.id in run.records]
    settings = {"routes": route_list, "seeds": seed_values, "controllers": [str(c) for c in controllers], "noises": list(noises),
                "presets": presets, "rate_hz": rate_hz, "time_limit_s": time_limit_s, "workers": workers or os.cpu_count() or 1,
                "engine": run.engine, "resumed": run.resumed}
    return BatchResult(scenario=scenario, rows=run.rows, table=summarise_rows(run.rows), kept=kept,
                       wall_s=run.wall_s, settings=settings)
