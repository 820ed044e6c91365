"""APF-PF in plain, vectorised NumPy: the reference for parity tests and benchmarks.

This module implements APF-PF (Ahmad et al., ACC 2021) (APF-PF: a particle filter over a 2.5D
voxel grid of a depth image, whose belief weights artificial potential fields) with the
exact conventions of the Rust implementation in ``crates/subterra``. It imports only
NumPy and the standard library, so it also loads without the compiled ``subterra._core``
(for example by file path).

Conventions and units
---------------------
* Configuration: a nested ``dict`` exactly as a preset TOML file (``configs/*.toml``),
  e.g. ``cfg["grid"]["block_width_px"]``. Units are in the key names (px, m, voxels,
  points, m/s, rad/s).
* Camera: a ``dict`` with ``fx, fy, cx, cy`` (pixels) and ``width, height`` (pixels).
* ``body_from_camera``: a 4x4 homogeneous transform (metres) from the camera optical
  frame (x right, y down, z forward) to the body frame (FLU: x forward, y left, z up).
* Voxel ``(i, j, k)``: ``i`` column block (``u // k_w``), ``j`` row block (``v // k_h``),
  ``k`` depth bin. Its state id is ``(j * n_w + i) * n_d + k``; the free state ("no
  obstacle inside the sensing horizon") is the last id, ``n_w * n_h * n_d``; there are
  ``S = n_w * n_h * n_d + 1`` states. Count arrays have shape ``(n_h, n_w, n_d)``, so
  ``counts.reshape(-1)`` is in state-id order.
* Forces and goals are in the body frame (metres, newton-like units of the potentials);
  commands in m/s and rad/s.

The transition matrix is kept dense here, ``(S, S)`` float64: fine for the presets
(S = 1431 for a 640x480 camera, 16 MB) but O(S^2) memory for large grids.
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np

from subterra._compat import tomllib

__all__ = [
    "DEFAULT_BODY_FROM_CAMERA",
    "REPO_ROOT",
    "HistogramFilter",
    "ParticleFilter",
    "ReferencePipeline",
    "block_pixel_counts",
    "closest_depth",
    "command",
    "grid_shape",
    "histogram_update",
    "load_config",
    "log_likelihood",
    "num_states",
    "preset",
    "repulsive_forces",
    "state_id",
    "transition_matrix",
    "voxel_centers_body",
    "voxel_counts",
    "voxel_of_state",
]

#: Repository root: python/subterra/bench/reference/apf_pf.py -> 4 parents up from here.
REPO_ROOT = Path(__file__).resolve().parents[4]

#: Forward-looking camera in an FLU body: camera z -> body x, camera x -> body -y,
#: camera y -> body -z, no translation.
DEFAULT_BODY_FROM_CAMERA = np.array(
    [
        [0.0, 0.0, 1.0, 0.0],
        [-1.0, 0.0, 0.0, 0.0],
        [0.0, -1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
)

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
# Added before flooring a depth bin, so that e.g. (0.3 - 0.1) / 0.1 = 1.9999999999999998
# lands in bin 2.
_BIN_EPS = 1e-9


# --------------------------------------------------------------------------- config


def load_config(path) -> dict:
    """Load a preset TOML file into a nested dict (same layout as the file)."""
    with open(path, "rb") as f:
        return tomllib.load(f)


def preset(name: str) -> dict:
    """Load the named preset ``<repo>/configs/<name>.toml`` (e.g. ``"flight"``, ``"cable"``).

    Raises ``ValueError`` for an unknown name.
    """
    configs = REPO_ROOT / "configs"
    path = configs / f"{name}.toml"
    if not isinstance(name, str) or "/" in name or "\\" in name or not path.is_file():
        known = sorted(p.stem for p in configs.glob("*.toml"))
        raise ValueError(f"unknown preset {name!r}; known presets: {known}")
    return load_config(path)


# --------------------------------------------------------------------------- grid


def _camera_size(camera: dict) -> tuple[int, int]:
    """(width, height) of the camera in pixels, checked."""
    w, h = int(camera["width"]), int(camera["height"])
    if w <= 0 or h <= 0:
        raise ValueError(f"camera width and height must be positive, got {w}x{h}")
    return w, h


def grid_shape(cfg: dict, camera: dict) -> tuple[int, int, int]:
    """``(n_w, n_h, n_d)``: column blocks, row blocks and depth bins of the voxel grid.

    ``n_w = ceil(W / k_w)``, ``n_h = ceil(H / k_h)`` (integer ceil, pixels) and
    ``n_d = round((d_max - d_min) / k_d)`` (metres).
    """
    g = cfg["grid"]
    k_w, k_h = int(g["block_width_px"]), int(g["block_height_px"])
    k_d, d_min, d_max = float(g["depth_bin_m"]), float(g["depth_min_m"]), float(g["depth_max_m"])
    if k_w <= 0 or k_h <= 0:
        raise ValueError(f"grid block size must be positive, got {k_w}x{k_h} px")
    if not (k_d > 0 and math.isfinite(k_d)):
        raise ValueError(f"grid.depth_bin_m must be positive and finite, got {k_d}")
    if not (0 <= d_min < d_max and math.isfinite(d_max)):
        raise ValueError(f"grid depth range must satisfy 0 <= min < max, got [{d_min}, {d_max}]")
    w, h = _camera_size(camera)
    n_w = -(-w // k_w)
    n_h = -(-h // k_h)
    n_d = round((d_max - d_min) / k_d)
    if n_d < 1:
        raise ValueError("grid depth range is shorter than half a bin")
    return n_w, n_h, n_d


def num_states(cfg: dict, camera: dict) -> int:
    """Number of states ``S = n_w * n_h * n_d + 1`` (voxels plus the free state)."""
    n_w, n_h, n_d = grid_shape(cfg, camera)
    return n_w * n_h * n_d + 1


def state_id(i: int, j: int, k: int, cfg: dict, camera: dict) -> int:
    """State id ``(j * n_w + i) * n_d + k`` of voxel ``(i, j, k)``."""
    n_w, n_h, n_d = grid_shape(cfg, camera)
    if not (0 <= i < n_w and 0 <= j < n_h and 0 <= k < n_d):
        raise ValueError(f"voxel {(i, j, k)} outside the grid {(n_w, n_h, n_d)}")
    return (j * n_w + i) * n_d + k


def voxel_of_state(s: int, cfg: dict, camera: dict):
    """Voxel ``(i, j, k)`` of state id ``s``, or ``None`` for the free state."""
    n_w, n_h, n_d = grid_shape(cfg, camera)
    n_vox = n_w * n_h * n_d
    if not 0 <= s <= n_vox:
        raise ValueError(f"state {s} outside [0, {n_vox}]")
    if s == n_vox:
        return None
    block, k = divmod(int(s), n_d)
    j, i = divmod(block, n_w)
    return i, j, k


def _voxel_ijk(n_w: int, n_h: int, n_d: int):
    """Arrays ``i, j, k`` (int64) of every voxel, in state-id order."""
    j, i, k = np.indices((n_h, n_w, n_d)).reshape(3, -1)
    return i, j, k


@lru_cache(maxsize=16)
def _pixel_block_ids(width: int, height: int, k_w: int, k_h: int) -> np.ndarray:
    """(H, W) int64: block index ``(v // k_h) * n_w + u // k_w`` of every pixel (read-only)."""
    n_w = -(-width // k_w)
    ids = (np.arange(height) // k_h)[:, None] * n_w + (np.arange(width) // k_w)[None, :]
    ids = ids.astype(np.int64)
    ids.setflags(write=False)
    return ids


def _depth_metres(depth: np.ndarray, scale: float) -> np.ndarray:
    """Depth image as float64 metres: ``raw * scale`` for uint16, the value for floats."""
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"depth must be a 2-D (H, W) image, got shape {depth.shape}")
    if depth.dtype == np.uint16:
        scale = float(scale)
        if not (scale > 0 and math.isfinite(scale)):
            raise ValueError(f"scale must be positive and finite, got {scale}")
        return depth.astype(np.float64) * scale
    if depth.dtype in (np.float32, np.float64):
        return depth.astype(np.float64)
    raise ValueError(f"depth must be uint16 (with a scale) or float32 metres, got {depth.dtype}")


def voxel_counts(depth: np.ndarray, scale: float, cfg: dict, camera: dict) -> np.ndarray:
    """Points per voxel: int64 array of shape ``(n_h, n_w, n_d)``.

    ``depth`` is an (H, W) image matching the camera: ``uint16`` raw units (``z = raw *
    scale`` metres, in float64) or ``float32`` metres (``scale`` ignored). A pixel is valid
    iff ``z`` is finite and ``> 0``; its depth bin is ``k = floor((z - d_min)/k_d + 1e-9)``
    and it is counted iff ``0 <= k < n_d`` and ``z < d_max`` (the second test matters only
    for a range that is a hair short of whole bins, which validation tolerates).
    """
    w, h = _camera_size(camera)
    z = _depth_metres(depth, scale)
    if z.shape != (h, w):
        raise ValueError(f"depth has shape {z.shape}, the camera is {h}x{w} (H x W)")
    g = cfg["grid"]
    n_w, n_h, n_d = grid_shape(cfg, camera)
    d_min, k_d, d_max = float(g["depth_min_m"]), float(g["depth_bin_m"]), float(g["depth_max_m"])
    with np.errstate(invalid="ignore"):
        kf = np.floor((z - d_min) / k_d + _BIN_EPS)  # NaN / inf propagate and fail the tests below
        keep = np.isfinite(z) & (z > 0) & (z < d_max) & (kf >= 0) & (kf < n_d)
    blocks = _pixel_block_ids(w, h, int(g["block_width_px"]), int(g["block_height_px"]))
    ids = blocks[keep] * n_d + kf[keep].astype(np.int64)
    return np.bincount(ids, minlength=n_w * n_h * n_d).reshape(n_h, n_w, n_d)


def closest_depth(depth: np.ndarray, scale: float = 0.001):
    """Depth in metres of the closest valid pixel (finite, ``> 0``, any range), or ``None``."""
    z = _depth_metres(depth, scale)
    valid = z[np.isfinite(z) & (z > 0)]
    return float(valid.min()) if valid.size else None


def block_pixel_counts(cfg: dict, camera: dict) -> np.ndarray:
    """Pixels per block, int64 ``(n_h, n_w)``: ``B(i, j) = min(k_w, W - i k_w) * min(k_h, H - j k_h)``."""
    w, h = _camera_size(camera)
    k_w, k_h = int(cfg["grid"]["block_width_px"]), int(cfg["grid"]["block_height_px"])
    n_w, n_h, _ = grid_shape(cfg, camera)
    bw = np.minimum(k_w, w - np.arange(n_w) * k_w)
    bh = np.minimum(k_h, h - np.arange(n_h) * k_h)
    return (bh[:, None] * bw[None, :]).astype(np.int64)


# --------------------------------------------------------------------------- models


def _hn(x, sigma: float):
    """Unnormalised half-normal ``exp(-x^2 / (2 sigma^2))``."""
    return np.exp(-0.5 * (np.asarray(x, dtype=np.float64) / sigma) ** 2)


def transition_matrix(cfg: dict, camera: dict) -> np.ndarray:
    """Dense row-stochastic transition matrix ``T[s, s']``, float64 ``(S, S)``.

    Unnormalised, with ``hn(x; s) = exp(-x^2/2s^2)``, ``z(k) = d_min + (k + 0.5) k_d``
    (metres), ``L1`` the Manhattan distance in voxels and ``face(v) = min(i+1, n_w-i,
    j+1, n_h-j, n_d-k)`` (distance to the left, right, top, bottom and far faces):

    * voxel -> voxel: ``hn(L1(v, v'); sigma_s) * hn(z(k'); sigma_z)``
    * voxel -> free:  ``hn(face(v); sigma_s) * hn(z_free; sigma_z)``
    * free -> voxel:  ``hn(face(v'); sigma_s) * hn(z(k'); sigma_z)``
    * free -> free:   ``hn(0) * hn(z_free; sigma_z)``

    then every row is divided by its sum. ``z_free`` is ``d_max`` when
    ``transition.free_state_depth`` is ``"horizon"`` (or absent) and 0 when it is ``"zero"``
    (the authors' code stores the free state as the point (0, 0, 0)).
    """
    g, t = cfg["grid"], cfg["transition"]
    sigma_s, sigma_z = float(t["sigma_s_voxels"]), float(t["sigma_z_m"])
    if not (sigma_s > 0 and sigma_z > 0):
        raise ValueError(f"transition sigmas must be positive, got {sigma_s}, {sigma_z}")
    d_min, k_d, d_max = float(g["depth_min_m"]), float(g["depth_bin_m"]), float(g["depth_max_m"])
    n_w, n_h, n_d = grid_shape(cfg, camera)
    i, j, k = _voxel_ijk(n_w, n_h, n_d)
    n_vox = i.size

    depth_w = _hn(d_min + (k + 0.5) * k_d, sigma_z)  # target-depth factor, per voxel
    face = np.minimum.reduce([i + 1, n_w - i, j + 1, n_h - j, n_d - k])
    face_w = _hn(face, sigma_s)
    free_depth = t.get("free_state_depth", "horizon")
    if free_depth not in ("horizon", "zero"):
        raise ValueError(f"transition.free_state_depth must be 'horizon' or 'zero', got {free_depth!r}")
    free_depth_w = float(_hn(d_max if free_depth == "horizon" else 0.0, sigma_z))

    l1 = np.abs(i[:, None] - i[None, :]) + np.abs(j[:, None] - j[None, :]) + np.abs(k[:, None] - k[None, :])
    T = np.empty((n_vox + 1, n_vox + 1))
    T[:n_vox, :n_vox] = _hn(l1, sigma_s) * depth_w[None, :]
    T[:n_vox, n_vox] = face_w * free_depth_w
    T[n_vox, :n_vox] = face_w * depth_w
    T[n_vox, n_vox] = free_depth_w
    T /= T.sum(axis=1, keepdims=True)
    return T


def log_likelihood(counts: np.ndarray, cfg: dict, camera: dict) -> np.ndarray:
    """Log observation likelihood of every state, float64 ``(S,)``.

    ``counts`` is the ``(n_h, n_w, n_d)`` output of :func:`voxel_counts`. With
    ``A = k_w k_h`` and ``B`` the pixels of the voxel's block (:func:`block_pixel_counts`):

    * voxel: ``log N(n; B, sigma_o B / A)`` but with sigma_o's constant,
      ``-0.5 ((n - B) / (sigma_o B / A))^2 - log(sigma_o) - 0.5 log(2 pi)``;
    * free: ``log N(max n; 0, sigma_n) = -0.5 (max n / sigma_n)^2 - log(sigma_n) - 0.5 log(2 pi)``.

    ``sigma_o`` and ``sigma_n`` are in points (pixels).
    """
    o = cfg["observation"]
    sigma_o, sigma_n = float(o["sigma_o_points"]), float(o["sigma_n_points"])
    if not (sigma_o > 0 and sigma_n > 0):
        raise ValueError(f"observation sigmas must be positive, got {sigma_o}, {sigma_n}")
    n_w, n_h, n_d = grid_shape(cfg, camera)
    counts = np.asarray(counts)
    if counts.shape != (n_h, n_w, n_d):
        raise ValueError(f"counts has shape {counts.shape}, expected {(n_h, n_w, n_d)}")
    g = cfg["grid"]
    area = float(g["block_width_px"] * g["block_height_px"])
    b = block_pixel_counts(cfg, camera).astype(np.float64)[:, :, None]
    n = counts.astype(np.float64)

    out = np.empty(n.size + 1)
    out[:-1] = (-0.5 * ((n - b) / (sigma_o * b / area)) ** 2).reshape(-1)
    out[:-1] -= math.log(sigma_o) + _LOG_SQRT_2PI
    n_max = float(n.max()) if n.size else 0.0
    out[-1] = -0.5 * (n_max / sigma_n) ** 2 - math.log(sigma_n) - _LOG_SQRT_2PI
    return out


# --------------------------------------------------------------------------- filters


def histogram_update(belief: np.ndarray, transition: np.ndarray, loglik: np.ndarray) -> np.ndarray:
    """One exact Bayes step: predict ``b @ T``, multiply by ``exp(loglik)`` (log-sum-exp), normalise."""
    predicted = belief @ transition
    with np.errstate(divide="ignore"):
        log_post = np.log(predicted) + loglik
    log_post -= log_post.max()
    post = np.exp(log_post)
    return post / post.sum()


class HistogramFilter:
    """Exact (histogram) Bayes filter over the ``S`` states; the belief starts uniform."""

    def __init__(self, transition: np.ndarray):
        self.transition = np.asarray(transition, dtype=np.float64)
        s = self.transition.shape[0]
        self.belief = np.full(s, 1.0 / s)

    def step(self, loglik: np.ndarray) -> np.ndarray:
        """Predict and update with one frame's log-likelihood ``(S,)``; return the belief ``(S,)``."""
        self.belief = histogram_update(self.belief, self.transition, loglik)
        return self.belief


class ParticleFilter:
    """Particle filter over the ``S`` states with the defensive free-state proposal.

    ``particles`` particles, particle ``p`` starting in state ``p % S``; random numbers
    from ``numpy.random.default_rng(seed)``. Per frame:

    1. propagate: a particle in state ``s`` goes to the free state (the last) with
       ``q(s) = max(T(s, free), q_min)`` and otherwise to a voxel drawn from ``T(s, .)``
       restricted to the voxels (inverse CDF); its importance weight is ``T(s, free)/q(s)``
       or ``(1 - T(s, free))/(1 - q(s))``, the branch taken. ``q_min = free_proposal_min``
       (config ``filter.free_proposal_min``); ``q_min = 0`` is the paper's bootstrap filter;
    2. weight: ``w = ratio * exp(loglik[state] - max over particles of loglik[state])``;
    3. resample in proportion to ``w`` (``"systematic"``: one ``u0 ~ U[0, 1/N)`` and positions
       ``u0 + i/N``; ``"multinomial"``: ``N`` independent uniforms).

    The belief is the particle histogram. The draws differ from the Rust filter's (another
    generator), so the two agree in distribution, not bit for bit.
    """

    def __init__(
        self,
        transition: np.ndarray,
        particles: int,
        seed: int = 0,
        resampling: str = "systematic",
        free_proposal_min: float = 0.0,
    ):
        if resampling not in ("systematic", "multinomial"):
            raise ValueError(f"resampling must be 'systematic' or 'multinomial', got {resampling!r}")
        particles = int(particles)
        if particles < 1:
            raise ValueError(f"particles must be >= 1, got {particles}")
        q_min = float(free_proposal_min)
        if not 0.0 <= q_min < 1.0:
            raise ValueError(f"free_proposal_min must be in [0, 1), got {q_min}")
        transition = np.asarray(transition, dtype=np.float64)
        s = transition.shape[0]
        if s < 2 or transition.shape != (s, s):
            raise ValueError(f"transition must be a square matrix with >= 2 states, got shape {transition.shape}")
        self.num_states = s
        self.resampling = resampling
        self.free_proposal_min = q_min
        self.rng = np.random.default_rng(seed)
        self.states = np.arange(particles, dtype=np.int64) % s
        #: Importance weight ``T/q`` of each particle's last propagation (1 before the first).
        self.ratios = np.ones(particles)
        # The proposal of every source state: P(free) and the ratios of both branches.
        t_free = transition[:, -1]
        q = np.maximum(t_free, q_min)
        self._q_free = q
        with np.errstate(divide="ignore", invalid="ignore"):
            self._free_ratio = np.where(q > 0, t_free / q, 0.0)
            self._voxel_ratio = np.where(q < 1, (1.0 - t_free) / (1.0 - q), 0.0)
        # Inverse-CDF sampling of the voxel successors with one searchsorted: row r of the
        # cumulative table over the S - 1 voxels (normalised, i.e. T(r, .) restricted to the
        # voxels) is shifted by r, so the flattened table is non-decreasing and a particle in
        # state r with uniform u is found by searching for r + u.
        # (Resolution ~S * 2e-16 in probability, far below 1/N.)
        cum = np.cumsum(transition[:, :-1], axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            cum = np.minimum(cum / cum[:, -1:], 1.0)
        cum[:, -1] = 1.0
        self._cum_flat = (cum + np.arange(s)[:, None]).reshape(-1)

    @property
    def belief(self) -> np.ndarray:
        """Fraction of particles in each state, float64 ``(S,)``."""
        return np.bincount(self.states, minlength=self.num_states) / self.states.size

    def propagate(self) -> None:
        """Move every particle by one draw from the proposal and set its ``ratios`` entry."""
        s, n = self.num_states, self.states.size
        voxels = s - 1
        src = self.states
        branch = self.rng.random(n)
        u = self.rng.random(n)
        to_free = branch < self._q_free[src]
        idx = np.searchsorted(self._cum_flat, src + u, side="right")
        voxel = np.minimum(idx - src * voxels, voxels - 1)
        self.states = np.where(to_free, voxels, voxel)
        self.ratios = np.where(to_free, self._free_ratio[src], self._voxel_ratio[src])

    def step(self, loglik: np.ndarray) -> np.ndarray:
        """Propagate, weight by ``loglik`` ``(S,)``, resample; return the belief ``(S,)``."""
        self.propagate()
        n = self.states.size
        logw = np.asarray(loglik, dtype=np.float64)[self.states]
        w = self.ratios * np.exp(logw - logw.max())
        cw = np.cumsum(w)
        cw /= cw[-1]
        cw[-1] = 1.0
        if self.resampling == "systematic":
            positions = self.rng.random() / n + np.arange(n) / n
        else:
            positions = self.rng.random(n)
        picked = np.minimum(np.searchsorted(cw, positions, side="right"), n - 1)
        self.states = self.states[picked]
        self.ratios = np.ones(n)
        return self.belief


# --------------------------------------------------------------------------- APF


def _as_transform(body_from_camera) -> np.ndarray:
    m = DEFAULT_BODY_FROM_CAMERA if body_from_camera is None else np.asarray(body_from_camera, float)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise ValueError(f"body_from_camera must be a finite 4x4 matrix, got shape {m.shape}")
    return m


def voxel_points_body(cfg: dict, camera: dict, body_from_camera=None) -> np.ndarray:
    """The point of every voxel that repels, body frame, metres, ``(S - 1, 3)``: the centre
    (:func:`voxel_centers_body`) when ``apf.voxel_position`` is ``"centre"`` (or absent); with
    ``"near-corner"`` the block's top-left pixel ``(i k_w, j k_h)`` back-projected at the
    bin's near edge ``d_min + k k_d`` (the authors' code)."""
    position = cfg["apf"].get("voxel_position", "centre")
    if position == "centre":
        return voxel_centers_body(cfg, camera, body_from_camera)
    if position != "near-corner":
        raise ValueError(f"apf.voxel_position must be 'centre' or 'near-corner', got {position!r}")
    g = cfg["grid"]
    k_w, k_h = int(g["block_width_px"]), int(g["block_height_px"])
    d_min, k_d = float(g["depth_min_m"]), float(g["depth_bin_m"])
    fx, fy, cx, cy = (float(camera[key]) for key in ("fx", "fy", "cx", "cy"))
    m = _as_transform(body_from_camera)
    i, j, k = _voxel_ijk(*grid_shape(cfg, camera))
    z = d_min + k * k_d
    p_cam = np.stack([(i * k_w - cx) * z / fx, (j * k_h - cy) * z / fy, z], axis=1)
    return p_cam @ m[:3, :3].T + m[:3, 3]


def voxel_centers_body(cfg: dict, camera: dict, body_from_camera=None) -> np.ndarray:
    """Centre of every voxel in the body frame, metres, float64 ``(S - 1, 3)`` in state order.

    Centre pixel ``u_c = (i k_w + min((i+1) k_w, W) - 1) / 2`` (likewise ``v_c``), depth
    ``z_c = d_min + (k + 0.5) k_d``; pinhole back-projection ``p_cam = ((u_c - cx) z_c / fx,
    (v_c - cy) z_c / fy, z_c)``, then ``p_body = R p_cam + t``.
    """
    g = cfg["grid"]
    k_w, k_h = int(g["block_width_px"]), int(g["block_height_px"])
    d_min, k_d = float(g["depth_min_m"]), float(g["depth_bin_m"])
    w, h = _camera_size(camera)
    fx, fy, cx, cy = (float(camera[key]) for key in ("fx", "fy", "cx", "cy"))
    if not (fx > 0 and fy > 0):
        raise ValueError(f"camera fx, fy must be positive, got {fx}, {fy}")
    m = _as_transform(body_from_camera)
    n_w, n_h, n_d = grid_shape(cfg, camera)
    i, j, k = _voxel_ijk(n_w, n_h, n_d)
    u_c = (i * k_w + np.minimum((i + 1) * k_w, w) - 1) / 2.0
    v_c = (j * k_h + np.minimum((j + 1) * k_h, h) - 1) / 2.0
    z_c = d_min + (k + 0.5) * k_d
    p_cam = np.stack([(u_c - cx) * z_c / fx, (v_c - cy) * z_c / fy, z_c], axis=1)
    return p_cam @ m[:3, :3].T + m[:3, 3]


def repulsive_forces(cfg: dict, camera: dict, body_from_camera=None) -> np.ndarray:
    """Repulsive force of an obstacle in each state, body frame, float64 ``(S, 3)``.

    For a voxel's point ``x`` (:func:`voxel_points_body`; body frame, metres), ``d = |x|``,
    ``r = max(d, min_distance_m)``:
    ``F = eta (1/r - 1/rho_0) / r^2 * (-x / d)`` if ``r < rho_0`` (zero if ``d == 0``),
    else 0. The free state's row (last) is 0. The net repulsion is ``belief @ forces``.
    """
    a = cfg["apf"]
    rho_0, eta, r_min = float(a["rho_0_m"]), float(a["eta"]), float(a["min_distance_m"])
    x = voxel_points_body(cfg, camera, body_from_camera)
    d = np.linalg.norm(x, axis=1)
    r = np.maximum(d, r_min)
    active = (r < rho_0) & (d > 0)
    mag = np.zeros_like(d)
    mag[active] = eta * (1.0 / r[active] - 1.0 / rho_0) / r[active] ** 2 / d[active]
    forces = np.zeros((x.shape[0] + 1, 3))
    forces[:-1] = -x * mag[:, None]
    return forces


def command(goal_body, repulsive_body, cfg: dict) -> dict:
    """Velocity command from the goal and the net repulsion (both body frame).

    ``goal_body``: goal relative to the robot (m). Returns ``dict(v_x, v_y, v_z, yaw_rate,
    reached)`` in m/s and rad/s. Within ``success_radius_m`` of the goal: all zero and
    ``reached=True``. Attraction ``xi g`` (``|g| <= rho_r``) or ``rho_r xi g/|g|``; ``F =
    F_att + repulsive_body``, ``nu = F/|F|`` (zero command if ``|F| == 0``).
    Non-holonomic: ``alpha = atan2(nu_y, nu_x)``, ``yaw_rate = yaw_rate_max/pi * alpha``,
    ``v_x = max(0, v_x_max cos alpha)``, ``v_y = 0``, ``v_z = v_z_max nu_z``.
    Holonomic: ``(v_x_max nu_x, v_x_max nu_y, v_z_max nu_z)``, ``yaw_rate = 0``.
    """
    a = cfg["apf"]
    g = np.asarray(goal_body, dtype=np.float64).reshape(3)
    rep = np.asarray(repulsive_body, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(g)) and np.all(np.isfinite(rep))):
        raise ValueError("goal_body and repulsive_body must be finite 3-vectors")
    zero = {"v_x": 0.0, "v_y": 0.0, "v_z": 0.0, "yaw_rate": 0.0, "reached": False}
    g_norm = float(np.linalg.norm(g))
    if g_norm < float(a["success_radius_m"]):
        return dict(zero, reached=True)
    xi, rho_r = float(a["xi"]), float(a["rho_r_m"])
    f_att = xi * g if g_norm <= rho_r else rho_r * xi * g / g_norm
    f = f_att + rep
    f_norm = float(np.linalg.norm(f))
    if f_norm == 0.0:
        return zero
    nu = f / f_norm
    v_x_max, v_z_max = float(a["v_x_max_m_s"]), float(a["v_z_max_m_s"])
    mode = a["mode"]
    if mode == "nonholonomic":
        alpha = math.atan2(nu[1], nu[0])
        return {
            "v_x": max(0.0, v_x_max * math.cos(alpha)),
            "v_y": 0.0,
            "v_z": v_z_max * float(nu[2]),
            "yaw_rate": float(a["yaw_rate_max_rad_s"]) / math.pi * alpha,
            "reached": False,
        }
    if mode == "holonomic":
        return {
            "v_x": v_x_max * float(nu[0]),
            "v_y": v_x_max * float(nu[1]),
            "v_z": v_z_max * float(nu[2]),
            "yaw_rate": 0.0,
            "reached": False,
        }
    raise ValueError(f"apf.mode must be 'nonholonomic' or 'holonomic', got {mode!r}")


# --------------------------------------------------------------------------- pipeline


class ReferencePipeline:
    """One camera's APF-PF: depth image -> counts -> filter -> net repulsion.

    The transition matrix, the per-state repulsive forces and the filter (``filter.mode``:
    ``"particle"`` or ``"histogram"``) are built once here. ``seed`` seeds the particle
    filter's ``numpy.random.default_rng``.
    """

    def __init__(self, camera: dict, cfg: dict, body_from_camera=None, seed: int = 0):
        self.camera = dict(camera)
        self.cfg = cfg
        self.body_from_camera = _as_transform(body_from_camera).copy()
        self.shape = grid_shape(cfg, camera)  # (n_w, n_h, n_d)
        self.transition = transition_matrix(cfg, camera)
        self.forces = repulsive_forces(cfg, camera, self.body_from_camera)
        self.centres_camera = voxel_centers_body(cfg, camera, np.eye(4))  # (S - 1, 3), optical frame
        self.centres_body = voxel_centers_body(cfg, camera, self.body_from_camera)
        f = cfg["filter"]
        mode = f["mode"]
        if mode == "histogram":
            self.filter = HistogramFilter(self.transition)
        elif mode == "particle":
            self.filter = ParticleFilter(
                self.transition,
                f["particles"],
                seed,
                f.get("resampling", "systematic"),
                f.get("free_proposal_min", 0.0),
            )
        else:
            raise ValueError(f"filter.mode must be 'particle' or 'histogram', got {mode!r}")

    @property
    def num_states(self) -> int:
        return self.transition.shape[0]

    def update(self, depth: np.ndarray, scale: float = 0.001) -> dict:
        """Process one depth frame (uint16 with ``scale`` m/unit, or float32 metres).

        Returns a dict: ``counts`` (int64 ``(n_h, n_w, n_d)``), ``belief`` (``(S,)``),
        ``p_free`` (belief of the free state), ``most_probable`` (the most probable *voxel*,
        the free state excluded, as in Rust: ``None`` if no voxel has belief > 0, else a dict
        with ``state`` (id, lowest on ties), ``voxel`` ``(i, j, k)``, ``probability``,
        ``depth_m`` (depth of its centre along the optical axis, m), ``centre_camera`` and
        ``centre_body`` (m)), ``closest_depth_m`` (m, or ``None``) and ``repulsive_body``
        (``(3,)``, belief-weighted repulsive force in the body frame).
        """
        counts = voxel_counts(depth, scale, self.cfg, self.camera)
        belief = self.filter.step(log_likelihood(counts, self.cfg, self.camera))
        voxel_belief = belief[:-1]
        best = int(np.argmax(voxel_belief))
        most_probable = None
        if voxel_belief[best] > 0:
            i, j, k = voxel_of_state(best, self.cfg, self.camera)
            most_probable = {
                "state": best,
                "voxel": (i, j, k),
                "probability": float(voxel_belief[best]),
                "depth_m": float(self.centres_camera[best, 2]),
                "centre_camera": self.centres_camera[best].copy(),
                "centre_body": self.centres_body[best].copy(),
            }
        return {
            "counts": counts,
            "belief": belief,
            "p_free": float(belief[-1]),
            "most_probable": most_probable,
            "closest_depth_m": closest_depth(depth, scale),
            "repulsive_body": belief @ self.forces,
        }

    def command(self, goal_body, outputs) -> dict:
        """Command from the goal and the summed ``repulsive_body`` of one or more outputs.

        ``outputs``: one :meth:`update` dict or a sequence of them (one per camera, each
        camera with its own pipeline); forces add in the body frame.
        """
        if isinstance(outputs, dict):
            outputs = [outputs]
        rep = np.zeros(3)
        for out in outputs:
            rep = rep + np.asarray(out["repulsive_body"], dtype=np.float64)
        return command(goal_body, rep, self.cfg)
