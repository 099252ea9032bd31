"""Fleet layouts (FLEET_SPEC.md): ASCII maps with several starts and delivery stations.

The format is SPEC.md's (``#`` shelf, ``.`` floor, item markers ``0-9a-zA-Z``
in marker order, whitespace between cells ignored, square grids) except that
``S`` (start cells) and ``G`` (delivery stations) may appear any number of
times, at least once each. Starts and stations are listed in row-major order:
robot ``i`` starts on the ``i``-th ``S``.

A layout is pure NumPy data; the JAX environment copies it into its params
and the NumPy reference reads the same arrays. This parser is the only code
the two implementations share.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from wrl_jax.envs.warehouse.layout import FREE, GOAL, ITEM_MARKERS, SHELF, START, bfs_distances, scan_cells


@dataclasses.dataclass(frozen=True, eq=False)
class FleetLayout:
    """A validated square fleet layout.

    Attributes:
        shelves: ``(N, N)`` bool, True on shelf cells.
        starts: ``(S, 2)`` int32 start cells, row-major.
        stations: ``(G, 2)`` int32 delivery stations, row-major.
        items: ``(I, 2)`` int32 pick stations in marker order.
    """

    shelves: np.ndarray
    starts: np.ndarray
    stations: np.ndarray
    items: np.ndarray

    def __post_init__(self) -> None:
        for name in ("shelves", "starts", "stations", "items"):
            array = np.array(getattr(self, name))
            if name != "shelves":
                array = array.astype(np.int32).reshape(-1, 2)
            array.setflags(write=False)
            object.__setattr__(self, name, array)
        validate(self)

    @property
    def size(self) -> int:
        return int(self.shelves.shape[0])

    @property
    def num_starts(self) -> int:
        return int(self.starts.shape[0])

    @property
    def num_items(self) -> int:
        return int(self.items.shape[0])

    @property
    def num_stations(self) -> int:
        return int(self.stations.shape[0])

    def to_ascii(self) -> str:
        """The map in the spaced format; ``parse_fleet(layout.to_ascii())`` round-trips."""
        rows = [[SHELF if shelf else FREE for shelf in row] for row in self.shelves]
        for row, col in self.starts:
            rows[row][col] = START
        for row, col in self.stations:
            rows[row][col] = GOAL
        for index, (row, col) in enumerate(self.items):
            rows[row][col] = ITEM_MARKERS[index]
        return "\n".join(" ".join(row) for row in rows)

    def __repr__(self) -> str:
        return (f"FleetLayout(size={self.size}, starts={self.num_starts}, items={self.num_items}, "
                f"stations={self.num_stations}, shelves={int(self.shelves.sum())})")


def parse_fleet(ascii_map: str) -> FleetLayout:
    """Parse an ASCII fleet map into a validated :class:`FleetLayout`.

    Raises:
        ValueError: naming the problem and, where there is one, the cell
            ``(row, col)``: empty map, ragged or non-square grid, unknown
            character, no ``S``, no ``G``, no item, an item marker used twice
            or skipped, an item or station unreachable from some start.
    """
    shelves, starts, stations, items = scan_cells(ascii_map)
    return FleetLayout(shelves=shelves, starts=np.array(starts, dtype=np.int32).reshape(-1, 2),
                       stations=np.array(stations, dtype=np.int32).reshape(-1, 2),
                       items=np.array(items, dtype=np.int32).reshape(-1, 2))


def validate(layout: FleetLayout) -> None:
    """Check a layout's arrays (parsed or built by hand); raise ``ValueError`` naming the problem and cell."""
    shelves = layout.shelves
    if shelves.ndim != 2 or shelves.shape[0] != shelves.shape[1] or shelves.dtype != bool:
        raise ValueError(f"shelves must be a square bool array, got {shelves.dtype} {shelves.shape}")
    size = shelves.shape[0]
    if size < 2:
        raise ValueError(f"grid must be at least 2x2, got {size}x{size}")
    for kind, cells, hint in (("start 'S'", layout.starts, "S"), ("delivery station 'G'", layout.stations, "G"),
                              ("item", layout.items, "0-9a-zA-Z")):
        if len(cells) == 0:
            raise ValueError(f"map has no {kind}: mark at least one cell with {hint}")
    if layout.num_items > len(ITEM_MARKERS):
        raise ValueError(f"at most {len(ITEM_MARKERS)} items, got {layout.num_items}")
    named = ([(f"start {i}", c) for i, c in enumerate(layout.starts)]
             + [(f"station {i}", c) for i, c in enumerate(layout.stations)]
             + [(f"item {ITEM_MARKERS[i]!r}", c) for i, c in enumerate(layout.items)])
    seen: dict[tuple[int, int], str] = {}
    for name, cell in named:
        cell = (int(cell[0]), int(cell[1]))
        if not (0 <= cell[0] < size and 0 <= cell[1] < size):
            raise ValueError(f"{name} at cell {cell} lies outside the {size}x{size} grid")
        if shelves[cell]:
            raise ValueError(f"{name} at cell {cell} is on a shelf")
        if cell in seen:
            raise ValueError(f"{name} and {seen[cell]} share cell {cell}; every marked cell must be distinct")
        seen[cell] = name
    # Every target reachable from every start <=> all of them lie in start 0's free component: one BFS.
    starts = [(int(r), int(c)) for r, c in layout.starts]
    reach = bfs_distances(shelves, starts[0]) >= 0
    targets = [(name, (int(c[0]), int(c[1]))) for name, c in named[layout.num_starts:]]
    for name, cell in targets:
        if not reach[cell]:
            raise ValueError(f"{name} at cell {cell} is unreachable from start 0 at cell {starts[0]}")
    for index, start in enumerate(starts):
        if not reach[start]:  # outside start 0's component, so it reaches none of the targets
            name, cell = targets[0]
            raise ValueError(f"{name} at cell {cell} is unreachable from start {index} at cell {start}")
