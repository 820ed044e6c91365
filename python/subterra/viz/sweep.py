"""The figure of one swept field (:class:`subterra.batch.SweepResult`): success and
collision rates against the field's values, a line per controller or planner, each point
the mean over seeds with a bar from the worst to the best seed."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from subterra.errors import InputError
from subterra.viz.flight import _figure, _save

__all__ = ["plot_sweep_field"]


def plot_sweep_field(stats: dict[str, list[dict[str, Any]]], field: str, path: str | os.PathLike[str], *,
                     title: str | None = None, seeds: int | None = None) -> Path:
    """``stats``: :func:`subterra.batch.sweep.field_stats` of ``field``. Numbers are drawn on
    a numeric axis, anything else (names, switches) as categories in the sweep's order.
    Written to ``path`` (PNG); returns it."""
    if not stats or not any(stats.values()):
        raise InputError(f"argument `stats` holds no runs of field {field!r} to draw")
    values: list[Any] = []
    for points in stats.values():
        for p in points:
            if p["value"] not in values:
                values.append(p["value"])
    numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
    if numeric:
        values.sort()
    x_of = (lambda v: float(v)) if numeric else (lambda v: float(values.index(v)))
    fig = _figure(10.0, 4.0)
    axes = fig.subplots(1, 2)
    offsets = {line: (k - (len(stats) - 1) / 2) for k, line in enumerate(stats)}
    span = (max(values) - min(values)) if numeric and len(values) > 1 else 1.0
    for ax, metric, label in ((axes[0], "success", "success rate"), (axes[1], "collision", "collision rate")):
        for line, points in stats.items():
            if not points:
                continue
            x = [x_of(p["value"]) + 0.012 * span * offsets[line] for p in points]
            mean = [p[metric]["mean"] for p in points]
            low = [p[metric]["mean"] - p[metric]["min"] for p in points]
            high = [p[metric]["max"] - p[metric]["mean"] for p in points]
            ax.errorbar(x, mean, yerr=[low, high], marker="o", capsize=4, label=line, linestyle="-" if numeric else "none")
        ax.set_ylim(-0.05, 1.05)
        ax.set_ylabel(label)
        ax.set_xlabel(field)
        ax.grid(alpha=0.3)
        if not numeric:
            ax.set_xticks(range(len(values)), [str(v) for v in values])
    axes[0].legend(loc="best", fontsize=8)
    spread = f"mean over {seeds} seeds, bars: worst to best seed" if seeds else "mean over seeds, bars: worst to best seed"
    fig.suptitle(f"{title or field}\n({spread})", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)
