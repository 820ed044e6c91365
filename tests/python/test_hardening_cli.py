"""The command line's outputs and errors (issue 22): one lethal count in the summary, the
pictures and the exported grids; a truncated MCAP replayed up to the break; unknown names
and absurd numbers rejected with exit code 2; no traceback without ``--debug``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import subterra
from subterra.cli import main
from subterra.terrain import translation


def assert_argument_error(capsys, argv):
    """`subterra argv` exits 2 with one line `error: argument <option>: ...` (the option is
    argv[-2]) and no traceback."""
    option = argv[-2]
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: argument {option}: ") and err.count("\n") == 1, err

CLOUD_TOPIC = "/lidar/points"
T0 = 1_700_000_000_000_000_000
SENSOR_HEIGHT_M = 0.7
#: A terrain config whose lethal level (0.1) is below the risk of an unobserved cell
#: (``risk.unknown`` 0.15): every cell the scan does not reach is lethal but unobserved.
LOW_LETHAL = {"risk": {"lethal_risk": 0.1}}


def _scan(seed: int = 0, n: int = 20_000) -> np.ndarray:
    """A level lidar 0.7 m above flat ground (1-7 m around it) with a box 3 m ahead."""
    rng = np.random.default_rng(seed)
    r, a = rng.uniform(1.0, 7.0, n), rng.uniform(-np.pi, np.pi, n)
    ground = np.c_[r * np.cos(a), r * np.sin(a), np.full(n, -SENSOR_HEIGHT_M)]
    box = np.c_[rng.uniform(3.0, 3.4, 2000), rng.uniform(-0.3, 0.3, 2000), rng.uniform(-SENSOR_HEIGHT_M, 0.3, 2000)]
    return np.vstack([ground, box]).astype(np.float32)


def _low_lethal_config(tmp_path: Path) -> Path:
    path = tmp_path / "low-lethal.toml"
    path.write_text(subterra.TerrainConfig(LOW_LETHAL).to_toml(), encoding="utf-8")
    return path


def _map(points: np.ndarray, config: Path):
    mapper = subterra.TerrainMapper(config=config)
    return mapper.update(points, stamp=0.0, world_from_body=np.eye(4), body_from_sensor=translation(z=SENSOR_HEIGHT_M))


def _cloud_mcap(path: Path, scans: int = 4, *, chunk_size: int = 1 << 20) -> Path:
    pytest.importorskip("rosbags")
    from subterra.io import ros
    from subterra.io.recordings import McapWriter

    with McapWriter(path, chunk_size=chunk_size) as w:
        w.write("/tf_static", ros.tf_message([("base_link", "lidar", T0, translation(z=SENSOR_HEIGHT_M))]), log_time_ns=T0 - 1)
        for i in range(scans):
            s = T0 + i * 100_000_000
            w.write(CLOUD_TOPIC, ros.pointcloud2_message(_scan(i), stamp_ns=s, frame_id="lidar"), log_time_ns=s)
    return path


def _read_grids(path: Path) -> list:
    pytest.importorskip("mcap_ros2")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [m for _, ch, _, m in reader.iter_decoded_messages(log_time_order=True) if ch.topic == "/subterra/risk"]


# ---------------------------------------------------------------------- 1, 2: one lethal count


def test_terrain_summary_and_pictures_count_unobserved_lethal_cells_alike(tmp_path, monkeypatch, capsys):
    import matplotlib.axes

    titles: list[str] = []
    legends: list[str] = []
    set_title, legend = matplotlib.axes.Axes.set_title, matplotlib.axes.Axes.legend

    def record_title(self, label, *args, **kwargs):
        titles.append(str(label))
        return set_title(self, label, *args, **kwargs)

    def record_legend(self, *args, **kwargs):
        legends.extend(h.get_label() for h in kwargs.get("handles", []))
        return legend(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "set_title", record_title)
    monkeypatch.setattr(matplotlib.axes.Axes, "legend", record_legend)
    cloud = tmp_path / "scan.npy"
    np.save(cloud, _scan())
    config = _low_lethal_config(tmp_path)
    out = tmp_path / "terrain"
    argv = ["terrain", str(cloud), "--sensor-height", str(SENSOR_HEIGHT_M), "--config", str(config), "--out", str(out), "--no-progress"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    lethal = summary["lethal_cells"]["risk"]

    m = _map(_scan(), config)  # the same map, to look at its cells
    unobserved_lethal = m.lethal() & ~(m.layer("observed") > 0)
    assert unobserved_lethal.sum() > 1000, "the case this test is about: lethal cells that were never observed"
    assert lethal == m.lethal_count() == int(m.lethal().sum())
    assert f"{lethal} lethal cells of {summary['map']['cells']}" in printed
    assert f"risk ({lethal} lethal cells)" in titles, titles  # overview.png's risk panel
    assert f"lethal ({lethal} cells)" in legends, legends  # risk.png's legend
    assert np.all(m.to_image()[m.lethal()] == [220, 0, 0]), "every lethal cell is red, observed or not"


def test_occupancy_values_send_unobserved_lethal_cells_as_100():
    from subterra.viz.foxglove import occupancy_values

    risk = np.array([[0.95, 0.95, 0.5, np.nan], [0.2, 0.9, 0.89, 0.0]], np.float32)
    observed = np.array([[1, 0, 0, 0], [1, 0, 1, 1]], np.float32)
    np.testing.assert_array_equal(occupancy_values(risk, observed, 0.9), [[100, 100, -1, -1], [20, 100, 89, 0]])


def test_replay_grid_marks_every_lethal_cell_100(tmp_path):
    from subterra.replay import replay

    rec = _cloud_mcap(tmp_path / "rec.mcap", scans=1)
    config = _low_lethal_config(tmp_path)
    summary = replay(rec, tmp_path / "run", cloud_topic=CLOUD_TOPIC, terrain_config=config, rerun=False, plots=False, progress=False)
    (grid,) = _read_grids(tmp_path / "run" / "replay.mcap")
    values = np.array(grid.data, np.int8).reshape(grid.info.height, grid.info.width)
    m = _map(_scan(0), config)
    assert (m.lethal() & ~(m.layer("observed") > 0)).any()
    assert np.all(values[m.lethal()] == 100), "a lethal cell is 100, never -1, observed or not"
    assert int((values == 100).sum()) == summary["lethal_cells"]["risk"] == m.lethal_count()
    assert not (values == -1).any()  # here every unobserved cell is lethal


# ---------------------------------------------------------------------- 3: truncated MCAP


def _check_partial_run(out: Path, capsys, unit: str = "clouds") -> dict:
    captured = capsys.readouterr()
    assert captured.err.startswith("error: MCAP file is truncated or corrupt after") and "Traceback" not in captured.err
    assert "stopped at an error after" in captured.out and '("completed": false)' in captured.out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["completed"] is False and "truncated" in summary["error"]
    assert len(summary["scans"]) >= 1 and f"after {len(summary['scans'])} {unit}" in captured.out
    grids = _read_grids(out / "replay.mcap")  # a finished, readable file
    assert len(grids) == len(summary["scans"]) == summary["output_counts"]["/subterra/risk"]
    return summary


def test_truncated_ouster_mcap_is_replayed_up_to_the_break(shared_data, tmp_path, capsys):
    pytest.importorskip("rosbags")
    source = shared_data / "mcap-ouster-os1-64" / "test.mcap"
    if not source.is_file():
        pytest.skip(f"{source} is absent")
    data = source.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(0.6 * len(data))])  # the first cloud and /tf_static survive, the second does not
    out = tmp_path / "run"
    argv = ["replay", str(cut), "--cloud-topic", "/os1_cloud_node/points", "--sensor-height", "0.8", "--out", str(out),
            "--no-rerun", "--no-plots", "--no-progress"]
    assert main(argv) == 2
    summary = _check_partial_run(out, capsys)
    assert len(summary["scans"]) == 1 and summary["body_from_sensor_source"] == "--sensor-height (level sensor)"


def test_truncated_mcap_with_tf_is_replayed_up_to_the_break(tmp_path, capsys):
    full = _cloud_mcap(tmp_path / "full.mcap", scans=6, chunk_size=50_000)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full.read_bytes()[: int(0.6 * full.stat().st_size)])
    out = tmp_path / "run"
    assert main(["replay", str(cut), "--cloud-topic", CLOUD_TOPIC, "--out", str(out), "--no-rerun", "--no-plots", "--no-progress"]) == 2
    summary = _check_partial_run(out, capsys)
    assert 1 <= len(summary["scans"]) < 6 and summary["body_from_sensor_source"] == "tf_static: base_link <- lidar"


# ---------------------------------------------------------------------- 4: unknown names


@pytest.mark.parametrize(("argv", "expected"), [
    (["--layers", "risk,nope"], "error: argument --layers: unknown layer 'nope' (known: count, "),
    (["--layers", "nope"], "unknown layer 'nope'"),
])
def test_replay_rejects_unknown_layers(tmp_path, capsys, argv, expected):
    rec = _cloud_mcap(tmp_path / "rec.mcap", scans=1)
    assert main(["replay", str(rec), "--cloud-topic", CLOUD_TOPIC, "--out", str(tmp_path / "run"), *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and expected in err and "risk_variance" in err
    assert not (tmp_path / "run").exists(), "checked before anything is read or written"


@pytest.mark.parametrize(("argv", "expected"), [
    (["replay", "missing.mcap", "--depth-topic", "/d", "--info-topic", "/i", "--preset", "nope"], "unknown preset 'nope'"),
    (["fly", "--scenario", "nope"], "unknown scenario `nope`"),
    (["fly", "--preset", "nope"], "unknown preset `nope`"),
    (["fly", "--noise", "nope"], "got 'nope'"),
    (["fly-batch", "--controllers", "nope", "--seeds", "1"], "unknown controller 'nope'"),
    (["fly-batch", "--noise", "nope", "--seeds", "1"], "unknown noise model 'nope'"),
    (["fly-batch", "--preset", "nope", "--seeds", "1"], "unknown perception preset 'nope'"),
    (["fly-batch", "--routes", "Z-Q", "--seeds", "1"], "no route 'Z-Q'"),
    (["drive-batch", "--planners", "risk-aware,nope", "--seeds", "1"], "['risk-aware', 'nope']"),
    (["drive-batch", "--scenario", "nope", "--seeds", "1"], "unknown scenario `nope`"),
    (["sim", "render", "nope"], "unknown scenario `nope`"),
    (["sim", "render", "highbay", "--noise", "nope"], "unknown depth noise preset `nope`"),
])
def test_unknown_names_are_errors(tmp_path, capsys, argv, expected):
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and expected in err and "Traceback" not in err


# ---------------------------------------------------------------------- 5: absurd numbers


@pytest.mark.parametrize("argv", [
    ["terrain", "x.npy", "--sensor-height", "-1"],
    ["terrain", "x.npy", "--sensor-height", "nan"],
    ["terrain", "x.npy", "--sensor-height", "5000"],
    ["terrain", "x.npy", "--period", "0"],
    ["terrain", "x.npy", "--confidence", "1.5"],
    ["perceive", "d", "--intrinsics", "i", "--scale", "0"],
    ["perceive", "d", "--intrinsics", "i", "--seed", "-1"],
    ["perceive", "d", "--intrinsics", "i", "--goal", "nan,0,0"],
    ["bench", "perception", "--frames", "0"],
    ["bench", "perception", "--reference-frames", "-1"],
    ["bench", "terrain", "--repeats", "-3"],
    ["bench", "replay", "--messages", "0"],
    ["bench", "batch", "--flights", "0"],
    ["sim", "render", "highbay", "--seed", "-1"],
    ["fly", "--rate", "0"],
    ["fly", "--rate", "inf"],
    ["fly", "--time-limit", "-2"],
    ["fly", "--seed", "1.5"],
    ["fly-batch", "--seeds", "0"],
    ["fly-batch", "--first-seed", "-1"],
    ["fly-batch", "--workers", "0"],
    ["cable-test", "--frames", "0"],
    ["cable-test", "--seed", "-1"],
    ["drive", "--rate", "-1"],
    ["drive", "--time-limit", "nan"],
    ["drive", "--start", "1,inf"],
    ["drive", "--seed", "-3"],
    ["drive-batch", "--first-seed", "-1"],
    ["drive-batch", "--time-limit", "0"],
    ["drive-batch", "--workers", "1000"],
    ["sweep", "f.toml", "--workers", "0"],
    ["replay", "r.mcap", "--max-messages", "0"],
    ["replay", "r.mcap", "--sensor-height", "0"],
    ["replay", "r.mcap", "--scale", "-0.001"],
    ["replay", "r.mcap", "--goal", "1,2"],
    ["replay", "r.mcap", "--seed", "-1"],
])
def test_absurd_numbers_are_argument_errors(capsys, argv):
    assert_argument_error(capsys, argv)


def test_drive_batch_seeds_are_checked_by_the_handler(capsys):
    assert main(["drive-batch", "--seeds", "2000000"]) == 2
    assert "argument --seeds must be >= 1 and <= 1000000, got 2000000" in capsys.readouterr().err


# ---------------------------------------------------------------------- 6: no tracebacks


def _boom(args):
    raise RuntimeError("boom\nsecond line")


@pytest.mark.parametrize(("module", "name", "argv"), [
    ("subterra.cli", "_sim", ["sim", "render", "highbay"]),
    ("subterra.terrain.cli", "run_cli", ["terrain", "x.npy"]),
    ("subterra.drive.cli", "_drive", ["drive"]),
    ("subterra.replay", "run_cli", ["replay", "r.mcap"]),
])
def test_unexpected_exceptions_are_one_line_internal_errors(monkeypatch, capsys, module, name, argv):
    monkeypatch.setattr(f"{module}.{name}", _boom)
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err == "error: internal error: RuntimeError: boom second line (rerun with --debug for the traceback)\n"
    with pytest.raises(RuntimeError, match="boom"):
        main(["--debug", *argv])


def test_keyboard_interrupt_stays_130(monkeypatch, capsys):
    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr("subterra.terrain.cli.run_cli", interrupted)
    assert main(["terrain", "x.npy"]) == 130
    assert capsys.readouterr().err == "error: interrupted\n"


@pytest.mark.parametrize("command", ["drive", "terrain", "fly", "perceive", "replay"])
def test_non_utf8_config_is_a_one_line_error(tmp_path, capsys, command):
    bad = tmp_path / "latin1.toml"
    bad.write_bytes('name = "Gr\xfcnwald"\n'.encode("latin-1"))
    cloud = tmp_path / "scan.npy"
    np.save(cloud, _scan())
    if command == "terrain":
        argv = ["terrain", str(cloud), "--sensor-height", "0.7", "--no-progress"]
    elif command == "perceive":
        argv = ["perceive", str(tmp_path), "--intrinsics", str(tmp_path / "i.json")]
    elif command == "replay":
        argv = ["replay", str(_cloud_mcap(tmp_path / "rec.mcap", scans=1)), "--cloud-topic", CLOUD_TOPIC, "--no-progress"]
    else:
        argv = [command]
    assert main([*argv, "--config", str(bad), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err
    assert "UTF-8" in err and "latin1.toml" in err, err


@pytest.mark.parametrize("argv", [
    ["fly", "--world", ""],
    ["fly", "--config", ""],
    ["fly", "--faults", ""],
    ["fly", "--faults-config", ""],
    ["fly", "--route", ""],
    ["drive", "--world", ""],
    ["drive", "--config", " "],
    ["drive", "--faults", ""],
    ["perceive", "d", "--intrinsics", "i.json", "--config", ""],
    ["terrain", "x.npy", "--body-from-sensor", ""],
    ["terrain", "x.npy", "--poses", ""],
    ["terrain", "x.npy", "--config", ""],
    ["replay", "r.mcap", "--config", ""],
    ["demo", "--data", ""],
    # Once accepted: a sensor 1e-320 m above the ground, scans 1e-320 s apart.
    ["terrain", "x.npy", "--sensor-height", "1e-320"],
    ["terrain", "x.npy", "--period", "1e-320"],
    ["replay", "r.mcap", "--sensor-height", "0.001"],
    # The second probe: every path, folder, frame and connection option, and a run of 1e-320 s.
    ["replay", "r.mcap", "--world-frame", ""],
    ["replay", "r.mcap", "--body-frame", ""],
    ["replay", "r.mcap", "--out", ""],
    ["terrain", "scan.npy", "--out", ""],
    ["sim", "render", "tunnel", "--out", ""],
    ["node", "ground", "--config", ""],
    ["node", "drone", "--stats", ""],
    ["node", "ground", "--mavlink", ""],
    ["node", "ground", "--foxglove", ""],
    ["sil", "--config", ""],
    ["sil", "--out", ""],
    ["fly", "--out", ""],
    ["drive", "--out", ""],
    ["perceive", "d", "--intrinsics", "i.json", "--out", ""],
    # Once accepted: a run of 1e-320 s.
    ["drive", "--time-limit", "1e-320"],
    ["fly", "--time-limit", "1e-320"],
    ["sil", "--time-limit", "1e-320"],
])
def test_an_empty_or_absurd_option_value_is_an_argument_error(capsys, argv):
    # An empty value was taken as "not given": `fly --world ''` flew the default scenario.
    assert_argument_error(capsys, argv)


def test_terrain_poses_must_be_one_per_file(tmp_path, capsys):
    # Two poses for one scan ran without complaint (the second pose was dropped).
    cloud = tmp_path / "scan.npy"
    np.save(cloud, _scan(n=100))
    poses = tmp_path / "poses.txt"
    poses.write_text("1 0 0 0 0 1 0 0 0 0 1 0.7\n1 0 0 1 0 1 0 0 0 0 1 0.7\n")
    assert main(["terrain", str(cloud), "--poses", str(poses), "--sensor-height", "0.7", "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: argument `--poses` has 2 poses for 1 files") and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("kind", ["fifo", "dev-zero", "missing", "file", "empty-folder"])
def test_demo_data_that_is_not_the_data_folder_fails_at_once(tmp_path, capsys, kind):
    # `demo --data <FIFO | /dev/zero | /nonexistent>` ran the whole demo before looking at it.
    import os
    import time

    data = {"dev-zero": Path("/dev/zero"), "missing": tmp_path / "nope"}.get(kind, tmp_path / kind)
    if kind == "fifo":
        os.mkfifo(data)
    elif kind == "file":
        data.write_text("x")
    elif kind == "empty-folder":
        data.mkdir()
    started = time.perf_counter()
    assert main(["demo", "--data", str(data), "--quick", "--out", str(tmp_path / "out")]) == 2
    assert time.perf_counter() - started < 5.0
    err = capsys.readouterr().err
    assert err.startswith("error: argument `--data` must be the shared data folder") and err.count("\n") == 1, err
    assert str(data) in err and not (tmp_path / "out").exists()
