"""``subterra sil``: software in the loop over ROS 2 DDS, in two processes.

This process is the **simulator**: it renders the robot's sensor at the true pose and
publishes it with the odometry, the transforms and the clock as a robot driver would
(``sensor_msgs/PointCloud2`` or ``Image`` + ``CameraInfo``, ``nav_msgs/Odometry``,
``/tf``, ``/tf_static``, ``/clock``), sends the goal as a ``geometry_msgs/PoseStamped``,
and moves the robot by the ``geometry_msgs/TwistStamped`` it receives. The **node** is a
second process, ``subterra node ground|drone`` (:mod:`subterra.live.node`), started here
with a node config written to the run folder. Nothing passes between them but DDS
samples on the loopback interface.

The loop runs in **lockstep**: the simulator publishes the frame of time ``t`` and waits
for the command stamped ``t`` (the node stamps its command with the frame it acted on)
before it advances by one period, so the run does not depend on how busy the machine is,
and the time from publishing the frame to receiving its command is the bridge's
end-to-end latency (decode, pipeline, encode, both DDS hops). A command that does not
come within ``reply_timeout_s`` counts as missed and the robot gets a stop.

The run folder gets ``metrics.json`` (the simulator's metrics as ``drive``/``fly`` write
them, plus ``latency_ms_median``, ``latency_ms_p99``, ``commands_missed`` and the node's
own counts under ``node``), ``trajectory.csv``, ``node.toml``, ``node.log`` and
``node-stats.json``.

>>> from subterra.live.sil import sil
>>> result = sil("ground", "mine", seed=0, out="runs/sil-mine")
>>> result["success"], result["latency_ms_median"]
"""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from subterra.errors import InputError, SubterraError
from subterra.io import ros
from subterra.live.config import NodeConfig
from subterra.live.dds import RosParticipant, typestore

__all__ = ["SIL_SCENARIOS", "SilError", "sil"]

#: The scenarios each robot can run in the loop (the built-in worlds with a start and a goal).
SIL_SCENARIOS = {"ground": ("mine", "slopes", "rough", "ledge", "cave"), "drone": ("highbay",)}
_NS = 1_000_000_000
#: How long the simulator waits for the node to appear on the domain [s].
DISCOVERY_TIMEOUT_S = 60.0
#: The loop gives up when the node has answered none of this many frames in a row.
MAX_MISSED_IN_A_ROW = 5
_LIDAR_FRAME = "lidar"
_CAMERA_FRAME = "camera_depth_optical_frame"


class SilError(SubterraError, RuntimeError):
    """The loop could not run: the node did not start, did not appear or died."""


def _stamp_ns(t_s: float) -> int:
    return int(round(t_s * _NS))


def sil(
    robot: str = "ground",
    scenario: str | None = None,
    *,
    seed: int = 0,
    out: str | os.PathLike[str] = "runs/sil",
    domain_id: int | None = None,
    time_limit_s: float | None = None,
    node_config: NodeConfig | dict[str, Any] | str | os.PathLike[str] | None = None,
    reply_timeout_s: float = 5.0,
    progress: bool = False,
) -> dict[str, Any]:
    """Runs one software-in-the-loop episode (see the module doc); returns the metrics.

    ``robot``: ``ground`` (default scenario ``mine``) or ``drone`` (``highbay``, its first
    route). ``domain_id``: default one derived from this process id in [100, 199] (two
    runs side by side do not hear each other). ``node_config``: the node's settings (its
    domain, ``use_sim_time``, and the sensor and odometry QoS are set here: reliable, as a
    lockstep loop must lose no frame). ``time_limit_s``: simulated seconds, default as
    ``drive``/``fly`` choose it."""
    if not isinstance(robot, str) or robot not in SIL_SCENARIOS:
        raise InputError(f"argument `robot` must be one of {', '.join(SIL_SCENARIOS)}, got {robot!r:.40}")
    scenario = SIL_SCENARIOS[robot][0] if scenario is None else scenario
    if not isinstance(scenario, str) or scenario not in SIL_SCENARIOS[robot]:
        raise InputError(f"argument `scenario` for the {robot} robot must be one of {', '.join(SIL_SCENARIOS[robot])}, got {scenario!r:.40}")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**64:
        raise InputError(f"argument `seed` must be an integer in [0, 2^64), got {seed!r:.40}")
    if domain_id is None:
        domain_id = 100 + os.getpid() % 100
    if isinstance(domain_id, bool) or not isinstance(domain_id, int) or not 0 <= domain_id <= 232:
        raise InputError(f"argument `domain_id` must be an integer in [0, 232], got {domain_id!r:.40}")
    for name, value, top in (("time_limit_s", time_limit_s, 86_400.0), ("reply_timeout_s", reply_timeout_s, 600.0)):
        if value is None and name == "time_limit_s":
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and 0 < value <= top):
            raise InputError(f"argument `{name}` must be a number of seconds in (0, {top:.0f}], got {value!r:.40}")
    node_config = None if node_config is None else NodeConfig.resolve(node_config, "node_config")
    if not isinstance(out, (str, os.PathLike)) or "\x00" in os.fspath(out):
        raise InputError(f"argument `out` must be a folder path, got {out!r:.60}")
    out_dir = Path(out)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"argument `out` must be a folder, got an existing {'file' if out_dir.is_file() else 'special file'}: {out_dir}")
    if node_config is not None and not (node_config.topics.cmd_vel_stamped and node_config.topics.diagnostics):
        raise InputError("argument `node_config`: the loop needs topics.cmd_vel_stamped and topics.diagnostics (they pace it)")
    out_dir.mkdir(parents=True, exist_ok=True)
    cfg = (node_config or NodeConfig()).replace(
        node={"domain_id": domain_id, "use_sim_time": True},
        qos={"sensors": "reliable_sensor", "odometry": "reliable_sensor"},
    )
    (out_dir / "node.toml").write_text(cfg.to_toml(), encoding="utf-8")
    setup = _ground_setup(scenario, seed, time_limit_s) if robot == "ground" else _drone_setup(scenario, seed, time_limit_s)
    sim, dt = setup["sim"], setup["dt"]
    ts = typestore()
    t = cfg.topics
    q = "reliable_sensor"
    with RosParticipant(domain_id, loopback=True) as dds:
        pubs = {
            "clock": dds.publisher(t.clock, "rosgraph_msgs/msg/Clock"),
            "tf_static": dds.publisher(t.tf_static, "tf2_msgs/msg/TFMessage", "transient_local"),
            "tf": dds.publisher(t.tf, "tf2_msgs/msg/TFMessage"),
            "odom": dds.publisher(t.odometry[0], "nav_msgs/msg/Odometry", q),
            "goal": dds.publisher(t.goal, "geometry_msgs/msg/PoseStamped"),
        }
        if robot == "ground":
            pubs["points"] = dds.publisher(t.points, "sensor_msgs/msg/PointCloud2", q)
        else:
            pubs["depth"] = dds.publisher(t.depth[0], "sensor_msgs/msg/Image", q)
            pubs["info"] = dds.publisher(t.camera_info[0], "sensor_msgs/msg/CameraInfo", q)
        cmd_sub = dds.subscriber(t.cmd_vel_stamped, "geometry_msgs/msg/TwistStamped")
        diag_sub = dds.subscriber(t.diagnostics, "diagnostic_msgs/msg/DiagnosticArray")
        log = (out_dir / "node.log").open("w", encoding="utf-8")
        stats_path = out_dir / "node-stats.json"
        stats_path.unlink(missing_ok=True)
        # SciPy's Rotation (the tf and odometry messages below) is imported before the node starts:
        # its import (about a second on a busy machine) would otherwise sit between the node's
        # start and the goal, and the node's watchdog counts from its start.
        ros._transform_module()
        cmd = [sys.executable, "-m", "subterra.cli", "node", robot, "--config", str(out_dir / "node.toml"), "--loopback",
               "--stats", str(stats_path)]
        node = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        try:
            # Discovery: every publisher heard by the node, and its commands heard here.
            deadline = time.monotonic() + DISCOVERY_TIMEOUT_S
            waiting = [p for k, p in pubs.items() if k != "clock"] + [pubs["clock"], cmd_sub]
            while not all(e.matched for e in waiting):
                if node.poll() is not None:
                    raise SilError(f"the node exited with status {node.returncode} before it joined the domain: "
                                   f"{_tail(out_dir / 'node.log')}")
                if time.monotonic() > deadline:
                    missing = [e.topic for e in waiting if not e.matched]
                    raise SilError(f"the node did not appear on DDS domain {domain_id} within {DISCOVERY_TIMEOUT_S:.0f} s "
                                   f"(no match on {', '.join(missing)})")
                time.sleep(0.02)
            obs = sim.observe(**setup["observe"])
            t0 = _stamp_ns(obs["time_s"])
            body = cfg.frames.body
            # The sensor's mounting, as the simulator has it: body_from_sensor = body_from_world @ world_from_sensor.
            body_from_sensor = np.linalg.inv(np.asarray(obs["world_from_body"], dtype=np.float64)) @ np.asarray(
                obs["world_from_sensor"][setup["sensor"]], dtype=np.float64)
            pubs["tf_static"].publish(ros.tf_message([(body, setup["sensor_frame"], t0, body_from_sensor)], ts))
            pubs["clock"].publish(ros.clock_message(t0, ts))
            goal = np.eye(4)
            goal[:3, 3] = setup["goal"]
            pubs["goal"].publish(ros.pose_stamped_message(goal, stamp_ns=t0, frame_id=cfg.frames.world, typestore=ts))
            rows: list[list[Any]] = []
            latency: list[float] = []
            missed = missed_in_a_row = 0
            behaviour = ""
            true_risk: list[float] = []
            positions: list[np.ndarray] = []
            tilts: list[float] = []
            bar = None
            if progress:
                from subterra._extras import tqdm

                bar = tqdm(total=round(setup["time_limit_s"]), unit="s", desc=f"sil {robot} {scenario}", leave=False, disable=None,
                           bar_format="{desc}: {n:.0f}/{total:.0f} s sim {postfix}")
            while sim.status == "running":
                stamp = _stamp_ns(obs["time_s"])
                odom = np.asarray(obs["odometry"], dtype=np.float64)
                truth = np.asarray(obs["world_from_body"], dtype=np.float64)
                v_body = odom[:3, :3].T @ np.asarray(obs["velocity_world"], dtype=np.float64)
                pubs["clock"].publish(ros.clock_message(stamp, ts))
                pubs["tf"].publish(ros.tf_message([(cfg.frames.world, body, stamp, odom)], ts))
                pubs["odom"].publish(ros.odometry_message(odom, stamp_ns=stamp, frame_id=cfg.frames.world, child_frame_id=body,
                                                          twist=[*v_body, 0.0, 0.0, 0.0], typestore=ts))
                # The frame is built first: the latency runs from the moment it is handed to DDS.
                if robot == "ground":
                    frame = ts.serialize_cdr(ros.pointcloud2_message(obs["scans"]["lidar"], stamp_ns=stamp, frame_id=_LIDAR_FRAME,
                                                                     typestore=ts), "sensor_msgs/msg/PointCloud2")
                    sent = time.perf_counter()
                    pubs["points"].publish(frame)
                else:
                    pubs["info"].publish(ros.camera_info_message(setup["camera"], stamp_ns=stamp, frame_id=_CAMERA_FRAME, typestore=ts))
                    frame = ts.serialize_cdr(ros.image_message(obs["depth"]["front"], stamp_ns=stamp, frame_id=_CAMERA_FRAME,
                                                               encoding="16UC1", typestore=ts), "sensor_msgs/msg/Image")
                    sent = time.perf_counter()
                    pubs["depth"].publish(frame)
                command = None
                reply_deadline = time.monotonic() + reply_timeout_s
                while command is None and time.monotonic() < reply_deadline:
                    if node.poll() is not None:
                        raise SilError(f"the node exited with status {node.returncode} during the run: {_tail(out_dir / 'node.log')}")
                    dds.wait(0.02)
                    for msg in cmd_sub.take():
                        if ros.stamp_ns(msg.header) == stamp:
                            command = msg.twist
                    for msg in diag_sub.take():
                        for status in msg.status:
                            for kv in status.values:
                                if kv.key == "behaviour":
                                    behaviour = kv.value
                if command is None:
                    missed += 1
                    missed_in_a_row += 1
                    if missed_in_a_row >= MAX_MISSED_IN_A_ROW:
                        raise SilError(f"the node answered none of the last {missed_in_a_row} frames "
                                       f"(waited {reply_timeout_s:.0f} s for each): {_tail(out_dir / 'node.log')}")
                    vector = [0.0, 0.0, 0.0, 0.0]
                    lat = math.nan
                else:
                    missed_in_a_row = 0
                    lat = 1e3 * (time.perf_counter() - sent)
                    latency.append(lat)
                    vector = [command.linear.x, command.linear.y, command.linear.z, command.angular.z]
                    if robot == "ground":
                        vector = [command.linear.x, 0.0, 0.0, command.angular.z]
                step = sim.step(vector, dt, compute_time_s=0.0 if math.isnan(lat) else lat / 1e3)
                yaw = math.atan2(truth[1, 0], truth[0, 0])
                rows.append([obs["time_s"], *truth[:3, 3], yaw, *vector, lat, behaviour])
                if robot == "ground":
                    tilt = math.acos(max(-1.0, min(1.0, float(truth[2, 2]))))
                    tilts.append(tilt)
                    positions.append(truth[:3, 3].copy())
                    true_risk.append(setup["true_risk"](truth, tilt, yaw))
                if bar is not None:
                    bar.n = step["time_s"]
                    bar.set_postfix_str(f"latency {lat:.1f} ms, {behaviour}", refresh=False)
                    bar.update(0)
                if sim.status == "running":
                    if behaviour == "home":
                        sim.abort("returned_home")
                    elif behaviour == "failed":
                        sim.abort("gave_up")
                    else:
                        obs = sim.observe(**setup["observe"])
            if bar is not None:
                bar.close()
        finally:
            if node.poll() is None:
                node.send_signal(signal.SIGINT)
                try:
                    node.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    node.kill()
                    node.wait()
            log.close()
    metrics: dict[str, Any] = {
        "robot": robot,
        "scenario": scenario,
        "seed": seed,
        "transport": "ros2-dds",
        "domain_id": domain_id,
        "rate_hz": 1.0 / dt,
        "start": [float(v) for v in setup["start"]],
        "goal": [float(v) for v in setup["goal"]],
        "time_limit_s": setup["time_limit_s"],
        **{k: (v.item() if isinstance(v, np.generic) else v) for k, v in dict(sim.metrics()).items()},
        "latency_ms_median": float(np.median(latency)) if latency else None,
        "latency_ms_p99": float(np.percentile(latency, 99)) if latency else None,
        "commands_missed": missed,
        "final_behaviour": behaviour or None,
    }
    if robot == "ground" and positions:
        from subterra.drive.run import accumulated_risk

        metrics["accumulated_true_risk"] = accumulated_risk(np.asarray(true_risk), np.asarray(positions))
        metrics["max_tilt_deg"] = float(np.degrees(max(tilts)))
    metrics["node"] = json.loads(stats_path.read_text(encoding="utf-8")) if stats_path.is_file() else None
    with (out_dir / "trajectory.csv").open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["time_s", "x_m", "y_m", "z_m", "yaw_rad", "cmd_v_x", "cmd_v_y", "cmd_v_z", "cmd_yaw_rate", "latency_ms", "behaviour"])
        for r in rows:
            w.writerow([f"{r[0]:.3f}", *(f"{v:.4f}" for v in r[1:9]), f"{r[9]:.3f}", r[10]])
    (out_dir / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n", encoding="utf-8")
    return metrics


def _tail(path: Path, n: int = 12) -> str:
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").strip().splitlines()
    except OSError:
        return "(no log)"
    return "\n".join(lines[-n:]) or "(empty log)"


def _ground_setup(scenario: str, seed: int, time_limit_s: float | None) -> dict[str, Any]:
    from subterra import RobotConfig, TerrainConfig
    from subterra.drive.run import LIDAR_HEIGHT_M, true_risk, true_terrain_risk
    from subterra.sim import Lidar, Simulation, World
    from subterra.terrain import translation

    world = World.scenario(scenario, seed)
    regions = world.regions
    start = np.asarray(regions["start"][0][:2], dtype=np.float64)
    goal_xy = np.asarray(regions["goal"][0][:2], dtype=np.float64)
    yaw = math.atan2(goal_xy[1] - start[1], goal_xy[0] - start[0])
    body_from_sensor = translation(z=LIDAR_HEIGHT_M)
    sim = Simulation(world, "ground", {"lidar": (Lidar("os1_64"), body_from_sensor, "os1_64")}, seed=seed,
                     start=[start[0], start[1], 0.0], yaw=yaw)
    goal_z = world.ground_height(float(goal_xy[0]), float(goal_xy[1]))
    goal = np.array([goal_xy[0], goal_xy[1], 0.0 if goal_z is None else float(goal_z)])
    sim.set_goal(point=goal, radius_m=float(regions["goal"][1]))
    robot = RobotConfig().to_dict()
    ramps = TerrainConfig().to_dict()["risk"]
    if time_limit_s is None:
        time_limit_s = max(90.0, 4.0 * float(np.linalg.norm(goal_xy - start)) / (0.5 * float(robot["max_speed_m_s"])))
    sim.set_time_limit(time_limit_s)

    def risk(truth: np.ndarray, tilt: float, yaw_now: float) -> float:
        tilt_risk = float(true_risk(tilt, safe_deg=robot["tilt_safe_deg"], lethal_deg=robot["tilt_lethal_deg"]))
        return 1.0 - (1.0 - tilt_risk) * (1.0 - true_terrain_risk(world, truth[:2, 3], yaw_now, robot, ramps))

    return {"sim": sim, "dt": 0.1, "start": start, "goal": goal, "time_limit_s": time_limit_s, "observe": {},
            "sensor": "lidar", "sensor_frame": _LIDAR_FRAME, "true_risk": risk}


def _drone_setup(scenario: str, seed: int, time_limit_s: float | None) -> dict[str, Any]:
    from subterra import PerceptionConfig
    from subterra.flight.run import resolve_route
    from subterra.sim import DepthCamera, Simulation, World

    world = World.scenario(scenario, seed)
    _, a, b = resolve_route(world, None)
    regions = world.regions
    start = np.asarray(regions[a][0], dtype=np.float64)
    goal = np.asarray(regions[b][0], dtype=np.float64)
    camera = DepthCamera.d435()
    sim = Simulation(world, "quadrotor", {"front": (camera, None, "d435")}, seed=seed, start=start,
                     yaw=math.atan2(goal[1] - start[1], goal[0] - start[0]))
    sim.set_goal(region=b)
    v_max = float(PerceptionConfig.preset("flight-escape").to_dict()["apf"]["v_x_max_m_s"])
    if time_limit_s is None:
        time_limit_s = max(60.0, 4.0 * float(np.linalg.norm(goal - start)) / max(v_max, 1e-3))
    sim.set_time_limit(time_limit_s)
    return {"sim": sim, "dt": 1.0 / 15.0, "start": start, "goal": goal, "time_limit_s": time_limit_s,
            "observe": {"depth_dtype": "uint16"}, "sensor": "front", "sensor_frame": _CAMERA_FRAME, "camera": camera.camera}
