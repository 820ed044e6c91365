"""The simulator: worlds, ray-cast depth cameras and lidars with realistic noise, a
quadrotor and a ground robot, and per-run metrics (crate `subterra-sim`).

>>> from subterra import sim
>>> world = sim.World.scenario("highbay", seed=0)
>>> sensors = {"front": (sim.DepthCamera.d435(), None, "d435")}   # sensor, body_from_sensor, noise
>>> s = sim.Simulation(world, "quadrotor", sensors, seed=0, start=world.regions["A"][0])
>>> s.set_goal(region="B")
>>> obs = s.observe()                        # obs["depth"]["front"]: (480, 640) float32 [m]
>>> out = s.step([0.5, 0.0, 0.0, 0.0], dt=0.1)   # or a subterra.Command; {"status": "running", ...}

World files are TOML (docs/world-format.md); `World.from_toml(text)` or :func:`load_world`.
"""

from __future__ import annotations

import os
from pathlib import Path

from subterra._core import sim as _sim
from subterra._files import read_regular_text
from subterra.errors import FileFormatError

World = _sim.World
DepthCamera = _sim.DepthCamera
Lidar = _sim.Lidar
Simulation = _sim.Simulation
scenario_names = _sim.scenario_names

#: Depth noise presets of `DepthCamera.render(noise=...)` and `Simulation.add_depth_camera` (the core's list).
DEPTH_NOISE_PRESETS: tuple[str, ...] = _sim.DEPTH_NOISE_PRESETS
#: The depth noise of closed-loop flights unless one is named: a D435's phantom returns.
DEFAULT_DEPTH_NOISE = "d435-phantom"
#: Lidar noise presets (the core's list).
LIDAR_NOISE_PRESETS: tuple[str, ...] = _sim.LIDAR_NOISE_PRESETS

__all__ = [
    "DEFAULT_DEPTH_NOISE",
    "DEPTH_NOISE_PRESETS",
    "LIDAR_NOISE_PRESETS",
    "DepthCamera",
    "Lidar",
    "Simulation",
    "World",
    "load_world",
    "scenario_names",
]


def load_world(path: str | os.PathLike[str]) -> World:
    """Reads a world file (TOML). Errors name the field or the line, and end with the path.

    Raises :class:`~subterra.errors.FileFormatError` if the file cannot be read (missing,
    not a regular file, over 16 MiB, not UTF-8) or is not a valid world.
    """
    p = Path(path)
    text = read_regular_text(p, "world file")  # a FIFO, a device or a folder fails at once
    try:
        return World.from_toml(text)
    except FileFormatError as exc:
        raise FileFormatError(f"{exc}: {p}") from exc
