"""Matplotlib figures written as PNG files (no display needed)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from subterra._extras import require

__all__ = ["plot_depth_trace"]


def _pyplot():
    require("matplotlib", "viz", "Plots")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_depth_trace(
    records: Sequence[dict[str, Any]],
    path: str | os.PathLike[str],
    *,
    title: str = "APF-PF",
    truth_depth_m: Sequence[float] | None = None,
    horizon_m: float | None = 1.2,
) -> None:
    """The paper's Fig. 9 without the flight: per frame, the most probable voxel's depth
    (marker size by its belief) against the closest raw depth, and below it the repulsive
    force magnitude and P(free). ``truth_depth_m`` adds the true obstacle depth when known."""
    plt = _pyplot()
    frames = np.array([r["frame"] for r in records])
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 6), sharex=True, height_ratios=[3, 2])
    closest = np.array([np.nan if r["closest_depth_m"] is None else r["closest_depth_m"] for r in records])
    top.plot(frames, closest, color="0.55", lw=1.2, label="closest raw depth")
    occupied = [r for r in records if r["map_depth_m"] is not None and r["p_free"] < 0.5]
    if occupied:
        top.scatter(
            [r["frame"] for r in occupied],
            [r["map_depth_m"] for r in occupied],
            s=[10 + 120 * r["map_probability"] for r in occupied],
            color="tab:red",
            alpha=0.8,
            label="most probable voxel (size = belief)",
            zorder=3,
        )
    if truth_depth_m is not None:
        top.plot(frames, truth_depth_m, "k--", lw=1, label="true obstacle depth")
    if horizon_m is not None:
        top.axhline(horizon_m, color="tab:blue", ls=":", lw=1, label="sensing horizon")
    top.set_ylabel("depth [m]")
    top.set_title(title)
    top.legend(loc="upper right", fontsize=8)
    force = np.array([np.linalg.norm(r["repulsive_body"]) for r in records])
    bottom.plot(frames, force, color="tab:purple", label="|repulsive force|")
    bottom.set_ylabel("|F_rep| [N]")
    bottom.set_xlabel("frame")
    twin = bottom.twinx()
    twin.plot(frames, [r["p_free"] for r in records], color="tab:green", lw=1, label="P(free)")
    twin.set_ylim(-0.05, 1.05)
    twin.set_ylabel("P(free)")
    lines = bottom.get_legend_handles_labels()[0] + twin.get_legend_handles_labels()[0]
    labels = bottom.get_legend_handles_labels()[1] + twin.get_legend_handles_labels()[1]
    bottom.legend(lines, labels, loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
