"""Jobs: one seeded run (a flight, a drive) named by the function that runs it and its
keyword arguments.

A job is plain data, so it travels to a worker thread, a Ray worker process or another
machine unchanged, and its id (a hash of the function and the arguments) names it in the
JSON-lines log: a resumed batch recognises the jobs it has already run by their ids, and a
batch with other settings never mistakes another batch's rows for its own.

The function is given as ``"module:function"`` and imported where the job runs; it takes
the job's arguments as keywords and returns a record with a ``summary()`` method that gives
the job's row (a JSON-ready dict). Everything that makes a run differ is in the arguments
(the seed among them), so the row depends on nothing but the job.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from subterra.errors import InputError

__all__ = ["Job", "resolve", "run_job", "seed_list", "check_workers"]


def _plain(value: Any, where: str) -> Any:
    """``value`` checked to be JSON data (what crosses to a worker and into the log)."""
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise InputError(f"job argument `{where}` must be finite, got {value!r}")
        return value
    if isinstance(value, (list, tuple)):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, Mapping):
        return {str(k): _plain(v, f"{where}.{k}") for k, v in value.items()}
    raise InputError(f"job argument `{where}` must be JSON data (numbers, strings, lists, tables), got {type(value).__name__}")


@dataclass(frozen=True)
class Job:
    """One run: ``fn`` (``"module:function"``) called with ``params`` as keywords.
    ``keep``: the caller wants the full record back, not only the row (for figures); such
    a job runs in the calling process."""

    fn: str
    params: Mapping[str, Any]
    keep: bool = False
    id: str = field(init=False, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.fn, str) or self.fn.count(":") != 1:
            raise InputError(f"job function must be given as 'module:function', got {self.fn!r}")
        params = _plain(dict(self.params), "params")
        object.__setattr__(self, "params", params)
        text = json.dumps({"fn": self.fn, "params": params}, sort_keys=True, separators=(",", ":"))
        object.__setattr__(self, "id", hashlib.sha256(text.encode()).hexdigest()[:16])


_RESOLVED: dict[str, Callable[..., Any]] = {}


def resolve(fn: str) -> Callable[..., Any]:
    """The function a job names (imported once per process)."""
    if fn not in _RESOLVED:
        module, _, name = fn.partition(":")
        try:
            _RESOLVED[fn] = getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError) as exc:
            raise InputError(f"job function {fn!r} cannot be imported: {exc}") from exc
    return _RESOLVED[fn]


def run_job(job: Job) -> tuple[dict[str, Any], Any]:
    """Runs ``job`` here: its row (the record's ``summary()`` with the job id under
    ``"job"``) and the full record."""
    record = resolve(job.fn)(**job.params)
    row = dict(record.summary())
    row["job"] = job.id
    return row, record


def seed_list(seeds: int | Sequence[int], name: str = "seeds") -> list[int]:
    """``seeds``: a count (``0..n-1``) or explicit non-negative seeds, without repeats."""
    if isinstance(seeds, bool):
        raise InputError(f"argument `{name}` must be a count >= 1 or non-negative seeds, got {seeds!r}")
    if isinstance(seeds, int):
        out = list(range(seeds))
    else:
        try:
            out = [int(s) for s in seeds]
        except (TypeError, ValueError) as exc:
            raise InputError(f"argument `{name}` must be a count >= 1 or non-negative seeds, got {seeds!r}") from exc
    if not out or any(s < 0 for s in out) or len(set(out)) != len(out):
        raise InputError(f"argument `{name}` must be a count >= 1 or distinct non-negative seeds, got {seeds!r}")
    return out


def check_workers(workers: int | None) -> int | None:
    """``workers`` checked: None (the engine's default) or an integer in 1..256."""
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= 256):
        raise InputError(f"argument `workers` must be an integer in 1..256, got {workers!r}")
    return workers
