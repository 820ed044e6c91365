"""`subterra sweep`: the sweep file (fields, grid, random search, checks before any run)
and a 2x2 grid on 2 seeds run from the command line, with its table and figures."""

from __future__ import annotations

import json

import pytest

from subterra.batch import load_sweep
from subterra.batch.sweep import SweepResult, field_stats, point_params, sweep_jobs
from subterra.cli import main
from subterra.errors import ConfigError


def _fly(**extra):
    return {"kind": "fly", "worlds": ["highbay"], "routes": ["A-B"], "noises": ["none"], "seeds": 2, **extra}


def test_fields_resolve_to_config_paths():
    spec = load_sweep(_fly(grid={"perception": {"sigma_o": [120, 170, 300], "apf.rho_0_m": [1.0, 1.4]}}))
    assert spec.fields == ["perception.observation.sigma_o_points", "perception.apf.rho_0_m"]
    assert len(spec.points) == 6 and spec.points[0] == {"perception.observation.sigma_o_points": 120,
                                                          "perception.apf.rho_0_m": 1.0}
    assert point_params(spec, spec.points[-1])["perception"] == {"observation": {"sigma_o_points": 300},
                                                                 "apf": {"rho_0_m": 1.4}}
    jobs, labels = sweep_jobs(spec)
    assert len(jobs) == 6 * 2  # points x seeds (one world, route, controller, noise)
    assert len({j.id for j in jobs}) == 12 and {lab["seed"] for lab in labels} == {0, 1}
    drive = load_sweep({"kind": "drive", "seeds": [5], "planners": ["risk-aware", "additive"],
                        "grid": {"recovery.r_inst": [0.5, 0.7], "terrain.ground.void_min_gap_deg": [2.0]}})
    assert drive.fields == ["recovery.r_inst", "terrain.ground.void_min_gap_deg"]
    assert point_params(drive, drive.points[1])["navigator_config"] == {"recovery": {"r_inst": 0.7},
                                                                        "terrain": {"ground": {"void_min_gap_deg": 2.0}}}
    assert len(sweep_jobs(drive)[0]) == 2 * 2


def test_random_search_is_seeded_and_in_range():
    table = _fly(random={"samples": 5, "seed": 3, "perception": {"sigma_o": {"low": 100, "high": 300},
                                                                 "filter.mode": ["particle", "histogram"]}})
    a, b = load_sweep(table), load_sweep(table)
    assert a.points == b.points and len(a.points) == 5
    assert all(100 <= p["perception.observation.sigma_o_points"] <= 300 for p in a.points)
    assert {p["perception.filter.mode"] for p in a.points} <= {"particle", "histogram"}
    other = load_sweep({**table, "random": {**table["random"], "seed": 4}})
    assert other.points != a.points


def test_bad_sweeps_fail_before_anything_runs():
    with pytest.raises(ConfigError, match="ambiguous: perception.apf.rho_0_m, perception.memory.rho_0_m"):
        load_sweep(_fly(grid={"perception": {"rho_0": [1.0]}}))
    with pytest.raises(ConfigError, match="did you mean perception.observation.sigma_o_points"):
        load_sweep(_fly(grid={"perception": {"observation.sigma_o_pts": [1.0]}}))
    with pytest.raises(ConfigError, match="planner"):
        load_sweep(_fly(grid={"planner.r_inst": [0.5]}))  # a drive's field in a flight sweep
    with pytest.raises(ConfigError, match="perception.filter.mode = .magic.*unknown variant"):
        load_sweep(_fly(grid={"perception.filter.mode": ["magic"]}))  # the config rejects the value
    with pytest.raises(ConfigError, match="unknown sweep field `planners`"):
        load_sweep(_fly(planners=["risk-aware"], grid={"rate_hz": [10.0]}))
    with pytest.raises(ConfigError, match=r"exactly one of \[grid\] and \[random\]"):
        load_sweep(_fly())
    with pytest.raises(ConfigError, match="twice"):
        load_sweep(_fly(grid={"rate_hz": [10.0, 10.0]}))
    with pytest.raises(ConfigError, match="random.samples"):
        load_sweep(_fly(random={"rate_hz": [10.0]}))
    with pytest.raises(ConfigError, match="seeds"):
        load_sweep(_fly(seeds=0, grid={"rate_hz": [10.0]}))
    for seeds, match in (({"first": 100, "count": 10**40}, r"seeds.count. asks for 10+ seeds"),
                         ({"first": 2**63 - 2, "count": 3}, r"pass the largest seed 2\^63-1"),
                         ({"first": -1, "count": 3}, r"seeds.first. must be an integer >= 0")):
        with pytest.raises(ConfigError, match=match):
            load_sweep(_fly(seeds=seeds, grid={"rate_hz": [10.0]}))
    with pytest.raises(ConfigError, match="controllers"):
        load_sweep(_fly(controllers=["magic"], grid={"rate_hz": [10.0]}))
    with pytest.raises(ConfigError, match="routes"):
        load_sweep(_fly(routes=["A-Z"], grid={"rate_hz": [10.0]}))
    with pytest.raises(ConfigError, match="time_limit_s"):
        load_sweep(_fly(time_limit_s=-1, grid={"rate_hz": [10.0]}))


def test_a_2x2_grid_on_2_seeds_writes_its_table_and_figures(tmp_path):
    spec = tmp_path / "sweep.toml"
    spec.write_text(
        'kind = "drive"\nworlds = ["mine"]\nplanners = ["risk-aware"]\nseeds = 2\ntime_limit_s = 3.0\n\n'
        "[grid]\nrecovery.r_inst = [0.5, 0.7]\nplanner.lam = [0.1, 0.3]\n", encoding="utf-8")
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "2"]) == 0
    data = json.loads((out / "results.json").read_text())
    assert data["settings"]["fields"] == ["recovery.r_inst", "planner.lam"]
    assert len(data["runs"]) == 8 and len(data["summary"]) == 4
    assert {(t["values"]["recovery.r_inst"], t["values"]["planner.lam"]) for t in data["summary"]} == {
        (0.5, 0.1), (0.5, 0.3), (0.7, 0.1), (0.7, 0.3)}
    assert all(t["runs"] == 2 for t in data["summary"])
    md = (out / "results.md").read_text().splitlines()
    assert md[0].startswith("| recovery.r_inst | planner.lam | planner | world | noise | runs | success |")
    assert len(md) == 2 + 4 and md[2].startswith("| 0.5 | 0.1 | risk-aware | mine | os1_64 | 2 |")
    for field in ("recovery.r_inst", "planner.lam"):
        png = out / f"sweep-{field}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert len((out / "runs.jsonl").read_text().splitlines()) == 8
    # Resumed, it runs nothing more and writes the same table.
    assert main(["sweep", str(spec), "--out", str(out), "--resume", "--no-plots"]) == 0
    again = json.loads((out / "results.json").read_text())
    assert again["settings"]["resumed"] == 8 and again["summary"] == data["summary"]


def test_field_figures_average_over_the_rest_and_spread_over_seeds(tmp_path):
    # Two values of a categorical field x two values of another, on seeds 0 and 1.
    def row(mode, gain, seed, outcome):
        return {"success": outcome == "ok", "failure": None if outcome == "ok" else outcome,
                "sweep": {"point": 0, "values": {"mode": mode, "gain": gain}, "world": "w", "noise": "n", "arm": "apf-pf",
                          "seed": seed}}

    rows = [row("a", 1.0, 0, "ok"), row("a", 2.0, 0, "ok"), row("a", 1.0, 1, "collision"), row("a", 2.0, 1, "ok"),
            row("b", 1.0, 0, "timeout"), row("b", 2.0, 0, "timeout"), row("b", 1.0, 1, "ok"), row("b", 2.0, 1, "ok")]
    result = SweepResult(scenario="w", rows=rows, table=[], settings={"noises": ["n"], "fields": ["mode", "gain"],
                                                                      "kind": "fly", "seeds": [0, 1]})
    stats = field_stats(result, "mode")["apf-pf"]
    assert [p["value"] for p in stats] == ["a", "b"]
    # mode a: seed 0 succeeds twice (1.0), seed 1 once in two (0.5).
    assert stats[0]["success"] == {"mean": 0.75, "min": 0.5, "max": 1.0}
    assert stats[0]["collision"] == {"mean": 0.25, "min": 0.0, "max": 0.5}
    assert stats[1]["success"] == {"mean": 0.5, "min": 0.0, "max": 1.0} and stats[1]["seeds"] == 2
    gain = field_stats(result, "gain")["apf-pf"]
    assert [p["value"] for p in gain] == [1.0, 2.0] and gain[1]["success"]["mean"] == 0.75
    written = result.figures(tmp_path)
    assert set(written) == {"sweep_mode", "sweep_gain"}
    assert all(p.read_bytes()[:4] == b"\x89PNG" for p in written.values())
