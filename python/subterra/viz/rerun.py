"""Recording a flight to a Rerun file (``.rrd``), for the optional extra ``subterra[viz]``.

>>> from subterra.viz.rerun import RerunRecorder, rerun_available
>>> with RerunRecorder("flight.rrd", world=world) as rec:          # doctest: +SKIP
...     rec.log_frame(t_s, depth=depth_mm, world_from_camera=T, camera=camera,
...                   belief_points_world=p, belief_weights=w, position=xyz, command=cmd)

Open the file with ``rerun flight.rrd``. Each recorder owns its own
``rerun.RecordingStream`` (never the global one), so several can record at once.

Entities (world frame ENU, z up, metres; time on the ``sim_time`` timeline [s]):

* ``world/geometry/{cylinders,capsules,boxes,spheres,items,planes,terrain}`` (static):
  the world's primitives at their true size; planes as squares outlined over the
  world's extent; the height field as a mesh (holes left out).
* ``world/regions`` (static): the named regions as flat discs with labels;
  ``world/routes`` (static) arrows between them.
* ``world/camera``: ``world_from_camera``; ``world/camera/image``: the pinhole;
  ``world/camera/image/depth``: the depth image (uint16 mm or float32 m).
* ``world/belief``: the filter's belief as points in the world frame (size and colour
  by weight); ``world/robot``: the robot's position; ``world/path`` (static, written
  by :meth:`RerunRecorder.close`): the whole flown path.
* ``robot/command/{v_x,v_y,v_z,yaw_rate}`` and ``perception/p_free``: time series.
* Ground robot and terrain (:meth:`RerunRecorder.log_drive_step`,
  :meth:`RerunRecorder.log_cloud`): ``world/plan`` (the planned path),
  ``world/risk`` (the risk map's observed and lethal cells, green to red), ``world/cloud`` (the
  lidar scan, coloured by height) and ``robot/command/{v,yaw_rate}``.
"""

from __future__ import annotations

import math
import os
import uuid
from pathlib import Path
from types import ModuleType, TracebackType
from typing import Any

import numpy as np

from subterra._compat import tomllib
from subterra.errors import ConfigError, InputError

__all__ = ["RerunRecorder", "rerun_available"]

#: The timeline every frame is logged on [s].
TIMELINE = "sim_time"
#: Raw depth units of a uint16 image: millimetres (units per metre).
DEPTH_UNITS_PER_M_UINT16 = 1000.0
#: Height of the discs that show the named regions [m].
REGION_DISC_HEIGHT_M = 0.05
#: Radius of a solid mission item, a sphere in the simulator [m]. docs/world-format.md.
SOLID_ITEM_RADIUS_M = 0.15
#: Largest radius of a belief point, for the heaviest voxel [m]; lighter ones shrink to 30 %.
BELIEF_POINT_RADIUS_M = 0.05
#: Depth at which the viewer draws the camera's frustum [m].
FRUSTUM_DEPTH_M = 0.5
#: Radius of the robot's position marker and of the flown path's line [m].
ROBOT_RADIUS_M = 0.08
PATH_LINE_RADIUS_M = 0.02
#: A scan logged with :meth:`RerunRecorder.log_cloud` keeps at most this many points (an
#: even stride through the cloud): 20k points are ~0.3 MB in the file.
CLOUD_MAX_POINTS = 20_000
#: Radius of a logged lidar point [m].
CLOUD_POINT_RADIUS_M = 0.02
#: A plane is drawn as a square of this half-size [m] when the world has no bounded extent.
DEFAULT_PLANE_HALF_SIZE_M = 10.0

_INSTALL_HINT = "pip install 'subterra[viz]'"
_COMMAND_NAMES = ("v_x", "v_y", "v_z", "yaw_rate")
_OBSTACLE_RGBA = (150, 150, 150, 255)
_TAG_RGBA = {"wall": (110, 110, 110, 120), "cable": (180, 90, 30, 255), "pole": (160, 160, 170, 255)}
_REGION_RGBA = (60, 160, 90, 90)
_PLANE_RGBA = (120, 120, 120, 255)
_TERRAIN_RGBA = (140, 120, 100, 255)


def _import_rerun() -> ModuleType:
    try:
        import rerun as rr
    except ImportError as exc:
        raise ConfigError(f"Rerun recording needs the optional package rerun-sdk ({exc}); install it with: {_INSTALL_HINT}") from exc
    if not hasattr(rr, "RecordingStream") or not hasattr(rr.RecordingStream, "set_time"):
        version = getattr(rr, "__version__", "unknown")
        raise ConfigError(f"rerun-sdk {version} is too old (need >= 0.23 for RecordingStream.set_time); upgrade with: {_INSTALL_HINT}")
    return rr


def rerun_available() -> bool:
    """True if the optional Rerun SDK (``rerun-sdk``, extra ``subterra[viz]``) can be used."""
    try:
        _import_rerun()
    except ConfigError:
        return False
    return True


class RerunRecorder:
    """Writes one flight to a Rerun file (``.rrd``) at ``path`` (parent folders created).

    ``application_id`` names the recording in the viewer; ``world`` (a
    ``subterra.sim.World``), if given, is logged at once with :meth:`log_world`. Use it
    as a context manager, or call :meth:`close` to finish the file.

    ``depth_every``: log only every n-th depth image handed to :meth:`log_frame` (the
    first one included). A 640x480 uint16 frame costs about 0.5 MB in the file (Rerun
    stores it uncompressed; PNG halves a noisy frame at ~40 ms each), so a 60 s flight at
    15 Hz is ~430 MB with ``depth_every=1`` and ~90 MB with 5.

    Raises :class:`~subterra.errors.ConfigError` if ``rerun-sdk`` is not installed or
    ``depth_every`` is not an integer >= 1.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        application_id: str = "subterra",
        world: Any = None,
        depth_every: int = 1,
    ) -> None:
        if isinstance(depth_every, bool) or not isinstance(depth_every, (int, np.integer)) or depth_every < 1:
            raise ConfigError(f"argument `depth_every` must be an integer >= 1, got {depth_every!r}")
        self._depth_every = int(depth_every)
        self._depth_seen = 0
        self._rr = _import_rerun()
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._rec = self._rr.RecordingStream(application_id, recording_id=uuid.uuid4())
        self._rec.save(self.path)
        self._closed = False
        self._positions: list[np.ndarray] = []
        self._camera: tuple[float, ...] | None = None
        self._rec.log("world", self._rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        if world is not None:
            self.log_world(world)

    # ---------------------------------------------------------------- context manager

    def __enter__(self) -> RerunRecorder:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        """Logs the flown path (static), flushes and closes the file. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        if self._positions:
            strip = np.stack(self._positions)
            self._rec.log("world/path", self._rr.LineStrips3D([strip], radii=PATH_LINE_RADIUS_M, colors=[(30, 120, 220)]), static=True)
        self._rec.flush()
        self._rec.disconnect()

    def _check_open(self) -> None:
        if self._closed:
            raise InputError(f"RerunRecorder: the recorder is closed, cannot log more: {self.path}")

    # ---------------------------------------------------------------- world

    def log_world(self, world: Any) -> None:
        """Logs the world's geometry as static data: primitives at their true size, planes,
        the height field, mission items, named regions and routes."""
        self._check_open()
        to_toml = getattr(world, "to_toml", None)
        if to_toml is None:
            raise InputError(f"world: expected a subterra.sim.World, got {type(world).__name__}")
        spec = tomllib.loads(to_toml())
        rr, rec = self._rr, self._rec

        def log(entity: str, archetype: Any) -> None:
            rec.log(f"world/geometry/{entity}", archetype, static=True)

        for kind in ("cylinder", "capsule"):
            items = spec.get(kind, [])
            if not items:
                continue
            a = np.array([c["a"] for c in items], dtype=np.float64)
            b = np.array([c["b"] for c in items], dtype=np.float64)
            lengths = np.linalg.norm(b - a, axis=1)
            quats = [rr.Quaternion(xyzw=_quat_z_to(d)) for d in b - a]
            common = {
                "lengths": lengths,
                "radii": [c["radius"] for c in items],
                "quaternions": quats,
                "colors": [_colour(c) for c in items],
                "labels": [c.get("tag", "") for c in items],
                "show_labels": False,
            }
            if kind == "cylinder":
                log("cylinders", rr.Cylinders3D(centers=(a + b) / 2, **common))
            else:
                log("capsules", rr.Capsules3D(translations=a, **common))
        if spec.get("box"):
            boxes = spec["box"]
            log(
                "boxes",
                rr.Boxes3D(
                    centers=[bx["centre"] for bx in boxes],
                    half_sizes=[[s / 2 for s in bx["size"]] for bx in boxes],
                    rotation_axis_angles=[rr.RotationAxisAngle(axis=[0.0, 0.0, 1.0], radians=float(bx.get("yaw", 0.0))) for bx in boxes],
                    colors=[_colour(bx) for bx in boxes],
                    labels=[bx.get("tag", "") for bx in boxes],
                    show_labels=False,
                    fill_mode="solid",
                ),
            )
        spheres = list(spec.get("sphere", []))
        spheres += [
            {"centre": it["position"], "radius": SOLID_ITEM_RADIUS_M, "tag": it.get("kind", "")}
            for it in spec.get("item", [])
            if it.get("solid", False)
        ]
        if spheres:
            log(
                "spheres",
                rr.Ellipsoids3D(
                    centers=[s["centre"] for s in spheres],
                    radii=[s["radius"] for s in spheres],
                    colors=[_colour(s) for s in spheres],
                    fill_mode="solid",
                ),
            )
        if spec.get("item"):
            items = spec["item"]
            log(
                "items",
                rr.Points3D(
                    [it["position"] for it in items],
                    radii=[max(float(it.get("keep_out_radius", 0.0)), 0.05) for it in items],
                    colors=[(40, 180, 200, 80)],
                    labels=[it.get("kind", "") for it in items],
                ),
            )
        if spec.get("plane"):
            strips = [_plane_square(p, world) for p in spec["plane"]]
            log("planes", rr.LineStrips3D(strips, colors=[_PLANE_RGBA], labels=[p.get("tag", "") for p in spec["plane"]]))
        if spec.get("heightfield"):
            vertices, triangles = _terrain_mesh(spec["heightfield"])
            if triangles.shape[0] > 0:
                log("terrain", rr.Mesh3D(vertex_positions=vertices, triangle_indices=triangles, albedo_factor=_TERRAIN_RGBA))
        regions = spec.get("region", [])
        if regions:
            rec.log(
                "world/regions",
                rr.Cylinders3D(
                    centers=[r["centre"] for r in regions],
                    radii=[r["radius"] for r in regions],
                    lengths=[REGION_DISC_HEIGHT_M] * len(regions),
                    colors=[_REGION_RGBA],
                    labels=[r["name"] for r in regions],
                ),
                static=True,
            )
            centre = {r["name"]: np.asarray(r["centre"], dtype=np.float64) for r in regions}
            routes = [r for r in spec.get("route", []) if r["from"] in centre and r["to"] in centre]
            if routes:
                rec.log(
                    "world/routes",
                    rr.Arrows3D(
                        origins=[centre[r["from"]] for r in routes],
                        vectors=[centre[r["to"]] - centre[r["from"]] for r in routes],
                        labels=[r["name"] for r in routes],
                        colors=[(60, 160, 90, 160)],
                        radii=0.02,
                    ),
                    static=True,
                )

    # ---------------------------------------------------------------- frames

    def log_frame(
        self,
        time_s: float,
        *,
        depth: np.ndarray | None = None,
        world_from_camera: np.ndarray | None = None,
        camera: Any = None,
        belief_points_world: np.ndarray | None = None,
        belief_weights: np.ndarray | None = None,
        position: np.ndarray | None = None,
        command: np.ndarray | None = None,
        p_free: float | None = None,
    ) -> None:
        """Logs one control step at sim time ``time_s`` [s]; every other argument is optional.

        * ``depth``: (H, W) uint16 [mm] (0 = no return) or float32 [m] (0 or NaN = none);
          only every ``depth_every``-th one is written.
        * ``world_from_camera``: (4, 4) pose of the camera's optical frame (x right,
          y down, z forward) in the world.
        * ``camera``: a ``subterra.PinholeCamera``, logged when it changes; a depth image
          must match its size.
        * ``belief_points_world``: (N, 3) voxel centres in the world [m] and
          ``belief_weights`` (N,) their belief (point size and colour; uniform if None).
          An (0, 3) array clears the belief.
        * ``position``: (3,) the robot in the world [m]; ``command``: (4,)
          ``[v_x, v_y, v_z, yaw_rate]`` sent [m/s, rad/s]; ``p_free``: P(no obstacle).

        Raises :class:`InputError` on a wrong shape or dtype, or once closed.
        """
        self._check_open()
        t = _finite_float(time_s, "time_s")
        rr, rec = self._rr, self._rec
        # Validate everything before logging anything, so a bad frame logs nothing.
        if camera is not None:
            try:
                cam = tuple(float(getattr(camera, k)) for k in ("fx", "fy", "cx", "cy", "width", "height"))
            except (AttributeError, TypeError, ValueError):
                raise InputError(f"camera: expected a subterra.PinholeCamera, got {type(camera).__name__}") from None
        else:
            cam = self._camera
        if depth is not None:
            depth = np.asarray(depth)
            if depth.ndim != 2 or depth.dtype not in (np.uint16, np.float32):
                raise InputError(f"depth: expected an (H, W) uint16 [mm] or float32 [m] image, got {depth.dtype} of shape {depth.shape}")
            if cam is not None and depth.shape != (int(cam[5]), int(cam[4])):
                raise InputError(f"depth: the image is {depth.shape[1]}x{depth.shape[0]} but the camera is {int(cam[4])}x{int(cam[5])}")
        if world_from_camera is not None:
            world_from_camera = np.asarray(world_from_camera, dtype=np.float64)
            if world_from_camera.shape != (4, 4) or not np.all(np.isfinite(world_from_camera)):
                raise InputError(f"world_from_camera: expected a finite (4, 4) pose, got shape {world_from_camera.shape}")
        if belief_points_world is not None:
            belief_points_world = np.asarray(belief_points_world, dtype=np.float64)
            if belief_points_world.size == 0:
                belief_points_world = belief_points_world.reshape(0, 3)
            if belief_points_world.ndim != 2 or belief_points_world.shape[1] != 3:
                raise InputError(f"belief_points_world: expected an (N, 3) array [m], got shape {belief_points_world.shape}")
            if belief_weights is not None:
                belief_weights = np.asarray(belief_weights, dtype=np.float64)
                if belief_weights.shape != (belief_points_world.shape[0],):
                    raise InputError(
                        f"belief_weights: expected shape ({belief_points_world.shape[0]},) to match "
                        f"belief_points_world, got {belief_weights.shape}"
                    )
        elif belief_weights is not None:
            raise InputError("belief_weights: given without belief_points_world")
        if position is not None:
            position = _vector(position, 3, "position")
        if command is not None:
            command = _vector(command, 4, "command")
        if p_free is not None:
            p_free = _finite_float(p_free, "p_free")

        rec.set_time(TIMELINE, duration=t)
        if world_from_camera is not None:
            rec.log("world/camera", rr.Transform3D(translation=world_from_camera[:3, 3], mat3x3=world_from_camera[:3, :3]))
        if cam is not None and cam != self._camera:
            fx, fy, cx, cy, w, h = cam
            rec.log(
                "world/camera/image",
                rr.Pinhole(
                    focal_length=[fx, fy],
                    principal_point=[cx, cy],
                    resolution=[w, h],
                    camera_xyz=rr.ViewCoordinates.RDF,
                    image_plane_distance=FRUSTUM_DEPTH_M,
                ),
            )
            self._camera = cam
        if depth is not None:
            if self._depth_seen % self._depth_every == 0:
                meter = DEPTH_UNITS_PER_M_UINT16 if depth.dtype == np.uint16 else 1.0
                rec.log("world/camera/image/depth", rr.DepthImage(depth, meter=meter))
            self._depth_seen += 1
        if belief_points_world is not None:
            n = belief_points_world.shape[0]
            w = np.ones(n) if belief_weights is None else np.nan_to_num(belief_weights, nan=0.0)
            rel = w / w.max() if n and w.max() > 0 else np.ones(n)
            rec.log("world/belief", rr.Points3D(belief_points_world, radii=BELIEF_POINT_RADIUS_M * (0.3 + 0.7 * rel), colors=_heat(rel)))
        if position is not None:
            rec.log("world/robot", rr.Points3D([position], radii=ROBOT_RADIUS_M, colors=[(30, 120, 220)]))
            self._positions.append(position)
        if command is not None:
            for name, value in zip(_COMMAND_NAMES, command, strict=True):
                rec.log(f"robot/command/{name}", rr.Scalars(float(value)))
        if p_free is not None:
            rec.log("perception/p_free", rr.Scalars(p_free))


    def log_drive_step(
        self,
        time_s: float,
        *,
        position: np.ndarray | None = None,
        command: tuple[float, float] | np.ndarray | None = None,
        path: np.ndarray | None = None,
        risk_map: Any = None,
        z_m: float = 0.05,
    ) -> None:
        """Logs one step of a ground-robot drive at sim time ``time_s`` [s]: ``position``
        (3,) [m, world], ``command`` ``(v, ω)`` [m/s, rad/s], the planned ``path`` (N, 2)
        [m, world] drawn ``z_m`` above the ground plane, and a ``subterra.RiskMap`` as a
        coloured point grid of its observed and lethal cells (costly: log it every few steps)."""
        self._check_open()
        t = _finite_float(time_s, "time_s")
        rr, rec = self._rr, self._rec
        if position is not None:
            position = _vector(position, 3, "position")
        if command is not None:
            command = _vector(command, 2, "command")
        if path is not None:
            path = np.asarray(path, dtype=np.float64).reshape(-1, 2)
        rec.set_time(TIMELINE, duration=t)
        if position is not None:
            rec.log("world/robot", rr.Points3D([position], radii=ROBOT_RADIUS_M, colors=[(30, 120, 220)]))
            self._positions.append(position)
        if command is not None:
            rec.log("robot/command/v", rr.Scalars(float(command[0])))
            rec.log("robot/command/yaw_rate", rr.Scalars(float(command[1])))
        if path is not None and len(path) >= 2:
            rec.log("world/plan", rr.LineStrips3D([np.c_[path, np.full(len(path), z_m)]], radii=PATH_LINE_RADIUS_M, colors=[(250, 160, 0)]))
        if risk_map is not None:
            risk = risk_map.layer("risk")
            lethal = risk_map.lethal()
            seen = (risk_map.layer("observed") > 0) | lethal  # a lethal cell is never unknown
            iy, ix = np.nonzero(seen)
            ground = risk_map.layer("ground_height")[iy, ix]
            z = np.where(np.isfinite(ground), ground, 0.0) + z_m
            pts = np.c_[risk_map.x_centres[ix], risk_map.y_centres[iy], z]
            r = np.clip(risk[iy, ix], 0.0, 1.0)
            colours = np.c_[220 * r, 200 * (1 - r), np.zeros_like(r)].astype(np.uint8)
            colours[lethal[iy, ix]] = (220, 0, 0)  # red, as RiskMap.to_image draws a lethal cell
            rec.log("world/risk", rr.Points3D(pts, radii=0.45 * risk_map.resolution, colors=colours))


    def log_cloud(self, time_s: float, points_world: np.ndarray, *, max_points: int = CLOUD_MAX_POINTS) -> None:
        """Logs a lidar scan at ``time_s`` [s] as ``world/cloud``: ``points_world`` (N, 3)
        [m, world frame], coloured by height; clouds larger than ``max_points`` are thinned
        by an even stride (deterministic, every part of the scan kept)."""
        self._check_open()
        t = _finite_float(time_s, "time_s")
        if isinstance(max_points, bool) or not isinstance(max_points, (int, np.integer)) or max_points < 1:
            raise InputError(f"argument `max_points` must be an integer >= 1, got {max_points!r}")
        pts = np.asarray(points_world, dtype=np.float32)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InputError(f"argument `points_world` must have shape (N, 3), got {pts.shape}")
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if len(pts) > max_points:
            pts = pts[:: -(-len(pts) // max_points)]
        self._rec.set_time(TIMELINE, duration=t)
        if len(pts):
            z = pts[:, 2]
            lo, hi = np.percentile(z, [2, 98])
            colours = _heat(np.clip((z - lo) / max(hi - lo, 1e-6), 0.0, 1.0))
        else:
            colours = None
        self._rec.log("world/cloud", self._rr.Points3D(pts, radii=CLOUD_POINT_RADIUS_M, colors=colours))


# -------------------------------------------------------------------- helpers


def _finite_float(value: Any, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected a finite number, got {value!r}") from None
    if not math.isfinite(v):
        raise InputError(f"{name}: expected a finite number, got {v}")
    return v


def _vector(value: Any, n: int, name: str) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise InputError(f"{name}: expected a finite ({n},) array, got shape {v.shape}")
    return v


def _colour(item: dict[str, Any]) -> tuple[int, int, int, int]:
    return _TAG_RGBA.get(item.get("tag", ""), _OBSTACLE_RGBA)


def _heat(rel: np.ndarray) -> np.ndarray:
    """Colours from yellow (weight 0) to red (the heaviest), RGB uint8."""
    rel = np.clip(rel, 0.0, 1.0)
    return np.stack([np.full_like(rel, 255), 220 * (1.0 - rel), np.zeros_like(rel)], axis=1).astype(np.uint8)


def _quat_z_to(direction: np.ndarray) -> list[float]:
    """Unit quaternion (x, y, z, w) rotating +z onto ``direction`` (identity if it is zero)."""
    norm = float(np.linalg.norm(direction))
    if norm == 0.0:
        return [0.0, 0.0, 0.0, 1.0]
    d = direction / norm
    if d[2] < -1.0 + 1e-12:
        return [1.0, 0.0, 0.0, 0.0]  # half turn about x
    # q = (z x d, 1 + z.d), normalised: the half-angle construction.
    q = np.array([-d[1], d[0], 0.0, 1.0 + d[2]])
    return list(q / np.linalg.norm(q))


def _plane_square(plane: dict[str, Any], world: Any) -> np.ndarray:
    """A closed square on ``plane`` around the world's extent, as a (5, 3) line strip."""
    n = np.asarray(plane["normal"], dtype=np.float64)
    n = n / np.linalg.norm(n)
    p0 = np.asarray(plane["point"], dtype=np.float64)
    lo, hi = (np.asarray(b, dtype=np.float64) for b in world.bounds)
    if np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi >= lo):
        centre, half = (lo + hi) / 2, max(float(np.max(hi - lo)) / 2, 1.0)
    else:
        centre, half = p0, DEFAULT_PLANE_HALF_SIZE_M
    centre = centre - np.dot(centre - p0, n) * n
    u = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    corners = [centre + half * (su * u + sv * v) for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1), (-1, -1))]
    return np.array(corners)


def _terrain_mesh(hf: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (R*C, 3) and triangles (T, 3) of a height field, split along the (r, c) ->
    (r+1, c+1) diagonal as the simulator does; cells touching a hole are left out."""
    heights = np.array(hf["heights"], dtype=np.float64)
    if "hole_value" in hf:
        heights[heights == hf["hole_value"]] = np.nan
    rows, cols = heights.shape
    res = float(hf["resolution"])
    x0, y0 = hf["origin"]
    xs, ys = np.meshgrid(x0 + res * np.arange(cols), y0 + res * np.arange(rows))
    vertices = np.stack([xs, ys, np.nan_to_num(heights, nan=0.0)], axis=-1).reshape(-1, 3)
    idx = np.arange(rows * cols).reshape(rows, cols)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    ok = ~(np.isnan(heights[:-1, :-1]) | np.isnan(heights[:-1, 1:]) | np.isnan(heights[1:, :-1]) | np.isnan(heights[1:, 1:]))
    tri = np.concatenate([np.stack([a, b, d], axis=-1)[ok], np.stack([a, d, c], axis=-1)[ok]])
    return vertices.astype(np.float32), tri.astype(np.uint32)
