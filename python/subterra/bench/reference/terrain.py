"""The terrain risk map of one scan in plain NumPy: the reference for parity tests and
benchmarks.

This module re-implements, from their documentation, the terrain-risk pipeline as the Rust core
(``crates/subterra/src/terrain``) defines it, for the **coarse map made from one scan**:

1. :func:`segment_ground` / :func:`ground_heights`: the ground segmentation by line fits
   in cylindrical coordinates (Himmelsbach et al. 2010) exactly as the module doc of
   ``ground.rs`` ("The algorithm, exactly") writes it out: polar bins, lowest-point
   prototypes, per-sector line growing with the slope / prediction / RMSE / gap /
   start-height rules, each bin's line, and the label ``|h| <= max_dist_to_line_m``;
   and the byproducts per polar bin (coverage, lowest point, steepest ray:
   :class:`PolarTable`).
2. :func:`coarse_map`: all 21 layers of the coarse map of ``TerrainMapper.update`` on a
   fresh mapper, as the module doc of ``risk.rs`` ("The layers, exactly") defines them,
   with any rigid ``world_from_body`` and ``body_from_sensor`` and mission items, in
   stages that the tests can also feed with Rust's own layers: :func:`level_scan`
   (prefilter, levelling), :func:`bin_cells` (counts, heights, collision points),
   :func:`polar_fill` (ground line fill, ``observed``, ``negative_depth``),
   :func:`plane_fit` (``slope``, ``plane_residual``), :func:`step_heights`,
   :func:`settled_tilt` (settling over headings), :func:`mission_layer`,
   :func:`risk_layers` (the ramps, ``unknown``, ``risk``, ``risk_variance``) and
   :func:`cvar` (``RiskMap.cvar``). :func:`coarse_layers` is the binning stage alone
   (the six layers of the earlier reference).

How close it comes (``tests/python/test_terrain_reference.py`` checks each):

* **Bit-identical**: the labels, ``count``, ``ground_count``, ``ground_height`` (filled
  cells included), ``min_height``, ``max_height``, ``observed``, ``age``,
  ``step_height``, ``negative_depth``, ``collision``, ``step``, ``negative``,
  ``unknown``, ``mission``, ``risk_variance``; ``tilt_angle`` wherever a heading settles
  the footprint; and every risk layer given the same geometric layers.
* **Within a few float32 ulps**: ``slope`` and ``plane_residual`` (float64 in both, but
  Rust sums each window through summed-area tables of absolute cell positions, with
  ~1e-9 cancellation, where this module sums the window directly around the cell: some
  cells differ by <= 5e-8 after rounding to float32), hence ``tilt_angle`` where the slope
  stands in and ``tilt``, ``roughness`` and ``risk`` there (tests: 1e-6 rad or m, 1e-5
  for the ramps); :func:`cvar` within 1e-6 (Rust's Φ⁻¹ is Acklam's approximation,
  relative error 1.2e-9; this module uses :class:`statistics.NormalDist`).
* Where a cell's plane window holds ``plane_min_cells`` ground cells or more that all lie
  in one row or column, there is no plane: NaN here (exact integer test) and in Rust (a
  scale-free eigenvalue-ratio test since the fix of a degeneracy bug that passed on
  rounding noise). :attr:`CoarseMap.collinear` marks those cells.

Not reproduced (documented here so that nobody believes otherwise):

* Temporal fusion: one scan only (so ``age`` is 0 wherever the cell has points), and the
  fine map.
* The optional prefilter stages (voxel downsampling and sparse-outlier removal must be
  off, as they are by default).
* A sensor more than ``max_speed_m_s·window_s + 1 m`` from the body horizontally (Rust
  bins a scan into a scratch grid of that margin around the sensor).

Numerics, chosen to agree with the Rust code bit for bit where the docs leave room:

* Every segmentation computation is in float64 from the float32 input coordinates; the
  least-squares line is the one of ``ground.rs``'s running sums centred on the segment's
  first point (``LineSums``), so a threshold comparison sees the same rounding. The
  height above the line is rounded to float32 before the label test against
  ``float32(max_dist_to_line_m)``.
* The point's sector uses NumPy's ``arctan2`` for the documented ``atan2``. Rust uses a
  fast ``atan2`` corrected by cross products with the sector boundaries; the two differ
  only within ~1e-15 rad of a sector boundary — which points exactly on a grid's axes or
  diagonals are (then a whole run of prototypes moves sector and labels change).
  ``boundary_rule="edges"`` reproduces Rust's tie-break there as well.
* The polar fill asks for the sector of each *cell centre* with ground.rs's uncorrected
  ``fast_atan2`` (documented on ``GroundSegmenter::query``: error < 2e-5 rad, so a centre
  that close to a sector boundary may get the neighbouring sector; with the sensor over a
  cell corner, every centre on the diagonals through it lies on a boundary).
  :func:`fast_atan2` is that polynomial, the
  default; ``query_atan="exact"`` uses ``arctan2`` and then differs from Rust exactly in
  such cells. The query's radial bin is ``floor(r·(1/bin_m))`` (the points':
  ``floor(r/bin_m)``).
* Poses: the prefilter and levelling rotate in float32 as glam's ``Mat3 * Vec3``
  (``(R₀·x + R₁·y) + R₂·z``); the sensor offset ``R_wb·t_bs`` is float64. Point heights
  are float32 (``z_level + float32(sensor_z)``), ground heights float32 sums in input
  order, as the Rust accumulators; a filled height is ``float32(line_z + sensor_z)``.
* Ramps, the product ``1 - Π(1 - r_k)`` and σ are float64 from the float32 layers, then
  rounded to float32, as in ``risk.rs``.

The configuration is the nested ``dict`` of ``configs/terrain.toml``
(``subterra.TerrainConfig().to_dict()``), the robot the dict of
``subterra.RobotConfig().to_dict()``. The module imports only NumPy and the standard
library.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from statistics import NormalDist
from typing import Any

import numpy as np

from subterra._compat import tomllib

__all__ = [
    "DEFAULT_CONFIG_PATH",
    "FAST_ATAN2_COEFFICIENTS",
    "HUSKY",
    "LAYER_NAMES",
    "CellSums",
    "CoarseMap",
    "Geometry",
    "GroundLine",
    "GroundSegmentation",
    "LevelScan",
    "PolarQuery",
    "PolarTable",
    "bin_cells",
    "coarse_layers",
    "coarse_map",
    "cvar",
    "cvar_factor",
    "default_config",
    "fast_atan2",
    "fit_sector_lines",
    "footprint_corners",
    "ground_heights",
    "level_scan",
    "mission_layer",
    "plane_fit",
    "polar_bins",
    "polar_fill",
    "polar_query",
    "prototypes",
    "risk_layers",
    "segment_ground",
    "settled_tilt",
    "step_heights",
]

#: The committed default terrain config (equal to ``TerrainConfig()``).
DEFAULT_CONFIG_PATH = Path(__file__).resolve().parents[4] / "configs" / "terrain.toml"

#: The Husky-like robot of ``RobotConfig::default()`` (STEP, Fan et al. 2021) [m, m/s, deg].
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
    unseen_min = float(ground.get("unseen_rise_min_length_m", 0.0))
    lines: list[GroundLine] = []
    g_r, g_z = 0.0, -float(sensor_height_m)  # the ground estimate: height g_z seen at radius g_r
    seg: list[tuple[float, float, int]] = []
    sums: _Sums | None = None
    seen: list[float] = []  # the heights of the sector's prototypes, in visiting order
    seg_start = 0  # seg is seen[seg_start : seg_start + len(seg)]
    after_line = False  # the sector has an accepted line (else the estimate is the ground under the robot)

    def rises_unseen(first_r: float, first_z: float) -> bool:
        # The sector's first line only: a ramp no steeper than max_slope could climb the rise
        # over the blind ring, and nothing seen there lies more than T_b below the first prototype.
        rise = first_z - g_z
        return (unseen_min > 0.0 and not after_line and max_start < rise <= max_start + max_slope * max(first_r - g_r, 0.0)
                and all(z >= first_z - max_start for z in seen[:seg_start]))

    def on_ground(first_r: float, first_z: float, m: float, b: float) -> bool:
        # The first prototype within T_b of the estimate, or the line within T_b of it
        # somewhere between the estimate's radius and the first prototype's.
        if abs(first_z - g_z) <= max_start:
            return True
        lo, hi = min(g_r, first_r), max(g_r, first_r)
        d_lo, d_hi = m * lo + b - g_z, m * hi + b - g_z
        return (d_lo <= 0.0) != (d_hi < 0.0) or min(abs(d_lo), abs(d_hi)) <= max_start

    def close() -> None:
        nonlocal g_r, g_z, after_line
        if len(seg) < min_points or sums is None:
            return
        fit = sums.fit()
        if fit is None:
            return
        m, b, _ = fit
        unseen = rises_unseen(seg[0][0], seg[0][1]) and seg[-1][0] - seg[0][0] >= unseen_min and abs(m) * unseen_min <= max_start
        if not on_ground(seg[0][0], seg[0][1], m, b) and not unseen:
            return
        lines.append(GroundLine(m, b, seg[0][2], seg[-1][2], seg[0][0], seg[-1][0]))
        g_r, g_z = seg[-1][0], m * seg[-1][0] + b
        after_line = True

    for pr, pz, pk in zip(r.tolist(), z.tolist(), bins.tolist()):
        here = len(seen)
        seen.append(pz)
        while True:
            if not seg:
                seg, sums, seg_start = [(pr, pz, pk)], _Sums(pr, pz), here
                break
            qr, qz, _ = seg[-1]
            if pr - qr > max_gap:
                close()
                seg, sums, seg_start = [(pr, pz, pk)], _Sums(pr, pz), here
                break
            if len(seg) == 1:
                if abs(qz - g_z) <= max_start + max_slope * max(qr - g_r, 0.0) and abs(pz - qz) <= max_slope * (pr - qr):
                    seg.append((pr, pz, pk))
                    sums = sums.with_point(pr, pz)
                else:
                    seg, sums, seg_start = [(pr, pz, pk)], _Sums(pr, pz), here
                break
            grown = sums.with_point(pr, pz)
            f0, f1 = sums.fit(), grown.fit()
            accept = (
                f0 is not None
                and f1 is not None
                and abs(pz - (f0[0] * pr + f0[1])) <= max_pred
                and abs(f1[0]) <= max_slope
                and f1[2] <= max_rmse
                and (on_ground(seg[0][0], seg[0][1], f1[0], f1[1]) or rises_unseen(seg[0][0], seg[0][1]))
            )
            if accept:
                seg.append((pr, pz, pk))
                sums = grown
                break
            close()
            keep = seg[-1]
            seg_start += len(seg) - 1
            seg, sums = [keep], _Sums(keep[0], keep[1])
            # handle p again (it now meets the |seg| = 1 rule)
    close()
    return lines


def _bin_lines(lines: list[GroundLine], bins: int, sensor_height_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Step 4 for one sector: ``(m, b, cover_lo, cover_hi, cap_r)`` per bin (float64 arrays of
    length ``bins``): the bin's line (before the first line, the straight line from ``(0, -H)``
    to the first line at its first prototype's radius) and, where a line's bin interval contains the bin
    (*covered*), the radii of that line's first and last prototype (else ``+inf, -inf``:
    no radius is covered); ``cap_r``: the last prototype's radius of a rising line (beyond it
    the expected ground stays at its height there), ``+inf`` otherwise."""
    none_lo, none_hi = np.full(bins, np.inf), np.full(bins, -np.inf)
    if not lines:
        return np.zeros(bins), np.full(bins, -float(sensor_height_m)), none_lo, none_hi, np.full(bins, np.inf)
    first = np.array([ln.first_bin for ln in lines])[:, None]
    last = np.array([ln.last_bin for ln in lines])[:, None]
    k = np.arange(bins)[None, :]
    contains = (k >= first) & (k <= last)
    dist = np.where(k < first, first - k, k - last)
    # The first containing line, else the nearest (argmin: the earlier on a tie).
    covered = contains.any(axis=0)
    chosen = np.where(covered, contains.argmax(axis=0), dist.argmin(axis=0))
    m = np.array([ln.m for ln in lines])[chosen]
    b = np.array([ln.b for ln in lines])[chosen]
    lo = np.where(covered, np.array([ln.first_r_m for ln in lines])[chosen], none_lo)
    hi = np.where(covered, np.array([ln.last_r_m for ln in lines])[chosen], none_hi)
    cap = np.where(m > 0.0, np.array([ln.last_r_m for ln in lines])[chosen], np.inf)
    # Before the first line: from the ground under the sensor to the line's first prototype.
    first = lines[0]
    if first.first_r_m > 0.0:
        h = float(sensor_height_m)
        before = np.arange(bins) < min(first.first_bin, bins)
        m = np.where(before, (first.m * first.first_r_m + first.b + h) / first.first_r_m, m)
        b = np.where(before, -h, b)
        cap = np.where(before, np.inf, cap)
    return m, b, lo, hi, cap


def expected_ground(m: np.ndarray, b: np.ndarray, cap_r: np.ndarray, r: np.ndarray) -> np.ndarray:
    """ground.rs ``BinLine::expected``: ``m·min(r, cap_r) + b`` (the line, no higher beyond a
    rising line's last prototype)."""
    return m * np.where(r > cap_r, cap_r, r) + b


@dataclass
class PolarTable:
    """Per polar bin (flat index ``s·B + k``, ``S·B`` entries) what the segmentation knows,
    for the map's queries (ground.rs, "Byproducts per bin"): the bin's line ``z = m·r + b``
    [sensor-centred m], the radii ``[cover_lo, cover_hi]`` it covers (empty when the bin is
    not covered), the prototype's ``z`` (float32, ``+inf`` in an empty bin) and the
    steepest downward ray slope ``min(z/r)`` over the prototypes of the sector's farther
    bins (float32, ``+inf`` without one)."""

    sectors: int
    bins: int
    bin_m: float
    max_range_m: float
    m: np.ndarray
    b: np.ndarray
    cover_lo: np.ndarray
    cover_hi: np.ndarray
    proto_z: np.ndarray
    ray_slope: np.ndarray
    #: Per polar bin: void (ground.rs ``mark_voids``, :func:`_void_bins`); ``None``: none.
    void: np.ndarray | None = None
    #: Per polar bin: where a rising line's expected ground stops rising (:func:`_bin_lines`).
    cap_r: np.ndarray | None = None
    #: Per polar bin: the farthest return that came back (float32, ``-inf``: none) and the
    #: shadow depth beyond it (float32; ground.rs ``mark_shadows``, :func:`_shadow_depths`).
    solid_r: np.ndarray | None = None
    shadow_depth: np.ndarray | None = None


@dataclass
class GroundSegmentation:
    """What :func:`ground_heights` found: per point its height above its bin's line
    (float32, NaN without a bin), per sector the accepted lines and per polar bin the
    byproducts the map uses (:class:`PolarTable`)."""

    heights: np.ndarray
    lines: list[list[GroundLine]]
    max_dist_to_line_m: float
    polar: PolarTable | None = None

    @property
    def labels(self) -> np.ndarray:
        """Step 5: ground iff ``|h| <= max_dist_to_line_m`` (compared in float32)."""
        with np.errstate(invalid="ignore"):
            return np.abs(self.heights) <= np.float32(self.max_dist_to_line_m)


def _ray_slopes(proto_bin: np.ndarray, proto_r: np.ndarray, proto_z: np.ndarray, sectors: int, bins: int) -> np.ndarray:
    """Per polar bin, ``min(z/r)`` (float32, as ``(z as f64 / r) as f32``) over the
    prototypes of the *farther* bins of its sector; ``+inf`` without one."""
    own = np.full(sectors * bins, np.inf, dtype=np.float32)
    ok = np.isfinite(proto_z) & (proto_r > 0.0)
    own[proto_bin[ok]] = (proto_z[ok] / proto_r[ok]).astype(np.float32)
    own = own.reshape(sectors, bins)
    # Suffix minimum along the bins, shifted by one: strictly farther bins only.
    suffix = np.minimum.accumulate(own[:, ::-1], axis=1)[:, ::-1]
    ray = np.full_like(own, np.inf)
    ray[:, :-1] = suffix[:, 1:]
    return ray.reshape(-1)


def _void_bins(flat_bin: np.ndarray, r: np.ndarray, z32: np.ndarray, h: np.ndarray, m_bin: np.ndarray, b_bin: np.ndarray,
               cap_bin: np.ndarray, sectors: int, bins: int, bin_m: float, min_gap_deg: float, max_dist_to_line_m: float) -> np.ndarray:
    """ground.rs ``mark_voids``: per polar bin whether it is void. Each non-empty bin's ray
    span is ``(shallowest, steepest)`` depression ``atan(-slope)`` of its points' ``z/r``
    (float32, points with ``r > 0`` not more than ``max_dist_to_line_m`` below their line:
    ``h >= -max_dist_to_line_m`` in float32; deeper returns came through the floor); a run of empty bins between non-empty ``a`` and ``k``
    is void when, of the depressions between ``hi = min(shallowest of a, expected ground at
    (a+1)·Δ)`` and ``lo = max(steepest of the farther spans not steeper than a's shallowest,
    expected ground at k·Δ)``, more than ``min_gap`` is left uncovered by every bin's span
    (the expected ground's depression at ``r``: ``atan(-z/r)`` with ``z`` the bin's expected
    ground, :func:`expected_ground`).
    ``min_gap_deg`` 0: off, no bin is void."""
    void = np.zeros(sectors * bins, dtype=bool)
    if min_gap_deg == 0.0:  # void detection off
        return void
    with np.errstate(invalid="ignore"):
        ok = (flat_bin >= 0) & (r > 0.0) & (h >= -np.float32(max_dist_to_line_m))
    slope = (z32[ok].astype(np.float64) / r[ok]).astype(np.float32)
    top = np.full(sectors * bins, -np.inf, dtype=np.float32)
    low = np.full(sectors * bins, np.inf, dtype=np.float32)
    np.maximum.at(top, flat_bin[ok], slope)
    np.minimum.at(low, flat_bin[ok], slope)
    min_gap = math.radians(min_gap_deg)
    full = np.isfinite(top)
    for s in range(sectors):
        row = slice(s * bins, (s + 1) * bins)
        ks = np.nonzero(full[row])[0]
        if ks.size < 2:
            continue
        sh = np.arctan(-top[row].astype(np.float64))
        st = np.arctan(-low[row].astype(np.float64))
        m, b, cap = m_bin[row], b_bin[row], cap_bin[row]
        ground = lambda k, rr: math.atan(-((m[k] * (cap[k] if rr > cap[k] else rr) + b[k]) / rr))
        for j in range(1, ks.size):
            a, k = int(ks[j - 1]), int(ks[j])
            if k <= a + 1:
                continue
            t = sh[a]
            hi = min(t, ground(a + 1, (a + 1) * bin_m))
            far = np.concatenate([sh[ks[j:]], st[ks[j:]]])
            far = far[far <= t]
            if far.size == 0:
                continue
            lo = max(float(far.max()), ground(k - 1, k * bin_m))
            if hi - lo <= min_gap:
                continue
            spans = sorted((float(x), float(y)) for x, y in zip(sh[ks], st[ks]) if y > lo and x < hi)
            start, empty = lo, 0.0
            for x, y in spans:
                empty = max(empty, x - start)
                start = max(start, y)
            empty = max(empty, hi - start)
            if empty > min_gap:
                void[s * bins + a + 1:s * bins + k] = True
    return void


def _shadow_depths(flat_bin: np.ndarray, r: np.ndarray, h: np.ndarray, proto_r: np.ndarray, proto_z: np.ndarray,
                   ray_slope: np.ndarray, m_bin: np.ndarray, b_bin: np.ndarray, cap_bin: np.ndarray, sectors: int, bins: int,
                   bin_m: float, thr: float, enabled: bool, min_grazing_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """ground.rs ``mark_shadows``: per polar bin ``(solid_r, shadow_depth)`` (float32).
    ``solid_r``: the largest ``r`` (as float32) of the bin's points with ``r > 0`` and ``h >=
    -thr`` (float32), ``-inf`` without one. A bin's run start is the nearest bin at or before
    it with a ``solid_r``, if that one's ``-E(solid_r) >= tan(min_grazing_deg)·solid_r``,
    else none (``E``: :func:`expected_ground` with that bin's line). A bin's own depth (float32
    of the float64 value), with ``E`` the start's line: ``E(r_f) - ray_slope·r_f`` at its far
    edge ``r_f = (k + 1)·Δ``, or the larger of that and ``E(proto_r) - proto_z`` where the
    latter exceeds ``thr``; ``shadow_depth`` is the largest own depth from the bin to the next
    bin with a ``solid_r`` (exclusive), at least 0, and 0 without a start; all 0 when
    ``enabled`` is false. ``proto_r``, ``proto_z``: per polar bin (0 and ``+inf`` when empty)."""
    with np.errstate(invalid="ignore"):
        ok = (flat_bin >= 0) & (r > 0.0) & (h >= -np.float32(thr))
    solid_r = np.full(sectors * bins, -np.inf, dtype=np.float32)
    np.maximum.at(solid_r, flat_bin[ok], r[ok].astype(np.float32))
    shadow = np.zeros(sectors * bins, dtype=np.float32)
    if not enabled:
        return solid_r, shadow
    m2, b2, cap2 = m_bin.reshape(sectors, bins), b_bin.reshape(sectors, bins), cap_bin.reshape(sectors, bins)
    solid = (solid_r > -np.inf).reshape(sectors, bins)
    rs = np.where(solid, solid_r.reshape(sectors, bins).astype(np.float64), 0.0)
    steep_here = -expected_ground(m2, b2, cap2, rs) >= math.tan(math.radians(min_grazing_deg)) * rs
    # The run start of each bin (-1: none), from the sensor out.
    start = np.full((sectors, bins), -1, dtype=np.int64)
    cur = np.full(sectors, -1, dtype=np.int64)
    for j in range(bins):
        cur = np.where(solid[:, j], np.where(steep_here[:, j], j, -1), cur)
        start[:, j] = cur
    rows = np.arange(sectors)[:, None]
    st = np.where(start >= 0, start, 0)
    sm, sb_, sc = m2[rows, st], b2[rows, st], cap2[rows, st]
    k = np.arange(bins)[None, :]
    r_far = (k + 1).astype(np.float64) * bin_m
    with np.errstate(invalid="ignore", over="ignore"):
        under_ray = expected_ground(sm, sb_, sc, r_far) - ray_slope.reshape(sectors, bins).astype(np.float64) * r_far
        below = expected_ground(sm, sb_, sc, proto_r.reshape(sectors, bins)) - proto_z.reshape(sectors, bins).astype(np.float64)
    own = np.where(below > thr, np.maximum(under_ray, below), under_ray).astype(np.float32)
    own = np.where(start >= 0, own, np.float32(-np.inf))
    out = shadow.reshape(sectors, bins)
    run = np.zeros(sectors, dtype=np.float32)
    for j in range(bins - 1, -1, -1):
        deepest = np.where(own[:, j] > run, own[:, j], run)
        out[:, j] = np.maximum(deepest, np.float32(0.0))
        run = np.where(solid[:, j], np.float32(0.0), np.maximum(deepest, np.float32(0.0)))
    return solid_r, out.reshape(-1)


def void_samples(polar: PolarTable) -> np.ndarray:
    """ground.rs ``void_samples``: ``(n, 2)`` float32 sensor-centred positions on the
    centre ray of every void bin, at a quarter and three quarters of the bin."""
    if polar.void is None:
        return np.zeros((0, 2), dtype=np.float32)
    sb = np.nonzero(polar.void)[0]
    s, k = sb // polar.bins, sb % polar.bins
    a = -math.pi + (s + 0.5) * (2.0 * math.pi) / polar.sectors
    out = []
    for f in (0.25, 0.75):
        rr = (k + f) * polar.bin_m
        out.append(np.stack([rr * np.cos(a), rr * np.sin(a)], axis=1))
    # Rust pushes (0.25, 0.75) per bin, bin after bin: the order does not change any count.
    return np.concatenate(out).astype(np.float32) if out else np.zeros((0, 2), dtype=np.float32)


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
    lo_bin = np.full(sectors * bins, np.inf)
    hi_bin = np.full(sectors * bins, -np.inf)
    cap_bin = np.full(sectors * bins, np.inf)
    all_lines: list[list[GroundLine]] = []
    for s in range(sectors):
        a, e = bounds[s], bounds[s + 1]
        lines = fit_sector_lines(proto_bin[a:e] - s * bins, proto_r[a:e], proto_z[a:e], sensor_height, ground) if e > a else []
        all_lines.append(lines)
        if lines:
            row = slice(s * bins, (s + 1) * bins)
            m_bin[row], b_bin[row], lo_bin[row], hi_bin[row], cap_bin[row] = _bin_lines(lines, bins, sensor_height)
    has = flat_bin >= 0
    fb = np.where(has, flat_bin, 0)
    with np.errstate(invalid="ignore"):
        h = (z32.astype(np.float64) - (m_bin[fb] * r + b_bin[fb])).astype(np.float32)
    h[~has] = np.nan
    pz = np.full(sectors * bins, np.inf, dtype=np.float32)
    pz[proto_bin] = proto_z.astype(np.float32)
    pr = np.zeros(sectors * bins)
    pr[proto_bin] = proto_r
    ray = _ray_slopes(proto_bin, proto_r, proto_z, sectors, bins)
    solid_r, shadow = _shadow_depths(flat_bin, r, h, pr, pz, ray, m_bin, b_bin, cap_bin, sectors, bins, float(ground["bin_m"]),
                                     float(ground["max_dist_to_line_m"]), bool(ground.get("drop_shadows", True)),
                                     float(ground.get("drop_shadow_min_grazing_deg", 10.0)))
    polar = PolarTable(
        sectors, bins, float(ground["bin_m"]), float(ground["max_range_m"]), m_bin, b_bin, lo_bin, hi_bin, pz, ray,
        _void_bins(flat_bin, r, z32, h, m_bin, b_bin, cap_bin, sectors, bins, float(ground["bin_m"]), float(ground.get("void_min_gap_deg", 0.0)),
                   float(ground["max_dist_to_line_m"])),
        cap_bin, solid_r, shadow,
    )
    return GroundSegmentation(h, all_lines, float(ground["max_dist_to_line_m"]), polar)


def segment_ground(
    points: np.ndarray, *, sensor_height: float, config: dict[str, Any] | None = None, boundary_rule: str = "atan2"
) -> np.ndarray:
    """Ground labels (``True``: ground) as ``subterra.segment_ground`` gives them."""
    return ground_heights(points, sensor_height=sensor_height, config=config, boundary_rule=boundary_rule).labels


# --------------------------------------------------------------------------------------
# The coarse map of one scan (mapper.rs, risk.rs, grid.rs)
# --------------------------------------------------------------------------------------

#: The 21 layers of a ``RiskMap``, in storage order (``RiskMap.layer_names``).
LAYER_NAMES: tuple[str, ...] = (
    "count", "ground_count", "ground_height", "min_height", "max_height", "slope", "plane_residual",
    "step_height", "negative_depth", "tilt_angle", "observed", "age", "collision", "step", "negative",
    "tilt", "roughness", "unknown", "mission", "risk", "risk_variance",
)

#: ground.rs's ``fast_atan2``: a minimax polynomial for atan on [0, 1] (Abramowitz &
#: Stegun 4.4.49), error <= 1e-5 rad (< 2e-5 with rounding).
FAST_ATAN2_COEFFICIENTS = (0.999_866_0, -0.330_299_5, 0.180_141_0, -0.085_133_0, 0.020_835_1)


def _round(v: float) -> float:
    """Rust's ``f64::round``: to the nearest integer, halves away from zero."""
    a = abs(v)
    f = math.floor(a)
    if a - f >= 0.5:
        f += 1.0
    return math.copysign(f, v)


def _odd_half(size_m: float, res: float) -> int:
    """Half-width [cells] of the odd window nearest ``size_m``: ``max(1, round(size/res)) // 2``."""
    return max(1, int(_round(size_m / res))) // 2


@dataclass(frozen=True)
class Geometry:
    """A map's cells (grid.rs ``GridGeometry``): cell ``(ix, iy)`` covers world
    ``[(gx0 + ix)·res, (gx0 + ix + 1)·res) x [(gy0 + iy)·res, ...)``, ``(gx0, gy0) = origin_cell``."""

    resolution_m: float
    nx: int
    ny: int
    origin_cell: tuple[int, int]

    @staticmethod
    def centred_on(map_cfg: dict[str, float], x_m: float, y_m: float) -> Geometry:
        """The map of ``map_cfg`` (``resolution_m``, ``size_x_m``, ``size_y_m``) centred on
        the world position ``(x_m, y_m)``: lower corner ``floor(x/res) - nx/2``."""
        res = float(map_cfg["resolution_m"])
        nx, ny = (max(1, int(_round(map_cfg[k] / res))) for k in ("size_x_m", "size_y_m"))
        return Geometry(res, nx, ny, (math.floor(x_m / res) - nx // 2, math.floor(y_m / res) - ny // 2))

    @property
    def shape(self) -> tuple[int, int]:
        return self.ny, self.nx

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """World x of each column's centre and world y of each row's centre [m], as
        ``origin + (i + 0.5)·res``."""
        res = self.resolution_m
        ox, oy = self.origin_cell[0] * res, self.origin_cell[1] * res
        return ox + (np.arange(self.nx) + 0.5) * res, oy + (np.arange(self.ny) + 0.5) * res


def _pose(matrix: np.ndarray | None, argument: str) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` of a 4x4 rigid transform (float64); identity for ``None``."""
    if matrix is None:
        return np.eye(3), np.zeros(3)
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise ValueError(f"argument `{argument}` must have shape (4, 4), got {m.shape}")
    return m[:3, :3].copy(), m[:3, 3].copy()


def _rotate(rotation: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``R·v`` for each row of ``v``, summed as ``(R[:,0]·x + R[:,1]·y) + R[:,2]·z`` in the
    dtype of ``rotation`` (glam's ``Mat3 * Vec3``: the same float32 rounding)."""
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    return np.column_stack([(rotation[i, 0] * x + rotation[i, 1] * y) + rotation[i, 2] * z for i in range(3)])


@dataclass
class LevelScan:
    """A prefiltered scan as the mapper keeps it (mapper.rs): ``points`` relative to the
    sensor in world-aligned axes (float32; the segmentation's frame), the sensor relative
    to the body origin in world axes (``sensor_level``, float64) and the body's world
    position (``body_world``, float64) [m]."""

    points: np.ndarray
    sensor_level: np.ndarray
    body_world: np.ndarray


def level_scan(
    points: np.ndarray,
    *,
    body_from_sensor: np.ndarray | None = None,
    world_from_body: np.ndarray | None = None,
    config: dict[str, Any] | None = None,
    robot: dict[str, float] | None = None,
) -> LevelScan:
    """cloud.rs's prefilter and mapper.rs's levelling: drops non-finite points, points
    outside ``prefilter.min_range_m..max_range_m`` of the sensor and points in the robot's
    box grown by ``prefilter.self_margin_m`` (body frame, ``p_body = R_bs·p + t_bs`` in
    float32); then ``p_level = R_wb·p_body - R_wb·t_bs`` (float32 rotation, float64
    sensor offset rounded to float32), in input order."""
    cfg = default_config() if config is None else config
    robot = HUSKY if robot is None else robot
    pre = cfg["prefilter"]
    if pre["voxel_m"] > 0 or pre["outlier_min_neighbors"] > 0:
        raise NotImplementedError("the reference has no voxel downsampling or outlier removal; switch them off")
    r_bs, t_bs = _pose(body_from_sensor, "body_from_sensor")
    r_wb, t_wb = _pose(world_from_body, "world_from_body")
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    r_sq = (p[:, 0] * p[:, 0] + p[:, 1] * p[:, 1]) + p[:, 2] * p[:, 2]
    keep = (r_sq >= np.float32(pre["min_range_m"] * pre["min_range_m"])) & (r_sq <= np.float32(pre["max_range_m"] * pre["max_range_m"]))
    body = _rotate(r_bs.astype(np.float32), p[keep]) + t_bs.astype(np.float32)
    mg = pre["self_margin_m"]
    lo = np.array([-robot["length_m"] / 2 - mg, -robot["width_m"] / 2 - mg, -mg]).astype(np.float32)
    hi = np.array([robot["length_m"] / 2 + mg, robot["width_m"] / 2 + mg, robot["height_m"] + mg]).astype(np.float32)
    body = body[~((body >= lo).all(axis=1) & (body <= hi).all(axis=1))]
    sensor_level = _rotate(r_wb, t_bs[None, :])[0]
    level = _rotate(r_wb.astype(np.float32), body) + (-sensor_level).astype(np.float32)
    return LevelScan(level.astype(np.float32), sensor_level, t_wb)


def _translation(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def _ramp(x: np.ndarray, ramp: dict[str, float]) -> np.ndarray:
    """``clamp((x - safe)/(lethal - safe), 0, 1)`` in float64; NaN gives 0."""
    with np.errstate(invalid="ignore"):
        v = (np.asarray(x, dtype=np.float64) - ramp["safe"]) / (ramp["lethal"] - ramp["safe"])
    return np.where(v > 0.0, np.minimum(v, 1.0), 0.0)


@dataclass
class CellSums:
    """What the points of one scan add up to per cell (flat ``iy·nx + ix`` arrays): counts
    (int64), heights above the body origin (float32: sum of the ground points' z in input
    order, lowest and highest z, ``±inf`` in empty cells)."""

    count: np.ndarray
    ground_n: np.ndarray
    collision_n: np.ndarray
    ground_sum: np.ndarray
    min_z: np.ndarray
    max_z: np.ndarray
    #: Void samples per cell (risk.rs ``void_n``); ``None``: none.
    void_n: np.ndarray | None = None


def bin_cells(scan: LevelScan, heights: np.ndarray, geometry: Geometry, config: dict[str, Any], robot: dict[str, float],
              voids: np.ndarray | None = None) -> CellSums:
    """Bins the points into the map's cells (risk.rs ``bin_scan`` + ``merge_binned`` for
    one scan): the global cell ``floor((x_level + sensor_world_x)/res)`` (float64), ``z`` =
    ``z_level + float32(sensor_level_z)``; a point is ground iff ``|h| <= thr``, else a
    collision point iff ``clearance < h <= height + head_margin`` (float32 thresholds).
    Assumes the sensor is within ``max_speed·window_s + 1 m`` of the body horizontally
    (Rust's binning scratch extent)."""
    res = geometry.resolution_m
    nx, ny = geometry.nx, geometry.ny
    ox = float(scan.body_world[0] + scan.sensor_level[0])
    oy = float(scan.body_world[1] + scan.sensor_level[1])
    p = scan.points
    ix = np.floor((p[:, 0].astype(np.float64) + ox) / res).astype(np.int64) - geometry.origin_cell[0]
    iy = np.floor((p[:, 1].astype(np.float64) + oy) / res).astype(np.int64) - geometry.origin_cell[1]
    inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    cell = (iy * nx + ix)[inside]
    z = (p[:, 2] + np.float32(scan.sensor_level[2]))[inside]
    h = np.asarray(heights, dtype=np.float32)[inside]
    thr = config["ground"]["max_dist_to_line_m"]
    with np.errstate(invalid="ignore"):
        ground = np.abs(h) <= np.float32(thr)
        lo = np.float32(robot["ground_clearance_m"] - config["layers"]["clearance_margin_m"])
        hi = np.float32(robot["height_m"] + config["layers"]["head_margin_m"])
        collision = ~ground & (h > lo) & (h <= hi)
    n = nx * ny
    ground_sum = np.zeros(n, dtype=np.float32)
    np.add.at(ground_sum, cell[ground], z[ground])  # float32, in input order
    min_z = np.full(n, np.inf, dtype=np.float32)
    max_z = np.full(n, -np.inf, dtype=np.float32)
    np.minimum.at(min_z, cell, z)
    np.maximum.at(max_z, cell, z)
    void_n = np.zeros(n, dtype=np.int64)
    if voids is not None and len(voids):
        v = np.asarray(voids, dtype=np.float32)
        vx = np.floor((v[:, 0].astype(np.float64) + ox) / res).astype(np.int64) - geometry.origin_cell[0]
        vy = np.floor((v[:, 1].astype(np.float64) + oy) / res).astype(np.int64) - geometry.origin_cell[1]
        vin = (vx >= 0) & (vx < nx) & (vy >= 0) & (vy < ny)
        void_n = np.bincount((vy * nx + vx)[vin], minlength=n)
    return CellSums(
        np.bincount(cell, minlength=n), np.bincount(cell[ground], minlength=n), np.bincount(cell[collision], minlength=n),
        ground_sum, min_z, max_z, void_n,
    )


def fast_atan2(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """ground.rs's ``fast_atan2`` (float64): :data:`FAST_ATAN2_COEFFICIENTS` on
    ``t = min(|x|,|y|)/max(|x|,|y|)``, folded into the octant; 0 at the origin."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    ax, ay = np.abs(x), np.abs(y)
    swap = ay > ax
    num, den = np.where(swap, ax, ay), np.where(swap, ay, ax)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = num / den
    t2 = t * t
    c0, c1, c2, c3, c4 = FAST_ATAN2_COEFFICIENTS
    a = t * (c0 + t2 * (c1 + t2 * (c2 + t2 * (c3 + t2 * c4))))
    a = np.where(swap, math.pi / 2 - a, a)
    a = np.where(x < 0.0, math.pi - a, a)
    a = np.where(y < 0.0, -a, a)
    return np.where(den == 0.0, 0.0, a)


@dataclass
class PolarQuery:
    """:func:`polar_query` at each position: inside the polar range, covered by a line,
    the line's height and the floor bound (``+inf`` without evidence) [sensor-centred m]."""

    inside: np.ndarray
    covered: np.ndarray
    ground_z: np.ndarray
    floor_bound_z: np.ndarray
    void: np.ndarray | None = None
    #: The shadow depth at the position (0 outside a shadow) [m].
    shadow_depth: np.ndarray | None = None


def polar_query(polar: PolarTable, x: np.ndarray, y: np.ndarray, *, atan: str = "fast") -> PolarQuery:
    """ground.rs ``GroundSegmenter::query`` at sensor-centred positions ``(x, y)`` [m]:
    the polar bin ``(min(floor((atan2(y, x) + π)·S/2π), S - 1), min(floor(r·(1/Δ)), B - 1))``;
    ``ground_z = m·r + b`` of its line, *covered* iff the bin is covered and
    ``cover_lo <= r <= cover_hi``, ``floor_bound_z = min(proto_z, ray_slope·r)``.
    ``atan="fast"``: the sector from :func:`fast_atan2`, as Rust's query (a position within
    2e-5 rad of a sector boundary may be given the neighbouring sector); ``"exact"``: from
    ``numpy.arctan2``, the documented formula."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    r = np.sqrt(x * x + y * y)
    inside = r < polar.max_range_m
    if atan == "fast":
        angle = fast_atan2(y, x)
    elif atan == "exact":
        angle = np.arctan2(y, x)
    else:
        raise ValueError(f"atan must be 'fast' or 'exact', got {atan!r}")
    s = np.minimum(np.floor((angle + math.pi) * (polar.sectors / (2.0 * math.pi))), polar.sectors - 1)
    k = np.minimum(np.floor(np.where(inside, r, 0.0) * (1.0 / polar.bin_m)), polar.bins - 1)
    sb = np.where(inside, s * polar.bins + k, 0).astype(np.int64)
    cap = polar.cap_r[sb] if polar.cap_r is not None else np.full(r.shape, np.inf)
    ground_z = expected_ground(polar.m[sb], polar.b[sb], cap, r)
    covered = inside & (r >= polar.cover_lo[sb]) & (r <= polar.cover_hi[sb])
    with np.errstate(invalid="ignore"):
        # f64::min ignores a NaN (inf·0 at r = 0); so does fmin.
        floor_bound = np.fmin(polar.proto_z[sb].astype(np.float64), polar.ray_slope[sb].astype(np.float64) * r)
    void = inside & polar.void[sb] if polar.void is not None else np.zeros_like(inside)
    if polar.solid_r is not None and polar.shadow_depth is not None:
        shadow = np.where(inside & (r > polar.solid_r[sb].astype(np.float64)), polar.shadow_depth[sb].astype(np.float64), 0.0)
    else:
        shadow = np.zeros(r.shape)
    return PolarQuery(inside, covered, ground_z, floor_bound, void, shadow)


def polar_fill(
    cells: CellSums, polar: PolarTable, scan: LevelScan, geometry: Geometry, *, atan: str = "fast", ground_threshold: float = 0.1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """risk.rs ``ground_heights``: ``(height, observed, negative_depth)`` as float32
    ``(ny, nx)``. ``height`` (above the body origin) is the mean z of the cell's ground
    points (float32), else the newest scan's ground line at the cell centre where it covers
    the cell, else NaN; ``observed`` = 1 where the cell has a point or is covered;
    ``negative_depth = max(ground_z - floor_bound_z, 0)`` where the floor bound is finite
    and the cell has no ground point, else 0; on a cell with ground points, ``mean -
    min_z`` (float32) where that exceeds ``ground_threshold`` (``max_dist_to_line_m``),
    else 0."""
    s = scan.sensor_level
    # Cell centres relative to the sensor: (corner + (i + 0.5)·res) - sensor, corner = origin - body.
    res = geometry.resolution_m
    corner_x = geometry.origin_cell[0] * res - float(scan.body_world[0])
    corner_y = geometry.origin_cell[1] * res - float(scan.body_world[1])
    x = corner_x + (np.arange(geometry.nx) + 0.5) * res - s[0]
    y = corner_y + (np.arange(geometry.ny) + 0.5) * res - s[1]
    q = polar_query(polar, x[None, :], y[:, None], atan=atan)
    shape = geometry.shape
    ground_n = cells.ground_n.reshape(shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = cells.ground_sum.reshape(shape) / ground_n.astype(np.float32)
    fill = q.covered & (ground_n == 0)
    height = np.where(ground_n > 0, mean, np.where(fill, (q.ground_z + s[2]).astype(np.float32), np.float32(np.nan)))
    observed = ((cells.count.reshape(shape) > 0) | q.covered).astype(np.float32)
    with np.errstate(invalid="ignore"):
        depth = np.where(q.inside & np.isfinite(q.floor_bound_z) & (ground_n == 0), np.maximum(q.ground_z - q.floor_bound_z, 0.0), 0.0)
        if q.shadow_depth is not None:
            # In a drop's shadow the drop may begin anywhere (f32 max, as risk.rs).
            depth = np.where(q.inside & (ground_n == 0), np.maximum(depth.astype(np.float32), q.shadow_depth.astype(np.float32)), depth)
        drop = (mean - cells.min_z.reshape(shape)).astype(np.float32)
        depth = np.where((ground_n > 0) & (drop > np.float32(ground_threshold)), drop, depth)
    # Void: the floor found missing (this scan's bin, or a void sample in the cell) and no
    # ground point in the cell: observed, infinitely deep, no filled height.
    void_n = cells.void_n.reshape(shape) if cells.void_n is not None else np.zeros(shape, dtype=np.int64)
    void = (ground_n == 0) & (q.void | (void_n > 0))
    height = np.where(void, np.float32(np.nan), height)
    observed = np.where(void, np.float32(1.0), observed)
    depth = np.where(void, np.inf, depth)
    return height.astype(np.float32), observed, depth.astype(np.float32)


def _shifted(a: np.ndarray, dx: int, dy: int, pad: int) -> np.ndarray:
    """``a[iy + dy, ix + dx]`` for every cell of ``a`` (``a`` padded by ``pad`` cells)."""
    ny, nx = a.shape[0] - 2 * pad, a.shape[1] - 2 * pad
    return a[pad + dy:pad + dy + ny, pad + dx:pad + dx + nx]


def _pad_nan(a: np.ndarray, pad: int) -> np.ndarray:
    return np.pad(a, pad, constant_values=np.nan)


def plane_fit(height: np.ndarray, resolution_m: float, plane_window_m: float, plane_min_cells: int) -> tuple[np.ndarray, np.ndarray]:
    """``(slope, plane_residual)`` (float32 ``(ny, nx)``): for each cell with a height, the
    least-squares plane ``z = a·x + b·y + c`` through the heights of the cells with one in
    the ``w x w`` window centred on it (``w`` odd, nearest ``plane_window_m/res``; clipped
    at the map's edge), given at least ``plane_min_cells`` of them that are not collinear;
    slope ``atan(sqrt(a² + b²))`` [rad], residual ``sqrt(SSE/n)`` [m]; else NaN.

    Direct window sums: offsets in whole cells (exact), heights relative to the centre
    cell's (float64), normal equations by Cramer's rule."""
    slope, residual, _ = _plane_fit(height, resolution_m, plane_window_m, plane_min_cells)
    return slope, residual


def _plane_fit(height: np.ndarray, resolution_m: float, plane_window_m: float, plane_min_cells: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`plane_fit`, and the cells whose window would have enough cells but they are
    collinear (no plane by definition; see the module doc on Rust's handling)."""
    half = _odd_half(plane_window_m, resolution_m)
    h = height.astype(np.float64)
    hp = _pad_nan(h, half)
    shape = h.shape
    n = np.zeros(shape, dtype=np.int64)
    sx, sy, sxx, sxy, syy = (np.zeros(shape, dtype=np.int64) for _ in range(5))
    sz, sxz, syz, szz = (np.zeros(shape) for _ in range(4))
    with np.errstate(invalid="ignore"):
        for dy in range(-half, half + 1):
            for dx in range(-half, half + 1):
                win = _shifted(hp, dx, dy, half)
                ok = np.isfinite(win)
                dz = np.where(ok, win - h, 0.0)
                n += ok
                if dx:
                    sx += dx * ok
                    sxx += dx * dx * ok
                    sxz += dx * dz
                if dy:
                    sy += dy * ok
                    syy += dy * dy * ok
                    syz += dy * dz
                if dx and dy:
                    sxy += dx * dy * ok
                sz += dz
                szz += dz * dz
    # [sxx sxy sx; sxy syy sy; sx sy n] [a b c] = [sxz syz sz] (a, b per cell).
    c11 = syy * n - sy * sy
    c12 = sxy * n - sy * sx
    c13 = sxy * sy - syy * sx
    det = sxx * c11 - sxy * c12 + sx * c13  # exact integers: 0 iff the cells are collinear
    enough = np.isfinite(h) & (n >= plane_min_cells)
    ok = enough & (det != 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        fdet = det.astype(np.float64)
        a = (sxz * c11 - sxy * (syz * n - sy * sz) + sx * (syz * sy - syy * sz)) / fdet
        b = (sxx * (syz * n - sy * sz) - sxz * c12 + sx * (sxy * sz - syz * sx)) / fdet
        c = (sxx * (syy * sz - sy * syz) - sxy * (sxy * sz - syz * sx) + sxz * c13) / fdet
        sse = np.maximum(szz - a * sxz - b * syz - c * sz, 0.0)
        slope = np.arctan(np.sqrt(a * a + b * b) / resolution_m)
        residual = np.sqrt(sse / n)
    nan = np.float32(np.nan)
    return np.where(ok, slope, nan).astype(np.float32), np.where(ok, residual, nan).astype(np.float32), enough & (det == 0)


def step_heights(height: np.ndarray) -> np.ndarray:
    """``max |H(n) - H(c)|`` over the 8 neighbours ``n`` with a height (float32, 0 without
    one) for each cell with a height; NaN elsewhere."""
    hp = _pad_nan(height.astype(np.float32), 1)
    worst = np.zeros(height.shape, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dx or dy:
                    worst = np.fmax(worst, np.abs(_shifted(hp, dx, dy, 1) - height))
    return np.where(np.isfinite(height), worst, np.float32(np.nan)).astype(np.float32)


def footprint_corners(robot: dict[str, float], resolution_m: float, heading_rad: float) -> list[tuple[int, int]]:
    """The footprint's corners (front-left, front-right, rear-left, rear-right) at
    ``heading_rad`` from world x, rounded to whole cells ``round((R·c)/res)``."""
    a, b = robot["length_m"] / 2.0, robot["width_m"] / 2.0
    s, c = math.sin(heading_rad), math.cos(heading_rad)
    return [(int(_round((c * x - s * y) / resolution_m)), int(_round((s * x + c * y) / resolution_m))) for x, y in ((a, b), (a, -b), (-a, b), (-a, -b))]


def settled_tilt(height: np.ndarray, slope: np.ndarray, robot: dict[str, float], layers: dict[str, Any], resolution_m: float) -> np.ndarray:
    """The ``tilt_angle`` layer (float32, rad) by settling: each wheel rests on the highest
    height in the ``wheel_patch_m`` square around its footprint corner; at each of the
    ``tilt_headings`` headings ``j·180°/J`` the body rests on every triangle of three corners
    whose plane passes at or above the fourth; the layer is ``atan |∇z|`` of the steepest
    such plane over the headings. Where no heading has all four corners on the map with a
    height, ``slope`` stands in; NaN where the cell has no height."""
    patch = _odd_half(layers["wheel_patch_m"], resolution_m)
    hp = _pad_nan(height.astype(np.float32), patch)
    top = np.full(height.shape, np.nan, dtype=np.float32)
    for dy in range(-patch, patch + 1):
        for dx in range(-patch, patch + 1):
            top = np.fmax(top, _shifted(hp, dx, dy, patch))
    headings = int(layers["tilt_headings"])
    stencils = [footprint_corners(robot, resolution_m, j * math.pi / headings) for j in range(headings)]
    reach = max(max(abs(d) for corner in st for d in corner) for st in stencils)
    tp = _pad_nan(top, reach).astype(np.float64)
    worst = np.full(height.shape, -1.0)
    with np.errstate(invalid="ignore"):
        for corners in stencils:
            h = [_shifted(tp, dx, dy, reach) for dx, dy in corners]
            ok = np.isfinite(h[0]) & np.isfinite(h[1]) & np.isfinite(h[2]) & np.isfinite(h[3])
            for lifted in range(4):
                i, j, k = (q for q in range(4) if q != lifted)
                (xi, yi), (xj, yj), (xk, yk), (xo, yo) = corners[i], corners[j], corners[k], corners[lifted]
                ujx, ujy, ukx, uky = xj - xi, yj - yi, xk - xi, yk - yi
                det = ujx * uky - ujy * ukx
                if det == 0:
                    continue  # collinear corners: no plane
                dj, dk = h[j] - h[i], h[k] - h[i]
                gx = (dj * uky - dk * ujy) / det  # gradient [m per cell]
                gy = (dk * ujx - dj * ukx) / det
                rests = h[i] + gx * (xo - xi) + gy * (yo - yi) >= h[lifted]
                tan2 = (gx * gx + gy * gy) / (resolution_m * resolution_m)
                worst = np.where(ok & rests, np.maximum(worst, tan2), worst)
    tilt = np.where(worst >= 0.0, np.arctan(np.sqrt(np.maximum(worst, 0.0))).astype(np.float32), slope)
    return np.where(np.isfinite(height), tilt, np.float32(np.nan)).astype(np.float32)


def mission_layer(geometry: Geometry, items: Any, margin_m: float) -> np.ndarray:
    """The ``mission`` layer (float32): per item ``(x, y, radius)`` [m, world], 1 where the
    cell centre is within the radius, falling linearly to 0 over ``margin_m`` beyond it
    (``margin_m = 0``: a hard circle); the maximum over the items."""
    xc, yc = geometry.centres()
    out = np.zeros(geometry.shape, dtype=np.float32)
    for item in items:
        px, py, radius = (float(v) for v in np.asarray(item, dtype=np.float64).ravel())
        dx, dy = xc[None, :] - px, yc[:, None] - py
        d = np.sqrt(dx * dx + dy * dy)
        value = np.where(d <= radius, 1.0, np.maximum(1.0 - (d - radius) / margin_m, 0.0) if margin_m > 0 else 0.0)
        out = np.maximum(out, value.astype(np.float32))
    return out


def risk_layers(layers: dict[str, np.ndarray], config: dict[str, Any], robot: dict[str, float]) -> dict[str, np.ndarray]:
    """The risk layers from the geometric ones (float32 ``(ny, nx)`` in, float32 out):
    ``step``, ``negative``, ``tilt``, ``roughness`` = ramps of ``step_height``,
    ``negative_depth``, ``tilt_angle`` (the robot's tilt limits in radians),
    ``plane_residual``; ``observed`` also where ``negative > 0`` (rated by ray reasoning,
    written back into ``layers``); ``unknown = risk.unknown`` where not ``observed``; ``risk = 1 -
    Π(1 - r_k)`` over ``collision, step, negative, tilt, roughness, unknown, mission`` (that
    order, float64); ``risk_variance = σ²``, ``σ = min(sqrt(σ_range²/max(count, 1) +
    (drift·age)²)/height_span, max_sigma)`` where observed (age 0 in a cell without points),
    ``max_sigma`` elsewhere. ``layers`` must hold ``collision``, ``mission`` and the layers
    named above."""
    r, u = config["risk"], config["uncertainty"]
    tilt_ramp = {"safe": math.radians(robot["tilt_safe_deg"]), "lethal": math.radians(robot["tilt_lethal_deg"])}
    negative = _ramp(layers["negative_depth"], r["negative_m"])
    # A cell rated by ray reasoning (negative > 0) is observed.
    observed = (layers["observed"] > 0.0) | (negative > 0.0)
    layers["observed"] = observed.astype(np.float32)
    risks = {
        "collision": np.asarray(layers["collision"], dtype=np.float64),
        "step": _ramp(layers["step_height"], r["step_m"]),
        "negative": negative,
        "tilt": _ramp(layers["tilt_angle"], tilt_ramp),
        "roughness": _ramp(layers["plane_residual"], r["roughness_m"]),
        "unknown": np.where(observed, 0.0, float(r["unknown"])),
        "mission": np.asarray(layers["mission"], dtype=np.float64),
    }
    keep = np.ones(observed.shape)
    for value in risks.values():
        keep = keep * (1.0 - value)
    count = np.asarray(layers["count"], dtype=np.float64)
    with np.errstate(invalid="ignore"):
        age = np.where(count > 0, np.asarray(layers["age"], dtype=np.float64), 0.0)
    var_h = u["range_sigma_m"] * u["range_sigma_m"] / np.maximum(count, 1.0) + (u["drift_m_per_s"] * age) ** 2
    sigma = np.where(observed, np.minimum(np.sqrt(var_h) / u["height_span_m"], u["max_sigma"]), u["max_sigma"])
    out = {name: value.astype(np.float32) for name, value in risks.items()}
    out["risk"] = np.clip(1.0 - keep, 0.0, 1.0).astype(np.float32)
    out["risk_variance"] = (sigma * sigma).astype(np.float32)
    return out


def cvar_factor(alpha: float) -> float:
    """``φ(Φ⁻¹(α))/(1 - α)``: the CVaR of a standard normal at level α in (0, 1)."""
    if not (math.isfinite(alpha) and 0.0 < alpha < 1.0):
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    nd = NormalDist()
    return nd.pdf(nd.inv_cdf(alpha)) / (1.0 - alpha)


def cvar(risk: np.ndarray, risk_variance: np.ndarray, alpha: float) -> np.ndarray:
    """``CVaR_α`` of each cell's risk under a normal approximation (STEP):
    ``clip(μ + σ·φ(Φ⁻¹(α))/(1 - α), 0, 1)`` with ``μ = risk``, ``σ = sqrt(max(risk_variance, 0))``
    (float32 square root); float32."""
    sigma = np.sqrt(np.maximum(np.asarray(risk_variance, dtype=np.float32), np.float32(0.0))).astype(np.float64)
    return np.clip(np.asarray(risk, dtype=np.float64) + sigma * cvar_factor(alpha), 0.0, 1.0).astype(np.float32)


@dataclass
class CoarseMap:
    """The reference's coarse map: every layer of :data:`LAYER_NAMES` as float32
    ``(ny, nx)`` (row ``iy`` along world y) and the geometry."""

    layers: dict[str, np.ndarray]
    geometry: Geometry
    #: Cells with a height whose plane window holds ``plane_min_cells`` heights or more, all
    #: on one line: no plane, so ``slope`` and ``plane_residual`` are NaN (bool ``(ny, nx)``).
    collinear: np.ndarray | None = None

    def layer(self, name: str) -> np.ndarray:
        return self.layers[name]

    def cvar(self, alpha: float) -> np.ndarray:
        return cvar(self.layers["risk"], self.layers["risk_variance"], alpha)


def coarse_map(
    points: np.ndarray,
    *,
    sensor_height: float | None = None,
    body_from_sensor: np.ndarray | None = None,
    world_from_body: np.ndarray | None = None,
    config: dict[str, Any] | None = None,
    robot: dict[str, float] | None = None,
    mission_items: Any = (),
    boundary_rule: str = "atan2",
    query_atan: str = "fast",
) -> CoarseMap:
    """The coarse map of ``TerrainMapper(robot, config)`` after
    ``set_mission_items(mission_items)`` and one ``update(points, world_from_body=...,
    body_from_sensor=...)`` (a fresh mapper: one scan, age 0), with all 21 layers.

    ``sensor_height``: shorthand for ``body_from_sensor`` = translation ``(0, 0, h)``.
    ``boundary_rule``: the point sectors of the segmentation (:func:`polar_bins`);
    ``query_atan``: the cell-centre sectors of the polar fill (:func:`polar_query`)."""
    cfg = default_config() if config is None else config
    robot = HUSKY if robot is None else robot
    if sensor_height is not None:
        if body_from_sensor is not None:
            raise ValueError("give sensor_height or body_from_sensor, not both")
        body_from_sensor = _translation(z=sensor_height)
    scan = level_scan(points, body_from_sensor=body_from_sensor, world_from_body=world_from_body, config=cfg, robot=robot)
    seg = ground_heights(scan.points, sensor_height=float(scan.sensor_level[2]), config=cfg, boundary_rule=boundary_rule)
    geometry = Geometry.centred_on(cfg["coarse"], float(scan.body_world[0]), float(scan.body_world[1]))
    assert seg.polar is not None
    cells = bin_cells(scan, seg.heights, geometry, cfg, robot, void_samples(seg.polar))
    height, observed, depth = polar_fill(cells, seg.polar, scan, geometry, atan=query_atan,
                                         ground_threshold=float(cfg["ground"]["max_dist_to_line_m"]))
    res = geometry.resolution_m
    lay = cfg["layers"]
    slope, residual, collinear = _plane_fit(height, res, lay["plane_window_m"], int(lay["plane_min_cells"]))
    shape = geometry.shape
    z0 = np.float32(scan.body_world[2])
    has = cells.count.reshape(shape) > 0
    nan = np.float32(np.nan)
    layers: dict[str, np.ndarray] = {
        "count": cells.count.reshape(shape).astype(np.float32),
        "ground_count": cells.ground_n.reshape(shape).astype(np.float32),
        "ground_height": height + z0,
        "min_height": np.where(has, cells.min_z.reshape(shape) + z0, nan),
        "max_height": np.where(has, cells.max_z.reshape(shape) + z0, nan),
        "slope": slope,
        "plane_residual": residual,
        "step_height": step_heights(height),
        "negative_depth": depth,
        "tilt_angle": settled_tilt(height, slope, robot, lay, res),
        "observed": observed,
        "age": np.where(has, np.float32(0.0), nan),
        "collision": _ramp(cells.collision_n.reshape(shape), cfg["risk"]["collision_points"]).astype(np.float32),
        "mission": mission_layer(geometry, mission_items, float(cfg["risk"]["mission_margin_m"])),
    }
    layers.update(risk_layers(layers, cfg, robot))
    return CoarseMap({name: layers[name].astype(np.float32) for name in LAYER_NAMES}, geometry, collinear)


def coarse_layers(
    points: np.ndarray,
    *,
    sensor_height: float,
    config: dict[str, Any] | None = None,
    robot: dict[str, float] | None = None,
) -> dict[str, np.ndarray]:
    """The layers ``count``, ``ground_count``, ``min_height``, ``max_height``,
    ``ground_height`` (NaN where the cell has no ground point) and ``collision`` of the
    coarse map of one scan (``world_from_body`` = identity, ``body_from_sensor`` =
    translation ``(0, 0, sensor_height)``): the binning stage alone, without the polar fill
    and the later layers (see :func:`coarse_map` for all of them)."""
    cfg = default_config() if config is None else config
    robot = HUSKY if robot is None else robot
    scan = level_scan(points, body_from_sensor=_translation(z=sensor_height), config=cfg, robot=robot)
    heights = ground_heights(scan.points, sensor_height=float(scan.sensor_level[2]), config=cfg).heights
    geometry = Geometry.centred_on(cfg["coarse"], 0.0, 0.0)
    cells = bin_cells(scan, heights, geometry, cfg, robot)
    has = cells.count > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        ground_height = np.where(cells.ground_n > 0, cells.ground_sum / cells.ground_n.astype(np.float32), np.float32(np.nan))
    layers = {
        "count": cells.count.astype(np.float32),
        "ground_count": cells.ground_n.astype(np.float32),
        "ground_height": ground_height.astype(np.float32),
        "min_height": np.where(has, cells.min_z, np.float32(np.nan)),
        "max_height": np.where(has, cells.max_z, np.float32(np.nan)),
        "collision": _ramp(cells.collision_n, cfg["risk"]["collision_points"]).astype(np.float32),
    }
    return {k: v.reshape(geometry.shape) for k, v in layers.items()}
