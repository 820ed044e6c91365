"""`subterra demo` (what `make demo` runs): the pipelines on built-in scenes and real data,
a summary table on stdout and a report folder with an index."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from subterra._core import PinholeCamera
from subterra.perceive import run_perception, summarise
from subterra.scenarios.synthetic import approaching_box_frames, noise_only_frames
from subterra.viz.plots import plot_depth_trace

__all__ = ["run_demo"]

REALSENSE = "realsense-d435-room"


def _default_data() -> Path | None:
    for candidate in (Path("../shared/data"), Path(__file__).resolve().parents[3] / "shared" / "data"):
        if (candidate / REALSENSE).is_dir():
            return candidate
    return None


def _case(name: str, description: str, frames, camera, out: Path, truth=None) -> dict[str, Any]:
    perception, records = run_perception(frames, camera, progress=True, total=None)
    summary = summarise(perception, records, source=name, preset="flight")
    (out / f"{name}.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    plot_depth_trace(records, out / f"{name}.png", title=f"APF-PF (flight): {description}", truth_depth_m=truth)
    return {"name": name, "description": description, "summary": summary, "records": records, "truth": truth}


def run_demo(*, data: str | None = None, out: str | None = None) -> int:
    """Runs the demo; returns the exit code."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    report = Path(out or f"runs/demo-{stamp}")
    report.mkdir(parents=True, exist_ok=True)
    camera = PinholeCamera.d435()
    cases = []

    depth, truth = approaching_box_frames(camera, frames=40, seed=0)
    cases.append(_case("approaching-box", "a 0.5 m box approaching from 1.6 m to 0.5 m (synthetic, D435)",
                       ((f"{n}", d, None) for n, d in enumerate(depth)), camera, report, truth=truth))
    noise = noise_only_frames(camera, frames=20, seed=0)
    cases.append(_case("noise-only", "no obstacle, σ = 0.2 m noise on every 10th pixel (synthetic)",
                       ((f"{n}", d, None) for n, d in enumerate(noise)), camera, report))

    data_dir = Path(data) if data else _default_data()
    if data_dir is not None and (data_dir / REALSENSE).is_dir():
        from subterra.io import list_depth_files, read_depth, read_intrinsics

        room = data_dir / REALSENSE
        real_camera = read_intrinsics(room / "cam_params_realsense.json").to_camera()
        files = list_depth_files(room / "depth")
        frames = ((p.name, read_depth(p).data, 0.001) for p in files)
        cases.append(_case("realsense-room", f"real RealSense D435 frames ({len(files)}) from {room}", frames, real_camera, report))
    else:
        print("note: ../shared/data not found: the real RealSense frames are skipped (pass --data DIR)")

    from subterra.sim.render import render_scenario

    scenes = {name: render_scenario(name, report, seed=0) for name in ("highbay", "mine")}

    rows = []
    for c in cases:
        s, recs = c["summary"], c["records"]
        last = recs[-1]
        err = ""
        if c["truth"] is not None:
            seen = [(r["map_depth_m"], t) for r, t in zip(recs, c["truth"]) if r["map_depth_m"] is not None and t < 1.2 and r["p_free"] < 0.5]
            err = f"{np.median([abs(a - b) for a, b in seen]):.3f}" if seen else "n/a"
        rows.append((c["name"], s["frames"], f"{s['p_free_mean']:.3f}",
                     "-" if last["map_depth_m"] is None else f"{last['map_depth_m']:.2f}",
                     err, f"{s['timing']['median_ms']:.3f}", f"{s['timing']['p99_ms']:.3f}"))
    header = ("case", "frames", "mean P(free)", "last MAP depth [m]", "median |MAP - truth| [m]", "median [ms]", "p99 [ms]")
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    line = lambda r: "  ".join(str(x).ljust(w) for x, w in zip(r, widths))  # noqa: E731
    table = "\n".join([line(header), line(["-" * w for w in widths]), *(line(r) for r in rows)])
    print("\nAPF-PF demo (preset flight)\n")
    print(table)

    index = ["# subterra demo", "", f"Written {time.strftime('%Y-%m-%d %H:%M:%S')}.", "", "```", table, "```", ""]
    for c in cases:
        index += [f"## {c['name']}", "", c["description"], "", f"![{c['name']}]({c['name']}.png)", "",
                  f"Per-frame data: [{c['name']}.json]({c['name']}.json)", ""]
    index += ["## Simulated scenes", "", "The simulator's built-in worlds (closed-loop flights and drives build on them):", ""]
    for name, paths in scenes.items():
        index += [f"### {name}", "", f"![{name} depth]({paths['depth'].name})", "", f"![{name} map]({paths['map'].name})", ""]
    (report / "index.md").write_text("\n".join(index), encoding="utf-8")
    print(f"\nreport: {report / 'index.md'}")
    return 0
