"""RWARE floor plans as NumPy data: the parametric warehouse and rware's custom layout strings.

Both builders follow rware 2.0.0 (``Warehouse._make_layout_from_params`` and
``_make_layout_from_str``; bench/results/rware/NOTES.md section 2) and check their input
with a ``ValueError`` where rware only asserts. Coordinates are ``(x, y)``: x the column,
y the row growing downward; grids are indexed ``[y, x]``. The JAX parameters are built
from a layout once, in :mod:`wrl_jax.envs.rware.registration`.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True, eq=False)
class RwareLayout:
    """A validated floor plan.

    Attributes:
        highway: ``(H, W)`` bool, True on highway cells (corridors and goals); every other cell
            holds one shelf at reset.
        goals: ``(G, 2)`` int32 goal cells ``(x, y)`` in rware's order (delivery is checked goal by goal).
    """

    highway: np.ndarray
    goals: np.ndarray

    def __post_init__(self) -> None:
        highway = np.array(self.highway, dtype=bool)
        goals = np.array(self.goals, dtype=np.int32).reshape(-1, 2)
        highway.setflags(write=False)
        goals.setflags(write=False)
        object.__setattr__(self, "highway", highway)
        object.__setattr__(self, "goals", goals)
        if highway.ndim != 2 or highway.size == 0:
            raise ValueError(f"a layout needs a non-empty 2-D grid, got shape {highway.shape}")
        if len(goals) == 0:
            raise ValueError("a layout needs at least one goal cell")
        height, width = highway.shape
        inside = (goals[:, 0] >= 0) & (goals[:, 0] < width) & (goals[:, 1] >= 0) & (goals[:, 1] < height)
        if not inside.all():
            raise ValueError(f"goal {tuple(goals[~inside][0])} lies outside the {width}x{height} grid")

    @property
    def grid_size(self) -> tuple[int, int]:
        """rware's ``grid_size``: ``(H, W)``."""
        return int(self.highway.shape[0]), int(self.highway.shape[1])

    @property
    def shelf_cells(self) -> np.ndarray:
        """``(S, 2)`` int32 ``(x, y)`` of the non-highway cells, row-major: shelf ``i`` (id ``i+1``) starts there."""
        ys, xs = np.nonzero(~self.highway)
        return np.stack([xs, ys], axis=1).astype(np.int32).reshape(-1, 2)

    @property
    def num_shelves(self) -> int:
        return int((~self.highway).sum())


def _positive_int(name: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def layout_from_params(shelf_columns: int, shelf_rows: int, column_height: int) -> RwareLayout:
    """rware's parametric warehouse: ``shelf_rows`` x ``shelf_columns`` blocks of 2 x ``column_height`` shelves.

    ``H = (column_height + 1) shelf_rows + 2`` and ``W = 3 shelf_columns + 1``; the two goals sit
    in the middle of the bottom row, and the middle block of the bottom shelf row is removed
    (a queue in front of the goals). ``shelf_columns`` must be odd, as rware asserts.
    """
    shelf_columns = _positive_int("shelf_columns", shelf_columns)
    shelf_rows = _positive_int("shelf_rows", shelf_rows)
    column_height = _positive_int("column_height", column_height)
    if shelf_columns % 2 != 1:
        raise ValueError(f"shelf_columns must be odd (rware supports only odd counts), got {shelf_columns}")
    height, width = (column_height + 1) * shelf_rows + 2, 3 * shelf_columns + 1
    ys, xs = np.indices((height, width))
    queue = (ys > height - (column_height + 3)) & ((xs == width // 2 - 1) | (xs == width // 2))
    highway = (xs % 3 == 0) | (ys % (column_height + 1) == 0) | (ys == height - 1) | queue
    goals = [(width // 2 - 1, height - 1), (width // 2, height - 1)]
    return RwareLayout(highway=highway, goals=np.array(goals))


def parse_layout(text: str) -> RwareLayout:
    """rware's custom layout string: ``x`` shelf, ``.`` highway, ``g`` goal (case-insensitive).

    As rware reads it: the text is stripped, every space removed, then split on newlines; rows
    must have equal width; goals are listed in row-major order and at least one is required.
    """
    if not isinstance(text, str):
        raise ValueError(f"layout must be a string, got {type(text).__name__}")
    lines = text.strip().replace(" ", "").split("\n")
    width = len(lines[0])
    if width == 0:
        raise ValueError("layout is empty")
    highway = np.zeros((len(lines), width), dtype=bool)
    goals = []
    for y, line in enumerate(lines):
        if len(line) != width:
            raise ValueError(f"layout must be rectangular: row {y} has {len(line)} cells, row 0 has {width}")
        for x, char in enumerate(line):
            kind = char.lower()
            if kind not in "gx.":
                raise ValueError(f"layout cell {char!r} at (x={x}, y={y}) is not one of 'x' (shelf), "
                                 f"'.' (highway), 'g' (goal)")
            highway[y, x] = kind != "x"
            if kind == "g":
                goals.append((x, y))
    if not goals:
        raise ValueError("layout needs at least one goal 'g'")
    return RwareLayout(highway=highway, goals=np.array(goals))
