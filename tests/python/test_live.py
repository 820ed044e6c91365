"""The live ROS 2 bridge (subterra.live): DDS plumbing, the node's safety rules, the wire
format of every published type, and software in the loop in two processes.

Everything runs on the loopback interface with Cyclone DDS (the extra subterra[ros]; make
test installs it). Each test takes its own DDS domain so that tests and runs side by side do
not hear each other.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="the ROS 2 bridge needs the extra subterra[ros] (cyclonedds)")

from subterra.errors import ConfigError, InputError  # noqa: E402
from subterra.io import ros  # noqa: E402
from subterra.live import dds  # noqa: E402
from subterra.live.config import NodeConfig  # noqa: E402
from subterra.live.node import DroneNode, GroundNode, make_node  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
NS = 1_000_000_000


def _domain(offset: int) -> int:
    """The DDS domain of one test: a block of 25 domains per pytest-xdist worker, so that no two
    tests of one run ever share a domain (a node on a shared domain would hear the other
    test's goals and frames). The block is shifted per run (its uid), which keeps two runs
    side by side apart too, most of the time."""
    assert 0 <= offset < 25, offset
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID") or str(os.getppid())
    shift = int(hashlib.sha256(run.encode()).hexdigest(), 16) % 8
    return 1 + ((index + shift) % 8) * 25 + offset


def _flat_ground(height_m: float = 0.7) -> np.ndarray:
    """A lidar scan of flat open ground ``height_m`` below the sensor: rings every 0.1 m, 1°."""
    r, a = np.meshgrid(np.arange(1.0, 10.0, 0.1), np.radians(np.arange(0.0, 360.0, 1.0)))
    return np.stack([r * np.cos(a), r * np.sin(a), np.full_like(r, -height_m)], -1).reshape(-1, 3).astype(np.float32)


def _lidar_mount() -> np.ndarray:
    m = np.eye(4)
    m[2, 3] = 0.7
    return m


class Driver:
    """The robot's side of the wire for a node under test: publishes clock, tf, odometry,
    goals and frames; keeps the raw bytes of everything the node publishes."""

    OUTPUTS = {
        "/cmd_vel": "geometry_msgs/msg/Twist",
        "/cmd_vel_stamped": "geometry_msgs/msg/TwistStamped",
        "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
        "/subterra/path": "nav_msgs/msg/Path",
        "/subterra/map": "nav_msgs/msg/OccupancyGrid",
        "/subterra/grid_map": "grid_map_msgs/msg/GridMap",
        "/subterra/belief": "visualization_msgs/msg/MarkerArray",
    }

    def __init__(self, domain: int, robot: str) -> None:
        self.ts = dds.typestore()
        self.dds = dds.RosParticipant(domain, loopback=True)
        p = self.dds.publisher
        self.clock = p("/clock", "rosgraph_msgs/msg/Clock")
        self.tf_static = p("/tf_static", "tf2_msgs/msg/TFMessage", "transient_local")
        self.odom = p("/odom", "nav_msgs/msg/Odometry", "reliable_sensor")
        self.goal = p("/goal_pose", "geometry_msgs/msg/PoseStamped")
        if robot == "ground":
            self.points = p("/points", "sensor_msgs/msg/PointCloud2", "reliable_sensor")
        else:
            self.depth = p("/camera/depth/image_rect_raw", "sensor_msgs/msg/Image", "reliable_sensor")
            self.info = p("/camera/depth/camera_info", "sensor_msgs/msg/CameraInfo", "reliable_sensor")
        self.outputs = {topic: self.dds.subscriber(topic, kind, "reliable_sensor" if topic.startswith("/cmd") else "default")
                        for topic, kind in self.OUTPUTS.items()}
        self.raw: dict[str, list[bytes]] = {topic: [] for topic in self.OUTPUTS}
        self.stamped: dict[int, Any] = {}

    def wait_for(self, node_topics: list, timeout_s: float = 30.0) -> None:
        assert self.dds.wait_matched(node_topics, timeout_s), "the node did not appear on the domain"

    def poll(self) -> None:
        for topic, sub in self.outputs.items():
            for cdr in sub.take_raw():
                self.raw[topic].append(cdr)
                if topic == "/cmd_vel_stamped":
                    msg = self.ts.deserialize_cdr(cdr, self.OUTPUTS[topic])
                    self.stamped[ros.stamp_ns(msg.header)] = msg.twist

    def reply(self, stamp: int, timeout_s: float = 10.0) -> Any:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.dds.wait(0.02)
            self.poll()
            if stamp in self.stamped:
                return self.stamped[stamp]
        raise AssertionError(f"no command stamped {stamp}")

    def tick(self, stamp: int, frame_stamp: int | None = None, *, odom_stamp: int | None = None, pose: np.ndarray | None = None,
             frame: Any = None) -> None:
        """Clock at ``stamp``, odometry at ``odom_stamp`` (default ``stamp``; None-like -1 skips it),
        then ``frame`` (a scan or a depth image) stamped ``frame_stamp`` (default ``stamp``)."""
        ts = self.ts
        self.clock.publish(ros.clock_message(stamp, ts))
        o = stamp if odom_stamp is None else odom_stamp
        if o >= 0:
            self.odom.publish(ros.odometry_message(np.eye(4) if pose is None else pose, stamp_ns=o, typestore=ts))
        f = stamp if frame_stamp is None else frame_stamp
        if hasattr(self, "points"):
            self.points.publish(ros.pointcloud2_message(_flat_ground() if frame is None else frame, stamp_ns=f, frame_id="lidar", typestore=ts))
        else:
            from subterra import PinholeCamera

            cam = PinholeCamera(40.0, 40.0, 31.5, 23.5, 64, 48)
            self.info.publish(ros.camera_info_message(cam, stamp_ns=f, frame_id="camera", typestore=ts))
            image = np.full((48, 64), 800, np.uint16) if frame is None else frame  # a wall 0.8 m ahead
            self.depth.publish(ros.image_message(image, stamp_ns=f, frame_id="camera", encoding="16UC1", typestore=ts))

    def send_goal(self, xyz: tuple[float, float, float], frame_id: str = "odom", stamp: int = 0) -> None:
        """A goal as another ROS 2 node would send it (built field by field: NaN allowed)."""
        t = self.ts.types
        pose = t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=xyz[0], y=xyz[1], z=xyz[2]),
                                           orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
        self.goal.publish(t["geometry_msgs/msg/PoseStamped"](header=ros.header(stamp, frame_id, self.ts), pose=pose))

    def close(self) -> None:
        self.dds.close()


def _start(node) -> threading.Thread:
    t = threading.Thread(target=node.run, kwargs={"duration_s": 120.0}, daemon=True)
    t.start()
    return t


def _shutdown(node, thread: threading.Thread, *others) -> None:
    """Stops the node's run, leaves its domain, then closes the test's own endpoints."""
    node.stop()
    thread.join(timeout=10)
    node.close()
    for other in others:
        other.close()


def _config(domain: int, **rates: float) -> NodeConfig:
    return NodeConfig().replace(
        node={"domain_id": domain, "use_sim_time": True},
        qos={"sensors": "reliable_sensor", "odometry": "reliable_sensor", "commands": "reliable_sensor", "maps": "default"},
        rates={"map_hz": 100.0, "grid_map_hz": 100.0, "diagnostics_hz": 100.0, "belief_hz": 100.0, **rates},
    )


def _typed_equal(cdr: bytes, msgtype: str) -> None:
    """The bytes decode with rosbags (the ROS 2 typestore) and with Cyclone DDS's own typed CDR
    code, to the same values, and Cyclone's re-encoding is the same bytes."""
    ts = dds.typestore()
    a = ts.deserialize_cdr(cdr, msgtype)
    typed = dds.typed_idl_type(msgtype)
    b = typed.deserialize(cdr)

    def same(x, y, where):
        if hasattr(y, "__dataclass_fields__"):  # the message's fields (rosbags also lists its constants)
            for name in y.__dataclass_fields__:
                same(getattr(x, name), getattr(y, name), f"{where}.{name}")
        elif isinstance(x, np.ndarray):
            assert np.array_equal(np.asarray(x), np.asarray(y, dtype=x.dtype), equal_nan=x.dtype.kind == "f"), where
        elif isinstance(x, (list, tuple)):
            assert len(x) == len(y), where
            for i, (u, v) in enumerate(zip(x, y)):
                same(u, v, f"{where}[{i}]")
        elif isinstance(x, float) and math.isnan(x):
            assert math.isnan(y), where
        else:
            assert x == y, f"{where}: {x!r} != {y!r}"

    same(a, b, msgtype)
    assert bytes(b.serialize()).ljust(len(cdr), b"\0") == cdr, f"{msgtype}: Cyclone re-encodes to other bytes"


# ---------------------------------------------------------------------- config


def test_node_config_file_is_the_defaults_and_bad_fields_are_named(tmp_path):
    """configs/node.toml is NodeConfig(); an unknown field, a bad QoS, topic or number is a
    ConfigError naming the dotted field (and the file)."""
    assert NodeConfig.load(REPO / "configs" / "node.toml") == NodeConfig()
    assert NodeConfig.from_dict(NodeConfig().to_dict()) == NodeConfig()
    with pytest.raises(ConfigError, match=r"safety\.max_age_s is not a setting"):
        NodeConfig.from_dict({"safety": {"max_age_s": 1.0}})
    with pytest.raises(ConfigError, match=r"qos\.sensors must be one of"):
        NodeConfig.from_dict({"qos": {"sensors": "fast"}})
    with pytest.raises(ConfigError, match=r"topics\.cmd_vel"):
        NodeConfig.from_dict({"topics": {"cmd_vel": "/bad topic"}})
    with pytest.raises(ConfigError, match=r"safety\.watchdog_s must be finite, got nan"):
        NodeConfig.from_dict({"safety": {"watchdog_s": float("nan")}})
    with pytest.raises(ConfigError, match=r"node\.domain_id must be in \[0, 232\]"):
        NodeConfig.from_dict({"node": {"domain_id": 500}})
    with pytest.raises(ConfigError, match=r"topics\.depth and topics\.camera_info must pair"):
        NodeConfig.from_dict({"topics": {"depth": ["/a", "/b"]}})
    bad = tmp_path / "bad.toml"
    bad.write_text("[rates]\nmap_hz = 'often'\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"rates\.map_hz must be a number.*bad\.toml"):
        NodeConfig.load(bad)
    with pytest.raises(InputError, match="robot"):
        make_node("boat", NodeConfig())


def test_dds_names_follow_the_ros2_conventions():
    assert dds.dds_topic_name("/cmd_vel") == "rt/cmd_vel"
    assert dds.dds_topic_name("ns/points") == "rt/ns/points"
    assert dds.dds_type_name("sensor_msgs/msg/Image") == "sensor_msgs::msg::dds_::Image_"
    with pytest.raises(InputError, match="topic"):
        dds.dds_topic_name("/9lives")
    with pytest.raises(InputError, match="domain_id"):
        dds.RosParticipant(233)


# ---------------------------------------------------------------------- ground node


def test_ground_node_over_dds_commands_publishes_every_output_and_stops_when_inputs_cannot_be_trusted():
    """A GroundNode fed over DDS: it answers each frame with a command stamped with the
    frame's stamp, drives toward the goal on open ground, and publishes the path, the Nav2
    occupancy grid, the grid map and diagnostics, every one decoding as its ROS 2 type with
    rosbags and with Cyclone's typed CDR. A stale frame, a frame from the future and old
    odometry each get a stop, counted by reason."""
    domain = _domain(1)
    node = GroundNode(_config(domain), loopback=True)
    driver = Driver(domain, "ground")
    try:
        thread = _start(node)
        driver.wait_for([driver.points, driver.odom, driver.goal, driver.clock, driver.outputs["/cmd_vel_stamped"]])
        driver.tf_static.publish(ros.tf_message([("base_link", "lidar", 0, _lidar_mount())], driver.ts))
        # No goal yet: a stop.
        driver.tick(1 * NS)
        assert driver.reply(1 * NS).linear.x == 0.0
        driver.send_goal((4.0, 0.0, 0.0))
        time.sleep(0.2)
        speeds = []
        for k in range(2, 8):
            stamp = k * NS // 10 + NS
            driver.tick(stamp)
            speeds.append(driver.reply(stamp).linear.x)
        assert max(speeds) > 0.05, speeds
        # A frame 2 s old, a frame 1 s ahead of the clock, odometry 1 s behind the frame: stops.
        t = 3 * NS
        driver.tick(t, frame_stamp=t - 2 * NS + 1)
        assert driver.reply(t - 2 * NS + 1).linear.x == 0.0
        t += NS // 10
        driver.tick(t, frame_stamp=t + NS)
        assert driver.reply(t + NS).linear.x == 0.0
        t += NS
        driver.tick(t, odom_stamp=-1)  # the newest pose is now over 0.9 s older than the frame
        assert driver.reply(t).linear.x == 0.0
        time.sleep(0.3)
        driver.poll()
    finally:
        _shutdown(node, thread, driver)
    stops = node.stats.stops
    assert stops.get("no goal") == 1 and stops.get("stale frame") == 1, node.stats.summary()
    assert stops.get("frame from the future") == 1 and stops.get("odometry too old") == 1, stops
    assert node.stats.frames_dropped == 0
    for topic in ("/cmd_vel", "/cmd_vel_stamped", "/diagnostics", "/subterra/path", "/subterra/map", "/subterra/grid_map"):
        assert driver.raw[topic], f"nothing on {topic}"
        for cdr in driver.raw[topic][:3] + driver.raw[topic][-1:]:
            _typed_equal(cdr, Driver.OUTPUTS[topic])
    ts = dds.typestore()
    grid = ts.deserialize_cdr(driver.raw["/subterra/map"][-1], "nav_msgs/msg/OccupancyGrid")
    values = np.asarray(grid.data)
    assert values.size == grid.info.width * grid.info.height and values.min() >= -1 and values.max() <= 100
    assert (values >= 0).sum() > 100, "the open ground around the robot is observed"
    gm = ts.deserialize_cdr(driver.raw["/subterra/grid_map"][-1], "grid_map_msgs/msg/GridMap")
    assert "risk" in gm.layers and len(gm.data) == len(gm.layers)
    labels = [d.label for d in gm.data[0].layout.dim]
    assert labels == ["column_index", "row_index"]
    nx_, ny_ = gm.data[0].layout.dim[1].size, gm.data[0].layout.dim[0].size
    assert gm.data[0].data.size == nx_ * ny_ and math.isclose(gm.info.length_x, nx_ * gm.info.resolution)
    diag = ts.deserialize_cdr(driver.raw["/diagnostics"][-1], "diagnostic_msgs/msg/DiagnosticArray")
    keys = {kv.key for kv in diag.status[0].values}
    assert {"behaviour", "frames_dropped", "stops"} <= keys


def test_grid_map_layout_puts_the_largest_x_and_y_at_index_zero():
    """grid_map's storage: index (0, 0) is the cell of the largest x and y, rows toward -x,
    columns toward -y, column-major. A map with one marked cell shows where it lands."""
    import subterra

    nav = subterra.Navigator(goal=[4.0, 0.0])
    nav.step(_flat_ground(), stamp=0.0, world_from_body=np.eye(4), body_from_sensor=_lidar_mount())
    rm = nav.risk_map
    msg = ros.grid_map_message(rm, stamp_ns=0, frame_id="odom", layers=["ground_height"])
    ny, nx = rm.layer("risk").shape
    data = np.asarray(msg.data[0].data).reshape(ny, nx)  # column-major: one column (fixed y index) per row here
    grid = rm.layer("ground_height")
    # storage[c, r] = layer[ny-1-c, nx-1-r]
    assert np.array_equal(data, grid[::-1, ::-1], equal_nan=True)
    x0, x1, y0, y1 = rm.extent[:4]
    assert math.isclose(msg.info.pose.position.x, 0.5 * (x0 + x1)) and math.isclose(msg.info.pose.position.y, 0.5 * (y0 + y1))
    with pytest.raises(InputError, match="no layer 'nope'"):
        ros.grid_map_message(rm, stamp_ns=0, frame_id="odom", layers=["nope"])


def test_latest_frame_wins_and_drops_are_counted():
    """Frames that arrive while the compute thread is busy replace the waiting one; each
    replaced frame is a drop (the receive path never waits on the computation)."""
    node = GroundNode(_config(_domain(2)), loopback=True)
    try:
        for k in range(3):
            node._file_frame(("frame", k))
        assert node._frame == ("frame", 2)
        assert node.stats.frames_received == 3 and node.stats.frames_dropped == 2
    finally:
        node.close()


def test_watchdog_stops_the_robot_when_frames_stop_and_bad_goals_are_refused():
    """With a goal but no frames for safety.watchdog_s, the node publishes a stop (and says
    why); a goal in a frame it cannot transform, or not finite, is refused and counted."""
    domain = _domain(3)
    cfg = _config(domain).replace(safety={"watchdog_s": 0.2}, node={"use_sim_time": False})
    node = GroundNode(cfg, loopback=True)
    driver = Driver(domain, "ground")
    try:
        thread = _start(node)
        driver.wait_for([driver.goal, driver.outputs["/cmd_vel"]])
        driver.send_goal((1.0, 2.0, 0.0), frame_id="map")
        driver.send_goal((float("nan"), 0.0, 0.0))
        driver.send_goal((1.0, 0.0, 0.0))
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not node.stats.stops.get("no frame (watchdog)"):
            time.sleep(0.05)
        while time.monotonic() < deadline and not driver.raw["/cmd_vel"]:  # the stop is on its way
            driver.dds.wait(0.05)
            driver.poll()
    finally:
        _shutdown(node, thread, driver)
    assert node.stats.stops.get("no frame (watchdog)", 0) >= 1
    assert node.stats.goals == 1 and node.stats.rejected.get("/goal_pose") == 2, node.stats.summary()
    twists = [dds.typestore().deserialize_cdr(c, "geometry_msgs/msg/Twist") for c in driver.raw["/cmd_vel"]]
    assert twists and all(t.linear.x == 0.0 and t.angular.z == 0.0 for t in twists)


def test_with_simulated_time_the_watchdog_counts_on_the_clock():
    """With use_sim_time the watchdog's period is on /clock: while the simulation's clock
    stands still (a slow or paused simulator) no stop comes however long the wall clock runs;
    once the clock moves past the period without a frame, the stop comes."""
    domain = _domain(12)
    node = GroundNode(_config(domain).replace(safety={"watchdog_s": 0.2}), loopback=True)
    driver = Driver(domain, "ground")
    ts = dds.typestore()
    try:
        thread = _start(node)
        driver.wait_for([driver.goal, driver.clock, driver.outputs["/cmd_vel"]])
        driver.clock.publish(ros.clock_message(5 * NS, ts))
        driver.send_goal((1.0, 0.0, 0.0))
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and (node._goal is None or node._clock_ns is None):
            time.sleep(0.02)
        assert node._goal is not None and node._clock_ns == 5 * NS, "the goal and the clock reached the node"
        time.sleep(1.0)  # five wall-clock periods, the simulation's clock still
        assert node.stats.stops.get("no frame (watchdog)", 0) == 0, node.stats.summary()
        driver.clock.publish(ros.clock_message(5 * NS + NS // 2, ts))  # 0.5 s of simulated time later
        while time.monotonic() < deadline and not node.stats.stops.get("no frame (watchdog)"):
            time.sleep(0.02)
    finally:
        _shutdown(node, thread, driver)
    assert node.stats.stops.get("no frame (watchdog)", 0) >= 1, node.stats.summary()


# ---------------------------------------------------------------------- drone node


def test_drone_node_over_dds_flies_from_depth_images_and_publishes_the_belief():
    """A DroneNode fed depth images, camera info and the camera's mounting over DDS makes its
    pilot from them, answers each frame with a finite body-frame velocity, and publishes the
    belief (a wall 0.8 m ahead fills it) as markers that decode both ways."""
    domain = _domain(4)
    node = DroneNode(_config(domain), loopback=True)
    driver = Driver(domain, "drone")
    optical = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    try:
        thread = _start(node)
        driver.wait_for([driver.depth, driver.info, driver.odom, driver.goal, driver.outputs["/cmd_vel_stamped"]])
        driver.tf_static.publish(ros.tf_message([("base_link", "camera", 0, optical)], driver.ts))
        driver.send_goal((10.0, 0.0, 0.0))
        time.sleep(0.2)
        commands = []
        for k in range(1, 12):
            stamp = NS + k * NS // 15
            driver.tick(stamp)
            commands.append(driver.reply(stamp))
        time.sleep(0.2)
        driver.poll()
    finally:
        _shutdown(node, thread, driver)
    assert node.stats.stops == {}, node.stats.summary()
    vx = [c.linear.x for c in commands]
    assert all(math.isfinite(v) for v in vx), vx
    assert driver.raw["/subterra/belief"], "no belief markers"
    _typed_equal(driver.raw["/subterra/belief"][-1], "visualization_msgs/msg/MarkerArray")
    markers = dds.typestore().deserialize_cdr(driver.raw["/subterra/belief"][-1], "visualization_msgs/msg/MarkerArray").markers
    assert markers[0].header.frame_id == "base_link" and len(markers[0].points) > 0, "the wall is in the belief"
    for cdr in driver.raw["/cmd_vel_stamped"][:2]:
        _typed_equal(cdr, "geometry_msgs/msg/TwistStamped")


# ---------------------------------------------------------------------- software in the loop


@pytest.mark.parametrize(("robot", "scenario"), [("ground", "mine"), ("drone", "highbay")])
def test_software_in_the_loop_reaches_the_goal_over_dds(tmp_path, robot, scenario):
    """`subterra sil`: the simulator here, `subterra node` in a second process, DDS on the
    loopback interface in lockstep. The robot reaches its goal, every frame is answered, none
    is dropped, and the end-to-end latency (frame handed to DDS -> its command received) is
    in metrics.json with its median and p99."""
    from subterra.live.sil import sil

    # Seeds with a short episode (every seed 0-4 of both reaches its goal: docs/live.md).
    m = sil(robot, scenario, seed=0 if robot == "ground" else 1, out=tmp_path, domain_id=_domain(10 if robot == "ground" else 11))
    assert m["success"], (m["failure"], (tmp_path / "node.log").read_text())
    assert m["commands_missed"] == 0 and m["node"]["frames_dropped"] == 0 and not m["node"]["stops"]
    assert m["node"]["frames_processed"] == m["steps"]
    assert 0.0 < m["latency_ms_median"] <= m["latency_ms_p99"] < 1000.0
    assert m["collisions"] == 0
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["latency_ms_median"] == m["latency_ms_median"] and saved["transport"] == "ros2-dds"
    rows = (tmp_path / "trajectory.csv").read_text().splitlines()
    assert len(rows) == m["steps"] + 1
    print(f"sil {robot} {scenario}: latency median {m['latency_ms_median']:.2f} ms, p99 {m['latency_ms_p99']:.2f} ms")


# ---------------------------------------------------------------------- MAVLink


def _mavlink_peer():
    """A MAVLink endpoint on a free loopback UDP port (the autopilot's side): (connection, port)."""
    import socket

    from pymavlink import mavutil

    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    return mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}"), port


def _drain(peer, seconds: float) -> list[tuple[float, Any]]:
    out = []
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        m = peer.recv_match(blocking=True, timeout=0.05)
        if m is not None and m.get_type() != "BAD_DATA":
            out.append((time.monotonic() - t0, m))
    return out


def test_flu_enu_to_mavlink_frames():
    """FLU -> FRD negates y, z and the yaw rate; ENU -> NED swaps x and y and negates z and the yaw rate."""
    from subterra.live.mavlink import enu_to_ned, flu_to_frd

    assert flu_to_frd((1.0, 0.5, 0.2), 0.3) == (1.0, -0.5, -0.2, -0.3)
    assert enu_to_ned((1.0, 2.0, 3.0), 0.3) == (2.0, 1.0, -3.0, -0.3)


def test_mavlink_bridge_streams_setpoints_then_stops_when_commands_go_stale():
    """Against a MAVLink peer on loopback: velocity-only SET_POSITION_TARGET_LOCAL_NED in
    MAV_FRAME_BODY_NED with FRD values, at the stream rate, and heartbeats from an onboard
    controller; commands going stale (or a stop marked not fresh) give one zero setpoint and
    then silence; a fresh command resumes; a NaN command is refused; nothing else is ever
    sent (no arming, no mode change)."""
    from subterra.live.mavlink import VELOCITY_TYPE_MASK, MavlinkBridge

    peer, port = _mavlink_peer()
    bridge = MavlinkBridge(f"udpout:127.0.0.1:{port}", rate_hz=20.0, stale_after_s=0.3)
    try:
        bridge.command((1.0, 0.5, 0.2), 0.3)
        live = _drain(peer, 0.25)
        bridge.command((0.7, 0.0, 0.0), 0.0, fresh=False)  # a stop for untrusted inputs: not fresh
        stale = _drain(peer, 1.0)
        assert not bridge.command((float("nan"), 0.0, 0.0), 0.0)
        bridge.command((0.4, 0.0, 0.0), 0.0)
        resumed = _drain(peer, 0.2)
    finally:
        bridge.close()
        peer.close()
    kinds = {m.get_type() for _, m in live + stale + resumed}
    assert kinds <= {"SET_POSITION_TARGET_LOCAL_NED", "HEARTBEAT"}, kinds
    beats = [m for _, m in live + stale if m.get_type() == "HEARTBEAT"]
    assert beats and beats[0].type == 18 and beats[0].autopilot == 8  # onboard controller, not an autopilot
    sp = [m for _, m in live if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    assert len(sp) >= 4, "streamed at about 20 Hz"
    first = sp[0]
    assert first.coordinate_frame == 8 and first.type_mask == VELOCITY_TYPE_MASK
    assert (first.target_system, first.target_component) == (1, 1)
    assert np.allclose([first.vx, first.vy, first.vz, first.yaw_rate], [1.0, -0.5, -0.2, -0.3], atol=1e-6)
    after = [(t, m) for t, m in stale if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    zeros = [m for _, m in after if m.vx == 0.0 and m.vy == 0.0 and m.vz == 0.0]
    moving = [m for _, m in after if m.vx != 0.0]
    assert len(zeros) == 1, "one stop"
    assert all(t < 0.45 for t, m in after), "then no setpoint at all"
    assert not any(abs(m.vx - 0.7) < 1e-6 for m in moving), "the not-fresh command is never sent"
    assert bridge.stats.failsafes >= 1 and bridge.stats.rejected == 1
    again = [m for _, m in resumed if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    assert again and abs(again[0].vx - 0.4) < 1e-6


def test_mavlink_bridge_local_frame_and_bad_settings():
    from subterra.live.mavlink import MavlinkBridge

    peer, port = _mavlink_peer()
    try:
        with MavlinkBridge(f"udpout:127.0.0.1:{port}", frame="local") as bridge:
            bridge.command((1.0, 2.0, 3.0), 0.5)  # ENU
            msgs = [m for _, m in _drain(peer, 0.15) if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    finally:
        peer.close()
    assert msgs[0].coordinate_frame == 1
    assert np.allclose([msgs[0].vx, msgs[0].vy, msgs[0].vz, msgs[0].yaw_rate], [2.0, 1.0, -3.0, -0.5])
    with pytest.raises(ConfigError, match="frame"):
        MavlinkBridge("udpout:127.0.0.1:9", frame="ned")
    with pytest.raises(ConfigError, match="rate_hz"):
        MavlinkBridge("udpout:127.0.0.1:9", rate_hz=1.0)
    with pytest.raises(ConfigError, match="target_system"):
        MavlinkBridge("udpout:127.0.0.1:9", target_system=300)


def test_node_with_mavlink_never_streams_a_stop_for_untrusted_inputs():
    """A node whose every command is a stop (no frames: the watchdog) never starts the
    MAVLink stream: the autopilot hears only heartbeats, so its own failsafe stays in charge."""
    from subterra.live.mavlink import MavlinkBridge

    domain = _domain(5)
    peer, port = _mavlink_peer()
    bridge = MavlinkBridge(f"udpout:127.0.0.1:{port}")
    node = GroundNode(_config(domain).replace(safety={"watchdog_s": 0.1}, node={"use_sim_time": False}), loopback=True, mavlink=bridge)
    driver = Driver(domain, "ground")
    try:
        thread = _start(node)
        driver.wait_for([driver.goal])
        driver.send_goal((1.0, 0.0, 0.0))
        received = _drain(peer, 1.2)
    finally:
        _shutdown(node, thread, driver, bridge, peer)
    assert node.stats.stops.get("no frame (watchdog)", 0) >= 3
    assert {m.get_type() for _, m in received} == {"HEARTBEAT"}


# ---------------------------------------------------------------------- live view


def test_foxglove_view_serves_the_nodes_messages_to_a_websocket_client():
    """With a view, every message the node publishes is also served on Foxglove's WebSocket
    protocol: a client on loopback sees the channels advertised with their ROS 2 types and
    ros2msg schemas, subscribes, and receives CDR that decodes as the type."""
    import asyncio
    import struct

    websockets = pytest.importorskip("websockets")
    from subterra.live.view import FoxgloveView, parse_address

    assert parse_address("9000") == ("127.0.0.1", 9000)
    assert parse_address("0.0.0.0:9000") == ("0.0.0.0", 9000)
    with pytest.raises(ConfigError, match="PORT"):
        parse_address("nine")
    domain = _domain(6)
    view = FoxgloveView(port=0)
    assert view.host == "127.0.0.1" and view.port > 0
    node = GroundNode(_config(domain).replace(safety={"watchdog_s": 0.1}, node={"use_sim_time": False}), loopback=True, view=view)
    driver = Driver(domain, "ground")
    ts = dds.typestore()

    async def client() -> tuple[dict, list]:
        channels: dict[int, dict] = {}
        twists = []
        async with websockets.connect(view.url, subprotocols=["foxglove.sdk.v1"]) as ws:
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and len(twists) < 3:
                try:
                    m = await asyncio.wait_for(ws.recv(), 0.5)
                except asyncio.TimeoutError:
                    continue
                if isinstance(m, str):
                    j = json.loads(m)
                    if j["op"] == "advertise":
                        new = [c for c in j["channels"] if c["id"] not in channels]
                        channels.update({c["id"]: c for c in new})
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": c["id"], "channelId": c["id"]} for c in new]}))
                elif m[0] == 1:
                    sub_id = struct.unpack_from("<I", m, 1)[0]
                    if channels[sub_id]["topic"] == "/cmd_vel":
                        twists.append(ts.deserialize_cdr(bytes(m[13:]), "geometry_msgs/msg/Twist"))
        return channels, twists

    try:
        thread = _start(node)
        driver.wait_for([driver.goal])
        driver.send_goal((1.0, 0.0, 0.0))  # the watchdog now publishes stops, several a second
        channels, twists = asyncio.run(client())
    finally:
        _shutdown(node, thread, driver, view)
    by_topic = {c["topic"]: c for c in channels.values()}
    assert by_topic["/cmd_vel"]["schemaName"] == "geometry_msgs/msg/Twist" and by_topic["/cmd_vel"]["encoding"] == "cdr"
    assert by_topic["/cmd_vel"]["schemaEncoding"] == "ros2msg" and "Vector3 linear" in by_topic["/cmd_vel"]["schema"]
    assert len(twists) >= 3 and all(t.linear.x == 0.0 for t in twists)


def test_several_odometry_sources_go_through_the_hero_mux():
    """With two odometry topics the node's pose comes from the HeRO mux: the first (most
    trusted) source while it is healthy; when it falls silent, the second, reported in the
    diagnostics' odometry_source; with neither fresh, a stop."""
    from subterra.live.node import _Stop

    cfg = _config(_domain(7)).replace(topics={"odometry": ["/odom/lio", "/odom/wheels"]})
    node = GroundNode(cfg, loopback=True)

    class Sub:
        def __init__(self, topic: str) -> None:
            self.topic = topic

    lio, wheels = Sub("/odom/lio"), Sub("/odom/wheels")
    ts = dds.typestore()

    def pose(x: float) -> np.ndarray:
        m = np.eye(4)
        m[0, 3] = x
        return m

    try:
        t = NS
        for k in range(20):  # 2 s at 10 Hz, both sources agree
            t = NS + k * NS // 10
            node._on_odometry(ros.odometry_message(pose(0.1 * k), stamp_ns=t, typestore=ts), lio)
            node._on_odometry(ros.odometry_message(pose(0.1 * k), stamp_ns=t, typestore=ts), wheels)
            got, _, _ = node._pose_at(t)
        assert node._odometry_state["odometry_source"] == "/odom/lio"
        assert abs(got[0, 3] - 1.9) < 1e-9
        for k in range(20, 40):  # the lidar odometry falls silent
            t = NS + k * NS // 10
            node._on_odometry(ros.odometry_message(pose(0.1 * k), stamp_ns=t, typestore=ts), wheels)
            got, _, _ = node._pose_at(t)
        assert node._odometry_state["odometry_source"] == "/odom/wheels"
        assert abs(got[0, 3] - 3.9) < 0.2
        with pytest.raises(_Stop):
            node._pose_at(t + 5 * NS)
    finally:
        node.close()


def test_drone_node_with_two_cameras_and_a_stale_one():
    """Two cameras (topics.depth and topics.camera_info in pairs, each mounted by tf): the
    pilot is made with both; a frame whose second camera's latest image is more than
    safety.max_input_age_s older than the first's gets a stop."""
    from subterra import PinholeCamera

    domain = _domain(8)
    cfg = _config(domain).replace(topics={"depth": ["/left/depth", "/right/depth"], "camera_info": ["/left/info", "/right/info"]})
    node = DroneNode(cfg, loopback=True)
    d = dds.RosParticipant(domain, loopback=True)
    ts = dds.typestore()
    pubs = {name: d.publisher(f"/{name}/depth", "sensor_msgs/msg/Image", "reliable_sensor") for name in ("left", "right")}
    infos = {name: d.publisher(f"/{name}/info", "sensor_msgs/msg/CameraInfo", "reliable_sensor") for name in ("left", "right")}
    clock = d.publisher("/clock", "rosgraph_msgs/msg/Clock")
    odom = d.publisher("/odom", "nav_msgs/msg/Odometry", "reliable_sensor")
    goal = d.publisher("/goal_pose", "geometry_msgs/msg/PoseStamped")
    tf_static = d.publisher("/tf_static", "tf2_msgs/msg/TFMessage", "transient_local")
    cmd = d.subscriber("/cmd_vel_stamped", "geometry_msgs/msg/TwistStamped", "reliable_sensor")
    cam = PinholeCamera(40.0, 40.0, 31.5, 23.5, 64, 48)
    optical = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])

    def mount(yaw: float) -> np.ndarray:
        r = np.eye(4)
        r[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
        return r @ optical

    replies: dict[int, Any] = {}

    def tick(t: int, right_t: int | None = None) -> Any:
        clock.publish(ros.clock_message(t, ts))
        odom.publish(ros.odometry_message(np.eye(4), stamp_ns=t, typestore=ts))
        for name, stamp in (("right", t if right_t is None else right_t), ("left", t)):  # left (camera 0) last: it paces
            if stamp < 0:
                continue
            infos[name].publish(ros.camera_info_message(cam, stamp_ns=stamp, frame_id=name, typestore=ts))
            pubs[name].publish(ros.image_message(np.full((48, 64), 800, np.uint16), stamp_ns=stamp, frame_id=name, encoding="16UC1",
                                                 typestore=ts))
            time.sleep(0.01)
        deadline = time.monotonic() + 10
        while t not in replies and time.monotonic() < deadline:
            d.wait(0.02)
            for m in cmd.take():
                replies[ros.stamp_ns(m.header)] = m.twist
        return replies[t]

    try:
        thread = _start(node)
        assert d.wait_matched([*pubs.values(), *infos.values(), odom, goal, clock, cmd], 30)
        tf_static.publish(ros.tf_message([("base_link", "left", 0, mount(0.5)), ("base_link", "right", 0, mount(-0.5))], ts))
        target = np.eye(4)
        target[0, 3] = 10.0
        goal.publish(ros.pose_stamped_message(target, stamp_ns=0, frame_id="odom", typestore=ts))
        time.sleep(0.2)
        for k in range(1, 6):
            tick(NS + k * NS // 15)
        assert node._pilot is not None and node._pilot.camera_count == 2
        assert set(node.stats.stops) <= {"no frame (watchdog)"}, node.stats.summary()  # before the first frame
        t = 2 * NS
        tick(t, right_t=-1)  # no new right image: the right camera's newest is 0.6 s older
        assert node.stats.stops.get("camera 1 frame stale") == 1, node.stats.summary()
        assert node.stats.frames_received == 6 and node.stats.frames_dropped == 0, node.stats.summary()
    finally:
        _shutdown(node, thread, d)


def test_sil_refuses_bad_arguments_and_reports_a_node_that_cannot_start(tmp_path):
    """Bad robot, scenario or seed: InputError naming it. A node that exits at start (here:
    its navigator config file does not exist) is a SilError quoting the node's own error."""
    from subterra.live.sil import SilError, sil

    with pytest.raises(InputError, match="robot"):
        sil("boat")
    with pytest.raises(InputError, match="scenario"):
        sil("drone", "mine")
    with pytest.raises(InputError, match="seed"):
        sil("ground", seed=-1)
    broken = NodeConfig().replace(ground={"navigator_config": str(tmp_path / "missing.toml")})
    with pytest.raises(SilError, match=r"the node exited with status 2.*missing\.toml"):
        sil("ground", "mine", out=tmp_path / "run", node_config=broken, domain_id=_domain(9))


def test_every_input_type_the_loop_publishes_decodes_the_same_with_cyclone():
    """The simulator's side of the loop publishes what a robot's drivers do: each of those
    types, built by subterra.io.ros, decodes with Cyclone DDS's own typed CDR code to the
    same values as with rosbags (a ROS 2 node would read the same bytes)."""
    from subterra import PinholeCamera

    ts = dds.typestore()
    pose = np.eye(4)
    pose[:3, 3] = (1.0, -2.0, 0.5)
    messages = {
        "sensor_msgs/msg/PointCloud2": ros.pointcloud2_message(_flat_ground()[:500], stamp_ns=NS + 7, frame_id="lidar", typestore=ts),
        "sensor_msgs/msg/Image": ros.image_message(np.arange(48 * 64, dtype=np.uint16).reshape(48, 64), stamp_ns=NS, frame_id="camera",
                                                   encoding="16UC1", typestore=ts),
        "sensor_msgs/msg/CameraInfo": ros.camera_info_message(PinholeCamera(40.0, 41.0, 31.5, 23.5, 64, 48), stamp_ns=NS, frame_id="camera",
                                                              typestore=ts),
        "nav_msgs/msg/Odometry": ros.odometry_message(pose, stamp_ns=NS, twist=[0.5, 0.0, 0.0, 0.0, 0.0, 0.1], typestore=ts),
        "tf2_msgs/msg/TFMessage": ros.tf_message([("odom", "base_link", NS, pose), ("base_link", "lidar", 0, _lidar_mount())], ts),
        "rosgraph_msgs/msg/Clock": ros.clock_message(3 * NS + 11, ts),
        "geometry_msgs/msg/PoseStamped": ros.pose_stamped_message(pose, stamp_ns=NS, frame_id="odom", typestore=ts),
    }
    for msgtype, msg in messages.items():
        _typed_equal(bytes(ts.serialize_cdr(msg, msgtype)), msgtype)


# ---------------------------------------------------------------------- the probe's findings


def test_probe_findings_on_the_bridge_are_clear_errors(tmp_path):
    """What an independent probe of the live surface found, each now a clear subterra error
    naming the argument or field (it was a segfault, a hang, a dead thread, or a raw
    TypeError/AttributeError/OverflowError/RecursionError)."""
    import warnings

    from subterra.errors import FileFormatError, SubterraError
    from subterra.live.mavlink import MavlinkBridge
    from subterra.live.sil import sil
    from subterra.live.view import FoxgloveView, parse_address

    # DDS: a 70 000-character topic crashed Cyclone; type names, QoS, counts and timeouts.
    with pytest.raises(InputError, match="at most 250 characters"):
        dds.dds_topic_name("/" + "x" * 70000)
    with pytest.raises(InputError, match="topic"):
        dds.dds_topic_name("/ä")
    with pytest.raises(InputError, match="msgtype"):
        dds.dds_type_name(None)
    p = dds.RosParticipant(_domain(20), loopback=True)
    try:
        with pytest.raises(ConfigError, match="qos"):
            p.publisher("/a", "geometry_msgs/msg/Twist", qos=("bogus", "volatile", 1))
        with pytest.raises(ConfigError, match="depth"):
            p.publisher("/a", "geometry_msgs/msg/Twist", qos=("reliable", "volatile", 0))
        pub = p.publisher("/a", "geometry_msgs/msg/Twist")
        with pytest.raises(InputError, match="msg"):
            pub.publish(None)
        sub = p.subscriber("/a", "geometry_msgs/msg/Twist")
        with pytest.raises(InputError, match="`n`"):
            sub.take(0)
        with pytest.raises(InputError, match="timeout_s"):
            p.wait(float("inf"))
    finally:
        p.close()
    with pytest.raises(InputError, match="closed"):
        p.publisher("/b", "geometry_msgs/msg/Twist")
    # The navigator config: a FIFO hung the node and `subterra drive --config`.
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(ConfigError, match="not a regular file"):
        make_node("ground", NodeConfig.from_dict({"ground": {"navigator_config": str(fifo)}}), loopback=True)
    with pytest.raises(ConfigError, match="navigator.nope|nope"):
        (tmp_path / "nav.toml").write_text("[navigator]\nnope = 1\n", encoding="utf-8")
        make_node("ground", NodeConfig.from_dict({"ground": {"navigator_config": str(tmp_path / "nav.toml")}}), loopback=True)
    # NodeConfig: overflow, nesting, huge integers, non-tables, control characters, duplicates.
    with pytest.raises(ConfigError, match=r"rates\.map_hz must be finite"):
        NodeConfig.from_dict({"rates": {"map_hz": 10**400}})
    deep = tmp_path / "deep.toml"
    deep.write_text("[node]\nname = " + "[" * 5000 + "]" * 5000 + "\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="nested too deeply"):
        NodeConfig.load(deep)
    digits = tmp_path / "digits.toml"
    digits.write_text("[node]\ndomain_id = " + "9" * 5000 + "\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="digits.toml"):
        NodeConfig.load(digits)
    with pytest.raises(ConfigError, match="node must be a table"):
        NodeConfig().replace(node=5)
    with pytest.raises(ConfigError, match="frames.world"):
        NodeConfig.from_dict({"frames": {"world": "od\nom"}})
    with pytest.raises(ConfigError, match="printable"):
        NodeConfig.from_dict({"node": {"name": "\ud800"}})
    with pytest.raises(ConfigError, match=r"topics\.odometry\[0\] and topics\.cmd_vel|topics\.cmd_vel and topics\.odometry\[0\]"):
        NodeConfig.from_dict({"topics": {"cmd_vel": "/odom"}})
    with pytest.raises(ConfigError, match="drone.preset"):
        NodeConfig.from_dict({"drone": {"preset": "nope"}})
    with pytest.raises(FileFormatError, match="not a path"):
        NodeConfig.load(0)
    with pytest.raises(ConfigError, match="argument `config` must be None, a dict, a NodeConfig or a TOML path"):
        make_node("ground", 42)
    # MAVLink: a huge finite command killed the streaming thread; a bad port; strings and complex.
    with pytest.raises(ConfigError, match="port"):
        MavlinkBridge("udpout:127.0.0.1:99999")
    peer, port = _mavlink_peer()
    bridge = MavlinkBridge(f"udpout:127.0.0.1:{port}", stale_after_s=0.3)
    try:
        assert bridge.command((0.5, 0.0, 0.0))
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            for bad in ((1e300, 0.0, 0.0), ("1", "2", "3"), np.array([1j, 0, 0]), "abc", 5, None):
                assert not bridge.command(bad), bad
        assert bridge.stats.rejected == 6
        time.sleep(1.2)
        beats = [m for _, m in _drain(peer, 1.2) if m.get_type() == "HEARTBEAT"]
        assert beats, "the bridge's thread is alive"
    finally:
        bridge.close()
        peer.close()
    with pytest.raises(SubterraError):
        MavlinkBridge("/dev/zero")  # a serial link: MissingExtraError without pyserial, else InputError
    # The view.
    for bad in (None, 80, "٨٠", "8_0"):
        with pytest.raises(ConfigError, match="PORT"):
            parse_address(bad)
    with FoxgloveView(port=0) as view:
        with pytest.raises(InputError, match="msgtype"):
            view.publish("/a", "std_msgs/msg/Bogus", b"")
        with pytest.raises(InputError, match="cdr"):
            view.publish("/a", "std_msgs/msg/Header", None)
    # sil: checked before anything starts.
    for kwargs, field in (({"reply_timeout_s": float("nan")}, "reply_timeout_s"), ({"time_limit_s": "10"}, "time_limit_s"),
                          ({"domain_id": 999}, "domain_id"),
                          ({"out": tmp_path / "deep.toml"}, "out"), ({"robot": ["ground"]}, "robot")):
        with pytest.raises(InputError, match=field):
            sil(**{"robot": "ground", **kwargs})
    with pytest.raises(ConfigError, match="argument `node_config` must be None, a dict, a NodeConfig or a TOML path"):
        sil(robot="ground", node_config=42)


def test_probe_findings_on_the_ros_encoders_are_clear_errors():
    """The encoders check what they encode: stamps, frames, vectors, poses, sizes, types."""
    ts = dds.typestore()
    bad_calls = [
        (lambda: ros.clock_message(float("nan"), ts), "stamp"),
        (lambda: ros.clock_message(2**80, ts), "stamp"),
        (lambda: ros.twist_message((float("nan"), 0, 0), (0, 0, 0), ts), "linear"),
        (lambda: ros.twist_message(("1", "2", "3"), (0, 0, 0), ts), "linear"),
        (lambda: ros.twist_message((1, 2), (0, 0, 0), ts), "linear"),
        (lambda: ros.twist_stamped_message((0, 0, 0), (0, 0, 0), stamp_ns=0, frame_id=None, typestore=ts), "frame_id"),
        (lambda: ros.pose_stamped_message(np.full((4, 4), np.nan), stamp_ns=0, frame_id="odom", typestore=ts), "world_from_body"),
        (lambda: ros.pose_stamped_message(np.eye(3), stamp_ns=0, frame_id="odom", typestore=ts), "world_from_body"),
        (lambda: ros.path_message(np.broadcast_to(np.zeros(2), (10**9, 2)), stamp_ns=0, frame_id="map", typestore=ts), "poses"),
        (lambda: ros.path_message(np.array([[np.nan, 0.0]]), stamp_ns=0, frame_id="map", typestore=ts), "poses"),
        (lambda: ros.belief_markers_message(np.zeros(6), np.zeros(2), stamp_ns=0, frame_id="b", typestore=ts), "centres"),
        (lambda: ros.belief_markers_message(np.zeros((2, 3)), np.array([0.5, 2.0]), stamp_ns=0, frame_id="b", typestore=ts), "probabilities"),
        (lambda: ros.occupancy_grid_message(None, stamp_ns=0, frame_id="odom", typestore=ts), "risk_map"),
        (lambda: ros.diagnostics_message([("a", "ok", "m")], stamp_ns=0, typestore=ts), "statuses"),
        (lambda: ros.diagnostics_message([("a", ["ok"], "m", {})], stamp_ns=0, typestore=ts), "level"),
        (lambda: ros.diagnostics_message([(None, "ok", "m", {})], stamp_ns=0, typestore=ts), "name"),
    ]
    for call, field in bad_calls:  # the broadcast path of 10^9 points is refused before any loop
        with pytest.raises(InputError, match=field):
            call()


def test_cli_node_checks_its_stats_path_before_running(tmp_path):
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-m", "subterra.cli", "node", "ground", "--loopback", "--duration", "30", "--stats", str(tmp_path)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "--stats" in run.stderr and "Traceback" not in run.stderr


def test_second_probe_findings_are_clear_errors(tmp_path):
    """What a second probe found after the first round of fixes."""
    import subprocess
    import sys

    from subterra.live.mavlink import MavlinkBridge
    from subterra.live.sil import sil
    from subterra.live.view import FoxgloveView, parse_address

    run = subprocess.run([sys.executable, "-m", "subterra.cli", "sil", "-h"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and "pid % 100" in run.stdout  # a bare % in a help text crashed argparse
    p = dds.RosParticipant(_domain(21), loopback=True)
    pub = p.publisher("/x", "std_msgs/msg/Header")
    sub = p.subscriber("/x", "std_msgs/msg/Header")
    for bad in (b"", b"\x05\x01garbage"):
        with pytest.raises(InputError, match="encapsulation header"):
            pub.publish(bad)
    p.close()
    with pytest.raises(InputError, match="closed"):
        pub.publish(ros.header(0, "a", dds.typestore()))
    with pytest.raises(InputError, match="closed"):
        sub.take()
    with pytest.raises(InputError, match="closed"):
        p.wait_matched([pub], 0.1)
    for bad in ("/a/", "//a"):
        with pytest.raises(InputError, match="topic"):
            dds.dds_topic_name(bad)
    bridge = MavlinkBridge("udpout:127.0.0.1:9")
    assert not bridge.command(np.ma.masked_array([1.0, 2.0, 3.0], [1, 0, 0]))
    with pytest.raises(InputError, match="fresh"):
        bridge.command((0.1, 0.0, 0.0), fresh="no")
    bridge.close()
    with pytest.raises(InputError, match="closed"):
        bridge.command((0.1, 0.0, 0.0))
    with pytest.raises(ConfigError, match="host"):
        MavlinkBridge("udpout::14550")
    for bad in ("h o:1", "a:b:c:1", "[]:5"):
        with pytest.raises(ConfigError, match="HOST:PORT"):
            parse_address(bad)
    assert parse_address("[::1]:9000") == ("::1", 9000)
    with pytest.raises(ConfigError, match="name"):
        FoxgloveView(port=0, name="a\x00b")
    view = FoxgloveView(port=0)
    view.close()
    with pytest.raises(InputError, match="closed"):
        view.publish("/a", "std_msgs/msg/Header", b"\x00\x01\x00\x00")
    with pytest.raises(InputError, match="out"):
        sil("ground", out="a\x00b")
    node = GroundNode(_config(_domain(22)), loopback=True)
    try:
        for bad in (-1, float("nan"), True, "1"):
            with pytest.raises(InputError, match="duration_s"):
                node.run(bad)
    finally:
        node.close()
    with pytest.raises(InputError, match="closed"):
        node.run(0.1)
    with pytest.raises(ConfigError, match=r"ground\.navigator_config"):
        GroundNode(NodeConfig.from_dict({"ground": {"navigator_config": str(tmp_path / "missing.toml")}}), loopback=True)
    ts = dds.typestore()
    with pytest.raises(InputError, match="argument `stamp`"):
        ros.clock_message(1.5, ts)
    with pytest.raises(InputError, match="poses"):
        ros.path_message(np.array([[1e300, 0.0, 0.0]]), stamp_ns=1, frame_id="odom", typestore=ts)
    with pytest.raises(InputError, match="linear"):
        ros.twist_message([1e308, 0, 0], [0, 0, 0], ts)
    with pytest.raises(InputError, match="statuses"):
        ros.diagnostics_message([("n", "ok", "m", {})] * 100_001, stamp_ns=0, typestore=ts)
    with pytest.raises(ConfigError, match="odometry_hz"):
        NodeConfig.from_dict({"rates": {"odometry_hz": 1e-300}})
    with pytest.raises(ConfigError, match="watchdog_s"):
        NodeConfig.from_dict({"safety": {"watchdog_s": 5e-324}})


def test_the_node_imports_nothing_of_the_simulation_harness():
    """What a robot runs (``subterra.live.node``) does not pull in the simulator, the
    closed-loop runs or the batch engine."""
    code = ("import sys, subterra.live.node, subterra.live.mavlink\n"
            "print(sorted(m for m in sys.modules if m.split('.')[:2] in "
            "[['subterra', p] for p in ('drive', 'flight', 'sim', 'batch', 'scenarios')]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.strip() == "[]", out.stdout
