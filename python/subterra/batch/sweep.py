"""Parameter sweeps (``subterra sweep FILE.toml``): every point of a grid or a random search
over config fields, on every world, noise, seed (and route, controller or planner), run
on the batch engine; a results table and one figure per swept field.

The file is described in :mod:`subterra.batch.sweep_spec`. A point's row in the results
is the run's own row (``FlightResult.summary()`` or ``DriveResult.summary()``) with the
point under ``"sweep"``. The table has a line per point x controller (planner) x world x
noise; the figure of a field draws the success and collision rates against its values,
averaged over everything else swept, with the spread over seeds.

>>> from subterra.batch import sweep
>>> result = sweep("sweep.toml", engine="threads", log_path="runs/sweep/jobs.jsonl")
>>> result.save("runs/sweep")           # results.json, results.md, sweep-<field>.png
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from subterra.batch.engine import Engine, run_batch
from subterra.batch.jobs import Job
from subterra.batch.progress import ProgressArg
from subterra.batch.results import BatchReport, markdown_table
from subterra.batch.sweep_spec import RUN_FIELDS, SweepSpec, load_sweep

__all__ = ["SweepResult", "field_stats", "point_params", "register_cli", "sweep", "sweep_jobs"]


def _nested(dotted: Mapping[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, value in dotted.items():
        *sections, leaf = name.split(".")
        table = out
        for s in sections:
            table = table.setdefault(s, {})
        table[leaf] = value
    return out


def point_params(spec: SweepSpec, point: Mapping[str, Any]) -> dict[str, Any]:
    """The run settings of ``point``: the fixed ones, the swept run settings and the config
    fields (flights: ``perception``; drives: ``navigator_config``)."""
    params = dict(spec.fixed)
    config = {}
    for name, value in point.items():
        if name in RUN_FIELDS[spec.kind]:
            params[name] = value
        else:
            config[name] = value
    if spec.kind == "fly":
        nested = _nested(config)
        if nested:
            params["perception"] = nested["perception"]
    elif config:
        params["navigator_config"] = _nested(config)
    return params


def sweep_jobs(spec: SweepSpec) -> tuple[list[Job], list[dict[str, Any]]]:
    """Every run of the sweep, and for each what it stands for (``point``, ``values``,
    ``world``, ``noise``, ``arm``, ``seed``)."""
    if spec.kind == "fly":
        from subterra.flight.batch import FLY_JOB as fn
        from subterra.flight.batch import _routes
    else:
        from subterra.drive.batch import DRIVE_JOB as fn
    jobs, labels = [], []
    for k, point in enumerate(spec.points):
        base = point_params(spec, point)
        for world in spec.worlds:
            routes = _routes(world, spec.routes) if spec.kind == "fly" else [None]
            for noise in spec.noises:
                for seed in spec.seeds:
                    for route in routes:
                        for arm in spec.arms:
                            params = {"scenario": world, "seed": seed, "noise": noise, spec.arm_key: arm, **base}
                            if route is not None:
                                params["route"] = route
                            jobs.append(Job(fn, params))
                            labels.append({"point": k, "values": dict(point), "world": world, "noise": noise,
                                           "arm": arm, "seed": seed})
    return jobs, labels


def _fmt(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _summarise(spec: SweepSpec, rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    groups: dict[tuple[int, str, str, str], list[dict[str, Any]]] = {}
    for r in rows:
        s = r["sweep"]
        groups.setdefault((s["point"], s["arm"], s["world"], s["noise"]), []).append(r)
    table = []
    for (k, arm, world, noise), rs in sorted(groups.items()):
        per_seed: dict[int, list[bool]] = {}
        for r in rs:
            per_seed.setdefault(r["sweep"]["seed"], []).append(bool(r["success"]))
        seed_rates = [float(np.mean(v)) for v in per_seed.values()]
        failures = [r["failure"] for r in rs if not r["success"]]
        times = [r["time_s"] for r in rs if r["success"]]
        successes = sum(bool(r["success"]) for r in rs)
        table.append({
            "point": k, "values": spec.points[k], spec.arm_key: arm, "world": world, "noise": noise, "runs": len(rs),
            "successes": successes, "success_rate": successes / len(rs), "collisions": failures.count("collision"),
            "failures": {f: failures.count(f) for f in sorted(set(failures), key=str)},
            "success_rate_seed_min": min(seed_rates), "success_rate_seed_max": max(seed_rates),
            "median_time_s": float(np.median(times)) if times else None,
        })
    return table


def field_stats(result: SweepResult, field: str) -> dict[str, list[dict[str, Any]]]:
    """For the figure of ``field``: per line (controller or planner, with the noise when the
    sweep has several), per value of the field in order, the success and collision rates
    over everything else, as ``mean``/``min``/``max`` over seeds."""
    several_noises = len(result.settings["noises"]) > 1
    cells: dict[str, dict[Any, dict[int, list[tuple[bool, bool]]]]] = {}
    order: list[Any] = []
    for r in result.rows:
        s = r["sweep"]
        line = f"{s['arm']}, {s['noise']}" if several_noises else s["arm"]
        value = s["values"][field]
        if value not in order:
            order.append(value)
        cells.setdefault(line, {}).setdefault(value, {}).setdefault(s["seed"], []).append(
            (bool(r["success"]), r["failure"] == "collision"))
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in order):
        order.sort()
    out: dict[str, list[dict[str, Any]]] = {}
    for line, by_value in cells.items():
        points = []
        for value in order:
            if value not in by_value:
                continue
            success = [float(np.mean([o[0] for o in v])) for v in by_value[value].values()]
            collision = [float(np.mean([o[1] for o in v])) for v in by_value[value].values()]
            points.append({"value": value, "seeds": len(success),
                           "success": {"mean": float(np.mean(success)), "min": min(success), "max": max(success)},
                           "collision": {"mean": float(np.mean(collision)), "min": min(collision), "max": max(collision)}})
        out[line] = points
    return out


@dataclass
class SweepResult(BatchReport):
    """A sweep's rows (each with its point under ``"sweep"``), its table (a line per point x
    controller or planner x world x noise) and settings (``fields``, ``points``, ...)."""

    ROWS = "runs"

    def markdown(self) -> str:
        fields = self.settings["fields"]
        arm = self.settings["arm"]
        head = (*fields, arm, "world", "noise", "runs", "success", "collisions", "other failures",
                "success over seeds (min - max)", "time to goal [s] (median)")
        lines = []
        for t in self.table:
            other = ", ".join(f"{f}: {n}" for f, n in t["failures"].items() if f != "collision") or "-"
            lines.append((*(_fmt(t["values"][f]) for f in fields), t[arm], t["world"], t["noise"], t["runs"],
                          f"{t['successes']} ({100 * t['success_rate']:.0f}%)", t["collisions"], other,
                          f"{100 * t['success_rate_seed_min']:.0f}% - {100 * t['success_rate_seed_max']:.0f}%",
                          "-" if t["median_time_s"] is None else f"{t['median_time_s']:.1f}"))
        return markdown_table(head, lines)

    def figures(self, out: Path) -> dict[str, Path]:
        """``sweep-<field>.png`` per swept field: success and collision rates against its values."""
        from subterra.viz.sweep import plot_sweep_field

        written = {}
        for f in self.settings["fields"]:
            written[f"sweep_{f}"] = plot_sweep_field(field_stats(self, f), f, out / f"sweep-{f}.png",
                                                     title=f"{self.settings['kind']} sweep over {self.scenario}: {f}",
                                                     seeds=len(self.settings["seeds"]))
        return written


def sweep(
    spec: str | os.PathLike[str] | Mapping[str, Any] | SweepSpec,
    *,
    engine: str | Engine = "threads",
    workers: int | None = None,
    address: str | None = None,
    progress: ProgressArg = True,
    log_path: str | os.PathLike[str] | None = None,
    resume: bool = False,
) -> SweepResult:
    """Runs every point of ``spec`` (a sweep file, its parsed TOML or a
    :class:`~subterra.batch.sweep_spec.SweepSpec`) on ``engine``; see
    :func:`subterra.batch.run_batch` for the engine, the log and ``resume``."""
    spec = spec if isinstance(spec, SweepSpec) else load_sweep(spec)
    jobs, labels = sweep_jobs(spec)

    def status(rows: list[dict[str, Any]]) -> str:
        ok = sum(bool(r["success"]) for r in rows)
        return f"{ok} ok, {sum(r['failure'] == 'collision' for r in rows)} coll."

    run = run_batch(jobs, engine=engine, workers=workers, address=address, progress=progress,
                    desc=f"sweep {spec.kind} ({len(spec.points)} points)", unit="flight" if spec.kind == "fly" else "drive",
                    status=status, log_path=log_path, resume=resume)
    rows = [{**row, "sweep": label} for row, label in zip(run.rows, labels)]
    settings = {"kind": spec.kind, "mode": spec.mode, "fields": spec.fields, "points": spec.points,
                "worlds": spec.worlds, "routes": spec.routes, "arm": spec.arm_key, "arms": spec.arms, "noises": spec.noises,
                "seeds": spec.seeds, "fixed": spec.fixed, "engine": run.engine, "resumed": run.resumed}
    result = SweepResult(scenario=", ".join(spec.worlds), rows=rows, table=[], wall_s=run.wall_s, settings=settings)
    result.table = _summarise(spec, rows)
    return result


def register_cli(subparsers: argparse._SubParsersAction) -> None:
    """Adds ``sweep``; its handler is ``args.handler``."""
    from subterra.batch.cli import add_engine_options

    p = subparsers.add_parser("sweep", help="a grid or random search over config fields, worlds, noises and seeds")
    p.add_argument("file", help="the sweep (TOML): kind, worlds, noises, seeds and a [grid] or [random] of fields")
    p.add_argument("--no-plots", action="store_true", help="skip the figure per swept field")
    add_engine_options(p, unit="run")
    p.set_defaults(handler=_sweep_cli)


def _sweep_cli(args: argparse.Namespace) -> int:
    from subterra.batch.cli import engine_options, out_dir, save_and_report

    spec = load_sweep(args.file)
    out = out_dir(args, f"sweep-{Path(args.file).stem}")
    result = sweep(spec, log_path=out / "runs.jsonl", **engine_options(args))
    return save_and_report(result, out, args, "run")
