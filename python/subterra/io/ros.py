"""ROS messages <-> NumPy: images, camera info, point clouds, odometry and transforms.

The decoders take a decoded message object as the readers of :mod:`subterra.io.recordings`
return it (``rosbags`` dataclasses), or any object with the same attributes (ROS 1 and
ROS 2 spellings both work: ``K`` / ``k``, ``secs`` / ``sec``), and return NumPy arrays
in the library's conventions (docs/conventions.md):

* :func:`decode_image`: ``sensor_msgs/Image`` -> ``(H, W)`` or ``(H, W, C)`` array in
  native byte order; :func:`decode_depth_image` -> a :class:`~subterra.io.DepthImage`
  (``16UC1`` / ``mono16``: ``uint16`` with a scale, default 0.001 m per unit; ``32FC1``:
  ``float32`` metres). The ``is_bigendian`` flag and row padding (``step`` larger than
  ``width x pixel size``) are honoured.
* :func:`decode_camera_info`: ``sensor_msgs/CameraInfo`` -> :class:`~subterra.io.Intrinsics`
  (``K``, falling back to ``P`` when ``K`` is all zero; binning and ROI applied);
  ``.to_camera()`` gives a ``subterra.PinholeCamera``.
* :func:`decode_pointcloud2`: ``sensor_msgs/PointCloud2`` with any field layout (any
  order, gaps and trailing padding in ``point_step``, padded rows, big- or little-endian,
  ``count > 1``, organised ``height > 1``) -> :class:`CloudMessage`: ``float32`` ``(N, 3)``
  xyz and the other fields as separate arrays; points with a non-finite x, y or z are
  dropped and counted (``dropped``), their original indices kept (``index``).
* :func:`decode_odometry`: ``nav_msgs/Odometry`` -> :class:`OdometrySample`
  (``world_from_body`` 4x4, 6x6 pose covariance, body-frame twist).
* :func:`decode_transforms` and :class:`TransformBuffer`: ``tf2_msgs/TFMessage`` from
  ``/tf`` and ``/tf_static`` -> ``target_from_source`` lookups (static chains such as
  ``body_from_sensor``, and time-interpolated poses).

The encoders (:func:`image_message`, :func:`camera_info_message`,
:func:`pointcloud2_message`, :func:`odometry_message`, :func:`tf_message`) build the
same messages from arrays as ``rosbags`` message objects of a typestore (default ROS 2
Humble), ready for :func:`subterra.io.recordings.write_bag` or
:class:`subterra.io.recordings.McapWriter`; they need the ``rosbags`` package, the
decoders do not. Rotations (quaternion <-> matrix, the slerp of :class:`TransformBuffer`)
are SciPy's ``scipy.spatial.transform.Rotation``, imported on first use: decoding
odometry and tf, and encoding any pose, needs SciPy (the ``io`` and ``ros`` extras bring
it).

Every decoder names what it decodes in its errors (``where=``, e.g. the topic and the
stamp) so that a bad message in a recording is easy to find: a message whose arrays
do not match its header is a :class:`~subterra.errors.FileFormatError`, an encoding
the decoder does not handle an :class:`~subterra.errors.InputError`.
"""

from __future__ import annotations

import bisect
import dataclasses
import functools
import math
import numbers
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from .._extras import require
from ..errors import FileFormatError, InputError, SubterraError
from .depth import DEFAULT_UINT16_SCALE_M_PER_UNIT, DepthImage
from .intrinsics import Intrinsics

__all__ = [
    "DEPTH_ENCODINGS",
    "IMAGE_ENCODINGS",
    "POINTFIELD_DATATYPES",
    "CloudMessage",
    "OdometrySample",
    "TransformBuffer",
    "camera_info_message",
    "decode_camera_info",
    "decode_depth_image",
    "decode_image",
    "decode_odometry",
    "decode_pointcloud2",
    "decode_transforms",
    "default_typestore",
    "header",
    "image_message",
    "matrix_from_quaternion",
    "odometry_message",
    "pointcloud2_message",
    "quaternion_from_matrix",
    "stamp_ns",
    "belief_markers_message",
    "clock_message",
    "diagnostics_message",
    "grid_map_message",
    "occupancy_grid_message",
    "occupancy_values",
    "path_message",
    "pose_stamped_message",
    "tf_message",
    "time_message",
    "twist_message",
    "twist_stamped_message",
]

#: ``sensor_msgs/Image`` encodings :func:`decode_image` reads -> (NumPy type code, channels).
IMAGE_ENCODINGS: dict[str, tuple[str, int]] = {
    "mono8": ("u1", 1),
    "8UC1": ("u1", 1),
    "8SC1": ("i1", 1),
    "mono16": ("u2", 1),
    "16UC1": ("u2", 1),
    "16SC1": ("i2", 1),
    "32SC1": ("i4", 1),
    "32FC1": ("f4", 1),
    "64FC1": ("f8", 1),
    "rgb8": ("u1", 3),
    "bgr8": ("u1", 3),
    "rgba8": ("u1", 4),
    "bgra8": ("u1", 4),
    "8UC3": ("u1", 3),
    "8UC4": ("u1", 4),
    "rgb16": ("u2", 3),
    "bgr16": ("u2", 3),
    "16UC3": ("u2", 3),
}

#: Encodings that :func:`decode_depth_image` turns into depth: ``uint16`` raw units
#: (``16UC1``, ``mono16``; the REP 118 depth image is ``16UC1`` millimetres) or
#: ``float32`` metres (``32FC1``).
DEPTH_ENCODINGS: tuple[str, ...] = ("16UC1", "mono16", "32FC1")
# (type code, big-endian) -> dtype, built once: np.dtype() per image costs more than the view.
_IMAGE_DTYPES = {(code, big): np.dtype((">" if big else "<") + code) for code, _ in IMAGE_ENCODINGS.values() for big in (False, True)}

#: ``sensor_msgs/PointField`` datatype -> NumPy type code (without byte order).
POINTFIELD_DATATYPES: dict[int, str] = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
_POINTFIELD_BY_CODE = {code: datatype for datatype, code in POINTFIELD_DATATYPES.items()}

# Field names that only mark padding (PCL writes "_" for it); they are skipped.
_PADDING_FIELD_NAMES = ("", "_")
_XYZ = ("x", "y", "z")
_NS_PER_S = 1_000_000_000

#: How far a :class:`TransformBuffer` lookup may reach past a dynamic transform's first
#: or last sample and still take that sample [ns] (one 10 Hz tf period).
DEFAULT_EXTRAPOLATION_NS = 100_000_000

# A tf quaternion is a rotation when | |q|^2 - 1 | is below this (tf2's
# QUATERNION_NORMALIZATION_TOLERANCE: it rejects the transform otherwise).
_QUATERNION_NORM2_TOLERANCE = 1e-2
# A TransformBuffer rotation is rigid when max |R^T R - I| is below this and det R > 0.
_ROTATION_TOLERANCE = 1e-3
# The largest translation a TransformBuffer takes [m]: the core's limit for poses (1000 km from
# the origin; beyond it a value is corrupt, or geographic coordinates that must be re-centred).
_MAX_TRANSLATION_M = 1e6


# --------------------------------------------------------------------------- small helpers


def _where(where: str) -> str:
    return f" ({where})" if where else ""


def _get(msg: Any, *names: str, where: str = "", kind: str = "message") -> Any:
    """The first attribute of ``names`` that ``msg`` has (ROS 1 / ROS 2 spellings)."""
    for name in names:
        if hasattr(msg, name):
            return getattr(msg, name)
    raise InputError(f"{kind}: expected a field {names[0]!r}, got a {type(msg).__name__} without it{_where(where)}")


def _decoder(kind: str):
    """Decorates a ``decode_*`` function: a message whose fields do not match ``kind``
    (a field missing, a value that is not a number: a recording whose embedded schema
    was edited or belongs to another type) raises a :class:`FileFormatError` naming
    ``kind``, the field and the ``where`` of the call, instead of an AttributeError
    or a TypeError from deep inside the decoder."""

    def wrap(fn):
        @functools.wraps(fn)
        def decode(msg: Any, *args: Any, where: str = "", **kwargs: Any):
            try:
                return fn(msg, *args, where=where, **kwargs)
            except SubterraError:
                raise
            except AttributeError as exc:
                field = getattr(exc, "name", None) or str(exc)
                raise FileFormatError(
                    f"{kind}: the message has no field {field!r} (a message of another type, or a "
                    f"schema that does not match {kind}){_where(where)}"
                ) from exc
            except (TypeError, ValueError, OverflowError) as exc:
                raise FileFormatError(
                    f"{kind}: a field does not hold the value {kind} defines ({exc}){_where(where)}"
                ) from exc

        return decode

    return wrap


def stamp_ns(msg_or_header_or_time: Any) -> int:
    """Nanoseconds of a ``Time`` (``sec``/``nanosec`` or ROS 1 ``secs``/``nsecs``), of a
    ``Header`` (its ``stamp``) or of a message with a header."""
    t = msg_or_header_or_time
    if hasattr(t, "header"):
        t = t.header
    if hasattr(t, "stamp"):
        t = t.stamp
    sec = _get(t, "sec", "secs", kind="stamp")
    nsec = _get(t, "nanosec", "nsecs", "nsec", kind="stamp")
    return int(sec) * _NS_PER_S + int(nsec)


def _frame_id(msg: Any) -> str:
    return str(getattr(getattr(msg, "header", None), "frame_id", "") or "")


def _bytes_of(data: Any, where: str, kind: str) -> np.ndarray:
    """A message's ``uint8[]`` payload as a 1-D ``uint8`` array (no copy when possible)."""
    if isinstance(data, np.ndarray):
        if data.dtype != np.uint8:
            data = np.ascontiguousarray(data).view(np.uint8)
        return data if data.ndim == 1 else data.reshape(-1)
    if isinstance(data, (bytes, bytearray, memoryview)):
        return np.frombuffer(data, dtype=np.uint8)
    try:
        return np.asarray(data, dtype=np.uint8).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{kind}: expected the data as bytes or a uint8 array, got {type(data).__name__}{_where(where)}") from exc


def _rotation() -> Any:
    """SciPy's ``Rotation`` class (imported on first use: the core needs NumPy only)."""
    return _transform_module().Rotation


@functools.lru_cache(maxsize=1)
def _transform_module() -> Any:
    return require("scipy.spatial.transform", "io", "Quaternion and rotation conversions")


def matrix_from_quaternion(x: float, y: float, z: float, w: float, where: str = "") -> np.ndarray:
    """The 3x3 rotation of a quaternion (normalised first); a zero or non-finite
    quaternion is an :class:`InputError`. Needs SciPy (the ``io`` extra)."""
    q = np.array([x, y, z, w], dtype=np.float64)
    n = float(np.linalg.norm(q))
    if not (math.isfinite(n) and n > 1e-9):
        raise InputError(f"quaternion: expected a finite, non-zero (x, y, z, w), got {tuple(q.tolist())}{_where(where)}")
    return _rotation().from_quat(q / n).as_matrix()


def _rotations_of(matrices: np.ndarray, what: str) -> Any:
    """A ``Rotation`` of a 3x3 matrix or an ``(N, 3, 3)`` stack (SciPy takes the nearest
    rotation of a slightly non-orthogonal one); a non-finite matrix or a reflection is an
    InputError."""
    if not np.all(np.isfinite(matrices)):
        raise InputError(f"{what}: expected a finite rotation matrix, got NaN or inf")
    try:
        return _rotation().from_matrix(matrices)
    except ValueError as exc:  # det <= 0: a reflection or a degenerate matrix
        det = float(np.min(np.linalg.det(matrices)))
        raise InputError(f"{what}: expected a rotation matrix (det R > 0), got det {det:.3g}") from exc


def quaternion_from_matrix(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """``(x, y, z, w)`` of a 3x3 rotation matrix (or the rotation of a 4x4 pose), with
    w >= 0. Needs SciPy (the ``io`` extra).

    Raises:
        InputError: the matrix is not finite, or not a rotation (det R <= 0).
    """
    m = np.asarray(rotation, dtype=np.float64)[:3, :3]
    x, y, z, w = _rotations_of(m, "rotation").as_quat(canonical=True).tolist()
    return float(x), float(y), float(z), float(w)


def _pose_matrix(position: Any, orientation: Any, where: str) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = matrix_from_quaternion(orientation.x, orientation.y, orientation.z, orientation.w, where)
    t[:3, 3] = (position.x, position.y, position.z)
    if not np.all(np.isfinite(t)):
        raise InputError(f"pose: expected a finite position, got {t[:3, 3].tolist()}{_where(where)}")
    return t


# --------------------------------------------------------------------------- images


@_decoder("sensor_msgs/Image")
def decode_image(msg: Any, *, where: str = "") -> np.ndarray:
    """The pixels of a ``sensor_msgs/Image`` as an ``(H, W)`` (one channel) or ``(H, W, C)``
    array of the encoding's dtype in native byte order (a view of the message's bytes
    when possible).

    Raises:
        InputError: the encoding is not one of :data:`IMAGE_ENCODINGS` (compressed and
            Bayer images are not decoded); the message names it.
        FileFormatError: ``step`` or the data size does not match width x height.
    """
    encoding = str(_get(msg, "encoding", where=where, kind="image"))
    if encoding not in IMAGE_ENCODINGS:
        raise InputError(
            f"image: unknown encoding {encoding!r}, expected one of {', '.join(IMAGE_ENCODINGS)}{_where(where)}"
        )
    code, channels = IMAGE_ENCODINGS[encoding]
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    dtype = _IMAGE_DTYPES[code, bool(getattr(msg, "is_bigendian", 0))]
    row_bytes = width * channels * dtype.itemsize
    raw = _bytes_of(msg.data, where, "image")
    if step < row_bytes:
        raise FileFormatError(
            f"image: step {step} B is shorter than a row of {width} px x {channels * dtype.itemsize} B = {row_bytes} B{_where(where)}"
        )
    needed = (height - 1) * step + row_bytes if height else 0
    if raw.size < needed:
        raise FileFormatError(
            f"image: {raw.size} B of data for {width}x{height} {encoding} with step {step} (needs {needed} B){_where(where)}"
        )
    if height == 0 or width == 0:
        shape = (height, width) if channels == 1 else (height, width, channels)
        return np.zeros(shape, dtype=dtype.newbyteorder("="))
    if step == row_bytes:
        pixels = raw[: height * row_bytes]
    else:  # padded rows: take the first row_bytes of each
        rows = np.lib.stride_tricks.as_strided(raw, shape=(height, row_bytes), strides=(step, 1))
        pixels = np.ascontiguousarray(rows).reshape(-1)
    image = pixels.view(dtype)
    if not image.flags.aligned:  # a ROS 1 or MCAP payload can start at any byte
        image = pixels.copy().view(dtype)
    image = image.reshape((height, width) if channels == 1 else (height, width, channels))
    if not dtype.isnative:
        image = image.astype(dtype.newbyteorder("="))
    return image


@_decoder("sensor_msgs/Image")
def decode_depth_image(msg: Any, *, scale: float | None = None, where: str = "") -> DepthImage:
    """A depth ``sensor_msgs/Image`` as a :class:`~subterra.io.DepthImage`.

    ``16UC1`` / ``mono16``: ``uint16`` raw units, ``scale`` metres per unit (default
    0.001, REP 118 millimetres); ``32FC1``: ``float32`` metres (``scale`` must be None).

    Raises:
        InputError: any other encoding (the message lists :data:`DEPTH_ENCODINGS`), or a
            ``scale`` with ``32FC1``.
        FileFormatError: the data does not match the header.
    """
    encoding = str(_get(msg, "encoding", where=where, kind="image"))
    if encoding not in DEPTH_ENCODINGS:
        raise InputError(
            f"depth image: unknown encoding {encoding!r}, expected one of {', '.join(DEPTH_ENCODINGS)} "
            f"(uint16 raw units or float32 metres){_where(where)}"
        )
    data = decode_image(msg, where=where)
    if data.dtype == np.float32:
        if scale is not None:
            raise InputError(f"scale: a 32FC1 depth image is in metres, got scale {scale!r}{_where(where)}")
        scale = 1.0
    elif scale is None:
        scale = DEFAULT_UINT16_SCALE_M_PER_UNIT
    else:
        return DepthImage(data, scale, where)  # the scale is the caller's: check it
    if data.size == 0 or not data.flags.c_contiguous:
        return DepthImage(data, scale, where)  # refuses the empty image, copies a strided one
    # decode_image gave a native (H, W) uint16 / float32 array: the replay's per-message path.
    return DepthImage._trusted(data, scale, where)


@_decoder("sensor_msgs/CameraInfo")
def decode_camera_info(msg: Any, *, where: str = "") -> Intrinsics:
    """The pinhole intrinsics of a ``sensor_msgs/CameraInfo`` of the image it describes.

    fx, fy, cx, cy come from ``K`` (``k`` in ROS 2), or from ``P`` when ``K`` is all zero
    (some drivers fill only ``P``). Binning (``binning_x``/``binning_y`` > 1) and a
    region of interest are applied as ROS's ``image_geometry`` does, so the result
    matches the published image. Distortion (``D``) is not applied: subterra's camera
    is an ideal pinhole (depth images from RGB-D drivers are already undistorted).

    Raises:
        FileFormatError: ``K`` and ``P`` hold no focal length, or values are not finite.
    """
    k = np.asarray(_get(msg, "k", "K", where=where, kind="camera info"), dtype=np.float64).reshape(-1)
    p = np.asarray(_get(msg, "p", "P", where=where, kind="camera info"), dtype=np.float64).reshape(-1)
    if k.size == 9 and k[0] > 0 and k[4] > 0:
        fx, fy, cx, cy = k[0], k[4], k[2], k[5]
    elif p.size == 12 and p[0] > 0 and p[5] > 0:
        fx, fy, cx, cy = p[0], p[5], p[2], p[6]
    else:
        raise FileFormatError(f"camera info: K and P hold no positive focal length (K = {k.tolist()}){_where(where)}")
    width, height = int(msg.width), int(msg.height)
    roi = getattr(msg, "roi", None)
    if roi is not None and int(getattr(roi, "width", 0)) > 0 and int(getattr(roi, "height", 0)) > 0:
        cx, cy = cx - int(roi.x_offset), cy - int(roi.y_offset)
        width, height = int(roi.width), int(roi.height)
    bx = max(int(getattr(msg, "binning_x", 0) or 0), 1)
    by = max(int(getattr(msg, "binning_y", 0) or 0), 1)
    fx, cx, width = fx / bx, cx / bx, width // bx
    fy, cy, height = fy / by, cy / by, height // by
    values = (fx, fy, cx, cy)
    if not all(math.isfinite(v) for v in values):
        raise FileFormatError(f"camera info: non-finite intrinsics {values}{_where(where)}")
    try:
        return Intrinsics(float(fx), float(fy), float(cx), float(cy), width, height)
    except InputError as exc:
        raise FileFormatError(f"camera info: {exc}{_where(where)}") from exc


# --------------------------------------------------------------------------- point clouds


@dataclasses.dataclass(frozen=True, eq=False)
class CloudMessage:
    """A decoded ``sensor_msgs/PointCloud2``.

    Attributes:
        points: C-contiguous ``float32`` ``(N, 3)`` x, y, z [m] in ``frame_id``; only
            finite points (unless decoded with ``drop_invalid=False``).
        fields: the other fields by name, each ``(N,)`` (or ``(N, count)``) in native
            byte order, in the message's dtype, for the same points.
        frame_id: the header's frame.
        stamp_ns: the header's stamp [ns].
        width, height: the message's layout (``height > 1``: an organised cloud).
        dropped: points dropped because x, y or z was NaN or infinite.
        index: ``int64`` ``(N,)`` position of each kept point in the message
            (``row * width + column``), or None when nothing was dropped.
        is_dense: the message's ``is_dense`` flag, as sent (not trusted: the points are
            always checked).
    """

    points: np.ndarray
    fields: dict[str, np.ndarray]
    frame_id: str
    stamp_ns: int
    width: int
    height: int
    dropped: int
    index: np.ndarray | None
    is_dense: bool

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def to_point_cloud(self):
        """The kept points as a :class:`subterra.io.PointCloud` (unorganised)."""
        from .clouds import PointCloud

        return PointCloud(points=self.points, fields=dict(self.fields), path=self.frame_id, format="")


def _cloud_dtype(msg: Any, point_step: int, order: str, where: str) -> np.dtype:
    names: list[str] = []
    formats: list[Any] = []
    offsets: list[int] = []
    sizes: list[int] = []
    for f in msg.fields:
        name = str(f.name)
        if name in _PADDING_FIELD_NAMES:
            continue
        datatype, count, offset = int(f.datatype), int(f.count), int(f.offset)
        if datatype not in POINTFIELD_DATATYPES:
            raise FileFormatError(f"point cloud: field {name!r} has unknown datatype {datatype} (expected 1-8){_where(where)}")
        if name in names:
            raise FileFormatError(f"point cloud: field {name!r} appears twice{_where(where)}")
        count = max(count, 1)  # count 0 is written by some drivers for scalars
        code = order + POINTFIELD_DATATYPES[datatype]
        size = np.dtype(code).itemsize * count
        if offset < 0 or offset + size > point_step:
            raise FileFormatError(
                f"point cloud: field {name!r} at offset {offset} with {size} B does not fit in point_step {point_step}{_where(where)}"
            )
        names.append(name)
        formats.append(code if count == 1 else (code, (count,)))
        offsets.append(offset)
        sizes.append(size)
    # NumPy accepts overlapping fields; a PointCloud2 whose fields share bytes is corrupt.
    spans = sorted(zip(offsets, sizes, names))
    for (start_a, size_a, name_a), (start_b, _, name_b) in zip(spans, spans[1:]):
        if start_b < start_a + size_a:
            raise FileFormatError(
                f"point cloud: field {name_b!r} at offset {start_b} overlaps field {name_a!r} "
                f"(bytes {start_a}..{start_a + size_a - 1}){_where(where)}"
            )
    missing = [a for a in _XYZ if a not in names]
    if missing:
        raise FileFormatError(
            f"point cloud: no field {', '.join(missing)} (fields: {', '.join(names) or 'none'}){_where(where)}"
        )
    for axis in _XYZ:
        sub = formats[names.index(axis)]
        if isinstance(sub, tuple):
            raise FileFormatError(f"point cloud: field {axis!r} has count > 1{_where(where)}")
    try:
        return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})
    except (ValueError, TypeError) as exc:  # overlapping fields
        raise FileFormatError(f"point cloud: bad field layout: {exc}{_where(where)}") from exc


@_decoder("sensor_msgs/PointCloud2")
def decode_pointcloud2(
    msg: Any, *, drop_invalid: bool = True, fields: Iterable[str] | None = None, where: str = ""
) -> CloudMessage:
    """x, y, z and the other fields of a ``sensor_msgs/PointCloud2``.

    Any field layout is read: fields in any order with gaps between them and padding at
    the end of ``point_step``; rows padded to ``row_step``; big-endian data
    (``is_bigendian``); fields with ``count > 1`` (an ``(N, count)`` array); fields named
    ``_`` or ``""`` (padding) are skipped. x, y and z may be any PointField type and come
    back as ``float32``.

    With ``drop_invalid`` (the default) points whose x, y or z is NaN or infinite are
    dropped and counted (``dropped``); their indices in the message are in ``index``.
    ``is_dense`` is not trusted: every point is checked.

    ``fields`` names the extra fields to return (None: all of them; ``()``: none, the
    fastest when only the points are needed); a name the message lacks is an
    :class:`InputError` listing the fields it has.

    Raises:
        FileFormatError: x, y or z is missing; a field has an unknown datatype, does not
            fit in ``point_step`` or overlaps another; ``row_step`` is shorter than
            ``width x point_step``; the data is shorter than ``height x row_step``.
    """
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    order = ">" if int(getattr(msg, "is_bigendian", 0) or 0) else "<"
    frame_id, stamp = _frame_id(msg), stamp_ns(msg)
    if point_step <= 0 and width * height > 0:
        raise FileFormatError(f"point cloud: point_step is {point_step} for {width}x{height} points{_where(where)}")
    dtype = _cloud_dtype(msg, max(point_step, 1), order, where)
    wanted = None if fields is None else set(fields)
    if wanted is not None and not wanted <= set(dtype.names):
        missing = sorted(wanted - set(dtype.names))
        raise InputError(f"fields: the cloud has no field {', '.join(missing)} (fields: {', '.join(dtype.names)}){_where(where)}")
    raw = _bytes_of(msg.data, where, "point cloud")
    n = width * height
    if row_step < width * point_step:
        raise FileFormatError(
            f"point cloud: row_step {row_step} B is shorter than width {width} x point_step {point_step} B{_where(where)}"
        )
    needed = (height - 1) * row_step + width * point_step if n else 0
    if raw.size < needed:
        raise FileFormatError(
            f"point cloud: {raw.size} B of data for {width}x{height} points of {point_step} B with row_step "
            f"{row_step} (needs {needed} B): truncated message{_where(where)}"
        )
    if n == 0:
        empty = np.zeros((0, 3), np.float32)
        extra = {
            name: np.zeros((0, *dtype[name].shape), dtype[name].base.newbyteorder("="))
            for name in dtype.names
            if name not in _XYZ and (wanted is None or name in wanted)
        }
        return CloudMessage(empty, extra, frame_id, stamp, width, height, 0, None, bool(getattr(msg, "is_dense", True)))
    if row_step == width * point_step or height == 1:
        body = raw[: n * point_step]
    else:
        rows = np.lib.stride_tricks.as_strided(raw, shape=(height, width * point_step), strides=(row_step, 1))
        body = np.ascontiguousarray(rows).reshape(-1)
    records = np.frombuffer(body, dtype=dtype, count=n)
    points = _xyz(body, records, dtype, n, point_step, order)
    extra: dict[str, np.ndarray] = {}
    for name in dtype.names:
        if name in _XYZ or (wanted is not None and name not in wanted):
            continue
        column = records[name]
        extra[name] = column.astype(column.dtype.newbyteorder("="), copy=True) if not column.dtype.isnative else np.ascontiguousarray(column)
    dropped, index = 0, None
    if drop_invalid and not np.isfinite(points).all():  # the whole-array test is ~50x faster than per row
        finite = np.isfinite(points[:, 0]) & np.isfinite(points[:, 1]) & np.isfinite(points[:, 2])
        index = np.flatnonzero(finite)
        dropped = n - int(index.size)
        points = np.ascontiguousarray(points[index])
        extra = {k: np.ascontiguousarray(v[index]) for k, v in extra.items()}
    return CloudMessage(points, extra, frame_id, stamp, width, height, dropped, index, bool(getattr(msg, "is_dense", False)))


def _xyz(body: np.ndarray, records: np.ndarray, dtype: np.dtype, n: int, point_step: int, order: str) -> np.ndarray:
    """``float32`` ``(n, 3)`` xyz; one strided copy when x, y, z are consecutive float32."""
    offs = [dtype.fields[a][1] for a in _XYZ]
    types = [dtype.fields[a][0] for a in _XYZ]
    if (
        all(t.kind == "f" and t.itemsize == 4 for t in types)
        and offs[1] == offs[0] + 4
        and offs[2] == offs[0] + 8
        and point_step % 4 == 0
        and offs[0] % 4 == 0
    ):
        floats = body[: n * point_step].view(order + "f4").reshape(n, point_step // 4)
        first = offs[0] // 4
        return np.array(floats[:, first : first + 3], dtype=np.float32, order="C")  # a fresh, aligned copy
    out = np.empty((n, 3), np.float32)
    for i, axis in enumerate(_XYZ):
        out[:, i] = records[axis]
    return out


# --------------------------------------------------------------------------- odometry and tf


@dataclasses.dataclass(frozen=True, eq=False)
class OdometrySample:
    """A decoded ``nav_msgs/Odometry``.

    Attributes:
        stamp_ns: the header's stamp [ns].
        frame_id: the world (odometry) frame, e.g. ``odom``.
        child_frame_id: the body frame, e.g. ``base_link``.
        world_from_body: ``float64`` 4x4 pose of the body in the world [m].
        covariance: ``float64`` 6x6 pose covariance (x, y, z, roll, pitch, yaw) [m², rad²].
        twist: ``float64`` (6,) linear [m/s] and angular [rad/s] velocity in the body frame.
    """

    stamp_ns: int
    frame_id: str
    child_frame_id: str
    world_from_body: np.ndarray
    covariance: np.ndarray
    twist: np.ndarray


@_decoder("nav_msgs/Odometry")
def decode_odometry(msg: Any, *, where: str = "") -> OdometrySample:
    """A ``nav_msgs/Odometry`` as an :class:`OdometrySample`.

    Raises:
        InputError: the pose is not finite or its quaternion is zero.
        FileFormatError: the covariance does not hold 36 values.
    """
    pose = msg.pose.pose
    world_from_body = _pose_matrix(pose.position, pose.orientation, where)
    cov = np.asarray(msg.pose.covariance, dtype=np.float64).reshape(-1)
    if cov.size != 36:
        raise FileFormatError(f"odometry: pose covariance holds {cov.size} values, expected 36{_where(where)}")
    tw = msg.twist.twist
    twist = np.array([tw.linear.x, tw.linear.y, tw.linear.z, tw.angular.x, tw.angular.y, tw.angular.z], dtype=np.float64)
    return OdometrySample(stamp_ns(msg), _frame_id(msg), str(msg.child_frame_id), world_from_body, cov.reshape(6, 6), twist)


@_decoder("tf2_msgs/TFMessage")
def decode_transforms(msg: Any, *, where: str = "") -> list[tuple[str, str, int, np.ndarray]]:
    """``(parent, child, stamp_ns, parent_from_child)`` for each transform of a
    ``tf2_msgs/TFMessage`` (ROS 1 ``tf/tfMessage`` too).

    Raises:
        InputError: a rotation quaternion is not a unit quaternion (``| |q|^2 - 1 |``
            over 0.01, which tf2 rejects too) or a value is not finite; the message names
            the frames.
    """
    out = []
    for t in msg.transforms:
        tr = t.transform
        q = (float(tr.rotation.x), float(tr.rotation.y), float(tr.rotation.z), float(tr.rotation.w))
        norm2 = math.fsum(v * v for v in q)
        if not (math.isfinite(norm2) and abs(norm2 - 1.0) <= _QUATERNION_NORM2_TOLERANCE):
            raise InputError(
                f"transform {t.header.frame_id} -> {t.child_frame_id}: expected a unit rotation quaternion "
                f"(x, y, z, w), got {q} of norm {math.sqrt(norm2) if math.isfinite(norm2) else norm2:.6g}{_where(where)}"
            )
        m = np.eye(4)
        m[:3, :3] = matrix_from_quaternion(*q, where=where)
        m[:3, 3] = (tr.translation.x, tr.translation.y, tr.translation.z)
        if not np.all(np.isfinite(m)):
            raise InputError(f"transform {t.header.frame_id} -> {t.child_frame_id}: not finite{_where(where)}")
        out.append((_strip(t.header.frame_id), _strip(t.child_frame_id), stamp_ns(t), m))
    return out


def _checked_rigid(value: Any, label: str) -> np.ndarray:
    """A copy of ``value`` as a finite rigid 4x4 ``float64`` transform, or an InputError."""
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{label}: expected a 4x4 matrix of numbers, got {type(value).__name__}") from exc
    # Checked before the cast: a complex matrix would lose its imaginary part with a warning.
    if raw.dtype.kind not in "iuf":
        raise InputError(f"{label}: expected a 4x4 matrix of real numbers, got dtype {raw.dtype}")
    # The shape on the view, before the copy: a broadcast stack of 10^9 poses costs nothing.
    if raw.shape != (4, 4):
        raise InputError(f"{label}: expected shape (4, 4), got {raw.shape}")
    m = np.array(raw, dtype=np.float64)
    if not np.isfinite(m).all():
        raise InputError(f"{label}: expected finite values, got NaN or inf")
    if np.abs(m[3] - (0.0, 0.0, 0.0, 1.0)).max() > 1e-9:
        raise InputError(f"{label}: expected the bottom row 0 0 0 1, got {m[3].tolist()}")
    rotation = m[:3, :3]
    error = float(np.abs(rotation.T @ rotation - np.eye(3)).max())
    if error > _ROTATION_TOLERANCE:
        raise InputError(
            f"{label}: expected a rotation (orthonormal), got max |R^T R - I| = {error:.3g} "
            f"(over {_ROTATION_TOLERANCE:g}; a scale, a shear or a corrupt value)"
        )
    det = float(np.linalg.det(rotation))
    if det <= 0.0:
        raise InputError(f"{label}: expected a rotation with det +1, got det {det:.3g} (a reflection)")
    reach = float(np.abs(m[:3, 3]).max())
    if reach > _MAX_TRANSLATION_M:
        raise InputError(
            f"{label}: expected a translation within {_MAX_TRANSLATION_M:g} m, got {m[:3, 3].tolist()}"
        )
    return m


def _checked_stamp(value: Any, label: str) -> int:
    """``value`` as an int of nanoseconds in [0, :data:`MAX_STAMP_NS`], or an InputError
    naming ``stamp_ns`` and ``label``."""
    try:
        return _encoder_stamp(value, "stamp_ns")
    except InputError as exc:
        raise InputError(f"{exc} ({label})") from None


def _strip(frame: str) -> str:
    """tf frame names without the ROS 1 leading slash (``/base_link`` == ``base_link``)."""
    return str(frame).lstrip("/")


class TransformBuffer:
    """The transforms of ``/tf_static`` and ``/tf`` (and poses from odometry), for lookups.

    Static transforms hold at every time. A dynamic edge keeps its samples sorted by
    stamp; a lookup at time ``t`` interpolates between the two samples around ``t``
    (linear in translation, spherical-linear in rotation) and takes the first or last
    sample up to ``max_extrapolation_ns`` outside them. Frames are a tree: each child has
    one parent (a second parent for the same child replaces the first, as in tf2).

    Example: ``buf.add_message(tf_static_msg, static=True)``, then
    ``buf.lookup("base_link", "os_lidar")`` is ``body_from_sensor`` and
    ``buf.lookup("odom", "base_link", stamp_ns)`` the pose at a stamp.
    """

    def __init__(self, max_extrapolation_ns: int = DEFAULT_EXTRAPOLATION_NS, max_history_ns: int | None = None) -> None:
        """Raises:
        InputError: ``max_extrapolation_ns`` or ``max_history_ns`` (when given) is not an
            integer in [0, :data:`MAX_STAMP_NS`] [ns]; the message names the argument.
        """
        self.max_extrapolation_ns = _encoder_stamp(max_extrapolation_ns, "max_extrapolation_ns")
        #: A dynamic edge forgets samples this much older than its newest (None: keeps all;
        #: a live node keeps a few seconds so that it runs for days in bounded memory).
        self.max_history_ns = None if max_history_ns is None else _encoder_stamp(max_history_ns, "max_history_ns")
        self._parent: dict[str, str] = {}
        self._static: dict[str, np.ndarray] = {}
        self._stamps: dict[str, list[int]] = {}
        self._poses: dict[str, list[np.ndarray]] = {}

    @property
    def frames(self) -> list[str]:
        """Every frame named so far, sorted."""
        return sorted(set(self._parent) | set(self._parent.values()))

    def is_static(self, child: str) -> bool:
        return child in self._static

    def add(
        self,
        parent: str,
        child: str,
        parent_from_child: np.ndarray,
        *,
        stamp_ns: int = 0,
        static: bool = False,
        where: str = "",
    ) -> None:
        """Adds one transform ``parent_from_child`` (4x4) at ``stamp_ns``.

        Raises:
            InputError: the parent is the child; ``parent_from_child`` is not a finite
                rigid transform (rotation orthonormal within 1e-3 with det +1, bottom row
                ``0 0 0 1``, translation within 1e6 m); ``stamp_ns`` is not an integer in
                [0, :data:`MAX_STAMP_NS`]. The message names the argument and the frames.
        """
        parent, child = _strip(parent), _strip(child)
        if parent == child:
            raise InputError(f"transform: parent and child are both {parent!r}{_where(where)}")
        label = f"parent_from_child (transform {parent!r} -> {child!r}{', ' + where if where else ''})"
        m = _checked_rigid(parent_from_child, label)
        stamp_ns = _checked_stamp(stamp_ns, label)
        if self._parent.get(child, parent) != parent:  # re-parented: forget the old edge
            self._static.pop(child, None)
            self._stamps.pop(child, None)
            self._poses.pop(child, None)
        self._parent[child] = parent
        if static:
            self._static[child] = m
            return
        stamps = self._stamps.setdefault(child, [])
        poses = self._poses.setdefault(child, [])
        i = bisect.bisect_right(stamps, stamp_ns)
        if i and stamps[i - 1] == stamp_ns:
            poses[i - 1] = m
            return
        stamps.insert(i, int(stamp_ns))
        poses.insert(i, m)
        if self.max_history_ns is not None and stamps[-1] - stamps[0] > self.max_history_ns:
            keep = bisect.bisect_left(stamps, stamps[-1] - self.max_history_ns)
            del stamps[:keep], poses[:keep]

    def add_message(self, msg: Any, *, static: bool, where: str = "") -> int:
        """Adds every transform of a ``TFMessage``; returns how many."""
        items = decode_transforms(msg, where=where)
        for parent, child, stamp, m in items:
            self.add(parent, child, m, stamp_ns=stamp, static=static, where=where)
        return len(items)

    def _edge(self, child: str, stamp: int | None) -> np.ndarray | None:
        if child in self._static:
            return self._static[child]
        stamps, poses = self._stamps.get(child), self._poses.get(child)
        if not stamps:
            return None
        if stamp is None:
            return poses[-1]
        i = bisect.bisect_left(stamps, stamp)
        if i < len(stamps) and stamps[i] == stamp:
            return poses[i]
        if i == 0:
            return poses[0] if stamps[0] - stamp <= self.max_extrapolation_ns else None
        if i == len(stamps):
            return poses[-1] if stamp - stamps[-1] <= self.max_extrapolation_ns else None
        a = (stamp - stamps[i - 1]) / (stamps[i] - stamps[i - 1])
        return interpolate_pose(poses[i - 1], poses[i], a)

    def _chain(self, frame: str) -> list[str]:
        chain = [frame]
        seen = {frame}
        while chain[-1] in self._parent:
            nxt = self._parent[chain[-1]]
            if nxt in seen:  # a loop: stop
                break
            chain.append(nxt)
            seen.add(nxt)
        return chain

    def can_transform(self, target: str, source: str, stamp_ns: int | None = None) -> bool:
        try:
            self.lookup(target, source, stamp_ns)
        except InputError:
            return False
        return True

    def lookup(self, target: str, source: str, stamp_ns: int | None = None) -> np.ndarray:
        """``target_from_source`` (4x4) at ``stamp_ns`` (None: static edges and the newest
        sample of dynamic ones).

        Raises:
            InputError: the frames are not connected, or a dynamic edge on the way has no
                sample within ``max_extrapolation_ns`` of ``stamp_ns``; the message lists the
                frames known. ``stamp_ns`` is not None or an integer in [0,
                :data:`MAX_STAMP_NS`].
        """
        if stamp_ns is not None:
            stamp_ns = _encoder_stamp(stamp_ns, "stamp_ns")
        target, source = _strip(target), _strip(source)
        if target == source:
            return np.eye(4)
        up_source, up_target = self._chain(source), self._chain(target)
        common = next((f for f in up_source if f in set(up_target)), None)
        if common is None:
            known = ", ".join(self.frames) or "none"
            raise InputError(f"transform: no chain of transforms from {source!r} to {target!r}; frames known: {known}")

        def to_root(chain: list[str]) -> np.ndarray:
            m = np.eye(4)
            for child in chain[: chain.index(common)]:
                edge = self._edge(child, stamp_ns)
                if edge is None:
                    raise InputError(
                        f"transform: {self._parent[child]!r} -> {child!r} has no sample near t = {stamp_ns} ns "
                        f"(within {self.max_extrapolation_ns / 1e9:g} s)"
                    )
                m = edge @ m
            return m

        common_from_source = to_root(up_source)
        common_from_target = to_root(up_target)
        return np.linalg.inv(common_from_target) @ common_from_source

    def static_only(self, target: str, source: str) -> bool:
        """True if every edge between the two frames is static."""
        target, source = _strip(target), _strip(source)
        up_s, up_t = self._chain(source), self._chain(target)
        common = next((f for f in up_s if f in set(up_t)), None)
        if common is None:
            return False
        edges = up_s[: up_s.index(common)] + up_t[: up_t.index(common)]
        return all(e in self._static for e in edges)


def interpolate_pose(a: np.ndarray, b: np.ndarray, fraction: float) -> np.ndarray:
    """The pose ``fraction`` of the way from ``a`` to ``b`` (4x4): linear translation,
    slerp rotation (the shorter way round). Needs SciPy (the ``io`` extra).

    Raises:
        InputError: ``fraction`` is not finite, or a rotation is not finite or not a
            rotation (det R <= 0).
    """
    if not math.isfinite(fraction):
        raise InputError(f"fraction: expected a finite number, got {fraction!r}")
    ends = _rotations_of(np.stack([np.asarray(a, np.float64)[:3, :3], np.asarray(b, np.float64)[:3, :3]]), "pose")
    # Slerp's own formula (ra * exp(f * log(ra^-1 rb))) without its [0, 1] range check, so
    # that a fraction outside [0, 1] extrapolates as before.
    start = ends[0]
    step = (start.inv() * ends[1]).as_rotvec()
    out = np.eye(4)
    out[:3, :3] = (start * _rotation().from_rotvec(fraction * step)).as_matrix()
    out[:3, 3] = (1 - fraction) * a[:3, 3] + fraction * b[:3, 3]
    return out


class PoseTrack:
    """Poses over time (from odometry), interpolated at a stamp like a tf edge."""

    def __init__(self, max_extrapolation_ns: int = DEFAULT_EXTRAPOLATION_NS, max_history_ns: int | None = None) -> None:
        self._buffer = TransformBuffer(max_extrapolation_ns, max_history_ns)

    def add(self, stamp: int, world_from_body: np.ndarray) -> None:
        self._buffer.add("world", "body", world_from_body, stamp_ns=stamp)

    def __len__(self) -> int:
        return len(self._buffer._stamps.get("body", []))

    def at(self, stamp: int) -> np.ndarray | None:
        """``world_from_body`` at ``stamp`` [ns], or None when no sample is near."""
        return self._buffer._edge("body", stamp)

    @property
    def first(self) -> np.ndarray | None:
        poses = self._buffer._poses.get("body")
        return poses[0] if poses else None

    @property
    def latest(self) -> tuple[int, np.ndarray] | None:
        """The newest sample ``(stamp_ns, world_from_body)``, or None."""
        stamps, poses = self._buffer._stamps.get("body"), self._buffer._poses.get("body")
        return (stamps[-1], poses[-1]) if stamps else None


# --------------------------------------------------------------------------- encoders


# grid_map_msgs (ANYbotics/grid_map, its ROS 2 branch): not in the rosbags typestores.
_GRID_MAP_MSGS = {
    "grid_map_msgs/msg/GridMapInfo": "float64 resolution\nfloat64 length_x\nfloat64 length_y\ngeometry_msgs/Pose pose\n",
    "grid_map_msgs/msg/GridMap": (
        "std_msgs/Header header\ngrid_map_msgs/GridMapInfo info\nstring[] layers\nstring[] basic_layers\n"
        "std_msgs/Float32MultiArray[] data\nuint16 outer_start_index\nuint16 inner_start_index\n"
    ),
}


@functools.lru_cache(maxsize=1)
def default_typestore():
    """The ``rosbags`` typestore of ROS 2 Humble (the messages' definitions), with
    ``grid_map_msgs/msg/GridMap`` added; one shared instance."""
    typesys = require("rosbags.typesys", "io", "Writing ROS messages")
    Stores, get_types_from_msg, get_typestore = typesys.Stores, typesys.get_types_from_msg, typesys.get_typestore
    ts = get_typestore(Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for name, text in _GRID_MAP_MSGS.items():
        types.update(get_types_from_msg(text, name))
    ts.register(types)
    return ts


def _store(typestore: Any):
    return default_typestore() if typestore is None else typestore


#: The latest stamp a message can carry [ns]: ``builtin_interfaces/Time.sec`` is an int32.
MAX_STAMP_NS = (2**31 - 1) * _NS_PER_S
#: The most poses or markers one encoder call writes (each is a Python object).
MAX_ENCODED_ITEMS = 100_000


def _encoder_stamp(stamp: Any, name: str = "stamp_ns") -> int:
    if isinstance(stamp, bool) or not isinstance(stamp, numbers.Integral):
        if not (isinstance(stamp, numbers.Real) and math.isfinite(float(stamp)) and float(stamp).is_integer()):
            raise InputError(f"argument `{name}` must be an integer number of nanoseconds, got {stamp!r:.40}")
    value = int(stamp)
    if not 0 <= value <= MAX_STAMP_NS:
        raise InputError(f"argument `{name}` must be in [0, {MAX_STAMP_NS}] ns (a ROS time), got {value}")
    return value


def _encoder_frame(frame_id: Any, name: str = "frame_id") -> str:
    if not isinstance(frame_id, str) or len(frame_id) > 1024 or not frame_id.isprintable():
        raise InputError(f"argument `{name}` must be a frame id (printable text), got {frame_id!r:.60}")
    return frame_id


def _encoder_text(value: Any, name: str) -> str:
    if not isinstance(value, str) or len(value) > 65536 or "\x00" in value:
        raise InputError(f"argument `{name}` must be text, got {value!r:.60}")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise InputError(f"argument `{name}` must be valid text (a lone surrogate at {exc.start})") from exc
    return value


def _encoder_reals(value: Any, name: str, shape: tuple[int | None, ...]) -> np.ndarray:
    """``value`` as a finite float64 array of ``shape`` (None: any length), checked on the view."""
    if isinstance(value, np.ma.MaskedArray):
        raise InputError(f"argument `{name}`: a masked array (a masked value has no value)")
    try:
        raw = np.asarray(value)
    except Exception as exc:  # noqa: BLE001 - whatever an odd object's __array__ raises
        raise InputError(f"argument `{name}` must be an array of numbers, got {type(value).__name__}") from exc
    if raw.dtype.kind not in "iuf":
        raise InputError(f"argument `{name}` must hold real numbers, got dtype {raw.dtype}")
    if raw.ndim != len(shape) or any(want is not None and got != want for got, want in zip(raw.shape, shape)):
        want = "(" + ", ".join("N" if w is None else str(w) for w in shape) + ")"
        raise InputError(f"argument `{name}` must have shape {want}, got {raw.shape}")
    if raw.ndim and raw.shape[0] > MAX_ENCODED_ITEMS:
        raise InputError(f"argument `{name}`: at most {MAX_ENCODED_ITEMS} rows per message, got {raw.shape[0]}")
    with np.errstate(over="ignore", invalid="ignore"):
        out = raw.astype(np.float64)
    if not np.isfinite(out).all():
        raise InputError(f"argument `{name}` must be finite, got NaN or inf")
    if out.size and float(np.abs(out).max()) > _MAX_TRANSLATION_M:
        raise InputError(f"argument `{name}` must be within {_MAX_TRANSLATION_M:g} (m, m/s, rad/s), got {float(np.abs(out).max()):g}")
    return out


def time_message(stamp: int, typestore: Any = None, *, name: str = "stamp_ns"):
    """``builtin_interfaces/Time`` of ``stamp`` [ns] (an integer in [0, :data:`MAX_STAMP_NS`])."""
    ts = _store(typestore)
    stamp = _encoder_stamp(stamp, name)
    return ts.types["builtin_interfaces/msg/Time"](sec=int(stamp // _NS_PER_S), nanosec=int(stamp % _NS_PER_S))


def header(stamp: int, frame_id: str, typestore: Any = None):
    """``std_msgs/Header`` (ROS 1 typestores get ``seq`` 0)."""
    ts = _store(typestore)
    frame_id = _encoder_frame(frame_id)
    cls = ts.types["std_msgs/msg/Header"]
    kwargs = {"stamp": time_message(stamp, ts), "frame_id": frame_id}
    if "seq" in cls.__dataclass_fields__:
        kwargs["seq"] = 0
    return cls(**kwargs)


def image_message(
    data: np.ndarray,
    *,
    stamp_ns: int,
    frame_id: str,
    encoding: str | None = None,
    big_endian: bool = False,
    row_padding: int = 0,
    typestore: Any = None,
):
    """A ``sensor_msgs/Image`` of an ``(H, W)`` / ``(H, W, C)`` array.

    ``encoding`` defaults by dtype (``uint16`` -> ``16UC1``, ``float32`` -> ``32FC1``,
    ``uint8`` -> ``mono8``, ``float64`` -> ``64FC1``); ``row_padding`` bytes are added
    at the end of each row (``step`` grows by it).
    """
    ts = _store(typestore)
    a = np.asarray(data)
    defaults = {"u2": "16UC1", "f4": "32FC1", "u1": "mono8", "f8": "64FC1"}
    enc = encoding or defaults.get(a.dtype.str[1:])
    if enc not in IMAGE_ENCODINGS:
        raise InputError(f"encoding: expected one of {', '.join(IMAGE_ENCODINGS)} or a default dtype, got {enc!r} for {a.dtype}")
    code, channels = IMAGE_ENCODINGS[enc]
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] != channels) or (a.ndim == 2 and channels != 1):
        raise InputError(f"data: expected ({'H, W' if channels == 1 else f'H, W, {channels}'}) for {enc}, got shape {a.shape}")
    order = ">" if big_endian else "<"
    rows = np.ascontiguousarray(a, dtype=order + code).reshape(a.shape[0], -1).view(np.uint8)
    if row_padding:
        rows = np.hstack([rows, np.zeros((rows.shape[0], int(row_padding)), np.uint8)])
    return ts.types["sensor_msgs/msg/Image"](
        header=header(stamp_ns, frame_id, ts), height=a.shape[0], width=a.shape[1], encoding=enc,
        is_bigendian=int(big_endian), step=rows.shape[1], data=np.ascontiguousarray(rows).reshape(-1),
    )


def camera_info_message(intrinsics: Intrinsics | Any, *, stamp_ns: int, frame_id: str, typestore: Any = None):
    """A ``sensor_msgs/CameraInfo`` (plumb bob, no distortion) of an
    :class:`~subterra.io.Intrinsics` or ``subterra.PinholeCamera``."""
    ts = _store(typestore)
    c = intrinsics
    fx, fy, cx, cy = float(c.fx), float(c.fy), float(c.cx), float(c.cy)
    k = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], np.float64)
    p = np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0], np.float64)
    cls = ts.types["sensor_msgs/msg/CameraInfo"]
    names = cls.__dataclass_fields__
    upper = "K" in names  # ROS 1 spelling
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    kwargs = {
        "header": header(stamp_ns, frame_id, ts), "height": int(c.height), "width": int(c.width),
        "distortion_model": "plumb_bob", ("D" if upper else "d"): np.zeros(5, np.float64),
        ("K" if upper else "k"): k, ("R" if upper else "r"): np.eye(3).reshape(-1), ("P" if upper else "p"): p,
        "binning_x": 0, "binning_y": 0, "roi": roi,
    }
    return cls(**kwargs)


def pointcloud2_message(
    points: np.ndarray,
    fields: Mapping[str, np.ndarray] | None = None,
    *,
    stamp_ns: int,
    frame_id: str,
    organised_shape: tuple[int, int] | None = None,
    big_endian: bool = False,
    point_step: int | None = None,
    layout: Sequence[str] | None = None,
    row_padding: int = 0,
    is_dense: bool | None = None,
    typestore: Any = None,
):
    """A ``sensor_msgs/PointCloud2`` of ``(N, 3)`` points and extra ``(N,)`` / ``(N, k)`` fields.

    x, y, z keep the points' dtype (``float32`` or ``float64``); each field keeps its
    dtype. Fields are packed in ``layout`` order (default x, y, z, then ``fields``);
    ``point_step`` larger than the packed size adds padding at the end of each point;
    ``row_padding`` bytes pad each row; ``organised_shape = (height, width)`` makes an
    organised cloud. ``is_dense`` defaults to "all points finite".
    """
    ts = _store(typestore)
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3 or p.dtype.kind != "f":
        raise InputError(f"points: expected a float (N, 3) array, got {p.dtype} of shape {p.shape}")
    n = p.shape[0]
    columns: dict[str, np.ndarray] = {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2]}
    for name, value in (fields or {}).items():
        v = np.asarray(value)
        if v.shape[:1] != (n,) or v.ndim > 2:
            raise InputError(f"fields[{name!r}]: expected ({n},) or ({n}, k), got shape {v.shape}")
        if v.dtype.str[1:] not in _POINTFIELD_BY_CODE:
            raise InputError(f"fields[{name!r}]: dtype {v.dtype} has no PointField datatype")
        columns[name] = v
    order_names = list(layout) if layout is not None else list(columns)
    if sorted(order_names) != sorted(columns):
        raise InputError(f"layout: expected a permutation of {list(columns)}, got {order_names}")
    order = ">" if big_endian else "<"
    names, formats, offsets, point_fields = [], [], [], []
    offset = 0
    pf = ts.types["sensor_msgs/msg/PointField"]
    for name in order_names:
        v = columns[name]
        count = 1 if v.ndim == 1 else v.shape[1]
        code = v.dtype.str[1:]
        names.append(name)
        formats.append(order + code if count == 1 else (order + code, (count,)))
        offsets.append(offset)
        point_fields.append(pf(name=name, offset=offset, datatype=_POINTFIELD_BY_CODE[code], count=count))
        offset += np.dtype(code).itemsize * count
    step = offset if point_step is None else int(point_step)
    if step < offset:
        raise InputError(f"point_step: expected >= {offset} B (the packed fields), got {step}")
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    records = np.zeros(n, dtype=dtype)
    for name in names:
        records[name] = columns[name]
    height, width = organised_shape if organised_shape is not None else (1, n)
    if height * width != n:
        raise InputError(f"organised_shape: {height}x{width} != {n} points")
    rows = records.view(np.uint8).reshape(height, width * step) if n else np.zeros((height, 0), np.uint8)
    if row_padding:
        rows = np.hstack([rows, np.zeros((height, int(row_padding)), np.uint8)])
    dense = bool(np.isfinite(p).all()) if is_dense is None else bool(is_dense)
    return ts.types["sensor_msgs/msg/PointCloud2"](
        header=header(stamp_ns, frame_id, ts), height=height, width=width, fields=point_fields,
        is_bigendian=bool(big_endian), point_step=step, row_step=rows.shape[1] if n else width * step,
        data=np.ascontiguousarray(rows).reshape(-1), is_dense=dense,
    )


def _pose_msg(m: np.ndarray, ts: Any, quaternion: Sequence[float] | None = None):
    qx, qy, qz, qw = quaternion_from_matrix(m) if quaternion is None else (float(v) for v in quaternion)
    return ts.types["geometry_msgs/msg/Pose"](
        position=ts.types["geometry_msgs/msg/Point"](x=float(m[0, 3]), y=float(m[1, 3]), z=float(m[2, 3])),
        orientation=ts.types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
    )


def odometry_message(
    world_from_body: np.ndarray,
    *,
    stamp_ns: int,
    frame_id: str = "odom",
    child_frame_id: str = "base_link",
    covariance: np.ndarray | None = None,
    twist: Sequence[float] | None = None,
    typestore: Any = None,
):
    """A ``nav_msgs/Odometry`` of a 4x4 pose (and optional 6x6 covariance and body twist)."""
    ts = _store(typestore)
    cov = np.zeros(36) if covariance is None else np.asarray(covariance, np.float64).reshape(36)
    tw = np.zeros(6) if twist is None else np.asarray(twist, np.float64).reshape(6)
    vec = ts.types["geometry_msgs/msg/Vector3"]
    return ts.types["nav_msgs/msg/Odometry"](
        header=header(stamp_ns, frame_id, ts),
        child_frame_id=child_frame_id,
        pose=ts.types["geometry_msgs/msg/PoseWithCovariance"](pose=_pose_msg(np.asarray(world_from_body, np.float64), ts), covariance=cov),
        twist=ts.types["geometry_msgs/msg/TwistWithCovariance"](
            twist=ts.types["geometry_msgs/msg/Twist"](linear=vec(x=tw[0], y=tw[1], z=tw[2]), angular=vec(x=tw[3], y=tw[4], z=tw[5])),
            covariance=np.zeros(36),
        ),
    )


def tf_message(transforms: Iterable[tuple[str, str, int, np.ndarray]], typestore: Any = None):
    """A ``tf2_msgs/TFMessage`` of ``(parent, child, stamp_ns, parent_from_child)`` items."""
    ts = _store(typestore)
    items = []
    for parent, child, stamp, m in transforms:
        m = np.asarray(m, np.float64)
        qx, qy, qz, qw = quaternion_from_matrix(m)
        items.append(
            ts.types["geometry_msgs/msg/TransformStamped"](
                header=header(stamp, parent, ts),
                child_frame_id=child,
                transform=ts.types["geometry_msgs/msg/Transform"](
                    translation=ts.types["geometry_msgs/msg/Vector3"](x=float(m[0, 3]), y=float(m[1, 3]), z=float(m[2, 3])),
                    rotation=ts.types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
                ),
            )
        )
    if "tf2_msgs/msg/TFMessage" not in ts.types:  # ROS 1 Noetic's store lacks it; the definition is the same
        from rosbags.typesys import get_types_from_msg

        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    return ts.types["tf2_msgs/msg/TFMessage"](transforms=items)


def clock_message(stamp: int, typestore: Any = None):
    """``rosgraph_msgs/Clock`` of ``stamp`` [ns] (``/clock``, simulated time)."""
    ts = _store(typestore)
    return ts.types["rosgraph_msgs/msg/Clock"](clock=time_message(stamp, ts, name="stamp"))


def twist_message(linear: Sequence[float], angular: Sequence[float], typestore: Any = None):
    """``geometry_msgs/Twist`` of ``linear`` [m/s] and ``angular`` [rad/s] (3 numbers each)."""
    ts = _store(typestore)
    vec = ts.types["geometry_msgs/msg/Vector3"]
    lx, ly, lz = (float(v) for v in _encoder_reals(linear, "linear", (3,)))
    ax, ay, az = (float(v) for v in _encoder_reals(angular, "angular", (3,)))
    return ts.types["geometry_msgs/msg/Twist"](linear=vec(x=lx, y=ly, z=lz), angular=vec(x=ax, y=ay, z=az))


def twist_stamped_message(linear: Sequence[float], angular: Sequence[float], *, stamp_ns: int, frame_id: str, typestore: Any = None):
    """``geometry_msgs/TwistStamped`` (see :func:`twist_message`)."""
    ts = _store(typestore)
    return ts.types["geometry_msgs/msg/TwistStamped"](header=header(stamp_ns, frame_id, ts), twist=twist_message(linear, angular, ts))


def pose_stamped_message(world_from_body: np.ndarray, *, stamp_ns: int, frame_id: str, typestore: Any = None):
    """``geometry_msgs/PoseStamped`` of a 4x4 pose."""
    ts = _store(typestore)
    pose = _checked_rigid(world_from_body, "argument `world_from_body`")
    return ts.types["geometry_msgs/msg/PoseStamped"](header=header(stamp_ns, frame_id, ts), pose=_pose_msg(pose, ts))


def path_message(poses: Iterable[tuple[int, np.ndarray]] | np.ndarray, *, stamp_ns: int, frame_id: str, typestore: Any = None):
    """``nav_msgs/Path`` of ``(stamp_ns, 4x4 pose)`` items, or of an ``(N, 2)`` / ``(N, 3)``
    array of points (each pose then stamped ``stamp_ns`` and heading along the path)."""
    ts = _store(typestore)
    if isinstance(poses, np.ndarray):
        width = poses.shape[1] if poses.ndim == 2 and poses.shape[1] in (2, 3) else 3
        pts = _encoder_reals(poses, "poses", (None, width))
        items = []
        for i, p in enumerate(pts):
            d = (pts[min(i + 1, len(pts) - 1)] - pts[max(i - 1, 0)])[:2] if len(pts) > 1 else np.zeros(2)
            yaw = math.atan2(d[1], d[0]) if np.any(d) else 0.0
            m = np.eye(4)
            m[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
            m[: pts.shape[1], 3] = p
            items.append((stamp_ns, m))
    else:
        try:
            items = list(poses)
        except TypeError as exc:
            raise InputError(f"argument `poses` must be (stamp_ns, 4x4 pose) items or an (N, 2|3) array, got {type(poses).__name__}") from exc
        if len(items) > MAX_ENCODED_ITEMS:
            raise InputError(f"argument `poses`: at most {MAX_ENCODED_ITEMS} poses per message, got {len(items)}")
        if not all(isinstance(item, tuple) and len(item) == 2 for item in items):
            raise InputError("argument `poses` must be (stamp_ns, 4x4 pose) items or an (N, 2|3) array")
        items = [(s, _checked_rigid(m, f"argument `poses[{i}]`")) for i, (s, m) in enumerate(items)]
    # One SciPy call for every pose's quaternion (a call per pose costs ~0.2 ms).
    quaternions = (_rotations_of(np.stack([m[:3, :3] for _, m in items]), "argument `poses`").as_quat(canonical=True)
                   if items else np.zeros((0, 4)))
    stamped = [ts.types["geometry_msgs/msg/PoseStamped"](header=header(s, frame_id, ts), pose=_pose_msg(m, ts, q))
               for (s, m), q in zip(items, quaternions)]
    return ts.types["nav_msgs/msg/Path"](header=header(stamp_ns, frame_id, ts), poses=stamped)


def occupancy_values(risk: np.ndarray, observed: np.ndarray, lethal_risk: float) -> np.ndarray:
    """``int8`` occupancy of a risk layer with Nav2's meaning: 100 where the cell is lethal
    (``risk >= lethal_risk``, observed or not: a lethal cell is never unknown), -1 where it
    was not observed (or is NaN), else ``round(100 r)`` clipped to 0..99; same shape."""
    r = np.asarray(risk, dtype=np.float32)
    out = np.rint(np.clip(np.nan_to_num(r, nan=0.0), 0.0, 0.99) * 100.0).astype(np.int8)
    out[(np.asarray(observed) <= 0) | np.isnan(r)] = -1
    out[r >= np.float32(lethal_risk)] = 100
    return out


def _risk_map(risk_map: Any) -> Any:
    if not all(hasattr(risk_map, a) for a in ("layer", "layer_names", "extent", "resolution", "lethal_risk")):
        raise InputError(f"argument `risk_map` must be a subterra.RiskMap, got {type(risk_map).__name__}")
    return risk_map


def _map_origin(risk_map: Any, z: float = 0.0) -> np.ndarray:
    origin = np.eye(4)
    origin[0, 3], origin[1, 3], origin[2, 3] = risk_map.extent[0], risk_map.extent[2], z
    return origin


def occupancy_grid_message(risk_map: Any, *, stamp_ns: int, frame_id: str, typestore: Any = None):
    """The combined risk of a ``subterra.RiskMap`` as a ``nav_msgs/OccupancyGrid`` with Nav2's
    meaning (:func:`occupancy_values`: lethal 100, unobserved -1); ``info.origin`` is the
    corner of cell (0, 0), rows along world y."""
    ts = _store(typestore)
    risk = _risk_map(risk_map).layer("risk")
    ny, nx = risk.shape
    info = ts.types["nav_msgs/msg/MapMetaData"](
        map_load_time=time_message(stamp_ns, ts), resolution=float(risk_map.resolution),
        width=nx, height=ny, origin=_pose_msg(_map_origin(risk_map), ts),
    )
    values = occupancy_values(risk, risk_map.layer("observed"), risk_map.lethal_risk).reshape(-1)
    return ts.types["nav_msgs/msg/OccupancyGrid"](header=header(stamp_ns, frame_id, ts), info=info, data=values)


def grid_map_message(risk_map: Any, *, stamp_ns: int, frame_id: str, layers: Iterable[str] | None = None, typestore: Any = None):
    """Every layer of a ``subterra.RiskMap`` (or those named in ``layers``) as a
    ``grid_map_msgs/GridMap``, as ``grid_map_ros`` writes one: ``info.pose`` the map's centre,
    ``length_x``/``length_y`` its size [m]; each layer a column-major ``Float32MultiArray``
    (dimension 0 ``column_index``, dimension 1 ``row_index``) whose index (0, 0) is the cell of
    the largest x and y, rows toward -x and columns toward -y; NaN where a layer has no value.
    Needs a typestore with ``grid_map_msgs`` (:func:`default_typestore` has it)."""
    ts = _store(typestore)
    if "grid_map_msgs/msg/GridMap" not in ts.types:
        raise InputError("argument `typestore` has no grid_map_msgs/msg/GridMap: use subterra.io.ros.default_typestore()")
    _risk_map(risk_map)
    if layers is not None and (isinstance(layers, str) or not isinstance(layers, (list, tuple)) or not all(isinstance(n, str) for n in layers)):
        raise InputError(f"argument `layers` must be a list of layer names (or None: all), got {layers!r:.60}")
    names = list(risk_map.layer_names if layers is None else layers)
    unknown = [n for n in names if n not in risk_map.layer_names]
    if unknown:
        raise InputError(f"argument `layers`: no layer {unknown[0]!r}; the map has {', '.join(risk_map.layer_names)}")
    ny, nx = risk_map.layer("risk").shape
    res = float(risk_map.resolution)
    centre = np.eye(4)
    x0, x1, y0, y1 = (float(v) for v in risk_map.extent[:4])
    centre[0, 3], centre[1, 3] = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    dim = ts.types["std_msgs/msg/MultiArrayDimension"]
    arrays = []
    for name in names:
        grid = np.asarray(risk_map.layer(name), dtype=np.float32)
        # grid_map's matrix: row r <-> x index nx-1-r, column c <-> y index ny-1-c; stored column-major.
        matrix = grid.T[::-1, ::-1]
        layout = ts.types["std_msgs/msg/MultiArrayLayout"](
            dim=[dim(label="column_index", size=ny, stride=nx * ny), dim(label="row_index", size=nx, stride=nx)], data_offset=0,
        )
        arrays.append(ts.types["std_msgs/msg/Float32MultiArray"](layout=layout, data=np.ascontiguousarray(matrix.T).reshape(-1)))
    info = ts.types["grid_map_msgs/msg/GridMapInfo"](resolution=res, length_x=nx * res, length_y=ny * res, pose=_pose_msg(centre, ts))
    return ts.types["grid_map_msgs/msg/GridMap"](
        header=header(stamp_ns, frame_id, ts), info=info, layers=names, basic_layers=[], data=arrays,
        outer_start_index=0, inner_start_index=0,
    )


def _marker(ts: Any, stamp: int, frame_id: str, ns: str, marker_id: int, kind: int, scale: Sequence[float], rgba: Sequence[float], *,
            points: list | None = None, colors: list | None = None, text: str = "", z: float = 0.0) -> Any:
    t = ts.types
    pose = _pose_msg(np.eye(4), ts)
    pose.position.z = float(z)
    kwargs = dict(
        header=header(stamp, frame_id, ts), ns=ns, id=marker_id, type=kind,
        action=0, pose=pose, scale=t["geometry_msgs/msg/Vector3"](x=scale[0], y=scale[1], z=scale[2]),
        color=t["std_msgs/msg/ColorRGBA"](r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
        lifetime=t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0), frame_locked=False,
        points=points or [], colors=colors or [], text=text, mesh_resource="", mesh_use_embedded_materials=False,
    )
    fields = t["visualization_msgs/msg/Marker"].__dataclass_fields__
    if "texture_resource" in fields:  # later than Humble
        kwargs.update(
            texture_resource="",
            texture=t["sensor_msgs/msg/CompressedImage"](header=header(stamp, "", ts), format="", data=np.zeros(0, np.uint8)),
            uv_coordinates=[],
            mesh_file=t["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
        )
    return t["visualization_msgs/msg/Marker"](**{k: v for k, v in kwargs.items() if k in fields})


#: Diameter of a belief sphere [m], and the P(free) text's height and offset above the body [m].
BELIEF_SPHERE_M = 0.05
BELIEF_TEXT_HEIGHT_M = 0.08
BELIEF_TEXT_OFFSET_Z_M = 0.4


def belief_markers_message(centres: np.ndarray, probabilities: np.ndarray, *, stamp_ns: int, frame_id: str,
                           p_free: float | None = None, typestore: Any = None):
    """A ``visualization_msgs/MarkerArray`` of the APF-PF belief: marker 0 a ``SPHERE_LIST`` of
    the voxel ``centres`` (N, 3) [m, ``frame_id``] with their ``probabilities`` (colour yellow
    -> red and opacity by belief relative to the largest), marker 1 a ``TEXT_VIEW_FACING`` with
    ``P(free)`` when given."""
    ts = _store(typestore)
    c = _encoder_reals(centres, "centres", (None, 3))
    probs = _encoder_reals(probabilities, "probabilities", (None,))
    if probs.shape[0] != c.shape[0]:
        raise InputError(f"argument `probabilities`: expected {c.shape[0]} values, got {probs.shape[0]}")
    if probs.size and (probs.min() < 0.0 or probs.max() > 1.0):
        raise InputError(f"argument `probabilities` must be in [0, 1], got {probs.min():g} .. {probs.max():g}")
    if p_free is not None:
        p_free = float(_encoder_reals(p_free, "p_free", ()))
        if not 0.0 <= p_free <= 1.0:
            raise InputError(f"argument `p_free` must be in [0, 1], got {p_free}")
    t = ts.types
    point, colour = t["geometry_msgs/msg/Point"], t["std_msgs/msg/ColorRGBA"]
    rel = probs / probs.max() if probs.size and probs.max() > 0 else np.ones_like(probs)
    kinds = t["visualization_msgs/msg/Marker"]
    markers = [_marker(ts, stamp_ns, frame_id, "subterra/belief", 0, kinds.SPHERE_LIST, (BELIEF_SPHERE_M,) * 3, (1.0, 0.5, 0.0, 1.0),
                       points=[point(x=float(x), y=float(y), z=float(z)) for x, y, z in c],
                       colors=[colour(r=1.0, g=float(0.86 * (1 - w)), b=0.0, a=float(0.3 + 0.7 * w)) for w in rel])]
    if p_free is not None:
        markers.append(_marker(ts, stamp_ns, frame_id, "subterra/belief", 1, kinds.TEXT_VIEW_FACING, (0.0, 0.0, BELIEF_TEXT_HEIGHT_M),
                               (1.0, 1.0, 1.0, 1.0), text=f"P(free) = {p_free:.2f}", z=BELIEF_TEXT_OFFSET_Z_M))
    return t["visualization_msgs/msg/MarkerArray"](markers=markers)


#: ``diagnostic_msgs/DiagnosticStatus`` levels by name.
DIAGNOSTIC_LEVELS = {"ok": 0, "warn": 1, "error": 2, "stale": 3}


def diagnostics_message(statuses: Iterable[tuple[str, str, str, Mapping[str, Any]]], *, stamp_ns: int, hardware_id: str = "",
                        typestore: Any = None):
    """A ``diagnostic_msgs/DiagnosticArray`` of ``(name, level, message, values)`` items:
    ``level`` one of :data:`DIAGNOSTIC_LEVELS`, ``values`` a mapping written as key/value strings."""
    ts = _store(typestore)
    t = ts.types
    hardware_id = _encoder_text(hardware_id, "hardware_id")
    try:
        items = list(statuses)
    except TypeError as exc:
        raise InputError(f"argument `statuses` must be (name, level, message, values) items, got {type(statuses).__name__}") from exc
    if len(items) > MAX_ENCODED_ITEMS:
        raise InputError(f"argument `statuses`: at most {MAX_ENCODED_ITEMS} per message, got {len(items)}")
    status = []
    for i, item in enumerate(items):
        if not (isinstance(item, tuple) and len(item) == 4 and isinstance(item[3], Mapping)):
            raise InputError(f"argument `statuses[{i}]` must be (name, level, message, values: a mapping), got {item!r:.80}")
        name, level, message, values = item
        if not isinstance(level, str) or level not in DIAGNOSTIC_LEVELS:
            raise InputError(f"argument `statuses[{i}]`: level must be one of {', '.join(DIAGNOSTIC_LEVELS)}, got {level!r:.40}")
        if len(values) > MAX_ENCODED_ITEMS:
            raise InputError(f"argument `statuses[{i}]`: at most {MAX_ENCODED_ITEMS} values, got {len(values)}")
        try:
            pairs = [(str(k), str(v)) for k, v in values.items()]
        except Exception as exc:  # noqa: BLE001 - an object whose __str__ raises
            raise InputError(f"argument `statuses[{i}]`: a key or value that cannot be written as text ({type(exc).__name__})") from exc
        kv = [t["diagnostic_msgs/msg/KeyValue"](key=_encoder_text(k, f"statuses[{i}] key"), value=_encoder_text(v, f"statuses[{i}] value"))
              for k, v in pairs]
        status.append(t["diagnostic_msgs/msg/DiagnosticStatus"](level=DIAGNOSTIC_LEVELS[level], name=_encoder_text(name, f"statuses[{i}] name"),
                                                                message=_encoder_text(message, f"statuses[{i}] message"),
                                                                hardware_id=hardware_id, values=kv))
    return t["diagnostic_msgs/msg/DiagnosticArray"](header=header(stamp_ns, "", ts), status=status)
