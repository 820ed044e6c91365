"""Sensor trajectories from text files: KITTI poses and TUM trajectories.

A pose is a rigid transform ``world_from_body`` (4x4, ``float64``): it maps a point in
the body (sensor) frame to the world frame, ``p_world = R @ p_body + t`` [m]. A file
holds one pose per line; the number of values per line tells the format:

``"kitti"``: 12 values
    The 3x4 matrix ``[R | t]`` row-major (KITTI odometry ground truth, the Ouster SDK's
    ``*_poses_kitti.txt``). No timestamps: the i-th line belongs to the i-th scan.
``"tum"``: 8 values
    ``timestamp tx ty tz qx qy qz qw`` (TUM RGB-D benchmark, evo, most SLAM systems):
    time [s], position [m] and the orientation as a unit quaternion, scalar last.
``"tum-no-stamp"``: 7 values
    ``tx ty tz qx qy qz qw`` without the time (e.g. slambook's ``pose.txt``).

Blank lines and lines starting with ``#`` are skipped; values are separated by
whitespace or commas. Every pose is checked to be rigid: a KITTI rotation must satisfy
``max |R^T R - I| <= rotation_tolerance`` and ``det R > 0`` (a reflection is rejected),
a TUM quaternion must have ``| |q| - 1 | <= rotation_tolerance`` and is then normalised.
The values are returned as written (a KITTI rotation is not re-orthonormalised).
TUM timestamps must be finite and strictly increasing.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
from pathlib import Path
from typing import Union

import numpy as np

from .._files import read_regular_text
from ..errors import ConfigError, FileFormatError, InputError
from .depth import _as_path, _check_readable_file
from .ros import _MAX_TRANSLATION_M

__all__ = [
    "DEFAULT_ROTATION_TOLERANCE",
    "POSE_FORMATS",
    "Trajectory",
    "read_poses",
    "read_trajectory",
]

PathLike = Union[str, "os.PathLike[str]"]

#: Default tolerance of the rigidity checks: ``max |R^T R - I|`` for a rotation matrix
#: and ``| |q| - 1 |`` for a quaternion. Files written with 6 significant digits (KITTI
#: ground truth) or 4 decimals (TUM ground truth) are within 1e-4.
DEFAULT_ROTATION_TOLERANCE = 1e-3

#: Pose file formats, by the number of values per line.
POSE_FORMATS: dict[str, int] = {"kitti": 12, "tum": 8, "tum-no-stamp": 7}

_FORMAT_BY_COLUMNS = {columns: name for name, columns in POSE_FORMATS.items()}
# The largest trajectory file read: about 10 million TUM lines.
_MAX_POSE_FILE_BYTES = 1024 * 1024 * 1024
_FORMATS_HELP = (
    "12 values (KITTI: 3x4 [R | t] row-major), 8 (TUM: t tx ty tz qx qy qz qw) or 7 "
    "(tx ty tz qx qy qz qw)"
)


@dataclasses.dataclass(frozen=True, eq=False)
class Trajectory:
    """A sequence of poses, with their times when the file has them.

    Attributes:
        world_from_body: C-contiguous ``float64`` ``(M, 4, 4)`` rigid transforms (last
            row ``0 0 0 1``); translation in metres.
        stamps_s: ``float64`` ``(M,)`` times [s], strictly increasing, or ``None``
            (KITTI and 7-value files: pose i belongs to scan i).
        path: the file the poses were read from (as given), or a label.
        format: ``"kitti"``, ``"tum"`` or ``"tum-no-stamp"``.

    Equality is identity (comparing arrays element-wise is left to the caller).
    """

    world_from_body: np.ndarray
    stamps_s: np.ndarray | None
    path: str
    format: str

    def __post_init__(self) -> None:
        if not isinstance(self.path, (str, os.PathLike)):
            raise InputError(f"path: expected a str or os.PathLike, got {type(self.path).__name__}")
        poses = self.world_from_body
        if not isinstance(poses, np.ndarray) or poses.ndim != 3 or poses.shape[1:] != (4, 4):
            got = poses.shape if isinstance(poses, np.ndarray) else type(poses).__name__
            raise InputError(f"world_from_body: expected an (M, 4, 4) array, got {got}")
        stamps = self.stamps_s
        if stamps is not None:
            if not isinstance(stamps, np.ndarray) or stamps.shape != (poses.shape[0],):
                got = stamps.shape if isinstance(stamps, np.ndarray) else type(stamps).__name__
                raise InputError(f"stamps_s: expected None or shape ({poses.shape[0]},), got {got}")
            stamps = np.ascontiguousarray(stamps, dtype=np.float64)
        object.__setattr__(self, "world_from_body", np.ascontiguousarray(poses, dtype=np.float64))
        object.__setattr__(self, "stamps_s", stamps)
        object.__setattr__(self, "path", os.fspath(self.path))

    def __len__(self) -> int:
        """Number of poses M."""
        return int(self.world_from_body.shape[0])


def read_trajectory(
    path: PathLike,
    *,
    format: str | None = None,  # noqa: A002
    rotation_tolerance: float = DEFAULT_ROTATION_TOLERANCE,
) -> Trajectory:
    """Read poses (and times, for TUM) from a KITTI or TUM trajectory file.

    Args:
        path: the text file.
        format: one of :data:`POSE_FORMATS`, or ``None`` to tell it by the number of
            values on the first pose line.
        rotation_tolerance: largest ``max |R^T R - I|`` (KITTI) or ``| |q| - 1 |`` (TUM)
            accepted as rigid; finite and > 0.

    Returns:
        A :class:`Trajectory` with at least one pose.

    Raises:
        FileFormatError: the file is missing, empty, not text, has a line with the wrong
            number of values, a value that is not a finite number, a pose that is not
            rigid or lies beyond 1000 km of the origin, or (TUM) a time that does not
            increase. The message names the line
            and ends with the path.
        InputError: ``path`` is not a path or ``format`` is unknown.
        ConfigError: ``rotation_tolerance`` is not a finite number > 0.
    """
    if format is not None and format not in POSE_FORMATS:
        raise InputError(f"format: expected None or one of {list(POSE_FORMATS)}, got {format!r}")
    tolerance = _checked_tolerance(rotation_tolerance)
    file_path = _as_path(path, "path")
    _check_readable_file(file_path, "pose file")
    line_numbers, table = _read_table(file_path, format)
    kind = format or _FORMAT_BY_COLUMNS[table.shape[1]]
    if kind == "kitti":
        poses = np.zeros((table.shape[0], 4, 4))
        poses[:, :3, :] = table.reshape(-1, 3, 4)
        poses[:, 3, 3] = 1.0
        _check_rotations(poses[:, :3, :3], tolerance, line_numbers, file_path)
        stamps = None
    else:
        stamps = table[:, 0].copy() if kind == "tum" else None
        values = table[:, 1:] if kind == "tum" else table
        poses = _poses_from_quaternions(values, tolerance, line_numbers, file_path)
        if stamps is not None:
            _check_stamps(stamps, line_numbers, file_path)
    _check_translations(poses[:, :3, 3], line_numbers, file_path)
    return Trajectory(world_from_body=poses, stamps_s=stamps, path=os.fspath(path), format=kind)


def read_poses(
    path: PathLike,
    *,
    format: str | None = None,  # noqa: A002
    rotation_tolerance: float = DEFAULT_ROTATION_TOLERANCE,
) -> np.ndarray:
    """The ``(M, 4, 4)`` ``float64`` ``world_from_body`` poses of a KITTI or TUM file.

    :func:`read_trajectory` without the times; same arguments and errors.
    """
    return read_trajectory(
        path, format=format, rotation_tolerance=rotation_tolerance
    ).world_from_body


# --------------------------------------------------------------------------- helpers


def _checked_tolerance(value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ConfigError(
            f"rotation_tolerance: expected a finite number > 0, got {type(value).__name__} "
            f"{value!r}"
        )
    result = float(value)
    if not math.isfinite(result) or result <= 0.0:
        raise ConfigError(f"rotation_tolerance: expected a finite number > 0, got {result!r}")
    return result


def _read_table(path: Path, kind: str | None) -> tuple[np.ndarray, np.ndarray]:
    """``(line numbers, values (M, C))`` of the pose lines; C from ``kind`` or line 1."""
    # A regular file (a FIFO, device or folder fails at once) of UTF-8 text.
    text = read_regular_text(path, "pose file", max_bytes=_MAX_POSE_FILE_BYTES)
    columns = POSE_FORMATS[kind] if kind is not None else None
    numbers_found: list[int] = []
    rows: list[list[str]] = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        tokens = stripped.replace(",", " ").split()
        if columns is None:
            if len(tokens) not in _FORMAT_BY_COLUMNS:
                raise FileFormatError(
                    f"poses line {line_no}: expected {_FORMATS_HELP}, got {len(tokens)} values: "
                    f"{path}"
                )
            columns = len(tokens)
        elif len(tokens) != columns:
            raise FileFormatError(
                f"poses line {line_no}: expected {columns} values like the lines before "
                f"({_FORMAT_BY_COLUMNS[columns]}), got {len(tokens)}: {path}"
            )
        numbers_found.append(line_no)
        rows.append(tokens)
    if not rows:
        raise FileFormatError(
            f"poses: expected at least one pose line, got only blank or comment lines: {path}"
        )
    line_numbers = np.array(numbers_found)
    try:
        table = np.array(rows, dtype=np.float64)
    except ValueError:
        table = None
    if table is None or not np.isfinite(table).all():
        bad_row = _first_bad_row(rows, table)
        raise FileFormatError(
            f"poses line {line_numbers[bad_row]}: expected finite numbers, got "
            f"{' '.join(rows[bad_row])[:120]!r}: {path}"
        )
    return line_numbers, table


def _first_bad_row(rows: list[list[str]], table: np.ndarray | None) -> int:
    if table is not None:
        return int(np.argmax(~np.isfinite(table).all(axis=1)))
    for index, tokens in enumerate(rows):  # only on error: find the line to name
        try:
            [float(token) for token in tokens]
        except ValueError:
            return index
    return 0


def _check_rotations(
    rotations: np.ndarray, tolerance: float, line_numbers: np.ndarray, path: Path
) -> None:
    gram = np.einsum("mji,mjk->mik", rotations, rotations)
    error = np.abs(gram - np.eye(3)).max(axis=(1, 2))
    bad = error > tolerance
    if bad.any():
        i = int(np.argmax(bad))
        raise FileFormatError(
            f"poses line {line_numbers[i]}: expected a rotation (max |R^T R - I| <= "
            f"{tolerance:g}), got {error[i]:.3g}: not a rigid transform: {path}"
        )
    det = np.linalg.det(rotations)
    bad = det <= 0.0
    if bad.any():
        i = int(np.argmax(bad))
        raise FileFormatError(
            f"poses line {line_numbers[i]}: expected a proper rotation (det R = +1), got det "
            f"{det[i]:.3g} (a reflection): {path}"
        )


def _check_translations(translations: np.ndarray, line_numbers: np.ndarray, path: Path) -> None:
    """Every position within the limit of poses (1000 km of the origin, as the core's)."""
    bad = np.abs(translations).max(axis=1) > _MAX_TRANSLATION_M
    if bad.any():
        i = int(np.argmax(bad))
        raise FileFormatError(
            f"poses line {line_numbers[i]}: expected a translation within {_MAX_TRANSLATION_M:g} m "
            f"of the origin, got {translations[i].tolist()} (re-centre the coordinates): {path}"
        )


def _poses_from_quaternions(
    values: np.ndarray, tolerance: float, line_numbers: np.ndarray, path: Path
) -> np.ndarray:
    """``(M, 4, 4)`` from rows ``tx ty tz qx qy qz qw``."""
    quaternion = values[:, 3:7]
    norm = np.linalg.norm(quaternion, axis=1)
    bad = np.abs(norm - 1.0) > tolerance
    if bad.any():
        i = int(np.argmax(bad))
        raise FileFormatError(
            f"poses line {line_numbers[i]}: expected a unit quaternion qx qy qz qw (| |q| - 1 "
            f"| <= {tolerance:g}), got |q| = {norm[i]:.6g}: {path}"
        )
    x, y, z, w = (quaternion / norm[:, None]).T
    poses = np.zeros((values.shape[0], 4, 4))
    poses[:, 0, 0] = 1 - 2 * (y * y + z * z)
    poses[:, 0, 1] = 2 * (x * y - z * w)
    poses[:, 0, 2] = 2 * (x * z + y * w)
    poses[:, 1, 0] = 2 * (x * y + z * w)
    poses[:, 1, 1] = 1 - 2 * (x * x + z * z)
    poses[:, 1, 2] = 2 * (y * z - x * w)
    poses[:, 2, 0] = 2 * (x * z - y * w)
    poses[:, 2, 1] = 2 * (y * z + x * w)
    poses[:, 2, 2] = 1 - 2 * (x * x + y * y)
    poses[:, :3, 3] = values[:, :3]
    poses[:, 3, 3] = 1.0
    return poses


def _check_stamps(stamps: np.ndarray, line_numbers: np.ndarray, path: Path) -> None:
    bad = np.diff(stamps) <= 0.0
    if bad.any():
        i = int(np.argmax(bad)) + 1
        raise FileFormatError(
            f"poses line {line_numbers[i]}: expected timestamps that increase, got "
            f"{stamps[i]!r} after {stamps[i - 1]!r} on line {line_numbers[i - 1]}: {path}"
        )
