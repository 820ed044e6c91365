"""``subterra replay``: pipelines over recordings, the output MCAP read back independently.

The output MCAP is decoded with ``mcap-ros2-support`` (its own CDR decoder and ``ros2msg``
parser), so a wrong schema or encoding in our writer shows up. Real-data tests read
``../shared/data`` and skip when it is absent.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")
pytest.importorskip("mcap_ros2")

import subterra  # noqa: E402
from subterra import errors  # noqa: E402
from subterra.io import (  # noqa: E402
    Intrinsics,
    list_depth_files,
    read_depth,
    read_intrinsics,
    read_trajectory,
    ros,  # noqa: E402
)
from subterra.io.recordings import McapWriter, open_recording, write_bag  # noqa: E402
from subterra.replay import replay  # noqa: E402
from subterra.terrain import translation  # noqa: E402
from subterra.viz.foxglove import FoxgloveWriter, layer_image, occupancy_values  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
T0 = 1_700_000_000_000_000_000
PERIOD_NS = 33_333_333
DEPTH_TOPIC, INFO_TOPIC, ODOM_TOPIC, CLOUD_TOPIC = "/camera/depth/image_rect_raw", "/camera/depth/camera_info", "/odom", "/lidar/points"
OPTICAL = "camera_depth_optical_frame"


def read_output(path: Path) -> dict[str, list[tuple[int, str, object]]]:
    """Topic -> [(log time, schema name, decoded message)] through mcap-ros2-support."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, list[tuple[int, str, object]]] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg"
            out.setdefault(channel.topic, []).append((message.log_time, schema.name, decoded))
    return out


def stamp(header) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def depth_items(frames, intrinsics, *, frame_id: str = OPTICAL, encoding: str | None = None):
    """CameraInfo + Image per frame, the image logged 1 ns after its CameraInfo."""
    items = []
    for i, data in enumerate(frames):
        s = T0 + i * PERIOD_NS
        items.append((INFO_TOPIC, s, ros.camera_info_message(intrinsics, stamp_ns=s, frame_id=frame_id)))
        items.append((DEPTH_TOPIC, s + 1, ros.image_message(data, stamp_ns=s, frame_id=frame_id, encoding=encoding)))
    return items


def box_frames(n: int, shape=(120, 160), depth_mm: int = 800) -> list[np.ndarray]:
    frames = []
    for i in range(n):
        f = np.zeros(shape, np.uint16)
        f[30:90, 50:110] = depth_mm - 10 * i
        frames.append(f)
    return frames


SMALL = Intrinsics(96.0, 96.0, 79.5, 59.5, 160, 120)


# ----------------------------------------------------------------------------- depth, real RealSense frames


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_realsense_frames_in_a_ros2_bag_replay_like_perceive(shared_data: Path, tmp_path: Path, storage: str) -> None:
    from subterra.perceive import perceive_folder

    folder = shared_data / "realsense-d435-room"
    intr = read_intrinsics(folder / "cam_params_realsense.json")
    files = list_depth_files(folder / "depth")
    bag = write_bag(tmp_path / "bag", depth_items([read_depth(f).data for f in files], intr), storage=storage)

    summary = replay(bag, tmp_path / "run", depth_topic=DEPTH_TOPIC, info_topic=INFO_TOPIC, progress=False, rerun=False)
    assert summary["completed"] and summary["frames"] == 10 and summary["format"] == "ros2-bag" and summary["profile"] == storage
    assert (tmp_path / "run" / "perception.png").stat().st_size > 10_000
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["frames"] == 10

    # Same pipeline, same frames, same seed as `subterra perceive` on the PNG folder: the same result, frame by frame.
    reference = perceive_folder(folder / "depth", folder / "cam_params_realsense.json", out_dir=tmp_path / "perceive", progress=False)
    for got, want in zip(summary["records"], reference["records"], strict=True):
        assert got["p_free"] == want["p_free"] and got["map_depth_m"] == want["map_depth_m"]
        assert got["command"]["v_x"] == want["command"]["v_x"] and got["command"]["yaw_rate"] == want["command"]["yaw_rate"]

    out = read_output(tmp_path / "run" / "replay.mcap")
    assert {t: len(v) for t, v in out.items()} == {"/subterra/cmd": 10, "/subterra/belief": 10, "/tf_static": 1}
    image_stamps = [T0 + i * PERIOD_NS for i in range(10)]
    cmds = out["/subterra/cmd"]
    assert {name for _, name, _ in cmds} == {"geometry_msgs/msg/TwistStamped"}
    assert [log for log, _, _ in cmds] == [s + 1 for s in image_stamps]  # the image's log time
    assert [stamp(m.header) for _, _, m in cmds] == image_stamps  # the image's header stamp
    assert {m.header.frame_id for _, _, m in cmds} == {"base_link"}
    for (_, _, m), rec in zip(cmds, summary["records"]):
        assert (m.twist.linear.x, m.twist.linear.z, m.twist.angular.z) == (
            rec["command"]["v_x"], rec["command"]["v_z"], rec["command"]["yaw_rate"])
    beliefs = out["/subterra/belief"]
    assert {name for _, name, _ in beliefs} == {"visualization_msgs/msg/MarkerArray"}
    for (_, _, m), rec in zip(beliefs, summary["records"]):
        spheres, text = m.markers
        assert spheres.header.frame_id == "base_link" and spheres.type == 7 and stamp(spheres.header) == rec["stamp_ns"]
        assert text.text == f"P(free) = {rec['p_free']:.2f}"
        xs = np.array([p.x for p in spheres.points])
        if rec["p_free"] < 0.99:
            assert len(xs) > 0
        assert np.all((xs > 0.05) & (xs < 1.3))  # in front of the body, inside the 0.1-1.2 m horizon
        assert len(spheres.colors) == len(spheres.points)
    (_, name, tf), = out["/tf_static"]
    assert name == "tf2_msgs/msg/TFMessage"
    t = tf.transforms[0]
    assert (t.header.frame_id, t.child_frame_id) == ("base_link", OPTICAL)
    # The default mounting: optical z (forward) = body x: the quaternion of [[0,0,1],[-1,0,0],[0,-1,0]].
    np.testing.assert_allclose([t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w],
                               [-0.5, 0.5, -0.5, 0.5], atol=1e-12)


# ----------------------------------------------------------------------------- depth with odometry, Kinect


def _pgm_raw(path: Path) -> np.ndarray:
    """16-bit binary PGM decoded here by hand: header tokens, then big-endian samples."""
    data = path.read_bytes()
    tokens, pos = [], 0
    while len(tokens) < 4:
        while data[pos : pos + 1].isspace():
            pos += 1
        start = pos
        while not data[pos : pos + 1].isspace():
            pos += 1
        tokens.append(data[start:pos])
    width, height = int(tokens[1]), int(tokens[2])
    return np.frombuffer(data[pos + 1 : pos + 1 + 2 * width * height], ">u2").reshape(height, width)


def test_kinect_frames_with_poses_replay_with_odometry(shared_data: Path, tmp_path: Path) -> None:
    folder = shared_data / "kinect-dining"
    files = list_depth_files(folder / "depth")
    trajectory = read_trajectory(folder / "pose.txt")  # camera-to-world (optical frame), metres
    assert len(trajectory) == len(files) == 5
    body_from_optical = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1]], float)
    intr = Intrinsics(518.0, 519.0, 325.5, 253.5, 640, 480)
    frames = [read_depth(f).data for f in files]
    items = [("/tf_static", T0 - 1, ros.tf_message([("base_link", "kinect_optical", T0, body_from_optical)]))]
    items += depth_items(frames, intr, frame_id="kinect_optical")
    poses = []
    for i, world_from_optical in enumerate(trajectory.world_from_body):
        u, _, vt = np.linalg.svd(world_from_optical[:3, :3])
        world_from_optical = world_from_optical.copy()
        world_from_optical[:3, :3] = u @ vt
        world_from_body = world_from_optical @ np.linalg.inv(body_from_optical)
        poses.append(world_from_body)
        s = T0 + i * PERIOD_NS
        items.append((ODOM_TOPIC, s + 2, ros.odometry_message(world_from_body, stamp_ns=s, frame_id="odom", child_frame_id="base_link")))
    items.sort(key=lambda it: it[1])
    bag = write_bag(tmp_path / "kinect", items)

    # Metric depth: the decoded message at a valid pixel is the PGM's raw value / 1000.
    with open_recording(bag) as rec:
        msgs = [m for _, _, m in rec.messages([DEPTH_TOPIC])]
    raw = _pgm_raw(files[2])
    depth = ros.decode_depth_image(msgs[2])
    rows, cols = np.nonzero(raw)
    for r, c in ((rows[0], cols[0]), (rows[len(rows) // 2], cols[len(cols) // 2]), (240, 320)):
        assert depth.to_metres()[r, c] == pytest.approx(int(raw[r, c]) / 1000.0, rel=1e-6)
    assert depth.data[rows[0], cols[0]] == raw[rows[0], cols[0]] > 0

    goal = (2.0, -1.0, 1.0)
    summary = replay(bag, tmp_path / "run", depth_topic=DEPTH_TOPIC, info_topic=INFO_TOPIC, odom_topic=ODOM_TOPIC,
                     goal=goal, progress=False, rerun=False)
    assert summary["frame_ids"] == {"world": "odom", "body": "base_link"}
    assert summary["body_from_camera_source"] == "tf_static: base_link <- kinect_optical"
    np.testing.assert_allclose(summary["body_from_camera"], body_from_optical, atol=1e-12)
    assert summary["goal"] == {"frame": "odom", "xyz_m": list(goal)} and summary["frames_without_pose"] == 0
    for rec, pose in zip(summary["records"], poses, strict=True):  # the world goal seen from each pose
        np.testing.assert_allclose(rec["goal_body"], (np.linalg.inv(pose) @ np.append(goal, 1.0))[:3], atol=1e-9)
        assert 0.2 < rec["closest_depth_m"] < 10.0
    out = read_output(tmp_path / "run" / "replay.mcap")
    assert len(out["/subterra/cmd"]) == 5 and len(out["/tf"]) == 5
    for (_, _, tf), pose in zip(out["/tf"], poses):
        t = tf.transforms[0]
        assert (t.header.frame_id, t.child_frame_id) == ("odom", "base_link")
        np.testing.assert_allclose([t.transform.translation.x, t.transform.translation.y, t.transform.translation.z], pose[:3, 3])
    _, name, path = out["/subterra/path"][-1]
    assert name == "nav_msgs/msg/Path" and path.header.frame_id == "odom"
    np.testing.assert_allclose([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in path.poses],
                               [p[:3, 3] for p in poses])


def test_tum_frames_5000_units_per_metre(shared_data: Path, tmp_path: Path) -> None:
    folder = shared_data / "tum-desk"
    raws = [read_depth(folder / f"{i}_depth.png").data for i in (1, 2)]
    intr = Intrinsics(520.9, 521.0, 325.1, 249.7, 640, 480)
    metres = [(r.astype(np.float32) / np.float32(5000.0)) for r in raws]
    bag_raw = write_bag(tmp_path / "raw", depth_items(raws, intr))
    bag_m = write_bag(tmp_path / "metres", depth_items(metres, intr, encoding="32FC1"))
    with open_recording(bag_raw) as rec:
        msg = next(iter(rec.messages([DEPTH_TOPIC]))).message
    depth = ros.decode_depth_image(msg, scale=1 / 5000)
    r, c = np.argwhere(raws[0] > 0)[1000]
    assert depth.to_metres()[r, c] == pytest.approx(int(raws[0][r, c]) / 5000.0, rel=1e-6)
    a = replay(bag_raw, tmp_path / "a", depth_topic=DEPTH_TOPIC, info_topic=INFO_TOPIC, scale=1 / 5000, progress=False, rerun=False)
    b = replay(bag_m, tmp_path / "b", depth_topic=DEPTH_TOPIC, info_topic=INFO_TOPIC, progress=False, rerun=False)
    for x, y in zip(a["records"], b["records"], strict=True):
        assert x["closest_depth_m"] == pytest.approx(y["closest_depth_m"], rel=1e-6)
        assert 0.5 < x["closest_depth_m"] < 3.0  # a desk, not 5x closer or further
        assert x["valid_pixels"] == y["valid_pixels"]


# ----------------------------------------------------------------------------- terrain


def _scan(rng: np.random.Generator, robot_x: float, box_world=(3.2, 0.2), h: float = 0.7) -> np.ndarray:
    """A lidar scan (sensor frame, h above a flat floor) with a 0.4 m box at ``box_world``; organised 40 x 500."""
    xy = rng.uniform(-6, 6, (20_000, 2))
    floor = np.c_[xy, np.full(len(xy), -h)]
    bx = rng.uniform(-0.2, 0.2, (2_000, 2)) + np.asarray(box_world) - [robot_x, 0.0]
    box = np.c_[bx, rng.uniform(0.0, 0.5, 2_000) - h]
    return np.vstack([floor, box]).astype(np.float32)


def _terrain_items(rng: np.random.Generator, n: int = 4, nan_points: int = 7):
    items = [("/tf_static", T0 - 1, ros.tf_message([("base_link", "lidar", T0, translation(z=0.7))]))]
    scans, poses = [], []
    for i in range(n):
        s = T0 + i * 100_000_000
        pose = translation(x=0.5 * i)
        pts = _scan(rng, 0.5 * i)
        pts[:nan_points] = np.nan
        scans.append(pts)
        poses.append(pose)
        items.append((ODOM_TOPIC, s - 1, ros.odometry_message(pose, stamp_ns=s)))
        items.append((CLOUD_TOPIC, s + 5, ros.pointcloud2_message(pts, {"intensity": np.ones(len(pts), np.float32)}, stamp_ns=s,
                                                                  frame_id="lidar", organised_shape=(44, 500))))
    return items, scans, poses


def test_terrain_replay_with_odometry_matches_the_mapper(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    items, scans, poses = _terrain_items(rng)
    bag = write_bag(tmp_path / "bag", items, storage="mcap")
    summary = replay(bag, tmp_path / "run", cloud_topic=CLOUD_TOPIC, odom_topic=ODOM_TOPIC, layers=None, progress=False, plots=False)
    assert summary["completed"] and summary["pipeline"] == "terrain"
    assert summary["body_from_sensor_source"] == "tf_static: base_link <- lidar" and summary["poses"] == "odometry /odom"
    assert summary["dropped_non_finite"] == 4 * 7 and [s["points"] for s in summary["scans"]] == [22_000 - 7] * 4

    # The library directly, same clouds and poses: the replay's last map equals it cell for cell.
    mapper = subterra.TerrainMapper()
    for i, (pts, pose) in enumerate(zip(scans, poses)):
        risk_map = mapper.update(pts[np.isfinite(pts).all(axis=1)], stamp=0.1 * i, world_from_body=pose, body_from_sensor=translation(z=0.7))
    out = read_output(tmp_path / "run" / "replay.mcap")
    assert len(out["/subterra/risk"]) == 4 and len(out["/subterra/risk_fine"]) == 4 and len(out["/tf"]) == 4
    log, name, grid = out["/subterra/risk"][-1]
    assert name == "nav_msgs/msg/OccupancyGrid" and grid.header.frame_id == "odom"
    assert log == T0 + 300_000_000 + 5 and stamp(grid.header) == T0 + 300_000_000
    assert (grid.info.width, grid.info.height, grid.info.resolution) == (risk_map.nx, risk_map.ny, pytest.approx(risk_map.resolution))
    assert (grid.info.origin.position.x, grid.info.origin.position.y) == (risk_map.extent[0], risk_map.extent[2])
    values = np.array(grid.data, np.int8).reshape(risk_map.ny, risk_map.nx)
    np.testing.assert_array_equal(values, occupancy_values(risk_map.layer("risk"), risk_map.layer("observed"), risk_map.lethal_risk))
    ix, iy = risk_map.cell_of(3.2, 0.2)
    assert values[iy, ix] == 100  # the box is lethal
    ix, iy = risk_map.cell_of(1.0, -3.0)
    assert values[iy, ix] == 0  # open floor
    assert (values == -1).any() and values.min() == -1 and values.max() == 100
    # Every layer as a top-view 32FC1 image: row 0 is the largest world y.
    layers = {t.removeprefix("/subterra/layers/"): v for t, v in out.items() if t.startswith("/subterra/layers/")}
    assert sorted(layers) == sorted(risk_map.layer_names)
    _, name, img = layers["risk"][-1]
    assert name == "sensor_msgs/msg/Image" and img.encoding == "32FC1" and img.header.frame_id == "odom"
    pixels = np.frombuffer(bytes(img.data), "<f4").reshape(img.height, img.width)
    np.testing.assert_array_equal(pixels, risk_map.layer("risk")[::-1])
    np.testing.assert_array_equal(np.frombuffer(bytes(layers["ground_height"][-1][2].data), "<f4").reshape(200, 200),
                                  layer_image(risk_map.layer("ground_height")))
    (_, _, tf_static), = out["/tf_static"]
    assert tf_static.transforms[0].child_frame_id == "lidar" and tf_static.transforms[0].transform.translation.z == pytest.approx(0.7)
    _, _, path = out["/subterra/path"][-1]
    assert [p.pose.position.x for p in path.poses] == [0.0, 0.5, 1.0, 1.5]


def test_ouster_os1_64_mcap_terrain_replay(shared_data: Path, tmp_path: Path) -> None:
    path = shared_data / "mcap-ouster-os1-64" / "test.mcap"
    summary = replay(path, tmp_path / "run", cloud_topic="/os1_cloud_node/points", sensor_height=0.8, progress=False)
    assert summary["completed"] and len(summary["scans"]) == 2
    assert summary["body_from_sensor_source"] == "--sensor-height (level sensor)"
    for scan in summary["scans"]:
        assert scan["stats"]["input_points"] == 131072 and scan["organised"] == [64, 2048]
        assert scan["stats"]["kept"] > 30_000 and scan["frame_id"] == "os1_lidar"
    assert summary["map"]["scans_fused"] == 2
    assert summary["lethal_cells"]["collision"] > 0  # a lab: walls and furniture
    assert (tmp_path / "run" / "overview.png").stat().st_size > 10_000 and (tmp_path / "run" / "risk.png").is_file()
    out = read_output(tmp_path / "run" / "replay.mcap")
    assert len(out["/subterra/risk"]) == 2
    assert [stamp(m.header) for _, _, m in out["/subterra/risk"]] == [s["stamp_ns"] for s in summary["scans"]]
    # Without --sensor-height the height is estimated from the first cloud: in this lab the
    # histogram mode is a wall, and the lowest dense layer (the floor) gives ~0.8 m.
    estimated = replay(path, tmp_path / "est", cloud_topic="/os1_cloud_node/points", progress=False, plots=False)
    assert estimated["body_from_sensor_source"].startswith("estimated")
    assert estimated["body_from_sensor"][2][3] == pytest.approx(0.76, abs=0.1)


# ----------------------------------------------------------------------------- the Foxglove writer


def test_foxglove_writer_round_trip(tmp_path: Path) -> None:
    mapper = subterra.TerrainMapper()
    risk_map = mapper.update(_scan(np.random.default_rng(0), 0.0), body_from_sensor=translation(z=0.7))
    path = tmp_path / "o.mcap"
    with FoxgloveWriter(path, world_frame="map", body_frame="body", layers=("risk", "tilt")) as w:
        w.command(10, 9, 0.5, 0.0, -0.1, 0.25)
        w.belief(11, 9, np.array([[1.0, 0.2, -0.1], [0.5, 0.0, 0.0]]), np.array([0.2, 0.8]), p_free=0.0)
        w.risk_map(12, 9, risk_map)
        w.pose(13, 9, translation(x=1.0, y=2.0))
        w.pose(14, 10, translation(x=1.01, y=2.0))  # closer than the path spacing: not a new path pose
        w.static_transform(15, 9, "body", "lidar", translation(z=0.7))
    out = read_output(path)
    (log, _, cmd), = out["/subterra/cmd"]
    assert log == 10 and stamp(cmd.header) == 9 and cmd.header.frame_id == "body"
    assert (cmd.twist.linear.x, cmd.twist.linear.z, cmd.twist.angular.z) == (0.5, -0.1, 0.25)
    (_, _, arr), = out["/subterra/belief"]
    spheres = arr.markers[0]
    assert [(p.x, p.y, p.z) for p in spheres.points] == [(1.0, 0.2, -0.1), (0.5, 0.0, 0.0)]
    assert [c.a for c in spheres.colors] == pytest.approx([0.3 + 0.7 * 0.25, 1.0])
    assert arr.markers[1].text == "P(free) = 0.00"
    (_, _, grid), = out["/subterra/risk"]
    assert grid.header.frame_id == "map"
    np.testing.assert_array_equal(np.array(grid.data, np.int8), occupancy_values(risk_map.layer("risk"), risk_map.layer("observed"), risk_map.lethal_risk).ravel())
    assert sorted(out) == sorted(["/subterra/cmd", "/subterra/belief", "/subterra/risk", "/subterra/layers/risk",
                                  "/subterra/layers/tilt", "/tf", "/subterra/path", "/tf_static"])
    assert len(out["/tf"]) == 2
    _, _, p = out["/subterra/path"][-1]
    assert len(p.poses) == 1 and (p.poses[0].pose.position.x, p.poses[0].pose.position.y) == (1.0, 2.0)
    # Our own reader agrees.
    with open_recording(path) as rec:
        assert rec.topics["/subterra/layers/tilt"].type == "sensor_msgs/msg/Image"
        img = next(iter(rec.messages(["/subterra/layers/tilt"]))).message
        np.testing.assert_array_equal(ros.decode_image(img), risk_map.layer("tilt")[::-1])
    # Nav2's meaning: lethal (>= 0.9 here) is 100 observed or not, never -1; other observed
    # cells round(100 r) up to 99; unobserved -1.
    np.testing.assert_array_equal(
        occupancy_values(np.array([[0.0, 0.004, 0.5, 0.895, 0.9, 1.0, np.nan, 0.5, 1.0]]), np.array([[1, 1, 1, 1, 1, 1, 1, 0, 0]]), 0.9),
        [[0, 0, 50, 90, 100, 100, -1, -1, 100]])


# ----------------------------------------------------------------------------- bad recordings


def _depth_mcap(path: Path, frames, intr=SMALL, chunk_size: int = 1 << 20) -> Path:
    with McapWriter(path, chunk_size=chunk_size) as w:
        for topic, s, msg in depth_items(frames, intr):
            w.write(topic, msg, log_time_ns=s)
    return path


def test_truncated_recording_keeps_the_output_written_so_far(tmp_path: Path) -> None:
    full = _depth_mcap(tmp_path / "full.mcap", box_frames(20), chunk_size=20_000)  # about one frame a chunk
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full.read_bytes()[: full.stat().st_size // 2])
    with pytest.raises(errors.FileFormatError, match=r"truncated or corrupt after \d+ messages.*cut\.mcap"):
        replay(cut, tmp_path / "run", depth_topic=DEPTH_TOPIC, info_topic=INFO_TOPIC, progress=False, rerun=False)
    out = read_output(tmp_path / "run" / "replay.mcap")  # finished and readable
    done = len(out["/subterra/cmd"])
    assert 3 <= done < 20 and len(out["/subterra/belief"]) == done
    assert [stamp(m.header) for _, _, m in out["/subterra/cmd"]] == [T0 + i * PERIOD_NS for i in range(done)]
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["completed"] is False and "truncated" in summary["error"] and len(summary["records"]) == done
    assert (tmp_path / "run" / "perception.png").is_file()


def test_image_size_differs_from_camera_info(tmp_path: Path) -> None:
    frames = box_frames(5)
    frames[3] = np.zeros((60, 80), np.uint16)  # the 4th image is half the size
    path = _depth_mcap(tmp_path / "rec.mcap", frames)
    with pytest.raises(errors.InputError) as info:
        replay(path, tmp_path / "run", depth_topic=DEPTH_TOPIC, info_topic=INFO_TOPIC, progress=False, rerun=False)
    text = str(info.value)
    assert f"--depth-topic '{DEPTH_TOPIC}'" in text and "is 80x60" in text and f"--info-topic '{INFO_TOPIC}' says 160x120" in text
    assert text.endswith("rec.mcap")
    assert len(read_output(tmp_path / "run" / "replay.mcap")["/subterra/cmd"]) == 3


def test_unknown_depth_encoding(tmp_path: Path) -> None:
    items = depth_items([np.zeros((120, 160, 3), np.uint8)], SMALL, encoding="rgb8")
    bag = write_bag(tmp_path / "bag", items)
    with pytest.raises(errors.InputError, match=r"unknown encoding 'rgb8'.*image_rect_raw at stamp"):
        replay(bag, tmp_path / "run", depth_topic=DEPTH_TOPIC, info_topic=INFO_TOPIC, progress=False, rerun=False)
    assert read_output(tmp_path / "run" / "replay.mcap") == {}  # empty, but a finished MCAP


def test_empty_cloud_mid_way(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    items, _, _ = _terrain_items(rng, n=2, nan_points=0)
    s = T0 + 500_000_000
    items.append((CLOUD_TOPIC, s, ros.pointcloud2_message(np.zeros((0, 3), np.float32), stamp_ns=s, frame_id="lidar")))
    all_nan = np.full((10, 3), np.nan, np.float32)
    bag = write_bag(tmp_path / "bag", items)
    with pytest.raises(errors.InputError, match=r"the cloud at stamp \d+ ns has no points \(0x1, 0 non-finite dropped\)"):
        replay(bag, tmp_path / "run", cloud_topic=CLOUD_TOPIC, odom_topic=ODOM_TOPIC, progress=False, plots=False)
    out = read_output(tmp_path / "run" / "replay.mcap")
    assert len(out["/subterra/risk"]) == 2
    nan_bag = write_bag(tmp_path / "nan", [(CLOUD_TOPIC, T0, ros.pointcloud2_message(all_nan, stamp_ns=T0, frame_id="lidar"))])
    with pytest.raises(errors.InputError, match=r"has no points \(10x1, 10 non-finite dropped\)"):
        replay(nan_bag, tmp_path / "run2", cloud_topic=CLOUD_TOPIC, sensor_height=0.7, progress=False, plots=False)


def test_wrong_arguments(tmp_path: Path) -> None:
    path = _depth_mcap(tmp_path / "rec.mcap", box_frames(2))
    with pytest.raises(errors.InputError, match=r"--depth-topic '/nope' is not in the recording; topics present: "
                                                 r"/camera/depth/camera_info \(sensor_msgs/msg/CameraInfo, 2\), "
                                                 r"/camera/depth/image_rect_raw \(sensor_msgs/msg/Image, 2\)"):
        replay(path, tmp_path / "r", depth_topic="/nope", info_topic=INFO_TOPIC, progress=False)
    with pytest.raises(errors.InputError, match="--info-topic '/camera/depth/image_rect_raw' has type sensor_msgs/msg/Image"):
        replay(path, tmp_path / "r", depth_topic=DEPTH_TOPIC, info_topic=DEPTH_TOPIC, progress=False)
    with pytest.raises(errors.InputError, match="needs both --depth-topic"):
        replay(path, tmp_path / "r", pipeline="depth", depth_topic=DEPTH_TOPIC)
    with pytest.raises(errors.InputError, match="not both"):
        replay(path, tmp_path / "r", depth_topic=DEPTH_TOPIC, info_topic=INFO_TOPIC, cloud_topic="/x")


def test_cli_lists_topics_runs_and_reports_errors(tmp_path: Path) -> None:
    path = _depth_mcap(tmp_path / "rec.mcap", box_frames(4))

    def run(*argv: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "subterra.cli", "replay", str(path), *argv], cwd=REPO,
                              capture_output=True, text=True, timeout=300)

    listing = run()
    assert listing.returncode == 0, listing.stderr
    assert "/camera/depth/image_rect_raw  sensor_msgs/msg/Image       4" in listing.stdout
    assert f"depth pipeline: --depth-topic {DEPTH_TOPIC} --info-topic {INFO_TOPIC}" in listing.stdout
    ok = run("--depth-topic", DEPTH_TOPIC, "--info-topic", INFO_TOPIC, "--goal", "3,1,0", "--out", str(tmp_path / "run"), "--no-rerun")
    assert ok.returncode == 0, ok.stderr
    assert "4 images from" in ok.stdout and "/subterra/cmd x4" in ok.stdout
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["records"][0]["goal_body"] == [3.0, 1.0, 0.0]
    missing = run("--cloud-topic", "/points", "--out", str(tmp_path / "bad"))
    assert missing.returncode == 2 and missing.stdout == ""
    assert missing.stderr.startswith("error: --cloud-topic '/points' is not in the recording; topics present: ")
    assert len(missing.stderr.strip().splitlines()) == 1


def test_rerun_file_when_rerun_is_installed(tmp_path: Path) -> None:
    from subterra.viz.rerun import rerun_available

    if not rerun_available():
        pytest.skip("rerun-sdk is not installed (pip install 'subterra[viz]')")
    path = _depth_mcap(tmp_path / "rec.mcap", box_frames(6))
    summary = replay(path, tmp_path / "run", depth_topic=DEPTH_TOPIC, info_topic=INFO_TOPIC, progress=False)
    assert summary["rerun"] and (tmp_path / "run" / "replay.rrd").stat().st_size > 1000
    shutil.rmtree(tmp_path / "run")
    # The terrain pipeline: scans, robot, risk map (every RERUN_RISK_EVERY-th scan) in the world frame.
    items, _, _ = _terrain_items(np.random.default_rng(5))
    bag = write_bag(tmp_path / "bag", items, storage="mcap")
    summary = replay(bag, tmp_path / "run", cloud_topic=CLOUD_TOPIC, odom_topic=ODOM_TOPIC, progress=False, plots=False)
    rrd = tmp_path / "run" / "replay.rrd"
    assert summary["rerun"] == str(rrd)
    data = rrd.read_bytes()
    for entity in (b"world/cloud", b"world/risk", b"world/robot", b"world/path"):
        assert entity in data, entity
    assert replay(bag, tmp_path / "run2", cloud_topic=CLOUD_TOPIC, rerun=False, progress=False, plots=False)["rerun"] is None
    assert not (tmp_path / "run2" / "replay.rrd").exists()


def test_rerun_log_cloud_refuses_bad_input(tmp_path: Path) -> None:
    from subterra.viz.rerun import RerunRecorder, rerun_available

    if not rerun_available():
        pytest.skip("rerun-sdk is not installed (pip install 'subterra[viz]')")
    with RerunRecorder(tmp_path / "c.rrd") as rec:
        rec.log_cloud(0.0, np.zeros((0, 3)))  # an empty scan is logged as no points
        rec.log_cloud(0.1, np.random.default_rng(0).normal(size=(50_000, 3)), max_points=1000)
        with pytest.raises(errors.InputError, match=r"points_world.*\(N, 3\)"):
            rec.log_cloud(0.2, np.zeros((4, 2)))
        with pytest.raises(errors.InputError, match="max_points"):
            rec.log_cloud(0.2, np.zeros((4, 3)), max_points=0)
        with pytest.raises(errors.InputError, match="time_s"):
            rec.log_cloud(float("nan"), np.zeros((4, 3)))


def test_bench_replay_reports_every_container(tmp_path: Path) -> None:
    from subterra.bench.replay import bench_replay

    report = bench_replay(messages=3, data=tmp_path / "no-shared-data")  # synthetic clouds and images
    assert report["cloud_source"].startswith("synthetic") and report["image_source"].startswith("synthetic")
    assert sorted(report["results"]) == ["mcap (ros2, zstd chunks)", "ros2 bag (mcap storage)", "ros2 bag (sqlite3 storage)"]
    for row in report["results"].values():
        for kind in ("pointcloud2", "image"):
            r = row[kind]
            assert r["messages_timed"] == 2 and r["read_ms_median"] > 0 and r["decode_ms_median"] > 0
            assert r["messages_per_s"] == pytest.approx(1e3 / r["read_decode_ms_median"])
            assert r["decode_percent_of_pipeline"] == pytest.approx(100 * r["decode_ms_median"] / r["pipeline_ms_median"])
    assert report["target"]["worst_decode_percent"] == max(
        row[k]["decode_percent_of_pipeline"] for row in report["results"].values() for k in ("pointcloud2", "image"))
    with pytest.raises(errors.InputError, match="messages"):
        bench_replay(messages=1)
