"""HeRO, the odometry multiplexer, from Python: the health checks on hand-made streams, the
continuous pose through a switch, the committed defaults and bad input."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import tomllib

import subterra
from subterra.errors import ConfigError, InputError

ROOT = Path(__file__).resolve().parents[2]


def pose(x: float, y: float, yaw: float = 0.0) -> np.ndarray:
    m = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:2, 3] = [x, y]
    return m


# Each source's own world frame: where its estimator started.
FRAMES = {"vio": pose(0.0, 0.0), "lidar": pose(4.0, -1.0, 0.8), "wheels": pose(-2.0, 3.0, -2.0)}


def drive(mux: subterra.OdometryMux, seconds: float, tweak=lambda name, t, p: p):
    """The robot drives along +x at 1 m/s; each source reports it at 20 Hz in its frame."""
    outputs = []
    for i in range(round(seconds / 0.05)):
        t = i * 0.05 + 1e-6
        for name in mux.sources:
            p = tweak(name, t, FRAMES[name] @ pose(t, 0.0))
            if p is not None:
                mux.push(name, t, p, twist=[1.0, 0, 0, 0, 0, 0])
        outputs.append(mux.update(t))
    return outputs


def off_truth(outputs) -> float:
    """Largest distance of an output from the truth at its stamp (vio's frame is the mux's)."""
    return max(np.linalg.norm(o.world_from_body[:3, 3] - [o.stamp, 0, 0]) for o in outputs if o.world_from_body is not None)


def test_a_jumping_source_is_left_without_a_jump_in_the_pose():
    mux = subterra.OdometryMux([("vio", 20), ("lidar", 20), ("wheels", 20)])
    # vio relocalises at 2 s: 1.5 m sideways from then on.
    out = drive(mux, 6.0, lambda n, t, p: pose(0, 1.5) @ p if n == "vio" and t >= 2.0 else p)
    assert out[39].source == "vio" and out[40].source == "lidar"
    events = out[40].events
    assert {e["event"] for e in events} >= {"unhealthy", "switch"}
    jump = next(e for e in events if e["event"] == "unhealthy")
    assert jump["source"] == "vio" and jump["reason"].startswith("jump: 1.500 m and 0.0° off the step its twist predicts")
    assert out[40].faults["vio"].startswith("jump")
    assert out[-1].source == "vio"  # back after recover_s, re-anchored
    assert off_truth(out) < 1e-6


def test_a_drifting_source_is_outvoted_and_two_alone_are_a_dispute():
    mux = subterra.OdometryMux({"vio": 20, "lidar": 20, "wheels": 20})
    out = drive(mux, 8.0, lambda n, t, p: pose(0, 0.3 * (t - 3.0)) @ p if n == "vio" and t > 3.0 else p)
    flagged = next(i for i, o in enumerate(out) if (o.faults["vio"] or "").startswith("inconsistent"))
    assert 3.0 < flagged * 0.05 < 5.0 and out[flagged].source == "lidar"
    pair = subterra.OdometryMux([("vio", 20), ("wheels", 20)])
    out = drive(pair, 6.0, lambda n, t, p: pose(0, 0.4 * (t - 2.0)) @ p if n == "wheels" and t > 2.0 else p)
    assert out[-1].source == "vio" and out[-1].confidence == pytest.approx(0.5)
    assert any(e["event"] == "dispute" for o in out for e in o.events)


def test_every_source_lost_holds_the_pose_at_confidence_zero():
    mux = subterra.OdometryMux([("vio", 20), ("lidar", 20)])
    out = drive(mux, 6.0, lambda n, t, p: None if 2.0 <= t < 3.0 else p)
    assert out[50].source is None and out[50].confidence == 0.0
    np.testing.assert_array_equal(out[50].world_from_body, out[39].world_from_body)
    assert out[-1].source == "vio" and off_truth(out) < 1e-6


def test_the_covariance_bound_and_the_confidence():
    mux = subterra.OdometryMux([("vio", 10)])
    cov = np.zeros((6, 6))
    cov[0, 0] = 0.25**2
    mux.push("vio", 0.0, np.eye(4), covariance=cov)
    assert mux.update(0.0).confidence == pytest.approx(1 - 0.5**2)
    cov[1, 1] = 0.7**2
    mux.push("vio", 0.1, np.eye(4), covariance=cov)
    out = mux.update(0.1)
    assert out.source is None and out.faults["vio"].startswith("covariance: position std 0.700")


def test_the_committed_defaults_are_the_defaults():
    committed = tomllib.loads((ROOT / "configs" / "hero.toml").read_text(encoding="utf-8"))
    assert committed == subterra.HeroConfig().to_dict()
    mux = subterra.OdometryMux([("vio", 10)], config={"recover_s": 0.5})
    assert mux.config.to_dict()["recover_s"] == 0.5 and mux.config.to_dict()["jump_m"] == committed["jump_m"]


def test_bad_input_names_the_argument():
    with pytest.raises(InputError, match="sources"):
        subterra.OdometryMux([])
    with pytest.raises(InputError, match="sources"):
        subterra.OdometryMux("vio")
    with pytest.raises(InputError, match="twice"):
        subterra.OdometryMux([("a", 10), ("a", 10)])
    with pytest.raises(InputError, match="rate_hz"):
        subterra.OdometryMux([("a", -1)])
    with pytest.raises(ConfigError, match="recover_s"):
        subterra.OdometryMux([("a", 10)], config={"recover_s": -1})
    with pytest.raises(ConfigError, match="nope"):
        subterra.OdometryMux([("a", 10)], config={"nope": 1})
    mux = subterra.OdometryMux([("vio", 10), ("lidar", 10)])
    mux.push("vio", 1.0, np.eye(4))
    with pytest.raises(InputError, match="stamp"):
        mux.push("vio", 1.0, np.eye(4))
    with pytest.raises(InputError, match="vio, lidar"):
        mux.push("gps", 2.0, np.eye(4))
    with pytest.raises(InputError, match="world_from_body"):
        mux.push("lidar", 2.0, np.eye(3))
    with pytest.raises(InputError, match="world_from_body"):
        mux.push("lidar", 2.0, np.diag([2.0, 1, 1, 1]))
    with pytest.raises(InputError, match="covariance"):
        mux.push("lidar", 2.0, np.eye(4), covariance=np.zeros(5))
    with pytest.raises(InputError, match="covariance"):
        mux.push("lidar", 2.0, np.eye(4), covariance=np.full((6, 6), np.nan))
    with pytest.raises(InputError, match="twist"):
        mux.push("lidar", 2.0, np.eye(4), twist=[1, 2, 3])
    with pytest.raises(InputError, match="now"):
        mux.update(float("nan"))
    mux.update(3.0)
    with pytest.raises(InputError, match="now"):
        mux.update(2.0)


def test_the_picture_of_a_switch(tmp_path):
    from subterra.viz.hero import plot_odometry_mux

    mux = subterra.OdometryMux([("vio", 20), ("lidar", 20)])
    out = drive(mux, 5.0, lambda n, t, p: pose(0, 1.5) @ p if n == "vio" and t >= 2.0 else p)
    times = [o.stamp for o in out]
    truth = np.array([[t, 0.0] for t in times])
    path = plot_odometry_mux(times, truth, {"vio": truth, "lidar": truth}, np.array([o.world_from_body[:2, 3] for o in out]),
                             [o.source for o in out], [o.confidence for o in out], [e for o in out for e in o.events],
                             tmp_path / "mux.png")
    assert Path(path).stat().st_size > 10_000
