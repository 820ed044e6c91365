"""An MCAP file of what the pipelines computed, for Foxglove (and ``ros2 bag play``).

:class:`FoxgloveWriter` writes ROS 2 messages (CDR encoding, ``ros2msg`` schemas, the
message definitions of ROS 2 Humble) through :class:`subterra.io.recordings.McapWriter`:

================================  ==================================  =====================
topic                             type                                frame
================================  ==================================  =====================
``/subterra/cmd``                 ``geometry_msgs/msg/TwistStamped``  body (``base_link``)
``/subterra/belief``              ``visualization_msgs/msg/MarkerArray``  body
``/subterra/risk``                ``nav_msgs/msg/OccupancyGrid``      world (``odom``)
``/subterra/risk_fine``           ``nav_msgs/msg/OccupancyGrid``      world
``/subterra/layers/<name>``       ``sensor_msgs/msg/Image`` 32FC1     world
``/subterra/path``                ``nav_msgs/msg/Path``               world
``/tf``                           ``tf2_msgs/msg/TFMessage``          world -> body
``/tf_static``                    ``tf2_msgs/msg/TFMessage``          body -> sensor
================================  ==================================  =====================

* Commands: ``linear = (v_x, v_y, v_z)`` [m/s], ``angular.z = yaw_rate`` [rad/s], in the
  body frame (FLU).
* Belief: marker 0 is a ``SPHERE_LIST`` of the voxel centres with non-zero belief
  (colour yellow -> red and opacity by belief relative to the largest), marker 1 a
  ``TEXT_VIEW_FACING`` with ``P(free)``.
* Risk: ``OccupancyGrid`` with Nav2's meaning: 100 for a lethal cell (risk at or above
  the map's ``lethal_risk``, observed or not: never -1, which Nav2 reads as unknown),
  ``round(100 r)`` up to 99 for the other observed cells, -1 where the cell was never
  observed; ``info.origin`` is the corner of cell (0, 0) (the map's
  lowest x and y), rows along world y, as the ROS convention wants.
* Layers: one 32FC1 image per layer (NaN = no value), ``grid_map`` style, drawn as a top
  view: column = world x increasing to the right, row 0 = the largest world y (north
  up), so an image panel shows the map as the PNG figures do.
* Path: the body's poses in the world, one every ``path_spacing_m``, published at most
  once per ``path_period_ns`` of log time and when the file is closed.

Every message's ``header.stamp`` is the stamp of the input message it was computed from,
and its log time is that input message's log time, so the output lines up with the
recording when both are opened in Foxglove.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from typing import Any

import numpy as np

from subterra.errors import InputError
from subterra.io import ros
from subterra.io.recordings import McapWriter
from subterra.io.ros import occupancy_values

__all__ = [
    "DEFAULT_BODY_FRAME",
    "DEFAULT_WORLD_FRAME",
    "FoxgloveWriter",
    "TOPICS",
    "occupancy_values",
    "layer_image",
]

#: Body frame when the recording names none (REP 105).
DEFAULT_BODY_FRAME = "base_link"
#: World frame when the recording names none (REP 105: the odometry frame).
DEFAULT_WORLD_FRAME = "odom"

#: Output topic names.
TOPICS = {
    "cmd": "/subterra/cmd",
    "belief": "/subterra/belief",
    "risk": "/subterra/risk",
    "risk_fine": "/subterra/risk_fine",
    "layers": "/subterra/layers/",
    "path": "/subterra/path",
    "tf": "/tf",
    "tf_static": "/tf_static",
}

#: Path: keep a pose when the body moved this far from the last kept one [m].
DEFAULT_PATH_SPACING_M = 0.05
#: Path: publish at most once per this much log time [ns].
DEFAULT_PATH_PERIOD_NS = 1_000_000_000


def layer_image(layer: np.ndarray) -> np.ndarray:
    """A ``(ny, nx)`` map layer (row iy along world y) as a top-view ``float32`` image
    (row 0 = the largest y)."""
    return np.ascontiguousarray(np.asarray(layer, dtype=np.float32)[::-1])


class FoxgloveWriter:
    """Writes the pipeline outputs of a replay to an MCAP file (see the module doc).

    Args:
        path: the ``.mcap`` file (parent folders are created).
        world_frame: frame of maps, paths and poses (default ``odom``).
        body_frame: frame of commands and the belief (default ``base_link``).
        layers: map layers written as images (None: all, ``()``: none).
        path_spacing_m, path_period_ns: thinning of the published path.

    Use it as a context manager or call :meth:`close` (in a ``finally``): the file is
    complete and readable only after it.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        world_frame: str = DEFAULT_WORLD_FRAME,
        body_frame: str = DEFAULT_BODY_FRAME,
        layers: Iterable[str] | None = None,
        path_spacing_m: float = DEFAULT_PATH_SPACING_M,
        path_period_ns: int = DEFAULT_PATH_PERIOD_NS,
    ) -> None:
        if not world_frame or not body_frame or world_frame == body_frame:
            raise InputError(f"frames: expected two different non-empty frame ids, got world {world_frame!r}, body {body_frame!r}")
        self.world_frame = world_frame
        self.body_frame = body_frame
        self.layers = None if layers is None else tuple(layers)
        self.path_spacing_m = float(path_spacing_m)
        self.path_period_ns = int(path_period_ns)
        self._out = McapWriter(path)
        self._ts = self._out._store
        self.path = self._out.path
        self._path_poses: list[tuple[int, np.ndarray]] = []
        self._path_published_ns: int | None = None
        self._path_dirty = False
        self._last_log_ns = 0

    # ------------------------------------------------------------------ plumbing

    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic."""
        return dict(self._out.counts)

    def _write(self, topic: str, msg: Any, log_ns: int) -> None:
        self._out.write(topic, msg, log_time_ns=log_ns)
        self._last_log_ns = max(self._last_log_ns, int(log_ns))

    def close(self) -> None:
        """Publishes the final path and finishes the file; safe to call twice."""
        if self._out.closed:
            return
        try:
            if self._path_dirty:
                self._publish_path(self._last_log_ns)
        finally:
            self._out.close()

    def __enter__(self) -> FoxgloveWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ depth pipeline

    def command(self, log_ns: int, stamp: int, v_x: float, v_y: float, v_z: float, yaw_rate: float) -> None:
        """``TwistStamped`` on ``/subterra/cmd`` in the body frame [m/s, rad/s]."""
        msg = ros.twist_stamped_message((v_x, v_y, v_z), (0.0, 0.0, yaw_rate), stamp_ns=stamp, frame_id=self.body_frame, typestore=self._ts)
        self._write(TOPICS["cmd"], msg, log_ns)

    def belief(self, log_ns: int, stamp: int, centres_body: np.ndarray, probabilities: np.ndarray, p_free: float | None = None) -> None:
        """``MarkerArray`` on ``/subterra/belief``: voxel centres [m, body frame] with their belief."""
        msg = ros.belief_markers_message(centres_body, probabilities, stamp_ns=stamp, frame_id=self.body_frame, p_free=p_free,
                                         typestore=self._ts)
        self._write(TOPICS["belief"], msg, log_ns)

    # ------------------------------------------------------------------ terrain pipeline

    def risk_map(self, log_ns: int, stamp: int, risk_map: Any, *, topic: str | None = None, with_layers: bool = True) -> None:
        """The combined risk of a ``subterra.RiskMap`` as an ``OccupancyGrid`` (``topic``,
        default ``/subterra/risk``) and, with ``with_layers``, its layers as images."""
        grid = ros.occupancy_grid_message(risk_map, stamp_ns=stamp, frame_id=self.world_frame, typestore=self._ts)
        self._write(topic or TOPICS["risk"], grid, log_ns)
        if not with_layers:
            return
        names = risk_map.layer_names if self.layers is None else [n for n in self.layers if n in risk_map.layer_names]
        for name in names:
            image = layer_image(risk_map.layer(name))
            msg = ros.image_message(image, stamp_ns=stamp, frame_id=self.world_frame, encoding="32FC1", typestore=self._ts)
            self._write(TOPICS["layers"] + name, msg, log_ns)

    # ------------------------------------------------------------------ poses

    def static_transform(self, log_ns: int, stamp: int, parent: str, child: str, parent_from_child: np.ndarray) -> None:
        """One transform on ``/tf_static``."""
        self._write(TOPICS["tf_static"], ros.tf_message([(parent, child, stamp, parent_from_child)], self._ts), log_ns)

    def pose(self, log_ns: int, stamp: int, world_from_body: np.ndarray) -> None:
        """The body's pose: ``/tf`` (world -> body) and the path (published at most once
        per ``path_period_ns``)."""
        m = np.asarray(world_from_body, dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise InputError(f"world_from_body: expected a finite 4x4 pose, got shape {m.shape}")
        self._write(TOPICS["tf"], ros.tf_message([(self.world_frame, self.body_frame, stamp, m)], self._ts), log_ns)
        if not self._path_poses or np.linalg.norm(m[:3, 3] - self._path_poses[-1][1][:3, 3]) >= self.path_spacing_m:
            self._path_poses.append((stamp, m))
            self._path_dirty = True
        if self._path_dirty and (self._path_published_ns is None or log_ns - self._path_published_ns >= self.path_period_ns):
            self._publish_path(log_ns)

    def _publish_path(self, log_ns: int) -> None:
        stamp = self._path_poses[-1][0] if self._path_poses else 0
        msg = ros.path_message(self._path_poses, stamp_ns=stamp, frame_id=self.world_frame, typestore=self._ts)
        self._write(TOPICS["path"], msg, log_ns)
        self._path_published_ns = int(log_ns)
        self._path_dirty = False
