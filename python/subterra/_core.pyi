"""Type stubs of the compiled extension `subterra._core` (see crates/subterra-py)."""

import os
from collections.abc import Sequence
from types import ModuleType
from typing import Any, Literal, TypeVar

import numpy as np
import numpy.typing as npt

__version__: str
#: ``segment_ground``'s (and ``terrain --sensor-height``'s) sensor height bounds [m].
MIN_SENSOR_HEIGHT_M: float
MAX_SENSOR_HEIGHT_M: float

def preset_names() -> list[str]: ...

class PinholeCamera:
    """Pinhole intrinsics [px] of a depth camera (optical frame: x right, y down, z forward)."""

    def __init__(self, fx: float, fy: float, cx: float, cy: float, width: int, height: int) -> None: ...
    @staticmethod
    def d435() -> PinholeCamera: ...
    @property
    def fx(self) -> float: ...
    @property
    def fy(self) -> float: ...
    @property
    def cx(self) -> float: ...
    @property
    def cy(self) -> float: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...

class _Config:
    """What every config class has. ``XConfig(config)`` takes ``None`` (the defaults), a
    (partial, nested) dict laid over the defaults, an ``XConfig`` or the path of a TOML file
    laid out like ``configs/<name>.toml``; every ``config`` argument of the library takes the
    same four forms. A bad or unknown field is a ``ConfigError`` naming it."""

    def __init__(self, config: _ConfigLike[Any] = None) -> None: ...
    @classmethod
    def from_dict(cls: type[_C], d: dict[str, Any]) -> _C: ...
    @classmethod
    def from_toml(cls: type[_C], text: str) -> _C: ...
    @classmethod
    def load(cls: type[_C], path: str | os.PathLike[str]) -> _C: ...
    def to_dict(self) -> dict[str, Any]: ...
    def to_toml(self) -> str: ...

_C = TypeVar("_C", bound=_Config)
_ConfigLike = _C | dict[str, Any] | str | os.PathLike[str] | None

class PerceptionConfig(_Config):
    """APF-PF settings: grid, transition, observation, filter, apf (layout of configs/flight.toml;
    the defaults are the ``flight`` preset)."""

    @staticmethod
    def preset(name: str) -> PerceptionConfig: ...
    @staticmethod
    def from_json(text: str) -> PerceptionConfig: ...
    def to_json(self) -> str: ...
    @property
    def depth_bins(self) -> int: ...

class RobotConfig(_Config):
    """The ground robot: footprint, height, clearance [m], speed [m/s], tilt limits [deg] (Husky default)."""

    @staticmethod
    def husky() -> RobotConfig: ...

class TerrainConfig(_Config):
    """Terrain pipeline settings (layout of configs/terrain.toml)."""

class RiskAStarConfig(_Config):
    """Risk-aware A* settings (layout of configs/astar.toml)."""

class MpcConfig(_Config):
    """MPC tracker settings (layout of configs/mpc.toml)."""

class NavigatorConfig(_Config):
    """Ground navigation stack settings: sections ``planner``, ``tracker``, ``recovery``,
    ``navigator`` (layout of configs/navigator.toml; defaults for the Husky-like robot)."""

class HeroConfig(_Config):
    """HeRO health checks (layout of configs/hero.toml)."""

class QmdpConfig(_Config):
    """QMDP controller settings (defaults: the authors')."""

class MostProbableVoxel:
    @property
    def voxel(self) -> tuple[int, int, int]: ...
    @property
    def state(self) -> int: ...
    @property
    def probability(self) -> float: ...
    @property
    def depth_m(self) -> float: ...
    @property
    def centre_camera(self) -> npt.NDArray[np.float64]: ...
    @property
    def centre_body(self) -> npt.NDArray[np.float64]: ...

class PerceptionOutput:
    @property
    def belief_states(self) -> npt.NDArray[np.uint32]: ...
    @property
    def belief_probabilities(self) -> npt.NDArray[np.float64]: ...
    @property
    def p_free(self) -> float: ...
    @property
    def most_probable(self) -> MostProbableVoxel | None: ...
    @property
    def closest_depth_m(self) -> float | None: ...
    @property
    def valid_pixels(self) -> int: ...
    @property
    def in_range_pixels(self) -> int: ...
    @property
    def max_count(self) -> int: ...
    @property
    def repulsive_body(self) -> npt.NDArray[np.float64]:
        """The belief's repulsion ``Σ_s b(s)·F_rep(s)``, body frame [N]."""
    @property
    def timings(self) -> dict[str, float]:
        """Seconds per stage: ``count_s``, ``predict_s``, ``update_s``, ``belief_s``, ``total_s``."""

class DepthPerception:
    """APF-PF perception of one depth camera."""

    def __init__(
        self,
        camera: PinholeCamera,
        preset: str = "flight",
        *,
        config: _ConfigLike[PerceptionConfig] = None,
        body_from_camera: npt.ArrayLike | None = None,
        seed: int = 0,
        mode: Literal["particle", "histogram", "raw"] | None = None,
    ) -> None: ...
    def update(self, depth: npt.NDArray[np.uint16] | npt.NDArray[np.float32], scale: float | None = None) -> PerceptionOutput: ...
    @property
    def camera(self) -> PinholeCamera: ...
    @property
    def config(self) -> PerceptionConfig: ...
    @property
    def body_from_camera(self) -> npt.NDArray[np.float64]: ...
    @property
    def grid_shape(self) -> tuple[int, int, int]: ...
    @property
    def state_count(self) -> int: ...
    @property
    def free_state(self) -> int: ...
    @property
    def frames(self) -> int: ...
    @property
    def transition_build_s(self) -> float: ...
    @property
    def transition_memory_bytes(self) -> int: ...
    def belief(self) -> npt.NDArray[np.float64]: ...
    def counts(self) -> npt.NDArray[np.uint32] | None: ...
    def voxel_centres(self, frame: str = "camera") -> npt.NDArray[np.float64]: ...
    def forces_body(self) -> npt.NDArray[np.float64]: ...
    def transition_row(self, state: int) -> npt.NDArray[np.float64]: ...
    def state_of(self, i: int, j: int, k: int) -> int: ...
    def voxel_of(self, state: int) -> tuple[int, int, int] | None: ...

class MemoryOutput:
    """What one ``ObstacleMemory.update`` gives."""

    @property
    def repulsive_body(self) -> npt.NDArray[np.float64]:
        """The memory's repulsive force in the body frame [N]."""
    @property
    def cells(self) -> int:
        """Cells remembered after the update."""
    @property
    def nearest_m(self) -> float | None:
        """Distance from the body origin to the nearest remembered point [m]."""

class ObstacleMemory:
    """Where a camera's belief put obstacles, in the odometry frame, so that they still repel
    out of view (settings: the perception config's ``memory`` section; on in ``flight-memory``)."""

    def __init__(self, perception: DepthPerception) -> None: ...
    def update(self, output: PerceptionOutput, *, stamp: float, world_from_body: npt.ArrayLike, perception: DepthPerception | None = None) -> MemoryOutput: ...
    def reset(self) -> None: ...
    def points_world(self) -> npt.NDArray[np.float64]: ...
    def weights(self) -> npt.NDArray[np.float64]: ...
    def __len__(self) -> int: ...

class PilotOutput:
    """What one ``Pilot.step`` gives."""

    @property
    def command(self) -> Command: ...
    @property
    def perceptions(self) -> list[PerceptionOutput]:
        """Each camera's perception output, in camera order."""
    @property
    def target_world(self) -> npt.NDArray[np.float64]:
        """The point the attraction pulled toward before the escape (goal or carrot), world [m]."""
    @property
    def remaining_m(self) -> float:
        """Distance still to go, straight or along the path [m]."""
    @property
    def belief_push_body(self) -> npt.NDArray[np.float64]:
        """The belief's push, body frame: the summed repulsion [N], or the QMDP velocity [m/s]."""
    @property
    def memory_repulsive_body(self) -> npt.NDArray[np.float64]:
        """The obstacle memories' repulsion, body frame [N] (zero without a memory)."""
    @property
    def memory_cells(self) -> int: ...
    @property
    def escape(self) -> EscapeOutput | None: ...
    @property
    def escape_active(self) -> bool: ...
    @property
    def goal_body(self) -> npt.NDArray[np.float64]:
        """The goal the command pulled toward, body frame [m]."""
    @property
    def repulsive_body(self) -> npt.NDArray[np.float64]:
        """The repulsion the command used, body frame [N]."""
    @property
    def timings(self) -> dict[str, float]:
        """Seconds: ``perception_s``, ``control_s``, ``total_s``."""

class Pilot:
    """The drone's loop in one object: each camera's APF-PF filter, the obstacle memory and
    the escape when the preset turns them on, and the controller. ``step`` per control step."""

    def __init__(
        self,
        cameras: PinholeCamera | tuple[PinholeCamera, npt.ArrayLike] | list[PinholeCamera | tuple[PinholeCamera, npt.ArrayLike]],
        preset: str = "flight-escape",
        *,
        config: _ConfigLike[PerceptionConfig] = None,
        controller: Literal["apf-pf", "apf-pf-histogram", "apf-pf-qmdp", "raw-apf"] = "apf-pf",
        seed: int = 0,
        qmdp: dict[str, Any] | None = None,
    ) -> None: ...
    @staticmethod
    def controllers() -> list[str]: ...
    def set_goal(self, goal_world: npt.ArrayLike) -> None: ...
    def set_path(self, path: npt.ArrayLike, *, lookahead_m: float = 1.5) -> None: ...
    def step(
        self,
        frames: npt.NDArray[np.uint16] | npt.NDArray[np.float32] | list[npt.NDArray[np.uint16] | npt.NDArray[np.float32]],
        *,
        stamp: float,
        world_from_body: npt.ArrayLike,
        scale: float | None = None,
        confidence: float = 1.0,
    ) -> PilotOutput: ...
    def reset(self) -> None: ...
    @property
    def config(self) -> PerceptionConfig: ...
    @property
    def controller(self) -> str: ...
    @property
    def camera_count(self) -> int: ...
    def camera(self, n: int = 0) -> PinholeCamera: ...
    @property
    def has_memory(self) -> bool: ...
    def free_state(self, n: int = 0) -> int: ...
    def perception_info(self, n: int = 0) -> dict[str, Any]: ...
    def voxel_centres(self, frame: str = "camera", n: int = 0) -> npt.NDArray[np.float64]: ...
    def memory_points_world(self) -> npt.NDArray[np.float64]: ...
    @property
    def path_length_m(self) -> float | None: ...
    @property
    def steps(self) -> int: ...

class QmdpAction:
    """What one ``Qmdp.act`` gives."""

    @property
    def velocity_body(self) -> npt.NDArray[np.float64]:
        """The chosen evasive velocity, body frame [m/s]; it takes the repulsive force's place."""
    @property
    def index(self) -> int:
        """Its row in ``Qmdp.actions()``."""
    @property
    def value(self) -> float:
        """Its expected reward under the belief."""

class Qmdp:
    """QMDP action selection over ``perception``'s belief (the APF-PF authors' follow-up):
    evasive velocities scored by their expected reward, ``act(output)`` per frame; ``config``
    a ``QmdpConfig`` in any of the four forms (defaults: the authors' settings)."""

    def __init__(self, perception: DepthPerception, config: _ConfigLike[QmdpConfig] = None) -> None: ...
    @property
    def config(self) -> QmdpConfig: ...
    def act(self, output: PerceptionOutput) -> QmdpAction: ...
    def actions(self) -> npt.NDArray[np.float64]:
        """The action set, shape ``(A, 3)`` [m/s, body frame]."""
    def rewards(self) -> npt.NDArray[np.float64]:
        """The reward table ``R(s, a)``, shape ``(S, A)``, the free state last."""

class EscapeOutput:
    @property
    def goal_body(self) -> npt.NDArray[np.float64]:
        """The goal to attract toward, body frame [m]: the real goal, or the boundary target."""
    @property
    def mode(self) -> str:
        """``"goal"``, ``"follow-left"`` or ``"follow-right"``."""
    @property
    def active(self) -> bool: ...
    @property
    def boundary_world(self) -> npt.NDArray[np.float64] | None: ...
    @property
    def repulsive_body(self) -> npt.NDArray[np.float64]:
        """The repulsion the command should use, body frame [N] (capped while following)."""
    @property
    def engagements(self) -> int: ...

class Escape:
    """Escape from local minima by boundary following (settings: the config's ``escape`` section)."""

    def __init__(self, preset: str = "flight", *, config: _ConfigLike[PerceptionConfig] = None) -> None: ...
    def step(
        self,
        *,
        stamp: float,
        world_from_body: npt.ArrayLike,
        goal_world: npt.ArrayLike,
        remaining_m: float,
        memory: ObstacleMemory | None = None,
        repulsive_body: npt.ArrayLike | None = None,
    ) -> EscapeOutput: ...
    def reset(self) -> None: ...

class CarrotOutput:
    @property
    def carrot_world(self) -> npt.NDArray[np.float64]: ...
    @property
    def progress_m(self) -> float: ...
    @property
    def remaining_m(self) -> float: ...

class PathFollower:
    """A carrot ``lookahead_m`` ahead along a path of waypoints (world frame)."""

    def __init__(self, path: npt.ArrayLike, *, lookahead_m: float = 1.5) -> None: ...
    def update(self, position_world: npt.ArrayLike) -> CarrotOutput: ...
    def points(self) -> npt.NDArray[np.float64]: ...
    @property
    def length_m(self) -> float: ...
    def reset(self) -> None: ...

class Command:
    @property
    def v_x_m_s(self) -> float: ...
    @property
    def v_y_m_s(self) -> float: ...
    @property
    def v_z_m_s(self) -> float: ...
    @property
    def yaw_rate_rad_s(self) -> float: ...
    @property
    def reached(self) -> bool: ...
    @property
    def attractive_body(self) -> npt.NDArray[np.float64]: ...
    @property
    def repulsive_body(self) -> npt.NDArray[np.float64]: ...
    def as_array(self) -> npt.NDArray[np.float64]: ...

class ApfController:
    def __init__(self, preset: str = "flight", *, config: _ConfigLike[PerceptionConfig] = None) -> None: ...
    def command(
        self,
        goal_body: Sequence[float] | npt.ArrayLike,
        perception: PerceptionOutput | list[PerceptionOutput] | None = None,
        *,
        repulsive_body: Sequence[float] | npt.ArrayLike | None = None,
    ) -> Command: ...

_Matrix4 = npt.ArrayLike  # a 4x4 rigid transform (array or nested sequence)

class RiskMap:
    """A robot-centred, world-axis-aligned map; layers are float32 (ny, nx), row iy along world y."""

    def layer(self, name: str) -> npt.NDArray[np.float32]: ...
    @property
    def layer_names(self) -> list[str]: ...
    def risk_at(self, x: float, y: float) -> float | None: ...
    def value_at(self, name: str, x: float, y: float) -> float | None: ...
    @property
    def lethal_risk(self) -> float:
        """Risk at or above which a cell is lethal (the mapper's ``risk.lethal_risk``): the
        one definition of a lethal cell for every output."""
    def lethal(self) -> npt.NDArray[np.bool_]:
        """``(ny, nx)``: the lethal cells (combined risk >= ``lethal_risk``, observed or not)."""
    def lethal_count(self) -> int:
        """The number of lethal cells."""
    def cvar(self, alpha: float) -> npt.NDArray[np.float32]: ...
    def to_image(self, layer: str = "risk") -> npt.NDArray[np.uint8]: ...
    def cell_of(self, x: float, y: float) -> tuple[int, int] | None: ...
    @property
    def kind(self) -> Literal["coarse", "fine"]: ...
    @property
    def resolution(self) -> float: ...
    @property
    def nx(self) -> int: ...
    @property
    def ny(self) -> int: ...
    @property
    def shape(self) -> tuple[int, int]: ...
    @property
    def origin(self) -> tuple[float, float]: ...
    @property
    def origin_cell(self) -> tuple[int, int]: ...
    @property
    def extent(self) -> tuple[float, float, float, float]: ...
    @property
    def x_centres(self) -> npt.NDArray[np.float64]: ...
    @property
    def y_centres(self) -> npt.NDArray[np.float64]: ...
    @property
    def stamp(self) -> float: ...
    @property
    def scans(self) -> int: ...
    @property
    def points(self) -> int: ...
    @property
    def stats(self) -> dict[str, int]: ...
    @property
    def timings(self) -> dict[str, float]: ...

class TerrainMapper:
    """Terrain risk mapping for one ground robot and one sensor stream."""

    def __init__(
        self,
        robot: _ConfigLike[RobotConfig] = None,
        config: _ConfigLike[TerrainConfig] = None,
    ) -> None: ...
    def update(
        self,
        points: npt.ArrayLike,
        *,
        stamp: float | None = None,
        world_from_body: _Matrix4 | None = None,
        body_from_sensor: _Matrix4 | None = None,
        confidence: float = 1.0,
    ) -> RiskMap: ...
    @property
    def last_coarse(self) -> RiskMap | None: ...
    @property
    def last_fine(self) -> RiskMap | None: ...
    def set_mission_items(self, items: Sequence[Sequence[float] | dict[str, Any]] | npt.ArrayLike) -> None: ...
    def reset(self) -> None: ...
    @property
    def window_len(self) -> int: ...
    @property
    def robot(self) -> RobotConfig: ...
    @property
    def config(self) -> TerrainConfig: ...
    def newest_points(self) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]] | None: ...

def segment_ground(
    points: npt.ArrayLike, *, sensor_height: float, config: _ConfigLike[TerrainConfig] = None
) -> npt.NDArray[np.bool_]: ...

class RiskAStar:
    """Risk-aware A* on an 8-connected grid (docs/planning.md).

    Cell cost ``c = lam - ln(1 - r)`` [1/m] (NaN risk -> ``unknown_risk``); a move between
    neighbours ``d`` metres apart costs ``d * (c(a) + c(b)) / 2``; cells with ``r >= r_inst``
    are untraversable; without ``allow_corner_cutting`` a diagonal move needs both cells at its
    corner traversable. The least-cost path is returned; if its accumulated risk
    ``1 - exp(-sum d * (rho(a) + rho(b)) / 2)`` (``rho = -ln(1 - r)``) exceeds ``r_total`` the
    status is ``"budget_exceeded"``. Defaults: ``lam=0.1``, ``r_inst=0.8``, ``r_total=0.5``,
    ``carrot_m=1.0``, ``unknown_risk=0.15``, ``allow_corner_cutting=False``
    (``configs/astar.toml``). ``cost_model="additive"`` is the conventional baseline:
    ``c = 1 + additive_weight * r`` (default 2.0, Nav2 Smac's ``cost_penalty``), cells with
    ``r >= r_inst`` blocked, no budget (always ``"found"`` when reachable). Cells with
    ``r >= lethal_risk`` are untraversable whatever ``r_inst`` is (the navigator sets it to the
    terrain map's ``risk.lethal_risk``). Risks must lie in [0, 1] (NaN: unknown). ``config``: a
    ``RiskAStarConfig`` in any of the four forms (``{"r_total": 1.0}``); bad values raise
    :class:`subterra.errors.ConfigError`.
    """

    def __init__(self, config: _ConfigLike[RiskAStarConfig] = None) -> None: ...
    @property
    def config(self) -> RiskAStarConfig: ...
    def plan(
        self,
        risk: RiskMap | npt.ArrayLike,
        start: Sequence[float] | npt.ArrayLike,
        goal: Sequence[float] | npt.ArrayLike,
        *,
        resolution: float | None = None,
        origin: Sequence[float] | None = None,
    ) -> PlanOutcome:
        """Plans from the world position ``start`` (x, y) [m] to ``goal``.

        ``risk`` is a :class:`RiskMap` (its ``risk`` layer and geometry) or a 2-D float array
        ``(ny, nx)`` of per-metre risks (row iy along world y; converted to float32; NaN =
        unknown) with ``resolution`` [m/cell] (required) and ``origin`` (x, y) of cell (0, 0)'s
        lower-left corner [m] (default (0, 0)). Bad input raises
        :class:`subterra.errors.InputError` naming the argument. Releases the GIL.
        """
    def plan_cells(
        self,
        risk: RiskMap | npt.ArrayLike,
        start_cell: Sequence[int],
        goal_cell: Sequence[int],
        *,
        resolution: float | None = None,
        origin: Sequence[float] | None = None,
    ) -> PlanOutcome:
        """Like :meth:`plan` with the start and goal as cells ``(ix, iy)`` (``risk[iy, ix]``)."""
    def plan_toward(
        self,
        risk: RiskMap | npt.ArrayLike,
        start: Sequence[float] | npt.ArrayLike,
        target: Sequence[float] | npt.ArrayLike,
        *,
        resolution: float | None = None,
        origin: Sequence[float] | None = None,
    ) -> PlanOutcome:
        """Like :meth:`plan`, toward a ``target`` that may lie beyond the grid: the path leaves
        by the border cell whose cost plus λ per metre of straight line on to the target is
        least; ``goal_cell`` is that cell."""
    @property
    def lam(self) -> float: ...
    @property
    def r_inst(self) -> float: ...
    @property
    def r_total(self) -> float: ...
    @property
    def carrot_m(self) -> float: ...
    @property
    def unknown_risk(self) -> float: ...
    @property
    def allow_corner_cutting(self) -> bool: ...

class PlanOutcome:
    """The outcome of :meth:`RiskAStar.plan`. Path fields are None / empty without a path."""

    @property
    def status(self) -> Literal["found", "start_blocked", "goal_blocked", "no_path", "budget_exceeded"]:
        """``found``; ``start_blocked`` / ``goal_blocked`` (that cell has ``r >= r_inst``);
        ``no_path`` (no traversable path joins them); ``budget_exceeded`` (the least-cost path's
        accumulated risk exceeds ``r_total``; the path fields hold that rejected path)."""
    @property
    def found(self) -> bool: ...
    @property
    def path_world(self) -> npt.NDArray[np.float64]:
        """Cell centres of the path, start first, (N, 2) [m]; (0, 2) without a path."""
    @property
    def path_cells(self) -> npt.NDArray[np.int64]:
        """Cells ``(ix, iy)`` of the path, (N, 2); index a risk array as ``risk[iy, ix]``."""
    @property
    def accumulated_risk(self) -> float | None: ...
    @property
    def risk_integral(self) -> float | None: ...
    @property
    def length_m(self) -> float | None: ...
    @property
    def cost(self) -> float | None: ...
    @property
    def expanded(self) -> int: ...
    @property
    def carrot(self) -> tuple[float, float] | None:
        """The point ``carrot_m`` of path length ahead of the start along the path [m]; the
        goal's centre if the path is shorter; None unless ``found``."""
    @property
    def start_cell(self) -> tuple[int, int]: ...
    @property
    def goal_cell(self) -> tuple[int, int]: ...
    @property
    def time_s(self) -> float:
        """Seconds the core spent searching and tracing the path."""

class MpcOutput:
    """What one ``MpcTracker.solve`` gives (slacks, clearance and limits describe ``predicted``)."""

    @property
    def command(self) -> tuple[float, float]:
        """``(v, ω)`` to send now: speed at the end of the first step [m/s], yaw rate [rad/s]."""
    @property
    def predicted(self) -> npt.NDArray[np.float64]:
        """Predicted states ``[x, y, heading, speed]``, ``(N+1, 4)``; row 0 is the given state."""
    @property
    def inputs(self) -> npt.NDArray[np.float64]:
        """Planned inputs ``[accel, yaw_rate]``, ``(N, 2)`` [m/s², rad/s]."""
    @property
    def status(self) -> Literal["solved", "solved_inexact", "infeasible_backup", "solver_failed_backup"]:
        """How the solve ended; the two ``*_backup`` values mean ``predicted`` is the backup stop."""
    @property
    def is_backup(self) -> bool:
        """Whether ``predicted`` is the backup stop (brake along the heading, ω = 0)."""
    @property
    def iterations(self) -> int:
        """QPs solved (re-linearisations)."""
    @property
    def qp_iterations(self) -> int:
        """Interior-point iterations over all QPs."""
    @property
    def solve_time_s(self) -> float:
        """Wall time of the solve [s]."""
    @property
    def max_slack(self) -> float:
        """``max(max_speed_slack, max_obstacle_slack)``."""
    @property
    def max_speed_slack(self) -> float:
        """Largest excess of a predicted speed over its limits [m/s]."""
    @property
    def max_obstacle_slack(self) -> float:
        """Largest intrusion of a predicted footprint into an obstacle's margin [m]."""
    @property
    def min_clearance(self) -> float:
        """Smallest signed distance from a predicted footprint to a lethal polygon [m]; inf if none."""
    @property
    def speed_limits(self) -> npt.NDArray[np.float64]:
        """Speed limit ``v_max·(1 - r)`` at predicted states 1..N, ``(N,)`` [m/s]."""
    @property
    def reference_points(self) -> npt.NDArray[np.float64]:
        """Reference points of predicted states 1..N, ``(N, 2)`` [m]."""
    @property
    def polygons(self) -> list[npt.NDArray[np.float64]]:
        """The lethal polygons considered, each ``(K, 2)`` counter-clockwise [m] (for plotting)."""

class MpcTracker:
    """Kinodynamic MPC path tracker of a ground robot (the QP is written out in the module docs of crates/subterra/src/plan/mpc.rs).

    ``config``: None (the ``configs/mpc.toml`` defaults), a partial nested dict laid over them
    (``{"limits": {"max_speed_m_s": 0.5}}``), an ``MpcConfig`` or a TOML path. Keeps its last
    plan to warm-start the next solve; ``reset()`` forgets it.
    """

    def __init__(self, config: _ConfigLike[MpcConfig] = None) -> None: ...
    def solve(
        self,
        state: Sequence[float] | npt.ArrayLike,
        reference_path: npt.ArrayLike,
        *,
        risk: npt.ArrayLike | None = None,
        resolution: float | None = None,
        origin: Sequence[float] | None = None,
        risk_map: RiskMap | None = None,
        desired_speed: float | None = None,
    ) -> MpcOutput:
        """One solve from ``state`` ``[x, y, heading, speed]`` along ``reference_path`` ``(M, 2)``.

        Risk: ``risk`` (``(ny, nx)``, row ``iy`` along world y) with ``resolution`` [m/cell]
        and ``origin`` (world x, y of the lower-left corner of cell (0, 0)), or ``risk_map``
        (its ``risk`` layer); neither means no risk and no obstacles. Releases the GIL.
        """
    def last_qp(self) -> dict[str, Any] | None:
        """The QP of the last SQP iteration of the last solve (None before the first).

        1-D arrays ``p_colptr``, ``p_rowval``, ``p_nzval`` (``P``'s upper triangle in compressed
        columns: SciPy's ``indptr``, ``indices``, ``data``), ``q``, ``a_colptr``, ``a_rowval``,
        ``a_nzval``, ``b``, and the int ``equalities``: ``min ½zᵀPz + qᵀz`` s.t. ``A z = b`` in
        the first ``equalities`` rows and ``A z <= b`` in the rest.
        """
    @staticmethod
    def solve_qp(qp: dict[str, Any], *, solver: str | None = None, max_iterations: int | None = None) -> dict[str, Any]:
        """Solves a QP laid out as ``last_qp`` returns it with ``solver`` (``"banded"``, the
        tracker's own and the default, or ``"clarabel"``).

        Returns ``z`` (empty if failed), ``status`` (``"solved"``, ``"inexact"``, ``"failed"``),
        ``iterations`` and ``time_s`` (in the solver). Releases the GIL.
        """
    def reset(self) -> None: ...
    @property
    def config(self) -> MpcConfig: ...
    @property
    def horizon(self) -> int: ...
    @property
    def dt(self) -> float: ...

class NavigatorOutput:
    """What one ``Navigator.step`` decided."""

    @property
    def command(self) -> tuple[float, float]:
        """``(v, ω)``: forward speed [m/s] and yaw rate [rad/s] to command."""
    @property
    def behaviour(self) -> str:
        """``track``, ``clear_map``, ``rotate``, ``raise_thresholds``, ``back_out``, ``goal_reached``, ``home`` or ``failed``."""
    @property
    def target(self) -> str:
        """``goal``, or ``home`` after the goal was given up."""
    @property
    def plan_status(self) -> str | None:
        """Status of the plan made this step (``found``, ``no_path``, ``budget_exceeded``, ...), or None."""
    @property
    def path_world(self) -> npt.NDArray[np.float64]:
        """The path being tracked, ``(N, 2)`` world [m] (empty without one)."""
    @property
    def mpc_status(self) -> str | None:
        """``solved``, ``solved_inexact``, ``infeasible_backup``, ``solver_failed_backup``, or None when the MPC did not run."""
    @property
    def predicted(self) -> npt.NDArray[np.float64] | None:
        """The MPC's predicted states ``(N + 1, 4)`` ``[x, y, θ, v]``, or None."""
    @property
    def local_risk(self) -> float:
        """Risk under the robot [0-1]."""
    @property
    def speed_limit_m_s(self) -> float:
        """``v_max·(1 - local_risk)`` [m/s]."""
    @property
    def thresholds(self) -> tuple[float, float]:
        """``(R_inst, R_total)`` in force."""
    @property
    def transitions(self) -> list[dict[str, Any]]:
        """The recovery machine's transitions during this step (``time_s``, ``from``, ``to``, ``reason``, ``r_inst``, ``r_total``)."""
    @property
    def safety(self) -> str | None:
        """Why the command is not the behaviour's own (its motion would have swept the
        footprint over a lethal or unknown cell: the tracker's command replaced by a turn,
        a straight drive or a stop, or a recovery stopped), else None."""
    @property
    def timings(self) -> dict[str, float]:
        """Wall time per stage [s]: ``map_s``, ``plan_s``, ``track_s``, ``total_s``."""

class Navigator:
    """The ground robot's navigation stack (STEP, Fan et al. 2021): terrain mapper, risk-aware A*, MPC
    tracker and recovery behaviours, one ``step`` per control tick.

    ``goal``, ``home``: world (x, y) [m]; ``home`` defaults to the robot's position at the
    first step. ``robot``, ``terrain``, ``config``: a ``RobotConfig`` (default: Husky), a
    ``TerrainConfig`` and a ``NavigatorConfig`` in any of the four forms; a ``config`` dict
    (sections ``planner``, ``tracker``, ``recovery``, ``navigator``) is laid over the
    defaults for the robot.
    """

    def __init__(
        self,
        goal: Sequence[float],
        *,
        home: Sequence[float] | None = None,
        robot: _ConfigLike[RobotConfig] = None,
        terrain: _ConfigLike[TerrainConfig] = None,
        config: _ConfigLike[NavigatorConfig] = None,
    ) -> None: ...
    def step(
        self,
        points: npt.ArrayLike | None,
        *,
        stamp: float | None = None,
        world_from_body: npt.ArrayLike,
        body_from_sensor: npt.ArrayLike | None = None,
        confidence: float = 1.0,
        speed: float = 0.0,
    ) -> NavigatorOutput:
        """One control tick: ``points`` a new scan ``(N, 3)`` in the sensor frame [m] or None;
        ``stamp`` [s] (default 0.1 s after the previous step); ``world_from_body`` the 4x4
        odometry pose; ``speed`` the measured forward speed [m/s]. Releases the GIL."""
    def set_goal(self, goal: Sequence[float]) -> None:
        """Drives to a new ``goal`` (x, y) [m, world] from the next step, keeping the map, the
        remembered hazards and home; the plan and the recovery ladder start again."""
    @property
    def risk_map(self) -> RiskMap | None:
        """The last coarse risk map (None before the first scan)."""
    @property
    def plan_grid(self) -> npt.NDArray[np.float32] | None:
        """The navigator's grid ``(ny, nx)`` on ``risk_map``'s geometry: risk where observed,
        raised by the hazard memory; within ``navigator.near_memory_m`` of the robot, unobserved
        cells take the near memory's rating; lethal where the unseen-near rule
        (``navigator.unseen_near_lethal``) finds a hole's mouth and within
        ``navigator.void_rim_m`` of a void; NaN where unobserved otherwise (None before the
        first scan). The MPC, the local risk and ``back_out`` use it as it is; the A* plans on
        it grown into the unseen and inflated (``crates/subterra/src/plan/navigator/mod.rs``,
        steps 2-3)."""
    @property
    def driven_cells(self) -> int:
        """Cells the robot's footprint has stood on (the driven memory)."""
    @property
    def remembered_hazards(self) -> int:
        """Cells in the hazard memory (``navigator.hazard_memory``)."""
    @property
    def robot(self) -> RobotConfig: ...
    @property
    def config(self) -> NavigatorConfig:
        """Sections ``planner``, ``tracker``, ``recovery``, ``navigator``."""
    @property
    def transitions(self) -> list[dict[str, Any]]:
        """Every transition of the recovery machine so far, oldest first."""
    @property
    def goal(self) -> tuple[float, float]: ...
    @property
    def home(self) -> tuple[float, float]: ...

class _SimModule(ModuleType):
    """The simulator (``subterra.sim`` re-exports it with its docs)."""

    World: Any
    DepthCamera: Any
    Lidar: Any
    Simulation: Any
    DEPTH_NOISE_PRESETS: tuple[str, ...]
    LIDAR_NOISE_PRESETS: tuple[str, ...]
    def scenario_names(self) -> list[str]: ...

sim: _SimModule

class OdometryMuxOutput:
    """What one ``OdometryMux.update`` gives."""

    @property
    def stamp(self) -> float:
        """The stamp of the pose [s]: the chosen source's newest sample, or the held pose's."""
    @property
    def world_from_body(self) -> npt.NDArray[np.float64] | None:
        """The body's pose in the mux's world frame, 4x4; None before any source was chosen."""
    @property
    def source(self) -> str | None:
        """The chosen source's name; None when no source is usable (the pose is held)."""
    @property
    def confidence(self) -> float:
        """How far the pose can be trusted, in [0, 1]."""
    @property
    def faults(self) -> dict[str, str | None]:
        """Per source: why it is not used (one line), or None when it is usable."""
    @property
    def events(self) -> list[dict[str, Any]]:
        """The events since the last update (``time_s``, ``event``, ``source``, ``reason``,
        ``corrected_m``: how far a switch took the pose back, 0 for the rest)."""

class OdometryMux:
    """HeRO, the odometry multiplexer: health checks on several odometry sources (stale,
    jump, covariance, consistency) and the most trusted usable one passed on as one
    continuous pose with a confidence (docs/hero.md). ``sources``: ``[(name, rate_hz), ...]``
    most trusted first, or a dict in that order; ``config``: a ``HeroConfig`` in any of the
    four forms."""

    def __init__(self, sources: Sequence[tuple[str, float]] | dict[str, float], config: _ConfigLike[HeroConfig] = None) -> None: ...
    @property
    def config(self) -> HeroConfig: ...
    @property
    def sources(self) -> list[str]: ...
    def push(
        self,
        source: str,
        stamp: float,
        world_from_body: npt.ArrayLike,
        covariance: npt.ArrayLike | None = None,
        twist: npt.ArrayLike | None = None,
    ) -> None:
        """One sample of ``source``: 4x4 pose in its own world frame, 6x6 covariance over
        (x, y, z, roll, pitch, yaw), body-frame twist ``(vx, vy, vz, wx, wy, wz)``."""
    def update(self, now: float) -> OdometryMuxOutput:
        """The checks at time ``now``, the choice and the pose."""
