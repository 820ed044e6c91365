"""Pinhole camera intrinsics from files, dicts and named presets.

:func:`read_intrinsics` reads a ``.json``, ``.yaml`` or ``.yml`` file in one of four
layouts, recognised by their keys (all values in pixels):

plain
    ``{fx, fy, cx, cy, width, height}``.
Open3D ``PinholeCameraIntrinsic`` JSON
    ``width``, ``height`` and ``intrinsic_matrix``: the 3x3 matrix K as 9 numbers in
    **column-major** order, so ``fx = m[0]``, ``fy = m[4]``, ``cx = m[6]``,
    ``cy = m[7]``.
ROS ``camera_calibration_parsers`` YAML
    ``image_width``, ``image_height`` and ``camera_matrix: {rows: 3, cols: 3, data:
    [9 numbers, row-major]}``.
``sensor_msgs/CameraInfo`` dump (``rostopic echo`` / ``ros2 topic echo``, YAML or JSON)
    ``width``, ``height`` and ``K`` (ROS 1) or ``k`` (ROS 2): 9 numbers, row-major.

K must be a pinhole matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``: a non-zero skew
or a last row other than ``(0, 0, 1)`` is rejected. Distortion coefficients are
ignored: depth images are expected to be rectified (RealSense and Kinect depth are).
"""

from __future__ import annotations

import json
import math
import numbers
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Union

from .._extras import require
from .._files import read_regular_text
from ..errors import ConfigError, FileFormatError, InputError, SubterraError

__all__ = [
    "INTRINSICS_EXTENSIONS",
    "KNOWN_CAMERAS",
    "Intrinsics",
    "intrinsics_from_dict",
    "read_intrinsics",
]

PathLike = Union[str, "os.PathLike[str]"]

#: File extensions :func:`read_intrinsics` understands (lower case, with the dot).
INTRINSICS_EXTENSIONS: tuple[str, ...] = (".json", ".yaml", ".yml")

_PLAIN_KEYS = ("fx", "fy", "cx", "cy", "width", "height")
# Largest |skew| accepted as zero, relative to fx (rounding in written files).
_SKEW_TOLERANCE_REL = 1e-9
_FORMATS_HELP = (
    "a plain {fx, fy, cx, cy, width, height} mapping, an Open3D PinholeCameraIntrinsic "
    "(intrinsic_matrix), a ROS camera_calibration YAML (camera_matrix) or a "
    "sensor_msgs/CameraInfo dump (K or k)"
)


def _real(value: object, name: str, error: type[SubterraError]) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise error(f"{name}: expected a finite number, got {type(value).__name__} {value!r}")
    result = float(value)
    if not math.isfinite(result):
        raise error(f"{name}: expected a finite number, got {result!r}")
    return result


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of a camera in the optical frame (x right, y down, z forward).

    Attributes:
        fx: focal length along x [px], finite and > 0.
        fy: focal length along y [px], finite and > 0.
        cx: principal point x [px], finite (column 0 is the left edge).
        cy: principal point y [px], finite (row 0 is the top edge).
        width: image width [px], an int > 0.
        height: image height [px], an int > 0.

    Raises:
        ConfigError: a value is out of range or of the wrong type.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("fx", "fy"):
            value = _real(getattr(self, name), name, ConfigError)
            if value <= 0.0:
                raise ConfigError(f"{name}: expected a finite focal length > 0 [px], got {value!r}")
            object.__setattr__(self, name, value)
        for name in ("cx", "cy"):
            object.__setattr__(self, name, _real(getattr(self, name), name, ConfigError))
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                raise ConfigError(
                    f"{name}: expected an int > 0 [px], got {type(value).__name__} {value!r}"
                )
            if value <= 0:
                raise ConfigError(f"{name}: expected an int > 0 [px], got {value!r}")
            object.__setattr__(self, name, int(value))

    def _check_as_camera(self) -> None:
        """The camera's own limits (sides, pixels, focal lengths, principal point), so that
        intrinsics read from a file or a dict always make a camera; the message names the field."""
        from .._core import PinholeCamera  # the package's __init__ has loaded the core

        try:
            PinholeCamera(fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy, width=self.width, height=self.height)
        except SubterraError as exc:
            text = str(exc)
            field = next((name for name in _PLAIN_KEYS if f"`camera.{name}`" in text), "intrinsics")
            raise ConfigError(f"{field}: {text}") from None

    def to_camera(self) -> Any:
        """This camera as a :class:`subterra.PinholeCamera` (needs the compiled core)."""
        from subterra import PinholeCamera  # lazy: the io layer loads without _core

        return PinholeCamera(
            fx=self.fx,
            fy=self.fy,
            cx=self.cx,
            cy=self.cy,
            width=self.width,
            height=self.height,
        )


#: Intrinsics of the cameras in the shared real-data set (``../shared/data``) and of
#: the simulated D435.
KNOWN_CAMERAS: dict[str, Intrinsics] = {
    # realsense-d435-room/cam_params_realsense.json (Open3D, column-major K).
    "d435-room": Intrinsics(
        fx=617.25,
        fy=617.5486450195312,
        cx=317.3921203613281,
        cy=245.98019409179688,
        width=640,
        height=480,
    ),
    # kinect-dining: the intrinsics published with the data (slambook2, ch. 12).
    "kinect-dining": Intrinsics(fx=518.0, fy=519.0, cx=325.5, cy=253.5, width=640, height=480),
    # tum-desk: TUM RGB-D calibration as given in shared/data/README.md.
    "tum-desk": Intrinsics(fx=520.9, fy=521.0, cx=325.1, cy=249.7, width=640, height=480),
    # Simulated RealSense D435 depth stream at 640x480 (the simulator's default).
    "d435": Intrinsics(fx=385.0, fy=385.0, cx=319.5, cy=239.5, width=640, height=480),
}


def read_intrinsics(path: PathLike) -> Intrinsics:
    """Read camera intrinsics from a ``.json``, ``.yaml`` or ``.yml`` file.

    The layout (plain, Open3D, ROS calibration YAML, CameraInfo dump) is recognised
    from the keys; see the module documentation. A YAML stream with several documents
    (``ros2 topic echo`` output ending in ``---``) uses its first non-empty document.

    Raises:
        FileFormatError: the file is missing, unreadable, not valid JSON/YAML, of an
            unknown extension, lacks a field, or holds an invalid value; the message
            names the field and ends with the path.
        InputError: ``path`` is not a str or os.PathLike.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"path: expected a str or os.PathLike, got {type(path).__name__}")
    file_path = Path(path)
    suffix = file_path.suffix.lower()
    if suffix not in INTRINSICS_EXTENSIONS:
        raise FileFormatError(
            f"path: expected an intrinsics file with extension "
            f"{', '.join(INTRINSICS_EXTENSIONS)}, got {file_path.suffix or 'no extension'!r}: "
            f"{file_path}"
        )
    # A regular file of at most 16 MiB of UTF-8 text: a FIFO, device or folder fails at once.
    text = read_regular_text(file_path, "intrinsics file")

    document = _parse_json(text, file_path) if suffix == ".json" else _parse_yaml(text, file_path)
    try:
        return _intrinsics_from_mapping(document, str(file_path))
    except FileFormatError:
        raise
    except SubterraError as exc:
        raise FileFormatError(str(exc)) from exc


def intrinsics_from_dict(d: Mapping[str, Any], source: str = "<dict>") -> Intrinsics:
    """Build :class:`Intrinsics` from a parsed mapping in any supported layout.

    Args:
        d: the mapping (plain, Open3D, ROS calibration YAML or CameraInfo layout).
        source: where ``d`` came from; it ends every error message.

    Raises:
        InputError: ``d`` is not a mapping, a field is missing, of the wrong type, or K
            is not a pinhole matrix.
        ConfigError: a value is out of range (focal length <= 0, size <= 0, NaN, ...) or
            beyond the limits of :class:`subterra.PinholeCamera` (sides 1-16384 px, at most
            16.7 MP, focal lengths 1-10^6 px, principal point within one image size); the
            message names the field.
    """
    return _intrinsics_from_mapping(d, source)


# --------------------------------------------------------------------------- helpers


def _intrinsics_from_mapping(d: object, source: str) -> Intrinsics:
    if not isinstance(d, Mapping):
        raise InputError(
            f"intrinsics: expected a mapping ({_FORMATS_HELP}), got {type(d).__name__}: {source}"
        )
    if "fx" in d:
        values = {key: _field(d, key, source) for key in _PLAIN_KEYS}
        fx, fy, cx, cy = (_number(values[k], k, source) for k in ("fx", "fy", "cx", "cy"))
        width = _integer(values["width"], "width", source)
        height = _integer(values["height"], "height", source)
    elif "intrinsic_matrix" in d:
        matrix = _nine_numbers(_field(d, "intrinsic_matrix", source), "intrinsic_matrix", source)
        # Open3D stores K column-major: m[3 * col + row].
        k_row_major = [matrix[3 * col + row] for row in range(3) for col in range(3)]
        fx, fy, cx, cy = _pinhole_from_k(k_row_major, "intrinsic_matrix (column-major)", source)
        width = _integer(_field(d, "width", source), "width", source)
        height = _integer(_field(d, "height", source), "height", source)
    elif "camera_matrix" in d:
        block = _field(d, "camera_matrix", source)
        if not isinstance(block, Mapping):
            raise InputError(
                "camera_matrix: expected a mapping {rows: 3, cols: 3, data: [9 numbers]}, "
                f"got {type(block).__name__}: {source}"
            )
        for dim in ("rows", "cols"):
            if dim in block and _integer(block[dim], f"camera_matrix.{dim}", source) != 3:
                raise InputError(f"camera_matrix.{dim}: expected 3, got {block[dim]!r}: {source}")
        matrix = _nine_numbers(
            _field(block, "data", source, "camera_matrix.data"), "camera_matrix.data", source
        )
        fx, fy, cx, cy = _pinhole_from_k(matrix, "camera_matrix.data", source)
        width = _integer(_field(d, "image_width", source), "image_width", source)
        height = _integer(_field(d, "image_height", source), "image_height", source)
    elif "K" in d or "k" in d:
        key = "K" if "K" in d else "k"
        matrix = _nine_numbers(d[key], key, source)
        fx, fy, cx, cy = _pinhole_from_k(matrix, key, source)
        width = _integer(_field(d, "width", source), "width", source)
        height = _integer(_field(d, "height", source), "height", source)
    else:
        keys = sorted(str(k) for k in d)
        raise InputError(
            f"intrinsics: expected {_FORMATS_HELP}; missing field 'fx', 'intrinsic_matrix', "
            f"'camera_matrix' or 'K', got keys {keys}: {source}"
        )
    try:
        result = Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height)
        result._check_as_camera()
    except ConfigError as exc:
        raise ConfigError(f"{exc}: {source}") from exc
    return result


def _field(d: Mapping, key: str, source: str, label: str | None = None) -> object:
    if key not in d:
        keys = sorted(str(k) for k in d)
        raise InputError(f"{label or key}: missing field (got keys {keys}): {source}")
    return d[key]


def _number(value: object, name: str, source: str) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(
            f"{name}: expected a number, got {type(value).__name__} {value!r}: {source}"
        )
    return float(value)


def _integer(value: object, name: str, source: str) -> int:
    """An int, also from a float with an integral value (JSON writers emit 640.0)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(
            f"{name}: expected an integer [px], got {type(value).__name__} {value!r}: {source}"
        )
    if isinstance(value, numbers.Integral):
        return int(value)
    as_float = float(value)
    if not as_float.is_integer():
        raise InputError(f"{name}: expected an integer [px], got {as_float!r}: {source}")
    return int(as_float)


def _nine_numbers(value: object, name: str, source: str) -> list[float]:
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise InputError(
            f"{name}: expected a flat list of 9 numbers, got {type(value).__name__}: {source}"
        )
    if len(value) != 9:
        raise InputError(
            f"{name}: expected a flat list of 9 numbers, got {len(value)} items: {source}"
        )
    return [_number(item, f"{name}[{index}]", source) for index, item in enumerate(value)]


def _pinhole_from_k(k: list[float], name: str, source: str) -> tuple[float, float, float, float]:
    """``(fx, fy, cx, cy)`` from a row-major K; reject anything but a pinhole matrix."""
    fx, skew, cx, k10, fy, cy, k20, k21, k22 = k
    if (k10, k20, k21, k22) != (0.0, 0.0, 0.0, 1.0):
        raise InputError(
            f"{name}: expected a pinhole matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got "
            f"rows {k[0:3]}, {k[3:6]}, {k[6:9]} (wrong element order?): {source}"
        )
    if abs(skew) > _SKEW_TOLERANCE_REL * abs(fx):
        raise InputError(
            f"{name}: expected zero skew (K[0][1]), got {skew!r}: a skewed camera is not "
            f"supported: {source}"
        )
    return fx, fy, cx, cy


def _parse_json(text: str, path: Path) -> object:
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise FileFormatError(
            f"intrinsics: expected valid JSON, got {exc.msg} at line {exc.lineno} column "
            f"{exc.colno}: {path}"
        ) from exc
    except RecursionError as exc:  # the decoder recurses once per nested array / object
        raise FileFormatError(f"intrinsics: expected valid JSON, got nesting too deep to read: {path}") from exc


def _parse_yaml(text: str, path: Path) -> object:
    if text.lstrip().startswith("%YAML:1.0"):
        raise FileFormatError(
            "intrinsics: expected standard YAML, got an OpenCV FileStorage file "
            f"('%YAML:1.0', not supported; convert it to a ROS camera_calibration YAML): {path}"
        )
    yaml = require("yaml", "io", "Reading YAML intrinsics")
    try:
        documents = [doc for doc in yaml.safe_load_all(text) if doc is not None]
    except yaml.YAMLError as exc:
        where = ""
        mark = getattr(exc, "problem_mark", None)
        if mark is not None:
            where = f" at line {mark.line + 1} column {mark.column + 1}"
        problem = getattr(exc, "problem", None) or type(exc).__name__
        raise FileFormatError(
            f"intrinsics: expected valid YAML, got {problem}{where}: {path}"
        ) from exc
    except RecursionError as exc:  # the composer recurses once per nested node
        raise FileFormatError(f"intrinsics: expected valid YAML, got nesting too deep to read: {path}") from exc
    if not documents:
        raise FileFormatError(f"intrinsics: expected a YAML mapping, got an empty document: {path}")
    return documents[0]
