"""``subterra terrain FILE...``: the terrain mapper over point-cloud files, with figures.

The files are mapped in the order given, as consecutive scans of one sensor: stamps
from a TUM pose file, else ``--period`` apart (default 0.1 s, a 10 Hz lidar); poses
(``world_from_sensor``, one per file) from ``--poses``, else identity. The sensor's
mounting is ``--body-from-sensor`` or ``--sensor-height`` (a level sensor that high
above the ground); with neither, the height is estimated from the first cloud
(:func:`subterra.terrain.estimate_sensor_height`).

Written to ``--out``: ``layer_<name>.png`` for every layer of the coarse fused map,
``risk.png`` (the combined risk image of ``RiskMap.to_image``), ``risk_fine.png`` (the
fine map), ``cloud_top.png`` (the last cloud from above, ground green, obstacles red)
and ``summary.json`` (stats, timings, per-layer min/mean/max, lethal-cell counts).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from subterra._core import MAX_SENSOR_HEIGHT_M, MIN_SENSOR_HEIGHT_M  # --sensor-height [m], as segment_ground
from subterra._extras import require
from subterra.errors import InputError

__all__ = ["parse_body_from_sensor", "register_cli", "run_cli", "run_terrain"]

#: Default time between scans when the poses carry no stamps [s] (a 10 Hz lidar).
DEFAULT_PERIOD_S = 0.1
#: Most points drawn in the top view of the cloud (a seeded subsample beyond that).
TOP_VIEW_MAX_POINTS = 200_000
#: Shortest ``--period`` between scans [s] (a 1 kHz sensor; below: a typo).
MIN_PERIOD_S = 1e-3
#: Largest ``--period`` between scans [s].
MAX_PERIOD_S = 3600.0


def register_cli(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Adds the ``terrain`` subcommand to ``subparsers``; its handler is ``args.handler``."""
    from subterra.cli import float_in, nonempty, unit_float

    p = subparsers.add_parser("terrain", help="terrain risk maps from point-cloud files (PCD, PLY, KITTI .bin, .npy)")
    p.add_argument("files", nargs="+", metavar="FILE", help="point clouds in the sensor frame, in scan order")
    p.add_argument("--poses", type=nonempty, default=None, help="world_from_sensor per file: KITTI (3x4) or TUM text file (default identity)")
    mount = p.add_mutually_exclusive_group()
    mount.add_argument("--sensor-height", type=float_in(MIN_SENSOR_HEIGHT_M, MAX_SENSOR_HEIGHT_M, low_open=False, unit="m"), default=None, help="height of a level sensor above the ground [m] (default: estimated)")
    mount.add_argument(
        "--body-from-sensor", type=nonempty, default=None,
        help="sensor mounting: x,y,z [m] | x,y,z,roll,pitch,yaw [m, deg] | 12 or 16 numbers of the 3x4 / 4x4 matrix, row-major",
    )
    p.add_argument("--config", type=nonempty, default=None, help="terrain config TOML (default configs/terrain.toml values)")
    p.add_argument("--period", type=float_in(MIN_PERIOD_S, MAX_PERIOD_S, low_open=False, unit="s"), default=DEFAULT_PERIOD_S, help=f"seconds between scans without TUM stamps (default {DEFAULT_PERIOD_S})")
    p.add_argument("--confidence", type=unit_float, default=1.0, help="odometry confidence in [0, 1] (default 1)")
    p.add_argument("--out", type=nonempty, default=None, help="output folder (default runs/terrain-<time>)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(handler=run_cli)
    return p


def run_cli(args: argparse.Namespace) -> int:
    """Handler of ``subterra terrain``: maps the files, writes the figures, prints a summary line."""
    out = Path(args.out or f"runs/terrain-{time.strftime('%Y%m%d-%H%M%S')}")
    summary = run_terrain(
        args.files, out, poses=args.poses, sensor_height=args.sensor_height,
        body_from_sensor=parse_body_from_sensor(args.body_from_sensor) if args.body_from_sensor is not None else None,
        config=args.config, period_s=args.period, confidence=args.confidence, progress=not args.no_progress,
    )
    last = summary["scans"][-1]
    lethal = summary["lethal_cells"]["risk"]
    print(
        f"{len(summary['scans'])} scans, sensor {summary['sensor_height_m']:.2f} m up, "
        f"last update {1e3 * last['timings']['total_s']:.1f} ms, {lethal} lethal cells of {summary['map']['cells']}"
    )
    print(f"wrote {out / 'summary.json'} and {len(summary['figures'])} figures to {out}")
    return 0


def parse_body_from_sensor(text: str) -> np.ndarray:
    """``body_from_sensor`` from ``x,y,z``, ``x,y,z,roll,pitch,yaw`` [m, deg] or 12/16 matrix values."""
    try:
        v = [float(s) for s in text.replace(" ", ",").split(",") if s]
    except ValueError as exc:
        raise InputError(f"argument `--body-from-sensor` must be comma-separated numbers, got {text!r}") from exc
    if not all(math.isfinite(x) for x in v):
        raise InputError(f"argument `--body-from-sensor` must be finite numbers, got {text!r}")
    t = np.eye(4)
    if len(v) in (3, 6):
        t[:3, 3] = v[:3]
        if len(v) == 6:
            t[:3, :3] = _rotation_rpy(*(math.radians(a) for a in v[3:]))
    elif len(v) in (12, 16):
        t[: len(v) // 4] = np.reshape(v, (-1, 4))
    else:
        raise InputError(f"argument `--body-from-sensor` needs 3, 6, 12 or 16 numbers, got {len(v)}: {text!r}")
    return t


def _rotation_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (REP 103 fixed-axis roll, pitch, yaw) [rad]:
    SciPy's extrinsic ``"xyz"`` Euler angles."""
    transform = require("scipy.spatial.transform", "io", "A sensor mounting with roll, pitch and yaw")
    return transform.Rotation.from_euler("xyz", [roll, pitch, yaw]).as_matrix()


def _orthonormalised(pose: np.ndarray) -> np.ndarray:
    """The pose with its rotation replaced by the nearest rotation (SVD): text files hold
    6-9 digits, the mapper checks rigidity to 1e-5, and the reader already rejected
    anything not rigid to 1e-3."""
    u, _, vt = np.linalg.svd(pose[:3, :3])
    out = pose.copy()
    out[:3, :3] = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return out


def run_terrain(
    files: Sequence[str | Path],
    out: str | Path,
    *,
    poses: str | Path | None = None,
    sensor_height: float | None = None,
    body_from_sensor: np.ndarray | None = None,
    config: str | Path | None = None,
    robot=None,
    period_s: float = DEFAULT_PERIOD_S,
    confidence: float = 1.0,
    progress: bool = True,
) -> dict:
    """Maps ``files`` in order, writes the figures and ``summary.json`` to ``out``; returns the summary."""
    from subterra._extras import tqdm
    from subterra.io import read_cloud, read_trajectory
    from subterra.terrain import (
        TerrainMapper,
        estimate_sensor_height,
        lethal_cells,
        translation,
    )

    files = [Path(f) for f in files]
    if not files:
        raise InputError("argument `files` is empty: give at least one point-cloud file")
    if not (math.isfinite(period_s) and MIN_PERIOD_S <= period_s <= MAX_PERIOD_S):
        raise InputError(f"argument `--period` must be a finite number in [{MIN_PERIOD_S:g}, {MAX_PERIOD_S:g}] s, got {period_s}")
    if sensor_height is not None and not (math.isfinite(sensor_height) and MIN_SENSOR_HEIGHT_M <= sensor_height <= MAX_SENSOR_HEIGHT_M):
        raise InputError(
            f"argument `--sensor-height` must be a finite number in [{MIN_SENSOR_HEIGHT_M:g}, {MAX_SENSOR_HEIGHT_M:g}] m, got {sensor_height}"
        )
    if poses is not None:
        trajectory = read_trajectory(poses)
        if len(trajectory) != len(files):
            raise InputError(f"argument `--poses` has {len(trajectory)} poses for {len(files)} files (one per file): {poses}")
        world_from_sensor = [_orthonormalised(p) for p in trajectory.world_from_body[: len(files)]]
        stamps = trajectory.stamps_s[: len(files)] if trajectory.stamps_s is not None else None
    else:
        world_from_sensor = [np.eye(4)] * len(files)
        stamps = None
    if stamps is None:
        stamps = np.arange(len(files)) * period_s

    mapper = TerrainMapper(robot=robot, config=config)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scans = []
    risk_map = None
    body_world = np.eye(4)
    for i, path in enumerate(tqdm(files, desc="terrain", unit="scan", disable=not progress)):
        points = read_cloud(path).points
        if i == 0 and body_from_sensor is None:
            if sensor_height is None:
                sensor_height = estimate_sensor_height(points)
                if not sensor_height > 0:
                    raise InputError(
                        f"cannot estimate the height of the sensor above the ground from {path} (got {sensor_height:.2f} m): "
                        "give --sensor-height or --body-from-sensor"
                    )
            body_from_sensor = translation(z=sensor_height)
        body_world = world_from_sensor[i] @ np.linalg.inv(body_from_sensor)
        risk_map = mapper.update(points, stamp=float(stamps[i]), world_from_body=body_world, body_from_sensor=body_from_sensor, confidence=confidence)
        scans.append({"file": str(path), "stamp_s": float(stamps[i]), "stats": dict(risk_map.stats), "timings": dict(risk_map.timings)})
    assert risk_map is not None  # files is not empty

    figures = _write_figures(mapper, risk_map, body_world, out)
    layers = {}
    for name in risk_map.layer_names:
        a = risk_map.layer(name)
        finite = a[np.isfinite(a)]
        layers[name] = (
            {"min": float(finite.min()), "mean": float(finite.mean()), "max": float(finite.max()), "finite_cells": int(finite.size)}
            if finite.size else {"min": None, "mean": None, "max": None, "finite_cells": 0}
        )
    summary = {
        "files": [str(f) for f in files],
        "poses": str(poses) if poses is not None else None,
        "sensor_height_m": float(body_from_sensor[2, 3]),
        "body_from_sensor": body_from_sensor.tolist(),
        "robot": mapper.robot.to_dict(),
        "config": mapper.config.to_dict(),
        "map": {
            "resolution_m": risk_map.resolution, "shape": list(risk_map.shape), "cells": risk_map.nx * risk_map.ny,
            "origin_m": list(risk_map.origin), "extent_m": list(risk_map.extent), "scans_fused": risk_map.scans,
        },
        "scans": scans,
        "stats": scans[-1]["stats"],
        "timings": scans[-1]["timings"],
        "layers": layers,
        "lethal_cells": lethal_cells(risk_map),
        "figures": figures,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=False), encoding="utf-8")
    return summary


# Colour maps per layer kind: risks in [0, 1], heights in metres, counts, angles.
_UNITS = {
    "count": "points", "ground_count": "points", "ground_height": "m", "min_height": "m", "max_height": "m",
    "slope": "rad", "plane_residual": "m", "step_height": "m", "negative_depth": "m", "tilt_angle": "rad",
    "observed": "1 = observed", "age": "s", "risk_variance": "risk²",
}


def _write_figures(mapper, risk_map, body_world: np.ndarray, out: Path) -> list[str]:
    require("matplotlib", "viz", "Plots")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    require("matplotlib", "viz", "Plots")
    from matplotlib.patches import Patch

    written = []
    extent = risk_map.extent
    robot_xy = body_world[:2, 3]

    def save(fig, name: str) -> None:
        fig.savefig(out / name, dpi=80)
        plt.close(fig)
        written.append(name)

    for name in risk_map.layer_names:
        a = risk_map.layer(name)
        fig, ax = plt.subplots(figsize=(5.2, 4.4))
        is_risk = name not in _UNITS
        im = ax.imshow(np.ma.masked_invalid(a), origin="lower", extent=extent, interpolation="nearest",
                       cmap="RdYlGn_r" if is_risk else "viridis", vmin=0.0 if is_risk else None, vmax=1.0 if is_risk else None)
        fig.colorbar(im, ax=ax, label="risk" if is_risk else f"{name} [{_UNITS[name]}]")
        ax.plot(*robot_xy, "k+", ms=10)
        ax.set(title=f"{name} (coarse, {risk_map.resolution} m cells)", xlabel="world x [m]", ylabel="world y [m]")
        fig.tight_layout()
        save(fig, f"layer_{name}.png")

    for m, fname in ((risk_map, "risk.png"), (mapper.last_fine, "risk_fine.png")):
        if m is None:
            continue
        fig, ax = plt.subplots(figsize=(5.6, 4.8))
        ax.imshow(m.to_image(), origin="lower", extent=m.extent, interpolation="nearest")
        ax.plot(*robot_xy, "k+", ms=10)
        # The lethal count of the summary (RiskMap.lethal_count: observed or not, all red).
        ax.legend(handles=[Patch(color=(0, 200 / 255, 0), label="risk 0"),
                           Patch(color=(220 / 255, 0, 0), label=f"lethal ({m.lethal_count()} cells)"),
                           Patch(color=(0.5, 0.5, 0.5), label="unobserved")], loc="upper right", fontsize=7)
        ax.set(title=f"combined risk ({m.kind}, {m.resolution} m cells)", xlabel="world x [m]", ylabel="world y [m]")
        fig.tight_layout()
        save(fig, fname)

    from subterra.viz.terrain import plot_terrain_overview

    plot_terrain_overview(mapper, risk_map, out / "overview.png", robot_xy=robot_xy,
                          title=f"terrain: {risk_map.scans} scan(s) fused, {risk_map.resolution} m cells, robot at +")
    written.append("overview.png")

    newest = mapper.newest_points()
    if newest is not None:
        points, heights = newest
        xy = points[:, :2] + robot_xy
        threshold_m = mapper.config.to_dict()["ground"]["max_dist_to_line_m"]
        ground = np.abs(heights) <= threshold_m  # NaN -> obstacle
        if len(xy) > TOP_VIEW_MAX_POINTS:
            keep = np.random.default_rng(0).choice(len(xy), TOP_VIEW_MAX_POINTS, replace=False)
            xy, ground = xy[keep], ground[keep]
        fig, ax = plt.subplots(figsize=(5.6, 5.2))
        ax.scatter(*xy[ground].T, s=0.3, c="tab:green", label=f"ground ({int(ground.sum())})", rasterized=True)
        ax.scatter(*xy[~ground].T, s=0.3, c="tab:red", label=f"obstacle ({int((~ground).sum())})", rasterized=True)
        ax.plot(*robot_xy, "k+", ms=10)
        ax.set(xlim=extent[:2], ylim=extent[2:], aspect="equal", xlabel="world x [m]", ylabel="world y [m]",
               title="last cloud: ground segmentation")
        ax.legend(loc="upper right", markerscale=12, fontsize=7)
        fig.tight_layout()
        save(fig, "cloud_top.png")
    return written
