"""``subterra.Pilot``: the drone's loop in Rust, called the same way by ``fly``, ``perceive`` and
``replay``. Its bits are the Rust crate's (a digest both sides must reproduce), and they equal
the parts composed by hand; ``perceive`` and ``replay`` with ``flight-memory`` run the memory."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from subterra import ApfController, DepthPerception, Escape, ObstacleMemory, Pilot, PinholeCamera, errors
from subterra.perceive import run_perception

REPO = Path(__file__).resolve().parents[2]
PARITY = REPO / "tests" / "data" / "pilot_parity.txt"


def canonical_frame(n: int) -> np.ndarray:
    """Frame ``n`` of ``crates/subterra/tests/pilot_parity.rs``: a box closing in from 1.5 m at
    35 mm a frame, and on every third frame a thin pole 0.4 m ahead on the right (the memory's
    near-field guard takes it, the belief does not)."""
    depth = np.zeros((480, 640), np.uint16)
    depth[160:320, 220:420] = 1500 - 35 * n
    if n % 3 == 0:
        depth[:, 500:506] = 400
    return depth


def fnv1a(h: int, values) -> int:
    for b in np.asarray(values, dtype="<f8").tobytes():
        h ^= b
        h = (h * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return h


def pose(x: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, 0.0, 1.0)
    return m


def committed() -> dict[str, str]:
    lines = [line.split() for line in PARITY.read_text().splitlines() if line and not line.startswith("#")]
    return {k: v for k, v in lines}


@pytest.mark.parametrize(("key", "preset", "controller"), [("flight-escape/apf-pf", "flight-escape", "apf-pf"),
                                                           ("acc2021/apf-pf-qmdp", "acc2021", "apf-pf-qmdp")])
def test_python_reproduces_the_rust_digest(key: str, preset: str, controller: str) -> None:
    pilot = Pilot(PinholeCamera.d435(), preset, controller=controller, seed=11)
    pilot.set_goal([6.0, 0.5, 1.0])
    h = 0xCBF29CE484222325
    for n in range(30):
        out = pilot.step(canonical_frame(n), stamp=n / 15.0, world_from_body=pose(0.03 * n))
        c = out.command
        h = fnv1a(h, [c.v_x_m_s, c.v_y_m_s, c.v_z_m_s, c.yaw_rate_rad_s, *out.repulsive_body, out.perceptions[0].p_free])
    assert f"{h:016x}" == committed()[key]


def test_the_pilot_is_its_parts_composed_by_hand() -> None:
    camera = PinholeCamera.d435()
    pilot = Pilot(camera, "flight-escape", seed=4)
    goal = np.array([7.0, -0.4, 1.0])
    pilot.set_goal(goal)
    perception = DepthPerception(camera, "flight-escape", seed=4)
    memory = ObstacleMemory(perception)
    escape = Escape("flight-escape")
    controller = ApfController("flight-escape")
    remembered_any = False
    for n in range(24):
        depth, at, stamp = canonical_frame(n), pose(0.03 * n), n / 15.0
        got = pilot.step(depth, stamp=stamp, world_from_body=at)
        out = perception.update(depth)
        remembered = memory.update(out, stamp=stamp, world_from_body=at, perception=perception)
        rep = out.repulsive_body + remembered.repulsive_body
        e = escape.step(stamp=stamp, world_from_body=at, goal_world=goal, remaining_m=float(np.linalg.norm(goal - at[:3, 3])),
                        memory=memory, repulsive_body=rep)
        cmd = controller.command(e.goal_body, repulsive_body=e.repulsive_body)
        assert np.array_equal(got.perceptions[0].belief_states, out.belief_states)
        assert np.array_equal(got.belief_push_body, out.repulsive_body)
        assert np.array_equal(got.memory_repulsive_body, remembered.repulsive_body)
        assert got.memory_cells == remembered.cells
        assert np.array_equal(got.command.as_array(), cmd.as_array()), n
        remembered_any |= remembered.cells > 0
    assert remembered_any and len(pilot.memory_points_world()) == len(memory)


def test_a_path_is_followed_with_its_carrot() -> None:
    pilot = Pilot(PinholeCamera.d435(), "flight")
    pilot.set_path([[0, 0, 1], [4, 0, 1], [4, 4, 1]], lookahead_m=1.5)
    assert pilot.path_length_m == pytest.approx(8.0)
    out = pilot.step(np.zeros((480, 640), np.uint16), stamp=0.0, world_from_body=pose(0.0))
    np.testing.assert_allclose(out.target_world, [1.5, 0.0, 1.0])
    assert out.remaining_m == pytest.approx(8.0) and out.command.v_x_m_s > 0 and out.escape is None


def test_two_cameras_each_push_and_take_a_frame_each() -> None:
    up = np.array([[0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], float)  # optical z -> body z
    cam = PinholeCamera.d435()
    pilot = Pilot([cam, (cam, up)], "flight", controller="raw-apf")
    pilot.set_goal([5, 0, 1])
    wall, empty = canonical_frame(20), np.zeros((480, 640), np.uint16)
    ahead = pilot.step([wall, empty], stamp=0.0, world_from_body=pose(0.0))
    above = pilot.step([empty, wall], stamp=0.1, world_from_body=pose(0.0))
    assert ahead.belief_push_body[0] < 0 and above.belief_push_body[2] < 0
    np.testing.assert_array_equal(ahead.belief_push_body, ahead.perceptions[0].repulsive_body + ahead.perceptions[1].repulsive_body)
    with pytest.raises(errors.InputError, match="argument `frames` must hold one depth image per camera"):
        pilot.step(wall, stamp=0.2, world_from_body=pose(0.0))


def test_bad_arguments_name_themselves() -> None:
    cam = PinholeCamera.d435()
    with pytest.raises(errors.InputError, match="argument `controller`"):
        Pilot(cam, controller="nope")
    with pytest.raises(errors.InputError, match="argument `cameras`.*exactly one camera"):
        Pilot([cam, cam], controller="apf-pf-qmdp")
    with pytest.raises(errors.InputError, match="argument `cameras\\[1\\]`"):
        Pilot([cam, "cam"])
    with pytest.raises(errors.InputError, match="argument `qmdp` applies to controller"):
        Pilot(cam, qmdp={})
    pilot = Pilot(cam)
    with pytest.raises(errors.InputError, match="no goal"):
        pilot.step(np.zeros((480, 640), np.uint16), stamp=0.0, world_from_body=np.eye(4))
    pilot.set_goal([3, 0, 0])
    with pytest.raises(errors.InputError, match="argument `depth` has shape"):
        pilot.step(np.zeros((48, 64), np.uint16), stamp=0.0, world_from_body=np.eye(4))
    with pytest.raises(errors.InputError, match="argument `world_from_body`"):
        pilot.step(np.zeros((480, 640), np.uint16), stamp=0.0, world_from_body=np.full((4, 4), np.nan))
    with pytest.raises(errors.InputError, match="argument `goal_world`"):
        pilot.set_goal([np.nan, 0, 0])


def test_odometry_confidence_shortens_the_memory() -> None:
    """At confidence 0 the memory keeps only the newest frame's cells; a frame with nothing
    in it then leaves it empty, where at confidence 1 the box is still remembered."""
    cam = PinholeCamera.d435()
    kept = {}
    for confidence in (1.0, 0.0):
        pilot = Pilot(cam, "flight-memory")
        pilot.set_goal([5, 0, 1])
        for i in range(10):
            pilot.step(canonical_frame(i), stamp=0.1 * i, world_from_body=pose(0.0), confidence=confidence)
        kept[confidence] = pilot.step(np.zeros((480, 640), np.uint16), stamp=1.0, world_from_body=pose(0.0),
                                      confidence=confidence).memory_cells
    assert kept[1.0] > 0 and kept[0.0] == 0
    with pytest.raises(errors.InputError, match="argument `confidence`"):
        pilot.step(canonical_frame(0), stamp=2.0, world_from_body=pose(0.0), confidence=1.5)


def box_sequence(n: int = 24):
    for i in range(n):
        yield f"{i}", canonical_frame(i), 0.001


@pytest.mark.parametrize(("preset", "remembers"), [("flight", False), ("flight-memory", True)])
def test_perceive_runs_the_presets_memory(preset: str, remembers: bool) -> None:
    pilot, records = run_perception(box_sequence(), PinholeCamera.d435(), preset=preset, progress=False)
    cells = [r["memory_cells"] for r in records]
    assert pilot.has_memory is remembers
    assert (max(cells) > 0) is remembers
    # Everything seen lies beyond the memory's 0.6 m cut-off: it holds, but does not push.
    assert all(r["memory_repulsive_body"] == [0.0, 0.0, 0.0] for r in records)


def test_replay_runs_the_presets_memory(tmp_path: Path) -> None:
    pytest.importorskip("rosbags")
    pytest.importorskip("mcap")
    from subterra.io import Intrinsics, ros
    from subterra.io.recordings import McapWriter
    from subterra.replay import replay

    intr = Intrinsics(96.0, 96.0, 79.5, 59.5, 160, 120)
    path = tmp_path / "box.mcap"
    t0, period = 1_700_000_000_000_000_000, 66_666_667
    with McapWriter(path) as w:
        for i in range(10):
            f = np.zeros((120, 160), np.uint16)
            f[30:90, 50:110] = 800 - 10 * i
            s = t0 + i * period
            w.write("/info", ros.camera_info_message(intr, stamp_ns=s, frame_id="cam"), log_time_ns=s)
            w.write("/depth", ros.image_message(f, stamp_ns=s, frame_id="cam"), log_time_ns=s + 1)
    for preset, remembers in (("flight", False), ("flight-memory", True)):
        out = tmp_path / preset
        replay(path, out, depth_topic="/depth", info_topic="/info", preset=preset, progress=False, rerun=False, plots=False)
        summary = json.loads((out / "summary.json").read_text())
        assert summary["completed"] is True and summary["memory"] is remembers
        assert (max(r["memory_cells"] for r in summary["records"]) > 0) is remembers
