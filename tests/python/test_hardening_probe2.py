"""Findings of the second probe: each input once hung, was accepted as garbage or gave an error
that did not name the argument or field the user gave."""

from __future__ import annotations

import time

import numpy as np
import pytest

import subterra
from subterra.errors import ConfigError, InputError


def test_a_broadcast_view_of_10e8_mission_items_is_refused_at_once():
    mapper = subterra.TerrainMapper()
    t0 = time.perf_counter()
    with pytest.raises(InputError, match=r"argument `items` has 100000000 items"):
        mapper.set_mission_items(np.broadcast_to(np.float64(1), (10**8, 3)))
    assert time.perf_counter() - t0 < 1.0
    # A generator has no length: it stops at the limit.
    with pytest.raises(InputError, match=r"argument `items` has 10001 items"):
        mapper.set_mission_items((1.0, 2.0, 3.0) for _ in range(10**6))
    mapper.set_mission_items([(1.0, 2.0, 3.0)] * 10_000)


@pytest.mark.parametrize("value", [np.float32(2.0), np.float64(2.0), np.int64(2), np.int32(2)])
def test_numpy_scalars_in_a_config_dict_are_their_python_numbers(value):
    assert subterra.RobotConfig({"length_m": value}).to_dict()["length_m"] == 2.0
    nested = subterra.TerrainConfig({"coarse": {"resolution_m": np.float32(0.25)}})
    assert nested == subterra.TerrainConfig({"coarse": {"resolution_m": 0.25}})


def test_a_numpy_bool_in_a_config_dict_is_a_bool():
    d = subterra.NavigatorConfig().to_dict()
    flag = next(k for k, v in d["navigator"].items() if isinstance(v, bool))
    c = subterra.NavigatorConfig({"navigator": {flag: np.bool_(not d["navigator"][flag])}})
    assert c.to_dict()["navigator"][flag] is (not d["navigator"][flag])


@pytest.mark.parametrize("value", [1j, b"2", np.complex64(1), np.float32("nan")])
def test_an_unserialisable_config_value_is_a_config_error_naming_the_field(value):
    with pytest.raises(ConfigError, match=r"`robot\.length_m`"):
        subterra.RobotConfig({"length_m": value})
    with pytest.raises(ConfigError, match=r"`coarse\.resolution_m`"):
        subterra.TerrainConfig({"coarse": {"resolution_m": value}})


@pytest.mark.parametrize(("cls", "d", "section"), [
    (subterra.PerceptionConfig, {"transition": [1, 2]}, "transition"),
    (subterra.MpcConfig, {"footprint": [9.0, 9.0]}, "footprint"),
    (subterra.NavigatorConfig, {"planner": [1.0]}, "planner"),
])
def test_a_config_section_given_as_a_list_is_a_config_error_naming_it(cls, d, section):
    with pytest.raises(ConfigError, match=rf"config section `{section}` must be a dict"):
        cls(d)


@pytest.mark.parametrize(("d", "field"), [
    ({"planner": {"lam": 2**64}}, "planner.lam"),
    ({"tracker": {"dt_s": 2**64}}, "tracker.dt_s"),
])
def test_navigator_section_errors_name_the_navigators_field(d, field):
    with pytest.raises(ConfigError, match=rf"`{field}`"):
        subterra.NavigatorConfig(d)


def _world():
    import subterra.sim as sim
    return sim.World.scenario("highbay", 0)


def test_simulation_sensors_given_as_a_list_is_an_input_error_naming_sensors():
    import subterra.sim as sim
    cam = subterra.PinholeCamera(50.0, 50.0, 32.0, 24.0, 64, 48)
    with pytest.raises(InputError, match=r"argument `sensors` must be a dict"):
        sim.Simulation(_world(), "quadrotor", sensors=[sim.DepthCamera(cam)], start=[2.0, 2.0, 1.0])


def test_simulation_step_names_dt():
    import subterra.sim as sim
    s = sim.Simulation(_world(), "quadrotor", start=[2.0, 2.0, 1.0])
    with pytest.raises(InputError, match=r"argument `dt` is invalid"):
        s.step([0.1, 0, 0, 0], dt=1e9)


def test_pilot_goals_and_paths_beyond_1000_km_name_their_argument():
    cam = subterra.PinholeCamera(50.0, 50.0, 32.0, 24.0, 64, 48)
    pilot = subterra.Pilot(cam)
    with pytest.raises(InputError, match=r"argument `goal_world`.*1e6 m of the origin"):
        pilot.set_goal([1e308, 0, 0])
    with pytest.raises(InputError, match=r"argument `goal_world`"):
        pilot.set_goal([9e5, 9e5, 0])  # 1.27e6 m away: the distance counts, not each axis
    with pytest.raises(InputError, match=r"argument `path\[1\]`"):
        pilot.set_path([[0, 0, 0], [1e300, 0, 0]])
    with pytest.raises(InputError, match=r"argument `path\[1\]`"):
        subterra.PathFollower([[0, 0, 0], [1e300, 0, 0]])
    pilot.set_goal([5e5, 5e5, 0])


def test_a_navigator_at_9e5_9e5_is_refused():
    with pytest.raises(InputError, match=r"1e6 m of the origin"):
        subterra.Navigator((9e5, 9e5))


@pytest.mark.parametrize("origin", [(1e300, 0.0), (9e5, 9e5)])
def test_a_risk_grid_beyond_1000_km_is_refused_naming_origin(origin):
    risk = np.ones((10, 10), np.float32)
    with pytest.raises(InputError, match=r"argument `origin`"):
        subterra.RiskAStar().plan(risk, (1e300, 0.5), (1e300 + 5, 0.5), resolution=1.0, origin=origin)
    with pytest.raises(InputError, match=r"argument `origin`"):
        subterra.RiskAStar().plan_cells(risk, (0, 0), (5, 5), resolution=1.0, origin=origin)


def test_astar_start_and_goal_beyond_1000_km_name_their_argument():
    risk = np.zeros((10, 10), np.float32)
    with pytest.raises(InputError, match=r"argument `start`.*1e6 m"):
        subterra.RiskAStar().plan(risk, (1e300, 0.5), (5, 5), resolution=1.0)
    with pytest.raises(InputError, match=r"argument `goal`.*1e6 m"):
        subterra.RiskAStar().plan(risk, (0.5, 0.5), (0, -1e300), resolution=1.0)


@pytest.mark.parametrize("h", [1e308, -5.0, 5e-324, 0.0, 100.5])
def test_segment_ground_sensor_height_is_bounded_like_the_cli(h):
    with pytest.raises(InputError, match=r"argument `sensor_height`"):
        subterra.segment_ground(np.zeros((4, 3), np.float32), sensor_height=h)
    subterra.segment_ground(np.zeros((4, 3), np.float32), sensor_height=1.5)


def test_the_mpc_refuses_a_risk_grid_beyond_1000_km_naming_origin():
    with pytest.raises(InputError, match=r"argument `origin`"):
        subterra.MpcTracker().solve([0, 0, 0, 0], [[0, 0], [1, 0]], risk=np.ones((10, 10), np.float32), resolution=1.0, origin=(1e300, 0))


def _writers(tmp_path):
    import subterra.io as sio
    pts = np.zeros((4, 3), np.float32)
    return [
        lambda p: sio.write_pcd(p, pts),
        lambda p: sio.write_ply(p, pts),
        lambda p: sio.write_depth_png(p, np.ones((4, 4), np.uint16)),
        lambda p: sio.McapWriter(p).close(),
    ]


def test_writers_refuse_a_missing_folder_naming_the_path(tmp_path):
    target = tmp_path / "nonexistent" / "x"
    for write in _writers(tmp_path):
        with pytest.raises(InputError, match=r"does not exist.*nonexistent/x$"):
            write(target)
        assert not (tmp_path / "nonexistent").exists()


def test_writers_refuse_a_symlink_loop_naming_the_path(tmp_path):
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    for write in _writers(tmp_path):
        with pytest.raises(InputError, match=r"cannot write .*loop$"):
            write(loop)


def test_write_bag_refuses_an_existing_path_naming_it(tmp_path):
    pytest.importorskip("rosbags")
    import subterra.io as sio
    existing = tmp_path / "bag"
    existing.mkdir()
    with pytest.raises(InputError, match=r"exists already.*bag$"):
        sio.write_bag(existing, [])
    with pytest.raises(InputError, match=r"does not exist"):
        sio.write_bag(tmp_path / "missing" / "bag", [])


def test_mcap_writer_on_a_file_that_takes_no_bytes_is_an_input_error():
    import subterra.io as sio
    w = sio.McapWriter("/proc/self/mem")
    with pytest.raises(InputError, match=r"cannot write recording: .*/proc/self/mem"):
        w.close()
