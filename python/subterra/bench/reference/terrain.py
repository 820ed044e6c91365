"""Terrain ground segmentation and basic map layers in plain NumPy: the reference for
parity tests and benchmarks.

This module re-implements, from their documentation, two parts of DESIGN.md section 2
as the Rust core (``crates/subterra/src/terrain``) defines them:

1. :func:`segment_ground` / :func:`ground_heights`: the ground segmentation by line fits
   in cylindrical coordinates (Himmelsbach et al. 2010) exactly as the module doc of
   ``ground.rs`` ("The algorithm, exactly") writes it out: polar bins, lowest-point
   prototypes, per-sector line growing with the slope / prediction / RMSE / gap /
   start-height rules, each bin's line, and the label ``|h| <= max_dist_to_line_m``.
2. :func:`coarse_layers`: the coarse map's geometry layers from **one** scan, as the
   module doc of ``risk.rs`` ("The layers, exactly") defines them: ``count``,
   ``ground_count``, ``min_height``, ``max_height``, ``ground_height`` (where the cell
   has ground points) and the ``collision`` risk layer.

Not reproduced (documented here so that nobody believes otherwise):

* ``ground_height`` of cells without ground points (the newest scan's ground line at
  the cell centre where it *covers* the cell's polar bin; Rust queries the polar bin with
  a fast ``atan2``), hence also ``observed``, ``unknown``, and every layer computed from
  ground heights: ``slope``, ``plane_residual``, ``step_height``/``step``,
  ``tilt_angle``/``tilt``, ``roughness``; ``negative_depth``/``negative``; ``age``;
  ``mission``, ``risk`` and ``risk_variance``. :func:`coarse_layers` returns the layer
  ``ground_height`` NaN where the cell has no ground point; compare only where
  ``ground_count > 0``.
* Temporal fusion (one scan only), non-identity ``world_from_body``, a rotated
  sensor mount, and the optional prefilter stages (voxel downsampling and sparse-outlier
  removal must be off, as they are by default).

Numerics, chosen to agree with the Rust code bit for bit where the docs leave room:

* Every segmentation computation is in float64 from the float32 input coordinates; the
  least-squares line is the one of ``ground.rs``'s running sums centred on the segment's
  first point (``LineSums``), so a threshold comparison sees the same rounding. The
  height above the line is rounded to float32 before the label test against
  ``float32(max_dist_to_line_m)``.
* The sector uses NumPy's ``arctan2`` for the documented ``atan2``. Rust uses a fast
  ``atan2`` corrected by cross products with the sector boundaries; the two differ only
  within ~1e-15 rad of a sector boundary — which points exactly on a grid's axes or
  diagonals are (then a whole run of prototypes moves sector and labels change).
  ``boundary_rule="edges"`` reproduces Rust's tie-break there as well.
* Map heights are float32 sums in input order, as the Rust accumulators.

The configuration is the nested ``dict`` of ``configs/terrain.toml``
(``subterra.TerrainConfig().to_dict()``), the robot the dict of
``subterra.RobotConfig().to_dict()``. The module imports only NumPy and the standard
library.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "DEFAULT_CONFIG_PATH",
    "HUSKY",
    "GroundLine",
    "GroundSegmentation",
    "coarse_layers",
    "default_config",
    "fit_sector_lines",
    "ground_heights",
    "polar_bins",
    "prototypes",
    "segment_ground",
]

#: The committed default terrain config (equal to ``TerrainConfig()``).
DEFAULT_CONFIG_PATH = Path(__file__).resolve().parents[4] / "configs" / "terrain.toml"

#: The Husky-like robot of ``RobotConfig::default()`` (DESIGN §2) [m, m/s, deg].
HUSKY: dict[str, float] = {
    "length_m": 0.99,
    "width_m": 0.67,
    "height_m": 0.4,
    "ground_clearance_m": 0.13,
    "max_speed_m_s": 1.0,
    "tilt_safe_deg": 10.0,
    "tilt_lethal_deg": 25.0,
}


def default_config() -> dict[str, Any]:
    """The default terrain config as a nested dict, read from ``configs/terrain.toml``."""
    with open(DEFAULT_CONFIG_PATH, "rb") as f:
        return tomllib.load(f)


def _ground_cfg(config: dict[str, Any] | None) -> dict[str, Any]:
    cfg = default_config() if config is None else config
    return cfg.get("ground", cfg)


# --------------------------------------------------------------------------------------
# Ground segmentation (ground.rs, steps 1-5)
# --------------------------------------------------------------------------------------


def polar_bins(points: np.ndarray, ground: dict[str, Any], *, boundary_rule: str = "atan2") -> tuple[np.ndarray, np.ndarray]:
    """Step 1. Returns ``(flat_bin, r)``: per point the flat polar bin ``s·B + k`` (-1 for
    a point without a bin: ``r >= max_range_m`` or a non-finite coordinate) and its
    horizontal radius ``r`` [m] (float64).

    ``boundary_rule``: ``"atan2"`` is the documented ``floor((atan2(y, x) + π)·S/2π)``;
    ``"edges"`` then settles the sector as ground.rs's ``sector_of`` does (sign of the
    cross product with the boundary unit vectors at ``-π + s·2π/S``, for ``S >= 8``). They
    differ only for points within ~1e-15 rad of a sector boundary, e.g. exactly on the
    axes or diagonals of a grid."""
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3).astype(np.float64)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    r = np.sqrt(x * x + y * y)
    sectors = int(ground["sectors"])
    bins = math.ceil(ground["max_range_m"] / ground["bin_m"])
    with np.errstate(invalid="ignore"):
        valid = (r < ground["max_range_m"]) & np.isfinite(z)
        s = np.floor((np.arctan2(y, x) + math.pi) * (sectors / (2.0 * math.pi)))
        k = np.floor(r / ground["bin_m"])
    s = np.minimum(np.where(valid, s, 0), sectors - 1).astype(np.int64)
    if boundary_rule == "edges" and sectors >= 8:
        a = -math.pi + np.arange(sectors + 1) * (2.0 * math.pi) / sectors
        ex, ey = np.cos(a), np.sin(a)
        with np.errstate(invalid="ignore"):
            below = ex[s] * y - ey[s] * x < 0.0
            above = (ex[s + 1] * y - ey[s + 1] * x >= 0.0) & (s + 1 < sectors)
        s = np.where(below, np.maximum(s - 1, 0), np.where(above, s + 1, s))
    elif boundary_rule != "atan2" and boundary_rule != "edges":
        raise ValueError(f"boundary_rule must be 'atan2' or 'edges', got {boundary_rule!r}")
    k = np.minimum(np.where(valid, k, 0), bins - 1).astype(np.int64)
    return np.where(valid, s * bins + k, -1), r


def prototypes(flat_bin: np.ndarray, r: np.ndarray, z32: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 2. Each non-empty bin's lowest point (first in input order on a tie).
    Returns ``(bins, r, z)`` sorted by flat bin: the flat bin ids and the prototypes'
    radius [m] and z [m] (float64 of the float32 input)."""
    idx = np.flatnonzero(flat_bin >= 0)
    fb = flat_bin[idx]
    order = np.lexsort((idx, z32[idx], fb))  # by bin, then z, then input order
    fb_sorted = fb[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = fb_sorted[1:] != fb_sorted[:-1]
    chosen = idx[order[first]]
    return fb_sorted[first], r[chosen], z32[chosen].astype(np.float64)


@dataclass(frozen=True)
class GroundLine:
    """One accepted ground line of a sector: ``z = m·r + b`` over bins ``first_bin..=last_bin``."""

    m: float
    b: float
    first_bin: int
    last_bin: int
    first_r_m: float
    last_r_m: float


class _Sums:
    """Least-squares sums of a segment centred on its first point (``LineSums`` of
    ground.rs: the same operations in the same order, so the same rounding)."""

    __slots__ = ("n", "r0", "sr", "srr", "srz", "sz", "szz", "z0")

    def __init__(self, r: float, z: float) -> None:
        self.n, self.r0, self.z0 = 1.0, r, z
        self.sr = self.sz = self.srr = self.srz = self.szz = 0.0

    def with_point(self, r: float, z: float) -> _Sums:
        dr, dz = r - self.r0, z - self.z0
        out = _Sums.__new__(_Sums)
        out.n, out.r0, out.z0 = self.n + 1.0, self.r0, self.z0
        out.sr, out.sz = self.sr + dr, self.sz + dz
        out.srr, out.srz, out.szz = self.srr + dr * dr, self.srz + dr * dz, self.szz + dz * dz
        return out

    def fit(self) -> tuple[float, float, float] | None:
        """``(m, b, rmse)``; ``None`` when degenerate (all radii equal)."""
        n, sr, sz, srr, srz, szz = self.n, self.sr, self.sz, self.srr, self.srz, self.szz
        denom = n * srr - sr * sr
        if not denom > 0.0:
            return None
        m = (n * srz - sr * sz) / denom
        bc = (sz - m * sr) / n
        sse = szz - 2.0 * m * srz - 2.0 * bc * sz + m * m * srr + 2.0 * m * bc * sr + n * bc * bc
        b = bc + self.z0 - m * self.r0
        return m, b, math.sqrt(max(sse, 0.0) / n)


def fit_sector_lines(bins: np.ndarray, r: np.ndarray, z: np.ndarray, sensor_height_m: float, ground: dict[str, Any]) -> list[GroundLine]:
    """Step 3 for one sector: its prototypes (bin index within the sector, radius, z) in
    increasing bin order -> the accepted lines, in order of acceptance."""
    max_gap, max_slope = ground["max_gap_m"], ground["max_slope"]
    max_start, max_pred, max_rmse = ground["max_start_height_m"], ground["max_prediction_error_m"], ground["max_rmse_m"]
    min_points = int(ground["min_line_points"])
    lines: list[GroundLine] = []
    g = -float(sensor_height_m)
    seg: list[tuple[float, float, int]] = []
    sums: _Sums | None = None

    def close() -> None:
        nonlocal g
        if len(seg) < min_points or sums is None:
            return
        fit = sums.fit()
        if fit is None:
            return
        m, b, _ = fit
        lines.append(GroundLine(m, b, seg[0][2], seg[-1][2], seg[0][0], seg[-1][0]))
        g = m * seg[-1][0] + b

    for pr, pz, pk in zip(r.tolist(), z.tolist(), bins.tolist()):
        while True:
            if not seg:
                seg, sums = [(pr, pz, pk)], _Sums(pr, pz)
                break
            qr, qz, _ = seg[-1]
            if pr - qr > max_gap:
                close()
                seg, sums = [(pr, pz, pk)], _Sums(pr, pz)
                break
            if len(seg) == 1:
                if abs(qz - g) <= max_start and abs(pz - qz) <= max_slope * (pr - qr):
                    seg.append((pr, pz, pk))
                    sums = sums.with_point(pr, pz)
                else:
                    seg, sums = [(pr, pz, pk)], _Sums(pr, pz)
                break
            grown = sums.with_point(pr, pz)
            f0, f1 = sums.fit(), grown.fit()
            accept = (
                f0 is not None
                and f1 is not None
                and abs(pz - (f0[0] * pr + f0[1])) <= max_pred
                and abs(f1[0]) <= max_slope
                and f1[2] <= max_rmse
            )
            if accept:
                seg.append((pr, pz, pk))
                sums = grown
                break
            close()
            keep = seg[-1]
            seg, sums = [keep], _Sums(keep[0], keep[1])
            # handle p again (it now meets the |seg| = 1 rule)
    close()
    return lines


def _bin_lines(lines: list[GroundLine], bins: int, sensor_height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Step 4 for one sector: ``(m, b)`` per bin (float64 arrays of length ``bins``)."""
    if not lines:
        return np.zeros(bins), np.full(bins, -float(sensor_height_m))
    first = np.array([ln.first_bin for ln in lines])[:, None]
    last = np.array([ln.last_bin for ln in lines])[:, None]
    k = np.arange(bins)[None, :]
    contains = (k >= first) & (k <= last)
    dist = np.where(k < first, first - k, k - last)
    # The first containing line, else the nearest (argmin: the earlier on a tie).
    chosen = np.where(contains.any(axis=0), contains.argmax(axis=0), dist.argmin(axis=0))
    m = np.array([ln.m for ln in lines])[chosen]
    b = np.array([ln.b for ln in lines])[chosen]
    return m, b


@dataclass
class GroundSegmentation:
    """What :func:`ground_heights` found: per point its height above its bin's line
    (float32, NaN without a bin) and per sector the accepted lines."""

    heights: np.ndarray
    lines: list[list[GroundLine]]
    max_dist_to_line_m: float

    @property
    def labels(self) -> np.ndarray:
        """Step 5: ground iff ``|h| <= max_dist_to_line_m`` (compared in float32)."""
        with np.errstate(invalid="ignore"):
            return np.abs(self.heights) <= np.float32(self.max_dist_to_line_m)


def ground_heights(
    points: np.ndarray, *, sensor_height: float, config: dict[str, Any] | None = None, boundary_rule: str = "atan2"
) -> GroundSegmentation:
    """Steps 1-5 of ground.rs on ``points`` ``(N, 3)`` (sensor-centred, z up, float32);
    ``boundary_rule`` as in :func:`polar_bins`."""
    ground = _ground_cfg(config)
    p32 = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    sectors = int(ground["sectors"])
    bins = math.ceil(ground["max_range_m"] / ground["bin_m"])
    flat_bin, r = polar_bins(p32, ground, boundary_rule=boundary_rule)
    z32 = p32[:, 2]
    proto_bin, proto_r, proto_z = prototypes(flat_bin, r, z32)
    sector_of = proto_bin // bins
    bounds = np.searchsorted(sector_of, np.arange(sectors + 1))
    m_bin = np.zeros(sectors * bins)
    b_bin = np.full(sectors * bins, -float(sensor_height))
    all_lines: list[list[GroundLine]] = []
    for s in range(sectors):
        a, e = bounds[s], bounds[s + 1]
        lines = fit_sector_lines(proto_bin[a:e] - s * bins, proto_r[a:e], proto_z[a:e], sensor_height, ground) if e > a else []
        all_lines.append(lines)
        if lines:
            m_bin[s * bins:(s + 1) * bins], b_bin[s * bins:(s + 1) * bins] = _bin_lines(lines, bins, sensor_height)
    has = flat_bin >= 0
    fb = np.where(has, flat_bin, 0)
    with np.errstate(invalid="ignore"):
        h = (z32.astype(np.float64) - (m_bin[fb] * r + b_bin[fb])).astype(np.float32)
    h[~has] = np.nan
    return GroundSegmentation(h, all_lines, float(ground["max_dist_to_line_m"]))


def segment_ground(
    points: np.ndarray, *, sensor_height: float, config: dict[str, Any] | None = None, boundary_rule: str = "atan2"
) -> np.ndarray:
    """Ground labels (``True``: ground) as ``subterra.segment_ground`` gives them."""
    return ground_heights(points, sensor_height=sensor_height, config=config, boundary_rule=boundary_rule).labels


# --------------------------------------------------------------------------------------
# Coarse map geometry layers from one scan (risk.rs, mapper.rs)
# --------------------------------------------------------------------------------------


def _prefilter(points: np.ndarray, sensor_height: float, cfg: dict[str, Any], robot: dict[str, float]) -> np.ndarray:
    """cloud.rs for ``body_from_sensor`` = translation ``(0, 0, sensor_height)``: drops
    non-finite points, points outside the range limits and points in the robot's own box;
    returns the kept points in the body frame (float32, input order)."""
    pre = cfg["prefilter"]
    if pre["voxel_m"] > 0 or pre["outlier_min_neighbors"] > 0:
        raise NotImplementedError("the reference has no voxel downsampling or outlier removal; switch them off")
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    r_sq = p[:, 0] * p[:, 0] + p[:, 1] * p[:, 1] + p[:, 2] * p[:, 2]
    keep = (r_sq >= np.float32(pre["min_range_m"] ** 2)) & (r_sq <= np.float32(pre["max_range_m"] ** 2))
    b = p[keep] + np.array([0.0, 0.0, sensor_height], dtype=np.float32)
    mg = pre["self_margin_m"]
    lo = np.array([-robot["length_m"] / 2 - mg, -robot["width_m"] / 2 - mg, -mg]).astype(np.float32)
    hi = np.array([robot["length_m"] / 2 + mg, robot["width_m"] / 2 + mg, robot["height_m"] + mg]).astype(np.float32)
    inside = (b >= lo).all(axis=1) & (b <= hi).all(axis=1)
    return b[~inside]


def _ramp(x: np.ndarray, ramp: dict[str, float]) -> np.ndarray:
    """``clamp((x - safe)/(lethal - safe), 0, 1)``; NaN gives 0."""
    with np.errstate(invalid="ignore"):
        v = (np.asarray(x, dtype=np.float64) - ramp["safe"]) / (ramp["lethal"] - ramp["safe"])
    return np.where(v > 0.0, np.minimum(v, 1.0), 0.0)


def coarse_layers(
    points: np.ndarray,
    *,
    sensor_height: float,
    config: dict[str, Any] | None = None,
    robot: dict[str, float] | None = None,
) -> dict[str, np.ndarray]:
    """The coarse map of ``TerrainMapper.update(points, world_from_body=identity,
    body_from_sensor=translation(z=sensor_height))`` on a fresh mapper, for the layers
    ``count``, ``ground_count``, ``min_height``, ``max_height``, ``ground_height`` (NaN
    where the cell has no ground point: the polar fill is not reproduced) and
    ``collision``; float32 ``(ny, nx)`` arrays, row ``iy`` along world y."""
    cfg = default_config() if config is None else config
    robot = HUSKY if robot is None else robot
    coarse, thr = cfg["coarse"], cfg["ground"]["max_dist_to_line_m"]
    res = coarse["resolution_m"]
    nx, ny = (max(1, math.floor(coarse[k] / res + 0.5)) for k in ("size_x_m", "size_y_m"))  # Rust f64::round
    h32 = np.float32(sensor_height)
    body = _prefilter(points, sensor_height, cfg, robot)
    level = body - np.array([0.0, 0.0, h32], dtype=np.float32)  # sensor-centred, world axes
    heights = ground_heights(level, sensor_height=sensor_height, config=cfg).heights
    z = level[:, 2] + h32  # height above the body origin
    # Cells of the map centred on the body at the world origin: ix = floor(x / res) + nx/2.
    ix = np.floor(level[:, 0].astype(np.float64) / res).astype(np.int64) + nx // 2
    iy = np.floor(level[:, 1].astype(np.float64) / res).astype(np.int64) + ny // 2
    inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    cell = (iy * nx + ix)[inside]
    z, h = z[inside], heights[inside]
    n = nx * ny
    with np.errstate(invalid="ignore"):
        ground = np.abs(h) <= np.float32(thr)
        lo = np.float32(robot["ground_clearance_m"])
        hi = np.float32(robot["height_m"] + cfg["layers"]["head_margin_m"])
        collision = ~ground & (h > lo) & (h <= hi)
    count = np.bincount(cell, minlength=n)
    ground_n = np.bincount(cell[ground], minlength=n)
    collision_n = np.bincount(cell[collision], minlength=n)
    ground_sum = np.zeros(n, dtype=np.float32)
    np.add.at(ground_sum, cell[ground], z[ground])  # float32, in input order
    min_z = np.full(n, np.inf, dtype=np.float32)
    max_z = np.full(n, -np.inf, dtype=np.float32)
    np.minimum.at(min_z, cell, z)
    np.maximum.at(max_z, cell, z)
    has = count > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        ground_height = np.where(ground_n > 0, ground_sum / ground_n.astype(np.float32), np.float32(np.nan))
    layers = {
        "count": count.astype(np.float32),
        "ground_count": ground_n.astype(np.float32),
        "ground_height": ground_height.astype(np.float32),
        "min_height": np.where(has, min_z, np.float32(np.nan)),
        "max_height": np.where(has, max_z, np.float32(np.nan)),
        "collision": _ramp(collision_n, cfg["risk"]["collision_points"]).astype(np.float32),
    }
    return {k: v.reshape(ny, nx) for k, v in layers.items()}
