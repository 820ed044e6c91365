"""Pictures of the HeRO odometry multiplexer: the sources, the pose it passes on, which source
it chose and its confidence over time."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from subterra.viz.plots import _pyplot

#: One colour per source, in the mux's order.
_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink")


def plot_odometry_mux(
    times: Sequence[float],
    truth_xy: np.ndarray,
    sources_xy: Mapping[str, np.ndarray],
    output_xy: np.ndarray,
    chosen: Sequence[str | None],
    confidence: Sequence[float],
    events: Sequence[dict[str, Any]],
    path: str | os.PathLike[str],
    *,
    title: str = "HeRO: odometry sources and the pose passed on",
) -> str:
    """Writes a two-panel PNG to ``path``: left, the tracks in the plane (the truth, each source
    in the mux's frame as first aligned, the output); right, over time, the chosen source and the
    confidence, with the events marked. ``sources_xy[name]`` and ``output_xy`` have shape
    ``(len(times), 2)`` (NaN where a source gave nothing). Returns the path."""
    plt = _pyplot()
    times = np.asarray(times, dtype=float)
    names = list(sources_xy)
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.8), gridspec_kw={"width_ratios": [1.1, 1.0]})
    ax.plot(truth_xy[:, 0], truth_xy[:, 1], color="0.6", lw=4, alpha=0.5, label="truth")
    for k, name in enumerate(names):
        xy = np.asarray(sources_xy[name], dtype=float)
        ax.plot(xy[:, 0], xy[:, 1], color=_COLOURS[k % len(_COLOURS)], lw=1, ls="--", label=f"source {name}")
    ax.plot(output_xy[:, 0], output_xy[:, 1], color="black", lw=1.5, label="mux output")
    for e in events:
        if e["event"] == "switch":
            i = min(int(np.searchsorted(times, e["time_s"])), len(times) - 1)
            ax.plot(*output_xy[i], marker="o", ms=7, mfc="none", mec="red")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=8, loc="best")
    ax.grid(alpha=0.3)
    ax.set_title("tracks (red circles: switches)", fontsize=9)

    level = {name: len(names) - k for k, name in enumerate(names)}
    ys = np.array([level.get(c, 0) if c is not None else 0 for c in chosen], dtype=float)
    bx.step(times, ys, where="post", color="black", lw=1.5)
    bx.set_yticks([0, *level.values()], ["none", *names])
    bx.set_ylim(-0.5, len(names) + 0.5)
    bx.set_xlabel("time [s]")
    bx.set_ylabel("chosen source")
    cx = bx.twinx()
    cx.plot(times, confidence, color="tab:red", lw=1)
    cx.set_ylim(-0.05, 1.05)
    cx.set_ylabel("confidence", color="tab:red")
    shown = set()
    for e in events:
        if e["event"] == "unhealthy":
            label = e["reason"].split(":")[0]
            bx.axvline(e["time_s"], color="0.5", ls=":", lw=1)
            key = (round(e["time_s"], 1), e["source"])
            if key not in shown:
                shown.add(key)
                bx.annotate(f"{e['source']}: {label}", (e["time_s"], len(names) + 0.3), fontsize=7, rotation=90,
                            va="top", ha="right")
    bx.grid(alpha=0.3)
    bx.set_title("choice and confidence (dotted: a source fails a check)", fontsize=9)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)
