"""The MPC tracker's optimal control problem without obstacles, solved plainly with SciPy.

The reference for parity tests and benchmarks of :class:`subterra.MpcTracker` (STEP, Fan et al. 2021;
the Rust module docs of ``crates/subterra/src/plan/mpc.rs`` state the problem exactly). It
imports NumPy, SciPy and the standard library only, so it loads without the compiled
``subterra._core``.

What is the same as the Rust tracker
------------------------------------
* **Model.** Unicycle ``[x, y, θ, v]``, input ``[a, ω]`` held over ``T = dt_s``, horizon
  ``N``. The step is exact: ``θ⁺ = θ + ωT``, ``v⁺ = v + aT`` and the position moves by
  ``∫₀ᵀ (v + a t)(cos, sin)(θ + ω t) dt``, integrated here by Gauss-Legendre quadrature
  with :data:`QUADRATURE_NODES` nodes (exact up to rounding for ``|ωT| <= π``: the error
  is below ``|ωT|^24 / 24! < 2e-12`` relative; at the default ``|ωT| <= 0.15`` it is far
  below ``1e-16``). This is a different formula from the Rust closed forms
  (``C0(h) = sin h / h``, ... and their power series), so the two also check each other.
* **Targets** from a trajectory ``x_0..x_N`` (step 2 of the Rust docs, no obstacles so no
  sideways offset): ``s0`` the arc length of the path point closest to ``x_0``; stage
  ``k = 1..N`` at ``s_k = clip(s0 + Σ_{j<k} ½(v_j + v_{j+1})T, 0, L)``, its point on the
  path, its tangent the chord over ``± tracking.tangent_half_window_m``, heading reference
  the tangent's angle unwrapped to within π of ``θ_k``, speed reference
  ``min(v_des, sqrt(2·end_decel·(L - s_k)))``. Speed bounds ``vhi_k = v_max·(1 - r_k)``,
  ``vlo_k = max(v_min, -vhi_k)`` with ``r_k`` the largest risk along ``x_{k-1} → x_k →
  x_{k+1}`` sampled every half cell (ends included; NaN or off the grid: ``unknown_risk``;
  no grid: 0), widened to what braking at ``a_max`` from ``v_0`` reaches:
  ``max(vhi_k, v0 - a_max·k·T + 1e-3)``, ``min(vlo_k, v0 + a_max·k·T - 1e-3)``.
* **Cost** ``Σ_k f_k [w_c (n_k·(p_k - r_k))² + w_l (t_k·(p_k - r_k))² + w_θ (θ_k - θr_k)²
  + w_v (v_k - vr_k)²] + Σ_k [w_a a_k² + w_ω ω_k² + w_Δa (a_k - a_{k-1})² + w_Δω (ω_k -
  ω_{k-1})²]`` with ``f_N = terminal_factor`` (else 1) and the ``k = 0`` rate term only when
  the previous solve's first input ``(a_{-1}, ω_{-1})`` is given.
* **Constraints** ``|a_k| <= a_max``, ``|ω_k| <= ω_max``, ``vlo'_k <= v_k <= vhi'_k``.

How it is solved (the straightforward way)
------------------------------------------
Single shooting over the ``2N`` inputs with ``scipy.optimize.minimize(method="SLSQP")``: the
input limits are its box bounds; ``v_k = v_0 + T·Σ_{j<k} a_j`` is linear in the inputs, so
the speed bounds are ``2N`` linear inequality constraints with a constant Jacobian; the cost
comes from the exact rollout, its gradient by the adjoint (reverse) pass over the step
Jacobians (the quadrature sums differentiated by hand; a test checks it against finite
differences). The targets and speed bounds depend on the trajectory (they are "fixed for the
iteration" in the Rust SQP): the reference holds them fixed, solves the NLP to tolerance,
recomputes them from the solution and repeats until the inputs stop changing (a fixed point
``u* = argmin J(u; targets(x(u*)))``). That fixed point is where the Rust SQP converges too
(each of its QPs is the Gauss-Newton model of the same cost with the same targets and
bounds, and a zero step is a KKT point of both). The Rust tracker runs at most
``solver.sqp_iterations`` (default 2) QPs per solve and stops at ``solver.step_tolerance``;
it meets the fixed point only to that truncation (measured in ``subterra bench plan``).

The speed bounds make the fixed point fragile: the largest risk around ``p_k`` jumps when
``p_k`` crosses a cell edge, so near the edge of a risk band the passes can cycle (slower,
the stage stays outside the band and gets the high bound; faster, it enters and gets the
low one) and no fixed point exists. From pass :data:`MONOTONE_AFTER` on, each stage keeps
the largest risk any pass gave it, so the bounds only tighten, the passes end, and the
result is the optimum under those (slightly conservative) bounds; ``bounds_held`` says
when that happened. The Rust tracker resolves the same ambiguity differently (its line
search refuses a step that raises the speed excess), so in those states the two may
differ by more than at a true fixed point.

Not modelled: lethal cells (obstacle polygons, obstacle rows, reference offsets, slacks,
the safety check and backup stop). A risk grid with a cell at or above
``risk.lethal_risk`` is refused.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from subterra._compat import tomllib

__all__ = [
    "DEFAULT_CONFIG_PATH",
    "QUADRATURE_NODES",
    "MpcProblem",
    "ReferenceMpcResult",
    "default_config",
    "rollout",
    "solve",
    "step",
]

#: ``configs/mpc.toml`` of the source tree (the Rust defaults, field by field).
DEFAULT_CONFIG_PATH = Path(__file__).resolve().parents[4] / "configs" / "mpc.toml"
#: Gauss-Legendre nodes of the step integral (module notes).
QUADRATURE_NODES = 12
#: The braking envelope of the speed bounds is widened by this [m/s] (Rust ``ENVELOPE_SLACK_M_S``).
ENVELOPE_SLACK_M_S = 1e-3
#: The fixed point is reached when no input moves by more than this between outer passes [m/s², rad/s].
FIXED_POINT_TOL = 1e-6
#: Outer passes (targets recomputed, NLP re-solved) at most.
MAX_OUTER_ITERATIONS = 40
#: From this pass on each stage's risk is the largest any pass saw (module notes).
MONOTONE_AFTER = 12
#: SLSQP's tolerance on the cost change and its iteration cap.
SLSQP_FTOL = 1e-13
SLSQP_MAX_ITERATIONS = 500
#: SLSQP's exit status "positive directional derivative for linesearch".
SLSQP_NO_DESCENT = 8
#: How far a speed row may be violated at a status-8 fixed point that counts as converged [m/s].
SLSQP_FEASIBILITY_TOL = 1e-7

_TAU, _W = np.polynomial.legendre.leggauss(QUADRATURE_NODES)
#: Nodes on [0, 1] and weights summing to 1.
_TAU = 0.5 * (_TAU + 1.0)
_W = 0.5 * _W


def default_config() -> dict[str, Any]:
    """The committed ``configs/mpc.toml`` as a nested dict (the Rust ``MpcConfig::default()``)."""
    with DEFAULT_CONFIG_PATH.open("rb") as f:
        return tomllib.load(f)


def step(state: np.ndarray, accel: float, yaw_rate: float, dt: float, jacobians: bool = False):
    """One exact step of the unicycle (module notes). With ``jacobians``, also ``A = ∂x⁺/∂x``
    (4x4) and ``B = ∂x⁺/∂[a, ω]`` (4x2)."""
    x, y, th, v = state
    phi = th + yaw_rate * dt * _TAU
    speed = v + accel * dt * _TAU
    cos, sin = np.cos(phi), np.sin(phi)
    dx = dt * float(_W @ (speed * cos))
    dy = dt * float(_W @ (speed * sin))
    nxt = np.array([x + dx, y + dy, th + yaw_rate * dt, v + accel * dt])
    if not jacobians:
        return nxt
    a = np.eye(4)
    a[0, 2], a[1, 2] = -dy, dx
    a[0, 3], a[1, 3] = dt * float(_W @ cos), dt * float(_W @ sin)
    b = np.zeros((4, 2))
    wt = _W * _TAU
    b[0, 0], b[1, 0] = dt * dt * float(wt @ cos), dt * dt * float(wt @ sin)
    b[0, 1], b[1, 1] = -dt * dt * float(wt @ (speed * sin)), dt * dt * float(wt @ (speed * cos))
    b[2, 1], b[3, 0] = dt, dt
    return nxt, a, b


def arc_step(state: np.ndarray, command: tuple[float, float], dt: float) -> np.ndarray:
    """The robot the closed-loop checks drive: state ``[x, y, θ, v]``, the command's speed
    ``v`` and yaw rate ``ω`` held for ``dt`` (an exact arc); returns the new state."""
    x, y, th, _ = state
    v, w = command
    if abs(w) > 1e-9:
        x += v / w * (np.sin(th + w * dt) - np.sin(th))
        y += v / w * (np.cos(th) - np.cos(th + w * dt))
    else:
        x += v * dt * np.cos(th)
        y += v * dt * np.sin(th)
    return np.array([x, y, th + w * dt, v])


def rollout(state: np.ndarray, inputs: np.ndarray, dt: float) -> np.ndarray:
    """States ``x_0..x_N`` ``(N+1, 4)`` of ``inputs`` ``(N, 2)`` from ``state``."""
    xs = [np.asarray(state, dtype=np.float64)]
    for a, w in inputs:
        xs.append(step(xs[-1], a, w, dt))
    return np.array(xs)


class _Path:
    """A polyline by arc length, as the Rust ``Reference`` (repeated points dropped)."""

    def __init__(self, points: np.ndarray) -> None:
        keep = np.ones(len(points), dtype=bool)
        keep[1:] = np.any(points[1:] != points[:-1], axis=1)
        self.points = points[keep]
        if len(self.points) < 2:
            raise ValueError("reference_path has zero length (all points are the same)")
        self.s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(self.points, axis=0).T))])
        self.length = float(self.s[-1])

    def project(self, p: np.ndarray) -> float:
        """Arc length of the closest path point (the first along the path on a tie)."""
        a, b = self.points[:-1], self.points[1:]
        e = b - a
        t = np.clip(np.einsum("ij,ij->i", p - a, e) / np.einsum("ij,ij->i", e, e), 0.0, 1.0)
        d2 = np.sum((a + t[:, None] * e - p) ** 2, axis=1)
        i = int(np.argmin(d2))
        return float(self.s[i] + t[i] * (self.s[i + 1] - self.s[i]))

    def at(self, s: float) -> tuple[np.ndarray, np.ndarray]:
        """Point at arc length ``s`` (clamped) and its segment's unit tangent."""
        i = min(max(int(np.searchsorted(self.s, s, side="right")) - 1, 0), len(self.points) - 2)
        a, b = self.points[i], self.points[i + 1]
        seg = self.s[i + 1] - self.s[i]
        t = min(max((s - self.s[i]) / seg, 0.0), 1.0)
        return a + t * (b - a), (b - a) / seg

    def at_smoothed(self, s: float, half_window: float) -> tuple[np.ndarray, np.ndarray]:
        """Point at ``s`` with the chord over ``± half_window`` as tangent (the segment's when
        the chord is shorter than half the window, or without a window)."""
        point, tangent = self.at(s)
        if half_window <= 0.0:
            return point, tangent
        chord = self.at(s + half_window)[0] - self.at(s - half_window)[0]
        length = math.hypot(*chord)
        return point, (chord / length if length > 0.5 * half_window else tangent)


@dataclass
class _Grid:
    risk: np.ndarray  # (ny, nx) float64 of the float32 values (as Rust reads them)
    resolution: float
    origin: np.ndarray

    def risk_at(self, p: np.ndarray, unknown: float) -> float:
        ix, iy = math.floor((p[0] - self.origin[0]) / self.resolution), math.floor((p[1] - self.origin[1]) / self.resolution)
        ny, nx = self.risk.shape
        if ix < 0 or iy < 0 or ix >= nx or iy >= ny:
            return unknown
        r = self.risk[iy, ix]
        return unknown if math.isnan(r) else float(r)


@dataclass
class MpcProblem:
    """The optimal control problem of one solve with its targets held fixed: everything the
    cost and constraints need. Built by ``_problem`` from a trajectory; :func:`solve` holds one fixed per pass."""

    state: np.ndarray
    dt: float
    points: np.ndarray  # (N, 2) reference points r_1..r_N
    tangents: np.ndarray  # (N, 2)
    headings: np.ndarray  # (N,)
    speeds: np.ndarray  # (N,)
    factors: np.ndarray  # (N,)
    speed_hi: np.ndarray  # (N,) widened bounds
    speed_lo: np.ndarray  # (N,)
    weights: dict[str, float]
    previous_input: np.ndarray | None

    def cost(self, u_flat: np.ndarray, gradient: bool = True):
        """Cost of the inputs ``(2N,)`` (``[a_0, ω_0, a_1, ...]``) on their exact rollout, and
        its gradient (adjoint pass)."""
        w = self.weights
        u = u_flat.reshape(-1, 2)
        n = len(u)
        xs, jac = [self.state], []
        for k in range(n):
            nxt, a, b = step(xs[-1], u[k, 0], u[k, 1], self.dt, jacobians=True)
            xs.append(nxt)
            jac.append((a, b))
        x = np.array(xs[1:])
        e = x[:, :2] - self.points
        normals = np.stack([-self.tangents[:, 1], self.tangents[:, 0]], axis=1)
        ec = np.einsum("ij,ij->i", normals, e)
        el = np.einsum("ij,ij->i", self.tangents, e)
        eh = x[:, 2] - self.headings
        ev = x[:, 3] - self.speeds
        f = self.factors
        cost = float(np.sum(f * (w["contour"] * ec**2 + w["lag"] * el**2 + w["heading"] * eh**2 + w["speed"] * ev**2)))
        effort = np.array([w["accel"], w["yaw_rate"]])
        rate = np.array([w["accel_rate"], w["yaw_rate_rate"]])
        cost += float(np.sum(effort * u**2))
        before = u[:-1] if self.previous_input is None else np.vstack([self.previous_input, u[:-1]])
        du = u[1:] - before if self.previous_input is None else u - before
        cost += float(np.sum(rate * du**2))
        if not gradient:
            return cost
        # ∂J/∂x_k of the tracking terms, then back through the dynamics.
        gx = np.zeros((n, 4))
        gx[:, :2] = 2.0 * f[:, None] * (w["contour"] * ec[:, None] * normals + w["lag"] * el[:, None] * self.tangents)
        gx[:, 2] = 2.0 * f * w["heading"] * eh
        gx[:, 3] = 2.0 * f * w["speed"] * ev
        gu = 2.0 * effort * u
        if self.previous_input is None:
            gu[1:] += 2.0 * rate * du
            gu[:-1] -= 2.0 * rate * du
        else:
            gu += 2.0 * rate * du
            gu[:-1] -= 2.0 * rate * du[1:]
        lam = np.zeros(4)  # ∂J/∂x_{k+1} through everything after it
        for k in range(n - 1, -1, -1):
            lam = lam + gx[k]
            a, b = jac[k]
            gu[k] += b.T @ lam
            lam = a.T @ lam
        return cost, gu.reshape(-1)


@dataclass
class ReferenceMpcResult:
    """What :func:`solve` gives, named as :class:`subterra.MpcOutput` where they match."""

    command: tuple[float, float]
    predicted: np.ndarray  # (N+1, 4)
    inputs: np.ndarray  # (N, 2)
    reference_points: np.ndarray  # (N, 2)
    speed_limits: np.ndarray  # (N,) vhi_k at the predicted states (not widened)
    cost: float
    outer_iterations: int
    slsqp_iterations: int
    converged: bool
    bounds_held: bool  # the passes cycled and the risks were held monotone (module notes)
    solve_time_s: float
    problem: MpcProblem = field(repr=False)


def _merge(base: dict[str, Any], over: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in base.items()}
    for key, value in over.items():
        name = f"{prefix}{key}"
        if key not in out:
            raise ValueError(f"config: unknown key `{name}`")
        if isinstance(out[key], dict):
            if not isinstance(value, dict):
                raise ValueError(f"config: `{name}` must be a table, got {value!r}")
            out[key] = _merge(out[key], value, f"{name}.")
        else:
            out[key] = value
    return out


def _finite(name: str, value: Any, shape: tuple[int, ...] | None = None) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be real numbers, got {value!r}") from e
    if shape is not None and arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


def _stage_risk(c: dict[str, Any], x: np.ndarray, k: int, grid: _Grid | None) -> float:
    """The largest risk along ``x[k-1] → x[k] → x[k+1]`` (module notes)."""
    r = 0.0
    if grid is not None:
        unknown = float(c["risk"]["unknown_risk"])
        spacing = 0.5 * grid.resolution
        r = grid.risk_at(x[k, :2], unknown)
        for a, b in ((k - 1, k), (k, k + 1)):
            if b >= len(x):
                continue
            pa, pb = x[a, :2], x[b, :2]
            samples = max(int(min(math.ceil(math.hypot(*(pb - pa)) / spacing), 1e4)), 1)
            for i in range(samples + 1):
                r = max(r, grid.risk_at(pa + (pb - pa) * (i / samples), unknown))
    return r


def _problem(c: dict[str, Any], path: _Path, s0: float, desired: float, x: np.ndarray, grid: _Grid | None,
             previous_input: np.ndarray | None, risk_floor: np.ndarray | None = None) -> tuple[MpcProblem, np.ndarray]:
    """The targets and bounds of the trajectory ``x`` (module notes), and the stage risks
    ``r_k`` they were made with (each at least ``risk_floor[k-1]`` when given)."""
    n, dt = len(x) - 1, float(c["dt_s"])
    t, lim = c["tracking"], c["limits"]
    points, tangents, headings, speeds, hi, lo, risks = (np.zeros((n, 2)), np.zeros((n, 2)), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n))
    travel = 0.0
    v0 = x[0, 3]
    for k in range(1, n + 1):
        travel += 0.5 * (x[k - 1, 3] + x[k, 3]) * dt
        s = min(max(s0 + travel, 0.0), path.length)
        point, tangent = path.at_smoothed(s, t["tangent_half_window_m"])
        heading = math.atan2(tangent[1], tangent[0])
        turns = (x[k, 2] - heading) / (2.0 * math.pi)
        heading += math.copysign(math.floor(abs(turns) + 0.5), turns) * 2.0 * math.pi  # Rust f64::round
        r = _stage_risk(c, x, k, grid)
        if risk_floor is not None:
            r = max(r, float(risk_floor[k - 1]))
        vhi = lim["max_speed_m_s"] * (1.0 - r)
        vlo = max(lim["min_speed_m_s"], -vhi)
        change = lim["max_accel_m_s2"] * dt * k
        points[k - 1], tangents[k - 1], headings[k - 1] = point, tangent, heading
        speeds[k - 1] = min(desired, math.sqrt(2.0 * t["end_decel_m_s2"] * (path.length - s)))
        risks[k - 1] = r
        hi[k - 1] = max(vhi, v0 - change + ENVELOPE_SLACK_M_S)
        lo[k - 1] = min(vlo, v0 + change - ENVELOPE_SLACK_M_S)
    factors = np.ones(n)
    factors[-1] = c["weights"]["terminal_factor"]
    problem = MpcProblem(x[0].copy(), dt, points, tangents, headings, speeds, factors, hi, lo,
                         {k: float(v) for k, v in c["weights"].items()}, previous_input)
    return problem, risks


def solve(state, reference_path, *, risk=None, resolution: float | None = None, origin=None, desired_speed: float | None = None,
          previous_input=None, initial_inputs=None, config: dict[str, Any] | None = None) -> ReferenceMpcResult:
    """The obstacle-free MPC problem of ``MpcTracker.solve`` at ``state`` (module notes),
    solved to its fixed point with SLSQP.

    ``state`` ``[x, y, θ, v]``; ``reference_path`` ``(M, 2)`` world points (``M >= 2``,
    positive length); ``risk`` ``(ny, nx)`` in [0, 1] or NaN (row ``iy`` along world y) with
    ``resolution`` [m] and ``origin`` (world x, y of cell (0, 0)'s lower-left corner); no cell
    may be lethal (``>= risk.lethal_risk``): obstacles are not modelled. ``desired_speed``
    in ``[0, v_max]`` (None: the config's). ``previous_input`` ``[a, ω]``: the previous
    solve's first input (``MpcTracker``'s last ``inputs[0]``), which adds the ``k = 0``
    input-rate term; None on a first solve. ``initial_inputs`` ``(N, 2)``: where the first
    pass starts (default zeros; only the speed of convergence depends on it when the fixed
    point is unique). ``config``: a partial nested dict over ``configs/mpc.toml``.
    Raises ``ValueError`` naming the argument."""
    t0 = time.perf_counter()
    from scipy.optimize import minimize

    if config is not None and not isinstance(config, dict):
        raise ValueError(f"config must be a dict (partial, over configs/mpc.toml) or None, got {type(config).__name__}")
    c = _merge(default_config(), config or {})
    n, dt = int(c["horizon"]), float(c["dt_s"])
    lim = c["limits"]
    if n < 1 or not dt > 0.0:
        raise ValueError(f"config: horizon must be >= 1 and dt_s > 0, got {n} and {dt}")
    x0 = _finite("state", state, (4,))
    pts = _finite("reference_path", reference_path)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
        raise ValueError(f"reference_path must have shape (M, 2) with M >= 2, got {pts.shape}")
    path = _Path(pts)
    desired = float(c["tracking"]["desired_speed_m_s"] if desired_speed is None else desired_speed)
    if not (math.isfinite(desired) and 0.0 <= desired <= lim["max_speed_m_s"]):
        raise ValueError(f"desired_speed must be in [0, max_speed_m_s = {lim['max_speed_m_s']}] m/s, got {desired}")
    grid = None
    if risk is not None:
        if resolution is None or origin is None:
            raise ValueError("risk needs resolution and origin")
        r = np.asarray(risk)
        if r.ndim != 2 or r.size == 0:
            raise ValueError(f"risk must be a non-empty (ny, nx) array, got shape {r.shape}")
        r = r.astype(np.float32).astype(np.float64)  # the Rust tracker reads float32
        if np.any(~np.isnan(r) & ((r < 0.0) | (r > 1.0))):
            raise ValueError("risk values must be in [0, 1] or NaN (unknown)")
        if np.any(r >= c["risk"]["lethal_risk"]):
            iy, ix = np.argwhere(r >= c["risk"]["lethal_risk"])[0]
            raise ValueError(f"risk has lethal cells (>= risk.lethal_risk = {c['risk']['lethal_risk']}, first at iy={iy}, ix={ix}): "
                             "the reference models no obstacles")
        res = float(_finite("resolution", resolution, ()))
        if res <= 0.0:
            raise ValueError(f"resolution must be > 0 m, got {res}")
        grid = _Grid(r, res, _finite("origin", origin, (2,)))
    elif resolution is not None or origin is not None:
        raise ValueError("resolution and origin need risk")
    prev = None if previous_input is None else _finite("previous_input", previous_input, (2,))
    u = np.zeros((n, 2)) if initial_inputs is None else _finite("initial_inputs", initial_inputs, (n, 2)).copy()
    bounds_u = np.array([lim["max_accel_m_s2"], lim["max_yaw_rate_rad_s"]])
    u = np.clip(u, -bounds_u, bounds_u)

    # v_k = v0 + T Σ_{j<k} a_j: the speeds are S @ u_flat + v0.
    speed_rows = np.zeros((n, 2 * n))
    for k in range(1, n + 1):
        speed_rows[k - 1, 0 : 2 * k : 2] = dt
    s0 = path.project(x0[:2])
    box = [(-bounds_u[0], bounds_u[0]), (-bounds_u[1], bounds_u[1])] * n
    slsqp_iterations, converged, outer = 0, False, 0
    floor = None
    for outer in range(1, MAX_OUTER_ITERATIONS + 1):
        problem, risks = _problem(c, path, s0, desired, rollout(x0, u, dt), grid, prev, floor)
        if outer >= MONOTONE_AFTER:
            floor = risks
        constraints = [
            {"type": "ineq", "fun": lambda z, p=problem: p.speed_hi - x0[3] - speed_rows @ z, "jac": lambda z: -speed_rows},
            {"type": "ineq", "fun": lambda z, p=problem: x0[3] + speed_rows @ z - p.speed_lo, "jac": lambda z: speed_rows},
        ]
        out = minimize(problem.cost, u.reshape(-1), jac=True, method="SLSQP", bounds=box, constraints=constraints,
                       options={"ftol": SLSQP_FTOL, "maxiter": SLSQP_MAX_ITERATIONS})
        slsqp_iterations += int(out.nit)
        new = np.clip(out.x.reshape(n, 2), -bounds_u, bounds_u)
        change = float(np.max(np.abs(new - u)))
        u = new
        if change <= FIXED_POINT_TOL:
            # At the fixed point SciPy 1.17's SLSQP may end with status 8 ("positive
            # directional derivative for linesearch"): with ftol 1e-13 no descent is left
            # at machine precision. The pass did not move the inputs either: converged, if
            # the speed rows hold there (status 8 also comes from an infeasible start).
            feasible = all(float(np.min(g["fun"](u.reshape(-1)))) >= -SLSQP_FEASIBILITY_TOL for g in constraints)
            converged = bool(out.success) or (out.status == SLSQP_NO_DESCENT and feasible)
            break
    x = rollout(x0, u, dt)
    problem, _ = _problem(c, path, s0, desired, x, grid, prev, floor)
    _, risks = _problem(c, path, s0, desired, x, grid, prev)
    return ReferenceMpcResult(
        command=(float(x[1, 3]), float(u[0, 1])),
        predicted=x,
        inputs=u,
        reference_points=problem.points,
        speed_limits=c["limits"]["max_speed_m_s"] * (1.0 - risks),
        cost=float(problem.cost(u.reshape(-1), gradient=False)),
        outer_iterations=outer,
        slsqp_iterations=slsqp_iterations,
        converged=converged,
        bounds_held=bool(floor is not None and np.any(floor > risks)),
        solve_time_s=time.perf_counter() - t0,
        problem=problem,
    )
