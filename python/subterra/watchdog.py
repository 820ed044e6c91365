"""A sensor watchdog for the control loop: is this frame new evidence, and how much of the
last command may still be trusted.

A robot must not fly on a camera that stopped: a driver that hangs delivers nothing, one that
misbehaves delivers the same frame again (frozen), a covered lens or dense dust gives frames
with no returns (blind). None of them is new evidence. :class:`SensorWatchdog` says so per
frame, and scales the last command down linearly over ``timeout_s`` since the last good frame:
the drone slows, then hovers until frames come back. `subterra fly --faults` uses it; a live
loop calls it the same way before `Pilot.step`.
"""

from __future__ import annotations

import math

import numpy as np

from subterra.errors import InputError


class SensorWatchdog:
    """Judges each frame: ``check(t, frame)`` -> ``(fresh, age_s, reason)``; ``scale(t)`` is
    ``1 - age / timeout_s`` clipped to [0, 1]. A frame is not fresh when it is None (lost),
    equal to the previous one (frozen), or has fewer than ``min_valid_fraction`` of its values
    valid (not ``no_return``) or of ``min_points`` points (blind)."""

    def __init__(self, timeout_s: float = 0.5, *, min_valid_fraction: float = 0.01, min_points: int = 100,
                 no_return: float = 0.0) -> None:
        if not (isinstance(timeout_s, (int, float)) and math.isfinite(timeout_s) and 0 < timeout_s <= 3600):
            raise InputError(f"argument `timeout_s` must be in (0, 3600] s, got {timeout_s!r}")
        if not (isinstance(min_valid_fraction, (int, float)) and 0 <= min_valid_fraction <= 1):
            raise InputError(f"argument `min_valid_fraction` must be in [0, 1], got {min_valid_fraction!r}")
        self.timeout_s = float(timeout_s)
        self.min_valid_fraction = float(min_valid_fraction)
        self.min_points = int(min_points)
        self.no_return = no_return
        self._last: np.ndarray | None = None
        self._fresh_s: float | None = None
        self._t: float | None = None

    def check(self, t: float, frame: np.ndarray | None) -> tuple[bool, float, str | None]:
        """Whether ``frame`` (taken at ``t`` [s]) is new evidence, the age of the last one that
        was [s] (0 when this one is), and why not (``"lost"``, ``"frozen"``, ``"blind"``)."""
        if not math.isfinite(t):
            raise InputError(f"argument `t` must be finite, got {t!r}")
        self._t = t
        reason = None
        if frame is None:
            reason = "lost"
        else:
            frame = np.asarray(frame)
            cloud = frame.ndim == 2 and frame.shape[-1] == 3
            if cloud and frame.shape[0] < self.min_points:
                reason = "blind"
            elif not cloud and np.count_nonzero(frame != self.no_return) < self.min_valid_fraction * frame.size:
                reason = "blind"
            elif self._last is not None and frame.shape == self._last.shape and np.array_equal(frame, self._last):
                reason = "frozen"
            self._last = frame.copy()
        if reason is None:
            self._fresh_s = t
            return True, 0.0, None
        age = math.inf if self._fresh_s is None else t - self._fresh_s
        return False, age, f"{reason} frames ({age:.2f} s since the last good one)" if math.isfinite(age) else f"{reason} frames"

    def scale(self, t: float | None = None) -> float:
        """How much of the last command to keep at ``t`` (default: the last check's time)."""
        t = self._t if t is None else t
        if t is None or self._fresh_s is None:
            return 0.0
        return float(min(1.0, max(0.0, 1.0 - (t - self._fresh_s) / self.timeout_s)))
