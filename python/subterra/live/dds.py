"""ROS 2 messages over Eclipse Cyclone DDS, with no ROS installation.

A ROS 2 node is a DDS participant that follows a few conventions (the ROS 2 design
article "Topic and Service name mapping to DDS" and ``rmw_cyclonedds``):

* a topic ``/cmd_vel`` is the DDS topic ``rt/cmd_vel``;
* the message type ``geometry_msgs/msg/Twist`` is the DDS type
  ``geometry_msgs::msg::dds_::Twist_``;
* samples are CDR encoded (XCDR1, little-endian), exactly the bytes ``ros2 bag`` stores;
* QoS comes from a handful of profiles (:data:`QOS_PROFILES`: ``default``,
  ``sensor_data``, ``transient_local`` as ``/tf_static`` and maps use).

This module does those three things over the ``cyclonedds`` package (the extra
``subterra[ros]``), which brings its own DDS binaries. The messages are the ``rosbags``
message classes of ROS 2 Humble (:func:`subterra.io.ros.default_typestore`, with
``grid_map_msgs`` added), serialized and deserialized by ``rosbags``: the DDS type is
built from the same definitions, for discovery and type matching only, so a large image
is never converted field by field.

>>> from subterra.live.dds import RosParticipant
>>> with RosParticipant(domain_id=0) as node:
...     pub = node.publisher("/cmd_vel", "geometry_msgs/msg/Twist")
...     sub = node.subscriber("/odom", "nav_msgs/msg/Odometry", qos="sensor_data")
...     pub.publish(twist)                     # a rosbags message object
...     for msg in sub.take(): ...

DDS traffic is not authenticated or encrypted (the bundled Cyclone DDS has no DDS
Security): anyone on the network segment and domain can read the topics and publish
goals or commands. docs/live.md says how to keep it to one machine or interface.
"""

from __future__ import annotations

import functools
import math
import os
import threading
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from subterra._extras import require
from subterra.errors import ConfigError, InputError

__all__ = [
    "QOS_PROFILES",
    "RosParticipant",
    "RosPublisher",
    "RosSubscriber",
    "dds_topic_name",
    "dds_type_name",
    "loopback_config",
    "typestore",
]

#: QoS profiles by name, as ROS 2 defines them (rmw_qos_profile_*): reliability,
#: durability, history depth.
QOS_PROFILES: dict[str, tuple[str, str, int]] = {
    "default": ("reliable", "volatile", 10),
    "sensor_data": ("best_effort", "volatile", 5),
    "transient_local": ("reliable", "transient_local", 1),
    # Lockstep software in the loop: nothing lost, nothing dropped by a short queue.
    "reliable_sensor": ("reliable", "volatile", 5),
}

#: Largest DDS domain id ROS 2 allows (232 for Cyclone's port mapping).
MAX_DOMAIN_ID = 232
#: Deepest history queue a QoS may ask for (samples).
MAX_QUEUE_DEPTH = 1000
#: Longest topic name (without the leading slash): ROS 2 caps a DDS topic at 255 characters.
MAX_TOPIC_CHARS = 250
_NAME_START = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ_")
_NAME_CHARS = _NAME_START | frozenset("0123456789")

def typestore() -> Any:
    """The ``rosbags`` typestore the bridge speaks: ROS 2 Humble with ``grid_map_msgs``
    (:func:`subterra.io.ros.default_typestore`)."""
    from subterra.io.ros import default_typestore

    require("rosbags.typesys", "ros", "The ROS 2 bridge")
    return default_typestore()


def dds_topic_name(topic: str) -> str:
    """The DDS topic of a ROS 2 topic: ``/cmd_vel`` -> ``rt/cmd_vel`` (a name without a
    leading slash is taken from the root namespace)."""
    if not isinstance(topic, str) or not topic.strip("/"):
        raise InputError(f"argument `topic` must be a non-empty ROS topic name, got {topic!r:.80}")
    name = topic.strip("/")
    if len(name) > MAX_TOPIC_CHARS:
        raise InputError(f"argument `topic` must be at most {MAX_TOPIC_CHARS} characters (ROS 2's limit), got {len(name)}")
    if "//" in topic or topic.endswith("/") or not all(part and (part[0] in _NAME_START) and all(c in _NAME_CHARS for c in part)
                               for part in name.split("/")):
        raise InputError(f"argument `topic` {topic!r} is not a valid ROS 2 name (letters, digits and _ between slashes, "
                         "each token starting with a letter or _)")
    return "rt/" + name


def dds_type_name(msgtype: str) -> str:
    """The DDS type of a ROS 2 message type: ``sensor_msgs/msg/Image`` ->
    ``sensor_msgs::msg::dds_::Image_``."""
    if not isinstance(msgtype, str):
        raise InputError(f"argument `msgtype` must be a ROS 2 type name such as sensor_msgs/msg/Image, got {type(msgtype).__name__}")
    parts = msgtype.split("/")
    if len(parts) != 3 or parts[1] != "msg" or not all(p and all(c in _NAME_CHARS for c in p) for p in parts):
        raise InputError(f"argument `msgtype` must look like pkg/msg/Type, got {msgtype!r}")
    return f"{parts[0]}::msg::dds_::{parts[2]}_"


class _Cdr(bytes):
    """One received sample's CDR bytes (cyclonedds sets ``sample_info`` on it)."""


def _raw_serialize(self: Any, buffer: Any = None, endianness: Any = None, use_version_2: Any = None) -> bytes:
    return self._cdr


def _raw_deserialize(cls: Any, data: Any, has_header: bool = True, use_version_2: Any = None) -> _Cdr:
    return _Cdr(data)


@functools.cache
def _idl_type(msgtype: str, raw: bool = True) -> Any:
    """The Cyclone DDS IDL struct of a ROS 2 message, built from its ``rosbags`` definition.

    With ``raw`` (the bridge's) it describes the type for discovery, and its (de)serializers
    are replaced by ones that pass CDR bytes through, which ``rosbags`` produces and reads.
    Without, it is an ordinary typed Cyclone DDS struct, which serializes field by field with
    Cyclone's own CDR code (the tests decode the bridge's bytes with it)."""
    from cyclonedds.idl import make_idl_struct
    from cyclonedds.idl import types as t
    from rosbags.typesys.base import Nodetype

    base = {
        "bool": bool, "byte": t.byte, "octet": t.byte, "char": t.uint8, "int8": t.int8, "uint8": t.uint8,
        "int16": t.int16, "uint16": t.uint16, "int32": t.int32, "uint32": t.uint32, "int64": t.int64,
        "uint64": t.uint64, "float32": t.float32, "float64": t.float64,
    }
    ts = typestore()
    if msgtype not in ts.fielddefs:
        raise InputError(f"argument `msgtype`: unknown ROS 2 message type {msgtype!r}")
    _, fields = ts.fielddefs[msgtype]

    def convert(node: Any) -> Any:
        kind, detail = node
        if kind == Nodetype.BASE:
            name, bound = detail
            if name == "string":
                return t.bounded_str[bound] if bound else str
            return base[name]
        if kind == Nodetype.NAME:
            return _idl_type(detail, raw)
        if kind == Nodetype.ARRAY:
            return t.array[convert(detail[0]), detail[1]]
        if kind == Nodetype.SEQUENCE:
            return t.sequence[convert(detail[0]), detail[1]] if detail[1] else t.sequence[convert(detail[0])]
        raise InputError(f"argument `msgtype`: {msgtype} has a field of unsupported kind {kind}")  # pragma: no cover

    annotations = {name: convert(node) for name, node in fields}
    if not annotations:  # an empty ROS message is a struct with one uint8 in DDS
        annotations = {"structure_needs_at_least_one_member": t.uint8}
    cls = make_idl_struct(msgtype.split("/")[-1], dds_type_name(msgtype), annotations)
    if raw:
        cls.serialize = _raw_serialize
        cls.deserialize = classmethod(_raw_deserialize)
    return cls


def typed_idl_type(msgtype: str) -> Any:
    """An ordinary (field by field) Cyclone DDS IDL struct of a ROS 2 message, for checking
    bytes against Cyclone's own CDR code: ``typed_idl_type(t).deserialize(cdr)``."""
    require("cyclonedds", "ros", "The ROS 2 bridge")
    return _idl_type(msgtype, False)


def _qos(profile: str | tuple[str, str, int]) -> Any:
    from cyclonedds.core import Policy, Qos
    from cyclonedds.util import duration

    if isinstance(profile, str):
        if profile not in QOS_PROFILES:
            raise ConfigError(f"qos must be one of {', '.join(QOS_PROFILES)}, got {profile!r}")
        profile = QOS_PROFILES[profile]
    if not (isinstance(profile, tuple) and len(profile) == 3):
        raise ConfigError(f"qos must be a profile name ({', '.join(QOS_PROFILES)}) or (reliability, durability, depth), "
                          f"got {profile!r:.80}")
    reliability, durability, depth = profile
    if reliability not in ("reliable", "best_effort") or durability not in ("volatile", "transient_local"):
        raise ConfigError(f"qos: reliability must be reliable or best_effort and durability volatile or transient_local, "
                          f"got {reliability!r:.40}, {durability!r:.40}")
    if isinstance(depth, bool) or not isinstance(depth, int) or not 1 <= depth <= MAX_QUEUE_DEPTH:
        raise ConfigError(f"qos: the history depth must be an integer in [1, {MAX_QUEUE_DEPTH}], got {depth!r:.40}")
    policies = [
        Policy.Reliability.Reliable(duration(seconds=1)) if reliability == "reliable" else Policy.Reliability.BestEffort,
        Policy.Durability.TransientLocal if durability == "transient_local" else Policy.Durability.Volatile,
        Policy.History.KeepLast(int(depth)),
    ]
    return Qos(*policies)


def loopback_config() -> str:
    """A Cyclone DDS configuration (for ``CYCLONEDDS_URI``) that keeps the traffic on the
    loopback interface of this machine: discovery by unicast to 127.0.0.1, no multicast."""
    return ("<CycloneDDS><Domain><General><Interfaces><NetworkInterface name=\"lo\"/></Interfaces>"
            "<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>"
            "<MaxAutoParticipantIndex>60</MaxAutoParticipantIndex><Peers><Peer address=\"127.0.0.1\"/></Peers>"
            "</Discovery></Domain></CycloneDDS>")


@dataclass
class RosPublisher:
    """Publishes one ROS 2 topic. :meth:`publish` takes a ``rosbags`` message object of
    ``msgtype`` (or its CDR bytes) and counts what it sent."""

    topic: str
    msgtype: str
    _writer: Any
    _cls: Any
    _owner: Any = None
    count: int = 0
    bytes_sent: int = 0

    def publish(self, msg: Any) -> None:
        if self._owner is not None and self._owner._dp is None:
            raise InputError(f"the publisher of {self.topic} belongs to a closed RosParticipant")
        if isinstance(msg, (bytes, bytearray, memoryview)):
            cdr = bytes(msg)
            if len(cdr) < 4 or cdr[:2] not in (b"\x00\x00", b"\x00\x01"):
                raise InputError(f"argument `msg`: CDR bytes start with the 4-byte encapsulation header (00 00 or 00 01, ...), "
                                 f"got {cdr[:4]!r}")
        else:
            if getattr(msg, "__msgtype__", None) != self.msgtype:
                raise InputError(f"argument `msg` must be a {self.msgtype} message (or its CDR bytes) for {self.topic}, "
                                 f"got {getattr(msg, '__msgtype__', type(msg).__name__)}")
            try:
                cdr = typestore().serialize_cdr(msg, self.msgtype)
            except Exception as exc:  # rosbags raises several types for a field of the wrong kind
                raise InputError(f"argument `msg`: a {self.msgtype} that cannot be serialized ({type(exc).__name__}: {exc})") from exc
        sample = self._cls.__new__(self._cls)
        sample._cdr = bytes(cdr)
        self._writer.write(sample)
        self.count += 1
        self.bytes_sent += len(sample._cdr)
        mirror = None if self._owner is None else self._owner.mirror
        if mirror is not None:
            mirror(self.topic, self.msgtype, sample._cdr)

    @property
    def matched(self) -> int:
        """How many subscriptions (readers) this publisher has found."""
        return len(self._writer.get_matched_subscriptions())


@dataclass
class RosSubscriber:
    """Receives one ROS 2 topic. :meth:`take` returns the waiting messages, oldest first,
    deserialized to ``rosbags`` message objects; a sample that does not decode as
    ``msgtype`` is counted in ``rejected`` (with its error in ``last_error``) and skipped."""

    topic: str
    msgtype: str
    _reader: Any
    _owner: Any = None
    count: int = 0
    rejected: int = 0
    last_error: str = ""

    def take(self, n: int = 64) -> list[Any]:
        n = _count(n)
        self._check_open()
        out = []
        ts = typestore()
        for sample in self._reader.take(n):
            if not isinstance(sample, _Cdr):  # a dispose or unregister notice: no data
                continue
            try:
                out.append(ts.deserialize_cdr(bytes(sample), self.msgtype))
            except Exception as exc:  # rosbags raises several types for malformed CDR
                self.rejected += 1
                self.last_error = f"{self.topic}: a {self.msgtype} that does not decode ({type(exc).__name__}: {exc})"
                continue
            self.count += 1
        return out

    def take_raw(self, n: int = 64) -> list[bytes]:
        """The waiting samples' CDR bytes (with the 4-byte encapsulation header), undecoded."""
        n = _count(n)
        self._check_open()
        return [bytes(s) for s in self._reader.take(n) if isinstance(s, _Cdr)]

    def _check_open(self) -> None:
        if self._owner is not None and self._owner._dp is None:
            raise InputError(f"the subscriber of {self.topic} belongs to a closed RosParticipant")

    @property
    def matched(self) -> int:
        """How many publications (writers) this subscriber has found."""
        return len(self._reader.get_matched_publications())


def _count(n: Any) -> int:
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_QUEUE_DEPTH:
        raise InputError(f"argument `n` must be an integer in [1, {MAX_QUEUE_DEPTH}], got {n!r:.40}")
    return n


def _seconds(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and 0.0 <= value <= 3600.0):
        raise InputError(f"argument `{name}` must be a number of seconds in [0, 3600], got {value!r:.40}")
    return float(value)


class RosParticipant:
    """A DDS participant on ``domain_id`` that publishes and subscribes ROS 2 topics.

    ``loopback``: keep discovery and traffic on 127.0.0.1 (the tests and software in the
    loop; it sets ``CYCLONEDDS_URI`` for this process unless one is set). A participant is
    used from one thread at a time per publisher or subscriber; :meth:`wait` blocks until
    any subscriber has data (or the timeout)."""

    def __init__(self, domain_id: int = 0, *, loopback: bool = False) -> None:
        require("cyclonedds", "ros", "The ROS 2 bridge")
        if isinstance(domain_id, bool) or not isinstance(domain_id, int) or not 0 <= domain_id <= MAX_DOMAIN_ID:
            raise InputError(f"argument `domain_id` must be an integer in [0, {MAX_DOMAIN_ID}], got {domain_id!r}")
        if loopback and "CYCLONEDDS_URI" not in os.environ:
            os.environ["CYCLONEDDS_URI"] = loopback_config()
        from cyclonedds.core import (
            InstanceState,
            ReadCondition,
            SampleState,
            ViewState,
            WaitSet,
        )
        from cyclonedds.domain import DomainParticipant

        self.domain_id = domain_id
        self._dp = DomainParticipant(domain_id)
        self._waitset = WaitSet(self._dp)
        self._read_condition = (ReadCondition, SampleState.NotRead | ViewState.Any | InstanceState.Any)
        self._topics: dict[str, tuple[Any, str]] = {}
        self._lock = threading.Lock()
        self.publishers: list[RosPublisher] = []
        self.subscribers: list[RosSubscriber] = []
        #: Called with ``(topic, msgtype, cdr)`` for every message published (a live view), or None.
        self.mirror: Any = None

    def _topic(self, topic: str, msgtype: str) -> Any:
        from cyclonedds.topic import Topic

        if self._dp is None:
            raise InputError("this RosParticipant is closed")
        name = dds_topic_name(topic)
        dds_type_name(msgtype)
        with self._lock:
            if name in self._topics:
                existing, kind = self._topics[name]
                if kind != msgtype:
                    raise InputError(f"topic {topic!r} is already used with type {kind}, not {msgtype}")
                return existing
            made = Topic(self._dp, name, _idl_type(msgtype))
            self._topics[name] = (made, msgtype)
            return made

    def publisher(self, topic: str, msgtype: str, qos: str | tuple[str, str, int] = "default") -> RosPublisher:
        """A publisher of ``msgtype`` (``pkg/msg/Type``) on ``topic`` with a QoS profile."""
        from cyclonedds.pub import DataWriter

        t = self._topic(topic, msgtype)
        pub = RosPublisher(topic, msgtype, DataWriter(self._dp, t, qos=_qos(qos)), _idl_type(msgtype), self)
        self.publishers.append(pub)
        return pub

    def subscriber(self, topic: str, msgtype: str, qos: str | tuple[str, str, int] = "default") -> RosSubscriber:
        """A subscriber of ``msgtype`` on ``topic`` with a QoS profile."""
        from cyclonedds.sub import DataReader

        t = self._topic(topic, msgtype)
        reader = DataReader(self._dp, t, qos=_qos(qos))
        cond_cls, mask = self._read_condition
        self._waitset.attach(cond_cls(reader, mask))
        sub = RosSubscriber(topic, msgtype, reader, self)
        self.subscribers.append(sub)
        return sub

    def wait(self, timeout_s: float) -> bool:
        """Blocks until a subscriber has an unread sample or ``timeout_s`` passes; True if
        data is waiting."""
        from cyclonedds.util import duration

        timeout_s = _seconds(timeout_s, "timeout_s")
        if self._waitset is None:
            raise InputError("this RosParticipant is closed")
        return self._waitset.wait(duration(seconds=timeout_s)) > 0

    def wait_matched(self, endpoints: Iterable[RosPublisher | RosSubscriber], timeout_s: float) -> bool:
        """Waits until each of ``endpoints`` has found at least one peer (discovery)."""
        import time

        deadline = time.monotonic() + _seconds(timeout_s, "timeout_s")
        if not isinstance(endpoints, (list, tuple)) or not all(isinstance(e, (RosPublisher, RosSubscriber)) for e in endpoints):
            raise InputError("argument `endpoints` must be a list of this participant's publishers and subscribers")
        if self._dp is None:
            raise InputError("this RosParticipant is closed")
        endpoints = list(endpoints)
        while time.monotonic() < deadline:
            if all(e.matched > 0 for e in endpoints):
                return True
            time.sleep(0.01)
        return all(e.matched > 0 for e in endpoints)

    def close(self) -> None:
        """Leaves the domain (every publisher and subscriber goes with it)."""
        dp, self._dp = getattr(self, "_dp", None), None
        if dp is not None:
            self.publishers.clear()
            self.subscribers.clear()
            self._topics.clear()
            self._waitset = None
            del dp

    def __enter__(self) -> RosParticipant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
