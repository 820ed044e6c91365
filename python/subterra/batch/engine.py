"""The batch engine: runs a list of jobs on an engine, streams their rows into the log and
the progress bar as they finish, and hands back the rows in job order.

Engines:

* ``threads`` (default): a thread pool in this process. The simulator, the filters and the
  navigator release the GIL, so flights and drives run in parallel on every core.
* ``ray``: tasks on a Ray cluster (``subterra[cluster]``), a local one started for the
  batch or an existing one (``address``); see :mod:`subterra.batch.ray_engine`.

Each job's row depends only on the job (its arguments carry the seed), never on the
engine, the number of workers or the order jobs finish in.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from contextlib import closing
from dataclasses import dataclass, field
from typing import Any, Protocol

from subterra.batch.jobs import Job, check_workers, run_job
from subterra.batch.log import JobLog
from subterra.batch.progress import Progress, ProgressArg
from subterra.errors import InputError

__all__ = ["ENGINES", "BatchRun", "Engine", "ThreadsEngine", "make_engine", "run_batch"]

#: The engines ``--engine`` takes.
ENGINES = ("threads", "ray")


class Engine(Protocol):
    """Runs jobs and yields ``(index, row, record)`` as each finishes (``record`` is the
    full record for jobs with ``keep``, else None)."""

    name: str

    def run(self, jobs: Sequence[Job]) -> Iterator[tuple[int, dict[str, Any], Any]]: ...

    def close(self) -> None: ...


class ThreadsEngine:
    """A pool of ``workers`` threads (default: the CPU count) in this process."""

    name = "threads"

    def __init__(self, workers: int | None = None) -> None:
        self.workers = check_workers(workers) or os.cpu_count() or 1

    def run(self, jobs: Sequence[Job]) -> Iterator[tuple[int, dict[str, Any], Any]]:
        if not jobs:
            return
        pool = ThreadPoolExecutor(max_workers=min(self.workers, len(jobs)))
        try:
            futures: dict[Future[tuple[dict[str, Any], Any]], int] = {pool.submit(run_job, job): i for i, job in enumerate(jobs)}
            pending = set(futures)
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for f in sorted(finished, key=futures.__getitem__):
                    i = futures[f]
                    row, record = f.result()
                    yield i, row, record if jobs[i].keep else None
        finally:
            # Interrupted or failed: drop the jobs not started (running ones end on their own).
            pool.shutdown(wait=True, cancel_futures=True)

    def close(self) -> None:
        pass


def make_engine(engine: str | Engine = "threads", *, workers: int | None = None, address: str | None = None) -> Engine:
    """The engine named ``engine`` (an :class:`Engine` is returned as is). ``address``
    (Ray only): join this cluster instead of starting a local one."""
    if not isinstance(engine, str):
        return engine
    if engine == "threads":
        if address is not None:
            raise InputError("argument `address` needs the ray engine (--engine ray)")
        return ThreadsEngine(workers)
    if engine == "ray":
        from subterra.batch.ray_engine import RayEngine

        return RayEngine(workers=workers, address=address)
    raise InputError(f"argument `engine` must be one of {', '.join(ENGINES)}, got {engine!r}")


@dataclass
class BatchRun:
    """What :func:`run_batch` ran: ``rows`` in job order (those found in the log when
    resuming included), ``records`` (full records of the ``keep`` jobs run now, by job id),
    ``resumed`` (how many rows came from the log), ``wall_s`` and the engine's name."""

    rows: list[dict[str, Any]]
    records: dict[str, Any] = field(default_factory=dict)
    resumed: int = 0
    wall_s: float = 0.0
    engine: str = "threads"


def run_batch(
    jobs: Sequence[Job],
    *,
    engine: str | Engine = "threads",
    workers: int | None = None,
    address: str | None = None,
    progress: ProgressArg = True,
    desc: str = "batch",
    unit: str = "job",
    status: Callable[[list[dict[str, Any]]], str] | None = None,
    log_path: str | os.PathLike[str] | None = None,
    resume: bool = False,
) -> BatchRun:
    """Runs ``jobs`` on ``engine`` and returns their rows in job order.

    ``log_path``: the JSON-lines log, a row per job as it finishes (a fresh file per run).
    ``resume``: continue that log instead; jobs whose rows it holds are not run again.
    ``progress``: a bar on stderr (``desc``, ``unit``; ``status(rows so far)`` as its
    postfix), False, or a callback ``(done, total, row)``.
    """
    jobs = list(jobs)
    ids = [job.id for job in jobs]
    if len(set(ids)) != len(ids):
        raise InputError("argument `jobs` holds the same job twice (same function and arguments)")
    if resume and log_path is None:
        raise InputError("argument `resume` needs a log to resume from (`log_path`, --out)")
    started = time.perf_counter()
    log = JobLog(log_path, ids, resume=resume)
    rows: list[dict[str, Any] | None] = [log.done.get(i) for i in ids]
    todo = [n for n, row in enumerate(rows) if row is None]
    bar = Progress(progress, len(jobs), desc=desc, unit=unit, done=len(jobs) - len(todo), status=status)
    for row in rows:
        if row is not None:
            bar.rows.append(row)
    records: dict[str, Any] = {}
    runner = None
    try:
        if todo:
            runner = make_engine(engine, workers=workers, address=address)
            # closing(): a failure here stops the engine's jobs at once, not when the generator is collected.
            with closing(runner.run([jobs[n] for n in todo])) as finished:
                for k, row, record in finished:
                    n = todo[k]
                    rows[n] = row
                    if record is not None:
                        records[ids[n]] = record
                    log.write(row)
                    bar.update(row)
    finally:
        bar.close()
        log.close()
        if runner is not None and runner is not engine:  # an engine handed in stays open for the caller
            runner.close()
    name = engine if isinstance(engine, str) else engine.name
    return BatchRun(rows=[r for r in rows if r is not None], records=records, resumed=len(jobs) - len(todo),
                    wall_s=time.perf_counter() - started, engine=name)
