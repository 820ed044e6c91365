"""`subterra bench perception`: APF-PF per-frame time, Rust against the NumPy reference.

Both run the same frames, one after the other, in the same process: a 640x480 ``uint16``
frame in, the command out (count -> filter -> belief -> repulsion -> command). The Rust side
is one :class:`subterra.Pilot` step per frame (the drone's loop as ``fly`` runs it, a camera
standing still, goal 5 m ahead).
"""

from __future__ import annotations

import math
import platform
import time
from typing import Any

import numpy as np

from subterra._core import (
    ApfController,
    DepthPerception,
    PerceptionConfig,
    Pilot,
    PinholeCamera,
    Qmdp,
    __version__,
)
from subterra.bench.reference import apf_pf as reference
from subterra.perceive import timing_summary
from subterra.scenarios.synthetic import approaching_box_frames

__all__ = ["bench_perception"]

GOAL_BODY = (5.0, 0.0, 0.0)


def _camera_dict(camera: PinholeCamera) -> dict[str, float]:
    return {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy,
            "width": camera.width, "height": camera.height}


def bench_perception(
    *,
    frames: int = 200,
    reference_frames: int = 30,
    preset: str = "flight",
    mode: str = "particle",
    seed: int = 0,
    warmup: int = 5,
    progress: bool = True,
) -> dict[str, Any]:
    """Times ``frames`` Rust updates and ``reference_frames`` NumPy reference updates on the
    same synthetic sequence (a box approaching the D435 camera). Returns the JSON report."""
    if frames < 1 or reference_frames < 0 or warmup < 0:
        raise ValueError("frames must be >= 1, reference_frames and warmup >= 0")
    camera = PinholeCamera.d435()
    cfg_dict = reference.preset(preset)
    cfg_dict["filter"]["mode"] = mode
    import json

    config = PerceptionConfig.from_json(json.dumps(cfg_dict))
    depth, _ = approaching_box_frames(camera, frames=max(frames, reference_frames) + warmup, seed=seed)

    controller_name = {"particle": "apf-pf", "histogram": "apf-pf-histogram", "raw": "raw-apf"}[mode]
    pilot = Pilot(camera, preset, config=config, controller=controller_name, seed=seed)
    pilot.set_goal(GOAL_BODY)
    at_rest = np.eye(4)
    for n in range(warmup):
        pilot.step(depth[n], stamp=n / 15.0, world_from_body=at_rest)
    wall, inner = [], []
    stages: dict[str, list[float]] = {"count_s": [], "predict_s": [], "update_s": [], "belief_s": []}
    iterator = range(frames)
    if progress:
        from subterra._extras import tqdm

        iterator = tqdm(iterator, desc="rust", unit="frame", leave=False, disable=None)
    for n in iterator:
        frame = depth[warmup + n]
        t0 = time.perf_counter()
        step = pilot.step(frame, stamp=(warmup + n) / 15.0, world_from_body=at_rest)
        wall.append(time.perf_counter() - t0)
        inner.append(step.timings["total_s"])
        timings = step.perceptions[0].timings
        for k in stages:
            stages[k].append(timings[k])
    info = pilot.perception_info()
    perception = DepthPerception(camera, preset, config=config, seed=seed)
    controller = ApfController(preset, config=config)

    # The QMDP controller's step on the same beliefs (the controller `apf-pf-qmdp`).
    qmdp_wall: list[float] = []
    qmdp_pilot_wall: list[float] = []
    qmdp_build_s = math.nan
    if mode != "raw":
        t0 = time.perf_counter()
        qmdp = Qmdp(perception)
        qmdp_build_s = time.perf_counter() - t0
        replay = DepthPerception(camera, preset, config=config, seed=seed)
        for n in range(warmup + frames):
            out = replay.update(depth[n])
            t0 = time.perf_counter()
            action = qmdp.act(out)
            controller.command(GOAL_BODY, repulsive_body=action.velocity_body)
            if n >= warmup:
                qmdp_wall.append(time.perf_counter() - t0)
        # The whole step of the `apf-pf-qmdp` pilot (filter and QMDP), as `fly` runs it.
        qmdp_pilot = Pilot(camera, preset, config=config, controller="apf-pf-qmdp", seed=seed)
        qmdp_pilot.set_goal(GOAL_BODY)
        for n in range(warmup + frames):
            t0 = time.perf_counter()
            qmdp_pilot.step(depth[n], stamp=n / 15.0, world_from_body=at_rest)
            if n >= warmup:
                qmdp_pilot_wall.append(time.perf_counter() - t0)

    ref_wall: list[float] = []
    if reference_frames:
        pipeline = reference.ReferencePipeline(_camera_dict(camera), cfg_dict, seed=seed)
        for n in range(min(warmup, 2)):
            pipeline.command(GOAL_BODY, pipeline.update(depth[n]))
        iterator = range(reference_frames)
        if progress:
            from subterra._extras import tqdm

            iterator = tqdm(iterator, desc="numpy reference", unit="frame", leave=False, disable=None)
        for n in iterator:
            frame = depth[warmup + n]
            t0 = time.perf_counter()
            pipeline.command(GOAL_BODY, pipeline.update(frame))
            ref_wall.append(time.perf_counter() - t0)

    rust = timing_summary(wall)
    ref = timing_summary(ref_wall) if ref_wall else None
    return {
        "benchmark": "perception",
        "subterra_version": __version__,
        "machine": {"python": platform.python_version(), "processor": platform.processor() or platform.machine()},
        "preset": preset,
        "mode": mode,
        "image": {"width": camera.width, "height": camera.height, "dtype": "uint16"},
        "frames": frames,
        "transition": {
            "build_ms": info["transition_build_s"] * 1e3,
            "memory_bytes": info["transition_memory_bytes"],
            "states": info["state_count"],
        },
        "rust": {
            "what": "one Pilot.step per frame (frame in, command out)",
            "frame_wall": rust,
            "frame_inside_rust": timing_summary(inner),
            "stage_median_ms": {k.removesuffix("_s"): timing_summary(v)["median_ms"] for k, v in stages.items()},
        },
        "qmdp": None if not qmdp_wall else {
            "build_ms": qmdp_build_s * 1e3,
            "actions": len(qmdp.actions()),
            "step_wall": timing_summary(qmdp_wall),
            "pilot_frame_wall": timing_summary(qmdp_pilot_wall),
        },
        "numpy_reference": None if ref is None else {
            "frames": len(ref_wall),
            "frame_wall": ref,
            # The reference is the filter and the APF command only: with the obstacle memory
            # or the escape on, the pilot does more work than it, and the ratio says so.
            "same_work": not (config.to_dict()["memory"]["enabled"] or config.to_dict()["escape"]["enabled"]),
            "what": "count -> filter -> belief -> repulsion -> command (no obstacle memory, no escape)",
        },
        "speedup_vs_numpy_median": None if ref is None else ref["median_ms"] / rust["median_ms"],
        "target_median_ms": 0.25,
    }
