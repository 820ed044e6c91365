"""Tests of the NumPy reference APF-PF (subterra.bench.reference.apf_pf) against hand-computed values."""

from __future__ import annotations

import copy
import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]


def _load_reference():
    """Import the reference module; fall back to loading it by file path.

    The reference needs only NumPy, but ``subterra/__init__.py`` may import the compiled
    ``_core``, which is not built in every checkout.
    """
    try:
        import subterra  # noqa: F401
    except ImportError:
        sys.path.insert(0, str(REPO / "python"))
    try:
        from subterra.bench.reference import apf_pf

        return apf_pf
    except ImportError:
        path = REPO / "python" / "subterra" / "bench" / "reference" / "apf_pf.py"
        spec = importlib.util.spec_from_file_location("_subterra_reference_apf_pf", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
        return module


apf_pf = _load_reference()

LOG_SQRT_2PI = 0.5 * math.log(2 * math.pi)

# 640x480 camera whose principal point is the centre pixel of block (6, 4): u_c = (300 +
# 349)/2 = 324.5, v_c = (200 + 249)/2 = 224.5, so the voxels (6, 4, k) lie on the optical axis.
CAM = {"fx": 500.0, "fy": 500.0, "cx": 324.5, "cy": 224.5, "width": 640, "height": 480}


def sid(i, j, k):
    """State id of voxel (i, j, k) on the flight grid of CAM (13 x 10 x 11)."""
    return (j * 13 + i) * 11 + k


@pytest.fixture(scope="module")
def flight():
    return apf_pf.preset("flight")


@pytest.fixture(scope="module")
def flight_T(flight):
    return apf_pf.transition_matrix(flight, CAM)


def with_changes(cfg, **sections):
    """Deep copy of ``cfg`` with ``section={key: value}`` overrides."""
    out = copy.deepcopy(cfg)
    for section, values in sections.items():
        out[section].update(values)
    return out


def tiny_cfg(flight, d_max=0.3, sigma_s=1.0, sigma_z=0.2):
    """2x2-pixel blocks, 0.1 m bins from 0.1 m."""
    return with_changes(
        flight,
        grid={"block_width_px": 2, "block_height_px": 2, "depth_bin_m": 0.1, "depth_min_m": 0.1, "depth_max_m": d_max},
        transition={"sigma_s_voxels": sigma_s, "sigma_z_m": sigma_z},
    )


def blank(value=0, dtype=np.uint16):
    return np.full((480, 640), value, dtype=dtype)


# --------------------------------------------------------------------------- config


def test_presets_load(flight):
    assert flight["grid"]["block_width_px"] == 50
    assert flight["observation"]["sigma_o_points"] == 170.0
    assert flight["filter"]["particles"] == 20000
    cable = apf_pf.preset("cable")
    assert cable["observation"]["sigma_o_points"] == 300.0
    assert cable["observation"]["sigma_n_points"] == 1.0
    assert apf_pf.load_config(REPO / "configs" / "flight.toml") == flight
    with pytest.raises(ValueError):
        apf_pf.preset("no_such_preset")


# --------------------------------------------------------------------------- grid and counts


def test_grid_shape_flight(flight):
    assert apf_pf.grid_shape(flight, CAM) == (13, 10, 11)
    assert apf_pf.num_states(flight, CAM) == 1431
    # (0.4 - 0.1) / 0.1 = 3.0000000000000004 still rounds to 3 bins.
    assert apf_pf.grid_shape(tiny_cfg(flight, d_max=0.4), dict(CAM, width=6, height=6)) == (3, 3, 3)
    assert apf_pf.state_id(2, 1, 2, flight, CAM) == (1 * 13 + 2) * 11 + 2 == 167
    assert apf_pf.voxel_of_state(167, flight, CAM) == (2, 1, 2)
    assert apf_pf.voxel_of_state(1430, flight, CAM) is None


def test_single_pixel_lands_in_voxel(flight):
    depth = blank()
    depth[60, 120] = 350  # v=60, u=120; 0.35 m
    counts = apf_pf.voxel_counts(depth, 0.001, flight, CAM)
    assert counts.shape == (10, 13, 11) and counts.dtype == np.int64
    assert counts.sum() == 1
    assert counts[1, 2, 2] == 1  # (j=1, i=2, k=2): voxel (2, 1, 2)


def test_depth_bin_edges(flight):
    depth = blank()
    depth[0, 0] = 100  # 0.1 m -> bin 0
    depth[0, 1] = 1199  # 1.199 m -> bin 10
    depth[0, 2] = 1200  # 1.2 m: (1.2-0.1)/0.1 = 10.999999999999998 + 1e-9 -> 11: out
    depth[0, 3] = 99  # below d_min: out
    depth[0, 4] = 300  # (0.3-0.1)/0.1 = 1.9999999999999998 -> bin 2 thanks to 1e-9
    depth[0, 5] = 800  # 0.7/0.1 = 6.999999999999999 -> bin 7
    depth[0, 6] = 65535  # 65.5 m: out
    counts = apf_pf.voxel_counts(depth, 0.001, flight, CAM)
    assert counts.sum() == 4
    assert counts[0, 0, 0] == 1 and counts[0, 0, 10] == 1
    assert counts[0, 0, 2] == 1 and counts[0, 0, 7] == 1
    # other scale: raw 35 at 0.01 m/unit = 0.35 m -> bin 2
    d2 = blank()
    d2[0, 0] = 35
    assert apf_pf.voxel_counts(d2, 0.01, flight, CAM)[0, 0, 2] == 1


def test_float_depth_ignores_invalid(flight):
    depth = blank(np.nan, np.float32)
    depth[0, 0] = np.inf
    depth[0, 1] = -np.inf
    depth[0, 2] = 0.0
    depth[0, 3] = -0.5
    depth[0, 4] = 0.35
    depth[479, 639] = 1.15
    counts = apf_pf.voxel_counts(depth, 123.0, flight, CAM)  # scale ignored for float32
    assert counts.sum() == 2
    assert counts[0, 0, 2] == 1
    assert counts[9, 12, 10] == 1


def test_closest_depth():
    depth = blank(np.nan, np.float32)
    assert apf_pf.closest_depth(depth, 0.001) is None
    depth[1, 1] = np.inf
    depth[2, 2] = 0.0
    depth[3, 3] = 2.5  # out of the grid's range, still counts
    assert apf_pf.closest_depth(depth, 0.001) == pytest.approx(2.5)
    depth[4, 4] = 0.35
    assert apf_pf.closest_depth(depth, 0.001) == pytest.approx(0.35)
    raw = blank()
    raw[5, 5] = 5000
    raw[6, 6] = 7000
    assert apf_pf.closest_depth(raw, 0.001) == pytest.approx(5.0)
    assert apf_pf.closest_depth(blank(), 0.001) is None


def test_bad_depth_rejected(flight):
    with pytest.raises(ValueError):
        apf_pf.voxel_counts(np.zeros((480, 641), np.uint16), 0.001, flight, CAM)
    with pytest.raises(ValueError):
        apf_pf.voxel_counts(np.zeros((480, 640), np.int32), 0.001, flight, CAM)
    with pytest.raises(ValueError):
        apf_pf.voxel_counts(np.zeros(640, np.uint16), 0.001, flight, CAM)


def test_block_pixel_counts(flight):
    b = apf_pf.block_pixel_counts(flight, CAM)
    assert b.shape == (10, 13)
    assert b[0, 0] == 2500
    assert b[3, 12] == 40 * 50  # last column: 640 - 600 = 40 px
    assert b[9, 0] == 50 * 30  # last row: 480 - 450 = 30 px
    assert b[9, 12] == 40 * 30
    assert b.sum() == 640 * 480


# --------------------------------------------------------------------------- transition


def hn(x, sigma):
    return math.exp(-x * x / (2 * sigma * sigma))


def test_transition_rows_tiny_grid(flight):
    cfg = tiny_cfg(flight)  # 4x4 px camera -> 2x2x2 voxels, S = 9
    cam = dict(CAM, width=4, height=4)
    T = apf_pf.transition_matrix(cfg, cam)
    assert T.shape == (9, 9)

    def e(l1, z):
        return hn(l1, 1.0) * hn(z, 0.2)

    # State ids (j*2 + i)*2 + k: 0 (0,0,0) 1 (0,0,1) 2 (1,0,0) 3 (1,0,1) 4 (0,1,0)
    # 5 (0,1,1) 6 (1,1,0) 7 (1,1,1) 8 free. Bin centres z(0) = 0.15, z(1) = 0.25 m.
    # From voxel (0,0,0): L1 = 0 1 1 2 1 2 2 3; face = min(1, 2, 1, 2, 2) = 1.
    row0 = [e(0, 0.15), e(1, 0.25), e(1, 0.15), e(2, 0.25), e(1, 0.15), e(2, 0.25), e(2, 0.15), e(3, 0.25), e(1, 0.3)]
    np.testing.assert_allclose(T[0], np.array(row0) / sum(row0), rtol=1e-12)
    # From voxel (1,1,1) = state 7: L1 = 3 2 2 1 2 1 1 0; face = min(2,1,2,1, 2-1=1) = 1.
    row7 = [e(3, 0.15), e(2, 0.25), e(2, 0.15), e(1, 0.25), e(2, 0.15), e(1, 0.25), e(1, 0.15), e(0, 0.25), e(1, 0.3)]
    np.testing.assert_allclose(T[7], np.array(row7) / sum(row7), rtol=1e-12)
    # From free: every voxel of a 2x2x2 grid is on a face (face = 1); free->free: hn(0) hn(d_max).
    row8 = [e(1, 0.15), e(1, 0.25)] * 4 + [e(0, 0.3)]
    np.testing.assert_allclose(T[8], np.array(row8) / sum(row8), rtol=1e-12)
    np.testing.assert_allclose(T.sum(axis=1), 1.0, rtol=0, atol=1e-14)


def test_transition_face_excludes_near_face(flight):
    cfg = tiny_cfg(flight, d_max=0.4)  # 6x6 px -> 3x3x3 voxels, z = 0.15, 0.25, 0.35
    cam = dict(CAM, width=6, height=6)
    T = apf_pf.transition_matrix(cfg, cam)
    free = 27

    def sid(i, j, k):
        return (j * 3 + i) * 3 + k

    # T[v, free] / T[v, v] = hn(face) hn(d_max) / (hn(0) hn(z(k))).
    for k, face, z in [(0, 2, 0.15), (1, 2, 0.25), (2, 1, 0.35)]:  # (1,1,0): near face NOT counted
        v = sid(1, 1, k)
        assert T[v, free] / T[v, v] == pytest.approx(hn(face, 1.0) * hn(0.4, 0.2) / hn(z, 0.2), rel=1e-12)
    # free -> centre voxel (face 2) vs free -> corner voxel (0,0,0) (face 1), same depth bin 0/1
    assert T[free, sid(1, 1, 1)] / T[free, sid(0, 0, 1)] == pytest.approx(hn(2, 1.0) / hn(1, 1.0), rel=1e-12)


def test_transition_flight_rows_sum_to_one(flight_T):
    assert flight_T.shape == (1431, 1431)
    assert np.all(flight_T > 0)
    np.testing.assert_allclose(flight_T.sum(axis=1), 1.0, rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- observation


def test_log_likelihood_values(flight):
    counts = np.zeros((10, 13, 11), np.int64)
    counts[3, 4, 5] = 2500  # full interior voxel
    counts[3, 12, 0] = 2000  # full voxel of the 40-px last column
    counts[9, 12, 1] = 1200  # full corner voxel (40 x 30 px)
    counts[2, 2, 2] = 1250  # half-full interior voxel
    ll = apf_pf.log_likelihood(counts, flight, CAM)
    assert ll.shape == (1431,)
    c = -math.log(170.0) - LOG_SQRT_2PI
    assert ll[sid(4, 3, 5)] == pytest.approx(c, rel=1e-12)
    assert ll[sid(12, 3, 0)] == pytest.approx(c, rel=1e-12)
    assert ll[sid(12, 9, 1)] == pytest.approx(c, rel=1e-12)
    assert ll[sid(2, 2, 2)] == pytest.approx(-0.5 * (1250 / 170) ** 2 + c, rel=1e-12)
    # Empty voxel: (0 - B)/(sigma_o B/A) = -A/sigma_o for every block, edge or not.
    empty = -0.5 * (2500 / 170) ** 2 + c
    assert ll[sid(0, 0, 0)] == pytest.approx(empty, rel=1e-12)
    assert ll[sid(12, 9, 10)] == pytest.approx(empty, rel=1e-12)
    # Free: the largest count is 2500.
    assert ll[-1] == pytest.approx(-0.5 * (2500 / 60) ** 2 - math.log(60.0) - LOG_SQRT_2PI, rel=1e-12)
    ll0 = apf_pf.log_likelihood(np.zeros((10, 13, 11), np.int64), flight, CAM)
    assert ll0[-1] == pytest.approx(-math.log(60.0) - LOG_SQRT_2PI, rel=1e-12)
    with pytest.raises(ValueError):
        apf_pf.log_likelihood(np.zeros((10, 13, 10)), flight, CAM)


# --------------------------------------------------------------------------- filters


def box_frame(z_raw=800, rows=slice(150, 300), cols=slice(250, 400)):
    """uint16 frame (mm) with a box filling blocks i = 5..7, j = 3..5 at z_raw mm."""
    depth = blank()
    depth[rows, cols] = z_raw
    return depth


def test_histogram_filter_map_at_box_depth(flight):
    cfg = with_changes(flight, filter={"mode": "histogram"})
    pipe = apf_pf.ReferencePipeline(CAM, cfg)
    for _ in range(3):
        out = pipe.update(box_frame(800), 0.001)
    assert out["counts"][4, 6, 7] == 2500  # 0.8 m -> bin floor(0.7/0.1 + 1e-9) = 7
    assert out["counts"].sum() == 150 * 150
    mp = out["most_probable"]
    i, j, k = mp["voxel"]
    assert apf_pf.voxel_of_state(mp["state"], cfg, CAM) == (i, j, k)
    assert k == 7 and 5 <= i <= 7 and 3 <= j <= 5
    assert mp["depth_m"] == pytest.approx(0.85) and mp["centre_camera"][2] == pytest.approx(0.85)
    np.testing.assert_allclose(mp["centre_body"], pipe.centres_body[mp["state"]])
    assert mp["probability"] == out["belief"][:-1].max() == pytest.approx(out["belief"].max())
    assert out["belief"].sum() == pytest.approx(1.0)
    assert out["p_free"] < 1e-6
    assert out["closest_depth_m"] == pytest.approx(0.8)
    np.testing.assert_allclose(out["repulsive_body"], out["belief"] @ pipe.forces)
    assert out["repulsive_body"][0] < 0  # an obstacle ahead pushes backward


def test_empty_frame_drives_p_free_up(flight):
    pipe = apf_pf.ReferencePipeline(CAM, with_changes(flight, filter={"mode": "histogram"}))
    assert pipe.filter.belief[-1] == pytest.approx(1 / 1431)
    for _ in range(3):
        out = pipe.update(blank(), 0.001)
        assert out["p_free"] > 0.99
        # The most probable voxel excludes the free state (as in Rust): some voxel, barely.
        assert out["most_probable"]["state"] < 1430
        assert out["most_probable"]["probability"] == out["belief"][:-1].max() < 0.01
        assert out["closest_depth_m"] is None
        np.testing.assert_allclose(out["repulsive_body"], 0.0, atol=1e-3)


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_empty_frame_drives_p_free_up_particle(flight, seed):
    # With the flight model a particle reaches the free state with probability ~2e-5..8e-5
    # per frame (T[free, free] = 2.25e-5); the defensive proposal (filter.free_proposal_min
    # = 0.05 in the preset) sends ~1000 of the 20000 particles there, weighted by T/q.
    assert flight["filter"]["free_proposal_min"] == 0.05
    pipe = apf_pf.ReferencePipeline(CAM, flight, seed=seed)
    assert pipe.filter.free_proposal_min == 0.05
    assert pipe.filter.belief[-1] == 13 / 20000  # 20000 = 13 * 1431 + 1397: particle p in state p % S
    for _ in range(3):
        out = pipe.update(blank(), 0.001)
        assert out["p_free"] > 0.99
        assert out["most_probable"] is None  # every particle sits in the free state
        np.testing.assert_allclose(out["repulsive_body"], 0.0, atol=1e-3)


def test_empty_frame_bootstrap_misses_free_state(flight):
    """Regression (why filter.free_proposal_min exists): with q_min = 0, the paper's bootstrap,
    about one of N = 20000 particles reaches the free state per frame, so P(free) after an
    empty frame is 0 or 1 by chance; the defensive proposal makes it ~1 for every seed."""
    bootstrap = with_changes(flight, filter={"free_proposal_min": 0.0})
    p_free = [apf_pf.ReferencePipeline(CAM, bootstrap, seed=s).update(blank(), 0.001)["p_free"] for s in range(10)]
    assert min(p_free) < 0.01 and max(p_free) > 0.99
    defensive = [apf_pf.ReferencePipeline(CAM, flight, seed=s).update(blank(), 0.001)["p_free"] for s in range(10)]
    assert min(defensive) > 0.99


def test_empty_frame_bootstrap_with_free_state_at_depth_zero():
    """The authors' convention (preset acc2021: s_free at depth 0, the plain bootstrap
    filter, multinomial): ~90 particles reach the free state per frame, so one empty frame
    gives P(free) = 1 for every seed without any extra proposal."""
    acc = apf_pf.preset("acc2021")
    assert acc["filter"]["free_proposal_min"] == 0.0 and acc["transition"]["free_state_depth"] == "zero"
    p_free = [apf_pf.ReferencePipeline(CAM, acc, seed=s).update(blank(), 0.001)["p_free"] for s in range(10)]
    assert min(p_free) > 0.99
    T = apf_pf.transition_matrix(acc, CAM)
    T_horizon = apf_pf.transition_matrix(with_changes(acc, transition={"free_state_depth": "horizon"}), CAM)
    # Voxel -> free is e^{+4.5}-ish more likely at depth 0 than at the horizon (d_max = 1.2, sigma_z = 0.4).
    ratio = T[:-1, -1].mean() / T_horizon[:-1, -1].mean()
    assert 40 < ratio < 120, ratio


def test_near_corner_voxel_points(flight):
    """apf.voxel_position = near-corner: the block's top-left pixel at the bin's near edge."""
    acc = with_changes(flight, apf={"voxel_position": "near-corner"})
    pts = apf_pf.voxel_points_body(acc, CAM, np.eye(4))
    s = apf_pf.state_id(6, 4, 9, flight, CAM)
    fx, fy, cx, cy = (CAM[k] for k in ("fx", "fy", "cx", "cy"))
    np.testing.assert_allclose(pts[s], [(300 - cx) * 1.0 / fx, (200 - cy) * 1.0 / fy, 1.0], atol=1e-12)
    np.testing.assert_allclose(apf_pf.voxel_points_body(flight, CAM, np.eye(4)), apf_pf.voxel_centers_body(flight, CAM, np.eye(4)))
    with pytest.raises(ValueError, match="voxel_position"):
        apf_pf.voxel_points_body(with_changes(flight, apf={"voxel_position": "middle"}), CAM)


def test_histogram_update_by_hand():
    T = np.array([[0.5, 0.5], [0.25, 0.75]])
    b = apf_pf.histogram_update(np.array([1.0, 0.0]), T, np.log([2.0, 1.0]))
    # predicted (0.5, 0.5), times (2, 1) -> (1, 0.5) / 1.5
    np.testing.assert_allclose(b, [2 / 3, 1 / 3])
    # huge negative log-likelihoods do not underflow to NaN
    b = apf_pf.histogram_update(np.array([0.5, 0.5]), T, np.array([-1e5, -1e5 - math.log(3)]))
    # predicted (0.375, 0.625), times (1, 1/3) -> (0.375, 0.208333) / 0.583333
    np.testing.assert_allclose(b, [0.375 / (0.375 + 0.625 / 3), (0.625 / 3) / (0.375 + 0.625 / 3)])


def test_particle_filter_seeded_and_initial_spread(flight_T):
    a = apf_pf.ParticleFilter(flight_T, 20000, seed=7)
    np.testing.assert_array_equal(a.states[:3], [0, 1, 2])
    assert a.states[1431] == 0
    ll = np.zeros(1431)
    b1 = [a.step(ll).copy() for _ in range(2)]
    b2 = apf_pf.ParticleFilter(flight_T, 20000, seed=7)
    np.testing.assert_array_equal(b1[1], [b2.step(ll) for _ in range(2)][1])
    np.testing.assert_allclose(b1[1] * 20000, np.round(b1[1] * 20000), atol=1e-9)
    with pytest.raises(ValueError):
        apf_pf.ParticleFilter(flight_T, 100, resampling="stratified")


@pytest.mark.parametrize("q_min", [0.0, 0.05, 0.3])
def test_particle_propagation_matches_transition_row(flight_T, q_min):
    """The weighted frequencies of the successors (weights T/q) estimate T's row, whatever q_min."""
    n = 100000
    pf = apf_pf.ParticleFilter(flight_T, n, seed=1, free_proposal_min=q_min)
    for s0 in (0, 645, 1430):
        pf.states[:] = s0
        pf.propagate()
        t_free = flight_T[s0, -1]
        q = max(t_free, q_min)
        # The free branch is taken w.p. q; the voxel branch carries weight (1 - T)/(1 - q).
        free_share = np.mean(pf.states == 1430)
        assert abs(free_share - q) <= 5 * math.sqrt(q * (1 - q) / n) + 1e-4
        assert np.all(pf.ratios[pf.states == 1430] == pytest.approx(t_free / q, rel=1e-12))
        assert np.all(pf.ratios[pf.states != 1430] == pytest.approx((1 - t_free) / (1 - q), rel=1e-12))
        est = np.bincount(pf.states, weights=pf.ratios, minlength=1431) / n
        # 5 sigma of a binomial proportion, per state (the ratios are near 1 on voxels)
        p = flight_T[s0]
        tol = 5 * np.sqrt(p * (1 - p) / n) * (1 - t_free) / (1 - q) + 1e-4
        assert np.all(np.abs(est[:-1] - p[:-1]) <= tol[:-1])
        # Free: the estimate is exactly (T/q) * (free count)/n.
        assert est[-1] == pytest.approx(free_share * t_free / q if q > 0 else 0.0, rel=1e-12, abs=1e-300)
        assert abs(est[-1] - t_free) <= 5 * math.sqrt(q * (1 - q) / n) * t_free / max(q, 1e-300) + 1e-6


def test_particle_filter_rejects_bad_free_proposal_min(flight_T):
    for bad in (-0.1, 1.0, 2.0, float("nan")):
        with pytest.raises(ValueError, match="free_proposal_min"):
            apf_pf.ParticleFilter(flight_T, 100, free_proposal_min=bad)


@pytest.mark.parametrize(
    ("resampling", "q_min"), [("systematic", 0.0), ("multinomial", 0.0), ("systematic", 0.05), ("multinomial", 0.3)]
)
def test_particle_matches_histogram_soft_model(flight, resampling, q_min):
    """A 200x150 camera (4x3x11 voxels, S = 133) with broad noise: full beliefs agree.

    sigma_z = 1 m and sigma_n = 100 points make P(free) ~ 0.2 on empty frames (tolerances:
    about twice the worst error seen over 40 seeds).
    """
    cam = dict(CAM, width=200, height=150, cx=99.5, cy=74.5)
    cfg = with_changes(
        flight,
        transition={"sigma_z_m": 1.0},
        observation={"sigma_o_points": 3000.0, "sigma_n_points": 100.0},
        filter={"resampling": resampling},
    )
    T = apf_pf.transition_matrix(cfg, cam)
    hist = apf_pf.HistogramFilter(T)
    part = apf_pf.ParticleFilter(T, 20000, seed=11, resampling=resampling, free_proposal_min=q_min)
    for z in (800, 800, 500, 0, 0, 300):
        d = np.zeros((150, 200), np.uint16)
        d[40:110, 60:160] = z
        ll = apf_pf.log_likelihood(apf_pf.voxel_counts(d, 0.001, cfg, cam), cfg, cam)
        hb, pb = hist.step(ll), part.step(ll)
        if z == 0:
            assert 0.1 < hb[-1] < 0.5  # the free state matters on empty frames
        else:
            assert hb[-1] < 1e-6
        assert np.abs(hb[:-1] - pb[:-1]).max() < 0.008  # hb.max() is ~0.01
        assert abs(hb[-1] - pb[-1]) < 0.08
        # depth-bin marginals
        hk = hb[:-1].reshape(3, 4, 11).sum(axis=(0, 1))
        pk = pb[:-1].reshape(3, 4, 11).sum(axis=(0, 1))
        assert np.abs(hk - pk).max() < 0.025


def test_particle_matches_histogram_flight(flight):
    """Flight preset, 640x480, boxes moving about: MAP depth bin, P(free), net repulsion agree."""
    h = apf_pf.ReferencePipeline(CAM, with_changes(flight, filter={"mode": "histogram"}))
    p = apf_pf.ReferencePipeline(CAM, with_changes(flight, filter={"mode": "particle"}), seed=5)
    frames = [
        (box_frame(800), 7),
        (box_frame(800), 7),
        (box_frame(500, cols=slice(0, 150)), 4),
        (box_frame(1000), 9),
        (box_frame(800, rows=slice(300, 480)), 7),
    ]
    for d, k in frames:
        ho, po = h.update(d), p.update(d)
        assert ho["most_probable"]["voxel"][2] == k
        assert po["most_probable"]["voxel"][2] == k
        assert ho["p_free"] < 1e-6 and po["p_free"] == 0.0
        hk = ho["belief"][:-1].reshape(10, 13, 11).sum(axis=(0, 1))
        pk = po["belief"][:-1].reshape(10, 13, 11).sum(axis=(0, 1))
        assert hk[k] > 0.999 and pk[k] > 0.999
        # |repulsive_body| is 0.2 .. 2.6 here; worst error over 20 seeds was 0.074
        np.testing.assert_allclose(po["repulsive_body"], ho["repulsive_body"], rtol=0, atol=0.15)


# --------------------------------------------------------------------------- APF


def test_voxel_centres_body(flight):
    x = apf_pf.voxel_centers_body(flight, CAM)
    np.testing.assert_allclose(x[sid(6, 4, 4)], [0.55, 0, 0], atol=1e-15)  # on the axis, z = 0.55
    # block (7, 4): u_c = 374.5 -> x_cam = 50 * 0.55 / 500 = 0.055 (right) -> body y = -0.055
    np.testing.assert_allclose(x[sid(7, 4, 4)], [0.55, -0.055, 0], atol=1e-15)
    # block (6, 5): v_c = 274.5 -> y_cam = 0.055 (down) -> body z = -0.055
    np.testing.assert_allclose(x[sid(6, 5, 4)], [0.55, 0, -0.055], atol=1e-15)
    # last column block 12: u_c = (600 + 639)/2 = 619.5 -> x_cam = 295 * 0.15 / 500
    np.testing.assert_allclose(x[sid(12, 4, 0)], [0.15, -295 * 0.15 / 500, 0], atol=1e-15)
    m = np.eye(4)
    m[:3, 3] = [0.1, 0.2, 0.3]
    np.testing.assert_allclose(apf_pf.voxel_centers_body(flight, CAM, m)[sid(6, 4, 4)], [0.1, 0.2, 0.85])


def test_repulsive_forces(flight):
    f = apf_pf.repulsive_forces(flight, CAM)
    assert f.shape == (1431, 3)
    np.testing.assert_array_equal(f[-1], 0.0)
    # obstacle straight ahead at 0.55 m: eta (1/0.55 - 1/1.4) / 0.55^2 = 4.0141677 backward
    np.testing.assert_allclose(f[sid(6, 4, 4)], [-4.0141677, 0, 0], rtol=1e-7, atol=1e-12)
    # at 1.15 m: 1.1 (1/1.15 - 1/1.4) / 1.15^2 = 0.1291550
    np.testing.assert_allclose(f[sid(6, 4, 10)], [-0.1291550, 0, 0], rtol=1e-6, atol=1e-12)
    # obstacle right of the axis pushes left (+y); below pushes up (+z)
    assert f[sid(7, 4, 4)][1] > 0 and f[sid(6, 5, 4)][2] > 0
    # corner voxel (0, 0, 10): body (1.15, 0.69, 0.46), |x| = 1.4178 > rho_0 -> 0
    np.testing.assert_array_equal(f[sid(0, 0, 10)], 0.0)
    # cut-off: rho_0 = 0.5 < 0.55
    f2 = apf_pf.repulsive_forces(with_changes(flight, apf={"rho_0_m": 0.5}), CAM)
    np.testing.assert_array_equal(f2[sid(6, 4, 4)], 0.0)
    # clamp: min distance 1.0 m -> r = 1: 1.1 (1 - 1/1.4) = 0.3142857
    f3 = apf_pf.repulsive_forces(with_changes(flight, apf={"min_distance_m": 1.0}), CAM)
    np.testing.assert_allclose(f3[sid(6, 4, 4)], [-1.1 * (1 - 1 / 1.4), 0, 0], rtol=1e-12, atol=1e-15)


def test_command_mapping(flight):
    cmd = apf_pf.command
    c = cmd([2.0, 0, 0], [0, 0, 0], flight)  # straight ahead
    assert c == {"v_x": 0.6, "v_y": 0.0, "v_z": 0.0, "yaw_rate": 0.0, "reached": False}
    c = cmd([0, 2.0, 0], [0, 0, 0], flight)  # to the left: alpha = pi/2
    assert c["yaw_rate"] == pytest.approx(0.5) and c["v_x"] == pytest.approx(0.0, abs=1e-15)
    c = cmd([0, -2.0, 0], [0, 0, 0], flight)
    assert c["yaw_rate"] == pytest.approx(-0.5)
    c = cmd([-2.0, 0, 0], [0, 0, 0], flight)  # behind: alpha = pi
    assert c["yaw_rate"] == pytest.approx(1.0) and c["v_x"] == 0.0
    c = cmd([1.0, 0, 1.0], [0, 0, 0], flight)
    assert c["v_z"] == pytest.approx(0.6 / math.sqrt(2)) and c["v_x"] == pytest.approx(0.6)
    # conic attraction: |g| = 2 > rho_r: F_att = 0.5 * 0.4 * (1, 0, 0) = (0.2, 0, 0)
    c = cmd([2.0, 0, 0], [-0.1, 0.1, 0], flight)  # F = (0.1, 0.1, 0): alpha = pi/4
    assert c["yaw_rate"] == pytest.approx(0.25) and c["v_x"] == pytest.approx(0.6 * math.cos(math.pi / 4))
    # quadratic attraction: |g| = 0.4 <= rho_r: F_att = 0.4 * 0.4 = 0.16
    c = cmd([0.4, 0, 0], [-0.06, 0.1, 0], flight)
    assert c["yaw_rate"] == pytest.approx(0.25) and c["v_x"] == pytest.approx(0.6 * math.cos(math.pi / 4))
    # repulsion stronger than attraction straight ahead: turn around, no forward speed
    c = cmd([2.0, 0, 0], [-0.5, 0, 0], flight)
    assert c["v_x"] == 0.0 and c["yaw_rate"] == pytest.approx(1.0)
    # exact balance: zero command, not reached
    assert cmd([2.0, 0, 0], [-0.2, 0, 0], flight) == {
        "v_x": 0.0,
        "v_y": 0.0,
        "v_z": 0.0,
        "yaw_rate": 0.0,
        "reached": False,
    }
    # within the success radius
    assert cmd([0.2, 0.1, 0], [-5, 0, 0], flight) == {
        "v_x": 0.0,
        "v_y": 0.0,
        "v_z": 0.0,
        "yaw_rate": 0.0,
        "reached": True,
    }
    # holonomic
    hol = with_changes(flight, apf={"mode": "holonomic"})
    c = cmd([1.0, 1.0, 0], [0, 0, 0], hol)
    assert c["v_x"] == pytest.approx(0.6 / math.sqrt(2)) and c["v_y"] == pytest.approx(0.6 / math.sqrt(2))
    assert c["v_z"] == 0.0 and c["yaw_rate"] == 0.0
    with pytest.raises(ValueError):
        cmd([1.0, 0, 0], [0, 0, 0], with_changes(flight, apf={"mode": "sideways"}))


def test_pipeline_command_sums_cameras(flight):
    pipe = apf_pf.ReferencePipeline(CAM, with_changes(flight, filter={"mode": "histogram"}))
    outs = [{"repulsive_body": np.array([-0.05, 0.05, 0.0])}, {"repulsive_body": np.array([-0.05, 0.05, 0.0])}]
    c = pipe.command([2.0, 0, 0], outs)  # F = (0.2, 0, 0) + (-0.1, 0.1, 0): alpha = pi/4
    assert c["yaw_rate"] == pytest.approx(0.25)
    assert pipe.command([2.0, 0, 0], outs[0])["yaw_rate"] == pytest.approx(math.atan2(0.05, 0.15) / math.pi)
    # obstacle ahead at 0.5 m: the robot slows and is pushed back
    out = pipe.update(box_frame(500))
    assert out["repulsive_body"][0] < 0
    c = pipe.command([2.0, 0, 0], [out])
    assert c["v_x"] < 0.6
