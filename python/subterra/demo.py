"""`subterra demo` (what `make demo` runs): closed-loop flights in the simulator with APF-PF
and the raw-APF baseline, the thin-cable test, a small randomized batch, the ground robot
driving the mine with the risk-aware planner and the additive-cost baseline, APF-PF on real
RealSense frames when `../shared/data` is there, and pictures of the built-in scenes. It
prints summary tables and writes a report folder with an index linking every plot."""

from __future__ import annotations

import json
import os
import stat
import time
from pathlib import Path
from typing import Any

from subterra._files import _describe
from subterra.errors import InputError
from subterra.flight import fly, fly_batch
from subterra.flight.cable import cable_test
from subterra.sim import DEFAULT_DEPTH_NOISE
from subterra.viz.flight import plot_flight_path

__all__ = ["run_demo"]

REALSENSE = "realsense-d435-room"
#: The flight every controller flies in the demo.
DEMO_ROUTE = "A-B"
DEMO_NOISE = DEFAULT_DEPTH_NOISE
DEMO_SEED = 1
#: The demo's single flights: (controller, perception preset, run folder).
DEMO_FLIGHTS = (("apf-pf", "flight-escape", "fly-apf-pf"), ("apf-pf", "acc2021", "fly-apf-pf-acc2021"),
                ("raw-apf", "flight", "fly-raw-apf"))
#: The mine the ground robot drives in the demo.
DRIVE_SEED = 0


def _default_data() -> Path | None:
    for candidate in (Path("../shared/data"), Path(__file__).resolve().parents[3] / "shared" / "data"):
        if (candidate / REALSENSE).is_dir():
            return candidate
    return None


def _table(header: tuple[str, ...], rows: list[tuple[Any, ...]]) -> str:
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows, strict=False)]

    def line(r: tuple[Any, ...] | list[str]) -> str:
        return "  ".join(str(x).ljust(w) for x, w in zip(r, widths, strict=False)).rstrip()

    return "\n".join([line(header), line(["-" * w for w in widths]), *(line(r) for r in rows)])


def _real_data(data_dir: Path, report: Path) -> tuple[str, list[str]] | None:
    from subterra._core import PinholeCamera  # noqa: F401  (the extension must be importable)
    from subterra.io import list_depth_files, read_depth, read_intrinsics
    from subterra.perceive import run_perception, summarise
    from subterra.viz.plots import plot_depth_trace

    room = data_dir / REALSENSE
    camera = read_intrinsics(room / "cam_params_realsense.json").to_camera()
    files = list_depth_files(room / "depth")
    frames = ((p.name, read_depth(p).data, 0.001) for p in files)
    pilot, records = run_perception(frames, camera, progress=True, total=len(files))
    summary = summarise(pilot, records, source=str(room), preset="flight")
    (report / "realsense-room.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    plot_depth_trace(records, report / "realsense-room.png", title=f"APF-PF (flight): {len(files)} real RealSense D435 frames")
    t = summary["timing"]
    line = (f"{len(files)} real D435 frames from {room}: mean P(free) {summary['p_free_mean']:.3f}, "
            f"median {t['median_ms']:.3f} ms, p99 {t['p99_ms']:.3f} ms per frame")
    return line, ["## Real data: RealSense D435 room", "", line, "", "![realsense](realsense-room.png)", "",
                  "Per-frame data: [realsense-room.json](realsense-room.json)", ""]


def _checked_data(data: str | os.PathLike[str]) -> Path:
    """``data`` given explicitly: a folder that holds the RealSense frames, checked before the
    demo runs (without it, a FIFO or a missing path would fail minutes later, at step 5)."""
    if not str(data).strip():
        raise InputError(f"argument `--data` must be the shared data folder, got {str(data)!r}")
    path = Path(data)
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise InputError(f"argument `--data` must be the shared data folder, got a path that cannot be read ({reason}): {path}") from None
    if not stat.S_ISDIR(mode):
        kind = "a regular file" if stat.S_ISREG(mode) else _describe(mode)
        raise InputError(f"argument `--data` must be the shared data folder, got {kind}: {path}")
    if not (path / REALSENSE).is_dir():
        raise InputError(f"argument `--data` must be the shared data folder, with {REALSENSE}/ in it; not found in {path}")
    return path


def run_demo(*, data: str | None = None, out: str | None = None, quick: bool = False) -> int:
    """Runs the demo; returns the exit code. ``quick`` shortens everything (for tests):
    20 s flights, 30 cable-test frames, a batch of one route, 10 s drives.

    Raises:
        InputError: ``data`` is given but is not a folder holding ``realsense-d435-room/``
            (checked first, before anything runs).
    """
    data_dir = _checked_data(data) if data is not None else _default_data()
    started = time.perf_counter()
    stamp = time.strftime("%Y%m%d-%H%M%S")
    report = Path(out or f"runs/demo-{stamp}")
    report.mkdir(parents=True, exist_ok=True)
    index = ["# subterra demo", "", f"Written {time.strftime('%Y-%m-%d %H:%M:%S')}" + (" (quick run)" if quick else "") + ".", ""]
    summary: dict[str, Any] = {"quick": quick}

    # 1. One highbay route flown by each controller, same world, seed and noise.
    print(f"[1/5] highbay {DEMO_ROUTE}, noise {DEMO_NOISE}, seed {DEMO_SEED}: APF-PF (the default flight-escape, and "
          "the paper's acc2021) and the raw-APF baseline")
    flights = []
    for controller, preset, folder in DEMO_FLIGHTS:
        result = fly("highbay", DEMO_ROUTE, controller=controller, preset=preset, noise=DEMO_NOISE, seed=DEMO_SEED,
                     progress=True, time_limit_s=20.0 if quick else None)
        result.save(report / folder)
        result.extra["folder"] = folder
        flights.append(result)
    plot_flight_path(flights, report / "flight-paths.png",
                     title=f"highbay {DEMO_ROUTE}, seed {DEMO_SEED}, noise {DEMO_NOISE}: APF-PF vs raw APF")
    flight_rows = []
    for r in flights:
        m = r.summary()
        flight_rows.append((f"{r.controller} ({r.preset})", "goal" if m["success"] else m["failure"], f"{m['time_s']:.1f}", f"{m['path_length_m']:.1f}",
                            m["collisions"], f"{m['min_clearance_m']:.3f}", f"{m['compute_ms_median']:.2f}", f"{m['compute_ms_p99']:.2f}"))
    flight_table = _table(("controller (preset)", "outcome", "time [s]", "path [m]", "collisions", "min clearance [m]",
                           "compute median [ms]", "p99 [ms]"), flight_rows)
    summary["flights"] = [r.summary() for r in flights]
    index += ["## Closed-loop flight: APF-PF vs raw APF", "",
              f"`highbay` route {DEMO_ROUTE} (seed {DEMO_SEED}), D435 noise with phantom speckle, 15 Hz. `flight-escape` is "
              "the default (σ_o = 300, the obstacle memory and the escape from local minima); `acc2021` is the paper's "
              "filter with the authors' conventions; raw APF flies the paper's `flight` preset (docs/flight.md).", "",
              "```", flight_table, "```", "", "![paths](flight-paths.png)", ""]
    for r in flights:
        d = r.extra["folder"]
        index += [f"### {r.controller} ({r.preset})", "", f"![trace]({d}/depth-trace.png)", "", f"![compute]({d}/compute-time.png)", "",
                  f"Data: [{d}/frames.csv]({d}/frames.csv), [{d}/trajectory.csv]({d}/trajectory.csv), "
                  f"[{d}/metrics.json]({d}/metrics.json)", ""]

    # 2. The thin-cable test (paper §V-A).
    print("[2/5] cable test: a static robot facing an 8 mm cable, four noise conditions")
    cable = cable_test(report / "cable-test", frames=30 if quick else 150, seed=0, progress=True)
    cable_rows = [(c["name"], f"{c['detection_rate']:.2f}", f"{c['mean_confidence']:.3f}", f"{c['mean_cable_belief']:.3f}",
                   f"{c['mean_p_free']:.2f}") for c in cable["conditions"]]
    cable_table = _table(("noise", "detection rate", "mean confidence (top voxel)", "mean belief on the cable", "mean P(free)"),
                         cable_rows)
    ordering = ", ".join(f"{k}: {'holds' if v['holds'] else 'fails'}" for k, v in cable["ordering"].items())
    statement = cable.get("flight_comparison", {}).get("statement", "")
    summary["cable_test"] = {k: cable[k] for k in ("conditions", "ordering") if k in cable}
    index += ["## Thin-cable test (paper §V-A, Fig. 6)", "", "```", cable_table, "```", "",
              f"Ordering none >= every 10th >= every 2nd >= every pixel: {ordering}.", "", statement, "",
              "![cable test](cable-test/cable-test.png)", "", "Data: [cable-test/cable-test.json](cable-test/cable-test.json)", ""]

    # 3. A small randomized batch.
    routes = DEMO_ROUTE if quick else "all"
    seeds = [2] if quick else [2, 3]
    print(f"[3/5] fly-batch: highbay routes {routes}, seeds {seeds}, APF-PF and raw APF, noise {DEMO_NOISE}")
    batch = fly_batch("highbay", routes, seeds, noises=(DEMO_NOISE,), time_limit_s=20.0 if quick else None)
    batch_files = batch.save(report / "batch")
    totals = [t for t in batch.table if t["route"] == "all"]
    batch_rows = [(t["controller"], t["flights"], f"{t['successes']} ({100 * t['success_rate']:.0f}%)", t["collisions"],
                   t["local_minima"], t["timeouts"], "-" if t["min_clearance_m"] is None else f"{t['min_clearance_m']:.3f}")
                  for t in totals]
    batch_table = _table(("controller", "flights", "success", "collisions", "local minima", "timeouts", "min clearance [m]"), batch_rows)
    summary["batch"] = totals
    index += ["## Randomized batch", "", f"Every route of `highbay` on seeds {seeds} (a new obstacle layout each), both controllers. "
              "The full 250-flight run is `subterra fly-batch --scenario highbay --routes all --seeds 50`.", "",
              "```", batch_table, "```", "", "Per route: [batch/results.md](batch/results.md); every flight: "
              "[batch/results.json](batch/results.json).", ""]
    index += [f"![batch paths](batch/{p.name})" for k, p in batch_files.items() if k.startswith("paths_")]
    index.append("")

    # 4. The ground robot: the mine, risk-aware planner and the additive baseline.
    print(f"[4/5] ground robot: mine seed {DRIVE_SEED}, risk-aware planner and the additive-cost baseline")
    from subterra.drive import drive

    drives = []
    for planner in ("risk-aware", "additive"):
        result = drive("mine", planner=planner, seed=DRIVE_SEED, progress=True, time_limit_s=10.0 if quick else None)
        result.save(report / f"drive-{planner}")
        drives.append(result)
    drive_rows = []
    for r in drives:
        m = r.summary()
        drive_rows.append((r.planner, "goal" if m["success"] else m["failure"], f"{m['time_s']:.1f}", m["collisions"],
                           f"{m['max_tilt_deg']:.1f}", f"{m['accumulated_true_risk']:.3f}", m["recoveries"],
                           f"{m['compute_ms_median']:.1f}"))
    drive_table = _table(("planner", "outcome", "time [s]", "collisions", "max tilt [deg]", "accumulated true risk",
                          "recoveries", "compute median [ms]"), drive_rows)
    summary["drives"] = [r.summary() for r in drives]
    index += ["## Ground robot: risk-aware planning in the mine", "",
              f"`mine` seed {DRIVE_SEED}: simulated OS1-64 lidar -> terrain risk map -> risk-aware A* (or the additive-cost "
              "baseline) -> MPC with risk-limited speed -> recovery behaviours -> the simulated ground robot. The 100-seed "
              "comparison is `subterra drive-batch --scenario mine --seeds 100`.", "", "```", drive_table, "```", ""]
    for r in drives:
        d = f"drive-{r.planner}"
        index += [f"### {r.planner}", "", f"![map]({d}/map.png)", "", f"![speed and risk]({d}/speed-risk.png)", "",
                  f"Data: [{d}/trajectory.csv]({d}/trajectory.csv), [{d}/events.csv]({d}/events.csv), "
                  f"[{d}/metrics.json]({d}/metrics.json)", ""]

    # 5. Real data and the scenes.
    print("[5/5] APF-PF on real frames (if ../shared/data is there) and pictures of the built-in scenes")
    real = None
    if data_dir is not None and (data_dir / REALSENSE).is_dir():
        real = _real_data(data_dir, report)
        index += real[1]
    else:
        print("note: ../shared/data not found: the real RealSense frames are skipped (pass --data DIR)")
    from subterra.sim.render import render_scenario

    scenes = {name: render_scenario(name, report, seed=0) for name in ("highbay", "tunnel", "mine")}
    index += ["## Simulated scenes", ""]
    for name, paths in scenes.items():
        index += [f"### {name}", "", f"![{name} depth]({paths['depth'].name})", "", f"![{name} map]({paths['map'].name})", ""]

    summary["wall_s"] = round(time.perf_counter() - started, 1)
    (report / "summary.json").write_text(json.dumps(summary, indent=2, default=str), encoding="utf-8")
    (report / "index.md").write_text("\n".join(index), encoding="utf-8")

    print(f"\nsubterra demo: closed-loop flight, highbay {DEMO_ROUTE}, noise {DEMO_NOISE}, seed {DEMO_SEED}\n")
    print(flight_table)
    print("\nthin-cable test (cable preset)\n")
    print(cable_table)
    print(f"ordering: {ordering}")
    if statement:
        print(statement)
    print(f"\nrandomized batch (highbay, seeds {seeds}, routes {routes})\n")
    print(batch_table)
    print(f"\nground robot (mine, seed {DRIVE_SEED})\n")
    print(drive_table)
    if real is not None:
        print(f"\nreal data: {real[0]}")
    print(f"\nreport: {report / 'index.md'}  ({summary['wall_s']:.0f} s)")
    return 0
