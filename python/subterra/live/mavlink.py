"""A MAVLink offboard bridge: the drone's velocity commands to a PX4 or ArduPilot autopilot.

The pilot commands a body-frame velocity in ROS's FLU convention (x forward, y left, z up,
yaw rate counter-clockwise seen from above). The bridge streams it as
``SET_POSITION_TARGET_LOCAL_NED`` velocity setpoints (pymavlink, the extra
``subterra[mavlink]``) in one of two frames:

* ``body`` (default): ``MAV_FRAME_BODY_NED`` (8), axes forward-right-down (FRD):
  ``(vx, vy, vz, yaw_rate)_FRD = (vx, -vy, -vz, -yaw_rate)_FLU``. PX4 and ArduPilot both
  read it as a velocity relative to the vehicle's heading.
* ``local``: ``MAV_FRAME_LOCAL_NED`` (1), for a command already in the world frame (ENU):
  ``(vn, ve, vd) = (vy, vx, -vz)_ENU``, yaw rate negated.

The type mask uses velocity and yaw rate only (position, acceleration and yaw ignored).

Safe by default:

* it **never arms** the vehicle, switches its mode or sends any command other than
  setpoints and heartbeats: arming and the offboard/GUIDED switch are the operator's, and
  the autopilot's own pre-arm checks stay in charge;
* it streams the latest setpoint at ``rate_hz`` (PX4 leaves offboard below 2 Hz) only while
  commands are **fresh**: when no fresh command came for ``stale_after_s`` (perception
  stale, the node stopped, a stop for untrusted inputs), it sends one zero-velocity setpoint
  and **stops streaming**, so the autopilot's own offboard-loss failsafe takes over (PX4
  ``COM_OBL_RC_ACT``, ArduPilot's GUIDED timeout). Streaming resumes with the next fresh
  command;
* a non-finite command is never sent (it counts as stale).

A heartbeat (``MAV_TYPE_ONBOARD_CONTROLLER``) goes out at 1 Hz from the start.

>>> from subterra.live.mavlink import MavlinkBridge
>>> with MavlinkBridge("udpout:127.0.0.1:14540") as bridge:     # PX4 SITL's offboard port
...     bridge.command((0.5, 0.0, 0.0), yaw_rate=0.1)            # FLU, body frame, every frame
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from subterra._extras import require
from subterra.errors import ConfigError, InputError

__all__ = ["FRAMES", "MavlinkBridge", "MavlinkStats", "flu_to_frd", "enu_to_ned", "VELOCITY_TYPE_MASK"]

#: MAVLink frames by the bridge's name for them.
FRAMES = {"body": 8, "local": 1}  # MAV_FRAME_BODY_NED, MAV_FRAME_LOCAL_NED
#: POSITION_TARGET_TYPEMASK: ignore x, y, z (1, 2, 4), ax, ay, az (64, 128, 256) and yaw (1024).
VELOCITY_TYPE_MASK = 1 | 2 | 4 | 64 | 128 | 256 | 1024
_MAV_TYPE_ONBOARD_CONTROLLER = 18
_MAV_AUTOPILOT_INVALID = 8
_MAV_STATE_ACTIVE = 4
_MAV_COMP_ID_ONBOARD_COMPUTER = 191


#: The largest speed [m/s] and yaw rate [rad/s] the bridge sends; a larger command is refused.
MAX_SPEED_M_S = 50.0
MAX_YAW_RATE_RAD_S = 10.0


def _velocity(linear: Any, yaw_rate: Any) -> np.ndarray:
    """``(vx, vy, vz, yaw_rate)`` as four finite real numbers within the bridge's limits."""
    if isinstance(linear, np.ma.MaskedArray) or isinstance(yaw_rate, np.ma.MaskedArray):
        raise InputError("argument `linear`/`yaw_rate`: a masked array is not a command (a masked value has no value)")
    try:
        v = np.asarray(linear)
        w = np.asarray(yaw_rate)
    except Exception as exc:  # noqa: BLE001 - whatever an odd object's __array__ raises
        raise InputError(f"argument `linear`/`yaw_rate` must be numbers, got {linear!r:.60}, {yaw_rate!r:.40}") from exc
    if v.dtype.kind not in "fiu" or w.dtype.kind not in "fiu" or v.shape != (3,) or w.shape != ():
        raise InputError(f"argument `linear` must be 3 real numbers and `yaw_rate` one, got {linear!r:.60}, {yaw_rate!r:.40}")
    with np.errstate(over="ignore", invalid="ignore"):  # a longdouble beyond float64 becomes inf: refused below
        out = np.append(v.astype(np.float64), w.astype(np.float64))
    if not np.all(np.isfinite(out)):
        raise InputError(f"the command must be finite, got {out.tolist()}")
    if np.any(np.abs(out[:3]) > MAX_SPEED_M_S) or abs(out[3]) > MAX_YAW_RATE_RAD_S:
        raise InputError(f"the command must be within {MAX_SPEED_M_S} m/s and {MAX_YAW_RATE_RAD_S} rad/s, got {out.tolist()}")
    return out


def flu_to_frd(linear: Sequence[float], yaw_rate: float) -> tuple[float, float, float, float]:
    """A body velocity and yaw rate from ROS's FLU axes to MAVLink's FRD axes."""
    x, y, z, w = (float(v) for v in _velocity(linear, yaw_rate))
    return x, -y, -z, -w


def enu_to_ned(linear: Sequence[float], yaw_rate: float) -> tuple[float, float, float, float]:
    """A world velocity (ENU, REP 103) and yaw rate (about up) to NED (about down)."""
    e, n, u, w = (float(v) for v in _velocity(linear, yaw_rate))
    return n, e, -u, -w


@dataclass
class MavlinkStats:
    """What the bridge sent."""

    setpoints: int = 0
    heartbeats: int = 0
    failsafes: int = 0
    rejected: int = 0
    streaming: bool = False
    events: list[str] = field(default_factory=list)


def _check_connection(connection: Any) -> None:
    """A pymavlink connection string: ``udp*:HOST:PORT`` / ``tcp*:HOST:PORT`` with a port in
    1..65535, or a device path."""
    if not isinstance(connection, str) or not connection or len(connection) > 1024 or not connection.isprintable():
        raise ConfigError(f"argument `connection` must be a pymavlink connection string, got {connection!r:.80}")
    if connection.startswith(("udp", "tcp")):
        _, _, rest = connection.partition(":")
        host, _, port = rest.rpartition(":")
        if not (port.isascii() and port.isdigit() and 1 <= int(port) <= 65535):
            raise ConfigError(f"argument `connection` {connection!r}: the port must be in 1..65535")
        if not host or any(c.isspace() for c in host):
            raise ConfigError(f"argument `connection` {connection!r}: expected KIND:HOST:PORT with a host")


class MavlinkBridge:
    """Streams velocity setpoints to an autopilot (see the module doc).

    Args:
        connection: a pymavlink connection string (``udpout:HOST:PORT`` to an autopilot's
            UDP port, ``udpin:0.0.0.0:PORT``, ``tcp:HOST:PORT`` or a serial device).
        frame: ``body`` (FLU in, ``MAV_FRAME_BODY_NED`` out) or ``local`` (ENU in,
            ``MAV_FRAME_LOCAL_NED`` out).
        target_system, target_component: the autopilot's ids (1, 1 by default).
        system_id: this bridge's MAVLink system id (default 1, the vehicle's, as a companion
            computer on the vehicle uses); its component is the onboard computer (191).
        rate_hz: setpoint stream rate while fresh (default 20 Hz, in [2, 100]).
        stale_after_s: with no fresh command this long, send a stop and stop streaming.
        baud: the serial rate when ``connection`` is a serial device (``/dev/ttyAMA0``).
    """

    def __init__(
        self,
        connection: str = "udpout:127.0.0.1:14540",
        *,
        frame: str = "body",
        target_system: int = 1,
        target_component: int = 1,
        system_id: int = 1,
        rate_hz: float = 20.0,
        stale_after_s: float = 0.5,
        baud: int = 921600,
    ) -> None:
        if not isinstance(frame, str) or frame not in FRAMES:
            raise ConfigError(f"argument `frame` must be one of {', '.join(FRAMES)}, got {frame!r}")
        for name, value in (("target_system", target_system), ("target_component", target_component), ("system_id", system_id)):
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 255:
                raise ConfigError(f"argument `{name}` must be an integer in [0, 255], got {value!r}")
        if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and 2.0 <= rate_hz <= 100.0):
            raise ConfigError(f"argument `rate_hz` must be in [2, 100] Hz, got {rate_hz!r}")
        if not (isinstance(stale_after_s, (int, float)) and math.isfinite(stale_after_s) and 0.0 < stale_after_s <= 10.0):
            raise ConfigError(f"argument `stale_after_s` must be in (0, 10] s, got {stale_after_s!r}")
        if isinstance(baud, bool) or not isinstance(baud, int) or not 1200 <= baud <= 12_000_000:
            raise ConfigError(f"argument `baud` must be an integer in [1200, 12000000], got {baud!r}")
        _check_connection(connection)
        mavutil = require("pymavlink.mavutil", "mavlink", "The MAVLink bridge")
        self.frame = frame
        self.target = (target_system, target_component)
        self.rate_hz = float(rate_hz)
        self.stale_after_s = float(stale_after_s)
        self.stats = MavlinkStats()
        if not connection.startswith(("udp", "tcp")):  # a serial device: pymavlink needs pyserial
            require("serial", "mavlink", "A serial MAVLink link")
        try:
            self._conn = mavutil.mavlink_connection(connection, baud=int(baud), source_system=system_id,
                                                    source_component=_MAV_COMP_ID_ONBOARD_COMPUTER)
        except (OSError, ValueError, OverflowError) as exc:
            raise InputError(f"argument `connection`: cannot open {connection!r}: {exc}") from exc
        self._lock = threading.Lock()
        self._setpoint = (0.0, 0.0, 0.0, 0.0)
        self._last_fresh: float | None = None
        self._started = time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="subterra-mavlink", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ input

    def command(self, linear: Sequence[float], yaw_rate: float = 0.0, *, fresh: bool = True) -> bool:
        """The newest command (FLU body, or ENU world with ``frame="local"``) [m/s, rad/s].
        ``fresh=False`` (a stop because the inputs cannot be trusted) counts as no command:
        the stream stops after ``stale_after_s``. Returns whether it was taken: a command
        that is not 3 + 1 finite real numbers, or is beyond :data:`MAX_SPEED_M_S` /
        :data:`MAX_YAW_RATE_RAD_S`, is refused and counted in ``stats.rejected``."""
        if self._stop.is_set():
            raise InputError("this MavlinkBridge is closed")
        if not isinstance(fresh, (bool, np.bool_)):
            raise InputError(f"argument `fresh` must be True or False, got {fresh!r:.40}")
        convert = flu_to_frd if self.frame == "body" else enu_to_ned
        try:
            setpoint = convert(linear, yaw_rate)
        except InputError as exc:
            self.stats.rejected += 1
            self.stats.events.append(f"refused: {exc}")
            del self.stats.events[:-100]
            return False
        with self._lock:
            if fresh:
                self._setpoint = setpoint
                self._last_fresh = time.monotonic()
                if not self.stats.streaming:
                    self.stats.streaming = True
                    self.stats.events.append("stream started")
                    self._send(setpoint)
        return True

    # ------------------------------------------------------------------ output

    def _send(self, setpoint: tuple[float, float, float, float]) -> None:
        vx, vy, vz, yaw_rate = setpoint
        boot_ms = int(1e3 * (time.monotonic() - self._started)) & 0xFFFFFFFF
        self._conn.mav.set_position_target_local_ned_send(
            boot_ms, self.target[0], self.target[1], FRAMES[self.frame], VELOCITY_TYPE_MASK,
            0.0, 0.0, 0.0, vx, vy, vz, 0.0, 0.0, 0.0, 0.0, yaw_rate,
        )
        self.stats.setpoints += 1

    def _heartbeat(self) -> None:
        self._conn.mav.heartbeat_send(_MAV_TYPE_ONBOARD_CONTROLLER, _MAV_AUTOPILOT_INVALID, 0, 0, _MAV_STATE_ACTIVE)
        self.stats.heartbeats += 1

    def _loop(self) -> None:
        period = 1.0 / self.rate_hz
        next_beat = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            try:
                if now >= next_beat:
                    self._heartbeat()
                    next_beat = now + 1.0
                with self._lock:
                    if self.stats.streaming:
                        if self._last_fresh is None or now - self._last_fresh > self.stale_after_s:
                            # Stale: one stop, then silence; the autopilot's failsafe takes over.
                            self._setpoint = (0.0, 0.0, 0.0, 0.0)
                            self._send(self._setpoint)
                            self.stats.streaming = False
                            self.stats.failsafes += 1
                            self.stats.events.append(f"stale for {now - (self._last_fresh or now):.2f} s: stop sent, stream stopped")
                        else:
                            self._send(self._setpoint)
                self._conn.recv_match(blocking=False)  # drain what the autopilot sends (heartbeats, acks)
            except Exception as exc:  # noqa: BLE001 - the link went away, or a send failed: stop the stream, keep beating
                with self._lock:
                    self.stats.streaming = False
                if not self.stats.events or not self.stats.events[-1].startswith("link error"):
                    self.stats.events.append(f"link error: {type(exc).__name__}: {exc}")
            self._stop.wait(period)

    def close(self) -> None:
        """Sends a stop if it was streaming, and closes the link."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        with self._lock:
            if self.stats.streaming:
                try:
                    self._send((0.0, 0.0, 0.0, 0.0))
                except OSError:
                    pass
                self.stats.streaming = False
        self._conn.close()

    def __enter__(self) -> MavlinkBridge:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"MavlinkBridge(frame={self.frame!r}, target={self.target}, streaming={self.stats.streaming})"
