"""The `subterra` command line.

Errors are one line on stderr (``error: ...``) with exit code 2 (bad arguments, among them
unknown names and absurd numbers, which the argparse types below reject as ``error:
argument --x: ...``; bad inputs, configs or files); anything else is a bug, ``error:
internal error: ...`` with exit code 1.
``--debug`` shows the traceback instead. Every subcommand's handler runs through
:func:`main`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from subterra.errors import InputError, SubterraError

__all__ = [
    "finite_floats", "float_in", "int_in", "main", "nonempty", "nonnegative_int", "positive_float", "positive_int",
    "positive_rate", "seed_int", "sim_seconds", "unit_float",
]

# ---------------------------------------------------------------------- argparse types
# Each raises argparse.ArgumentTypeError, which argparse reports as
# ``subterra <cmd>: error: argument --x: <message>`` with exit code 2.

#: Most runs, frames, seeds, messages, ... a count option takes (beyond: a typo).
MAX_COUNT = 1_000_000


def float_in(low: float, high: float, *, low_open: bool = True, unit: str = "") -> Callable[[str], float]:
    """An argparse type: a finite number in ``(low, high]`` (``[low, high]`` with ``low_open=False``)."""
    interval = f"{'(' if low_open else '['}{low:g}, {high:g}]{f' {unit}' if unit else ''}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number in {interval}, got {text!r}") from None
        if not (math.isfinite(value) and (low < value if low_open else low <= value) and value <= high):
            raise argparse.ArgumentTypeError(f"must be a finite number in {interval}, got {text!r}")
        return value

    parse.__name__ = "number"
    return parse


def int_in(low: int, high: int) -> Callable[[str], int]:
    """An argparse type: an integer in ``low..high``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer in {low}..{high}, got {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be an integer in {low}..{high}, got {text!r}")
        return value

    parse.__name__ = "integer"
    return parse


def nonempty(text: str) -> str:
    """An argparse type: a path or a value given explicitly, so not empty (``--world ''`` is a
    mistake, not "no world": leave the option out for its default)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"expected a value (leave the option out for its default), got {text!r}")
    return text


nonempty.__name__ = "value"

#: Shortest ``--time-limit`` [s] (drive, fly, sil): one control step; below (1e-320) is a typo.
MIN_SIM_SECONDS = 0.01

#: A finite number > 0 (no upper bound).
positive_float = float_in(0.0, sys.float_info.max)
#: A number in [0, 1].
unit_float = float_in(0.0, 1.0, low_open=False)
#: A count of runs, frames, messages, ...: 1..MAX_COUNT.
positive_int = int_in(1, MAX_COUNT)
#: 0..MAX_COUNT (e.g. reference frames, where 0 skips the reference).
nonnegative_int = int_in(0, MAX_COUNT)
#: A random seed (the simulator's and the filters' seeds are unsigned).
seed_int = int_in(0, 2**32 - 1)
#: A rate [Hz]; the pipelines narrow it further (e.g. 1..200 Hz for flights).
positive_rate = float_in(0.0, 1000.0, unit="Hz")
#: Simulated seconds (MIN_SIM_SECONDS to a day).
sim_seconds = float_in(MIN_SIM_SECONDS, 86_400.0, low_open=False, unit="s")


def finite_floats(n: int, what: str) -> Callable[[str], tuple[float, ...]]:
    """An argparse type: ``n`` comma-separated finite numbers (``what`` names them, e.g. ``x,y,z in metres``)."""

    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(","))
        except ValueError:
            values = ()
        if len(values) != n or not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"expected {what} (finite numbers), got {text!r}")
        return values

    parse.__name__ = "numbers"
    return parse


_goal = finite_floats(3, "x,y,z in metres")


def add_fault_options(p: argparse.ArgumentParser, unit: str) -> None:
    """``--faults`` and ``--faults-config`` (subterra.sim.faults)."""
    from subterra.sim.faults import FAULT_NAMES

    p.add_argument("--faults", type=nonempty, default=None,
                   help=f"inject faults, comma-separated, or 'all' (a batch gives each {unit} the next in turn): " + ", ".join(FAULT_NAMES))
    p.add_argument("--faults-config", type=nonempty, default=None, help="TOML file with a [faults.<name>] table per fault's settings")


def fault_options(args: argparse.Namespace) -> tuple[list[str], dict | None]:
    """The faults and their settings of ``--faults`` and ``--faults-config``."""
    from subterra.sim.faults import load_faults_config, parse_faults

    faults = parse_faults(args.faults)
    config = load_faults_config(args.faults_config) if args.faults_config is not None else None
    if config and not faults:
        raise InputError("argument --faults-config: give --faults too (which faults to inject)")
    return faults, config


def _flight_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="highbay", help="built-in scenario with routes: highbay (default), tunnel or warehouse")
    p.add_argument("--preset", default="flight-escape",
                   help="perception preset: flight-escape (default: flight-memory with the escape from local minima), "
                        "acc2021 (the paper exactly, with the authors' conventions), flight (the paper's values with "
                        "subterra's conventions), flight-memory (sigma_o 300 and an obstacle memory), cable; "
                        "fly-batch takes a comma-separated list")
    p.add_argument("--config", type=nonempty, default=None, help="perception config TOML, instead of --preset")
    p.add_argument("--rate", type=positive_rate, default=15.0, help="camera and control rate [Hz] (default 15)")
    add_fault_options(p, "flight")


class _Parser(argparse.ArgumentParser):
    """argparse with the command's error format: one line ``error: argument --x: ...``, exit 2
    (the subcommands' parsers are of this class too)."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"error: {message} (see {self.prog} --help)\n")


def _parser() -> argparse.ArgumentParser:
    from subterra._core import Pilot
    from subterra.batch.cli import add_engine_options
    from subterra.sim import DEFAULT_DEPTH_NOISE, DEPTH_NOISE_PRESETS

    p = _Parser(prog="subterra", description="Perception and planning for robots underground.")
    from subterra import __version__

    p.add_argument("--debug", action="store_true", help="show the traceback on errors")
    p.add_argument("--version", action="version", version=f"subterra {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    per = sub.add_parser("perceive", help="run APF-PF over a folder of depth images")
    per.add_argument("directory", help="folder of 16-bit PNG / PGM depth images or .npy/.npz arrays")
    per.add_argument("--intrinsics", required=True, help="camera intrinsics: plain JSON, Open3D JSON or ROS CameraInfo YAML")
    per.add_argument("--preset", default="flight",
                     help="perception preset (default: flight); flight-memory and flight-escape run the obstacle "
                          "memory and the escape too, the camera taken as standing still")
    per.add_argument("--config", type=nonempty, help="TOML config file, instead of --preset")
    per.add_argument("--scale", type=float_in(0.0, 1.0, unit="m"), help="metres per unit of uint16 images (default 0.001; TUM: 0.0002)")
    per.add_argument("--seed", type=seed_int, default=0)
    per.add_argument("--goal", type=_goal, default=(5.0, 0.0, 0.0), help="goal x,y,z in the body frame [m]")
    per.add_argument("--out", type=nonempty, default="runs/perceive", help="output folder (default runs/perceive)")

    bench = sub.add_parser("bench", help="benchmarks against the NumPy reference")
    bench.add_argument("what", choices=["batch", "perception", "plan", "replay", "sim", "terrain"])
    bench.add_argument("--frames", type=positive_int, default=300)
    bench.add_argument("--reference-frames", type=nonnegative_int, default=30)
    bench.add_argument("--repeats", type=positive_int, default=20, help="terrain: timed map updates; plan: timed plans per case (default 20)")
    bench.add_argument("--mode", choices=["particle", "histogram"], default="particle")
    bench.add_argument("--preset", default="flight",
                       help="perception: the preset the pilot flies (default flight, the paper's values: the "
                            "NumPy reference implements the same filter; flight-memory and flight-escape add the "
                            "memory and the escape, which the reference does not have)")
    bench.add_argument("--messages", type=positive_int, default=20, help="replay: clouds and images per recording (default 20)")
    bench.add_argument("--seed", type=seed_int, default=0)
    bench.add_argument("--flights", type=positive_int, default=20, help="batch: flights per engine (default 20)")
    bench.add_argument("--out", type=nonempty, help="write the JSON report here too")

    sim = sub.add_parser("sim", help="the simulator: look at the built-in scenes")
    sim_sub = sim.add_subparsers(dest="sim_command", required=True)
    render = sim_sub.add_parser("render", help="PNGs of a scenario: a depth frame and a top-down map with a lidar scan")
    render.add_argument("scenario", help="highbay, cable, tunnel, mine or subway")
    render.add_argument("--seed", type=seed_int, default=0)
    render.add_argument("--noise", default="d435", help="depth noise preset (default d435)")
    render.add_argument("--out", type=nonempty, default="runs/render", help="output folder (default runs/render)")

    fly = sub.add_parser("fly", help="one closed-loop flight in the simulator (depth camera -> controller -> quadrotor)")
    _flight_options(fly)
    fly.add_argument("--route", type=nonempty, default=None, help="route, e.g. A-B (default: the world's first; highbay: A-B, B-C, C-D, D-C, D-B; tunnel: start-goal)")
    fly.add_argument("--controller", default="apf-pf", choices=list(Pilot.controllers()),
                     help="apf-pf (particle filter, the paper), apf-pf-histogram (exact filter), apf-pf-qmdp (QMDP "
                          "action selection over the particle belief, the authors' follow-up) or raw-apf (the baseline)")
    fly.add_argument("--noise", default="d435", help="depth noise model: " + ", ".join(DEPTH_NOISE_PRESETS) + " (default d435)")
    fly.add_argument("--seed", type=seed_int, default=0, help="world layout, noise and filter seed (default 0)")
    fly.add_argument("--time-limit", type=sim_seconds, default=None, help="seconds of simulated time (default: 4x the straight-line time)")
    fly.add_argument("--world", type=nonempty, default=None, help="fly in this world file (TOML) instead of a built-in scenario")
    fly.add_argument("--no-rerun", action="store_true", help="do not write flight.rrd even if rerun-sdk is installed")
    fly.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    fly.add_argument("--out", type=nonempty, default=None, help="run folder (default runs/fly-<scenario>-<route>-<controller>-<noise>-s<seed>)")

    batch = sub.add_parser("fly-batch", help="many randomized flights, APF-PF and the raw-APF baseline side by side")
    _flight_options(batch)
    batch.add_argument("--routes", default="all", help="comma-separated routes or 'all' (default)")
    batch.add_argument("--seeds", type=positive_int, default=50, help="seeds 0..N-1, one obstacle layout each (default 50)")
    batch.add_argument("--first-seed", type=seed_int, default=0, help="start the seeds here (default 0)")
    batch.add_argument("--controllers", default="apf-pf,raw-apf@flight",
                       help="comma-separated; name@preset flies that preset whatever --preset says "
                            "(default apf-pf,raw-apf@flight: the paper's raw-APF baseline beside --preset's APF-PF)")
    batch.add_argument("--noise", default=DEFAULT_DEPTH_NOISE, help=f"comma-separated noise models (default {DEFAULT_DEPTH_NOISE})")
    batch.add_argument("--no-plots", action="store_true", help="skip the path figure")
    add_engine_options(batch, unit="flight")

    from subterra.flight.cable import register_cli as register_cable_test

    register_cable_test(sub)

    from subterra.terrain.cli import register_cli as register_terrain

    register_terrain(sub)

    from subterra.replay import register_cli as register_replay

    register_replay(sub)

    from subterra.drive.cli import register_cli as register_drive

    register_drive(sub)

    from subterra.batch.sweep import register_cli as register_sweep

    register_sweep(sub)

    from subterra.live.cli import register_cli as register_live

    register_live(sub)

    demo = sub.add_parser("demo", help="the main job: simulated flights, the cable test and a small batch, with a report")
    demo.add_argument("--data", type=nonempty, default=None, help="shared data folder (default: ../shared/data if present)")
    demo.add_argument("--out", type=nonempty, default=None, help="report folder (default runs/demo-<time>)")
    demo.add_argument("--quick", action="store_true", help="a short version (20 s flights, fewer frames, one batch route)")
    _debug_everywhere(p)
    return p


def _debug_everywhere(parser: argparse.ArgumentParser) -> None:
    """``--debug`` after any subcommand too (``subterra drive --debug``), not only before it."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                if not any("--debug" in a.option_strings for a in child._actions):
                    child.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show the traceback on errors")
                _debug_everywhere(child)


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
    if args.what == "batch":
        from subterra.bench.batch import bench_batch

        report = bench_batch(flights=args.flights, seed=args.seed)
    elif args.what == "sim":
        from subterra.bench.sim import bench_sim

        report = bench_sim(seed=args.seed)
    elif args.what == "replay":
        from subterra.bench.replay import bench_replay

        report = bench_replay(messages=args.messages, seed=args.seed)
    elif args.what == "plan":
        from subterra.bench.plan import bench_plan

        report = bench_plan(repeats=args.repeats, seed=args.seed)
    elif args.what == "terrain":
        from subterra.bench.terrain import bench_terrain

        report = bench_terrain(points=100_000, scans=10, repeats=args.repeats, seed=args.seed, reference_repeats=3)
    else:
        from subterra.bench.perception import bench_perception

        report = bench_perception(frames=args.frames, reference_frames=args.reference_frames, preset=args.preset, mode=args.mode, seed=args.seed)
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


def _fly(args: argparse.Namespace) -> int:
    from subterra import load_config
    from subterra.flight import fly
    from subterra.sim import load_world
    from subterra.viz.rerun import rerun_available

    config = load_config(args.config) if args.config is not None else None
    world = load_world(args.world) if args.world is not None else None
    scenario = world.name if world is not None else args.scenario
    route = args.route or (world.routes[0][0] if world is not None and world.routes else None)
    if route is None and world is None:
        from subterra.sim import World

        first = World.scenario(scenario, args.seed).routes
        route = first[0][0] if first else None
    out = Path(args.out or f"runs/fly-{scenario}-{route}-{args.controller}-{args.noise}-s{args.seed}")
    rerun = None if args.no_rerun or not rerun_available() else out / "flight.rrd"
    if rerun is not None:
        out.mkdir(parents=True, exist_ok=True)
    faults, faults_config = fault_options(args)
    result = fly(args.scenario, route, faults=faults, faults_config=faults_config, controller=args.controller, noise=args.noise, preset=args.preset, config=config,
                 seed=args.seed, world=world, rate_hz=args.rate, time_limit_s=args.time_limit, progress=True, rerun_path=rerun)
    paths = result.save(out, plots=not args.no_plots)
    m = result.summary()
    outcome = "reached the goal" if m["success"] else f"failed: {m['failure']}"
    print(f"{scenario} {result.route} with {args.controller}, noise {args.noise}, seed {args.seed}: {outcome} "
          f"after {m['time_s']:.1f} s, {m['path_length_m']:.1f} m; collisions {m['collisions']}, "
          f"min clearance {m['min_clearance_m']:.3f} m; compute median {m['compute_ms_median']:.2f} ms, p99 {m['compute_ms_p99']:.2f} ms")
    for kind, path in paths.items():
        print(f"  {kind}: {path}")
    if rerun is None and not args.no_rerun:
        print("  (no flight.rrd: pip install 'subterra[viz]' for a Rerun recording)")
    return 0


def _fly_batch(args: argparse.Namespace) -> int:
    from subterra.batch.cli import engine_options, out_dir, save_and_report
    from subterra.flight import fly_batch

    if args.config:
        raise InputError("argument --config: fly-batch takes --preset, not --config")
    if args.seeds < 1:
        raise InputError(f"argument --seeds must be >= 1, got {args.seeds}")
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    out = out_dir(args, f"fly-batch-{args.scenario}")
    faults, faults_config = fault_options(args)
    result = fly_batch(args.scenario, args.routes, seeds, faults=faults, faults_config=faults_config, controllers=[c.strip() for c in args.controllers.split(",") if c.strip()],
                       noises=[n.strip() for n in args.noise.split(",") if n.strip()], preset=args.preset, rate_hz=args.rate,
                       keep_records=not args.no_plots, log_path=out / "flights.jsonl", **engine_options(args))
    return save_and_report(result, out, args, "flight")


def _demo(args: argparse.Namespace) -> int:
    from subterra.demo import run_demo

    return run_demo(data=args.data, out=args.out, quick=args.quick)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `subterra` command."""
    args = _parser().parse_args(argv)
    handlers = {"perceive": _perceive, "bench": _bench, "sim": _sim, "demo": _demo, "fly": _fly, "fly-batch": _fly_batch}
    try:
        handler = getattr(args, "handler", None) or handlers[args.command]
        return handler(args)
    except (SubterraError, ValueError, OSError) as exc:
        if args.debug:
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - a bug: one line, never a traceback without --debug
        if args.debug:
            raise
        print(f"error: internal error: {type(exc).__name__}: {_one_line(exc)} (rerun with --debug for the traceback)", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
