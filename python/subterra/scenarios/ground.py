"""Small hand-made worlds for the ground robot, each built to force one recovery behaviour
(STEP, Fan et al. 2021; "adaptive thresholds and recovery").

- ``dead-end``: a wall across the hall with one 2 m doorway into a corridor that is
  closed at its far end; the goal lies beyond. No path to the goal exists: the robot
  climbs the whole recovery ladder (clear map, rotate, raise thresholds, back out),
  gives up the goal and drives home.
- ``risky-slope``: a 19.5° ramp, 0.5 m up to a plateau, across the whole hall between
  start and goal (foot and crest rounded over 0.6 m, see :data:`RAMP_ROUNDING_M`). Its
  tilt risk, about 0.63 (the Husky's tilt ramp is 10°-25°), is above the nominal
  ``R_inst`` = 0.6: the robot must raise its thresholds to climb it (19.5° is far from the
  35° rollover limit). Its navigator needs two settings off by default
  (``GroundScenario.navigator_config``): :data:`PLATEAU_MIN_LENGTH_M`, to see the plateau
  as ground from the ramp's foot, and ``navigator.near_memory_highest``, to keep the ramp's
  rating from afar while it is in the blind ring.
- ``blocked-return``: the dead end, and the base the robot should return to is walled in
  too: after the ladder has run on the way to the goal and again on the way to the base,
  the robot stops (``failed``), without touching anything.

Each world is a TOML text in the format of ``docs/world-format.md`` (a flat height field
for the floor, boxes for walls), so a user can save it and edit it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from subterra.errors import InputError

#: Hall size [m]: x from 0 to LENGTH, y from 0 to WIDTH.
HALL_LENGTH_M = 26.0
HALL_WIDTH_M = 10.0
#: Height of the walls [m] (well above the robot's 0.4 m).
WALL_HEIGHT_M = 1.5
#: Thickness of the walls [m].
WALL_THICKNESS_M = 0.2
#: Height-field spacing [m].
FLOOR_RESOLUTION_M = 0.1
#: ``risky-slope``: the ramp's slope [deg] (tilt risk (19.5 - 10)/15 = 0.63 for the
#: Husky: above the nominal R_inst = 0.6), height [m] (1.4 m of ramp: an accumulated
#: risk of ~0.75, within the budget once raised) and where its foot is [m].
RAMP_SLOPE_DEG = 19.5
RAMP_HEIGHT_M = 0.5
RAMP_FOOT_X_M = 11.0
#: ``risky-slope``: the foot and the crest are rounded, the ramp's profile averaged over this
#: length [m] (its middle 0.8 m keep the full slope). Over a sharp 19.5° crest the footprint's
#: half-length (0.5 m) overhangs the ramp by tan(19.5°)·0.5 = 0.18 m, more than the 0.13 m
#: the simulator's ground robot allows before it calls a fall (``max_drop_m`` = clearance):
#: no robot could cross it. Rounded over 0.6 m the overhang stays below 0.08 m.
RAMP_ROUNDING_M = 0.6

#: ``risky-slope``: ``ground.unseen_rise_min_length_m`` of its mapper [m]. From the ramp's
#: foot the lidar (0.7 m up, blind within ~2.3 m) sees none of the ramp, and the plateau
#: beyond is a level line 0.43 m above the robot's ground: by the line fit's start rule the
#: top of an obstacle, lethal. With this the sector's first line, level and at least this
#: long, is the plateau. Off in the default navigator: a level line above the robot's ground
#: may as well be the top of a box whose face hides in the blind ring, which the default
#: keeps an obstacle; a world of ramps to plateaus turns it on.
PLATEAU_MIN_LENGTH_M = 2.0

RECOVERY_SCENARIOS = ("dead-end", "risky-slope", "blocked-return")


@dataclass(frozen=True)
class GroundScenario:
    """A world with where the robot starts, where it should go, and where home is."""

    name: str
    toml: str
    start: tuple[float, float]
    yaw: float
    goal: tuple[float, float]
    home: tuple[float, float]
    #: What must happen (the recovery behaviours a correct navigator shows here).
    expect: tuple[str, ...]
    #: The final behaviour a correct navigator ends in.
    final: str
    description: str = ""
    extra: dict = field(default_factory=dict)
    #: Settings the scenario needs laid over the navigator's (``drive(navigator_config=...)``).
    navigator_config: dict = field(default_factory=dict)

    def world(self):
        """The world, parsed (a :class:`subterra.sim.World`)."""
        from subterra.sim import World

        return World.from_toml(self.toml)


def _box(centre: tuple[float, float, float], size: tuple[float, float, float], tag: str = "wall") -> str:
    c = ", ".join(f"{v:.4f}" for v in centre)
    s = ", ".join(f"{v:.4f}" for v in size)
    return f'[[box]]\ncentre = [{c}]\nsize = [{s}]\ntag = "{tag}"\n'


def _wall(x0: float, y0: float, x1: float, y1: float) -> str:
    """An axis-aligned wall from (x0, y0) to (x1, y1) (one of the two must be equal)."""
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    sx = abs(x1 - x0) + WALL_THICKNESS_M
    sy = abs(y1 - y0) + WALL_THICKNESS_M
    return _box((cx, cy, WALL_HEIGHT_M / 2), (sx, sy, WALL_HEIGHT_M))


def _floor(heights: np.ndarray) -> str:
    rows = ",\n".join("  [" + ", ".join(f"{h:.4f}" for h in row) + "]" for row in heights)
    return f"[heightfield]\norigin = [-1.0, -1.0]\nresolution = {FLOOR_RESOLUTION_M}\nheights = [\n{rows}\n]\n"


def _floor_grid() -> tuple[np.ndarray, np.ndarray]:
    xs = np.arange(-1.0, HALL_LENGTH_M + 1.0 + 1e-9, FLOOR_RESOLUTION_M)
    ys = np.arange(-1.0, HALL_WIDTH_M + 1.0 + 1e-9, FLOOR_RESOLUTION_M)
    return np.meshgrid(xs, ys)


def _hall() -> list[str]:
    return [
        _wall(0.0, 0.0, HALL_LENGTH_M, 0.0),
        _wall(0.0, HALL_WIDTH_M, HALL_LENGTH_M, HALL_WIDTH_M),
        _wall(0.0, 0.0, 0.0, HALL_WIDTH_M),
        _wall(HALL_LENGTH_M, 0.0, HALL_LENGTH_M, HALL_WIDTH_M),
    ]


def _regions(start: tuple[float, float], goal: tuple[float, float]) -> str:
    return (
        f'[[region]]\nname = "start"\ncentre = [{start[0]}, {start[1]}, 0.0]\nradius = 1.0\n'
        f'[[region]]\nname = "goal"\ncentre = [{goal[0]}, {goal[1]}, 0.0]\nradius = 1.0\n'
        '[[route]]\nname = "start-goal"\nfrom = "start"\nto = "goal"\n'
    )


#: ``dead-end``: width of the doorway and of the corridor behind it, wall centre to wall
#: centre [m] (1.8 m between the faces). The Husky's corners sweep a circle 1.2 m across
#: when it turns in place; the recoveries check that circle, 5 cm wider and cell by cell
#: (0.1 m), against the mapped walls before they turn, which a narrower corridor fails.
DOORWAY_WIDTH_M = 2.0


def _dead_end_walls() -> list[str]:
    door_lo, door_hi = HALL_WIDTH_M / 2 - DOORWAY_WIDTH_M / 2, HALL_WIDTH_M / 2 + DOORWAY_WIDTH_M / 2
    x_cross, x_end = 10.0, 16.0
    return [
        _wall(x_cross, 0.0, x_cross, door_lo),
        _wall(x_cross, door_hi, x_cross, HALL_WIDTH_M),
        _wall(x_cross, door_lo, x_end, door_lo),
        _wall(x_cross, door_hi, x_end, door_hi),
        _wall(x_end, door_lo, x_end, door_hi),
    ]


def _rounded_ramp(x: np.ndarray) -> np.ndarray:
    """``risky-slope``'s floor height at ``x`` [m]: the ramp from ``RAMP_FOOT_X_M`` up
    ``RAMP_HEIGHT_M`` at ``RAMP_SLOPE_DEG``, averaged over ``RAMP_ROUNDING_M`` (a moving
    average, on a 1 cm profile)."""
    run = RAMP_HEIGHT_M / np.tan(np.radians(RAMP_SLOPE_DEG))
    step = 0.01
    xs = np.arange(RAMP_FOOT_X_M - RAMP_ROUNDING_M, RAMP_FOOT_X_M + run + RAMP_ROUNDING_M + step / 2, step)
    sharp = RAMP_HEIGHT_M * np.clip((xs - RAMP_FOOT_X_M) / run, 0.0, 1.0)
    n = max(1, round(RAMP_ROUNDING_M / step))
    padded = np.concatenate([np.zeros(n), sharp, np.full(n, RAMP_HEIGHT_M)])
    smooth = np.convolve(padded, np.ones(n) / n, mode="same")[n:-n]
    return np.interp(x, xs, smooth)


def recovery_scenario(name: str) -> GroundScenario:
    """The scenario ``name`` (one of :data:`RECOVERY_SCENARIOS`)."""
    mid = HALL_WIDTH_M / 2
    start, goal = (2.0, mid), (22.0, mid)
    xg, _ = _floor_grid()
    navigator_config: dict = {}
    heights = np.zeros_like(xg)
    parts = _hall()
    if name == "dead-end":
        parts += _dead_end_walls()
        home = start
        expect = ("clear_map", "rotate", "raise_thresholds", "back_out")
        final = "home"
        description = "a corridor closed at its far end is the only way on: give up the goal, back out, go home"
    elif name == "risky-slope":
        heights = _rounded_ramp(xg)
        home = start
        expect = ("raise_thresholds",)
        final = "goal_reached"
        description = (f"a {RAMP_SLOPE_DEG:.1f}° ramp {RAMP_HEIGHT_M} m up to a plateau, wall to wall: raise the "
                       "thresholds to climb it")
        navigator_config = {"terrain": {"ground": {"unseen_rise_min_length_m": PLATEAU_MIN_LENGTH_M}},
                            "navigator": {"near_memory_highest": True}}
    elif name == "blocked-return":
        parts += _dead_end_walls()
        home = (5.0, 2.0)
        parts += [_wall(4.0, 0.0, 4.0, 3.0), _wall(4.0, 3.0, 6.0, 3.0), _wall(6.0, 0.0, 6.0, 3.0)]  # base walled in
        expect = ("clear_map", "rotate", "raise_thresholds", "back_out")
        final = "failed"
        description = "the goal is beyond a dead end and the base is walled in: stop safely when every behaviour has failed twice"
    else:
        raise InputError(f"argument `name` must be one of {', '.join(RECOVERY_SCENARIOS)}, got {name!r}")
    text = f'name = "{name}"\n' + "".join(parts) + _regions(start, goal) + _floor(heights)
    return GroundScenario(name=name, toml=text, start=start, yaw=0.0, goal=goal, home=home, expect=expect, final=final,
                          description=description, navigator_config=navigator_config)
