"""`subterra bench sim`: simulated sensor frames per second, against MuJoCo's `mj_multiRay`
casting the same rays into the same world in the same run (when `mujoco` is installed).

Times are of the Python calls (`DepthCamera.render`, `Lidar.scan`), with the fresh NumPy
arrays they return; `cargo bench -p subterra-sim --bench sim` times the Rust casts alone."""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np

from subterra._compat import tomllib
from subterra.perceive import timing_summary
from subterra.sim import DepthCamera, Lidar, World
from subterra.sim.render import BODY_FROM_OPTICAL, pose_matrix, start_pose

__all__ = ["bench_sim", "mujoco_model"]


def _rotation_z(yaw: float) -> str:
    return f"0 0 {yaw!r}"


def mujoco_model(world: World):
    """The world as a MuJoCo model (bounded primitives and planes; no height field), or
    ``None`` if `mujoco` is not installed or the world has terrain."""
    try:
        import mujoco
    except ImportError:
        return None
    spec = tomllib.loads(world.to_toml())
    if spec.get("heightfield"):
        return None
    geoms = []
    f = lambda v: " ".join(repr(float(x)) for x in v)  # noqa: E731
    for c in spec.get("cylinder", []):
        geoms.append(f'<geom type="cylinder" fromto="{f(c["a"])} {f(c["b"])}" size="{c["radius"]!r}"/>')
    for c in spec.get("capsule", []):
        geoms.append(f'<geom type="capsule" fromto="{f(c["a"])} {f(c["b"])}" size="{c["radius"]!r}"/>')
    for b in spec.get("box", []):
        half = [s / 2 for s in b["size"]]
        geoms.append(f'<geom type="box" pos="{f(b["centre"])}" size="{f(half)}" euler="{_rotation_z(b.get("yaw", 0.0))}"/>')
    for s in spec.get("sphere", []):
        geoms.append(f'<geom type="sphere" pos="{f(s["centre"])}" size="{s["radius"]!r}"/>')
    for item in spec.get("item", []):
        if item.get("solid"):
            geoms.append(f'<geom type="sphere" pos="{f(item["position"])}" size="0.15"/>')
    for p in spec.get("plane", []):
        geoms.append(f'<geom type="plane" pos="{f(p["point"])}" zaxis="{f(p["normal"])}" size="0 0 1"/>')
    xml = f'<mujoco><compiler angle="radian"/><worldbody>{"".join(geoms)}</worldbody></mujoco>'
    model = mujoco.MjModel.from_xml_string(xml)
    return model


def _median_ms(fn, repeats: int, warmup: int = 2) -> dict[str, float]:
    # Untimed calls first: a sensor's first frames fill the buffers it then renders into.
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return timing_summary(times)


def bench_sim(*, repeats: int = 20, seed: int = 0) -> dict[str, Any]:
    """Times a D435 frame of `highbay` and `tunnel` (one thread and all cores) and an
    os1_64 scan of `mine`, each from the scenario's start pose; with MuJoCo where possible."""
    threads = os.cpu_count() or 1
    camera = DepthCamera.d435()
    cam = camera.camera
    report: dict[str, Any] = {"benchmark": "sim", "repeats": repeats, "threads_all": threads, "cases": {}}
    for name in ("highbay", "tunnel"):
        world = World.scenario(name, seed)
        position, yaw, _ = start_pose(world)
        world_from_camera = pose_matrix(position, yaw) @ BODY_FROM_OPTICAL
        depth = camera.render(world, world_from_camera)
        case: dict[str, Any] = {
            "rays": cam.width * cam.height,
            "valid_fraction": float((depth > 0).mean()),
            "rust_one_thread": _median_ms(lambda: camera.render(world, world_from_camera), repeats),
            "rust_all_threads": _median_ms(lambda: camera.render(world, world_from_camera, threads=threads), repeats),
            "target_one_thread_median_ms": 10.0,
        }
        model = mujoco_model(world)
        if model is not None:
            import mujoco

            data = mujoco.MjData(model)
            mujoco.mj_forward(model, data)  # places the geoms (world frame poses)
            v, u = np.mgrid[0 : cam.height, 0 : cam.width]
            rays = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u, float)], -1).reshape(-1, 3)
            z_over_range = 1.0 / np.linalg.norm(rays, axis=1)
            dirs = (rays * z_over_range[:, None]) @ world_from_camera[:3, :3].T
            vec = np.ascontiguousarray(dirs.ravel())
            n = dirs.shape[0]
            geomid = np.zeros(n, np.int32)
            dist = np.zeros(n, np.float64)
            pnt = np.ascontiguousarray(world_from_camera[:3, 3], np.float64)

            def cast():
                mujoco.mj_multiRay(model, data, pnt, vec, None, 1, -1, geomid, dist, None, n, 10.0 / z_over_range.min())

            case["mujoco_multiray"] = _median_ms(cast, repeats)
            mj_depth = np.where(dist >= 0, dist * z_over_range, 0.0)
            mj_depth[mj_depth > 10.0] = 0.0
            both = (mj_depth > 0) & (depth.ravel() > 0)
            case["mujoco_depth_agreement_p99_m"] = float(np.percentile(np.abs(mj_depth[both] - depth.ravel()[both]), 99)) if both.any() else None
            case["ratio_mujoco_over_rust"] = case["mujoco_multiray"]["median_ms"] / case["rust_one_thread"]["median_ms"]
        else:
            case["mujoco_multiray"] = "mujoco not installed (pip install mujoco)"
        report["cases"][f"depth_d435_{name}"] = case

    world = World.scenario("mine", seed)
    position, yaw, _ = start_pose(world)
    ground = world.ground_height(position[0], position[1]) or 0.0
    sensor = pose_matrix([position[0], position[1], ground + 0.7], yaw)
    lidar = Lidar("os1_64")
    report["cases"]["lidar_os1_64_mine"] = {
        "rays": lidar.ray_count,
        "rust_one_thread": _median_ms(lambda: lidar.scan(world, sensor), repeats),
        "target_one_thread_median_ms": 5.0,
        "mujoco_multiray": "not run: the mine is a height field (MuJoCo hfield set-up left out)",
    }
    return report
