"""Closed-loop flights of the aerial robot in the simulator: one flight (`fly`), batches
of randomized flights with the raw-APF baseline beside APF-PF (`fly_batch`), and the
thin-cable test of the APF-PF paper (`cable_test`)."""

from __future__ import annotations

from subterra.flight.batch import BatchResult, fly_batch
from subterra.flight.run import CONTROLLERS, FlightResult, fly, resolve_path, resolve_route

__all__ = ["CONTROLLERS", "BatchResult", "FlightResult", "fly", "fly_batch", "resolve_path", "resolve_route"]
