"""Regenerates the figure of docs/mpc.md from the code: `.venv/bin/python docs/make_figures_mpc.py`.

A closed loop of `subterra.MpcTracker` on the benchmark scene (crates/subterra/benches/mpc.rs):
a curved reference through a band of risk 0.5 and past lethal blocks, one reaching into the
path. The robot is a velocity-commanded unicycle holding each command for `dt`.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Polygon  # noqa: E402

import subterra  # noqa: E402
from subterra.bench.reference.mpc import arc_step as plant_step  # noqa: E402

FIGURES = Path(__file__).resolve().parent / "figures"
NX, RES, ORIGIN = 200, 0.1, (-5.0, -10.0)
LENGTH, WIDTH = 0.99, 0.67


def scene() -> tuple[np.ndarray, np.ndarray]:
    """The reference (an arc of radius 6 m) and the risk grid of the benchmark."""
    phi = np.arange(79) * 0.1 / 6.0
    path = np.column_stack([6 * np.sin(phi), 6 * (1 - np.cos(phi))])
    xc = ORIGIN[0] + RES * (np.arange(NX) + 0.5)
    yc = ORIGIN[1] + RES * (np.arange(NX) + 0.5)
    x, y = np.meshgrid(xc, yc)
    risk = 0.125 + 0.075 * np.sin(1.3 * x) * np.cos(0.7 * y)
    risk[(x >= 2.8) & (x < 3.3)] = 0.5
    for x0, x1, y0, y1 in [(2.0, 2.5, -1.3, -0.7), (4.0, 4.5, 1.6, 2.1), (5.0, 5.6, 0.6, 1.1), (1.5, 2.0, 0.8, 1.3)]:
        risk[(x >= x0) & (x < x1) & (y >= y0) & (y < y1)] = 1.0
    return path, risk.astype(np.float32)


def rectangle(state: np.ndarray) -> np.ndarray:
    x, y, th, _ = state
    c, s = np.cos(th), np.sin(th)
    body = np.array([[1, -1], [1, 1], [-1, 1], [-1, -1]]) * [LENGTH / 2, WIDTH / 2]
    return np.column_stack([x + c * body[:, 0] - s * body[:, 1], y + s * body[:, 0] + c * body[:, 1]])


def main() -> None:
    path, risk = scene()
    tracker = subterra.MpcTracker()
    state = np.array([0.0, -0.2, 0.0, 0.5])
    states, outs = [state], []
    for _ in range(110):
        out = tracker.solve(state, path, risk=risk, resolution=RES, origin=ORIGIN)
        outs.append(out)
        state = plant_step(state, out.command, tracker.dt)
        states.append(state)
    states = np.array(states)

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 5.2), gridspec_kw={"width_ratios": [1.5, 1]})
    extent = (ORIGIN[0], ORIGIN[0] + NX * RES, ORIGIN[1], ORIGIN[1] + NX * RES)
    image = ax.imshow(risk, origin="lower", extent=extent, cmap="RdYlGn_r", vmin=0, vmax=1)
    fig.colorbar(image, ax=ax, label="risk", shrink=0.8)
    for poly in outs[25].polygons:
        ax.add_patch(Polygon(poly, closed=True, fill=False, edgecolor="k", lw=1.2))
    ax.plot(path[:, 0], path[:, 1], "b--", lw=1.2, label="reference path")
    ax.plot(states[:, 0], states[:, 1], "k-", lw=1.5, label="closed loop")
    for k in range(0, len(states), 8):
        ax.add_patch(Polygon(rectangle(states[k]), closed=True, fill=False, edgecolor="0.25", lw=0.7))
    pred = outs[25].predicted
    ax.plot(pred[:, 0], pred[:, 1], "m.-", ms=4, lw=1, label="prediction at step 25")
    ax.plot(outs[25].reference_points[:, 0], outs[25].reference_points[:, 1], "c.", ms=4, label="its reference points")
    ax.set_xlim(-1.2, 7.6)
    ax.set_ylim(-1.6, 4.6)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title("MpcTracker: footprints every 0.8 s, lethal polygons (black)")

    t = np.arange(len(outs)) * tracker.dt
    limit = [out.speed_limits[0] for out in outs]
    bx.plot(t, states[1:, 3], "k-", label="speed sent, v0 + a0·dt")
    bx.plot(t, limit, "r--", label="risk limit v_max·(1 - r) at the next state")
    bx.plot(t, [o.inputs[0, 1] for o in outs], "b:", label="yaw rate sent [rad/s]")
    bx.set_xlabel("time [s]")
    bx.set_ylabel("[m/s], [rad/s]")
    times = np.array([o.solve_time_s for o in outs]) * 1e3
    bx.set_title(f"commands; solve time median {np.median(times):.2f} ms (this run)")
    bx.legend(fontsize=8, loc="lower right")
    bx.grid(alpha=0.3)
    fig.tight_layout()
    FIGURES.mkdir(exist_ok=True)
    fig.savefig(FIGURES / "mpc-closed-loop.png", dpi=110)
    print("wrote", FIGURES / "mpc-closed-loop.png")


if __name__ == "__main__":
    main()
