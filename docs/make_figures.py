"""Regenerates the figures of docs/ from the code: `.venv/bin/python docs/make_figures.py [terrain|replay|plan|drive|flight|hero]`
(with `terrain`, `replay`, `plan`, `drive`, `flight` or `hero`, only those figures)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import subterra
from subterra.perceive import run_perception
from subterra.scenarios import approaching_box_frames
from subterra.viz.plots import plot_depth_trace

FIGURES = Path(__file__).resolve().parent / "figures"
#: The tunnel flight whose escapes docs/flight.md shows.
ESCAPE_SEED = 50


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
def plan_figures() -> None:
    """docs/planning.md: risk-aware A* on the simulated mine's coarse map and on a benchmark grid."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from subterra.bench.plan import random_risk_grid
    from subterra.sim import Lidar, World
    from subterra.sim.render import pose_matrix, start_pose
    from subterra.terrain import translation

    world = World.scenario("mine", 0)
    position, yaw, _ = start_pose(world)
    ground = world.ground_height(position[0], position[1]) or 0.0
    world_from_body = pose_matrix(np.array([position[0], position[1], ground]), yaw)
    body_from_sensor = translation(z=0.7)
    points, _ = Lidar("os1_64").scan(world, world_from_body @ body_from_sensor)
    risk_map = subterra.TerrainMapper().update(points, world_from_body=world_from_body, body_from_sensor=body_from_sensor)
    planner = subterra.RiskAStar()
    start = (float(position[0]), float(position[1]))
    colours = {"found": "tab:blue", "budget_exceeded": "tab:orange"}
    fig, axes = plt.subplots(1, 2, figsize=(13, 6.2))
    ax = axes[0]
    ax.imshow(risk_map.to_image(), origin="lower", extent=risk_map.extent)
    for a in np.radians(np.arange(0, 360, 45)):
        goal = (start[0] + 8.0 * np.cos(yaw + a), start[1] + 8.0 * np.sin(yaw + a))
        result = planner.plan(risk_map, start, goal)
        if result.path_world.size:
            ax.plot(*result.path_world.T, color=colours[result.status], lw=1.6)
        ax.plot(*goal, marker="x" if result.status == "goal_blocked" else "o", color="k", ms=5)
        if result.carrot is not None:
            ax.plot(*result.carrot, marker="D", color="w", mec="k", ms=4)
    ax.plot(*start, marker="+", color="k", ms=12, mew=2)
    ax.set_title("mine (seed 0), one OS1-64 scan: paths to 8 goals 8 m away\n"
                 "blue found, orange over the risk budget 0.5, x goal blocked, diamond carrot (1 m)", fontsize=9)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    n = 200
    risk = random_risk_grid(n, 0)
    ax = axes[1]
    image = ax.imshow(risk, origin="lower", extent=(0, n * 0.1, 0, n * 0.1), cmap="magma_r", vmin=0, vmax=1)
    result = subterra.RiskAStar({"r_total": 1.0}).plan_cells(risk, (0, 0), (n - 1, n - 1), resolution=0.1)
    ax.plot(*result.path_world.T, color="tab:cyan", lw=1.8)
    ax.set_title(f"benchmark grid 200x200 (seed 0): cost {result.cost:.3f}, {result.length_m:.1f} m,\n"
                 f"accumulated risk {result.accumulated_risk:.3f}, {result.expanded} cells expanded", fontsize=9)
    ax.set_xlabel("x [m]")
    fig.colorbar(image, ax=ax, fraction=0.046, label="risk per metre")
    fig.tight_layout()
    fig.savefig(FIGURES / "plan-astar.png", dpi=110)
    plt.close(fig)


def drive_figures() -> None:
    """docs/drive.md: the ground robot across the mine (seed 0), the dead end that runs the recovery ladder, and
    both planners in the trade-off worlds and the cave (seed 0)."""
    from subterra.drive import drive
    from subterra.scenarios.ground import recovery_scenario
    from subterra.viz.drive import plot_drive_map, plot_speed_risk

    mine = drive("mine", seed=0)
    plot_drive_map(mine, FIGURES / "drive-mine.png")
    plot_speed_risk(mine, FIGURES / "drive-mine-speed.png")
    sc = recovery_scenario("dead-end")
    dead_end = drive(world=sc.world(), start=sc.start, yaw=sc.yaw, goal=sc.goal, home=sc.home, seed=0, time_limit_s=240)
    plot_drive_map(dead_end, FIGURES / "drive-dead-end.png")
    # The worlds with a trade-off, and the cave: both planners on seed 0.
    for scenario in ("ledge", "rough", "slopes", "cave"):
        for planner in ("risk-aware", "additive"):
            plot_drive_map(drive(scenario, planner=planner, seed=0), FIGURES / f"drive-{scenario}-{planner}.png")


def flight_figures() -> None:
    # Closed-loop flights (docs/flight.md): highbay B-C, seed 3, both controllers.
    from subterra.flight import fly
    from subterra.viz.flight import plot_compute_time, plot_flight_path, plot_flight_trace

    flights = [fly("highbay", "B-C", controller=c, noise="d435-phantom", seed=3) for c in ("apf-pf", "raw-apf")]
    plot_flight_path(flights, FIGURES / "flight-paths.png", title="highbay B-C, seed 3, D435 + phantom speckle: APF-PF vs raw APF")
    plot_flight_trace(flights[0], FIGURES / "flight-trace-apf-pf.png")
    plot_flight_trace(flights[1], FIGURES / "flight-trace-raw-apf.png")
    plot_compute_time(flights[0], FIGURES / "flight-compute-apf-pf.png")
    # The obstacle memory (docs/flight.md): highbay A-B, seed 10, the paper's preset grazes a 22 mm pole.
    pair = [fly("highbay", "A-B", preset=p, noise="d435-phantom", seed=10) for p in ("flight", "flight-memory")]
    plot_flight_path(pair, FIGURES / "flight-memory-paths.png",
                     title="highbay A-B, seed 10, D435 + phantom speckle: APF-PF, flight vs flight-memory")
    # The escape from local minima (docs/flight.md): the tunnel, the default preset.
    escape = fly("tunnel", "start-goal", noise="d435-phantom", seed=ESCAPE_SEED)
    plot_flight_path([escape], FIGURES / "flight-escape.png",
                     title=f"tunnel, seed {ESCAPE_SEED}, D435 + phantom speckle: APF-PF (flight-escape) following boundaries")


def hero_figures() -> None:
    """docs/hero.md: three odometry sources on a 30 s drive, seeded; vio relocalises (a jump), lidar
    stops for 2 s, the wheels slip; the mux's choice, its pose and confidence."""
    from subterra.viz.hero import plot_odometry_mux

    rng = np.random.default_rng(0)

    def pose(x: float, y: float, yaw: float) -> np.ndarray:
        m = np.eye(4)
        m[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
        m[:2, 3] = [x, y]
        return m

    rates = {"vio": 30.0, "lidar": 10.0, "wheels": 50.0}
    # Each source's own world frame (vio's is the mux's, as it is chosen first).
    frames = {"vio": np.eye(4), "lidar": pose(3.0, -2.0, 0.6), "wheels": pose(-1.0, 4.0, -1.1)}
    mux = subterra.OdometryMux(list(rates.items()))
    dt, speed, turn = 0.01, 1.0, 0.15
    x = y = yaw = 0.0
    wheel = np.zeros(3)  # the wheels' dead reckoning: 2 % long, and slipping (1.8x) at 20-24 s
    jump = pose(0.8, -0.5, 0.1)  # vio's relocalisation at 8 s
    last = {name: -1.0 for name in rates}
    times, truth, output, chosen, confidence, events = [], [], [], [], [], []
    tracks: dict[str, list] = {name: [] for name in rates}
    for i in range(3000):
        t = i * dt
        x, y, yaw = x + speed * np.cos(yaw) * dt, y + speed * np.sin(yaw) * dt, yaw + turn * dt
        scale = 1.8 if 20.0 <= t < 24.0 else 1.02
        wheel += [scale * speed * np.cos(wheel[2]) * dt, scale * speed * np.sin(wheel[2]) * dt, turn * dt]
        seen = {"vio": (jump if t >= 8.0 else np.eye(4)) @ pose(x, y, yaw), "lidar": pose(x, y, yaw), "wheels": pose(*wheel)}
        for name, rate in rates.items():
            if t - last[name] < 1.0 / rate - 1e-9 or (name == "lidar" and 15.0 <= t < 17.0):
                continue
            last[name] = t
            noise = pose(*rng.normal(0, [0.005, 0.005, 0.002])) if name != "wheels" else np.eye(4)
            cov = np.diag([0.02**2, 0.02**2, 0.02**2, 1e-4, 1e-4, 1e-4])
            mux.push(name, t, frames[name] @ seen[name] @ noise, covariance=cov, twist=[speed, 0, 0, 0, 0, turn])
        if i % 5 == 0:
            out = mux.update(t)
            times.append(t)
            truth.append((x, y))
            for name in rates:
                tracks[name].append((np.nan, np.nan) if name == "lidar" and 15.0 <= t < 17.0 else seen[name][:2, 3])
            output.append(out.world_from_body[:2, 3] if out.world_from_body is not None else (np.nan, np.nan))
            chosen.append(out.source)
            confidence.append(out.confidence)
            events.extend(out.events)
    plot_odometry_mux(times, np.array(truth), {n: np.array(v, dtype=float) for n, v in tracks.items()},
                      np.array(output, dtype=float), chosen, confidence, events, FIGURES / "hero-switch.png",
                      title="HeRO on a 30 s drive: vio relocalises at 8 s, lidar stops at 15-17 s, the wheels slip at 20-24 s")


def main() -> None:
    FIGURES.mkdir(exist_ok=True)
    only = {"terrain": terrain_figures, "replay": replay_figures, "plan": plan_figures, "drive": drive_figures,
            "flight": flight_figures, "hero": hero_figures}
    if sys.argv[1:2] and sys.argv[1] in only:
        only[sys.argv[1]]()
        return
    for make in only.values():
        make()
    camera = subterra.PinholeCamera.d435()
    depth, truth = approaching_box_frames(camera, frames=40, seed=0)
    _, records = run_perception(((str(n), d, None) for n, d in enumerate(depth)), camera, progress=False)
    plot_depth_trace(records, FIGURES / "apf-pf-approaching-box.png",
                     title="APF-PF (flight): a 0.5 m box approaching a D435 (synthetic, seed 0)", truth_depth_m=truth)

    from subterra.sim.render import render_scenario

    for name in ("highbay", "warehouse", "mine"):
        render_scenario(name, FIGURES, seed=0)

    from subterra.flight.cable import cable_test

    summary = cable_test(FIGURES / "cable-test-run", frames=150, seed=0, progress=False)
    (FIGURES / "cable-test-run" / "cable-test.png").replace(FIGURES / "cable-test.png")
    for leftover in (FIGURES / "cable-test-run").iterdir():
        leftover.unlink()
    (FIGURES / "cable-test-run").rmdir()
    print("cable test ordering:", {k: v["holds"] for k, v in summary["ordering"].items()})


if __name__ == "__main__":
    main()
