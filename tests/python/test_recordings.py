"""Reading recordings (ROS 1 / ROS 2 bags, MCAP) and decoding their messages to NumPy.

Hand-built messages check every decoder against values written independently (raw bytes
packed with ``struct``, ROS 1 messages serialised by the ``genpy`` code vendored in
``mcap-ros1-support``, our MCAP output decoded by ``mcap-ros2-support``); the real Ouster
OS1-64 MCAP (``../shared/data``, skipped when absent) checks the ROS 1 path end to end.
"""

from __future__ import annotations

import shutil
import struct
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("rosbags")
pytest.importorskip("mcap")

from subterra import errors  # noqa: E402
from subterra.io import (
    Intrinsics,  # noqa: E402
    ros,  # noqa: E402
)
from subterra.io.recordings import McapWriter, open_recording, write_bag  # noqa: E402

T0 = 1_700_000_000_123_456_789


# ----------------------------------------------------------------------------- helpers


def _time(ns: int) -> SimpleNamespace:
    return SimpleNamespace(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _header(ns: int = T0, frame: str = "lidar") -> SimpleNamespace:
    return SimpleNamespace(stamp=_time(ns), frame_id=frame)


def _field(name: str, offset: int, datatype: int, count: int = 1) -> SimpleNamespace:
    return SimpleNamespace(name=name, offset=offset, datatype=datatype, count=count)


def _cloud_msg(fields, rows: list[bytes], width: int, point_step: int, row_step: int | None = None,
               big: bool = False, dense: bool = True) -> SimpleNamespace:
    height = len(rows)
    row_step = row_step if row_step is not None else width * point_step
    data = b"".join(r.ljust(row_step, b"\xee") for r in rows)
    return SimpleNamespace(header=_header(), height=height, width=width, fields=fields, is_bigendian=big,
                           point_step=point_step, row_step=row_step, data=data, is_dense=dense)


# ----------------------------------------------------------------------------- PointCloud2


def test_pointcloud2_hand_packed_padding_and_gaps() -> None:
    # x y z float32, a 4-byte gap, intensity float32 at 16, ring uint16 at 20, 10 bytes of padding: 32 B a point.
    fields = [_field("x", 0, 7), _field("y", 4, 7), _field("z", 8, 7), _field("intensity", 16, 7), _field("ring", 20, 4)]
    pts = [(1.0, 2.0, 3.0, 10.5, 7), (-4.0, 5.5, -6.25, 0.0, 63)]
    row = b"".join(struct.pack("<3f4xfH10x", x, y, z, i, r) for x, y, z, i, r in pts)
    cloud = ros.decode_pointcloud2(_cloud_msg(fields, [row], 2, 32))
    np.testing.assert_array_equal(cloud.points, np.array([p[:3] for p in pts], np.float32))
    assert cloud.points.dtype == np.float32 and cloud.points.flags.c_contiguous
    np.testing.assert_array_equal(cloud.fields["intensity"], [10.5, 0.0])
    assert cloud.fields["ring"].dtype == np.uint16 and cloud.fields["ring"].tolist() == [7, 63]
    assert set(cloud.fields) == {"intensity", "ring"} and cloud.dropped == 0 and cloud.index is None
    assert cloud.stamp_ns == T0 and cloud.frame_id == "lidar" and (cloud.height, cloud.width) == (1, 2)


def test_pointcloud2_hand_packed_big_endian_float64_and_shuffled_order() -> None:
    # Fields out of order (intensity first, then z, x, y), xyz float64, big-endian.
    fields = [_field("intensity", 0, 2), _field("z", 1, 8), _field("x", 9, 8), _field("y", 17, 8), _field("t", 25, 6)]
    pts = [(0.5, -1.5, 2.25, 200, 123456789), (1e-3, 7.0, -8.0, 3, 1)]
    row = b"".join(struct.pack(">BdddI", i, z, x, y, t) for x, y, z, i, t in pts)
    cloud = ros.decode_pointcloud2(_cloud_msg(fields, [row], 2, 29, big=True))
    np.testing.assert_array_equal(cloud.points, np.array([p[:3] for p in pts], np.float32))
    assert cloud.fields["intensity"].tolist() == [200, 3]
    t = cloud.fields["t"]
    assert t.dtype == np.uint32 and t.dtype.isnative and t.tolist() == [123456789, 1]


def test_pointcloud2_big_endian_float32_fast_path() -> None:
    fields = [_field("x", 0, 7), _field("y", 4, 7), _field("z", 8, 7)]
    pts = np.array([[1.5, -2.0, 3.0], [4.0, 5.0, -6.5]], np.float32)
    row = b"".join(struct.pack(">3f4x", *p) for p in pts)
    cloud = ros.decode_pointcloud2(_cloud_msg(fields, [row], 2, 16, big=True))
    np.testing.assert_array_equal(cloud.points, pts)
    assert cloud.points.dtype == np.dtype("=f4")


def test_pointcloud2_organised_with_nans_padded_rows_and_count() -> None:
    # 3 rows x 2 columns, rows padded to 40 B, a 2-count field; NaN / inf points dropped and counted.
    fields = [_field("x", 0, 7), _field("y", 4, 7), _field("z", 8, 7), _field("normal", 12, 7, count=2)]
    nan, inf = float("nan"), float("inf")
    grid = [
        [(0.0, 0.0, 1.0), (nan, nan, nan)],
        [(1.0, 2.0, 3.0), (4.0, inf, 6.0)],
        [(7.0, 8.0, nan), (9.0, 10.0, 11.0)],
    ]
    rows = [b"".join(struct.pack("<5f", *p, 0.5 * (r * 2 + c), -float(r * 2 + c)) for c, p in enumerate(row))
            for r, row in enumerate(grid)]
    cloud = ros.decode_pointcloud2(_cloud_msg(fields, rows, 2, 20, row_step=40, dense=False))
    assert (cloud.height, cloud.width) == (3, 2)
    assert cloud.dropped == 3 and cloud.index.tolist() == [0, 2, 5]
    np.testing.assert_array_equal(cloud.points, [[0, 0, 1], [1, 2, 3], [9, 10, 11]])
    assert cloud.fields["normal"].shape == (3, 2)
    np.testing.assert_array_equal(cloud.fields["normal"], [[0.0, 0.0], [1.0, -2.0], [2.5, -5.0]])
    kept = ros.decode_pointcloud2(_cloud_msg(fields, rows, 2, 20, row_step=40), drop_invalid=False)
    assert len(kept) == 6 and kept.dropped == 0 and np.isnan(kept.points[1]).all()


def test_pointcloud2_encoder_round_trips_odd_layouts() -> None:
    rng = np.random.default_rng(3)
    points = rng.normal(size=(12, 3)).astype(np.float32)
    points[[2, 7]] = np.nan
    fields = {"intensity": rng.random(12).astype(np.float32), "ring": rng.integers(0, 64, 12).astype(np.uint8),
              "t": rng.integers(0, 2**31, 12).astype(np.uint32), "rgb": rng.integers(0, 255, (12, 3)).astype(np.uint8)}
    for big in (False, True):
        msg = ros.pointcloud2_message(points, fields, stamp_ns=T0, frame_id="os_lidar", organised_shape=(3, 4),
                                      big_endian=big, point_step=40, layout=["ring", "t", "x", "rgb", "y", "intensity", "z"],
                                      row_padding=6)
        assert msg.row_step == 4 * 40 + 6 and msg.is_dense is False
        cloud = ros.decode_pointcloud2(msg)
        keep = np.isfinite(points).all(axis=1)
        np.testing.assert_array_equal(cloud.points, points[keep])
        for name, value in fields.items():
            np.testing.assert_array_equal(cloud.fields[name], value[keep])
        assert cloud.dropped == 2 and (cloud.height, cloud.width) == (3, 4)
    only = ros.decode_pointcloud2(msg, fields=("ring",))
    assert set(only.fields) == {"ring"}
    with pytest.raises(errors.InputError, match="no field nope"):
        ros.decode_pointcloud2(msg, fields=("nope",))


def test_empty_pointcloud2_decodes_to_no_points() -> None:
    msg = ros.pointcloud2_message(np.zeros((0, 3), np.float32), {"intensity": np.zeros(0, np.float32)}, stamp_ns=T0, frame_id="l")
    cloud = ros.decode_pointcloud2(msg)
    assert cloud.points.shape == (0, 3) and cloud.fields["intensity"].shape == (0,) and cloud.dropped == 0


@pytest.mark.parametrize(
    ("fields", "point_step", "size", "match"),
    [
        ([_field("x", 0, 7), _field("y", 4, 7)], 12, 24, "no field z"),
        ([_field("x", 0, 7), _field("y", 4, 7), _field("z", 8, 9)], 12, 24, "unknown datatype 9"),
        ([_field("x", 0, 7), _field("y", 4, 7), _field("z", 10, 7)], 12, 24, "does not fit in point_step 12"),
        ([_field("x", 0, 7), _field("y", 4, 7), _field("z", 8, 7)], 12, 23, "truncated message"),
        ([_field("x", 0, 7), _field("x", 4, 7), _field("z", 8, 7)], 12, 24, "appears twice"),
    ],
)
def test_bad_pointcloud2_is_a_file_format_error(fields, point_step, size, match) -> None:
    msg = SimpleNamespace(header=_header(), height=1, width=2, fields=fields, is_bigendian=False, point_step=point_step,
                          row_step=2 * point_step, data=bytes(size), is_dense=True)
    with pytest.raises(errors.FileFormatError, match=match) as info:
        ros.decode_pointcloud2(msg, where="/points at 5")
    assert "(/points at 5)" in str(info.value)


# ----------------------------------------------------------------------------- images and camera info


def test_image_hand_packed_big_endian_with_row_padding() -> None:
    values = np.array([[1, 2, 1000], [65535, 0, 300]], np.uint16)
    data = b"".join(struct.pack(">3H", *row) + b"\x00\x11" for row in values)  # 2 padding bytes a row
    msg = SimpleNamespace(header=_header(frame="cam"), height=2, width=3, encoding="16UC1", is_bigendian=1, step=8, data=data)
    image = ros.decode_image(msg)
    assert image.dtype == np.uint16 and image.dtype.isnative
    np.testing.assert_array_equal(image, values)
    depth = ros.decode_depth_image(msg)
    assert depth.scale_m_per_unit == 0.001
    np.testing.assert_allclose(depth.to_metres()[0, 2], 1.0)
    assert ros.decode_depth_image(msg, scale=1 / 5000).to_metres()[0, 2] == pytest.approx(0.2)


@pytest.mark.parametrize(("encoding", "dtype"), [("32FC1", np.float32), ("mono16", np.uint16), ("16UC1", np.uint16), ("mono8", np.uint8)])
def test_image_encoder_round_trip(encoding: str, dtype) -> None:
    rng = np.random.default_rng(0)
    array = (rng.random((5, 7)) * 200).astype(dtype)
    for big in (False, True):
        msg = ros.image_message(array, stamp_ns=T0, frame_id="cam", encoding=encoding, big_endian=big, row_padding=3)
        assert msg.step == 7 * np.dtype(dtype).itemsize + 3
        np.testing.assert_array_equal(ros.decode_image(msg), array)


def test_depth_image_rejects_unknown_encodings_and_short_data() -> None:
    rgb = ros.image_message(np.zeros((2, 3, 3), np.uint8), stamp_ns=T0, frame_id="c", encoding="rgb8")
    assert ros.decode_image(rgb).shape == (2, 3, 3)
    with pytest.raises(errors.InputError, match=r"unknown encoding 'rgb8'.*16UC1.*\(/camera at 1\)"):
        ros.decode_depth_image(rgb, where="/camera at 1")
    weird = SimpleNamespace(header=_header(), height=2, width=2, encoding="bayer_rggb8", is_bigendian=0, step=2, data=bytes(4))
    with pytest.raises(errors.InputError, match="unknown encoding 'bayer_rggb8'"):
        ros.decode_image(weird)
    short = SimpleNamespace(header=_header(), height=2, width=2, encoding="16UC1", is_bigendian=0, step=4, data=bytes(7))
    with pytest.raises(errors.FileFormatError, match="7 B of data"):
        ros.decode_image(short)
    with pytest.raises(errors.InputError, match="32FC1 depth image is in metres"):
        ros.decode_depth_image(ros.image_message(np.zeros((2, 2), np.float32), stamp_ns=0, frame_id="c"), scale=0.001)


def test_depth_image_from_a_payload_at_an_odd_byte_and_the_checks_the_fast_path_keeps() -> None:
    values = np.arange(12, dtype="<u2").reshape(3, 4) * 250
    payload = np.frombuffer(b"\x00" + values.tobytes(), np.uint8)[1:]  # starts at an odd address, as in a ROS 1 bag
    msg = SimpleNamespace(header=_header(), height=3, width=4, encoding="16UC1", is_bigendian=0, step=8, data=payload)
    depth = ros.decode_depth_image(msg, where="/depth at 2")
    assert depth.data.flags.aligned and depth.data.flags.c_contiguous and depth.data.dtype == np.uint16
    np.testing.assert_array_equal(depth.data, values)
    assert depth.scale_m_per_unit == 0.001 and depth.path == "/depth at 2"
    # A caller's scale is still checked, and an empty image is still refused.
    with pytest.raises(errors.ConfigError, match="scale_m_per_unit: expected a finite number in \\[1e-06, 1\\]"):
        ros.decode_depth_image(msg, scale=-1.0)
    empty = SimpleNamespace(header=_header(), height=0, width=4, encoding="16UC1", is_bigendian=0, step=8, data=b"")
    with pytest.raises(errors.InputError, match="non-empty"):
        ros.decode_depth_image(empty)
    floats = ros.decode_depth_image(ros.image_message(np.full((2, 3), 1.5, np.float32), stamp_ns=0, frame_id="c"))
    assert floats.scale_m_per_unit == 1.0 and floats.to_metres()[1, 2] == 1.5


def test_camera_info_to_intrinsics_and_camera() -> None:
    intr = Intrinsics(617.25, 617.549, 317.392, 245.98, 640, 480)
    msg = ros.camera_info_message(intr, stamp_ns=T0, frame_id="cam")
    assert ros.decode_camera_info(msg) == intr
    camera = ros.decode_camera_info(msg).to_camera()
    assert (camera.fx, camera.cy, camera.width, camera.height) == (617.25, 245.98, 640, 480)
    # ROS 1 spelling (K, P), only P filled, binning 2 and a region of interest.
    ros1 = SimpleNamespace(K=[0.0] * 9, P=[500.0, 0, 320, 0, 0, 510, 240, 0, 0, 0, 1, 0], width=640, height=480,
                           binning_x=2, binning_y=2, roi=SimpleNamespace(x_offset=20, y_offset=40, width=600, height=400))
    assert ros.decode_camera_info(ros1) == Intrinsics(250.0, 255.0, 150.0, 100.0, 300, 200)
    bad = SimpleNamespace(K=[0.0] * 9, P=[0.0] * 12, width=640, height=480)
    with pytest.raises(errors.FileFormatError, match="no positive focal length"):
        ros.decode_camera_info(bad)


# ----------------------------------------------------------------------------- odometry and tf


def _pose(yaw: float, xyz) -> np.ndarray:
    m = np.eye(4)
    m[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    m[:3, 3] = xyz
    return m


def test_odometry_round_trip_and_quaternions() -> None:
    pose = _pose(0.7, (1.0, -2.0, 0.5))
    cov = np.diag(np.arange(1.0, 7.0))
    msg = ros.odometry_message(pose, stamp_ns=T0, frame_id="odom", child_frame_id="base_link", covariance=cov,
                               twist=[0.5, 0, 0, 0, 0, 0.1])
    sample = ros.decode_odometry(msg)
    np.testing.assert_allclose(sample.world_from_body, pose, atol=1e-12)
    np.testing.assert_array_equal(sample.covariance, cov)
    assert sample.twist.tolist() == [0.5, 0, 0, 0, 0, 0.1]
    assert (sample.stamp_ns, sample.frame_id, sample.child_frame_id) == (T0, "odom", "base_link")
    for q in [(0, 0, 0, 1), (1, 0, 0, 0), (0.2, -0.4, 0.1, 0.8), (0, 0, 1, 0)]:
        m = ros.matrix_from_quaternion(*q)
        np.testing.assert_allclose(ros.matrix_from_quaternion(*ros.quaternion_from_matrix(m)), m, atol=1e-12)
    with pytest.raises(errors.InputError, match="quaternion"):
        ros.matrix_from_quaternion(0, 0, 0, 0)


def test_rotations_match_the_closed_forms() -> None:
    """matrix_from_quaternion, quaternion_from_matrix and interpolate_pose (SciPy's Rotation)
    against the textbook formulas, and their errors."""

    def closed_form(x, y, z, w):
        return np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ])

    rng = np.random.default_rng(7)
    for q in rng.standard_normal((50, 4)):
        m = ros.matrix_from_quaternion(*q)
        np.testing.assert_allclose(m, closed_form(*(q / np.linalg.norm(q))), atol=1e-12)
        back = ros.quaternion_from_matrix(m)
        assert back[3] >= 0 and abs(np.linalg.norm(back) - 1) < 1e-12
        np.testing.assert_allclose(np.abs(back), np.abs(q / np.linalg.norm(q)), atol=1e-12)  # q or -q
    for bad in ((0, 0, 0, 0), (np.nan, 0, 0, 1), (np.inf, 0, 0, 1)):
        with pytest.raises(errors.InputError, match=r"quaternion: expected a finite, non-zero \(x, y, z, w\)"):
            ros.matrix_from_quaternion(*bad)
    for bad in (np.diag([1.0, 1.0, -1.0]), np.full((3, 3), np.nan)):
        with pytest.raises(errors.InputError, match="rotation: expected a"):
            ros.quaternion_from_matrix(bad)

    def yaw(a, xyz=(0.0, 0.0, 0.0)):
        return _pose(a, xyz)

    a, b = yaw(0.0), yaw(np.pi / 2, (2.0, -4.0, 1.0))
    np.testing.assert_allclose(ros.interpolate_pose(a, b, 0.5), yaw(np.pi / 4, (1.0, -2.0, 0.5)), atol=1e-12)
    np.testing.assert_allclose(ros.interpolate_pose(a, b, 0.0), a, atol=1e-12)
    np.testing.assert_allclose(ros.interpolate_pose(a, b, 1.0), b, atol=1e-12)
    np.testing.assert_allclose(ros.interpolate_pose(a, b, 1.5), yaw(3 * np.pi / 4, (3.0, -6.0, 1.5)), atol=1e-12)
    # The shorter way round: from +170 deg to -170 deg passes 180 deg, not 0.
    np.testing.assert_allclose(ros.interpolate_pose(yaw(np.radians(170)), yaw(np.radians(-170)), 0.5), yaw(np.pi), atol=1e-12)
    with pytest.raises(errors.InputError, match="fraction"):
        ros.interpolate_pose(a, b, float("nan"))


def test_transform_buffer_static_chain_and_interpolation() -> None:
    buf = ros.TransformBuffer()
    base_from_mount = _pose(0.0, (0.2, 0.0, 0.5))
    mount_from_lidar = _pose(np.pi, (0.0, 0.0, 0.036))
    buf.add_message(ros.tf_message([("base_link", "mount", 0, base_from_mount), ("/mount", "lidar", 0, mount_from_lidar)]), static=True)
    np.testing.assert_allclose(buf.lookup("base_link", "lidar"), base_from_mount @ mount_from_lidar, atol=1e-12)
    np.testing.assert_allclose(buf.lookup("lidar", "base_link"), np.linalg.inv(base_from_mount @ mount_from_lidar), atol=1e-12)
    assert buf.static_only("base_link", "lidar")
    # Dynamic odom -> base_link at t = 0 and t = 1 s: halfway is halfway in x and in yaw.
    buf.add("odom", "base_link", _pose(0.0, (0, 0, 0)), stamp_ns=0)
    buf.add("odom", "base_link", _pose(1.0, (2, 0, 0)), stamp_ns=1_000_000_000)
    np.testing.assert_allclose(buf.lookup("odom", "base_link", 500_000_000), _pose(0.5, (1, 0, 0)), atol=1e-12)
    np.testing.assert_allclose(buf.lookup("odom", "lidar", 500_000_000),
                               _pose(0.5, (1, 0, 0)) @ base_from_mount @ mount_from_lidar, atol=1e-12)
    assert not buf.static_only("odom", "lidar")
    with pytest.raises(errors.InputError, match="no sample near"):
        buf.lookup("odom", "base_link", 5_000_000_000)
    with pytest.raises(errors.InputError, match=r"no chain.*frames known: base_link, lidar, mount, odom"):
        buf.lookup("map", "lidar")


# ----------------------------------------------------------------------------- recordings


def _messages():
    """A few messages of every kind, in log-time order."""
    intr = Intrinsics(385.0, 385.0, 319.5, 239.5, 8, 6)
    depth = (np.arange(48, dtype=np.uint16).reshape(6, 8) * 37)
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(10, 3)).astype(np.float32)
    items = [("/tf_static", T0, ros.tf_message([("base_link", "lidar", T0, _pose(0.0, (0, 0, 0.7)))]))]
    for i in range(3):
        s = T0 + i * 100_000_000
        items.append(("/cam/info", s, ros.camera_info_message(intr, stamp_ns=s, frame_id="cam")))
        items.append(("/cam/depth", s + 1, ros.image_message(depth + i, stamp_ns=s, frame_id="cam")))
        items.append(("/points", s + 2, ros.pointcloud2_message(pts + i, {"intensity": np.full(10, i, np.float32)},
                                                                stamp_ns=s, frame_id="lidar")))
        items.append(("/odom", s + 3, ros.odometry_message(_pose(0.1 * i, (i, 0, 0)), stamp_ns=s)))
    return items, depth, pts


def _check_read_back(path: Path) -> None:
    items, depth, pts = _messages()
    with open_recording(path) as rec:
        topics = rec.topics
        assert {k: (v.type, v.count) for k, v in topics.items()} == {
            "/cam/depth": ("sensor_msgs/msg/Image", 3), "/cam/info": ("sensor_msgs/msg/CameraInfo", 3),
            "/odom": ("nav_msgs/msg/Odometry", 3), "/points": ("sensor_msgs/msg/PointCloud2", 3),
            "/tf_static": ("tf2_msgs/msg/TFMessage", 1),
        }
        got = list(rec.messages())
        assert [(t, s) for t, s, _ in got] == [(t, s) for t, s, _ in items]  # log-time order, every message
        depths = [m for t, _, m in got if t == "/cam/depth"]
        for i, m in enumerate(depths):
            np.testing.assert_array_equal(ros.decode_depth_image(m).data, depth + i)
        clouds = [ros.decode_pointcloud2(m) for t, _, m in got if t == "/points"]
        np.testing.assert_array_equal(clouds[2].points, pts + 2)
        assert clouds[1].fields["intensity"].tolist() == [1.0] * 10
        info = ros.decode_camera_info(got[1].message)
        assert (info.fx, info.width, info.height) == (385.0, 8, 6)
        odom = ros.decode_odometry([m for t, _, m in got if t == "/odom"][2])
        np.testing.assert_allclose(odom.world_from_body, _pose(0.2, (2, 0, 0)), atol=1e-12)
        assert odom.stamp_ns == T0 + 200_000_000
        only = list(rec.messages(["/points", "/odom"]))
        assert [t for t, _, _ in only] == ["/points", "/odom"] * 3


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_ros2_bag_round_trip(tmp_path: Path, storage: str) -> None:
    bag = write_bag(tmp_path / "bag", _messages()[0], storage=storage)
    with open_recording(bag) as rec:
        assert rec.format == "ros2-bag" and rec.profile == storage
    _check_read_back(bag)


def test_ros1_bag_round_trip(tmp_path: Path) -> None:
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    intr = Intrinsics(385.0, 385.0, 319.5, 239.5, 8, 6)
    pts = np.arange(12, dtype=np.float32).reshape(4, 3)
    items = [
        ("/cam/info", T0, ros.camera_info_message(intr, stamp_ns=T0, frame_id="cam", typestore=store)),
        ("/points", T0 + 5, ros.pointcloud2_message(pts, stamp_ns=T0, frame_id="lidar", typestore=store, big_endian=True)),
        ("/tf_static", T0 + 9, ros.tf_message([("base_link", "lidar", T0, _pose(0.0, (0, 0, 0.4)))], typestore=store)),
    ]
    bag = write_bag(tmp_path / "run.bag", items, typestore=store)
    with open_recording(bag) as rec:
        assert rec.format == "ros1-bag"
        assert {t.name: t.encoding for t in rec.topics.values()} == {"/cam/info": "ros1", "/points": "ros1", "/tf_static": "ros1"}
        got = list(rec.messages())
    assert [(t, s) for t, s, _ in got] == [(t, s) for t, s, _ in items]
    assert ros.decode_camera_info(got[0].message) == intr  # ROS 1 field names K, P
    np.testing.assert_array_equal(ros.decode_pointcloud2(got[1].message).points, pts)
    buf = ros.TransformBuffer()
    buf.add_message(got[2].message, static=True)
    assert buf.lookup("base_link", "lidar")[2, 3] == pytest.approx(0.4)


def test_mcap_writer_round_trip_and_independent_decoder(tmp_path: Path) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    items, depth, pts = _messages()
    path = tmp_path / "out.mcap"
    with McapWriter(path) as writer:
        for topic, stamp, msg in items:
            writer.write(topic, msg, log_time_ns=stamp)
    assert writer.counts["/points"] == 3
    _check_read_back(path)
    # mcap-ros2-support parses our ros2msg schemas and decodes the CDR on its own.
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        decoded = {}
        for schema, channel, message, obj in reader.iter_decoded_messages():
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            decoded.setdefault(channel.topic, []).append((message.log_time, obj))
    image = decoded["/cam/depth"][1][1]
    assert (image.height, image.width, image.encoding, image.header.frame_id) == (6, 8, "16UC1", "cam")
    np.testing.assert_array_equal(np.frombuffer(bytes(image.data), "<u2").reshape(6, 8), depth + 1)
    cloud = decoded["/points"][0][1]
    assert [f.name for f in cloud.fields] == ["x", "y", "z", "intensity"] and cloud.point_step == 16
    assert decoded["/odom"][2][1].pose.pose.position.x == 2.0
    assert decoded["/cam/info"][0][1].k[0] == 385.0


def test_recordings_with_the_same_schemas_share_one_compiled_typestore(tmp_path: Path) -> None:
    """A second recording embedding the same schemas decodes with the store compiled for
    the first (rosbags compiles per store); a schema of other text gets its own."""
    from subterra.io import recordings

    items, _, _ = _messages()
    paths = [tmp_path / "a.mcap", tmp_path / "b.mcap"]
    for path in paths:
        with McapWriter(path) as writer:
            for topic, stamp, msg in items:
                writer.write(topic, msg, log_time_ns=stamp)
    recordings._typestore.cache_clear()
    for path in paths:
        with open_recording(path) as rec:
            decoded = list(rec.messages())
        assert len(decoded) == len(items)
    info = recordings._typestore.cache_info()
    kinds = {type(msg).__name__ for _, _, msg in items}
    assert info.misses == len(kinds) and info.hits == len(kinds), info


def test_a_summary_that_does_not_list_a_channel_of_the_data_is_corrupt(tmp_path: Path) -> None:
    """A recording whose summary names a channel ``/tf_statyc`` while its (uncompressed)
    data has ``/tf_static``: found by the recording_mcap fuzz target, where the message's
    topic was missing from ``topics`` (a KeyError in the caller's lookup)."""
    found = Path(__file__).resolve().parents[2] / "fuzz" / "regressions" / "recording_mcap" / "channel-missing-from-summary"
    path = tmp_path / "renamed.mcap"
    shutil.copyfile(found, path)
    with open_recording(path) as rec:
        assert "/tf_statyc" in rec.topics and "/tf_static" not in rec.topics
        with pytest.raises(errors.FileFormatError, match=r"corrupt: message \d+ is on topic '/tf_static'.*summary does not list") as info:
            list(rec.messages())
    assert str(info.value).endswith(str(path))


def test_plain_mcap_with_ros1_encoding_from_an_independent_writer(tmp_path: Path) -> None:
    from mcap_ros1._vendor.genpy import dynamic
    from mcap_ros1.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    text, _ = get_typestore(Stores.ROS1_NOETIC).generate_msgdef("sensor_msgs/msg/PointCloud2", ros_version=1)
    classes = dynamic.generate_dynamic("sensor_msgs/PointCloud2", text)
    cls, field_cls = classes["sensor_msgs/PointCloud2"], classes["sensor_msgs/PointField"]
    pts = np.array([[1, 2, 3], [np.nan, 0, 0], [-4, 5, -6]], np.float32)
    data = b"".join(struct.pack("<3fxxxxB3x", *p, 9) for p in pts)  # 20 B a point: xyz, 4 B gap, ring
    msg = cls()
    msg.header.stamp.secs, msg.header.stamp.nsecs, msg.header.frame_id = 100, 5, "os1_lidar"
    msg.height, msg.width, msg.point_step, msg.row_step, msg.is_bigendian, msg.is_dense = 1, 3, 20, 60, False, False
    msg.fields = [field_cls("x", 0, 7, 1), field_cls("y", 4, 7, 1), field_cls("z", 8, 7, 1), field_cls("ring", 16, 2, 1)]
    msg.data = data
    path = tmp_path / "ros1.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.write_message("/os1_cloud_node/points", msg, log_time=42)
        writer.finish()
    with open_recording(path) as rec:
        assert rec.format == "mcap" and rec.profile == "ros1"
        assert rec.topics["/os1_cloud_node/points"].encoding == "ros1"
        [(topic, stamp, got)] = list(rec.messages())
    cloud = ros.decode_pointcloud2(got)
    assert (topic, stamp, cloud.stamp_ns, cloud.frame_id) == ("/os1_cloud_node/points", 42, 100_000_000_005, "os1_lidar")
    np.testing.assert_array_equal(cloud.points, pts[[0, 2]])
    assert cloud.dropped == 1 and cloud.fields["ring"].tolist() == [9, 9]


def test_big_endian_cdr_message_in_mcap(tmp_path: Path) -> None:
    from mcap.writer import Writer

    store = ros.default_typestore()
    pts = np.array([[1.0, 2.0, 3.0]], np.float32)
    msg = ros.pointcloud2_message(pts, stamp_ns=T0, frame_id="l")
    path = tmp_path / "be.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2")
        text, _ = store.generate_msgdef(msg.__msgtype__, ros_version=2)
        sid = w.register_schema(msg.__msgtype__, "ros2msg", text.encode())
        cid = w.register_channel("/p", "cdr", sid)
        w.add_message(cid, log_time=1, data=bytes(store.serialize_cdr(msg, msg.__msgtype__, little_endian=False)), publish_time=1)
        w.finish()
    with open_recording(path) as rec:
        [(_, _, got)] = list(rec.messages(["/p"]))
    assert ros.stamp_ns(got) == T0
    np.testing.assert_array_equal(ros.decode_pointcloud2(got).points, pts)


# ----------------------------------------------------------------------------- bad recordings


def test_missing_topic_lists_the_topics_present(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "bag", _messages()[0])
    with open_recording(bag) as rec:
        with pytest.raises(errors.InputError) as info:
            list(rec.messages(["/camera/depth"]))
        text = str(info.value)
        assert "'/camera/depth' is not in the recording" in text
        for topic in ("/cam/depth (sensor_msgs/msg/Image, 3)", "/points (sensor_msgs/msg/PointCloud2, 3)", "/odom"):
            assert topic in text
        assert text.endswith(str(bag))
        with pytest.raises(errors.InputError, match="has type sensor_msgs/msg/PointCloud2, expected sensor_msgs/msg/Image"):
            rec.topic("/points", ["sensor_msgs/Image"])


def test_truncated_mcap_reads_up_to_the_break(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    items = [(f"/{name}", T0 + 10 * i + k, ros.pointcloud2_message(rng.normal(size=(1000, 3)).astype(np.float32),
                                                                    stamp_ns=T0 + 10 * i, frame_id="l"))
             for i in range(8) for k, name in enumerate(("front", "back"))]
    full = tmp_path / "full.mcap"
    with McapWriter(full, chunk_size=4096) as writer:  # one cloud (12 kB) a chunk
        for topic, stamp, msg in items:
            writer.write(topic, msg, log_time_ns=stamp)
    raw = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(raw[: len(raw) // 2])
    with open_recording(cut) as rec:
        assert rec.damage is not None and "breaks off after" in rec.damage
        counts = {t.name: t.count for t in rec.topics.values()}
        assert 0 < sum(counts.values()) < len(items)
        got = []
        with pytest.raises(errors.FileFormatError, match=r"truncated or corrupt after \d+ messages.*cut\.mcap$"):
            for item in rec.messages(["/front", "/back"]):
                got.append(item)
        assert len(got) == sum(counts.values())
        assert [s for _, s, _ in got] == [s for _, s, _ in items[: len(got)]]
        for (_, _, m), (_, _, sent) in zip(got, items):  # what came before the break decodes
            np.testing.assert_array_equal(ros.decode_pointcloud2(m).points, ros.decode_pointcloud2(sent).points)


def test_truncated_and_corrupt_bags_are_file_format_errors(tmp_path: Path) -> None:
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    items = [("/p", T0 + i, ros.pointcloud2_message(np.ones((50, 3), np.float32), stamp_ns=T0, frame_id="l", typestore=store))
             for i in range(5)]
    bag1 = write_bag(tmp_path / "a.bag", items)
    cut1 = tmp_path / "cut.bag"
    cut1.write_bytes(bag1.read_bytes()[: bag1.stat().st_size // 2])
    with pytest.raises(errors.FileFormatError, match=r"cut\.bag$"):
        open_recording(cut1)
    bag2 = write_bag(tmp_path / "b", _messages()[0], storage="sqlite3")
    db = next(bag2.glob("*.db3"))
    db.write_bytes(db.read_bytes()[:3000])
    with pytest.raises(errors.FileFormatError) as info:
        with open_recording(bag2) as rec:
            list(rec.messages())
    assert str(bag2) in str(info.value)
    garbage = tmp_path / "x.mcap"
    garbage.write_bytes(b"not a recording at all")
    with pytest.raises(errors.FileFormatError, match="not a recording"):
        open_recording(garbage)
    empty = tmp_path / "e.mcap"
    empty.write_bytes(b"")
    with pytest.raises(errors.FileFormatError, match="empty"):
        open_recording(empty)
    with pytest.raises(errors.FileFormatError, match="not found"):
        open_recording(tmp_path / "nope.mcap")
    (tmp_path / "folder").mkdir()
    with pytest.raises(errors.FileFormatError, match="no metadata.yaml"):
        open_recording(tmp_path / "folder")


def test_unknown_message_encoding_is_a_file_format_error(tmp_path: Path) -> None:
    from mcap.writer import Writer

    path = tmp_path / "json.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="")
        sid = w.register_schema("Pose", "jsonschema", b"{}")
        cid = w.register_channel("/pose_json", "json", sid)
        w.add_message(cid, log_time=1, data=b'{"x": 1}', publish_time=1)
        w.finish()
    with open_recording(path) as rec:
        assert rec.topics["/pose_json"].encoding == "json"
        with pytest.raises(errors.FileFormatError, match=r"'/pose_json' has message encoding 'json'.*json\.mcap$"):
            list(rec.messages(["/pose_json"]))


# ----------------------------------------------------------------------------- real data


def test_ouster_os1_64_mcap_clouds_match_their_headers(shared_data: Path) -> None:
    path = shared_data / "mcap-ouster-os1-64" / "test.mcap"
    with open_recording(path) as rec:
        assert rec.format == "mcap" and rec.profile == "ros1" and rec.damage is None
        assert rec.topics["/os1_cloud_node/points"].count == 2
        assert rec.topics["/os1_cloud_node/points"].type == "sensor_msgs/msg/PointCloud2"
        messages = list(rec.messages(["/os1_cloud_node/points", "/tf_static"]))
    buf = ros.TransformBuffer()
    clouds = []
    for topic, _, msg in messages:
        if topic == "/tf_static":
            buf.add_message(msg, static=True)
            continue
        cloud = ros.decode_pointcloud2(msg)
        clouds.append(cloud)
        # Point count = width x height from the header; every field decoded.
        assert (msg.height, msg.width) == (64, 2048) and msg.point_step == 48
        assert len(cloud) + cloud.dropped == msg.width * msg.height == 131072
        assert sorted(cloud.fields) == ["intensity", "noise", "range", "reflectivity", "ring", "t"]
        assert cloud.frame_id == "os1_lidar"
        # The values are what the fields say: 64 rings, a 10 Hz sweep, range [mm] = |xyz|.
        ring = cloud.fields["ring"]
        assert ring.dtype == np.uint8 and ring.min() == 0 and ring.max() == 63
        assert np.bincount(ring).tolist() == [2048] * 64  # an organised 64 x 2048 scan
        t = cloud.fields["t"]
        assert t.dtype == np.uint32 and 0 <= t.min() and t.max() < 100_000_000  # ns within one 100 ms sweep
        rng_mm = cloud.fields["range"].astype(np.float64)
        hit = rng_mm > 0
        assert 0.3 < hit.mean() < 0.5
        norm_mm = 1000.0 * np.linalg.norm(cloud.points[hit].astype(np.float64), axis=1)
        assert np.median(np.abs(norm_mm - rng_mm[hit])) < 30.0  # the lidar frame sits a few cm off the range origin
        assert (cloud.points[~hit] == 0).all()  # no return: the driver writes (0, 0, 0)
        assert cloud.fields["intensity"].dtype == np.float32 and cloud.fields["reflectivity"].dtype == np.uint16
        assert 1.0 < np.abs(cloud.points).max() < 30.0
    assert len(clouds) == 2 and clouds[1].stamp_ns - clouds[0].stamp_ns == pytest.approx(1e8, rel=0.05)
    sensor_from_lidar = buf.lookup("os1_sensor", "os1_lidar")
    np.testing.assert_allclose(sensor_from_lidar[:3, 3], [0, 0, 0.03618])
    np.testing.assert_allclose(sensor_from_lidar[:3, :3], np.diag([-1.0, -1.0, 1.0]), atol=1e-12)


def test_ouster_mcap_copy_cut_in_half_fails_cleanly(shared_data: Path, tmp_path: Path) -> None:
    src = shared_data / "mcap-ouster-os1-64" / "test.mcap"
    cut = tmp_path / "cut.mcap"
    with open(src, "rb") as f:
        cut.write_bytes(f.read(3_000_000))
    with open_recording(cut) as rec:
        assert rec.topics["/os1_cloud_node/points"].count == 1
        got = []
        with pytest.raises(errors.FileFormatError, match="truncated or corrupt after 1 messages"):
            for item in rec.messages(["/os1_cloud_node/points"]):
                got.append(item)
    assert len(ros.decode_pointcloud2(got[0].message)) == 131072
    shutil.rmtree(tmp_path, ignore_errors=True)


def test_a_message_of_another_schema_is_a_file_format_error() -> None:
    """A recording whose embedded schema lost a field (a ``Transform`` without its
    ``translation``; found by the ``recording_mcap`` fuzz target) or holds a text where a
    number belongs is a FileFormatError naming the message type and the place."""
    quat = SimpleNamespace(x=0.0, y=0.0, z=0.0, w=1.0)
    tf = SimpleNamespace(header=_header(), child_frame_id="base_link", transform=SimpleNamespace(rotation=quat))
    with pytest.raises(errors.FileFormatError, match=r"tf2_msgs/TFMessage: the message has no field 'translation'.*topic /tf"):
        ros.decode_transforms(SimpleNamespace(transforms=[tf]), where="topic /tf")
    tf.transform.translation = SimpleNamespace(x="one", y=0.0, z=0.0)
    with pytest.raises(errors.FileFormatError, match=r"tf2_msgs/TFMessage: a field does not hold"):
        ros.decode_transforms(SimpleNamespace(transforms=[tf]))
    with pytest.raises(errors.FileFormatError, match=r"nav_msgs/Odometry: the message has no field 'pose'"):
        ros.decode_odometry(SimpleNamespace(header=_header()))
    with pytest.raises(errors.FileFormatError, match=r"sensor_msgs/PointCloud2"):
        ros.decode_pointcloud2(SimpleNamespace(header=_header()))
