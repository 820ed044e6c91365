"""The progress of a batch, on stderr (stdout is left to the results).

On a terminal: a tqdm bar with a status line (e.g. successes and collisions so far per
controller). Elsewhere (a log file, CI): a plain line every ~5 % of the jobs. Or a callback
``(done, total, row)`` for programs, or nothing.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any

__all__ = ["Progress", "ProgressArg"]

#: ``True`` (bar or plain lines on stderr), ``False`` (silent) or ``callback(done, total, row)``.
ProgressArg = bool | Callable[[int, int, dict[str, Any]], None]


class Progress:
    """Counts finished jobs; ``done`` of them may be done already (a resumed batch)."""

    def __init__(self, progress: ProgressArg, total: int, *, desc: str, unit: str = "job", done: int = 0,
                 status: Callable[[list[dict[str, Any]]], str] | None = None) -> None:
        self.total, self.done, self.desc, self.unit, self.status = total, done, desc, unit, status
        self.callback = progress if callable(progress) and progress is not True else None
        self.bar: Any = None
        self.plain_every = 0
        self.started = time.perf_counter()
        self.rows: list[dict[str, Any]] = []
        self._status, self._status_at = "", -1.0
        if progress is True:
            from subterra._extras import tqdm

            self.bar = tqdm(total=total, initial=done, desc=desc, unit=unit, disable=None, file=sys.stderr)
            if self.bar.disable:
                self.bar, self.plain_every = None, max(1, total // 20)

    def update(self, row: dict[str, Any]) -> None:
        self.done += 1
        self.rows.append(row)
        if self.bar is not None:
            self.bar.set_postfix_str(self._status_now(), refresh=False)
            self.bar.update(1)
        elif self.plain_every and (self.done % self.plain_every == 0 or self.done == self.total):
            status = self.status(self.rows) if self.status is not None else ""
            tail = f"; {status}" if status else ""
            print(f"{self.desc}: {self.done}/{self.total} {self.unit}s, {time.perf_counter() - self.started:.0f} s{tail}",
                  file=sys.stderr, flush=True)
        elif self.callback is not None:
            self.callback(self.done, self.total, row)

    def _status_now(self) -> str:
        """The bar's status, recomputed at most twice a second (it reads every row so far)."""
        if self.status is None:
            return ""
        now = time.perf_counter()
        if now - self._status_at >= 0.5 or self.done == self.total:
            self._status, self._status_at = self.status(self.rows), now
        return self._status

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
