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
import operator
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from subterra.errors import InputError

__all__ = ["Job", "resolve", "run_job", "seed_list", "seed_range", "check_workers", "MAX_SEEDS", "MAX_SEED"]


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


MAX_SEEDS = 1_000_000
"""Most seeds one batch takes (a million runs is past any study; more is a typo)."""
MAX_SEED = 2**63 - 1
"""Largest seed (a signed 64-bit integer: NumPy, JSON readers and the core all hold it)."""


def seed_list(seeds: int | Sequence[int], name: str = "seeds") -> list[int]:
    """``seeds``: a count (``0..n-1``) or explicit non-negative seeds, without repeats;
    at most :data:`MAX_SEEDS` of them, each at most :data:`MAX_SEED`."""
    if isinstance(seeds, bool):
        raise InputError(f"argument `{name}` must be a count >= 1 or non-negative seeds, got {seeds!r}")
    if isinstance(seeds, int):
        if seeds > MAX_SEEDS:
            raise InputError(f"argument `{name}` asks for {seeds} seeds; a batch takes at most {MAX_SEEDS:,}")
        out = list(range(seeds))
    else:
        try:
            if len(seeds) > MAX_SEEDS:
                raise InputError(f"argument `{name}` holds {len(seeds)} seeds; a batch takes at most {MAX_SEEDS:,}")
            out = [operator.index(s) if not isinstance(s, bool) else _not_a_seed(s) for s in seeds]
        except (TypeError, ValueError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(f"argument `{name}` must be a count >= 1 or non-negative integer seeds, got {seeds!r}") from exc
    if not out or any(s < 0 or s > MAX_SEED for s in out) or len(set(out)) != len(out):
        raise InputError(
            f"argument `{name}` must be a count >= 1 or distinct seeds in 0..2^63-1, got {_short(seeds)}"
        )
    return out


def seed_range(first: Any, count: Any, name: str = "seeds") -> list[int]:
    """``count`` consecutive seeds from ``first``, checked as :func:`seed_list` checks."""
    for label, value, low in (("first", first, 0), ("count", count, 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise InputError(f"argument `{name}.{label}` must be an integer >= {low}, got {value!r}")
    if count > MAX_SEEDS:
        raise InputError(f"argument `{name}.count` asks for {count} seeds; a batch takes at most {MAX_SEEDS:,}")
    if first + count - 1 > MAX_SEED:
        raise InputError(f"argument `{name}`: seeds {first}..{first + count - 1} pass the largest seed 2^63-1")
    return list(range(first, first + count))


def _not_a_seed(value: Any) -> int:
    raise TypeError(f"{value!r} is not a seed")


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else f"{text[:60]}... ({len(text)} characters)"


def check_workers(workers: int | None) -> int | None:
    """``workers`` checked: None (the engine's default) or an integer in 1..256."""
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= 256):
        raise InputError(f"argument `workers` must be an integer in 1..256, got {workers!r}")
    return workers
