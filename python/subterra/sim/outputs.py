"""What every closed-loop run writes beside its own tables: ``events.csv``, ``metrics.json``,
its plots and the path of its Rerun recording (``drive`` and ``fly`` share it)."""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np


def plain(value: Any) -> Any:
    """``value`` as JSON writes it: NumPy scalars and arrays as Python numbers and lists,
    a non-finite float as ``null``."""
    if isinstance(value, (np.floating, np.integer)):
        value = value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_run_outputs(
    out: Path,
    written: dict[str, Path],
    *,
    events_header: Sequence[str],
    events: Iterable[Sequence[Any]],
    summary: Mapping[str, Any],
    plots: Mapping[str, tuple[Callable[[Path], Path], str]] | None,
    rerun: str | None,
) -> dict[str, Path]:
    """Writes ``events.csv`` (one row per event), ``metrics.json`` (``summary``) and, when
    ``plots`` is given, each plot ``name: (draw, file name)``; adds their paths (and the
    Rerun recording's, if any) to ``written`` and returns it."""
    written["events"] = out / "events.csv"
    with written["events"].open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(events_header)
        w.writerows(events)
    written["metrics"] = out / "metrics.json"
    written["metrics"].write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    for name, (draw, file_name) in (plots or {}).items():
        written[name] = draw(out / file_name)
    if rerun is not None:
        written["rerun"] = Path(rerun)
    return written
