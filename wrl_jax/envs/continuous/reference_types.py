"""The NumPy reference's data (docs/CONTINUOUS_SPEC.md): parameters, layout, state and a step's draws."""

from __future__ import annotations

import dataclasses

import numpy as np

from wrl_jax.envs.warehouse import layout as grid
from wrl_jax.envs.warehouse.maps import WAREHOUSE_8X8, WAREHOUSE_12X12

F32 = np.float32


@dataclasses.dataclass(frozen=True)
class ContinuousParams:
    """Every parameter of the contract; ``num_rays`` (L) and ``num_obstacles`` (M) fix shapes.

    ``max_steps`` defaults to the 8x8 study map's 300: use :meth:`for_layout` to get 500 on the
    12x12 map and to be made to name a limit on any other layout.
    """

    dt: float = 0.2
    v_max: float = 1.0
    w_max: float = 2.0
    robot_radius: float = 0.3
    reach_radius: float = 0.35
    lidar_range: float = 4.0
    step_penalty: float = -0.5
    collision_penalty: float = -10.0
    shaping_coef: float = 2.0
    pickup_reward: float = 50.0
    delivery_reward: float = 200.0
    max_steps: int = 300
    obstacle_radius: float = 0.3
    obstacle_speed: float = 0.5
    gain_range: tuple[float, float] = (0.8, 1.2)
    actuation_noise: float = 0.05
    lidar_noise: float = 0.02
    lidar_dropout: float = 0.02
    start_jitter: float = 0.2
    randomize: bool = False
    num_rays: int = 32
    num_obstacles: int = 0

    def __post_init__(self) -> None:
        if self.num_rays < 1 or self.num_obstacles < 0 or self.max_steps < 1:
            raise ValueError(f"need num_rays >= 1, num_obstacles >= 0, max_steps >= 1; got "
                             f"{self.num_rays}, {self.num_obstacles}, {self.max_steps}")

    @classmethod
    def for_layout(cls, layout: str | ContinuousLayout, max_steps: int | None = None,
                   **overrides) -> ContinuousParams:
        """Params for a layout: the study maps default to 300 (8x8) and 500 (12x12) steps; any
        other layout must name ``max_steps`` (contract, "Precisions": "other layouts take
        ``max_steps`` as an argument")."""
        if max_steps is None:
            max_steps = study_max_steps(layout)
            if max_steps is None:
                raise ValueError("max_steps is required for a layout other than the study's 8x8 and 12x12 maps")
        return cls(max_steps=max_steps, **overrides)


@dataclasses.dataclass(frozen=True, eq=False)
class ContinuousLayout:
    """Shelf grid and marked cells; cell ``(r, c)`` is the square ``[c, c+1] x [r, r+1]``.

    Rectangular grids are accepted (``height`` rows, ``width`` columns); free = not shelf.
    """

    shelves: np.ndarray
    start: tuple[int, int]
    goal: tuple[int, int]
    items: np.ndarray

    def __post_init__(self) -> None:
        shelves = np.asarray(self.shelves, dtype=bool)
        if shelves.ndim != 2:
            raise ValueError(f"shelves must be a 2-D bool grid, got shape {shelves.shape}")
        object.__setattr__(self, "shelves", shelves)
        object.__setattr__(self, "start", tuple(int(v) for v in self.start))
        object.__setattr__(self, "goal", tuple(int(v) for v in self.goal))
        object.__setattr__(self, "items", np.asarray(self.items, dtype=np.int32).reshape(-1, 2))
        for name, cell in [("start", self.start), ("goal", self.goal)] + [
                (f"item {i}", tuple(int(v) for v in c)) for i, c in enumerate(self.items)]:
            if not self.is_free(*cell):
                raise ValueError(f"{name} at cell {cell} is outside the map or on a shelf")
        if len(self.items) == 0:
            raise ValueError("layout has no items")

    @classmethod
    def from_text(cls, text: str) -> ContinuousLayout:
        """Parse an ASCII map of SPEC.md (``S``, ``G``, ``#``, ``.``, item markers)."""
        parsed = grid.parse(text)
        return cls(parsed.shelves, tuple(parsed.start), tuple(parsed.goal), parsed.items)

    @property
    def width(self) -> int:
        return int(self.shelves.shape[1])

    @property
    def height(self) -> int:
        return int(self.shelves.shape[0])

    def is_free(self, row: int, col: int) -> bool:
        """Inside the map and not a shelf."""
        return 0 <= row < self.height and 0 <= col < self.width and not self.shelves[row, col]

    @staticmethod
    def cell_centre(row: int, col: int) -> np.ndarray:
        """``(x, y) = (col + 0.5, row + 0.5)`` in float32 (exact)."""
        return np.array([col + 0.5, row + 0.5], dtype=F32)


def study_max_steps(layout: str | ContinuousLayout) -> int | None:
    """300 for the study's 8x8 map, 500 for its 12x12 map (compared as parsed grids, so
    spacing does not matter), None for any other layout."""
    if isinstance(layout, str):
        layout = ContinuousLayout.from_text(layout)
    for text, steps in ((WAREHOUSE_8X8, 300), (WAREHOUSE_12X12, 500)):
        study = ContinuousLayout.from_text(text)
        if (study.shelves.shape == layout.shelves.shape and np.array_equal(study.shelves, layout.shelves)
                and study.start == layout.start and study.goal == layout.goal
                and np.array_equal(study.items, layout.items)):
            return steps
    return None


@dataclasses.dataclass
class ContinuousState:
    """Float32 metres and radians; ``obstacle_from`` is int32 ``(row, col)``, the rest ``(x, y)``.

    ``obstacle_from[m]`` is the cell whose centre obstacle m last stood on: its start cell on the
    first leg, then the cell of the waypoint it last landed on (the origin of its current leg).
    The commands ``v, w`` are not state: the observation takes them from the step that applied them.
    """

    pos: np.ndarray
    theta: np.float32
    carrying: bool
    item: np.ndarray
    time: int
    obstacle_pos: np.ndarray
    obstacle_waypoint: np.ndarray
    obstacle_from: np.ndarray
    gains: np.ndarray

    def replace(self, **changes) -> ContinuousState:
        return dataclasses.replace(self, **changes)


@dataclasses.dataclass(frozen=True)
class StepDraws:
    """One step's random draws: ``noise`` (2,) already in m/s and rad/s, ``waypoint_u`` (M,) in
    [0, 1) (read only by an obstacle that lands this step), ``lidar_noise`` (L,) metres,
    ``lidar_drop`` (L,) bool. Not randomized: all zeros (:meth:`zeros`)."""

    noise: np.ndarray
    waypoint_u: np.ndarray
    lidar_noise: np.ndarray
    lidar_drop: np.ndarray

    @classmethod
    def zeros(cls, params: ContinuousParams) -> StepDraws:
        return cls(np.zeros(2, F32), np.zeros(params.num_obstacles, F32),
                   np.zeros(params.num_rays, F32), np.zeros(params.num_rays, bool))
