"""The Python face of terrain risk mapping (issue 5).

Synthetic clouds with known answers (flat plane, a 0.3 m box, a mission item), the
ground segmentation on its own, bad input, the committed default config, the
``subterra terrain`` command, and the real Ouster OS1-128 scans (skipped when
``../shared/data`` is absent).
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import subterra
from subterra.errors import ConfigError, FileFormatError, InputError
from subterra.terrain import estimate_sensor_height, lethal_cells, translation

REPO = Path(__file__).resolve().parents[2]
SENSOR_HEIGHT_M = 0.7
#: The box of the box scene: x, y extent [m] (body frame = world frame, robot at origin).
BOX_X, BOX_Y, BOX_H = (3.0, 3.6), (-0.4, 0.4), 0.3
RISK_LAYERS = ("collision", "step", "negative", "tilt", "roughness", "unknown", "mission", "risk")


def plane(half_m: float = 9.0, step_m: float = 0.05, z_m: float = -SENSOR_HEIGHT_M) -> np.ndarray:
    """A flat, dense grid of ground points in the sensor frame (sensor SENSOR_HEIGHT_M up)."""
    g = np.arange(-half_m, half_m + 1e-9, step_m)
    x, y = np.meshgrid(g, g)
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z_m)]).astype(np.float32)


def box_scene() -> tuple[np.ndarray, np.ndarray]:
    """Plane (minus the box's footprint) plus a 0.3 m box's top and sides; and the box-point mask."""
    ground = plane()
    under = (ground[:, 0] >= BOX_X[0]) & (ground[:, 0] <= BOX_X[1]) & (ground[:, 1] >= BOX_Y[0]) & (ground[:, 1] <= BOX_Y[1])
    ground = ground[~under]
    s = 0.02
    xs, ys, zs = np.arange(BOX_X[0], BOX_X[1] + 1e-9, s), np.arange(BOX_Y[0], BOX_Y[1] + 1e-9, s), np.arange(0.02, BOX_H + 1e-9, s)
    top = np.array([(x, y, BOX_H) for x in xs for y in ys])
    front = np.array([(BOX_X[0], y, z) for y in ys for z in zs])
    sides = np.array([(x, y, z) for x in xs for y in BOX_Y for z in zs])
    box = np.vstack([top, front, sides]) - [0.0, 0.0, SENSOR_HEIGHT_M]
    points = np.vstack([ground, box]).astype(np.float32)
    is_box = np.r_[np.zeros(len(ground), bool), np.ones(len(box), bool)]
    return points, is_box


def cell_centres(m) -> tuple[np.ndarray, np.ndarray]:
    """World x, y of every cell centre, each (ny, nx)."""
    return np.meshgrid(m.x_centres, m.y_centres)


def check_risks_in_unit_interval(m) -> None:
    for name in RISK_LAYERS:
        a = m.layer(name)
        assert a.dtype == np.float32 and a.shape == m.shape
        assert np.all(np.isfinite(a)), name
        assert a.min() >= 0.0 and a.max() <= 1.0, name


@pytest.fixture(scope="module")
def box_maps():
    points, _ = box_scene()
    mapper = subterra.TerrainMapper()
    coarse = mapper.update(points, stamp=0.0, body_from_sensor=translation(z=SENSOR_HEIGHT_M))
    return mapper, coarse


# ------------------------------------------------------------------ synthetic scenes


def test_flat_plane_is_ground_with_risk_near_zero():
    mapper = subterra.TerrainMapper()
    m = mapper.update(plane(), stamp=0.0, body_from_sensor=translation(z=SENSOR_HEIGHT_M))
    s = m.stats
    assert s["ground_points"] / s["kept"] >= 0.99, s
    check_risks_in_unit_interval(m)
    x, y = cell_centres(m)
    seen = m.layer("observed") > 0
    near = (np.hypot(x, y) < 7.0) & seen
    assert near.sum() > 0.9 * (np.pi * 49 - 1.0) / m.resolution**2  # the plane is seen around the robot
    risk = m.layer("risk")
    assert np.percentile(risk[near], 99) <= 0.05, np.percentile(risk[near], 99)
    for name in ("collision", "step", "negative", "tilt"):
        assert m.layer(name)[near].max() == 0.0, name
    assert m.layer("unknown")[~seen].min() == pytest.approx(mapper.config.to_dict()["risk"]["unknown"])
    assert np.nanmax(np.abs(m.layer("ground_height")[near] + 0.0)) < 0.02  # body origin on the ground: z = 0
    assert mapper.last_fine is not None and mapper.last_fine.kind == "fine"
    assert mapper.last_fine.resolution == 0.05 and m.kind == "coarse"


def test_box_makes_lethal_collision_cells_under_it(box_maps):
    _, m = box_maps
    check_risks_in_unit_interval(m)
    x, y = cell_centres(m)
    res = m.resolution
    lethal = m.layer("collision") >= 1.0
    # Exactly under the box, within one cell.
    within_one = (x >= BOX_X[0] - res) & (x <= BOX_X[1] + res) & (y >= BOX_Y[0] - res) & (y <= BOX_Y[1] + res)
    assert lethal.any() and not (lethal & ~within_one).any()
    inside = (x > BOX_X[0] + res) & (x < BOX_X[1] - res) & (y > BOX_Y[0] + res) & (y < BOX_Y[1] - res)
    assert lethal[inside].all()
    assert m.risk_at(3.3, 0.0) == 1.0
    assert m.risk_at(-3.3, 0.0) < 0.05
    assert m.risk_at(1e4, 0.0) is None
    assert lethal_cells(m)["collision"] == int(lethal.sum())


def test_a_rock_just_under_the_clearance_is_a_collision_within_the_margin():
    # A flat-topped rock whose top stands 0.115 m over the floor, under the Husky's 0.13 m
    # clearance: over curved ground the belly rides lower, so within the default 3 cm margin
    # its points count for `collision`; with no margin they do not.
    ground = plane()
    rock_x, rock_y = (3.0, 3.3), (-0.15, 0.15)
    s = 0.02
    top = np.array([(x, y, 0.115) for x in np.arange(*rock_x, s) for y in np.arange(*rock_y, s)]) - [0.0, 0.0, SENSOR_HEIGHT_M]
    points = np.vstack([ground, top]).astype(np.float32)
    mount = translation(z=SENSOR_HEIGHT_M)
    default = subterra.TerrainMapper().update(points, stamp=0.0, body_from_sensor=mount)
    bare = subterra.TerrainMapper(config={"layers": {"clearance_margin_m": 0.0}}).update(points, stamp=0.0, body_from_sensor=mount)
    assert subterra.TerrainConfig().to_dict()["layers"]["clearance_margin_m"] == 0.03
    assert default.layer("collision").max() == 1.0 and default.risk_at(3.15, 0.0) >= default.lethal_risk
    assert bare.layer("collision").max() == 0.0
    with pytest.raises(ConfigError, match="layers.clearance_margin_m"):
        subterra.TerrainConfig({"layers": {"clearance_margin_m": -0.01}})


def test_box_image_and_cvar(box_maps):
    _, m = box_maps
    img = m.to_image()
    assert img.dtype == np.uint8 and img.shape == (*m.shape, 3)
    ix, iy = m.cell_of(3.3, 0.0)
    assert tuple(img[iy, ix]) == (220, 0, 0)  # lethal: red
    ix, iy = m.cell_of(-3.3, 0.0)
    assert img[iy, ix, 1] > 150 and img[iy, ix, 0] < 30  # safe: green
    unseen = m.layer("observed") == 0
    assert unseen.any() and (img[unseen] == 128).all()  # unobserved: grey
    c = m.cvar(0.9)
    assert c.shape == m.shape and c.dtype == np.float32
    assert (c >= m.layer("risk") - 1e-6).all() and c.max() <= 1.0
    assert (c[unseen] > m.layer("risk")[unseen]).all()  # unknown cells carry the largest spread
    x0, x1, y0, y1 = m.extent
    assert (x1 - x0, y1 - y0) == pytest.approx((m.nx * m.resolution, m.ny * m.resolution))
    assert m.origin == pytest.approx((x0, y0))
    assert set(m.layer_names) >= {"tilt", "collision", "risk", "risk_variance", "ground_height", "observed"}


def test_mission_item_makes_a_lethal_circle_of_its_radius():
    mapper = subterra.TerrainMapper()
    centre, radius = (4.0, -2.0), 1.2
    mapper.set_mission_items([(*centre, radius)])
    m = mapper.update(plane(), stamp=0.0, body_from_sensor=translation(z=SENSOR_HEIGHT_M))
    x, y = cell_centres(m)
    d = np.hypot(x - centre[0], y - centre[1])
    mission = m.layer("mission")
    assert (mission[d <= radius - m.resolution] == 1.0).all()
    assert (mission[d > radius + m.resolution] == 0.0).all()
    assert (m.layer("risk")[d <= radius - m.resolution] == 1.0).all()
    # Dict items, and clearing them.
    mapper.set_mission_items([{"position": (0.0, 5.0), "radius": 0.5}])
    m = mapper.update(plane(), stamp=0.1, body_from_sensor=translation(z=SENSOR_HEIGHT_M))
    assert m.value_at("mission", 0.0, 5.0) == 1.0 and m.value_at("mission", *centre) == 0.0
    mapper.set_mission_items([])
    m = mapper.update(plane(), stamp=0.2, body_from_sensor=translation(z=SENSOR_HEIGHT_M))
    assert m.layer("mission").max() == 0.0


def test_segment_ground_plane_and_box():
    points, is_box = box_scene()
    labels = subterra.segment_ground(points, sensor_height=SENSOR_HEIGHT_M)
    assert labels.dtype == np.bool_ and labels.shape == (len(points),)
    assert labels[~is_box].mean() >= 0.99
    high = is_box & (points[:, 2] + SENSOR_HEIGHT_M > 0.15)
    assert (~labels[high]).mean() >= 0.95
    # A stricter line threshold from a dict, and a TerrainConfig, give the same labels as the default here.
    assert (subterra.segment_ground(points, sensor_height=SENSOR_HEIGHT_M, config=subterra.TerrainConfig()) == labels).all()
    strict = subterra.segment_ground(points, sensor_height=SENSOR_HEIGHT_M, config={"ground": {"max_dist_to_line_m": 0.01}})
    assert strict[~is_box].mean() >= 0.99


def test_float64_and_non_contiguous_points_give_the_same_map():
    points, _ = box_scene()
    a = subterra.TerrainMapper().update(points, stamp=0.0, body_from_sensor=translation(z=SENSOR_HEIGHT_M))
    b = subterra.TerrainMapper().update(points.astype(np.float64), stamp=0.0, body_from_sensor=translation(z=SENSOR_HEIGHT_M))
    fortran = np.asfortranarray(points)
    strided = np.hstack([points, points])[:, ::2][:, [0, 1, 2]]
    wide = np.zeros((len(points), 6), np.float32)
    wide[:, ::2] = points
    c = subterra.TerrainMapper().update(fortran, stamp=0.0, body_from_sensor=translation(z=SENSOR_HEIGHT_M))
    d = subterra.TerrainMapper().update(wide[:, ::2], stamp=0.0, body_from_sensor=translation(z=SENSOR_HEIGHT_M))
    for other in (b, c, d):
        for name in ("risk", "count", "collision"):
            np.testing.assert_array_equal(a.layer(name), other.layer(name))
    assert strided.shape == points.shape
    labels = subterra.segment_ground(points, sensor_height=SENSOR_HEIGHT_M)
    np.testing.assert_array_equal(subterra.segment_ground(fortran.astype(np.float64), sensor_height=SENSOR_HEIGHT_M), labels)


def test_nan_points_are_dropped_and_counted():
    points = plane()
    points[::10] = np.nan
    m = subterra.TerrainMapper().update(points, stamp=0.0, body_from_sensor=translation(z=SENSOR_HEIGHT_M))
    assert m.stats["non_finite"] == len(points[::10])
    assert m.stats["input_points"] == len(points)
    check_risks_in_unit_interval(m)


def test_layer_is_a_copy(box_maps):
    _, m = box_maps
    a = m.layer("collision")
    a[:] = 7.0
    assert m.layer("collision").max() <= 1.0


def test_fusion_window_and_confidence():
    points, _ = box_scene()
    mapper = subterra.TerrainMapper()
    for k in range(3):
        pose = translation(x=0.1 * k)
        m = mapper.update(points + [-0.1 * k, 0, 0], stamp=0.1 * k, world_from_body=pose, body_from_sensor=translation(z=SENSOR_HEIGHT_M))
    assert m.scans == 3 and m.stats["fused_scans"] == 3 and mapper.window_len == 3
    # The box stays where it is in the world: same lethal cells as one scan.
    one = subterra.TerrainMapper().update(points, stamp=0.0, body_from_sensor=translation(z=SENSOR_HEIGHT_M))
    assert m.risk_at(3.3, 0.0) == 1.0 and one.risk_at(3.3, 0.0) == 1.0
    m0 = mapper.update(points, stamp=0.3, world_from_body=translation(), body_from_sensor=translation(z=SENSOR_HEIGHT_M), confidence=0.0)
    assert m0.stats["fused_scans"] == 1
    mapper.reset()
    assert mapper.window_len == 0
    mapper.update(points, stamp=0.0, body_from_sensor=translation(z=SENSOR_HEIGHT_M))  # time may restart after reset


def test_default_stamps_advance_by_a_tenth_of_a_second():
    mapper = subterra.TerrainMapper()
    assert mapper.update(plane()).stamp == 0.0
    assert mapper.update(plane()).stamp == pytest.approx(0.1)


# ------------------------------------------------------------------ bad input


def test_bad_points_name_the_argument():
    mapper = subterra.TerrainMapper()
    for bad in (np.zeros((10, 2), np.float32), np.zeros((0, 3), np.float32), np.zeros(9, np.float32),
                np.zeros((4, 3), np.complex64), np.array([["a", "b", "c"]]), "points", None):
        with pytest.raises(InputError, match="points"):
            mapper.update(bad, stamp=0.0)
    with pytest.raises(InputError, match="points"):
        subterra.segment_ground(np.zeros((5, 4)), sensor_height=1.0)
    with pytest.raises(InputError, match="sensor_height"):
        subterra.segment_ground(plane(), sensor_height=float("nan"))


def test_bad_poses_and_values_name_the_argument():
    mapper = subterra.TerrainMapper()
    nan = np.eye(4)
    nan[0, 0] = np.nan
    shear = np.eye(4)
    shear[0, 1] = 0.3
    scaled = np.diag([2.0, 2.0, 2.0, 1.0])
    with pytest.raises(InputError, match="world_from_body"):
        mapper.update(plane(), stamp=0.0, world_from_body=nan)
    with pytest.raises(InputError, match="body_from_sensor"):
        mapper.update(plane(), stamp=0.0, body_from_sensor=shear)
    with pytest.raises(InputError, match="world_from_body"):
        mapper.update(plane(), stamp=0.0, world_from_body=scaled)
    with pytest.raises(InputError, match="world_from_body"):
        mapper.update(plane(), stamp=0.0, world_from_body=np.eye(3))
    with pytest.raises(InputError, match="confidence"):
        mapper.update(plane(), stamp=0.0, confidence=1.5)
    mapper.update(plane(), stamp=1.0)
    with pytest.raises(InputError, match="stamp"):
        mapper.update(plane(), stamp=0.5)
    with pytest.raises(InputError, match="items"):
        mapper.set_mission_items([(0.0, float("nan"), 1.0)])
    with pytest.raises(InputError, match="items"):
        mapper.set_mission_items([(0.0, 1.0)])
    with warnings.catch_warnings():  # a complex item is refused, not cast with a ComplexWarning
        warnings.simplefilter("error")
        with pytest.raises(InputError, match=r"items\[0\]"):
            mapper.set_mission_items([np.array([1 + 1j, 2.0, 1.0])])
        with pytest.raises(InputError, match=r"items\[0\]"):
            mapper.set_mission_items([{"position": np.array([1j, 0.0]), "radius": 1.0}])
    m = mapper.last_coarse
    with pytest.raises(InputError, match="tilts"):
        m.layer("tilts")
    with pytest.raises(InputError, match="alpha"):
        m.cvar(1.5)
    with pytest.raises(InputError, match="x"):
        m.risk_at(float("nan"), 0.0)


def test_absurd_configs_are_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="coarse.resolution_m"):
        subterra.TerrainMapper(config={"coarse": {"resolution_m": -1.0}})
    with pytest.raises(ConfigError, match="coarse.resolution_m"):
        subterra.TerrainMapper(config={"coarse": {"resolution_m": 1e-5}})
    with pytest.raises(ConfigError, match="window_ss"):
        subterra.TerrainMapper(config={"fusion": {"window_ss": 1.0}})
    with pytest.raises(ConfigError, match="robot.ground_clearance_m"):
        subterra.TerrainMapper(robot={"height_m": 0.1})
    with pytest.raises(ConfigError, match="robot"):
        subterra.TerrainMapper(robot=3)
    with pytest.raises(ConfigError, match="max_slope"):
        subterra.segment_ground(plane(), sensor_height=0.7, config={"ground": {"max_slope": -1.0}})
    with pytest.raises(FileFormatError, match="missing.toml"):
        subterra.TerrainMapper(config=tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text(subterra.TerrainConfig().to_toml().replace("window_s = 2.0", "window_s = -2.0"))
    with pytest.raises(ConfigError, match=r"fusion.window_s.*bad.toml"):
        subterra.TerrainMapper(config=str(bad))
    # Partial dicts lie over the defaults.
    c = subterra.TerrainConfig({"coarse": {"resolution_m": 0.2}})
    assert c.to_dict()["coarse"] == {"resolution_m": 0.2, "size_x_m": 20.0, "size_y_m": 20.0}
    r = subterra.RobotConfig({"height_m": 0.6})
    assert r.to_dict()["height_m"] == 0.6 and r.to_dict()["length_m"] == 0.99
    assert subterra.TerrainMapper(robot=r, config=c).update(plane(), stamp=0.0).shape == (100, 100)


def test_committed_default_config_equals_the_built_in_default():
    """configs/terrain.toml is TerrainConfig::default(); a changed default must change the file."""
    path = REPO / "configs" / "terrain.toml"
    assert subterra.TerrainConfig.load(path) == subterra.TerrainConfig()
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    start = next(i for i, line in enumerate(lines) if line.strip() and not line.startswith("#"))  # after the header comment
    assert "".join(lines[start:]) == subterra.TerrainConfig().to_toml()
    assert subterra.TerrainMapper(config=path).config == subterra.TerrainConfig()
    assert subterra.RobotConfig().to_dict() == {
        "length_m": 0.99, "width_m": 0.67, "height_m": 0.4, "ground_clearance_m": 0.13,
        "max_speed_m_s": 1.0, "tilt_safe_deg": 10.0, "tilt_lethal_deg": 25.0,
    }


# ------------------------------------------------------------------ the CLI


def test_cli_writes_every_file(tmp_path):
    from subterra.io import write_pcd
    from subterra.terrain.cli import register_cli

    points, _ = box_scene()
    files = []
    for k in range(3):
        shifted = points - np.float32([0.2 * k, 0.0, 0.0])  # the robot drives 0.2 m per scan
        if k == 1:
            files.append(tmp_path / f"scan{k}.npy")
            np.save(files[-1], shifted)
        else:
            files.append(tmp_path / f"scan{k}.pcd")
            write_pcd(files[-1], shifted, binary=(k == 2))
    poses = tmp_path / "poses.txt"
    poses.write_text("".join(" ".join(f"{v:.9f}" for v in (translation(x=0.2 * k, z=SENSOR_HEIGHT_M))[:3].ravel()) + "\n" for k in range(3)))
    parser = argparse.ArgumentParser()
    register_cli(parser.add_subparsers(dest="command"))
    out = tmp_path / "out"
    args = parser.parse_args(["terrain", *map(str, files), "--poses", str(poses), "--sensor-height", str(SENSOR_HEIGHT_M),
                              "--out", str(out), "--no-progress"])
    assert args.handler(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    names = subterra.TerrainMapper().update(plane()).layer_names
    expected = {f"layer_{n}.png" for n in names} | {"risk.png", "risk_fine.png", "cloud_top.png", "overview.png", "summary.json"}
    assert expected <= {p.name for p in out.iterdir()}
    assert all((out / f).stat().st_size > 1000 for f in expected)
    assert len(summary["scans"]) == 3 and summary["map"]["scans_fused"] == 3
    assert summary["sensor_height_m"] == SENSOR_HEIGHT_M
    assert summary["lethal_cells"]["collision"] > 0
    assert set(summary["layers"]) == set(names) and summary["layers"]["risk"]["max"] == 1.0
    assert summary["stats"]["ground_points"] > 0 and summary["timings"]["total_s"] > 0
    # The estimated sensor height of the plane scene, and the error path.
    assert estimate_sensor_height(points) == pytest.approx(SENSOR_HEIGHT_M, abs=0.03)
    args = parser.parse_args(["terrain", str(tmp_path / "nope.pcd"), "--out", str(out), "--no-progress"])
    with pytest.raises(FileFormatError, match="nope.pcd"):
        args.handler(args)


def test_body_from_sensor_roll_pitch_yaw_is_rz_ry_rx():
    """``x,y,z,roll,pitch,yaw`` [m, deg] is REP 103's fixed-axis rotation Rz(yaw) Ry(pitch) Rx(roll)."""
    from subterra.terrain.cli import parse_body_from_sensor

    def rx(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])

    def ry(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])

    def rz(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])

    m = parse_body_from_sensor("0.1,-0.2,0.7,10,-20,135")
    roll, pitch, yaw = np.radians([10, -20, 135])
    np.testing.assert_allclose(m[:3, :3], rz(yaw) @ ry(pitch) @ rx(roll), atol=1e-12)
    np.testing.assert_array_equal(m[:3, 3], [0.1, -0.2, 0.7])
    np.testing.assert_array_equal(m[3], [0, 0, 0, 1])
    # A quarter turn of yaw takes the sensor's x axis to the body's y axis.
    np.testing.assert_allclose(parse_body_from_sensor("0,0,0,0,0,90")[:3, 0], [0, 1, 0], atol=1e-12)
    with pytest.raises(InputError, match="3, 6, 12 or 16 numbers"):
        parse_body_from_sensor("1,2,3,4")


def test_overview_figure(tmp_path):
    from PIL import Image

    from subterra.viz.terrain import plot_terrain_overview

    points, _ = box_scene()
    mapper = subterra.TerrainMapper()
    risk_map = mapper.update(points, body_from_sensor=translation(z=SENSOR_HEIGHT_M))
    path = plot_terrain_overview(mapper, risk_map, tmp_path / "sub" / "overview.png")
    wide = np.asarray(Image.open(path).convert("RGB"))
    narrow = np.asarray(Image.open(plot_terrain_overview(mapper, risk_map, tmp_path / "two.png", layers=("risk",))).convert("RGB"))
    assert wide.shape[1] > 1.4 * narrow.shape[1]  # six panels in three columns against two
    # The lethal box is drawn in the colour map's red end.
    red = (wide[..., 0] > 150) & (wide[..., 1] < 60) & (wide[..., 2] < 60)
    assert red.sum() > 50
    with pytest.raises(InputError, match="`layers`.*'slop'"):
        plot_terrain_overview(mapper, risk_map, tmp_path / "bad.png", layers=("slop",))


# ------------------------------------------------------------------ real data: Ouster OS1-128


def ransac_plane(points: np.ndarray, *, iterations: int = 300, tol_m: float = 0.05, seed: int = 0) -> tuple[np.ndarray, float]:
    """Unit normal n (n_z > 0) and offset d of the plane n·p + d = 0 with the most inliers, refined by least squares."""
    rng = np.random.default_rng(seed)
    best, best_count = None, -1
    for _ in range(iterations):
        a, b, c = points[rng.choice(len(points), 3, replace=False)]
        n = np.cross(b - a, c - a)
        if np.linalg.norm(n) < 1e-9:
            continue
        n /= np.linalg.norm(n)
        count = np.count_nonzero(np.abs(points @ n - n @ a) < tol_m)
        if count > best_count:
            best, best_count = (n, -n @ a), count
    n, d = best
    inliers = points[np.abs(points @ n + d) < tol_m]
    centre = inliers.mean(axis=0)
    n = np.linalg.svd(inliers - centre)[2][2]
    n = n if n[2] > 0 else -n
    return n, float(-n @ centre)


def levelled(points: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Points rotated so that the plane normal n becomes +z (Rodrigues)."""
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(n, z), float(n @ z)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    r = np.eye(3) + k + k @ k / (1.0 + c)
    return points @ r.T


@pytest.fixture(scope="module")
def ouster(shared_data):
    root = shared_data / "ouster-os1-128-outdoor"
    scans = [np.load(root / f"OS-1-128_scan{i}.npy") for i in range(3)]
    poses_files = sorted(root.glob("*poses_kitti.txt"))
    if not poses_files:
        pytest.skip("the Ouster poses file is absent")
    from subterra.io import read_poses

    poses = read_poses(poses_files[0])
    p = scans[0].astype(np.float64)
    p = p[np.isfinite(p).all(axis=1)]
    r = np.hypot(p[:, 0], p[:, 1])
    n, d = ransac_plane(p[(r >= 5.0) & (r <= 15.0)])
    return scans, poses, n, d


def test_ouster_ground_segmentation(ouster):
    scans, _, n, d = ouster
    p = scans[0].astype(np.float64)
    p = p[np.isfinite(p).all(axis=1)]
    height = d  # the sensor (origin) is d above the plane n·p + d = 0
    assert 0.3 < height < 3.0 and n[2] > 0.98, (height, n)  # a roof- or mast-mounted, nearly level sensor
    labels = subterra.segment_ground(levelled(p, n).astype(np.float32), sensor_height=height)
    above = p @ n + d
    r = np.hypot(p[:, 0], p[:, 1])
    ring = (r >= 5.0) & (r <= 15.0)
    road = ring & (np.abs(above) <= 0.15)
    high = (r <= 15.0) & (above > 0.5)
    ground_rate, obstacle_rate = labels[road].mean(), (~labels[high]).mean()
    print(f"OS1-128 scan0: sensor {height:.3f} m up, tilt {np.degrees(np.arccos(n[2])):.2f} deg; "
          f"road points {road.sum()} -> {100 * ground_rate:.2f}% ground; points >0.5 m up {high.sum()} -> {100 * obstacle_rate:.2f}% obstacle")
    assert road.sum() > 10_000 and high.sum() > 1_000
    assert ground_rate >= 0.95
    assert obstacle_rate >= 0.95
    # The histogram estimate the CLI uses agrees with RANSAC.
    assert estimate_sensor_height(p) == pytest.approx(height, abs=0.1)


def obstacle_cells(m) -> set[tuple[int, int]]:
    """Global indices (gx, gy) of the cells with lethal collision risk."""
    iy, ix = np.nonzero(m.layer("collision") >= 1.0)
    gx0, gy0 = m.origin_cell
    return set(zip((ix + gx0).tolist(), (iy + gy0).tolist()))


def dilated(cells: set[tuple[int, int]]) -> set[tuple[int, int]]:
    return {(x + dx, y + dy) for x, y in cells for dx in (-1, 0, 1) for dy in (-1, 0, 1)}


def test_ouster_scans_fuse_without_smearing(ouster):
    scans, poses, _, d = ouster
    body_from_sensor = translation(z=d)
    sensor_from_body = np.linalg.inv(body_from_sensor)

    def fused(pose_list, which):
        mapper = subterra.TerrainMapper()
        for n, k in enumerate(which):
            m = mapper.update(scans[k], stamp=0.1 * n, world_from_body=pose_list[k] @ sensor_from_body, body_from_sensor=body_from_sensor)
        return m

    alone = obstacle_cells(fused(poses, [0]))
    # Every obstacle cell some scan alone, at its pose, holds: fusing adds what the other
    # viewpoints saw, and a smear is what no single scan saw.
    singles = set().union(*(obstacle_cells(fused(poses, [k])) for k in range(3)))
    together_map = fused(poses, [0, 1, 2])
    together = obstacle_cells(together_map)
    smeared = obstacle_cells(fused([np.eye(4)] * 3, [0, 1, 2]))  # control: the robot's motion ignored
    assert together_map.scans == 3
    recall = len(alone & together) / len(alone)
    precision = len(together & dilated(singles)) / len(together)
    precision_smeared = len(smeared & dilated(singles)) / len(smeared)
    print(f"OS1-128 fusion: {len(alone)} obstacle cells alone, {len(singles)} in some scan, {len(together)} fused; "
          f"recall {recall:.3f}, fused within 1 cell of a single scan's: {precision:.3f} (identity poses: {precision_smeared:.3f})")
    assert len(alone) > 200
    assert recall >= 0.9
    assert precision >= 0.9
    assert precision > precision_smeared


def test_sensor_height_indoors_is_the_lowest_dense_layer():
    # Regression (OS1-64 lab recording): a room whose walls fill every z bin above a sparse
    # floor put the histogram mode on a wall, 0.37 m *above* the sensor.
    rng = np.random.default_rng(4)
    angle = rng.uniform(0, 2 * np.pi, 40_000)
    walls = np.c_[6 * np.cos(angle), 6 * np.sin(angle), rng.uniform(-0.3, 2.0, angle.size)]
    walls[: angle.size // 4, 2] = rng.normal(0.35, 0.02, angle.size // 4)  # a dense shelf at +0.35 m
    r = rng.uniform(3.0, 5.9, 1_500)
    phi = rng.uniform(0, 2 * np.pi, r.size)
    floor = np.c_[r * np.cos(phi), r * np.sin(phi), rng.normal(-0.8, 0.01, r.size)]
    stray = np.c_[rng.uniform(3, 5, (3, 2)), [-1.6, -1.7, -1.9]]  # a few low outliers do not count
    points = np.vstack([walls, floor, stray]).astype(np.float32)
    assert estimate_sensor_height(points) == pytest.approx(0.8, abs=0.03)
