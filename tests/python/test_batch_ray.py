"""The Ray engine: a 4-job drive-batch and a 4-job fly-batch on a local Ray with 2 CPUs
give every job the same row, bit for bit, as the threads engine (wall-clock timings
aside), so does a small sweep, and a batch resumed on Ray runs only the jobs its log lacks.

`make test` installs Ray (the `cluster` extra), so these run everywhere the suite runs."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from subterra.batch import sweep
from subterra.drive.batch import drive_batch
from subterra.flight.batch import fly_batch

try:
    import ray  # noqa: F401

    from subterra.batch.ray_engine import RayEngine
except ImportError:  # pragma: no cover - the suite installs it
    pytest.fail("Ray is not installed: pip install 'subterra[cluster]' (`make test` does)", pytrace=False)

#: Row fields that measure wall-clock time, the only ones that may differ between runs.
TIMING = {"wall_s", "compute_ms_median", "compute_ms_p99", "map_ms_median", "plan_ms_median", "track_ms_median"}


def _outcome(rows):
    return {r["job"]: {k: v for k, v in r.items() if k not in TIMING} for r in rows}


@pytest.fixture(scope="module")
def ray_engine():
    engine = RayEngine(workers=2)  # a local Ray with 2 CPUs, started by the engine
    yield engine
    engine.close()


@pytest.fixture(scope="module")
def threads_drives(tmp_path_factory):
    """The drives on threads, with their log."""
    log = tmp_path_factory.mktemp("drives") / "drives.jsonl"
    return _drives(engine="threads", workers=2, log_path=log), log


def _drives(**kw):
    return drive_batch("mine", [0, 1], planners=("risk-aware", "additive"), time_limit_s=3.0, keep_records=False,
                       progress=False, **kw)


def _flights(**kw):
    return fly_batch("highbay", ["A-B", "B-C"], [3, 4], controllers=("apf-pf",), noises=("d435",), rate_hz=10.0,
                     time_limit_s=4.0, keep_records=False, progress=False, **kw)


def test_ray_gives_every_job_the_rows_of_threads(ray_engine, threads_drives):
    import ray

    assert ray.cluster_resources().get("CPU") == 2
    for batch in (_drives, _flights):
        threads = threads_drives[0] if batch is _drives else batch(engine="threads", workers=2)
        on_ray = batch(engine=ray_engine)
        assert len(threads.rows) == len(on_ray.rows) == 4
        assert on_ray.settings["engine"] == "ray"
        assert _outcome(on_ray.rows) == _outcome(threads.rows)
        # The comparison covers the outcome, not only the names of the jobs.
        assert {"time_s", "success", "failure", "seed"} <= set(next(iter(_outcome(on_ray.rows).values())))
        assert len({r["seed"] for r in on_ray.rows}) == 2
        untimed = [[{k: v for k, v in t.items() if "compute" not in k} for t in b.table] for b in (on_ray, threads)]
        assert untimed[0] == untimed[1]


def test_resume_on_ray_runs_only_the_missing_jobs(ray_engine, threads_drives, tmp_path):
    full, full_log = threads_drives
    log = tmp_path / "drives.jsonl"
    lines = full_log.read_text().splitlines()
    log.write_text("\n".join(lines[:2]) + "\n")  # interrupted after two drives
    resumed = _drives(engine=ray_engine, log_path=log, resume=True)
    assert resumed.settings["resumed"] == 2
    relogged = [json.loads(line) for line in log.read_text().splitlines()]
    assert len(relogged) == 4 and len({r["job"] for r in relogged}) == 4
    assert _outcome(resumed.rows) == _outcome(full.rows)


def test_a_sweep_on_ray_gives_the_rows_of_threads(ray_engine):
    spec = {"kind": "drive", "seeds": [2], "time_limit_s": 3.0, "grid": {"recovery.r_inst": [0.5, 0.7]}}
    threads = sweep(spec, engine="threads", workers=2, progress=False)
    on_ray = sweep(spec, engine=ray_engine, progress=False)
    assert len(on_ray.rows) == 2 and on_ray.settings["engine"] == "ray"
    assert _outcome(on_ray.rows) == _outcome(threads.rows)
    assert [r["sweep"] for r in on_ray.rows] == [r["sweep"] for r in threads.rows]


def test_a_batch_joins_a_running_cluster_with_address(ray_engine, tmp_path):
    import ray

    address = ray.get_runtime_context().gcs_address
    out = tmp_path / "joined"
    argv = ["drive-batch", "--seeds", "1", "--planners", "additive", "--time-limit", "3", "--no-plots",
            "--engine", "ray", "--address", address, "--out", str(out)]
    done = subprocess.run([sys.executable, "-m", "subterra.cli", *argv], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    data = json.loads((out / "results.json").read_text())
    assert data["settings"]["engine"] == "ray" and len(data["drives"]) == 1
    assert "drive-batch mine: 1/1 drives" in done.stderr  # progress on stderr, the table on stdout
    assert "| additive | 1 |" in done.stdout
