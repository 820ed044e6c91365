"""Figures of closed-loop flights (`subterra fly`), written as PNG files (no display).

Each function takes what :func:`subterra.flight.run.fly` returns (a ``FlightResult``; any
object with the same attributes works) and reproduces a figure of the APF-PF paper
(Ahmad, Sunberg, Humbert, ACC 2021):

* :func:`plot_flight_path`: Fig. 10, the flown paths over a top-down map of the world.
* :func:`plot_flight_trace`: Fig. 9, what the filter believed against what was there.
* :func:`plot_compute_time`: Fig. 11, the controller's compute time per frame.

The figures are built with :class:`matplotlib.figure.Figure` and the Agg renderer, never
through ``pyplot``: no backend is switched, no window opens, and nothing is left in a
global figure registry. Every function creates the PNG's parent folders and returns its
:class:`~pathlib.Path`. Bad input raises :class:`subterra.errors.InputError`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from subterra._compat import tomllib
from subterra._extras import require
from subterra.errors import InputError

__all__ = ["plot_compute_time", "plot_flight_path", "plot_flight_trace"]

#: Resolution of the written PNGs [dots per inch].
DPI = 110
#: Width of every figure [inch]; the path figure's height follows the world's aspect.
FIGURE_WIDTH_IN = 10.0
#: Bounds of the path figure's height [inch], so long tunnels and square halls both read.
PATH_FIGURE_HEIGHT_IN = (3.5, 9.0)
#: Margin around the world's bounds and the paths on the map [m].
MAP_MARGIN_M = 0.5
#: Obstacles within the flown altitudes +- this margin are drawn dark [m]: about a
#: quadrotor's half height plus the APF's reach below and above it.
ALTITUDE_BAND_MARGIN_M = 0.3
#: A cylinder or capsule whose ends are this close in x-y is drawn as a circle [m].
VERTICAL_TOLERANCE_M = 1e-3
#: A plane with |normal.z| below this is a vertical wall, drawn as a line on the map.
VERTICAL_PLANE_MAX_NZ = 0.1
#: Radius of a solid mission item (the simulator models it as a sphere) [m]. docs/world-format.md.
SOLID_ITEM_RADIUS_M = 0.15
#: The trace's depth axis ends at this multiple of the perception horizon: the filter
#: only sees up to the horizon, so farther raw returns are clipped off the top.
DEPTH_AXIS_HORIZON_FACTOR = 2.5
#: Marker area of the most probable voxel [pt^2] = base + scale * its belief.
MPV_MARKER_AREA = (8.0, 140.0)

#: Colour and legend name of each controller (others take the next colour of the cycle).
CONTROLLER_STYLE = {
    "apf-pf": ("tab:blue", "APF-PF"),
    "raw-apf": ("tab:orange", "raw APF (no filter)"),
    "apf-pf (flight-memory)": ("tab:green", "APF-PF + obstacle memory (flight-memory)"),
    "raw-apf (flight-memory)": ("tab:purple", "raw APF + obstacle memory (flight-memory)"),
}
_OTHER_COLOURS = ("tab:green", "tab:purple", "tab:cyan", "tab:olive", "tab:pink", "tab:brown")
#: Colours of obstacles on the map, by tag (default for any other tag).
TAG_COLOUR = {"wall": "0.25", "cable": "tab:brown", "rock": "0.55", "rubble": "0.55"}
OBSTACLE_COLOUR = "0.4"
#: Obstacles wholly above or below the flown altitudes (ceiling slabs, overhead pipes).
OUT_OF_BAND_COLOUR = "0.82"
#: Pure red is kept for collisions, so a test (or a reader) can find them.
COLLISION_COLOUR = "red"

_TRACE_KEYS = (
    "time_s",
    "mpv_depth_m",
    "mpv_probability",
    "closest_depth_m",
    "truth_closest_m",
    "obstacle_in_view",
    "repulsive_norm",
)


# --------------------------------------------------------------------------- public


def plot_flight_path(results: Any, path: str | os.PathLike[str], *, title: str | None = None) -> Path:
    """Fig. 10: the flown path(s) over a top-down map of the world, written to ``path`` (PNG).

    ``results`` is one ``FlightResult`` or a sequence of them flown in the same world (the
    same scenario and seed): APF-PF against raw APF, or several routes. The map shows
    vertical cylinders and capsules as filled circles of their true radius (slanted ones
    as their top-down outline), spheres as circles, boxes as rectangles turned by their
    yaw, vertical planes as lines, the height field in grey (holes black), mission items,
    and the named regions. Each path is coloured by its controller; the start of each
    flight is a green dot, the end a square, a collision a red x and a local minimum a
    magenta diamond at the last position; where the escape followed an obstacle's boundary
    a broad orange band lies under the path; the goal region is a dashed circle. Equal
    aspect, metres.

    Returns the path of the written file. Raises :class:`InputError` on an empty list,
    an object without the ``FlightResult`` attributes, or flights in different worlds.
    """
    flights = _as_flight_list(results)
    world = flights[0].world
    spec = _world_spec(world, "results[0].world")
    toml0 = world.to_toml()
    for i, f in enumerate(flights[1:], start=1):
        if f.world is not world and f.world.to_toml() != toml0:
            raise InputError(
                f"results: all flights must be in the same world; results[0] is in "
                f"{_flight_name(flights[0])!r}, results[{i}] in {_flight_name(f)!r}"
            )
    paths = [_positions(f.path, f"results[{i}].path") for i, f in enumerate(flights)]

    lo, hi = _map_extent(world, paths, flights)
    width_m, height_m = hi[0] - lo[0], hi[1] - lo[1]
    axes_height = FIGURE_WIDTH_IN * 0.85 * height_m / max(width_m, 1e-9)
    fig_height = float(np.clip(axes_height + 1.2, *PATH_FIGURE_HEIGHT_IN))
    fig = _figure(FIGURE_WIDTH_IN, fig_height)
    ax = fig.add_subplot(1, 1, 1)

    z = np.concatenate([p[:, 2] for p in paths])
    z = z[np.isfinite(z)]
    z_band = (float(z.min()) - ALTITUDE_BAND_MARGIN_M, float(z.max()) + ALTITUDE_BAND_MARGIN_M) if z.size else None
    proxies = _draw_world(ax, spec, z_band)
    colours = _controller_colours(flights)
    _draw_flights(ax, flights, paths, colours)

    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, color="0.9", lw=0.5, zorder=0)
    ax.set_title(title if title is not None else _path_title(flights), fontsize=10)
    handles, labels = ax.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))
    unique.update((p.get_label(), p) for p in proxies)
    ax.legend(unique.values(), unique.keys(), loc="best", fontsize=7, framealpha=0.85)
    return _save(fig, path, tight=True)


def plot_flight_trace(result: Any, path: str | os.PathLike[str]) -> Path:
    """Fig. 9: over sim time, what the filter believed against what was there (PNG).

    Top: the most probable voxel's depth (``mpv_depth_m``; marker area grows with its
    belief ``mpv_probability``), the closest raw (noisy) depth, and the closest
    noise-free depth as a thin line; the perception horizon ``horizon_m`` dashed. Bottom:
    the repulsive force magnitude and, on a second axis, P(free). Both panels shade the
    time intervals where a real obstacle was within the horizon (``obstacle_in_view``,
    ground truth). NaN samples (no belief, no return) leave gaps; a flight with no frames
    gives empty axes with a note.

    Returns the path of the written file. Raises :class:`InputError` if a frame array is
    missing or the arrays differ in length.
    """
    frames = _frames(result, _TRACE_KEYS)
    horizon_m = _finite_positive(result, "horizon_m")
    rate_hz = _finite_positive(result, "rate_hz")
    t = frames["time_s"]
    n = t.shape[0]
    if n > 0 and not np.isfinite(t).any():
        raise InputError("result.frames['time_s']: expected finite sim times [s], got only NaN/inf")

    fig = _figure(FIGURE_WIDTH_IN, 6.5)
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[3, 2])

    shade_label = f"real obstacle within {horizon_m:g} m (ground truth)"
    for ax, label in ((top, shade_label), (bottom, None)):
        for t0, t1 in _true_intervals(t, frames["obstacle_in_view"], 1.0 / rate_hz):
            ax.axvspan(t0, t1, color="tab:red", alpha=0.12, lw=0, label=label, zorder=0)
            label = None

    depth_top = DEPTH_AXIS_HORIZON_FACTOR * horizon_m
    top.plot(t, frames["closest_depth_m"], color="0.55", lw=1.0, label="closest raw depth")
    top.plot(t, frames["truth_closest_m"], color="k", lw=0.6, label="closest true depth")
    mpv, prob = frames["mpv_depth_m"], frames["mpv_probability"]
    shown = np.isfinite(mpv) & np.isfinite(prob)
    base, scale = MPV_MARKER_AREA
    top.scatter(
        t[shown],
        mpv[shown],
        s=base + scale * np.clip(prob[shown], 0.0, 1.0),
        color="tab:blue",
        alpha=0.7,
        lw=0,
        label="most probable voxel (area = belief)",
        zorder=3,
    )
    top.axhline(horizon_m, color="tab:blue", ls="--", lw=0.8, label=f"perception horizon {horizon_m:g} m")
    top.set_ylim(0.0, depth_top)
    top.set_ylabel(f"depth [m] (axis ends at {depth_top:g} m)")
    top.set_title(_trace_title(result), fontsize=10)
    top.legend(loc="upper right", fontsize=7, framealpha=0.85)

    bottom.plot(t, frames["repulsive_norm"], color="tab:purple", lw=1.0, label="|repulsive force|")
    bottom.set_ylabel("|F_rep|")
    bottom.set_xlabel("sim time [s]")
    handles, labels = bottom.get_legend_handles_labels()
    p_free = _optional_frame(result, "p_free", n)
    if p_free is not None:
        twin = bottom.twinx()
        twin.plot(t, p_free, color="tab:green", lw=0.8, label="P(free)")
        twin.set_ylim(-0.05, 1.05)
        twin.set_ylabel("P(free)")
        h2, l2 = twin.get_legend_handles_labels()
        handles, labels = handles + h2, labels + l2
    bottom.legend(handles, labels, loc="upper right", fontsize=7, framealpha=0.85)
    if not np.isfinite(frames["repulsive_norm"]).any():
        bottom.set_ylim(0.0, 1.0)

    if n == 0:
        top.set_xlim(0.0, 1.0)
        top.text(0.5, 0.5, "no frames", transform=top.transAxes, ha="center", va="center", color="0.4")
    fig.tight_layout()
    return _save(fig, path)


def plot_compute_time(result: Any, path: str | os.PathLike[str]) -> Path:
    """Fig. 11: the controller's compute time per frame (perception + command), with its
    median, its 99th percentile and the real-time budget ``1000 / rate_hz`` ms (PNG).

    The title counts the frames over budget. NaN samples are skipped; a flight with no
    timed frame gives empty axes with a note.

    Returns the path of the written file. Raises :class:`InputError` if ``compute_ms`` or
    ``time_s`` is missing or they differ in length, or if ``rate_hz`` is not positive.
    """
    frames = _frames(result, ("time_s", "compute_ms"))
    rate_hz = _finite_positive(result, "rate_hz")
    budget_ms = 1000.0 / rate_hz
    t, ms = frames["time_s"], frames["compute_ms"]
    timed = np.isfinite(ms) & np.isfinite(t)

    fig = _figure(FIGURE_WIDTH_IN, 4.5)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(t[timed], ms[timed], color="tab:blue", lw=0.8, marker=".", ms=3, label="compute time per frame")
    ax.axhline(budget_ms, color="tab:red", lw=1.2, label=f"budget 1000 / {rate_hz:g} Hz = {budget_ms:.3g} ms")
    if timed.any():
        median, p99 = np.percentile(ms[timed], [50.0, 99.0])
        over = int(np.count_nonzero(ms[timed] > budget_ms))
        ax.axhline(median, color="k", ls="--", lw=1.0, label=f"median {median:.3g} ms")
        ax.axhline(p99, color="tab:orange", ls=":", lw=1.2, label=f"p99 {p99:.3g} ms")
        ax.set_ylim(0.0, 1.1 * max(budget_ms, float(ms[timed].max())))
        summary = f"{over} of {int(timed.sum())} frames over budget"
    else:
        ax.set_ylim(0.0, 1.1 * budget_ms)
        ax.set_xlim(0.0, 1.0)
        ax.text(0.5, 0.5, "no timed frames", transform=ax.transAxes, ha="center", va="center", color="0.4")
        summary = "no timed frames"
    ax.set_xlabel("sim time [s]")
    ax.set_ylabel("controller compute time [ms]")
    ax.set_title(f"{_trace_title(result)}\n{summary}", fontsize=10)
    ax.legend(loc="upper right", fontsize=7, framealpha=0.85)
    ax.grid(True, color="0.9", lw=0.5)
    fig.tight_layout()
    return _save(fig, path)


# --------------------------------------------------------------------------- input


def _as_flight_list(results: Any) -> list[Any]:
    if isinstance(results, (str, bytes, dict)):
        raise InputError(f"results: expected a FlightResult or a list of them, got {type(results).__name__}")
    flights = list(results) if isinstance(results, Iterable) and not hasattr(results, "frames") else [results]
    if not flights:
        raise InputError("results: expected at least one FlightResult, got an empty sequence")
    for i, f in enumerate(flights):
        missing = [a for a in ("world", "path", "controller") if not hasattr(f, a)]
        if missing:
            raise InputError(f"results[{i}]: expected a FlightResult, got {type(f).__name__} without {', '.join(missing)}")
    return flights


def _world_spec(world: Any, name: str) -> dict[str, Any]:
    to_toml = getattr(world, "to_toml", None)
    if to_toml is None:
        raise InputError(f"{name}: expected a subterra.sim.World, got {type(world).__name__}")
    return tomllib.loads(to_toml())


def _positions(value: Any, name: str) -> np.ndarray:
    p = np.asarray(value, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0:
        raise InputError(f"{name}: expected an (N, 3) array of world positions [m] with N >= 1, got shape {p.shape}")
    return p


def _frames(result: Any, keys: Sequence[str]) -> dict[str, np.ndarray]:
    frames = getattr(result, "frames", None)
    if not isinstance(frames, dict):
        raise InputError(f"result: expected a FlightResult with a 'frames' dict, got {type(result).__name__}")
    out: dict[str, np.ndarray] = {}
    for key in keys:
        if key not in frames:
            raise InputError(f"result.frames: missing {key!r} (have {sorted(frames)})")
        a = np.asarray(frames[key])
        if a.ndim != 1:
            raise InputError(f"result.frames[{key!r}]: expected a 1-D array (one value per frame), got shape {a.shape}")
        out[key] = a.astype(bool) if key == "obstacle_in_view" else a.astype(np.float64)
    lengths = {k: v.shape[0] for k, v in out.items()}
    if len(set(lengths.values())) > 1:
        raise InputError(f"result.frames: arrays differ in length: {lengths}")
    return out


def _optional_frame(result: Any, key: str, n: int) -> np.ndarray | None:
    a = result.frames.get(key)
    if a is None:
        return None
    a = np.asarray(a, dtype=np.float64)
    if a.shape != (n,):
        raise InputError(f"result.frames[{key!r}]: expected shape ({n},), got {a.shape}")
    return a


def _finite_positive(result: Any, name: str) -> float:
    value = getattr(result, name, None)
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"result.{name}: expected a number > 0, got {value!r}") from None
    if not (math.isfinite(v) and v > 0.0):
        raise InputError(f"result.{name}: expected a finite number > 0, got {v}")
    return v


def _true_intervals(t: np.ndarray, flags: np.ndarray, dt_s: float) -> list[tuple[float, float]]:
    """Time spans ``[t_first, t_last + dt_s]`` of the runs of True in ``flags``."""
    if flags.shape[0] == 0:
        return []
    f = np.concatenate(([False], flags, [False])).astype(np.int8)
    starts = np.flatnonzero(np.diff(f) == 1)
    ends = np.flatnonzero(np.diff(f) == -1) - 1
    return [(float(t[a]), float(t[b]) + dt_s) for a, b in zip(starts, ends, strict=True) if np.isfinite(t[a]) and np.isfinite(t[b])]


# --------------------------------------------------------------------------- drawing


def _figure(width_in: float, height_in: float):
    require("matplotlib", "viz", "Plots")
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), dpi=DPI)


def _save(fig, path: str | os.PathLike[str], *, tight: bool = False) -> Path:
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        fig.savefig(out, format="png", dpi=DPI, bbox_inches="tight" if tight else None)
    finally:
        fig.clear()
    return out


def _map_extent(world: Any, paths: list[np.ndarray], flights: list[Any]) -> tuple[np.ndarray, np.ndarray]:
    pts = [p[:, :2] for p in paths]
    for f in flights:
        for attr in ("start", "goal"):
            v = getattr(f, attr, None)
            if v is not None and np.all(np.isfinite(np.asarray(v, dtype=np.float64)[:2])):
                pts.append(np.asarray(v, dtype=np.float64)[None, :2])
    lo_w, hi_w = (np.asarray(b, dtype=np.float64)[:2] for b in world.bounds)
    if np.all(np.isfinite(lo_w)) and np.all(np.isfinite(hi_w)) and np.all(hi_w >= lo_w):
        pts.append(np.stack([lo_w, hi_w]))
    allp = np.concatenate(pts)
    allp = allp[np.all(np.isfinite(allp), axis=1)]
    if allp.shape[0] == 0:
        raise InputError("results: no finite position to draw (every path point is NaN)")
    return allp.min(axis=0) - MAP_MARGIN_M, allp.max(axis=0) + MAP_MARGIN_M


def _draw_world(ax, spec: dict[str, Any], z_band: tuple[float, float] | None) -> list[Any]:
    """Draws the world's geometry; returns legend proxies for what it drew. Obstacles
    that overlap the altitude band ``z_band`` [m] (all if None) are drawn dark, the
    others (floor and ceiling slabs, pipes overhead) light."""
    require("matplotlib", "viz", "Plots")
    import matplotlib
    from matplotlib.patches import Circle, Patch, Polygon, Rectangle

    proxies: list[Any] = []
    hf = spec.get("heightfield")
    if hf:
        heights = np.array(hf["heights"], dtype=np.float64)
        if "hole_value" in hf:
            heights[heights == hf["hole_value"]] = np.nan
        res = float(hf["resolution"])
        x0, y0 = hf["origin"]
        rows, cols = heights.shape
        extent = (x0 - res / 2, x0 + (cols - 0.5) * res, y0 - res / 2, y0 + (rows - 0.5) * res)
        ax.imshow(
            np.ma.masked_invalid(heights),
            origin="lower",
            extent=extent,
            cmap="Greys",
            alpha=0.35,
            interpolation="nearest",
            zorder=0,
        )
        proxies.append(Patch(color="0.6", alpha=0.35, label="terrain (darker = higher)"))
        holes = np.isnan(heights)
        if holes.any():
            ax.imshow(
                np.ma.masked_where(~holes, np.ones_like(heights)),
                origin="lower",
                extent=extent,
                cmap=matplotlib.colors.ListedColormap(["black"]),
                interpolation="nearest",
                zorder=0.5,
            )
            proxies.append(Patch(color="black", label="terrain hole (drop-off)"))

    for plane in spec.get("plane", []):
        n = np.asarray(plane["normal"], dtype=np.float64)
        if abs(n[2]) / max(float(np.linalg.norm(n)), 1e-12) >= VERTICAL_PLANE_MAX_NZ:
            continue
        p = np.asarray(plane["point"], dtype=np.float64)[:2]
        d = np.array([-n[1], n[0]]) / max(float(np.hypot(n[0], n[1])), 1e-12)
        ax.axline(tuple(p), tuple(p + d), color=TAG_COLOUR["wall"], lw=2.0, zorder=2)

    band_hit = [False, False]  # drawn: [in the altitude band, outside it]

    def style(item: dict[str, Any], z_lo: float, z_hi: float) -> dict[str, Any]:
        inside = z_band is None or (z_hi >= z_band[0] and z_lo <= z_band[1])
        band_hit[0 if inside else 1] = True
        if inside:
            return {"color": TAG_COLOUR.get(item.get("tag", ""), OBSTACLE_COLOUR), "lw": 0.6, "zorder": 3}
        return {"color": OUT_OF_BAND_COLOUR, "alpha": 0.5, "lw": 0, "zorder": 1}

    for kind in ("cylinder", "capsule"):
        for c in spec.get(kind, []):
            a3, b3, r = np.asarray(c["a"], float), np.asarray(c["b"], float), float(c["radius"])
            st = style(c, min(a3[2], b3[2]) - r, max(a3[2], b3[2]) + r)
            a, b = a3[:2], b3[:2]
            if np.hypot(*(b - a)) <= VERTICAL_TOLERANCE_M:
                ax.add_patch(Circle(tuple(a), r, **st))
                continue
            u = (b - a) / np.hypot(*(b - a))
            side = np.array([-u[1], u[0]]) * r
            ax.add_patch(Polygon([a + side, b + side, b - side, a - side], closed=True, **st))
            if kind == "capsule":
                ax.add_patch(Circle(tuple(a), r, **st))
                ax.add_patch(Circle(tuple(b), r, **st))
    for sp in spec.get("sphere", []):
        c3, r = np.asarray(sp["centre"], float), float(sp["radius"])
        ax.add_patch(Circle(tuple(c3[:2]), r, **style(sp, c3[2] - r, c3[2] + r)))
    for box in spec.get("box", []):
        cx, cy, cz = box["centre"]
        sx, sy, sz = box["size"]
        yaw_deg = math.degrees(float(box.get("yaw", 0.0)))
        st = style(box, cz - sz / 2, cz + sz / 2)
        ax.add_patch(Rectangle((cx - sx / 2, cy - sy / 2), sx, sy, angle=yaw_deg, rotation_point="center", **st))
    for item in spec.get("item", []):
        p = tuple(np.asarray(item["position"], float)[:2])
        if item.get("solid", False):
            ax.add_patch(Circle(p, SOLID_ITEM_RADIUS_M, color="tab:cyan", zorder=3))
        if item.get("keep_out_radius", 0.0) > 0.0:
            ax.add_patch(Circle(p, item["keep_out_radius"], fill=False, ec="tab:cyan", ls=":", lw=0.8, zorder=3))
        ax.annotate(item.get("kind", ""), p, fontsize=6, color="tab:cyan", xytext=(3, 3), textcoords="offset points")
    for region in spec.get("region", []):
        c = tuple(np.asarray(region["centre"], float)[:2])
        ax.add_patch(Circle(c, float(region["radius"]), color="tab:gray", alpha=0.18, lw=0, zorder=1))
        ax.annotate(region["name"], c, ha="center", va="center", fontsize=8, color="0.3", zorder=1)
    if band_hit[0]:
        where = "" if z_band is None else f" at flight height (z {z_band[0]:.2g} to {z_band[1]:.2g} m)"
        proxies.append(Patch(color=OBSTACLE_COLOUR, label=f"obstacle{where}, true size"))
    if band_hit[1]:
        proxies.append(Patch(color=OUT_OF_BAND_COLOUR, alpha=0.5, label="obstacle above or below the flight"))
    if spec.get("region"):
        proxies.append(Patch(color="tab:gray", alpha=0.18, label="named region"))
    return proxies


def _controller_key(f: Any) -> str:
    """The controller's name, with its preset when that is not the paper's `flight`."""
    preset = str(getattr(f, "preset", "flight"))
    return str(f.controller) if preset == "flight" else f"{f.controller} ({preset})"


def _controller_colours(flights: list[Any]) -> dict[str, tuple[str, str]]:
    out: dict[str, tuple[str, str]] = {}
    others = iter(_OTHER_COLOURS * (1 + len(flights) // len(_OTHER_COLOURS)))
    for f in flights:
        name = _controller_key(f)
        if name not in out:
            out[name] = CONTROLLER_STYLE.get(name, (next(others), name))
    return out


def _failure(f: Any) -> str | None:
    metrics = getattr(f, "metrics", None) or {}
    failure = metrics.get("failure") if isinstance(metrics, dict) else None
    return None if failure in (None, "") else str(failure)


def _draw_flights(ax, flights: list[Any], paths: list[np.ndarray], colours: dict[str, tuple[str, str]]) -> None:
    require("matplotlib", "viz", "Plots")
    from matplotlib.patches import Circle

    reached = {name: [0, 0] for name in colours}
    for f in flights:
        reached[_controller_key(f)][1] += 1
        reached[_controller_key(f)][0] += _failure(f) is None
    for f, p in zip(flights, paths, strict=True):
        colour, label = colours[_controller_key(f)]
        ok, total = reached[_controller_key(f)]
        ax.plot(p[:, 0], p[:, 1], color=colour, lw=1.6, alpha=0.9, zorder=5, label=f"{label}: {ok}/{total} without failure")
        escaping = _optional_frame(f, "escape_active", len(p) - 1)
        if escaping is not None and escaping.astype(bool).any():
            # Where the escape followed an obstacle's boundary: a broad band under the path.
            along = np.where(escaping.astype(bool)[:, None], p[:-1, :2], np.nan)
            ax.plot(along[:, 0], along[:, 1], color="tab:orange", lw=5, alpha=0.55, solid_capstyle="round", zorder=4.5,
                    label="escape: following a boundary")
        ax.plot(*p[0, :2], "o", color="tab:green", mec="k", mew=0.5, ms=7, zorder=6, label="start")
        ax.plot(*p[-1, :2], "s", color=colour, mec="k", mew=0.5, ms=6, zorder=6, label="end (colour: controller)")
        goal = getattr(f, "goal", None)
        radius = getattr(f, "goal_radius_m", None)
        if goal is not None and radius is not None and np.all(np.isfinite(np.asarray(goal, float)[:2])):
            centre = tuple(np.asarray(goal, float)[:2])
            ax.add_patch(Circle(centre, float(radius), fill=False, ec="tab:green", ls="--", lw=1.0, zorder=4, label="goal region"))
        failure = _failure(f)
        if failure == "collision":
            ax.plot(*p[-1, :2], "x", color=COLLISION_COLOUR, ms=11, mew=2.5, zorder=7, label="collision")
        elif failure == "local_minimum":
            ax.plot(*p[-1, :2], "D", color="magenta", mec="k", mew=0.5, ms=8, zorder=7, label="local minimum")
        elif failure is not None:
            ax.plot(*p[-1, :2], "P", color="0.2", ms=9, zorder=7, label=f"failure: {failure}")


def _flight_name(f: Any) -> str:
    return f"{getattr(f, 'scenario', '?')} (seed {getattr(f, 'seed', '?')})"


def _path_title(flights: list[Any]) -> str:
    f0 = flights[0]
    parts = [_flight_name(f0)]
    routes = sorted({str(getattr(f, "route", "")) for f in flights} - {""})
    if routes:
        parts.append("route " + ", ".join(routes))
    parts.append(" vs ".join(sorted({_controller_key(f) for f in flights})))
    if getattr(f0, "noise", None):
        parts.append(f"noise {f0.noise}")
    return ", ".join(parts)


def _trace_title(result: Any) -> str:
    route = getattr(result, "route", "")
    where = f"{getattr(result, 'scenario', '?')}" + (f" {route}" if route else "")
    return (
        f"{where}: {getattr(result, 'controller', '?')} (seed {getattr(result, 'seed', '?')}, "
        f"noise {getattr(result, 'noise', '?')}, preset {getattr(result, 'preset', '?')})"
    )
