"""`subterra drive` and `subterra drive-batch`: the ground robot in the simulator.

``drive`` runs one closed-loop drive (simulated lidar -> terrain map -> risk-aware A* ->
MPC -> recovery -> ground robot) on a built-in scenario (``mine``), on one of the worlds
that force a recovery behaviour (``dead-end``, ``risky-slope``, ``blocked-return``) or on a
world file, and writes its run folder. ``drive-batch`` drives many seeds with the
risk-aware planner and the additive-cost baseline side by side.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from subterra.errors import ConfigError, InputError

__all__ = ["register_cli"]


def _navigator_config(path: str | None) -> dict[str, Any] | None:
    """The ``--config`` TOML as a dict of sections (``planner``, ``tracker``, ``recovery``,
    ``navigator``); the navigator checks the keys."""
    if path is None:
        return None
    from subterra._files import read_toml
    from subterra.errors import FileFormatError

    try:  # a regular file only (a FIFO or /dev/zero is refused at once), UTF-8, bounded
        return read_toml(Path(path), "navigator config")
    except (FileFormatError, ConfigError) as exc:
        raise ConfigError(f"argument --config: {exc}") from exc


def _merged(base: dict[str, Any], over: dict[str, Any] | None) -> dict[str, Any]:
    """``over`` laid over ``base``, table by table (a scenario's settings under the user's)."""
    out = dict(base)
    for key, value in (over or {}).items():
        out[key] = _merged(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def register_cli(subparsers: argparse._SubParsersAction) -> None:
    """Adds ``drive`` and ``drive-batch`` to ``subparsers``; their handlers are ``args.handler``."""
    from subterra.batch.cli import add_engine_options
    from subterra.cli import add_fault_options, finite_floats, nonempty, positive_rate, seed_int, sim_seconds
    from subterra.drive.run import GROUND_SCENARIOS, PLANNERS
    from subterra.scenarios.ground import RECOVERY_SCENARIOS
    from subterra.sim import LIDAR_NOISE_PRESETS

    scenarios = ", ".join((*GROUND_SCENARIOS, *RECOVERY_SCENARIOS))
    p = subparsers.add_parser("drive", help="one closed-loop drive of the ground robot (lidar -> risk map -> A* -> MPC)")
    p.add_argument("--scenario", default="mine", help=f"{scenarios} (default mine)")
    p.add_argument("--world", type=nonempty, default=None, help="drive in this world file (TOML, docs/world-format.md) instead")
    p.add_argument("--planner", default="risk-aware", choices=PLANNERS, help="risk-aware (STEP, Fan et al. 2021; default) or additive (the baseline)")
    p.add_argument("--seed", type=seed_int, default=0, help="world layout and lidar noise seed (default 0)")
    p.add_argument("--start", type=finite_floats(2, "x,y in metres"), default=None, help="start x,y [m] (default: the world's start region)")
    p.add_argument("--goal", type=finite_floats(2, "x,y in metres"), default=None, help="goal x,y [m] (default: the world's goal region)")
    p.add_argument("--noise", default="os1_64", choices=LIDAR_NOISE_PRESETS, help="lidar noise (default os1_64)")
    p.add_argument("--config", type=nonempty, default=None, help="navigator TOML: sections [planner], [tracker], [recovery], [navigator]")
    p.add_argument("--rate", type=positive_rate, default=10.0, help="lidar and control rate [Hz] (default 10)")
    p.add_argument("--time-limit", type=sim_seconds, default=None, help="seconds of simulated time (default: 4x the straight-line time at half speed, >= 90)")
    p.add_argument("--no-rerun", action="store_true", help="do not write drive.rrd even if rerun-sdk is installed")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    p.add_argument("--out", type=nonempty, default=None, help="run folder (default runs/drive-<scenario>-<planner>-s<seed>)")
    add_fault_options(p, "drive")
    p.set_defaults(handler=_drive)

    b = subparsers.add_parser("drive-batch", help="many randomized drives, risk-aware planner and additive baseline side by side")
    b.add_argument("--scenario", default="mine", help=f"built-in scenario: {', '.join(GROUND_SCENARIOS)} (default mine)")
    # --seeds: an int checked by the handler (an error line and exit code 2, which tests rely on).
    b.add_argument("--seeds", type=int, default=100, help="seeds 0..N-1 from --first-seed, one world each (default 100)")
    b.add_argument("--first-seed", type=seed_int, default=0, help="start the seeds here (default 0)")
    b.add_argument("--planners", default=",".join(PLANNERS), help=f"comma-separated (default {','.join(PLANNERS)})")
    b.add_argument("--time-limit", type=sim_seconds, default=None, help="seconds of simulated time per drive (default as drive)")
    b.add_argument("--no-plots", action="store_true", help="skip the maps of the first seed")
    b.add_argument("--config", type=nonempty, default=None, help="navigator TOML for every drive: sections [planner], [tracker], [recovery], [navigator]")
    add_fault_options(b, "drive")
    add_engine_options(b, unit="drive")
    b.set_defaults(handler=_drive_batch)


def _drive(args: argparse.Namespace) -> int:
    from subterra.cli import fault_options
    from subterra.drive.run import drive
    from subterra.scenarios.ground import RECOVERY_SCENARIOS, recovery_scenario
    from subterra.sim import load_world
    from subterra.viz.rerun import rerun_available

    kwargs: dict[str, Any] = {}
    scenario_config: dict[str, Any] = {}
    if args.world is not None:
        world = load_world(args.world)
        name = world.name or Path(args.world).stem
    elif args.scenario in RECOVERY_SCENARIOS:
        sc = recovery_scenario(args.scenario)
        world, name = sc.world(), sc.name
        kwargs = {"start": sc.start, "yaw": sc.yaw, "goal": sc.goal, "home": sc.home}
        scenario_config = sc.navigator_config
    else:
        world, name = None, args.scenario
    if args.start is not None:
        kwargs["start"], kwargs["yaw"] = args.start, None
    if args.goal is not None:
        kwargs["goal"] = args.goal
    faults, faults_config = fault_options(args)
    out = Path(args.out or f"runs/drive-{name}-{args.planner}-s{args.seed}")
    rerun = None if args.no_rerun or not rerun_available() else out / "drive.rrd"
    result = drive(name, planner=args.planner, seed=args.seed, world=world, noise=args.noise,
                   navigator_config=_merged(scenario_config, _navigator_config(args.config)), rate_hz=args.rate,
                   time_limit_s=args.time_limit, faults=faults, faults_config=faults_config,
                   progress=True, rerun_path=rerun, **kwargs)
    paths = result.save(out, plots=not args.no_plots)
    m = result.summary()
    outcome = "reached the goal" if m["success"] else f"failed: {m['failure']}"
    behaviours = ", ".join(b for b in m["behaviours_used"] if b != "track") or "none"
    print(f"{result.scenario} with the {args.planner} planner, seed {args.seed}: {outcome} after {m['time_s']:.1f} s; "
          f"collisions {m['collisions']}, max tilt {m['max_tilt_deg']:.1f} deg, accumulated true risk "
          f"{m['accumulated_true_risk']:.3f}; recovery behaviours: {behaviours}; compute median {m['compute_ms_median']:.1f} ms/step")
    for kind, path in paths.items():
        print(f"  {kind}: {path}")
    if rerun is None and not args.no_rerun:
        print("  (no drive.rrd: pip install 'subterra[viz]' for a Rerun recording)")
    return 0


def _drive_batch(args: argparse.Namespace) -> int:
    from subterra.batch.cli import engine_options, out_dir, save_and_report
    from subterra.cli import MAX_COUNT, fault_options
    from subterra.drive.batch import drive_batch

    if not 1 <= args.seeds <= MAX_COUNT:
        raise InputError(f"argument --seeds must be >= 1 and <= {MAX_COUNT}, got {args.seeds}")
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    planners = [p.strip() for p in args.planners.split(",") if p.strip()]
    out = out_dir(args, f"drive-batch-{args.scenario}")
    faults, faults_config = fault_options(args)
    result = drive_batch(args.scenario, seeds, planners=planners, time_limit_s=args.time_limit, faults=faults, faults_config=faults_config,
                         navigator_config=_navigator_config(args.config), keep_records=not args.no_plots,
                         log_path=out / "drives.jsonl", **engine_options(args))
    return save_and_report(result, out, args, "drive")
