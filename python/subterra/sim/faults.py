"""Fault injection for closed-loop runs: sensors that drop, freeze, get noisy or go blind, and
odometry sources that drift, jump or fall silent. Seeded and composable.

A :class:`FaultInjector` sits between the simulator and the stack: each control tick it passes
the sensor frame through (or drops, repeats, blurs or blanks it) and gives the samples of the
vehicle's odometry sources (``vio``, ``lidar``, ``wheels``: three estimators with their own
noise), which a :class:`subterra.OdometryMux` turns into the pose the stack uses. Every fault
has a window in simulated time, drawn from the seed unless the config fixes it, and is logged
as two events (start and end).

Faults (``--faults NAME[,NAME...]`` on ``fly``, ``fly-batch``, ``drive``, ``drive-batch``;
``all`` is every one, and in a batch every job gets the next one in turn):

========================  =====================================================================
``frame-drop``            each sensor frame is lost with probability ``probability`` (0.5)
``frame-burst``           every sensor frame is lost (a driver restart)
``frozen``                the last frame before the window is delivered again and again
``noise-burst``           range noise of ``sigma_m`` (0.05 m) on every return, and
                          ``dropout`` (0.1) of the returns lost
``blinded``               no returns at all (a lens covered, a lidar in dense dust)
``odom-drift``            ``source`` (``vio``) drifts sideways at ``rate_m_s`` (0.15 m/s);
                          the error it built up stays after the window (fixed in the world)
``odom-jump``             ``source`` (``vio``) jumps ``distance_m`` (1.0 m) and ``yaw_deg`` (10°)
                          at the window's start and stays so
``odom-loss``             ``source`` (``vio``) gives no samples
``odom-loss-all``         no odometry source gives samples
========================  =====================================================================

Every fault takes ``start_s`` (default: drawn in ``[start_min_s, start_max_s]`` = [4, 12] s
from the seed) and ``duration_s`` (defaults per fault: 6 s for ``frame-drop`` and
``odom-drift``, 20 s for ``odom-jump``, 2 s for ``frame-burst`` and ``odom-loss-all``, 3 s
otherwise). In a TOML file they are a ``[faults.<name>]`` table each.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from subterra.errors import ConfigError, InputError

#: Every fault, in the order ``all`` runs them.
FAULT_NAMES: tuple[str, ...] = (
    "frame-drop", "frame-burst", "frozen", "noise-burst", "blinded",
    "odom-drift", "odom-jump", "odom-loss", "odom-loss-all",
)

#: The simulated vehicles' odometry sources, most trusted first.
ODOMETRY_SOURCES: tuple[str, ...] = ("vio", "lidar", "wheels")

_SENSOR_FAULTS = {"frame-drop", "frame-burst", "frozen", "noise-burst", "blinded"}

_DEFAULTS: dict[str, dict[str, Any]] = {
    "frame-drop": {"duration_s": 6.0, "probability": 0.5},
    "frame-burst": {"duration_s": 2.0},
    "frozen": {"duration_s": 3.0},
    "noise-burst": {"duration_s": 3.0, "sigma_m": 0.05, "dropout": 0.1},
    "blinded": {"duration_s": 3.0},
    "odom-drift": {"duration_s": 6.0, "rate_m_s": 0.15, "source": "vio"},
    "odom-jump": {"duration_s": 20.0, "distance_m": 1.0, "yaw_deg": 10.0, "source": "vio"},
    "odom-loss": {"duration_s": 3.0, "source": "vio"},
    "odom-loss-all": {"duration_s": 2.0},
}
_COMMON = {"start_s": None, "start_min_s": 4.0, "start_max_s": 12.0}

#: Noise of the simulated odometry sources other than the vehicle's own (vio): position and
#: yaw standard deviations per sample [m, rad], and the wheels' scale error.
_SOURCE_NOISE = {"lidar": (0.01, 0.002), "wheels": (0.005, 0.001)}
_WHEEL_SCALE = 1.01


def parse_faults(names: str | Iterable[str] | None) -> list[str]:
    """The fault names of ``--faults``: a comma-separated string or a sequence; ``all`` is every
    one; None or empty: none. Raises :class:`InputError` naming an unknown one."""
    if names is None:
        return []
    items = [n.strip() for n in names.split(",")] if isinstance(names, str) else [str(n).strip() for n in names]
    out: list[str] = []
    for n in items:
        if not n:
            continue
        if n == "all":
            out.extend(f for f in FAULT_NAMES if f not in out)
        elif n in FAULT_NAMES:
            if n not in out:
                out.append(n)
        else:
            raise InputError(f"argument `faults`: unknown fault {n!r}; known: all, {', '.join(FAULT_NAMES)}")
    return out


def load_faults_config(path: str | os.PathLike[str]) -> dict[str, dict[str, Any]]:
    """The ``[faults]`` table of a TOML file: ``{name: {field: value}}``. Raises
    :class:`~subterra.errors.FileFormatError` for a file that cannot be read or parsed and
    :class:`ConfigError` for a table that is not one."""
    from subterra._files import read_toml

    doc = read_toml(path, "faults config")
    table = doc.get("faults", {})
    if not isinstance(table, dict) or not all(isinstance(v, dict) for v in table.values()):
        raise ConfigError(f"config field `faults` must be a table of [faults.<name>] tables: {os.fspath(path)}")
    return table


def _number(name: str, key: str, value: Any, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not lo <= value <= hi:
        raise ConfigError(f"config field `faults.{name}.{key}` must be a number in [{lo}, {hi}], got {value!r}")
    return float(value)


@dataclass
class _Window:
    name: str
    start_s: float
    end_s: float
    params: dict[str, Any]
    started: bool = False
    ended: bool = False

    def active(self, t: float) -> bool:
        return self.start_s <= t < self.end_s


@dataclass
class FaultInjector:
    """Applies ``faults`` (names of :data:`FAULT_NAMES`) to one run, seeded by ``seed``;
    ``config``: ``{name: {field: value}}`` over the defaults (module docs)."""

    faults: Sequence[str]
    seed: int = 0
    config: Mapping[str, Mapping[str, Any]] | None = None
    windows: list[_Window] = field(init=False, default_factory=list)
    events: list[dict[str, Any]] = field(init=False, default_factory=list)

    def __post_init__(self) -> None:
        names = parse_faults(self.faults)
        config = dict(self.config or {})
        for key in config:
            if key not in FAULT_NAMES:
                raise ConfigError(f"config field `faults.{key}` is not a fault; known: {', '.join(FAULT_NAMES)}")
        rng = np.random.default_rng([int(self.seed), 0xFA17])
        for name in names:
            given = dict(config.get(name) or {})
            allowed = {**_COMMON, **_DEFAULTS[name]}
            for key in given:
                if key not in allowed:
                    raise ConfigError(f"config field `faults.{name}.{key}` is unknown; known: {', '.join(allowed)}")
            p = {**allowed, **given}
            lo = _number(name, "start_min_s", p["start_min_s"], 0.0, 1e6)
            hi = _number(name, "start_max_s", p["start_max_s"], lo, 1e6)
            start = rng.uniform(lo, hi) if p["start_s"] is None else _number(name, "start_s", p["start_s"], 0.0, 1e6)
            duration = _number(name, "duration_s", p["duration_s"], 0.0, 1e6)
            if "probability" in p:
                _number(name, "probability", p["probability"], 0.0, 1.0)
            for key, hi_v in (("sigma_m", 10.0), ("dropout", 1.0), ("rate_m_s", 100.0), ("distance_m", 1000.0), ("yaw_deg", 180.0)):
                if key in p:
                    _number(name, key, p[key], 0.0, hi_v)
            if "source" in p and p["source"] not in ODOMETRY_SOURCES:
                raise ConfigError(f"config field `faults.{name}.source` must be one of {', '.join(ODOMETRY_SOURCES)}, got {p['source']!r}")
            self.windows.append(_Window(name, float(start), float(start) + duration, p))
        self._rng = np.random.default_rng([int(self.seed), 0x5E45])
        self._last_frame: dict[str, Any] = {}
        self._frozen: dict[str, Any] = {}
        self._sources: dict[str, dict[str, Any]] = {}

    @property
    def names(self) -> list[str]:
        """The faults this injector applies."""
        return [w.name for w in self.windows]

    def _log(self, t: float) -> None:
        for w in self.windows:
            if not w.started and t >= w.start_s:
                w.started = True
                detail = ", ".join(f"{k} {v}" for k, v in w.params.items() if k not in _COMMON and k not in ("duration_s", "source"))
                reason = f"{w.name} until {w.end_s:.2f} s" + (f" ({detail})" if detail else "")
                self.events.append({"time_s": t, "event": "fault-start", "fault": w.name, "source": w.params.get("source"), "reason": reason})
            if w.started and not w.ended and t >= w.end_s:
                w.ended = True
                self.events.append({"time_s": t, "event": "fault-end", "fault": w.name, "source": w.params.get("source"), "reason": w.name})

    def _active(self, t: float, names: set[str]) -> list[_Window]:
        return [w for w in self.windows if w.name in names and w.active(t)]

    def sensor(self, t: float, name: str, frame: np.ndarray, *, no_return: float = 0.0) -> np.ndarray | None:
        """The frame of sensor ``name`` the stack gets at time ``t``: ``frame`` itself, None
        (lost), the frozen one, a noisy copy or a blank one (every value ``no_return``; for a
        point cloud, no points). Depth images are ``(H, W)``; point clouds ``(N, 3)``."""
        self._log(t)
        active = self._active(t, _SENSOR_FAULTS)
        out: np.ndarray | None = frame
        for w in active:
            if w.name == "frame-burst" or (w.name == "frame-drop" and self._rng.random() < w.params["probability"]):
                out = None
            elif w.name == "frozen":
                out = self._frozen.setdefault(name, self._last_frame.get(name, frame))
            elif w.name == "blinded" and out is not None:
                out = np.zeros((0, 3), out.dtype) if out.ndim == 2 and out.shape[1] == 3 else np.full_like(out, no_return)
            elif w.name == "noise-burst" and out is not None:
                out = self._noisy(out, w.params, no_return)
        if not any(w.name == "frozen" for w in active):
            self._frozen.pop(name, None)
            self._last_frame[name] = frame
        return out

    def _noisy(self, frame: np.ndarray, p: Mapping[str, Any], no_return: float) -> np.ndarray:
        sigma, dropout = float(p["sigma_m"]), float(p["dropout"])
        if frame.ndim == 2 and frame.shape[1] == 3:  # a point cloud: noise along each ray
            r = np.linalg.norm(frame, axis=1, keepdims=True)
            scale = 1.0 + self._rng.normal(0.0, sigma, size=r.shape) / np.maximum(r, 1e-6)
            keep = self._rng.random(len(frame)) >= dropout
            return (frame * scale)[keep].astype(frame.dtype)
        valid = frame != no_return
        if np.issubdtype(frame.dtype, np.integer):  # a uint16 depth image in millimetres
            noisy = frame.astype(np.float64) + self._rng.normal(0.0, sigma * 1000.0, size=frame.shape)
            noisy = np.clip(np.rint(noisy), 1, np.iinfo(frame.dtype).max).astype(frame.dtype)
        else:
            noisy = (frame + self._rng.normal(0.0, sigma, size=frame.shape)).astype(frame.dtype)
        noisy[~valid] = no_return
        noisy[self._rng.random(frame.shape) < dropout] = no_return
        return noisy

    def odometry(self, t: float, vehicle_odometry: np.ndarray, truth: np.ndarray) -> list[tuple[str, np.ndarray]]:
        """The odometry samples at time ``t``: ``(source, world_from_body)`` for every source
        that gives one. ``vio`` is the vehicle's own odometry (the simulator's, with its drift),
        chained from its increments (:meth:`_integrate`);
        ``lidar`` and ``wheels`` are estimators of the true pose with their own noise (the
        wheels' distance 1 % long), each in its own world frame (where it started)."""
        self._log(t)
        lost_all = bool(self._active(t, {"odom-loss-all"}))
        out: list[tuple[str, np.ndarray]] = []
        for name in ODOMETRY_SOURCES:
            state = self._sources.setdefault(name, {"origin": None, "last_truth": None, "pose": None, "drift": np.zeros(3), "drift_t": None, "jump": None})
            if name == "vio":
                pose = self._integrate(state, vehicle_odometry)
            else:
                pose = self._estimate(name, state, truth)
            # The drift builds up sideways (the body's y at each moment) as an offset in the
            # source's world frame, which stays when the window ends (the estimator's error
            # is not undone); a body-frame offset would swing with every turn.
            for w in self.windows:
                if w.name == "odom-drift" and w.params["source"] == name:
                    since = w.start_s if state["drift_t"] is None else max(w.start_s, state["drift_t"])
                    span = min(t, w.end_s) - since
                    if span > 0.0:
                        state["drift"] = state["drift"] + pose[:3, 1] * (w.params["rate_m_s"] * span)
            state["drift_t"] = t
            if np.any(state["drift"]):
                pose = pose.copy()
                pose[:3, 3] += state["drift"]
            for w in self.windows:
                if w.name == "odom-jump" and w.params["source"] == name and t >= w.start_s:
                    a = math.radians(w.params["yaw_deg"])
                    jump = np.eye(4)
                    jump[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
                    jump[:2, 3] = [w.params["distance_m"], 0.0]
                    pose = jump @ pose
            lost = lost_all or any(w.params["source"] == name for w in self._active(t, {"odom-loss"}))
            if not lost:
                out.append((name, pose))
        return out

    @staticmethod
    def _integrate(state: dict[str, Any], odometry: np.ndarray) -> np.ndarray:
        """The vehicle's odometry as a dead reckoning: its increments, each in the body frame,
        chained from its first pose. The simulator's odometry adds a heading bias that does
        not turn the position it reports; chained, the bias turns the motion that follows, as
        a real estimator's heading error does, so that the pose a switch re-anchors on holds
        the heading the source moves along."""
        odometry = np.asarray(odometry, dtype=np.float64)
        if state["pose"] is None:
            state["pose"] = odometry.copy()
        else:
            state["pose"] = state["pose"] @ (np.linalg.inv(state["last_truth"]) @ odometry)
        state["last_truth"] = odometry.copy()
        return state["pose"].copy()

    def _estimate(self, name: str, state: dict[str, Any], truth: np.ndarray) -> np.ndarray:
        """Dead reckoning of ``truth``'s increments with the source's noise (and the wheels'
        scale error), from the identity: each source's world frame is where it started."""
        truth = np.asarray(truth, dtype=np.float64)
        if state["pose"] is None:
            state["pose"] = np.eye(4)
            state["pose"][2, 3] = truth[2, 3]
            state["pose"][:3, :3] = truth[:3, :3]
        else:
            delta = np.linalg.inv(state["last_truth"]) @ truth
            sigma_p, sigma_yaw = _SOURCE_NOISE[name]
            moved = float(np.linalg.norm(delta[:2, 3]))
            if moved > 0.0 or abs(delta[1, 0]) > 0.0:
                if name == "wheels":
                    delta[:3, 3] *= _WHEEL_SCALE
                delta[:2, 3] += self._rng.normal(0.0, sigma_p * min(1.0, moved / 0.1 + 0.1), size=2)
                a = self._rng.normal(0.0, sigma_yaw)
                turn = np.eye(4)
                turn[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
                delta = delta @ turn
            state["pose"] = state["pose"] @ delta
        state["last_truth"] = truth.copy()
        return state["pose"].copy()
