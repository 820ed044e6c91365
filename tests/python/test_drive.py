"""The closed-loop ground robot: simulated lidar -> Navigator (mapper, risk-aware A*, MPC,
recovery) -> ground robot, and the recovery behaviours forced by hand-made worlds."""

from __future__ import annotations

import json

import numpy as np
import pytest

import subterra
from subterra.drive import drive
from subterra.errors import ConfigError, InputError
from subterra.scenarios.ground import RECOVERY_SCENARIOS, recovery_scenario


def _behaviours(result) -> list[str]:
    return [e["to"] for e in result.events if e["from"] != e["to"]]


def test_mine_drive_reaches_the_goal_and_writes_its_run_folder(tmp_path):
    result = drive("mine", seed=0, time_limit_s=60)
    m = result.metrics
    assert m["success"], (m["failure"], result.events[-3:])
    assert m["failure"] is None and m["collisions"] == 0
    assert np.linalg.norm(result.steps["position"][-1, :2] - result.goal) < 1.5
    # The MPC drove, below the risk-limited speed, and on the plan. The backup stop is
    # allowed on a tick or two: remembered hazards in the blind ring can give the MPC an
    # obstacle half-plane the current state already violates (1 of 286 ticks on this drive).
    solved = result.steps["mpc_status"][result.steps["mpc_status"] != ""]
    assert set(solved) <= {"solved", "solved_inexact", "infeasible_backup"}
    assert np.mean(np.isin(solved, ["solved", "solved_inexact"])) >= 0.98
    assert np.all(result.steps["command"][:, 0] <= result.steps["speed_limit_m_s"] + 1e-6)
    assert m["max_tilt_deg"] < 25.0
    written = result.save(tmp_path / "run")
    for key in ("trajectory", "metrics", "map_plot", "speed_plot", "compute_plot"):
        assert written[key].stat().st_size > 200, key
    assert written["events"].read_text().startswith("time_s,from,to,reason")  # no recovery needed here
    summary = json.loads(written["metrics"].read_text())
    assert summary["success"] and summary["planner"] == "risk-aware" and summary["steps"] == len(result.steps["time_s"])


def test_dead_end_climbs_the_ladder_backs_out_and_goes_home():
    sc = recovery_scenario("dead-end")
    result = drive(world=sc.world(), start=sc.start, yaw=sc.yaw, goal=sc.goal, home=sc.home, seed=0, time_limit_s=240)
    used = _behaviours(result)
    for behaviour in sc.expect:
        assert behaviour in used, (behaviour, used)
    # In the order of the ladder: clear, rotate, raise, back out, then home.
    first = [used.index(b) for b in ("clear_map", "rotate", "raise_thresholds", "back_out", "home")]
    assert first == sorted(first)
    assert result.metrics["failure"] == "returned_home" and result.metrics["collisions"] == 0
    assert np.linalg.norm(result.steps["position"][-1, :2] - sc.home) < 1.0
    assert any("giving up the goal" in e["reason"] for e in result.events)
    raised = [e for e in result.events if e["to"] == "raise_thresholds"]
    assert raised[-1]["r_inst"] == pytest.approx(0.9) and raised[-1]["r_total"] == pytest.approx(0.95)


def test_risky_slope_is_climbed_once_the_thresholds_are_raised():
    sc = recovery_scenario("risky-slope")
    result = drive(world=sc.world(), start=sc.start, yaw=sc.yaw, goal=sc.goal, home=sc.home, seed=0, time_limit_s=90,
                   navigator_config=sc.navigator_config)
    m = result.metrics
    assert m["success"], (m["failure"], result.events[-4:])
    assert m["collisions"] == 0 and m["failure"] is None
    raised = [e for e in result.events if e["to"] == "raise_thresholds"]
    assert raised, _behaviours(result)
    # The ramp's tilt risk (~0.63) is above the nominal R_inst = 0.6: it was climbed only
    # after a raise, on the plateau 0.5 m up, at the ramp's tilt.
    assert raised[0]["r_inst"] > 0.6 and "no path within the risk budget" in raised[0]["reason"]
    climbing = result.steps["position"][:, 0] > 11.5
    assert result.steps["time_s"][climbing][0] > raised[0]["time_s"]
    assert result.steps["position"][-1, 2] == pytest.approx(0.5, abs=0.02)
    assert 17.0 < m["max_tilt_deg"] < 25.0


def test_blocked_return_stops_safely_after_the_ladder_ran_twice():
    sc = recovery_scenario("blocked-return")
    result = drive(world=sc.world(), start=sc.start, yaw=sc.yaw, goal=sc.goal, home=sc.home, seed=0, time_limit_s=360)
    used = _behaviours(result)
    assert result.metrics["failure"] == "gave_up", (result.metrics["failure"], used[-6:])
    assert result.metrics["collisions"] == 0 and used[-1] == "failed"
    # The whole ladder, back-out included, on the way to the goal and again on the way home
    # (there it may run more than once: a ladder starts again when the robot gets closer to home).
    events = [e for e in result.events if e["from"] != e["to"] or "giving up" in e["reason"]]
    gave_up = next(i for i, e in enumerate(events) if "giving up the goal" in e["reason"])
    assert any(e["to"] == "back_out" for e in events[:gave_up])
    assert any(e["to"] == "back_out" for e in events[gave_up:])
    assert any("every behaviour tried on the way home" in e["reason"] for e in result.events)


def test_recovery_scenarios_are_valid_worlds():
    for name in RECOVERY_SCENARIOS:
        sc = recovery_scenario(name)
        world = sc.world()
        assert world.ground_height(*sc.start) is not None and world.ground_height(*sc.goal) is not None
    with pytest.raises(InputError, match="`name`"):
        recovery_scenario("cave-in")


def test_navigator_bad_inputs_name_the_argument():
    with pytest.raises(InputError, match="`goal`"):
        subterra.Navigator(goal=(np.nan, 1.0))
    with pytest.raises(ConfigError, match="nope"):
        subterra.Navigator(goal=(1.0, 1.0), config={"navigator": {"nope": 1}})
    with pytest.raises(ConfigError, match="navigator.replan_period_s"):
        subterra.Navigator(goal=(1.0, 1.0), config={"navigator": {"replan_period_s": -1.0}})
    nav = subterra.Navigator(goal=(5.0, 0.0))
    with pytest.raises(InputError, match="world_from_body"):
        nav.step(None, stamp=0.0, world_from_body=np.full((4, 4), np.nan))
    with pytest.raises(InputError, match="points"):
        nav.step(np.zeros((0, 3), np.float32), stamp=0.0, world_from_body=np.eye(4))
    # Before any scan: stop and wait.
    out = nav.step(None, stamp=0.0, world_from_body=np.eye(4))
    assert out.command == (0.0, 0.0) and nav.risk_map is None
    with pytest.raises(InputError, match="planner"):
        drive("mine", planner="dijkstra")
    with pytest.raises(InputError, match="terrain.ground"):
        drive("mine", navigator_config={"terrain": {"ground": 3}})
    with pytest.raises(ConfigError, match="unseen_rise_min_length_m"):
        drive("mine", navigator_config={"terrain": {"ground": {"unseen_rise_min_length_m": -2.0}}})


def _ground_scan(x_range, y_range, *, box=None, spacing=0.05, sensor_height=0.7):
    """Points in a level sensor's frame: a flat floor ``sensor_height`` below over the given
    ranges [m], plus the faces of ``box`` ``(x0, x1, y0, y1, height)`` standing on it."""
    xs, ys = np.meshgrid(np.arange(*x_range, spacing), np.arange(*y_range, spacing))
    pts = [np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, -sensor_height)], axis=1)]
    if box is not None:
        x0, x1, y0, y1, h = box
        by, bz = np.meshgrid(np.arange(y0, y1, spacing / 2), np.arange(0.0, h, spacing / 2))
        pts.append(np.stack([np.full(by.size, x0), by.ravel(), bz.ravel() - sensor_height], axis=1))
        bx, by = np.meshgrid(np.arange(x0, x1, spacing / 2), np.arange(y0, y1, spacing / 2))
        pts.append(np.stack([bx.ravel(), by.ravel(), np.full(bx.size, h - sensor_height)], axis=1))
    return np.concatenate(pts).astype(np.float32)


def test_turn_room_price_keeps_the_plan_off_a_wall_where_there_is_room():
    from subterra.terrain import translation

    mount = translation(z=0.7)
    # A wall 0.45 m beside the straight line to the goal: the robot fits there (inscribed
    # radius 0.335 m) but could not turn in place (circumscribed 0.60 m).
    scan = _ground_scan((0.5, 9.0), (-3.0, 3.0), box=(1.5, 6.5, 0.45, 0.85, 0.5))
    paths = {}
    for price in (0.0, 1.0):
        nav = subterra.Navigator(goal=(8.0, 0.0), config={"navigator": {"turn_room_price": price}})
        assert nav.config.to_dict()["navigator"]["turn_room_price"] == price
        out = nav.step(scan, stamp=0.0, world_from_body=np.eye(4), body_from_sensor=mount)
        path = np.asarray(out.path_world)
        assert len(path) > 10, price
        paths[price] = path[(path[:, 0] > 2.5) & (path[:, 0] < 5.5)]
    # Without the price the plan runs straight past the wall; with it, it keeps ~0.6 m off.
    assert np.abs(paths[0.0][:, 1]).max() < 0.06
    assert (0.45 - paths[1.0][:, 1]).min() > 0.5
    # Off by default; out of range is an error naming the field.
    assert subterra.Navigator(goal=(8.0, 0.0)).config.to_dict()["navigator"]["turn_room_price"] == 0.0
    for bad in (-0.1, float("nan"), 1e3):
        with pytest.raises(ConfigError, match="navigator.turn_room_price"):
            subterra.Navigator(goal=(8.0, 0.0), config={"navigator": {"turn_room_price": bad}})


@pytest.mark.parametrize("memory", [True, False])
def test_hazard_memory_keeps_a_lethal_box_that_left_the_fused_window(memory):
    from subterra.terrain import translation

    mount = translation(z=0.7)
    nav = subterra.Navigator(goal=(8.0, 0.0), config={"navigator": {"hazard_memory": memory}})
    box = (3.0, 3.4, -0.2, 0.2, 0.5)
    nav.step(_ground_scan((0.5, 8.0), (-3.0, 3.0), box=box), stamp=0.0, world_from_body=np.eye(4), body_from_sensor=mount)
    rm = nav.risk_map
    grid = nav.plan_grid
    assert grid.shape == rm.layer("risk").shape and grid.dtype == np.float32
    ix, iy = rm.cell_of(3.2, 0.0)
    assert grid[iy, ix] >= 0.9 and rm.layer("risk")[iy, ix] >= 0.9
    assert (nav.remembered_hazards > 0) == memory
    # 5 s later only the far floor is in view: the box has left the 2 s window.
    nav.step(_ground_scan((6.0, 8.0), (-3.0, 3.0)), stamp=5.0, world_from_body=np.eye(4), body_from_sensor=mount)
    rm = nav.risk_map
    assert rm.layer("observed")[iy, ix] == 0.0
    if memory:
        assert nav.plan_grid[iy, ix] >= 0.9
    else:
        assert np.isnan(nav.plan_grid[iy, ix])


def test_a_stale_lidar_or_lost_odometry_stops_the_robot_with_the_reason():
    from subterra.terrain import translation

    mount = translation(z=0.7)
    nav = subterra.Navigator(goal=(6.0, 0.0))
    assert nav.config.to_dict()["navigator"]["scan_timeout_s"] == 0.5
    floor = _ground_scan((0.5, 8.0), (-3.0, 3.0))
    out = nav.step(floor, stamp=0.0, world_from_body=np.eye(4), body_from_sensor=mount)
    moving = [nav.step(floor if k % 2 else None, stamp=0.1 * k, world_from_body=np.eye(4), body_from_sensor=mount)
              for k in range(1, 8)]
    assert any(o.command[0] > 0 for o in moving), "a flat floor: it drives"
    assert all(o.safety is None or not o.safety.startswith("stale") for o in moving)
    # The lidar stops publishing: the robot drives on the last map for scan_timeout_s, then stops.
    last = 0.7
    outs = [(t, nav.step(None, stamp=t, world_from_body=np.eye(4), body_from_sensor=mount)) for t in np.arange(0.8, 2.0, 0.1)]
    for t, o in outs:
        if t - last > 0.5 + 1e-9:
            assert o.command == (0.0, 0.0) and o.safety.startswith("stale scan"), (t, o.command, o.safety)
    # Scans again: it goes on.
    out = nav.step(floor, stamp=2.0, world_from_body=np.eye(4), body_from_sensor=mount)
    assert out.safety is None or not out.safety.startswith("stale")
    # No usable odometry (confidence 0): it stops, with the reason.
    out = nav.step(floor, stamp=2.1, world_from_body=np.eye(4), body_from_sensor=mount, confidence=0.0)
    assert out.command == (0.0, 0.0) and out.safety == "no odometry: confidence 0"
    with pytest.raises(ConfigError, match="scan_timeout_s"):
        subterra.Navigator(goal=(6.0, 0.0), config={"navigator": {"scan_timeout_s": 0.0}})


def test_drive_batch_gives_every_drive_the_navigator_config(tmp_path, capsys):
    from subterra.cli import main
    from subterra.drive.batch import drive_batch

    def batch(config):
        return drive_batch("mine", [0], planners=("risk-aware",), time_limit_s=3.0, keep_records=False, progress=False,
                           workers=1, navigator_config=config)

    slow_config = {"tracker": {"limits": {"max_speed_m_s": 0.2}, "tracking": {"desired_speed_m_s": 0.2}}}
    default, slow = batch(None), batch(slow_config)
    assert slow.settings["navigator_config"] == slow_config
    # The setting reached the drive: at 0.2 m/s it covers less ground in the same 3 s.
    assert slow.rows[0]["path_length_m"] < default.rows[0]["path_length_m"] - 0.2
    # A bad field fails before any drive, naming it; so does a bad --config file.
    with pytest.raises(ConfigError, match="navigator.turn_room_price"):
        batch({"navigator": {"turn_room_price": -1.0}})
    bad = tmp_path / "nav.toml"
    bad.write_text("[navigator\n")
    assert main(["drive-batch", "--seeds", "1", "--config", str(bad), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "argument --config" in err and "Traceback" not in err


def test_navigator_set_goal_keeps_the_map_and_plans_to_the_new_goal():
    """Navigator.set_goal: the next step plans to the new goal over the map it has (the
    risk map's cells stay observed), the recovery ladder starts again; a goal that is not
    two finite numbers is an InputError naming `goal` and changes nothing."""
    import numpy as np

    from subterra import Navigator
    from subterra.errors import InputError

    r, a = np.meshgrid(np.arange(1.0, 10.0, 0.1), np.radians(np.arange(0.0, 360.0, 1.0)))
    scan = np.stack([r * np.cos(a), r * np.sin(a), np.full_like(r, -0.7)], -1).reshape(-1, 3).astype(np.float32)
    mount = np.eye(4)
    mount[2, 3] = 0.7
    nav = Navigator(goal=[4.0, 0.0])
    out = nav.step(scan, stamp=0.0, world_from_body=np.eye(4), body_from_sensor=mount)
    assert out.path_world[-1][0] > 3.0
    observed = int((nav.risk_map.layer("observed") > 0).sum())
    with pytest.raises(InputError, match="goal"):
        nav.set_goal([float("nan"), 1.0])
    assert nav.goal == (4.0, 0.0)
    nav.set_goal([0.0, -4.0])
    assert nav.goal == (0.0, -4.0) and nav.transitions == []
    out = nav.step(None, stamp=0.1, world_from_body=np.eye(4), body_from_sensor=mount)
    end = np.asarray(out.path_world)[-1]
    assert abs(end[0]) < 0.5 and end[1] < -3.0, out.path_world
    assert int((nav.risk_map.layer("observed") > 0).sum()) == observed
