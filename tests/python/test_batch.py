"""The batch engine (`subterra.batch`): jobs, the threads engine, the JSON-lines log with
fresh runs and `--resume`, progress on stderr, and the results files."""

from __future__ import annotations

import json
import threading
import time

import pytest

from subterra.batch import BatchReport, Job, ThreadsEngine, make_engine, markdown_table, run_batch, seed_list
from subterra.errors import InputError

CALLS: list[int] = []
_LOCK = threading.Lock()


class _Record:
    def __init__(self, x: int) -> None:
        self.x = x

    def summary(self) -> dict:
        return {"x": self.x, "square": self.x * self.x}


def square(x: int, delay_s: float = 0.0) -> _Record:
    """A job function: later jobs finish first when their delay is shorter."""
    time.sleep(delay_s)
    with _LOCK:
        CALLS.append(x)
    return _Record(x)


def explode(x: int) -> _Record:
    if x == 2:
        raise RuntimeError("job 2 failed")
    return _Record(x)


def _jobs(n: int, *, keep_first: bool = False) -> list[Job]:
    return [Job("test_batch:square", {"x": x, "delay_s": 0.02 * (n - x)}, keep=keep_first and x == 0) for x in range(n)]


@pytest.fixture(autouse=True)
def _clear_calls():
    CALLS.clear()


def test_job_ids_name_function_and_arguments():
    a = Job("test_batch:square", {"x": 1, "delay_s": 0.0})
    assert a.id == Job("test_batch:square", {"delay_s": 0.0, "x": 1}).id  # argument order does not matter
    assert a.id != Job("test_batch:square", {"x": 2, "delay_s": 0.0}).id
    assert a.id != Job("test_other:square", {"x": 1, "delay_s": 0.0}).id
    with pytest.raises(InputError, match="params.world"):
        Job("test_batch:square", {"x": 1, "world": object()})
    with pytest.raises(InputError, match="finite"):
        Job("test_batch:square", {"x": float("nan")})
    with pytest.raises(InputError, match="module:function"):
        Job("square", {"x": 1})


def test_rows_come_back_in_job_order_whatever_finishes_first(tmp_path):
    log = tmp_path / "jobs.jsonl"
    run = run_batch(_jobs(5, keep_first=True), workers=3, progress=False, log_path=log)
    assert [r["x"] for r in run.rows] == [0, 1, 2, 3, 4]
    assert [r["square"] for r in run.rows] == [0, 1, 4, 9, 16]
    # The log is written as jobs land: the short jobs (the last ones) first.
    logged = [json.loads(line) for line in log.read_text().splitlines()]
    assert sorted(logged, key=lambda r: r["x"]) == run.rows
    assert [r["x"] for r in logged] != [0, 1, 2, 3, 4]
    # Full records only for the jobs that asked for them.
    assert list(run.records) == [run.rows[0]["job"]] and run.records[run.rows[0]["job"]].x == 0
    assert run.resumed == 0 and run.engine == "threads"


def test_every_run_starts_a_fresh_log_and_keeps_the_old_one_aside(tmp_path):
    log = tmp_path / "jobs.jsonl"
    run_batch(_jobs(2), progress=False, log_path=log)
    run_batch(_jobs(3), progress=False, log_path=log)
    assert len(log.read_text().splitlines()) == 3
    assert len((tmp_path / "jobs.jsonl.prev").read_text().splitlines()) == 2


def test_resume_runs_only_the_missing_jobs(tmp_path):
    log = tmp_path / "jobs.jsonl"
    jobs = _jobs(6)
    first = run_batch(jobs[:4], progress=False, log_path=log)
    # An interruption while writing leaves a cut line; a row of another batch is ignored.
    with log.open("a") as f:
        f.write(json.dumps({"job": "0123456789abcdef", "x": 99}) + "\n")
        f.write('{"x": 5, "squ')
    CALLS.clear()
    seen = []
    again = run_batch(jobs, progress=lambda done, total, row: seen.append((done, total)), log_path=log, resume=True)
    assert sorted(CALLS) == [4, 5]
    assert again.resumed == 4
    assert again.rows[:4] == first.rows and [r["x"] for r in again.rows] == [0, 1, 2, 3, 4, 5]
    assert seen == [(5, 6), (6, 6)]
    lines = log.read_text().splitlines()
    assert len(lines) == 7 and all(json.loads(line) for line in lines)  # the cut line is gone
    CALLS.clear()
    run_batch(jobs, progress=False, log_path=log, resume=True)
    assert CALLS == []


def test_a_failing_job_stops_the_batch_and_the_log_keeps_the_rest(tmp_path):
    log = tmp_path / "jobs.jsonl"
    jobs = [Job("test_batch:explode", {"x": x}) for x in range(4)]
    with pytest.raises(RuntimeError, match="job 2 failed"):
        run_batch(jobs, workers=1, progress=False, log_path=log)
    assert [json.loads(line)["x"] for line in log.read_text().splitlines()] == [0, 1]


def test_bad_arguments_name_the_argument(tmp_path):
    with pytest.raises(InputError, match="jobs"):
        run_batch(_jobs(2) + _jobs(2)[:1], progress=False)
    with pytest.raises(InputError, match="resume"):
        run_batch(_jobs(1), progress=False, resume=True)
    with pytest.raises(InputError, match="engine"):
        run_batch(_jobs(1), engine="spark", progress=False)
    with pytest.raises(InputError, match="address"):
        make_engine("threads", address="auto")
    with pytest.raises(InputError, match="workers"):
        ThreadsEngine(0)
    with pytest.raises(InputError, match="cannot be imported"):
        run_batch([Job("subterra.nothing:here", {})], progress=False)
    with pytest.raises(InputError, match="seeds"):
        seed_list([1, 1])
    with pytest.raises(InputError, match="seeds"):
        seed_list(0)
    assert seed_list(3) == [0, 1, 2] and seed_list((5, 7)) == [5, 7]
    # Counts and seeds beyond what a batch or a 64-bit seed holds (the sweep_file fuzz
    # target found an OverflowError from range() with a 100-digit count).
    with pytest.raises(InputError, match=r"asks for 10+ seeds; a batch takes at most 1,000,000"):
        seed_list(10**30)
    for bad in ([2**63], [True, 2], [1.0], "012"):
        with pytest.raises(InputError, match="argument `seeds`"):
            seed_list(bad)


def test_progress_goes_to_stderr_as_plain_lines_off_a_terminal(capsys):
    run_batch(_jobs(4), progress=True, desc="test-batch", unit="square", status=lambda rows: f"{len(rows)} rows")
    out, err = capsys.readouterr()
    assert out == ""
    assert "test-batch: 4/4 squares" in err and "4 rows" in err


def test_ray_engine_without_ray_names_the_extra(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails as if it were not installed
    with pytest.raises(InputError, match=r"subterra\[cluster\]") as info:
        run_batch(_jobs(1), engine="ray", progress=False)
    assert "\n" not in str(info.value)


def test_reports_write_json_and_markdown(tmp_path):
    class Report(BatchReport):
        ROWS = "squares"

        def markdown(self) -> str:
            return markdown_table(("x", "square"), [(r["x"], r["square"]) for r in self.rows])

    rows = run_batch(_jobs(2), progress=False).rows
    written = Report(scenario="none", rows=rows, table=[], settings={"n": 2}).save(tmp_path / "out")
    data = json.loads(written["json"].read_text())
    assert data["squares"] == rows and data["settings"] == {"n": 2}
    assert written["markdown"].read_text() == "| x | square |\n|---|---|\n| 0 | 0 |\n| 1 | 1 |\n"
