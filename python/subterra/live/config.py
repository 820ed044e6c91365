"""The live node's settings: topics, frames, QoS, rates and the safety limits (a TOML file).

Every field has a ROS-like default (``configs/node.toml`` is the defaults, written out);
a file or dict only names what it changes. An unknown field, a wrong type or a value out of
range is a :class:`~subterra.errors.ConfigError` naming the dotted field
(``safety.max_input_age_s``).

>>> from subterra.live.config import NodeConfig
>>> cfg = NodeConfig.load("robot.toml")          # or NodeConfig.from_dict({...}), NodeConfig()
>>> cfg = NodeConfig.resolve(value)              # None, a dict, a NodeConfig or a TOML path
>>> cfg.topics.cmd_vel, cfg.qos.sensors
('/cmd_vel', 'sensor_data')
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from typing import Any

from subterra._files import read_toml
from subterra.errors import ConfigError

__all__ = ["NodeConfig"]

_QOS_NAMES = ("default", "sensor_data", "transient_local", "reliable_sensor")


@dataclass(frozen=True)
class Node:
    """``[node]``: ``domain_id`` the DDS domain (0-232, as ``ROS_DOMAIN_ID``);
    ``use_sim_time``: stamps and ages are read against ``/clock`` (a simulator), not the wall
    clock; ``name``: the node's name in diagnostics."""

    domain_id: int = 0
    use_sim_time: bool = False
    name: str = "subterra"


@dataclass(frozen=True)
class Frames:
    """``[frames]``: the world (odometry) frame and the body frame (REP 105)."""

    world: str = "odom"
    body: str = "base_link"


@dataclass(frozen=True)
class Topics:
    """``[topics]``: inputs and outputs. Lists take one topic per camera or odometry source
    (``depth[i]`` pairs with ``camera_info[i]``). An empty output name turns it off."""

    points: str = "/points"
    depth: tuple[str, ...] = ("/camera/depth/image_rect_raw",)
    camera_info: tuple[str, ...] = ("/camera/depth/camera_info",)
    odometry: tuple[str, ...] = ("/odom",)
    goal: str = "/goal_pose"
    tf: str = "/tf"
    tf_static: str = "/tf_static"
    clock: str = "/clock"
    cmd_vel: str = "/cmd_vel"
    cmd_vel_stamped: str = "/cmd_vel_stamped"
    path: str = "/subterra/path"
    map: str = "/subterra/map"
    grid_map: str = "/subterra/grid_map"
    belief: str = "/subterra/belief"
    diagnostics: str = "/diagnostics"


@dataclass(frozen=True)
class QosProfiles:
    """``[qos]``: the ROS 2 QoS profile of each group of topics: ``default`` (reliable,
    volatile, depth 10), ``sensor_data`` (best effort, depth 5), ``transient_local``
    (reliable, latched, depth 1) or ``reliable_sensor`` (reliable, depth 5: software in the
    loop, where no frame may be lost). A best-effort subscription matches any publisher; a
    reliable one only a reliable publisher."""

    sensors: str = "sensor_data"
    odometry: str = "sensor_data"
    tf: str = "default"
    tf_static: str = "transient_local"
    goal: str = "default"
    commands: str = "default"
    outputs: str = "default"
    maps: str = "transient_local"


@dataclass(frozen=True)
class Rates:
    """``[rates]``: ``odometry_hz`` the rate each odometry source is expected at (with
    several sources, the HeRO mux judges a source stale by it); how often the slower outputs
    are published [Hz] (0 turns one off). The command, the stamped command and the path go
    out with every processed frame."""

    odometry_hz: float = 10.0
    map_hz: float = 1.0
    grid_map_hz: float = 0.5
    belief_hz: float = 5.0
    diagnostics_hz: float = 1.0


@dataclass(frozen=True)
class Safety:
    """``[safety]``: when a command is replaced by a stop.

    ``max_input_age_s``: a frame older than this against the node's clock is stale;
    ``max_odometry_age_s``: the newest pose may be at most this much older than the frame;
    ``max_future_s``: a frame or pose stamped further ahead of the clock is not trusted;
    ``watchdog_s``: with no new frame for this long the node publishes a stop (once per
    period) and says so in its diagnostics. A stop is a zero ``Twist``."""

    max_input_age_s: float = 0.5
    max_odometry_age_s: float = 0.25
    max_future_s: float = 0.05
    watchdog_s: float = 0.5


@dataclass(frozen=True)
class Ground:
    """``[ground]``: ``navigator_config``: a navigator TOML (sections ``planner``,
    ``tracker``, ``recovery``, ``navigator``, ``terrain``, as ``subterra drive-batch
    --config`` takes; empty: the defaults); ``void_min_gap_deg``: void detection of a spinning
    lidar (the terrain mapper's ``ground.void_min_gap_deg``; 0 turns it off)."""

    navigator_config: str = ""
    void_min_gap_deg: float = 2.5


@dataclass(frozen=True)
class Drone:
    """``[drone]``: the pilot's perception ``preset``, ``controller`` and filter ``seed``."""

    preset: str = "flight-escape"
    controller: str = "apf-pf"
    seed: int = 0


@dataclass(frozen=True)
class NodeConfig:
    """Everything ``subterra node`` reads (see the module doc)."""

    node: Node = field(default_factory=Node)
    frames: Frames = field(default_factory=Frames)
    topics: Topics = field(default_factory=Topics)
    qos: QosProfiles = field(default_factory=QosProfiles)
    rates: Rates = field(default_factory=Rates)
    safety: Safety = field(default_factory=Safety)
    ground: Ground = field(default_factory=Ground)
    drone: Drone = field(default_factory=Drone)

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> NodeConfig:
        """The defaults with the tables of ``data`` laid over them (checked)."""
        if data is None:
            return cls()
        if not isinstance(data, dict):
            raise ConfigError(f"node config must be a table, got {type(data).__name__}")
        sections = {f.name: f for f in dataclasses.fields(cls)}
        built = {}
        for key, value in data.items():
            if key not in sections:
                raise ConfigError(f"node config: unknown section {key!r} (sections: {', '.join(sections)})")
            if not isinstance(value, dict):
                raise ConfigError(f"node config: {key} must be a table, got {value!r}")
            built[key] = _section(key, sections[key].default_factory, value)  # type: ignore[misc]
        config = cls(**built)
        config.validate()
        return config

    @classmethod
    def resolve(cls, value: NodeConfig | dict[str, Any] | str | os.PathLike[str] | None, argument: str = "config") -> NodeConfig:
        """A config in any of the library's four forms: ``None`` (the defaults), a dict of
        tables laid over them, a :class:`NodeConfig`, or the path of a TOML file."""
        if value is None or isinstance(value, cls):
            return value or cls()
        if isinstance(value, dict):
            return cls.from_dict(value)
        if isinstance(value, (str, os.PathLike)):
            return cls.load(value)
        raise ConfigError(f"argument `{argument}` must be None, a dict, a NodeConfig or a TOML path, got {type(value).__name__}")

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> NodeConfig:
        """Reads a TOML file (errors name the field and end with the path)."""
        data = read_toml(path, "node config")
        try:
            return cls.from_dict(data)
        except ConfigError as exc:
            raise ConfigError(f"{exc}: {path}") from exc

    def to_dict(self) -> dict[str, Any]:
        """Plain tables (lists for the topic lists), as the TOML file has them."""
        return {k: {f: list(v) if isinstance(v, tuple) else v for f, v in d.items()} for k, d in dataclasses.asdict(self).items()}

    def to_toml(self) -> str:
        """The settings as TOML text (:meth:`load` reads it back)."""
        lines: list[str] = []
        for section, values in self.to_dict().items():
            lines.append(f"[{section}]")
            for key, value in values.items():
                lines.append(f"{key} = {_toml_value(value)}")
            lines.append("")
        return "\n".join(lines)

    def replace(self, **sections: dict[str, Any]) -> NodeConfig:
        """A copy with fields of some sections changed: ``cfg.replace(node={"domain_id": 7})``."""
        data = self.to_dict()
        for name, values in sections.items():
            if name not in data:
                raise ConfigError(f"node config: unknown section {name!r}")
            if not isinstance(values, dict):
                raise ConfigError(f"node config: {name} must be a table (a dict), got {type(values).__name__}")
            data[name] = {**data[name], **values}
        return NodeConfig.from_dict(data)

    def validate(self) -> None:
        """Raises :class:`ConfigError` naming the first bad field."""
        n = self.node
        if not 0 <= n.domain_id <= 232:
            raise ConfigError(f"node.domain_id must be in [0, 232], got {n.domain_id}")
        for name, frame in (("frames.world", self.frames.world), ("frames.body", self.frames.body)):
            if not frame or frame.startswith("/") or not frame.isascii() or not all(c.isprintable() and not c.isspace() for c in frame):
                raise ConfigError(f"{name} must be a non-empty frame id of printable ASCII without spaces or a leading '/', got {frame!r:.80}")
        if not n.name or not n.name.isprintable() or len(n.name) > 255:
            raise ConfigError(f"node.name must be printable text of 1 to 255 characters, got {n.name!r:.80}")
        if self.frames.world == self.frames.body:
            raise ConfigError(f"frames.world and frames.body must differ, both are {self.frames.world!r}")
        from subterra.live.dds import dds_topic_name

        for f in dataclasses.fields(Topics):
            value = getattr(self.topics, f.name)
            for i, topic in enumerate(value if isinstance(value, tuple) else (value,)):
                label = f"topics.{f.name}" + (f"[{i}]" if isinstance(value, tuple) else "")
                if topic == "" and not isinstance(value, tuple) and f.name not in ("points", "goal", "tf", "tf_static", "clock", "cmd_vel"):
                    continue
                try:
                    dds_topic_name(topic)
                except Exception as exc:
                    raise ConfigError(f"{label}: {exc}") from None
        seen: dict[str, str] = {}
        for f in dataclasses.fields(Topics):
            value = getattr(self.topics, f.name)
            for i, topic in enumerate(value if isinstance(value, tuple) else (value,)):
                label = f"topics.{f.name}" + (f"[{i}]" if isinstance(value, tuple) else "")
                if topic and topic.strip("/") in seen:
                    raise ConfigError(f"{label} and {seen[topic.strip('/')]} are both {topic!r}: each topic has one role")
                seen[topic.strip("/")] = label
        if len(self.topics.depth) != len(self.topics.camera_info):
            raise ConfigError(f"topics.depth and topics.camera_info must pair one to one, got {len(self.topics.depth)} and "
                              f"{len(self.topics.camera_info)}")
        if not self.topics.depth or not self.topics.odometry:
            raise ConfigError("topics.depth and topics.odometry must each name at least one topic")
        if len(self.topics.depth) > 8:
            raise ConfigError(f"topics.depth: at most 8 cameras, got {len(self.topics.depth)}")
        if len(self.topics.odometry) > 8:
            raise ConfigError(f"topics.odometry: at most 8 sources, got {len(self.topics.odometry)}")
        for f in dataclasses.fields(QosProfiles):
            value = getattr(self.qos, f.name)
            if value not in _QOS_NAMES:
                raise ConfigError(f"qos.{f.name} must be one of {', '.join(_QOS_NAMES)}, got {value!r}")
        for f in dataclasses.fields(Rates):
            value = getattr(self.rates, f.name)
            if not (math.isfinite(value) and (0.01 <= value if f.name == "odometry_hz" else value == 0.0 or 0.01 <= value) and value <= 1000.0):
                raise ConfigError(f"rates.{f.name} must be 0 (off) or in [0.01, 1000] Hz (odometry_hz not 0), got {value}")
        for f in dataclasses.fields(Safety):
            value = getattr(self.safety, f.name)
            if not (math.isfinite(value) and 0.001 <= value <= 60.0):
                raise ConfigError(f"safety.{f.name} must be in [0.001, 60] s, got {value}")
        if not (math.isfinite(self.ground.void_min_gap_deg) and 0.0 <= self.ground.void_min_gap_deg <= 90.0):
            raise ConfigError(f"ground.void_min_gap_deg must be in [0, 90], got {self.ground.void_min_gap_deg}")
        if not 0 <= self.drone.seed < 2**64:
            raise ConfigError(f"drone.seed must be in [0, 2^64), got {self.drone.seed}")
        from subterra._core import Pilot, preset_names

        if self.drone.preset not in preset_names():
            raise ConfigError(f"drone.preset must be one of {', '.join(preset_names())}, got {self.drone.preset!r:.80}")
        if self.drone.controller not in Pilot.controllers():
            raise ConfigError(f"drone.controller must be one of {', '.join(Pilot.controllers())}, got {self.drone.controller!r:.80}")
        if "\x00" in self.ground.navigator_config or not self.ground.navigator_config.isprintable():
            raise ConfigError(f"ground.navigator_config must be a file path (printable), got {self.ground.navigator_config!r:.80}")


def _section(name: str, factory: Any, values: dict[str, Any]) -> Any:
    default = factory()
    fields = {f.name: f for f in dataclasses.fields(default)}
    out = {}
    for key, value in values.items():
        if key not in fields:
            raise ConfigError(f"{name}.{key} is not a setting (the {name} settings: {', '.join(fields)})")
        out[key] = _typed(f"{name}.{key}", getattr(default, key), value)
    return dataclasses.replace(default, **out)


def _typed(label: str, default: Any, value: Any) -> Any:
    """``value`` checked against the type of the default (bool, int, float, str, tuple of str)."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{label} must be true or false, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int) or not -(2**63) <= value < 2**63:
            raise ConfigError(f"{label} must be an integer, got {value!r}")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{label} must be a number, got {value!r:.80}")
        if isinstance(value, int) and abs(value) > 2**63:
            raise ConfigError(f"{label} must be finite, got an integer of {len(str(abs(value)))} digits")
        if not math.isfinite(float(value)):
            raise ConfigError(f"{label} must be finite, got {value!r}")
        return float(value)
    if isinstance(default, str):
        if not isinstance(value, str) or len(value) > 4096 or not value.isprintable():
            raise ConfigError(f"{label} must be printable text (up to 4096 characters), got {value!r:.80}")
        return value
    if isinstance(default, tuple):
        items = [value] if isinstance(value, str) else value
        if not isinstance(items, list) or len(items) > 64 or not all(isinstance(v, str) and len(v) <= 4096 for v in items):
            raise ConfigError(f"{label} must be a topic name or a list of up to 64 of them, got {value!r:.80}")
        return tuple(items)
    raise ConfigError(f"{label}: unsupported setting type")  # pragma: no cover


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(value)  # pragma: no cover
