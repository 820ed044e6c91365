"""Figures of a ground-robot drive (:class:`subterra.drive.DriveResult`): the risk map with
the planned and driven paths, speed against the local risk, and compute time per stage."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from subterra._extras import require
from subterra.errors import InputError
from subterra.viz.flight import _draw_world, _figure, _save, _world_spec

#: Colour of each behaviour on the path and in the speed plot's shading.
BEHAVIOUR_COLOURS = {
    "track": "tab:blue", "clear_map": "tab:olive", "rotate": "tab:purple", "raise_thresholds": "tab:orange",
    "back_out": "tab:red", "goal_reached": "tab:green", "home": "tab:green", "failed": "black",
}
#: Margin around the drawn content [m].
MAP_MARGIN_M = 1.0


def _check(result: Any) -> dict[str, np.ndarray]:
    steps = getattr(result, "steps", None)
    if not isinstance(steps, dict) or "time_s" not in steps:
        raise InputError(f"result: expected a subterra.drive.DriveResult, got {type(result).__name__}")
    if len(steps["time_s"]) == 0:
        raise InputError("result: the drive has no steps to draw")
    return steps


def plot_drive_map(result: Any, path: str | os.PathLike[str], *, title: str | None = None) -> Path:
    """The world from above with the last coarse risk map laid over it (green = 0 to red =
    lethal, unobserved cells left out unless lethal), the driven path coloured by behaviour, the last
    planned path (dashed), start, goal and home, and a marker at every recovery transition.
    Written to ``path`` (PNG); returns it."""
    steps = _check(result)
    world = result.world
    spec = _world_spec(world, "result.world")
    pos = np.asarray(result.path, dtype=np.float64)
    pts = [pos[:, :2], np.asarray([result.start, result.goal, result.home], dtype=np.float64)]
    rm = result.risk_map
    if rm is not None:
        e = rm.extent
        pts.append(np.array([[e[0], e[2]], [e[1], e[3]]]))
    allp = np.concatenate(pts)
    lo, hi = allp.min(axis=0) - MAP_MARGIN_M, allp.max(axis=0) + MAP_MARGIN_M
    aspect = (hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-9)
    fig = _figure(10.0, float(np.clip(10.0 * aspect * 0.85 + 1.2, 4.0, 12.0)))
    ax = fig.add_subplot(1, 1, 1)
    proxies = _draw_world(ax, spec, None)
    if rm is not None:
        rgba = np.zeros((*rm.shape, 4))
        risk = np.clip(np.nan_to_num(rm.layer("risk")), 0.0, 1.0)
        rgba[..., 0] = 0.86 * risk
        rgba[..., 1] = 0.78 * (1.0 - risk)
        rgba[..., 3] = np.where((rm.layer("observed") > 0) | rm.lethal(), 0.55, 0.0)  # a lethal cell is never unknown
        ax.imshow(rgba, origin="lower", extent=rm.extent, interpolation="nearest", zorder=1.5)
        e = rm.extent
        ax.plot([e[0], e[1], e[1], e[0], e[0]], [e[2], e[2], e[3], e[3], e[2]], color="0.4", lw=0.6, ls=":",
                label="last risk map (green 0 - red lethal)")
    behaviour = steps["behaviour"]
    xy = steps["position"][:, :2]
    for name in dict.fromkeys(behaviour):
        sel = behaviour == name
        ax.scatter(*xy[sel].T, s=4, color=BEHAVIOUR_COLOURS.get(name, "0.3"), label=f"driven: {name}", zorder=4)
    if len(result.last_plan):
        ax.plot(*np.asarray(result.last_plan).T, color="tab:orange", ls="--", lw=1.2, label="last plan", zorder=4)
    for e in result.events:
        if e["from"] == e["to"]:
            continue
        k = int(np.searchsorted(steps["time_s"], e["time_s"]))
        k = min(k, len(xy) - 1)
        ax.plot(*xy[k], marker="o", mfc="none", mec=BEHAVIOUR_COLOURS.get(e["to"], "k"), ms=8, zorder=5)
    ax.plot(*result.start, "o", color="tab:green", ms=8, label="start", zorder=6)
    ax.plot(*result.goal, "*", color="gold", mec="k", ms=14, label="goal", zorder=6)
    if not np.allclose(result.home, result.start):
        ax.plot(*result.home, "s", color="tab:cyan", mec="k", ms=8, label="home", zorder=6)
    ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), aspect="equal", xlabel="x [m]", ylabel="y [m]")
    failure = result.metrics.get("failure")
    ax.set_title(title or (f"{result.scenario} seed {result.seed}, {result.planner} planner: "
                           f"{'goal reached' if result.success else failure} in {result.metrics.get('time_s', 0):.1f} s"),
                 fontsize=10)
    handles, labels = ax.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))
    unique.update((p.get_label(), p) for p in proxies)
    ax.legend(unique.values(), unique.keys(), loc="best", fontsize=7, framealpha=0.85)
    return _save(fig, path, tight=True)


def _shade_behaviours(ax, t: np.ndarray, behaviour: np.ndarray) -> None:
    if len(t) < 2:
        return
    dt = float(np.median(np.diff(t)))
    start = 0
    for k in range(1, len(t) + 1):
        if k == len(t) or behaviour[k] != behaviour[start]:
            name = str(behaviour[start])
            if name != "track":
                ax.axvspan(t[start], t[k - 1] + dt, color=BEHAVIOUR_COLOURS.get(name, "0.5"), alpha=0.15, lw=0)
            start = k


def plot_speed_risk(result: Any, path: str | os.PathLike[str]) -> Path:
    """Speed over time against the risk-limited bound ``v_max·(1 - r)`` at the robot, with
    the map's local risk and the true (tilt) risk below; recovery behaviours shaded.
    Written to ``path`` (PNG); returns it."""
    require("matplotlib", "viz", "Plots")
    from matplotlib.patches import Patch

    s = _check(result)
    t = s["time_s"]
    fig = _figure(10.0, 6.0)
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[3, 2])
    top.plot(t, s["speed_m_s"], color="tab:blue", lw=1.2, label="speed")
    top.plot(t, s["command"][:, 0], color="tab:blue", lw=0.8, ls=":", label="commanded speed")
    top.plot(t, s["speed_limit_m_s"], color="tab:red", lw=1.0, ls="--", label="risk limit v_max·(1 - r)")
    top.set_ylabel("speed [m/s]")
    bottom.plot(t, s["local_risk"], color="tab:red", lw=1.0, label="map risk under the robot")
    bottom.plot(t, s["true_risk"], color="0.3", lw=1.0, label="true risk (tilt of the settled pose, steps and roughness of the true ground)")
    bottom.set(ylabel="risk", xlabel="sim time [s]", ylim=(-0.02, 1.02))
    for ax in (top, bottom):
        _shade_behaviours(ax, t, s["behaviour"])
        ax.grid(True, color="0.9", lw=0.5)
    shaded = [Patch(color=BEHAVIOUR_COLOURS[b], alpha=0.15, label=b) for b in dict.fromkeys(s["behaviour"]) if b != "track"]
    handles, labels = top.get_legend_handles_labels()
    top.legend(handles + shaded, labels + [p.get_label() for p in shaded], fontsize=7, loc="upper right")
    bottom.legend(fontsize=7, loc="upper right")
    top.set_title(f"{result.scenario} seed {result.seed}, {result.planner} planner: speed against risk", fontsize=10)
    return _save(fig, path, tight=True)


def plot_drive_compute(result: Any, path: str | os.PathLike[str]) -> Path:
    """The navigator's wall time per control step and stage (map update, planning, MPC),
    with the medians in the legend. Written to ``path`` (PNG); returns it."""
    s = _check(result)
    t = s["time_s"]
    fig = _figure(10.0, 4.0)
    ax = fig.add_subplot(1, 1, 1)
    for stage, colour in (("map", "tab:green"), ("plan", "tab:orange"), ("track", "tab:purple"), ("total", "k")):
        v = s[f"{stage}_ms"]
        ax.plot(t, v, color=colour, lw=0.8 if stage != "total" else 1.2, label=f"{stage} (median {np.median(v):.2f} ms)")
    ax.set(xlabel="sim time [s]", ylabel="wall time per step [ms]")
    ax.set_ylim(bottom=0)
    ax.grid(True, color="0.9", lw=0.5)
    ax.legend(fontsize=7, loc="upper right")
    ax.set_title(f"{result.scenario} seed {result.seed}: navigator compute time per stage", fontsize=10)
    return _save(fig, path, tight=True)
