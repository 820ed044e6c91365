"""Reading real sensor data: depth images, camera intrinsics, point clouds and poses.

* :mod:`subterra.io.depth`: :func:`read_depth` (16-bit PNG, 16-bit binary PGM, ``.npy``,
  ``.npz``) returning a :class:`DepthImage` (``uint16`` raw units with a scale in
  metres per unit, or ``float32`` metres), :func:`list_depth_files` (natural order) and
  :func:`write_depth_png`.
* :mod:`subterra.io.intrinsics`: :class:`Intrinsics` (fx, fy, cx, cy [px], width,
  height [px]), :func:`read_intrinsics` (plain JSON, Open3D JSON, ROS
  camera_calibration YAML, ``sensor_msgs/CameraInfo`` dumps), :func:`intrinsics_from_dict`
  and the presets :data:`KNOWN_CAMERAS`.
* :mod:`subterra.io.clouds`: :func:`read_cloud` (PCD ascii / binary /
  binary_compressed, PLY ascii / binary, KITTI ``.bin``, ``.npy``) returning a
  :class:`PointCloud` (``float32`` ``(N, 3)`` points [m], NaN points kept, and the
  other per-point fields as separate arrays); :func:`write_pcd` and :func:`write_ply`.
* :mod:`subterra.io.poses`: :func:`read_trajectory` (KITTI 3x4 poses, TUM ``t tx ty tz
  qx qy qz qw``) returning a :class:`Trajectory` (``world_from_body`` ``(M, 4, 4)``
  and the times for TUM), and :func:`read_poses` (the poses alone); every pose is
  checked to be rigid.

* :mod:`subterra.io.recordings`: :func:`open_recording` (ROS 1 ``.bag``, ROS 2 bags with
  sqlite3 or MCAP storage, plain MCAP with ROS 1 or ROS 2 encoding) returning a
  :class:`Recording` (topics, messages in log-time order); :class:`McapWriter` (ROS 2
  MCAP) and :func:`write_bag`.
* :mod:`subterra.io.ros`: ROS messages <-> NumPy: ``Image``, ``CameraInfo``,
  ``PointCloud2`` (any layout), ``Odometry``, ``tf`` (:class:`TransformBuffer`).

This package needs NumPy, Pillow and PyYAML (and ``rosbags`` / ``mcap`` for recordings,
imported when used), not the compiled core. Every error is
a :class:`subterra.errors.SubterraError`; a bad file raises
:class:`subterra.errors.FileFormatError` whose message ends with the path.
"""

from __future__ import annotations

from .clouds import (
    CLOUD_EXTENSIONS,
    CLOUD_FORMATS,
    PointCloud,
    read_cloud,
    write_pcd,
    write_ply,
)
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
from .poses import (
    DEFAULT_ROTATION_TOLERANCE,
    POSE_FORMATS,
    Trajectory,
    read_poses,
    read_trajectory,
)
from .recordings import McapWriter, RecordedMessage, Recording, TopicInfo, open_recording, write_bag
from .ros import (
    CloudMessage,
    OdometrySample,
    TransformBuffer,
    decode_camera_info,
    decode_depth_image,
    decode_image,
    decode_odometry,
    decode_pointcloud2,
    decode_transforms,
)

__all__ = [
    "CLOUD_EXTENSIONS",
    "CLOUD_FORMATS",
    "DEFAULT_ROTATION_TOLERANCE",
    "DEFAULT_UINT16_SCALE_M_PER_UNIT",
    "DEPTH_EXTENSIONS",
    "INTRINSICS_EXTENSIONS",
    "KNOWN_CAMERAS",
    "POSE_FORMATS",
    "CloudMessage",
    "DepthImage",
    "Intrinsics",
    "McapWriter",
    "OdometrySample",
    "RecordedMessage",
    "Recording",
    "TopicInfo",
    "TransformBuffer",
    "decode_camera_info",
    "decode_depth_image",
    "decode_image",
    "decode_odometry",
    "decode_pointcloud2",
    "decode_transforms",
    "open_recording",
    "write_bag",
    "PointCloud",
    "Trajectory",
    "intrinsics_from_dict",
    "list_depth_files",
    "read_cloud",
    "read_depth",
    "read_intrinsics",
    "read_poses",
    "read_trajectory",
    "write_depth_png",
    "write_pcd",
    "write_ply",
]
