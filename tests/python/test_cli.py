"""The `subterra` command line: outputs, progress, and one-line errors."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import subterra
from subterra.cli import main
from subterra.io import write_depth_png
from subterra.scenarios import approaching_box_frames

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture()
def box_folder(tmp_path):
    camera = subterra.PinholeCamera.d435()
    depth, truth = approaching_box_frames(camera, frames=8, start_m=1.0, end_m=0.6, seed=1)
    folder = tmp_path / "depth"
    folder.mkdir()
    for n, d in enumerate(depth):
        write_depth_png(folder / f"{n:04d}.png", d)
    intrinsics = tmp_path / "camera.json"
    intrinsics.write_text(json.dumps({"fx": 385.0, "fy": 385.0, "cx": 319.5, "cy": 239.5, "width": 640, "height": 480}))
    return folder, intrinsics, truth


def test_perceive_writes_summary_and_plot(box_folder, tmp_path, capsys):
    folder, intrinsics, truth = box_folder
    out = tmp_path / "run"
    assert main(["perceive", str(folder), "--intrinsics", str(intrinsics), "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 8
    assert summary["grid_shape"] == [13, 10, 11]
    assert (out / "perception.png").stat().st_size > 10_000
    last = summary["records"][-1]
    # The box is 0.6 m ahead in the last frame: the most probable voxel is within a bin of it.
    assert abs(last["map_depth_m"] - truth[-1]) <= 0.1
    assert last["p_free"] < 0.05
    assert summary["timing"]["median_ms"] > 0
    assert "wrote" in capsys.readouterr().out


def test_perceive_bad_inputs_are_one_line_errors(box_folder, tmp_path):
    folder, intrinsics, _ = box_folder
    bad = tmp_path / "bad.json"
    bad.write_text("{\"fx\": 1}")
    for argv in (
        ["perceive", str(tmp_path / "nowhere"), "--intrinsics", str(intrinsics)],
        ["perceive", str(folder), "--intrinsics", str(bad)],
        ["perceive", str(folder), "--intrinsics", str(intrinsics), "--preset", "hover"],
        ["perceive", str(folder), "--intrinsics", str(intrinsics), "--scale", "-1"],
    ):
        result = subprocess.run([sys.executable, "-m", "subterra.cli", *argv, "--out", str(tmp_path / "o")],
                                capture_output=True, text=True, cwd=tmp_path)
        assert result.returncode == 2, (argv, result.stderr)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
        assert "Traceback" not in result.stderr


def test_perceive_rejects_images_that_do_not_match_the_intrinsics(tmp_path):
    folder = tmp_path / "d"
    folder.mkdir()
    write_depth_png(folder / "0.png", np.full((240, 320), 500, np.uint16))
    intrinsics = tmp_path / "c.json"
    intrinsics.write_text(json.dumps({"fx": 385.0, "fy": 385.0, "cx": 319.5, "cy": 239.5, "width": 640, "height": 480}))
    with pytest.raises(subterra.errors.InputError, match="320x240.*640x480"):
        main(["--debug", "perceive", str(folder), "--intrinsics", str(intrinsics), "--out", str(tmp_path / "o")])


def test_bench_perception_reports_rust_and_reference(tmp_path):
    out = tmp_path / "bench.json"
    assert main(["bench", "perception", "--frames", "20", "--reference-frames", "3", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["frames"] == 20 and report["numpy_reference"]["frames"] == 3
    assert report["rust"]["frame_wall"]["median_ms"] > 0
    assert report["speedup_vs_numpy_median"] == pytest.approx(
        report["numpy_reference"]["frame_wall"]["median_ms"] / report["rust"]["frame_wall"]["median_ms"])
    assert report["transition"]["states"] == 1431
    assert set(report["rust"]["stage_median_ms"]) == {"count", "predict", "update", "belief"}
    assert report["qmdp"]["pilot_frame_wall"]["median_ms"] > 0
    assert report["preset"] == "flight" and report["numpy_reference"]["same_work"] is True


def test_bench_perception_times_another_preset_and_says_what_the_reference_lacks(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "perception", "--preset", "flight-escape", "--frames", "5", "--reference-frames", "2",
                 "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["preset"] == "flight-escape" and report["numpy_reference"]["same_work"] is False
    assert "memory" in report["numpy_reference"]["what"]
    assert main(["bench", "perception", "--preset", "hover", "--frames", "2"]) != 0
    assert "hover" in capsys.readouterr().err


def test_demo_writes_an_index_and_a_table(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--quick", "--out", str(out)]) == 0
    index = (out / "index.md").read_text()
    linked = re.findall(r"\]\(([^)]+)\)", index)
    assert linked, index
    for rel in linked:
        assert (out / rel).is_file(), f"index links a missing file: {rel}"
    for expected in ("flight-paths.png", "fly-apf-pf/depth-trace.png", "fly-apf-pf-acc2021/depth-trace.png", "fly-raw-apf/compute-time.png",
                     "cable-test/cable-test.png", "batch/results.md", "highbay-depth.png", "mine-map.png",
                     "drive-risk-aware/map.png", "drive-additive/speed-risk.png"):
        assert expected in linked, expected
    printed = capsys.readouterr().out
    assert "raw-apf" in printed and "apf-pf" in printed and "detection rate" in printed
    summary = json.loads((out / "summary.json").read_text())
    assert {f["controller"] for f in summary["flights"]} == {"apf-pf", "raw-apf"}
    assert summary["flights"][0]["collisions"] == 0
    assert [d["planner"] for d in summary["drives"]] == ["risk-aware", "additive"]
    assert all(d["collisions"] == 0 and d["scenario"] == "mine" for d in summary["drives"])
    assert "ground robot (mine" in printed


def test_bench_terrain_writes_a_report(tmp_path):
    out = tmp_path / "terrain.json"
    assert main(["bench", "terrain", "--repeats", "2", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["points"] > 0
    assert {"single_scan", "fused_window", "segment_ground", "numpy_reference"} <= set(report)


def test_drive_cli_runs_a_recovery_world_and_refuses_bad_arguments(tmp_path, capsys):
    out = tmp_path / "drive"
    assert main(["drive", "--scenario", "dead-end", "--time-limit", "3", "--no-plots", "--no-rerun", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("dead-end with the risk-aware planner, seed 0: failed: timeout after 3.0 s")
    assert "recovery behaviours: none;" in printed
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["scenario"] == "dead-end" and metrics["start"] == [2.0, 5.0] and metrics["goal"] == [22.0, 5.0]
    assert (out / "trajectory.csv").read_text().count("\n") == metrics["steps"] + 1
    bad = tmp_path / "bad.toml"
    bad.write_text("[planner\n")
    assert main(["drive", "--config", str(bad), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: argument --config:") and "is not valid TOML" in err
    assert main(["drive", "--scenario", "atlantis", "--out", str(tmp_path / "y")]) == 2
    assert "atlantis" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["drive", "--goal", "3"])
    assert main(["drive-batch", "--seeds", "0"]) == 2
    assert "--seeds must be >= 1" in capsys.readouterr().err
