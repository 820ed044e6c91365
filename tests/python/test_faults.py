"""Fault injection (subterra.sim.faults), the sensor watchdog, and the stack's response to
each fault in closed loop: the drone hovers without depth or odometry, the ground robot stops
without scans or odometry, a jumping odometry source is switched away from."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from worlds import EASY_ROOM

from subterra.errors import ConfigError, InputError
from subterra.sim.faults import FAULT_NAMES, FaultInjector, load_faults_config, parse_faults
from subterra.watchdog import SensorWatchdog


def test_fault_names_parse_and_bad_ones_are_named():
    assert parse_faults("all") == list(FAULT_NAMES)
    assert parse_faults("frozen, blinded,frozen") == ["frozen", "blinded"]
    assert parse_faults(None) == [] and parse_faults("") == []
    with pytest.raises(InputError, match="unknown fault 'smoke'"):
        parse_faults("frozen,smoke")
    with pytest.raises(ConfigError, match="faults.frozen.sigma_m"):
        FaultInjector(["frozen"], config={"frozen": {"sigma_m": 1.0}})
    with pytest.raises(ConfigError, match="faults.frame-drop.probability"):
        FaultInjector(["frame-drop"], config={"frame-drop": {"probability": 2.0}})
    with pytest.raises(ConfigError, match="faults.odom-loss.source"):
        FaultInjector(["odom-loss"], config={"odom-loss": {"source": "gps"}})


def test_windows_are_seeded_and_sensor_faults_do_what_they_say():
    a, b, c = (FaultInjector(list(FAULT_NAMES), seed=s) for s in (3, 3, 4))
    assert [w.start_s for w in a.windows] == [w.start_s for w in b.windows]
    assert [w.start_s for w in a.windows] != [w.start_s for w in c.windows]
    assert all(4.0 <= w.start_s <= 12.0 for w in a.windows)
    frame = np.arange(12, dtype=np.uint16).reshape(3, 4) + 500
    f = FaultInjector(["frozen"], seed=0, config={"frozen": {"start_s": 1.0, "duration_s": 1.0}})
    assert f.sensor(0.9, "cam", frame) is frame
    later = frame + 7
    np.testing.assert_array_equal(f.sensor(1.2, "cam", later), frame)  # the frame before, again
    assert f.sensor(2.1, "cam", later) is later
    assert [e["event"] for e in f.events] == ["fault-start", "fault-end"]
    f = FaultInjector(["blinded"], seed=0, config={"blinded": {"start_s": 0.0}})
    assert not f.sensor(0.5, "cam", frame).any()
    assert f.sensor(0.5, "lidar", np.ones((50, 3), np.float32)).shape == (0, 3)
    f = FaultInjector(["frame-burst"], seed=0, config={"frame-burst": {"start_s": 0.0}})
    assert f.sensor(0.5, "cam", frame) is None
    f = FaultInjector(["frame-drop"], seed=0, config={"frame-drop": {"start_s": 0.0, "duration_s": 100.0}})
    lost = sum(f.sensor(0.1 * k, "cam", frame) is None for k in range(400))
    assert 150 < lost < 250  # probability 0.5
    f = FaultInjector(["noise-burst"], seed=0, config={"noise-burst": {"start_s": 0.0}})
    depth = np.full((40, 40), 2000, np.uint16)
    noisy = f.sensor(0.5, "cam", depth)
    kept = noisy[noisy > 0].astype(float)
    assert 0.05 < (noisy == 0).mean() < 0.15 and 30 < kept.std() < 70  # sigma 50 mm, 10 % dropout


def test_odometry_sources_and_their_faults():
    truth = np.eye(4)
    f = FaultInjector(["odom-jump", "odom-loss-all"], seed=0,
                      config={"odom-jump": {"start_s": 1.0}, "odom-loss-all": {"start_s": 3.0, "duration_s": 1.0}})
    names = lambda t: [n for n, _ in f.odometry(t, truth, truth)]  # noqa: E731
    assert names(0.0) == ["vio", "lidar", "wheels"]
    vio = dict(f.odometry(1.5, truth, truth))["vio"]
    assert np.linalg.norm(vio[:3, 3]) == pytest.approx(1.0)  # jumped 1 m
    assert names(3.5) == []
    assert names(4.5) == ["vio", "lidar", "wheels"]


def _yawed(x: float, y: float, yaw: float) -> np.ndarray:
    m = np.eye(4)
    m[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    m[:2, 3] = [x, y]
    return m


def test_a_drift_builds_up_sideways_and_stays_fixed_in_the_world_after_its_window():
    f = FaultInjector(["odom-drift"], seed=0, config={"odom-drift": {"start_s": 1.0, "duration_s": 2.0, "rate_m_s": 0.2}})
    offset = lambda t, pose: dict(f.odometry(t, pose, pose))["vio"][:3, 3] - pose[:3, 3]  # noqa: E731
    for k in range(11):  # heading +x: the drift goes to +y (the body's left)
        t = k * 0.1
        assert offset(t, _yawed(t, 0.0, 0.0)) == pytest.approx([0.0, 0.0, 0.0], abs=1e-12)
    for k in range(11, 31):
        t = k * 0.1
        got = offset(t, _yawed(t, 0.0, 0.0))
    assert got == pytest.approx([0.0, 0.4, 0.0], abs=1e-9)  # 2 s at 0.2 m/s
    # After the window the robot turns a quarter: the error stays where it was in the world.
    for k in range(31, 40):
        t = k * 0.1
        assert offset(t, _yawed(3.0, 0.0, (k - 30) * np.pi / 18)) == pytest.approx([0.0, 0.4, 0.0], abs=1e-9)


def test_the_mux_takes_a_drift_back_out_when_the_vote_catches_it():
    from subterra import OdometryMux

    f = FaultInjector(["odom-drift"], seed=0, config={"odom-drift": {"start_s": 2.0, "duration_s": 6.0, "rate_m_s": 0.3}})
    mux = OdometryMux([("vio", 10.0), ("lidar", 10.0), ("wheels", 10.0)])
    caught = None
    for k in range(80):
        t = k * 0.1
        truth = _yawed(0.8 * t, 0.0, 0.0)
        for name, pose in f.odometry(t, truth, truth):
            mux.push(name, t, pose)
        out = mux.update(t)
        for e in out.events:
            if e["event"] == "switch" and e["source"] == "lidar":
                caught = (t, e["reason"])
    assert caught is not None and 2.0 < caught[0] < 5.0
    assert "taken back" in caught[1]
    # vio would be 0.3 m/s x (8 - 2) s = 1.8 m off by now; the output follows the truth.
    end = out.world_from_body[:3, 3]
    assert abs(end[1]) < 0.1 and end[0] == pytest.approx(0.8 * 7.9, abs=0.15)


def test_the_watchdog_tells_lost_frozen_and_blind_frames_and_scales_the_command():
    w = SensorWatchdog(timeout_s=0.5)
    frame = np.random.default_rng(0).integers(1, 5000, (48, 64)).astype(np.uint16)
    assert w.check(0.0, frame) == (True, 0.0, None)
    fresh, age, reason = w.check(0.1, frame.copy())
    assert not fresh and reason.startswith("frozen") and age == pytest.approx(0.1)
    assert w.check(0.2, None)[2].startswith("lost")
    assert w.check(0.3, np.zeros_like(frame))[2].startswith("blind")
    assert w.check(0.35, np.zeros_like(frame))[2].startswith("blind"), "a blank frame twice is blind, not frozen"
    assert w.scale(0.25) == pytest.approx(0.5) and w.scale(0.6) == 0.0
    assert w.check(0.7, frame + 1)[0] and w.scale() == 1.0
    assert SensorWatchdog().check(0.0, np.zeros((10, 3)))[2] == "blind frames"
    with pytest.raises(InputError, match="timeout_s"):
        SensorWatchdog(timeout_s=0)


def test_a_faults_config_file(tmp_path):
    p = tmp_path / "faults.toml"
    p.write_text('[faults.frozen]\nstart_s = 2.0\nduration_s = 1.5\n', encoding="utf-8")
    assert load_faults_config(p) == {"frozen": {"start_s": 2.0, "duration_s": 1.5}}
    p.write_text("[faults]\nfrozen = 3\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="faults"):
        load_faults_config(p)


def _events(path):
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def test_the_drone_hovers_without_depth_and_goes_on(tmp_path):
    from subterra.flight import fly

    r = fly("highbay", "A-B", seed=3, time_limit_s=20.0, faults="frame-burst",
            faults_config={"frame-burst": {"start_s": 3.0, "duration_s": 2.0}})
    kinds = [e["event"] for e in r.events]
    assert kinds.count("hover") == 1 and kinds.count("resume") == 1
    t = r.frames["time_s"]
    speed = np.linalg.norm(r.frames["command"][:, :3], axis=1)
    hover = (t > 3.0 + 0.5 + 0.07) & (t < 5.0)
    assert hover.any() and np.all(speed[hover] == 0.0), "hovering: zero velocity commanded"
    slowing = (t > 3.05) & (t < 3.5)
    assert np.all(speed[slowing] <= speed[(t > 2.5) & (t < 3.0)].max() + 1e-9)
    assert r.metrics["collisions"] == 0 and speed[t > 5.2].max() > 0.3, "and flies on after"
    r.save(tmp_path / "run", plots=False)
    assert any(e["event"] == "fault-start" for e in _events(tmp_path / "run" / "events.csv"))


def test_the_drone_switches_odometry_on_a_jump_and_hovers_with_none():
    from subterra.flight import fly

    r = fly("highbay", "A-B", seed=3, time_limit_s=12.0, faults="odom-jump,odom-loss-all",
            faults_config={"odom-jump": {"start_s": 2.0}, "odom-loss-all": {"start_s": 6.0, "duration_s": 1.0}})
    switches = [e for e in r.events if e["event"] == "odometry-switch"]
    # vio jumps (lidar takes over), is used again after recover_s (2 s), then every source falls silent.
    assert [e["source"] for e in switches][:4] == ["vio", "lidar", "vio", None]
    assert any(e["event"] == "hover" and e["reason"] == "no odometry" for e in r.events)
    assert r.metrics["collisions"] == 0


def test_the_drone_takes_a_drift_out_of_its_pose_and_its_memory():
    from subterra.flight import fly

    r = fly("highbay", "A-B", seed=3, time_limit_s=10.0, faults="odom-drift",
            faults_config={"odom-drift": {"start_s": 1.0, "rate_m_s": 0.4}})
    switches = [e for e in r.events if e["event"] == "odometry-switch" and e["source"] == "lidar"]
    assert switches and "taken back" in switches[0]["reason"]
    assert r.metrics["collisions"] == 0



def _every_source_ahead(monkeypatch, dx_m):
    """Every odometry source the injector gives reads ``dx_m`` ahead in world x."""
    real = FaultInjector.odometry

    def ahead(self, t, vehicle_odometry, truth):
        out = []
        for name, pose in real(self, t, vehicle_odometry, truth):
            pose = pose.copy()
            pose[0, 3] += dx_m
            out.append((name, pose))
        return out

    monkeypatch.setattr(FaultInjector, "odometry", ahead)


def test_a_pose_error_every_source_shares_ends_as_odometry_error_not_a_local_minimum(monkeypatch):
    """Every source 1 m ahead of the truth (no vote can catch an error they share): the drone
    stops 1 m short of the goal, where its pose says the goal is, and the flight says so."""
    from subterra import sim
    from subterra.flight import fly

    _every_source_ahead(monkeypatch, 1.0)
    # A fault window that never opens within the flight: the injector (and the mux) run.
    r = fly(world=sim.World.from_toml(EASY_ROOM), route="S-G", seed=3, time_limit_s=40.0, faults="odom-loss-all",
            faults_config={"odom-loss-all": {"start_s": 500.0}})
    assert r.failure == "odometry_error", r.summary()
    assert abs(r.path[-1][0] - 6.0) < 0.35, r.path[-1]
    stop = [e for e in r.events if e["event"] == "stop"]
    assert len(stop) == 1 and "at the goal by its odometry" in stop[0]["reason"], stop
    assert r.metrics["collisions"] == 0


def test_the_ground_robot_stops_without_scans_and_with_no_odometry(tmp_path):
    from subterra.drive import drive

    r = drive("mine", seed=0, time_limit_s=14.0, faults="frame-burst,odom-loss-all",
              faults_config={"frame-burst": {"start_s": 4.0, "duration_s": 2.0},
                             "odom-loss-all": {"start_s": 9.0, "duration_s": 2.0}})
    t = r.steps["time_s"]
    v = r.steps["command"][:, 0]
    assert np.all(v[(t > 4.0 + 0.55) & (t < 6.0)] == 0.0), "stale scans: stopped"
    assert np.all(v[(t > 9.3) & (t < 11.0)] == 0.0), "no odometry: stopped"
    reasons = [e["reason"] for e in r.events]
    assert any(x.startswith("safety: stale scan") for x in reasons)
    assert any(x.startswith("safety: no odometry") for x in reasons)
    assert any(x.startswith("fault-start") for x in reasons)
    assert r.metrics["collisions"] == 0 and r.metrics["failure"] not in ("fall", "rollover", "collision")
    r.save(tmp_path / "d", plots=False)


def test_the_ground_robot_at_the_goal_by_a_shared_pose_error_stops_as_odometry_error(monkeypatch):
    """Every source 2 m ahead of the truth: the navigator reaches the goal by its pose 2 m
    short of it (the goal region is 1 m across); the drive ends there and says why."""
    from subterra.drive import drive

    _every_source_ahead(monkeypatch, 2.0)
    r = drive("rough", seed=0, time_limit_s=40.0, faults="odom-loss-all", faults_config={"odom-loss-all": {"start_s": 500.0}})
    assert r.metrics["failure"] == "odometry_error", r.metrics
    stop = [e for e in r.events if e["reason"].startswith("stop: at the goal by its odometry")]
    assert len(stop) == 1, r.events
    assert 1.5 < float(np.linalg.norm(r.steps["position"][-1][:2] - r.goal[:2])) < 2.6
