"""The simulator through its Python face: worlds, sensors, the step loop, errors, CLI."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from subterra import errors, sim
from subterra.cli import main
from subterra.sim.render import BODY_FROM_OPTICAL, pose_matrix

REPO = Path(__file__).resolve().parents[2]

WALL = """
name = "wall"
[[plane]]
point = [3.0, 0.0, 0.0]
normal = [-1.0, 0.0, 0.0]
[[sphere]]
centre = [2.0, 1.0, 0.0]
radius = 0.25
tag = "boulder"
[[region]]
name = "start"
centre = [0.0, 0.0, 0.0]
radius = 0.5
[[region]]
name = "goal"
centre = [2.0, -1.0, 0.0]
radius = 0.5
"""


def test_world_file_queries_are_exact():
    world = sim.World.from_toml(WALL)
    assert world.name == "wall" and set(world.regions) == {"start", "goal"}
    hit = world.cast_ray([0, 0, 0], [1, 0, 0])
    assert hit["distance_m"] == pytest.approx(3.0, abs=1e-9)
    np.testing.assert_allclose(hit["normal"], [-1, 0, 0], atol=1e-12)
    # Toward the sphere's centre: distance to its surface.
    d = np.array([2.0, 1.0, 0.0])
    hit = world.cast_ray([0, 0, 0], d)
    assert hit["distance_m"] == pytest.approx(np.linalg.norm(d) - 0.25, abs=1e-6)
    assert world.primitive(hit["primitive"])[0] == "boulder"
    assert world.cast_ray([0, 0, 0], [-1, 0, 0]) is None
    assert world.clearance([2.0, 1.0, 0.6]) == pytest.approx(0.35, abs=1e-6)


def test_world_errors_name_the_field(tmp_path):
    with pytest.raises(errors.FileFormatError, match=r"sphere\[0\]\.radius"):
        sim.World.from_toml(WALL.replace("radius = 0.25", "radius = -0.25"))
    with pytest.raises(errors.FileFormatError, match="line"):
        sim.World.from_toml("[[sphere]\ncentre = 1")
    bad = tmp_path / "w.toml"
    bad.write_text("[[cylinder]]\na = [0, 0, 0]\n")
    with pytest.raises(errors.FileFormatError, match=str(bad)):
        sim.load_world(bad)
    with pytest.raises(errors.ConfigError, match="moon"):
        sim.World.scenario("moon")
    with pytest.raises(errors.InputError, match="direction"):
        sim.World.from_toml(WALL).cast_ray([0, 0, 0], [0, 0, 0])


def test_example_world_file_loads():
    world = sim.load_world(REPO / "docs" / "examples" / "world.toml")
    assert world.primitive_count > 0 and world.routes


def test_scenarios_are_seeded():
    for name in sim.scenario_names():
        a, b, c = sim.World.scenario(name, 1), sim.World.scenario(name, 1), sim.World.scenario(name, 2)
        assert a.to_toml() == b.to_toml()
        assert a.to_toml() != c.to_toml(), name


def test_depth_camera_sees_a_wall_at_its_distance():
    world = sim.World.from_toml(WALL)
    camera = sim.DepthCamera.d435()
    depth = camera.render(world, pose_matrix([0.0, -1.0, 0.0], 0.0) @ BODY_FROM_OPTICAL)
    assert depth.shape == (480, 640) and depth.dtype == np.float32
    # Every pixel looks at the wall plane x = 3 (z along the optical axis = 3 m), bar the boulder's.
    wall = depth[np.abs(depth - 3.0) < 1e-4]
    assert wall.size > 0.8 * depth.size
    noisy = camera.render(world, pose_matrix([0.0, -1.0, 0.0], 0.0) @ BODY_FROM_OPTICAL, noise="paper-every-10th", seed=3)
    changed = np.flatnonzero((noisy != depth).ravel())
    assert np.all(changed % 10 == 0)
    again = camera.render(world, pose_matrix([0.0, -1.0, 0.0], 0.0) @ BODY_FROM_OPTICAL, noise="paper-every-10th", seed=3)
    assert np.array_equal(noisy, again)
    with pytest.raises(errors.ConfigError, match="noise"):
        camera.render(world, np.eye(4), noise="fog")
    with pytest.raises(errors.InputError, match="world_from_camera"):
        camera.render(world, np.ones((4, 4)))


def test_lidar_scan_of_a_wall():
    world = sim.World.from_toml(WALL)
    lidar = sim.Lidar("vlp16")
    points, ring = lidar.scan(world, pose_matrix([0.0, -1.0, 0.0], 0.0))
    assert points.dtype == np.float32 and points.shape[1] == 3 and ring.shape == (points.shape[0],)
    assert set(np.unique(ring)) <= set(range(16))
    ahead = points[np.abs(np.arctan2(points[:, 1], points[:, 0])) < 0.1]
    np.testing.assert_allclose(ahead[:, 0], 3.0, atol=1e-4)  # the wall, 3 m ahead in the sensor frame
    with pytest.raises(errors.ConfigError, match="lidar"):
        sim.Lidar("hdl64")


def test_sensors_render_into_kept_buffers_without_touching_returned_arrays():
    # A camera and a lidar render into buffers they keep between calls: what a call returned
    # stays as it was after later calls from elsewhere, and a pose gives the same arrays
    # whatever came before (one thread or several, with noise or without).
    world = sim.World.scenario("mine", 2)
    camera, lidar = sim.DepthCamera.d435(), sim.Lidar("os1_64")
    poses = [pose_matrix([5.0, 10.0, 1.2], yaw) for yaw in (0.0, 2.0)]
    depth = camera.render(world, poses[0] @ BODY_FROM_OPTICAL)
    points, ring = lidar.scan(world, poses[0])
    kept = (depth.copy(), points.copy(), ring.copy())
    other = camera.render(world, poses[1] @ BODY_FROM_OPTICAL, threads=2)
    other_points, _ = lidar.scan(world, poses[1], noise="os1_64", seed=4)
    assert not np.array_equal(other, depth)
    assert other_points.shape != points.shape or not np.array_equal(other_points, points)
    for returned, copy in zip((depth, points, ring), kept):
        assert np.array_equal(returned, copy)
    assert np.array_equal(camera.render(world, poses[0] @ BODY_FROM_OPTICAL, threads=2), depth)
    again_points, again_ring = lidar.scan(world, poses[0])
    assert np.array_equal(again_points, points) and np.array_equal(again_ring, ring)


def test_simulation_flies_to_the_goal_and_is_deterministic():
    world = sim.World.from_toml(WALL)

    def run(seed):
        s = sim.Simulation(world, "quadrotor", {"front": (sim.DepthCamera.d435(), None, "d435")}, seed, start=[0.0, 0.0, 0.0])
        s.set_goal(region="goal")
        s.set_time_limit(30.0)
        frames = []
        while s.status == "running":
            obs = s.observe()
            frames.append(obs["depth"]["front"])
            p = obs["world_from_body"][:3, 3]
            goal = np.array([2.0, -1.0, 0.0]) - p
            heading = math.atan2(goal[1], goal[0])
            s.step([0.5 * math.cos(heading), 0.5 * math.sin(heading), 0.0, 0.0], dt=0.1)
        return s.metrics(), frames

    metrics, frames = run(0)
    assert metrics["success"] and metrics["failure"] is None and metrics["collisions"] == 0
    straight = math.hypot(2.0, 1.0) - 0.5
    assert straight <= metrics["path_length_m"] < straight + 0.5
    again, frames2 = run(0)
    assert again == metrics and all(np.array_equal(a, b) for a, b in zip(frames, frames2))
    _, frames3 = run(1)
    assert not np.array_equal(frames[0], frames3[0])


def test_simulation_detects_a_collision_and_bad_steps():
    world = sim.World.from_toml(WALL)
    s = sim.Simulation(world, "quadrotor", start=[0.0, 0.0, 0.0])
    while s.status == "running":
        out = s.step([0.6, 0.0, 0.0, 0.0], 0.1)
    assert out["status"] == "failed" and out["failure"] == "collision"
    assert s.metrics()["collisions"] == 1
    s = sim.Simulation(world, "quadrotor", start=[0.0, 0.0, 0.0])
    with pytest.raises(errors.InputError, match="dt"):
        s.step([0.1, 0, 0, 0], dt=-1.0)
    with pytest.raises(errors.InputError, match="v_x"):
        s.step([float("nan"), 0, 0, 0])
    with pytest.raises(errors.InputError, match="command"):
        s.step([0.1, 0.0])
    with pytest.raises(errors.InputError, match="sensors"):
        sim.Simulation(world, "quadrotor", {"x": 3})
    with pytest.raises(errors.ConfigError, match="vehicle"):
        sim.Simulation(world, "submarine")
    with pytest.raises(errors.ConfigError, match="nowhere"):
        s.set_goal(region="nowhere")


def test_ground_robot_on_the_mine():
    world = sim.World.scenario("mine", 0)
    start = world.regions["start"][0]
    s = sim.Simulation(world, "ground", start=start, seed=0)
    s.add_lidar("os1", sim.Lidar("os1_64"), body_from_sensor=pose_matrix([0.0, 0.0, 0.5], 0.0), noise="os1_64")
    obs = s.observe()
    assert obs["scans"]["os1"].shape[0] > 10_000
    z = obs["world_from_body"][2, 3]
    assert z == pytest.approx(world.ground_height(start[0], start[1]), abs=0.15)
    out = s.step([0.5, 0.0, 0.0, 0.0], dt=0.2)
    assert out["status"] == "running"


def test_apf_commands_drive_the_simulated_quadrotor():
    import subterra

    world = sim.World.from_toml(WALL)
    s = sim.Simulation(world, "quadrotor", {"front": sim.DepthCamera.d435()}, 0, start=[0.0, 0.0, 0.0])
    perception = subterra.DepthPerception(sim.DepthCamera.d435().camera, seed=0)
    controller = subterra.ApfController()
    obs = s.observe()
    out = perception.update(obs["depth"]["front"])
    cmd = controller.command([2.0, -1.0, 0.0], [out])
    step = s.step(cmd, 0.1)
    assert step["status"] == "running" and s.time_s == pytest.approx(0.1)


def test_cli_sim_render_writes_pictures(tmp_path, capsys):
    assert main(["sim", "render", "cable", "--out", str(tmp_path)]) == 0
    for name in ("cable-depth.png", "cable-map.png"):
        assert (tmp_path / name).stat().st_size > 10_000
    assert "wrote" in capsys.readouterr().out
    assert main(["sim", "render", "moon", "--out", str(tmp_path)]) == 2


def test_bench_sim_reports_rust_and_mujoco_on_the_same_rays():
    from subterra.bench.sim import bench_sim

    report = bench_sim(repeats=1)
    for name in ("depth_d435_highbay", "depth_d435_tunnel"):
        case = report["cases"][name]
        assert case["rays"] == 640 * 480 and case["rust_one_thread"]["median_ms"] > 0
        if isinstance(case["mujoco_multiray"], dict):
            # The same rays into the same world: MuJoCo's depths agree with ours.
            assert case["mujoco_depth_agreement_p99_m"] < 1e-4
    assert report["cases"]["lidar_os1_64_mine"]["rays"] == 64 * 1024
