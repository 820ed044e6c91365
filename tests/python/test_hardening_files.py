"""Issue 22, files: nothing kills or hangs the process, nothing wrong is accepted.

Every file entry point refuses a FIFO, a device or a folder at once (a FIFO used to block
forever, ``/dev/zero`` used to fill the memory), refuses files over its size limit and
non-UTF-8 text with a :class:`FileFormatError` naming the path; formats check their
counts against the bytes they hold (PLY, PCD, PointCloud2, ``.npz``); deeply nested
YAML / JSON / TOML is an error, not a ``RecursionError``; a ``TransformBuffer`` takes
only finite rigid transforms.

A call that could block runs in a daemon thread joined with a timeout, so a regression
fails the test instead of hanging the run.
"""

from __future__ import annotations

import io
import json
import os
import struct
import threading
import time
import zipfile
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

import subterra
from subterra import errors, sim
from subterra.batch import load_sweep
from subterra.io import clouds, depth, intrinsics, poses, ros
from subterra.io.recordings import open_recording
from subterra.terrain import load_terrain_config

needs_fifo = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs os.mkfifo (POSIX)")
needs_dev_zero = pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="needs /dev/zero")

FINISH_S = 5.0


def _outcome(call: Callable[[], Any], unblock: Path | None = None) -> BaseException | None:
    """Run ``call`` in a daemon thread; fail if it has not finished within FINISH_S.

    Returns the exception it raised (None if it returned). A call stuck opening or reading
    the FIFO ``unblock`` is released by opening and closing the write end.
    """
    box: dict[str, BaseException | None] = {}

    def run() -> None:
        try:
            call()
        except BaseException as exc:  # noqa: BLE001 - handed back to the test
            box["exc"] = exc
        else:
            box["exc"] = None

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(FINISH_S)
    if thread.is_alive():
        if unblock is not None:
            try:
                os.close(os.open(unblock, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass
        pytest.fail(f"the call did not finish within {FINISH_S} s (blocked on a FIFO?)")
    return box["exc"]


def _raises(exc: BaseException | None, cls: type[BaseException], phrase: str, path: Path | str) -> str:
    assert type(exc) is cls, f"expected {cls.__name__}, got {type(exc).__name__}: {exc}"
    message = str(exc)
    assert phrase in message, message
    assert message.endswith(str(path)), message
    return message


# ------------------------------------------------------------------- FIFOs, devices, folders

_ENTRY_POINTS: dict[str, tuple[str, Callable[[Path], Any]]] = {
    "load_world": ("world.toml", sim.load_world),
    "load_config": ("flight.toml", subterra.load_config),
    "load_terrain_config": ("terrain.toml", load_terrain_config),
    "load_sweep": ("sweep.toml", load_sweep),
    "open_recording": ("run.mcap", open_recording),
    "read_cloud": ("scan.pcd", clouds.read_cloud),
    "read_cloud_kitti": ("scan.bin", lambda p: clouds.read_cloud(p, format="kitti")),
    "read_depth_png": ("frame.png", depth.read_depth),
    "read_depth_npz": ("frame.npz", depth.read_depth),
    "read_depth_pgm": ("frame.pgm", depth.read_depth),
    "read_intrinsics": ("camera.yaml", intrinsics.read_intrinsics),
    "read_trajectory": ("poses.txt", poses.read_trajectory),
}


@needs_fifo
@pytest.mark.parametrize("entry", sorted(_ENTRY_POINTS))
def test_a_fifo_is_refused_at_once(tmp_path: Path, entry: str) -> None:
    name, reader = _ENTRY_POINTS[entry]
    fifo = tmp_path / name
    os.mkfifo(fifo)
    exc = _outcome(lambda: reader(fifo), unblock=fifo)
    _raises(exc, errors.FileFormatError, "not a regular file (got a FIFO", fifo)


@needs_fifo
def test_a_fifo_inside_a_ros2_bag_folder_is_refused_at_once(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: sqlite3\n"
        "  relative_file_paths:\n    - bag_0.db3\n"
    )
    os.mkfifo(bag / "bag_0.db3")
    exc = _outcome(lambda: open_recording(bag), unblock=bag / "bag_0.db3")
    _raises(exc, errors.FileFormatError, "not a regular file (got a FIFO", bag / "bag_0.db3")

    other = tmp_path / "bag2"
    other.mkdir()
    os.mkfifo(other / "metadata.yaml")
    exc = _outcome(lambda: open_recording(other), unblock=other / "metadata.yaml")
    _raises(exc, errors.FileFormatError, "not a regular file (got a FIFO", other / "metadata.yaml")


@needs_dev_zero
@pytest.mark.parametrize("entry", ["load_world", "load_config", "load_sweep", "read_cloud_kitti", "open_recording"])
def test_dev_zero_is_refused_not_read(entry: str) -> None:
    _, reader = _ENTRY_POINTS[entry]
    exc = _outcome(lambda: reader(Path("/dev/zero")))
    _raises(exc, errors.FileFormatError, "not a regular file (got a character device)", "/dev/zero")


@pytest.mark.parametrize("entry", ["load_world", "load_config", "load_terrain_config", "load_sweep", "read_cloud"])
def test_a_folder_is_refused(tmp_path: Path, entry: str) -> None:
    name, reader = _ENTRY_POINTS[entry]
    folder = tmp_path / name
    folder.mkdir()
    with pytest.raises(errors.FileFormatError, match=r"not a regular file \(got a folder\)") as info:
        reader(folder)
    assert str(info.value).endswith(str(folder))


def test_a_missing_file_names_the_reason_and_the_path(tmp_path: Path) -> None:
    path = tmp_path / "nope.toml"
    with pytest.raises(errors.FileFormatError, match=r"cannot read config file: missing path") as info:
        subterra.load_config(path)
    assert str(info.value).endswith(str(path))


@pytest.mark.parametrize("entry", ["load_world", "load_config", "load_terrain_config", "load_sweep", "read_intrinsics"])
def test_non_utf8_text_is_a_file_format_error_with_the_byte_offset(tmp_path: Path, entry: str) -> None:
    name, reader = _ENTRY_POINTS[entry]
    path = tmp_path / name
    path.write_bytes(b"a =\n\xff\xfe 1\n")
    with pytest.raises(errors.FileFormatError, match=r"not UTF-8 text \(byte offset 4, line 2") as info:
        reader(path)
    assert str(info.value).endswith(str(path))


def test_a_text_file_over_the_limit_is_refused_before_it_is_read(tmp_path: Path) -> None:
    path = tmp_path / "huge.toml"
    with open(path, "wb") as handle:
        handle.truncate(17 * 1024 * 1024)  # sparse: no disk, no memory
    for reader in (subterra.load_config, sim.load_world, load_sweep):
        with pytest.raises(errors.FileFormatError, match=r"17825792 bytes, over the limit of 16777216") as info:
            reader(path)
        assert str(info.value).endswith(str(path))


# ------------------------------------------------------------------------------------- PLY


def _ply_header(encoding: str, vertices: int, props: str, *extra: str) -> bytes:
    lines = ["ply", f"format {encoding} 1.0", f"element vertex {vertices}"]
    lines += [f"property float {p}" for p in props]
    lines += list(extra)
    return ("\n".join([*lines, "end_header"]) + "\n").encode()


def test_ascii_ply_whose_vertex_count_reaches_into_the_faces_is_refused(tmp_path: Path) -> None:
    # 3 vertices declared, 2 present: the face line "3 0 1 2" has 4 values like a vertex.
    path = tmp_path / "lie.ply"
    face = ("element face 1", "property list uchar int vertex_indices")
    path.write_bytes(_ply_header("ascii", 3, "xyzw", *face) + b"0 0 0 1\n1 0 0 1\n3 0 1 2\n")
    with pytest.raises(errors.FileFormatError, match=r"declares 4 element lines \(vertex 3, face 1\), got 3") as info:
        clouds.read_cloud(path)
    assert str(info.value).endswith(str(path))

    path.write_bytes(_ply_header("ascii", 2, "xyz") + b"0 0 0\n1 0 0\n2 0 0\n")  # one line over
    with pytest.raises(errors.FileFormatError, match=r"declares 2 element lines \(vertex 2\), got 3"):
        clouds.read_cloud(path)

    path.write_bytes(_ply_header("ascii", 2, "xyz", *face) + b"0 0 0\n1 0 0\n3 0 1 2\n\n")  # a final blank line is fine
    assert len(clouds.read_cloud(path)) == 2


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian"])
@pytest.mark.parametrize("faces_first", [False, True], ids=["vertices", "faces-first"])
def test_ply_element_counts_beyond_any_integer_are_truncation_errors(tmp_path: Path, fmt: str, faces_first: bool) -> None:
    # Found by the cloud_ply fuzz target: an ascii count past 2^63 raised OverflowError
    # from bytes.split instead of saying the file is shorter than its header.
    faces = "element face 99999999999999999999999999999\nproperty list uchar int vertex_indices\n" if faces_first else ""
    header = f"ply\nformat {fmt} 1.0\n{faces}element vertex 1{'0' * 40}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    path = tmp_path / "huge.ply"
    path.write_bytes(header.encode() + b"1 2 3\n" * 3)
    with pytest.raises(errors.FileFormatError, match=r"truncated|end inside") as info:
        clouds.read_cloud(path)
    assert str(info.value).endswith(str(path))


@pytest.mark.parametrize("order", ["<", ">"], ids=["little", "big"])
def test_binary_ply_whose_vertex_count_reaches_into_the_faces_is_refused(tmp_path: Path, order: str) -> None:
    encoding = "binary_little_endian" if order == "<" else "binary_big_endian"
    face = ("element face 1", "property list uchar int vertex_indices")
    vertices = np.arange(6, dtype=order + "f4").tobytes()  # 2 vertices of 12 bytes
    # 13 bytes of a face: more than a vertex. A third vertex would end 1 byte before the file
    # does, and that byte (0x02) cannot be a face: its list of 2 ints needs 8 more bytes.
    faces = b"\x03" + np.array([0, 1, 0x02000002], order + "i4").tobytes()
    path = tmp_path / "lie.ply"
    path.write_bytes(_ply_header(encoding, 3, "xyz", *face) + vertices + faces)
    with pytest.raises(errors.FileFormatError, match=r"expected 1 'face' records after the vertices, got 1 bytes") as info:
        clouds.read_cloud(path)
    assert "vertex 3, face 1" in str(info.value) and str(info.value).endswith(str(path))

    path.write_bytes(_ply_header(encoding, 2, "xyz", *face) + vertices + faces + b"junk")
    with pytest.raises(errors.FileFormatError, match=r"4 bytes after the last element.*trailing garbage"):
        clouds.read_cloud(path)

    path.write_bytes(_ply_header(encoding, 2, "xyz", *face) + vertices + faces + b"\n")
    np.testing.assert_array_equal(clouds.read_cloud(path).points, np.arange(6, dtype=np.float32).reshape(2, 3))


def test_binary_ply_with_many_triangles_after_the_vertices_reads(tmp_path: Path) -> None:
    vertices = np.zeros((4, 3), "<f4")
    tri = np.zeros(1000, [("n", "u1"), ("i", "<i4", (3,))])
    tri["n"] = 3
    path = tmp_path / "mesh.ply"
    face = ("element face 1000", "property list uchar int vertex_indices")
    path.write_bytes(_ply_header("binary_little_endian", 4, "xyz", *face) + vertices.tobytes() + tri.tobytes())
    assert len(clouds.read_cloud(path)) == 4
    path.write_bytes(path.read_bytes()[:-1])
    with pytest.raises(errors.FileFormatError, match=r"1000 'face' records after the vertices"):
        clouds.read_cloud(path)


def test_pcd_lzf_size_that_no_stream_can_inflate_to_is_refused(tmp_path: Path) -> None:
    header = (
        b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1000000\nHEIGHT 1\n"
        b"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 1000000\nDATA binary_compressed\n"
    )
    path = tmp_path / "bomb.pcd"
    path.write_bytes(header + struct.pack("<II", 10, 12_000_000) + bytes(10))
    with pytest.raises(errors.FileFormatError, match=r"12000000 bytes cannot come from 10 LZF bytes"):
        clouds.read_cloud(path)


# ------------------------------------------------------------------------------ PointCloud2


def _cloud_msg(fields: list[tuple[str, int, int]], point_step: int, n: int = 2) -> SimpleNamespace:
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=1, nanosec=0), frame_id="lidar"),
        height=1, width=n, is_bigendian=False, point_step=point_step, row_step=n * point_step,
        data=bytes(n * point_step), is_dense=True,
        fields=[SimpleNamespace(name=a, offset=o, datatype=d, count=1) for a, o, d in fields],
    )  # fmt: skip


def test_pointcloud2_fields_that_overlap_are_refused() -> None:
    msg = _cloud_msg([("x", 0, 7), ("y", 2, 7), ("z", 8, 7)], point_step=12)
    with pytest.raises(errors.FileFormatError, match=r"field 'y' at offset 2 overlaps field 'x' \(bytes 0..3\).*\(/points\)"):
        ros.decode_pointcloud2(msg, where="/points")
    msg = _cloud_msg([("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 10, 4)], point_step=16)
    with pytest.raises(errors.FileFormatError, match=r"field 'intensity' at offset 10 overlaps field 'z'"):
        ros.decode_pointcloud2(msg)
    msg = _cloud_msg([("x", 0, 7), ("y", 4, 7), ("z", 8, 8)], point_step=12)
    with pytest.raises(errors.FileFormatError, match=r"field 'z' at offset 8 with 8 B does not fit in point_step 12"):
        ros.decode_pointcloud2(msg)
    assert len(ros.decode_pointcloud2(_cloud_msg([("x", 0, 7), ("y", 4, 7), ("z", 8, 7)], point_step=12))) == 2


# ------------------------------------------------------------------------------------ .npz


def _npz_with_header(path: Path, shape: tuple[int, ...], data: bytes, dtype: str = "<u2") -> None:
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, {"descr": dtype, "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("depth.npy", buffer.getvalue() + data)


def test_an_npz_declaring_a_huge_depth_image_is_refused_before_it_is_inflated(tmp_path: Path) -> None:
    path = tmp_path / "bomb.npz"
    _npz_with_header(path, (100_000, 100_000), bytes(1000))  # 20 GB declared, 1 kB stored
    start = time.perf_counter()
    with pytest.raises(errors.FileFormatError, match=r"declares shape \(100000, 100000\).*over the limit") as info:
        depth.read_depth(path)
    assert time.perf_counter() - start < 2.0
    assert str(info.value).startswith("depth .npz array 'depth': declares shape")
    assert str(info.value).endswith(str(path))

    _npz_with_header(path, (100, 100), bytes(10))  # a header that promises more than the member holds
    with pytest.raises(errors.FileFormatError, match=r"needs 20000 bytes, the archive member holds 10"):
        depth.read_depth(path)

    image = np.arange(12, dtype=np.uint16).reshape(3, 4)
    np.savez_compressed(path, depth=image)
    np.testing.assert_array_equal(depth.read_depth(path).data, image)


def test_a_png_declaring_a_huge_image_is_refused(tmp_path: Path) -> None:
    import zlib

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", 20_000, 20_000, 16, 0, 0, 0, 0)  # 400 Mpx of 16-bit gray
    path = tmp_path / "bomb.png"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b""))
    with pytest.raises(errors.FileFormatError, match=r"over the limit") as info:
        depth.read_depth(path)
    assert str(info.value).endswith(str(path))


# --------------------------------------------------------------------------- deep nesting


def test_deeply_nested_json_and_yaml_are_file_format_errors(tmp_path: Path) -> None:
    deep = "[" * 100_000 + "]" * 100_000
    for name in ("camera.json", "camera.yaml"):
        path = tmp_path / name
        path.write_text(deep)
        with pytest.raises(errors.FileFormatError, match=r"nesting too deep") as info:
            intrinsics.read_intrinsics(path)
        assert str(info.value).endswith(str(path))


def test_deeply_nested_bag_metadata_is_a_file_format_error(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: " + "[" * 100_000 + "]" * 100_000)
    with pytest.raises(errors.FileFormatError, match=r"nested too deeply") as info:
        open_recording(bag)
    assert str(info.value).endswith(str(bag / "metadata.yaml"))


def test_deeply_nested_toml_is_an_error_not_a_recursion_error(tmp_path: Path) -> None:
    path = tmp_path / "sweep.toml"
    path.write_text("a = " + "[" * 100_000 + "]" * 100_000 + "\n")
    with pytest.raises(errors.ConfigError, match=r"not valid TOML"):
        load_sweep(path)
    for reader in (subterra.load_config, load_terrain_config):
        with pytest.raises(errors.ConfigError) as info:
            reader(path)
        assert str(info.value).endswith(str(path))
    with pytest.raises(errors.FileFormatError, match=r"recurs") as info:
        sim.load_world(path)
    assert str(info.value).endswith(str(path))


# ------------------------------------------------------------------------ TransformBuffer


def _tf_msg(q: tuple[float, float, float, float], t: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> SimpleNamespace:
    stamp = SimpleNamespace(sec=1, nanosec=0)
    transform = SimpleNamespace(
        header=SimpleNamespace(stamp=stamp, frame_id="odom"),
        child_frame_id="base_link",
        transform=SimpleNamespace(
            translation=SimpleNamespace(x=t[0], y=t[1], z=t[2]),
            rotation=SimpleNamespace(x=q[0], y=q[1], z=q[2], w=q[3]),
        ),
    )
    return SimpleNamespace(transforms=[transform])


@pytest.mark.parametrize(
    ("matrix", "phrase"),
    [
        (np.full((4, 4), np.nan), "expected finite values"),
        (np.diag([2.0, 2.0, 2.0, 1.0]), "expected a rotation (orthonormal)"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "det +1, got det -1"),
        (np.vstack([np.eye(4)[:3], [0.0, 0.0, 1.0, 1.0]]), "bottom row 0 0 0 1"),
    ],
)
def test_transform_buffer_refuses_non_rigid_or_non_finite_matrices(matrix: np.ndarray, phrase: str) -> None:
    buf = ros.TransformBuffer()
    with pytest.raises(errors.InputError, match=r"parent_from_child \(transform 'odom' -> 'base_link'\)") as info:
        buf.add("odom", "base_link", matrix, stamp_ns=5)
    assert phrase in str(info.value)
    assert buf.frames == []  # nothing was stored


def test_transform_buffer_refuses_far_translations_bad_shapes_and_stamps() -> None:
    buf = ros.TransformBuffer()
    far = np.eye(4)
    far[0, 3] = 2e6
    with pytest.raises(errors.InputError, match=r"translation within 1e\+06 m"):
        buf.add("odom", "base_link", far)
    with pytest.raises(errors.InputError, match=r"expected shape \(4, 4\), got \(3, 3\)"):
        buf.add("odom", "base_link", np.eye(3))
    with pytest.raises(errors.InputError, match=r"argument `stamp_ns` must be an integer"):
        buf.add("odom", "base_link", np.eye(4), stamp_ns=float("nan"))
    buf.add("odom", "base_link", np.eye(4), stamp_ns=np.int64(7))
    assert buf.can_transform("odom", "base_link", 7)


@pytest.mark.parametrize("stamp", [-1, 2**64, 1.5, "3", None])
def test_transform_buffer_stamps_are_ros_times(stamp: Any) -> None:
    # -1, 2**64 and 1.5 were once stored; a lookup at 'a' raised "'<' not supported".
    buf = ros.TransformBuffer()
    with pytest.raises(errors.InputError, match=r"argument `stamp_ns` must be (an integer|in \[0, )") as info:
        buf.add("odom", "base_link", np.eye(4), stamp_ns=stamp)
    assert "'odom' -> 'base_link'" in str(info.value)
    buf.add("odom", "base_link", np.eye(4), stamp_ns=ros.MAX_STAMP_NS)
    if stamp is not None:  # None: the newest sample
        with pytest.raises(errors.InputError, match=r"argument `stamp_ns`"):
            buf.lookup("odom", "base_link", stamp)
    with pytest.raises(errors.InputError, match=r"argument `stamp_ns`"):
        buf.lookup("odom", "base_link", "a")


@pytest.mark.parametrize("value", [float("nan"), None, -1, 1.5, "3", 2**64])
@pytest.mark.parametrize("name", ["max_extrapolation_ns", "max_history_ns"])
def test_transform_buffer_durations_are_integers_of_nanoseconds(name: str, value: Any) -> None:
    # NaN gave a bare ValueError, None a bare TypeError; -1, 1.5 and '3' were taken.
    if name == "max_history_ns" and value is None:
        ros.TransformBuffer(max_history_ns=None)  # None: keep every sample
        return
    with pytest.raises(errors.InputError, match=f"argument `{name}`"):
        ros.TransformBuffer(**{name: value})


def test_transform_buffer_refuses_a_stack_of_poses_before_copying_it() -> None:
    # A (10^9, 4, 4) broadcast view was copied first: a MemoryError asking for 119 GiB.
    with pytest.raises(errors.InputError, match=r"expected shape \(4, 4\), got \(1000000000, 4, 4\)"):
        ros.TransformBuffer().add("odom", "base_link", np.broadcast_to(np.eye(4), (10**9, 4, 4)))


@pytest.mark.parametrize(
    ("field", "value", "phrase"),
    [
        ("width", 10**9, "camera.width"),
        ("cx", 1e308, "camera.cx"),
        ("fx", 1e-300, "camera.fx"),
        ("height", 2**40, "camera.height"),
    ],
)
def test_intrinsics_beyond_the_cameras_limits_are_refused(tmp_path: Path, field: str, value: Any, phrase: str) -> None:
    # Once read as Intrinsics(width=1000000000, ...): the camera's limits apply to the files too.
    d = {"fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480, field: value}
    with pytest.raises(errors.ConfigError, match=rf"^{field}: .*{phrase}.*: <dict>$"):
        intrinsics.intrinsics_from_dict(d)
    path = tmp_path / "camera.json"
    path.write_text(json.dumps(d))
    with pytest.raises(errors.FileFormatError, match=rf"^{field}: .*{phrase}.*camera\.json$"):
        intrinsics.read_intrinsics(path)


@pytest.mark.parametrize("fmt", ["kitti", "tum"])
def test_a_trajectory_beyond_1000_km_is_refused_naming_the_line(tmp_path: Path, fmt: str) -> None:
    # A KITTI or TUM translation of 1e308 m was read as a pose.
    row = ("1 0 0 {t} 0 1 0 0 0 0 1 0" if fmt == "kitti" else "{s} {t} 0 0 0 0 0 1")
    lines = [row.format(t=0.0, s=0.0), "# a comment", row.format(t=1e308, s=1.0)]
    path = tmp_path / "poses.txt"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(errors.FileFormatError, match=r"poses line 3: expected a translation within 1e\+06 m .*poses\.txt$"):
        poses.read_trajectory(path)


@pytest.mark.parametrize("scale", [5e-324, 1e-7, 2.0])
def test_a_depth_file_scale_outside_a_micrometre_to_a_metre_is_refused(tmp_path: Path, scale: float) -> None:
    path = tmp_path / "d.npy"
    np.save(path, np.ones((4, 4), np.uint16))
    with pytest.raises(errors.ConfigError, match=r"^scale: expected a finite number in \[1e-06, 1\]"):
        depth.read_depth(path, scale=scale)
    assert depth.read_depth(path, scale=1e-4).scale_m_per_unit == 1e-4


def test_transform_buffer_refuses_nan_and_unnormalised_quaternions_from_messages() -> None:
    buf = ros.TransformBuffer()
    with pytest.raises(errors.InputError, match=r"transform odom -> base_link: expected a unit rotation quaternion.*\(/tf at 1\)"):
        buf.add_message(_tf_msg((0.0, 0.0, 0.0, 2.0)), static=False, where="/tf at 1")
    with pytest.raises(errors.InputError, match=r"transform odom -> base_link: expected a unit rotation quaternion"):
        buf.add_message(_tf_msg((float("nan"), 0.0, 0.0, 1.0)), static=False)
    with pytest.raises(errors.InputError, match=r"transform odom -> base_link: not finite"):
        buf.add_message(_tf_msg((0.0, 0.0, 0.0, 1.0), (float("inf"), 0.0, 0.0)), static=False)
    with pytest.raises(errors.InputError, match=r"'odom' -> 'base_link', /tf\).*translation within"):
        buf.add_message(_tf_msg((0.0, 0.0, 0.0, 1.0), (3e7, 0.0, 0.0)), static=True, where="/tf")
    assert buf.frames == []
    # Slightly off unit quaternions, as recorded by real drivers, are normalised.
    assert buf.add_message(_tf_msg((0.0, 0.0, 0.0, 1.002)), static=True) == 1
    np.testing.assert_allclose(buf.lookup("odom", "base_link"), np.eye(4), atol=1e-12)
    assert json.dumps(buf.frames) == '["base_link", "odom"]'


@pytest.mark.parametrize("writer", ["pcd", "ply", "png", "mcap"])
def test_a_writer_given_a_fifo_or_a_folder_fails_at_once(tmp_path, writer) -> None:
    """A FIFO nobody reads once blocked the writers forever."""
    from subterra import io as sio

    def write(path):
        points = np.zeros((3, 3), np.float32)
        if writer == "pcd":
            sio.write_pcd(path, points)
        elif writer == "ply":
            sio.write_ply(path, points)
        elif writer == "png":
            sio.write_depth_png(path, np.zeros((4, 4), np.uint16))
        else:
            sio.McapWriter(path).close()

    fifo = tmp_path / f"out.{writer}"
    os.mkfifo(fifo)
    folder = tmp_path / f"dir.{writer}"
    folder.mkdir()
    for target in (fifo, folder):
        errors_seen: list[BaseException] = []
        t = threading.Thread(target=lambda: _collect(errors_seen, write, target), daemon=True)
        t.start()
        t.join(5)
        if t.is_alive():  # unblock the writer before failing
            with open(fifo, "rb"):
                pass
        assert not t.is_alive(), f"{writer} blocked on {target}"
        assert len(errors_seen) == 1 and isinstance(errors_seen[0], errors.FileFormatError), errors_seen
        assert "not a regular file" in str(errors_seen[0])


def _collect(sink: list, fn, *args) -> None:
    try:
        fn(*args)
    except BaseException as exc:  # noqa: BLE001 - the test inspects it
        sink.append(exc)


@pytest.mark.parametrize(
    "write",
    [
        lambda path: clouds.write_pcd(path / "a.pcd", np.broadcast_to(np.ones(3, np.float32), (10**9, 3))),
        lambda path: clouds.write_ply(path / "a.ply", np.broadcast_to(np.ones(3, np.float32), (10**9, 3))),
        lambda path: depth.write_depth_png(path / "a.png", np.broadcast_to(np.uint16(1), (10**5, 10**5))),
    ],
    ids=["pcd", "ply", "png"],
)
def test_a_writer_refuses_a_huge_view_before_copying_it(tmp_path: Path, write) -> None:
    # Once a MemoryError asking for 11 GiB (clouds) or 18.6 GiB (PNG): the view was made
    # contiguous before its size was looked at.
    with pytest.raises(errors.InputError, match="over the limit"):
        write(tmp_path)



def test_a_small_cloud_reads_under_an_address_space_limit(tmp_path: Path) -> None:
    # Every read reserved its 4 GiB limit first (`read(max_bytes + 1)`): under an
    # address-space cap a one-point PLY failed with a bare MemoryError.
    import subprocess
    import sys

    ply = tmp_path / "one.ply"
    ply.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n")
    code = (
        "import resource, sys\n"
        "resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))\n"
        "from subterra.io import clouds\n"
        "print(clouds.read_cloud(sys.argv[1]).points.shape)\n"
    )
    done = subprocess.run([sys.executable, "-c", code, str(ply)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "(1, 3)" in done.stdout
