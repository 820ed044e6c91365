"""QMDP action selection (`subterra.Qmdp`, controller `apf-pf-qmdp`): the reward table is
the documented formula over the perception's voxel points, the choice backs off from what
the belief holds ahead and stands still when it holds nothing, and a flight runs with it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from worlds import EASY_ROOM

import subterra
from subterra import flight, sim
from subterra.errors import ConfigError, FileFormatError, InputError


def _box_frame(depth_mm: int = 450) -> np.ndarray:
    image = np.zeros((480, 640), dtype=np.uint16)
    image[140:340, 220:420] = depth_mm
    return image


@pytest.fixture(scope="module")
def perception():
    return subterra.DepthPerception(subterra.PinholeCamera.d435(), "flight", seed=0)


@pytest.fixture(scope="module")
def qmdp(perception):
    return subterra.Qmdp(perception)


def _potential(c: dict, x: np.ndarray) -> np.ndarray:
    d = np.maximum(np.linalg.norm(x, axis=-1), c["min_distance_m"])
    return np.where(d < c["potential_range_m"], 0.5 * c["potential_gain"] * (1 / d - 1 / c["potential_range_m"]) ** 2, 0.0)


def test_the_reward_table_is_the_formula_over_the_voxel_points(perception, qmdp):
    assert qmdp.config == subterra.QmdpConfig()
    c = qmdp.config.to_dict()
    actions, rewards = qmdp.actions(), qmdp.rewards()
    assert actions.shape == (405, 3) and rewards.shape == (perception.state_count, 405)
    assert (actions == 0).all(axis=1).sum() == 1
    cost = -(np.asarray(c["action_cost"]) * actions**2).sum(axis=1)
    np.testing.assert_allclose(rewards[perception.free_state], cost, rtol=1e-14)
    # `flight` places a voxel at its centre; the look-ahead samples t = 0, 0.1, ..., 0.5 s.
    points = perception.voxel_centres("body")
    steps = np.arange(round(c["lookahead_s"] / c["step_s"]) + 1) * c["step_s"]
    rng = np.random.default_rng(0)
    for s in rng.choice(len(points), 40, replace=False):
        moved = points[s][None, None, :] - actions[:, None, :] * steps[None, :, None]
        expected = cost - _potential(c, moved).sum(axis=1)
        np.testing.assert_allclose(rewards[s], expected, rtol=1e-12, atol=1e-12)


def test_backs_off_from_a_box_ahead_and_stands_still_in_free_space():
    p = subterra.DepthPerception(subterra.PinholeCamera.d435(), "flight", seed=0)
    q = subterra.Qmdp(p)
    for _ in range(5):
        out = p.update(_box_frame())
    a = q.act(out)
    assert out.p_free < 0.05
    assert a.velocity_body[0] < 0.0, a
    np.testing.assert_array_equal(q.actions()[a.index], a.velocity_body)
    # The choice is the best expected reward under the output's belief.
    values = out.belief_probabilities @ q.rewards()[out.belief_states]
    assert a.value == pytest.approx(values.max(), rel=1e-12) and values[a.index] == values.max()
    for _ in range(10):
        out = p.update(np.zeros((480, 640), dtype=np.uint16))
    assert out.p_free > 0.99
    assert np.all(q.act(out).velocity_body == 0.0)


def test_outputs_of_another_perception_and_bad_settings_are_refused(qmdp):
    other = subterra.DepthPerception(subterra.PinholeCamera(300, 300, 160, 120, 320, 240), "flight", seed=0)
    with pytest.raises(InputError, match=r"argument `output`.*different perception"):
        qmdp.act(other.update(np.zeros((240, 320), dtype=np.uint16)))
    p = subterra.DepthPerception(subterra.PinholeCamera.d435(), "flight", seed=0)
    with pytest.raises(ConfigError, match=r"action_step_m_s"):
        subterra.Qmdp(p, {"action_step_m_s": [0.0, 0.2, 0.2]})
    with pytest.raises(ConfigError, match=r"action_step_m_s.*more than 101 actions"):
        subterra.Qmdp(p, {"action_step_m_s": [1e-9, 0.2, 0.2]})
    with pytest.raises(ConfigError, match=r"lookahead_s"):
        subterra.Qmdp(p, {"lookahead_s": math.inf})
    with pytest.raises(ConfigError, match=r"nope"):
        subterra.Qmdp(p, {"nope": 1})
    with pytest.raises(ConfigError, match=r"argument `config` must be None, a dict, a QmdpConfig or a TOML path"):
        subterra.Qmdp(p, 42)
    with pytest.raises(FileFormatError, match="no-such-qmdp.toml"):
        subterra.Qmdp(p, "no-such-qmdp.toml")
    # A coarser action set is smaller and still holds 0.
    q = subterra.Qmdp(p, {"action_step_m_s": [0.4, 0.8, 0.8]})
    assert len(q.actions()) == 3 * 3 * 3 and (q.actions() == 0).all(axis=1).any()




def test_a_qmdp_flight_passes_a_pole_and_is_the_same_bits_twice():
    world = sim.World.from_toml(EASY_ROOM)
    runs = [flight.fly(world=world, route="S-G", controller="apf-pf-qmdp", noise="d435", seed=3, time_limit_s=40.0)
            for _ in range(2)]
    r = runs[0]
    assert r.controller == "apf-pf-qmdp"
    assert r.success and r.metrics["collisions"] == 0, r.summary()
    assert np.array_equal(runs[0].path, runs[1].path)
    assert np.array_equal(runs[0].frames["command"], runs[1].frames["command"])
