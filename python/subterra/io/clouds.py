"""Point clouds from files: PCD, PLY, KITTI velodyne ``.bin`` and ``.npy``.

A point cloud is a ``float32`` ``(N, 3)`` array of x, y, z [m] in the sensor frame and
any number of extra per-point fields (intensity, ring, time, ...) as separate arrays
(docs/conventions.md). :func:`read_cloud` returns both in a :class:`PointCloud`.

NaN points are kept. Organised clouds (an Ouster or a depth camera writing ``WIDTH x
HEIGHT``) mark "no return" with a NaN point so that the point at row ``r``, column ``c``
stays at index ``r * width + c``. The reader keeps them as NaN; the terrain mapper drops
and counts them (:meth:`PointCloud.finite_mask`).

Formats
-------
The format is chosen by the file's content where it has a signature (``ply``, the
NumPy magic, a PCD header) and otherwise by its extension (case-insensitive); a
``format=`` argument overrides both.

``.pcd`` (``"pcd"``)
    PCL's PCD v0.7 (and v0.5/v0.6 headers, which have the same keys): ``DATA ascii``,
    ``DATA binary`` and ``DATA binary_compressed`` (LZF, by the core: the ``lzf`` crate, a Rust
    port of liblzf; a corrupt stream is explained by a NumPy decoder that names the byte).
    Fields of any ``TYPE`` (I, U, F) / ``SIZE`` (1, 2, 4, 8; F only 4 and 8) /
    ``COUNT``; ``x``, ``y`` and ``z`` must be present with ``COUNT 1``. A field with
    ``COUNT k > 1`` comes back as an ``(N, k)`` array. Padding fields named ``_`` are
    dropped. ``WIDTH x HEIGHT`` with ``HEIGHT > 1`` is an organised cloud
    (:attr:`PointCloud.organised_shape`). ``VIEWPOINT`` is checked (7 numbers) and not
    applied: like PCL, the points stay in the frame they were written in. A packed
    ``rgb`` field is returned as stored (``F4`` or ``U4``); view it as ``uint32`` for
    the colour bytes. Binary data is little-endian (PCL writes the host order, and every
    platform PCL runs on is little-endian); bytes after the data are ignored, as PCL
    does (older PCL versions pad binary files to a whole page). ASCII data must hold
    exactly ``POINTS`` x (sum of ``COUNT``) numbers; ``nan``, ``-nan`` and ``inf`` are
    read as such.
``.ply`` (``"ply"``)
    ``ascii 1.0``, ``binary_little_endian 1.0`` and ``binary_big_endian 1.0``. The
    ``vertex`` element must hold scalar properties ``x``, ``y`` and ``z``; its other
    scalar properties become fields. Other elements (faces, edges, a camera, ...) are
    skipped, also when they come before ``vertex`` and hold list properties. In an ASCII
    file each element instance must be on its own line (as every writer does). List
    properties on ``vertex`` itself are not supported.
``.bin`` (``"kitti"``)
    KITTI velodyne scans: little-endian ``float32`` records ``x y z intensity``; the
    intensity becomes the field ``intensity``.
``.npy`` (``"npy"``)
    A float array ``(N, C)`` or an organised ``(H, W, C)`` with ``C >= 3``: columns 0-2
    are x, y, z; each further column ``i`` becomes the field ``"column<i>"``
    (``column3``, ``column4``, ...) with the array's dtype. Or a structured array
    ``(N,)`` / ``(H, W)`` with fields ``x``, ``y``, ``z`` (any real dtype) and others,
    which keep their names. Integer arrays are rejected (not metres).

Coordinates stored as ``float64`` are rounded to ``float32``; values beyond its range
become +-inf (not finite, so dropped like NaN).

A file of 0 bytes is rejected in every format (a failed write, not an empty scan); a
header that declares 0 points reads as an empty cloud.

Not supported: PCD with ``TYPE F SIZE 2``, PLY list properties on ``vertex``, ``.npz``,
LAS/LAZ, E57 (convert them with PDAL or CloudCompare to PLY or PCD).

:func:`write_pcd` and :func:`write_ply` write clouds back (binary or ASCII) so that
:func:`read_cloud` returns the same values.
"""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Union

import numpy as np

from .._files import open_for_writing
from ..errors import FileFormatError, InputError
from .depth import _as_path, _check_readable_file, _read_bytes, _read_head

#: Most points :func:`write_pcd` and :func:`write_ply` write (the core's limit on one cloud,
#: 2^25); checked on the array's shape before it is copied.
MAX_WRITE_POINTS = 1 << 25

__all__ = [
    "CLOUD_EXTENSIONS",
    "CLOUD_FORMATS",
    "PointCloud",
    "read_cloud",
    "write_pcd",
    "write_ply",
]

PathLike = Union[str, "os.PathLike[str]"]

#: The formats :func:`read_cloud` reads (the values of :attr:`PointCloud.format`).
CLOUD_FORMATS: tuple[str, ...] = ("pcd", "ply", "kitti", "npy")

#: File extension (lower case, with the dot) -> format, used when the content has no
#: signature.
CLOUD_EXTENSIONS: dict[str, str] = {".pcd": "pcd", ".ply": "ply", ".bin": "kitti", ".npy": "npy"}

_XYZ = ("x", "y", "z")
_NPY_MAGIC = b"\x93NUMPY"
# Bytes read to recognise a format by its content.
_SNIFF_BYTES = 64
# Field names must be one header token: printable ASCII without spaces, not empty.
_FIELD_NAME = re.compile(r"^[!-~]+$")

# PCD TYPE / SIZE -> NumPy type code (little-endian on disk). PCL has no 2-byte float.
_PCD_TYPES: dict[tuple[str, int], str] = {
    ("I", 1): "i1",
    ("I", 2): "i2",
    ("I", 4): "i4",
    ("I", 8): "i8",
    ("U", 1): "u1",
    ("U", 2): "u2",
    ("U", 4): "u4",
    ("U", 8): "u8",
    ("F", 4): "f4",
    ("F", 8): "f8",
}
_PCD_DATA_KINDS = ("ascii", "binary", "binary_compressed")
_PCD_PADDING_FIELD = "_"
# Largest point record accepted [bytes]: the biggest PCL descriptors (SHOT with colour,
# 1353 floats) take about 5.4 kB, so a larger record means a corrupt COUNT.
_PCD_MAX_POINT_BYTES = 1 << 20
_PCD_VIEWPOINT_NUMBERS = 7
_PCD_IDENTITY_VIEWPOINT = "0 0 0 1 0 0 0"
# binary_compressed: two little-endian uint32 (compressed and uncompressed size).
_PCD_COMPRESSED_SIZES_BYTES = 8

# PLY property type names (both spellings of the spec) -> NumPy type code.
_PLY_TYPES: dict[str, str] = {
    "char": "i1",
    "uchar": "u1",
    "short": "i2",
    "ushort": "u2",
    "int": "i4",
    "uint": "u4",
    "float": "f4",
    "double": "f8",
    "int8": "i1",
    "uint8": "u1",
    "int16": "i2",
    "uint16": "u2",
    "int32": "i4",
    "uint32": "u4",
    "float32": "f4",
    "float64": "f8",
}
_PLY_NAMES_BY_CODE: dict[str, str] = {
    "i1": "char",
    "u1": "uchar",
    "i2": "short",
    "u2": "ushort",
    "i4": "int",
    "u4": "uint",
    "f4": "float",
    "f8": "double",
}
_PLY_ENCODINGS: dict[str, str] = {
    "ascii": "",
    "binary_little_endian": "<",
    "binary_big_endian": ">",
}
_PLY_VERTEX = "vertex"
# Bytes that may follow the last element of a binary PLY (a final newline).
_PLY_TRAILING_SPACE = b" \t\r\n"

# KITTI velodyne: float32 x, y, z, intensity.
_KITTI_COLUMNS = 4
_KITTI_RECORD_BYTES = 4 * _KITTI_COLUMNS

# LZF (liblzf, used by PCL's binary_compressed): a control byte < 32 starts a literal
# run of ctrl + 1 bytes; otherwise the top 3 bits are a back-reference length (7 means
# "7 + the next byte") and the low 5 bits the high byte of the offset.
_LZF_LITERAL_LIMIT = 32
_LZF_LONG_REF = 7
_LZF_MIN_REF_LEN = 2
# The most output per input byte: a 3-byte long back-reference copies up to 264 bytes.
_LZF_MAX_RATIO = 88
# The NumPy decoder explains a corrupt LZF stream only up to this output size [bytes]; beyond,
# the error says the stream is corrupt without the byte (it would take seconds and GBs).
_LZF_EXPLAIN_MAX_BYTES = 64 << 20


@dataclasses.dataclass(frozen=True, eq=False)
class PointCloud:
    """A point cloud and its extra per-point fields.

    Attributes:
        points: C-contiguous ``float32`` ``(N, 3)`` array of x, y, z [m] in the sensor
            frame. NaN rows are points without a return (kept so organised indices stay
            valid); see :meth:`finite_mask`.
        fields: extra per-point fields by name (``intensity``, ``ring``, ``t``, ...),
            each a C-contiguous, native-byte-order array of shape ``(N,)``, or
            ``(N, k)`` for a PCD field with ``COUNT k``, in the dtype of the file.
            Never holds ``x``, ``y`` or ``z``.
        path: the file the cloud was read from (as given), or a label.
        format: ``"pcd"``, ``"ply"``, ``"kitti"`` or ``"npy"`` (empty when built
            from arrays).
        organised_shape: ``(height, width)`` of an organised cloud (point ``(r, c)`` at
            index ``r * width + c``), or ``None``.

    Equality is identity (comparing arrays element-wise is left to the caller).
    """

    points: np.ndarray
    fields: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    path: str = ""
    format: str = ""
    organised_shape: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.path, (str, os.PathLike)):
            raise InputError(f"path: expected a str or os.PathLike, got {type(self.path).__name__}")
        path = os.fspath(self.path)
        suffix = f": {path}" if path else ""
        points = _checked_points(self.points, "points", suffix)
        count = points.shape[0]
        if not isinstance(self.fields, Mapping):
            raise InputError(
                f"fields: expected a mapping of name -> array, got {type(self.fields).__name__}"
                + suffix
            )
        fields = {
            name: _checked_field(name, value, count, suffix) for name, value in self.fields.items()
        }
        shape = self.organised_shape
        if shape is not None:
            if (
                not isinstance(shape, tuple)
                or len(shape) != 2
                or not all(isinstance(v, (int, np.integer)) and v >= 0 for v in shape)
            ):
                raise InputError(
                    f"organised_shape: expected None or (height, width) of ints >= 0, got "
                    f"{shape!r}" + suffix
                )
            shape = (int(shape[0]), int(shape[1]))
            if shape[0] * shape[1] != count:
                raise InputError(
                    f"organised_shape: expected height x width = {count} points, got "
                    f"{shape[0]}x{shape[1]}" + suffix
                )
        object.__setattr__(self, "points", points)
        object.__setattr__(self, "fields", fields)
        object.__setattr__(self, "path", path)
        object.__setattr__(self, "organised_shape", shape)

    def __len__(self) -> int:
        """Number of points N, NaN points included."""
        return int(self.points.shape[0])

    def finite_mask(self) -> np.ndarray:
        """``bool`` ``(N,)``: True where x, y and z are all finite (a real return)."""
        return np.isfinite(self.points).all(axis=1)


def read_cloud(path: PathLike, *, format: str | None = None) -> PointCloud:  # noqa: A002
    """Read a point cloud from a PCD, PLY, KITTI ``.bin`` or ``.npy`` file.

    Args:
        path: the file. Its format is recognised by its content (PLY, PCD, NumPy
            signatures) or else by its extension (:data:`CLOUD_EXTENSIONS`).
        format: one of :data:`CLOUD_FORMATS` to skip recognition (e.g. ``"kitti"`` for
            a velodyne scan named ``.dat``).

    Returns:
        A :class:`PointCloud`: ``float32`` ``(N, 3)`` points (NaN points kept) and the
        file's other per-point fields.

    Raises:
        FileFormatError: the file is missing, empty, of an unrecognised format,
            truncated, corrupt, or lacks x, y or z; the message names the problem and
            ends with the path.
        InputError: ``path`` is not a path, or ``format`` is not a known format.
    """
    if format is not None and format not in CLOUD_FORMATS:
        raise InputError(f"format: expected None or one of {list(CLOUD_FORMATS)}, got {format!r}")
    file_path = _as_path(path, "path")
    _check_readable_file(file_path, "point cloud")
    kind = format or _sniff_format(file_path)
    if kind == "npy":
        points, fields, shape = _read_npy(file_path)
    else:
        raw = _read_bytes(file_path, "point cloud")
        if kind == "pcd":
            points, fields, shape = _read_pcd(raw, file_path)
        elif kind == "ply":
            points, fields, shape = _read_ply(raw, file_path)
        else:
            points, fields, shape = _read_kitti(raw, file_path)
    try:
        return PointCloud(
            points=points,
            fields=fields,
            path=os.fspath(path),
            format=kind,
            organised_shape=shape,
        )
    except InputError as exc:  # e.g. a .npy field name that cannot be a header token
        raise FileFormatError(str(exc)) from exc


def write_pcd(
    path: PathLike,
    points: np.ndarray,
    fields: Mapping[str, np.ndarray] | None = None,
    binary: bool = True,
    compressed: bool = False,
) -> None:
    """Write a cloud as a PCD v0.7 file (``DATA binary``, ``DATA binary_compressed`` or
    ``DATA ascii``).

    x, y and z are written as ``F 4`` (``float32``; a ``float64`` input is rounded);
    each field keeps its dtype (``int8``..``uint64``, ``float32``, ``float64``); an
    ``(N, k)`` field is one PCD field with ``COUNT k``. ASCII numbers are the shortest
    text that reads back to the same value, NaN as ``nan``. The cloud is unorganised
    (``WIDTH N``, ``HEIGHT 1``) with the identity ``VIEWPOINT``.

    Args:
        path: the file to write (replaced if it exists).
        points: ``(N, 3)`` real array [m].
        fields: extra per-point arrays of shape ``(N,)`` or ``(N, k)``; names are single
            tokens other than ``x``, ``y``, ``z`` and ``_``.
        binary: ``True`` for ``DATA binary`` (little-endian), ``False`` for ``DATA ascii``.
        compressed: with ``binary``, ``DATA binary_compressed`` as PCL writes it: the
            fields one after another (all x, then all y, ...), LZF-compressed.

    Raises:
        InputError: ``path`` is not a path, ``points`` is not ``(N, 3)`` real, or a
            field has a bad name, length or dtype.
        OSError: the file cannot be written (missing folder, no permission, ...).
    """
    file_path = _as_path(path, "path")
    suffix = f": {file_path}"
    for name, flag in (("binary", binary), ("compressed", compressed)):
        if not isinstance(flag, (bool, np.bool_)):
            raise InputError(f"argument `{name}` must be True or False, got {flag!r:.40}{suffix}")
    if compressed and not binary:
        raise InputError(f"argument `compressed` needs binary=True (an ASCII PCD is not compressed){suffix}")
    xyz = _checked_points(points, "points", suffix)
    columns = _checked_fields_for_writing(fields, xyz.shape[0], suffix, ply=False)
    count = xyz.shape[0]
    names = ["x", "y", "z"] + [name for name, _ in columns]
    codes = ["f4"] * 3 + [array.dtype.str[1:] for _, array in columns]
    counts = [1, 1, 1] + [1 if array.ndim == 1 else array.shape[1] for _, array in columns]
    header = "\n".join(
        [
            "# .PCD v0.7 - Point Cloud Data file format (written by subterra)",
            "VERSION 0.7",
            "FIELDS " + " ".join(names),
            "SIZE " + " ".join(str(int(code[1])) for code in codes),
            "TYPE " + " ".join({"i": "I", "u": "U", "f": "F"}[code[0]] for code in codes),
            "COUNT " + " ".join(str(c) for c in counts),
            f"WIDTH {count}",
            "HEIGHT 1",
            f"VIEWPOINT {_PCD_IDENTITY_VIEWPOINT}",
            f"POINTS {count}",
            f"DATA {'ascii' if not binary else 'binary_compressed' if compressed else 'binary'}",
            "",
        ]
    ).encode("ascii")
    all_columns = [("x", xyz[:, 0]), ("y", xyz[:, 1]), ("z", xyz[:, 2])] + columns
    if compressed:
        plain = b"".join(np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<")).tobytes() for _, a in all_columns)
        packed = _lzf_compress(plain)
        body = np.array([len(packed), len(plain)], "<u4").tobytes() + packed
    else:
        body = _binary_records(all_columns, "<") if binary else _ascii_records(all_columns)
    with open_for_writing(file_path, "point cloud") as handle:
        handle.write(header)
        handle.write(body)


def write_ply(
    path: PathLike,
    points: np.ndarray,
    fields: Mapping[str, np.ndarray] | None = None,
    binary: bool = True,
) -> None:
    """Write a cloud as a PLY file with one ``vertex`` element and no faces.

    x, y and z are ``float`` (``float32``; a ``float64`` input is rounded); each field
    keeps its dtype (``int8``..``uint32``, ``float32``, ``float64``; PLY has no 64-bit
    integers). PLY properties are scalars, so an ``(N, k)`` field ``name`` is written
    as ``k`` properties ``name_0`` .. ``name_<k-1>`` and reads back as ``k`` fields.

    Args:
        path: the file to write (replaced if it exists).
        points: ``(N, 3)`` real array [m].
        fields: extra per-point arrays of shape ``(N,)`` or ``(N, k)``; names are single
            tokens other than ``x``, ``y`` and ``z``.
        binary: ``True`` for ``binary_little_endian 1.0``, ``False`` for ``ascii 1.0``.

    Raises:
        InputError: ``path`` is not a path, ``points`` is not ``(N, 3)`` real, or a
            field has a bad name, length or dtype.
        OSError: the file cannot be written (missing folder, no permission, ...).
    """
    file_path = _as_path(path, "path")
    suffix = f": {file_path}"
    xyz = _checked_points(points, "points", suffix)
    columns: list[tuple[str, np.ndarray]] = [("x", xyz[:, 0]), ("y", xyz[:, 1]), ("z", xyz[:, 2])]
    for name, array in _checked_fields_for_writing(fields, xyz.shape[0], suffix, ply=True):
        if array.ndim == 1:
            columns.append((name, array))
        else:
            columns.extend((f"{name}_{i}", array[:, i]) for i in range(array.shape[1]))
    seen: set[str] = set()
    for name, _ in columns:
        if name in seen:
            raise InputError(
                f"fields: expected unique PLY property names, got {name!r} twice (an (N, k) "
                f"field is written as name_0 .. name_<k-1>){suffix}"
            )
        seen.add(name)
    lines = [
        "ply",
        f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
        "comment written by subterra",
        f"element {_PLY_VERTEX} {xyz.shape[0]}",
    ]
    lines += [f"property {_PLY_NAMES_BY_CODE[a.dtype.str[1:]]} {n}" for n, a in columns]
    lines += ["end_header", ""]
    body = _binary_records(columns, "<") if binary else _ascii_records(columns)
    with open_for_writing(file_path, "point cloud") as handle:
        handle.write("\n".join(lines).encode("ascii"))
        handle.write(body)


# --------------------------------------------------------------------------- helpers


def _sniff_format(path: Path) -> str:
    head = _read_head(path, _SNIFF_BYTES, "point cloud")
    if head.startswith(_NPY_MAGIC):
        return "npy"
    if head[:3] == b"ply" and head[3:4] in (b"\n", b"\r"):
        return "ply"
    if head.startswith((b"# .PCD", b"VERSION", b"FIELDS")):
        return "pcd"
    by_extension = CLOUD_EXTENSIONS.get(path.suffix.lower())
    if by_extension is None:
        raise FileFormatError(
            f"point cloud: expected a PCD, PLY or .npy file (recognised by content) or the "
            f"extension {', '.join(CLOUD_EXTENSIONS)}, got {path.suffix or 'no extension'!r} "
            f"and content starting {head[:16]!r}: {path}"
        )
    return by_extension


def _checked_points(points: object, name: str, suffix: str) -> np.ndarray:
    if not isinstance(points, np.ndarray):
        raise InputError(
            f"{name}: expected a numpy.ndarray (N, 3), got {type(points).__name__}{suffix}"
        )
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"{name}: expected shape (N, 3), got {points.shape}{suffix}")
    if points.dtype.kind != "f":
        raise InputError(f"{name}: expected a float array [m], got dtype {points.dtype}{suffix}")
    # Checked on the view, before the copy: a broadcast view of 10^9 points is refused, not
    # materialised (the core's limit on one cloud).
    if points.shape[0] > MAX_WRITE_POINTS:
        raise InputError(
            f"{name}: {points.shape[0]} points, over the limit of {MAX_WRITE_POINTS}{suffix}"
        )
    with np.errstate(over="ignore"):  # beyond the float32 range: +-inf, not a warning
        return np.ascontiguousarray(points, dtype=np.float32)


def _checked_field(name: object, value: object, count: int, suffix: str) -> np.ndarray:
    if not isinstance(name, str) or not _FIELD_NAME.match(name):
        raise InputError(
            f"fields: expected names that are printable ASCII words without spaces, got "
            f"{name!r}{suffix}"
        )
    if name in _XYZ:
        raise InputError(f"fields[{name!r}]: x, y and z belong in points, not in fields{suffix}")
    if not isinstance(value, np.ndarray):
        raise InputError(
            f"fields[{name!r}]: expected a numpy.ndarray, got {type(value).__name__}{suffix}"
        )
    if value.ndim not in (1, 2) or value.shape[0] != count:
        raise InputError(
            f"fields[{name!r}]: expected shape ({count},) or ({count}, k), got {value.shape}"
            f"{suffix}"
        )
    if value.dtype.kind not in "biuf":
        raise InputError(f"fields[{name!r}]: expected a numeric dtype, got {value.dtype}{suffix}")
    return np.ascontiguousarray(value, dtype=value.dtype.newbyteorder("="))


def _checked_fields_for_writing(
    fields: Mapping[str, np.ndarray] | None, count: int, suffix: str, *, ply: bool
) -> list[tuple[str, np.ndarray]]:
    if fields is None:
        return []
    if not isinstance(fields, Mapping):
        raise InputError(
            f"fields: expected None or a mapping of name -> array, got {type(fields).__name__}"
            f"{suffix}"
        )
    allowed = set(_PLY_NAMES_BY_CODE) if ply else set(_PCD_TYPES.values())
    columns = []
    for name, value in fields.items():
        array = _checked_field(name, value, count, suffix)
        if name == _PCD_PADDING_FIELD and not ply:
            raise InputError(f"fields: '_' is PCD padding and would be dropped on reading{suffix}")
        code = array.dtype.str[1:]
        if array.dtype.kind == "b" or code not in allowed:
            kinds = (
                "int8, uint8, int16, uint16, int32, uint32, float32 or float64 (PLY has no "
                "64-bit integers)"
                if ply
                else "int8..int64, uint8..uint64, float32 or float64"
            )
            raise InputError(f"fields[{name!r}]: expected dtype {kinds}, got {array.dtype}{suffix}")
        if array.ndim == 2 and array.shape[1] == 0:
            raise InputError(
                f"fields[{name!r}]: expected (N, k) with k >= 1, got {array.shape}{suffix}"
            )
        columns.append((name, array))
    return columns


def _binary_records(columns: list[tuple[str, np.ndarray]], byte_order: str) -> bytes:
    """Interleave the columns into packed records (array of structs)."""
    count = columns[0][1].shape[0]
    dtype = np.dtype(
        [(f"f{i}", byte_order + a.dtype.str[1:], a.shape[1:]) for i, (_, a) in enumerate(columns)]
    )
    records = np.empty(count, dtype=dtype)
    for i, (_, array) in enumerate(columns):
        records[f"f{i}"] = array
    return records.tobytes()


def _ascii_records(columns: list[tuple[str, np.ndarray]]) -> bytes:
    """One line per point, values separated by spaces (shortest round-trip text)."""
    count = columns[0][1].shape[0]
    if count == 0:
        return b""
    texts: list[np.ndarray] = []
    for _, array in columns:
        parts = array.reshape(count, -1)
        texts.extend(parts[:, i].astype(str) for i in range(parts.shape[1]))
    line = texts[0]
    for text in texts[1:]:
        line = np.char.add(np.char.add(line, " "), text)
    return ("\n".join(line.tolist()) + "\n").encode("ascii")


def _xyz_from(columns: Mapping[str, np.ndarray], count: int) -> np.ndarray:
    points = np.empty((count, 3), dtype=np.float32)
    with np.errstate(over="ignore"):  # beyond the float32 range: +-inf, not a warning
        for axis, name in enumerate(_XYZ):
            points[:, axis] = columns[name]
    return points


def _own(array: np.ndarray) -> np.ndarray:
    """A C-contiguous, native-byte-order, writable copy."""
    return np.array(array, dtype=array.dtype.newbyteorder("="), order="C", copy=True)


# ------------------------------------------------------------------------------ PCD


@dataclasses.dataclass
class _PcdHeader:
    names: list[str]
    codes: list[str]  # NumPy type codes, e.g. "f4"
    counts: list[int]
    width: int
    height: int
    points: int
    data: str
    offset: int  # first byte of the data


def _read_pcd(raw: bytes, path: Path) -> tuple[np.ndarray, dict, tuple[int, int] | None]:
    header = _parse_pcd_header(raw, path)
    n = header.points
    if header.data == "ascii":
        columns = _pcd_ascii_columns(raw, header, path)
    elif header.data == "binary":
        columns = _pcd_binary_columns(raw, header, path)
    else:
        columns = _pcd_compressed_columns(raw, header, path)
    fields = {
        name: _own(array)
        for name, array in columns.items()
        if name not in _XYZ and name != _PCD_PADDING_FIELD
    }
    shape = (header.height, header.width) if header.height > 1 else None
    return _xyz_from(columns, n), fields, shape


def _parse_pcd_header(raw: bytes, path: Path) -> _PcdHeader:
    values: dict[str, list[str]] = {}
    pos = 0
    line_no = 0
    data_kind = None
    while data_kind is None:
        if pos >= len(raw):
            raise FileFormatError(
                f"PCD header: expected a 'DATA ascii|binary|binary_compressed' line, got end "
                f"of file after {line_no} lines (truncated header): {path}"
            )
        end = raw.find(b"\n", pos)
        end = len(raw) if end < 0 else end
        line_bytes = raw[pos:end].strip()
        line_no += 1
        pos = end + 1
        try:
            line = line_bytes.decode("ascii")
        except UnicodeDecodeError as exc:
            raise FileFormatError(
                f"PCD header line {line_no}: expected ASCII text, got byte "
                f"0x{line_bytes[exc.start]:02x} (not a PCD file?): {path}"
            ) from exc
        if not line.split() or line.startswith("#"):
            continue  # blank (str.split also counts the separators \x1c-\x1f as space) or a comment
        key, *args = line.split()
        if key not in (
            "VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT",
            "POINTS", "DATA",
        ):  # fmt: skip
            raise FileFormatError(
                f"PCD header line {line_no}: expected a keyword VERSION, FIELDS, SIZE, TYPE, "
                f"COUNT, WIDTH, HEIGHT, VIEWPOINT, POINTS or DATA, got {line[:40]!r}: {path}"
            )
        if key in values:
            raise FileFormatError(f"PCD header line {line_no}: {key} appears twice: {path}")
        if not args:
            raise FileFormatError(f"PCD header line {line_no}: {key} has no value: {path}")
        values[key] = args
        if key == "DATA":
            if len(args) != 1 or args[0] not in _PCD_DATA_KINDS:
                raise FileFormatError(
                    f"PCD header line {line_no}: expected DATA ascii, binary or "
                    f"binary_compressed, got {line[:60]!r}: {path}"
                )
            data_kind = args[0]
    offset = pos if pos <= len(raw) else len(raw)

    for key in ("FIELDS", "SIZE", "TYPE", "WIDTH"):
        if key not in values:
            raise FileFormatError(f"PCD header: missing the {key} line before DATA: {path}")
    names = values["FIELDS"]
    nfields = len(names)
    sizes = _pcd_ints(values["SIZE"], "SIZE", path)
    counts = _pcd_ints(values["COUNT"], "COUNT", path) if "COUNT" in values else [1] * nfields
    types = values["TYPE"]
    for key, items in (("SIZE", sizes), ("TYPE", types), ("COUNT", counts)):
        if len(items) != nfields:
            raise FileFormatError(
                f"PCD header: expected {nfields} {key} values (one per field in FIELDS "
                f"{' '.join(names)}), got {len(items)}: {path}"
            )
    codes = []
    for name, size, kind, count in zip(names, sizes, types, counts, strict=True):
        code = _PCD_TYPES.get((kind, size))
        if code is None:
            raise FileFormatError(
                f"PCD header: field {name!r} has TYPE {kind} SIZE {size}; expected TYPE I or U "
                f"with SIZE 1, 2, 4 or 8, or TYPE F with SIZE 4 or 8: {path}"
            )
        if count < 1:
            raise FileFormatError(
                f"PCD header: field {name!r} has COUNT {count}; expected >= 1: {path}"
            )
        codes.append(code)
    point_bytes = sum(size * count for size, count in zip(sizes, counts, strict=True))
    if point_bytes > _PCD_MAX_POINT_BYTES:
        raise FileFormatError(
            f"PCD header: expected a point record of at most {_PCD_MAX_POINT_BYTES} bytes, got "
            f"{point_bytes} (SIZE x COUNT summed; corrupt COUNT?): {path}"
        )
    named = [n for n in names if n != _PCD_PADDING_FIELD]
    if len(set(named)) != len(named):
        twice = sorted({n for n in named if named.count(n) > 1})
        raise FileFormatError(f"PCD header: field names {twice} appear twice in FIELDS: {path}")
    for axis in _XYZ:
        if axis not in names:
            raise FileFormatError(
                f"PCD header: expected fields x, y and z, got FIELDS {' '.join(names)}: {path}"
            )
        if counts[names.index(axis)] != 1:
            raise FileFormatError(
                f"PCD header: field {axis!r} has COUNT {counts[names.index(axis)]}; expected 1: "
                f"{path}"
            )
    width = _pcd_ints(values["WIDTH"], "WIDTH", path, single=True)[0]
    height = _pcd_ints(values.get("HEIGHT", ["1"]), "HEIGHT", path, single=True)[0]
    points = width * height
    if "POINTS" in values:
        declared = _pcd_ints(values["POINTS"], "POINTS", path, single=True)[0]
        if declared != points:
            raise FileFormatError(
                f"PCD header: expected POINTS = WIDTH x HEIGHT = {width}x{height} = {points}, "
                f"got POINTS {declared}: {path}"
            )
    if "VIEWPOINT" in values:
        viewpoint = values["VIEWPOINT"]
        try:
            numbers = [float(v) for v in viewpoint]
        except ValueError:
            numbers = []
        if len(numbers) != _PCD_VIEWPOINT_NUMBERS or not np.all(np.isfinite(numbers)):
            raise FileFormatError(
                f"PCD header: expected VIEWPOINT tx ty tz qw qx qy qz (7 finite numbers), got "
                f"{' '.join(viewpoint)[:80]!r}: {path}"
            )
    return _PcdHeader(names, codes, counts, width, height, points, data_kind, offset)


def _pcd_ints(items: list[str], key: str, path: Path, *, single: bool = False) -> list[int]:
    if single and len(items) != 1:
        raise FileFormatError(f"PCD header: expected one integer after {key}, got {items}: {path}")
    try:
        result = [int(item) for item in items]
    except ValueError:
        result = None
    if result is None or any(v < 0 for v in result):
        raise FileFormatError(
            f"PCD header: expected integers >= 0 after {key}, got {' '.join(items)[:80]!r}: {path}"
        )
    return result


def _pcd_record_dtype(header: _PcdHeader) -> np.dtype:
    return np.dtype(
        [
            (f"f{i}", "<" + code, (count,) if count > 1 else ())
            for i, (code, count) in enumerate(zip(header.codes, header.counts, strict=True))
        ]
    )


def _pcd_named(header: _PcdHeader, arrays: list[np.ndarray]) -> dict[str, np.ndarray]:
    return {
        name: array
        for name, array in zip(header.names, arrays, strict=True)
        if name != _PCD_PADDING_FIELD
    }


def _pcd_ascii_columns(raw: bytes, header: _PcdHeader, path: Path) -> dict[str, np.ndarray]:
    n = header.points
    per_point = sum(header.counts)
    tokens = raw[header.offset :].split()
    if len(tokens) != n * per_point:
        problem = "truncated file" if len(tokens) < n * per_point else "wrong header or extra data"
        raise FileFormatError(
            f"PCD ascii data: expected {n} points x {per_point} values = {n * per_point} "
            f"numbers, got {len(tokens)} ({problem}): {path}"
        )
    table = np.array(tokens, dtype=bytes).reshape(n, per_point)
    arrays = []
    column = 0
    for name, code, count in zip(header.names, header.codes, header.counts, strict=True):
        text = table[:, column] if count == 1 else table[:, column : column + count]
        column += count
        arrays.append(_parse_numbers(text, np.dtype(code), f"PCD ascii field {name!r}", path))
    return _pcd_named(header, arrays)


def _parse_numbers(text: np.ndarray, dtype: np.dtype, what: str, path: Path) -> np.ndarray:
    """Convert an array of ASCII tokens to ``dtype`` (vectorised, with a clear error)."""
    try:
        return text.astype(dtype)
    except (ValueError, OverflowError) as exc:
        kind = "numbers" if dtype.kind == "f" else f"integers that fit {dtype}"
        raise FileFormatError(f"{what}: expected {kind}, got {exc}: {path}") from exc


def _pcd_binary_columns(raw: bytes, header: _PcdHeader, path: Path) -> dict[str, np.ndarray]:
    dtype = _pcd_record_dtype(header)
    needed = header.points * dtype.itemsize
    available = len(raw) - header.offset
    if available < needed:
        raise FileFormatError(
            f"PCD binary data: expected {needed} bytes for {header.points} points of "
            f"{dtype.itemsize} bytes, got {available} (truncated file): {path}"
        )
    records = np.frombuffer(raw, dtype=dtype, count=header.points, offset=header.offset)
    return _pcd_named(header, [records[f"f{i}"] for i in range(len(header.names))])


def _pcd_compressed_columns(raw: bytes, header: _PcdHeader, path: Path) -> dict[str, np.ndarray]:
    start = header.offset
    if len(raw) - start < _PCD_COMPRESSED_SIZES_BYTES:
        raise FileFormatError(
            f"PCD binary_compressed data: expected two uint32 sizes after the header, got "
            f"{len(raw) - start} bytes (truncated file): {path}"
        )
    compressed, uncompressed = (int(v) for v in np.frombuffer(raw, "<u4", count=2, offset=start))
    point_size = _pcd_record_dtype(header).itemsize
    needed = header.points * point_size
    if uncompressed != needed:
        raise FileFormatError(
            f"PCD binary_compressed data: expected an uncompressed size of {needed} bytes "
            f"({header.points} points of {point_size} bytes), got {uncompressed} (corrupt "
            f"file or wrong header): {path}"
        )
    if uncompressed > compressed * _LZF_MAX_RATIO:
        raise FileFormatError(
            f"PCD binary_compressed data: an uncompressed size of {uncompressed} bytes cannot "
            f"come from {compressed} LZF bytes (at most {_LZF_MAX_RATIO}x; corrupt file or "
            f"wrong header): {path}"
        )
    start += _PCD_COMPRESSED_SIZES_BYTES
    available = len(raw) - start
    if available < compressed:
        raise FileFormatError(
            f"PCD binary_compressed data: expected {compressed} compressed bytes, got "
            f"{available} (truncated file): {path}"
        )
    data = _lzf_decompress_fast(raw[start : start + compressed], needed)
    if data is None and needed > _LZF_EXPLAIN_MAX_BYTES and _core_lzf_available():
        raise FileFormatError(
            f"PCD binary_compressed data: expected {compressed} LZF bytes that decompress to {needed} bytes, "
            f"got a corrupt stream (truncated, or a bad back-reference): {path}"
        )
    if data is None:  # corrupt: the NumPy decoder says where and why (or decodes it after all)
        source = np.frombuffer(raw, np.uint8, count=compressed, offset=start)
        data = _lzf_decompress(source, needed, "PCD binary_compressed data", path)
    # Decompressed layout is a struct of arrays: all values of field 0, then field 1, ...
    arrays = []
    pos = 0
    n = header.points
    for code, count in zip(header.codes, header.counts, strict=True):
        values = np.frombuffer(data, "<" + code, count=n * count, offset=pos)
        arrays.append(values.reshape(n, count) if count > 1 else values)
        pos += n * count * int(code[1])
    return _pcd_named(header, arrays)


def _lzf_decompress_fast(source: bytes, expected_size: int) -> bytes | None:
    """LZF-decompress with the core (the ``lzf`` crate, a port of liblzf): the bytes, or
    None when the stream is corrupt or of another size (or the core is not built: the
    NumPy decoder then does the work)."""
    try:
        from subterra._core import lzf_decompress
    except ImportError:
        return None
    return lzf_decompress(bytes(source), int(expected_size))


def _core_lzf_available() -> bool:
    try:
        from subterra._core import lzf_decompress  # noqa: F401
    except ImportError:
        return False
    return True


def _lzf_compress(data: bytes) -> bytes:
    """LZF-compress with the core; data LZF cannot shrink is stored as literal runs (a valid
    LZF stream, 1/32 larger), as liblzf readers accept."""
    try:
        from subterra._core import lzf_compress
    except ImportError:  # no core: literal runs only
        def lzf_compress(_: bytes) -> None:
            return None
    packed = lzf_compress(data) if data else b""
    if packed is not None:
        return packed
    raw = np.frombuffer(data, np.uint8)
    runs = -(-raw.size // _LZF_LITERAL_LIMIT)
    out = np.zeros((runs, _LZF_LITERAL_LIMIT + 1), np.uint8)
    padded = np.zeros(runs * _LZF_LITERAL_LIMIT, np.uint8)
    padded[: raw.size] = raw
    out[:, 0] = _LZF_LITERAL_LIMIT - 1
    out[:, 1:] = padded.reshape(runs, _LZF_LITERAL_LIMIT)
    last = raw.size - (runs - 1) * _LZF_LITERAL_LIMIT
    out[-1, 0] = last - 1
    return out.reshape(-1)[: (runs - 1) * (_LZF_LITERAL_LIMIT + 1) + 1 + last].tobytes()


def _lzf_decompress(source: np.ndarray, expected_size: int, what: str, path: Path) -> bytes:
    """Decompress an LZF stream with NumPy only (no per-byte Python loop): the reader's
    fallback that explains a corrupt stream (the core decodes the good ones, about 100x
    faster).

    Two sequential dependencies are resolved by pointer doubling, each in O(log)
    vectorised passes:

    1. Token boundaries: every byte position gets the position of the next token if a
       token started there; the chain from position 0 is found by repeated squaring of
       that jump table.
    2. Back-references: every output byte points at the earlier output byte it copies
       (itself for a literal byte); following the pointers to a literal byte by doubling
       handles overlapping copies (runs) as well.

    Cost: O(L log L) NumPy work; peak memory about 25 bytes per output byte (a few
    integer arrays the size of the output). A 107k-point Ouster scan (2.4 MB
    uncompressed) decodes in about 0.3 s.
    """
    n = int(source.size)
    if n == 0:
        if expected_size == 0:
            return b""
        raise FileFormatError(
            f"{what}: expected LZF data for {expected_size} bytes, got 0 compressed bytes: {path}"
        )
    index = np.int32 if max(n, expected_size) < 2**31 - 2 else np.int64
    ctrl = source.astype(index)
    is_literal = ctrl < _LZF_LITERAL_LIMIT
    is_long = (ctrl >> 5) == _LZF_LONG_REF
    step = np.where(is_literal, ctrl + 2, np.where(is_long, 3, 2)).astype(index)
    end, overrun = n, n + 1  # absorbing states: exactly at the end / past the end
    jump = np.empty(n + 2, dtype=index)
    jump[:n] = np.arange(n, dtype=index) + step
    jump[:n][jump[:n] > n] = overrun
    jump[end], jump[overrun] = end, overrun

    chain = np.zeros(1, dtype=index)  # positions jump^m(0), m < 2^k
    while chain[-1] < end:
        chain = np.concatenate([chain, jump[chain]])
        if chain[-1] >= end:
            break
        jump = jump[jump]
    del jump
    if (chain == overrun).any():
        raise FileFormatError(
            f"{what}: expected complete LZF tokens, got a token running past the last of "
            f"{n} compressed bytes (truncated or corrupt): {path}"
        )
    starts = np.unique(chain[chain < end])
    del chain

    c = ctrl[starts]
    literal = is_literal[starts]
    b1 = ctrl[np.minimum(starts + 1, n - 1)]
    b2 = ctrl[np.minimum(starts + 2, n - 1)]
    long_ref = ~literal & is_long[starts]
    ref_len = np.where(long_ref, _LZF_LONG_REF + b1, c >> 5) + _LZF_MIN_REF_LEN
    out_len = np.where(literal, c + 1, ref_len)
    distance = ((c & 0x1F) << 8) + np.where(long_ref, b2, b1) + 1
    out_end = np.cumsum(out_len, dtype=np.int64)
    total = int(out_end[-1])
    if total != expected_size:
        raise FileFormatError(
            f"{what}: expected {expected_size} bytes after LZF decompression, got {total} "
            f"(corrupt file): {path}"
        )
    out_start = (out_end - out_len).astype(index)
    bad = ~literal & (distance > out_start)
    if bad.any():
        at = int(starts[np.argmax(bad)])
        raise FileFormatError(
            f"{what}: expected LZF back-references inside the output, got one before its "
            f"start (token at compressed byte {at}; corrupt file): {path}"
        )
    byte_literal = np.repeat(literal, out_len)
    back = np.repeat(np.where(literal, 0, distance).astype(index), out_len)
    pointer = np.arange(total, dtype=index) - back
    del back
    pending = np.flatnonzero(~byte_literal).astype(index)
    while pending.size:
        pointer[pending] = pointer[pointer[pending]]
        pending = pending[~byte_literal[pointer[pending]]]
    # A literal output byte j of a token starting at compressed byte s copies byte
    # s + 1 + (j - out_start).
    shift = np.repeat((starts + 1 - out_start).astype(index), out_len)
    return source[pointer + shift[pointer]].tobytes()


# ------------------------------------------------------------------------------ PLY
# Why not plyfile (1.1.5, measured): fed the bytes already read (io.BytesIO, so that the
# file checks stay here) it cannot memory-map and reads every record of every element in
# a Python loop: 11.7 s for 1M binary points that this reader takes in 23 ms, 1.8 s for
# 200k ASCII points (0.42 s here), 1.8 s to skip 400k triangles (5 ms here). It sizes
# np.empty by the header's counts before reading (a lying count: MemoryError or
# ValueError), accepts trailing data and extra ASCII lines, and its errors lack the line,
# the counts and the byte positions that these messages give; the checks around it would
# keep most of this code.


@dataclasses.dataclass
class _PlyProperty:
    name: str
    code: str  # NumPy type code of a scalar, or of the list items
    count_code: str | None  # NumPy type code of the list length; None for a scalar


@dataclasses.dataclass
class _PlyElement:
    name: str
    count: int
    properties: list[_PlyProperty]


def _read_ply(raw: bytes, path: Path) -> tuple[np.ndarray, dict, None]:
    encoding, elements, offset = _parse_ply_header(raw, path)
    vertex_index = next((i for i, e in enumerate(elements) if e.name == _PLY_VERTEX), None)
    if vertex_index is None:
        names = [e.name for e in elements]
        raise FileFormatError(
            f"PLY header: expected a 'vertex' element, got elements {names}: {path}"
        )
    vertex = elements[vertex_index]
    names = [p.name for p in vertex.properties]
    for prop in vertex.properties:
        if prop.count_code is not None:
            raise FileFormatError(
                f"PLY header: vertex property {prop.name!r} is a list; expected scalar vertex "
                f"properties (list properties on vertex are not supported): {path}"
            )
    if len(set(names)) != len(names):
        twice = sorted({n for n in names if names.count(n) > 1})
        raise FileFormatError(f"PLY header: vertex properties {twice} appear twice: {path}")
    for axis in _XYZ:
        if axis not in names:
            raise FileFormatError(
                f"PLY header: expected vertex properties x, y and z, got {names}: {path}"
            )
    before = elements[:vertex_index]
    after = elements[vertex_index + 1 :]
    declared = _ply_declared(elements)
    if encoding == "ascii":
        columns = _ply_ascii_vertices(raw, offset, before, vertex, after, declared, path)
    else:
        byte_order = _PLY_ENCODINGS[encoding]
        for element in before:
            offset = _ply_skip_binary(raw, offset, element, byte_order, path, "before the vertices", declared)
        columns, end = _ply_binary_vertices(raw, offset, vertex, byte_order, declared, path)
        # The elements after the vertices must fill the rest of the file: a vertex count
        # that is too large reads faces as vertices, one too small leaves data over.
        for element in after:
            end = _ply_skip_binary(raw, end, element, byte_order, path, "after the vertices", declared)
        left = len(raw) - end
        if raw[end:].strip(_PLY_TRAILING_SPACE):
            raise FileFormatError(
                f"PLY binary data: {left} bytes after the last element the header declares "
                f"({declared}): a wrong element count or trailing garbage: {path}"
            )
    fields = {name: _own(array) for name, array in columns.items() if name not in _XYZ}
    return _xyz_from(columns, vertex.count), fields, None


def _parse_ply_header(raw: bytes, path: Path) -> tuple[str, list[_PlyElement], int]:
    if raw[:3] != b"ply" or raw[3:4] not in (b"\n", b"\r"):
        raise FileFormatError(
            f"PLY header: expected the magic line 'ply', got {raw[:16]!r} (not a PLY file): {path}"
        )
    encoding = None
    elements: list[_PlyElement] = []
    pos = 0
    line_no = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise FileFormatError(
                f"PLY header: expected 'end_header', got end of file after {line_no} lines "
                f"(truncated header): {path}"
            )
        line_bytes = raw[pos:end].strip()
        line_no += 1
        pos = end + 1
        try:
            line = line_bytes.decode("ascii")
        except UnicodeDecodeError as exc:
            raise FileFormatError(
                f"PLY header line {line_no}: expected ASCII text, got byte "
                f"0x{line_bytes[exc.start]:02x}: {path}"
            ) from exc
        words = line.split()
        if line_no == 1 or not words or words[0] in ("comment", "obj_info"):
            continue
        key = words[0]
        if key == "end_header":
            break
        if key == "format":
            if len(words) != 3 or words[1] not in _PLY_ENCODINGS or words[2] != "1.0":
                raise FileFormatError(
                    f"PLY header line {line_no}: expected 'format ascii|binary_little_endian|"
                    f"binary_big_endian 1.0', got {line[:60]!r}: {path}"
                )
            if encoding is not None:
                raise FileFormatError(f"PLY header line {line_no}: format appears twice: {path}")
            encoding = words[1]
        elif key == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise FileFormatError(
                    f"PLY header line {line_no}: expected 'element <name> <count >= 0>', got "
                    f"{line[:60]!r}: {path}"
                )
            elements.append(_PlyElement(words[1], int(words[2]), []))
        elif key == "property":
            if not elements:
                raise FileFormatError(
                    f"PLY header line {line_no}: expected an element line before "
                    f"{line[:60]!r}: {path}"
                )
            elements[-1].properties.append(_ply_property(words, line, line_no, path))
        else:
            raise FileFormatError(
                f"PLY header line {line_no}: expected format, element, property, comment, "
                f"obj_info or end_header, got {line[:60]!r}: {path}"
            )
    if encoding is None:
        raise FileFormatError(f"PLY header: missing the 'format' line: {path}")
    return encoding, elements, pos


def _ply_property(words: list[str], line: str, line_no: int, path: Path) -> _PlyProperty:
    if len(words) == 3 and words[1] in _PLY_TYPES:
        return _PlyProperty(words[2], _PLY_TYPES[words[1]], None)
    if (
        len(words) == 5
        and words[1] == "list"
        and words[2] in _PLY_TYPES
        and words[3] in _PLY_TYPES
        and _PLY_TYPES[words[2]][0] in "iu"
    ):
        return _PlyProperty(words[4], _PLY_TYPES[words[3]], _PLY_TYPES[words[2]])
    raise FileFormatError(
        f"PLY header line {line_no}: expected 'property <type> <name>' or 'property list "
        f"<integer type> <type> <name>' with types {', '.join(list(_PLY_TYPES)[:8])}, got "
        f"{line[:60]!r}: {path}"
    )


def _ply_declared(elements: list[_PlyElement]) -> str:
    """The element counts of a header, for messages: ``"vertex 8, face 12"``."""
    return ", ".join(f"{e.name} {e.count}" for e in elements)


def _ply_ascii_vertices(
    raw: bytes,
    offset: int,
    before: list[_PlyElement],
    vertex: _PlyElement,
    after: list[_PlyElement],
    declared: str,
    path: Path,
) -> dict[str, np.ndarray]:
    skip = sum(element.count for element in before)
    n = vertex.count
    nprops = len(vertex.properties)
    have = raw.count(b"\n", offset) + 1
    # One line per element instance: counts beyond the lines the file has are a lie (and
    # may exceed what split() takes: the header's counts are arbitrary integers).
    lines = raw[offset:].split(b"\n", skip + n) if skip + n <= have else []
    vertex_lines = lines[skip : skip + n]
    if len(vertex_lines) < n:
        raise FileFormatError(
            f"PLY ascii data: expected {skip} lines of earlier elements and {n} vertex "
            f"lines, got {min(len(lines), have) if lines else have} lines (truncated file): {path}"
        )
    tokens = b" ".join(vertex_lines).split()
    if len(tokens) != n * nprops:
        raise FileFormatError(
            f"PLY ascii data: expected {n} vertex lines of {nprops} values = {n * nprops} "
            f"numbers, got {len(tokens)} (truncated file or wrong header): {path}"
        )
    # One line per element instance: the lines after the vertices must be exactly those
    # of the later elements. A vertex count that is too large reads face lines as
    # vertices (and leaves too few lines for the faces); one too small leaves lines over.
    rest = lines[skip + n].rstrip() if len(lines) > skip + n else b""
    rest_lines = rest.count(b"\n") + 1 if rest else 0
    expected_rest = sum(element.count for element in after)
    if rest_lines != expected_rest:
        total = skip + n + expected_rest
        raise FileFormatError(
            f"PLY ascii data: the header declares {total} element lines ({declared}), got "
            f"{skip + n + rest_lines} (a wrong element count, a truncated file or trailing "
            f"garbage): {path}"
        )
    table = np.array(tokens, dtype=bytes).reshape(n, nprops)
    return {
        p.name: _parse_numbers(table[:, i], np.dtype(p.code), f"PLY vertex {p.name!r}", path)
        for i, p in enumerate(vertex.properties)
    }


def _ply_binary_vertices(
    raw: bytes, offset: int, vertex: _PlyElement, byte_order: str, declared: str, path: Path
) -> tuple[dict[str, np.ndarray], int]:
    """The vertex columns and the offset just after them."""
    dtype = np.dtype([(f"f{i}", byte_order + p.code) for i, p in enumerate(vertex.properties)])
    needed = vertex.count * dtype.itemsize
    available = len(raw) - offset
    if available < needed:
        raise FileFormatError(
            f"PLY binary data: expected {needed} bytes for {vertex.count} vertices of "
            f"{dtype.itemsize} bytes, got {available} (truncated file, or a vertex count "
            f"larger than the data; the header declares {declared}): {path}"
        )
    records = np.frombuffer(raw, dtype=dtype, count=vertex.count, offset=offset)
    return {p.name: records[f"f{i}"] for i, p in enumerate(vertex.properties)}, offset + needed


def _ply_skip_binary(
    raw: bytes,
    offset: int,
    element: _PlyElement,
    byte_order: str,
    path: Path,
    place: str = "before the vertices",
    declared: str = "",
) -> int:
    """The offset just after ``element``'s data (which may hold list properties)."""
    available = len(raw) - offset
    header = f"; the header declares {declared}" if declared else ""
    truncated = FileFormatError(
        f"PLY binary data: expected {element.count} {element.name!r} records {place}, got "
        f"{available} bytes that end inside them (truncated file, or an element count "
        f"larger than the data{header}): {path}"
    )
    if all(p.count_code is None for p in element.properties):
        size = sum(int(p.code[1]) for p in element.properties)
        if element.count * size > available:
            raise truncated
        return offset + element.count * size
    if element.count == 0:
        return offset
    if element.count > available:  # a record with a list holds at least its length byte
        raise truncated
    uniform_end = _ply_skip_uniform(raw, offset, element, byte_order)
    if uniform_end is not None:
        return uniform_end
    # Records have variable size. For every byte position compute where a record
    # starting there would end (vectorised), then jump `count` records from position 0
    # by repeated squaring of that table.
    data = np.frombuffer(raw, np.uint8, offset=offset)
    overrun = available + 1
    ends = np.arange(available + 2, dtype=np.int64)
    inside = ends <= available
    for prop in element.properties:
        if prop.count_code is None:
            ends = ends + int(prop.code[1])
        else:
            size = int(prop.count_code[1])
            ok = inside & (ends + size <= available)
            lengths = _ply_list_lengths(data, np.where(ok, ends, 0), prop.count_code, byte_order)
            ok &= lengths >= 0
            ends = np.where(ok, ends + size + lengths * int(prop.code[1]), overrun)
        inside = ends <= available
        ends = np.where(inside, ends, overrun)
    ends[overrun] = overrun
    position, jump, remaining = 0, ends, element.count
    while remaining:
        if remaining & 1:
            position = int(jump[position])
        remaining >>= 1
        if remaining:
            jump = jump[jump]
    if position >= overrun or position > available:
        raise truncated
    return offset + position


def _ply_skip_uniform(raw: bytes, offset: int, element: _PlyElement, byte_order: str) -> int | None:
    """The end of ``element``'s data if every record has the lists of the first one
    (a triangle mesh), else None. Needs memory for a boolean per record only."""
    names, formats, offsets, lengths = [], [], [], []
    pos = offset
    for i, prop in enumerate(element.properties):
        if prop.count_code is None:
            pos += int(prop.code[1])
            continue
        size = int(prop.count_code[1])
        if pos + size > len(raw):
            return None
        length = int.from_bytes(
            raw[pos : pos + size], "little" if byte_order == "<" else "big", signed=prop.count_code[0] == "i"
        )
        if length < 0:
            return None
        names.append(f"n{i}")
        formats.append(byte_order + prop.count_code)
        offsets.append(pos - offset)
        lengths.append(length)
        pos += size + length * int(prop.code[1])
    record = pos - offset
    if element.count * record > len(raw) - offset:
        return None
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": record})
    records = np.frombuffer(raw, dtype=dtype, count=element.count, offset=offset)
    if all(bool((records[name] == length).all()) for name, length in zip(names, lengths)):
        return offset + element.count * record
    return None


def _ply_list_lengths(data: np.ndarray, at: np.ndarray, code: str, byte_order: str) -> np.ndarray:
    """The list lengths (type ``code``) stored at byte positions ``at`` of ``data``."""
    size = int(code[1])
    value = np.zeros(at.shape, dtype=np.int64)
    padded = np.concatenate([data, np.zeros(size, np.uint8)])
    for k in range(size):
        shift = 8 * (k if byte_order == "<" else size - 1 - k)
        value |= padded[at + k].astype(np.int64) << shift
    if code[0] == "i":
        sign = 1 << (8 * size - 1)
        value = (value ^ sign) - sign
    return value


# ---------------------------------------------------------------------- KITTI / npy


def _read_kitti(raw: bytes, path: Path) -> tuple[np.ndarray, dict, None]:
    if len(raw) % _KITTI_RECORD_BYTES:
        raise FileFormatError(
            f"KITTI .bin: expected a multiple of {_KITTI_RECORD_BYTES} bytes (float32 x, y, z, "
            f"intensity per point), got {len(raw)} (truncated, or not a velodyne scan): {path}"
        )
    table = np.frombuffer(raw, dtype="<f4").reshape(-1, _KITTI_COLUMNS)
    points = np.array(table[:, :3], dtype=np.float32, order="C", copy=True)
    return points, {"intensity": _own(table[:, 3])}, None


def _read_npy(path: Path) -> tuple[np.ndarray, dict, tuple[int, int] | None]:
    head = _read_head(path, len(_NPY_MAGIC), "point cloud")
    if head != _NPY_MAGIC:
        raise FileFormatError(
            f"cloud .npy: expected the NumPy magic {_NPY_MAGIC!r}, got {head!r} (not a .npy "
            f"file): {path}"
        )
    try:
        # Memory-mapping checks the header's shape against the file size before any data
        # is read, so a truncated file fails without allocating the full array.
        array = np.load(path, mmap_mode="r", allow_pickle=False)
        try:
            return _cloud_from_array(array, path)
        finally:
            del array
    except FileFormatError:
        raise
    except Exception as exc:  # NumPy reports bad headers with several exception types
        raise FileFormatError(
            f"cloud .npy: expected a valid .npy file, got a corrupt or truncated one "
            f"({type(exc).__name__}: {exc}): {path}"
        ) from exc


def _cloud_from_array(
    array: np.ndarray, path: Path
) -> tuple[np.ndarray, dict, tuple[int, int] | None]:
    names = array.dtype.names
    if names is not None:
        if array.ndim not in (1, 2):
            raise FileFormatError(
                f"cloud .npy: expected a structured array of shape (N,) or (H, W), got "
                f"{array.shape}: {path}"
            )
        missing = [axis for axis in _XYZ if axis not in names]
        if missing:
            raise FileFormatError(
                f"cloud .npy: expected structured fields x, y and z, got {list(names)}: {path}"
            )
        for name in names:
            if array.dtype[name].base.kind not in "biuf":
                raise FileFormatError(
                    f"cloud .npy: expected numeric fields, got {name!r} of dtype "
                    f"{array.dtype[name]}: {path}"
                )
        shape = (int(array.shape[0]), int(array.shape[1])) if array.ndim == 2 else None
        flat = array.reshape(-1)
        columns = {name: flat[name] for name in names}
        for axis in _XYZ:
            if columns[axis].ndim != 1 or columns[axis].dtype.kind not in "iuf":
                raise FileFormatError(
                    f"cloud .npy: expected real scalar fields x, y, z, got {axis!r} of dtype "
                    f"{array.dtype[axis]}: {path}"
                )
        count = flat.shape[0]
        fields = {
            name: _own(a.reshape(count, -1) if a.ndim > 2 else a)
            for name, a in columns.items()
            if name not in _XYZ
        }
        return _xyz_from(columns, count), fields, shape
    if array.dtype.kind != "f":
        raise FileFormatError(
            f"cloud .npy: expected a float array of x, y, z [m] (or a structured array), "
            f"got dtype {array.dtype}: {path}"
        )
    if array.ndim not in (2, 3) or array.shape[-1] < 3:
        raise FileFormatError(
            f"cloud .npy: expected shape (N, C) or (H, W, C) with C >= 3 (x, y, z first), "
            f"got {array.shape}: {path}"
        )
    shape = (int(array.shape[0]), int(array.shape[1])) if array.ndim == 3 else None
    table = array.reshape(-1, array.shape[-1])
    with np.errstate(over="ignore"):  # beyond the float32 range: +-inf, not a warning
        points = np.array(table[:, :3], dtype=np.float32, order="C", copy=True)
    fields = {f"column{i}": _own(table[:, i]) for i in range(3, table.shape[1])}
    return points, fields, shape
