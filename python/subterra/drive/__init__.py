"""Closed-loop drives of the ground robot in the simulator: one drive (`drive`), batches
with the additive-cost baseline beside the risk-aware planner (`drive_batch`), and the
scenarios that force each recovery behaviour (`subterra.scenarios.ground`)."""

from __future__ import annotations

from subterra.drive.batch import DriveBatchResult, drive_batch
from subterra.drive.run import PLANNERS, DriveResult, drive

__all__ = ["PLANNERS", "DriveBatchResult", "DriveResult", "drive", "drive_batch"]
