"""Writes the seed corpora of the fuzz targets: ``fuzz/seeds/<target>/``.

Every seed is a small, valid example made by subterra's own writers and configs (clouds by
``write_pcd`` / ``write_ply``, depth images by ``write_depth_png`` and NumPy, recordings by
``McapWriter``, configs by the presets' ``to_toml`` and ``configs/*.toml``, worlds by
``World.to_toml``); the array targets get a few fixed pseudo-random inputs, from which
libFuzzer grows its own. The output is deterministic: rerunning rewrites the same files.

    python fuzz/make_corpus.py [--out fuzz/seeds]
"""

from __future__ import annotations

import argparse
import io
import json
import random
import shutil
import sys
import zipfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))

import targets  # noqa: E402  (the registry: every target gets a folder)


def _points(n: int = 12, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    p = rng.uniform(-5, 5, (n, 3)).astype(np.float32)
    p[3] = np.nan  # a missing return, kept by the readers
    return p


def clouds(out: Path) -> None:
    from subterra.io import write_pcd, write_ply

    pts = _points()
    fields = {"intensity": np.arange(len(pts), dtype=np.float32), "ring": (np.arange(len(pts)) % 4).astype(np.uint16)}
    tmp = out / "_tmp"
    tmp.mkdir(parents=True, exist_ok=True)
    for name, kw in (("binary", {"binary": True}), ("ascii", {"binary": False})):
        write_pcd(tmp / "a.pcd", pts, fields, **kw)
        _put(out, "cloud_pcd", f"{name}.pcd", (tmp / "a.pcd").read_bytes())
        write_ply(tmp / "a.ply", pts, fields, **kw)
        _put(out, "cloud_ply", f"{name}.ply", (tmp / "a.ply").read_bytes())
    try:  # binary_compressed (LZF), where the writer offers it
        write_pcd(tmp / "a.pcd", pts, fields, binary="compressed")  # type: ignore[arg-type]
        _put(out, "cloud_pcd", "compressed.pcd", (tmp / "a.pcd").read_bytes())
    except Exception:  # noqa: BLE001 - an optional seed
        pass
    write_pcd(tmp / "a.pcd", pts[:3], None, binary=False)
    _put(out, "cloud_pcd", "xyz.pcd", (tmp / "a.pcd").read_bytes())
    # PLY with a face element after the vertices (skipped by the reader).
    ply = (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
           b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    _put(out, "cloud_ply", "face.ply", ply)
    kitti = np.column_stack([pts, np.linspace(0, 1, len(pts), dtype=np.float32)]).astype("<f4")
    _put(out, "cloud_kitti", "scan.bin", kitti.tobytes())
    _put(out, "cloud_kitti", "one.bin", kitti[:1].tobytes())
    shutil.rmtree(tmp)


def depth(out: Path) -> None:
    from subterra.io import write_depth_png

    tmp = out / "_tmp"
    tmp.mkdir(parents=True, exist_ok=True)
    img = (np.arange(48, dtype=np.uint16).reshape(6, 8) * 50).astype(np.uint16)
    img[0, 0] = 0
    write_depth_png(tmp / "d.png", img)
    _put(out, "depth_png", "mm.png", (tmp / "d.png").read_bytes())
    write_depth_png(tmp / "d.png", img[:1, :2])
    _put(out, "depth_png", "tiny.png", (tmp / "d.png").read_bytes())
    metres = img.astype(np.float32) / 1000
    metres[1, 1] = np.nan
    for name, arr in (("u16", img), ("f32", metres), ("f64", metres.astype(np.float64))):
        buf = io.BytesIO()
        np.save(buf, arr)
        _put(out, "depth_npy", f"{name}.npy", buf.getvalue())
    buf = io.BytesIO()
    np.save(buf, np.asfortranarray(img))
    _put(out, "depth_npy", "fortran.npy", buf.getvalue())
    for name, saver, kw in (("plain", np.savez, {"depth": img}), ("deflated", np.savez_compressed, {"depth": metres}),
                            ("single", np.savez, {"d": img})):
        buf = io.BytesIO()
        saver(buf, **kw)
        _put(out, "depth_npz", f"{name}.npz", buf.getvalue())
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:  # two arrays, one named depth
        for key, arr in (("rgb", img[:2]), ("depth", img)):
            member = io.BytesIO()
            np.save(member, arr)
            z.writestr(zipfile.ZipInfo(key + ".npy", date_time=(2024, 1, 1, 0, 0, 0)), member.getvalue())
    _put(out, "depth_npz", "two.npz", buf.getvalue())
    h, w = img.shape
    _put(out, "depth_pgm", "mm.pgm", f"P5\n{w} {h}\n65535\n".encode() + img.astype(">u2").tobytes())
    _put(out, "depth_pgm", "comment.pgm", f"P5 # depth\n# made by make_corpus\n{w} {h} 4095\n".encode() + img.astype(">u2").tobytes())
    shutil.rmtree(tmp)


def intrinsics(out: Path) -> None:
    plain = {"fx": 385.0, "fy": 385.0, "cx": 319.5, "cy": 239.5, "width": 640, "height": 480}
    open3d = {"width": 640, "height": 480, "intrinsic_matrix": [385.0, 0, 0, 0, 385.0, 0, 319.5, 239.5, 1]}
    k = [385.0, 0, 319.5, 0, 385.0, 239.5, 0, 0, 1]
    info = {"header": {"frame_id": "camera"}, "height": 480, "width": 640, "distortion_model": "plumb_bob",
            "d": [0.0] * 5, "k": k, "r": [1, 0, 0, 0, 1, 0, 0, 0, 1], "p": k[:3] + [0] + k[3:6] + [0] + k[6:] + [0]}
    for name, doc in (("plain", plain), ("open3d", open3d), ("camera_info", info)):
        _put(out, "intrinsics_json", f"{name}.json", json.dumps(doc, indent=1).encode())
    ros = ("image_width: 640\nimage_height: 480\ncamera_name: depth\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
           "  data: [385.0, 0.0, 319.5, 0.0, 385.0, 239.5, 0.0, 0.0, 1.0]\ndistortion_model: plumb_bob\n"
           "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [0, 0, 0, 0, 0]\n")
    _put(out, "intrinsics_yaml", "calibration.yaml", ros.encode())
    echo = "header:\n  frame_id: camera\nheight: 480\nwidth: 640\nK: [385.0, 0.0, 319.5, 0.0, 385.0, 239.5, 0.0, 0.0, 1.0]\n---\n"
    _put(out, "intrinsics_yaml", "echo.yaml", echo.encode())
    _put(out, "intrinsics_yaml", "plain.yaml", "".join(f"{k}: {v}\n" for k, v in plain.items()).encode())


def poses(out: Path) -> None:
    tum = "# timestamp tx ty tz qx qy qz qw\n" + "".join(
        f"{1.0 + 0.1 * i:.6f} {0.1 * i:.4f} 0.0 0.5 0.0 0.0 {np.sin(0.05 * i):.6f} {np.cos(0.05 * i):.6f}\n" for i in range(5))
    _put(out, "poses_tum", "tum.txt", tum.encode())
    _put(out, "poses_tum", "nostamp.txt", b"0 0 0 0 0 0 1\n1,0,0,0,0,0,1\n")
    kitti = "".join(f"1 0 0 {0.5 * i:g} 0 1 0 0 0 0 1 {0.1 * i:g}\n" for i in range(4))
    _put(out, "poses_kitti", "kitti.txt", kitti.encode())
    c, s = np.cos(0.3), np.sin(0.3)
    rotated = f"{c:.9f} {-s:.9f} 0 1 {s:.9f} {c:.9f} 0 2 0 0 1 3\n\n# comment\n1 0 0 0 0 1 0 0 0 0 1 0\n"
    _put(out, "poses_kitti", "rotated.txt", rotated.encode())


def recordings(out: Path) -> None:
    from mcap.writer import CompressionType, Writer

    from subterra.io import McapWriter, ros

    ts = ros.default_typestore()
    pts = _points(6)
    msgs = [
        ("/os_lidar/points", ros.pointcloud2_message(pts, {"intensity": np.ones(6, np.float32)}, stamp_ns=10, frame_id="os_lidar", typestore=ts)),
        ("/tf_static", ros.tf_message([("base_link", "os_lidar", 0, np.eye(4))], ts)),
        ("/tf", ros.tf_message([("odom", "base_link", 10, np.eye(4))], ts)),
        ("/odom", ros.odometry_message(np.eye(4), stamp_ns=10, typestore=ts)),
    ]
    tmp = out / "_tmp"
    tmp.mkdir(parents=True, exist_ok=True)
    with McapWriter(tmp / "r.mcap", typestore=ts) as w:
        for i, (topic, msg) in enumerate(msgs):
            w.write(topic, msg, log_time_ns=10 + i)
    _put(out, "recording_mcap", "zstd.mcap", (tmp / "r.mcap").read_bytes())
    for name, chunked in (("plain", False), ("chunked", True)):
        buf = io.BytesIO()
        writer = Writer(buf, compression=CompressionType.NONE, use_chunking=chunked)
        writer.start(profile="ros2", library="subterra-fuzz")
        schemas: dict[str, int] = {}
        for i, (topic, msg) in enumerate(msgs):
            msgtype = msg.__msgtype__
            if msgtype not in schemas:
                msgdef, _ = ts.generate_msgdef(msgtype, ros_version=2)
                schemas[msgtype] = writer.register_schema(name=msgtype, encoding="ros2msg", data=msgdef.encode())
            channel = writer.register_channel(topic=topic, message_encoding="cdr", schema_id=schemas[msgtype])
            writer.add_message(channel_id=channel, log_time=10 + i, data=bytes(ts.serialize_cdr(msg, msgtype)), publish_time=10 + i)
        writer.finish()
        raw = buf.getvalue()
        _put(out, "recording_mcap", f"{name}.mcap", raw)
        if not chunked:
            _put(out, "recording_mcap", "truncated.mcap", raw[: len(raw) * 2 // 3])
    shutil.rmtree(tmp)


def configs(out: Path) -> None:
    import subterra
    from subterra import sim

    for preset in sorted(subterra.preset_names()):
        cfg = subterra.PerceptionConfig.preset(preset)
        _put(out, "perception_config_file", f"{preset}.toml", cfg.to_toml().encode())
        _put(out, "perception_config_toml", f"{preset}.toml", cfg.to_toml().encode())
        _put(out, "perception_config_json", f"{preset}.json", cfg.to_json().encode())
    for name in ("flight", "flight-memory"):
        text = (REPO / "configs" / f"{name}.toml").read_text()
        _put(out, "perception_config_file", f"configs-{name}.toml", text.encode())
    terrain = subterra.TerrainConfig().to_toml()
    _put(out, "terrain_config_file", "default.toml", terrain.encode())
    _put(out, "terrain_config_toml", "default.toml", terrain.encode())
    _put(out, "terrain_config_toml", "partial.toml", b"fine_enabled = false\n[coarse]\nresolution_m = 0.2\nsize_x_m = 4.0\n")
    _put(out, "terrain_config_file", "configs-terrain.toml", (REPO / "configs" / "terrain.toml").read_bytes())
    _put(out, "mpc_config_file", "configs-mpc.toml", (REPO / "configs" / "mpc.toml").read_bytes())
    _put(out, "mpc_config_file", "partial.toml", b"[limits]\nmax_speed_m_s = 0.5\n")
    small = sim.World.from_toml(targets.SMALL_WORLD).to_toml()
    for target in ("world_file", "world_from_toml"):
        _put(out, target, "small.toml", small.encode())
        _put(out, target, "hand.toml", targets.SMALL_WORLD.encode())
        _put(out, target, "example.toml", (REPO / "docs" / "examples" / "world.toml").read_bytes())
        _put(out, target, "empty.toml", b"")
    _put(out, "world_file", "cable.toml", sim.World.scenario("cable", seed=0).to_toml().encode())
    _put(out, "world_from_toml", "slopes.toml", sim.World.scenario("slopes", seed=0).to_toml().encode()[:16000])
    sweeps = {
        "grid.toml": 'kind = "fly"\nworlds = ["highbay"]\nseeds = 2\n[grid]\nperception.sigma_o = [120, 170]\nperception.apf.rho_0_m = [1.0, 1.4]\n',
        "random.toml": ('worlds = ["highbay"]\nnoises = ["d435-phantom"]\nseeds = {first = 100, count = 3}\n[random]\nsamples = 3\nseed = 0\n'
                        'perception.sigma_o = {low = 100, high = 300}\nperception.filter.mode = ["particle", "histogram"]\n'),
        "drive.toml": 'kind = "drive"\nworlds = ["mine"]\nplanners = ["risk-aware"]\nseeds = [1, 2]\n[grid]\nplanner.lam = [0.1, 0.2]\nterrain.coarse.resolution_m = [0.1]\n',
        "settings.toml": 'time_limit_s = 20\nrate_hz = 10\npreset = "flight-memory"\n[grid]\nstall_window_s = [2.0, 3.0]\n',
    }
    for name, text in sweeps.items():
        _put(out, "sweep_file", name, text.encode())
    _put(out, "node_config_file", "default.toml", (REPO / "configs" / "node.toml").read_bytes())
    _put(out, "node_config_file", "partial.toml", b'[node]\ndomain_id = 7\n[topics]\npoints = "/ouster/points"\nodometry = ["/a", "/b"]\n')


def codecs(out: Path) -> None:
    """LZF streams: a size (4 bytes, as FuzzedDataProvider reads an int) then the stream."""
    from subterra.io import clouds as io_clouds

    plain = (np.arange(600, dtype=np.float32) % 7).tobytes()
    packed = io_clouds._lzf_compress(plain)
    _put(out, "lzf_codec", "floats", len(plain).to_bytes(4, "little") + packed)
    literal = bytes(range(40))
    _put(out, "lzf_codec", "literal", len(literal).to_bytes(4, "little") + io_clouds._lzf_compress(literal))


def fdp_blobs(out: Path) -> None:
    """A few fixed pseudo-random inputs for each target that draws its arguments from the bytes."""
    rnd = random.Random(20240522)
    for name, fn in targets.TARGETS.items():
        if getattr(fn, "file_suffix", None) or (out / name).is_dir():
            continue
        for size in (0, 16, 128, 512, 1500):
            _put(out, name, f"random-{size}", rnd.randbytes(size))


def _put(out: Path, target: str, name: str, data: bytes) -> None:
    if target not in targets.TARGETS:
        raise KeyError(target)
    folder = out / target
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_bytes(data)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=HERE / "seeds")
    args = parser.parse_args(argv)
    out: Path = args.out
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    for make in (clouds, depth, intrinsics, poses, recordings, configs, codecs, fdp_blobs):
        make(out)
    missing = [name for name in targets.TARGETS if not (out / name).is_dir()]
    if missing:
        print(f"no seeds for {missing}", file=sys.stderr)
        return 1
    total = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    print(f"{sum(1 for f in out.rglob('*') if f.is_file())} seeds, {total} bytes, for {len(targets.TARGETS)} targets in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
