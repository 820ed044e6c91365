"""One closed-loop flight: simulated depth camera -> controller -> quadrotor.

The loop, per control step (``rate_hz``): the simulator renders the forward D435 at the
true pose with the chosen noise (``uint16`` millimetres, as the sensor gives them); the
controller (APF-PF, or the raw-APF baseline through the same interface) turns the frame
and the goal, expressed in the body frame from the odometry, into a body-frame velocity
command; the quadrotor tracks it for one step. The run ends at the goal, on a collision,
at the time limit, or when the robot has stalled (a local minimum of the potential).

>>> from subterra.flight import fly
>>> result = fly("highbay", "A-B", controller="apf-pf", noise="d435", seed=0)
>>> result.metrics["success"], result.metrics["failure"]
>>> result.save("runs/fly-A-B")          # CSV, JSON and the paper's Fig. 9-11
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

from subterra._core import OdometryMux, PerceptionConfig, Pilot
from subterra.errors import InputError
from subterra.sim import DEPTH_NOISE_PRESETS, DepthCamera, Simulation, World
from subterra.sim.faults import ODOMETRY_SOURCES, FaultInjector, parse_faults
from subterra.sim.outputs import plain, write_run_outputs
from subterra.watchdog import SensorWatchdog

__all__ = ["CONTROLLERS", "FlightResult", "fly", "resolve_path", "resolve_route"]

#: Controllers a flight can run (:meth:`subterra.Pilot.controllers`): ``apf-pf`` (the
#: particle filter, the paper), ``apf-pf-histogram`` (the exact filter), ``apf-pf-qmdp``
#: (the particle filter's belief scores a discrete set of evasive velocities in the force's
#: place, the authors' follow-up; docs/flight.md) and ``raw-apf``, the baseline the APF-PF
#: paper argues against: the same voxel binning and potentials, but the belief is each
#: frame's raw histogram of in-range points (no filter).
CONTROLLERS: tuple[str, ...] = tuple(Pilot.controllers())

#: Per-frame arrays of a flight (see :class:`FlightResult`), in CSV column order.
FRAME_FIELDS = (
    "time_s", "position", "yaw", "mpv_voxel", "mpv_depth_m", "mpv_probability", "mpv_body", "p_free",
    "closest_depth_m", "truth_closest_m", "obstacle_in_view", "repulsive_body", "repulsive_norm",
    "memory_repulsive_norm", "memory_cells", "escape_active", "carrot", "command", "compute_ms", "clearance_m",
)


@dataclass
class FlightResult:
    """Everything one flight recorded. ``frames`` holds one row per control step:

    ``time_s`` (F,), ``position`` (F, 3) true world position at the observation, ``yaw``
    (F,) [rad], ``mpv_voxel`` (F, 3) most probable voxel (i, j, k) or -1, ``mpv_depth_m``,
    ``mpv_probability`` (F,) (NaN when no voxel has belief), ``mpv_body`` (F, 3) its centre
    in the body frame, ``p_free`` (F,), ``closest_depth_m`` (F,) closest valid raw (noisy)
    depth, ``truth_closest_m`` (F,) closest noise-free depth (NaN when nothing returns),
    ``obstacle_in_view`` (F,) bool (a real surface within the filter's horizon),
    ``repulsive_body`` (F, 3) and ``repulsive_norm`` (F,) the repulsion the command used
    (belief plus, with the preset's obstacle memory on, the memory's), ``memory_repulsive_norm``
    (F,) the memory's share and ``memory_cells`` (F,) what it held (0 without a memory),
    ``escape_active`` (F,) bool (the preset's escape was following an obstacle's boundary),
    ``carrot`` (F, 3) the point the attraction pulled toward before the escape (the goal,
    or the carrot along the path),
    ``command`` (F, 4) ``[v_x, v_y,
    v_z, yaw_rate]``, ``compute_ms`` (F,) controller wall time, ``clearance_m`` (F,) after
    the step (negative = penetration). ``path`` is (F + 1, 3): every observed position and
    the final one.
    """

    scenario: str
    route: str
    controller: str
    noise: str
    preset: str
    seed: int
    world: World
    start: np.ndarray
    goal: np.ndarray
    goal_radius_m: float
    rate_hz: float
    horizon_m: float
    rho_0_m: float
    frames: dict[str, np.ndarray]
    metrics: dict[str, Any]
    path: np.ndarray
    wall_s: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)
    #: What happened besides the frames: injected faults, odometry switches, hovers, each a
    #: dict with ``time_s``, ``event``, ``source`` and ``reason`` (``events.csv``).
    events: list[dict[str, Any]] = field(default_factory=list)

    @property
    def success(self) -> bool:
        return bool(self.metrics.get("success"))

    @property
    def failure(self) -> str | None:
        return self.metrics.get("failure")

    def summary(self) -> dict[str, Any]:
        """The metrics plus what was flown, as plain JSON-ready values."""
        compute = self.frames["compute_ms"]
        in_view = self.frames["obstacle_in_view"]
        return {
            "scenario": self.scenario,
            "route": self.route,
            "controller": self.controller,
            "noise": self.noise,
            "preset": self.preset,
            "seed": self.seed,
            "rate_hz": self.rate_hz,
            "start": [float(v) for v in self.start],
            "goal": [float(v) for v in self.goal],
            "goal_radius_m": self.goal_radius_m,
            **{k: plain(v) for k, v in self.metrics.items()},
            "frames": int(compute.size),
            "compute_ms_median": float(np.median(compute)) if compute.size else None,
            "compute_ms_p99": float(np.percentile(compute, 99)) if compute.size else None,
            "obstacle_in_view_fraction": float(in_view.mean()) if in_view.size else 0.0,
            "faults": sorted({e["fault"] for e in self.events if e.get("event") == "fault-start"}),
            "hovers": sum(1 for e in self.events if e.get("event") == "hover"),
            "odometry_switches": sum(1 for e in self.events if e.get("event") == "odometry-switch" and "from none" not in (e.get("reason") or "")),
            "wall_s": round(self.wall_s, 3),
        }

    def save(self, out_dir: str | os.PathLike[str], *, plots: bool = True) -> dict[str, Path]:
        """Writes the run folder: ``trajectory.csv``, ``frames.csv`` (the per-frame
        summary), ``metrics.json`` and, with ``plots``, ``path.png`` (Fig. 10),
        ``depth-trace.png`` (Fig. 9) and ``compute-time.png`` (Fig. 11). Returns the paths."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        written = {
            "trajectory": _write_trajectory(self, out / "trajectory.csv"),
            "frames": _write_frames(self, out / "frames.csv"),
        }
        drawn = None
        if plots:
            from subterra.viz.flight import plot_compute_time, plot_flight_path, plot_flight_trace

            drawn = {
                "path_plot": (lambda p: plot_flight_path(self, p), "path.png"),
                "trace_plot": (lambda p: plot_flight_trace(self, p), "depth-trace.png"),
                "compute_plot": (lambda p: plot_compute_time(self, p), "compute-time.png"),
            }
        events = ([f"{e['time_s']:.3f}", e["event"], e.get("source") or "", e.get("reason") or ""] for e in self.events)
        return write_run_outputs(out, written, events_header=["time_s", "event", "source", "reason"], events=events,
                                 summary=self.summary(), plots=drawn, rerun=self.extra.get("rerun"))


def _write_trajectory(result: FlightResult, path: Path) -> Path:
    f = result.frames
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "x_m", "y_m", "z_m", "yaw_rad"])
        for t, p, yaw in zip(f["time_s"], f["position"], f["yaw"], strict=True):
            w.writerow([f"{t:.4f}", f"{p[0]:.4f}", f"{p[1]:.4f}", f"{p[2]:.4f}", f"{yaw:.5f}"])
        end = result.path[-1]
        w.writerow([f"{result.metrics.get('time_s', float('nan')):.4f}", f"{end[0]:.4f}", f"{end[1]:.4f}", f"{end[2]:.4f}", ""])
    return path


def _write_frames(result: FlightResult, path: Path) -> Path:
    f = result.frames
    header = [
        "time_s", "x_m", "y_m", "z_m", "yaw_rad", "mpv_i", "mpv_j", "mpv_k", "mpv_depth_m", "mpv_probability",
        "mpv_x_body_m", "mpv_y_body_m", "mpv_z_body_m", "p_free", "closest_depth_m", "truth_closest_m",
        "obstacle_in_view", "rep_x", "rep_y", "rep_z", "rep_norm", "memory_rep_norm", "memory_cells",
        "escape_active", "carrot_x_m", "carrot_y_m", "carrot_z_m",
        "cmd_v_x", "cmd_v_y", "cmd_v_z", "cmd_yaw_rate", "compute_ms", "clearance_m",
    ]

    def num(v: float, digits: int = 5) -> str:
        return "" if not math.isfinite(v) else f"{v:.{digits}f}"

    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for n in range(f["time_s"].size):
            row = [num(f["time_s"][n], 4), *(num(v, 4) for v in f["position"][n]), num(f["yaw"][n])]
            row += [str(int(v)) if v >= 0 else "" for v in f["mpv_voxel"][n]]
            row += [num(f["mpv_depth_m"][n]), num(f["mpv_probability"][n]), *(num(v) for v in f["mpv_body"][n])]
            row += [num(f["p_free"][n]), num(f["closest_depth_m"][n]), num(f["truth_closest_m"][n])]
            row += [str(int(f["obstacle_in_view"][n])), *(num(v) for v in f["repulsive_body"][n]), num(f["repulsive_norm"][n])]
            row += [num(f["memory_repulsive_norm"][n]), str(int(f["memory_cells"][n]))]
            row += [str(int(f["escape_active"][n])), *(num(v, 4) for v in f["carrot"][n])]
            row += [*(num(v) for v in f["command"][n]), num(f["compute_ms"][n], 4), num(f["clearance_m"][n], 4)]
            w.writerow(row)
    return path


def resolve_route(world: World, route: str | None) -> tuple[str, str, str]:
    """``(name, from, to)`` of ``route`` on ``world``: a route name (``"A-B"``), two region
    names joined by ``-``, or None for the world's first route. Raises :class:`InputError`
    naming the known routes."""
    regions = world.regions
    if route is None:
        if not world.routes:
            raise InputError(f"argument `route`: world {world.name!r} defines no route; name two regions as 'from-to' (regions: {', '.join(regions) or 'none'})")
        return world.routes[0]
    for name, a, b in world.routes:
        if route == name or route == f"{a}-{b}":
            return name, a, b
    parts = route.split("-")
    if len(parts) == 2 and all(p in regions for p in parts):
        return route, parts[0], parts[1]
    known = ", ".join(f"{a}-{b}" for _, a, b in world.routes) or "none"
    raise InputError(f"argument `route`: no route {route!r} in world {world.name!r} (routes: {known}; regions: {', '.join(regions) or 'none'})")


def resolve_path(world: World, start_region: str, goal_region: str, path: Any) -> np.ndarray | None:
    """The waypoints to follow from ``start_region`` to ``goal_region``, shape ``(N, 3)``
    with the start first and the goal last, or None to fly straight at the goal.

    ``path``: ``"auto"`` (the world's waypoint regions ``wp1``, ``wp2``, ... in order, when
    it has any; else None), ``"none"`` (None), or a sequence of 3-vectors (world frame [m])
    to pass between start and goal. Raises :class:`InputError` for anything else."""
    regions = world.regions
    start, goal = np.asarray(regions[start_region][0], float), np.asarray(regions[goal_region][0], float)
    if isinstance(path, str):
        if path == "none":
            return None
        if path != "auto":
            raise InputError(f"argument `path` must be 'auto', 'none' or a sequence of 3-vectors, got {path!r}")
        names = sorted((n for n in regions if n.startswith("wp") and n[2:].isdigit()), key=lambda n: int(n[2:]))
        if not names:
            return None
        middle = np.array([regions[n][0] for n in names], dtype=np.float64).reshape(-1, 3)
        if start_region != "start" or goal_region != "goal":
            # The waypoints run from "start" to "goal"; flown the other way, reverse them.
            if start_region == "goal" and goal_region == "start":
                middle = middle[::-1]
            else:
                return None
    else:
        try:
            middle = np.asarray(path, dtype=np.float64).reshape(-1, 3)
        except (TypeError, ValueError) as exc:
            raise InputError(f"argument `path` must be a sequence of 3-vectors [m], got {type(path).__name__}") from exc
        if not np.all(np.isfinite(middle)):
            raise InputError("argument `path` must hold finite numbers")
    return np.vstack([start, middle, goal])


def _yaw_of(world_from_body: np.ndarray) -> float:
    return math.atan2(world_from_body[1, 0], world_from_body[0, 0])


class _IdlePerception:
    most_probable = None
    p_free = math.nan
    closest_depth_m = None


class _IdlePilotOutput:
    perceptions = (_IdlePerception(),)
    repulsive_body = np.zeros(3)
    memory_repulsive_body = np.zeros(3)
    memory_cells = 0
    escape_active = False
    target_world = np.full(3, math.nan)


def fly(
    scenario: str = "highbay",
    route: str | None = None,
    *,
    controller: str = "apf-pf",
    noise: str = "d435",
    preset: str = "flight-escape",
    config: PerceptionConfig | None = None,
    seed: int = 0,
    world: World | None = None,
    rate_hz: float = 15.0,
    time_limit_s: float | None = None,
    stall_window_s: float = 10.0,
    stall_distance_m: float = 0.3,
    progress: bool | Callable[[dict[str, Any]], None] = False,
    rerun_path: str | os.PathLike[str] | None = None,
    rerun_depth_every: int = 5,
    path: Any = "auto",
    lookahead_m: float = 1.5,
    faults: str | Sequence[str] | None = None,
    faults_config: dict[str, Any] | None = None,
) -> FlightResult:
    """Flies ``route`` of ``scenario`` (or of ``world``; default: its first route, e.g.
    highbay's ``A-B``, tunnel's ``start-goal``) once and returns the record.

    ``controller``: ``"apf-pf"`` (particle filter, the paper), ``"apf-pf-histogram"`` (the
    exact filter), ``"apf-pf-qmdp"`` (the particle filter's belief scores a discrete set of
    evasive velocities, QMDP) or ``"raw-apf"`` (the baseline: no filter). ``noise``: a depth noise preset
    of :data:`subterra.sim.DEPTH_NOISE_PRESETS`. ``seed`` seeds the world's layout (built-in
    scenarios), the sensor noise and the particle filter. The run ends at the goal region,
    on a collision, after ``time_limit_s`` (default: 4x the straight-line time at the
    preset's top speed, at least 60 s), or as ``local_minimum`` when the robot has stayed
    within ``stall_distance_m`` of where it was ``stall_window_s`` seconds ago for all that
    time; as ``odometry_error`` (with a ``stop`` event giving both distances) when it stayed
    so because its pose put it at the goal while in truth it is not (a fault's pose error).
    ``progress``: True for a live line on stderr, or a callback receiving a dict per step.
    ``rerun_path``: also record a Rerun ``.rrd`` (needs ``subterra[viz]``) with the depth
    image of every ``rerun_depth_every``-th frame (a D435 frame is ~0.5 MB in the file)
    and everything else every frame.
    ``path``: waypoints to follow with a carrot ``lookahead_m`` ahead (:func:`resolve_path`:
    by default the world's waypoint regions, e.g. the tunnel's ``wp1`` ... ``wp7``).
    The preset's obstacle memory (``memory.enabled``) and escape from local minima
    (``escape.enabled``) run when the preset turns them on.
    ``faults``: names of :data:`subterra.sim.faults.FAULT_NAMES` to inject (``faults_config``:
    their settings, ``{name: {field: value}}``); with any, the pose comes from a
    :class:`subterra.OdometryMux` over the vehicle's three odometry sources, and a
    :class:`subterra.watchdog.SensorWatchdog` slows the drone while the depth camera
    gives nothing new (lost, frozen or blank frames) and hovers it after its timeout, as it
    hovers while no odometry source is usable. Events go to ``events``.
    """
    if controller not in CONTROLLERS:
        raise InputError(f"argument `controller` must be one of {', '.join(CONTROLLERS)}, got {controller!r}")
    if noise not in DEPTH_NOISE_PRESETS:
        raise InputError(f"argument `noise` must be one of {', '.join(DEPTH_NOISE_PRESETS)}, got {noise!r}")
    if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and 1.0 <= rate_hz <= 200.0):
        raise InputError(f"argument `rate_hz` must be in [1, 200] Hz, got {rate_hz!r}")
    if time_limit_s is not None and not (math.isfinite(time_limit_s) and time_limit_s > 0):
        raise InputError(f"argument `time_limit_s` must be finite and > 0, got {time_limit_s!r}")
    if not (math.isfinite(stall_window_s) and stall_window_s > 0):
        raise InputError(f"argument `stall_window_s` must be finite and > 0, got {stall_window_s!r}")
    if not (math.isfinite(stall_distance_m) and stall_distance_m >= 0):
        raise InputError(f"argument `stall_distance_m` must be finite and >= 0, got {stall_distance_m!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"argument `seed` must be an integer >= 0, got {seed!r}")
    seed = int(seed)
    started = time.perf_counter()
    if world is None:
        world = World.scenario(scenario, seed)
    else:
        scenario = world.name
    route_name, a, b = resolve_route(world, route)
    regions = world.regions
    waypoints = resolve_path(world, a, b, path)
    if not (isinstance(lookahead_m, (int, float)) and math.isfinite(lookahead_m) and lookahead_m > 0):
        raise InputError(f"argument `lookahead_m` must be finite and > 0, got {lookahead_m!r}")
    start = np.asarray(regions[a][0], dtype=np.float64)
    goal, goal_radius = np.asarray(regions[b][0], dtype=np.float64), float(regions[b][1])
    first = goal if waypoints is None else waypoints[1]
    yaw0 = math.atan2(first[1] - start[1], first[0] - start[0])

    camera = DepthCamera.d435()
    sim = Simulation(world, "quadrotor", {"front": (camera, None, noise)}, seed=seed, start=start, yaw=yaw0)
    sim.set_goal(region=b)
    # One pilot: the filter, the obstacle memory and the escape when the preset turns them
    # on (`flight-memory`, `flight-escape`), and the controller.
    pilot = Pilot(camera.camera, preset, config=config, controller=controller, seed=seed)
    cfg = pilot.config.to_dict()
    if waypoints is None:
        pilot.set_goal(goal)
    else:
        pilot.set_path(waypoints, lookahead_m=float(lookahead_m))
    v_max = float(cfg["apf"]["v_x_max_m_s"])
    if time_limit_s is None:
        way_m = float(np.linalg.norm(goal - start)) if waypoints is None else float(pilot.path_length_m)
        time_limit_s = max(60.0, 4.0 * way_m / max(v_max, 1e-3))
    sim.set_time_limit(time_limit_s)
    grid = cfg["grid"]
    horizon_m = float(grid["depth_max_m"])
    centres_body = pilot.voxel_centres("body") if rerun_path is not None else None
    free_state = pilot.free_state()

    recorder = None
    if rerun_path is not None:
        from subterra.viz.rerun import RerunRecorder

        recorder = RerunRecorder(rerun_path, application_id=f"subterra-fly-{route_name}", depth_every=rerun_depth_every)
        recorder.log_world(world)

    injector = mux = watchdog = None
    events: list[dict[str, Any]] = []
    if parse_faults(faults):
        injector = FaultInjector(parse_faults(faults), seed=seed, config=faults_config)
        mux = OdometryMux([(name, float(rate_hz)) for name in ODOMETRY_SOURCES])
        watchdog = SensorWatchdog()
    last_command = np.zeros(4)
    hovering: str | None = None
    step_out = None
    # What the frames record before the pilot's first step, if the run starts halted.
    pilot_idle = _IdlePilotOutput()

    dt = 1.0 / float(rate_hz)
    stall_steps = max(1, round(stall_window_s * rate_hz))
    rows: dict[str, list[Any]] = {k: [] for k in FRAME_FIELDS}
    positions: list[np.ndarray] = []
    bar = None
    if progress is True:
        from subterra._extras import tqdm

        bar = tqdm(total=round(time_limit_s), unit="s", desc=f"fly {route_name} {controller}", leave=False, disable=None,
                   bar_format="{desc}: {n:.0f}/{total:.0f} s sim {postfix}")
    try:
        while sim.status == "running":
            obs = sim.observe(depth_dtype="uint16")
            truth_body = obs["world_from_body"]
            odom = obs["odometry"]
            t_obs = obs["time_s"]
            depth = obs["depth"]["front"]
            samples = []
            if injector is not None:  # the simulated sensors' faults: not the stack's time
                depth = injector.sensor(t_obs, "front", depth, no_return=0)
                samples = injector.odometry(t_obs, odom, truth_body)
            tick = time.perf_counter()
            halt = None
            confidence = 1.0
            if injector is not None:
                for name, pose in samples:
                    mux.push(name, t_obs, pose)
                mux_out = mux.update(t_obs)
                confidence = mux_out.confidence
                if any(e["corrected_m"] > 0.0 for e in mux_out.events):
                    # The pose was taken back (a drift found by the vote): what the memory
                    # recorded during the drift lies elsewhere in the corrected frame.
                    pilot.reset()
                events.extend({"time_s": e["time_s"], "event": f"odometry-{e['event']}", "source": e["source"], "reason": e["reason"]}
                              for e in mux_out.events)
                if mux_out.source is None or mux_out.world_from_body is None:
                    halt = "no odometry"
                else:
                    odom = mux_out.world_from_body
                fresh, age_s, reason = watchdog.check(t_obs, depth)
                if halt is None and not fresh:
                    halt = reason
            if halt is None:
                step_out = pilot.step(depth, stamp=t_obs, world_from_body=odom, confidence=confidence)
                out = step_out.perceptions[0]
                cmd = step_out.command
                command = cmd.as_array()
                last_command = command
                if hovering is not None:
                    events.append({"time_s": t_obs, "event": "resume", "source": None, "reason": f"after: {hovering}"})
                    hovering = None
            else:
                # No new depth (or no pose): slow down, and hover after the watchdog's timeout.
                scale = 0.0 if halt == "no odometry" else watchdog.scale(t_obs)
                command = last_command * scale
                if scale == 0.0 and hovering is None:
                    hovering = halt
                    events.append({"time_s": t_obs, "event": "hover", "source": None, "reason": halt})
            compute_s = time.perf_counter() - tick
            step = sim.step(command, dt, compute_time_s=compute_s)

            position = truth_body[:3, 3].copy()
            positions.append(position)
            if step_out is None:  # halted from the first tick: nothing perceived yet
                step_out = pilot_idle
                out = step_out.perceptions[0]
            mp = out.most_probable
            truth_min = obs["depth_truth_min"]["front"]
            rows["time_s"].append(obs["time_s"])
            rows["position"].append(position)
            rows["yaw"].append(_yaw_of(truth_body))
            rows["mpv_voxel"].append(mp.voxel if mp else (-1, -1, -1))
            rows["mpv_depth_m"].append(mp.depth_m if mp else math.nan)
            rows["mpv_probability"].append(mp.probability if mp else math.nan)
            rows["mpv_body"].append(mp.centre_body if mp else (math.nan,) * 3)
            rows["p_free"].append(out.p_free)
            rows["closest_depth_m"].append(out.closest_depth_m if out.closest_depth_m is not None else math.nan)
            rows["truth_closest_m"].append(truth_min if truth_min is not None else math.nan)
            rows["obstacle_in_view"].append(truth_min is not None and truth_min < horizon_m)
            rep = step_out.repulsive_body
            rows["repulsive_body"].append(rep)
            rows["repulsive_norm"].append(float(np.linalg.norm(rep)))
            rows["memory_repulsive_norm"].append(float(np.linalg.norm(step_out.memory_repulsive_body)))
            rows["memory_cells"].append(step_out.memory_cells)
            rows["escape_active"].append(step_out.escape_active)
            rows["carrot"].append(step_out.target_world)
            rows["command"].append(command)
            rows["compute_ms"].append(compute_s * 1e3)
            rows["clearance_m"].append(step["clearance_m"])

            if recorder is not None:
                states = out.belief_states
                keep = states != free_state
                pts = centres_body[states[keep]] @ truth_body[:3, :3].T + truth_body[:3, 3]
                recorder.log_frame(
                    obs["time_s"], depth=obs["depth"]["front"], world_from_camera=obs["world_from_sensor"]["front"],
                    camera=camera.camera, belief_points_world=pts, belief_weights=out.belief_probabilities[keep],
                    position=position, command=cmd.as_array(), p_free=out.p_free,
                )
            if bar is not None:
                bar.n = step["time_s"]
                bar.set_postfix_str(
                    f"to goal {np.linalg.norm(goal - position):.1f} m, clearance {step['clearance_m']:.2f} m, "
                    f"{compute_s * 1e3:.2f} ms/frame", refresh=False)
                bar.update(0)
            elif callable(progress):
                progress({"time_s": step["time_s"], "position": position, "status": step["status"],
                          "clearance_m": step["clearance_m"], "compute_ms": compute_s * 1e3})
            if sim.status == "running" and len(positions) > stall_steps:
                # Stalled: never farther than stall_distance_m from where it was a window ago
                # (a robot that follows a boundary away and comes back has not stalled).
                window = np.asarray(positions[-1 - stall_steps:])
                if float(np.max(np.linalg.norm(window - window[0], axis=1))) < stall_distance_m:
                    if step_out.command.reached:
                        # It stopped because its pose says it is at the goal: not a local
                        # minimum but the odometry's error (after a fault) at the goal.
                        believed = float(np.linalg.norm(goal - np.asarray(odom, dtype=np.float64)[:3, 3]))
                        events.append({"time_s": t_obs, "event": "stop", "source": None,
                                       "reason": f"at the goal by its odometry ({believed:.2f} m from it), "
                                                 f"{float(np.linalg.norm(goal - position)):.2f} m from it in truth"})
                        sim.abort("odometry_error")
                    else:
                        sim.abort("local_minimum")
    finally:
        if bar is not None:
            bar.close()
        if recorder is not None:
            recorder.close()

    final = sim.world_from_body[:3, 3].copy()
    frames = {
        "time_s": np.asarray(rows["time_s"], dtype=np.float64),
        "position": np.asarray(rows["position"], dtype=np.float64).reshape(-1, 3),
        "yaw": np.asarray(rows["yaw"], dtype=np.float64),
        "mpv_voxel": np.asarray(rows["mpv_voxel"], dtype=np.int64).reshape(-1, 3),
        "mpv_depth_m": np.asarray(rows["mpv_depth_m"], dtype=np.float64),
        "mpv_probability": np.asarray(rows["mpv_probability"], dtype=np.float64),
        "mpv_body": np.asarray(rows["mpv_body"], dtype=np.float64).reshape(-1, 3),
        "p_free": np.asarray(rows["p_free"], dtype=np.float64),
        "closest_depth_m": np.asarray(rows["closest_depth_m"], dtype=np.float64),
        "truth_closest_m": np.asarray(rows["truth_closest_m"], dtype=np.float64),
        "obstacle_in_view": np.asarray(rows["obstacle_in_view"], dtype=bool),
        "repulsive_body": np.asarray(rows["repulsive_body"], dtype=np.float64).reshape(-1, 3),
        "repulsive_norm": np.asarray(rows["repulsive_norm"], dtype=np.float64),
        "memory_repulsive_norm": np.asarray(rows["memory_repulsive_norm"], dtype=np.float64),
        "memory_cells": np.asarray(rows["memory_cells"], dtype=np.int64),
        "escape_active": np.asarray(rows["escape_active"], dtype=bool),
        "carrot": np.asarray(rows["carrot"], dtype=np.float64).reshape(-1, 3),
        "command": np.asarray(rows["command"], dtype=np.float64).reshape(-1, 4),
        "compute_ms": np.asarray(rows["compute_ms"], dtype=np.float64),
        "clearance_m": np.asarray(rows["clearance_m"], dtype=np.float64),
    }
    path = np.vstack([frames["position"], final[None, :]])
    result = FlightResult(
        scenario=scenario, route=route_name, controller=controller, noise=noise, preset=preset, seed=seed,
        world=world, start=start, goal=goal, goal_radius_m=goal_radius, rate_hz=float(rate_hz),
        horizon_m=horizon_m, rho_0_m=float(cfg["apf"]["rho_0_m"]), frames=frames, metrics=dict(sim.metrics()),
        path=path, wall_s=time.perf_counter() - started,
        events=sorted((injector.events if injector is not None else []) + events, key=lambda e: e["time_s"]),
    )
    result.metrics["time_limit_s"] = time_limit_s
    result.metrics["escape_frames"] = int(frames["escape_active"].sum())
    result.metrics["path_waypoints"] = 0 if waypoints is None else int(waypoints.shape[0])
    if rerun_path is not None:
        result.extra["rerun"] = str(rerun_path)
    return result
