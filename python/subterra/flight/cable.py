"""`subterra cable-test`: the thin-cable test of the APF-PF paper §V-A (its Fig. 6).

A static robot at region ``start`` of the ``cable`` scenario faces an 8 mm cable hanging
0.6-0.9 m ahead (a wall ~3 m behind it is beyond the 1.2 m sensing horizon). A simulated
D435 renders the same view every frame under four noise conditions, in the paper's
order: Gaussian noise σ = 0.2 m on every pixel, on every 2nd pixel, on every 10th pixel
(of the row-major pixel stream, subterra-sim's ``paper-*`` presets), and none. One APF-PF
filter per condition (the ``cable`` preset by default: σ_o = 300, σ_n = 1) runs over the
frames; per frame we keep the most probable voxel (the free state excluded), its belief,
``P(free)`` and the belief on the cable's voxels.

Per condition (definitions also written into the JSON):

* ``detection_rate``: fraction of frames whose most probable voxel lies within one depth
  bin of the cable's bin (``|k - k_cable| <= 1``); a frame where no voxel holds belief
  (all of it on the free state) is a miss.
* ``mean_confidence``: mean over all frames of ``b(s*)``, the belief of the most probable
  voxel ``s*`` (free state excluded); 0 in a frame where no voxel holds belief.
* ``mean_cable_belief``: mean over frames of the belief summed over the cable's voxels:
  the image blocks the noise-free cable falls in, at depth bins within one of the cable's.
  The cable crosses about ten blocks, so the belief it earns is shared among ten voxels
  and ``mean_confidence`` saturates near 1/10 however clean the image; this sum does not.

The ordering the paper reports is checked for each metric: none >= every 10th >= every
2nd >= every pixel. The ``flight`` preset (σ_n = 60, σ_o = 170) runs on the same frames
for comparison: by design it treats a structure this thin as noise and keeps its belief on
the free state.

Seeds: ``seed`` picks the world (cable position), the filter's random stream and, through
``numpy.random.SeedSequence(seed)``, one noise seed per frame; every condition and preset
sees the same per-frame noise seeds (common random numbers), so the conditions differ only
in the noise pattern. Same seed, same JSON, bit for bit.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from subterra._compat import tomllib
from subterra._extras import require
from subterra.errors import ConfigError, InputError, SubterraError

__all__ = ["CONDITIONS", "cable_test", "register_cli"]

#: Scenario of the test (crate subterra-sim): an 8 mm cable ahead of a static robot.
SCENARIO = "cable"
#: Tag of the cable primitive in the scenario's world.
CABLE_TAG = "cable"
#: The four noise conditions of §V-A in the paper's order, densest noise first:
#: ``(label, depth noise preset of subterra.sim.DepthCamera.render)``.
CONDITIONS: tuple[tuple[str, str], ...] = (
    ("every pixel", "paper-every-pixel"),
    ("every 2nd pixel", "paper-every-2nd"),
    ("every 10th pixel", "paper-every-10th"),
    ("none", "none"),
)
#: A frame detects the cable when its most probable voxel is within this many depth bins
#: of the cable's bin (issue 4).
DETECTION_TOLERANCE_BINS = 1
#: Largest distance [m] of a noise-free in-range return from the cable's depth on the
#: optical axis: the cable hangs a little tilted, its depth changes by ~2 cm over the image.
CABLE_DEPTH_SPREAD_M = 0.05
#: Frames per condition by default (5 s of a 30 Hz depth stream).
DEFAULT_FRAMES = 150
#: The comparison preset: the paper's flight settings (§V-B).
COMPARISON_PRESET = "flight"
#: The free state counts as "rejecting the cable" when it holds at least this mean belief
#: in the noise-free condition.
REJECTS_P_FREE = 0.5
#: Fig. 6 marker area [pt²] = MARKER_MIN + MARKER_PER_BELIEF * belief.
MARKER_MIN = 4.0
MARKER_PER_BELIEF = 600.0
#: Per-frame traces kept in the JSON are rounded to this many decimals.
TRACE_DECIMALS = 6

_METRICS = ("detection_rate", "mean_confidence", "mean_cable_belief")

_DEFINITIONS = {
    "detection_rate": (
        "fraction of frames whose most probable voxel (free state excluded) has depth bin k with "
        f"|k - cable.bin| <= {DETECTION_TOLERANCE_BINS}; a frame whose belief is all on the free state is a miss"
    ),
    "mean_confidence": (
        "mean over all frames of b(s*), the belief of the most probable voxel s* (free state excluded), "
        "0 in a frame where no voxel holds belief"
    ),
    "mean_cable_belief": (
        "mean over all frames of the belief summed over the cable's voxels: the image blocks the "
        f"noise-free cable falls in, at depth bins within {DETECTION_TOLERANCE_BINS} of cable.bin"
    ),
    "chance_detection_rate": (
        "detection rate of a most probable voxel whose depth bin is drawn uniformly: "
        "(bins within the tolerance of cable.bin) / (depth bins)"
    ),
    "ordering": "values in the paper's order (every pixel, every 2nd, every 10th, none) must be non-decreasing",
    "cable.depth_m": (
        "depth along the optical axis of the cable's near surface at the point of its axis closest to "
        "the optical axis (world geometry), i.e. the depth the camera measures there"
    ),
}


def _check_arguments(frames: Any, seed: Any, preset: Any) -> None:
    from subterra import preset_names

    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
        raise InputError(f"frames must be an integer >= 1, got {frames!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**64:
        raise InputError(f"seed must be an integer in [0, 2^64), got {seed!r}")
    names = preset_names()
    if preset not in names:
        raise ConfigError(f"preset must be one of {', '.join(names)}, got {preset!r}")


def _cable_geometry(world: Any, world_from_camera: np.ndarray) -> dict[str, Any]:
    """The cable capsule of ``world`` and its depth along the camera's optical axis."""
    geometry = tomllib.loads(world.to_toml())
    cables = [c for c in geometry.get("capsule", []) if c.get("tag") == CABLE_TAG]
    if len(cables) != 1:
        raise SubterraError(f"the {SCENARIO!r} scenario should hold one capsule tagged {CABLE_TAG!r}, found {len(cables)}")
    cable = cables[0]
    a, b = np.asarray(cable["a"], dtype=np.float64), np.asarray(cable["b"], dtype=np.float64)
    radius_m = float(cable["radius"])
    origin, axis = world_from_camera[:3, 3], world_from_camera[:3, 2]
    # Closest points of the segment a + s(b - a), s in [0, 1], and the ray origin + t axis.
    u, w0 = b - a, a - origin
    uu, ua, aa = u @ u, u @ axis, axis @ axis
    du, da = u @ w0, axis @ w0
    denominator = uu * aa - ua * ua
    if denominator <= 0.0:
        raise SubterraError("the cable is parallel to the camera's optical axis: no depth to test against")
    s = float(np.clip((ua * da - aa * du) / denominator, 0.0, 1.0))
    on_axis = a + s * u
    depth_axis_m = float((on_axis - origin) @ axis)
    if depth_axis_m <= radius_m:
        raise SubterraError(f"the cable is not in front of the camera (depth {depth_axis_m:.3f} m)")
    return {
        "tag": CABLE_TAG,
        "a_m": a.tolist(),
        "b_m": b.tolist(),
        "radius_m": radius_m,
        "diameter_m": 2.0 * radius_m,
        "closest_point_world_m": on_axis.tolist(),
        "depth_m": depth_axis_m - radius_m,
    }


def _bin_of(depth_m: float, grid: dict[str, Any]) -> int:
    return math.floor((depth_m - grid["depth_min_m"]) / grid["depth_bin_m"])


def _check_ordering(values: Sequence[float], labels: Sequence[str]) -> dict[str, Any]:
    violations = [
        f"{labels[n]} ({values[n]:.4g}) > {labels[n + 1]} ({values[n + 1]:.4g})"
        for n in range(len(values) - 1)
        if values[n] > values[n + 1]
    ]
    return {"order": list(labels), "values": list(values), "holds": not violations, "violations": violations}


def _run_condition(
    world: Any,
    sensor: Any,
    world_from_camera: np.ndarray,
    noise: str,
    noise_seeds: np.ndarray,
    *,
    preset: str,
    seed: int,
    cable_bin: int,
    cable_voxels: Sequence[tuple[int, int, int]],
    desc: str,
    progress: bool,
) -> dict[str, Any]:
    from subterra import DepthPerception

    perception = DepthPerception(sensor.camera, preset, seed=seed)
    cable_states = np.array([perception.state_of(*voxel) for voxel in cable_voxels], dtype=np.int64)
    depth_m: list[float | None] = []
    bins: list[int | None] = []
    probability: list[float] = []
    p_free: list[float] = []
    cable_belief: list[float] = []
    max_count: list[int] = []
    frames = range(len(noise_seeds))
    if progress:
        from subterra._extras import tqdm

        frames = tqdm(frames, desc=desc, unit="frame", leave=False, disable=None)
    for n in frames:
        depth = sensor.render(world, world_from_camera, noise=noise, seed=int(noise_seeds[n]))
        out = perception.update(depth)
        mp = out.most_probable
        depth_m.append(None if mp is None else float(mp.depth_m))
        bins.append(None if mp is None else int(mp.voxel[2]))
        probability.append(0.0 if mp is None else float(mp.probability))
        p_free.append(float(out.p_free))
        cable_belief.append(float(perception.belief()[cable_states].sum()))
        max_count.append(int(out.max_count))
    detected = [k is not None and abs(k - cable_bin) <= DETECTION_TOLERANCE_BINS for k in bins]
    count = len(noise_seeds)
    return {
        "noise": noise,
        "frames": count,
        "detection_rate": sum(detected) / count,
        "mean_confidence": float(np.mean(probability)),
        "confidence_std": float(np.std(probability)),
        "mean_cable_belief": float(np.mean(cable_belief)),
        "mean_p_free": float(np.mean(p_free)),
        "free_frames": sum(k is None for k in bins),
        "mean_max_count": float(np.mean(max_count)),
        "trace": {
            "most_probable_depth_m": [None if d is None else round(d, TRACE_DECIMALS) for d in depth_m],
            "most_probable_bin": bins,
            "most_probable_probability": [round(p, TRACE_DECIMALS) for p in probability],
            "p_free": [round(p, TRACE_DECIMALS) for p in p_free],
            "cable_belief": [round(p, TRACE_DECIMALS) for p in cable_belief],
            "detected": detected,
        },
    }


def _flight_statement(flight: dict[str, Any], block_px: int, cable_label: str) -> tuple[bool, str]:
    """Whether the comparison preset rejected the cable, and one sentence saying so with numbers."""
    observation = flight["observation"]
    sigma_n, sigma_o = observation["sigma_n_points"], observation["sigma_o_points"]
    clean = flight["conditions"][-1]
    n = clean["mean_max_count"]
    rejects = clean["mean_p_free"] >= REJECTS_P_FREE
    worst = max(c["detection_rate"] for c in flight["conditions"])
    numbers = (
        f"the cable's fullest block holds {n:.0f} of its {block_px} pixels, {n / sigma_n:.1f} σ_n from an empty "
        f"block but {(block_px - n) / sigma_o:.1f} σ_o short of a full one, so the free state wins "
        f"(mean P(free) {clean['mean_p_free']:.2f} without noise; highest detection rate over the conditions {worst:.2f})"
    )
    head = f"`{COMPARISON_PRESET}` (σ_n = {sigma_n:g}, σ_o = {sigma_o:g})"
    if rejects:
        return True, f"{head} rejects the 8 mm cable as noise by design: {numbers}; {cable_label} is the paper's setting for thin obstacles."
    return False, f"{head} did NOT reject the 8 mm cable here, against its design: {numbers}."


def cable_test(
    out_dir: str | os.PathLike[str],
    *,
    frames: int = DEFAULT_FRAMES,
    seed: int = 0,
    preset: str = "cable",
    compare_flight: bool = True,
    progress: bool = True,
) -> dict[str, Any]:
    """Runs the thin-cable test of the APF-PF paper §V-A and writes ``cable-test.json``
    and ``cable-test.png`` (Fig. 6) into ``out_dir``. Returns the JSON's content.

    ``frames`` per condition (>= 1); ``seed`` (>= 0) picks the world, the filter's stream
    and the per-frame noise seeds; ``preset`` is the perception preset under test;
    ``compare_flight`` also runs the ``flight`` preset on the same frames (skipped when
    ``preset`` is ``flight``). Metrics (see the module docstring and the JSON's
    ``definitions``): ``detection_rate`` (most probable voxel within one depth bin of the
    cable), ``mean_confidence`` (mean belief of the most probable voxel, free state
    excluded, 0 when no voxel holds belief) and ``mean_cable_belief``.

    Raises :class:`~subterra.errors.InputError` for ``frames`` < 1 or a bad ``seed`` and
    :class:`~subterra.errors.ConfigError` for an unknown ``preset``.
    """
    _check_arguments(frames, seed, preset)
    frames, seed = int(frames), int(seed)
    from subterra import PerceptionConfig, sim
    from subterra.sim.render import BODY_FROM_OPTICAL, pose_matrix, start_pose

    world = sim.World.scenario(SCENARIO, seed)
    position, yaw, _ = start_pose(world)
    world_from_camera = pose_matrix(position, yaw) @ BODY_FROM_OPTICAL
    sensor = sim.DepthCamera.d435()
    config = PerceptionConfig.preset(preset).to_dict()
    grid = config["grid"]
    depth_bins = PerceptionConfig.preset(preset).depth_bins
    grid_states = math.ceil(sensor.camera.width / grid["block_width_px"]) * math.ceil(sensor.camera.height / grid["block_height_px"]) * depth_bins

    cable = _cable_geometry(world, world_from_camera)
    cable_bin = _bin_of(cable["depth_m"], grid)
    if not 0 <= cable_bin < depth_bins:
        raise SubterraError(f"the cable at {cable['depth_m']:.3f} m is outside the {preset!r} preset's depth range")
    k_lo, k_hi = max(0, cable_bin - DETECTION_TOLERANCE_BINS), min(depth_bins - 1, cable_bin + DETECTION_TOLERANCE_BINS)

    def bin_edge(k: int) -> float:
        return grid["depth_min_m"] + k * grid["depth_bin_m"]

    cable["bin"] = cable_bin
    cable["bin_range_m"] = [bin_edge(cable_bin), bin_edge(cable_bin + 1)]
    cable["detection_window_m"] = [bin_edge(k_lo), bin_edge(k_hi + 1)]

    # Which pixels see the cable: the noise-free frame's returns inside the sensing range
    # (the wall and the floor are beyond it), all of them at the cable's depth.
    truth = sensor.render(world, world_from_camera)
    seen = (truth > 0.0) & (truth < grid["depth_max_m"])
    rows, cols = np.nonzero(seen)
    if rows.size == 0:
        raise SubterraError("the noise-free frame has no return inside the sensing range: the cable is not in view")
    rendered = truth[seen].astype(np.float64)
    if np.abs(rendered - cable["depth_m"]).max() > CABLE_DEPTH_SPREAD_M:
        raise SubterraError(
            f"the noise-free frame has returns at {rendered.min():.3f}-{rendered.max():.3f} m inside the sensing range, "
            f"not only the cable at {cable['depth_m']:.3f} m"
        )
    blocks = sorted({(int(u) // grid["block_width_px"], int(v) // grid["block_height_px"]) for v, u in zip(rows, cols)})
    cable["rendered"] = {
        "pixels": int(rows.size),
        "depth_range_m": [float(rendered.min()), float(rendered.max())],
        "bins": sorted({_bin_of(float(z), grid) for z in np.unique(rendered)}),
        "columns_px": [int(cols.min()), int(cols.max())],
        "blocks_ij": [list(b) for b in blocks],
    }
    cable_voxels = [(i, j, k) for i, j in blocks for k in range(k_lo, k_hi + 1)]
    noise_seeds = np.random.SeedSequence(seed).generate_state(frames, dtype=np.uint64)

    def run_all(name: str) -> list[dict[str, Any]]:
        return [
            {"name": label, **_run_condition(
                world, sensor, world_from_camera, noise, noise_seeds, preset=name, seed=seed, cable_bin=cable_bin,
                cable_voxels=cable_voxels, desc=f"cable-test {name}: {label}", progress=progress,
            )}
            for label, noise in CONDITIONS
        ]

    conditions = run_all(preset)
    labels = [c["name"] for c in conditions]
    ordering = {metric: _check_ordering([c[metric] for c in conditions], labels) for metric in _METRICS}
    chance = (k_hi - k_lo + 1) / depth_bins
    summary: dict[str, Any] = {
        "test": "APF-PF thin-cable test (paper §V-A, Fig. 6)",
        "preset": preset,
        "seed": seed,
        "frames_per_condition": frames,
        "scenario": SCENARIO,
        "camera": {
            "sensor": "D435 (subterra.sim.DepthCamera.d435)",
            "position_world_m": [float(v) for v in position],
            "yaw_rad": float(yaw),
        },
        "grid": grid,
        "observation": config["observation"],
        "cable": cable,
        "definitions": _DEFINITIONS,
        "chance_detection_rate": chance,
        "conditions": conditions,
        "ordering": ordering,
        "targets": {
            "detection_ordering_holds": ordering["detection_rate"]["holds"],
            "confidence_ordering_holds": ordering["mean_confidence"]["holds"],
            "cable_belief_ordering_holds": ordering["mean_cable_belief"]["holds"],
            "every_pixel_detection_rate": conditions[0]["detection_rate"],
            "every_pixel_mean_confidence": conditions[0]["mean_confidence"],
            "uniform_belief": 1.0 / (grid_states + 1),
        },
    }
    if compare_flight and preset != COMPARISON_PRESET:
        flight_config = PerceptionConfig.preset(COMPARISON_PRESET).to_dict()
        if flight_config["grid"] != grid:
            raise SubterraError(f"the {COMPARISON_PRESET!r} and {preset!r} presets have different grids: no like-for-like comparison")
        flight = {
            "preset": COMPARISON_PRESET,
            "observation": flight_config["observation"],
            "conditions": [{k: v for k, v in c.items() if k != "trace"} for c in run_all(COMPARISON_PRESET)],
        }
        block_px = grid["block_width_px"] * grid["block_height_px"]
        flight["rejects_cable"], flight["statement"] = _flight_statement(flight, block_px, f"`{preset}`")
        summary["flight_comparison"] = flight

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "cable-test.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    _plot(summary, out / "cable-test.png")
    return summary


def _describe(condition: dict[str, Any]) -> str:
    return "no noise" if condition["noise"] == "none" else f"noise on {condition['name']}"


def _plot(summary: dict[str, Any], path: Path) -> None:
    """Fig. 6: per condition, the most probable voxel's depth per frame, marker area by its belief."""
    require("matplotlib", "viz", "Plots")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cable, grid = summary["cable"], summary["grid"]
    conditions = summary["conditions"]
    fig, axes = plt.subplots(len(conditions), 1, figsize=(9, 2.3 * len(conditions) + 0.8), sharex=True, squeeze=False)
    window = cable["detection_window_m"]
    for ax, condition in zip(axes[:, 0], conditions):
        trace = condition["trace"]
        frames = np.arange(condition["frames"])
        depth = np.array([np.nan if d is None else d for d in trace["most_probable_depth_m"]])
        belief = np.asarray(trace["most_probable_probability"])
        ax.axhspan(*window, color="tab:green", alpha=0.12, lw=0, label="cable bin ± 1 (detection)")
        ax.axhline(cable["depth_m"], color="k", ls="--", lw=1, label=f"cable ({cable['depth_m']:.3f} m)")
        held = np.isfinite(depth)
        ax.scatter(frames[held], depth[held], s=MARKER_MIN + MARKER_PER_BELIEF * belief[held], color="tab:red", alpha=0.7,
                   lw=0, label="most probable voxel (area = belief)", zorder=3)
        if (~held).any():
            ax.scatter(frames[~held], np.full((~held).sum(), grid["depth_max_m"]), marker="x", color="tab:blue", s=12,
                       label="all belief on the free state", zorder=3)
        ax.set_ylim(grid["depth_min_m"] - 0.02, grid["depth_max_m"] + 0.05)
        ax.set_ylabel("depth [m]")
        ax.set_title(
            f"{_describe(condition)}: detection {condition['detection_rate']:.2f}, "
            f"mean confidence {condition['mean_confidence']:.3f}, cable belief {condition['mean_cable_belief']:.2f}",
            fontsize=9,
        )
    for p in (0.01, 0.1, 0.3):
        axes[0, 0].scatter([], [], s=MARKER_MIN + MARKER_PER_BELIEF * p, color="tab:red", alpha=0.7, lw=0, label=f"belief {p:g}")
    axes[0, 0].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False)
    axes[-1, 0].set_xlabel("frame")
    fig.suptitle(
        f"APF-PF `{summary['preset']}` preset facing an {cable['diameter_m'] * 1e3:.0f} mm cable "
        f"(seed {summary['seed']}, {summary['frames_per_condition']} frames per condition)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


def register_cli(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Adds the ``cable-test`` subcommand to ``subparsers``; its handler is ``args.handler``."""
    from subterra.cli import nonempty, positive_int, seed_int

    p = subparsers.add_parser("cable-test", help="the thin-cable test of the APF-PF paper §V-A (Fig. 6)")
    p.add_argument("--frames", type=positive_int, default=DEFAULT_FRAMES, help=f"frames per noise condition (default {DEFAULT_FRAMES})")
    p.add_argument("--seed", type=seed_int, default=0, help="world, filter and noise seed (default 0)")
    p.add_argument("--out", type=nonempty, default=None, help="output folder (default runs/cable-test-<time>)")
    p.add_argument("--no-flight-comparison", action="store_true", help="skip the run of the `flight` preset on the same frames")
    p.set_defaults(handler=run_cli)
    return p


def run_cli(args: argparse.Namespace) -> int:
    """Handler of ``subterra cable-test``: runs the test, prints a table and where the files went."""
    out = Path(args.out or f"runs/cable-test-{time.strftime('%Y%m%d-%H%M%S')}")
    start = time.perf_counter()
    summary = cable_test(out, frames=args.frames, seed=args.seed, compare_flight=not args.no_flight_comparison)
    elapsed_s = time.perf_counter() - start
    cable = summary["cable"]
    print(
        f"{summary['preset']} preset, {summary['frames_per_condition']} frames per condition, seed {summary['seed']}: "
        f"cable at {cable['depth_m']:.3f} m (bin {cable['bin']}, detection window "
        f"{cable['detection_window_m'][0]:.1f}-{cable['detection_window_m'][1]:.1f} m, chance {summary['chance_detection_rate']:.2f})"
    )
    print(f"{'noise':<26}{'detection':>10}{'confidence':>12}{'cable belief':>14}{'P(free)':>9}")
    for c in summary["conditions"]:
        print(f"{_describe(c):<26}{c['detection_rate']:>10.3f}{c['mean_confidence']:>12.4f}{c['mean_cable_belief']:>14.3f}{c['mean_p_free']:>9.3f}")
    names = {"detection_rate": "detection", "mean_confidence": "confidence", "mean_cable_belief": "cable belief"}
    verdicts = [
        f"{names[m]} {'holds' if o['holds'] else 'FAILS (' + '; '.join(o['violations']) + ')'}"
        for m, o in summary["ordering"].items()
    ]
    print("ordering none >= every 10th >= every 2nd >= every pixel: " + ", ".join(verdicts))
    if "flight_comparison" in summary:
        print(summary["flight_comparison"]["statement"])
    print(f"wrote {out / 'cable-test.json'} and {out / 'cable-test.png'} in {elapsed_s:.1f} s")
    return 0
