"""One config path: every config class takes the same four forms (None, a dict laid over the
defaults, a config object, a TOML path), every constructor that takes a config takes all
four, and every bad or unknown field is a ConfigError naming it, whatever the form."""

from __future__ import annotations

import pickle
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import subterra
from subterra.errors import ConfigError
from subterra.live.config import NodeConfig

ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class Case:
    cls: Any
    patch: dict[str, Any]  # a change that passes the checks
    bad: dict[str, Any]  # a value the checks refuse
    field: str  # the dotted field an error about `bad` names
    committed: str | None  # the committed defaults under configs/

    @property
    def name(self) -> str:
        return self.cls.__name__


CASES = [
    Case(subterra.PerceptionConfig, {"filter": {"particles": 1000}}, {"filter": {"particles": 0}}, "filter.particles", "flight.toml"),
    Case(subterra.RobotConfig, {"length_m": 1.2}, {"length_m": -1.0}, "length_m", None),
    Case(subterra.TerrainConfig, {"coarse": {"resolution_m": 0.2}}, {"coarse": {"resolution_m": -1.0}}, "coarse.resolution_m", "terrain.toml"),
    Case(subterra.RiskAStarConfig, {"lam": 0.5}, {"lam": -1.0}, "lam", "astar.toml"),
    Case(subterra.MpcConfig, {"limits": {"max_speed_m_s": 1.5}}, {"limits": {"max_speed_m_s": -1.0}}, "limits.max_speed_m_s", "mpc.toml"),
    Case(subterra.NavigatorConfig, {"navigator": {"scan_timeout_s": 0.3}}, {"navigator": {"scan_timeout_s": -1.0}},
         "navigator.scan_timeout_s", "navigator.toml"),
    Case(subterra.HeroConfig, {"recover_s": 0.5}, {"recover_s": -1.0}, "recover_s", "hero.toml"),
    Case(subterra.QmdpConfig, {"potential_gain": 3.0}, {"potential_gain": -1.0}, "potential_gain", None),
    Case(NodeConfig, {"node": {"domain_id": 7}}, {"node": {"domain_id": 999}}, "node.domain_id", "node.toml"),
]
IDS = [c.name for c in CASES]
FORMS = ["none", "dict", "object", "toml_str_path", "toml_pathlike"]


def _leaves(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        out.update(_leaves(v, f"{prefix}{k}.") if isinstance(v, dict) else {prefix + k: v})
    return out


def _form(case: Case, form: str, patch: dict[str, Any], tmp_path: Path) -> Any:
    """`patch` (laid over the defaults) in the given form."""
    if form == "none":
        return None
    if form == "dict":
        return patch
    config = case.cls.from_dict(patch)
    if form == "object":
        return config
    path = tmp_path / f"{case.name}.toml"
    path.write_text(config.to_toml(), encoding="utf-8")
    return str(path) if form == "toml_str_path" else path


def _resolve(case: Case, value: Any) -> Any:
    if case.cls is NodeConfig:
        return NodeConfig.resolve(value)
    return case.cls(value)


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_every_form_gives_the_same_config(case: Case, form: str, tmp_path: Path) -> None:
    expected = case.cls() if form == "none" else case.cls.from_dict(case.patch)
    got = _resolve(case, _form(case, form, case.patch, tmp_path))
    assert got == expected
    leaves = _leaves(got.to_dict())
    if form != "none":
        for field, value in _leaves(case.patch).items():
            assert leaves[field] == value, field
    # TOML text and dicts round-trip; a config pickles (worker processes, Ray).
    path = tmp_path / "round-trip.toml"
    path.write_text(got.to_toml(), encoding="utf-8")
    assert case.cls.load(path) == got
    assert case.cls.from_dict(got.to_dict()) == got
    assert pickle.loads(pickle.dumps(got)) == got


@pytest.mark.parametrize("case", [c for c in CASES if c.committed], ids=[c.name for c in CASES if c.committed])
def test_the_committed_file_is_the_default(case: Case) -> None:
    """(RobotConfig and QmdpConfig have no file: their defaults live in the code only.)"""
    loaded = case.cls.load(ROOT / "configs" / case.committed)
    expected = subterra.PerceptionConfig.preset("flight") if case.cls is subterra.PerceptionConfig else case.cls()
    assert loaded == expected


def _bad_toml(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _toml_with(case: Case, patch: dict[str, Any]) -> str:
    """The defaults as TOML with `patch`'s leaves changed in place (bypassing the checks)."""
    lines = case.cls().to_toml().splitlines()
    section = ""
    for field, value in _leaves(patch).items():
        head, _, leaf = field.rpartition(".")
        for i, line in enumerate(lines):
            stripped = line.strip()
            if stripped.startswith("[") and stripped.endswith("]"):
                section = stripped.strip("[]")
            elif section == head and stripped.split("=")[0].strip() == leaf:
                lines[i] = f"{leaf} = {value!r}".replace("'", '"')
                break
        else:
            raise AssertionError(f"{case.name}: {field} not in its TOML")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_a_bad_value_names_the_field_in_every_form(case: Case, tmp_path: Path) -> None:
    leaf = case.field.rpartition(".")[2]
    with pytest.raises(ConfigError, match=leaf):
        _resolve(case, case.bad)
    with pytest.raises(ConfigError, match=leaf):
        case.cls.from_dict(case.bad)
    path = _bad_toml(tmp_path, _toml_with(case, case.bad))
    with pytest.raises(ConfigError, match=leaf) as info:
        _resolve(case, path)
    assert str(path) in str(info.value), "a file's error ends with its path"


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_an_unknown_field_is_named_in_every_form(case: Case, tmp_path: Path) -> None:
    section = next(iter(case.patch))
    nested = isinstance(case.patch[section], dict)
    patch = {section: {"no_such_field": 1}} if nested else {"no_such_field": 1}
    with pytest.raises(ConfigError, match="no_such_field"):
        _resolve(case, patch)
    text = case.cls().to_toml()
    text = text.replace(f"[{section}]\n", f"[{section}]\nno_such_field = 1\n", 1) if nested else "no_such_field = 1\n" + text
    path = _bad_toml(tmp_path, text)
    with pytest.raises(ConfigError, match="no_such_field"):
        _resolve(case, path)


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_a_value_of_no_form_is_refused_naming_the_argument(case: Case) -> None:
    with pytest.raises(ConfigError, match=rf"argument `config` must be None, a dict, a {case.name} or a TOML path, got int"):
        _resolve(case, 42)


# ---------------------------------------------------------------- every consumer


def _camera() -> subterra.PinholeCamera:
    return subterra.PinholeCamera.d435()


def _points() -> np.ndarray:
    xs, ys = np.meshgrid(np.linspace(-3, 3, 30), np.linspace(-3, 3, 30))
    return np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, -0.7)], axis=1).astype(np.float32)


CONSUMERS: list[tuple[str, Any, Callable[[Any], Any]]] = [
    ("DepthPerception", subterra.PerceptionConfig, lambda c: subterra.DepthPerception(_camera(), config=c).config),
    ("Pilot", subterra.PerceptionConfig, lambda c: subterra.Pilot(_camera(), config=c).config),
    ("Escape", subterra.PerceptionConfig, lambda c: subterra.Escape(config=c) and None),
    ("TerrainMapper.robot", subterra.RobotConfig, lambda c: subterra.TerrainMapper(robot=c).robot),
    ("TerrainMapper.config", subterra.TerrainConfig, lambda c: subterra.TerrainMapper(config=c).config),
    ("segment_ground", subterra.TerrainConfig, lambda c: subterra.segment_ground(_points(), sensor_height=0.7, config=c) is not None and None),
    ("RiskAStar", subterra.RiskAStarConfig, lambda c: subterra.RiskAStar(c).config),
    ("MpcTracker", subterra.MpcConfig, lambda c: subterra.MpcTracker(c).config),
    ("Navigator.robot", subterra.RobotConfig, lambda c: subterra.Navigator((5.0, 0.0), robot=c).robot),
    ("Navigator.terrain", subterra.TerrainConfig, lambda c: subterra.Navigator((5.0, 0.0), terrain=c) and None),
    ("Navigator.config", subterra.NavigatorConfig, lambda c: subterra.Navigator((5.0, 0.0), config=c).config),
    ("OdometryMux", subterra.HeroConfig, lambda c: subterra.OdometryMux([("vio", 10.0)], config=c).config),
    ("Qmdp", subterra.QmdpConfig, lambda c: subterra.Qmdp(subterra.DepthPerception(_camera()), config=c).config),
]


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize(("name", "cls", "make"), CONSUMERS, ids=[c[0] for c in CONSUMERS])
def test_every_constructor_takes_every_form(name: str, cls: Any, make: Callable[[Any], Any], form: str, tmp_path: Path) -> None:
    case = next(c for c in CASES if c.cls is cls)
    got = make(_form(case, form, case.patch, tmp_path))
    if got is None:  # no getter: taking the value without an error is what is checked
        return
    if form == "none":
        expected = cls.preset("flight-escape") if name == "Pilot" else cls()
        # The navigator gives its planner and tracker the terrain map's lethal risk.
        derived = {"planner.lethal_risk", "tracker.risk.lethal_risk"} if name == "Navigator.config" else set()
        want, have = _leaves(expected.to_dict()), _leaves(got.to_dict())
        assert {k: v for k, v in have.items() if k not in derived} == {k: v for k, v in want.items() if k not in derived}
    else:
        leaves = _leaves(got.to_dict())
        for field, value in _leaves(case.patch).items():
            assert leaves[field] == value, (name, field)
    with pytest.raises(ConfigError, match=case.field.rpartition(".")[2]):
        make(case.bad)


def test_a_navigator_dict_lies_over_the_defaults_for_its_robot() -> None:
    """A `config` dict keeps the robot-dependent defaults (the tracker's footprint) it does not name."""
    robot = {"length_m": 1.4, "width_m": 0.9}
    nav = subterra.Navigator((5.0, 0.0), robot=robot, config={"navigator": {"scan_timeout_s": 0.3}})
    tracker = nav.config.to_dict()["tracker"]
    assert (tracker["footprint"]["length_m"], tracker["footprint"]["width_m"]) == (1.4, 0.9)
    assert nav.config.to_dict()["navigator"]["scan_timeout_s"] == 0.3


def test_a_field_of_the_wrong_type_is_named() -> None:
    with pytest.raises(ConfigError, match="cost_model"):
        subterra.RiskAStar({"cost_model": 1})
    with pytest.raises(ConfigError, match="cost_model"):
        subterra.RiskAStar({"cost_model": "nav2"})


def test_a_perception_dict_lies_over_the_named_preset() -> None:
    cable = subterra.PerceptionConfig.preset("cable").to_dict()
    got = subterra.DepthPerception(_camera(), preset="cable", config={"filter": {"particles": 1000}}).config.to_dict()
    assert got["filter"]["particles"] == 1000
    assert got["observation"] == cable["observation"]
