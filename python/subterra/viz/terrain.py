"""One picture of a terrain update: the segmented cloud and the risk layers side by side."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from subterra.errors import InputError
from subterra.viz.plots import _pyplot

#: The panels of :func:`plot_terrain_overview` after the cloud, in order.
OVERVIEW_LAYERS = ("collision", "step", "negative", "tilt", "risk")
#: Subsample of the cloud drawn in the top view (all points make a slow, heavy figure).
OVERVIEW_MAX_POINTS = 60_000


def plot_terrain_overview(
    mapper: Any,
    risk_map: Any,
    path: str | os.PathLike[str],
    *,
    robot_xy: tuple[float, float] | np.ndarray | None = None,
    title: str | None = None,
    layers: tuple[str, ...] = OVERVIEW_LAYERS,
) -> Path:
    """Writes a grid of panels to ``path``: the newest cloud from above (ground green,
    obstacles red) and each of ``layers`` of ``risk_map`` in [0, 1] (grey = not observed),
    with the robot as a black ``+`` at ``robot_xy`` (world metres; default the map's
    centre). ``mapper`` is the :class:`subterra.TerrainMapper` that made ``risk_map``."""
    names = tuple(risk_map.layer_names)
    for name in layers:
        if name not in names:
            raise InputError(f"argument `layers` names {name!r}, which is not a layer; the layers are {', '.join(names)}")
    plt = _pyplot()

    extent = risk_map.extent
    if robot_xy is None:
        robot_xy = ((extent[0] + extent[1]) / 2, (extent[2] + extent[3]) / 2)
    robot_xy = np.asarray(robot_xy, dtype=np.float64)
    observed = risk_map.layer("observed") > 0
    panels = 1 + len(layers)
    cols = min(3, panels)
    rows = (panels + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.0 * cols + 0.8, 3.9 * rows + 0.4), squeeze=False,
                             layout="constrained")
    flat = axes.ravel()

    ax = flat[0]
    newest = mapper.newest_points()
    if newest is not None:
        points, heights = newest
        xy = points[:, :2] + robot_xy
        threshold_m = mapper.config.to_dict()["ground"]["max_dist_to_line_m"]
        ground = np.abs(heights) <= threshold_m  # NaN (no ground line) counts as obstacle
        if len(xy) > OVERVIEW_MAX_POINTS:
            keep = np.random.default_rng(0).choice(len(xy), OVERVIEW_MAX_POINTS, replace=False)
            xy, ground = xy[keep], ground[keep]
        ax.scatter(*xy[ground].T, s=0.2, c="tab:green", label="ground", rasterized=True)
        ax.scatter(*xy[~ground].T, s=0.2, c="tab:red", label="obstacle", rasterized=True)
        ax.legend(loc="upper right", markerscale=15, fontsize=7)
    ax.set_title("newest scan: ground segmentation", fontsize=10)

    cmap = plt.get_cmap("RdYlGn_r").with_extremes(bad=(0.6, 0.6, 0.6))
    image = None
    for ax, name in zip(flat[1:], layers):
        values = risk_map.layer(name)
        level = np.float32(risk_map.lethal_risk)
        # A lethal cell is drawn (at its value) whether observed or not: never as unknown.
        is_lethal = risk_map.lethal() if name == "risk" else values >= level
        a = np.where(observed | is_lethal, values, np.nan)
        image = ax.imshow(np.ma.masked_invalid(a), origin="lower", extent=extent, interpolation="nearest",
                          cmap=cmap, vmin=0.0, vmax=1.0)
        lethal = int(np.count_nonzero(is_lethal))
        ax.set_title(f"{name} ({lethal} lethal cells)", fontsize=10)
    for ax in flat[:panels]:
        ax.plot(*robot_xy, "k+", ms=10, mew=2)
        ax.set(xlim=extent[:2], ylim=extent[2:], aspect="equal")
        ax.tick_params(labelsize=7)
    for ax in flat[panels:]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("world x [m]", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("world y [m]", fontsize=8)
    if image is not None:
        fig.colorbar(image, ax=list(flat), shrink=0.6, label="risk (grey: not observed)")
    fig.suptitle(title or f"terrain: {risk_map.scans} scan(s) fused, {risk_map.resolution} m cells", fontsize=11)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
