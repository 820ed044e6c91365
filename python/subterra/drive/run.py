"""One closed-loop drive: simulated lidar -> terrain mapper -> risk-aware A* -> MPC -> ground
robot, with the recovery behaviours when stuck.

The loop, per control step (``rate_hz``, default 10 Hz, one lidar scan per step): the
simulator ray-casts the lidar at the true pose (with the chosen noise); the
:class:`subterra.Navigator` (Rust) updates its risk map from the scan at the odometry pose,
replans when due, solves the MPC and answers with a command ``(v, ω)`` and its behaviour;
the robot drives one step on the simulator's terrain, which settles it and fails it on a
collision, a rollover or a fall. The run ends at the goal, on a failure, at the time
limit, or when the navigator gives up (``gave_up``), has returned home
(``returned_home``) or stops at the goal by its pose while in truth it is not there
(``odometry_error``, after an odometry fault).

>>> from subterra.drive import drive
>>> result = drive("mine", seed=0)
>>> result.metrics["success"], result.metrics["failure"]
>>> result.save("runs/drive-mine")          # CSV, JSON, events and plots
"""

from __future__ import annotations

import csv
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from subterra._core import OdometryMux
from subterra.errors import InputError
from subterra.sim import LIDAR_NOISE_PRESETS, Lidar, Simulation, World
from subterra.sim.faults import ODOMETRY_SOURCES, FaultInjector, parse_faults
from subterra.sim.outputs import plain, write_run_outputs
from subterra.watchdog import SensorWatchdog

__all__ = ["GROUND_SCENARIOS", "PLANNERS", "DriveResult", "drive", "true_risk", "true_terrain_risk"]

#: The built-in ground scenarios of the simulator (seeded generators): the mine, the three
#: worlds with a trade-off between a short risky route and a longer safe one, and the cave.
GROUND_SCENARIOS = ("mine", "slopes", "rough", "ledge", "cave")
#: Planners a drive can use: the risk-aware A* of STEP, and the baseline with a
#: conventional additive cost (Nav2-style ``d·(1 + k·r)`` over the same risk map, cells at
#: or above ``R_inst`` blocked).
PLANNERS = ("risk-aware", "additive")
#: Lidar mounting height above the body origin (on the ground) [m].
LIDAR_HEIGHT_M = 0.7
#: ``ground.void_min_gap_deg`` of the drive's terrain mapper: void (bottomless hole)
#: detection on, above the ring spacing of both simulated lidars (VLP-16 2.0°, OS1-64
#: 0.53°) [deg]. A gap of under 2 OS1-64 rings was found to flag the shadow of walls and of
#: single dropped returns as holes: a whole empty stretch of several rings is needed.
#: docs/terrain.md.
LIDAR_VOID_MIN_GAP_DEG = 2.5
#: Per-step arrays of a drive, in CSV column order (see :class:`DriveResult`).
STEP_FIELDS = (
    "time_s", "position", "yaw", "roll", "pitch", "speed_m_s", "command", "behaviour", "target", "plan_status",
    "mpc_status", "local_risk", "speed_limit_m_s", "true_risk", "clearance_m", "map_ms", "plan_ms", "track_ms",
    "total_ms",
)


def true_risk(tilt_rad: np.ndarray | float, *, safe_deg: float, lethal_deg: float) -> np.ndarray:
    """The tilt risk the robot actually ran at (angle of its settled z axis from vertical):
    the robot's tilt ramp, ``clamp((tilt - safe) / (lethal - safe), 0, 1)``."""
    t = np.degrees(np.asarray(tilt_rad, dtype=np.float64))
    return np.clip((t - safe_deg) / (lethal_deg - safe_deg), 0.0, 1.0)


def _ramp(value: float, ramp: dict[str, float]) -> float:
    if not math.isfinite(value):
        return 1.0
    return min(max((value - ramp["safe"]) / (ramp["lethal"] - ramp["safe"]), 0.0), 1.0)


def true_terrain_risk(world: World, position: np.ndarray, yaw: float, robot: dict[str, float], risk: dict[str, Any],
                      resolution_m: float = 0.1) -> float:
    """The step and roughness risk of the true ground under the robot's footprint, with the
    mapper's own ramps (``risk["step_m"]``, ``risk["roughness_m"]``): the world's height field
    sampled every ``resolution_m`` over the footprint (``robot["length_m"] x
    robot["width_m"]`` at ``position``, heading ``yaw``); ``step`` the largest height
    difference between neighbouring samples, ``roughness`` the RMS residual of the
    least-squares plane through them. ``1 - (1 - step)(1 - roughness)``; 1 where a sample is
    missing ground (a hole under the footprint)."""
    hl, hw = 0.5 * float(robot["length_m"]), 0.5 * float(robot["width_m"])
    us = np.arange(-hl, hl + 1e-9, resolution_m)
    vs = np.arange(-hw, hw + 1e-9, resolution_m)
    c, s = math.cos(yaw), math.sin(yaw)
    z = np.empty((len(vs), len(us)))
    for i, v in enumerate(vs):
        for j, u in enumerate(us):
            h = world.ground_height(float(position[0] + c * u - s * v), float(position[1] + s * u + c * v))
            z[i, j] = np.nan if h is None else h
    if not np.all(np.isfinite(z)):
        return 1.0
    step = max(float(np.abs(np.diff(z, axis=0)).max(initial=0.0)), float(np.abs(np.diff(z, axis=1)).max(initial=0.0)))
    uu, vv = np.meshgrid(us, vs)
    a = np.column_stack([uu.ravel(), vv.ravel(), np.ones(uu.size)])
    coef, *_ = np.linalg.lstsq(a, z.ravel(), rcond=None)
    rough = float(np.sqrt(np.mean((z.ravel() - a @ coef) ** 2)))
    return 1.0 - (1.0 - _ramp(step, risk["step_m"])) * (1.0 - _ramp(rough, risk["roughness_m"]))


@dataclass
class DriveResult:
    """Everything one drive recorded. ``steps`` holds one row per control step:

    ``time_s`` (S,), ``position`` (S, 3) true world position, ``yaw``, ``roll``, ``pitch``
    (S,) [rad] as settled on the terrain, ``speed_m_s`` (S,), ``command`` (S, 2) ``[v, ω]``,
    ``behaviour``, ``target``, ``plan_status``, ``mpc_status`` (S,) strings (empty when the
    stage did not run), ``local_risk`` (S,) the map's risk under the robot,
    ``speed_limit_m_s`` (S,) ``v_max·(1 - r)`` there, ``true_risk`` (S,) the risk the robot
    really ran: the tilt ramp of its settled pose (:func:`true_risk`) combined with the step
    and roughness of the true ground under its footprint (:func:`true_terrain_risk`),
    ``clearance_m`` (S,), and the navigator's wall time per
    stage ``map_ms``, ``plan_ms``, ``track_ms``, ``total_ms``. ``events`` lists the
    recovery machine's transitions (``time_s``, ``from``, ``to``, ``reason``, ``r_inst``,
    ``r_total``); ``path`` is (S + 1, 3).
    """

    scenario: str
    planner: str
    seed: int
    world: World
    start: np.ndarray
    goal: np.ndarray
    home: np.ndarray
    rate_hz: float
    steps: dict[str, np.ndarray]
    events: list[dict[str, Any]]
    metrics: dict[str, Any]
    path: np.ndarray
    last_plan: np.ndarray
    risk_map: Any = None
    wall_s: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def success(self) -> bool:
        return bool(self.metrics.get("success"))

    @property
    def failure(self) -> str | None:
        return self.metrics.get("failure")

    def summary(self) -> dict[str, Any]:
        """The metrics plus what was driven, as plain JSON-ready values."""
        total = self.steps["total_ms"]
        behaviours = sorted({e["to"] for e in self.events if e["from"] != e["to"]})
        return {
            "scenario": self.scenario,
            "planner": self.planner,
            "seed": self.seed,
            "rate_hz": self.rate_hz,
            "start": [float(v) for v in self.start],
            "goal": [float(v) for v in self.goal],
            "home": [float(v) for v in self.home],
            **{k: plain(v) for k, v in self.metrics.items()},
            "steps": int(total.size),
            "recoveries": sum(1 for e in self.events if e["to"] == "clear_map"),
            "behaviours_used": behaviours,
            "final_behaviour": str(self.steps["behaviour"][-1]) if total.size else None,
            "compute_ms_median": float(np.median(total)) if total.size else None,
            "compute_ms_p99": float(np.percentile(total, 99)) if total.size else None,
            **{f"{stage}_ms_median": float(np.median(self.steps[f"{stage}_ms"])) if total.size else None
               for stage in ("map", "plan", "track")},
            "wall_s": round(self.wall_s, 3),
        }

    def save(self, out_dir: str | os.PathLike[str], *, plots: bool = True) -> dict[str, Path]:
        """Writes the run folder: ``trajectory.csv`` (every step), ``events.csv`` (every
        behaviour transition with its reason), ``metrics.json`` and, with ``plots``,
        ``map.png`` (the last risk map with the planned and driven paths), ``speed-risk.png``
        (speed against the local risk and its limit over time, behaviours shaded) and
        ``compute-time.png`` (per stage). Returns the paths."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        written = {"trajectory": out / "trajectory.csv"}
        _write_steps(self, written["trajectory"])
        drawn = None
        if plots:
            from subterra.viz.drive import plot_drive_compute, plot_drive_map, plot_speed_risk

            drawn = {
                "map_plot": (lambda p: plot_drive_map(self, p), "map.png"),
                "speed_plot": (lambda p: plot_speed_risk(self, p), "speed-risk.png"),
                "compute_plot": (lambda p: plot_drive_compute(self, p), "compute-time.png"),
            }
        events = ([f"{e['time_s']:.3f}", e["from"], e["to"], e["reason"], f"{e['r_inst']:.3f}", f"{e['r_total']:.3f}"] for e in self.events)
        return write_run_outputs(out, written, events_header=["time_s", "from", "to", "reason", "r_inst", "r_total"], events=events,
                                 summary=self.summary(), plots=drawn, rerun=self.extra.get("rerun"))


def _write_steps(result: DriveResult, path: Path) -> None:
    s = result.steps
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["time_s", "x_m", "y_m", "z_m", "yaw_rad", "roll_rad", "pitch_rad", "speed_m_s", "cmd_v_m_s",
                    "cmd_yaw_rate_rad_s", "behaviour", "target", "plan_status", "mpc_status", "local_risk",
                    "speed_limit_m_s", "true_risk", "clearance_m", "map_ms", "plan_ms", "track_ms", "total_ms"])
        for i in range(len(s["time_s"])):
            w.writerow([
                f"{s['time_s'][i]:.3f}", *(f"{v:.4f}" for v in s["position"][i]), f"{s['yaw'][i]:.4f}",
                f"{s['roll'][i]:.4f}", f"{s['pitch'][i]:.4f}", f"{s['speed_m_s'][i]:.3f}",
                *(f"{v:.4f}" for v in s["command"][i]), s["behaviour"][i], s["target"][i], s["plan_status"][i],
                s["mpc_status"][i], f"{s['local_risk'][i]:.4f}", f"{s['speed_limit_m_s'][i]:.3f}",
                f"{s['true_risk'][i]:.4f}", f"{s['clearance_m'][i]:.4f}",
                *(f"{s[k][i]:.3f}" for k in ("map_ms", "plan_ms", "track_ms", "total_ms")),
            ])


def _roll_pitch(world_from_body: np.ndarray) -> tuple[float, float]:
    r = world_from_body[:3, :3]
    return math.atan2(r[2, 1], r[2, 2]), -math.asin(max(-1.0, min(1.0, r[2, 0])))


def accumulated_risk(risks: np.ndarray, positions: np.ndarray) -> float:
    """``1 - exp(-Σ d·(-ln(1 - r)))`` along a driven path: ``d`` the distance between
    consecutive positions, ``r`` the mean of their risks (clamped below 1), as the planner
    accumulates risk (STEP, Fan et al. 2021)."""
    if len(risks) < 2:
        return 0.0
    r = np.clip(np.asarray(risks, dtype=np.float64), 0.0, 1.0 - 1e-9)
    hazard = -np.log1p(-r)
    d = np.linalg.norm(np.diff(np.asarray(positions, dtype=np.float64)[:, :2], axis=0), axis=1)
    return float(-np.expm1(-np.sum(d * 0.5 * (hazard[1:] + hazard[:-1]))))


def drive(
    scenario: str = "mine",
    *,
    planner: str = "risk-aware",
    seed: int = 0,
    world: World | None = None,
    start: tuple[float, float] | None = None,
    yaw: float | None = None,
    goal: tuple[float, float] | None = None,
    home: tuple[float, float] | None = None,
    lidar: str = "os1_64",
    noise: str = "os1_64",
    navigator_config: dict[str, Any] | None = None,
    rate_hz: float = 10.0,
    time_limit_s: float | None = None,
    progress: bool | Callable[[dict[str, Any]], None] = False,
    rerun_path: str | os.PathLike[str] | None = None,
    faults: str | Sequence[str] | None = None,
    faults_config: dict[str, Any] | None = None,
) -> DriveResult:
    """Drives the ground robot across ``scenario`` (or ``world``) once and returns the record.

    ``planner``: ``"risk-aware"`` (STEP, Fan et al. 2021) or ``"additive"`` (the baseline). ``seed``
    seeds the world's layout (built-in scenarios) and the lidar noise. ``start``/``yaw``/
    ``goal``: default the world's ``start`` and ``goal`` regions (heading toward the goal);
    ``home`` (where the robot returns when it gives up): default the start. ``lidar``: a
    :class:`subterra.sim.Lidar` preset, mounted level :data:`LIDAR_HEIGHT_M` above the body
    origin; ``noise``: one of :data:`subterra.sim.LIDAR_NOISE_PRESETS`.
    ``navigator_config``: a (partial) dict laid over the navigator's defaults (sections
    ``planner``, ``tracker``, ``recovery``, ``navigator``, and ``terrain``: the mapper's
    settings, laid over the drive's, which turn void detection on). ``time_limit_s``: default 4x the
    straight-line time at half the robot's top speed, at least 90 s. ``progress``: True for a
    live line on stderr, or a callback receiving a dict per step.
    ``faults``: names of :data:`subterra.sim.faults.FAULT_NAMES` to inject (``faults_config``:
    their settings); with any, the pose and its confidence come from a
    :class:`subterra.OdometryMux` over the vehicle's three odometry sources, and a scan that
    is lost, frozen or blank reaches the navigator as no scan (it stops after
    ``navigator.scan_timeout_s``; with no usable odometry it stops at once).
    """
    from subterra import Navigator
    from subterra.terrain import translation

    if planner not in PLANNERS:
        raise InputError(f"argument `planner` must be one of {', '.join(PLANNERS)}, got {planner!r}")
    if noise not in LIDAR_NOISE_PRESETS:
        raise InputError(f"argument `noise` must be one of {', '.join(LIDAR_NOISE_PRESETS)}, got {noise!r}")
    if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and 1.0 <= rate_hz <= 100.0):
        raise InputError(f"argument `rate_hz` must be in [1, 100] Hz, got {rate_hz!r}")
    if time_limit_s is not None and not (math.isfinite(time_limit_s) and time_limit_s > 0):
        raise InputError(f"argument `time_limit_s` must be finite and > 0, got {time_limit_s!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"argument `seed` must be an integer >= 0, got {seed!r}")
    seed = int(seed)
    started = time.perf_counter()
    if world is None:
        world = World.scenario(scenario, seed)
    else:
        scenario = world.name or scenario
    regions = world.regions
    if start is None or goal is None:
        missing = [r for r in ("start", "goal") if r not in regions]
        if missing:
            raise InputError(f"argument `world` has no region {missing[0]!r}; give `start` and `goal`")
    start_xy = _xy("start", start if start is not None else regions["start"][0][:2])
    goal_xy = _xy("goal", goal if goal is not None else regions["goal"][0][:2])
    home_xy = _xy("home", home) if home is not None else start_xy.copy()
    goal_radius = float(regions["goal"][1]) if goal is None else 0.5
    if yaw is None:
        yaw = math.atan2(goal_xy[1] - start_xy[1], goal_xy[0] - start_xy[0])

    body_from_sensor = translation(z=LIDAR_HEIGHT_M)
    sim = Simulation(world, "ground", {"lidar": (Lidar(lidar), body_from_sensor, noise)}, seed=seed,
                     start=[start_xy[0], start_xy[1], 0.0], yaw=yaw)
    # The goal ball is centred on the ground there (the body origin is on the ground): at
    # z = 0 a goal on a plateau 0.5 m up (risky-slope) could never be reached with radius 0.5.
    goal_z = world.ground_height(float(goal_xy[0]), float(goal_xy[1]))
    sim.set_goal(point=[goal_xy[0], goal_xy[1], 0.0 if goal_z is None else float(goal_z)], radius_m=goal_radius)
    config = dict(navigator_config or {})
    planner_cfg = dict(config.get("planner", {}))
    planner_cfg.setdefault("cost_model", "risk" if planner == "risk-aware" else "additive")
    config["planner"] = planner_cfg
    # The simulated lidars are spinning lidars: missing returns mark bottomless holes.
    terrain = {"ground": {"void_min_gap_deg": LIDAR_VOID_MIN_GAP_DEG}}
    for section, values in dict(config.pop("terrain", None) or {}).items():
        if not isinstance(values, dict):
            raise InputError(f"argument `navigator_config` section terrain.{section} must be a table, got {values!r}")
        terrain[section] = {**terrain.get(section, {}), **values}
    nav = Navigator(goal=goal_xy, home=home_xy, config=config, terrain=terrain)
    robot = nav.robot.to_dict()
    from subterra import TerrainConfig

    risk_ramps = TerrainConfig(terrain).to_dict()["risk"]
    v_max = float(robot["max_speed_m_s"])
    if time_limit_s is None:
        time_limit_s = max(90.0, 4.0 * float(np.linalg.norm(goal_xy - start_xy)) / (0.5 * v_max))
    sim.set_time_limit(time_limit_s)

    recorder = None
    if rerun_path is not None:
        from subterra.viz.rerun import RerunRecorder

        recorder = RerunRecorder(rerun_path, application_id=f"subterra-drive-{scenario}")
        recorder.log_world(world)

    dt = 1.0 / float(rate_hz)
    rows: dict[str, list[Any]] = {k: [] for k in STEP_FIELDS}
    events: list[dict[str, Any]] = []
    bar = None
    if progress is True:
        from subterra._extras import tqdm

        bar = tqdm(total=round(time_limit_s), unit="s", desc=f"drive {scenario} {planner}", leave=False, disable=None,
                   bar_format="{desc}: {n:.0f}/{total:.0f} s sim {postfix}")
    last_plan = np.zeros((0, 2))
    last_safety = None
    injector = mux = watchdog = None
    fault_events: list[dict[str, Any]] = []
    if parse_faults(faults):
        injector = FaultInjector(parse_faults(faults), seed=seed, config=faults_config)
        mux = OdometryMux([(name, float(rate_hz)) for name in ODOMETRY_SOURCES])
        watchdog = SensorWatchdog(min_points=100)
    pose_held = None
    try:
        while sim.status == "running":
            obs = sim.observe()
            truth = obs["world_from_body"]
            odom = obs["odometry"]
            # Signed forward speed, as wheel odometry gives it.
            speed = float(np.dot(np.asarray(obs["velocity_world"], dtype=np.float64)[:2], odom[:2, 0]))
            scan = obs["scans"]["lidar"]
            confidence = 1.0
            if injector is not None:
                t_obs = obs["time_s"]
                scan = injector.sensor(t_obs, "lidar", scan)
                fresh, _, _ = watchdog.check(t_obs, scan)
                scan = scan if fresh else None
                for name, pose in injector.odometry(t_obs, odom, truth):
                    mux.push(name, t_obs, pose)
                mux_out = mux.update(t_obs)
                for e in mux_out.events:
                    fault_events.append({"time_s": e["time_s"], "event": f"odometry-{e['event']}", "source": e["source"], "reason": e["reason"]})
                confidence = mux_out.confidence
                odom = mux_out.world_from_body if mux_out.world_from_body is not None else (pose_held if pose_held is not None else odom)
                pose_held = odom
            out = nav.step(scan, stamp=obs["time_s"], world_from_body=odom,
                           body_from_sensor=body_from_sensor, speed=speed, confidence=confidence)
            v, w = out.command
            step = sim.step([v, 0.0, 0.0, w], dt, compute_time_s=out.timings["total_s"])
            events.extend(out.transitions)
            # A safety stop or a replaced command is an event when it starts (not every tick).
            if out.safety is not None and out.safety != last_safety and not out.transitions:
                events.append({"time_s": obs["time_s"], "from": out.behaviour, "to": out.behaviour,
                               "reason": f"safety: {out.safety}", "r_inst": out.thresholds[0], "r_total": out.thresholds[1]})
            last_safety = out.safety
            if len(out.path_world):
                last_plan = np.asarray(out.path_world, dtype=np.float64)
            roll, pitch = _roll_pitch(truth)
            tilt = math.acos(max(-1.0, min(1.0, float(truth[2, 2]))))
            rows["time_s"].append(obs["time_s"])
            rows["position"].append(truth[:3, 3].copy())
            rows["yaw"].append(math.atan2(truth[1, 0], truth[0, 0]))
            rows["roll"].append(roll)
            rows["pitch"].append(pitch)
            rows["speed_m_s"].append(speed)
            rows["command"].append((v, w))
            rows["behaviour"].append(out.behaviour)
            rows["target"].append(out.target)
            rows["plan_status"].append(out.plan_status or "")
            rows["mpc_status"].append(out.mpc_status or "")
            rows["local_risk"].append(out.local_risk)
            rows["speed_limit_m_s"].append(out.speed_limit_m_s)
            tilt_risk = float(true_risk(tilt, safe_deg=robot["tilt_safe_deg"], lethal_deg=robot["tilt_lethal_deg"]))
            terrain_risk = true_terrain_risk(world, truth[:2, 3], rows["yaw"][-1], robot, risk_ramps)
            rows["true_risk"].append(1.0 - (1.0 - tilt_risk) * (1.0 - terrain_risk))
            rows["clearance_m"].append(step["clearance_m"])
            for stage in ("map", "plan", "track", "total"):
                rows[f"{stage}_ms"].append(1e3 * out.timings[f"{stage}_s"])
            if recorder is not None:
                recorder.log_drive_step(obs["time_s"], position=truth[:3, 3], command=(v, w), path=last_plan,
                                        risk_map=nav.risk_map if len(rows["time_s"]) % 10 == 1 else None)
            if bar is not None:
                bar.n = step["time_s"]
                bar.set_postfix_str(f"to goal {np.linalg.norm(goal_xy - truth[:2, 3]):.1f} m, {out.behaviour}, "
                                    f"risk {out.local_risk:.2f}, {1e3 * out.timings['total_s']:.1f} ms/step", refresh=False)
                bar.update(0)
            elif callable(progress):
                progress({"time_s": step["time_s"], "position": truth[:3, 3].copy(), "status": step["status"],
                          "behaviour": out.behaviour, "compute_ms": 1e3 * out.timings["total_s"]})
            if sim.status == "running":
                if out.behaviour == "home":
                    sim.abort("returned_home")
                elif out.behaviour == "failed":
                    sim.abort("gave_up")
                elif out.behaviour == "goal_reached" and float(np.linalg.norm(goal_xy - truth[:2, 3])) > goal_radius:
                    # At the goal by its pose, not in truth: the odometry's error (a fault's).
                    believed = float(np.linalg.norm(goal_xy - np.asarray(odom, dtype=np.float64)[:2, 3]))
                    events.append({"time_s": obs["time_s"], "from": out.behaviour, "to": out.behaviour,
                                   "reason": f"stop: at the goal by its odometry ({believed:.2f} m from it), "
                                             f"{float(np.linalg.norm(goal_xy - truth[:2, 3])):.2f} m from it in truth",
                                   "r_inst": out.thresholds[0], "r_total": out.thresholds[1]})
                    sim.abort("odometry_error")
    finally:
        if bar is not None:
            bar.close()
        if recorder is not None:
            recorder.close()

    steps = {
        "time_s": np.asarray(rows["time_s"], dtype=np.float64),
        "position": np.asarray(rows["position"], dtype=np.float64).reshape(-1, 3),
        **{k: np.asarray(rows[k], dtype=np.float64) for k in ("yaw", "roll", "pitch", "speed_m_s", "local_risk",
                                                              "speed_limit_m_s", "true_risk", "clearance_m")},
        "command": np.asarray(rows["command"], dtype=np.float64).reshape(-1, 2),
        **{k: np.asarray(rows[k], dtype=str) for k in ("behaviour", "target", "plan_status", "mpc_status")},
        **{f"{s}_ms": np.asarray(rows[f"{s}_ms"], dtype=np.float64) for s in ("map", "plan", "track", "total")},
    }
    final = sim.world_from_body[:3, 3].copy()
    path = np.vstack([steps["position"], final[None, :]])
    metrics = dict(sim.metrics())
    metrics["time_limit_s"] = time_limit_s
    metrics["accumulated_true_risk"] = accumulated_risk(steps["true_risk"], steps["position"])
    metrics["max_true_risk"] = float(steps["true_risk"].max()) if steps["true_risk"].size else 0.0
    metrics["max_tilt_deg"] = float(np.degrees(np.max(np.hypot(steps["roll"], steps["pitch"])))) if steps["roll"].size else 0.0
    if injector is not None:
        # Faults and odometry events in the behaviour log's columns (from = to = the behaviour then).
        behaviour_at = lambda t: str(steps["behaviour"][max(0, int(np.searchsorted(steps["time_s"], t, side="right")) - 1)]) if steps["time_s"].size else ""  # noqa: E731
        for e in injector.events + fault_events:
            b = behaviour_at(e["time_s"])
            label = e["event"] if not e.get("source") else f"{e['event']} {e['source']}"
            events.append({"time_s": e["time_s"], "from": b, "to": b, "reason": f"{label}: {e['reason']}",
                           "r_inst": math.nan, "r_total": math.nan})
        events.sort(key=lambda e: e["time_s"])
        metrics["faults"] = injector.names
        metrics["odometry_switches"] = sum(1 for e in fault_events if e["event"] == "odometry-switch" and "from none" not in e["reason"])
    result = DriveResult(
        scenario=scenario, planner=planner, seed=seed, world=world, start=start_xy, goal=goal_xy, home=home_xy,
        rate_hz=float(rate_hz), steps=steps, events=events, metrics=metrics, path=path, last_plan=last_plan,
        risk_map=nav.risk_map, wall_s=time.perf_counter() - started,
    )
    if rerun_path is not None:
        result.extra["rerun"] = str(rerun_path)
    return result


def _xy(name: str, value: Any) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.size < 2 or not np.all(np.isfinite(a[:2])):
        raise InputError(f"argument `{name}` must be a finite (x, y) position [m], got {value!r}")
    return a[:2].copy()
