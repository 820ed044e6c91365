"""Run APF-PF over a sequence of depth frames and summarise it (`subterra perceive`)."""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from subterra._core import PerceptionConfig, Pilot, PinholeCamera
from subterra.errors import InputError

__all__ = ["run_perception", "perceive_folder", "timing_summary"]


def timing_summary(seconds: Sequence[float]) -> dict[str, float]:
    """Median, p99 and mean of per-frame times, in milliseconds."""
    ms = np.asarray(seconds, dtype=np.float64) * 1e3
    if ms.size == 0:
        return {"median_ms": float("nan"), "p99_ms": float("nan"), "mean_ms": float("nan")}
    return {
        "median_ms": float(np.median(ms)),
        "p99_ms": float(np.percentile(ms, 99)),
        "mean_ms": float(ms.mean()),
    }


def run_perception(
    frames: Iterable[tuple[str, np.ndarray, float | None]],
    camera: PinholeCamera,
    *,
    preset: str = "flight",
    config: PerceptionConfig | None = None,
    seed: int = 0,
    goal_body: Sequence[float] = (5.0, 0.0, 0.0),
    frame_period_s: float = 1.0 / 15.0,
    progress: bool = True,
    total: int | None = None,
) -> tuple[Pilot, list[dict[str, Any]]]:
    """Runs the drone's pilot (:class:`subterra.Pilot`) over ``(name, depth, scale)``
    frames; one record per frame.

    The frames are taken as seen by a camera standing still at the body origin, looking
    forward, ``frame_period_s`` apart, with the goal at ``goal_body``: the preset's obstacle
    memory and escape (``flight-memory``, ``flight-escape``) run as in a flight. Each record
    holds the most probable voxel (depth, probability, index), ``P(free)``, the closest raw
    depth, the belief's repulsive force, the memory's (``memory_cells`` it held), the command
    toward the goal and the per-stage timings in seconds.
    """
    if not (isinstance(frame_period_s, (int, float)) and np.isfinite(frame_period_s) and frame_period_s > 0):
        raise InputError(f"argument `frame_period_s` must be finite and > 0, got {frame_period_s!r}")
    pilot = Pilot(camera, preset, config=config, controller="apf-pf", seed=seed)
    pilot.set_goal(goal_body)
    at_rest = np.eye(4)
    records: list[dict[str, Any]] = []
    iterator: Iterable[tuple[str, np.ndarray, float | None]] = frames
    if progress:
        from subterra._extras import tqdm

        iterator = tqdm(frames, total=total, desc="perceive", unit="frame", leave=False, disable=None)
    for n, (name, depth, scale) in enumerate(iterator):
        step = pilot.step(depth, stamp=n * frame_period_s, world_from_body=at_rest, scale=scale)
        out, cmd = step.perceptions[0], step.command
        mp = out.most_probable
        records.append(
            {
                "frame": n,
                "name": name,
                "p_free": out.p_free,
                "map_depth_m": None if mp is None else mp.depth_m,
                "map_probability": None if mp is None else mp.probability,
                "map_voxel": None if mp is None else list(mp.voxel),
                "closest_depth_m": out.closest_depth_m,
                "valid_pixels": out.valid_pixels,
                "in_range_pixels": out.in_range_pixels,
                "repulsive_body": out.repulsive_body.tolist(),
                "memory_repulsive_body": step.memory_repulsive_body.tolist(),
                "memory_cells": step.memory_cells,
                "command": {"v_x": cmd.v_x_m_s, "v_y": cmd.v_y_m_s, "v_z": cmd.v_z_m_s, "yaw_rate": cmd.yaw_rate_rad_s},
                "timings_s": {**out.timings, "pilot_s": step.timings["total_s"]},
            }
        )
    return pilot, records


def perceive_folder(
    directory: str | os.PathLike[str],
    intrinsics: str | os.PathLike[str],
    *,
    out_dir: str | os.PathLike[str],
    preset: str = "flight",
    config: PerceptionConfig | None = None,
    scale: float | None = None,
    seed: int = 0,
    goal_body: Sequence[float] = (5.0, 0.0, 0.0),
    progress: bool = True,
) -> dict[str, Any]:
    """Runs APF-PF over every depth image in ``directory`` and writes ``summary.json`` and
    ``perception.png`` into ``out_dir``. Returns the summary."""
    from subterra.io import list_depth_files, read_depth, read_intrinsics

    files = list_depth_files(directory)
    camera = read_intrinsics(intrinsics).to_camera()

    def frames() -> Iterable[tuple[str, np.ndarray, float | None]]:
        for path in files:
            image = read_depth(path, scale=scale)
            if image.data.shape != (camera.height, camera.width):
                raise InputError(
                    f"depth image is {image.data.shape[1]}x{image.data.shape[0]} but the intrinsics "
                    f"say {camera.width}x{camera.height}: {path}"
                )
            yield path.name, image.data, (image.scale_m_per_unit if image.data.dtype == np.uint16 else None)

    pilot, records = run_perception(
        frames(), camera, preset=preset, config=config, seed=seed, goal_body=goal_body,
        progress=progress, total=len(files),
    )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = summarise(pilot, records, source=str(directory), preset=preset)
    (out / "summary.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    from subterra.viz.plots import plot_depth_trace

    plot_depth_trace(records, out / "perception.png", title=f"APF-PF ({preset}) on {Path(directory).name}")
    return summary


def summarise(pilot: Pilot, records: list[dict[str, Any]], *, source: str, preset: str) -> dict[str, Any]:
    """The JSON summary of a run of ``pilot`` (its first camera)."""
    totals = [r["timings_s"]["total_s"] for r in records]
    stages = {
        stage: timing_summary([r["timings_s"][stage] for r in records])["median_ms"]
        for stage in ("count_s", "predict_s", "update_s", "belief_s", "pilot_s")
        if all(stage in r["timings_s"] for r in records)
    }
    cam = pilot.camera()
    info = pilot.perception_info()
    return {
        "source": source,
        "preset": preset,
        "frames": len(records),
        "camera": {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy, "width": cam.width, "height": cam.height},
        "grid_shape": list(info["grid_shape"]),
        "states": info["state_count"],
        "memory": pilot.has_memory,
        "transition": {
            "build_ms": info["transition_build_s"] * 1e3,
            "memory_bytes": info["transition_memory_bytes"],
        },
        "timing": {**timing_summary(totals), "stage_median_ms": {k.removesuffix("_s"): v for k, v in stages.items()}},
        "p_free_mean": float(np.mean([r["p_free"] for r in records])) if records else None,
        "records": records,
    }
