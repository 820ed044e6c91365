"""`subterra cable-test` (python/subterra/flight/cable.py): the thin-cable test of the
APF-PF paper §V-A on a reduced frame count.

One run of 10 frames per condition (with the `flight` comparison) is shared by the tests;
two short runs with the same seed check that the JSON is bit-identical.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

pytest.importorskip("subterra._core")

from subterra.errors import ConfigError, InputError  # noqa: E402
from subterra.flight.cable import CONDITIONS, _check_ordering, cable_test, register_cli  # noqa: E402

FRAMES = 10
SEED = 0


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("cable-test")
    summary = cable_test(out, frames=FRAMES, seed=SEED, progress=False)
    return out, summary


def test_detection_ordering_holds_on_a_reduced_run(run):
    _, summary = run
    conditions = summary["conditions"]
    assert [c["noise"] for c in conditions] == [noise for _, noise in CONDITIONS]
    rates = [c["detection_rate"] for c in conditions]
    assert rates == sorted(rates), rates  # every pixel <= every 2nd <= every 10th <= none
    assert summary["ordering"]["detection_rate"]["holds"]
    assert summary["targets"]["detection_ordering_holds"]
    # Noise on every pixel really hurts: fewer detections and a belief close to flat.
    assert rates[0] < rates[-1] == 1.0
    assert conditions[0]["mean_confidence"] < 0.1 * conditions[-1]["mean_confidence"]
    # The belief on the cable's voxels falls as the noise gets denser.
    assert summary["ordering"]["mean_cable_belief"]["holds"]


def test_metrics_are_what_the_definitions_say(run):
    _, summary = run
    cable_bin = summary["cable"]["bin"]
    for c in summary["conditions"]:
        trace = c["trace"]
        hits = [k is not None and abs(k - cable_bin) <= 1 for k in trace["most_probable_bin"]]
        assert trace["detected"] == hits
        assert c["detection_rate"] == pytest.approx(np.mean(hits))
        assert c["mean_confidence"] == pytest.approx(np.mean(trace["most_probable_probability"]), abs=1e-6)
        assert c["free_frames"] == sum(k is None for k in trace["most_probable_bin"])
        assert all(0.0 <= p <= 1.0 for p in trace["cable_belief"])


def test_json_has_the_fields(run):
    out, summary = run
    on_disk = json.loads((out / "cable-test.json").read_text(encoding="utf-8"))
    assert on_disk == summary
    for key in ("preset", "seed", "frames_per_condition", "cable", "definitions", "conditions", "ordering", "targets", "chance_detection_rate"):
        assert key in on_disk, key
    assert on_disk["preset"] == "cable" and on_disk["frames_per_condition"] == FRAMES
    for key in ("detection_rate", "mean_confidence", "mean_cable_belief"):
        assert key in on_disk["definitions"]
    for c in on_disk["conditions"]:
        assert c["frames"] == FRAMES
        for key in ("detection_rate", "mean_confidence", "mean_cable_belief", "mean_p_free", "trace"):
            assert key in c, key
        assert len(c["trace"]["most_probable_bin"]) == FRAMES
    cable = on_disk["cable"]
    assert cable["diameter_m"] == pytest.approx(0.008)
    assert 0.6 - 0.004 <= cable["depth_m"] <= 0.9
    # The geometric depth agrees with what the noise-free camera measures.
    lo, hi = cable["rendered"]["depth_range_m"]
    assert lo - 0.005 <= cable["depth_m"] <= hi + 0.005
    assert cable["bin"] == int((cable["depth_m"] - 0.1) // 0.1)
    assert cable["detection_window_m"] == pytest.approx([0.1 + 0.1 * (cable["bin"] - 1), 0.1 + 0.1 * (cable["bin"] + 2)])


def test_png_is_a_nonempty_image(run):
    out, _ = run
    from PIL import Image

    path = out / "cable-test.png"
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with Image.open(path) as image:
        width, height = image.size
        pixels = np.asarray(image.convert("L"))
    assert width > 400 and height > 400
    assert pixels.std() > 10  # not a blank canvas


def test_flight_preset_rejects_the_cable_and_says_so(run):
    _, summary = run
    flight = summary["flight_comparison"]
    assert flight["preset"] == "flight"
    assert flight["observation"]["sigma_n_points"] == 60 and flight["observation"]["sigma_o_points"] == 170
    assert [c["noise"] for c in flight["conditions"]] == [noise for _, noise in CONDITIONS]
    assert all(c["detection_rate"] <= summary["chance_detection_rate"] for c in flight["conditions"])
    assert flight["conditions"][-1]["mean_p_free"] > 0.5
    assert flight["rejects_cable"]
    assert "rejects the 8 mm cable as noise by design" in flight["statement"]
    assert "σ_n = 60, σ_o = 170" in flight["statement"]


def test_same_seed_gives_identical_json(tmp_path):
    first, second = tmp_path / "first", tmp_path / "second"
    cable_test(first, frames=3, seed=7, progress=False)
    cable_test(second, frames=3, seed=7, progress=False)
    assert (first / "cable-test.json").read_bytes() == (second / "cable-test.json").read_bytes()
    other = cable_test(tmp_path / "other", frames=3, seed=8, progress=False, compare_flight=False)
    assert other["cable"]["depth_m"] != json.loads((first / "cable-test.json").read_text(encoding="utf-8"))["cable"]["depth_m"]


@pytest.mark.parametrize(
    ("kwargs", "error", "name"),
    [
        ({"frames": 0}, InputError, "frames"),
        ({"frames": -3}, InputError, "frames"),
        ({"frames": 2.5}, InputError, "frames"),
        ({"frames": True}, InputError, "frames"),
        ({"seed": -1}, InputError, "seed"),
        ({"preset": "indoor"}, ConfigError, "preset"),
    ],
)
def test_bad_arguments_raise_naming_the_argument(tmp_path, kwargs, error, name):
    out = tmp_path / "never"
    with pytest.raises(error, match=name):
        cable_test(out, progress=False, **kwargs)
    assert not out.exists()  # checked before any work or output


def test_ordering_check_names_the_violating_pair():
    check = _check_ordering([0.1, 0.3, 0.2, 0.4], ["a", "b", "c", "d"])
    assert not check["holds"]
    assert check["violations"] == ["b (0.3) > c (0.2)"]
    assert _check_ordering([0.0, 1.0, 1.0, 1.0], ["a", "b", "c", "d"])["holds"]


def test_cli_subcommand_prints_a_table_and_writes_the_files(tmp_path, capsys):
    parser = argparse.ArgumentParser(prog="subterra")
    register_cli(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["cable-test", "--frames", "3", "--seed", "1", "--out", str(tmp_path), "--no-flight-comparison"])
    assert args.handler(args) == 0
    text = capsys.readouterr().out
    assert "every 10th pixel" in text and "no noise" in text and "ordering" in text
    assert str(tmp_path / "cable-test.json") in text
    summary = json.loads((tmp_path / "cable-test.json").read_text(encoding="utf-8"))
    assert summary["seed"] == 1 and summary["frames_per_condition"] == 3
    assert "flight_comparison" not in summary
    assert (tmp_path / "cable-test.png").stat().st_size > 0
