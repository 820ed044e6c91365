"""The Ray engine: every job a Ray task (one CPU each), on a local Ray started for the batch
(as many workers as cores, or ``workers``) or on an existing cluster (``address``).

Rows stream back as tasks finish. The full records of ``keep`` jobs (for figures) hold
simulator objects that do not cross processes, so those few jobs run in this process, in a
thread beside the tasks; they give the same rows wherever they run. If Ray is already
initialised in this process (``ray.init`` by the caller), the engine uses that and leaves
it running.

Every node of a cluster needs subterra installed in the Python that Ray runs
(docs/batches.md); a job function is imported on the worker by its name.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

from subterra.batch.jobs import Job, check_workers, run_job
from subterra.errors import InputError

__all__ = ["RayEngine"]

#: Object store of a local Ray: rows are small; Ray's default (30 % of the memory) is not needed.
LOCAL_OBJECT_STORE_BYTES = 256 * 1024 * 1024


def _row(job: Job) -> dict[str, Any]:
    """The task: run the job on a worker, send back its row."""
    return run_job(job)[0]


class RayEngine:
    """``workers``: CPUs of the local Ray (default: the CPU count), or on a cluster the
    most tasks in flight at once (default: no cap, Ray schedules one per free CPU).
    ``address``: a cluster to join (``"auto"``, ``"ray://head:10001"``, ``"10.0.0.1:6379"``)."""

    name = "ray"

    def __init__(self, workers: int | None = None, address: str | None = None) -> None:
        try:
            import ray
        except ImportError as exc:
            raise InputError("the ray engine (--engine ray) needs Ray: pip install 'subterra[cluster]'") from exc
        self._ray = ray
        self.workers = check_workers(workers)
        self._started = False
        if not ray.is_initialized():
            if address is not None:
                ray.init(address=address, logging_level=logging.WARNING)
            else:
                ray.init(num_cpus=self.workers or os.cpu_count() or 1, include_dashboard=False,
                         object_store_memory=LOCAL_OBJECT_STORE_BYTES, logging_level=logging.WARNING)
            self._started = True
            self._cap = self.workers if address is not None else None
        else:
            self._cap = self.workers
        self._task = ray.remote(num_cpus=1, max_retries=0)(_row)

    def run(self, jobs: Sequence[Job]) -> Iterator[tuple[int, dict[str, Any], Any]]:
        ray = self._ray
        local = [i for i, job in enumerate(jobs) if job.keep]
        remote = [i for i, job in enumerate(jobs) if not job.keep]
        pool = ThreadPoolExecutor(max_workers=1) if local else None
        here: dict[Future[tuple[dict[str, Any], Any]], int] = {}
        if pool is not None:
            here = {pool.submit(run_job, jobs[i]): i for i in local}
        queue = list(reversed(remote))
        flying: dict[Any, int] = {}
        try:
            while queue or flying or here:
                while queue and (self._cap is None or len(flying) < self._cap):
                    i = queue.pop()
                    flying[self._task.remote(jobs[i])] = i
                if flying:
                    ready, _ = ray.wait(list(flying), num_returns=1, timeout=0.2 if here else None)
                    for ref in ready:
                        i = flying.pop(ref)
                        yield i, ray.get(ref), None
                for f in [f for f in here if f.done()]:
                    i = here.pop(f)
                    row, record = f.result()
                    yield i, row, record
                if here and not flying and not queue:
                    f = next(iter(here))
                    f.result()  # only local jobs left: wait for them here
        finally:
            for ref in flying:
                ray.cancel(ref)
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)

    def close(self) -> None:
        if self._started:
            self._ray.shutdown()
            self._started = False
