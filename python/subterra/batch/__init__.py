"""Batches of seeded runs: jobs, the engines that run them (threads here, or Ray), the
JSON-lines log that lets a batch resume, progress on stderr, and the results files.

>>> from subterra.batch import Job, run_batch
>>> jobs = [Job("subterra.flight.run:fly", {"scenario": "highbay", "route": "A-B", "seed": s}) for s in range(4)]
>>> run = run_batch(jobs, engine="threads", log_path="runs/x/flights.jsonl")
>>> [row["success"] for row in run.rows]

``subterra fly-batch``, ``drive-batch`` and ``sweep`` (:func:`sweep`: a grid or random
search over config fields) are built on it.
"""

from __future__ import annotations

from subterra.batch.engine import ENGINES, BatchRun, Engine, ThreadsEngine, make_engine, run_batch
from subterra.batch.jobs import Job, check_workers, run_job, seed_list
from subterra.batch.progress import ProgressArg
from subterra.batch.results import BatchReport, markdown_table
from subterra.batch.sweep import SweepResult, sweep
from subterra.batch.sweep_spec import SweepSpec, load_sweep

__all__ = [
    "ENGINES",
    "BatchReport",
    "BatchRun",
    "Engine",
    "Job",
    "ProgressArg",
    "SweepResult",
    "SweepSpec",
    "ThreadsEngine",
    "check_workers",
    "load_sweep",
    "make_engine",
    "markdown_table",
    "run_batch",
    "run_job",
    "seed_list",
    "sweep",
]
