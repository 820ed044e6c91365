"""Tests of subterra.io.clouds (PCD, PLY, KITTI .bin, .npy) and subterra.io.poses.

These modules need only NumPy. When the compiled core is not built (``import subterra``
fails), they are loaded from the source tree through a bare ``subterra`` package module
that is removed from ``sys.modules`` again afterwards, so other test files still see the
real import failure.

Real-data tests read ``<repo>/../shared/data`` through the ``shared_data`` fixture and
skip when it is absent.
"""

from __future__ import annotations

import importlib
import sys
import types
from pathlib import Path

import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
PACKAGE_DIR = REPO_ROOT / "python" / "subterra"


def _load_modules() -> tuple[types.ModuleType, types.ModuleType, types.ModuleType]:
    """``(errors, clouds, poses)``, from the installed package or the source tree."""
    names = ("subterra.errors", "subterra.io.clouds", "subterra.io.poses")
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
            if sys.modules.get("subterra") is bare:
                del sys.modules["subterra"]
    return tuple(importlib.import_module(name) for name in names)  # type: ignore[return-value]


errors, clouds, poses = _load_modules()
FileFormatError = errors.FileFormatError
InputError = errors.InputError


# --------------------------------------------------------------------------- helpers


def _cloud(n: int = 300, seed: int = 0) -> np.ndarray:
    """(n, 3) float32 points over many magnitudes, with two NaN rows and an inf."""
    rng = np.random.default_rng(seed)
    points = (rng.standard_normal((n, 3)) * 10.0 ** rng.integers(-3, 3, (n, 1))).astype(np.float32)
    points[3] = np.nan
    points[7, 1] = np.nan
    points[11, 2] = np.inf
    return points


def _fields(n: int, seed: int = 1, *, ply: bool = False) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    fields = {
        "intensity": rng.random(n, dtype=np.float32) * 1000,
        "ring": rng.integers(0, 128, n, dtype=np.uint16),
        "t": np.cumsum(rng.random(n)) * 1e-5 + 1.7e9,  # float64 times need all 53 bits
        "label": rng.integers(-128, 128, n, dtype=np.int8),
        "range_mm": rng.integers(0, 2**32, n, dtype=np.uint32),
        "normal": rng.standard_normal((n, 3)).astype(np.float32),
    }
    if not ply:
        fields["id"] = rng.integers(-(2**62), 2**62, n, dtype=np.int64)
        fields["big"] = np.full(n, 2**64 - 1, dtype=np.uint64)
    return fields


def _expected_fields(fields: dict[str, np.ndarray], *, ply: bool) -> dict[str, np.ndarray]:
    """What reading back gives: PLY splits an (N, k) field into name_0 .. name_<k-1>."""
    if not ply:
        return fields
    out = {}
    for name, array in fields.items():
        if array.ndim == 1:
            out[name] = array
        else:
            out.update({f"{name}_{i}": array[:, i] for i in range(array.shape[1])})
    return out


def _raises_format_error(path: Path, match: str) -> FileFormatError:
    with pytest.raises(FileFormatError, match=match) as info:
        clouds.read_cloud(path)
    assert str(info.value).endswith(str(path)), str(info.value)
    return info.value


def _lzf_compress(data: bytes) -> bytes:
    """A small greedy LZF (liblzf format) compressor; overlapping matches included."""
    out = bytearray()
    literals = bytearray()
    last_seen: dict[bytes, int] = {}

    def flush() -> None:
        for k in range(0, len(literals), 32):
            chunk = literals[k : k + 32]
            out.append(len(chunk) - 1)
            out.extend(chunk)
        literals.clear()

    i, n = 0, len(data)
    while i < n:
        key = data[i : i + 3]
        ref = last_seen.get(key) if len(key) == 3 else None
        if len(key) == 3:
            last_seen[key] = i
        if ref is not None and i - ref <= 8192:
            length = 3
            while i + length < n and length < 264 and data[ref + length] == data[i + length]:
                length += 1
            flush()
            distance, code = i - ref - 1, length - 2
            if code < 7:
                out.append((code << 5) | (distance >> 8))
            else:
                out.extend([(7 << 5) | (distance >> 8), code - 7])
            out.append(distance & 0xFF)
            i += length
        else:
            literals.append(data[i])
            i += 1
    flush()
    return bytes(out)


def _lzf_decompress_reference(data: bytes) -> bytes:
    """liblzf's lzf_decompress, byte by byte (for small test data only)."""
    out = bytearray()
    i = 0
    while i < len(data):
        ctrl = data[i]
        i += 1
        if ctrl < 32:
            out += data[i : i + ctrl + 1]
            i += ctrl + 1
        else:
            length = ctrl >> 5
            if length == 7:
                length += data[i]
                i += 1
            ref = len(out) - ((ctrl & 0x1F) << 8) - 1 - data[i]
            i += 1
            for _ in range(length + 2):
                out.append(out[ref])
                ref += 1
    return bytes(out)


def _compressed_pcd(binary_pcd: bytes, padding: bytes = b"") -> bytes:
    """Turn a ``DATA binary`` PCD written by write_pcd into ``DATA binary_compressed``."""
    head, _, body = binary_pcd.partition(b"DATA binary\n")
    text = head.decode()
    lines = {line.split()[0]: line.split()[1:] for line in text.splitlines() if line[:1].isalpha()}
    n = int(lines["POINTS"][0])
    sizes = [int(s) * int(c) for s, c in zip(lines["SIZE"], lines["COUNT"], strict=True)]
    records = np.frombuffer(body, np.uint8).reshape(n, sum(sizes))
    planes = np.split(records, np.cumsum(sizes)[:-1], axis=1)  # struct of arrays
    plain = b"".join(plane.tobytes() for plane in planes)
    packed = _lzf_compress(plain)
    sizes_bytes = np.array([len(packed), len(plain)], "<u4").tobytes()
    return head + b"DATA binary_compressed\n" + sizes_bytes + packed + padding


# ------------------------------------------------------------------------ round trips


@pytest.mark.parametrize("binary", [True, False], ids=["binary", "ascii"])
@pytest.mark.parametrize("kind", ["pcd", "ply"])
def test_round_trip_keeps_points_nan_and_every_field(
    tmp_path: Path, kind: str, binary: bool
) -> None:
    points = _cloud()
    fields = _fields(len(points), ply=kind == "ply")
    path = tmp_path / f"cloud.{kind}"
    writer = clouds.write_pcd if kind == "pcd" else clouds.write_ply
    writer(path, points, fields, binary)

    cloud = clouds.read_cloud(path)

    assert cloud.format == kind and cloud.path == str(path) and cloud.organised_shape is None
    assert cloud.points.dtype == np.float32 and cloud.points.shape == points.shape
    assert cloud.points.flags.c_contiguous and cloud.points.flags.writeable
    np.testing.assert_array_equal(cloud.points, points)  # bit-exact, NaN where NaN
    expected = _expected_fields(fields, ply=kind == "ply")
    assert sorted(cloud.fields) == sorted(expected)
    for name, array in expected.items():
        got = cloud.fields[name]
        assert got.dtype == array.dtype, name
        assert got.shape == array.shape, name
        np.testing.assert_array_equal(got, array, err_msg=name)
    assert len(cloud) == len(points)
    assert int((~cloud.finite_mask()).sum()) == 3


def test_round_trip_of_float64_points_rounds_to_float32(tmp_path: Path) -> None:
    points = np.array([[0.1, 1 / 3, -2.5], [1e-9, 123456.789, 0.0]])
    for kind, writer in (("pcd", clouds.write_pcd), ("ply", clouds.write_ply)):
        path = tmp_path / f"f64.{kind}"
        writer(path, points)
        cloud = clouds.read_cloud(path)
        np.testing.assert_array_equal(cloud.points, points.astype(np.float32))
        assert cloud.fields == {}


@pytest.mark.parametrize("kind", ["pcd", "ply"])
def test_empty_cloud_round_trips(tmp_path: Path, kind: str) -> None:
    path = tmp_path / f"empty.{kind}"
    writer = clouds.write_pcd if kind == "pcd" else clouds.write_ply
    for binary in (True, False):
        writer(path, np.zeros((0, 3), np.float32), {"i": np.zeros(0, np.uint8)}, binary)
        cloud = clouds.read_cloud(path)
        assert cloud.points.shape == (0, 3) and cloud.fields["i"].shape == (0,)


def test_binary_compressed_pcd_matches_the_binary_file(tmp_path: Path) -> None:
    points = _cloud(400)
    points[100:300] = 0.0  # long zero runs: overlapping back-references
    fields = _fields(len(points))
    binary = tmp_path / "b.pcd"
    clouds.write_pcd(binary, points, fields)
    path = tmp_path / "c.pcd"
    # Older PCL versions pad the file to a page: trailing zeros must be ignored.
    path.write_bytes(_compressed_pcd(binary.read_bytes(), padding=bytes(100)))

    cloud = clouds.read_cloud(path)

    np.testing.assert_array_equal(cloud.points, points)
    for name, array in fields.items():
        np.testing.assert_array_equal(cloud.fields[name], array, err_msg=name)
        assert cloud.fields[name].dtype == array.dtype
        assert cloud.fields[name].flags.c_contiguous


def test_kitti_bin_round_trip(tmp_path: Path) -> None:
    table = np.random.default_rng(3).standard_normal((257, 4)).astype("<f4")
    path = tmp_path / "000000.bin"
    table.tofile(path)

    cloud = clouds.read_cloud(path)

    assert cloud.format == "kitti"
    np.testing.assert_array_equal(cloud.points, table[:, :3])
    assert list(cloud.fields) == ["intensity"]
    np.testing.assert_array_equal(cloud.fields["intensity"], table[:, 3])
    assert cloud.points.flags.c_contiguous and cloud.points.flags.writeable


def test_npy_plain_columns_and_organised(tmp_path: Path) -> None:
    xyz = _cloud(50)
    path = tmp_path / "xyz.npy"
    np.save(path, xyz)
    cloud = clouds.read_cloud(path)
    np.testing.assert_array_equal(cloud.points, xyz)
    assert cloud.fields == {} and cloud.format == "npy"
    assert cloud.points.flags.writeable  # a copy, not the read-only file mapping

    wide = np.arange(50 * 5, dtype=np.float64).reshape(50, 5) / 7
    np.save(path, wide)
    cloud = clouds.read_cloud(path)
    np.testing.assert_array_equal(cloud.points, wide[:, :3].astype(np.float32))
    assert sorted(cloud.fields) == ["column3", "column4"]
    assert cloud.fields["column4"].dtype == np.float64
    np.testing.assert_array_equal(cloud.fields["column3"], wide[:, 3])

    grid = np.arange(4 * 6 * 4, dtype=np.float32).reshape(4, 6, 4)
    grid[1, 2, :3] = np.nan
    np.save(path, grid)
    cloud = clouds.read_cloud(path)
    assert cloud.organised_shape == (4, 6)
    np.testing.assert_array_equal(cloud.points, grid.reshape(-1, 4)[:, :3])
    assert np.flatnonzero(~cloud.finite_mask()).tolist() == [1 * 6 + 2]


def test_npy_structured_array_keeps_field_names(tmp_path: Path) -> None:
    dtype = np.dtype(
        [("x", "<f8"), ("y", "<f8"), ("z", ">f4"), ("intensity", "<u2"), ("n", "<f4", (3,))]
    )
    records = np.zeros(5, dtype=dtype)
    records["x"] = [1, 2, 3, 4, 5]
    records["z"] = [-1, -2, -3, -4, np.nan]
    records["intensity"] = [10, 20, 30, 40, 50]
    records["n"] = np.arange(15).reshape(5, 3)
    path = tmp_path / "structured.npy"
    np.save(path, records)

    cloud = clouds.read_cloud(path)

    np.testing.assert_array_equal(cloud.points[:, 0], [1, 2, 3, 4, 5])
    np.testing.assert_array_equal(cloud.points[:, 2], [-1, -2, -3, -4, np.nan])
    assert sorted(cloud.fields) == ["intensity", "n"]
    assert cloud.fields["intensity"].tolist() == [10, 20, 30, 40, 50]
    assert cloud.fields["n"].shape == (5, 3) and cloud.fields["n"][4].tolist() == [12, 13, 14]


# ----------------------------------------------------------- hand-written PCD / PLY


def test_handwritten_ascii_pcd_organised_with_nan_and_count(tmp_path: Path) -> None:
    path = tmp_path / "organised.pcd"
    path.write_text(
        "# .PCD v0.7 - Point Cloud Data file format\n"
        "VERSION 0.7\n"
        "FIELDS x y z rgb normal ring\n"
        "SIZE 4 4 4 4 4 2\n"
        "TYPE F F F U F U\n"
        "COUNT 1 1 1 1 2 1\n"
        "WIDTH 2\n"
        "HEIGHT 2\n"
        "VIEWPOINT 0 0 0 1 0 0 0\n"
        "POINTS 4\n"
        "DATA ascii\n"
        "1.5 -2 0.25 4278190335 0.5 0.5 7\n"
        "nan nan nan 0 0 0 8\n"
        "3 4 5 16711680 1 0 9\r\n"
        "-0.125 1e2 6 255 0 -1 65535\n"
    )

    cloud = clouds.read_cloud(path)

    assert cloud.organised_shape == (2, 2)
    np.testing.assert_array_equal(
        cloud.points,
        np.array([[1.5, -2, 0.25], [np.nan] * 3, [3, 4, 5], [-0.125, 100, 6]], np.float32),
    )
    assert cloud.finite_mask().tolist() == [True, False, True, True]
    assert cloud.fields["rgb"].dtype == np.uint32
    assert cloud.fields["rgb"].tolist() == [4278190335, 0, 16711680, 255]
    assert cloud.fields["normal"].shape == (4, 2) and cloud.fields["normal"].dtype == np.float32
    assert cloud.fields["normal"].tolist() == [[0.5, 0.5], [0, 0], [1, 0], [0, -1]]
    assert cloud.fields["ring"].dtype == np.uint16 and cloud.fields["ring"].tolist() == [
        7,
        8,
        9,
        65535,
    ]


def test_handwritten_binary_pcd_with_float64_xyz_padding_and_trailing_bytes(tmp_path: Path) -> None:
    dtype = np.dtype(
        [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("_", "u1", (3,)), ("i", "<i1"), ("s", "<u2")]
    )
    records = np.zeros(3, dtype)
    records["x"] = [1.0, 2.0, 3.0]
    records["y"] = [0.1, 0.2, 0.3]
    records["z"] = [-1.0, np.nan, 1e30]
    records["_"] = 0xAB
    records["i"] = [-128, 0, 127]
    records["s"] = [1, 256, 65535]
    header = (
        "VERSION .7\nFIELDS x y z _ i s\nSIZE 8 8 8 1 1 2\nTYPE F F F U I U\n"
        "COUNT 1 1 1 3 1 1\nWIDTH 3\nHEIGHT 1\nPOINTS 3\nDATA binary\n"
    )
    path = tmp_path / "hand.pcd"
    path.write_bytes(header.encode() + records.tobytes() + bytes(4096))

    cloud = clouds.read_cloud(path)

    np.testing.assert_array_equal(
        cloud.points, np.array([[1, 0.1, -1], [2, 0.2, np.nan], [3, 0.3, 1e30]], np.float32)
    )
    assert sorted(cloud.fields) == ["i", "s"]  # padding "_" dropped
    assert cloud.fields["i"].tolist() == [-128, 0, 127] and cloud.fields["i"].dtype == np.int8
    assert cloud.fields["s"].tolist() == [1, 256, 65535]


def test_handwritten_ascii_ply_skips_elements_before_and_after_vertex(tmp_path: Path) -> None:
    path = tmp_path / "hand.ply"
    path.write_text(
        "ply\n"
        "format ascii 1.0\n"
        "comment made by hand\n"
        "obj_info a tiny mesh\n"
        "element camera 1\n"
        "property float focal\n"
        "property list uchar int tags\n"
        "element vertex 3\n"
        "property float x\n"
        "property float y\n"
        "property double z\n"
        "property uchar intensity\n"
        "property int32 id\n"
        "element face 1\n"
        "property list uchar int vertex_indices\n"
        "end_header\n"
        "500.0 3 1 2 3\n"
        "0 0 0 255 -1\n"
        "1.5 -2.25 1e-3 0 2147483647\n"
        "nan 2 3 17 0\n"
        "3 0 1 2\n"
    )

    cloud = clouds.read_cloud(path)

    assert cloud.format == "ply"
    np.testing.assert_array_equal(
        cloud.points, np.array([[0, 0, 0], [1.5, -2.25, 1e-3], [np.nan, 2, 3]], np.float32)
    )
    assert cloud.fields["intensity"].dtype == np.uint8
    assert cloud.fields["intensity"].tolist() == [255, 0, 17]
    assert cloud.fields["id"].tolist() == [-1, 2147483647, 0]


@pytest.mark.parametrize("order", ["<", ">"], ids=["little", "big"])
def test_binary_ply_with_list_element_before_vertex(tmp_path: Path, order: str) -> None:
    # Two faces of different lengths (a triangle and a quad) before the vertices: their
    # byte size is only known by reading the list lengths.
    faces = (
        np.array([3], "u1").tobytes()
        + np.array([0, 1, 2], order + "i4").tobytes()
        + np.array([7], order + "i2").tobytes()
        + np.array([4], "u1").tobytes()
        + np.array([0, 1, 2, 3], order + "i4").tobytes()
        + np.array([-7], order + "i2").tobytes()
    )
    vertex = np.zeros(
        4, [("x", order + "f4"), ("y", order + "f4"), ("z", order + "f4"), ("w", order + "f8")]
    )
    vertex["x"] = [1, 2, 3, 4]
    vertex["y"] = [-1, -2, -3, -4]
    vertex["z"] = [0.5, 0.25, np.nan, 1e-3]
    vertex["w"] = [1 / 3, 2 / 3, 1.0, -1.0]
    encoding = "binary_little_endian" if order == "<" else "binary_big_endian"
    header = (
        f"ply\nformat {encoding} 1.0\nelement face 2\nproperty list uchar int vertex_indices\n"
        "property short flags\nelement vertex 4\nproperty float x\nproperty float y\n"
        "property float z\nproperty double w\nelement edge 1\nproperty int a\nend_header\n"
    )
    path = tmp_path / f"{order == '<'}.ply"
    path.write_bytes(header.encode() + faces + vertex.tobytes() + bytes(4))

    cloud = clouds.read_cloud(path)

    np.testing.assert_array_equal(cloud.points[:, 0], [1, 2, 3, 4])
    np.testing.assert_array_equal(
        cloud.points[:, 2], np.array([0.5, 0.25, np.nan, 1e-3], np.float32)
    )
    assert cloud.fields["w"].dtype == np.float64 and cloud.fields["w"].dtype.isnative
    np.testing.assert_array_equal(cloud.fields["w"], [1 / 3, 2 / 3, 1.0, -1.0])

    # The same file cut inside the faces is a truncated file, not a wrong vertex table.
    cut = tmp_path / "cut.ply"
    cut.write_bytes(header.encode() + faces[:20])
    _raises_format_error(cut, r"face.*truncated")


# ------------------------------------------------------------------------------ LZF


def test_lzf_decoder_matches_reference_on_handmade_and_compressed_streams() -> None:
    handmade = bytes([1]) + b"ab" + bytes([(4 << 5) | 0, 1])  # "ab" + copy 6 from 2 back
    assert clouds._lzf_decompress(np.frombuffer(handmade, np.uint8), 8, "t", "p") == b"abababab"
    long_ref = bytes([0]) + b"z" + bytes([(7 << 5) | 0, 100, 0])  # "z" + copy 109 from 1 back
    assert clouds._lzf_decompress(np.frombuffer(long_ref, np.uint8), 110, "t", "p") == b"z" * 110

    rng = np.random.default_rng(5)
    pieces = [rng.integers(0, 4, 3000, dtype=np.uint8).tobytes(), bytes(700), b"xyz" * 300,
              rng.integers(0, 256, 9000, dtype=np.uint8).tobytes()]  # fmt: skip
    data = b"".join(pieces)
    packed = _lzf_compress(data)
    assert len(packed) < len(data)
    assert _lzf_decompress_reference(packed) == data
    assert clouds._lzf_decompress(np.frombuffer(packed, np.uint8), len(data), "t", "p") == data


@pytest.mark.parametrize(
    ("stream", "size", "match"),
    [
        (bytes([(1 << 5) | 0, 0]), 3, "before its start"),  # back-reference into nothing
        (bytes([5]) + b"ab", 6, "past the last"),  # literal run cut short
        (bytes([(7 << 5)]), 9, "past the last"),  # long reference without its bytes
        (bytes([1]) + b"ab", 5, "expected 5 bytes"),  # decompresses to 2, header says 5
        (b"", 4, "got 0 compressed"),
    ],
)
def test_lzf_corrupt_streams_raise(stream: bytes, size: int, match: str) -> None:
    with pytest.raises(FileFormatError, match=match):
        clouds._lzf_decompress(np.frombuffer(stream, np.uint8), size, "PCD data", "f.pcd")


# ------------------------------------------------------------------ format recognition


def test_format_is_recognised_by_content_and_can_be_forced(tmp_path: Path) -> None:
    points = _cloud(20)
    pcd = tmp_path / "scan.txt"
    clouds.write_pcd(pcd, points)
    assert clouds.read_cloud(pcd).format == "pcd"
    misnamed = tmp_path / "really_a_ply.pcd"
    clouds.write_ply(misnamed, points, binary=False)
    assert clouds.read_cloud(misnamed).format == "ply"
    velodyne = tmp_path / "scan.dat"
    np.zeros((4, 4), "<f4").tofile(velodyne)
    with pytest.raises(FileFormatError, match=r"extension.*'\.dat'") as info:
        clouds.read_cloud(velodyne)
    assert str(info.value).endswith(str(velodyne))
    assert len(clouds.read_cloud(velodyne, format="kitti")) == 4
    with pytest.raises(InputError, match="format"):
        clouds.read_cloud(velodyne, format="las")


# ----------------------------------------------------------------------- bad files

_PCD_HEAD = (
    "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\n"
)
_PCD_BODY = "DATA ascii\n1 2 3\n4 5 6\n"


def _pcd_case(name: str, old: str, new: str, match: str):
    return pytest.param(_PCD_HEAD.replace(old, new) + _PCD_BODY, match, id=name)


@pytest.mark.parametrize(
    ("content", "match"),
    [
        pytest.param(
            _PCD_HEAD + "DATA ascii\n1 2 3\n4 5\n",
            r"expected 2 points x 3 values.*truncated",
            id="ascii-short",
        ),
        pytest.param(_PCD_HEAD + _PCD_BODY + "7 8 9\n", r"got 9 .*extra data", id="ascii-long"),
        pytest.param(
            _PCD_HEAD + "DATA ascii\n1 2 3\n4 five 6\n",
            r"field 'y'.*numbers.*five",
            id="ascii-word",
        ),
        pytest.param(
            _PCD_HEAD + "DATA binary\n" + "x" * 23,
            r"expected 24 bytes.*got 23.*truncated",
            id="binary-short",
        ),
        pytest.param(
            _PCD_HEAD + "DATA binary_compressed\n" + "abc",
            r"two uint32 sizes",
            id="compressed-short",
        ),
        pytest.param(
            _PCD_HEAD + "DATA lzma\n", r"DATA ascii, binary or binary_compressed", id="data-kind"
        ),
        pytest.param(_PCD_HEAD, r"DATA.*end of file.*truncated header", id="no-data"),
        _pcd_case("no-fields", "FIELDS x y z\n", "", r"missing the FIELDS line"),
        _pcd_case("size-count", "SIZE 4 4 4", "SIZE 4 4", r"expected 3 SIZE values"),
        _pcd_case("float16", "SIZE 4 4 4", "SIZE 4 4 2", r"'z' has TYPE F SIZE 2"),
        _pcd_case("no-z", "FIELDS x y z", "FIELDS x y q", r"expected fields x, y and z"),
        _pcd_case("twice", "FIELDS x y z", "FIELDS x y y", r"\['y'\] appear twice"),
        _pcd_case("z-count", "COUNT 1 1 1", "COUNT 1 1 2", r"'z' has COUNT 2"),
        _pcd_case("huge-count", "COUNT 1 1 1", "COUNT 1 1 1 99999999999", r"3 COUNT values"),
        _pcd_case(
            "huge-record",
            "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1",
            "FIELDS x y z d\nSIZE 4 4 4 8\nTYPE F F F F\nCOUNT 1 1 1 99999999999",
            r"at most 1048576 bytes, got 800000000004",
        ),
        _pcd_case("points", "POINTS 2", "POINTS 3", r"POINTS = WIDTH x HEIGHT = 2x1 = 2"),
        _pcd_case("width", "WIDTH 2", "WIDTH two", r"integers >= 0 after WIDTH"),
        _pcd_case("viewpoint", "HEIGHT 1", "HEIGHT 1\nVIEWPOINT 0 0 0 1", r"VIEWPOINT tx ty"),
        _pcd_case(
            "keyword", "VERSION 0.7", "VERSION 0.7\nCOLOUR red", r"line 2: expected a keyword"
        ),
        _pcd_case("repeated", "WIDTH 2", "WIDTH 2\nWIDTH 2", r"WIDTH appears twice"),
        pytest.param(
            "VERSION 0.7\nFIELDS x y z\n\xe9\n", r"line 3: expected ASCII text", id="latin-1"
        ),
    ],
)
def test_bad_pcd_files_raise_file_format_error(tmp_path: Path, content: str, match: str) -> None:
    path = tmp_path / "bad.pcd"
    path.write_bytes(content.encode("latin-1"))
    _raises_format_error(path, match)


def test_pcd_integer_overflow_in_ascii_is_a_file_error(tmp_path: Path) -> None:
    path = tmp_path / "overflow.pcd"
    path.write_text("FIELDS x y z r\nSIZE 4 4 4 1\nTYPE F F F U\nWIDTH 1\nDATA ascii\n1 2 3 300\n")
    _raises_format_error(path, r"field 'r'.*integers that fit uint8")


def test_compressed_pcd_with_wrong_sizes_raises(tmp_path: Path) -> None:
    binary = tmp_path / "b.pcd"
    clouds.write_pcd(binary, _cloud(30))
    good = _compressed_pcd(binary.read_bytes())
    head, _, rest = good.partition(b"DATA binary_compressed\n")
    packed_size, plain_size = np.frombuffer(rest[:8], "<u4")
    path = tmp_path / "c.pcd"
    path.write_bytes(
        head
        + b"DATA binary_compressed\n"
        + np.array([packed_size, plain_size + 4], "<u4").tobytes()
        + rest[8:]
    )
    _raises_format_error(path, r"uncompressed size of 360 bytes.*got 364")
    path.write_bytes(good[:-5])
    _raises_format_error(path, rf"expected {packed_size} compressed bytes.*truncated")


_PLY_HEAD = (
    "ply\nformat ascii 1.0\nelement vertex 2\n"
    "property float x\nproperty float y\nproperty float z\n"
)


def _ply_case(name: str, old: str, new: str, match: str, body: str = "end_header\n"):
    return pytest.param(_PLY_HEAD.replace(old, new) + body, match, id=name)


@pytest.mark.parametrize(
    ("content", "match"),
    [
        _ply_case(
            "one-line", "", "", r"0 lines of earlier elements and 2 vertex", "end_header\n1 2 3"
        ),
        _ply_case("short-line", "", "", r"2 vertex lines of 3 values", "end_header\n1 2 3\n4 5\n"),
        _ply_case("word", "", "", r"vertex 'z'.*numbers", "end_header\n1 2 3\n4 5 x\n"),
        _ply_case("no-end", "", "", r"end_header.*truncated header", "end_header"),
        _ply_case("version", "ascii 1.0", "ascii 2.0", r"format ascii"),
        _ply_case("no-format", "format ascii 1.0\n", "", r"missing the 'format'"),
        _ply_case("no-vertex", "vertex 2", "point 2", r"'vertex' element"),
        _ply_case("no-z", "float z", "float w", r"x, y and z, got \['x', 'y', 'w'\]"),
        _ply_case("list", "float z", "list uchar float z", r"'z' is a list"),
        _ply_case("type", "float z", "half z", r"line 6: expected 'property"),
        _ply_case("count", "vertex 2", "vertex -2", r"count >= 0"),
        _ply_case("keyword", "", "", r"got 'texture foo'", "texture foo\nend_header\n"),
        _ply_case(
            "binary-short",
            "ascii",
            "binary_little_endian",
            r"24 bytes.*got 23.*truncated",
            "end_header\n" + "\0" * 23,
        ),  # fmt: skip
    ],
)
def test_bad_ply_files_raise_file_format_error(tmp_path: Path, content: str, match: str) -> None:
    path = tmp_path / "bad.ply"
    path.write_bytes(content.encode())
    _raises_format_error(path, match)


def test_bad_kitti_npy_and_generic_files_raise(tmp_path: Path) -> None:
    path = tmp_path / "scan.bin"
    path.write_bytes(bytes(4 * 4 * 3 + 5))
    _raises_format_error(path, r"multiple of 16 bytes.*got 53")

    npy = tmp_path / "c.npy"
    np.save(npy, np.zeros((5, 3), np.int32))
    _raises_format_error(npy, r"float array.*got dtype int32")
    np.save(npy, np.zeros((5, 2), np.float32))
    _raises_format_error(npy, r"C >= 3.*\(5, 2\)")
    np.save(npy, np.zeros(5, [("x", "f4"), ("y", "f4")]))
    _raises_format_error(npy, r"structured fields x, y and z")
    np.save(npy, np.zeros((100, 3), np.float32))
    npy.write_bytes(npy.read_bytes()[:300])
    _raises_format_error(npy, r"corrupt or truncated")

    _raises_format_error(tmp_path / "missing.pcd", r"missing path")
    (tmp_path / "empty.ply").write_bytes(b"")
    _raises_format_error(tmp_path / "empty.ply", r"empty file \(0 bytes\)")
    (tmp_path / "folder.pcd").mkdir()
    _raises_format_error(tmp_path / "folder.pcd", r"got a folder")
    (tmp_path / "garbage.pcd").write_bytes(b"\x00\x01garbage\xff\n" * 10)
    _raises_format_error(tmp_path / "garbage.pcd", r"PCD header line 1")


def test_truncated_and_corrupted_files_only_ever_raise_file_format_error(tmp_path: Path) -> None:
    points = _cloud(40)
    fields = {"i": np.arange(40, dtype=np.uint16), "n": np.ones((40, 2), np.float32)}
    sources = {}
    for kind, writer in (("pcd", clouds.write_pcd), ("ply", clouds.write_ply)):
        for binary in (True, False):
            path = tmp_path / f"src{binary}.{kind}"
            writer(path, points, fields, binary)
            sources[f"{kind}-{binary}"] = path.read_bytes()
    sources["pcd-compressed"] = _compressed_pcd(sources["pcd-True"])
    rng = np.random.default_rng(11)
    target = tmp_path / "damaged"
    for name, raw in sources.items():
        target = target.with_suffix("." + name[:3])
        cuts = np.unique(np.linspace(1, len(raw) - 1, 30).astype(int))
        damaged = [raw[:cut] for cut in cuts]
        for _ in range(30):
            flipped = bytearray(raw)
            for at in rng.integers(0, len(raw), 3):
                flipped[at] = int(rng.integers(0, 256))
            damaged.append(bytes(flipped))
        for content in damaged:
            target.write_bytes(content)
            try:
                cloud = clouds.read_cloud(target)
            except FileFormatError as exc:
                assert str(exc).endswith(str(target)), (name, str(exc))
            else:
                assert cloud.points.shape[1] == 3 and cloud.points.dtype == np.float32


# -------------------------------------------------------------- writers and the type


def test_writers_reject_bad_arguments(tmp_path: Path) -> None:
    path = tmp_path / "out.pcd"
    xyz = np.zeros((4, 3), np.float32)
    cases = [
        (clouds.write_pcd, (np.zeros((4, 2)),), r"points: expected shape \(N, 3\)"),
        (clouds.write_pcd, (np.zeros((4, 3), np.int32),), r"points: expected a float array"),
        (clouds.write_pcd, ([[0, 0, 0]],), r"points: expected a numpy.ndarray"),
        (clouds.write_pcd, (xyz, {"i": np.zeros(3)}), r"fields\['i'\]: expected shape \(4,\)"),
        (clouds.write_pcd, (xyz, {"a b": np.zeros(4)}), r"printable ASCII words"),
        (clouds.write_pcd, (xyz, {"z": np.zeros(4)}), r"belong in points"),
        (clouds.write_pcd, (xyz, {"_": np.zeros(4)}), r"padding"),
        (clouds.write_pcd, (xyz, {"b": np.zeros(4, bool)}), r"dtype int8..int64"),
        (clouds.write_pcd, (xyz, {"h": np.zeros(4, np.float16)}), r"got float16"),
        (clouds.write_ply, (xyz, {"i": np.zeros(4, np.int64)}), r"no 64-bit integers"),
        (clouds.write_ply, (xyz, {"n": np.zeros((4, 2)), "n_0": np.zeros(4)}), r"'n_0' twice"),
    ]
    for writer, args, match in cases:
        with pytest.raises(InputError, match=match) as info:
            writer(path, *args)
        assert not isinstance(info.value, FileFormatError)
        assert str(info.value).endswith(str(path)), str(info.value)


def test_point_cloud_validates_its_arrays() -> None:
    cloud = clouds.PointCloud(np.zeros((6, 3)), {"i": np.zeros(6, ">u2")}, organised_shape=(2, 3))
    assert cloud.points.dtype == np.float32 and cloud.fields["i"].dtype.isnative
    assert cloud.path == "" and cloud.format == "" and len(cloud) == 6
    with pytest.raises(InputError, match=r"height x width = 6 points, got 4x2"):
        clouds.PointCloud(np.zeros((6, 3)), organised_shape=(4, 2))
    with pytest.raises(InputError, match=r"fields\['t'\]: expected shape \(6,\)"):
        clouds.PointCloud(np.zeros((6, 3)), {"t": np.zeros(5)})
    with pytest.raises(InputError, match=r"points: expected shape"):
        clouds.PointCloud(np.zeros((6, 4)))


# --------------------------------------------------------------------------- poses


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _kitti_line(rotation: np.ndarray, translation) -> str:
    return " ".join(
        f"{v:.9e}" for v in np.hstack([rotation, np.reshape(translation, (3, 1))]).ravel()
    )


def test_kitti_poses_read_as_4x4(tmp_path: Path) -> None:
    path = tmp_path / "poses.txt"
    path.write_text(
        _kitti_line(np.eye(3), [0, 0, 0])
        + "\n\n"
        + _kitti_line(_rot_z(np.pi / 2), [1, 2, 3])
        + "\n"
    )

    trajectory = poses.read_trajectory(path)

    assert trajectory.format == "kitti" and trajectory.stamps_s is None and len(trajectory) == 2
    expected = np.eye(4)
    expected[:3, :3] = _rot_z(np.pi / 2)
    expected[:3, 3] = [1, 2, 3]
    np.testing.assert_allclose(trajectory.world_from_body[1], expected, atol=1e-9)
    np.testing.assert_array_equal(poses.read_poses(path), trajectory.world_from_body)
    p_body = np.array([1.0, 0, 0, 1])
    np.testing.assert_allclose(trajectory.world_from_body[1] @ p_body, [1, 3, 3, 1], atol=1e-9)


def test_tum_trajectory_with_stamps_comments_and_commas(tmp_path: Path) -> None:
    half = np.sqrt(0.5)
    path = tmp_path / "groundtruth.txt"
    path.write_text(
        "# ground truth trajectory\n# timestamp tx ty tz qx qy qz qw\n"
        "1305031102.175304 1.0 2.0 3.0 0 0 0 1\n"
        f"1305031102.185,0,0,1,0,0,{half:.4f},{half:.4f}\n"  # 4 decimals, |q| != 1 exactly
    )

    trajectory = poses.read_trajectory(path)

    assert trajectory.format == "tum"
    np.testing.assert_array_equal(trajectory.stamps_s, [1305031102.175304, 1305031102.185])
    np.testing.assert_array_equal(trajectory.world_from_body[0, :3, 3], [1, 2, 3])
    np.testing.assert_allclose(trajectory.world_from_body[1, :3, :3], _rot_z(np.pi / 2), atol=1e-12)
    rotation = trajectory.world_from_body[:, :3, :3]
    np.testing.assert_allclose(
        np.einsum("mji,mjk->mik", rotation, rotation),
        np.broadcast_to(np.eye(3), (2, 3, 3)),
        atol=1e-12,
    )


@pytest.mark.parametrize(
    ("lines", "match"),
    [
        (
            ["1 0 0 0 0 1 0 0 0 0 1 0", "2 0 0 0 0 1 0 0 0 0 1 0"],
            r"line 2: expected a rotation.*got 3",
        ),
        (["1 0 0 0 0 1 0 0 0 0 -1 0"], r"line 1: expected a proper rotation.*det -1.*reflection"),
        (["1 0 0 0 0 1 0 0 0 0 1"], r"line 1: expected 12 values .*8 .*7.*got 11 values"),
        (
            ["1 0 0 0 0 1 0 0 0 0 1 0", "0 0 0 0 0 0 1"],
            r"line 2: expected 12 values like the lines before",
        ),
        (["1 0 0 0 0 1 0 0 0 0 1 nan"], r"line 1: expected finite numbers"),
        (
            ["# c", "1 0 0 0 0 1 0 0 0 0 1 0", "1 0 0 0 0 1 0 0 0 0 1 x"],
            r"line 3: expected finite numbers",
        ),
        (["5 0 0 0 0 0 0 1", "5 1 0 0 0 0 0 1"], r"line 2: expected timestamps that increase"),
        (["5 0 0 0 0 0 0 0.9"], r"line 1: expected a unit quaternion.*0\.9"),
        (["# only a comment", ""], r"at least one pose line"),
    ],
)
def test_bad_pose_files_name_the_line(tmp_path: Path, lines: list[str], match: str) -> None:
    path = tmp_path / "poses.txt"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(FileFormatError, match=match) as info:
        poses.read_trajectory(path)
    assert str(info.value).endswith(str(path))


def test_pose_arguments_are_checked(tmp_path: Path) -> None:
    path = tmp_path / "poses.txt"
    path.write_text("0 0 0 0 0 0 1\n")
    assert poses.read_trajectory(path).format == "tum-no-stamp"
    with pytest.raises(FileFormatError, match=r"expected 8 values"):
        poses.read_trajectory(path, format="tum")
    with pytest.raises(InputError, match=r"format"):
        poses.read_trajectory(path, format="euroc")
    with pytest.raises(errors.ConfigError, match=r"rotation_tolerance"):
        poses.read_trajectory(path, rotation_tolerance=0.0)
    with pytest.raises(FileFormatError, match=r"missing path"):
        poses.read_poses(tmp_path / "nope.txt")


# ------------------------------------------------------------------------ real data


def test_ouster_os1_128_scans_and_kitti_poses(shared_data: Path) -> None:
    folder = shared_data / "ouster-os1-128-outdoor"
    scans = [folder / f"OS-1-128_scan{i}.npy" for i in range(3)]
    pose_file = folder / "OS-1-128_v2.3.0_1024x10_lb_n3_poses_kitti.txt"
    for path in [*scans, pose_file]:
        if not path.exists():
            pytest.skip(f"real data file {path} is absent")

    counts = []
    for path in scans:
        cloud = clouds.read_cloud(path)
        assert cloud.format == "npy" and cloud.fields == {} and cloud.organised_shape is None
        assert cloud.points.dtype == np.float32 and cloud.points.flags.c_contiguous
        assert cloud.finite_mask().all()  # zero-range returns were removed
        range_m = np.linalg.norm(cloud.points, axis=1)
        assert range_m.min() > 1.0  # OS1 minimum range ~0.5 m; this scan starts at 1.25 m
        assert 5.0 < np.median(range_m) < 20.0  # measured 11.3-11.4 m
        assert np.percentile(range_m, 99) < 60.0  # measured 54.9-55.1 m
        assert np.mean((range_m >= 1.0) & (range_m <= 60.0)) > 0.99
        assert -5.0 < np.percentile(cloud.points[:, 2], 1) < 0.0  # ground below the sensor
        counts.append(len(cloud))
    assert counts == [107647, 107357, 107532]

    trajectory = poses.read_trajectory(pose_file)
    assert trajectory.format == "kitti" and len(trajectory) == 3
    pose = trajectory.world_from_body
    np.testing.assert_allclose(pose[0], np.eye(4), atol=1e-12)
    rotation = pose[:, :3, :3]
    np.testing.assert_allclose(
        np.einsum("mji,mjk->mik", rotation, rotation),
        np.broadcast_to(np.eye(3), (3, 3, 3)),
        atol=1e-9,
    )
    np.testing.assert_allclose(np.linalg.det(rotation), 1.0, atol=1e-9)
    step_m = np.linalg.norm(np.diff(pose[:, :3, 3], axis=0), axis=1)
    np.testing.assert_allclose(step_m, [0.2456, 0.2528], atol=1e-3)  # ~2.5 m/s at 10 Hz


def test_kinect_dining_poses_without_stamps(shared_data: Path) -> None:
    path = shared_data / "kinect-dining" / "pose.txt"
    if not path.exists():
        pytest.skip(f"real data file {path} is absent")
    trajectory = poses.read_trajectory(path)
    assert trajectory.format == "tum-no-stamp" and len(trajectory) == 5
    np.testing.assert_allclose(
        trajectory.world_from_body[0, :3, 3], [-0.228993, 0.00645704, 0.0287837]
    )
    np.testing.assert_allclose(np.linalg.det(trajectory.world_from_body[:, :3, :3]), 1.0, atol=1e-9)


def test_write_binary_compressed_pcd_round_trips_and_matches_the_numpy_decoder(tmp_path: Path) -> None:
    """write_pcd(compressed=True) writes PCL's binary_compressed layout; read_cloud gives the
    same points and fields back (NaN included), through the core's LZF decoder, and the NumPy
    decoder (kept to explain corrupt streams) decodes the same bytes identically. Random
    bytes that LZF cannot shrink are stored as literal runs, still a valid stream."""
    points = _cloud(3000)
    points[500:1500] = 0.0
    fields = _fields(len(points))
    path = tmp_path / "c.pcd"
    clouds.write_pcd(path, points, fields, compressed=True)
    assert b"DATA binary_compressed\n" in path.read_bytes()[:400]
    cloud = clouds.read_cloud(path)
    np.testing.assert_array_equal(cloud.points, points)
    for name, array in _expected_fields(fields, ply=False).items():
        np.testing.assert_array_equal(cloud.fields[name], array, err_msg=name)
    raw = path.read_bytes()
    start = raw.index(b"DATA binary_compressed\n") + len(b"DATA binary_compressed\n")
    size_c, size_u = np.frombuffer(raw, "<u4", count=2, offset=start)
    packed = raw[start + 8 : start + 8 + int(size_c)]
    fast = clouds._lzf_decompress_fast(packed, int(size_u))
    slow = clouds._lzf_decompress(np.frombuffer(packed, np.uint8), int(size_u), "test", path)
    assert fast == slow and len(fast) == int(size_u)
    assert fast == _lzf_decompress_reference(packed)
    noise = np.random.default_rng(3).integers(0, 256, 1000, dtype=np.uint8).tobytes()
    stored = clouds._lzf_compress(noise)
    assert _lzf_decompress_reference(stored) == noise and clouds._lzf_decompress_fast(stored, len(noise)) == noise
    assert clouds._lzf_decompress_fast(packed[:-5], int(size_u)) is None  # truncated: the caller explains
    with pytest.raises(InputError, match="compressed"):
        clouds.write_pcd(tmp_path / "a.pcd", points, binary=False, compressed=True)


def test_lzf_core_functions_and_write_pcd_flags_refuse_bad_arguments(tmp_path: Path) -> None:
    """The core LZF functions take bytes and an int size (errors name the argument); a
    corrupt stream that claims a huge output is refused without decoding it with NumPy
    (which would take seconds and GBs); write_pcd's flags must be booleans."""
    core = pytest.importorskip("subterra._core")
    for data, size in ((b"\x00a", -1), (b"\x00a", 2**64), (b"\x00a", 1.5), (b"\x00a", True), (bytearray(b"\x00a"), 1), (None, 1)):
        with pytest.raises(InputError):
            core.lzf_decompress(data, size)
    assert core.lzf_decompress(b"\x00a", 1) == b"a"
    with pytest.raises(InputError, match="data"):
        core.lzf_compress("text")
    # A stream of 102-byte back-references (ratio 34, under LZF's 88) that claims 100 MB and
    # ends in a broken token.
    points = (100 << 20) // 12
    stream = b"\x00a" + b"\xe0\x5d\x00" * ((points * 12 - 1) // 102) + b"\xe0"
    head = f"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {points}\nHEIGHT 1\nPOINTS {points}\n"
    body = np.array([len(stream), points * 12], "<u4").tobytes() + stream
    path = tmp_path / "bomb.pcd"
    path.write_bytes(head.encode() + b"DATA binary_compressed\n" + body)
    with pytest.raises(FileFormatError, match="corrupt"):
        clouds.read_cloud(path)
    for flags in ({"compressed": "false"}, {"binary": "no"}, {"compressed": None}):
        with pytest.raises(InputError, match="True or False"):
            clouds.write_pcd(tmp_path / "f.pcd", np.zeros((1, 3), np.float32), **flags)
