"""Regenerates the figures of docs/ from the code: `.venv/bin/python docs/make_figures.py [terrain|replay]`
(with `terrain` or `replay`, only those figures)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import subterra
from subterra.perceive import run_perception
from subterra.scenarios import approaching_box_frames
from subterra.viz.plots import plot_depth_trace

FIGURES = Path(__file__).resolve().parent / "figures"


def terrain_figures() -> None:
    """docs/terrain.md: the simulated mine seen by an OS1-64, and the real Ouster OS1-128 scans."""
    from subterra.sim import Lidar, World
    from subterra.sim.render import pose_matrix, start_pose
    from subterra.terrain import translation
    from subterra.viz.terrain import plot_terrain_overview

    world = World.scenario("mine", 0)
    position, yaw, _ = start_pose(world)
    ground = world.ground_height(position[0], position[1]) or 0.0
    world_from_body = pose_matrix(np.array([position[0], position[1], ground]), yaw)
    body_from_sensor = translation(z=0.7)
    points, _ = Lidar("os1_64").scan(world, world_from_body @ body_from_sensor)
    mapper = subterra.TerrainMapper()
    risk_map = mapper.update(points, world_from_body=world_from_body, body_from_sensor=body_from_sensor)
    plot_terrain_overview(mapper, risk_map, FIGURES / "terrain-mine.png", robot_xy=world_from_body[:2, 3],
                          title="simulated mine (seed 0), one OS1-64 scan 0.7 m up: segmentation and risk layers")

    data = Path(__file__).resolve().parents[2] / "shared" / "data" / "ouster-os1-128-outdoor"
    if not data.is_dir():
        print("../shared/data is absent: skipping the Ouster figure")
        return
    from subterra.terrain.cli import run_terrain

    run = FIGURES / "terrain-ouster-run"
    run_terrain([data / f"OS-1-128_scan{i}.npy" for i in range(3)], run,
                poses=data / "OS-1-128_v2.3.0_1024x10_lb_n3_poses_kitti.txt", progress=False)
    (run / "overview.png").replace(FIGURES / "terrain-ouster.png")
    for leftover in run.iterdir():
        leftover.unlink()
    run.rmdir()


def replay_figures() -> None:
    """docs/replay.md: `subterra replay` on the real OS1-64 MCAP and on RealSense frames in a ROS 2 bag."""
    import shutil
    import tempfile

    from subterra.io import list_depth_files, read_depth, read_intrinsics, ros
    from subterra.io.recordings import write_bag
    from subterra.replay import replay

    data = Path(__file__).resolve().parents[2] / "shared" / "data"
    if not data.is_dir():
        print("../shared/data is absent: skipping the replay figures")
        return
    with tempfile.TemporaryDirectory() as tmp:
        replay(data / "mcap-ouster-os1-64" / "test.mcap", Path(tmp) / "os1", cloud_topic="/os1_cloud_node/points",
               sensor_height=0.8, progress=False)
        shutil.copy(Path(tmp) / "os1" / "overview.png", FIGURES / "replay-os1-64.png")
        folder = data / "realsense-d435-room"
        intr = read_intrinsics(folder / "cam_params_realsense.json")
        items = []
        for i, f in enumerate(list_depth_files(folder / "depth")):
            s = 1_700_000_000_000_000_000 + i * 33_333_333
            items.append(("/camera/depth/camera_info", s, ros.camera_info_message(intr, stamp_ns=s, frame_id="camera_depth_optical_frame")))
            items.append(("/camera/depth/image_rect_raw", s + 1,
                          ros.image_message(read_depth(f).data, stamp_ns=s, frame_id="camera_depth_optical_frame")))
        bag = write_bag(Path(tmp) / "realsense", items)
        replay(bag, Path(tmp) / "rs", depth_topic="/camera/depth/image_rect_raw", info_topic="/camera/depth/camera_info",
               progress=False, rerun=False)
        shutil.copy(Path(tmp) / "rs" / "perception.png", FIGURES / "replay-realsense.png")


def main() -> None:
    FIGURES.mkdir(exist_ok=True)
    if sys.argv[1:] == ["replay"]:
        replay_figures()
        return
    terrain_figures()
    if sys.argv[1:] == ["terrain"]:
        return
    replay_figures()
    camera = subterra.PinholeCamera.d435()
    depth, truth = approaching_box_frames(camera, frames=40, seed=0)
    _, records = run_perception(((str(n), d, None) for n, d in enumerate(depth)), camera, progress=False)
    plot_depth_trace(records, FIGURES / "apf-pf-approaching-box.png",
                     title="APF-PF (flight): a 0.5 m box approaching a D435 (synthetic, seed 0)", truth_depth_m=truth)

    from subterra.sim.render import render_scenario

    for name in ("highbay", "mine"):
        render_scenario(name, FIGURES, seed=0)

    # Closed-loop flights (docs/flight.md): highbay B-C, seed 3, both controllers.
    from subterra.flight import fly
    from subterra.flight.cable import cable_test
    from subterra.viz.flight import plot_compute_time, plot_flight_path, plot_flight_trace

    flights = [fly("highbay", "B-C", controller=c, noise="d435-phantom", seed=3) for c in ("apf-pf", "raw-apf")]
    plot_flight_path(flights, FIGURES / "flight-paths.png", title="highbay B-C, seed 3, D435 + phantom speckle: APF-PF vs raw APF")
    plot_flight_trace(flights[0], FIGURES / "flight-trace-apf-pf.png")
    plot_flight_trace(flights[1], FIGURES / "flight-trace-raw-apf.png")
    plot_compute_time(flights[0], FIGURES / "flight-compute-apf-pf.png")
    summary = cable_test(FIGURES / "cable-test-run", frames=150, seed=0, progress=False)
    (FIGURES / "cable-test-run" / "cable-test.png").replace(FIGURES / "cable-test.png")
    for leftover in (FIGURES / "cable-test-run").iterdir():
        leftover.unlink()
    (FIGURES / "cable-test-run").rmdir()
    print("cable test ordering:", {k: v["holds"] for k, v in summary["ordering"].items()})


if __name__ == "__main__":
    main()
