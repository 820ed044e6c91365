"""Robot recordings: ROS 1 bags, ROS 2 bags and MCAP files, read and written.

:func:`open_recording` opens

* a ROS 1 bag (``.bag``), through ``rosbags``;
* a ROS 2 bag: its folder (with ``metadata.yaml``, storage ``sqlite3`` or ``mcap``) or a
  bare ``.db3`` file, through ``rosbags``;
* a plain MCAP file (``.mcap``, or any file starting with the MCAP magic) with ROS 1
  (``ros1`` messages, ``ros1msg`` schemas) or ROS 2 (``cdr`` messages, ``ros2msg`` or
  ``ros2idl`` schemas) encoding, through ``mcap``,

and returns a :class:`Recording`: its topics (:class:`TopicInfo`: name, type, count,
encoding) and :meth:`Recording.messages`, which yields ``(topic, stamp_ns, message)``
(:class:`RecordedMessage`) in log-time order over the topics asked for. Messages are
decoded with the definitions stored in the file (``rosbags`` typestores; ROS 2 Humble's
or ROS 1 Noetic's built-in ones for old bags without definitions) into ``rosbags``
dataclasses, which :mod:`subterra.io.ros` turns into NumPy arrays.

A truncated MCAP (no summary at the end: a recorder killed mid-way, a copy cut short)
is read in file order up to where it breaks, and then :meth:`Recording.messages` raises
:class:`~subterra.errors.FileFormatError` saying after how many messages; a caller that
writes as it goes (``subterra replay``) keeps everything before that point.

Writing: :class:`McapWriter` writes ROS 2 messages (CDR, ``ros2msg`` schemas generated
from the typestore) to an MCAP file that Foxglove, ``ros2 bag`` and the readers here
open; :func:`write_bag` writes a ROS 2 bag (``sqlite3`` or ``mcap`` storage) or a ROS 1
``.bag``.

Errors: a missing, truncated or corrupt file and a message encoding other than ROS 1 /
CDR are :class:`~subterra.errors.FileFormatError` (the message ends with the path); a
topic that is not in the recording is an :class:`~subterra.errors.InputError` whose
message lists the topics present. The file libraries' own exceptions never escape.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import sqlite3
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path, PurePath
from typing import Any, NamedTuple

from .._files import (
    check_regular_file,
    check_writable,
    open_for_writing,
    open_regular,
    read_regular_text,
)
from ..errors import FileFormatError, InputError, SubterraError

__all__ = [
    "MCAP_MAGIC",
    "RECORDING_FORMATS",
    "McapWriter",
    "RecordedMessage",
    "Recording",
    "TopicInfo",
    "normalise_type",
    "open_recording",
    "write_bag",
]

#: The first bytes of every MCAP file.
MCAP_MAGIC = b"\x89MCAP0\r\n"
_ROSBAG1_MAGIC = b"#ROSBAG V2.0"
_SQLITE_MAGIC = b"SQLite format 3\x00"

#: What :attr:`Recording.format` can be.
RECORDING_FORMATS = ("ros1-bag", "ros2-bag", "mcap")

# MCAP message encoding -> the schema encodings that describe it.
_MCAP_ENCODINGS = {"ros1": ("ros1msg",), "cdr": ("ros2msg", "ros2idl")}
_IDL_SEPARATOR = "=" * 80 + "\n"


def _need(module: str) -> Any:
    from .._extras import require

    return require(module, "io", "Reading and writing recordings")


def normalise_type(name: str) -> str:
    """ROS 2 style type name: ``sensor_msgs/Image`` -> ``sensor_msgs/msg/Image``."""
    parts = str(name).strip("/").split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return "/".join(parts)


@dataclasses.dataclass(frozen=True)
class TopicInfo:
    """One topic of a recording.

    Attributes:
        name: the topic, e.g. ``/camera/depth/image_rect_raw``.
        type: the message type, ROS 2 spelling (``sensor_msgs/msg/Image``).
        count: messages on the topic (of the readable part, for a truncated MCAP).
        encoding: ``ros1`` or ``cdr`` (others are listed but cannot be decoded).
    """

    name: str
    type: str
    count: int
    encoding: str


class RecordedMessage(NamedTuple):
    """A message of a recording: its topic, log time [ns] and the decoded message."""

    topic: str
    stamp_ns: int
    message: Any


class Recording:
    """An open recording (see :func:`open_recording`). Close it, or use ``with``.

    Attributes:
        path: the file or folder.
        format: ``"ros1-bag"``, ``"ros2-bag"`` or ``"mcap"``.
        profile: the MCAP profile (``ros1``, ``ros2``, ...) or the bag's storage
            (``sqlite3``, ``mcap``); empty when unknown.
        damage: why the file is incomplete (a truncated MCAP), else ``None``.
    """

    def __init__(self, path: Path, fmt: str, source: Any) -> None:
        self.path = path
        self.format = fmt
        self._source = source
        self.profile: str = source.profile
        self.damage: str | None = source.damage

    # ------------------------------------------------------------------ topics

    @property
    def topics(self) -> dict[str, TopicInfo]:
        """Every topic by name, sorted by name."""
        return dict(sorted(self._source.topics.items()))

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self._source.topics.values())

    def describe_topics(self) -> str:
        """One line per topic: ``name  type  count``."""
        rows = list(self.topics.values())
        if not rows:
            return "(no topics)"
        w = max(len(t.name) for t in rows)
        v = max(len(t.type) for t in rows)
        return "\n".join(f"{t.name:<{w}}  {t.type:<{v}}  {t.count}" for t in rows)

    def _present(self) -> str:
        return ", ".join(f"{t.name} ({t.type}, {t.count})" for t in self.topics.values()) or "none"

    def topic(self, name: str, types: Iterable[str] | None = None, *, role: str = "topic") -> TopicInfo:
        """The topic ``name``, checked to have one of ``types`` (ROS 1 or 2 spelling).

        Raises:
            InputError: the topic is absent (the message lists the topics present) or
                has another type. ``role`` names the argument in the message.
        """
        info = self._source.topics.get(name)
        if info is None:
            raise InputError(f"{role} {name!r} is not in the recording; topics present: {self._present()}: {self.path}")
        if types is not None:
            wanted = [normalise_type(t) for t in types]
            if info.type not in wanted:
                raise InputError(
                    f"{role} {name!r} has type {info.type}, expected {' or '.join(wanted)}: {self.path}"
                )
        return info

    def topics_of_type(self, *types: str) -> list[str]:
        """Names of the topics with one of ``types``."""
        wanted = {normalise_type(t) for t in types}
        return [t.name for t in self.topics.values() if t.type in wanted]

    # ------------------------------------------------------------------ messages

    def messages(self, topics: Iterable[str] | str | None = None) -> Iterator[RecordedMessage]:
        """``(topic, stamp_ns, message)`` for the ``topics`` (None: all), in log-time order.

        Raises:
            InputError: a topic is not in the recording (the message lists those present).
            FileFormatError: a topic's encoding cannot be decoded, a message is corrupt,
                or the file breaks off (a truncated MCAP: after the messages before it).
        """
        if isinstance(topics, str):
            topics = [topics]
        selected = None if topics is None else list(dict.fromkeys(topics))
        for name in selected or []:
            self.topic(name)
        for name in selected if selected is not None else list(self._source.topics):
            info = self._source.topics[name]
            if info.encoding not in _MCAP_ENCODINGS:
                raise FileFormatError(
                    f"topic {name!r} has message encoding {info.encoding!r}; subterra decodes ros1 and cdr "
                    f"(ROS 1 and ROS 2) messages: {self.path}"
                )
        yield from self._source.messages(selected)

    def close(self) -> None:
        self._source.close()

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Recording({str(self.path)!r}, format={self.format!r}, topics={len(self._source.topics)})"


def open_recording(path: str | os.PathLike[str]) -> Recording:
    """Opens a ROS 1 bag, a ROS 2 bag (folder or ``.db3``) or an MCAP file.

    The kind is recognised by content (MCAP, ROS 1 bag and SQLite signatures) or, for a
    folder, by its ``metadata.yaml``. Only regular files are opened: a FIFO or a device
    (at the path, or as the metadata or a storage file of a bag folder) fails at once.

    Raises:
        FileFormatError: the path is missing, not a recording, not a regular file or
            folder, truncated so that it cannot be opened (a bag without its index), or
            corrupt; the message ends with the path.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"path: expected a str or os.PathLike, got {type(path).__name__}")
    p = Path(path)
    if not p.exists():
        raise FileFormatError(f"recording not found: {p}")
    if p.is_dir():
        if not os.path.lexists(p / "metadata.yaml"):
            raise FileFormatError(f"folder is not a ROS 2 bag (no metadata.yaml): {p}")
        meta = _bag_metadata(p)
        return Recording(p, "ros2-bag", _RosbagsSource(p, ros2=True, metadata=meta))
    with open_regular(p, "recording") as f:  # a FIFO or a device fails here, at once
        try:
            head = f.read(16)
        except OSError as exc:
            raise FileFormatError(f"cannot read recording: {exc.strerror or exc}: {p}") from exc
    if not head:
        raise FileFormatError(f"recording is empty (0 bytes): {p}")
    if head.startswith(MCAP_MAGIC):
        return Recording(p, "mcap", _McapSource(p))
    if head.startswith(_ROSBAG1_MAGIC[: len(head)]) and len(head) >= len(_ROSBAG1_MAGIC):
        if p.suffix != ".bag":
            raise FileFormatError(f"ROS 1 bag must have the extension .bag to be read: {p}")
        return Recording(p, "ros1-bag", _RosbagsSource(p, ros2=False))
    if head.startswith(_SQLITE_MAGIC):
        if p.suffix != ".db3":
            raise FileFormatError(f"SQLite ROS 2 bag file must have the extension .db3: {p}")
        return Recording(p, "ros2-bag", _RosbagsSource(p, ros2=True))
    raise FileFormatError(f"not a recording: expected an MCAP file, a ROS 1 .bag or a ROS 2 bag (.db3 or folder): {p}")


def _bag_metadata(folder: Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of a bag folder's ``metadata.yaml``, after checking
    that it and the storage files it lists are regular files (rosbags would block on a FIFO)."""
    import yaml

    meta_path = folder / "metadata.yaml"
    text = read_regular_text(meta_path, "ROS 2 bag metadata")
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise FileFormatError(f"ROS 2 bag metadata is not valid YAML ({exc}): {meta_path}") from exc
    except RecursionError as exc:  # the composer recurses once per nested node
        raise FileFormatError(f"ROS 2 bag metadata is not valid YAML: nested too deeply: {meta_path}") from exc
    info = document.get("rosbag2_bagfile_information") if isinstance(document, dict) else None
    if not isinstance(info, dict):
        raise FileFormatError(f"ROS 2 bag metadata has no rosbag2_bagfile_information mapping: {meta_path}")
    names = info.get("relative_file_paths") or []
    if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
        raise FileFormatError(f"ROS 2 bag metadata: relative_file_paths is not a list of file names: {meta_path}")
    for name in names:
        storage = folder / PurePath(name).name  # where rosbags looks for it
        if os.path.lexists(storage):  # a missing file is reported by rosbags
            check_regular_file(storage, "ROS 2 bag storage file")
    return info


def _wrap(exc: BaseException, what: str, path: Path) -> SubterraError:
    if isinstance(exc, SubterraError):
        return exc
    detail = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
    return FileFormatError(f"{what} ({detail}): {path}")


# ------------------------------------------------------------------ rosbags: ROS 1 and ROS 2 bags


class _RosbagsSource:
    def __init__(self, path: Path, *, ros2: bool, metadata: dict[str, Any] | None = None) -> None:
        highlevel = _need("rosbags.highlevel")
        typesys = _need("rosbags.typesys")
        self.path = path
        self.damage: str | None = None
        store = typesys.Stores.ROS2_HUMBLE if ros2 else typesys.Stores.ROS1_NOETIC
        try:
            self._reader = highlevel.AnyReader([path], default_typestore=typesys.get_typestore(store))
            self._reader.open()
        except (Exception, sqlite3.Error) as exc:
            raise _wrap(exc, "cannot open the bag (truncated, corrupt or not a bag)", path) from exc
        self.profile = ""
        if ros2:
            self.profile = "sqlite3"
            if metadata is not None:  # a bag folder: open_recording has read its metadata.yaml
                self.profile = str(metadata.get("storage_identifier", ""))
        self.topics: dict[str, TopicInfo] = {}
        self._connections: dict[str, list[Any]] = {}
        for conn in self._reader.connections:
            ext = conn.ext
            encoding = getattr(ext, "serialization_format", None) or ("cdr" if ros2 else "ros1")
            self._connections.setdefault(conn.topic, []).append(conn)
            old = self.topics.get(conn.topic)
            count = conn.msgcount + (old.count if old else 0)
            self.topics[conn.topic] = TopicInfo(conn.topic, normalise_type(conn.msgtype), count, encoding)

    def messages(self, topics: list[str] | None) -> Iterator[RecordedMessage]:
        conns = [c for t in (topics if topics is not None else list(self._connections)) for c in self._connections[t]]
        if not conns:
            return
        it = self._reader.messages(connections=conns)
        store = self._reader.typestore
        deserialize = store.deserialize_cdr if self._reader.is2 else store.deserialize_ros1
        n = 0
        while True:
            try:
                item = next(it)
            except StopIteration:
                return
            except (Exception, sqlite3.Error) as exc:
                raise _wrap(exc, f"bag is corrupt after {n} messages", self.path) from exc
            conn, stamp, raw = item
            try:
                # A memoryview: rosbags slices off the CDR header, which would copy a bytes object.
                msg = deserialize(memoryview(raw), conn.msgtype)
            except Exception as exc:  # noqa: BLE001 - rosbags raises several kinds
                raise _wrap(exc, f"cannot decode a {conn.msgtype} message on {conn.topic} at log time {stamp} ns", self.path) from exc
            n += 1
            yield RecordedMessage(conn.topic, int(stamp), msg)

    def close(self) -> None:
        try:
            self._reader.close()
        except Exception:  # noqa: BLE001 - closing a broken bag must not raise
            pass


# ------------------------------------------------------------------ mcap: plain MCAP files


class _McapSource:
    def __init__(self, path: Path) -> None:
        self._mcap_reader = _need("mcap.reader")
        self.path = path
        self.damage = None
        self._file = open_regular(path, "recording")  # closed in close()
        self._decoders: dict[int, Callable[[bytes], Any]] = {}
        try:
            reader = self._mcap_reader.make_reader(self._file, validate_crcs=True)
            self.profile = reader.get_header().profile
        except Exception as exc:  # noqa: BLE001
            self._file.close()
            raise _wrap(exc, "cannot read the MCAP header", path) from exc
        summary = None
        try:
            summary = reader.get_summary()
        except Exception as exc:  # noqa: BLE001 - a truncated file has no readable footer
            self.damage = f"no readable summary at the end ({type(exc).__name__}: {exc})"
        if summary is None and self.damage is None:
            self.damage = "no summary section"
        self._summary = summary if summary is not None and summary.chunk_indexes else None
        self._schemas: dict[int, Any] = {}
        self._channels: dict[int, Any] = {}
        if summary is not None and summary.statistics is not None and summary.channels:
            self._schemas = dict(summary.schemas)
            self._channels = dict(summary.channels)
            counts: Counter[int] = Counter(summary.statistics.channel_message_counts)
        else:
            counts = self._scan()
        self.topics: dict[str, TopicInfo] = {}
        for cid, ch in self._channels.items():
            schema = self._schemas.get(ch.schema_id)
            type_name = normalise_type(schema.name) if schema is not None else "(no schema)"
            old = self.topics.get(ch.topic)
            count = counts.get(cid, 0) + (old.count if old else 0)
            encoding = ch.message_encoding if schema is not None else f"{ch.message_encoding} (no schema)"
            self.topics[ch.topic] = TopicInfo(ch.topic, type_name, count, encoding)

    def _scan(self) -> Counter[int]:
        """Counts messages per channel by reading the file through, to where it breaks."""
        counts: Counter[int] = Counter()
        self._file.seek(0)
        reader = self._mcap_reader.NonSeekingReader(self._file, validate_crcs=True)
        it = reader.iter_messages(log_time_order=False)
        while True:
            try:
                schema, channel, _ = next(it)
            except StopIteration:
                break
            except Exception as exc:  # noqa: BLE001
                broken = f"breaks off after {sum(counts.values())} messages ({type(exc).__name__}: {exc})"
                self.damage = f"{self.damage}; {broken}" if self.damage else broken
                break
            counts[channel.id] += 1
            self._channels.setdefault(channel.id, channel)
            if schema is not None:
                self._schemas.setdefault(schema.id, schema)
        # Channels and schemas declared before the break but without messages.
        for record in getattr(reader, "_channels", {}).values():
            self._channels.setdefault(record.id, record)
        for record in getattr(reader, "_schemas", {}).values():
            self._schemas.setdefault(record.id, record)
        return counts

    def _decoder(self, schema: Any, channel: Any) -> Callable[[bytes], Any]:
        decoder = self._decoders.get(schema.id)
        if decoder is not None:
            return decoder
        name = normalise_type(schema.name)
        try:
            store = _typestore(schema.encoding, name, bytes(schema.data))
        except Exception as exc:  # noqa: BLE001
            raise _wrap(exc, f"cannot parse the {schema.encoding} schema of {schema.name} (topic {channel.topic})", self.path) from exc
        # memoryview: rosbags slices off the CDR header, which would copy a bytes object.
        if channel.message_encoding == "ros1":
            def decoder(raw: bytes) -> Any:
                return store.deserialize_ros1(memoryview(raw), name)
        else:
            def decoder(raw: bytes) -> Any:
                return store.deserialize_cdr(memoryview(raw), name)
        self._decoders[schema.id] = decoder
        return decoder

    def messages(self, topics: list[str] | None) -> Iterator[RecordedMessage]:
        self._file.seek(0)
        if self._summary is not None:
            reader = self._mcap_reader.make_reader(self._file, validate_crcs=True)
            it = reader.iter_messages(topics=topics, log_time_order=True)
        else:
            reader = self._mcap_reader.NonSeekingReader(self._file, validate_crcs=True)
            it = reader.iter_messages(topics=topics, log_time_order=False)
        n = 0
        while True:
            try:
                item = next(it)
            except StopIteration:
                return
            except Exception as exc:  # noqa: BLE001 - mcap raises several kinds
                raise _wrap(exc, f"MCAP file is truncated or corrupt after {n} messages", self.path) from exc
            schema, channel, message = item
            if channel.topic not in self.topics:
                # The data declares a channel that the summary (read when the file was
                # opened) does not list: the two disagree, so neither can be trusted.
                raise FileFormatError(
                    f"MCAP file is corrupt: message {n} is on topic {channel.topic!r} (channel {channel.id}), which "
                    f"its summary does not list (topics: {', '.join(sorted(self.topics)) or 'none'}): {self.path}"
                )
            if schema is None:
                raise FileFormatError(f"topic {channel.topic!r} has no schema, cannot decode it: {self.path}")
            if schema.encoding not in _MCAP_ENCODINGS.get(channel.message_encoding, ()):
                raise FileFormatError(
                    f"topic {channel.topic!r}: unknown encoding {channel.message_encoding!r} with schema encoding "
                    f"{schema.encoding!r}; subterra decodes ros1 (ros1msg) and cdr (ros2msg, ros2idl): {self.path}"
                )
            decode = self._decoder(schema, channel)
            try:
                msg = decode(message.data)
            except Exception as exc:  # noqa: BLE001
                raise _wrap(
                    exc, f"cannot decode a {schema.name} message on {channel.topic} at log time {message.log_time} ns", self.path
                ) from exc
            n += 1
            yield RecordedMessage(channel.topic, int(message.log_time), msg)

    def close(self) -> None:
        self._file.close()


# ------------------------------------------------------------------ writers


class McapWriter:
    """Writes ROS 2 messages to an MCAP file (profile ``ros2``, CDR, ``ros2msg`` schemas).

    Messages are ``rosbags`` message objects (e.g. from :mod:`subterra.io.ros`'s
    encoders or ``typestore.types[...]``); a topic's type is fixed by its first message.
    Chunks are written as they fill (``chunk_size`` bytes, zstd-compressed), so memory
    stays bounded. :meth:`close` writes the summary and the index; until then the file is
    incomplete, so use it as a context manager or close it in a ``finally``.
    """

    def __init__(self, path: str | os.PathLike[str], *, typestore: Any = None, chunk_size: int = 1 << 20) -> None:
        mcap_writer = _need("mcap.writer")
        from .ros import default_typestore

        self.path = Path(path)
        self._store = typestore if typestore is not None else default_typestore()
        self._file = open_for_writing(self.path, "recording")  # closed in close()
        self._writer = mcap_writer.Writer(self._file, chunk_size=chunk_size)
        self._writer.start(profile="ros2", library="subterra")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self.counts: Counter[str] = Counter()
        self.closed = False

    def _channel(self, topic: str, msgtype: str) -> int:
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != msgtype:
                raise InputError(f"topic {topic!r} already carries {known[1]}, got a {msgtype}: {self.path}")
            return known[0]
        schema_id = self._schemas.get(msgtype)
        if schema_id is None:
            msgdef, _ = self._store.generate_msgdef(msgtype, ros_version=2)
            schema_id = self._writer.register_schema(name=msgtype, encoding="ros2msg", data=msgdef.encode("utf-8"))
            self._schemas[msgtype] = schema_id
        channel_id = self._writer.register_channel(topic=topic, message_encoding="cdr", schema_id=schema_id)
        self._channels[topic] = (channel_id, msgtype)
        return channel_id

    def write(self, topic: str, msg: Any, *, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        """Adds ``msg`` on ``topic`` at ``log_time_ns`` [ns]."""
        if self.closed:
            raise InputError(f"McapWriter: the file is closed, cannot write {topic!r}: {self.path}")
        msgtype = msg.__msgtype__
        channel_id = self._channel(topic, msgtype)
        data = self._store.serialize_cdr(msg, msgtype)
        self._writer.add_message(
            channel_id=channel_id, log_time=int(log_time_ns), data=bytes(data),
            publish_time=int(log_time_ns if publish_time_ns is None else publish_time_ns),
        )
        self.counts[topic] += 1

    def close(self) -> None:
        """Writes the summary and closes the file; safe to call twice."""
        if self.closed:
            return
        self.closed = True
        try:
            try:
                self._writer.finish()
            finally:
                self._file.close()
        except OSError as exc:  # a file that opens but takes no bytes (/proc/self/mem, a full disk)
            raise InputError(f"cannot write recording: {exc.strerror or exc}: {self.path}") from None

    def __enter__(self) -> McapWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_bag(
    path: str | os.PathLike[str],
    messages: Iterable[tuple[str, int, Any]],
    *,
    storage: str = "sqlite3",
    typestore: Any = None,
) -> Path:
    """Writes ``(topic, log_time_ns, message)`` items to a bag and returns its path.

    ``path`` ending in ``.bag``: a ROS 1 bag (messages built with a ROS 1 typestore, e.g.
    ``get_typestore(Stores.ROS1_NOETIC)``, which is the default ``typestore`` then).
    Otherwise a ROS 2 bag folder with ``storage`` ``"sqlite3"`` or ``"mcap"`` (messages
    of a ROS 2 typestore, default Humble). The path must not exist yet and its folder must (an
    :class:`~subterra.errors.InputError` naming the path otherwise).
    """
    p = Path(path)
    check_writable(p, "bag", new=True)
    typesys = _need("rosbags.typesys")
    if p.suffix == ".bag":
        rosbag1 = _need("rosbags.rosbag1")
        store = typestore if typestore is not None else typesys.get_typestore(typesys.Stores.ROS1_NOETIC)
        writer = rosbag1.Writer(p)
        serialize = store.serialize_ros1
    else:
        rosbag2 = _need("rosbags.rosbag2")
        plugins = {"sqlite3": rosbag2.StoragePlugin.SQLITE3, "mcap": rosbag2.StoragePlugin.MCAP}
        if storage not in plugins:
            raise InputError(f"storage: expected 'sqlite3' or 'mcap', got {storage!r}")
        from .ros import default_typestore

        store = typestore if typestore is not None else default_typestore()
        writer = rosbag2.Writer(p, version=8, storage_plugin=plugins[storage])
        serialize = store.serialize_cdr
    connections: dict[str, Any] = {}
    writer.open()
    try:
        for topic, stamp, msg in messages:
            conn = connections.get(topic)
            if conn is None:
                conn = writer.add_connection(topic, msg.__msgtype__, typestore=store)
                connections[topic] = conn
            writer.write(conn, int(stamp), serialize(msg, msg.__msgtype__))
    finally:
        writer.close()
    return p


@functools.lru_cache(maxsize=64)
def _typestore(encoding: str, name: str, data: bytes) -> Any:
    """A rosbags typestore holding the types of one embedded schema (``ros2msg``,
    ``ros1msg`` or ``ros2idl`` text). Kept per schema text for the process: recordings
    of one robot embed the same schemas, and rosbags compiles a (de)serializer per store,
    which costs more than reading a short file. A schema that does not parse raises (and
    is not kept)."""
    typesys = _need("rosbags.typesys")
    text = data.decode("utf-8", errors="replace")
    if encoding == "ros2idl":
        types: dict[str, Any] = {}
        parts = text.split(_IDL_SEPARATOR)[1:] if text.startswith(_IDL_SEPARATOR + "IDL: ") else [text]
        for part in parts:
            idl = part.split("\n", 1)[1] if part.startswith("IDL: ") else part
            types.update(typesys.get_types_from_idl(idl))
    else:
        types = typesys.get_types_from_msg(text, name)
    store = typesys.get_typestore(typesys.Stores.EMPTY)
    store.register(types)
    return store
