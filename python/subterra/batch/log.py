"""The JSON-lines log of a batch: one row per finished job, written as it lands, so an
interrupted batch keeps what it ran.

Every run starts a fresh log (a log already there is moved aside to ``<name>.prev``, so a
forgotten ``--resume`` loses nothing), unless it resumes: then the rows already in the log
whose job ids belong to this batch count as done, and the new rows are appended. Rows of
other jobs (another batch's settings) are left in the file and ignored.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import IO, Any

from subterra.errors import FileFormatError

__all__ = ["JobLog"]


class JobLog:
    """``path``: the ``.jsonl`` file (None: no log). ``done``: the rows of this batch's
    jobs found in the log when resuming, by job id."""

    def __init__(self, path: str | os.PathLike[str] | None, job_ids: Iterable[str], *, resume: bool = False) -> None:
        self.path = None if path is None else Path(path)
        self.done: dict[str, dict[str, Any]] = {}
        self.ignored = 0
        self._file: IO[str] | None = None
        if self.path is None:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if resume and self.path.exists():
            data = self.path.read_bytes()
            complete = data[: data.rfind(b"\n") + 1]  # a last line without its newline was cut short
            wanted = set(job_ids)
            for n, line in enumerate(complete.decode("utf-8").splitlines(), start=1):
                if not line.strip():
                    continue
                try:
                    row = json.loads(line)
                except json.JSONDecodeError as exc:
                    raise FileFormatError(f"{self.path}: line {n} is not JSON ({exc.msg}); cannot resume from it") from exc
                job = row.get("job") if isinstance(row, dict) else None
                if job in wanted:
                    self.done[job] = row
                else:
                    self.ignored += 1
            if len(complete) < len(data):
                with self.path.open("r+b") as f:
                    f.truncate(len(complete))
            self._file = self.path.open("a", encoding="utf-8")
        else:
            if self.path.exists():
                self.path.replace(self.path.with_name(self.path.name + ".prev"))
            self._file = self.path.open("w", encoding="utf-8")

    def write(self, row: dict[str, Any]) -> None:
        if self._file is not None:
            self._file.write(json.dumps(row) + "\n")
            self._file.flush()

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
