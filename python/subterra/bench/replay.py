"""`subterra bench replay`: what reading a recording costs next to the pipeline it feeds.

In one process, for ``PointCloud2`` and depth ``Image`` messages stored in

* a plain MCAP file (ROS 2, CDR, zstd chunks: what :class:`~subterra.io.recordings.McapWriter`
  and ``ros2 bag record -s mcap`` write),
* a ROS 2 bag with sqlite3 storage and one with MCAP storage (written by ``rosbags``),
* the real ROS 1 MCAP ``mcap-ouster-os1-64/test.mcap`` when ``../shared/data`` is present,

it runs what ``subterra replay`` runs, one message at a time, and times each stage in that
one loop: **read** (the container: chunk, decompression, row fetch, plus ``rosbags``
deserialisation into a message object), **decode** (:mod:`subterra.io.ros`: message ->
NumPy arrays, xyz only for clouds as ``subterra replay`` does, and in a second pass with
every field), and the **pipeline** on the decoded message (clouds:
``TerrainMapper.update``, a 2 s fused window; images: ``DepthPerception.update`` +
``ApfController.command`` at the ``flight`` preset). It reports messages per second of
read + decode and both as a percentage of the pipeline's time (target: decode < 20%).

The messages are built on the fly: clouds from the real Ouster OS1-128 scans
(``ouster-os1-128-outdoor``, ~107k points, with intensity / ring / time fields in a
32-byte point like the Ouster driver's) and images from the real RealSense D435 frames
(640x480 16UC1), or seeded synthetic ones when the shared data is absent.
"""

from __future__ import annotations

import os
import platform
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["bench_replay"]

DATA_DIR = Path(__file__).resolve().parents[3].parent / "shared" / "data"
CLOUD_TOPIC = "/os_cloud_node/points"
DEPTH_TOPIC = "/camera/depth/image_rect_raw"
INFO_TOPIC = "/camera/depth/camera_info"
#: The decode target: decoding adds less than this to the pipeline's time per message [%].
TARGET_PERCENT = 20.0
#: Lidar period and mounting height of the synthetic setup [s], [m].
SCAN_PERIOD_NS = 100_000_000
IMAGE_PERIOD_NS = 33_333_333
#: The real OS1-64 MCAP holds 2 clouds: read it this many times for the medians.
REAL_PASSES = 5


def _ms(values: list[float]) -> float:
    return float(np.median(values) * 1e3)


def _clouds(n: int, rng: np.random.Generator, data: Path) -> tuple[list[np.ndarray], str]:
    scans = sorted((data / "ouster-os1-128-outdoor").glob("OS-1-128_scan*.npy"))
    if scans:
        base = [np.load(p).astype(np.float32) for p in scans]
        source = f"real Ouster OS1-128 scans ({len(base)}, repeated), {data / 'ouster-os1-128-outdoor'}"
    else:
        from subterra.bench.terrain import synthetic_scan

        base = [synthetic_scan(rng, points=100_000) for _ in range(3)]
        source = "synthetic OS1-128-like scans (seeded; ../shared/data absent)"
    return [base[i % len(base)] for i in range(n)], source


def _images(n: int, data: Path):
    from subterra.io import Intrinsics, list_depth_files, read_depth, read_intrinsics

    folder = data / "realsense-d435-room"
    if (folder / "depth").is_dir():
        frames = [read_depth(p).data for p in list_depth_files(folder / "depth")]
        intr = read_intrinsics(folder / "cam_params_realsense.json")
        source = f"real RealSense D435 frames ({len(frames)}, repeated), {folder}"
    else:
        frames = []
        for i in range(10):
            f = np.zeros((480, 640), np.uint16)
            f[140:340, 220:420] = 800 - 20 * i
            frames.append(f)
        intr = Intrinsics(385.0, 385.0, 319.5, 239.5, 640, 480)
        source = "synthetic 640x480 box frames (../shared/data absent)"
    return [frames[i % len(frames)] for i in range(n)], intr, source


def _items(clouds, frames, intr) -> list[tuple[str, int, Any]]:
    from subterra.io import ros

    t0 = 1_700_000_000_000_000_000
    items = []
    for i, pts in enumerate(clouds):
        s = t0 + i * SCAN_PERIOD_NS
        n = len(pts)
        fields = {  # the Ouster driver's point: x y z _ intensity t reflectivity ring ... in 32 B
            "intensity": np.linspace(0, 800, n, dtype=np.float32),
            "t": (np.arange(n, dtype=np.uint32) * (SCAN_PERIOD_NS // max(n, 1))).astype(np.uint32),
            "reflectivity": np.zeros(n, np.uint16),
            "ring": (np.arange(n) % 128).astype(np.uint8),
        }
        items.append((CLOUD_TOPIC, s, ros.pointcloud2_message(pts, fields, stamp_ns=s, frame_id="os_lidar", point_step=32)))
    for i, f in enumerate(frames):
        s = t0 + i * IMAGE_PERIOD_NS
        items.append((INFO_TOPIC, s, ros.camera_info_message(intr, stamp_ns=s, frame_id="camera_depth_optical_frame")))
        items.append((DEPTH_TOPIC, s + 1, ros.image_message(f, stamp_ns=s, frame_id="camera_depth_optical_frame")))
    items.sort(key=lambda it: it[1])
    return items


def _time_topic(path: Path, topic: str, decode, pipeline=None, passes: int = 1) -> dict[str, Any]:
    """Read + deserialise, decode and (when ``pipeline`` is given) pipeline times of every
    message on ``topic``, over ``passes`` reads of the file (values of the first pass).

    The three stages run one message at a time, as ``subterra replay`` runs them, so each
    is timed with the caches the others leave: decompressing a chunk evicts what decode and
    pipeline would find warm in a loop of their own."""
    from subterra.io.recordings import open_recording

    read, dec, pipe, out = [], [], [], []
    for k in range(passes):
        with open_recording(path) as rec:
            it = rec.messages([topic])
            while True:
                t0 = time.perf_counter()
                try:
                    _, _, msg = next(it)
                except StopIteration:
                    break
                t1 = time.perf_counter()
                value = decode(msg)
                t2 = time.perf_counter()
                if pipeline is not None:
                    pipeline(value)
                    pipe.append(time.perf_counter() - t2)
                read.append(t1 - t0)
                dec.append(t2 - t1)
                if k == 0:
                    out.append(value)
    # The first message also builds the topic's deserialiser (rosbags code generation): _row reports it apart.
    return {"read": read, "decode": dec, "pipeline": pipe, "values": out}


def _cloud_pipeline(sensor_height: float | None = None):
    """A terrain update per decoded cloud (``TerrainMapper.update``, default config: coarse
    + fine maps, 2 s fused window); the mount is estimated from the first cloud when
    ``sensor_height`` is None."""
    import subterra
    from subterra.terrain import estimate_sensor_height, translation

    mapper = subterra.TerrainMapper()
    state = {"i": 0, "mount": None if sensor_height is None else translation(z=sensor_height)}

    def run(cloud) -> None:
        points = cloud.points
        if state["mount"] is None:
            state["mount"] = translation(z=estimate_sensor_height(points))
        mapper.update(points, stamp=state["i"] * SCAN_PERIOD_NS / 1e9, body_from_sensor=state["mount"])
        state["i"] += 1

    return run


def _image_pipeline(camera):
    """An APF-PF frame per decoded depth image (``DepthPerception.update`` +
    ``ApfController.command``, ``flight`` preset)."""
    import subterra

    perception = subterra.DepthPerception(camera, "flight", seed=0)
    controller = subterra.ApfController("flight")

    def run(depth) -> None:
        out = perception.update(depth.data, depth.scale_m_per_unit)
        controller.command([5.0, 0.0, 0.0], perception=[out])

    return run


def _row(timed: dict[str, Any], decode_all_ms: float | None = None) -> dict[str, Any]:
    read, dec, pipe = (timed[k][1:] or timed[k] for k in ("read", "decode", "pipeline"))
    ingest = [a + b for a, b in zip(read, dec)]
    pipeline_ms = _ms(pipe)
    row = {
        "messages_timed": len(read),
        "first_message_read_ms": timed["read"][0] * 1e3,
        "read_ms_median": _ms(read),
        "decode_ms_median": _ms(dec),
        "read_decode_ms_median": _ms(ingest),
        "messages_per_s": float(1.0 / np.median(ingest)),
        "pipeline_ms_median": pipeline_ms,
        "decode_percent_of_pipeline": 100.0 * _ms(dec) / pipeline_ms,
        "read_decode_percent_of_pipeline": 100.0 * _ms(ingest) / pipeline_ms,
    }
    if decode_all_ms is not None:
        row["decode_all_fields_ms_median"] = decode_all_ms
    return row


def bench_replay(*, messages: int = 20, seed: int = 0, data: str | Path | None = None, keep: str | Path | None = None) -> dict[str, Any]:
    """Runs the benchmark (see the module doc) with ``messages`` clouds and images per
    container; returns the JSON-ready report. ``keep``: leave the generated recordings
    in this folder instead of a temporary one."""
    import subterra
    from subterra.errors import InputError
    from subterra.io import ros
    from subterra.io.recordings import McapWriter, write_bag

    if messages < 3:
        raise InputError(f"argument `messages` must be >= 3, got {messages}")
    data = Path(data) if data is not None else DATA_DIR
    rng = np.random.default_rng(seed)
    clouds, cloud_source = _clouds(messages, rng, data)
    frames, intr, image_source = _images(messages, data)
    items = _items(clouds, frames, intr)
    camera = intr.to_camera()

    tmp = Path(keep) if keep is not None else Path(tempfile.mkdtemp(prefix="subterra-bench-replay-"))
    tmp.mkdir(parents=True, exist_ok=True)
    try:
        containers: dict[str, Path] = {}
        t0 = time.perf_counter()
        with McapWriter(tmp / "plain.mcap") as w:
            for topic, s, msg in items:
                w.write(topic, msg, log_time_ns=s)
        containers["mcap (ros2, zstd chunks)"] = tmp / "plain.mcap"
        for storage in ("sqlite3", "mcap"):
            shutil.rmtree(tmp / f"bag-{storage}", ignore_errors=True)
            containers[f"ros2 bag ({storage} storage)"] = write_bag(tmp / f"bag-{storage}", items, storage=storage)
        write_s = time.perf_counter() - t0

        results: dict[str, Any] = {}
        for name, path in containers.items():
            clouds_t = _time_topic(path, CLOUD_TOPIC, lambda m: ros.decode_pointcloud2(m, fields=()), _cloud_pipeline())
            all_fields = _time_topic(path, CLOUD_TOPIC, lambda m: ros.decode_pointcloud2(m))
            images_t = _time_topic(path, DEPTH_TOPIC, lambda m: ros.decode_depth_image(m), _image_pipeline(camera))
            results[name] = {
                "file_mb": round(sum(f.stat().st_size for f in ([path] if path.is_file() else path.iterdir())) / 1e6, 1),
                "pointcloud2": _row(clouds_t, _ms(all_fields["decode"][1:])),
                "image": _row(images_t),
            }
        real = data / "mcap-ouster-os1-64" / "test.mcap"
        if real.is_file():
            # The floor is the lowest dense layer, ~0.8 m under this sensor (the mode-based estimate finds a wall).
            t = _time_topic(real, "/os1_cloud_node/points", lambda m: ros.decode_pointcloud2(m, fields=()),
                            _cloud_pipeline(sensor_height=0.8), passes=REAL_PASSES)
            results[f"real ros1 mcap (OS1-64 test.mcap, 2 clouds read {REAL_PASSES} times, zstd chunks shared with lidar packets)"] = {
                "file_mb": round(real.stat().st_size / 1e6, 1),
                "pointcloud2": _row(t),
            }
    finally:
        if keep is None:
            shutil.rmtree(tmp, ignore_errors=True)

    worst_decode = max(r[k]["decode_percent_of_pipeline"] for r in results.values() for k in ("pointcloud2", "image") if k in r)
    return {
        "benchmark": "replay",
        "subterra_version": subterra.__version__,
        "machine": {"python": platform.python_version(), "processor": platform.processor() or platform.machine(), "cpus": os.cpu_count()},
        "messages_per_container": messages,
        "cloud_source": cloud_source,
        "cloud_points": int(np.median([len(c) for c in clouds])),
        "image_source": image_source,
        "write_recordings_s": write_s,
        "pipelines": {
            "pointcloud2": "TerrainMapper.update (coarse + fine maps, 2 s fused window)",
            "image": "DepthPerception.update + ApfController.command (flight preset, 640x480)",
        },
        "columns": {
            "read": "container + rosbags deserialisation to a message object, per message (the first message, which also "
                    "builds the deserialiser, is left out of the medians and shown as first_message_read_ms)",
            "decode": "subterra.io.ros: message -> NumPy (clouds: xyz only, as replay does; decode_all_fields: every field)",
            "pipeline": "the pipeline on the decoded message, in the same loop (read, decode, pipeline per message, "
                        "as replay runs them)",
        },
        "results": results,
        "target": {"decode_percent_of_pipeline_below": TARGET_PERCENT, "worst_decode_percent": worst_decode,
                   "met": worst_decode < TARGET_PERCENT},
    }
