"""APF-PF perception and commands through the public Python API (``subterra``).

Behaviour, not implementation: the belief is a distribution, counts are the valid in-range
pixels, seeded runs repeat bit for bit, the particle filter agrees with the exact filter,
obstacles are found where they are and push the robot away, empty and noisy frames read
as free, several cameras add up, bad input raises a ``subterra.errors`` class naming the
argument, and real RealSense frames put the belief on real points.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from conftest import config_dict, make_box_frame
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import subterra
from subterra import errors

MODES = ["particle", "histogram"]
# The standard box of make_box_frame: rows 140..339, cols 220..419 fully cover the 50-px
# blocks i = 5..7 (columns 250..399) and j = 3..5 (rows 150..299) of the 640x480 image.
BOX_FULL_I = range(5, 8)
BOX_FULL_J = range(3, 6)


def config(mode: str = "particle", preset: str = "flight", **sections) -> subterra.PerceptionConfig:
    sections.setdefault("filter", {})
    sections["filter"] = {"mode": mode, **sections["filter"]}
    return subterra.PerceptionConfig.from_json(json.dumps(config_dict(preset, **sections)))


def perception(camera, mode: str = "particle", seed: int = 0, **kwargs) -> subterra.DepthPerception:
    return subterra.DepthPerception(camera, config=config(mode), seed=seed, **kwargs)


def blank(dtype=np.uint16) -> np.ndarray:
    return np.zeros((480, 640), dtype)


def noise_frame(rng: np.random.Generator) -> np.ndarray:
    """Every 10th pixel (row-major) a return at N(0.6, 0.2) m clipped positive, the rest none."""
    frame = np.zeros((480, 640), np.float32)
    z = np.clip(rng.normal(0.6, 0.2, frame.size // 10), 1e-3, None)
    frame.reshape(-1)[::10] = z
    return frame


def depth_marginal(belief: np.ndarray, grid_shape) -> np.ndarray:
    n_w, n_h, n_d = grid_shape
    return belief[:-1].reshape(n_h, n_w, n_d).sum(axis=(0, 1))


# --------------------------------------------------------------------------- the belief


@pytest.mark.parametrize("mode", MODES)
def test_belief_is_a_distribution(d435, mode):
    p = perception(d435, mode)
    assert p.belief().shape == (p.state_count,)
    assert p.belief().sum() == pytest.approx(1.0, abs=1e-12)  # before the first frame: spread evenly
    nan = np.full((480, 640), np.nan, np.float32)
    noise = noise_frame(np.random.default_rng(1))
    frames = [make_box_frame(0.8), blank(), make_box_frame(0.4, cols=slice(0, 200)), nan, noise]
    for frame in frames:
        out = p.update(frame)
        b = p.belief()
        assert np.all(b >= 0) and np.all(np.isfinite(b))
        assert b.sum() == pytest.approx(1.0, abs=1e-12)
        assert out.p_free == b[-1]
        # The sparse view: ascending ids, the same values, and (nearly) all the mass.
        assert np.all(np.diff(out.belief_states.astype(np.int64)) > 0)
        np.testing.assert_array_equal(out.belief_probabilities, b[out.belief_states])
        assert out.belief_probabilities.sum() == pytest.approx(1.0, abs=1e-9)
        if out.most_probable is not None:
            assert out.most_probable.probability == b[:-1].max()
    if mode == "particle":
        # A histogram of 20000 particles.
        counts = p.belief() * 20000
        np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)


def test_in_range_pixels_equal_numpy(d435):
    p = perception(d435)
    rng = np.random.default_rng(2)
    raw = rng.integers(0, 2000, size=(480, 640)).astype(np.uint16)
    raw[rng.random(raw.shape) < 0.3] = 0
    out = p.update(raw)
    assert out.in_range_pixels == np.count_nonzero((raw >= 100) & (raw < 1200))  # [0.1, 1.2) m in mm
    assert out.valid_pixels == np.count_nonzero(raw)
    assert out.in_range_pixels == p.counts().sum()
    assert out.closest_depth_m == pytest.approx(raw[raw > 0].min() / 1000, rel=1e-12)
    # Half-millimetre units: the same pixels, twice the raw values.
    out2 = p.update(raw * 2, scale=0.0005)
    assert out2.in_range_pixels == out.in_range_pixels
    metres = (raw / 1000).astype(np.float32)
    no_return = np.array([0, np.nan, np.inf, -np.inf, -1.0], np.float32)
    metres[raw == 0] = rng.choice(no_return, size=np.count_nonzero(raw == 0))
    out3 = p.update(metres)
    z = metres.astype(np.float64)
    with np.errstate(invalid="ignore"):
        assert out3.in_range_pixels == np.count_nonzero(np.isfinite(z) & (z >= 0.1) & (z < 1.2))
        assert out3.valid_pixels == np.count_nonzero(np.isfinite(z) & (z > 0))


_SMALL = subterra.PinholeCamera(fx=40.0, fy=40.0, cx=18.0, cy=11.0, width=37, height=23)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    raw=hnp.arrays(np.uint16, (23, 37), elements=st.integers(0, 65535) | st.integers(90, 1210) | st.just(0)),
    scale=st.sampled_from([0.001, 0.0005, 0.0001]),
)
def test_counts_equal_valid_in_range_pixels_property(raw, scale):
    p = subterra.DepthPerception(_SMALL, config=config("histogram", grid={"block_width_px": 8, "block_height_px": 5}))
    out = p.update(raw, scale=scale)
    z = raw.astype(np.float64) * scale
    k = np.floor((z - 0.1) / 0.1 + 1e-9)
    expected = (raw > 0) & (k >= 0) & (k < 11) & (z < 1.2)
    assert out.in_range_pixels == np.count_nonzero(expected) == p.counts().sum()
    assert out.valid_pixels == np.count_nonzero(raw)
    assert p.counts().shape == (5, 5, 11)
    # Each counted pixel lands in its own block and bin.
    v, u = np.nonzero(expected)
    want = np.zeros((5, 5, 11), np.int64)
    np.add.at(want, (v // 5, u // 8, k[v, u].astype(np.int64)), 1)
    np.testing.assert_array_equal(p.counts(), want)


def _run(p, frames):
    bits = []
    for frame in frames:
        p.update(frame)
        bits.append(p.belief().tobytes())
    return bits


def test_same_seed_same_bits_different_seed_different(d435):
    rng = np.random.default_rng(4)
    frames = [
        make_box_frame(0.8),
        noise_frame(rng),
        make_box_frame(0.5, cols=slice(0, 200)),
        blank(),
        make_box_frame(1.0),
    ]
    a = _run(perception(d435, seed=12), frames)
    b = _run(perception(d435, seed=12), frames)
    c = _run(perception(d435, seed=13), frames)
    assert a == b
    assert sum(x != y for x, y in zip(a, c)) >= 3
    # The histogram filter has no randomness: the seed does not matter.
    assert _run(perception(d435, "histogram", seed=1), frames) == _run(perception(d435, "histogram", seed=2), frames)


# --------------------------------------------------------------------------- particle vs exact


def test_particle_agrees_with_histogram_on_flight(d435):
    """Flight preset: P(free) and the depth-bin marginal of the voxel belief agree frame by frame."""
    h = perception(d435, "histogram")
    p = perception(d435, "particle", seed=5)
    frames = [
        make_box_frame(0.8),
        make_box_frame(0.8),
        make_box_frame(0.5, cols=slice(0, 150)),
        make_box_frame(1.0),
        blank(),
        blank(),
        make_box_frame(0.3, rows=slice(300, 480)),
    ]
    for n, frame in enumerate(frames):
        ho, po = h.update(frame), p.update(frame)
        assert abs(ho.p_free - po.p_free) < 0.02, n
        dh, dp = depth_marginal(h.belief(), h.grid_shape), depth_marginal(p.belief(), p.grid_shape)
        assert np.abs(dh - dp).max() < 0.02, n
        if ho.p_free < 0.5:
            assert ho.most_probable.depth_m == po.most_probable.depth_m, n
        else:  # free: every particle sits in the free state, no voxel has belief
            assert po.most_probable is None or po.most_probable.probability < 0.01, n
        # The net repulsion: the particle filter's voxels within the box scatter (~20
        # distinct particles survive a frame on this sharp model), so a loose bound (worst of
        # 30 seeds: 0.03).
        rh, rp = ho.repulsive_body, po.repulsive_body
        assert np.linalg.norm(rh - rp) <= 0.08 * np.linalg.norm(rh) + 0.02, n


@pytest.mark.parametrize(("q_min", "resampling"), [(0.05, "systematic"), (0.0, "multinomial"), (0.3, "systematic")])
def test_particle_agrees_with_histogram_on_a_soft_model(q_min, resampling):
    """A 200x150 camera (4x3x11 voxels) with broad noise, so the free state keeps ~0.2 on
    empty frames: the whole belief agrees, whatever the free-proposal floor q_min (the
    importance weights T/q keep it unbiased). Tolerances: ~2x the worst of 40 seeds."""
    camera = subterra.PinholeCamera(fx=150.0, fy=150.0, cx=99.5, cy=74.5, width=200, height=150)
    soft = {"transition": {"sigma_z_m": 1.0}, "observation": {"sigma_o_points": 3000.0, "sigma_n_points": 100.0}}
    h = subterra.DepthPerception(camera, config=config("histogram", **soft))
    particle = config("particle", filter={"free_proposal_min": q_min, "resampling": resampling}, **soft)
    p = subterra.DepthPerception(camera, config=particle, seed=11)
    for z in (800, 800, 500, 0, 0, 300):
        frame = np.zeros((150, 200), np.uint16)
        frame[40:110, 60:160] = z
        ho, po = h.update(frame), p.update(frame)
        hb, pb = h.belief(), p.belief()
        if z == 0:
            assert 0.1 < ho.p_free < 0.5  # the free state matters here
        assert np.abs(hb[:-1] - pb[:-1]).max() < 0.008  # hb.max() is ~0.01
        assert abs(ho.p_free - po.p_free) < (0.08 if q_min == 0 else 0.04)
        assert np.abs(depth_marginal(hb, h.grid_shape) - depth_marginal(pb, p.grid_shape)).max() < 0.025


# --------------------------------------------------------------------------- obstacles and free space


@pytest.mark.parametrize("mode", MODES)
def test_box_at_0_8_m(d435, mode):
    p = perception(d435, mode)
    for _ in range(3):
        out = p.update(make_box_frame(0.8))
    mp = out.most_probable
    i, j, k = mp.voxel
    assert k == 7 and mp.depth_m == pytest.approx(0.85)  # the 0.8-0.9 m bin
    assert i in BOX_FULL_I and j in BOX_FULL_J
    assert mp.state == p.state_of(i, j, k)
    np.testing.assert_allclose(mp.centre_camera, p.voxel_centres("camera")[mp.state], rtol=1e-12)
    np.testing.assert_allclose(mp.centre_body, p.voxel_centres("body")[mp.state], rtol=1e-12)
    assert mp.centre_body[0] == pytest.approx(0.85)  # forward camera: optical z is body x
    # All the voxel belief is in the box's bin and blocks, most of it in the fully covered ones
    # (the blocks j = 6 are 80 % covered: their count 2000 is 2.9 σ_o from full).
    b = p.belief()[:-1].reshape(10, 13, 11)
    assert b[2:7, 4:9, 7].sum() > 0.999
    assert b[3:6, 5:8, 7].sum() > 0.95
    assert out.p_free < 1e-6
    assert out.closest_depth_m == pytest.approx(0.8)
    assert out.repulsive_body[0] < -0.5  # pushed back
    assert abs(out.repulsive_body[1]) < 0.2 * abs(out.repulsive_body[0])  # a centred box barely pushes sideways


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("start", ["uniform", "after a box"])
def test_empty_frames_drive_p_free_up(d435, mode, start):
    seeds = range(5) if mode == "particle" else [0]
    for seed in seeds:
        p = perception(d435, mode, seed=seed)
        if start == "after a box":
            for _ in range(3):
                p.update(make_box_frame(0.6))
            assert p.belief()[-1] < 1e-6
        for _ in range(3):
            out = p.update(blank())
        assert out.p_free > 0.95, f"seed {seed}"
        assert out.closest_depth_m is None and out.in_range_pixels == 0
        assert np.linalg.norm(out.repulsive_body) < 0.05


@pytest.mark.parametrize("mode", MODES)
def test_all_nan_frame_is_a_frame_without_returns(d435, mode):
    p = perception(d435, mode)
    p.update(make_box_frame(0.7))
    for _ in range(3):
        out = p.update(np.full((480, 640), np.nan, np.float32))
    assert out.valid_pixels == 0 and out.closest_depth_m is None
    assert out.p_free > 0.95


@pytest.mark.parametrize("mode", MODES)
def test_sparse_noise_reads_as_free(d435, mode):
    """Every 10th pixel at N(0.6, 0.2) m: at most ~70 points per voxel of 2500 px, far from
    full (σ_o = 170) and close enough to empty for the free state (σ_n = 60)."""
    rng = np.random.default_rng(0)
    p = perception(d435, mode, seed=3)
    for _ in range(5):
        out = p.update(noise_frame(rng))
        assert out.in_range_pixels > 25000
        assert out.p_free > 0.9


def _goal_command(out, goal=(5.0, 0.0, 0.0)):
    return subterra.ApfController("flight").command(goal_body=list(goal), perception=[out])


@pytest.mark.parametrize("mode", MODES)
def test_command_turns_away_from_an_off_centre_box(d435, mode):
    clear = subterra.ApfController("flight").command([5.0, 0.0, 0.0])
    assert clear.v_x_m_s == pytest.approx(0.6) and clear.yaw_rate_rad_s == 0.0
    for cols, side in [(slice(420, 620), "right"), (slice(20, 220), "left")]:
        p = perception(d435, mode)
        for _ in range(3):
            out = p.update(make_box_frame(0.6, cols=cols))
        cmd = _goal_command(out)
        if side == "right":  # image right is body -y: pushed to +y, turn left (yaw rate > 0)
            assert out.repulsive_body[1] > 0 and cmd.yaw_rate_rad_s > 0.05
        else:
            assert out.repulsive_body[1] < 0 and cmd.yaw_rate_rad_s < -0.05
        assert out.repulsive_body[0] < 0
        assert cmd.v_x_m_s < 0.6 and not cmd.reached
        np.testing.assert_array_equal(cmd.repulsive_body, out.repulsive_body)
        np.testing.assert_allclose(cmd.attractive_body, [0.2, 0.0, 0.0])


def test_command_stops_at_the_goal(d435):
    out = perception(d435).update(make_box_frame(0.5))
    cmd = _goal_command(out, goal=(0.2, 0.1, 0.0))
    assert cmd.reached and np.all(cmd.as_array() == 0)


# Optical z -> body z, optical x -> body +y, optical y -> body -x.
UPWARD = np.array(
    [
        [0.0, -1.0, 0.0, 0.0],
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
)


@pytest.mark.parametrize("mode", MODES)
def test_two_cameras_add_their_repulsion(d435, mode):
    forward = perception(d435, mode, seed=1)
    upward = perception(d435, mode, seed=2, body_from_camera=UPWARD)
    np.testing.assert_array_equal(upward.body_from_camera, UPWARD)
    # A ceiling 0.6 m above, seen by the upward camera over its middle; a wall 0.9 m ahead.
    for _ in range(3):
        a = forward.update(make_box_frame(0.9))
        b = upward.update(make_box_frame(0.6))
    assert b.most_probable.centre_body[2] == pytest.approx(0.65)  # above the robot
    assert a.repulsive_body[0] < 0 and abs(a.repulsive_body[2]) < 0.2 * abs(a.repulsive_body[0])
    assert b.repulsive_body[2] < 0 and abs(b.repulsive_body[0]) < 0.2 * abs(b.repulsive_body[2])  # pushed down
    controller = subterra.ApfController("flight")
    goal = [5.0, 0.0, 0.0]
    both = controller.command(goal, perception=[a, b])
    np.testing.assert_allclose(both.repulsive_body, a.repulsive_body + b.repulsive_body, rtol=1e-15, atol=1e-15)
    summed = controller.command(goal, repulsive_body=a.repulsive_body + b.repulsive_body)
    np.testing.assert_allclose(both.as_array(), summed.as_array(), rtol=1e-15, atol=1e-15)
    only_forward = controller.command(goal, perception=a)
    assert both.v_z_m_s < -0.05  # the ceiling pushes down
    # Without the upward camera the vertical command is only the particle noise of a
    # centred wall: well below what the ceiling adds.
    assert abs(only_forward.v_z_m_s) < 0.5 * abs(both.v_z_m_s)
    # An extra force adds too.
    extra = controller.command(goal, perception=[a, b], repulsive_body=[0.0, 0.1, 0.0])
    np.testing.assert_allclose(extra.repulsive_body, a.repulsive_body + b.repulsive_body + [0.0, 0.1, 0.0], atol=1e-15)


# --------------------------------------------------------------------------- bad input


def _perc():
    return subterra.DepthPerception(subterra.PinholeCamera.d435(), seed=0)


def _config_json(**sections):
    return json.dumps(config_dict("flight", **sections))


NOT_A_ROTATION = np.diag([2.0, 1.0, 1.0, 1.0])
REFLECTION = np.diag([1.0, 1.0, -1.0, 1.0])

BAD_INPUT = {
    "float64 depth": (lambda: _perc().update(np.zeros((480, 640))), errors.InputError, "depth"),
    "int32 depth": (lambda: _perc().update(np.zeros((480, 640), np.int32)), errors.InputError, "depth"),
    "wrong shape": (lambda: _perc().update(np.zeros((480, 639), np.uint16)), errors.InputError, "depth"),
    "transposed shape": (lambda: _perc().update(np.zeros((640, 480), np.uint16)), errors.InputError, "depth"),
    "3-D array": (lambda: _perc().update(np.zeros((480, 640, 1), np.uint16)), errors.InputError, "depth"),
    "empty array": (lambda: _perc().update(np.zeros((0, 0), np.uint16)), errors.InputError, "depth"),
    "empty float array": (lambda: _perc().update(np.zeros((0, 0), np.float32)), errors.InputError, "depth"),
    "list": (lambda: _perc().update([[0] * 640] * 480), errors.InputError, "depth"),
    "None depth": (lambda: _perc().update(None), errors.InputError, "depth"),
    "zero scale": (lambda: _perc().update(blank(), scale=0.0), errors.InputError, "scale"),
    "negative scale": (lambda: _perc().update(blank(), scale=-0.001), errors.InputError, "scale"),
    "NaN scale": (lambda: _perc().update(blank(), scale=float("nan")), errors.InputError, "scale"),
    "scale on float32": (lambda: _perc().update(blank(np.float32), scale=0.001), errors.InputError, "scale"),
    "NaN goal": (lambda: subterra.ApfController().command([float("nan"), 0.0, 0.0]), errors.InputError, "goal_body"),
    "2-vector goal": (lambda: subterra.ApfController().command([1.0, 0.0]), errors.InputError, "goal_body"),
    "inf repulsion": (
        lambda: subterra.ApfController().command([1.0, 0.0, 0.0], repulsive_body=[np.inf, 0, 0]),
        errors.InputError,
        "repulsive_body",
    ),
    "not an output": (
        lambda: subterra.ApfController().command([1.0, 0, 0], perception=[1]),
        errors.InputError,
        "perception",
    ),
    "zero fx": (lambda: subterra.PinholeCamera(0.0, 385.0, 319.5, 239.5, 640, 480), errors.ConfigError, "fx"),
    "negative fx": (lambda: subterra.PinholeCamera(-385.0, 385.0, 319.5, 239.5, 640, 480), errors.ConfigError, "fx"),
    "NaN fy": (lambda: subterra.PinholeCamera(385.0, float("nan"), 319.5, 239.5, 640, 480), errors.ConfigError, "fy"),
    "zero width": (lambda: subterra.PinholeCamera(385.0, 385.0, 319.5, 239.5, 0, 480), errors.ConfigError, "width"),
    "negative height": (
        lambda: subterra.PinholeCamera(385.0, 385.0, 319.5, 239.5, 640, -1),
        errors.ConfigError,
        "height",
    ),
    "unknown preset": (
        lambda: subterra.DepthPerception(subterra.PinholeCamera.d435(), "hover"),
        errors.ConfigError,
        "hover",
    ),
    "unknown preset config": (lambda: subterra.PerceptionConfig.preset("hover"), errors.ConfigError, "hover"),
    "unknown preset controller": (lambda: subterra.ApfController("hover"), errors.ConfigError, "hover"),
    "negative sigma_o": (
        lambda: subterra.PerceptionConfig.from_json(_config_json(observation={"sigma_o_points": -170.0})),
        errors.ConfigError,
        "observation.sigma_o_points",
    ),
    "zero sigma_s": (
        lambda: subterra.PerceptionConfig.from_json(_config_json(transition={"sigma_s_voxels": 0.0})),
        errors.ConfigError,
        "transition.sigma_s_voxels",
    ),
    "zero particles": (
        lambda: subterra.PerceptionConfig.from_json(_config_json(filter={"particles": 0})),
        errors.ConfigError,
        "filter.particles",
    ),
    "negative particles": (
        lambda: subterra.PerceptionConfig.from_json(_config_json(filter={"particles": -5})),
        errors.ConfigError,
        "-5",
    ),
    "free_proposal_min 1": (
        lambda: subterra.PerceptionConfig.from_json(_config_json(filter={"free_proposal_min": 1.0})),
        errors.ConfigError,
        "filter.free_proposal_min",
    ),
    "unknown filter mode": (
        lambda: subterra.PerceptionConfig.from_json(_config_json(filter={"mode": "kalman"})),
        errors.ConfigError,
        "kalman",
    ),
    "bins do not divide": (
        lambda: subterra.PerceptionConfig.from_json(_config_json(grid={"depth_bin_m": 0.3})),
        errors.ConfigError,
        "grid.depth_bin_m",
    ),
    "malformed JSON": (lambda: subterra.PerceptionConfig.from_json("{"), errors.ConfigError, "parse"),
    "non-rotation body_from_camera": (
        lambda: subterra.DepthPerception(subterra.PinholeCamera.d435(), body_from_camera=NOT_A_ROTATION),
        errors.InputError,
        "body_from_camera",
    ),
    "reflection body_from_camera": (
        lambda: subterra.DepthPerception(subterra.PinholeCamera.d435(), body_from_camera=REFLECTION),
        errors.InputError,
        "body_from_camera",
    ),
    "3x3 body_from_camera": (
        lambda: subterra.DepthPerception(subterra.PinholeCamera.d435(), body_from_camera=np.eye(3)),
        errors.InputError,
        "body_from_camera",
    ),
    "NaN body_from_camera": (
        lambda: subterra.DepthPerception(subterra.PinholeCamera.d435(), body_from_camera=np.full((4, 4), np.nan)),
        errors.InputError,
        "body_from_camera",
    ),
    "negative seed": (
        lambda: subterra.DepthPerception(subterra.PinholeCamera.d435(), seed=-1),
        errors.InputError,
        "seed",
    ),
    "state out of range": (lambda: _perc().transition_row(1431), errors.InputError, "state"),
    "unknown frame": (lambda: _perc().voxel_centres("world"), errors.InputError, "frame"),
}


@pytest.mark.parametrize("case", list(BAD_INPUT))
def test_bad_input_raises_a_named_error(case):
    call, cls, named = BAD_INPUT[case]
    with pytest.raises(cls) as info:
        call()
    assert isinstance(info.value, errors.SubterraError) and isinstance(info.value, ValueError)
    assert named in str(info.value), str(info.value)


def test_perception_still_works_after_bad_input(d435):
    p = perception(d435)
    for bad in (np.zeros((480, 640)), np.zeros((0, 0), np.uint16), [[0]]):
        with pytest.raises(errors.InputError):
            p.update(bad)
    assert p.frames == 0
    out = p.update(make_box_frame(0.8))
    assert out.most_probable.voxel[2] == 7 and p.frames == 1


def test_huge_or_negative_seed_raises_a_named_error(d435):
    # Regression: the seed was taken as i64, so 2**63..2**64-1 (valid u64) gave a bare OverflowError.
    subterra.DepthPerception(d435, seed=2**64 - 1)
    for bad in (2**64, -1, 1.5, "0"):
        with pytest.raises(errors.InputError, match="seed"):
            subterra.DepthPerception(d435, seed=bad)


def test_bad_input_never_kills_the_interpreter():
    """Every bad call above in a fresh interpreter: it must exit normally (no panic, no abort)."""
    script = textwrap.dedent(
        """
        import sys
        sys.path.insert(0, sys.argv[1])
        import test_perception as t
        from subterra import errors
        for name, (call, cls, named) in t.BAD_INPUT.items():
            try:
                call()
            except errors.SubterraError:
                continue
            except BaseException as e:  # a PanicException is a BaseException
                print(f"{name}: {type(e).__name__}: {e}")
                sys.exit(3)
            print(f"{name}: no error")
            sys.exit(4)
        print("ok")
        """
    )
    here = str(Path(__file__).parent)
    done = subprocess.run([sys.executable, "-c", script, here], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip().endswith("ok"), done.stdout + done.stderr


# --------------------------------------------------------------------------- real data


def _dilate(mask: np.ndarray) -> np.ndarray:
    """3x3x3 binary dilation (within one voxel along every axis, diagonals included)."""
    padded = np.pad(mask, 1)
    out = np.zeros_like(mask)
    n0, n1, n2 = mask.shape
    for d0 in range(3):
        for d1 in range(3):
            for d2 in range(3):
                out |= padded[d0 : d0 + n0, d1 : d1 + n1, d2 : d2 + n2]
    return out


@pytest.mark.parametrize("mode", MODES)
def test_realsense_room_frames(shared_data, mode):
    import subterra.io

    root = shared_data / "realsense-d435-room"
    if not root.is_dir():
        pytest.skip(f"{root} is absent")
    camera = subterra.io.read_intrinsics(root / "cam_params_realsense.json").to_camera()
    assert (camera.width, camera.height) == (640, 480) and camera.fx == pytest.approx(617.25)
    files = sorted((root / "depth").glob("*.png"))
    assert len(files) == 10
    p = subterra.DepthPerception(camera, config=config(mode), seed=0)
    for path in files:
        image = subterra.io.read_depth(path)
        out = p.update(image.data, scale=image.scale_m_per_unit)
        counts = p.counts()
        assert out.in_range_pixels == counts.sum() > 0, path.name
        b = p.belief()
        assert b.sum() == pytest.approx(1.0, abs=1e-12)
        voxel_mass = b[:-1].sum()
        assert voxel_mass > 0.5, path.name  # a room within 1.2 m: not free
        belief = b[:-1].reshape(counts.shape)
        near_points = _dilate(counts > 0)
        assert belief[near_points].sum() >= 0.9 * voxel_mass, path.name
        # The most probable voxel holds points and is no nearer than the nearest return.
        mp = out.most_probable
        i, j, k = mp.voxel
        assert counts[j, i, k] > 0, path.name
        assert mp.depth_m >= out.closest_depth_m - 0.05, path.name
    assert p.frames == 10


@pytest.mark.parametrize(
    ("section", "field", "value"),
    [("apf", "eta", 1e308), ("grid", "depth_max_m", 1e300), ("apf", "min_distance_m", 1e-200)],
)
def test_absurd_config_values_are_named(section, field, value):
    # Regression: eta = 1e308 passed validation and made the repulsion -inf/NaN; d_max = 1e300
    # reported 2**64-1 depth bins.
    cfg = subterra.PerceptionConfig.preset("flight").to_dict()
    cfg[section][field] = value
    with pytest.raises(errors.ConfigError, match=r"apf\.eta|grid\.depth_bin_m"):
        subterra.PerceptionConfig.from_dict(cfg)


def test_command_takes_any_sequence_of_outputs(d435):
    p = subterra.DepthPerception(d435, seed=0)
    out = p.update(make_box_frame(0.8))
    ctl = subterra.ApfController()
    as_list = ctl.command([5, 0, 0], [out, out]).as_array()
    assert np.array_equal(ctl.command([5, 0, 0], (out, out)).as_array(), as_list)
    assert np.array_equal(ctl.command([5, 0, 0], repulsive_body=2 * out.repulsive_body).as_array(), as_list)
    with pytest.raises(errors.InputError, match=r"perception\[1\]"):
        ctl.command([5, 0, 0], [out, 3])
