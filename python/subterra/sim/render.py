"""`subterra sim render SCENARIO`: pictures of a scene so a person can see it."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from subterra._extras import require
from subterra.sim import DepthCamera, Lidar, World

__all__ = ["pose_matrix", "render_scenario", "start_pose"]


def pose_matrix(position, yaw: float) -> np.ndarray:
    """`world_from_body` of a body at ``position`` [m] with heading ``yaw`` [rad] (FLU, z up)."""
    c, s = math.cos(yaw), math.sin(yaw)
    m = np.eye(4)
    m[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    m[:3, 3] = position
    return m


#: Forward-looking optical frame in an FLU body: optical z -> body x, x -> -y, y -> -z.
BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def start_pose(world: World) -> tuple[np.ndarray, float, str | None]:
    """Where a run on ``world`` starts: its first route's start region (or the first
    region), facing the route's goal. Returns ``(position, yaw, goal region)``."""
    regions = world.regions
    if world.routes:
        _, a, b = world.routes[0]
        start, goal = np.array(regions[a][0]), np.array(regions[b][0])
        return start, math.atan2(goal[1] - start[1], goal[0] - start[0]), b
    if regions:
        return np.array(next(iter(regions.values()))[0]), 0.0, None
    lo, hi = world.bounds
    return (lo + hi) / 2, 0.0, None


def render_scenario(name: str, out_dir: str | os.PathLike[str], *, seed: int = 0, noise: str = "d435") -> dict[str, Path]:
    """Writes ``<name>-depth.png`` (a D435 frame from the start, truth and noisy),
    ``<name>-map.png`` (top-down world with regions, routes and the lidar scan) and
    returns their paths."""
    require("matplotlib", "viz", "Plots")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    world = World.scenario(name, seed)
    position, yaw, _ = start_pose(world)
    if name in ("mine", "subway", "slopes", "rough", "ledge", "cave"):
        ground = world.ground_height(position[0], position[1])
        position = np.array([position[0], position[1], (ground or 0.0) + 0.4])
    world_from_body = pose_matrix(position, yaw)
    camera = DepthCamera.d435()
    truth = camera.render(world, world_from_body @ BODY_FROM_OPTICAL)
    noisy = camera.render(world, world_from_body @ BODY_FROM_OPTICAL, noise=noise, seed=seed)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.4))
    for ax, img, title in ((axes[0], truth, "ground truth"), (axes[1], noisy, f"noise: {noise}")):
        shown = np.where(img > 0, img, np.nan)
        im = ax.imshow(shown, cmap="turbo", vmin=0.0, vmax=min(10.0, float(np.nanmax(shown)) if np.isfinite(shown).any() else 10.0))
        ax.set_title(f"{name}: D435 depth, {title}")
        ax.axis("off")
    fig.colorbar(im, ax=axes, label="depth [m] (white = no return)", shrink=0.85)
    depth_png = out / f"{name}-depth.png"
    fig.savefig(depth_png, dpi=100)
    plt.close(fig)

    lidar = Lidar("os1_64")
    points, _ = lidar.scan(world, world_from_body)
    world_points = points.astype(np.float64) @ world_from_body[:3, :3].T + world_from_body[:3, 3]
    fig, ax = plt.subplots(figsize=(10, 6))
    lo, hi = world.bounds
    ax.scatter(world_points[:, 0], world_points[:, 1], s=0.5, c=world_points[:, 2], cmap="viridis", label="os1_64 scan (colour = height)")
    for region, (centre, radius) in world.regions.items():
        ax.add_patch(plt.Circle(centre[:2], radius, color="tab:red", alpha=0.3))
        ax.annotate(region, centre[:2], ha="center", va="center", fontsize=9)
    for _, a, b in world.routes:
        ca, cb = world.regions[a][0], world.regions[b][0]
        ax.annotate("", xy=cb[:2], xytext=ca[:2], arrowprops={"arrowstyle": "->", "color": "tab:red", "alpha": 0.5})
    ax.plot(*position[:2], "k^", ms=10, label="sensor")
    ax.set_xlim(lo[0] - 0.5, hi[0] + 0.5)
    ax.set_ylim(lo[1] - 0.5, hi[1] + 0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{name} (seed {seed}): {world.primitive_count} primitives, top-down with one lidar scan")
    ax.legend(loc="upper right", fontsize=8)
    map_png = out / f"{name}-map.png"
    fig.savefig(map_png, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return {"depth": depth_png, "map": map_png}
