"""Rust (``subterra._core``) against the NumPy reference (``subterra.bench.reference.apf_pf``).

Same inputs through both: the voxel counts must be equal exactly, the transition rows,
forces, histogram-filter beliefs and commands equal to rounding. Two set-ups: the
``flight`` preset on the simulated D435, and a small custom grid whose blocks do not tile
the image and whose camera is mounted with a rotation and an offset.
"""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
from conftest import camera_dict, config_dict, make_box_frame, with_changes

import subterra
from subterra.bench.reference import apf_pf

# A small camera and grid: 101x77 px in 16x10-px blocks (7 x 8 blocks, the last column
# 5 px wide, the last row 7 px high), 12 bins of 0.15 m over [0.2, 2.0] m.
SMALL_CAMERA = {"fx": 120.0, "fy": 110.0, "cx": 50.3, "cy": 37.1, "width": 101, "height": 77}
SMALL_SECTIONS = {
    "grid": {"block_width_px": 16, "block_height_px": 10, "depth_bin_m": 0.15, "depth_min_m": 0.2, "depth_max_m": 2.0},
    "transition": {"sigma_s_voxels": 3.0, "sigma_z_m": 0.8},
    "observation": {"sigma_o_points": 40.0, "sigma_n_points": 15.0},
    "apf": {"rho_0_m": 1.6, "eta": 0.7},
}
# Upward camera 0.1 m ahead of and 0.2 m above the body origin, turned 30 deg about body z.
_C, _S = np.cos(np.pi / 6), np.sin(np.pi / 6)
SMALL_BODY_FROM_CAMERA = np.array(
    [
        [_C, -_S, 0.0, 0.0],
        [_S, _C, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
) @ np.array(
    [
        [0.0, -1.0, 0.0, 0.1],
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.2],
        [0.0, 0.0, 0.0, 1.0],
    ]
)


class Setup:
    """One camera + config, built for both implementations."""

    def __init__(self, camera: dict, cfg: dict, body_from_camera=None):
        self.camera_dict = camera
        self.cfg = cfg
        self.body_from_camera = body_from_camera
        self.camera = subterra.PinholeCamera(**camera)
        self.config = subterra.PerceptionConfig.from_json(json.dumps(cfg))
        self.shape = (camera["height"], camera["width"])

    def perception(self, **changes) -> subterra.DepthPerception:
        config = self.config
        if changes:
            config = subterra.PerceptionConfig.from_json(json.dumps(with_changes(self.cfg, **changes)))
        return subterra.DepthPerception(self.camera, config=config, body_from_camera=self.body_from_camera)

    def reference(self, **changes) -> apf_pf.ReferencePipeline:
        return apf_pf.ReferencePipeline(self.camera_dict, with_changes(self.cfg, **changes), self.body_from_camera)


@pytest.fixture(scope="module", params=["flight-d435", "small", "small-acc2021"])
def setup(request, d435):
    if request.param == "flight-d435":
        return Setup(camera_dict(d435), config_dict("flight"))
    if request.param == "small-acc2021":
        # The authors' conventions: s_free at depth 0, repulsion from the near corner.
        sections = {**SMALL_SECTIONS, "transition": {**SMALL_SECTIONS["transition"], "free_state_depth": "zero"},
                    "apf": {**SMALL_SECTIONS["apf"], "voxel_position": "near-corner"}}
        return Setup(SMALL_CAMERA, config_dict("acc2021", **sections), SMALL_BODY_FROM_CAMERA)
    return Setup(SMALL_CAMERA, config_dict("flight", **SMALL_SECTIONS), SMALL_BODY_FROM_CAMERA)


@pytest.fixture(scope="module")
def transition(setup):
    return apf_pf.transition_matrix(setup.cfg, setup.camera_dict)


def test_setups_agree_on_the_grid(setup):
    p = setup.perception()
    n_w, n_h, n_d = apf_pf.grid_shape(setup.cfg, setup.camera_dict)
    assert p.grid_shape == (n_w, n_h, n_d)
    assert p.state_count == apf_pf.num_states(setup.cfg, setup.camera_dict) == p.free_state + 1
    assert setup.config.depth_bins == n_d
    rng = np.random.default_rng(0)
    for s in [0, p.free_state - 1, *rng.integers(0, p.free_state, 20)]:
        assert p.voxel_of(int(s)) == apf_pf.voxel_of_state(int(s), setup.cfg, setup.camera_dict)
        assert p.state_of(*p.voxel_of(int(s))) == s
    assert p.voxel_of(p.free_state) is None


# --------------------------------------------------------------------------- counts


def _odd_frames(shape, rng):
    """uint16 and float32 frames with no-returns, NaN, +-inf, negatives, bin edges, out of range."""
    h, w = shape
    raw = rng.integers(0, 2600, size=shape).astype(np.uint16)
    raw[rng.random(shape) < 0.2] = 0
    raw[rng.random(shape) < 0.02] = 65535
    # Bin edges of both grids in mm (0.1 m steps; 0.2 + 0.15 k) and their neighbours.
    edges = [100 * k + d for k in range(1, 22) for d in (-1, 0, 1)] + [200 + 150 * k for k in range(13)]
    edges = np.array(edges, np.uint16)
    raw.reshape(-1)[: edges.size] = edges
    metres = raw.astype(np.float32) / np.float32(1000.0)
    specials = np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, -0.5, 1e-30, 1e-45, 3e38], np.float32)
    flat = metres.reshape(-1)
    pick = rng.choice(flat.size, size=flat.size // 10, replace=False)
    flat[pick] = rng.choice(specials, size=pick.size)
    # float32 metres exactly on the bin edges (0.3 f32 is 0.30000001192092896 m)
    flat[-edges.size :] = edges.astype(np.float32) / np.float32(1000.0)
    box = make_box_frame(0.85, slice(h // 4, h // 2), slice(w // 3, w // 2), shape=shape)
    return [("random uint16", raw, 0.001), ("box uint16", box, 0.001), ("specials float32", metres, None)]


def test_counts_equal_exactly(setup):
    p = setup.perception()
    assert p.counts() is None  # before the first frame
    rng = np.random.default_rng(42)
    for name, frame, scale in _odd_frames(setup.shape, rng):
        out = p.update(frame) if scale is None else p.update(frame, scale=scale)
        ref = apf_pf.voxel_counts(frame, 0.001 if scale is None else scale, setup.cfg, setup.camera_dict)
        counts = p.counts()
        assert counts.shape == ref.shape == tuple(reversed(p.grid_shape[:2])) + (p.grid_shape[2],), name
        np.testing.assert_array_equal(counts, ref, err_msg=name)
        assert out.in_range_pixels == ref.sum(), name
        assert out.max_count == ref.max(), name
        z = frame.astype(np.float64) * (scale or 1.0)
        valid = np.isfinite(z) & (z > 0)
        assert out.valid_pixels == np.count_nonzero(valid), name
        assert out.closest_depth_m == apf_pf.closest_depth(frame, scale or 0.001), name


@pytest.mark.parametrize("scale", [0.001, 0.0001, 0.00025, 1 / 5000, 0.0125])
def test_counts_equal_for_other_scales(setup, scale):
    """uint16 counting goes through a lookup table per scale: switching scales must rebuild it."""
    p = setup.perception()
    rng = np.random.default_rng(7)
    raw = rng.integers(0, 65536, size=setup.shape, dtype=np.uint16)
    raw[:, ::3] = rng.integers(0, int(2.1 / scale) + 2, size=raw[:, ::3].shape)
    for s in (scale, 0.001, scale):
        p.update(raw, scale=s)
        ref = apf_pf.voxel_counts(raw, s, setup.cfg, setup.camera_dict)
        np.testing.assert_array_equal(p.counts(), ref, err_msg=str(s))


def _layouts(shape):
    rng = np.random.default_rng(3)
    h, w = shape
    wide = rng.integers(0, 2500, size=(h, 2 * w)).astype(np.uint16)
    return {
        "strided uint16": wide[:, ::2],
        "reversed float32": (wide[:, :w] / 1000).astype(np.float32)[:, ::-1],
        "fortran uint16": np.asfortranarray(wide[:, :w]),
        "fortran float32": np.asfortranarray((wide[:, :w] / 1000).astype(np.float32)),
        "transposed uint16": np.ascontiguousarray(wide[:, :w].T).T,
    }


@pytest.mark.parametrize(
    "layout",
    [
        "strided uint16",
        "reversed float32",
        "fortran uint16",
        "fortran float32",
        "transposed uint16",
    ],
)
def test_counts_equal_for_any_memory_layout(setup, layout):
    frame = _layouts(setup.shape)[layout]
    p = setup.perception()
    p.update(frame)
    ref = apf_pf.voxel_counts(np.ascontiguousarray(frame), 0.001, setup.cfg, setup.camera_dict)
    np.testing.assert_array_equal(p.counts(), ref)


def test_counts_at_the_horizon_of_a_range_a_hair_short_of_whole_bins(d435):
    """Regression: validation accepts d_max = 1.2 - 1e-8 (11 bins within 1e-6); a depth in
    [d_max, 1.2) is beyond the horizon in Rust, and the reference used to count it in bin 10."""
    cfg = config_dict("flight", grid={"depth_max_m": 1.2 - 1e-8})
    s = Setup(camera_dict(d435), cfg)
    scale = (1.2 - 5e-9) / 60000  # raw 60000 -> 1.199999995 m, inside [d_max, 1.2)
    frame = np.zeros((480, 640), np.uint16)
    frame[0, :7] = 60000
    frame[1, :5] = 59999  # 1.19999997 m: below d_max, bin 10
    p = s.perception()
    out = p.update(frame, scale=scale)
    ref = apf_pf.voxel_counts(frame, scale, cfg, s.camera_dict)
    np.testing.assert_array_equal(p.counts(), ref)
    assert out.in_range_pixels == ref.sum() == 5


# --------------------------------------------------------------------------- models


def test_transition_rows_equal_the_dense_matrix(setup, transition):
    p = setup.perception()
    n_w, n_h, n_d = p.grid_shape
    S = p.state_count
    corners = [p.state_of(i, j, k) for i in (0, n_w - 1) for j in (0, n_h - 1) for k in (0, n_d - 1)]
    centre = p.state_of(n_w // 2, n_h // 2, n_d // 2)
    edge = p.state_of(n_w - 1, n_h // 2, 1)
    states = sorted({*corners, centre, edge, 1, S - 2, S - 1})
    for s in states:
        row = p.transition_row(s)
        assert row.shape == (S,)
        np.testing.assert_allclose(row, transition[s], rtol=1e-12, atol=1e-15, err_msg=f"state {s}")
        assert row.sum() == pytest.approx(1.0, abs=1e-12)
    # Every row, to 1e-12 absolute (a few ms).
    rows = np.array([p.transition_row(s) for s in range(S)])
    np.testing.assert_allclose(rows, transition, rtol=0, atol=1e-12)


def test_forces_and_voxel_centres_equal(setup):
    p = setup.perception()
    forces = apf_pf.repulsive_forces(setup.cfg, setup.camera_dict, setup.body_from_camera)
    assert p.forces_body().shape == (p.state_count, 3)
    np.testing.assert_allclose(p.forces_body(), forces, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(p.forces_body()[-1], 0.0)
    assert np.count_nonzero(np.linalg.norm(forces, axis=1)) > 10  # some voxels inside rho_0
    np.testing.assert_allclose(
        p.voxel_centres("body"),
        apf_pf.voxel_centers_body(setup.cfg, setup.camera_dict, setup.body_from_camera),
        rtol=1e-12,
        atol=1e-15,
    )
    camera_centres = apf_pf.voxel_centers_body(setup.cfg, setup.camera_dict, np.eye(4))
    np.testing.assert_allclose(p.voxel_centres("camera"), camera_centres, rtol=1e-12, atol=1e-15)
    expected = apf_pf.DEFAULT_BODY_FROM_CAMERA if setup.body_from_camera is None else setup.body_from_camera
    np.testing.assert_allclose(p.body_from_camera, expected, atol=1e-15)


# --------------------------------------------------------------------------- histogram filter


def _sequence(shape):
    """Five frames: a box, the box nearer and off-centre (float32), nothing, noise, a low wall."""
    h, w = shape
    rng = np.random.default_rng(5)
    noise = np.zeros(shape, np.uint16)
    noise.reshape(-1)[::7] = np.clip(rng.normal(900, 300, noise.size)[::7], 0, 3000).astype(np.uint16)
    return [
        make_box_frame(0.8, slice(h // 4, h // 2), slice(w // 3, 2 * w // 3), shape=shape),
        make_box_frame(
            0.55, slice(h // 3, 2 * h // 3), slice(0, w // 4), shape=shape, dtype=np.float32, background=np.nan
        ),
        np.zeros(shape, np.uint16),
        noise,
        make_box_frame(1.05, slice(2 * h // 3, h), slice(0, w), shape=shape),
    ]


def test_histogram_filter_beliefs_equal_over_a_sequence(setup):
    p = setup.perception(filter={"mode": "histogram"})
    ref = setup.reference(filter={"mode": "histogram"})
    np.testing.assert_allclose(p.belief(), ref.filter.belief, rtol=1e-12)
    for n, frame in enumerate(_sequence(setup.shape)):
        out, r = p.update(frame), ref.update(frame)
        belief = p.belief()
        np.testing.assert_allclose(belief, r["belief"], rtol=0, atol=1e-9, err_msg=f"frame {n}")
        # Relative agreement too, where the belief is not negligible.
        big = r["belief"] > 1e-6
        np.testing.assert_allclose(belief[big], r["belief"][big], rtol=1e-9, err_msg=f"frame {n}")
        assert out.p_free == pytest.approx(r["p_free"], abs=1e-9)
        mp, rmp = out.most_probable, r["most_probable"]
        assert mp.state == rmp["state"] and mp.voxel == rmp["voxel"], f"frame {n}"
        assert mp.probability == pytest.approx(rmp["probability"], abs=1e-9)
        assert mp.depth_m == pytest.approx(rmp["depth_m"], rel=1e-12)
        np.testing.assert_allclose(mp.centre_body, rmp["centre_body"], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(out.repulsive_body, r["repulsive_body"], rtol=1e-9, atol=1e-9)
        assert out.closest_depth_m == r["closest_depth_m"]
        # The sparse view holds the dense belief above 1e-12.
        np.testing.assert_array_equal(out.belief_states, np.flatnonzero(belief > 1e-12))
        np.testing.assert_array_equal(out.belief_probabilities, belief[belief > 1e-12])
    assert p.frames == 5


# --------------------------------------------------------------------------- commands


GOALS = [np.array(g, float) for g in itertools.product([-2.0, -0.35, 0.0, 0.2, 0.45, 3.0], repeat=3)]
FORCES = [
    np.zeros(3),
    np.array([-0.1, 0.1, 0.0]),
    np.array([-0.2, 0.0, 0.0]),
    np.array([-0.5, 0.0, 0.0]),
    np.array([0.3, -0.25, 0.1]),
    np.array([-1e-3, 2e-3, -4e-3]),
    np.array([-4.0, 3.0, 2.0]),
]


@pytest.mark.parametrize("mode", ["nonholonomic", "holonomic"])
def test_commands_equal(mode):
    cfg = config_dict("flight", apf={"mode": mode})
    controller = subterra.ApfController(config=subterra.PerceptionConfig.from_json(json.dumps(cfg)))
    reached = moving = 0
    for goal, force in itertools.product(GOALS, FORCES):
        cmd = controller.command(goal, repulsive_body=force)
        ref = apf_pf.command(goal, force, cfg)
        label = f"goal {goal}, force {force}"
        assert cmd.reached == ref["reached"], label
        want = [ref[k] for k in ("v_x", "v_y", "v_z", "yaw_rate")]
        np.testing.assert_allclose(cmd.as_array(), want, rtol=1e-12, atol=1e-15, err_msg=label)
        np.testing.assert_allclose(cmd.repulsive_body, force, rtol=0, atol=0)
        reached += cmd.reached
        moving += np.any(cmd.as_array() != 0)
    assert reached > 0 and moving > 0.5 * len(GOALS) * len(FORCES)


def test_command_with_perception_outputs_equals_reference(d435, d435_dict):
    cfg = config_dict("flight", filter={"mode": "histogram"})
    config = subterra.PerceptionConfig.from_json(json.dumps(cfg))
    p = subterra.DepthPerception(d435, config=config)
    ref = apf_pf.ReferencePipeline(d435_dict, cfg)
    frame = make_box_frame(0.6, slice(100, 300), slice(350, 600))
    out, r = p.update(frame), ref.update(frame)
    controller = subterra.ApfController(config=config)
    for goal in ([3.0, 0.0, 0.0], [1.0, 1.0, 0.5], [0.4, -0.1, 0.0]):
        cmd = controller.command(goal, perception=out)
        want = ref.command(goal, r)
        expected = [want[k] for k in ("v_x", "v_y", "v_z", "yaw_rate")]
        np.testing.assert_allclose(cmd.as_array(), expected, rtol=1e-9, atol=1e-12)
