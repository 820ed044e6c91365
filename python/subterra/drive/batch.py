"""Many randomized drives (`subterra drive-batch`): every seed of a scenario driven with the
risk-aware planner and with the additive-cost baseline, on the same worlds and noise.

Each seed is a new world (the built-in generators are seeded) and a new lidar-noise stream.
Every drive is one job of the batch engine (:mod:`subterra.batch`: threads here or a Ray
cluster); results depend on neither the engine nor the number of workers.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from subterra.batch import BatchReport, Engine, Job, ProgressArg, check_workers, markdown_table, run_batch, seed_list
from subterra.drive.run import PLANNERS
from subterra.errors import InputError

__all__ = ["DRIVE_JOB", "DriveBatchResult", "FAILURE_CAUSES", "drive_batch", "summarise_drives"]

#: The job function of a drive: :func:`subterra.drive.drive` with the job's arguments.
DRIVE_JOB = "subterra.drive.run:drive"

#: Failure causes counted in the table; anything else is "other".
FAILURE_CAUSES = ("rollover", "fall", "collision", "timeout", "gave_up", "returned_home")


@dataclass
class DriveBatchResult(BatchReport):
    """Per-drive rows (``DriveResult.summary()`` dicts), the summary table, and the full
    records of the first seed (for plotting)."""

    ROWS = "drives"

    def markdown(self) -> str:
        """The results table, one line per planner."""
        head = ("planner", "drives", "success", "rollovers", "falls", "collisions", "timeouts", "gave up / home",
                "accumulated true risk (median / max)", "time to goal [s] (median)", "recoveries", "compute [ms] (median)")
        lines = []
        for r in self.table:
            risk = "-" if r["median_true_risk"] is None else f"{r['median_true_risk']:.3f} / {r['max_true_risk']:.3f}"
            t = "-" if r["median_time_s"] is None else f"{r['median_time_s']:.1f}"
            c = "-" if r["compute_ms_median"] is None else f"{r['compute_ms_median']:.1f}"
            lines.append((r["planner"], r["drives"], f"{r['successes']} ({100 * r['success_rate']:.0f}%)", r["rollover"],
                          r["fall"], r["collision"], r["timeout"], f"{r['gave_up']} / {r['returned_home']}", risk, t,
                          r["recoveries"], c))
        failed = [f"- {r['planner']}: " + "; ".join(r["failed_drives"]) for r in self.table if r["failed_drives"]]
        return markdown_table(head, lines) + ("\nFailures:\n" + "\n".join(failed) + "\n" if failed else "")

    def figures(self, out: Path) -> dict[str, Path]:
        """``map-seed<N>-<planner>.png``: the map of every kept drive."""
        from subterra.viz.drive import plot_drive_map

        return {f"map_{r.planner}": plot_drive_map(r, out / f"map-seed{r.seed}-{r.planner}.png") for r in self.kept}


def summarise_drives(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Groups drive rows by planner (and by injected fault, the planner column then reading
    ``planner, fault``, before each planner's total); counts successes and failures by cause."""
    table = []
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        if r.get("faults"):
            groups.setdefault(f"{r['planner']}, {','.join(r['faults'])}", []).append(r)
    for planner in dict.fromkeys(r["planner"] for r in rows):
        for label, rs in groups.items():
            if label.startswith(f"{planner}, "):
                table.append(_line(label, rs))
        table.append(_line(planner, [r for r in rows if r["planner"] == planner]))
    return table


def _line(planner: str, rs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """One line of the table over the drives ``rs``."""
    failures = [r["failure"] for r in rs if not r["success"]]
    risks = [r["accumulated_true_risk"] for r in rs]
    times = [r["time_s"] for r in rs if r["success"]]
    compute = [r["compute_ms_median"] for r in rs if r["compute_ms_median"] is not None]
    n = len(rs)
    successes = sum(bool(r["success"]) for r in rs)
    return {
        "planner": planner, "drives": n, "successes": successes, "success_rate": successes / n if n else 0.0,
        **{cause: failures.count(cause) for cause in FAILURE_CAUSES},
        "other_failures": sum(1 for f in failures if f not in FAILURE_CAUSES),
        "median_true_risk": float(np.median(risks)) if risks else None,
        "max_true_risk": float(np.max(risks)) if risks else None,
        "median_time_s": float(np.median(times)) if times else None,
        "recoveries": int(sum(r["recoveries"] for r in rs)),
        "compute_ms_median": float(np.median(compute)) if compute else None,
        "failed_drives": [f"seed {r['seed']}: {r['failure']}" for r in rs if not r["success"]],
        "odometry_switches": int(sum(r.get("odometry_switches") or 0 for r in rs)),
    }


def drive_batch(
    scenario: str = "mine",
    seeds: int | Sequence[int] = 100,
    *,
    planners: Sequence[str] = PLANNERS,
    time_limit_s: float | None = None,
    workers: int | None = None,
    keep_records: bool = True,
    progress: ProgressArg = True,
    log_path: str | os.PathLike[str] | None = None,
    engine: str | Engine = "threads",
    address: str | None = None,
    resume: bool = False,
    faults: str | Sequence[str] | None = None,
    faults_config: dict[str, Any] | None = None,
    navigator_config: dict[str, Any] | None = None,
) -> DriveBatchResult:
    """Drives every (seed, planner) and summarises. ``seeds``: a count (``0..n-1``) or
    explicit seeds. ``log_path``: the JSON-lines log, a row per drive as it lands (a fresh
    file; ``resume``: continue it and drive only what it does not hold). ``engine``:
    ``"threads"`` or ``"ray"`` (``address``: an existing Ray cluster); ``workers``: parallel
    drives (default: the CPU count). The first seed's full records are kept for the maps
    (``keep_records=False``: rows only, so every drive may run on a remote engine).
    ``faults``: fault names (:data:`subterra.sim.faults.FAULT_NAMES`, ``"all"`` for every one):
    the seeds take them in turn, one each (both planners the same), and the table has a line
    per planner and fault; ``faults_config``: their settings. ``navigator_config``: the
    navigator's settings for every drive (as :func:`subterra.drive.drive` takes them),
    checked before the first drive."""
    from subterra.sim.faults import parse_faults

    fault_list = parse_faults(faults)
    seed_values = seed_list(seeds)
    if not planners or any(p not in PLANNERS for p in planners):
        raise InputError(f"argument `planners` must name some of {', '.join(PLANNERS)}, got {list(planners)!r}")
    check_workers(workers)
    base = {"time_limit_s": time_limit_s}
    if navigator_config:
        from subterra import Navigator

        # A bad field fails here, naming it, not once per drive in the workers.
        Navigator(goal=(1.0, 0.0), config={k: v for k, v in navigator_config.items() if k != "terrain"},
                  terrain=navigator_config.get("terrain"))
        base["navigator_config"] = navigator_config
    jobs = [Job(DRIVE_JOB, {"scenario": scenario, "planner": planner, "seed": seed, **base},
                keep=keep_records and seed == seed_values[0])
            for seed in seed_values for planner in planners]
    if fault_list:
        jobs = [Job(DRIVE_JOB, {**job.params, "faults": [fault_list[(k // len(planners)) % len(fault_list)]],
                                "faults_config": faults_config}, keep=job.keep) for k, job in enumerate(jobs)]

    def status(rows: list[dict[str, Any]]) -> str:
        r = rows[-1]
        return f"seed {r['seed']} {r['planner']}: {'ok' if r['success'] else r['failure']}"

    run = run_batch(jobs, engine=engine, workers=workers, address=address, progress=progress,
                    desc=f"drive-batch {scenario}", unit="drive", status=status, log_path=log_path, resume=resume)
    kept = [run.records[job.id] for job in jobs if job.id in run.records]
    settings = {"seeds": seed_values, "planners": list(planners), "time_limit_s": time_limit_s, "engine": run.engine,
                "resumed": run.resumed, "faults": fault_list, "navigator_config": navigator_config or {}}
    return DriveBatchResult(scenario=scenario, rows=run.rows, table=summarise_drives(run.rows), kept=kept,
                            wall_s=run.wall_s, settings=settings)
