"""subterra: perception and planning for robots in caves, mines, tunnels and warehouses.

APF-PF (Ahmad, Sunberg, Humbert, ACC 2021): a particle filter over a 2.5D voxel grid of
a depth image estimates where the nearest obstacle probably is; the belief weights
artificial potential fields that command an aerial robot.

>>> import numpy as np, subterra
>>> camera = subterra.PinholeCamera.d435()
>>> perception = subterra.DepthPerception(camera, preset="flight", seed=0)
>>> out = perception.update(np.zeros((480, 640), np.uint16))
>>> cmd = subterra.ApfController("flight").command(goal_body=[5.0, 0.0, 0.0], perception=[out])

Frames and units follow ROS REP 103/105: body FLU, camera optical (x right, y down,
z forward), metres, seconds, radians. Every error is a :class:`subterra.errors.SubterraError`.

Terrain risk for ground robots (STEP, Fan et al. 2021; :mod:`subterra.terrain`): ``TerrainMapper``
turns lidar scans into a multi-layer ``RiskMap``; ``segment_ground`` labels ground points.

Planning (STEP, Fan et al. 2021; ``docs/planning.md``): ``RiskAStar`` finds the least-risk path on a
``RiskMap`` or any risk array and returns a ``PlanOutcome``; ``Navigator`` wires the terrain
mapper, the planner, the MPC tracker and the recovery behaviours for a robot's own loop.

Path tracking (STEP, Fan et al. 2021): ``MpcTracker`` follows a reference path with a kinodynamic MPC
(risk-limited speed, obstacle half-planes, a backup stop); ``solve`` returns an
``MpcOutput`` with the command ``(v, ω)`` to send (the QP: ``plan/mpc.rs`` module docs).

Configuration: every stage has a config class (``PerceptionConfig``, ``RobotConfig``,
``TerrainConfig``, ``RiskAStarConfig``, ``MpcConfig``, ``NavigatorConfig``, ``HeroConfig``,
``QmdpConfig``) with the same methods (``from_dict``, ``from_toml``, ``load``, ``to_dict``,
``to_toml``), and every ``config`` argument takes ``None`` (the defaults), a partial nested
dict laid over them, a config object or a TOML path. A bad or unknown field is a
:class:`~subterra.errors.ConfigError` naming it (``coarse.resolution_m``).
"""

from __future__ import annotations

import os
from pathlib import Path

from subterra import errors
from subterra._core import (
    ApfController,
    Command,
    DepthPerception,
    Escape,
    HeroConfig,
    MemoryOutput,
    MostProbableVoxel,
    MpcConfig,
    MpcOutput,
    MpcTracker,
    Navigator,
    NavigatorConfig,
    NavigatorOutput,
    ObstacleMemory,
    OdometryMux,
    OdometryMuxOutput,
    PathFollower,
    PerceptionConfig,
    PerceptionOutput,
    Pilot,
    PilotOutput,
    PinholeCamera,
    PlanOutcome,
    Qmdp,
    QmdpAction,
    QmdpConfig,
    RiskAStar,
    RiskAStarConfig,
    RiskMap,
    RobotConfig,
    TerrainConfig,
    TerrainMapper,
    __version__,
    preset_names,
    segment_ground,
)

__all__ = [
    "ApfController",
    "Command",
    "DepthPerception",
    "Escape",
    "HeroConfig",
    "MemoryOutput",
    "MostProbableVoxel",
    "MpcConfig",
    "MpcOutput",
    "MpcTracker",
    "Navigator",
    "NavigatorConfig",
    "NavigatorOutput",
    "ObstacleMemory",
    "PathFollower",
    "OdometryMux",
    "OdometryMuxOutput",
    "PerceptionConfig",
    "PerceptionOutput",
    "Pilot",
    "PilotOutput",
    "PinholeCamera",
    "PlanOutcome",
    "Qmdp",
    "QmdpAction",
    "QmdpConfig",
    "RiskAStar",
    "RiskAStarConfig",
    "RiskMap",
    "RobotConfig",
    "TerrainConfig",
    "TerrainMapper",
    "__version__",
    "errors",
    "load_config",
    "preset_names",
    "segment_ground",
]


def load_config(path: str | os.PathLike[str]) -> PerceptionConfig:
    """Reads a perception config from a TOML file laid out like ``configs/flight.toml``
    (the same as :meth:`PerceptionConfig.load`).

    Raises :class:`~subterra.errors.FileFormatError` if the file cannot be read (missing,
    not a regular file, over 16 MiB, not UTF-8) and :class:`~subterra.errors.ConfigError`
    if a value is invalid (the message names it and ends with the path).
    """
    return PerceptionConfig.load(Path(path))
