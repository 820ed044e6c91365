"""Many randomized drives (`subterra drive-batch`): every seed of a scenario driven with the
risk-aware planner and with the additive-cost baseline, on the same worlds and noise.

Each seed is a new world (the built-in generators are seeded) and a new lidar-noise stream.
Drives run in parallel threads (the simulator and the navigator release the GIL); results
do not depend on the number of workers.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from subterra.drive.run import PLANNERS, DriveResult, drive
from subterra.errors import InputError

__all__ = ["DriveBatchResult", "FAILURE_CAUSES", "drive_batch", "summarise_drives"]

#: Failure causes counted in the table; anything else is "other".
FAILURE_CAUSES = ("rollover", "fall", "collision", "timeout", "gave_up", "returned_home")


@dataclass
class DriveBatchResult:
    """Per-drive rows (``DriveResult.summary()`` dicts), the summary table, and the full
    records of the first seed (for plotting)."""

    scenario: str
    rows: list[dict[str, Any]]
    table: list[dict[str, Any]]
    kept: list[DriveResult] = field(default_factory=list)
    wall_s: float = 0.0
    settings: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"scenario": self.scenario, "settings": self.settings, "wall_s": round(self.wall_s, 1),
                "summary": self.table, "drives": self.rows}

    def markdown(self) -> str:
        """The results table, one line per planner."""
        head = ("| planner | drives | success | rollovers | falls | collisions | timeouts | gave up / home "
                "| accumulated true risk (median / max) | time to goal [s] (median) | recoveries | compute [ms] (median) |")
        lines = [head, "|" + "---|" * 12]
        for r in self.table:
            risk = "-" if r["median_true_risk"] is None else f"{r['median_true_risk']:.3f} / {r['max_true_risk']:.3f}"
            t = "-" if r["median_time_s"] is None else f"{r['median_time_s']:.1f}"
            c = "-" if r["compute_ms_median"] is None else f"{r['compute_ms_median']:.1f}"
            lines.append(
                f"| {r['planner']} | {r['drives']} | {r['successes']} ({100 * r['success_rate']:.0f}%) | {r['rollover']} "
                f"| {r['fall']} | {r['collision']} | {r['timeout']} | {r['gave_up']} / {r['returned_home']} | {risk} | {t} "
                f"| {r['recoveries']} | {c} |"
            )
        failed = [f"- {r['planner']}: " + "; ".join(r["failed_drives"]) for r in self.table if r["failed_drives"]]
        return "\n".join(lines) + "\n" + ("\nFailures:\n" + "\n".join(failed) + "\n" if failed else "")

    def save(self, out_dir: str | os.PathLike[str], *, plots: bool = True) -> dict[str, Path]:
        """Writes ``results.json``, ``results.md`` and, with ``plots``, the map of every kept drive."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        written = {"json": out / "results.json", "markdown": out / "results.md"}
        written["json"].write_text(json.dumps(self.to_json(), indent=2) + "\n", encoding="utf-8")
        written["markdown"].write_text(self.markdown(), encoding="utf-8")
        if plots:
            from subterra.viz.drive import plot_drive_map

            for r in self.kept:
                written[f"map_{r.planner}"] = plot_drive_map(r, out / f"map-seed{r.seed}-{r.planner}.png")
        return written


def summarise_drives(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Groups drive rows by planner; counts successes and failures by cause."""
    table = []
    for planner in dict.fromkeys(r["planner"] for r in rows):
        rs = [r for r in rows if r["planner"] == planner]
        failures = [r["failure"] for r in rs if not r["success"]]
        risks = [r["accumulated_true_risk"] for r in rs]
        times = [r["time_s"] for r in rs if r["success"]]
        compute = [r["compute_ms_median"] for r in rs if r["compute_ms_median"] is not None]
        n = len(rs)
        successes = sum(bool(r["success"]) for r in rs)
        table.append({
            "planner": planner, "drives": n, "successes": successes, "success_rate": successes / n if n else 0.0,
            **{cause: failures.count(cause) for cause in FAILURE_CAUSES},
            "other_failures": sum(1 for f in failures if f not in FAILURE_CAUSES),
            "median_true_risk": float(np.median(risks)) if risks else None,
            "max_true_risk": float(np.max(risks)) if risks else None,
            "median_time_s": float(np.median(times)) if times else None,
            "recoveries": int(sum(r["recoveries"] for r in rs)),
            "compute_ms_median": float(np.median(compute)) if compute else None,
            "failed_drives": [f"seed {r['seed']}: {r['failure']}" for r in rs if not r["success"]],
        })
    return table


def drive_batch(
    scenario: str = "mine",
    seeds: int | Sequence[int] = 100,
    *,
    planners: Sequence[str] = PLANNERS,
    time_limit_s: float | None = None,
    workers: int | None = None,
    progress: bool | Callable[[int, int, dict[str, Any]], None] = True,
    log_path: str | os.PathLike[str] | None = None,
) -> DriveBatchResult:
    """Drives every (seed, planner) and summarises. ``seeds``: a count (``0..n-1``) or
    explicit seeds. ``workers``: parallel drives (default: the CPU count). ``log_path``: a
    JSON-lines file appended as each drive lands (an interrupted batch keeps what it drove)."""
    seed_list = list(range(seeds)) if isinstance(seeds, int) else [int(s) for s in seeds]
    if not seed_list or any(s < 0 for s in seed_list):
        raise InputError(f"argument `seeds` must be a count >= 1 or non-negative seeds, got {seeds!r}")
    if not planners or any(p not in PLANNERS for p in planners):
        raise InputError(f"argument `planners` must name some of {', '.join(PLANNERS)}, got {list(planners)!r}")
    if workers is not None and not (isinstance(workers, int) and 1 <= workers <= 256):
        raise InputError(f"argument `workers` must be an integer in 1..256, got {workers!r}")
    jobs = [(seed, planner) for seed in seed_list for planner in planners]
    started = time.perf_counter()

    def run(job: tuple[int, str]) -> DriveResult:
        seed, planner = job
        return drive(scenario, planner=planner, seed=seed, time_limit_s=time_limit_s)

    bar, plain_every = None, 0
    if progress is True:
        from tqdm import tqdm

        bar = tqdm(total=len(jobs), desc=f"drive-batch {scenario}", unit="drive", disable=None)
        if bar.disable:
            bar, plain_every = None, max(1, len(jobs) // 20)
    rows: list[dict[str, Any]] = []
    kept: list[DriveResult] = []
    log = None
    if log_path is not None:
        Path(log_path).parent.mkdir(parents=True, exist_ok=True)
        log = Path(log_path).open("a", encoding="utf-8")
    try:
        with ThreadPoolExecutor(max_workers=workers or os.cpu_count() or 1) as pool:
            for done, result in enumerate(pool.map(run, jobs), start=1):
                row = result.summary()
                rows.append(row)
                if result.seed == seed_list[0]:
                    kept.append(result)
                if log is not None:
                    log.write(json.dumps(row) + "\n")
                    log.flush()
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix_str(f"seed {row['seed']} {row['planner']}: {'ok' if row['success'] else row['failure']}")
                elif plain_every and (done % plain_every == 0 or done == len(jobs)):
                    print(f"drive-batch {scenario}: {done}/{len(jobs)} drives", flush=True)
                elif callable(progress):
                    progress(done, len(jobs), row)
    finally:
        if bar is not None:
            bar.close()
        if log is not None:
            log.close()
    settings = {"seeds": seed_list, "planners": list(planners), "time_limit_s": time_limit_s}
    return DriveBatchResult(scenario=scenario, rows=rows, table=summarise_drives(rows), kept=kept,
                            wall_s=time.perf_counter() - started, settings=settings)
