"""The obstacle memory (`subterra.ObstacleMemory`, preset `flight-memory`): what the belief
put near the robot still repels once it has left the camera's view."""

from __future__ import annotations

import math

import numpy as np
import pytest

import subterra
from subterra.errors import ConfigError, InputError


def _pose(x: float = 0.0, y: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:2, 3] = [x, y]
    return m


def _box_frame(depth_mm: int = 450) -> np.ndarray:
    """A D435 frame with a wall-sized patch `depth_mm` ahead in the middle, nothing else."""
    image = np.zeros((480, 640), dtype=np.uint16)
    image[140:340, 220:420] = depth_mm
    return image


@pytest.fixture
def perception():
    config = subterra.PerceptionConfig.preset("flight-memory")
    return subterra.DepthPerception(subterra.PinholeCamera.d435(), config=config, seed=0, mode="histogram")


def test_flight_memory_is_flight_with_sigma_o_300_and_the_memory_on():
    flight = subterra.PerceptionConfig.preset("flight").to_dict()
    memory = subterra.PerceptionConfig.preset("flight-memory").to_dict()
    assert flight["memory"]["enabled"] is False and memory["memory"]["enabled"] is True
    assert memory["observation"]["sigma_o_points"] == 300.0 and flight["observation"]["sigma_o_points"] == 170.0
    memory["observation"]["sigma_o_points"] = 170.0
    memory["memory"]["enabled"] = False
    assert memory == flight, "flight-memory differs from flight in exactly two values"
    assert "flight-memory" in subterra.preset_names()


def test_an_obstacle_that_left_the_view_still_repels(perception):
    memory = subterra.ObstacleMemory(perception)
    # Belief on the patch 0.45 m ahead for a few frames.
    for n in range(5):
        out = perception.update(_box_frame())
        m = memory.update(out, stamp=0.1 * n, world_from_body=_pose())
    assert out.p_free < 0.01 and m.cells > 0
    assert m.repulsive_body[0] < 0.0, "ahead: pushes back"
    # Turned 90° left, the camera now sees nothing: the belief is free within a frame or
    # two and repels nothing, the memory still pushes away from the patch, now on the right.
    for n in range(5):
        out = perception.update(np.zeros((480, 640), dtype=np.uint16))
        m = memory.update(out, stamp=1.0 + 0.1 * n, world_from_body=_pose(yaw=math.pi / 2))
    assert out.p_free > 0.99 and np.linalg.norm(out.repulsive_body) < 1e-6
    assert m.cells > 0 and m.repulsive_body[1] > 0.5, m
    assert m.nearest_m == pytest.approx(0.45, abs=0.1)
    points = memory.points_world()
    assert points.shape == (m.cells, 3) and memory.weights().shape == (m.cells,)
    assert np.all(points[:, 0] > 0.2), "the patch was ahead of the start pose (+x world)"
    # In view again but no longer believed: forgotten after the view timeout (1 s).
    for n in range(15):
        out = perception.update(np.zeros((480, 640), dtype=np.uint16))
        m = memory.update(out, stamp=2.0 + 0.1 * n, world_from_body=_pose())
    assert m.cells == 0 and np.all(m.repulsive_body == 0.0)


def test_same_calls_same_bits(perception):
    def run():
        p = subterra.DepthPerception(subterra.PinholeCamera.d435(), "flight-memory", seed=3)
        memory = subterra.ObstacleMemory(p)
        forces = []
        for n in range(8):
            out = p.update(_box_frame(400 + 40 * n))
            forces.append(memory.update(out, stamp=0.1 * n, world_from_body=_pose(0.05 * n, 0.0, 0.2 * n)).repulsive_body)
        return np.array(forces)

    assert np.array_equal(run(), run())


def test_bad_input_names_the_argument(perception):
    memory = subterra.ObstacleMemory(perception)
    out = perception.update(_box_frame())
    with pytest.raises(InputError, match="stamp"):
        memory.update(out, stamp=math.nan, world_from_body=_pose())
    memory.update(out, stamp=1.0, world_from_body=_pose())
    with pytest.raises(InputError, match="back in time"):
        memory.update(out, stamp=0.5, world_from_body=_pose())
    skewed = _pose()
    skewed[0, 1] = 0.5
    with pytest.raises(InputError, match="world_from_body"):
        memory.update(out, stamp=2.0, world_from_body=skewed)
    with pytest.raises(InputError, match="world_from_body"):
        memory.update(out, stamp=2.0, world_from_body=np.eye(3))
    memory.reset()
    assert len(memory) == 0
    memory.update(out, stamp=0.0, world_from_body=_pose())  # reset forgets the clock
    d = subterra.PerceptionConfig.preset("flight-memory").to_dict()
    d["memory"]["rho_0_m"] = -1.0
    with pytest.raises(ConfigError, match="memory.rho_0_m"):
        subterra.PerceptionConfig.from_dict(d)
    d["memory"] = {"in_view_timeout_s": 20.0, "timeout_s": 10.0}
    with pytest.raises(ConfigError, match="memory.in_view_timeout_s"):
        subterra.PerceptionConfig.from_dict(d)
    d["memory"] = {"enabled": True, "bogus": 1}
    with pytest.raises(ConfigError, match="bogus"):
        subterra.PerceptionConfig.from_dict(d)


def test_a_config_without_a_memory_section_has_it_off():
    d = subterra.PerceptionConfig.preset("flight").to_dict()
    del d["memory"]
    assert subterra.PerceptionConfig.from_dict(d) == subterra.PerceptionConfig.preset("flight")


def test_the_memory_keeps_a_passed_pole_off_the_robot():
    # Regression: highbay B-C seed 17 with D435 + speckle noise. With the paper's `flight`
    # preset the robot grazes a 22 mm pole 14 s in, and with flight-memory's σ_o = 300 but
    # no memory it still does: the robot turns away until the pole leaves the view and flies
    # on past it blind. With the memory the pole keeps repelling: no contact (the flight
    # then stalls in front of a wall of poles, a local minimum, not a collision).
    fly = pytest.importorskip("subterra.flight").fly
    d = subterra.PerceptionConfig.preset("flight-memory").to_dict()
    d["memory"]["enabled"] = False
    no_memory = fly("highbay", "B-C", config=subterra.PerceptionConfig.from_dict(d), noise="d435-phantom", seed=17,
                    time_limit_s=20.0)
    assert no_memory.metrics["failure"] == "collision" and no_memory.frames["memory_cells"].max() == 0
    kept = fly("highbay", "B-C", preset="flight-memory", noise="d435-phantom", seed=17, time_limit_s=20.0)
    assert kept.metrics["collisions"] == 0 and kept.metrics["min_clearance_m"] > 0.05, kept.metrics
    assert kept.frames["memory_cells"].max() > 0 and kept.frames["memory_repulsive_norm"].max() > 0.0


def _cable_frame() -> np.ndarray:
    """A D435 frame of a wall 1.0 m ahead everywhere, and a 14 mm cable 0.45 m ahead in
    the middle (12 px wide at fx = 385, from the top of the image to its middle)."""
    image = np.full((480, 640), 1000, dtype=np.uint16)
    image[:250, 314:326] = 450
    return image


def test_the_near_field_guard_remembers_a_cable_the_belief_leaves_on_the_wall():
    # The belief is over one obstacle: a full wall voxel 1 m ahead outweighs the cable's
    # 600 of a block's 2500 points, so the most probable voxel stays on the wall. The guard
    # (flight-escape: 3 σ_n = 180 points within ρ_m = 0.6 m) remembers the cable anyway.
    config = subterra.PerceptionConfig.preset("flight-escape")
    assert config.to_dict()["memory"]["guard_sigmas"] == 3.0
    perception = subterra.DepthPerception(subterra.PinholeCamera.d435(), config=config, seed=0, mode="histogram")
    guarded, blind = subterra.ObstacleMemory(perception), subterra.ObstacleMemory(perception)
    for n in range(5):
        out = perception.update(_cable_frame())
        g = guarded.update(out, stamp=0.1 * n, world_from_body=_pose(), perception=perception)
        b = blind.update(out, stamp=0.1 * n, world_from_body=_pose())
    assert out.most_probable is not None and out.most_probable.depth_m > 0.9, "the belief sits on the wall"
    assert b.nearest_m is None or b.nearest_m > 0.6, "without the counts the cable is not remembered"
    assert g.nearest_m is not None and g.nearest_m < 0.6 and g.cells > b.cells
    assert g.repulsive_body[0] < 0.0 and np.linalg.norm(g.repulsive_body) > np.linalg.norm(b.repulsive_body)
    near = guarded.points_world()[np.linalg.norm(guarded.points_world(), axis=1) < 0.6]
    assert np.all(guarded.weights()[np.linalg.norm(guarded.points_world(), axis=1) < 0.6] == 1.0)
    assert np.all(np.abs(near[:, 0] - 0.45) < 0.06), "at the cable's depth bin (0.4-0.5 m)"


def test_the_guard_ignores_speckle_and_needs_the_perception_that_counted():
    config = subterra.PerceptionConfig.preset("flight-escape")
    perception = subterra.DepthPerception(subterra.PinholeCamera.d435(), config=config, seed=0, mode="histogram")
    memory = subterra.ObstacleMemory(perception)
    # A speckle blob (radius 6 px: 113 points, under 3 σ_n) 0.45 m ahead on an empty frame.
    image = np.zeros((480, 640), dtype=np.uint16)
    yy, xx = np.mgrid[:480, :640]
    image[(yy - 240) ** 2 + (xx - 320) ** 2 <= 36] = 450
    out = perception.update(image)
    assert memory.update(out, stamp=0.0, world_from_body=_pose(), perception=perception).cells == 0
    other = subterra.DepthPerception(subterra.PinholeCamera(200.0, 200.0, 99.5, 99.5, 200, 200), config=config, seed=0)
    other.update(np.full((200, 200), 450, dtype=np.uint16))
    with pytest.raises(InputError, match="perception"):
        memory.update(out, stamp=0.1, world_from_body=_pose(), perception=other)


@pytest.mark.parametrize("bad", [0.5, -1.0, float("nan"), 101.0])
def test_a_guard_under_one_sigma_or_absurd_is_refused_by_name(bad):
    d = subterra.PerceptionConfig.preset("flight-escape").to_dict()
    d["memory"]["guard_sigmas"] = bad
    with pytest.raises(ConfigError, match="memory.guard_sigmas"):
        subterra.PerceptionConfig.from_dict(d)


def test_guarded_cells_are_averaged_not_summed():
    # A wall 0.45 m ahead fills every near voxel past the guard's threshold: the memory's
    # push is the mean over them (each guarded cell weighs 1), the size of one voxel's, not
    # a sum that grows with the wall's area.
    config = subterra.PerceptionConfig.preset("flight-escape")
    perception = subterra.DepthPerception(subterra.PinholeCamera.d435(), config=config, seed=0, mode="histogram")
    memory = subterra.ObstacleMemory(perception)
    out = perception.update(np.full((480, 640), 450, dtype=np.uint16))
    m = memory.update(out, stamp=0.0, world_from_body=_pose(), perception=perception)
    assert m.cells > 10
    single = subterra.ObstacleMemory(perception)
    image = np.zeros((480, 640), dtype=np.uint16)
    image[230:250, 310:330] = 450  # one voxel's worth, straight ahead (400 points)
    one = single.update(perception.update(image), stamp=0.0, world_from_body=_pose(), perception=perception)
    assert one.cells >= 1
    assert np.linalg.norm(m.repulsive_body) <= 1.5 * np.linalg.norm(one.repulsive_body)


def test_tunnel_seed_35_passes_the_cable_that_it_once_hit():
    # Regression, closed loop: tunnel seed 35 (development range) with D435 + speckle noise.
    # Before the guard and the goal-facing escape side, the robot met a 14 mm cable hanging
    # to flight height 36 s in (the belief stayed on the wall behind it). The guard's own
    # effect is shown frame by frame above: after the escape change this flight also passes
    # without it, so only the whole stack's outcome is asserted here.
    fly = pytest.importorskip("subterra.flight").fly
    on = fly("tunnel", "start-goal", preset="flight-escape", noise="d435-phantom", seed=35, time_limit_s=40.0)
    assert on.metrics["collisions"] == 0 and on.metrics["min_clearance_m"] > 0.1, on.metrics
