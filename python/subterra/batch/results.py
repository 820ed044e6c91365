"""The results of a batch: per-job rows, a summary table, and the files they are written to
(``results.json``: settings, summary and every row; ``results.md``: the table; figures).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

__all__ = ["BatchReport", "markdown_table"]


def markdown_table(head: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A Markdown table: a header line, the rule, a line per row."""
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


@dataclass
class BatchReport:
    """Rows (one per job, in job order), the summary ``table``, the full records ``kept``
    for figures, the wall time and the settings. Subclasses name the rows (``ROWS``) and
    give :meth:`markdown` and :meth:`figures`."""

    ROWS: ClassVar[str] = "jobs"

    scenario: str
    rows: list[dict[str, Any]]
    table: list[dict[str, Any]]
    kept: list[Any] = field(default_factory=list)
    wall_s: float = 0.0
    settings: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"scenario": self.scenario, "settings": self.settings, "wall_s": round(self.wall_s, 1),
                "summary": self.table, self.ROWS: self.rows}

    def markdown(self) -> str:
        """The results table."""
        raise NotImplementedError

    def figures(self, out: Path) -> dict[str, Path]:
        """Writes the figures into ``out``; returns their paths by name."""
        return {}

    def save(self, out_dir: str | os.PathLike[str], *, plots: bool = True) -> dict[str, Path]:
        """Writes ``results.json``, ``results.md`` and, with ``plots``, the figures."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        written = {"json": out / "results.json", "markdown": out / "results.md"}
        written["json"].write_text(json.dumps(self.to_json(), indent=2) + "\n", encoding="utf-8")
        written["markdown"].write_text(self.markdown(), encoding="utf-8")
        if plots:
            written.update(self.figures(out))
        return written
