"""`subterra bench terrain`: terrain risk-map update time, Rust against the NumPy reference.

In one process and on one scan: a 100k-point scan -> the full risk map (coarse 200x200
with all layers, plus the fine map), a fused window of ``scans`` scans, Rust's
``segment_ground`` alone, and the NumPy reference (:mod:`subterra.bench.reference.terrain`)
of the same segmentation and of the whole coarse map of that scan (all 21 layers), with
the speed-up ratios and how closely the reference's map agrees with Rust's.

The scan is the real Ouster OS1-128 scan from ``../shared/data/ouster-os1-128-outdoor``
when present (cropped or repeated to ``points``), else a seeded synthetic OS1-128-like
scan (:func:`synthetic_scan`); the report says which.
"""

from __future__ import annotations

import math
import os
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["OUSTER_DIR", "bench_terrain", "random_terrain", "synthetic_scan"]

#: The real OS1-128 recording (three scans), if the shared data is present.
OUSTER_DIR = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "ouster-os1-128-outdoor"

#: OS1-128: 128 beams over a 45° vertical field of view (±22.5°).
OS1_128_BEAMS = 128
OS1_128_VFOV_DEG = 45.0


def random_terrain(rng: np.random.Generator, *, boxes: int = 8, steps: int = 2, max_slope_deg: float = 8.0):
    """A seeded random height field ``z = f(x, y)`` [m, world, ground at the robot = 0]:
    a sloped plane, ``steps`` straight steps (0.05-0.4 m up or down) and ``boxes``
    axis-aligned boxes (0.2-1.5 m tall) placed 2-25 m from the origin. Returns ``f``
    (vectorised over arrays)."""
    slope = np.tan(np.radians(rng.uniform(0.0, max_slope_deg)))
    az = rng.uniform(0, 2 * np.pi)
    gx, gy = slope * np.cos(az), slope * np.sin(az)
    step_dirs = rng.uniform(0, 2 * np.pi, steps)
    step_dist = rng.uniform(4.0, 20.0, steps)
    step_h = rng.uniform(0.05, 0.4, steps) * rng.choice([-1.0, 1.0], steps)
    box_r = rng.uniform(2.0, 25.0, boxes)
    box_a = rng.uniform(0, 2 * np.pi, boxes)
    box_c = np.column_stack([box_r * np.cos(box_a), box_r * np.sin(box_a)])
    box_half = rng.uniform(0.2, 1.5, (boxes, 2))
    box_h = rng.uniform(0.2, 1.5, boxes)

    def height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        z = gx * x + gy * y
        for d, dist, h in zip(step_dirs, step_dist, step_h):
            z = z + np.where(x * np.cos(d) + y * np.sin(d) > dist, h, 0.0)
        for c, half, h in zip(box_c, box_half, box_h):
            inside = (np.abs(x - c[0]) <= half[0]) & (np.abs(y - c[1]) <= half[1])
            z = np.where(inside, np.maximum(z, gx * c[0] + gy * c[1] + h), z)
        return z

    return height


def synthetic_scan(
    rng: np.random.Generator,
    *,
    points: int = 100_000,
    sensor_height: float = 0.7,
    beams: int = OS1_128_BEAMS,
    vfov_deg: float = OS1_128_VFOV_DEG,
    max_range_m: float = 40.0,
    step_m: float = 0.05,
    noise_m: float = 0.01,
    terrain=None,
) -> np.ndarray:
    """A spinning-lidar scan (``beams`` elevations evenly over ±vfov/2, ``points/beams``
    azimuths) ray-marched in ``step_m`` steps against ``terrain`` (default: a
    :func:`random_terrain`) from a sensor ``sensor_height`` above the ground at the origin.
    Range noise N(0, noise_m). Returns float32 ``(M, 3)`` sensor-centred points, M <=
    ``points`` (rays that hit nothing within ``max_range_m`` give no point)."""
    terrain = random_terrain(rng) if terrain is None else terrain
    azimuths = max(1, points // beams)
    el = np.radians(np.linspace(-vfov_deg / 2, vfov_deg / 2, beams))
    az = np.linspace(-np.pi, np.pi, azimuths, endpoint=False) + rng.uniform(0, 2 * np.pi / azimuths)
    el, az = (a.ravel() for a in np.meshgrid(el, az, indexing="ij"))
    d = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    t_hit = np.full(len(d), np.nan)
    active = np.flatnonzero(d[:, 2] < np.tan(np.radians(5.0)))  # the upward beams see the boxes only
    t = 0.3
    while t < max_range_m and active.size:
        p = d[active] * t
        below = p[:, 2] + sensor_height <= terrain(p[:, 0], p[:, 1])
        hit = active[below]
        # The crossing lies in (t - step, t]: take the midpoint.
        t_hit[hit] = t - 0.5 * step_m if t > 0.3 else t
        active = active[~below]
        t += step_m
    ok = np.isfinite(t_hit)
    rng_m = t_hit[ok] + rng.normal(0.0, noise_m, ok.sum())
    return (d[ok] * rng_m[:, None]).astype(np.float32)


def _ouster_scans(points: int) -> list[np.ndarray] | None:
    """The three real OS1-128 scans (finite points), each repeated or cropped to ``points``."""
    if not OUSTER_DIR.is_dir():
        return None
    out = []
    for i in range(3):
        p = np.load(OUSTER_DIR / f"OS-1-128_scan{i}.npy").astype(np.float32).reshape(-1, 3)
        p = p[np.isfinite(p).all(axis=1) & (np.abs(p).sum(axis=1) > 0)]
        reps = math.ceil(points / len(p))
        out.append(np.tile(p, (reps, 1))[:points])
    return out


def _summary(seconds: list[float]) -> dict[str, float]:
    ms = np.asarray(seconds, dtype=np.float64) * 1e3
    return {"median_ms": float(np.median(ms)), "p99_ms": float(np.percentile(ms, 99)), "mean_ms": float(ms.mean()), "runs": int(ms.size)}


def bench_terrain(
    points: int = 100_000,
    scans: int = 10,
    repeats: int = 20,
    seed: int = 0,
    reference_repeats: int = 3,
    use_real_data: bool = True,
) -> dict[str, Any]:
    """Times the terrain pipeline on one thread (``RAYON_NUM_THREADS=1`` is set if unset;
    the terrain core itself is single-threaded). Returns a JSON-ready report:

    * ``single_scan``: fresh mapper per run, one ``update`` of one scan (coarse map with
      every layer + fine map); wall time and the Rust stage timings (``RiskMap.timings``).
    * ``fused_window``: ``scans`` scans at 10 Hz along a straight drive, all fused
      (confidence 1); the time of the last update.
    * ``segment_ground``: Rust's segmentation alone, and the NumPy reference's.
    * ``numpy_reference``: the reference segmentation and the reference coarse map (all
      21 layers, from the scan; ``coarse_map_covers`` lists them) of the same scan;
      speed-ups against Rust's whole update and against its coarse path (prefilter +
      segmentation + coarse map stages); how many layers are bit-identical to Rust's and,
      for the others, in how many cells and by how much they differ.
    """
    os.environ.setdefault("RAYON_NUM_THREADS", "1")
    import subterra
    from subterra.bench.reference import terrain as reference
    from subterra.terrain import translation

    if points < 1 or scans < 1 or repeats < 1 or reference_repeats < 0:
        raise ValueError("points, scans, repeats must be >= 1 and reference_repeats >= 0")
    rng = np.random.default_rng(seed)
    real = _ouster_scans(points) if use_real_data else None
    if real is not None:
        from subterra.terrain import estimate_sensor_height

        sensor_height = float(estimate_sensor_height(real[0]))
        source = f"ouster-os1-128-outdoor scan0..2 ({OUSTER_DIR}), tiled/cropped to {points} points"
        frames = [real[i % 3] for i in range(scans)]
    else:
        sensor_height = 0.7
        terrain = random_terrain(rng)
        scan = synthetic_scan(rng, points=int(points * 2.2), sensor_height=sensor_height, terrain=terrain)
        scan = scan[rng.permutation(len(scan))[:points]] if len(scan) > points else scan
        source = f"synthetic OS1-128-like (128 beams, ±22.5°) over a random terrain, seed {seed}"
        frames = [scan] * scans
    scan = frames[0]
    body_from_sensor = translation(z=sensor_height)

    # 1. One scan -> full map, fresh mapper each time.
    wall, stages = [], {k: [] for k in ("prefilter_s", "segment_s", "coarse_s", "fine_s", "total_s")}
    for i in range(repeats + 1):
        mapper = subterra.TerrainMapper()
        t0 = time.perf_counter()
        risk_map = mapper.update(scan, stamp=0.0, body_from_sensor=body_from_sensor)
        dt = time.perf_counter() - t0
        if i == 0:
            continue  # warm-up
        wall.append(dt)
        for k, values in stages.items():
            values.append(risk_map.timings[k])
    stats = risk_map.stats

    # 2. A fused window: scans at 10 Hz, driving 0.1 m per scan along x.
    fused_wall, fused_stages = [], {k: [] for k in stages}
    fused_scans = 0
    for _ in range(max(1, repeats // 4)):
        mapper = subterra.TerrainMapper(config={"fusion": {"window_s": max(2.0, 0.1 * scans), "max_scans": max(20, scans)}})
        for j, frame in enumerate(frames):
            pose = translation(x=0.1 * j)
            t0 = time.perf_counter()
            m = mapper.update(frame, stamp=0.1 * j, world_from_body=pose, body_from_sensor=body_from_sensor, confidence=1.0)
            dt = time.perf_counter() - t0
        fused_wall.append(dt)
        for k, values in fused_stages.items():
            values.append(m.timings[k])
        fused_scans = m.scans

    # 3. segment_ground alone.
    level = scan.astype(np.float32)
    seg_wall = []
    for i in range(repeats + 1):
        t0 = time.perf_counter()
        labels = subterra.segment_ground(level, sensor_height=sensor_height)
        if i:
            seg_wall.append(time.perf_counter() - t0)

    # 4. The NumPy reference of the same work: the segmentation, and the whole coarse map.
    ref: dict[str, Any] | None = None
    if reference_repeats:
        cfg = reference.default_config()
        ref_seg, ref_map = [], []
        for _ in range(reference_repeats):
            t0 = time.perf_counter()
            ref_labels = reference.segment_ground(level, sensor_height=sensor_height, config=cfg)
            ref_seg.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            coarse = reference.coarse_map(scan, sensor_height=sensor_height, config=cfg)
            ref_map.append(time.perf_counter() - t0)
        agree = float((ref_labels == labels).mean())
        collision_agree = float((coarse.layer("collision") == risk_map.layer("collision")).mean())
        differing: dict[str, dict[str, Any]] = {}
        for name in reference.LAYER_NAMES:
            a, b = risk_map.layer(name), coarse.layer(name)
            same = (a == b) | (np.isnan(a) & np.isnan(b))
            if not same.all():
                both = np.isfinite(a) & np.isfinite(b)
                diff = np.abs(a[both].astype(np.float64) - b[both])
                differing[name] = {
                    "cells": int((~same).sum()),
                    "nan_mismatch_cells": int((np.isnan(a) != np.isnan(b)).sum()),
                    "max_abs_diff": float(diff.max()) if diff.size else 0.0,
                }
        seg_s, map_s = _summary(ref_seg), _summary(ref_map)
        coarse_path_ms = sum(float(np.median(stages[k]) * 1e3) for k in ("prefilter_s", "segment_s", "coarse_s"))
        ref = {
            "runs": reference_repeats,
            "segment_ground": seg_s,
            "coarse_map": map_s,
            "coarse_map_covers": list(reference.LAYER_NAMES) + ["cvar (RiskMap.cvar)"],
            "label_agreement": agree,
            "collision_layer_agreement": collision_agree,
            "bit_identical_layers": len(reference.LAYER_NAMES) - len(differing),
            "differing_layers": differing,
            "speedup_segment_ground_median": seg_s["median_ms"] / _summary(seg_wall)["median_ms"],
            # The reference's map includes its own prefilter and segmentation: compare with the
            # whole Rust update (which also makes the fine map) and with its coarse path alone.
            "speedup_full_update_vs_reference_map_median": map_s["median_ms"] / _summary(wall)["median_ms"],
            "speedup_coarse_path_vs_reference_map_median": map_s["median_ms"] / coarse_path_ms,
        }

    return {
        "benchmark": "terrain",
        "subterra_version": subterra.__version__,
        "machine": {"python": platform.python_version(), "processor": platform.processor() or platform.machine(), "cpus": os.cpu_count()},
        "threads": os.environ.get("RAYON_NUM_THREADS"),
        "scan_source": source,
        "points": len(scan),
        "sensor_height_m": sensor_height,
        "ground_points": int(stats.get("ground_points", 0)),
        "map": {"shape": list(risk_map.shape), "resolution_m": risk_map.resolution, "layers": len(risk_map.layer_names)},
        "single_scan": {
            "update_wall": _summary(wall),
            "rust_stage_median_ms": {k.removesuffix("_s"): float(np.median(v) * 1e3) for k, v in stages.items()},
        },
        "fused_window": {
            "scans": fused_scans,
            "update_wall": _summary(fused_wall),
            "rust_stage_median_ms": {k.removesuffix("_s"): float(np.median(v) * 1e3) for k, v in fused_stages.items()},
        },
        "segment_ground": {"wall": _summary(seg_wall)},
        "numpy_reference": ref,
        "targets_ms": {"single_scan": 10.0, "fused_window": 25.0},
    }
