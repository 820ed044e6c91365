"""A live view of the node: Foxglove's WebSocket protocol (``foxglove-sdk``, extra
``subterra[viz]``).

:class:`FoxgloveView` serves every message the node publishes (commands, path, maps,
grid map, belief, diagnostics) on a Foxglove WebSocket server, as the same ROS 2 CDR
bytes that go out over DDS with their ``ros2msg`` schemas: open Foxglove, connect to
``ws://HOST:PORT`` and the topics appear with their ROS names and types. No ROS install
and no ``foxglove_bridge`` are needed.

The server listens on the loopback interface (``127.0.0.1``) unless another address is
given: it has no authentication, and anyone who can reach the port sees the robot's maps.
To watch from another machine, tunnel it (``ssh -L 8765:127.0.0.1:8765 robot``) rather
than listening on ``0.0.0.0``.

>>> from subterra.live.view import FoxgloveView
>>> view = FoxgloveView(port=8765)
>>> node = make_node("ground", config, view=view)      # ``subterra node ground --foxglove 8765``
"""

from __future__ import annotations

import threading
import time
from typing import Any

from subterra._extras import require
from subterra.errors import ConfigError, InputError
from subterra.live.dds import typestore

__all__ = ["FoxgloveView", "parse_address"]

#: Where the view listens by default.
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765


def parse_address(text: str) -> tuple[str, int]:
    """``PORT`` or ``HOST:PORT`` -> (host, port); host default :data:`DEFAULT_HOST`; port 0 picks a free one."""
    if not isinstance(text, str) or not text.isascii() or not text.isprintable():
        raise ConfigError(f"the view address must be PORT or HOST:PORT, got {text!r:.80}")
    host, _, port = text.rpartition(":")
    bracketed = host.startswith("[") and host.endswith("]")
    host = host[1:-1] if bracketed else host
    if (bracketed and not host) or any(c.isspace() for c in host) or (":" in host and not bracketed):
        raise ConfigError(f"the view address must be PORT or HOST:PORT (an IPv6 host in brackets), got {text!r:.80}")
    host = host or DEFAULT_HOST
    if not port.isdigit():
        raise ConfigError(f"the view address must be PORT or HOST:PORT, got {text!r:.80}")
    number = int(port)
    if not 0 <= number <= 65535:
        raise ConfigError(f"the view port must be in [0, 65535], got {number}")
    return host, number


class FoxgloveView:
    """A Foxglove WebSocket server that mirrors the node's published messages.

    Args:
        host: the address to listen on (default loopback only).
        port: TCP port (0: a free one; :attr:`port` tells which).
        name: the server's name in Foxglove.
    """

    def __init__(self, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, *, name: str = "subterra") -> None:
        foxglove = require("foxglove", "viz", "The live view")
        if not isinstance(name, str) or not name.isprintable() or len(name) > 255:
            raise ConfigError(f"argument `name` must be printable text, got {name!r:.60}")
        if not isinstance(host, str) or not host.isprintable() or any(c.isspace() for c in host):
            raise ConfigError(f"argument `host` must be a host name or address, got {host!r:.60}")
        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise ConfigError(f"argument `port` must be an integer in [0, 65535], got {port!r}")
        self._foxglove = foxglove
        self._context = foxglove.Context()
        try:
            self._server = foxglove.start_server(name=name, host=host, port=port, context=self._context)
        except Exception as exc:  # the SDK raises its own error types for a busy or bad address
            raise ConfigError(f"the live view cannot listen on {host}:{port}: {exc}") from exc
        self.host = host
        self.port = int(self._server.port)
        self._channels: dict[str, Any] = {}
        self._lock = threading.Lock()
        self.messages = 0

    def publish(self, topic: str, msgtype: str, cdr: bytes, log_time_ns: int | None = None) -> None:
        """Sends one message (its ROS 2 CDR bytes) on ``topic``; the channel is made with the
        type's ``ros2msg`` schema the first time."""
        if self._server is None:
            raise InputError("this FoxgloveView is closed")
        if not isinstance(cdr, (bytes, bytearray, memoryview)):
            raise InputError(f"argument `cdr` must be the message's CDR bytes, got {type(cdr).__name__}")
        if log_time_ns is not None and (isinstance(log_time_ns, bool) or not isinstance(log_time_ns, int) or not 0 <= log_time_ns < 2**63):
            raise InputError(f"argument `log_time_ns` must be an integer in [0, 2^63), got {log_time_ns!r:.40}")
        if not isinstance(msgtype, str) or msgtype not in typestore().types:
            raise InputError(f"argument `msgtype`: unknown ROS 2 message type {msgtype!r:.80}")
        if not isinstance(topic, str) or not topic.startswith("/") or not topic.isprintable() or len(topic) > 256:
            raise InputError(f"argument `topic` must be a ROS topic name such as /cmd_vel, got {topic!r:.80}")
        with self._lock:
            channel = self._channels.get(topic)
            if channel is None:
                msgdef, _ = typestore().generate_msgdef(msgtype, ros_version=2)
                schema = self._foxglove.Schema(name=msgtype, encoding="ros2msg", data=msgdef.encode("utf-8"))
                channel = self._foxglove.Channel(topic, schema=schema, message_encoding="cdr", context=self._context)
                self._channels[topic] = channel
            channel.log(bytes(cdr), log_time=time.time_ns() if log_time_ns is None else int(log_time_ns))
            self.messages += 1

    @property
    def url(self) -> str:
        """What to open in Foxglove."""
        return f"ws://{self.host}:{self.port}"

    def close(self) -> None:
        """Stops the server."""
        server, self._server = getattr(self, "_server", None), None
        if server is not None:
            server.stop()

    def __enter__(self) -> FoxgloveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
