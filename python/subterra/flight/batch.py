"""Many randomized flights (`subterra fly-batch`): every route x seed x noise model x
perception preset, flown by APF-PF and by the raw-APF baseline on the same worlds, seeds
and noise.

Each seed is a new obstacle layout (the built-in generators are seeded), a new noise
stream and a new particle-filter stream. Flights run in parallel threads (the simulator
and the filter release the GIL); results do not depend on the number of workers.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from subterra.errors import InputError
from subterra.flight.run import CONTROLLERS, FlightResult, fly, resolve_route
from subterra.sim import DEPTH_NOISE_PRESETS, World

__all__ = ["BatchResult", "fly_batch", "summarise_rows"]

#: Failure causes reported per flight; anything else is counted as "other".
FAILURE_CAUSES = ("collision", "local_minimum", "timeout")


@dataclass
class BatchResult:
    """Per-flight rows (``FlightResult.summary()`` dicts), the summary table and the full
    records of the flights kept for plotting (the first seed of each route)."""

    scenario: str
    rows: list[dict[str, Any]]
    table: list[dict[str, Any]]
    kept: list[FlightResult] = field(default_factory=list)
    wall_s: float = 0.0
    settings: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"scenario": self.scenario, "settings": self.settings, "wall_s": round(self.wall_s, 1),
                "summary": self.table, "flights": self.rows}

    def markdown(self) -> str:
        """The results table (one line per controller x preset x noise x route, then the totals)."""
        head = ("| controller | preset | noise | route | flights | success | collisions | local minima | timeouts "
                "| min clearance [m] (worst / median) | time to goal [s] (median) | compute [ms] (median / p99) |")
        lines = [head, "|" + "---|" * 12]
        for r in self.table:
            clear = "-" if r["min_clearance_m"] is None else f"{r['min_clearance_m']:.3f} / {r['median_min_clearance_m']:.3f}"
            t = "-" if r["median_time_s"] is None else f"{r['median_time_s']:.1f}"
            c = "-" if r["compute_ms_median"] is None else f"{r['compute_ms_median']:.2f} / {r['compute_ms_p99']:.2f}"
            lines.append(
                f"| {r['controller']} | {r['preset']} | {r['noise']} | {r['route']} | {r['flights']} | {r['successes']} ({100 * r['success_rate']:.0f}%) "
                f"| {r['collisions']} | {r['local_minima']} | {r['timeouts']} | {clear} | {t} | {c} |"
            )
        return "\n".join(lines) + "\n"

    def save(self, out_dir: str | os.PathLike[str], *, plots: bool = True) -> dict[str, Path]:
        """Writes ``results.json``, ``results.md`` and, with ``plots``,
        ``paths-seed<N>-<noise>[-<preset>].png`` (every kept route, both controllers, over
        the world of that seed; the preset in the name when the batch flew several)."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        written = {"json": out / "results.json", "markdown": out / "results.md"}
        written["json"].write_text(json.dumps(self.to_json(), indent=2) + "\n", encoding="utf-8")
        written["markdown"].write_text(self.markdown(), encoding="utf-8")
        if plots and self.kept:
            from subterra.viz.flight import plot_flight_path

            groups: dict[tuple[str, str], list[FlightResult]] = {}
            for r in self.kept:
                groups.setdefault((r.noise, r.preset), []).append(r)
            several = len({preset for _, preset in groups}) > 1
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
        groups.setdefault((r["controller"], preset, r["noise"], r["route"]), []).append(r)
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
    controllers: Sequence[str] = ("apf-pf", "raw-apf"),
    noises: Sequence[str] = ("d435-phantom",),
    preset: str | Sequence[str] = "flight",
    rate_hz: float = 15.0,
    time_limit_s: float | None = None,
    workers: int | None = None,
    keep_seed: int | None = None,
    progress: bool | Callable[[int, int, dict[str, Any]], None] = True,
    log_path: str | os.PathLike[str] | None = None,
) -> BatchResult:
    """Flies every (preset, noise, seed, route, controller) combination and summarises them.

    ``preset``: a perception preset name, a comma-separated list or a sequence of names
    (e.g. ``"flight,flight-memory"``: the paper's and the obstacle memory's side by side).

    ``seeds``: a count (seeds ``0..n-1``) or explicit seeds. ``time_limit_s``: per flight
    (default: :func:`~subterra.flight.fly`'s, from the route length). ``workers``: parallel flights
    (default: the machine's CPU count). ``keep_seed``: keep the full records of this seed
    for plotting (default: the first seed). ``progress``: a progress bar, or a callback
    ``(done, total, row)``.
    """
    seed_list = list(range(seeds)) if isinstance(seeds, int) else [int(s) for s in seeds]
    if not seed_list or any(s < 0 for s in seed_list):
        raise InputError(f"argument `seeds` must be a count >= 1 or non-negative seeds, got {seeds!r}")
    for c in controllers:
        if c not in CONTROLLERS:
            raise InputError(f"argument `controllers`: unknown controller {c!r} (known: {', '.join(CONTROLLERS)})")
    if not controllers:
        raise InputError("argument `controllers` must not be empty")
    for n in noises:
        if n not in DEPTH_NOISE_PRESETS:
            raise InputError(f"argument `noises`: unknown noise model {n!r} (known: {', '.join(DEPTH_NOISE_PRESETS)})")
    if not noises:
        raise InputError("argument `noises` must not be empty")
    if workers is not None and not (isinstance(workers, int) and 1 <= workers <= 256):
        raise InputError(f"argument `workers` must be an integer in 1..256, got {workers!r}")
    from subterra._core import preset_names

    presets = [p.strip() for p in preset.split(",") if p.strip()] if isinstance(preset, str) else [str(p) for p in preset]
    if not presets:
        raise InputError("argument `preset` must name at least one perception preset")
    for p in presets:
        if p not in preset_names():
            raise InputError(f"argument `preset`: unknown perception preset {p!r} (known: {', '.join(preset_names())})")
    route_list = _routes(scenario, routes)
    keep = seed_list[0] if keep_seed is None else keep_seed
    jobs = [(p, noise, seed, route, controller) for p in presets for noise in noises for seed in seed_list
            for route in route_list for controller in controllers]
    workers = workers or os.cpu_count() or 1
    started = time.perf_counter()

    def run(job: tuple[str, str, int, str, str]) -> FlightResult:
        p, noise, seed, route, controller = job
        return fly(scenario, route, controller=controller, noise=noise, preset=p, seed=seed, rate_hz=rate_hz,
                   time_limit_s=time_limit_s)

    bar = None
    plain_every = 0
    if progress is True:
        import sys

        from tqdm import tqdm

        bar = tqdm(total=len(jobs), desc=f"fly-batch {scenario}", unit="flight", disable=None)
        if bar.disable:  # not a terminal (a log file, CI): a plain line every ~5 %
            bar, plain_every = None, max(1, len(jobs) // 20)
    rows: list[dict[str, Any] | None] = [None] * len(jobs)
    kept: list[FlightResult] = []
    label = (lambda c, p: f"{c}@{p}") if len(presets) > 1 else (lambda c, p: c)
    counts = {label(c, p): {"ok": 0, "collisions": 0} for p in presets for c in controllers}
    log = None
    if log_path is not None:
        Path(log_path).parent.mkdir(parents=True, exist_ok=True)
        log = Path(log_path).open("a", encoding="utf-8")
    try:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            for done, (n, result) in enumerate(zip(range(len(jobs)), pool.map(run, jobs)), start=1):
                row = result.summary()
                rows[n] = row
                if log is not None:
                    log.write(json.dumps(row) + "\n")
                    log.flush()
                if result.seed == keep:
                    kept.append(result)
                c = counts[label(result.controller, result.preset)]
                c["ok"] += int(result.success)
                c["collisions"] += int(result.failure == "collision")
                status = ", ".join(f"{k}: {v['ok']} ok, {v['collisions']} coll." for k, v in counts.items())
                if bar is not None:
                    bar.set_postfix_str(status, refresh=False)
                    bar.update(1)
                elif plain_every and (done % plain_every == 0 or done == len(jobs)):
                    print(f"fly-batch {scenario}: {done}/{len(jobs)} flights, {time.perf_counter() - started:.0f} s; {status}",
                          file=sys.stderr, flush=True)
                elif callable(progress):
                    progress(done, len(jobs), row)
    finally:
        if bar is not None:
            bar.close()
        if log is not None:
            log.close()
    final_rows = [r for r in rows if r is not None]
    settings = {"routes": route_list, "seeds": seed_list, "controllers": list(controllers), "noises": list(noises),
                "presets": presets, "rate_hz": rate_hz, "time_limit_s": time_limit_s, "workers": workers}
    return BatchResult(scenario=scenario, rows=final_rows, table=summarise_rows(final_rows), kept=kept,
                       wall_s=time.perf_counter() - started, settings=settings)
