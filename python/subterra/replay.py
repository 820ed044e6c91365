"""``subterra replay RECORDING``: run a pipeline over a ROS bag or an MCAP file.

With no topics, lists the recording's topics (name, type, count). Otherwise runs

* ``--pipeline depth`` (``--depth-topic``, ``--info-topic``): APF-PF
  (:class:`subterra.DepthPerception` + :class:`subterra.ApfController`) on every depth
  image, in log-time order. The camera is the first ``CameraInfo``; ``body_from_camera``
  comes from ``/tf_static`` when the recording links the body frame to the image's frame,
  else the forward-looking default. The goal: with ``--odom-topic``, ``--goal`` is a point
  in the odometry's world frame (default 5 m ahead of the first pose), turned into the
  body frame with the pose at each image's stamp; without odometry, ``--goal`` is fixed in
  the body frame (default 5 m straight ahead).
* ``--pipeline terrain`` (``--cloud-topic``): :class:`subterra.TerrainMapper` on every
  cloud. Poses ``world_from_body`` from ``--odom-topic`` (interpolated at each cloud's
  stamp), else from ``/tf`` (world frame -> body frame), else the identity (a robot
  standing still); ``body_from_sensor`` from ``/tf_static`` when it links the body frame to
  the cloud's frame, else ``--sensor-height``, else the height estimated from the first
  cloud.

and writes to ``--out``: the figures of the simulated runs (depth: ``perception.png``;
terrain: the layer PNGs, ``risk.png``, ``overview.png``, ...), ``summary.json`` (what was
used, per-message timings: read, decode, pipeline, write) and ``replay.mcap``
(:mod:`subterra.viz.foxglove`: commands, belief markers, risk grids, layer images, path,
tf), plus ``replay.rrd`` when ``rerun-sdk`` is installed.

The MCAP is written as the replay goes and closed in a ``finally``: when the recording
turns out to be corrupt half-way (or a message is bad), the error is raised after the MCAP
and a ``summary.json`` with ``"error"`` have been written for the messages before it.

Frames: the output's world frame is the odometry's ``frame_id`` (``--world-frame``,
default ``odom``), its body frame the odometry's ``child_frame_id`` (``--body-frame``,
default ``base_link``), as REP 105 names them.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from subterra.errors import FileFormatError, InputError, SubterraError

__all__ = [
    "DEFAULT_GOAL_AHEAD_M",
    "DEFAULT_LAYERS",
    "PIPELINES",
    "layer_names",
    "register_cli",
    "replay",
    "run_cli",
]

PIPELINES = ("depth", "terrain")
#: Default goal: this far straight ahead of the body [m] (at the first pose with odometry).
DEFAULT_GOAL_AHEAD_M = 5.0
#: ``body_from_camera`` of a camera looking along the body's x axis from its origin (optical
#: z = body x, optical x = body -y, optical y = body -z): the mounting when the recording's
#: TF does not give one.
_FORWARD_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
#: Map layers written as images to the output MCAP unless ``--layers`` says otherwise.
DEFAULT_LAYERS = (
    "ground_height", "collision", "step", "negative", "tilt", "roughness", "unknown", "mission", "risk", "risk_variance",
)
#: Poses further than this from the nearest odometry / tf sample are not used [ns].
POSE_TOLERANCE_NS = 500_000_000
#: Depth images written to the Rerun file: one in this many.
RERUN_DEPTH_EVERY = 5
#: The terrain pipeline logs the risk map into replay.rrd every n-th scan (40k cells each).
RERUN_RISK_EVERY = 5

_IMAGE = "sensor_msgs/msg/Image"
_INFO = "sensor_msgs/msg/CameraInfo"
_CLOUD = "sensor_msgs/msg/PointCloud2"
_ODOM = "nav_msgs/msg/Odometry"
_TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")


# ---------------------------------------------------------------------- helpers


def _timed(it: Iterator[Any]) -> Iterator[tuple[Any, float]]:
    """Each item of ``it`` with the seconds spent getting it (reading + deserialising)."""
    while True:
        t0 = time.perf_counter()
        try:
            item = next(it)
        except StopIteration:
            return
        yield item, time.perf_counter() - t0


def _stamp(msg: Any, log_ns: int) -> int:
    """The header stamp [ns], or the log time when the header has none (stamp 0)."""
    from subterra.io.ros import stamp_ns

    try:
        s = stamp_ns(msg)
    except SubterraError:
        return log_ns
    return s if s > 0 else log_ns


def _median_ms(values: Sequence[float]) -> float | None:
    return float(np.median(values) * 1e3) if len(values) else None


def _timing(times: list[tuple[float, float, float, float]]) -> dict[str, Any]:
    """The medians of the per-message (read, decode, pipeline, write) seconds, in ms."""
    read, decode, pipeline, write = (np.array([t[i] for t in times]) for i in range(4))
    out = {
        "read_ms_median": _median_ms(read),
        "decode_ms_median": _median_ms(decode),
        "pipeline_ms_median": _median_ms(pipeline),
        "write_ms_median": _median_ms(write),
    }
    if times:
        ingest = read + decode
        out["read_decode_ms_median"] = float(np.median(ingest) * 1e3)
        out["read_decode_percent_of_pipeline"] = float(100.0 * np.median(ingest) / np.median(pipeline))
    return out


class _Context:
    """What the pre-pass learns: odometry poses, tf, and the frames to use."""

    def __init__(self) -> None:
        from subterra.io.ros import PoseTrack, TransformBuffer

        self.track = PoseTrack(POSE_TOLERANCE_NS)
        self.tf = TransformBuffer(POSE_TOLERANCE_NS)
        self.odom_frames: tuple[str, str] | None = None
        self.tf_messages = 0
        self.odom_messages = 0
        #: The recording broke off (or a message was corrupt) during the pre-pass: the poses
        #: and tf before it are kept, the replay runs up to the break and reports it.
        self.error: FileFormatError | None = None


def _pre_pass(rec: Any, odom_topic: str | None) -> _Context:
    from subterra.io.ros import decode_odometry

    ctx = _Context()
    tf_topics = [t.name for t in rec.topics.values() if t.type in _TF_TYPES]
    topics = tf_topics + ([odom_topic] if odom_topic else [])
    if not topics:
        return ctx
    try:
        for topic, log_ns, msg in rec.messages(topics):
            where = f"{topic} at log time {log_ns} ns"
            if topic == odom_topic:
                sample = decode_odometry(msg, where=where)
                ctx.track.add(sample.stamp_ns if sample.stamp_ns > 0 else log_ns, sample.world_from_body)
                ctx.odom_frames = ctx.odom_frames or (sample.frame_id.lstrip("/"), sample.child_frame_id.lstrip("/"))
                ctx.odom_messages += 1
            else:
                ctx.tf_messages += 1
                ctx.tf.add_message(msg, static=topic.endswith("tf_static"), where=where)
    except FileFormatError as exc:  # a truncated or corrupt file: use what came before the break
        ctx.error = exc
    if odom_topic and ctx.odom_messages == 0:
        raise InputError(f"--odom-topic {odom_topic!r} has no messages: {rec.path}")
    return ctx


def _frames(ctx: _Context, world_frame: str | None, body_frame: str | None) -> tuple[str, str]:
    from subterra.viz.foxglove import DEFAULT_BODY_FRAME, DEFAULT_WORLD_FRAME

    world = world_frame or (ctx.odom_frames[0] if ctx.odom_frames and ctx.odom_frames[0] else DEFAULT_WORLD_FRAME)
    body = body_frame or (ctx.odom_frames[1] if ctx.odom_frames and ctx.odom_frames[1] else DEFAULT_BODY_FRAME)
    return world.lstrip("/"), body.lstrip("/")


def _mount(ctx: _Context, body: str, sensor_frame: str) -> np.ndarray | None:
    """``body_from_sensor`` from static tf, or None when tf does not link the two."""
    sensor_frame = sensor_frame.lstrip("/")
    if not sensor_frame or sensor_frame == body or not ctx.tf.static_only(body, sensor_frame):
        return None
    return ctx.tf.lookup(body, sensor_frame)


def _pose(ctx: _Context, world: str, body: str, stamp: int, odom: bool) -> np.ndarray | None:
    if odom:
        return ctx.track.at(stamp)
    if world in ctx.tf.frames and body in ctx.tf.frames:
        try:
            return ctx.tf.lookup(world, body, stamp)
        except InputError:
            return None
    return None


def _with_context(exc: SubterraError, where: str) -> SubterraError:
    """The same kind of error, with where it happened appended (the path stays last)."""
    new = type(exc)(f"{exc} (at {where})")
    new.__cause__ = exc
    return new


def _progress(total: int, desc: str, enabled: bool):
    from subterra._extras import tqdm

    return tqdm(total=total, desc=desc, unit="msg", leave=False, disable=None if enabled else True)


# ---------------------------------------------------------------------- entry point


def replay(
    recording: str | Path,
    out: str | Path,
    *,
    pipeline: str | None = None,
    depth_topic: str | None = None,
    info_topic: str | None = None,
    cloud_topic: str | None = None,
    odom_topic: str | None = None,
    goal: Sequence[float] | None = None,
    preset: str = "flight",
    config: Any = None,
    terrain_config: Any = None,
    scale: float | None = None,
    seed: int = 0,
    world_frame: str | None = None,
    body_frame: str | None = None,
    sensor_height: float | None = None,
    layers: Sequence[str] | None = DEFAULT_LAYERS,
    max_messages: int | None = None,
    rerun: bool | None = None,
    plots: bool = True,
    progress: bool = True,
) -> dict[str, Any]:
    """Runs ``pipeline`` over ``recording`` and writes the run folder ``out``; returns the summary.

    ``pipeline`` None is inferred from the topics given. ``layers``: terrain layers
    written as images (None: all). ``max_messages``: stop after that many images or
    clouds. ``rerun``: write ``replay.rrd`` (None = when ``rerun-sdk`` is
    installed).

    Raises:
        InputError: a topic is missing (the message lists the topics present) or of the
            wrong type; the image size differs from the ``CameraInfo``'s; a cloud is
            empty; bad arguments.
        FileFormatError: the recording is truncated, corrupt or of an unknown encoding.
    """
    from subterra.io.recordings import open_recording

    pipeline = _pipeline(pipeline, depth_topic, info_topic, cloud_topic)
    if max_messages is not None and max_messages < 1:
        raise InputError(f"argument `--max-messages` must be >= 1, got {max_messages}")
    if goal is not None:
        goal = np.asarray(goal, dtype=np.float64)
        if goal.shape != (3,) or not np.all(np.isfinite(goal)):
            raise InputError(f"argument `--goal` must be three finite numbers x,y,z [m], got {goal.tolist()}")
    if pipeline == "terrain" and layers is not None:
        known = layer_names()
        unknown = [name for name in layers if name not in known]
        if unknown:
            raise InputError(f"argument --layers: unknown layer {unknown[0]!r} (known: {', '.join(known)}; or 'all', 'none')")
    if pipeline == "depth" and config is None:
        from subterra import preset_names

        if preset not in preset_names():
            raise InputError(f"argument --preset: unknown preset {preset!r} (known: {', '.join(preset_names())})")
    out = Path(out)
    with open_recording(recording) as rec:
        steps: _Steps
        if pipeline == "depth":
            steps = _DepthSteps(rec, depth_topic, info_topic, odom_topic, goal, preset, config, scale, seed, world_frame, body_frame)
        else:
            steps = _TerrainSteps(rec, cloud_topic, odom_topic, terrain_config, world_frame, body_frame, sensor_height, layers)
        return _run(rec, out, steps, max_messages=max_messages, rerun=rerun, plots=plots, progress=progress)


@functools.cache
def layer_names() -> tuple[str, ...]:
    """The names of a ``subterra.RiskMap``'s layers (what ``--layers`` may name)."""
    from subterra import TerrainMapper

    m = TerrainMapper().update(np.array([[1.0, 0.0, 0.0]], np.float32), stamp=0.0, world_from_body=np.eye(4), body_from_sensor=np.eye(4))
    return tuple(m.layer_names)


def _pipeline(pipeline: str | None, depth_topic: str | None, info_topic: str | None, cloud_topic: str | None) -> str:
    if pipeline is not None and pipeline not in PIPELINES:
        raise InputError(f"argument `--pipeline` must be depth or terrain, got {pipeline!r}")
    depth_given = depth_topic is not None or info_topic is not None
    if depth_given and cloud_topic is not None:
        raise InputError("give --depth-topic/--info-topic (depth pipeline) or --cloud-topic (terrain pipeline), not both")
    inferred = "depth" if depth_given else "terrain" if cloud_topic is not None else None
    if pipeline is None:
        pipeline = inferred
    if pipeline is None:
        raise InputError("no topic given: --depth-topic and --info-topic (depth) or --cloud-topic (terrain)")
    if pipeline == "depth" and (depth_topic is None or info_topic is None):
        raise InputError("--pipeline depth needs both --depth-topic (sensor_msgs/Image) and --info-topic (sensor_msgs/CameraInfo)")
    if pipeline == "terrain" and cloud_topic is None:
        raise InputError("--pipeline terrain needs --cloud-topic (sensor_msgs/PointCloud2)")
    return pipeline


# ---------------------------------------------------------------------- the replay loop


class _Steps:
    """What differs between the pipelines; :func:`_run` owns the loop around it.

    ``__init__`` checks the topics and runs the pre-pass, before anything is written. Then, for
    each message of ``topic``: ``decode(msg, stamp, where)`` (timed as decode) gives the data;
    ``prepare(msg, data, log_ns, stamp, writer)`` sets up on the first message and finds the
    pose; ``run(data, stamp)`` (timed as pipeline) gives the result;
    ``write(writer, recorder, index, log_ns, stamp, data, result)`` (timed as write) writes it to
    ``replay.mcap`` and ``replay.rrd`` (``recorder`` None: none) and returns the message's record.
    At the end ``summary(records, out, plots)`` writes the figures and gives the pipeline's keys
    of the summary: those on what was used, and those on what came out (ending with ``figures``).
    """

    pipeline: str  # the summary's "pipeline"; the progress bar says "replay <pipeline>"
    layers: Sequence[str] | None = ()  # terrain layers written as images to replay.mcap (None: all)
    allow_nan = True  # json.dumps's allow_nan for summary.json

    def __init__(self, rec: Any, topic: str, count: int, topics: dict[str, str | None], odom_topic: str | None,
                 world_frame: str | None, body_frame: str | None) -> None:
        self.path: Path = rec.path
        self.topic, self.count, self.topics = topic, count, topics
        self.odom = odom_topic is not None
        self.ctx = _pre_pass(rec, odom_topic)
        self.world, self.body = _frames(self.ctx, world_frame, body_frame)


def _run(rec: Any, out: Path, steps: _Steps, *, max_messages: int | None, rerun: bool | None, plots: bool,
         progress: bool) -> dict[str, Any]:
    """Runs ``steps`` over the messages of ``steps.topic``, writes the run folder ``out``; returns the summary.

    A :class:`SubterraError` (a truncated recording, a bad message) ends the replay: ``replay.mcap``
    is finished and ``summary.json`` written (``"completed": false``) first, then the error raised."""
    from subterra.viz.foxglove import FoxgloveWriter

    out.mkdir(parents=True, exist_ok=True)
    writer = FoxgloveWriter(out / "replay.mcap", world_frame=steps.world, body_frame=steps.body, layers=steps.layers)
    recorder = _rerun_recorder(out, rerun)
    records: list[dict[str, Any]] = []
    times: list[tuple[float, float, float, float]] = []  # read, decode, pipeline, write [s]
    error: SubterraError | None = None
    bar = _progress(steps.count if max_messages is None else min(steps.count, max_messages), f"replay {steps.pipeline}", progress)
    try:
        for (topic, log_ns, msg), dt_read in _timed(rec.messages([steps.topic])):
            stamp = _stamp(msg, log_ns)
            where = f"{topic} at stamp {stamp} ns"
            t0 = time.perf_counter()
            data = steps.decode(msg, stamp, where)
            t1 = time.perf_counter()
            steps.prepare(msg, data, log_ns, stamp, writer)
            try:
                t2 = time.perf_counter()
                result = steps.run(data, stamp)
                t3 = time.perf_counter()
            except SubterraError as exc:
                raise _with_context(exc, where) from exc
            records.append(steps.write(writer, recorder, len(records), log_ns, stamp, data, result))
            times.append((dt_read, t1 - t0, t3 - t2, time.perf_counter() - t3))
            bar.update(1)
            if max_messages is not None and len(records) >= max_messages:
                break
        else:
            error = steps.ctx.error  # the pre-pass met a break (or a corrupt message) the main pass did not
    except SubterraError as exc:
        error = exc
    finally:
        bar.close()
        writer.close()
        if recorder is not None:
            recorder.close()

    used, found = steps.summary(records, out, plots)
    summary: dict[str, Any] = {
        "recording": str(rec.path), "format": rec.format, "profile": rec.profile, "pipeline": steps.pipeline,
        "completed": error is None, "error": None if error is None else str(error),
        "topics": steps.topics,
        "frame_ids": {"world": steps.world, "body": steps.body},
        **used,
        "output_mcap": str(writer.path), "output_counts": writer.counts,
        "rerun": str(recorder.path) if recorder is not None else None,
        "replay_timing": _timing(times),
        **found,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=steps.allow_nan), encoding="utf-8")
    if error is not None:
        error.partial_summary = summary  # type: ignore[attr-defined]  # for the CLI's report
        raise error
    return summary


def _rerun_recorder(out: Path, rerun: bool | None):
    """The run's ``replay.rrd`` recorder, or None (``rerun`` False, or None without rerun-sdk)."""
    if rerun is False:
        return None
    from subterra.viz.rerun import RerunRecorder, rerun_available

    if not rerun_available():
        if rerun:
            raise InputError("--rerun needs rerun-sdk: pip install 'subterra[viz]'")
        return None
    return RerunRecorder(out / "replay.rrd", application_id="subterra-replay", depth_every=RERUN_DEPTH_EVERY)


# ---------------------------------------------------------------------- depth


class _DepthSteps(_Steps):
    """APF-PF (:class:`subterra.Pilot`, one camera) on every depth image."""

    pipeline = "depth"

    def __init__(self, rec, depth_topic, info_topic, odom_topic, goal, preset, config, scale, seed, world_frame, body_frame) -> None:
        from subterra.io.ros import decode_camera_info

        images = rec.topic(depth_topic, [_IMAGE], role="--depth-topic")
        rec.topic(info_topic, [_INFO], role="--info-topic")
        if odom_topic is not None:
            rec.topic(odom_topic, [_ODOM], role="--odom-topic")
        # The camera: the first CameraInfo.
        first_info = next(iter(rec.messages([info_topic])), None)
        if first_info is None:
            raise InputError(f"--info-topic {info_topic!r} has no messages: {rec.path}")
        intrinsics = decode_camera_info(first_info.message, where=f"{info_topic} at log time {first_info.stamp_ns} ns")
        self.camera = intrinsics.to_camera()
        super().__init__(rec, depth_topic, images.count, {"depth": depth_topic, "info": info_topic, "odom": odom_topic},
                         odom_topic, world_frame, body_frame)
        self.info_topic, self.goal, self.preset, self.config, self.scale, self.seed = info_topic, goal, preset, config, scale, seed
        self.pilot: Any = None
        self.goal_world = self.pose = self.last_pose = None
        self.last_stamp_s = -np.inf
        self.frames_out_of_order = self.frames_without_pose = self.first_log = 0
        self.body_from_camera, self.mount_source = None, "default: forward-looking camera (optical z = body x)"

    def decode(self, msg: Any, stamp: int, where: str) -> Any:
        from subterra.io.ros import decode_depth_image

        depth = decode_depth_image(msg, scale=self.scale, where=where)
        if depth.data.shape != (self.camera.height, self.camera.width):
            raise InputError(
                f"--depth-topic {self.topic!r}: the image at stamp {stamp} ns is {depth.data.shape[1]}x{depth.data.shape[0]} "
                f"but --info-topic {self.info_topic!r} says {self.camera.width}x{self.camera.height}: {self.path}"
            )
        return depth

    def prepare(self, msg: Any, depth: Any, log_ns: int, stamp: int, writer: Any) -> None:
        ctx, body, goal = self.ctx, self.body, self.goal
        if self.pilot is None:  # the first image: its frame gives the mounting
            from subterra import Pilot

            self.first_log = log_ns
            frame = str(msg.header.frame_id).lstrip("/")
            self.body_from_camera = _mount(ctx, body, frame)
            if self.body_from_camera is not None:
                self.mount_source = f"tf_static: {body} <- {frame}"
            else:
                self.body_from_camera = _FORWARD_OPTICAL
            self.pilot = Pilot([(self.camera, self.body_from_camera)], self.preset, config=self.config, controller="apf-pf",
                               seed=self.seed)
            self.centres_body = self.pilot.voxel_centres("body")
            self.free_state = self.pilot.free_state()
            if frame and frame != body:
                writer.static_transform(log_ns, stamp, body, frame, self.body_from_camera)
            # No odometry: a camera standing still at the origin, the goal fixed in its body frame.
            self.last_pose = ctx.track.first if self.odom else np.eye(4)
            self.goal_world = goal if goal is not None else (self.last_pose @ np.array([DEFAULT_GOAL_AHEAD_M, 0, 0, 1.0]))[:3]
            self.pilot.set_goal(self.goal_world)
        self.pose = _pose(ctx, self.world, body, stamp, self.odom) if self.odom else None
        if self.odom and self.pose is None:
            self.frames_without_pose += 1  # flown on at the last pose known
        elif self.pose is not None:
            self.last_pose = self.pose
        # The memory and the escape need time to run forward: a stamp older than the last
        # is taken at the last one (and counted).
        if stamp / 1e9 < self.last_stamp_s:
            self.frames_out_of_order += 1
        else:
            self.last_stamp_s = stamp / 1e9

    def run(self, depth: Any, stamp: int) -> Any:
        return self.pilot.step(depth.data, stamp=self.last_stamp_s, world_from_body=self.last_pose,
                               scale=depth.scale_m_per_unit if depth.data.dtype == np.uint16 else None)

    def write(self, writer: Any, recorder: Any, index: int, log_ns: int, stamp: int, depth: Any, step: Any) -> dict[str, Any]:
        result, cmd = step.perceptions[0], step.command
        states = np.asarray(result.belief_states, dtype=np.int64)
        probs = np.asarray(result.belief_probabilities, dtype=np.float64)
        grid = states != self.free_state
        centres = self.centres_body[states[grid]] if grid.any() else np.zeros((0, 3))
        writer.command(log_ns, stamp, cmd.v_x_m_s, cmd.v_y_m_s, cmd.v_z_m_s, cmd.yaw_rate_rad_s)
        writer.belief(log_ns, stamp, centres, probs[grid], p_free=result.p_free)
        if self.pose is not None:
            writer.pose(log_ns, stamp, self.pose)
        if recorder is not None:
            _rerun_frame(recorder, (log_ns - self.first_log) / 1e9, depth, self.camera, centres, probs[grid], self.pose,
                         self.body_from_camera, cmd, result.p_free)
        mp = result.most_probable
        return {
            "frame": index, "name": f"{stamp}", "stamp_ns": stamp, "log_time_ns": log_ns,
            "p_free": result.p_free,
            "map_depth_m": None if mp is None else mp.depth_m,
            "map_probability": None if mp is None else mp.probability,
            "map_voxel": None if mp is None else list(mp.voxel),
            "closest_depth_m": result.closest_depth_m,
            "valid_pixels": result.valid_pixels, "in_range_pixels": result.in_range_pixels,
            "repulsive_body": result.repulsive_body.tolist(),
            "memory_repulsive_body": step.memory_repulsive_body.tolist(),
            "memory_cells": step.memory_cells,
            "goal_body": [float(v) for v in step.goal_body],
            "command": {"v_x": cmd.v_x_m_s, "v_y": cmd.v_y_m_s, "v_z": cmd.v_z_m_s, "yaw_rate": cmd.yaw_rate_rad_s, "reached": cmd.reached},
            "timings_s": {**result.timings, "pilot_s": step.timings["total_s"]},
        }

    def summary(self, records: list[dict[str, Any]], out: Path, plots: bool) -> tuple[dict[str, Any], dict[str, Any]]:
        from subterra.perceive import summarise

        goal = self.goal_world  # with odometry in the world frame, else fixed in the body frame
        used = {
            "body_from_camera": None if self.body_from_camera is None else self.body_from_camera.tolist(),
            "body_from_camera_source": self.mount_source,
            "goal": {"frame": self.world if self.odom else self.body, "xyz_m": None if goal is None else [float(v) for v in goal]},
            "frames_without_pose": self.frames_without_pose,
            "frames_out_of_order": self.frames_out_of_order,
        }
        found = {"records": records} if self.pilot is None else summarise(self.pilot, records, source=str(self.path), preset=self.preset)
        found["figures"] = []
        if plots and records:
            from subterra.viz.plots import plot_depth_trace

            plot_depth_trace(records, out / "perception.png", title=f"APF-PF ({self.preset}) on {self.path.name} {self.topic}")
            found["figures"].append("perception.png")
        return used, found


def _rerun_frame(recorder, time_s, depth, camera, centres_body, probs, pose, body_from_camera, cmd, p_free) -> None:
    world_from_body = pose if pose is not None else np.eye(4)
    data = depth.data
    if data.dtype == np.uint16 and depth.scale_m_per_unit != 0.001:
        data = (data.astype(np.float32) * np.float32(depth.scale_m_per_unit))
    centres_world = (world_from_body[:3, :3] @ centres_body.T).T + world_from_body[:3, 3] if len(centres_body) else np.zeros((0, 3))
    recorder.log_frame(
        time_s, depth=data, world_from_camera=world_from_body @ body_from_camera, camera=camera,
        belief_points_world=centres_world, belief_weights=probs, position=world_from_body[:3, 3],
        command=np.array([cmd.v_x_m_s, cmd.v_y_m_s, cmd.v_z_m_s, cmd.yaw_rate_rad_s]), p_free=p_free,
    )


# ---------------------------------------------------------------------- terrain


class _TerrainSteps(_Steps):
    """:class:`subterra.TerrainMapper` on every cloud."""

    pipeline = "terrain"
    allow_nan = False

    def __init__(self, rec, cloud_topic, odom_topic, terrain_config, world_frame, body_frame, sensor_height, layers) -> None:
        from subterra import TerrainMapper

        clouds = rec.topic(cloud_topic, [_CLOUD], role="--cloud-topic")
        if odom_topic is not None:
            rec.topic(odom_topic, [_ODOM], role="--odom-topic")
        if sensor_height is not None and not (math.isfinite(sensor_height) and sensor_height > 0):
            raise InputError(f"argument `--sensor-height` must be a finite number > 0 m, got {sensor_height}")
        super().__init__(rec, cloud_topic, clouds.count, {"cloud": cloud_topic, "odom": odom_topic}, odom_topic,
                         world_frame, body_frame)
        if self.odom:
            self.pose_kind, self.pose_source = "odom", f"odometry {odom_topic}"
        elif self.world in self.ctx.tf.frames and self.body in self.ctx.tf.frames:
            self.pose_kind, self.pose_source = "tf", f"tf: {self.world} <- {self.body}"
        else:
            self.pose_kind, self.pose_source = "none", "none: identity (the robot stands still at the world origin)"
        self.mapper = TerrainMapper(config=terrain_config)
        self.sensor_height, self.layers = sensor_height, layers
        self.body_from_sensor = self.mount_source = self.risk_map = None
        self.first_stamp, self.world_from_body = 0, np.eye(4)

    def decode(self, msg: Any, stamp: int, where: str) -> Any:
        from subterra.io.ros import decode_pointcloud2

        cloud = decode_pointcloud2(msg, fields=(), where=where)
        if len(cloud) == 0:
            raise InputError(
                f"--cloud-topic {self.topic!r}: the cloud at stamp {stamp} ns has no points "
                f"({cloud.width}x{cloud.height}, {cloud.dropped} non-finite dropped): {self.path}"
            )
        return cloud

    def prepare(self, msg: Any, cloud: Any, log_ns: int, stamp: int, writer: Any) -> None:
        body = self.body
        if self.body_from_sensor is None:  # the first cloud: its frame gives the mounting
            from subterra.terrain import estimate_sensor_height, translation

            self.body_from_sensor = _mount(self.ctx, body, cloud.frame_id)
            if self.body_from_sensor is not None:
                self.mount_source = f"tf_static: {body} <- {cloud.frame_id}"
            else:
                if self.sensor_height is None:
                    self.sensor_height = estimate_sensor_height(cloud.points)
                    self.mount_source = "estimated from the first cloud (level sensor)"
                    if not self.sensor_height > 0:
                        raise InputError(
                            f"cannot estimate the height of the sensor above the ground from the first cloud on "
                            f"{self.topic!r} (got {self.sensor_height:.2f} m) and tf has no {body} <- {cloud.frame_id or '?'}: "
                            f"give --sensor-height or --body-frame: {self.path}"
                        )
                else:
                    self.mount_source = "--sensor-height (level sensor)"
                self.body_from_sensor = translation(z=self.sensor_height)
            if cloud.frame_id and cloud.frame_id.lstrip("/") != body:
                writer.static_transform(log_ns, stamp, body, cloud.frame_id.lstrip("/"), self.body_from_sensor)
            self.first_stamp = stamp
        pose = np.eye(4) if self.pose_kind == "none" else _pose(self.ctx, self.world, body, stamp, self.odom)
        if pose is None:
            raise InputError(f"no pose within {POSE_TOLERANCE_NS / 1e9:g} s of the cloud ({self.pose_source}): {self.path}")
        self.world_from_body = pose

    def run(self, cloud: Any, stamp: int) -> Any:
        self.risk_map = self.mapper.update(cloud.points, stamp=(stamp - self.first_stamp) / 1e9,
                                           world_from_body=self.world_from_body, body_from_sensor=self.body_from_sensor)
        return self.risk_map

    def write(self, writer: Any, recorder: Any, index: int, log_ns: int, stamp: int, cloud: Any, risk_map: Any) -> dict[str, Any]:
        world_from_body = self.world_from_body
        writer.pose(log_ns, stamp, world_from_body)
        writer.risk_map(log_ns, stamp, risk_map)
        if self.mapper.last_fine is not None:
            writer.risk_map(log_ns, stamp, self.mapper.last_fine, topic="/subterra/risk_fine", with_layers=False)
        if recorder is not None:
            _rerun_scan(recorder, (stamp - self.first_stamp) / 1e9, cloud.points, world_from_body @ self.body_from_sensor,
                        world_from_body, risk_map if index % RERUN_RISK_EVERY == 0 else None)
        return {
            "stamp_ns": stamp, "log_time_ns": log_ns, "frame_id": cloud.frame_id, "points": len(cloud),
            "dropped_non_finite": cloud.dropped, "organised": [cloud.height, cloud.width],
            "position_m": world_from_body[:3, 3].tolist(), "stats": dict(risk_map.stats), "timings": dict(risk_map.timings),
        }

    def summary(self, records: list[dict[str, Any]], out: Path, plots: bool) -> tuple[dict[str, Any], dict[str, Any]]:
        from subterra.terrain import lethal_cells

        used = {
            "poses": self.pose_source,
            "body_from_sensor": None if self.body_from_sensor is None else np.asarray(self.body_from_sensor).tolist(),
            "body_from_sensor_source": self.mount_source,
            "dropped_non_finite": sum(scan["dropped_non_finite"] for scan in records),
        }
        risk_map = self.risk_map
        if risk_map is None:
            return used, {"scans": records, "figures": []}
        layers_stats = {}
        for name in risk_map.layer_names:
            a = risk_map.layer(name)
            finite = a[np.isfinite(a)]
            layers_stats[name] = (
                {"min": float(finite.min()), "mean": float(finite.mean()), "max": float(finite.max()), "finite_cells": int(finite.size)}
                if finite.size else {"min": None, "mean": None, "max": None, "finite_cells": 0}
            )
        found = {
            "scans": records,
            "map": {"resolution_m": risk_map.resolution, "shape": list(risk_map.shape), "cells": risk_map.nx * risk_map.ny,
                    "origin_m": list(risk_map.origin), "extent_m": list(risk_map.extent), "scans_fused": risk_map.scans},
            "layers": layers_stats, "lethal_cells": lethal_cells(risk_map),
            "robot": self.mapper.robot.to_dict(), "config": self.mapper.config.to_dict(),
            "figures": [],
        }
        if plots:
            from subterra.terrain.cli import _write_figures

            found["figures"] = _write_figures(self.mapper, risk_map, self.world_from_body, out)
        return used, found


def _rerun_scan(recorder, time_s, points_sensor, world_from_sensor, world_from_body, risk_map) -> None:
    """One scan into ``replay.rrd``: the cloud in the world frame, the robot's position and,
    when given, the risk map's observed cells."""
    points = points_sensor @ world_from_sensor[:3, :3].T.astype(np.float32) + world_from_sensor[:3, 3].astype(np.float32)
    recorder.log_cloud(time_s, points)
    recorder.log_drive_step(time_s, position=world_from_body[:3, 3], risk_map=risk_map)


# ---------------------------------------------------------------------- CLI


def register_cli(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Adds the ``replay`` subcommand to ``subparsers``; its handler is ``args.handler``."""
    from subterra.cli import finite_floats, float_in, nonempty, positive_int, seed_int
    from subterra.terrain.cli import MAX_SENSOR_HEIGHT_M, MIN_SENSOR_HEIGHT_M

    p = subparsers.add_parser(
        "replay", help="run the depth or terrain pipeline over a ROS 1/2 bag or an MCAP file (no topics: list them)",
    )
    p.add_argument("recording", help="ROS 1 .bag, ROS 2 bag (folder or .db3) or .mcap file")
    p.add_argument("--pipeline", choices=PIPELINES, default=None, help="depth (APF-PF) or terrain (risk map); default from the topics")
    p.add_argument("--depth-topic", default=None, help="sensor_msgs/Image depth topic (16UC1/mono16 or 32FC1)")
    p.add_argument("--info-topic", default=None, help="sensor_msgs/CameraInfo topic of the depth camera")
    p.add_argument("--cloud-topic", default=None, help="sensor_msgs/PointCloud2 topic (terrain)")
    p.add_argument("--odom-topic", default=None, help="nav_msgs/Odometry topic: poses world_from_body")
    p.add_argument("--goal", type=finite_floats(3, "x,y,z in metres"), default=None,
                   help="depth: goal x,y,z [m], in the odometry's world frame with --odom-topic, else in the body frame (default 5 m ahead)")
    p.add_argument("--preset", default="flight", help="depth: perception preset (default flight)")
    p.add_argument("--config", type=nonempty, default=None, help="depth: perception config TOML; terrain: terrain config TOML")
    p.add_argument("--scale", type=float_in(0.0, 1.0, unit="m"), default=None, help="depth: metres per unit of 16UC1/mono16 images (default 0.001)")
    p.add_argument("--seed", type=seed_int, default=0, help="depth: particle filter seed (default 0)")
    p.add_argument("--sensor-height", type=float_in(MIN_SENSOR_HEIGHT_M, MAX_SENSOR_HEIGHT_M, low_open=False, unit="m"), default=None, help="terrain: lidar height above the ground when tf lacks it [m]")
    p.add_argument("--world-frame", type=nonempty, default=None, help="world frame id (default: the odometry's frame_id, else odom)")
    p.add_argument("--body-frame", type=nonempty, default=None, help="body frame id (default: the odometry's child_frame_id, else base_link)")
    p.add_argument("--layers", default=",".join(DEFAULT_LAYERS),
                   help="terrain: map layers written as images to replay.mcap: comma-separated, 'all' or 'none'")
    p.add_argument("--max-messages", type=positive_int, default=None, help="stop after this many images / clouds")
    p.add_argument("--no-rerun", action="store_true", help="no replay.rrd even if rerun-sdk is installed")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--out", type=nonempty, default=None, help="run folder (default runs/replay-<recording>-<pipeline>)")
    p.set_defaults(handler=run_cli)
    return p


def run_cli(args: argparse.Namespace) -> int:
    """Handler of ``subterra replay``."""
    from subterra.io.recordings import open_recording

    if args.depth_topic is None and args.info_topic is None and args.cloud_topic is None:
        with open_recording(args.recording) as rec:
            print(f"{rec.path}: {rec.format}{f' ({rec.profile})' if rec.profile else ''}, {rec.message_count} messages")
            print(rec.describe_topics())
            if rec.damage:
                print(f"warning: the file is incomplete: {rec.damage}")
            hints = {
                "depth": (rec.topics_of_type(_IMAGE), rec.topics_of_type(_INFO)),
                "terrain": (rec.topics_of_type(_CLOUD),),
            }
            if hints["depth"][0] and hints["depth"][1]:
                print(f"depth pipeline: --depth-topic {hints['depth'][0][0]} --info-topic {hints['depth'][1][0]}")
            if hints["terrain"][0]:
                print(f"terrain pipeline: --cloud-topic {hints['terrain'][0][0]}")
        return 0
    pipeline = _pipeline(args.pipeline, args.depth_topic, args.info_topic, args.cloud_topic)
    out = Path(args.out or f"runs/replay-{Path(args.recording).stem}-{pipeline}")
    if args.layers == "all":
        layers = None
    elif args.layers in ("none", ""):
        layers = ()
    else:
        layers = tuple(s.strip() for s in args.layers.split(",") if s.strip())
    config = terrain_config = None
    if args.config:
        if pipeline == "depth":
            from subterra import load_config

            config = load_config(args.config)
        else:
            terrain_config = args.config
    unit = "images" if pipeline == "depth" else "clouds"
    try:
        summary = replay(
            args.recording, out, pipeline=pipeline, depth_topic=args.depth_topic, info_topic=args.info_topic,
            cloud_topic=args.cloud_topic, odom_topic=args.odom_topic, goal=args.goal, preset=args.preset, config=config,
            terrain_config=terrain_config, scale=args.scale, seed=args.seed, world_frame=args.world_frame,
            body_frame=args.body_frame, sensor_height=args.sensor_height, layers=layers, max_messages=args.max_messages,
            rerun=False if args.no_rerun else None, plots=not args.no_plots, progress=not args.no_progress,
        )
    except SubterraError as exc:
        partial = getattr(exc, "partial_summary", None)
        if partial is not None:  # the input broke off: say what was written before the error
            n = len(partial["records"]) if pipeline == "depth" else len(partial["scans"])
            print(f"stopped at an error after {n} {unit}: wrote {out / 'summary.json'} (\"completed\": false) "
                  f"and {partial['output_mcap']} with the output so far")
        raise
    t = summary["replay_timing"]
    n = len(summary["records"]) if pipeline == "depth" else len(summary["scans"])
    line = f"{n} {unit} from {args.recording}: pipeline median {t['pipeline_ms_median']:.2f} ms"
    if t.get("read_decode_percent_of_pipeline") is not None:
        line += f", read + decode {t['read_decode_ms_median']:.2f} ms ({t['read_decode_percent_of_pipeline']:.0f}% of the pipeline)"
    print(line)
    counts = ", ".join(f"{k} x{v}" for k, v in sorted(summary["output_counts"].items()))
    print(f"wrote {out / 'summary.json'}, {summary['output_mcap']} ({counts}) and {len(summary['figures'])} figures")
    if summary.get("rerun"):
        print(f"wrote {summary['rerun']}")
    return 0
