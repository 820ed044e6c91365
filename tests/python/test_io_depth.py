"""Tests of subterra.io.depth and subterra.io.intrinsics.

These modules need only NumPy, Pillow and PyYAML. When the compiled core is not built
(``import subterra`` fails), they are loaded from the source tree through a bare
``subterra`` package module that is removed from ``sys.modules`` again afterwards, so
other test files still see the real import failure.

Real-data tests read ``<repo>/../shared/data`` and skip when it is absent.
"""

from __future__ import annotations

import importlib
import json
import math
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

REPO_ROOT = Path(__file__).resolve().parents[2]
PACKAGE_DIR = REPO_ROOT / "python" / "subterra"
DATA_DIR = (REPO_ROOT / ".." / "shared" / "data").resolve()


def _load_modules() -> tuple[types.ModuleType, types.ModuleType, types.ModuleType]:
    """``(errors, depth, intrinsics)``, from the installed package or the source tree."""
    names = ("subterra.errors", "subterra.io.depth", "subterra.io.intrinsics")
    try:
        import subterra  # noqa: F401  (the real package, with the compiled core)
    except ImportError:
        bare = types.ModuleType("subterra")
        bare.__path__ = [str(PACKAGE_DIR)]
        bare.__file__ = str(PACKAGE_DIR / "__init__.py")
        sys.modules["subterra"] = bare
        try:
            return tuple(importlib.import_module(name) for name in names)  # type: ignore[return-value]
        finally:
            # Leave no half package behind: a later `import subterra` fails as it should.
            if sys.modules.get("subterra") is bare:
                del sys.modules["subterra"]
    return tuple(importlib.import_module(name) for name in names)  # type: ignore[return-value]


errors, depth, intrinsics = _load_modules()

needs_data = pytest.mark.skipif(
    not DATA_DIR.is_dir(), reason=f"real sensor data folder {DATA_DIR} is absent"
)


def _data(*parts: str) -> Path:
    path = DATA_DIR.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data file {path} is absent")
    return path


def _pgm_bytes(
    width: int, height: int, maxval: int, values: list[int], header_extra: bytes = b""
) -> bytes:
    header = b"P5\n" + header_extra + f"{width} {height}\n{maxval}\n".encode()
    raster = b"".join(v.to_bytes(2, "big") for v in values)
    return header + raster


# ------------------------------------------------------------------------ depth: PNG


def test_png_round_trip_keeps_every_value(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    data = rng.integers(0, 65536, size=(37, 53), dtype=np.uint16)
    data[0, 0], data[0, 1], data[0, 2] = 0, 65535, 256  # extremes and a byte-order probe
    path = tmp_path / "frame.png"
    depth.write_depth_png(path, data)

    image = depth.read_depth(path)

    assert image.data.dtype == np.uint16
    assert image.data.shape == (37, 53)
    assert image.data.flags.c_contiguous and image.data.flags.writeable
    np.testing.assert_array_equal(image.data, data)
    assert image.scale_m_per_unit == 0.001
    assert image.path == str(path)
    assert (image.height, image.width) == (37, 53)


def test_png_scale_and_metres(tmp_path: Path) -> None:
    path = tmp_path / "tum.png"
    depth.write_depth_png(path, np.array([[0, 5000], [10000, 2500]], dtype=np.uint16))

    image = depth.read_depth(str(path), scale=1 / 5000)

    assert image.scale_m_per_unit == pytest.approx(0.0002)
    metres = image.to_metres()
    assert metres.dtype == np.float32
    np.testing.assert_allclose(metres, [[0.0, 1.0], [2.0, 0.5]], rtol=1e-6)


def test_big_endian_array_is_written_with_the_right_values(tmp_path: Path) -> None:
    data = np.array([[1, 256], [4660, 65280]], dtype=">u2")
    path = tmp_path / "be.png"
    depth.write_depth_png(path, data)
    np.testing.assert_array_equal(depth.read_depth(path).data, [[1, 256], [4660, 65280]])


@pytest.mark.parametrize(
    ("mode", "array"),
    [
        ("L", np.full((4, 5), 200, dtype=np.uint8)),
        ("RGB", np.full((4, 5, 3), 200, dtype=np.uint8)),
    ],
)
def test_8bit_and_colour_png_are_rejected(tmp_path: Path, mode: str, array: np.ndarray) -> None:
    path = tmp_path / f"{mode}.png"
    Image.fromarray(array).save(path)
    with pytest.raises(errors.FileFormatError, match=f"mode '{mode}'") as info:
        depth.read_depth(path)
    assert str(info.value).endswith(str(path))


def test_truncated_png_raises_file_format_error_with_path(tmp_path: Path) -> None:
    full = tmp_path / "full.png"
    depth.write_depth_png(
        full, np.random.default_rng(1).integers(0, 9000, (120, 160), dtype=np.uint16)
    )
    raw = full.read_bytes()
    for cut in (len(raw) // 2, 20, 5):
        path = tmp_path / f"cut{cut}.png"
        path.write_bytes(raw[:cut])
        with pytest.raises(errors.FileFormatError) as info:
            depth.read_depth(path)
        assert str(info.value).endswith(str(path)), str(info.value)
        assert isinstance(info.value.__cause__, Exception) or "signature" in str(info.value)


def test_corrupt_png_data_raises_file_format_error(tmp_path: Path) -> None:
    full = tmp_path / "full.png"
    depth.write_depth_png(
        full, np.random.default_rng(2).integers(0, 9000, (64, 64), dtype=np.uint16)
    )
    raw = bytearray(full.read_bytes())
    idat = raw.index(b"IDAT")
    raw[idat + 10 : idat + 60] = bytes(50)  # zero out compressed pixels and break the CRC
    path = tmp_path / "corrupt.png"
    path.write_bytes(bytes(raw))
    with pytest.raises(errors.FileFormatError, match=r"corrupt or truncated") as info:
        depth.read_depth(path)
    assert str(info.value).endswith(str(path))


def test_text_file_named_png_is_rejected(tmp_path: Path) -> None:
    path = tmp_path / "fake.png"
    path.write_text("not an image at all")
    with pytest.raises(errors.FileFormatError, match=r"PNG signature") as info:
        depth.read_depth(path)
    assert str(info.value).endswith(str(path))


def test_mode_i_values_outside_uint16_are_rejected() -> None:
    ok = depth._png_array_to_uint16(np.array([[0, 65535]], dtype=np.int32), "I", "x.png")
    assert ok.dtype == np.uint16 and ok.tolist() == [[0, 65535]]
    with pytest.raises(errors.FileFormatError, match=r"0..65535"):
        depth._png_array_to_uint16(np.array([[0, 70000]], dtype=np.int32), "I", "x.png")


# ------------------------------------------------------------------------ depth: PGM


def test_handmade_16bit_pgm_reads_exact_big_endian_values(tmp_path: Path) -> None:
    values = [0, 1, 256, 1000, 65535, 4660]  # 256 and 1 tell the byte orders apart
    path = tmp_path / "hand.pgm"
    path.write_bytes(_pgm_bytes(3, 2, 65535, values, header_extra=b"# written by a test\n"))

    image = depth.read_depth(path)

    assert image.data.dtype == np.uint16
    assert image.data.tolist() == [[0, 1, 256], [1000, 65535, 4660]]
    assert image.scale_m_per_unit == 0.001
    assert image.data.flags.c_contiguous and image.data.flags.writeable


def test_pgm_with_small_maxval_keeps_raw_values(tmp_path: Path) -> None:
    path = tmp_path / "m.pgm"
    path.write_bytes(_pgm_bytes(2, 1, 4095, [4095, 300]))
    assert depth.read_depth(path).data.tolist() == [[4095, 300]]


def test_pgm_comment_after_maxval_is_the_separator(tmp_path: Path) -> None:
    path = tmp_path / "c.pgm"
    path.write_bytes(b"P5 2 1 65535# note\n" + (513).to_bytes(2, "big") + (2).to_bytes(2, "big"))
    assert depth.read_depth(path).data.tolist() == [[513, 2]]


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (_pgm_bytes(4, 3, 65535, list(range(12)))[:-5], "truncated"),
        (b"P5\n640 48", "truncated header"),
        (b"P5\n4 3\n255\n" + bytes(12), "maxval 255"),
        (b"P2\n2 1\n65535\n1 2\n", "P2"),
        (b"P6\n2 1\n65535\n" + bytes(12), "PPM"),
        (b"P5\n0 3\n65535\n", "width and height > 0"),
        (b"P5\n2 1\n70000\n" + bytes(4), "maxval in 1..65535"),
        (b"P5\nab 1\n65535\n" + bytes(4), "decimal width"),
        (_pgm_bytes(2, 1, 1000, [1000, 2000]), "<= maxval 1000"),
        (b"GIF89a", "magic"),
    ],
)
def test_bad_pgm_raises_file_format_error_with_path(
    tmp_path: Path, content: bytes, match: str
) -> None:
    path = tmp_path / "bad.pgm"
    path.write_bytes(content)
    with pytest.raises(errors.FileFormatError, match=match) as info:
        depth.read_depth(path)
    assert str(info.value).endswith(str(path))


# ------------------------------------------------------------------------ depth: npy / npz


def test_npy_uint16_and_float32(tmp_path: Path) -> None:
    raw = np.array([[0, 1200], [65535, 7]], dtype=np.uint16)
    np.save(tmp_path / "u.npy", raw)
    metres = np.array([[0.0, 1.25], [np.nan, np.inf]], dtype=np.float32)
    np.save(tmp_path / "f.npy", metres)

    u = depth.read_depth(tmp_path / "u.npy", scale=0.00025)
    f = depth.read_depth(tmp_path / "f.npy")

    assert u.data.dtype == np.uint16 and u.scale_m_per_unit == 0.00025
    np.testing.assert_array_equal(u.data, raw)
    assert f.data.dtype == np.float32 and f.scale_m_per_unit == 1.0
    np.testing.assert_array_equal(f.data, metres)  # NaN and inf kept ("no return")
    assert u.data.flags.writeable and f.data.flags.writeable


def test_npy_float64_big_endian_and_fortran_order_are_normalised(tmp_path: Path) -> None:
    np.save(tmp_path / "d.npy", np.array([[0.5, 2.0]], dtype=np.float64))
    np.save(tmp_path / "be.npy", np.array([[1, 256]], dtype=">u2"))
    np.save(tmp_path / "fo.npy", np.asfortranarray(np.arange(6, dtype=np.uint16).reshape(2, 3)))

    d = depth.read_depth(tmp_path / "d.npy", scale=1.0)
    be = depth.read_depth(tmp_path / "be.npy")
    fo = depth.read_depth(tmp_path / "fo.npy")

    assert d.data.dtype == np.float32 and d.data.tolist() == [[0.5, 2.0]]
    assert be.data.dtype == np.dtype(np.uint16) and be.data.dtype.isnative
    assert be.data.tolist() == [[1, 256]]
    assert fo.data.flags.c_contiguous and fo.data.tolist() == [[0, 1, 2], [3, 4, 5]]


def test_npz_depth_key_or_only_array(tmp_path: Path) -> None:
    frame = np.array([[10, 20], [30, 40]], dtype=np.uint16)
    np.savez(tmp_path / "named.npz", rgb=np.zeros((2, 2, 3), np.uint8), depth=frame)
    np.savez_compressed(tmp_path / "only.npz", frame=frame.astype(np.float32) / 1000)

    named = depth.read_depth(tmp_path / "named.npz")
    only = depth.read_depth(tmp_path / "only.npz")

    assert named.data.dtype == np.uint16 and named.data.tolist() == frame.tolist()
    assert only.data.dtype == np.float32 and only.scale_m_per_unit == 1.0
    np.testing.assert_allclose(only.data, frame / 1000, rtol=1e-6)


def test_npz_without_depth_key_and_several_arrays_is_rejected(tmp_path: Path) -> None:
    path = tmp_path / "two.npz"
    np.savez(path, a=np.zeros((2, 2), np.uint16), b=np.zeros((2, 2), np.uint16))
    with pytest.raises(errors.FileFormatError, match=r"'depth'") as info:
        depth.read_depth(path)
    assert str(info.value).endswith(str(path))


@pytest.mark.parametrize(
    ("array", "match"),
    [
        (np.zeros((2, 3, 4), np.uint16), r"2-D .*\(2, 3, 4\)"),
        (np.zeros(5, np.float32), r"2-D .*\(5,\)"),
        (np.zeros((0, 4), np.uint16), "non-empty"),
        (np.zeros((2, 2), np.int32), "int32"),
        (np.zeros((2, 2), np.uint8), "uint8"),
    ],
)
@pytest.mark.parametrize("suffix", [".npy", ".npz"])
def test_wrong_array_shape_or_dtype_is_rejected(tmp_path: Path, array, match, suffix) -> None:
    path = tmp_path / f"bad{suffix}"
    if suffix == ".npy":
        np.save(path, array)
    else:
        np.savez(path, depth=array)
    with pytest.raises(errors.FileFormatError, match=match) as info:
        depth.read_depth(path)
    assert isinstance(info.value, errors.InputError)
    assert str(info.value).endswith(str(path))


def test_truncated_npy_and_npz_raise_file_format_error(tmp_path: Path) -> None:
    for suffix, save in ((".npy", np.save), (".npz", np.savez)):
        full = tmp_path / f"full{suffix}"
        save(
            full, np.arange(10000, dtype=np.uint16).reshape(100, 100)
        ) if suffix == ".npy" else save(
            full, depth=np.arange(10000, dtype=np.uint16).reshape(100, 100)
        )
        raw = full.read_bytes()
        path = tmp_path / f"cut{suffix}"
        path.write_bytes(raw[: len(raw) // 2])
        with pytest.raises(errors.FileFormatError) as info:
            depth.read_depth(path)
        assert str(info.value).endswith(str(path)), str(info.value)
        assert info.value.__cause__ is not None  # the library error is chained


# ------------------------------------------------------------------------ depth: paths and scale


@pytest.mark.parametrize("suffix", [".png", ".pgm", ".npy", ".npz"])
def test_empty_file_is_rejected(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"empty{suffix}"
    path.write_bytes(b"")
    with pytest.raises(errors.FileFormatError, match=r"empty") as info:
        depth.read_depth(path)
    assert str(info.value).endswith(str(path))


@pytest.mark.parametrize("name", ["frame.jpg", "frame.txt", "frame"])
def test_unknown_extension_is_rejected(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    path.write_bytes(b"data")
    with pytest.raises(errors.FileFormatError, match=r"\.png, \.pgm, \.npy, \.npz") as info:
        depth.read_depth(path)
    assert str(info.value).endswith(str(path))


def test_missing_file_and_folder_are_rejected(tmp_path: Path) -> None:
    with pytest.raises(errors.FileFormatError, match=r"missing") as info:
        depth.read_depth(tmp_path / "nope.png")
    assert str(info.value).endswith(str(tmp_path / "nope.png"))
    folder = tmp_path / "dir.png"
    folder.mkdir()
    with pytest.raises(errors.FileFormatError, match=r"folder"):
        depth.read_depth(folder)


def test_uppercase_extension_is_accepted(tmp_path: Path) -> None:
    path = tmp_path / "FRAME.PNG"
    depth.write_depth_png(path, np.ones((2, 2), np.uint16))
    assert depth.read_depth(path).data.sum() == 4


@pytest.mark.parametrize("scale", [0, -0.001, math.nan, math.inf, "0.001", True, [0.001]])
def test_bad_scale_raises_config_error_naming_scale(tmp_path: Path, scale) -> None:
    path = tmp_path / "ok.png"
    depth.write_depth_png(path, np.ones((2, 2), np.uint16))
    with pytest.raises(errors.ConfigError, match=r"^scale: expected a finite number in \[1e-06, 1\]"):
        depth.read_depth(path, scale=scale)


def test_scale_for_float_metres_is_an_input_error(tmp_path: Path) -> None:
    path = tmp_path / "m.npy"
    np.save(path, np.ones((2, 2), np.float32))
    assert depth.read_depth(path, scale=1.0).scale_m_per_unit == 1.0
    with pytest.raises(errors.InputError, match=r"scale: expected None or 1.0") as info:
        depth.read_depth(path, scale=0.001)
    assert str(info.value).endswith(str(path))


def test_path_of_wrong_type_is_an_input_error() -> None:
    with pytest.raises(errors.InputError, match=r"^path: expected a str or os.PathLike, got int"):
        depth.read_depth(42)  # type: ignore[arg-type]


def test_depth_image_validates_direct_construction() -> None:
    with pytest.raises(errors.InputError, match=r"data: expected a 2-D"):
        depth.DepthImage(np.zeros((2, 2, 2), np.uint16), 0.001, "x")
    with pytest.raises(errors.InputError, match=r"data: expected dtype"):
        depth.DepthImage(np.zeros((2, 2), np.int64), 0.001, "x")
    with pytest.raises(errors.ConfigError, match=r"scale_m_per_unit"):
        depth.DepthImage(np.zeros((2, 2), np.uint16), -1.0, "x")
    with pytest.raises(errors.InputError, match=r"scale_m_per_unit: expected 1.0"):
        depth.DepthImage(np.zeros((2, 2), np.float32), 0.001, "x")
    image = depth.DepthImage(np.zeros((3, 2), np.uint16).T, 0.001, "x")  # F-order input
    assert image.data.flags.c_contiguous
    with pytest.raises(AttributeError):
        image.scale_m_per_unit = 2.0  # type: ignore[misc]


def test_write_depth_png_rejects_non_uint16_data(tmp_path: Path) -> None:
    path = tmp_path / "out.png"
    with pytest.raises(errors.InputError, match=r"data: expected dtype uint16 .*got float32"):
        depth.write_depth_png(path, np.zeros((2, 2), np.float32))
    with pytest.raises(errors.InputError, match=r"data: expected a 2-D .*\(2, 2, 3\)"):
        depth.write_depth_png(path, np.zeros((2, 2, 3), np.uint16))
    with pytest.raises(errors.InputError, match=r"data: expected a numpy.ndarray"):
        depth.write_depth_png(path, [[1, 2]])  # type: ignore[arg-type]
    assert not path.exists()


# ------------------------------------------------------------------------ list_depth_files


def test_list_depth_files_sorts_naturally_and_filters(tmp_path: Path) -> None:
    for name in [
        "10.pgm",
        "2.pgm",
        "1.pgm",
        "img_10.png",
        "img_9.png",
        "B.npy",
        "a.NPZ",
        "notes.txt",
        "._2.pgm",
        ".hidden.png",
    ]:
        (tmp_path / name).write_bytes(b"x")
    (tmp_path / "sub.png").mkdir()

    names = [p.name for p in depth.list_depth_files(tmp_path)]

    assert names == ["1.pgm", "2.pgm", "10.pgm", "a.NPZ", "B.npy", "img_9.png", "img_10.png"]
    assert all(isinstance(p, Path) for p in depth.list_depth_files(str(tmp_path)))


def test_list_depth_files_keeps_zero_padded_order(tmp_path: Path) -> None:
    names = [f"{i:06d}.png" for i in (12, 3, 0, 100, 1)]
    for name in names:
        (tmp_path / name).write_bytes(b"x")
    assert [p.name for p in depth.list_depth_files(tmp_path)] == sorted(names)


def test_list_depth_files_errors(tmp_path: Path) -> None:
    with pytest.raises(errors.InputError, match=r"directory: expected an existing folder") as info:
        depth.list_depth_files(tmp_path / "missing")
    assert str(info.value).endswith(str(tmp_path / "missing"))
    (tmp_path / "readme.txt").write_text("no depth here")
    with pytest.raises(errors.InputError, match=r"got none") as info:
        depth.list_depth_files(tmp_path)
    assert str(info.value).endswith(str(tmp_path))
    with pytest.raises(errors.InputError, match=r"expected a folder, got a file"):
        depth.list_depth_files(tmp_path / "readme.txt")


# ------------------------------------------------------------------------ intrinsics


def test_plain_json_intrinsics(tmp_path: Path) -> None:
    path = tmp_path / "cam.json"
    path.write_text(
        json.dumps(
            {
                "fx": 600.5,
                "fy": 601.25,
                "cx": 320.0,
                "cy": 240.5,
                "width": 640,
                "height": 480,
                "depth_scale": 0.001,
            }
        )
    )
    cam = intrinsics.read_intrinsics(path)
    assert cam == intrinsics.Intrinsics(600.5, 601.25, 320.0, 240.5, 640, 480)
    assert isinstance(cam.width, int) and isinstance(cam.fx, float)


def test_open3d_json_is_column_major(tmp_path: Path) -> None:
    path = tmp_path / "o3d.json"
    matrix = [500.0, 0, 0, 0, 510.0, 0, 330.5, 250.25, 1]
    path.write_text(json.dumps({"width": 848, "height": 480, "intrinsic_matrix": matrix}))
    cam = intrinsics.read_intrinsics(path)
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (
        500.0,
        510.0,
        330.5,
        250.25,
        848,
        480,
    )


def test_open3d_matrix_written_row_major_is_rejected(tmp_path: Path) -> None:
    path = tmp_path / "o3d.json"
    matrix = [500.0, 0, 330.5, 0, 510.0, 250.25, 0, 0, 1]  # row-major by mistake
    path.write_text(json.dumps({"width": 640, "height": 480, "intrinsic_matrix": matrix}))
    with pytest.raises(errors.FileFormatError, match=r"intrinsic_matrix.*pinhole") as info:
        intrinsics.read_intrinsics(path)
    assert str(info.value).endswith(str(path))


ROS_CALIBRATION_YAML = """\
image_width: 640
image_height: 480
camera_name: depth_camera
camera_matrix:
  rows: 3
  cols: 3
  data: [525.5, 0, 319.75, 0, 526.125, 239.5, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.01, -0.02, 0, 0, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [525.5, 0, 319.75, 0, 0, 526.125, 239.5, 0, 0, 0, 1, 0]
"""

CAMERA_INFO_ROS1_YAML = """\
header:
  seq: 12
  stamp: {secs: 1, nsecs: 0}
  frame_id: camera_depth_optical_frame
height: 480
width: 640
distortion_model: plumb_bob
D: [0.0, 0.0, 0.0, 0.0, 0.0]
K: [385.25, 0.0, 319.5, 0.0, 385.75, 239.25, 0.0, 0.0, 1.0]
R: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
P: [385.25, 0.0, 319.5, 0.0, 0.0, 385.75, 239.25, 0.0, 0.0, 0.0, 1.0, 0.0]
binning_x: 0
binning_y: 0
---
"""


def test_ros_calibration_yaml(tmp_path: Path) -> None:
    path = tmp_path / "depth_camera.yaml"
    path.write_text(ROS_CALIBRATION_YAML)
    assert intrinsics.read_intrinsics(path) == intrinsics.Intrinsics(
        525.5, 526.125, 319.75, 239.5, 640, 480
    )


def test_camera_info_dumps_ros1_yaml_and_ros2_json(tmp_path: Path) -> None:
    ros1 = tmp_path / "info.yml"
    ros1.write_text(CAMERA_INFO_ROS1_YAML)  # rostopic echo output, trailing '---'
    ros2 = tmp_path / "info.json"
    ros2.write_text(
        json.dumps(
            {"height": 720, "width": 1280, "k": [910.0, 0, 640.5, 0, 911.5, 360.25, 0, 0, 1]}
        )
    )
    assert intrinsics.read_intrinsics(ros1) == intrinsics.Intrinsics(
        385.25, 385.75, 319.5, 239.25, 640, 480
    )
    assert intrinsics.read_intrinsics(ros2) == intrinsics.Intrinsics(
        910.0, 911.5, 640.5, 360.25, 1280, 720
    )


@pytest.mark.parametrize(
    ("document", "field"),
    [
        ({"fx": 1.0, "fy": 1.0, "cx": 1.0, "width": 4, "height": 4}, "cy"),
        ({"height": 4, "intrinsic_matrix": [1, 0, 0, 0, 1, 0, 1, 1, 1]}, "width"),
        (
            {
                "image_width": 4,
                "camera_matrix": {"rows": 3, "cols": 3, "data": [1, 0, 1, 0, 1, 1, 0, 0, 1]},
            },
            "image_height",
        ),
        ({"image_width": 4, "image_height": 4, "camera_matrix": {"rows": 3}}, "camera_matrix.data"),
        ({"width": 4, "K": [1, 0, 1, 0, 1, 1, 0, 0, 1]}, "height"),
    ],
)
def test_missing_field_is_named_with_the_path(tmp_path: Path, document: dict, field: str) -> None:
    path = tmp_path / "cam.json"
    path.write_text(json.dumps(document))
    with pytest.raises(errors.FileFormatError, match=f"^{field}: missing field") as info:
        intrinsics.read_intrinsics(path)
    assert str(info.value).endswith(str(path))


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (
            '{"fx": 0, "fy": 1, "cx": 1, "cy": 1, "width": 4, "height": 4}',
            "fx: expected a finite focal length > 0",
        ),
        (
            '{"fx": 1, "fy": 1, "cx": 1, "cy": 1, "width": 4.5, "height": 4}',
            "width: expected an integer",
        ),
        (
            '{"fx": "500", "fy": 1, "cx": 1, "cy": 1, "width": 4, "height": 4}',
            "fx: expected a number, got str",
        ),
        (
            '{"fx": 1, "fy": 1, "cx": NaN, "cy": 1, "width": 4, "height": 4}',
            "cx: expected a finite number",
        ),
        (
            '{"fx": 1, "fy": 1, "cx": 1, "cy": 1, "width": 0, "height": 4}',
            "width: expected an int > 0",
        ),
        (
            '{"width": 4, "height": 4, "K": [1, 0, 1, 0, 1, 1]}',
            "K: expected a flat list of 9 numbers, got 6",
        ),
        ('{"width": 4, "height": 4, "K": [1, 0.5, 1, 0, 1, 1, 0, 0, 1]}', "K: expected zero skew"),
        ('{"focal": 500}', r"got keys \['focal'\]"),
        ("[1, 2, 3]", "expected a mapping"),
        ('{"fx": 1,', "expected valid JSON"),
    ],
)
def test_invalid_intrinsics_file_raises_file_format_error(
    tmp_path: Path, text: str, match: str
) -> None:
    path = tmp_path / "cam.json"
    path.write_text(text)
    with pytest.raises(errors.FileFormatError, match=match) as info:
        intrinsics.read_intrinsics(path)
    assert str(info.value).endswith(str(path))


def test_bad_yaml_extension_and_missing_file(tmp_path: Path) -> None:
    bad = tmp_path / "cam.yaml"
    bad.write_text("camera_matrix: [1, 2\n  rows: 3\n")
    with pytest.raises(errors.FileFormatError, match=r"expected valid YAML.*line") as info:
        intrinsics.read_intrinsics(bad)
    assert str(info.value).endswith(str(bad))
    opencv = tmp_path / "opencv.yml"
    opencv.write_text("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n  rows: 3\n")
    with pytest.raises(errors.FileFormatError, match=r"OpenCV FileStorage"):
        intrinsics.read_intrinsics(opencv)
    txt = tmp_path / "cam.txt"
    txt.write_text("fx: 1")
    with pytest.raises(errors.FileFormatError, match=r"\.json, \.yaml, \.yml"):
        intrinsics.read_intrinsics(txt)
    with pytest.raises(errors.FileFormatError, match=r"missing path") as info:
        intrinsics.read_intrinsics(tmp_path / "none.json")
    assert str(info.value).endswith(str(tmp_path / "none.json"))
    empty = tmp_path / "empty.yaml"
    empty.write_text("")
    with pytest.raises(errors.FileFormatError, match=r"empty document"):
        intrinsics.read_intrinsics(empty)


def test_intrinsics_from_dict_and_direct_validation() -> None:
    cam = intrinsics.intrinsics_from_dict(
        {"width": 640.0, "height": 480, "K": [500, 0, 320, 0, 500, 240, 0, 0, 1]},
        source="topic /cam",
    )
    assert cam == intrinsics.Intrinsics(500.0, 500.0, 320.0, 240.0, 640, 480)
    with pytest.raises(errors.InputError, match=r"height: missing field.*: topic /cam$"):
        intrinsics.intrinsics_from_dict(
            {"width": 1, "k": [1, 0, 0, 0, 1, 0, 0, 0, 1]}, source="topic /cam"
        )
    with pytest.raises(errors.ConfigError, match=r"fy: .*<dict>$"):
        intrinsics.intrinsics_from_dict(
            {"fx": 1, "fy": -1, "cx": 0, "cy": 0, "width": 2, "height": 2}
        )
    with pytest.raises(errors.ConfigError, match=r"fx: expected a finite focal length > 0"):
        intrinsics.Intrinsics(-1.0, 1.0, 0.0, 0.0, 4, 4)
    with pytest.raises(errors.ConfigError, match=r"height: expected an int > 0 \[px\], got float"):
        intrinsics.Intrinsics(1.0, 1.0, 0.0, 0.0, 4, 4.0)  # type: ignore[arg-type]
    with pytest.raises(errors.ConfigError, match=r"cy: expected a finite number"):
        intrinsics.Intrinsics(1.0, 1.0, 0.0, math.inf, 4, 4)


def test_known_cameras_presets() -> None:
    known = intrinsics.KNOWN_CAMERAS
    assert set(known) == {"d435-room", "kinect-dining", "tum-desk", "d435"}
    assert known["d435-room"] == intrinsics.Intrinsics(
        617.25, 617.5486450195312, 317.3921203613281, 245.98019409179688, 640, 480
    )
    assert known["kinect-dining"] == intrinsics.Intrinsics(518.0, 519.0, 325.5, 253.5, 640, 480)
    assert known["tum-desk"] == intrinsics.Intrinsics(520.9, 521.0, 325.1, 249.7, 640, 480)
    assert known["d435"] == intrinsics.Intrinsics(385.0, 385.0, 319.5, 239.5, 640, 480)


def test_to_camera_passes_every_field_by_name(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []

    class FakePinholeCamera:
        def __init__(self, **kwargs):
            calls.append(kwargs)

    fake = types.ModuleType("subterra")
    fake.PinholeCamera = FakePinholeCamera  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "subterra", fake)

    camera = intrinsics.KNOWN_CAMERAS["tum-desk"].to_camera()

    assert isinstance(camera, FakePinholeCamera)
    assert calls == [dict(fx=520.9, fy=521.0, cx=325.1, cy=249.7, width=640, height=480)]


def test_io_package_reexports() -> None:
    io = sys.modules.get("subterra.io")
    if io is None:
        pytest.skip("subterra.io was not imported as a package")
    for name in io.__all__:
        assert hasattr(io, name), name
    assert io.read_depth is depth.read_depth and io.Intrinsics is intrinsics.Intrinsics


# ------------------------------------------------------------------------ real data


@needs_data
def test_realsense_depth_pngs_and_open3d_intrinsics() -> None:
    files = depth.list_depth_files(_data("realsense-d435-room", "depth"))
    assert [p.name for p in files] == [f"{i:06d}.png" for i in range(10)]
    for path in files:
        image = depth.read_depth(path)
        assert image.data.dtype == np.uint16 and image.data.shape == (480, 640)
        assert image.scale_m_per_unit == 0.001
        assert 0 < np.count_nonzero(image.data) < image.data.size  # real holes, real returns

    cam = intrinsics.read_intrinsics(_data("realsense-d435-room", "cam_params_realsense.json"))
    assert cam.fx == 617.25
    assert cam.fy == pytest.approx(617.5486450195312, abs=0)
    assert cam.cx == pytest.approx(317.392, abs=1e-3) and cam.cx == 317.3921203613281
    assert cam.cy == 245.98019409179688
    assert (cam.width, cam.height) == (640, 480)
    assert cam == intrinsics.KNOWN_CAMERAS["d435-room"]


@needs_data
def test_kinect_pgms_are_plausible_millimetres() -> None:
    files = depth.list_depth_files(_data("kinect-dining", "depth"))
    assert [p.name for p in files] == ["1.pgm", "2.pgm", "3.pgm", "4.pgm", "5.pgm"]
    for path in files:
        image = depth.read_depth(path)
        assert image.data.dtype == np.uint16 and image.data.shape == (480, 640)
        valid = image.data[image.data > 0]
        assert valid.size > image.data.size // 2
        assert 500 <= float(np.median(valid)) <= 10000
        # Our P5 decoder agrees with Pillow's independent one.
        with Image.open(path) as reference:
            np.testing.assert_array_equal(image.data, np.asarray(reference).astype(np.uint16))


@needs_data
def test_tum_png_with_scale_one_five_thousandth() -> None:
    image = depth.read_depth(_data("tum-desk", "1_depth.png"), scale=1 / 5000)
    assert image.data.dtype == np.uint16 and image.data.shape == (480, 640)
    metres = image.to_metres()
    valid = metres[image.data > 0]
    assert 0.5 <= float(np.median(valid)) <= 5.0
    rows, cols = np.nonzero(image.data)
    r, c = rows[len(rows) // 2], cols[len(cols) // 2]
    assert metres[r, c] == pytest.approx(int(image.data[r, c]) / 5000, rel=1e-6)
    assert int(image.data[r, c]) * image.scale_m_per_unit == pytest.approx(
        int(image.data[r, c]) / 5000
    )


@needs_data
def test_tum_colour_png_is_not_a_depth_image() -> None:
    path = _data("tum-desk", "1.png")
    with pytest.raises(errors.FileFormatError, match=r"mode 'RGB'") as info:
        depth.read_depth(path)
    assert str(info.value).endswith(str(path))
