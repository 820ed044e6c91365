"""Synthetic depth frames with a known answer, for demos, tests and benchmarks.

They are drawn with NumPy from a seeded generator: same seed, same frames.
"""

from __future__ import annotations

import numpy as np

from subterra._core import PinholeCamera

__all__ = ["approaching_box_frames", "noise_only_frames"]

#: A wall this far away is beyond every preset's horizon [m].
BACKGROUND_DEPTH_M = 3.0


def approaching_box_frames(
    camera: PinholeCamera,
    frames: int = 30,
    *,
    start_m: float = 1.6,
    end_m: float = 0.5,
    box_size_m: float = 0.5,
    noise_sigma_m: float = 0.01,
    dropout: float = 0.05,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """A square box straight ahead coming from ``start_m`` to ``end_m`` in front of a far wall.

    Returns ``(depth, box_depth_m)``: ``depth`` is ``(frames, H, W)`` ``uint16`` millimetres
    with Gaussian noise of ``noise_sigma_m`` and a fraction ``dropout`` of no-return pixels;
    ``box_depth_m`` is the box's true depth per frame.
    """
    if frames < 1:
        raise ValueError(f"argument `frames` must be >= 1, got {frames}")
    rng = np.random.default_rng(seed)
    h, w = camera.height, camera.width
    v, u = np.mgrid[0:h, 0:w]
    box_depth = np.linspace(start_m, end_m, frames)
    out = np.empty((frames, h, w), np.uint16)
    for n, z in enumerate(box_depth):
        half_px_u = 0.5 * box_size_m * camera.fx / z
        half_px_v = 0.5 * box_size_m * camera.fy / z
        inside = (np.abs(u - camera.cx) <= half_px_u) & (np.abs(v - camera.cy) <= half_px_v)
        metres = np.where(inside, z, BACKGROUND_DEPTH_M) + rng.normal(0.0, noise_sigma_m, (h, w))
        metres[rng.random((h, w)) < dropout] = 0.0
        out[n] = np.clip(np.round(metres * 1000.0), 0, 65535).astype(np.uint16)
    return out, box_depth


def noise_only_frames(
    camera: PinholeCamera,
    frames: int = 10,
    *,
    every: int = 10,
    mean_m: float = 0.6,
    sigma_m: float = 0.2,
    seed: int = 0,
) -> np.ndarray:
    """Frames with no obstacle: every ``every``-th pixel returns a depth drawn from
    ``N(mean_m, sigma_m)`` (the paper's test noise), the rest return nothing.
    ``(frames, H, W)`` ``uint16`` millimetres."""
    rng = np.random.default_rng(seed)
    h, w = camera.height, camera.width
    out = np.zeros((frames, h * w), np.uint16)
    idx = np.arange(0, h * w, every)
    for n in range(frames):
        metres = np.abs(rng.normal(mean_m, sigma_m, idx.size))
        out[n, idx] = np.clip(np.round(metres * 1000.0), 1, 65535).astype(np.uint16)
    return out.reshape(frames, h, w)
