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


if __name__ == "__main__":
    main()
