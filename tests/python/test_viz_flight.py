"""Flight figures (`subterra.viz.flight`) and the Rerun recorder (`subterra.viz.rerun`).

The flights are synthetic: a dataclass with the fields of the flight contract
(`FlightResult`), flown along a straight line in the `highbay` world, so these tests
do not depend on the closed loop.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pytest
from PIL import Image

from subterra.errors import ConfigError, InputError

FRAMES = 60
RATE_HZ = 10.0
HORIZON_M = 1.2


@dataclass
class FakeFlight:
    """The fields of `subterra.flight.run.FlightResult` that the figures read."""

    world: Any
    frames: dict[str, np.ndarray]
    path: np.ndarray
    start: np.ndarray
    goal: np.ndarray
    scenario: str = "highbay"
    route: str = "A-B"
    controller: str = "apf-pf"
    noise: str = "d435"
    preset: str = "flight"
    seed: int = 0
    goal_radius_m: float = 0.5
    rate_hz: float = RATE_HZ
    horizon_m: float = HORIZON_M
    rho_0_m: float = 1.4
    metrics: dict = field(default_factory=lambda: {"failure": None})


@pytest.fixture(scope="module")
def highbay():
    from subterra.sim import World

    return World.scenario("highbay", seed=0)


def make_flight(world, *, n: int = FRAMES, controller: str = "apf-pf", failure: str | None = None, y_offset_m: float = 0.0) -> FakeFlight:
    """A flight from region A towards B along y = 2 (+ offset): an obstacle is in view
    for the middle third, where the filter's belief and the repulsion rise."""
    start, goal = np.array([1.5, 2.0, 1.25]), np.array([15.5, 2.0, 1.25])
    s = np.linspace(0.0, 1.0, n + 1)
    path = start + s[:, None] * (goal - start)
    path[:, 1] += y_offset_m * np.sin(np.pi * s)
    t = np.arange(n) / RATE_HZ
    in_view = (np.arange(n) >= n // 3) & (np.arange(n) < 2 * n // 3)
    truth = np.where(in_view, np.linspace(1.1, 0.5, n), 4.0)
    rng = np.random.default_rng(0)
    frames = {
        "time_s": t,
        "position": path[:-1],
        "yaw": np.zeros(n),
        "mpv_depth_m": np.where(in_view, truth + 0.05, np.nan),
        "mpv_probability": np.where(in_view, np.linspace(0.1, 0.9, n), np.nan),
        "mpv_body": np.full((n, 3), np.nan),
        "p_free": np.where(in_view, 0.1, 0.9),
        "closest_depth_m": truth + rng.normal(0.0, 0.02, n),
        "truth_closest_m": truth,
        "obstacle_in_view": in_view,
        "repulsive_body": np.zeros((n, 3)),
        "repulsive_norm": np.where(in_view, 2.0, 0.0),
        "command": np.zeros((n, 4)),
        "compute_ms": 2.0 + rng.gamma(2.0, 0.5, n),
        "clearance_m": np.full(n, 1.0),
    }
    return FakeFlight(world=world, frames=frames, path=path, start=start, goal=goal, controller=controller, metrics={"failure": failure})


def nan_flight(world, n: int = FRAMES) -> FakeFlight:
    """Every per-frame measurement NaN (no belief, no return, no timing)."""
    f = make_flight(world, n=n)
    frames = dict(f.frames)
    for key in ("mpv_depth_m", "mpv_probability", "p_free", "closest_depth_m", "truth_closest_m", "repulsive_norm", "compute_ms"):
        frames[key] = np.full(n, np.nan)
    frames["obstacle_in_view"] = np.zeros(n, bool)
    return replace(f, frames=frames)


def open_png(path) -> Image.Image:
    assert path.is_file() and path.stat().st_size > 0
    img = Image.open(path)
    img.load()
    assert img.format == "PNG"
    return img


def red_pixels(img: Image.Image) -> int:
    """Pixels of pure red: the collision marker's colour, used nowhere else."""
    a = np.asarray(img.convert("RGB")).astype(int)
    return int(np.count_nonzero((a[..., 0] > 240) & (a[..., 1] < 15) & (a[..., 2] < 15)))


# --------------------------------------------------------------------------- figures


def test_flight_path_one_flight_writes_png_into_new_folders(tmp_path, highbay):
    from subterra.viz.flight import plot_flight_path

    out = plot_flight_path(make_flight(highbay), tmp_path / "a" / "b" / "path.png")
    assert out == tmp_path / "a" / "b" / "path.png"
    img = open_png(out)
    assert 600 <= img.width <= 1400 and 250 <= img.height <= 1000
    assert red_pixels(img) == 0, "no collision, yet pure red (the collision marker) was drawn"


def test_flight_path_marks_a_collision_in_red(tmp_path, highbay):
    from subterra.viz.flight import plot_flight_path

    flights = [
        make_flight(highbay, controller="apf-pf", failure="local_minimum", y_offset_m=1.0),
        make_flight(highbay, n=20, controller="raw-apf", failure="collision"),
    ]
    out = plot_flight_path(flights, str(tmp_path / "both.png"), title="APF-PF vs raw APF")
    assert red_pixels(open_png(out)) > 20


@pytest.mark.parametrize("scenario", ["cable", "mine"])
def test_flight_path_draws_other_geometry(tmp_path, scenario):
    """Capsules (cable), spheres, solid items and a height field with holes (mine)."""
    from subterra.sim import World
    from subterra.viz.flight import plot_flight_path

    world = World.scenario(scenario, seed=0)
    f = replace(make_flight(world, n=5), scenario=scenario)
    assert open_png(plot_flight_path(f, tmp_path / f"{scenario}.png")).width > 500


def test_flight_path_rejects_bad_input(tmp_path, highbay):
    from subterra.sim import World
    from subterra.viz.flight import plot_flight_path

    with pytest.raises(InputError, match="empty"):
        plot_flight_path([], tmp_path / "x.png")
    with pytest.raises(InputError, match="FlightResult"):
        plot_flight_path([object()], tmp_path / "x.png")
    other = replace(make_flight(World.scenario("highbay", seed=1)), seed=1)
    with pytest.raises(InputError, match="same world"):
        plot_flight_path([make_flight(highbay), other], tmp_path / "x.png")
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        plot_flight_path(replace(make_flight(highbay), path=np.zeros((0, 3))), tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


def test_flight_trace_writes_png(tmp_path, highbay):
    from subterra.viz.flight import plot_flight_trace

    img = open_png(plot_flight_trace(make_flight(highbay), tmp_path / "trace.png"))
    assert (img.width, img.height) == (1100, 715)


@pytest.mark.parametrize("n", [FRAMES, 0])
def test_flight_trace_and_compute_time_survive_nan_and_empty_frames(tmp_path, highbay, n):
    from subterra.viz.flight import plot_compute_time, plot_flight_trace

    f = nan_flight(highbay, n=n)
    assert open_png(plot_flight_trace(f, tmp_path / "trace.png")).width == 1100
    assert open_png(plot_compute_time(f, tmp_path / "compute.png")).width == 1100


def test_flight_trace_rejects_bad_frames(tmp_path, highbay):
    from subterra.viz.flight import plot_flight_trace

    f = make_flight(highbay)
    short = dict(f.frames, repulsive_norm=np.zeros(FRAMES - 1))
    with pytest.raises(InputError, match="differ in length"):
        plot_flight_trace(replace(f, frames=short), tmp_path / "x.png")
    missing = {k: v for k, v in f.frames.items() if k != "mpv_depth_m"}
    with pytest.raises(InputError, match="mpv_depth_m"):
        plot_flight_trace(replace(f, frames=missing), tmp_path / "x.png")
    with pytest.raises(InputError, match="horizon_m"):
        plot_flight_trace(replace(f, horizon_m=float("nan")), tmp_path / "x.png")


def test_compute_time_writes_png_and_rejects_zero_rate(tmp_path, highbay):
    from subterra.viz.flight import plot_compute_time

    img = open_png(plot_compute_time(make_flight(highbay), tmp_path / "compute.png"))
    assert (img.width, img.height) == (1100, 495)
    with pytest.raises(InputError, match="rate_hz"):
        plot_compute_time(replace(make_flight(highbay), rate_hz=0.0), tmp_path / "x.png")


# --------------------------------------------------------------------------- rerun


def test_recorder_without_rerun_raises_config_error_with_install_hint(tmp_path, monkeypatch):
    from subterra.viz import rerun as viz_rerun

    monkeypatch.setitem(sys.modules, "rerun", None)  # `import rerun` now raises ImportError
    assert viz_rerun.rerun_available() is False
    with pytest.raises(ConfigError, match=r"pip install 'subterra\[viz\]'"):
        viz_rerun.RerunRecorder(tmp_path / "x.rrd")
    assert not (tmp_path / "x.rrd").exists()


@pytest.fixture
def rerun_strict():
    """Rerun in strict mode: a wrong archetype argument raises instead of only warning."""
    rr = pytest.importorskip("rerun")
    before = rr.strict_mode()
    rr.set_strict_mode(True)
    yield rr
    rr.set_strict_mode(before)


def test_recorder_writes_rrd_that_reads_back(tmp_path, rerun_strict):
    import subterra
    from subterra.sim import World
    from subterra.viz.rerun import RerunRecorder, rerun_available

    rr = rerun_strict
    assert rerun_available()
    camera = subterra.PinholeCamera(40.0, 40.0, 32.0, 24.0, 64, 48)
    world = World.scenario("cable", seed=0)
    world_from_camera = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 1.25], [0.0, 0.0, 0.0, 1.0]])
    first, second = tmp_path / "one" / "a.rrd", tmp_path / "b.rrd"
    other = RerunRecorder(second, application_id="other", depth_every=2)  # two recorders at once
    with RerunRecorder(first, world=world) as rec:
        for k in range(3):
            depth = np.full((48, 64), 800 + k, np.uint16) if k % 2 == 0 else np.full((48, 64), 0.8, np.float32)
            rec.log_frame(
                k / RATE_HZ,
                depth=depth,
                world_from_camera=world_from_camera,
                camera=camera,
                belief_points_world=np.array([[0.8, 0.0, 1.25], [0.9, 0.1, 1.2]]),
                belief_weights=np.array([0.7, 0.3]),
                position=np.array([0.1 * k, 0.0, 1.25]),
                command=np.array([0.5, 0.0, 0.0, 0.1]),
                p_free=0.2,
            )
            other.log_frame(k / RATE_HZ, position=np.zeros(3), depth=np.zeros((4, 4), np.float32))
        rec.log_frame(0.3, belief_points_world=np.zeros((0, 3)))  # an empty belief clears it
    other.close()
    other.close()  # closing twice is harmless
    for rrd in (first, second):
        assert rrd.is_file() and rrd.stat().st_size > 0

    reader_cls = getattr(getattr(rr, "chunk", None), "RrdReader", None)
    if reader_cls is None:
        pytest.skip(f"rerun {rr.__version__} has no rerun.chunk.RrdReader to read the file back")
    chunks = reader_cls(first).stream().to_chunks()
    entities = {c.entity_path for c in chunks}
    expected = ("/world/geometry/capsules", "/world/regions", "/world/camera", "/world/camera/image/depth", "/world/belief")
    for entity in (*expected, "/robot/command/v_x", "/perception/p_free", "/world/path"):
        assert entity in entities, f"{entity} missing from {sorted(entities)}"
    assert any("sim_time" in c.timeline_names for c in chunks if c.entity_path == "/world/camera/image/depth")
    assert all(c.is_static for c in chunks if c.entity_path.startswith("/world/geometry"))
    assert reader_cls(first).recordings()[0].application_id == "subterra"
    depth_rows = sum(c.num_rows for c in reader_cls(second).stream().to_chunks() if c.entity_path == "/world/camera/image/depth")
    assert depth_rows == 2, "depth_every=2 over 3 frames keeps frames 0 and 2"


def test_recorder_rejects_bad_frames(tmp_path, rerun_strict):
    import subterra
    from subterra.viz.rerun import RerunRecorder

    with RerunRecorder(tmp_path / "bad.rrd") as rec:
        with pytest.raises(InputError, match="depth"):
            rec.log_frame(0.0, depth=np.zeros((4, 4, 3), np.uint16))
        with pytest.raises(InputError, match="depth"):
            rec.log_frame(0.0, depth=np.zeros((4, 4), np.int64))
        with pytest.raises(InputError, match="world_from_camera"):
            rec.log_frame(0.0, world_from_camera=np.eye(3))
        with pytest.raises(InputError, match="belief_weights"):
            rec.log_frame(0.0, belief_points_world=np.zeros((2, 3)), belief_weights=np.ones(3))
        with pytest.raises(InputError, match="time_s"):
            rec.log_frame(math.nan)
        with pytest.raises(InputError, match="camera"):
            rec.log_frame(0.0, depth=np.zeros((4, 4), np.float32), camera=subterra.PinholeCamera.d435())
    with pytest.raises(InputError, match="closed"):
        rec.log_frame(0.0)
    with pytest.raises(ConfigError, match="depth_every"):
        RerunRecorder(tmp_path / "x.rrd", depth_every=0)
