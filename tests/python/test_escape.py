"""Escape from local minima (`subterra.Escape`) and the carrot along a path
(`subterra.PathFollower`) from Python; their flights are tested in the core's unit tests
(a pole, a wall and a U) and in test_flight."""

from __future__ import annotations

import numpy as np
import pytest

import subterra
from subterra.errors import ConfigError, InputError
from subterra.flight import resolve_path
from subterra.flight.run import resolve_route
from subterra.sim import World


def test_the_carrot_leads_along_an_l_shaped_path():
    f = subterra.PathFollower([[0, 0, 1], [4, 0, 1], [4, 3, 1]], lookahead_m=1.5)
    assert f.length_m == 7.0
    out = f.update([1.0, 0.5, 1.0])
    np.testing.assert_allclose(out.carrot_world, [2.5, 0.0, 1.0], atol=1e-12)
    assert out.progress_m == pytest.approx(1.0) and out.remaining_m == pytest.approx(6.5)
    out = f.update([3.5, 0.0, 1.0])
    np.testing.assert_allclose(out.carrot_world, [4.0, 1.0, 1.0], atol=1e-12)
    np.testing.assert_array_equal(f.points(), [[0, 0, 1], [4, 0, 1], [4, 3, 1]])


def test_bad_paths_name_the_argument():
    with pytest.raises(InputError, match="path"):
        subterra.PathFollower([[0, 0, 0]])
    with pytest.raises(InputError, match=r"path\[1\]"):
        subterra.PathFollower([[0, 0, 0], [1, 2]])
    with pytest.raises(InputError, match="lookahead_m"):
        subterra.PathFollower([[0, 0, 0], [1, 0, 0]], lookahead_m=-1.0)
    with pytest.raises(InputError, match="position_world"):
        subterra.PathFollower([[0, 0, 0], [1, 0, 0]]).update([np.nan, 0, 0])


def test_the_tunnels_waypoints_are_the_path():
    world = World.scenario("tunnel", 3)
    path = resolve_path(world, "start", "goal", "auto")
    names = sorted((n for n in world.regions if n.startswith("wp")), key=lambda n: int(n[2:]))
    assert len(names) >= 3 and path.shape == (len(names) + 2, 3)
    np.testing.assert_array_equal(path[0], world.regions["start"][0])
    np.testing.assert_array_equal(path[-1], world.regions["goal"][0])
    np.testing.assert_array_equal(path[1:-1], [world.regions[n][0] for n in names])
    back = resolve_path(world, "goal", "start", "auto")
    np.testing.assert_array_equal(back[1:-1], path[1:-1][::-1])
    assert resolve_path(world, "start", "goal", "none") is None
    assert resolve_path(World.scenario("highbay", 0), "A", "B", "auto") is None
    mine = resolve_path(world, "start", "goal", [[1.0, 2.0, 1.2]])
    assert mine.shape == (3, 3)
    with pytest.raises(InputError, match="path"):
        resolve_path(world, "start", "goal", "zigzag")


def test_without_a_route_a_flight_takes_the_worlds_first():
    assert resolve_route(World.scenario("tunnel", 3), None) == ("start-goal", "start", "goal")
    assert resolve_route(World.scenario("highbay", 0), None) == ("A-B", "A", "B")
    with pytest.raises(InputError, match="route.*start-goal"):
        resolve_route(World.scenario("tunnel", 3), "A-B")


def test_escape_passes_the_goal_through_until_a_stall_near_an_obstacle():
    config = subterra.PerceptionConfig.preset("flight").to_dict()
    assert config["escape"]["enabled"] is False
    config["escape"]["enabled"] = True
    escape = subterra.Escape(config=subterra.PerceptionConfig.from_dict(config))
    pose = np.eye(4)
    stall = config["escape"]["stall_s"]
    goal = [4.0, 0.0, 0.0]
    # Moving toward the goal: never engages, the goal comes back in the body frame.
    for k in range(40):
        x = 0.05 * k
        pose[0, 3] = x
        out = escape.step(stamp=0.1 * k, world_from_body=pose, goal_world=goal, remaining_m=4.0 - x,
                          repulsive_body=[-1.0, 0.0, 0.0])
        assert out.mode == "goal" and not out.active
        np.testing.assert_allclose(out.goal_body, [4.0 - x, 0.0, 0.0], atol=1e-12)
    # Held in place, pushed back by an obstacle ahead: follows its boundary after stall_s.
    t0, modes = 4.0, []
    for k in range(int(stall / 0.1) + 5):
        modes.append(escape.step(stamp=t0 + 0.1 * k, world_from_body=pose, goal_world=goal, remaining_m=2.05,
                                 repulsive_body=[-1.0, 0.0, 0.0]).mode)
    assert modes[0] == "goal" and modes[-1] in ("follow-left", "follow-right")
    with pytest.raises(InputError, match="remaining_m"):
        escape.step(stamp=10.0, world_from_body=pose, goal_world=goal, remaining_m=-1.0)
    with pytest.raises(InputError, match="stamp"):
        escape.step(stamp=0.0, world_from_body=pose, goal_world=goal, remaining_m=1.0)


def test_bad_escape_settings_name_the_field():
    config = subterra.PerceptionConfig.preset("flight").to_dict()
    config["escape"]["max_standoff_m"] = 0.1
    with pytest.raises(ConfigError, match="escape.max_standoff_m"):
        subterra.PerceptionConfig.from_dict(config)
