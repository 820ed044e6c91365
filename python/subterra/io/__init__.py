"""Reading real sensor data: depth images and camera intrinsics.

* :mod:`subterra.io.depth`: :func:`read_depth` (16-bit PNG, 16-bit binary PGM, ``.npy``,
  ``.npz``) returning a :class:`DepthImage` (``uint16`` raw units with a scale in
  metres per unit, or ``float32`` metres), :func:`list_depth_files` (natural order) and
  :func:`write_depth_png`.
* :mod:`subterra.io.intrinsics`: :class:`Intrinsics` (fx, fy, cx, cy [px], width,
  height [px]), :func:`read_intrinsics` (plain JSON, Open3D JSON, ROS
  camera_calibration YAML, ``sensor_msgs/CameraInfo`` dumps), :func:`intrinsics_from_dict`
  and the presets :data:`KNOWN_CAMERAS`.

This package needs only NumPy, Pillow and PyYAML, not the compiled core. Every error is
a :class:`subterra.errors.SubterraError`; a bad file raises
:class:`subterra.errors.FileFormatError` whose message ends with the path.
"""

from __future__ import annotations

from .depth import (
    DEFAULT_UINT16_SCALE_M_PER_UNIT,
    DEPTH_EXTENSIONS,
    DepthImage,
    list_depth_files,
    read_depth,
    write_depth_png,
)
from .intrinsics import (
    INTRINSICS_EXTENSIONS,
    KNOWN_CAMERAS,
    Intrinsics,
    intrinsics_from_dict,
    read_intrinsics,
)

__all__ = [
    "DEFAULT_UINT16_SCALE_M_PER_UNIT",
    "DEPTH_EXTENSIONS",
    "INTRINSICS_EXTENSIONS",
    "KNOWN_CAMERAS",
    "DepthImage",
    "Intrinsics",
    "intrinsics_from_dict",
    "list_depth_files",
    "read_depth",
    "read_intrinsics",
    "write_depth_png",
]
