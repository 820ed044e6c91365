"""``subterra node ground|drone``: the library as a live ROS 2 node over DDS.

One process, three parts:

* the **receive thread** takes every sample DDS has for the node's subscriptions, decodes
  it (``rosbags``) and files it: transforms into a :class:`~subterra.io.ros.TransformBuffer`,
  poses into a track per odometry source, goals, the clock, camera infos. A sensor frame
  goes into a one-frame slot: **the latest frame wins**; a frame replaced before the
  compute thread took it is counted in ``frames_dropped``. The thread never waits on the
  computation.
* the **compute thread** takes the newest frame, checks that it can be trusted (see
  below), runs the same Rust pipeline as ``subterra drive`` (a :class:`subterra.Navigator`)
  or ``subterra fly`` (a :class:`subterra.Pilot`), which releases the GIL while it works,
  and publishes the command and the outputs.
* a **watchdog** in the compute thread: with no frame for ``safety.watchdog_s`` on the
  node's clock (the wall clock, or ``/clock`` with ``use_sim_time``), it publishes a stop.

A command is replaced by a stop (a zero ``Twist``) when it cannot be trusted: no goal
yet, a frame older than ``safety.max_input_age_s`` or stamped more than
``safety.max_future_s`` ahead of the node's clock, no pose within
``safety.max_odometry_age_s`` of the frame (or no usable odometry source), a transform
missing, or a non-finite value anywhere in the command. The reason is counted and goes to
``/diagnostics``; the node never arms a vehicle and only takes goals on ``topics.goal``.

Inputs and outputs (topic names, QoS and rates from :class:`~subterra.live.config.NodeConfig`):

============================  ======================================  =====================
topic (default)               type                                    robot
============================  ======================================  =====================
``/points``                   ``sensor_msgs/PointCloud2``             ground (in)
``/camera/depth/...``         ``sensor_msgs/Image`` + ``CameraInfo``   drone (in), per camera
``/odom``                     ``nav_msgs/Odometry``                   both (in), per source
``/goal_pose``                ``geometry_msgs/PoseStamped``           both (in)
``/tf``, ``/tf_static``       ``tf2_msgs/TFMessage``                  both (in)
``/clock``                    ``rosgraph_msgs/Clock``                 with ``use_sim_time``
``/cmd_vel``                  ``geometry_msgs/Twist`` (body, FLU)     both (out)
``/cmd_vel_stamped``          ``geometry_msgs/TwistStamped``          both (out): stamp = the frame's
``/subterra/path``            ``nav_msgs/Path``                       ground (out)
``/subterra/map``             ``nav_msgs/OccupancyGrid`` (Nav2)        ground (out)
``/subterra/grid_map``        ``grid_map_msgs/GridMap``               ground (out), every layer
``/subterra/belief``          ``visualization_msgs/MarkerArray``      drone (out)
``/diagnostics``              ``diagnostic_msgs/DiagnosticArray``     both (out)
============================  ======================================  =====================

>>> from subterra.live import GroundNode, NodeConfig
>>> node = GroundNode(NodeConfig.load("robot.toml"))
>>> node.run()          # until Ctrl-C (or node.stop() from another thread)
"""

from __future__ import annotations

import abc
import json
import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from subterra.errors import ConfigError, InputError, SubterraError
from subterra.io import ros
from subterra.live.config import NodeConfig
from subterra.live.dds import RosParticipant, typestore

__all__ = ["DroneNode", "GroundNode", "NodeStats", "ROBOTS", "make_node"]

#: The robots a node can drive.
ROBOTS = ("ground", "drone")
_NS = 1_000_000_000
# How much transform and pose history the node keeps [ns].
_HISTORY_NS = 10 * _NS
# With simulated time, how long a frame stamped ahead of /clock waits for the clock [s].
_CLOCK_GRACE_S = 0.1


@dataclass
class NodeStats:
    """What a node counted (``subterra node --stats FILE`` writes it as JSON at exit)."""

    frames_received: int = 0
    frames_processed: int = 0
    frames_dropped: int = 0
    commands: int = 0
    stops: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    goals: int = 0
    #: Frames whose pose was held from an older odometry sample (none newer had arrived).
    poses_extrapolated: int = 0
    compute_ms: list[float] = field(default_factory=list)
    #: The pipeline's own time per frame (the Rust step), inside ``compute_ms`` [ms].
    pipeline_ms: list[float] = field(default_factory=list)
    last_error: str = ""

    def stop(self, reason: str) -> None:
        self.stops[reason] = self.stops.get(reason, 0) + 1

    def reject(self, what: str, why: str) -> None:
        self.rejected[what] = self.rejected.get(what, 0) + 1
        self.last_error = f"{what}: {why}"

    def summary(self) -> dict[str, Any]:
        c = np.asarray(self.compute_ms, dtype=np.float64)
        p = np.asarray(self.pipeline_ms, dtype=np.float64)
        return {
            "frames_received": self.frames_received,
            "frames_processed": self.frames_processed,
            "frames_dropped": self.frames_dropped,
            "commands": self.commands,
            "stops": dict(self.stops),
            "rejected": dict(self.rejected),
            "goals": self.goals,
            "poses_extrapolated": self.poses_extrapolated,
            "compute_ms_median": float(np.median(c)) if c.size else None,
            "compute_ms_p99": float(np.percentile(c, 99)) if c.size else None,
            "pipeline_ms_median": float(np.median(p)) if p.size else None,
            "last_error": self.last_error,
        }


class _Stop(Exception):
    """This frame's command is a stop; the message is the reason (counted, in diagnostics)."""


class LiveNode(abc.ABC):
    """The receive thread, the compute thread, the safety checks and the outputs that both
    robots share; :class:`GroundNode` and :class:`DroneNode` add their pipeline."""

    robot = ""

    def __init__(self, config: NodeConfig | dict[str, Any] | str | os.PathLike[str] | None = None, *, loopback: bool = False, mavlink: Any = None, view: Any = None) -> None:
        from subterra.live.mavlink import MavlinkBridge
        from subterra.live.view import FoxgloveView

        if mavlink is not None and not isinstance(mavlink, MavlinkBridge):
            raise InputError(f"argument `mavlink` must be a MavlinkBridge, got {type(mavlink).__name__}")
        if view is not None and not isinstance(view, FoxgloveView):
            raise InputError(f"argument `view` must be a FoxgloveView, got {type(view).__name__}")
        self.config = NodeConfig.resolve(config)
        #: A :class:`~subterra.live.mavlink.MavlinkBridge` that gets every command too (or None).
        self.mavlink = mavlink
        #: A :class:`~subterra.live.view.FoxgloveView` that shows every published message (or None).
        self.view = view
        c = self.config
        self.stats = NodeStats()
        self._dds = RosParticipant(c.node.domain_id, loopback=loopback)
        self._ts = typestore()
        if view is not None:
            self._dds.mirror = view.publish
        self._lock = threading.Lock()
        self._frame_ready = threading.Condition(self._lock)
        # The inputs the receive thread files (tf, poses, the mux, camera infos): the compute
        # thread reads them under this lock, never while the pipeline runs.
        self._inputs = threading.RLock()
        self._stopping = threading.Event()
        # SciPy's Rotation (tf, odometry) is imported now rather than by the first tf message on
        # the receive thread: the import takes about a second on a busy machine, and frames
        # waiting behind it would trip the watchdog.
        ros._transform_module()
        self._tf = ros.TransformBuffer(max_history_ns=_HISTORY_NS)
        self._tracks = {topic: ros.PoseTrack(max_history_ns=_HISTORY_NS) for topic in c.topics.odometry}
        self._twist: dict[str, tuple[int, np.ndarray]] = {}
        self._mux = None
        if len(c.topics.odometry) > 1:
            from subterra import OdometryMux

            self._mux = OdometryMux([(t, c.rates.odometry_hz) for t in c.topics.odometry])
        self._clock_ns: int | None = None
        self._goal: np.ndarray | None = None
        self._goal_new = False
        self._frame: Any = None
        self._frame_wall = 0.0
        self._last_frame_wall = time.monotonic()
        self._last_frame_clock_ns: int | None = None
        self._last_publish: dict[str, float] = {}
        self._state: dict[str, Any] = {"behaviour": "waiting for a goal"}
        self._last_stop_reason = ""
        self._frame_times: list[float] = []
        self._odometry_state: dict[str, Any] = {}
        q = c.qos
        t = c.topics
        sub = self._dds.subscriber
        self._subs: list[tuple[Any, Callable[[Any, Any], None]]] = []
        if c.node.use_sim_time:
            self._subs.append((sub(t.clock, "rosgraph_msgs/msg/Clock", "default"), self._on_clock))
        self._subs.append((sub(t.tf_static, "tf2_msgs/msg/TFMessage", q.tf_static), self._on_tf_static))
        self._subs.append((sub(t.tf, "tf2_msgs/msg/TFMessage", q.tf), self._on_tf))
        for topic in t.odometry:
            self._subs.append((sub(topic, "nav_msgs/msg/Odometry", q.odometry), self._on_odometry))
        self._subs.append((sub(t.goal, "geometry_msgs/msg/PoseStamped", q.goal), self._on_goal))
        pub = self._dds.publisher
        self._cmd = pub(t.cmd_vel, "geometry_msgs/msg/Twist", q.commands)
        self._cmd_stamped = pub(t.cmd_vel_stamped, "geometry_msgs/msg/TwistStamped", q.commands) if t.cmd_vel_stamped else None
        self._diag = pub(t.diagnostics, "diagnostic_msgs/msg/DiagnosticArray", q.outputs) if t.diagnostics else None
        self._setup()

    # ------------------------------------------------------------------ subclass hooks

    @abc.abstractmethod
    def _setup(self) -> None:
        """Subscribes the robot's sensor topics and makes its outputs."""

    @abc.abstractmethod
    def _compute(self, frame: Any, stamp_ns: int, pose: np.ndarray, speed: float, confidence: float) -> tuple[np.ndarray, np.ndarray, Any]:
        """The pipeline on one frame: returns the body-frame (linear, angular) command and a
        callable that publishes the other outputs (run after the command is out)."""

    @abc.abstractmethod
    def _on_new_goal(self, goal: np.ndarray) -> None:
        """Hands a new goal [m, world] to the pipeline."""

    # ------------------------------------------------------------------ receive thread

    def _now_ns(self) -> int | None:
        if self.config.node.use_sim_time:
            return self._clock_ns
        return time.time_ns()

    def _on_clock(self, msg: Any, _sub: Any) -> None:
        self._clock_ns = max(self._clock_ns or 0, ros.stamp_ns(msg.clock))

    def _on_tf_static(self, msg: Any, sub: Any) -> None:
        self._tf.add_message(msg, static=True, where=sub.topic)

    def _on_tf(self, msg: Any, sub: Any) -> None:
        self._tf.add_message(msg, static=False, where=sub.topic)

    def _on_odometry(self, msg: Any, sub: Any) -> None:
        sample = ros.decode_odometry(msg, where=sub.topic)
        world = ros._strip(msg.header.frame_id)
        body = ros._strip(msg.child_frame_id)
        frames = self.config.frames
        if world != frames.world or (body and body != frames.body):
            raise InputError(f"odometry from {world} to {body}; the node's frames are {frames.world} -> {frames.body}")
        self._tracks[sub.topic].add(sample.stamp_ns, sample.world_from_body)
        self._twist[sub.topic] = (sample.stamp_ns, np.asarray(sample.twist, dtype=np.float64))
        if self._mux is not None:
            self._mux.push(sub.topic, sample.stamp_ns / _NS, sample.world_from_body)

    def _on_goal(self, msg: Any, sub: Any) -> None:
        frame = ros._strip(msg.header.frame_id) or self.config.frames.world
        p = msg.pose.position
        point = np.array([p.x, p.y, p.z, 1.0], dtype=np.float64)
        if not np.all(np.isfinite(point)):
            raise InputError("a goal that is not finite")
        if frame != self.config.frames.world:
            stamp = ros.stamp_ns(msg.header)
            if not self._tf.can_transform(self.config.frames.world, frame, stamp or None):
                raise InputError(f"a goal in frame {frame!r}, with no transform to {self.config.frames.world!r}")
            point = self._tf.lookup(self.config.frames.world, frame, stamp or None) @ point
        self._goal = point[:3]
        self._goal_new = True
        self.stats.goals += 1

    def _file_frame(self, frame: Any) -> None:
        """Puts a sensor frame into the slot (latest wins) and wakes the compute thread."""
        with self._frame_ready:
            self.stats.frames_received += 1
            if self._frame is not None:
                self.stats.frames_dropped += 1
            self._frame = frame
            self._frame_wall = time.monotonic()
            self._frame_times.append(self._frame_wall)
            del self._frame_times[:-20]
            self._frame_ready.notify()

    def _receive(self) -> None:
        while not self._stopping.is_set():
            if not self._dds.wait(0.05):
                continue
            for sub, handle in self._subs:
                for msg in sub.take():
                    try:
                        with self._inputs:
                            handle(msg, sub)
                    except Exception as exc:  # noqa: BLE001 - a bad message is counted; the thread goes on
                        self.stats.reject(sub.topic, f"{type(exc).__name__}: {exc}" if not isinstance(exc, SubterraError) else str(exc))
                if sub.rejected:
                    self.stats.rejected[sub.topic] = self.stats.rejected.get(sub.topic, 0) + sub.rejected
                    self.stats.last_error = sub.last_error
                    sub.rejected = 0

    # ------------------------------------------------------------------ compute thread

    def _pose_at(self, stamp_ns: int) -> tuple[np.ndarray, float, float]:
        """The body pose at ``stamp_ns`` from the odometry (the HeRO mux with several
        sources), the forward speed and the pose's confidence, or raises :class:`_Stop`."""
        limit = int(self.config.safety.max_odometry_age_s * _NS)
        if self._mux is not None:
            out = self._mux.update(stamp_ns / _NS)
            self._odometry_state = {"odometry_source": out.source or "none",
                                    "odometry_faults": json.dumps({k: v for k, v in out.faults.items() if v})}
            if out.world_from_body is None or out.source is None:
                raise _Stop("no usable odometry source")
            if stamp_ns - int(out.stamp * _NS) > limit:
                raise _Stop("odometry too old")
            return np.asarray(out.world_from_body), self._speed(out.source), float(out.confidence)
        topic = self.config.topics.odometry[0]
        track = self._tracks[topic]
        if track.latest is None:
            raise _Stop("no odometry yet")
        newest_ns, newest = track.latest
        if stamp_ns - newest_ns > limit:
            raise _Stop("odometry too old")
        if newest_ns < stamp_ns:
            self.stats.poses_extrapolated += 1
        pose = track.at(stamp_ns)
        return np.asarray(newest if pose is None else pose), self._speed(topic), 1.0

    def _speed(self, topic: str) -> float:
        item = self._twist.get(topic)
        return float(item[1][0]) if item is not None and math.isfinite(item[1][0]) else 0.0

    def _check_stamp(self, stamp_ns: int) -> None:
        now = self._now_ns()
        s = self.config.safety
        if self.config.node.use_sim_time and (now is None or stamp_ns - now > s.max_future_s * _NS):
            # /clock and the frame travel on different topics: give the clock a moment to catch up.
            deadline = time.monotonic() + _CLOCK_GRACE_S
            while time.monotonic() < deadline and (now is None or stamp_ns - now > s.max_future_s * _NS):
                time.sleep(0.002)
                now = self._now_ns()
        if now is None:
            raise _Stop("no clock yet")
        if stamp_ns - now > s.max_future_s * _NS:
            raise _Stop("frame from the future")
        if now - stamp_ns > s.max_input_age_s * _NS:
            raise _Stop("stale frame")

    def _process(self, frame: Any, received_wall: float) -> None:
        stamp_ns = frame.stamp_ns
        started = time.perf_counter()
        reason = ""
        try:
            with self._inputs:
                goal, new_goal, self._goal_new = self._goal, self._goal_new, False
            if goal is None:
                raise _Stop("no goal")
            if new_goal:
                self._on_new_goal(goal.copy())
            self._check_stamp(stamp_ns)
            with self._inputs:
                pose, speed, confidence = self._pose_at(stamp_ns)
            linear, angular, outputs = self._compute(frame, stamp_ns, pose, speed, confidence)
            if not (np.all(np.isfinite(linear)) and np.all(np.isfinite(angular))):
                raise _Stop("non-finite command")
        except _Stop as stop:
            reason = str(stop)
            linear = angular = np.zeros(3)
            outputs = None
        except SubterraError as exc:
            reason = "pipeline error"
            self.stats.last_error = str(exc)
            linear = angular = np.zeros(3)
            outputs = None
        except Exception as exc:  # noqa: BLE001 - a bug must stop the robot, not the node
            reason = "internal error"
            self.stats.last_error = f"{type(exc).__name__}: {exc}"
            linear = angular = np.zeros(3)
            outputs = None
        self.stats.frames_processed += 1
        self._publish_command(linear, angular, stamp_ns, reason)
        self.stats.compute_ms.append(1e3 * (time.perf_counter() - started))
        if outputs is not None:  # the path, maps and markers go out after the command
            outputs()

    def _publish_command(self, linear: np.ndarray, angular: np.ndarray, stamp_ns: int, reason: str = "") -> None:
        if reason:
            self.stats.stop(reason)
            if reason != self._last_stop_reason:
                self._publish_diagnostics(stamp_ns, force=True, stop=reason)
        self._last_stop_reason = reason
        if self.mavlink is not None:  # a stop for untrusted inputs is not fresh: the stream ends
            self.mavlink.command(linear, float(angular[2]), fresh=not reason)
        self._cmd.publish(ros.twist_message(linear, angular, self._ts))
        if self._cmd_stamped is not None:
            self._cmd_stamped.publish(ros.twist_stamped_message(linear, angular, stamp_ns=stamp_ns, frame_id=self.config.frames.body,
                                                                typestore=self._ts))
        self.stats.commands += 1
        self._publish_diagnostics(stamp_ns)

    def _due(self, name: str, rate_hz: float, force: bool = False) -> bool:
        if rate_hz <= 0.0 and not force:
            return False
        now = time.monotonic()
        last = self._last_publish.get(name)
        if force or last is None or now - last >= 1.0 / rate_hz:
            self._last_publish[name] = now
            return True
        return False

    def _publish_diagnostics(self, stamp_ns: int, *, force: bool = False, stop: str = "") -> None:
        if self._diag is None or not self._due("diagnostics", self.config.rates.diagnostics_hz, force):
            return
        s = self.stats.summary()
        times = self._frame_times[-20:]
        rate = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 and times[-1] > times[0] else 0.0
        values = {**self._state, **self._odometry_state, "frame_rate_hz": round(rate, 2),
                  "frames_received": s["frames_received"], "frames_processed": s["frames_processed"],
                  "frames_dropped": s["frames_dropped"], "compute_ms_median": s["compute_ms_median"],
                  "compute_ms_p99": s["compute_ms_p99"], "pipeline_ms_median": s["pipeline_ms_median"],
                  "stops": json.dumps(s["stops"]), "rejected": json.dumps(s["rejected"])}
        level = "warn" if stop or self._last_stop_reason else "ok"
        message = f"stop: {stop or self._last_stop_reason}" if level == "warn" else str(self._state.get("behaviour", "running"))
        self._diag.publish(ros.diagnostics_message([(f"{self.config.node.name}: {self.robot}", level, message, values)],
                                                   stamp_ns=stamp_ns, hardware_id=self.config.node.name, typestore=self._ts))

    def _compute_loop(self) -> None:
        watchdog = self.config.safety.watchdog_s
        while not self._stopping.is_set():
            with self._frame_ready:
                if self._frame is None:
                    self._frame_ready.wait(timeout=min(0.05, watchdog))
                frame, self._frame = self._frame, None
                received = self._frame_wall
            if frame is not None:
                self._last_frame_wall = time.monotonic()
                self._last_frame_clock_ns = self._clock_ns
                self._process(frame, received)
            elif self._goal is not None and self._watchdog_due(watchdog):
                # No frame for a watchdog period: stop, once per period.
                now = self._now_ns() or 0
                self._publish_command(np.zeros(3), np.zeros(3), now, "no frame (watchdog)")

    def _watchdog_due(self, watchdog_s: float) -> bool:
        """Whether no frame came for ``watchdog_s`` on the node's clock; if so the period starts
        again. With ``use_sim_time`` that is ``/clock``: a simulator that is slow or paused has
        lost no sensor (its time stands still too), and before the first clock nothing is due."""
        if not self.config.node.use_sim_time:
            if time.monotonic() - self._last_frame_wall <= watchdog_s:
                return False
            self._last_frame_wall = time.monotonic()
            return True
        now = self._clock_ns
        if now is None:
            return False
        if self._last_frame_clock_ns is None:
            self._last_frame_clock_ns = now
        if now - self._last_frame_clock_ns <= watchdog_s * _NS:
            return False
        self._last_frame_clock_ns = now
        return True

    # ------------------------------------------------------------------ running

    def run(self, duration_s: float | None = None) -> NodeStats:
        """Runs until :meth:`stop` (or ``duration_s`` of wall time); returns the counts. A stop
        command is published on the way out."""
        if duration_s is not None and (isinstance(duration_s, bool) or not isinstance(duration_s, (int, float))
                                       or not (math.isfinite(duration_s) and 0 < duration_s <= 1e7)):
            raise InputError(f"argument `duration_s` must be a number of seconds in (0, 1e7], or None, got {duration_s!r:.40}")
        if self._dds._dp is None:
            raise InputError("this node is closed")
        receiver = threading.Thread(target=self._receive, name="subterra-node-receive", daemon=True)
        receiver.start()
        deadline = None if duration_s is None else time.monotonic() + duration_s
        computer = threading.Thread(target=self._compute_loop, name="subterra-node-compute", daemon=True)
        computer.start()
        try:
            while computer.is_alive() and (deadline is None or time.monotonic() < deadline):
                computer.join(timeout=0.1)
        finally:
            self._stopping.set()
            computer.join(timeout=5.0)
            receiver.join(timeout=5.0)
            try:
                self._cmd.publish(ros.twist_message(np.zeros(3), np.zeros(3), self._ts))
            except Exception:  # noqa: BLE001 - the domain may already be gone at shutdown
                pass
        return self.stats

    def stop(self) -> None:
        """Asks :meth:`run` to return (thread-safe)."""
        self._stopping.set()

    def close(self) -> None:
        """Leaves the DDS domain."""
        self._stopping.set()
        self._dds.close()

    def __enter__(self) -> LiveNode:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass
class _CloudFrame:
    stamp_ns: int
    frame_id: str
    points: np.ndarray


class GroundNode(LiveNode):
    """The ground robot: point clouds -> :class:`subterra.Navigator` (terrain map, risk-aware
    A*, MPC, recoveries) -> ``(v, ω)`` on ``cmd_vel``; path, Nav2 occupancy grid, every map
    layer as a ``GridMap``, and the behaviour in ``/diagnostics``."""

    robot = "ground"

    def _setup(self) -> None:
        c = self.config
        self._nav = self._make_navigator(_navigator_config(c.ground.navigator_config))  # a bad setting fails here, named
        self._subs.append((self._dds.subscriber(c.topics.points, "sensor_msgs/msg/PointCloud2", c.qos.sensors), self._on_points))
        pub = self._dds.publisher
        self._path = pub(c.topics.path, "nav_msgs/msg/Path", c.qos.outputs) if c.topics.path else None
        self._map = pub(c.topics.map, "nav_msgs/msg/OccupancyGrid", c.qos.maps) if c.topics.map else None
        self._grid_map = pub(c.topics.grid_map, "grid_map_msgs/msg/GridMap", c.qos.maps) if c.topics.grid_map else None

    def _on_points(self, msg: Any, sub: Any) -> None:
        cloud = ros.decode_pointcloud2(msg, where=sub.topic)
        self._file_frame(_CloudFrame(cloud.stamp_ns, ros._strip(cloud.frame_id), cloud.points))

    def _make_navigator(self, config: dict[str, Any]) -> Any:
        """The navigator, made at start (its goal is set when one arrives; home is where the
        robot is at its first step)."""
        from subterra import Navigator

        config = dict(config)
        terrain = {"ground": {"void_min_gap_deg": self.config.ground.void_min_gap_deg}}
        sections = config.pop("terrain", None) or {}
        if not isinstance(sections, dict):
            raise ConfigError(f"ground.navigator_config: terrain must be a table, got {sections!r:.60}")
        for section, values in sections.items():
            if not isinstance(values, dict):
                raise ConfigError(f"ground.navigator_config: terrain.{section} must be a table, got {values!r:.60}")
            terrain[section] = {**terrain.get(section, {}), **values}
        return Navigator(goal=[0.0, 0.0], config=config, terrain=terrain)

    def _on_new_goal(self, goal: np.ndarray) -> None:
        self._nav.set_goal(goal[:2])

    def _compute(self, frame: _CloudFrame, stamp_ns: int, pose: np.ndarray, speed: float, confidence: float) -> tuple[np.ndarray, np.ndarray, Any]:
        body = self.config.frames.body
        sensor = frame.frame_id or body
        with self._inputs:
            if not self._tf.can_transform(body, sensor, stamp_ns):
                raise _Stop(f"no transform {body} <- {sensor}")
            body_from_sensor = self._tf.lookup(body, sensor, stamp_ns)
        out = self._nav.step(frame.points, stamp=stamp_ns / _NS, world_from_body=pose, body_from_sensor=body_from_sensor,
                             speed=speed, confidence=confidence)
        self.stats.pipeline_ms.append(1e3 * out.timings["total_s"])
        self._state = {"behaviour": out.behaviour, "target": out.target, "plan_status": out.plan_status or "",
                       "mpc_status": out.mpc_status or "", "local_risk": round(float(out.local_risk), 4),
                       "safety": out.safety or ""}

        def outputs() -> None:
            world = self.config.frames.world
            if self._path is not None and len(out.path_world):
                self._path.publish(ros.path_message(np.asarray(out.path_world), stamp_ns=stamp_ns, frame_id=world, typestore=self._ts))
            risk_map = self._nav.risk_map
            if risk_map is not None:
                if self._map is not None and self._due("map", self.config.rates.map_hz):
                    self._map.publish(ros.occupancy_grid_message(risk_map, stamp_ns=stamp_ns, frame_id=world, typestore=self._ts))
                if self._grid_map is not None and self._due("grid_map", self.config.rates.grid_map_hz):
                    self._grid_map.publish(ros.grid_map_message(risk_map, stamp_ns=stamp_ns, frame_id=world, typestore=self._ts))
            if out.transitions:
                self._publish_diagnostics(stamp_ns, force=True)

        v, w = out.command
        return np.array([v, 0.0, 0.0]), np.array([0.0, 0.0, w]), outputs


@dataclass
class _DepthFrame:
    stamp_ns: int
    images: list[Any]  # one DepthImage per camera, camera 0's is this frame's
    frame_ids: list[str]
    stamps: list[int]  # each camera's frame stamp [ns]


class DroneNode(LiveNode):
    """The drone: depth images (one or more cameras) -> :class:`subterra.Pilot` (APF-PF, the
    obstacle memory, the escape) -> a body-frame velocity on ``cmd_vel``; the belief as
    markers. The pilot is made when every camera's ``CameraInfo`` and mounting transform
    have been seen and a goal has arrived."""

    robot = "drone"

    def _setup(self) -> None:
        c = self.config
        self._pilot = None
        self._infos: dict[int, Any] = {}
        self._latest: dict[int, tuple[int, Any, str]] = {}
        # Camera 0 paces the loop: its subscription is taken last in each pass, so that the
        # other cameras' images of the same instant are already filed when its frame pairs them.
        for i, (depth, info) in reversed(list(enumerate(zip(c.topics.depth, c.topics.camera_info)))):
            self._subs.append((self._dds.subscriber(info, "sensor_msgs/msg/CameraInfo", c.qos.sensors), self._info_handler(i)))
            self._subs.append((self._dds.subscriber(depth, "sensor_msgs/msg/Image", c.qos.sensors), self._depth_handler(i)))
        self._belief = self._dds.publisher(c.topics.belief, "visualization_msgs/msg/MarkerArray", c.qos.outputs) if c.topics.belief else None
        self._centres = None

    def _info_handler(self, i: int) -> Callable[[Any, Any], None]:
        def handle(msg: Any, sub: Any) -> None:
            if i not in self._infos:
                self._infos[i] = ros.decode_camera_info(msg, where=sub.topic)
        return handle

    def _depth_handler(self, i: int) -> Callable[[Any, Any], None]:
        def handle(msg: Any, sub: Any) -> None:
            image = ros.decode_depth_image(msg, where=sub.topic)
            stamp = ros.stamp_ns(msg.header)
            self._latest[i] = (stamp, image, ros._strip(msg.header.frame_id))
            if i == 0:  # camera 0 paces the loop; the others give their newest frame
                cams = [self._latest.get(k) for k in range(len(self.config.topics.depth))]
                if all(cam is not None for cam in cams):
                    self._file_frame(_DepthFrame(stamp, [cam[1] for cam in cams], [cam[2] for cam in cams], [cam[0] for cam in cams]))
        return handle

    def _on_new_goal(self, goal: np.ndarray) -> None:
        if self._pilot is not None:
            self._pilot.set_goal(goal)

    def _make_pilot(self, frame: _DepthFrame, stamp_ns: int) -> None:
        from subterra import Pilot

        cameras = []
        for i, frame_id in enumerate(frame.frame_ids):
            if i not in self._infos:
                raise _Stop(f"no camera info for camera {i}")
            body = self.config.frames.body
            if not self._tf.can_transform(body, frame_id or body, stamp_ns):
                raise _Stop(f"no transform {body} <- {frame_id}")
            cameras.append((self._infos[i].to_camera(), self._tf.lookup(body, frame_id or body, stamp_ns)))
        d = self.config.drone
        self._pilot = Pilot(cameras, d.preset, controller=d.controller, seed=d.seed)
        self._pilot.set_goal(self._goal)
        self._centres = self._pilot.voxel_centres("body")
        self._free = self._pilot.free_state()

    def _compute(self, frame: _DepthFrame, stamp_ns: int, pose: np.ndarray, speed: float, confidence: float) -> tuple[np.ndarray, np.ndarray, Any]:
        with self._inputs:
            if self._pilot is None:
                self._make_pilot(frame, stamp_ns)
        for i, stamp in enumerate(frame.stamps):
            if abs(stamp - stamp_ns) > self.config.safety.max_input_age_s * _NS:
                raise _Stop(f"camera {i} frame stale")
        scale = frame.images[0].scale_m_per_unit if frame.images[0].data.dtype == np.uint16 else None
        data = [im.data for im in frame.images]
        out = self._pilot.step(data if len(data) > 1 else data[0], stamp=stamp_ns / _NS, world_from_body=pose, scale=scale,
                               confidence=confidence)
        cmd = np.asarray(out.command.as_array(), dtype=np.float64)
        self.stats.pipeline_ms.append(1e3 * out.timings["total_s"])
        self._state = {"behaviour": "escape" if out.escape_active else "apf", "remaining_m": round(float(out.remaining_m), 3)}

        def outputs() -> None:
            if self._belief is not None and self._due("belief", self.config.rates.belief_hz):
                p = out.perceptions[0]
                states = np.asarray(p.belief_states, dtype=np.int64)
                probs = np.asarray(p.belief_probabilities, dtype=np.float64)
                keep = states != self._free
                centres = self._centres[states[keep]] if keep.any() else np.zeros((0, 3))
                self._belief.publish(ros.belief_markers_message(centres, probs[keep], stamp_ns=stamp_ns,
                                                                frame_id=self.config.frames.body, p_free=p.p_free, typestore=self._ts))

        return cmd[:3], np.array([0.0, 0.0, cmd[3]]), outputs


def _navigator_config(path: str) -> dict[str, Any]:
    if not path:
        return {}
    from subterra._files import read_toml
    from subterra.errors import FileFormatError

    try:
        return read_toml(path, "navigator config")
    except (FileFormatError, ConfigError) as exc:
        raise ConfigError(f"ground.navigator_config: {exc}") from exc


def make_node(robot: str, config: NodeConfig | None = None, *, loopback: bool = False, mavlink: Any = None,
              view: Any = None) -> LiveNode:
    """A :class:`GroundNode` or :class:`DroneNode` (``robot``: one of :data:`ROBOTS`);
    ``mavlink``: a :class:`~subterra.live.mavlink.MavlinkBridge` that also gets the commands;
    ``view``: a :class:`~subterra.live.view.FoxgloveView` that shows what the node publishes."""
    if not isinstance(robot, str) or robot not in ROBOTS:
        raise InputError(f"argument `robot` must be one of {', '.join(ROBOTS)}, got {robot!r:.40}")
    return (GroundNode if robot == "ground" else DroneNode)(config, loopback=loopback, mavlink=mavlink, view=view)


def write_stats(stats: NodeStats, path: str | os.PathLike[str]) -> Path:
    """Writes :meth:`NodeStats.summary` as JSON."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(stats.summary(), indent=2) + "\n", encoding="utf-8")
    return p
