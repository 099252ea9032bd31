"""Warehouse layouts: ASCII maps parsed into validated NumPy arrays.

A layout is pure data. The JAX environment copies it into its params, so one
compiled program serves every layout of the same grid size; the NumPy
reference environment reads the same arrays. Parsing is the only code the two
environments share (SPEC.md: "it may share the layout parser, not the
transition logic").

Map characters:
    ``S`` start, ``G`` goal, ``#`` shelf, ``.`` free floor, and item markers
    ``0-9`` then ``a-z``, ``A-Z`` (a marker's rank in that alphabet is its
    position in the item list). Whitespace between cells is ignored, so both
    ``"S..#"`` and ``"S . . #"`` parse.
"""

from __future__ import annotations

import dataclasses
import string
from collections import deque

import numpy as np

ITEM_MARKERS = string.digits + string.ascii_lowercase + string.ascii_uppercase
"""Item markers in list order: item ``i`` is drawn as ``ITEM_MARKERS[i]``."""

FREE, SHELF, START, GOAL = ".", "#", "S", "G"

# Unit moves of the four actions, (row, col): 0 up, 1 down, 2 left, 3 right.
MOVES = np.array([[-1, 0], [1, 0], [0, -1], [0, 1]], dtype=np.int32)


@dataclasses.dataclass(frozen=True, eq=False)
class Layout:
    """A validated square warehouse layout.

    Attributes:
        shelves: ``(N, N)`` bool, True on shelf cells.
        start: ``(2,)`` int32 start cell ``(row, col)``.
        goal: ``(2,)`` int32 goal cell.
        items: ``(K, 2)`` int32 item cells in list order.
    """

    shelves: np.ndarray
    start: np.ndarray
    goal: np.ndarray
    items: np.ndarray

    def __post_init__(self) -> None:
        for name in ("shelves", "start", "goal", "items"):
            array = np.array(getattr(self, name))
            array.setflags(write=False)
            object.__setattr__(self, name, array)
        validate(self)

    @property
    def size(self) -> int:
        """Grid side ``N``."""
        return int(self.shelves.shape[0])

    @property
    def num_items(self) -> int:
        return int(self.items.shape[0])

    def to_ascii(self) -> str:
        """The map in the spaced format of SPEC.md; ``parse(layout.to_ascii())`` round-trips."""
        rows = [[SHELF if shelf else FREE for shelf in row] for row in self.shelves]
        rows[self.start[0]][self.start[1]] = START
        rows[self.goal[0]][self.goal[1]] = GOAL
        for index, (row, col) in enumerate(self.items):
            rows[row][col] = ITEM_MARKERS[index]
        return "\n".join(" ".join(row) for row in rows)

    def __repr__(self) -> str:
        return f"Layout(size={self.size}, items={self.num_items}, shelves={int(self.shelves.sum())})"


def parse(ascii_map: str) -> Layout:
    """Parse an ASCII map into a validated :class:`Layout`.

    Raises:
        ValueError: naming the problem and, where there is one, the cell
            ``(row, col)``: unknown character, ragged or non-square grid,
            missing or repeated start/goal/item marker, no items, an item
            marker skipped in the sequence, an unreachable item or goal.
    """
    shelves, starts, goals, items = scan_cells(ascii_map)
    for name, found in (("start 'S'", starts), ("goal 'G'", goals)):
        if not found:
            raise ValueError(f"map has no {name}")
        if len(found) > 1:
            raise ValueError(f"map has {len(found)} of {name}, at cells {found}; expected exactly one")
    if not items:
        raise ValueError("map has no items: mark item cells with 0-9, a-z, A-Z")
    return Layout(
        shelves=shelves,
        start=np.array(starts[0], dtype=np.int32),
        goal=np.array(goals[0], dtype=np.int32),
        items=np.array(items, dtype=np.int32).reshape(-1, 2),
    )


def scan_cells(ascii_map: str) -> tuple[np.ndarray, list, list, list]:
    """``(shelves, starts, goals, items)`` of an ASCII map: the grid checks and the cell scan both parsers share.

    ``starts`` and ``goals`` are every ``S`` and ``G`` cell in row-major order (a single-robot
    map must have one of each, a fleet map any number: the callers check), ``items`` the item
    cells in marker order.

    Raises:
        ValueError: empty map, ragged or non-square grid, unknown character (with its cell),
            an item marker used twice (both cells) or a marker skipped in the sequence.
    """
    lines = [line for line in (raw.strip() for raw in ascii_map.strip("\n").splitlines()) if line]
    if not lines:
        raise ValueError("empty map: expected rows of cells")
    grid = [[ch for ch in line if not ch.isspace()] for line in lines]
    width = len(grid[0])
    for row, cells in enumerate(grid):
        if len(cells) != width:
            raise ValueError(f"ragged map: row {row} has {len(cells)} cells, row 0 has {width}")
    if len(grid) != width:
        raise ValueError(f"map must be square: {len(grid)} rows of {width} cells")

    shelves = np.zeros((width, width), dtype=bool)
    starts, goals, markers = [], [], {}
    for row, cells in enumerate(grid):
        for col, ch in enumerate(cells):
            if ch == SHELF:
                shelves[row, col] = True
            elif ch == START:
                starts.append((row, col))
            elif ch == GOAL:
                goals.append((row, col))
            elif ch in ITEM_MARKERS:
                if ch in markers:
                    raise ValueError(
                        f"item marker {ch!r} appears twice: at {markers[ch]} and at {(row, col)}"
                    )
                markers[ch] = (row, col)
            elif ch != FREE:
                raise ValueError(
                    f"unknown character {ch!r} at cell {(row, col)}: "
                    f"expected one of 'S', 'G', '#', '.', or an item marker 0-9a-zA-Z"
                )
    ranks = sorted(ITEM_MARKERS.index(ch) for ch in markers)
    if ranks != list(range(len(ranks))):
        missing = ITEM_MARKERS[next(i for i, rank in enumerate(ranks) if rank != i)]
        raise ValueError(
            f"item markers must run 0, 1, 2, ... without gaps; {missing!r} is missing "
            f"but later markers are present"
        )
    return shelves, starts, goals, [markers[ITEM_MARKERS[i]] for i in range(len(ranks))]


def validate(layout: Layout) -> None:
    """Check a layout's arrays; raise ``ValueError`` naming the problem and cell.

    Layouts built from arrays (not from a map) get the same checks as parsed ones.
    """
    shelves, start, goal, items = layout.shelves, layout.start, layout.goal, layout.items
    if shelves.ndim != 2 or shelves.shape[0] != shelves.shape[1] or shelves.dtype != bool:
        raise ValueError(f"shelves must be a square bool array, got {shelves.dtype} {shelves.shape}")
    size = shelves.shape[0]
    if size < 2:
        raise ValueError(f"grid must be at least 2x2, got {size}x{size}")
    if start.shape != (2,) or goal.shape != (2,):
        raise ValueError("start and goal must be (row, col) pairs")
    if items.ndim != 2 or items.shape[1] != 2 or items.shape[0] == 0:
        raise ValueError(f"items must be a non-empty (K, 2) array of cells, got shape {items.shape}")
    if len(items) > len(ITEM_MARKERS):
        raise ValueError(f"at most {len(ITEM_MARKERS)} items, got {len(items)}")
    for name, cell in [("start", start), ("goal", goal)] + [(f"item {i}", c) for i, c in enumerate(items)]:
        if not (0 <= cell[0] < size and 0 <= cell[1] < size):
            raise ValueError(f"{name} at cell {tuple(int(v) for v in cell)} lies outside the {size}x{size} grid")
        if shelves[cell[0], cell[1]]:
            raise ValueError(f"{name} at cell {tuple(int(v) for v in cell)} is on a shelf")
    named = [("start", tuple(start)), ("goal", tuple(goal))] + [(f"item {i}", tuple(c)) for i, c in enumerate(items)]
    seen: dict[tuple, str] = {}
    for name, cell in named:
        cell = tuple(int(v) for v in cell)
        if cell in seen:
            raise ValueError(f"{name} and {seen[cell]} share cell {cell}; every marked cell must be distinct")
        seen[cell] = name
    from_start = bfs_distances(shelves, tuple(start))
    if from_start[goal[0], goal[1]] < 0:
        raise ValueError(f"goal at cell {tuple(int(v) for v in goal)} is unreachable from the start")
    for index, (row, col) in enumerate(items):
        if from_start[row, col] < 0:
            raise ValueError(f"item {index} at cell {(int(row), int(col))} is unreachable from the start")


def bfs_distances(shelves: np.ndarray, source: tuple[int, int]) -> np.ndarray:
    """Shortest free-cell path length from ``source`` to every cell; -1 where unreachable (any rectangular grid)."""
    height, width = shelves.shape
    dist = np.full(shelves.shape, -1, dtype=np.int32)
    dist[source] = 0
    queue = deque([source])
    while queue:
        row, col = queue.popleft()
        for d_row, d_col in MOVES:
            nr, nc = row + d_row, col + d_col
            if 0 <= nr < height and 0 <= nc < width and not shelves[nr, nc] and dist[nr, nc] < 0:
                dist[nr, nc] = dist[row, col] + 1
                queue.append((nr, nc))
    return dist


def optimal_route_lengths(layout: Layout) -> np.ndarray:
    """BFS optimum of each item's pick-and-place route: start -> item -> goal, ``(K,)`` int32."""
    from_start = bfs_distances(layout.shelves, tuple(layout.start))
    from_goal = bfs_distances(layout.shelves, tuple(layout.goal))
    rows, cols = layout.items[:, 0], layout.items[:, 1]
    return (from_start[rows, cols] + from_goal[rows, cols]).astype(np.int32)
