"""Closed-loop flights (`subterra fly`, `fly-batch`): depth camera -> controller -> quadrotor.

Small hand-written worlds keep these short; each flight is seeded, so the outcome is the
same on every run.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from worlds import EASY_ROOM

from subterra.errors import InputError

sim = pytest.importorskip("subterra.sim")
flight = pytest.importorskip("subterra.flight")

#: A wall across the way to the goal: the robot must stop or turn before touching it.
WALL_AHEAD = EASY_ROOM.replace(
    '[[cylinder]]\na = [4.0, 2.35, 0.0]\nb = [4.0, 2.35, 3.0]\nradius = 0.045\ntag = "pole"',
    '[[box]]\ncentre = [3.0, 2.0, 1.5]\nsize = [0.2, 4.0, 3.0]\ntag = "wall"',
)


@pytest.fixture(scope="module")
def easy_flight():
    world = sim.World.from_toml(EASY_ROOM)
    return flight.fly(world=world, route="S-G", controller="apf-pf", noise="d435", seed=3, time_limit_s=40.0)


def test_easy_flight_reaches_the_goal_without_collision(easy_flight):
    r = easy_flight
    assert r.success, r.summary()
    assert r.failure is None and r.metrics["collisions"] == 0
    assert r.metrics["min_clearance_m"] > 0.05
    # It ends in the goal region and flew roughly the straight line (6 m), not a detour.
    assert np.linalg.norm(r.path[-1][:2] - r.goal[:2]) <= r.goal_radius_m + 1e-9
    assert 5.0 <= r.metrics["path_length_m"] <= 8.0
    # The pole came within the filter's horizon on the way, and the filter saw it.
    assert r.frames["obstacle_in_view"].any()
    seen = r.frames["mpv_depth_m"][r.frames["obstacle_in_view"]]
    assert np.isfinite(seen).mean() > 0.5
    # Every per-frame array has one row per step.
    n = r.frames["time_s"].size
    assert n == r.metrics["steps"] and all(len(v) == n for v in r.frames.values())
    assert np.all(np.diff(r.frames["time_s"]) > 0)


def test_same_seed_same_flight():
    world = sim.World.from_toml(EASY_ROOM)
    a = flight.fly(world=world, route="S-G", noise="d435-phantom", seed=5, time_limit_s=6.0)
    b = flight.fly(world=world, route="S-G", noise="d435-phantom", seed=5, time_limit_s=6.0)
    assert np.array_equal(a.path, b.path)
    assert np.array_equal(a.frames["command"], b.frames["command"])


@pytest.mark.parametrize("controller", ["apf-pf", "raw-apf"])
def test_wall_ahead_stops_or_turns_before_contact(controller):
    world = sim.World.from_toml(WALL_AHEAD)
    # The paper's plain field (no escape): it stalls in front of the wall.
    r = flight.fly(world=world, route="S-G", controller=controller, noise="none", seed=0, time_limit_s=30.0, stall_window_s=5.0,
                   preset="flight")
    assert r.metrics["collisions"] == 0, r.summary()
    assert not r.success
    assert r.failure in ("local_minimum", "timeout")
    # The sphere (0.27 m) never reached the wall face at x = 2.9 m.
    assert r.metrics["min_clearance_m"] > 0.0
    assert r.path[:, 0].max() < 2.9 - 0.27
    # The repulsion acted: the last commands do not push forward into the wall.
    assert r.frames["repulsive_norm"][-10:].min() > 0.0


#: A wall 2 m wide across the way in a room 8 m wide: there is a way round it.
SHORT_WALL_AHEAD = (
    EASY_ROOM.replace("centre = [4.0, -0.1, 1.5]", "centre = [4.0, -2.1, 1.5]")
    .replace("centre = [4.0, 4.1, 1.5]", "centre = [4.0, 6.1, 1.5]")
    .replace("centre = [-0.1, 2.0, 1.5]\nsize = [0.2, 4.0, 3.0]", "centre = [-0.1, 2.0, 1.5]\nsize = [0.2, 8.0, 3.0]")
    .replace("centre = [8.1, 2.0, 1.5]\nsize = [0.2, 4.0, 3.0]", "centre = [8.1, 2.0, 1.5]\nsize = [0.2, 8.0, 3.0]")
    .replace('[[cylinder]]\na = [4.0, 2.35, 0.0]\nb = [4.0, 2.35, 3.0]\nradius = 0.045\ntag = "pole"',
             '[[box]]\ncentre = [3.0, 2.0, 1.5]\nsize = [0.2, 2.0, 3.0]\ntag = "wall"')
)


def test_the_escape_goes_round_a_wall_the_plain_field_stalls_at():
    world = sim.World.from_toml(SHORT_WALL_AHEAD)
    plain = flight.fly(world=world, route="S-G", noise="none", seed=0, time_limit_s=60.0, stall_window_s=5.0, preset="flight")
    assert not plain.success and plain.failure == "local_minimum", plain.summary()
    r = flight.fly(world=world, route="S-G", noise="none", seed=0, time_limit_s=60.0, preset="flight-escape")
    assert r.metrics["collisions"] == 0, r.summary()
    assert r.frames["escape_active"].any() and r.metrics["escape_frames"] > 0
    assert r.success, r.summary()
    # Round one of the wall's ends (y = 1 or 3 m), not through it.
    crossing = r.path[np.argmax(r.path[:, 0] > 3.0)]
    assert abs(crossing[1] - 2.0) > 1.0 + 0.27, crossing


def test_raw_apf_runs_through_the_same_interface(easy_flight):
    world = sim.World.from_toml(EASY_ROOM)
    raw = flight.fly(world=world, route="S-G", controller="raw-apf", noise="d435", seed=3, time_limit_s=40.0)
    assert raw.controller == "raw-apf"
    assert set(raw.frames) == set(easy_flight.frames)
    # No filter: the belief is the frame's histogram, so P(free) is exactly 0 or 1.
    assert set(np.unique(raw.frames["p_free"])) <= {0.0, 1.0}
    assert raw.summary().keys() == easy_flight.summary().keys()


def test_run_folder_has_every_file(easy_flight, tmp_path):
    from PIL import Image

    paths = easy_flight.save(tmp_path / "run")
    names = {p.name for p in paths.values()}
    assert {"trajectory.csv", "frames.csv", "metrics.json", "path.png", "depth-trace.png", "compute-time.png"} <= names
    for key in ("path_plot", "trace_plot", "compute_plot"):
        with Image.open(paths[key]) as im:
            assert im.size[0] > 300 and im.size[1] > 200
            assert np.asarray(im.convert("L")).std() > 5, f"{key} looks blank"
    metrics = json.loads(paths["metrics"].read_text())
    assert metrics["success"] is True and metrics["controller"] == "apf-pf"
    frames = np.genfromtxt(paths["frames"], delimiter=",", names=True)
    assert frames.size == easy_flight.frames["time_s"].size
    assert np.allclose(frames["compute_ms"], easy_flight.frames["compute_ms"], atol=1e-3)
    traj = np.genfromtxt(paths["trajectory"], delimiter=",", names=True)
    assert traj.size == easy_flight.path.shape[0]


def test_batch_summarises_both_controllers(tmp_path):
    world_routes = ["A-B"]
    log = tmp_path / "flights.jsonl"
    b = flight.fly_batch("highbay", world_routes, [7], controllers=("apf-pf", "raw-apf@flight"), noises=("none",),
                         workers=2, progress=False, rate_hz=10.0, time_limit_s=25.0, log_path=log)
    assert len(b.rows) == 2
    # The default preset for apf-pf; raw-apf pinned to the paper's (no memory, no escape).
    assert {(r["controller"], r["preset"]) for r in b.rows} == {("apf-pf", "flight-escape"), ("raw-apf", "flight")}
    # Every flight is logged as it finishes (an interrupted batch keeps what it flew).
    logged = [json.loads(line) for line in log.read_text().splitlines()]
    assert sorted(logged, key=lambda r: r["job"]) == sorted(b.rows, key=lambda r: r["job"])
    assert {r["controller"] for r in b.rows} == {"apf-pf", "raw-apf"}
    totals = [t for t in b.table if t["route"] == "all"]
    assert len(totals) == 2
    for t in totals:
        assert t["flights"] == 1
        assert t["successes"] + t["collisions"] + t["local_minima"] + t["timeouts"] + t["other_failures"] == 1
    md = b.markdown()
    assert "apf-pf" in md and "raw-apf" in md


def test_batch_flies_presets_side_by_side(tmp_path):
    b = flight.fly_batch("highbay", ["A-B"], [7], controllers=("apf-pf",), noises=("none",), preset="flight,flight-memory",
                         workers=2, progress=False, rate_hz=10.0, time_limit_s=10.0)
    assert sorted(r["preset"] for r in b.rows) == ["flight", "flight-memory"]
    totals = {t["preset"]: t for t in b.table if t["route"] == "all"}
    assert set(totals) == {"flight", "flight-memory"} and all(t["flights"] == 1 for t in totals.values())
    assert b.settings["presets"] == ["flight", "flight-memory"]
    assert "| apf-pf | flight-memory | none | A-B |" in b.markdown()
    written = b.save(tmp_path / "batch")
    assert {"paths_none-flight", "paths_none-flight-memory"} <= set(written)
    with pytest.raises(InputError, match="preset"):
        flight.fly_batch("highbay", ["A-B"], [7], preset="flight,fast", progress=False)


def test_bad_arguments_name_the_argument():
    with pytest.raises(InputError, match="controller"):
        flight.fly(controller="magic")
    with pytest.raises(InputError, match="noise"):
        flight.fly(noise="fog")
    with pytest.raises(InputError, match="route"):
        flight.fly(route="A-Z")
    with pytest.raises(InputError, match="rate_hz"):
        flight.fly(rate_hz=0.0)
    with pytest.raises(InputError, match="seeds"):
        flight.fly_batch(seeds=0)
    with pytest.raises(InputError, match="controllers"):
        flight.fly_batch(seeds=1, controllers=("apf-pf", "nope"))


def test_the_warehouse_is_a_second_world_to_fly():
    """The shelf-and-pole world: five routes between six regions, flown like the hall."""
    world = sim.World.scenario("warehouse", 0)
    assert [f"{a}-{b}" for _, a, b in world.routes] == ["A-B", "C-D", "E-F", "B-A", "D-C"]
    r = flight.fly(world=world, route="A-B", noise="d435-phantom", seed=0, rate_hz=10.0, time_limit_s=12.0)
    assert r.metrics["collisions"] == 0
    start, goal = r.path[0], r.goal
    assert np.linalg.norm(goal[:2] - r.path[-1][:2]) < np.linalg.norm(goal[:2] - start[:2]) - 4.0, "flew down the aisle"
