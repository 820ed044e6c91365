"""Terrain risk for a ground robot (STEP, Fan et al. 2021): lidar scans in, a multi-layer risk map out.

>>> import numpy as np, subterra
>>> from subterra.terrain import translation
>>> mapper = subterra.TerrainMapper()          # Husky robot, the configs/terrain.toml values
>>> xy = np.mgrid[-8:8:0.1, -8:8:0.1].reshape(2, -1).T
>>> ground = np.column_stack([xy, np.full(len(xy), -0.5)]).astype(np.float32)  # sensor 0.5 m up
>>> risk_map = mapper.update(ground, stamp=0.0, body_from_sensor=translation(z=0.5))
>>> risk_map.layer("tilt").shape
(200, 200)

The classes are the Rust core's (``subterra._core``):

* :class:`TerrainMapper` ``(robot=None | dict | RobotConfig, config=None | dict |
  TerrainConfig | path)``; ``update(points, stamp=, world_from_body=, body_from_sensor=,
  confidence=)`` returns the coarse fused :class:`RiskMap`; the fine short-range map of
  the same update is ``mapper.last_fine``.
* :class:`RiskMap`: ``layer(name)`` (a ``float32`` ``(ny, nx)`` copy, row ``iy`` along
  world y), ``layer_names``, ``risk_at(x, y)``, ``value_at(name, x, y)``,
  ``cvar(alpha)``, ``to_image()``, ``resolution``, ``origin``, ``extent``, ``stats``,
  ``timings``.
* :func:`segment_ground` ``(points, sensor_height=, config=None)``: ground labels.
* :class:`RobotConfig`, :class:`TerrainConfig`: typed configs (partial dicts are laid
  over the defaults).

Frames: the body frame is FLU with its origin on the ground at the footprint's centre
(REP 120 ``base_footprint``), so a lidar mounted ``h`` metres up has
``body_from_sensor`` = translation ``(0, 0, h)``. Maps are world-axis-aligned and centred
on the robot. See ``docs/terrain.md``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from subterra._core import RiskMap, RobotConfig, TerrainConfig, TerrainMapper, segment_ground
from subterra.errors import InputError

__all__ = [
    "DEFAULT_CONFIG_PATH",
    "RiskMap",
    "RobotConfig",
    "TerrainConfig",
    "TerrainMapper",
    "estimate_sensor_height",
    "load_terrain_config",
    "lethal_cells",
    "segment_ground",
    "translation",
]

#: The committed default config (equal to ``TerrainConfig()``; a test checks it).
DEFAULT_CONFIG_PATH = Path(__file__).resolve().parents[3] / "configs" / "terrain.toml"

#: Horizontal ring [m] whose lowest dense layer of points is taken as the ground by
#: :func:`estimate_sensor_height`: past the robot's own shadow, before the returns thin out.
SENSOR_HEIGHT_RING_M = (3.0, 15.0)
#: Height-histogram bin of :func:`estimate_sensor_height` [m].
#: A bin is part of a dense layer with at least this fraction of the fullest bin's points.
SENSOR_HEIGHT_DENSE_FRACTION = 0.05
#: ... and at least this many points.
SENSOR_HEIGHT_MIN_POINTS = 10
SENSOR_HEIGHT_BIN_M = 0.05


def load_terrain_config(path: str | os.PathLike[str]) -> TerrainConfig:
    """Reads a terrain config from a TOML file laid out like ``configs/terrain.toml``.

    Raises :class:`~subterra.errors.FileFormatError` if the file cannot be read and
    :class:`~subterra.errors.ConfigError` if a value is invalid (the message names the
    field and ends with the path). The file must be a regular file of at most 16 MiB of
    UTF-8 text: a FIFO, a device or a folder fails at once.
    """
    from subterra._files import read_regular_text
    from subterra.errors import ConfigError

    p = Path(path)
    text = read_regular_text(p, "terrain config file")
    try:
        return TerrainConfig.from_toml(text)
    except ConfigError as exc:
        raise ConfigError(f"{exc}: {p}") from exc


def translation(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    """A 4x4 ``float64`` pure translation [m], e.g. ``body_from_sensor = translation(z=0.7)``."""
    t = np.eye(4)
    t[:3, 3] = (_finite(x, "x"), _finite(y, "y"), _finite(z, "z"))
    return t


#: Most points :func:`estimate_sensor_height` takes (the core's limit on one cloud, 2^25);
#: checked on the array's shape before anything is copied.
MAX_POINTS = 1 << 25


def _finite(value: object, name: str) -> float:
    """A finite real number (not a bool, a complex, a string or None), or an InputError naming it."""
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))
    if not ok or not np.isfinite(float(value)):
        raise InputError(f"argument `{name}` must be a finite real number, got {value!r}")
    return float(value)


def estimate_sensor_height(points: np.ndarray, *, ring_m: tuple[float, float] = SENSOR_HEIGHT_RING_M) -> float:
    """Height of a roughly level sensor above the ground around it [m].

    The points' z in ``ring_m`` (horizontal range, sensor-centred) are binned in
    :data:`SENSOR_HEIGHT_BIN_M` bins. The ground is the fullest bin (on open ground most
    returns of the ring are ground), refined to the mean z within one bin of it; returns
    ``-z``. If that puts the sensor at or below the ground (indoors, where walls and
    furniture fill the bins above the floor), the ground is instead the **lowest dense
    layer**: the lowest bin holding at least :data:`SENSOR_HEIGHT_DENSE_FRACTION` of the
    fullest bin's count and at least :data:`SENSOR_HEIGHT_MIN_POINTS` points. Give the
    mounting height instead when it is known.

    Raises :class:`~subterra.errors.InputError` if no point lies in the ring.
    """
    try:
        lo_m, hi_m = ring_m
    except (TypeError, ValueError):
        raise InputError(f"argument `ring_m` must be 2 numbers (min, max) [m], got {ring_m!r}") from None
    lo_m, hi_m = _finite(lo_m, "ring_m"), _finite(hi_m, "ring_m")
    if not 0.0 <= lo_m < hi_m:
        raise InputError(f"argument `ring_m` must be (min, max) with 0 <= min < max [m], got {ring_m!r}")
    ring_m = (lo_m, hi_m)
    # The dtype and the shape are checked on the view, before the float64 copy: a broadcast
    # view of 10^9 points is refused, not materialised.
    p = points if isinstance(points, np.ndarray) else np.asarray(points)
    if p.dtype.kind not in "fiu":
        raise InputError(f"argument `points` must be a real (N, 3) array [m], got dtype {p.dtype}")
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"argument `points` must have shape (N, 3), got {p.shape}")
    if p.shape[0] > MAX_POINTS:
        raise InputError(f"argument `points` has shape {p.shape}: more than {MAX_POINTS} points, the most accepted")
    p = p.astype(np.float64)
    p = p[np.isfinite(p).all(axis=1)]
    r = np.hypot(p[:, 0], p[:, 1])
    z = p[(r >= ring_m[0]) & (r <= ring_m[1]), 2]
    if z.size == 0:
        raise InputError(f"argument `points` has no finite point {ring_m[0]}-{ring_m[1]} m from the sensor to find the ground in")
    lo = np.floor(z.min() / SENSOR_HEIGHT_BIN_M) * SENSOR_HEIGHT_BIN_M
    counts, edges = np.histogram(z, bins=np.arange(lo, z.max() + 2 * SENSOR_HEIGHT_BIN_M, SENSOR_HEIGHT_BIN_M))

    def refined(k: int) -> float:
        centre = 0.5 * (edges[k] + edges[k + 1])
        return float(-z[np.abs(z - centre) <= SENSOR_HEIGHT_BIN_M].mean())

    height = refined(int(np.argmax(counts)))
    if height <= 0.0:
        dense = np.flatnonzero(counts >= max(SENSOR_HEIGHT_DENSE_FRACTION * counts.max(), SENSOR_HEIGHT_MIN_POINTS))
        if dense.size:
            height = refined(int(dense[0]))
    return height


def lethal_cells(risk_map: RiskMap) -> dict[str, int]:
    """Number of lethal cells: for the combined ``risk`` the map's own count
    (:meth:`RiskMap.lethal_count`, risk at or above ``risk_map.lethal_risk``, observed or
    not: the cells the planners never enter, the pictures draw red and an exported
    ``OccupancyGrid`` marks 100), and per risk layer the cells that layer alone makes lethal
    (at or above the same level)."""
    names = ("collision", "step", "negative", "tilt", "roughness", "unknown", "mission")
    level = np.float32(risk_map.lethal_risk)
    counts = {name: int(np.count_nonzero(risk_map.layer(name) >= level)) for name in names}
    counts["risk"] = int(risk_map.lethal_count())
    return counts
