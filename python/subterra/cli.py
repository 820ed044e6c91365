"""The `subterra` command line.

Errors are one line on stderr (``error: ...``) with exit code 2; ``--debug`` shows the
traceback instead.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from subterra.errors import SubterraError

__all__ = ["main"]


def _goal(text: str) -> tuple[float, float, float]:
    try:
        x, y, z = (float(v) for v in text.split(","))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected x,y,z in metres, got {text!r}") from exc
    return x, y, z


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="subterra", description="Perception and planning for robots underground.")
    p.add_argument("--debug", action="store_true", help="show the traceback on errors")
    sub = p.add_subparsers(dest="command", required=True)

    per = sub.add_parser("perceive", help="run APF-PF over a folder of depth images")
    per.add_argument("directory", help="folder of 16-bit PNG / PGM depth images or .npy/.npz arrays")
    per.add_argument("--intrinsics", required=True, help="camera intrinsics: plain JSON, Open3D JSON or ROS CameraInfo YAML")
    per.add_argument("--preset", default="flight", help="perception preset (default: flight)")
    per.add_argument("--config", help="TOML config file, instead of --preset")
    per.add_argument("--scale", type=float, help="metres per unit of uint16 images (default 0.001; TUM: 0.0002)")
    per.add_argument("--seed", type=int, default=0)
    per.add_argument("--goal", type=_goal, default=(5.0, 0.0, 0.0), help="goal x,y,z in the body frame [m]")
    per.add_argument("--out", default="runs/perceive", help="output folder (default runs/perceive)")

    bench = sub.add_parser("bench", help="benchmarks against the NumPy reference")
    bench.add_argument("what", choices=["perception", "sim"])
    bench.add_argument("--frames", type=int, default=300)
    bench.add_argument("--reference-frames", type=int, default=30)
    bench.add_argument("--mode", choices=["particle", "histogram"], default="particle")
    bench.add_argument("--seed", type=int, default=0)
    bench.add_argument("--out", help="write the JSON report here too")

    sim = sub.add_parser("sim", help="the simulator: look at the built-in scenes")
    sim_sub = sim.add_subparsers(dest="sim_command", required=True)
    render = sim_sub.add_parser("render", help="PNGs of a scenario: a depth frame and a top-down map with a lidar scan")
    render.add_argument("scenario", help="highbay, cable, tunnel, mine or subway")
    render.add_argument("--seed", type=int, default=0)
    render.add_argument("--noise", default="d435", help="depth noise preset (default d435)")
    render.add_argument("--out", default="runs/render", help="output folder (default runs/render)")

    demo = sub.add_parser("demo", help="the main job: run the pipelines on built-in scenes and real data")
    demo.add_argument("--data", default=None, help="shared data folder (default: ../shared/data if present)")
    demo.add_argument("--out", default=None, help="report folder (default runs/demo-<time>)")
    return p


def _perceive(args: argparse.Namespace) -> int:
    from subterra import load_config
    from subterra.perceive import perceive_folder

    config = load_config(args.config) if args.config else None
    summary = perceive_folder(
        args.directory, args.intrinsics, out_dir=args.out, preset=args.preset, config=config,
        scale=args.scale, seed=args.seed, goal_body=args.goal,
    )
    t = summary["timing"]
    print(
        f"{summary['frames']} frames, grid {tuple(summary['grid_shape'])}, "
        f"median {t['median_ms']:.3f} ms, p99 {t['p99_ms']:.3f} ms per frame, "
        f"mean P(free) {summary['p_free_mean']:.3f}"
    )
    print(f"wrote {Path(args.out) / 'summary.json'} and {Path(args.out) / 'perception.png'}")
    return 0


def _bench(args: argparse.Namespace) -> int:
    if args.what == "sim":
        from subterra.bench.sim import bench_sim

        report = bench_sim(seed=args.seed)
    else:
        from subterra.bench.perception import bench_perception

        report = bench_perception(frames=args.frames, reference_frames=args.reference_frames, mode=args.mode, seed=args.seed)
    text = json.dumps(report, indent=2)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text, encoding="utf-8")
    print(text)
    return 0


def _sim(args: argparse.Namespace) -> int:
    from subterra.sim.render import render_scenario

    paths = render_scenario(args.scenario, args.out, seed=args.seed, noise=args.noise)
    for kind, path in paths.items():
        print(f"wrote {kind}: {path}")
    return 0


def _demo(args: argparse.Namespace) -> int:
    from subterra.demo import run_demo

    return run_demo(data=args.data, out=args.out)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `subterra` command."""
    args = _parser().parse_args(argv)
    handlers = {"perceive": _perceive, "bench": _bench, "sim": _sim, "demo": _demo}
    try:
        return handlers[args.command](args)
    except (SubterraError, ValueError, OSError) as exc:
        if args.debug:
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
