"""The sweep file (``subterra sweep FILE.toml``): what to run and which fields to vary.

.. code-block:: toml

    kind = "fly"                      # fly (default) or drive
    worlds = ["highbay"]              # built-in scenarios
    routes = "all"                    # fly: routes of each world (default all)
    controllers = ["apf-pf"]          # fly (drive: planners = ["risk-aware", "additive"])
    noises = ["d435-phantom"]         # depth noise (drive: lidar noise)
    seeds = 10                        # a count, a list, or {first = 100, count = 10}
    preset = "flight"                 # fly: the perception preset the fields lie over
    time_limit_s = 40                 # per run (default: the run's own)

    [grid]                            # every combination of these values
    perception.sigma_o = [120, 170, 300]
    perception.apf.rho_0_m = [1.0, 1.4]

    # or a random search: `samples` points drawn with `seed`
    # [random]
    # samples = 20
    # seed = 0
    # perception.sigma_o = {low = 100, high = 300}      # uniform; log = true: log-uniform; integer = true
    # perception.filter.mode = ["particle", "histogram"] # a choice

A field is a config field or a run setting. Flights: ``perception.<section>.<field>``
(the perception config, laid over ``preset``) or ``preset``, ``rate_hz``, ``time_limit_s``,
``stall_window_s``, ``stall_distance_m``. Drives: ``planner.*``, ``tracker.*``,
``recovery.*``, ``navigator.*`` (the navigator's config) and ``terrain.*`` (the mapper's),
or ``rate_hz``, ``time_limit_s``, ``lidar``. After the section, a field may be named by
the end of its path when that is unique (``perception.sigma_o_points``), and without its
unit suffix (``perception.sigma_o`` for ``observation.sigma_o_points``). Every point is
checked against the config before anything runs.
"""

from __future__ import annotations

import difflib
import itertools
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from subterra._files import read_toml
from subterra.batch.jobs import seed_list, seed_range
from subterra.errors import ConfigError, InputError, SubterraError
from subterra.sim import DEFAULT_DEPTH_NOISE

__all__ = ["KINDS", "SweepSpec", "load_sweep"]

#: What a sweep can run.
KINDS = ("fly", "drive")
#: Run settings a sweep may vary, per kind.
RUN_FIELDS = {"fly": ("preset", "rate_hz", "time_limit_s", "stall_window_s", "stall_distance_m"),
              "drive": ("rate_hz", "time_limit_s", "lidar")}
#: Config sections of a drive (the navigator's, and the mapper's `terrain`).
DRIVE_SECTIONS = ("planner", "tracker", "recovery", "navigator", "terrain")
_COMMON_KEYS = ("kind", "worlds", "noises", "seeds", "grid", "random", "time_limit_s", "rate_hz")
_KIND_KEYS = {"fly": ("routes", "controllers", "preset"), "drive": ("planners", "lidar")}
_DEFAULTS = {"fly": {"worlds": ["highbay"], "noises": [DEFAULT_DEPTH_NOISE], "arms": ["apf-pf"]},
             "drive": {"worlds": ["mine"], "noises": ["os1_64"], "arms": ["risk-aware"]}}


@dataclass
class SweepSpec:
    """A parsed sweep: the kind, the axes every point runs on (``worlds``, ``routes``
    (flights), ``arms`` (controllers or planners), ``noises``, ``seeds``), the fixed run
    settings, the swept ``fields`` (resolved names) and the ``points`` (a dict of field
    values each), ``mode`` ``grid`` or ``random``."""

    kind: str
    worlds: list[str]
    routes: str | list[str]
    arms: list[str]
    noises: list[str]
    seeds: list[int]
    fixed: dict[str, Any]
    fields: list[str]
    points: list[dict[str, Any]]
    mode: str
    source: dict[str, Any] = field(default_factory=dict)

    @property
    def arm_key(self) -> str:
        return "controller" if self.kind == "fly" else "planner"


def _flat(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested tables as dotted names (TOML's ``a.b = 1`` and ``"a.b" = 1`` alike); a
    table with ``low``/``high`` is a value (a random range), not a section."""
    out: dict[str, Any] = {}
    for k, v in table.items():
        name = f"{prefix}{k}"
        if isinstance(v, Mapping) and not ({"low", "high"} & set(v)):
            out.update(_flat(v, name + "."))
        else:
            out[name] = v
    return out


def _strings(value: Any, name: str) -> list[str]:
    if isinstance(value, str):
        value = [v.strip() for v in value.split(",") if v.strip()]
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"sweep field `{name}` must be a non-empty list of names, got {value!r}")
    return value


def _seeds(value: Any) -> list[int]:
    if isinstance(value, Mapping):
        unknown = set(value) - {"first", "count"}
        if unknown or "count" not in value:
            raise ConfigError(f"sweep field `seeds` as a table takes `first` and `count`, got {dict(value)!r}")
        try:
            return seed_range(value.get("first", 0), value["count"], "seeds")
        except InputError as exc:
            raise ConfigError(f"sweep field {exc}".replace("argument ", "")) from exc
    try:
        return seed_list(value, "seeds")
    except InputError as exc:
        raise ConfigError(f"sweep field {exc}".replace("argument ", "")) from exc


def _config_paths(kind: str, preset: str) -> dict[str, list[str]]:
    """Every config path a field may name, by section prefix."""
    if kind == "fly":
        from subterra._core import PerceptionConfig

        return {"perception": list(_flat(PerceptionConfig.preset(preset).to_dict()))}
    from subterra import Navigator, TerrainConfig

    nav = _flat(Navigator((1.0, 0.0)).config.to_dict())
    paths = {s: [p.partition(".")[2] for p in nav if p.startswith(s + ".")] for s in DRIVE_SECTIONS if s != "terrain"}
    paths["terrain"] = list(_flat(TerrainConfig().to_dict()))
    return paths


def _unitless_match(path: str, rest: str) -> bool:
    """``rest`` names ``path`` without its unit suffix (``sigma_o``, ``observation.sigma_o``)."""
    head, _, leaf = rest.rpartition(".")
    path_head, _, path_leaf = path.rpartition(".")
    if not path_leaf.startswith(leaf + "_"):
        return False
    return not head or path_head == head or path_head.endswith("." + head)


def _resolve(kind: str, name: str, paths: dict[str, list[str]]) -> str:
    """The full dotted name of sweep field ``name``."""
    if name in RUN_FIELDS[kind]:
        return name
    section, _, rest = name.partition(".")
    if section not in paths or not rest:
        known = ", ".join([*(f"{s}.*" for s in paths), *RUN_FIELDS[kind]])
        raise ConfigError(f"sweep field `{name}`: a {kind} sweep varies {known}")
    options = paths[section]
    if rest in options:
        return name
    ends = [p for p in options if p.endswith("." + rest)]
    if not ends:  # without the unit suffix: sigma_o for sigma_o_points
        ends = [p for p in options if _unitless_match(p, rest)]
    if len(ends) == 1:
        return f"{section}.{ends[0]}"
    if ends:
        raise ConfigError(f"sweep field `{name}` is ambiguous: " + ", ".join(f"{section}.{p}" for p in ends))
    close = difflib.get_close_matches(rest, options, n=3, cutoff=0.5)
    hint = f" (did you mean {', '.join(f'{section}.{c}' for c in close)}?)" if close else ""
    raise ConfigError(f"sweep field `{name}` is not a field of the {section} config{hint}")


def _grid(fields: dict[str, Any]) -> list[dict[str, Any]]:
    for name, values in fields.items():
        if not isinstance(values, list) or not values:
            raise ConfigError(f"sweep field `grid.{name}` must be a non-empty list of values, got {values!r}")
        if len({repr(v) for v in values}) != len(values):
            raise ConfigError(f"sweep field `grid.{name}` lists a value twice: {values!r}")
    names = list(fields)
    return [dict(zip(names, combo)) for combo in itertools.product(*(fields[n] for n in names))]


def _draw(name: str, spec: Any, rng: np.random.Generator) -> Any:
    if isinstance(spec, list):
        if not spec:
            raise ConfigError(f"sweep field `random.{name}` must list at least one value")
        return spec[int(rng.integers(len(spec)))]
    if not isinstance(spec, Mapping) or set(spec) - {"low", "high", "log", "integer"}:
        raise ConfigError(f"sweep field `random.{name}` must be a list or {{low, high[, log, integer]}}, got {spec!r}")
    low, high = spec.get("low"), spec.get("high")
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (low, high)) or not low < high:
        raise ConfigError(f"sweep field `random.{name}` needs numbers low < high, got {dict(spec)!r}")
    if spec.get("log", False):
        if low <= 0:
            raise ConfigError(f"sweep field `random.{name}`: a log range needs low > 0, got {low!r}")
        value = float(np.exp(rng.uniform(np.log(low), np.log(high))))
    else:
        value = float(rng.uniform(low, high))
    return int(round(value)) if spec.get("integer", False) else value


def _random(table: Mapping[str, Any]) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    samples, seed = table.get("samples"), table.get("seed", 0)
    if not isinstance(samples, int) or isinstance(samples, bool) or not 1 <= samples <= 100_000:
        raise ConfigError(f"sweep field `random.samples` must be an integer in 1..100000, got {samples!r}")
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise ConfigError(f"sweep field `random.seed` must be an integer >= 0, got {seed!r}")
    fields = _flat({k: v for k, v in table.items() if k not in ("samples", "seed")})
    rng = np.random.default_rng(seed)
    names = sorted(fields)
    return fields, [{n: _draw(n, fields[n], rng) for n in names} for _ in range(samples)]


def _check_point(spec: SweepSpec, point: dict[str, Any]) -> None:
    """Builds the configs of ``point`` once here, so a bad value fails before any run."""
    from subterra.batch.sweep import point_params

    params = point_params(spec, point)
    try:
        if spec.kind == "fly":
            from subterra.flight.batch import perception_config

            perception_config(params.get("preset", "flight"), params.get("perception"))
        else:
            from subterra import Navigator, TerrainConfig

            config = dict(params.get("navigator_config") or {})
            terrain = config.pop("terrain", None)
            Navigator((1.0, 0.0), config=config)
            TerrainConfig(terrain)
    except SubterraError as exc:
        values = ", ".join(f"{k} = {v!r}" for k, v in point.items())
        raise ConfigError(f"sweep point ({values}): {exc}") from exc


def _check_axes(spec: SweepSpec) -> None:
    """Worlds, controllers or planners, noises and routes name what exists."""
    from subterra.sim import DEPTH_NOISE_PRESETS, LIDAR_NOISE_PRESETS, scenario_names

    if spec.kind == "fly":
        from subterra.flight.run import CONTROLLERS as arms

        noises, arms_key = DEPTH_NOISE_PRESETS, "controllers"
    else:
        from subterra.drive.run import PLANNERS as arms

        noises, arms_key = LIDAR_NOISE_PRESETS, "planners"
    for key, values, known in (("worlds", spec.worlds, scenario_names()), (arms_key, spec.arms, arms),
                               ("noises", spec.noises, noises)):
        for v in values:
            if v not in known:
                raise ConfigError(f"sweep field `{key}`: unknown {v!r} (known: {', '.join(known)})")
    for key in ("time_limit_s", "rate_hz"):
        v = spec.fixed.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0):
            raise ConfigError(f"sweep field `{key}` must be a number > 0, got {v!r}")
    if spec.kind == "fly":
        from subterra.flight.batch import _routes

        try:
            for world in spec.worlds:
                _routes(world, spec.routes)
        except InputError as exc:
            raise ConfigError(f"sweep field `routes`: {exc}") from exc


def load_sweep(spec: str | os.PathLike[str] | Mapping[str, Any]) -> SweepSpec:
    """Reads a sweep file (or its parsed TOML) and checks it; see the module docs.

    Raises :class:`~subterra.errors.FileFormatError` if the file cannot be read (missing,
    not a regular file, over 16 MiB, not UTF-8) and :class:`~subterra.errors.ConfigError`
    if it is not valid TOML or a value is invalid.
    """
    if isinstance(spec, Mapping):
        table, where = dict(spec), "sweep"
    else:
        path = Path(spec)
        table = read_toml(path, "sweep file")  # a FIFO, a device or a folder fails at once
        where = str(path)
    kind = table.get("kind", "fly")
    if kind not in KINDS:
        raise ConfigError(f"sweep field `kind` must be one of {', '.join(KINDS)}, got {kind!r}")
    unknown = sorted(set(table) - set(_COMMON_KEYS) - set(_KIND_KEYS[kind]))
    if unknown:
        raise ConfigError(f"{where}: unknown sweep field `{unknown[0]}` (a {kind} sweep takes "
                          f"{', '.join(_COMMON_KEYS + _KIND_KEYS[kind])})")
    if ("grid" in table) == ("random" in table):
        raise ConfigError(f"{where}: a sweep needs exactly one of [grid] and [random]")
    defaults = _DEFAULTS[kind]
    arms_key = "controllers" if kind == "fly" else "planners"
    fixed = {k: table[k] for k in ("time_limit_s", "rate_hz", "preset", "lidar") if k in table}
    preset = fixed.get("preset", "flight")
    if "grid" in table:
        if not isinstance(table["grid"], Mapping) or not table["grid"]:
            raise ConfigError("sweep field `grid` must be a table of fields and their values")
        mode, raw = "grid", _flat(table["grid"])
        points = None
    else:
        if not isinstance(table["random"], Mapping):
            raise ConfigError("sweep field `random` must be a table (samples, seed and the fields' ranges)")
        mode = "random"
        raw, points = _random(table["random"])
    if not raw:
        raise ConfigError(f"sweep field `{mode}` names no field to vary")
    paths = _config_paths(kind, preset)
    names = {n: _resolve(kind, n, paths) for n in raw}
    if len(set(names.values())) != len(names):
        raise ConfigError(f"sweep fields {sorted(names)} name the same field twice")
    resolved = {names[n]: v for n, v in raw.items()}
    if points is None:
        points = _grid(resolved)
    else:
        points = [{names[n]: v for n, v in p.items()} for p in points]
    out = SweepSpec(
        kind=kind,
        worlds=_strings(table.get("worlds", defaults["worlds"]), "worlds"),
        routes=table.get("routes", "all") if kind == "fly" else [],
        arms=_strings(table.get(arms_key, defaults["arms"]), arms_key),
        noises=_strings(table.get("noises", defaults["noises"]), "noises"),
        seeds=_seeds(table.get("seeds", 4)),
        fixed=fixed, fields=list(resolved), points=points, mode=mode, source=table,
    )
    _check_axes(out)
    for point in out.points:
        _check_point(out, point)
    return out
