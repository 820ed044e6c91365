"""Inputs that once killed the process, hung it or were accepted as garbage, through the
compiled core: each gives the error named here, at once, without allocating what it implies.

Resource limits are checked on the view before any copy (a broadcast 10^10-element array costs
nothing to make and must cost nothing to refuse), physically absurd values are errors, every
argument conversion names its argument, config errors name the field, and the stateful objects
can be shared between threads (calls run one at a time)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import subterra
import subterra.sim
import subterra.terrain
from subterra.errors import ConfigError, InputError
from subterra.sim import DepthCamera

HUGE = (100_000, 100_000)


def _huge(dtype) -> np.ndarray:
    """A read-only view of 10^10 elements backed by one."""
    return np.broadcast_to(np.zeros(1, dtype), HUGE)


def _config(**grid) -> subterra.PerceptionConfig:
    d = subterra.PerceptionConfig.preset("flight").to_dict()
    d["grid"].update(grid)
    return subterra.PerceptionConfig.from_dict(d)


# ------------------------------------------------------------------ resource limits


def test_a_grid_whose_transition_model_would_not_fit_is_a_config_error():
    # 1 cm bins over 0.1-10.1 m: 130k states, about 26 GB of transition tables (aborted).
    with pytest.raises(ConfigError, match=r"grid\.depth_bin_m.*GB"):
        subterra.DepthPerception(subterra.PinholeCamera.d435(), config=_config(depth_bin_m=0.01, depth_min_m=0.1, depth_max_m=10.1))
    # 500 bins (took 18 s and 5.5 GB).
    with pytest.raises(ConfigError, match=r"grid\.depth_bin_m"):
        subterra.DepthPerception(subterra.PinholeCamera.d435(), config=_config(depth_bin_m=0.02, depth_min_m=0.1, depth_max_m=10.1))


@pytest.mark.parametrize(
    "call",
    [
        lambda: subterra.DepthPerception(subterra.PinholeCamera.d435()).update(_huge(np.uint16)),
        lambda: subterra.DepthPerception(subterra.PinholeCamera.d435()).update(_huge(np.float32)),
        lambda: subterra.RiskAStar().plan(_huge(np.float32), [0, 0], [1, 1], resolution=0.1),
        lambda: subterra.RiskAStar().plan(_huge(np.float64), [0, 0], [1, 1], resolution=0.1),
        lambda: subterra.MpcTracker().solve([0, 0, 0, 0], [[0, 0], [1, 0]], risk=_huge(np.float32), resolution=0.1, origin=(0, 0)),
        lambda: subterra.MpcTracker().solve([0, 0, 0, 0], [[0, 0], [1, 0]], risk=_huge(np.float64), resolution=0.1, origin=(0, 0)),
        lambda: subterra.MpcTracker().solve([0, 0, 0, 0], np.broadcast_to(np.zeros(2), (10**9, 2))),
        lambda: subterra.TerrainMapper().update(_huge(np.float32)),
        lambda: subterra.TerrainMapper().update(np.broadcast_to(np.ones(3, np.float64), (10**9, 3))),
        lambda: subterra.RiskAStar().plan(np.zeros((4, 4), np.float32), np.broadcast_to(np.zeros(1), (10**8,)), [1, 1], resolution=0.1),
        # Once walked point by point (minutes, then gigabytes) before any limit was checked.
        lambda: subterra.PathFollower(np.broadcast_to(np.zeros(3), (10**9, 3))),
        lambda: subterra.Pilot(subterra.PinholeCamera.d435()).set_path(np.broadcast_to(np.zeros(3), (10**9, 3))),
        # Once copied to float64 first: a MemoryError asking for 22 GiB.
        lambda: subterra.terrain.estimate_sensor_height(np.broadcast_to(np.ones(3, np.float32), (10**9, 3))),
    ],
    ids=["depth-u16", "depth-f32", "astar-f32", "astar-f64", "mpc-f32", "mpc-f64", "mpc-path", "terrain", "terrain-f64", "astar-start",
         "follower-path", "pilot-path", "sensor-height"],
)
def test_a_huge_view_is_refused_before_it_is_copied(call):
    with pytest.raises(InputError, match=r"argument `(depth|risk|reference_path|points|start|path)`"):
        call()


def test_a_path_without_a_length_stops_at_the_limit():
    points = ([float(i), 0.0, 0.0] for i in range(2**20 + 1))
    with pytest.raises(InputError, match=r"argument `path` has 1048577 points: more than 1048576"):
        subterra.PathFollower(points)


@pytest.mark.parametrize("value", [None, float("nan"), float("inf"), "1.0", True, 1 + 0j])
def test_a_translation_is_three_finite_real_numbers(value):
    # Once np.eye(4) with NaN (from None) or 1.0 (from "1.0") in its last column.
    with pytest.raises(InputError, match="argument `y` must be a finite real number"):
        subterra.terrain.translation(0.0, value, 0.0)
    assert subterra.terrain.translation(1, np.float32(2), np.int64(3))[:3, 3].tolist() == [1.0, 2.0, 3.0]


@pytest.mark.parametrize(
    ("kwargs", "phrase"),
    [
        ({"ring_m": (1.0,)}, "argument `ring_m` must be 2 numbers"),
        ({"ring_m": None}, "argument `ring_m` must be 2 numbers"),
        ({"ring_m": (15.0, 3.0)}, "argument `ring_m` must be \\(min, max\\)"),
        ({"ring_m": (0.0, float("inf"))}, "argument `ring_m` must be a finite real number"),
        ({"points": np.zeros((10, 3), "U2")}, "argument `points` must be a real"),
        ({"points": "points"}, "argument `points` must be a real"),
    ],
)
def test_estimate_sensor_height_arguments_are_checked(kwargs, phrase):
    # Once IndexError, TypeError, UFuncTypeError or a height from an infinite ring.
    args = {"points": np.zeros((10, 3), np.float32)} | kwargs
    with pytest.raises(InputError, match=phrase):
        subterra.terrain.estimate_sensor_height(args.pop("points"), **args)


def test_too_many_points_is_reported_with_the_whole_shape():
    # The message printed the first axis only ("has shape [1000000000]"), as if 1-D.
    for dtype in (np.float32, np.float64):
        with pytest.raises(InputError, match=r"argument `points` has shape \[1000000000, 3\]: more than"):
            subterra.TerrainMapper().update(np.broadcast_to(np.ones(3, dtype), (10**9, 3)))


def test_the_depth_image_must_have_the_camera_shape():
    p = subterra.DepthPerception(subterra.PinholeCamera.d435())
    with pytest.raises(InputError, match=r"must be \(480, 640\)"):
        p.update(np.zeros((640, 480), np.uint16))
    with pytest.raises(InputError, match="argument `scale`"):
        p.update(np.zeros((480, 640), np.uint16), scale=float("nan"))


def test_a_camera_the_simulator_cannot_render_is_refused():
    big = subterra.PinholeCamera(1000, 1000, 2047.5, 2047.5, 4096, 4096)
    with pytest.raises(ConfigError, match="camera.height"):
        DepthCamera(big)
    with pytest.raises(ConfigError, match="pixels"):
        subterra.PinholeCamera(1000, 1000, 8000, 8000, 16384, 16384)


# ------------------------------------------------------------------ physically absurd values


@pytest.mark.parametrize("fx", [1e-310, 1e-3, 0.5, 1e7])
def test_a_focal_length_no_camera_has_is_refused(fx):
    # A denormal focal length once gave NaN forces (and the error named `repulsive_body`).
    with pytest.raises(ConfigError, match=r"camera\.fx.*\[1, 1e6\] px"):
        subterra.PinholeCamera(fx, 300, 320, 240, 640, 480)


def test_a_denormal_is_printed_short():
    with pytest.raises(ConfigError) as info:
        subterra.PinholeCamera(1e-310, 300, 320, 240, 640, 480)
    assert len(str(info.value)) < 200 and "1e-310" in str(info.value)


def test_a_principal_point_far_off_the_image_is_refused():
    with pytest.raises(ConfigError, match=r"camera\.cx"):
        subterra.PinholeCamera(300, 300, 1e9, 240, 640, 480)


@pytest.mark.parametrize("t", [1e308, -2e6, 1.5e6])
def test_a_pose_far_beyond_any_world_is_refused(t):
    # Translated by 1e308 the map origin became 9.2e17 and plans were "found".
    pose = np.eye(4)
    pose[1, 3] = t
    points = np.random.default_rng(0).normal(size=(100, 3))
    with pytest.raises(InputError, match=r"world_from_body.*re-centre"):
        subterra.TerrainMapper().update(points, world_from_body=pose)
    with pytest.raises(InputError, match="world_from_body"):
        subterra.Navigator([5, 0]).step(points, world_from_body=pose)


def test_a_vehicle_cannot_start_far_off_the_world():
    # A start translated by 1e308 once gave a simulation (and the error of a NaN named `vehicle`).
    world = subterra.sim.World.scenario("highbay", 0)
    for start in ([1e308, 0, 1], [0, -1e7, 1]):
        for vehicle in ("quadrotor", "ground"):
            with pytest.raises(InputError, match=r"argument `start`.*outside the world"):
                subterra.sim.Simulation(world, vehicle, start=start)


def test_a_vehicle_starting_in_collision_names_start():
    # The Rust constructor names its `vehicle`; from Python the place is `start`.
    world = subterra.sim.World.scenario("highbay", 0)
    with pytest.raises(InputError, match=r"argument `start`.*starts in collision"):
        subterra.sim.Simulation(world, "quadrotor", start=[0, 0, 0])


def test_a_complex_pose_is_refused_not_made_real():
    # It was cast to float64 with only a ComplexWarning, the imaginary part dropped.
    from subterra.io.ros import TransformBuffer

    pose = np.eye(4, dtype=complex)
    pose[0, 3] = 5j
    points = np.random.default_rng(0).normal(size=(100, 3))
    with pytest.raises(InputError, match=r"world_from_body.*real numbers.*complex"):
        subterra.TerrainMapper().update(points, world_from_body=pose)
    with pytest.raises(InputError, match=r"world_from_body.*real numbers"):
        subterra.Navigator([5, 0]).step(points, stamp=0.0, world_from_body=pose)
    with pytest.raises(InputError, match=r"body_from_sensor.*real numbers"):
        subterra.Navigator([5, 0]).step(points, stamp=0.0, world_from_body=np.eye(4), body_from_sensor=pose)
    with pytest.raises(InputError, match="real numbers"):
        TransformBuffer().add("odom", "base", pose)
    with pytest.raises(InputError, match="shape"):
        subterra.TerrainMapper().update(points, world_from_body=np.broadcast_to(np.eye(4)[0], (100000, 4)))


def test_risk_outside_0_1_and_complex_arrays_are_refused():
    for bad in (2.0, np.inf, -0.5):
        risk = np.zeros((8, 8), np.float32)
        risk[3, 4] = bad
        with pytest.raises(InputError, match=r"risk.*row 3, column 4"):
            subterra.RiskAStar().plan(risk, [0.05, 0.05], [0.75, 0.75], resolution=0.1)
    with pytest.raises(InputError, match="complex"):
        subterra.RiskAStar().plan(np.zeros((8, 8), np.complex64), [0.05, 0.05], [0.75, 0.75], resolution=0.1)
    with pytest.raises(InputError, match=r"argument `points`.*real numbers"):
        subterra.TerrainMapper().update(np.zeros((10, 3), np.complex128))


@pytest.mark.parametrize("resolution", [5e-324, 1e-9, 1e-4])
def test_a_cell_finer_than_a_millimetre_is_refused(resolution):
    # Found by the mpc_solve fuzz target: a denormal resolution made every step of the
    # horizon thousands of cells long, 0.4 s per solve on a 10 x 7 grid.
    risk = np.zeros((10, 7), np.float32)
    with pytest.raises(InputError, match=r"resolution.*must be in \[1e-3, 1e4\] m"):
        subterra.MpcTracker().solve([4, 4, 4, 4], [[0, 0], [2, 0]], risk=risk, resolution=resolution, origin=(0, 0))
    with pytest.raises(InputError, match=r"resolution.*must be in \[1e-3, 1e4\] m"):
        subterra.RiskAStar().plan(risk, [0.0, 0.0], [0.0, 0.0], resolution=resolution)


@pytest.mark.parametrize("value", [np.complex64(1 + 1j), np.array(1 + 2j), np.bool_(True)])
def test_a_complex_or_boolean_numpy_scalar_is_not_a_real_number(value):
    # float() of a NumPy complex64 drops the imaginary part with only a warning.
    with pytest.raises(InputError, match="argument `lookahead_m` must be a real number"):
        subterra.PathFollower([[0, 0, 0], [1, 0, 0]], lookahead_m=value)


def test_a_simulator_command_of_complex_numbers_is_refused():
    s = subterra.sim.Simulation(subterra.sim.World.scenario("highbay", 0), "quadrotor", start=[2.0, 2.0, 1.0])
    with pytest.raises(InputError, match=r"argument `command`.*real numbers"):
        s.step(np.array([1j, 0, 0, 0]))
    with pytest.raises(InputError, match=r"argument `command`.*got 3 numbers"):
        s.step([0.1, 0.0, 0.0])
    s.step(np.zeros(4, np.float32))  # any real dtype is fine


@pytest.mark.parametrize("goal", [[1, 2, 3], [1], [[1, 2], [3, 4]], [1, float("nan")], [1j, 2]])
def test_a_navigator_goal_is_two_finite_numbers(goal):
    # [1, 2, 3] once dropped z silently.
    with pytest.raises(InputError, match="argument `goal`"):
        subterra.Navigator(goal)


def test_an_obstacle_memory_takes_only_its_own_perceptions_outputs():
    d = subterra.PerceptionConfig.preset("flight-memory")
    own = subterra.DepthPerception(subterra.PinholeCamera.d435(), config=d)
    other = subterra.DepthPerception(subterra.PinholeCamera(200, 200, 99.5, 99.5, 200, 200), config=d)
    memory = subterra.ObstacleMemory(own)
    with pytest.raises(InputError, match=r"argument `output`.*different perception"):
        memory.update(other.update(np.full((200, 200), 1000, np.uint16)), stamp=0.0, world_from_body=np.eye(4))
    memory.update(own.update(np.full((480, 640), 1000, np.uint16)), stamp=0.0, world_from_body=np.eye(4))


# ------------------------------------------------------------------ errors that name their argument


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"fx": None}, "fx"),
        ({"fy": "300"}, "fy"),
        ({"cx": 1j}, "cx"),
        ({"width": 2**64}, "width"),
        ({"height": -1}, "height"),
        ({"width": 640.5}, "width"),
        ({"height": True}, "height"),
    ],
)
def test_camera_arguments_are_named(kwargs, name):
    # A value of the right type but out of range is a ConfigError naming `camera.<name>`; a
    # value of the wrong type an InputError naming the argument.
    args = {"fx": 300.0, "fy": 300.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480, **kwargs}
    with pytest.raises((InputError, ConfigError), match=f"(argument `|camera\\.){name}`") as info:
        subterra.PinholeCamera(**args)
    # Not the range of the 128-bit integer the binding reads sides into.
    assert "170141183460469231731687303715884105727" not in str(info.value)


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda p: p.state_of(1.5, 0, 0), "i"),
        (lambda p: p.state_of(0, 0, 2**70), "k"),
        (lambda p: p.transition_row("1"), "state"),
        (lambda p: p.update(np.zeros((480, 640), np.uint16), scale="1"), "scale"),
        (lambda p: subterra.TerrainMapper().update(np.ones((10, 3)), confidence=None), "confidence"),
        (lambda p: subterra.TerrainMapper().update(np.ones((10, 3)), stamp="now"), "stamp"),
        (lambda p: subterra.sim.Simulation(subterra.sim.World.scenario("highbay", 0), "quadrotor", yaw=None), "yaw"),
        (lambda p: subterra.sim.World.scenario("mine", -1), "seed"),
        (lambda p: subterra.PathFollower([[0, 0, 0], [1, 0, 0]], lookahead_m=[1.0]), "lookahead_m"),
        (lambda p: subterra.Navigator([5, 0]).step(None, world_from_body=np.eye(4), speed=1j), "speed"),
        (lambda p: subterra.PerceptionConfig.preset(3), "name"),
        (lambda p: subterra.PerceptionConfig.preset("\udc80"), "name"),
        (lambda p: subterra.DepthPerception(subterra.PinholeCamera.d435(), preset=None), "preset"),
        (lambda p: subterra.DepthPerception(subterra.PinholeCamera.d435(), mode=2), "mode"),
        (lambda p: p.voxel_centres(frame=b"camera"), "frame"),
        (lambda p: subterra.sim.World.scenario(None), "name"),
        (lambda p: subterra.sim.Lidar(preset=["vlp16"]), "preset"),
        (lambda p: subterra.TerrainMapper().update(np.ones((10, 3))).layer(0), "name"),
        # Arguments typed as a subterra class or a Python int once gave pyo3's bare TypeError
        # ("'None' is not an instance of 'PinholeCamera'") or OverflowError, naming nothing.
        (lambda p: subterra.DepthPerception(None), "camera"),
        (lambda p: subterra.ObstacleMemory("p"), "perception"),
        (lambda p: subterra.ObstacleMemory(p).update(None, stamp=0.0, world_from_body=np.eye(4)), "output"),
        (lambda p: subterra.Qmdp(p).act(1), "output"),
        (lambda p: subterra.Escape().step(stamp=0.0, world_from_body=np.eye(4), goal_world=[1, 0, 0], remaining_m=1.0, memory=3), "memory"),
        (lambda p: subterra.sim.Simulation("highbay"), "world"),
        (lambda p: subterra.sim.DepthCamera("d435"), "camera"),
        (lambda p: subterra.sim.Lidar().scan(None, np.eye(4)), "world"),
        (lambda p: subterra.sim.Simulation(subterra.sim.World.scenario("highbay", 0), start=[2.0, 2.0, 1.0]).add_depth_camera("c", subterra.PinholeCamera.d435()), "camera"),
        (lambda p: subterra.sim.Simulation(subterra.sim.World.scenario("highbay", 0), start=[2.0, 2.0, 1.0]).set_goal(region=1), "region"),
        (lambda p: subterra.Pilot(subterra.PinholeCamera.d435()).camera(-1), "n"),
        (lambda p: subterra.Pilot(subterra.PinholeCamera.d435()).perception_info("0"), "n"),
        (lambda p: subterra.Pilot(subterra.PinholeCamera.d435()).step(np.zeros((480, 640), np.uint16), stamp=0.0, world_from_body=np.eye(4), confidence="1"), "confidence"),
        # np.complex128(1) was once taken as 1.0 with only a ComplexWarning.
        (lambda p: subterra.RiskAStar().plan(np.zeros((4, 4), np.float32), [0.1, 0.1], [0.2, 0.2], resolution=np.complex128(1)), "resolution"),
    ],
    ids=["float-index", "huge-index", "str-state", "str-scale", "none-confidence", "str-stamp", "none-yaw", "negative-seed", "list-lookahead", "complex-speed",
         "int-preset-name", "surrogate-name", "none-preset", "int-mode", "bytes-frame", "none-scenario", "list-lidar-preset", "int-layer",
         "none-camera", "str-perception", "none-output", "int-output", "int-memory", "str-world", "str-sim-camera", "none-world",
         "pinhole-for-depth-camera", "int-region", "negative-n", "str-n", "str-pilot-confidence", "complex-resolution"],
)
def test_a_value_of_the_wrong_type_is_an_input_error_naming_the_argument(call, name):
    # pyo3's own conversion raised a bare TypeError or OverflowError ("while processing 'x'"
    # only as a note, which the CLI's one-line errors do not show).
    perception = subterra.DepthPerception(subterra.PinholeCamera.d435())
    with pytest.raises(InputError, match=f"argument `{name}`"):
        call(perception)


def test_seed_errors_name_the_seed():
    with pytest.raises(InputError, match="argument `seed`"):
        subterra.DepthPerception(subterra.PinholeCamera.d435(), seed=-1)


def test_config_parse_errors_name_the_field_on_one_line():
    toml = subterra.PerceptionConfig.preset("flight").to_toml()
    with pytest.raises(ConfigError) as info:
        subterra.PerceptionConfig.from_toml(toml.replace("particles = 20000", "particles = -5"))
    message = str(info.value)
    assert "filter.particles" in message and "line" in message and "\n" not in message
    with pytest.raises(ConfigError) as info:
        subterra.PerceptionConfig.from_toml("[[[[ ]]] = ==")
    assert "\n" not in str(info.value) and "line 1" in str(info.value)


def test_a_nan_in_a_config_dict_names_the_field():
    # Once "expected value at line 1 column 29".
    d = subterra.PerceptionConfig.preset("flight").to_dict()
    d["grid"]["depth_bin_m"] = float("nan")
    with pytest.raises(ConfigError, match=r"grid\.depth_bin_m.*finite"):
        subterra.PerceptionConfig.from_dict(d)
    with pytest.raises(ConfigError, match=r"planner\.lam.*finite"):
        subterra.Navigator([5, 0], config={"planner": {"lam": float("inf")}})
    with pytest.raises(ConfigError, match=r"field `planner\.lam`"):
        subterra.Navigator([5, 0], config={"planner": {"lam": "x"}})
    with pytest.raises(ConfigError, match="NaN"):
        subterra.PerceptionConfig.from_json('{"grid": {"depth_bin_m": NaN}}')


def test_a_deeply_nested_config_is_an_error_not_a_recursion_error():
    deep: dict = {}
    node = deep
    for _ in range(10_000):
        node["a"] = {}
        node = node["a"]
    with pytest.raises(ConfigError, match="nested deeper"):
        subterra.Navigator([5, 0], config=deep)
    with pytest.raises(ConfigError, match="could not be parsed"):
        subterra.PerceptionConfig.from_json("[" * 100_000 + "]" * 100_000)


# ------------------------------------------------------------------ threads


def _hammer(objects_and_calls, threads=4, rounds=20):
    errors: list[BaseException] = []

    def work(call):
        try:
            for _ in range(rounds):
                call()
        except BaseException as exc:  # noqa: BLE001 - collected and re-raised below
            errors.append(exc)

    pool = [threading.Thread(target=work, args=(c,)) for c in objects_and_calls for _ in range(threads)]
    for t in pool:
        t.start()
    for t in pool:
        t.join(timeout=60)
        assert not t.is_alive(), "a thread hung"
    assert not errors, errors[0]


def test_a_perception_shared_by_threads_runs_one_update_at_a_time():
    # Once RuntimeError("Already borrowed").
    p = subterra.DepthPerception(subterra.PinholeCamera.d435(), config=subterra.PerceptionConfig.preset("flight"), seed=1)
    depth = np.full((480, 640), 1000, np.uint16)
    _hammer([lambda: p.update(depth), lambda: p.frames, lambda: p.belief()], rounds=10)
    assert p.frames == 4 * 10


def test_a_navigator_and_a_mapper_shared_by_threads_work():
    rng = np.random.default_rng(0)
    points = rng.uniform(-5, 5, size=(2000, 3)).astype(np.float32)
    points[:, 2] = -0.6
    nav = subterra.Navigator([5, 0])
    mapper = subterra.TerrainMapper()
    stamp = iter(np.arange(0, 1000, 0.1))
    lock = threading.Lock()

    def nav_step():
        with lock:
            t = next(stamp)
        # Stamps from several threads may reach the navigator out of order: that is an error
        # of its own (named), never a crash.
        try:
            nav.step(points, stamp=t, world_from_body=np.eye(4))
        except InputError as exc:
            assert "argument `stamp`" in str(exc)

    _hammer([nav_step, lambda: nav.risk_map, lambda: mapper.update(points), lambda: mapper.last_coarse], threads=2, rounds=5)


def test_a_section_config_names_its_fields_alike_for_nan_and_out_of_range():
    # NaN was named `length_m` (the dict's own key) while -1 was named `robot.length_m`.
    from subterra.terrain import segment_ground

    for value in (float("nan"), -1.0):
        with pytest.raises(ConfigError, match=r"`robot\.length_m`"):
            subterra.RobotConfig({"length_m": value})
        with pytest.raises(ConfigError, match=r"`ground\.bin_m`"):
            segment_ground(np.zeros((10, 3), np.float32), sensor_height=0.7, config={"ground": {"bin_m": value}})


# ------------------------------------------------------------------ values beyond any world


@pytest.mark.parametrize(
    ("call", "name"),
    [
        # Once an all-zero command (the attraction of a goal 1e308 m away overflowed).
        (lambda: subterra.ApfController().command([1e308, 0, 0]), "goal_body"),
        (lambda: subterra.Navigator((1e308, 0)), "goal"),
        (lambda: subterra.Navigator((1, 0), home=(0, -2e6)), "home"),
        (lambda: subterra.Navigator((1, 0)).set_goal((1e7, 0)), "goal"),
        # Once `solver_failed_backup` (x) and `solved` (a heading of 1e308 rad).
        (lambda: subterra.MpcTracker().solve([1e308, 0, 0, 0], [[0, 0], [5, 0]]), "state"),
        (lambda: subterra.MpcTracker().solve([0, 0, 1e308, 0], [[0, 0], [5, 0]]), "state"),
        (lambda: subterra.MpcTracker().solve([0, 0, -2e6, 0], [[0, 0], [5, 0]]), "state"),
        # Once 0.0: the ground plane extended 1e308 m.
        (lambda: subterra.sim.World.scenario("highbay", 0).ground_height(1e308, 0), "x"),
        (lambda: subterra.Navigator((5, 0)).step(None, stamp=0.0, world_from_body=np.eye(4), speed=1e308), "speed"),
        (lambda: subterra.Navigator((5, 0)).step(None, stamp=0.0, world_from_body=np.eye(4), speed=-101.0), "speed"),
    ],
    ids=["apf-goal", "nav-goal", "nav-home", "nav-set-goal", "mpc-x", "mpc-heading", "mpc-heading-2e6", "ground-height",
         "nav-speed", "nav-speed-back"],
)
def test_a_position_heading_or_speed_beyond_any_world_is_refused(call, name):
    with pytest.raises(InputError, match=f"`{name}`"):
        call()


def test_positions_within_the_limits_still_work():
    assert subterra.MpcTracker().solve([0, 0, 1e5, 0], [[0, 0], [5, 0]]).status != "invalid"
    assert subterra.ApfController().command([9e5, 0, 0]).v_x_m_s > 0
    assert subterra.sim.World.scenario("highbay", 0).ground_height(9e5, 0) is not None


@pytest.mark.parametrize("stamp", [1e308, -1e308, 2e10])
@pytest.mark.parametrize(
    "call",
    [
        lambda p, t: subterra.ObstacleMemory(p).update(p.update(np.zeros((480, 640), np.uint16)), stamp=t, world_from_body=np.eye(4)),
        lambda p, t: subterra.Escape().step(stamp=t, world_from_body=np.eye(4), goal_world=[1, 0, 0], remaining_m=1.0),
        lambda p, t: subterra.Pilot(subterra.PinholeCamera.d435()).step(np.zeros((480, 640), np.uint16), stamp=t, world_from_body=np.eye(4)),
        lambda p, t: subterra.TerrainMapper().update(np.ones((10, 3), np.float32), stamp=t),
        lambda p, t: subterra.Navigator((5, 0)).step(None, stamp=t, world_from_body=np.eye(4)),
        lambda p, t: subterra.OdometryMux([("vio", 10.0)]).push("vio", t, np.eye(4)),
    ],
    ids=["memory", "escape", "pilot", "mapper", "navigator", "mux"],
)
def test_a_stamp_beyond_1e10_s_is_refused(call, stamp):
    # Once accepted everywhere (a map stamped 1e308 s).
    perception = subterra.DepthPerception(subterra.PinholeCamera.d435())
    with pytest.raises(InputError, match=r"argument `stamp` .*within 1e10 s"):
        call(perception, stamp)


@pytest.mark.parametrize("scale", [5e-324, 1e-7, 1.5])
def test_a_depth_scale_outside_a_micrometre_to_a_metre_is_refused(scale):
    # 5e-324 m per unit was taken: every pixel at 0 m, the closest depth printed 0.000.
    perception = subterra.DepthPerception(subterra.PinholeCamera.d435())
    with pytest.raises(InputError, match=r"argument `scale` .*\[1e-6, 1\] m/unit"):
        perception.update(np.ones((480, 640), np.uint16), scale=scale)
    perception.update(np.ones((480, 640), np.uint16), scale=1e-4)


@pytest.mark.parametrize(("section", "value"), [("coarse", 1e308), ("fine", 11.0), ("coarse", 5e-4)])
def test_a_map_cell_outside_a_millimetre_to_ten_metres_is_refused(section, value):
    # A coarse cell of 1e308 m passed the cell budget (one cell).
    with pytest.raises(ConfigError, match=rf"{section}\.resolution_m"):
        subterra.TerrainConfig.from_dict({section: {"resolution_m": value}})
