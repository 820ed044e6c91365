"""Coverage-guided fuzz targets of subterra's file readers and array entry points (atheris).

Each target takes the bytes libFuzzer made and either writes them to a file and reads it
back with one of subterra's readers (``FILE_SUFFIX`` names the extension), or draws
typed arguments from them with :class:`atheris.FuzzedDataProvider` (arrays of fuzzed
shape, dtype, layout and values: NaN, inf, huge, denormal, negative, empty) and calls an
array entry point. A target catches exactly :class:`subterra.errors.SubterraError` (the
errors subterra raises on purpose); anything else propagates and is a finding, as are
an abort (a Rust panic that escapes, a segfault), a hang over ``-timeout`` seconds and a
memory use over ``-rss_limit_mb``.

Run one target (libFuzzer flags pass through; corpus folders last)::

    python fuzz/targets.py cloud_pcd -max_total_time=30 fuzz/corpus/cloud_pcd fuzz/seeds/cloud_pcd

``fuzz/run.py`` runs them all; ``TARGETS`` maps each name to its function. Only the
subterra modules a target needs are imported, inside ``atheris.instrument_imports``, so
that its Python surface is instrumented and a process starts quickly (the Rust core is
not instrumented: there the fuzzer is guided by the Python wrappers' coverage only).
Importing this module (the tests do) instruments nothing.
"""

from __future__ import annotations

import importlib
import math
import os
import sys
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import atheris
import numpy as np

# subterra is imported by name inside each target (``import subterra.io``, a dict lookup once
# the module is loaded): `main` imports the modules a target needs first, instrumented.

warnings.simplefilter("ignore")  # NumPy casts of NaN to int and overflows in the harness itself

# --------------------------------------------------------------------------- scratch files

_SCRATCH: Path | None = None


def scratch_dir() -> Path:
    """The folder the file targets write their input to: ``$SUBTERRA_FUZZ_TMP``, else a
    tmpfs folder ``/dev/shm/subterra-fuzz-<pid>`` (the system temp folder without /dev/shm)."""
    global _SCRATCH
    if _SCRATCH is None:
        env = os.environ.get("SUBTERRA_FUZZ_TMP")
        if env:
            base = Path(env)
        else:
            root = Path("/dev/shm") if os.path.isdir("/dev/shm") else Path(tempfile.gettempdir())
            base = root / f"subterra-fuzz-{os.getpid()}"
        base.mkdir(parents=True, exist_ok=True)
        _SCRATCH = base
    return _SCRATCH


def _write(data: bytes, name: str) -> Path:
    path = scratch_dir() / name
    with open(path, "wb") as f:
        f.write(data)
    return path


# --------------------------------------------------------------------------- value generators

NAN, INF = float("nan"), float("inf")
SPECIAL_FLOATS = [
    0.0, -0.0, 1.0, -1.0, 0.5, 2.0, 0.1, -0.1, 10.0, 100.0, 1e3, 1e6, -1e6, 1e7, 1e9, 1e15,
    1e30, 1e308, -1e308, 1.7976931348623157e308, 3.4028235e38, 3.5e38, 5e-324, -5e-324, 1e-310,
    1.1754943e-38, 1e-45, 1e-30, 65535.0, 65536.0, 2.0**31, 2.0**53, 2.0**63, 2.0**64,
    NAN, -NAN, INF, -INF,
]
SPECIAL_INTS = [0, 1, -1, 2, 3, 7, 255, 256, 65535, 65536, 2**31 - 1, 2**31, -(2**31), 2**32, 2**53, 2**63 - 1, -(2**63)]
# Every real dtype an ArrayLike may have; complex and bool ones are refused with an InputError.
DTYPES = [
    np.float32, np.float64, np.float16, np.uint16, np.uint8, np.int8, np.int16, np.int32,
    np.int64, np.uint32, np.uint64, np.bool_, np.complex64, np.complex128, np.longdouble,
]
FLOAT_DTYPES = [np.float32, np.float64]


def real(fdp: atheris.FuzzedDataProvider, lo: float = -10.0, hi: float = 10.0) -> float:
    """A float: mostly in ``[lo, hi]``, else special (NaN, inf, huge, denormal) or any double."""
    k = fdp.ConsumeIntInRange(0, 7)
    if k <= 3:
        return fdp.ConsumeFloatInRange(lo, hi)
    if k <= 5:
        return fdp.PickValueInList(SPECIAL_FLOATS)
    if k == 6:
        return fdp.ConsumeFloat()
    return float(fdp.ConsumeIntInRange(int(lo) - 2, int(hi) + 2))


def integer(fdp: atheris.FuzzedDataProvider, lo: int, hi: int) -> int:
    """An int: mostly in ``[lo, hi]``, sometimes a boundary value (all fit in int64)."""
    if fdp.ConsumeIntInRange(0, 9) == 0:
        return fdp.PickValueInList(SPECIAL_INTS)
    return fdp.ConsumeIntInRange(lo, hi)


def text(fdp: atheris.FuzzedDataProvider, choices: list[str], max_len: int = 12) -> str:
    """One of ``choices`` mostly, else a short fuzzed string (no lone surrogates)."""
    if choices and fdp.ConsumeIntInRange(0, 4):
        return fdp.PickValueInList(choices)
    return fdp.ConsumeUnicodeNoSurrogates(fdp.ConsumeIntInRange(0, max_len))


def any_value(fdp: atheris.FuzzedDataProvider, depth: int = 0) -> Any:
    """A value a config dict may hold: numbers (special ones too), bools, strings, lists, dicts, None."""
    k = fdp.ConsumeIntInRange(0, 9 if depth < 2 else 6)
    if k <= 2:
        return real(fdp, -100.0, 100.0)
    if k == 3:
        return integer(fdp, -5, 100_000)
    if k == 4:
        return fdp.ConsumeBool()
    if k == 5:
        return text(fdp, ["particle", "histogram", "raw", "systematic", "multinomial", "horizon", "zero",
                          "centre", "near-corner", "nonholonomic", "holonomic", "risk", "additive", ""])
    if k == 6:
        return None
    if k <= 8:
        return [any_value(fdp, depth + 1) for _ in range(fdp.ConsumeIntInRange(0, 4))]
    return {text(fdp, ["enabled", "x", ""]): any_value(fdp, depth + 1) for _ in range(fdp.ConsumeIntInRange(0, 3))}


def mutate_tree(fdp: atheris.FuzzedDataProvider, tree: dict[str, Any], max_edits: int = 4) -> dict[str, Any]:
    """A copy of a nested config dict with a few leaves replaced, removed or added."""
    import copy

    out = copy.deepcopy(tree)
    for _ in range(fdp.ConsumeIntInRange(0, max_edits)):
        node: Any = out
        # walk down to a dict
        while True:
            keys = list(node) if isinstance(node, dict) else []
            if not keys:
                break
            key = fdp.PickValueInList(keys)
            if isinstance(node[key], dict) and fdp.ConsumeIntInRange(0, 3):
                node = node[key]
                continue
            break
        if not isinstance(node, dict):
            continue
        op = fdp.ConsumeIntInRange(0, 9)
        keys = list(node)
        if keys and op <= 6:
            node[fdp.PickValueInList(keys)] = any_value(fdp)
        elif keys and op == 7:
            del node[fdp.PickValueInList(keys)]
        else:
            node[text(fdp, keys + ["unknown"])] = any_value(fdp)
    return out


def array(
    fdp: atheris.FuzzedDataProvider,
    shape: tuple[int | None, ...],
    *,
    dtypes: list[Any] = FLOAT_DTYPES,
    lo: float = -10.0,
    hi: float = 10.0,
    max_dim: int = 8,
    as_list: bool = True,
) -> Any:
    """An array of about ``shape`` (``None``: a fuzzed size up to ``max_dim``).

    Mostly the expected shape and one of ``dtypes``; sometimes any shape (0-d to 3-d,
    empty) or any real/complex/bool dtype. Values: uniform in ``[lo, hi]``, one constant,
    per-element fuzzed, and special values sprinkled in. Layouts: C, Fortran, strided,
    broadcast (stride 0), byte-swapped, read-only; sometimes a nested list.
    """
    if fdp.ConsumeIntInRange(0, 15) == 0:
        shp = tuple(fdp.ConsumeIntInRange(0, 5) for _ in range(fdp.ConsumeIntInRange(0, 3)))
    else:
        shp = tuple(fdp.ConsumeIntInRange(0, max_dim) if s is None else s for s in shape)
    dtype = np.dtype(fdp.PickValueInList(DTYPES) if fdp.ConsumeIntInRange(0, 11) == 0 else fdp.PickValueInList(dtypes))
    n = math.prod(shp)
    mode = fdp.ConsumeIntInRange(0, 4)
    if mode == 0:
        values = np.full(n, real(fdp, lo, hi))
    elif mode == 1 and n:
        values = np.array(fdp.ConsumeFloatList(n) + [0.0] * n)[:n]
    elif mode == 2 and n:
        values = np.array(fdp.ConsumeFloatListInRange(n, lo, hi) + [0.0] * n)[:n]
    else:
        seed = fdp.ConsumeIntInRange(0, 2**32 - 1)
        values = np.random.default_rng(seed).uniform(lo, hi, n)
    if n and fdp.ConsumeIntInRange(0, 2) == 0:
        for _ in range(fdp.ConsumeIntInRange(1, 3)):
            values[fdp.ConsumeIntInRange(0, n - 1)] = fdp.PickValueInList(SPECIAL_FLOATS)
    with np.errstate(all="ignore"):
        if dtype.kind in "iu":
            info = np.iinfo(dtype)
            clean = np.nan_to_num(values, nan=0.0, posinf=float(info.max), neginf=float(info.min))
            out = np.clip(clean, float(info.min), float(info.max)).astype(dtype)
        elif dtype.kind == "b":
            out = values > 0
        elif dtype.kind == "c":
            out = values.astype(dtype) + 1j * fdp.ConsumeFloatInRange(-1.0, 1.0)
        else:
            out = values.astype(dtype)
    out = out.reshape(shp)
    layout = fdp.ConsumeIntInRange(0, 12)
    if layout == 1:
        out = np.asfortranarray(out)
    elif layout == 2 and out.ndim:
        big = np.repeat(out, 2, axis=-1)
        out = big[..., ::2]  # non-contiguous
    elif layout == 3 and out.ndim and out.size:
        out = np.broadcast_to(out[(slice(None),) * (out.ndim - 1) + (slice(0, 1),)], out.shape)
    elif layout == 4 and out.dtype.itemsize > 1 and out.dtype.kind != "b":
        out = out.astype(out.dtype.newbyteorder(">" if sys.byteorder == "little" else "<"))
    elif layout == 5:
        out = out.copy()
        out.flags.writeable = False
    elif layout == 6 and out.ndim >= 2:
        out = np.ascontiguousarray(np.swapaxes(out, 0, 1)).swapaxes(0, 1)  # a transposed view
    elif layout == 7 and as_list and dtype.kind in "fiu" and dtype.itemsize <= 8:
        return out.tolist()
    return out


def rigid(fdp: atheris.FuzzedDataProvider, reach: float = 20.0) -> Any:
    """A 4x4 pose: identity, a rigid transform (fuzzed rotation, translation), a slightly
    non-rigid one, or any 4x4-ish array."""
    k = fdp.ConsumeIntInRange(0, 5)
    if k == 0:
        return np.eye(4)
    if k == 5:
        return array(fdp, (4, 4), lo=-2.0, hi=2.0)
    q = np.array([fdp.ConsumeFloatInRange(-1.0, 1.0) for _ in range(4)])
    norm = float(np.linalg.norm(q))
    q = np.array([0.0, 0.0, 0.0, 1.0]) if not norm > 1e-6 else q / norm
    x, y, z, w = q
    m = np.eye(4)
    m[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    m[:3, 3] = [real(fdp, -reach, reach) if k == 3 else fdp.ConsumeFloatInRange(-reach, reach) for _ in range(3)]
    if k == 4:
        m[fdp.ConsumeIntInRange(0, 3), fdp.ConsumeIntInRange(0, 3)] += real(fdp, -1e-2, 1e-2)
    return m


def point(fdp: atheris.FuzzedDataProvider, n: int, reach: float = 10.0) -> Any:
    """``n`` numbers: a list of floats (specials sometimes) or an array of about ``(n,)``."""
    if fdp.ConsumeBool():
        return [real(fdp, -reach, reach) for _ in range(n)]
    return array(fdp, (n,), lo=-reach, hi=reach)


def maybe(fdp: atheris.FuzzedDataProvider, make: Callable[[], Any]) -> Any:
    return make() if fdp.ConsumeBool() else None


# --------------------------------------------------------------------------- shared fixtures

CAMERA_ARGS = (4.0, 4.0, 3.5, 2.5, 8, 6)  # fx, fy, cx, cy [px], width, height [px]
_CACHE: dict[str, Any] = {}


def perception_config(fdp: atheris.FuzzedDataProvider, preset: str = "flight", *, edits: bool = True) -> Any:
    """A small perception config (blocks of 4x3 px on the 8x6 camera, 64 particles), a mode
    picked by the fuzzer, and sometimes a few fuzzed fields."""
    import subterra

    key = "pc:" + preset
    if key not in _CACHE:
        d = subterra.PerceptionConfig.preset(preset).to_dict()
        d["grid"].update(block_width_px=4, block_height_px=3)
        d["filter"]["particles"] = 64
        _CACHE[key] = d
    d = dict(_CACHE[key])
    d["filter"] = dict(d["filter"], mode=fdp.PickValueInList(["particle", "histogram", "particle"]))
    if edits and fdp.ConsumeIntInRange(0, 3) == 0:
        d = mutate_tree(fdp, d, 2)
    return subterra.PerceptionConfig.from_dict(d)


def camera() -> Any:
    import subterra

    return subterra.PinholeCamera(*CAMERA_ARGS)


def depth_frame(fdp: atheris.FuzzedDataProvider) -> Any:
    """A depth image for the 8x6 camera: uint16 [mm] or float32 [m], sometimes another
    shape or dtype."""
    if fdp.ConsumeBool():
        return array(fdp, (6, 8), dtypes=[np.uint16], lo=0.0, hi=3000.0, as_list=False)
    return array(fdp, (6, 8), dtypes=[np.float32], lo=0.0, hi=3.0, as_list=False)


def small_terrain(fdp: atheris.FuzzedDataProvider, *, edits: bool = True) -> dict[str, Any]:
    """A terrain config of a 4 m x 4 m coarse map (a 2 m fine map or none), sometimes edited."""
    d: dict[str, Any] = {
        "coarse": {"resolution_m": fdp.PickValueInList([0.1, 0.2, 0.25]), "size_x_m": 4.0, "size_y_m": 4.0},
        "fine_enabled": fdp.ConsumeBool(),
        "fine": {"resolution_m": 0.1, "size_x_m": 2.0, "size_y_m": 2.0},
        "ground": {"sectors": fdp.PickValueInList([36, 90, 360]), "max_range_m": 5.0},
        "prefilter": {"max_range_m": 5.0},
    }
    if edits and fdp.ConsumeIntInRange(0, 3) == 0:
        d = mutate_tree(fdp, d, 2)
    return d


def scan(fdp: atheris.FuzzedDataProvider, max_points: int = 48) -> Any:
    """Lidar points ``(N, 3)`` [m] in the sensor frame: mostly a noisy ground patch with a few
    obstacles, sometimes fuzzed values of any shape and dtype."""
    if fdp.ConsumeIntInRange(0, 2) == 0:
        return array(fdp, (None, 3), lo=-6.0, hi=6.0, max_dim=max_points)
    n = fdp.ConsumeIntInRange(0, max_points)
    rng = np.random.default_rng(fdp.ConsumeIntInRange(0, 2**16))
    pts = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), rng.normal(-0.5, 0.02, n)])
    if n and fdp.ConsumeBool():
        pts[: max(1, n // 4), 2] += fdp.ConsumeFloatInRange(-1.0, 1.5)
    if n and fdp.ConsumeIntInRange(0, 3) == 0:
        pts[fdp.ConsumeIntInRange(0, n - 1), fdp.ConsumeIntInRange(0, 2)] = fdp.PickValueInList(SPECIAL_FLOATS)
    return pts.astype(fdp.PickValueInList([np.float32, np.float64]))


# --------------------------------------------------------------------------- file readers


def _file_target(suffix: str, read: Callable[[Path], Any]) -> Callable[[bytes], None]:
    def target(data: bytes) -> None:
        from subterra.errors import SubterraError

        path = _write(data, "input" + suffix)
        try:
            read(path)
        except SubterraError:
            pass

    target.__doc__ = f"The fuzzed bytes as a {suffix} file, read back with {read.__name__.lstrip('_')}."
    target.file_suffix = suffix  # type: ignore[attr-defined]
    return target


def _read_cloud(path: Path) -> None:
    import subterra.io

    cloud = subterra.io.read_cloud(path)
    np.asarray(cloud.points).sum()
    len(cloud)


def _read_depth(path: Path) -> None:
    import subterra.io

    img = subterra.io.read_depth(path)
    img.data.sum()


def _read_intrinsics(path: Path) -> None:
    import subterra.io

    subterra.io.read_intrinsics(path)


def _read_poses(path: Path) -> None:
    import subterra.io

    traj = subterra.io.read_trajectory(path)
    len(traj)
    subterra.io.read_poses(path)


def _read_recording(path: Path) -> None:
    import subterra.io
    from subterra.io import ros

    with subterra.io.open_recording(path) as rec:
        rec.describe_topics()
        rec.message_count
        buf = ros.TransformBuffer()
        for i, item in enumerate(rec.messages()):
            if i >= 8:
                break
            kind = rec.topics[item.topic].type
            if kind == "sensor_msgs/msg/PointCloud2":
                ros.decode_pointcloud2(item.message)
            elif kind == "tf2_msgs/msg/TFMessage":
                buf.add_message(item.message, static=item.topic == "/tf_static")
            elif kind == "nav_msgs/msg/Odometry":
                ros.decode_odometry(item.message)
            elif kind == "sensor_msgs/msg/CameraInfo":
                ros.decode_camera_info(item.message)
            elif kind == "sensor_msgs/msg/Image":
                ros.decode_depth_image(item.message)


def _load_world(path: Path) -> None:
    import subterra.sim

    world = subterra.sim.load_world(path)
    world.primitive_count
    world.bounds
    world.regions


def _load_config(path: Path) -> None:
    import subterra

    subterra.load_config(path).to_toml()


def _load_terrain_config(path: Path) -> None:
    import subterra.terrain

    subterra.terrain.load_terrain_config(path).to_dict()


def _load_node_config(path: Path) -> None:
    from subterra.live.config import NodeConfig

    config = NodeConfig.load(path)
    NodeConfig.from_dict(config.to_dict())  # what it accepts writes out and reads back


def _mpc_config(path: Path) -> None:
    import subterra

    subterra.MpcTracker(config=path).config


def _load_sweep(path: Path) -> None:
    from subterra.batch.sweep_spec import load_sweep

    load_sweep(path)


# --------------------------------------------------------------------------- ROS decoders


def _typestore() -> Any:
    if "ts" not in _CACHE:
        from subterra.io.ros import default_typestore

        _CACHE["ts"] = default_typestore()
    return _CACHE["ts"]


def _header(fdp: atheris.FuzzedDataProvider, ts: Any, frame: str) -> Any:
    t = ts.types
    sec = fdp.ConsumeIntInRange(-(2**31), 2**31 - 1) if fdp.ConsumeIntInRange(0, 7) == 0 else fdp.ConsumeIntInRange(0, 100)
    nanosec = fdp.ConsumeIntInRange(0, 2**32 - 1) if fdp.ConsumeIntInRange(0, 7) == 0 else fdp.ConsumeIntInRange(0, 999_999_999)
    return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame)


def ros_pointcloud2(data: bytes) -> None:
    """A ``sensor_msgs/PointCloud2`` of fuzzed layout (fields, offsets, datatypes, counts,
    steps, endianness) and data, through ``decode_pointcloud2`` and ``to_point_cloud``."""
    from subterra.errors import SubterraError
    from subterra.io import ros

    fdp = atheris.FuzzedDataProvider(data)
    ts = _typestore()
    pf = ts.types["sensor_msgs/msg/PointField"]
    u32 = lambda small: fdp.ConsumeIntInRange(0, 2**32 - 1) if fdp.ConsumeIntInRange(0, 15) == 0 else fdp.ConsumeIntInRange(0, small)  # noqa: E731
    fields = []
    offset = 0
    for _ in range(fdp.ConsumeIntInRange(0, 6)):
        name = text(fdp, ["x", "y", "z", "intensity", "ring", "t", "rgb", "_", ""], 6)
        datatype = fdp.ConsumeIntInRange(0, 255) if fdp.ConsumeIntInRange(0, 15) == 0 else fdp.ConsumeIntInRange(1, 8)
        count = u32(3) if fdp.ConsumeIntInRange(0, 3) == 0 else 1
        off = u32(40) if fdp.ConsumeIntInRange(0, 3) == 0 else offset
        size = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 8: 8}.get(datatype, 4)
        offset = off + size * max(count, 1)
        fields.append(pf(name=name, offset=off, datatype=datatype, count=count))
    height, width = u32(4), u32(16)
    point_step = offset + fdp.ConsumeIntInRange(0, 4) if fdp.ConsumeIntInRange(0, 3) else u32(64)
    row_step = width * point_step + fdp.ConsumeIntInRange(0, 8) if fdp.ConsumeIntInRange(0, 3) else u32(512)
    row_step = min(row_step, 2**32 - 1)
    msg = ts.types["sensor_msgs/msg/PointCloud2"](
        header=_header(fdp, ts, text(fdp, ["os_lidar", "/velodyne", ""])),
        height=height, width=width, fields=fields, is_bigendian=fdp.ConsumeBool(),
        point_step=point_step, row_step=row_step,
        data=np.frombuffer(fdp.ConsumeBytes(fdp.remaining_bytes()), np.uint8), is_dense=fdp.ConsumeBool(),
    )
    try:
        cloud = ros.decode_pointcloud2(msg, drop_invalid=bool(len(data) % 2))
        len(cloud)
        cloud.to_point_cloud()
    except SubterraError:
        pass


def ros_tf(data: bytes) -> None:
    """A ``tf2_msgs/TFMessage`` of fuzzed frames, stamps, translations and quaternions, through
    ``decode_transforms``, ``TransformBuffer.add_message`` and lookups between its frames."""
    from subterra.errors import SubterraError
    from subterra.io import ros

    fdp = atheris.FuzzedDataProvider(data)
    ts = _typestore()
    t = ts.types
    frames = ["map", "odom", "base_link", "/base_link", "os_lidar", "camera", ""]
    buf = ros.TransformBuffer(max_extrapolation_ns=fdp.PickValueInList([0, 100_000_000, 10**18]))
    for _ in range(fdp.ConsumeIntInRange(1, 3)):
        items = []
        for _ in range(fdp.ConsumeIntInRange(0, 4)):
            if fdp.ConsumeIntInRange(0, 2):
                q = [fdp.ConsumeFloatInRange(-1.0, 1.0) for _ in range(4)]
                norm = math.sqrt(sum(v * v for v in q)) or 1.0
                q = [v / norm for v in q]
            else:
                q = [real(fdp, -1.5, 1.5) for _ in range(4)]
            tr = t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=real(fdp), y=real(fdp), z=real(fdp)),
                rotation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            )
            items.append(t["geometry_msgs/msg/TransformStamped"](
                header=_header(fdp, ts, text(fdp, frames)), child_frame_id=text(fdp, frames), transform=tr))
        msg = t["tf2_msgs/msg/TFMessage"](transforms=items)
        try:
            ros.decode_transforms(msg)
            buf.add_message(msg, static=fdp.ConsumeBool())
        except SubterraError:
            pass
    known = buf.frames or ["map"]
    for _ in range(fdp.ConsumeIntInRange(0, 3)):
        stamp = None if fdp.ConsumeBool() else fdp.ConsumeIntInRange(-(2**62), 2**62)
        a, b = fdp.PickValueInList(known), fdp.PickValueInList(known)
        try:
            buf.lookup(a, b, stamp)
            buf.can_transform(a, b, stamp)
            buf.static_only(a, b)
        except SubterraError:
            pass


# --------------------------------------------------------------------------- array entry points


def depth_perception_update(data: bytes) -> None:
    """``DepthPerception.update`` on fuzzed frames (shape, dtype, layout, values, scale), then
    the belief queries."""
    import subterra
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    try:
        p = subterra.DepthPerception(camera(), config=perception_config(fdp), seed=fdp.ConsumeIntInRange(0, 2**31),
                                     mode=fdp.PickValueInList([None, "particle", "histogram", "raw"]))
    except SubterraError:
        return
    for _ in range(fdp.ConsumeIntInRange(1, 3)):
        scale = None if fdp.ConsumeIntInRange(0, 2) else real(fdp, 1e-4, 1.0)
        try:
            out = p.update(depth_frame(fdp), scale=scale)
            out.most_probable
            out.belief_probabilities.sum()
            out.repulsive_body
        except SubterraError:
            pass
    try:
        p.belief()
        p.counts()
        p.forces_body()
        p.voxel_centres(fdp.PickValueInList(["camera", "body", "x"]))
        s = integer(fdp, -1, p.state_count + 1)
        p.voxel_of(s)
        p.transition_row(s)
        p.state_of(integer(fdp, -1, 3), integer(fdp, -1, 3), integer(fdp, -1, 12))
    except SubterraError:
        pass


def obstacle_memory_update(data: bytes) -> None:
    """``ObstacleMemory.update`` with fuzzed perception outputs, stamps and poses."""
    import subterra
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    try:
        p = subterra.DepthPerception(camera(), config=perception_config(fdp, "flight-memory"), seed=0)
        memory = subterra.ObstacleMemory(p)
    except SubterraError:
        return
    stamp = 0.0
    for _ in range(fdp.ConsumeIntInRange(1, 4)):
        stamp = stamp + fdp.ConsumeFloatInRange(0.0, 2.0) if fdp.ConsumeIntInRange(0, 5) else real(fdp, -10.0, 100.0)
        try:
            out = p.update(depth_frame(fdp))
            mo = memory.update(out, stamp=stamp, world_from_body=rigid(fdp))
            mo.repulsive_body
            mo.nearest_m
        except SubterraError:
            pass
    memory.points_world()
    memory.weights()
    len(memory)
    if fdp.ConsumeBool():
        memory.reset()


def qmdp_act(data: bytes) -> None:
    """``Qmdp`` with a fuzzed config over a perception of the small camera, ``act`` on
    fuzzed frames' outputs (and now and then an output of another perception)."""
    import subterra
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    if "qmdp" not in _CACHE:
        _CACHE["qmdp"] = subterra.QmdpConfig().to_dict()
    config = None if fdp.ConsumeIntInRange(0, 2) else mutate_tree(fdp, _CACHE["qmdp"], 3)
    try:
        p = subterra.DepthPerception(camera(), config=perception_config(fdp, edits=False), seed=0)
        q = subterra.Qmdp(p, config)
    except SubterraError:
        return
    other = p
    if fdp.ConsumeIntInRange(0, 7) == 0:
        try:
            other = subterra.DepthPerception(camera(), config=perception_config(fdp), seed=1)
        except SubterraError:
            pass
    for _ in range(fdp.ConsumeIntInRange(1, 3)):
        try:
            a = q.act(other.update(depth_frame(fdp)))
            a.velocity_body
            a.index
            a.value
        except SubterraError:
            pass
    q.actions()
    q.config
    if fdp.ConsumeIntInRange(0, 15) == 0:
        q.rewards()


def _output(fdp: atheris.FuzzedDataProvider, preset: str = "flight") -> Any:
    import subterra

    p = subterra.DepthPerception(camera(), config=perception_config(fdp, preset, edits=False), seed=0)
    return p.update(depth_frame(fdp))


def apf_command(data: bytes) -> None:
    """``ApfController.command`` with fuzzed goals, perception outputs and repulsions."""
    import subterra
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    try:
        apf = subterra.ApfController(config=perception_config(fdp))
        k = fdp.ConsumeIntInRange(0, 3)
        perception = None if k == 0 else _output(fdp) if k == 1 else [_output(fdp) for _ in range(fdp.ConsumeIntInRange(0, 3))]
        rep = maybe(fdp, lambda: point(fdp, 3, 100.0))
        cmd = apf.command(point(fdp, 3, 20.0), perception, repulsive_body=rep)
        cmd.as_array()
        cmd.attractive_body
    except SubterraError:
        pass


def escape_step(data: bytes) -> None:
    """``Escape.step`` over a few ticks with fuzzed stamps, poses, goals, memories and repulsions."""
    import subterra
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    try:
        cfg = perception_config(fdp, "flight-escape")
        esc = subterra.Escape(config=cfg)
        memory = None
        if fdp.ConsumeBool():
            p = subterra.DepthPerception(camera(), config=perception_config(fdp, "flight-escape", edits=False), seed=0)
            memory = subterra.ObstacleMemory(p)
            for i in range(fdp.ConsumeIntInRange(0, 2)):
                memory.update(p.update(depth_frame(fdp)), stamp=float(i), world_from_body=rigid(fdp))
    except SubterraError:
        return
    stamp = 0.0
    for _ in range(fdp.ConsumeIntInRange(1, 6)):
        stamp = stamp + fdp.ConsumeFloatInRange(0.0, 5.0) if fdp.ConsumeIntInRange(0, 5) else real(fdp, -10.0, 100.0)
        try:
            out = esc.step(
                stamp=stamp, world_from_body=rigid(fdp), goal_world=point(fdp, 3, 20.0),
                remaining_m=real(fdp, 0.0, 20.0), memory=memory if fdp.ConsumeBool() else None,
                repulsive_body=maybe(fdp, lambda: point(fdp, 3, 10.0)),
            )
            out.goal_body
            out.boundary_world
        except SubterraError:
            pass


def path_follower(data: bytes) -> None:
    """``PathFollower`` on a fuzzed path and lookahead, updated at fuzzed positions."""
    import subterra
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    try:
        pf = subterra.PathFollower(array(fdp, (None, 3), lo=-20.0, hi=20.0, max_dim=12), lookahead_m=real(fdp, 0.0, 5.0))
        pf.points()
        pf.length_m
    except SubterraError:
        return
    for _ in range(fdp.ConsumeIntInRange(1, 5)):
        try:
            out = pf.update(point(fdp, 3, 20.0))
            out.carrot_world
        except SubterraError:
            pass
    pf.reset()


def _astar(fdp: atheris.FuzzedDataProvider) -> Any:
    import subterra

    kw: dict[str, Any] = {}
    for name, lo, hi in (("lam", 0.0, 2.0), ("r_inst", 0.0, 1.0), ("r_total", 0.0, 1.0), ("carrot_m", 0.0, 5.0),
                         ("unknown_risk", 0.0, 1.0), ("additive_weight", 0.0, 10.0), ("lethal_risk", 0.0, 1.0)):
        if fdp.ConsumeIntInRange(0, 3) == 0:
            kw[name] = real(fdp, lo, hi)
    if fdp.ConsumeBool():
        kw["allow_corner_cutting"] = fdp.ConsumeBool()
    if fdp.ConsumeIntInRange(0, 3) == 0:
        kw["cost_model"] = text(fdp, ["risk", "additive"])
    return subterra.RiskAStar(kw)


def _risk_grid(fdp: atheris.FuzzedDataProvider) -> Any:
    return array(fdp, (None, None), lo=0.0, hi=1.0, max_dim=16, dtypes=[np.float32, np.float64])


def astar_plan(data: bytes) -> None:
    """``RiskAStar.plan`` on a fuzzed risk grid, start, goal, resolution and origin."""
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    try:
        planner = _astar(fdp)
        res = planner.plan(_risk_grid(fdp), point(fdp, 2, 2.0), point(fdp, 2, 2.0),
                           resolution=real(fdp, 0.01, 1.0), origin=maybe(fdp, lambda: (real(fdp, -2, 2), real(fdp, -2, 2))))
        res.path_world
        res.carrot
        res.cost
    except SubterraError:
        pass


def astar_plan_toward(data: bytes) -> None:
    """``RiskAStar.plan_toward`` on a fuzzed risk grid, start and a target on or off the grid."""
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    try:
        planner = _astar(fdp)
        res = planner.plan_toward(_risk_grid(fdp), point(fdp, 2, 2.0), point(fdp, 2, 1e7),
                                  resolution=real(fdp, 0.01, 1.0), origin=maybe(fdp, lambda: (real(fdp, -2, 2), real(fdp, -2, 2))))
        res.path_world
        res.goal_cell
        res.cost
    except SubterraError:
        pass


def astar_plan_cells(data: bytes) -> None:
    """``RiskAStar.plan_cells`` on a fuzzed risk grid and start/goal cells."""
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    try:
        planner = _astar(fdp)
        cells = [(integer(fdp, -2, 18), integer(fdp, -2, 18)) for _ in range(2)]
        res = planner.plan_cells(_risk_grid(fdp), cells[0], cells[1], resolution=maybe(fdp, lambda: real(fdp, 0.01, 1.0)),
                                 origin=maybe(fdp, lambda: [real(fdp, -2, 2), real(fdp, -2, 2)]))
        res.path_cells
        res.accumulated_risk
    except SubterraError:
        pass


def _mpc_config_dict(fdp: atheris.FuzzedDataProvider) -> Any:
    import subterra

    if "mpc" not in _CACHE:
        _CACHE["mpc"] = subterra.MpcConfig().to_dict()
    if fdp.ConsumeIntInRange(0, 2):
        return None
    return mutate_tree(fdp, _CACHE["mpc"], 3)


def mpc_solve(data: bytes) -> None:
    """``MpcTracker.solve`` with a fuzzed config, state, reference path, risk grid and speed."""
    import subterra
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    try:
        mpc = subterra.MpcTracker(config=_mpc_config_dict(fdp))
    except SubterraError:
        return
    for _ in range(fdp.ConsumeIntInRange(1, 2)):
        kw: dict[str, Any] = {}
        if fdp.ConsumeBool():
            kw.update(risk=_risk_grid(fdp), resolution=real(fdp, 0.05, 1.0), origin=(real(fdp, -2, 0), real(fdp, -2, 0)))
        if fdp.ConsumeBool():
            kw["desired_speed"] = real(fdp, 0.0, 2.0)
        try:
            res = mpc.solve(point(fdp, 4, 3.0), array(fdp, (None, 2), lo=-3.0, hi=3.0, max_dim=10), **kw)
            res.command
            res.predicted
            res.polygons
        except SubterraError:
            pass
    mpc.reset()


def terrain_mapper_update(data: bytes) -> None:
    """``TerrainMapper.update`` on fuzzed scans, stamps, poses and confidences, then the
    risk map's queries."""
    import subterra
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    try:
        robot = None if fdp.ConsumeIntInRange(0, 3) else mutate_tree(fdp, subterra.RobotConfig.husky().to_dict(), 2)
        mapper = subterra.TerrainMapper(robot=robot, config=small_terrain(fdp))
    except SubterraError:
        return
    stamp = 0.0
    rm = None
    for _ in range(fdp.ConsumeIntInRange(1, 3)):
        stamp = stamp + 0.1 if fdp.ConsumeIntInRange(0, 5) else real(fdp, -5.0, 100.0)
        try:
            rm = mapper.update(
                scan(fdp), stamp=maybe(fdp, lambda: stamp), world_from_body=maybe(fdp, lambda: rigid(fdp, 3.0)),
                body_from_sensor=maybe(fdp, lambda: rigid(fdp, 1.0)), confidence=real(fdp, 0.0, 1.0) if fdp.ConsumeBool() else 1.0,
            )
        except SubterraError:
            pass
    if rm is None:
        return
    x, y = real(fdp, -3, 3), real(fdp, -3, 3)
    try:
        rm.layer(text(fdp, rm.layer_names))
        rm.risk_at(x, y)
        rm.value_at(text(fdp, rm.layer_names), x, y)
        rm.cell_of(x, y)
        rm.cvar(real(fdp, 0.0, 1.0))
        rm.to_image(text(fdp, rm.layer_names))
        rm.lethal_count()
        mapper.newest_points()
        mapper.last_fine
        if fdp.ConsumeBool():
            mapper.set_mission_items(array(fdp, (None, 3), lo=-3, hi=3, max_dim=4))
    except SubterraError:
        pass


def segment_ground(data: bytes) -> None:
    """``segment_ground`` on fuzzed points, sensor heights and configs."""
    import subterra
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    try:
        labels = subterra.segment_ground(scan(fdp), sensor_height=real(fdp, 0.0, 2.0),
                                         config=small_terrain(fdp) if fdp.ConsumeBool() else None)
        labels.sum()
    except SubterraError:
        pass


def navigator_step(data: bytes) -> None:
    """``Navigator.step`` over a few ticks with fuzzed goals, configs, scans, poses and speeds."""
    import subterra
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    try:
        config = None
        if fdp.ConsumeIntInRange(0, 3) == 0:
            config = {fdp.PickValueInList(["planner", "tracker", "recovery", "navigator"]): {}}
            config = mutate_tree(fdp, config, 2)
        nav = subterra.Navigator(point(fdp, 2, 3.0), home=maybe(fdp, lambda: point(fdp, 2, 3.0)),
                                 terrain=small_terrain(fdp, edits=False), config=config)
    except SubterraError:
        return
    stamp = 0.0
    for _ in range(fdp.ConsumeIntInRange(1, 3)):
        stamp = stamp + 0.1 if fdp.ConsumeIntInRange(0, 5) else real(fdp, -5.0, 100.0)
        try:
            out = nav.step(
                scan(fdp) if fdp.ConsumeIntInRange(0, 3) else None, stamp=maybe(fdp, lambda: stamp),
                world_from_body=rigid(fdp, 2.0), body_from_sensor=maybe(fdp, lambda: rigid(fdp, 1.0)),
                confidence=real(fdp, 0.0, 1.0) if fdp.ConsumeBool() else 1.0, speed=real(fdp, -1.0, 2.0),
            )
            out.command
            out.transitions
        except SubterraError:
            pass
    nav.plan_grid
    nav.transitions


def lzf_codec(data: bytes) -> None:
    """The core's LZF decoder (PCD binary_compressed) on fuzzed streams and sizes, against the
    NumPy decoder: both decode the same bytes, or the core says no and NumPy says why."""
    from subterra.errors import SubterraError
    from subterra.io import clouds

    fdp = atheris.FuzzedDataProvider(data)
    size = fdp.ConsumeIntInRange(0, 1 << 16)
    stream = fdp.ConsumeBytes(fdp.remaining_bytes())
    if size > max(1, len(stream)) * 88:
        return  # the PCD reader refuses such a ratio before decoding
    fast = clouds._lzf_decompress_fast(stream, size)
    try:
        slow = clouds._lzf_decompress(np.frombuffer(stream, np.uint8), size, "fuzz", Path("fuzz"))
    except SubterraError:
        slow = None
    if fast != slow:
        raise AssertionError(f"the decoders disagree: core {None if fast is None else len(fast)} bytes, NumPy {None if slow is None else len(slow)}")
    if fast is not None and size:
        again = clouds._lzf_decompress_fast(clouds._lzf_compress(fast), size)
        if again != fast:
            raise AssertionError("LZF round trip changed the bytes")


def ros_encoders(data: bytes) -> None:
    """The ROS message encoders the live node publishes with, on fuzzed stamps, frames,
    vectors, poses, paths, beliefs and diagnostics; what they accept serializes."""
    from subterra.errors import SubterraError
    from subterra.io import ros

    fdp = atheris.FuzzedDataProvider(data)
    ts = ros.default_typestore()
    stamp = fdp.PickValueInList([0, 1, 10**18, 2**63, -1, float("nan"), 1.5, real(fdp, -1e3, 1e12)])
    frame = text(fdp, ["odom", "base_link", "", "a b", "\x00"])
    kind = fdp.ConsumeIntInRange(0, 5)
    try:
        if kind == 0:
            msg, name = ros.twist_stamped_message(point(fdp, 3), point(fdp, 3), stamp_ns=stamp, frame_id=frame, typestore=ts), "geometry_msgs/msg/TwistStamped"
        elif kind == 1:
            msg, name = ros.pose_stamped_message(rigid(fdp), stamp_ns=stamp, frame_id=frame, typestore=ts), "geometry_msgs/msg/PoseStamped"
        elif kind == 2:
            msg, name = ros.path_message(array(fdp, (None, fdp.PickValueInList([2, 3, 4])), max_dim=6), stamp_ns=stamp, frame_id=frame,
                                         typestore=ts), "nav_msgs/msg/Path"
        elif kind == 3:
            n = fdp.ConsumeIntInRange(0, 5)
            msg, name = ros.belief_markers_message(array(fdp, (n, 3)), array(fdp, (n,), lo=0.0, hi=1.0), stamp_ns=stamp, frame_id=frame,
                                                   p_free=maybe(fdp, lambda: real(fdp, 0.0, 1.0)), typestore=ts), "visualization_msgs/msg/MarkerArray"
        elif kind == 4:
            items = [(text(fdp, ["node"]), text(fdp, ["ok", "warn", "nope"]), text(fdp, ["m"]), {text(fdp, ["k"]): any_value(fdp)})
                     for _ in range(fdp.ConsumeIntInRange(0, 3))]
            msg, name = ros.diagnostics_message(items, stamp_ns=stamp, hardware_id=frame, typestore=ts), "diagnostic_msgs/msg/DiagnosticArray"
        else:
            msg, name = ros.clock_message(stamp, ts), "rosgraph_msgs/msg/Clock"
    except SubterraError:
        return
    ts.deserialize_cdr(ts.serialize_cdr(msg, name), name)


def _text(data: bytes) -> str:
    return data.decode("utf-8", "replace")


def perception_config_toml(data: bytes) -> None:
    """``PerceptionConfig.from_toml`` on fuzzed text, and the round trips of what it accepts."""
    import subterra
    from subterra.errors import SubterraError

    try:
        cfg = subterra.PerceptionConfig.from_toml(_text(data))
        subterra.PerceptionConfig.from_toml(cfg.to_toml())
        cfg.to_dict()
    except SubterraError:
        pass


def perception_config_json(data: bytes) -> None:
    """``PerceptionConfig.from_json`` on fuzzed text."""
    import subterra
    from subterra.errors import SubterraError

    try:
        cfg = subterra.PerceptionConfig.from_json(_text(data))
        subterra.PerceptionConfig.from_json(cfg.to_json())
    except SubterraError:
        pass


def perception_config_dict(data: bytes) -> None:
    """``PerceptionConfig.from_dict`` on a preset's dict with fuzzed fields (types, values, keys)."""
    import subterra
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    preset = fdp.PickValueInList(sorted(subterra.preset_names()))
    key = "pd:" + preset
    if key not in _CACHE:
        _CACHE[key] = subterra.PerceptionConfig.preset(preset).to_dict()
    try:
        subterra.PerceptionConfig.from_dict(mutate_tree(fdp, _CACHE[key], 5))
    except SubterraError:
        pass


def terrain_config_toml(data: bytes) -> None:
    """``TerrainConfig.from_toml`` on fuzzed text."""
    import subterra
    from subterra.errors import SubterraError

    try:
        cfg = subterra.TerrainConfig.from_toml(_text(data))
        subterra.TerrainConfig.from_toml(cfg.to_toml())
    except SubterraError:
        pass


def terrain_config_dict(data: bytes) -> None:
    """``TerrainConfig.from_dict`` (and ``TerrainConfig(d)``) on the defaults with fuzzed fields."""
    import subterra
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    if "td" not in _CACHE:
        _CACHE["td"] = subterra.TerrainConfig().to_dict()
    d = mutate_tree(fdp, _CACHE["td"], 5)
    if fdp.ConsumeBool():
        d = {k: v for k, v in d.items() if fdp.ConsumeBool()}  # partial dicts lie over the defaults
    try:
        (subterra.TerrainConfig.from_dict(d) if fdp.ConsumeBool() else subterra.TerrainConfig(d)).to_dict()
    except SubterraError:
        pass


def robot_config_dict(data: bytes) -> None:
    """``RobotConfig.from_dict`` on the Husky's dict with fuzzed fields."""
    import subterra
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    if "rd" not in _CACHE:
        _CACHE["rd"] = subterra.RobotConfig.husky().to_dict()
    d = mutate_tree(fdp, _CACHE["rd"], 4)
    if fdp.ConsumeBool():
        d = {k: v for k, v in d.items() if fdp.ConsumeBool()}
    try:
        subterra.RobotConfig.from_dict(d).to_dict()
    except SubterraError:
        pass


def world_from_toml(data: bytes) -> None:
    """``sim.World.from_toml`` on fuzzed text; a world it accepts is queried (rays, clearance,
    ground height, primitives) at points from the input's last bytes."""
    from subterra import sim
    from subterra.errors import SubterraError

    cut = len(data) - min(len(data), 64)
    try:
        world = sim.World.from_toml(_text(data[:cut]))
    except SubterraError:
        return
    fdp = atheris.FuzzedDataProvider(data[cut:])
    try:
        world.cast_ray(point(fdp, 3, 20.0), point(fdp, 3, 1.0), real(fdp, 0.0, 100.0))
        world.clearance(point(fdp, 3, 20.0))
        world.ground_height(real(fdp, -20, 20), real(fdp, -20, 20))
        world.primitive(integer(fdp, -1, world.primitive_count))
        sim.World.from_toml(world.to_toml())
    except SubterraError:
        pass


def simulation_step(data: bytes) -> None:
    """``sim.Simulation`` of a small world stepped with fuzzed commands, time steps and goals."""
    from subterra import sim
    from subterra.errors import SubterraError

    fdp = atheris.FuzzedDataProvider(data)
    if "world" not in _CACHE:
        _CACHE["world"] = sim.World.from_toml(SMALL_WORLD)
    world = _CACHE["world"]
    vehicle = fdp.PickValueInList(["quadrotor", "ground"])
    try:
        sensors = None
        if fdp.ConsumeIntInRange(0, 2) == 0:
            sensors = {"front": (sim.DepthCamera(camera()), maybe(fdp, lambda: rigid(fdp, 0.5)),
                                 fdp.PickValueInList(list(sim.DEPTH_NOISE_PRESETS)))}
        start = [fdp.ConsumeFloatInRange(-1.0, 1.0), fdp.ConsumeFloatInRange(-1.0, 1.0), 1.0 if vehicle == "quadrotor" else 0.0]
        s = sim.Simulation(world, vehicle, sensors, fdp.ConsumeIntInRange(0, 2**31), start=start, yaw=real(fdp, -4, 4))
        if fdp.ConsumeBool():
            s.set_goal(region="B")
        else:
            s.set_goal(point=point(fdp, 3, 5.0), radius_m=real(fdp, 0.0, 2.0))
        if fdp.ConsumeBool():
            s.set_time_limit(maybe(fdp, lambda: real(fdp, 0.0, 10.0)))
    except SubterraError:
        return
    for _ in range(fdp.ConsumeIntInRange(1, 6)):
        try:
            s.step(point(fdp, 4, 3.0), dt=real(fdp, 0.0, 0.5), compute_time_s=real(fdp, 0.0, 0.1))
            if sensors is not None and fdp.ConsumeBool():
                s.observe(depth_dtype=fdp.PickValueInList(["float32", "uint16"]))
        except SubterraError:
            pass
    s.metrics()
    s.status


SMALL_WORLD = """name = "fuzz"
[[plane]]
point = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
[[box]]
centre = [3.0, 0.0, 1.0]
size = [0.5, 2.0, 2.0]
[[cylinder]]
a = [2.0, 1.5, 0.0]
b = [2.0, 1.5, 3.0]
radius = 0.2
[[region]]
name = "A"
centre = [0.0, 0.0, 1.0]
radius = 0.5
[[region]]
name = "B"
centre = [5.0, 0.0, 1.0]
radius = 0.5
"""

# --------------------------------------------------------------------------- the registry

#: name -> target function (one libFuzzer input in, nothing out).
TARGETS: dict[str, Callable[[bytes], None]] = {
    "cloud_pcd": _file_target(".pcd", _read_cloud),
    "cloud_ply": _file_target(".ply", _read_cloud),
    "cloud_kitti": _file_target(".bin", _read_cloud),
    "depth_png": _file_target(".png", _read_depth),
    "depth_npy": _file_target(".npy", _read_depth),
    "depth_npz": _file_target(".npz", _read_depth),
    "depth_pgm": _file_target(".pgm", _read_depth),
    "intrinsics_json": _file_target(".json", _read_intrinsics),
    "intrinsics_yaml": _file_target(".yaml", _read_intrinsics),
    "poses_tum": _file_target(".txt", _read_poses),
    "poses_kitti": _file_target(".txt", _read_poses),
    "recording_mcap": _file_target(".mcap", _read_recording),
    "world_file": _file_target(".toml", _load_world),
    "perception_config_file": _file_target(".toml", _load_config),
    "terrain_config_file": _file_target(".toml", _load_terrain_config),
    "mpc_config_file": _file_target(".toml", _mpc_config),
    "sweep_file": _file_target(".toml", _load_sweep),
    "node_config_file": _file_target(".toml", _load_node_config),
    "ros_pointcloud2": ros_pointcloud2,
    "ros_tf": ros_tf,
    "depth_perception_update": depth_perception_update,
    "obstacle_memory_update": obstacle_memory_update,
    "qmdp_act": qmdp_act,
    "apf_command": apf_command,
    "escape_step": escape_step,
    "path_follower": path_follower,
    "astar_plan": astar_plan,
    "astar_plan_cells": astar_plan_cells,
    "astar_plan_toward": astar_plan_toward,
    "mpc_solve": mpc_solve,
    "terrain_mapper_update": terrain_mapper_update,
    "segment_ground": segment_ground,
    "navigator_step": navigator_step,
    "perception_config_toml": perception_config_toml,
    "perception_config_json": perception_config_json,
    "perception_config_dict": perception_config_dict,
    "terrain_config_toml": terrain_config_toml,
    "terrain_config_dict": terrain_config_dict,
    "robot_config_dict": robot_config_dict,
    "world_from_toml": world_from_toml,
    "simulation_step": simulation_step,
    "lzf_codec": lzf_codec,
    "ros_encoders": ros_encoders,
}

_IO = ["subterra", "subterra.io"]
#: The subterra modules each target needs (imported instrumented by `main`); default: subterra.
MODULES: dict[str, list[str]] = {
    name: _IO for name in TARGETS if name.startswith(("cloud_", "intrinsics_", "poses_", "recording_", "ros_"))
}
MODULES.update({name: _IO for name in ("depth_png", "depth_npy", "depth_npz", "depth_pgm")})
MODULES.update({
    "recording_mcap": _IO + ["subterra.io.recordings"],
    "world_file": ["subterra", "subterra.sim"],
    "world_from_toml": ["subterra", "subterra.sim"],
    "simulation_step": ["subterra", "subterra.sim"],
    "terrain_config_file": ["subterra", "subterra.terrain"],
    "node_config_file": ["subterra", "subterra.live.config"],
    "lzf_codec": _IO + ["subterra.io.clouds"],
    "ros_encoders": _IO,
    "sweep_file": ["subterra", "subterra.batch.sweep_spec", "subterra.batch.sweep", "subterra.flight.batch",
                   "subterra.flight.run", "subterra.drive.run", "subterra.sim"],
})
#: The largest input libFuzzer makes per target [bytes] (the default elsewhere).
MAX_LEN: dict[str, int] = {name: 16384 for name, fn in TARGETS.items() if getattr(fn, "file_suffix", None)}
MAX_LEN.update({"recording_mcap": 32768})
DEFAULT_MAX_LEN = 2048


def load(name: str) -> Callable[[bytes], None]:
    """The target ``name`` with its modules imported (instrumented when atheris is fuzzing)."""
    for module in MODULES.get(name, ["subterra"]):
        importlib.import_module(module)
    return TARGETS[name]


def _instrument_harness() -> None:
    """Instruments this module's own functions (the targets and the value generators): the Rust
    core gives libFuzzer no coverage, so the branches a target takes on its fuzzed arguments
    (which shape, dtype, layout, special value, which call raised) are what guides it there."""
    module = sys.modules[__name__]
    for key, value in list(vars(module).items()):
        if callable(value) and getattr(value, "__module__", None) == __name__ and hasattr(value, "__code__"):
            setattr(module, key, atheris.instrument_func(value))
    for key, fn in list(TARGETS.items()):
        if hasattr(fn, "__code__"):
            instrumented = atheris.instrument_func(fn)
            instrumented.__dict__.update(fn.__dict__)
            TARGETS[key] = instrumented


def main(argv: list[str]) -> None:
    if len(argv) < 2 or argv[1] not in TARGETS:
        sys.exit(f"usage: {argv[0]} TARGET [libFuzzer flags] [corpus folders]; targets: {', '.join(TARGETS)}")
    name = argv[1]
    with atheris.instrument_imports(include=["subterra"]):
        target = load(name)
    _instrument_harness()
    target = TARGETS[name]
    atheris.Setup([argv[0], *argv[2:]], target)
    atheris.Fuzz()


if __name__ == "__main__":
    main(sys.argv)
