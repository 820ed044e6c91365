"""Regenerates the figures of docs/ from the code: `.venv/bin/python docs/make_figures.py`."""

from __future__ import annotations

from pathlib import Path

import subterra
from subterra.perceive import run_perception
from subterra.scenarios import approaching_box_frames
from subterra.viz.plots import plot_depth_trace

FIGURES = Path(__file__).resolve().parent / "figures"


def main() -> None:
    FIGURES.mkdir(exist_ok=True)
    camera = subterra.PinholeCamera.d435()
    depth, truth = approaching_box_frames(camera, frames=40, seed=0)
    _, records = run_perception(((str(n), d, None) for n, d in enumerate(depth)), camera, progress=False)
    plot_depth_trace(records, FIGURES / "apf-pf-approaching-box.png",
                     title="APF-PF (flight): a 0.5 m box approaching a D435 (synthetic, seed 0)", truth_depth_m=truth)

    from subterra.sim.render import render_scenario

    for name in ("highbay", "mine"):
        render_scenario(name, FIGURES, seed=0)

    # Closed-loop flights (docs/flight.md): highbay B-C, seed 3, both controllers.
    from subterra.flight import fly
    from subterra.flight.cable import cable_test
    from subterra.viz.flight import plot_compute_time, plot_flight_path, plot_flight_trace

    flights = [fly("highbay", "B-C", controller=c, noise="d435-phantom", seed=3) for c in ("apf-pf", "raw-apf")]
    plot_flight_path(flights, FIGURES / "flight-paths.png", title="highbay B-C, seed 3, D435 + phantom speckle: APF-PF vs raw APF")
    plot_flight_trace(flights[0], FIGURES / "flight-trace-apf-pf.png")
    plot_flight_trace(flights[1], FIGURES / "flight-trace-raw-apf.png")
    plot_compute_time(flights[0], FIGURES / "flight-compute-apf-pf.png")
    summary = cable_test(FIGURES / "cable-test-run", frames=150, seed=0, progress=False)
    (FIGURES / "cable-test-run" / "cable-test.png").replace(FIGURES / "cable-test.png")
    for leftover in (FIGURES / "cable-test-run").iterdir():
        leftover.unlink()
    (FIGURES / "cable-test-run").rmdir()
    print("cable test ordering:", {k: v["holds"] for k, v in summary["ordering"].items()})


if __name__ == "__main__":
    main()
