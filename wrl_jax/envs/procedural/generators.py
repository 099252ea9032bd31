"""Warehouse generators: pure functions ``key -> PaddedLayout`` that ``jit`` and ``vmap``.

Three training families, each at the fixed maximum shape of a :class:`GeneratorConfig`
(default 16x16) with a real floor of random size within it:

- :func:`shelf_blocks`: pick floors. Rectangular shelf blocks in a periodic
  pattern, horizontal or vertical, separated by aisles (the gaps across the
  blocks' depth) and cross-aisles (the gaps along their length); block length
  and depth, aisle and cross-aisle widths and the border offsets are drawn
  per layout, and a random fraction of shelf cells is knocked out (gaps, as on
  real floors and RWARE's parametric maps).
- :func:`random_obstacles`: every floor cell is a shelf with a density drawn
  per layout.
- :func:`mixture`: one of the two, shelf blocks with probability ``shelf_mix``.

Three more families force long routes, for out-of-distribution tests of planning policies
(:mod:`~wrl_jax.envs.procedural.route_floors`): ``"serpentine"``, ``"spiral"`` and ``"comb"``.

Solvability is guaranteed by construction and checked inside ``jit``: the
start is drawn on a free cell, a flood fill (``lax.while_loop``) finds what it
reaches, and the goal and items are drawn only among reached cells. A draw
whose start reaches too little of the free floor (fewer cells than the items
need, or less than ``min_reach`` of the free floor, i.e. the start sits in a
side pocket) is redrawn with a fresh key; the last of ``max_attempts`` draws is
the repair, which clears the shelves (an empty floor is always solvable). Free cells
the start does not reach are then filled with shelves, so every free cell of a
generated layout is reachable: the NumPy BFS agrees (tests/envs/procedural/test_procedural.py).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp

from wrl_jax.envs.procedural.draws import HEADER_WORDS, Floor, between, cell_words, floor_size, fraction, threshold
from wrl_jax.envs.procedural.layout import PaddedLayout, flood_fill, in_bounds_mask
from wrl_jax.envs.procedural.route_floors import comb_floor, serpentine_floor, spiral_floor

FAMILIES = ("shelves", "obstacles", "mixture", "serpentine", "spiral", "comb")


@dataclasses.dataclass(frozen=True)
class GeneratorConfig:
    """Static settings of a generator (hashable: a ``jit`` static argument).

    Attributes:
        family: ``"shelves"``, ``"obstacles"`` or ``"mixture"`` (training), or a long-route family
            (``"serpentine"``, ``"spiral"``, ``"comb"``: :mod:`~wrl_jax.envs.procedural.route_floors`).
        max_shape: padded shape ``(H, W)`` of every layout.
        min_shape: smallest real floor; sizes are uniform in ``min_shape..max_shape`` (long-route
            families: at least 3/4 of ``max_shape`` per axis).
        max_items: item capacity ``I`` of the layout arrays.
        min_items: the number of items is uniform in ``min_items..max_items``.
        density: ``(low, high)`` range of the obstacle density (obstacles family).
        gap_rate: ``(low, high)`` range of the fraction of shelf cells knocked out (shelf family).
        aisle: ``(low, high)`` range of the aisle width between shelf blocks (shelf family); ``(1, 1)``
            gives the narrowest floors (an out-of-distribution set of the final evaluation). The
            long-route families draw their corridor widths in ``1..high``.
        shelf_mix: probability of the shelf family in the mixture.
        items_on_pick_faces: place items next to shelves first (where real pick faces are).
        min_reach: least fraction of the free floor the start must reach, else redraw.
        max_attempts: draws in all; the last one is the repair (an empty floor).
    """

    family: str = "mixture"
    max_shape: tuple[int, int] = (16, 16)
    min_shape: tuple[int, int] = (8, 8)
    max_items: int = 8
    min_items: int = 1
    density: tuple[float, float] = (0.05, 0.3)
    gap_rate: tuple[float, float] = (0.0, 0.15)
    aisle: tuple[int, int] = (1, 2)
    shelf_mix: float = 0.5
    items_on_pick_faces: bool = True
    min_reach: float = 0.5
    max_attempts: int = 8

    def __post_init__(self) -> None:
        if self.family not in FAMILIES:
            raise ValueError(f"unknown generator family {self.family!r}; expected one of {FAMILIES}")
        (min_h, min_w), (max_h, max_w) = self.min_shape, self.max_shape
        if not (2 <= min_h <= max_h and 2 <= min_w <= max_w):
            raise ValueError(f"need 2 <= min_shape <= max_shape per axis, got min {self.min_shape}, "
                             f"max {self.max_shape}")
        if max_h * max_w >= 2**16:
            raise ValueError(f"max_shape {self.max_shape} has 2**16 cells or more; the cell draws use 16 bits")
        if not 1 <= self.min_items <= self.max_items:
            raise ValueError(f"need 1 <= min_items <= max_items, got {self.min_items}, {self.max_items}")
        if min_h * min_w < self.max_items + 2:
            raise ValueError(f"a {min_h}x{min_w} floor has no room for start, goal and {self.max_items} items")
        for name in ("density", "gap_rate"):
            low, high = getattr(self, name)
            if not 0.0 <= low <= high < 1.0:
                raise ValueError(f"{name} must be a range 0 <= low <= high < 1, got {(low, high)}")
        if not 1 <= self.aisle[0] <= self.aisle[1]:
            raise ValueError(f"aisle must be a range 1 <= low <= high, got {self.aisle}")
        if not 0.0 <= self.shelf_mix <= 1.0 or not 0.0 <= self.min_reach <= 1.0:
            raise ValueError("shelf_mix and min_reach must lie in [0, 1]")
        if self.max_attempts < 2:
            raise ValueError(f"max_attempts must be at least 2 (the last is the repair), got {self.max_attempts}")


# ------------------------------------------------------------------ floors
def shelf_floor(header: jax.Array, cells: jax.Array, config: GeneratorConfig) -> Floor:
    """A pick floor of periodic shelf blocks with random dimensions and knocked-out gaps.

    Across the blocks: depth ``D`` in 1..2 cells, aisles ``A`` in ``config.aisle`` (1..2); along
    them: length ``L`` in 2..6, cross-aisles ``C`` in 1..2; margins of 0..1
    cells on both sides; only whole blocks; horizontal or vertical blocks.
    """
    height, width = floor_size(header, config)
    depth, aisle = between(header[2], 1, 2), between(header[3], *config.aisle)
    length, cross = between(header[4], 2, 6), between(header[5], 1, 2)
    offset_across, offset_along = between(header[6], 0, 1), between(header[7], 0, 1)
    vertical = header[8] >> 31 == 1
    rows = jnp.arange(config.max_shape[0], dtype=jnp.int32)[:, None]
    cols = jnp.arange(config.max_shape[1], dtype=jnp.int32)[None, :]
    across = jnp.where(vertical, cols, rows) - offset_across
    along = jnp.where(vertical, rows, cols) - offset_along
    # Whole blocks only, inside a margin as wide as the offset on the far side too (a perimeter aisle).
    across_room = jnp.where(vertical, width, height) - 2 * offset_across
    along_room = jnp.where(vertical, height, width) - 2 * offset_along
    in_across = (across >= 0) & (across % (depth + aisle) < depth) & (across - across % (depth + aisle) + depth
                                                                      <= across_room)
    in_along = (along >= 0) & (along % (length + cross) < length) & (along - along % (length + cross) + length
                                                                     <= along_room)
    shelves = in_across & in_along
    gap_rate = fraction(header[9], *config.gap_rate)
    shelves = shelves & ~(cells < threshold(gap_rate))
    return shelves & in_bounds_mask(height, width, config.max_shape), height, width


def obstacle_floor(header: jax.Array, cells: jax.Array, config: GeneratorConfig) -> Floor:
    """A floor whose cells are shelves independently, with a density drawn per layout."""
    height, width = floor_size(header, config)
    density = fraction(header[10], *config.density)
    shelves = cells < threshold(density)
    return shelves & in_bounds_mask(height, width, config.max_shape), height, width


def mixture_floor(header: jax.Array, cells: jax.Array, config: GeneratorConfig) -> Floor:
    """A shelf floor with probability ``shelf_mix``, else an obstacle floor (both computed, one kept)."""
    pick_shelves = header[11] < threshold(jnp.float32(config.shelf_mix)) if config.shelf_mix < 1 else True
    return jax.tree.map(lambda a, b: jnp.where(pick_shelves, a, b),
                        shelf_floor(header, cells, config), obstacle_floor(header, cells, config))


FLOORS: dict[str, Callable[[jax.Array, jax.Array, GeneratorConfig], Floor]] = {
    "shelves": shelf_floor, "obstacles": obstacle_floor, "mixture": mixture_floor,
    "serpentine": serpentine_floor, "spiral": spiral_floor, "comb": comb_floor,
}


# ------------------------------------------------------------------ placement
def _unique_ranks(scores: jax.Array, config: GeneratorConfig) -> jax.Array:
    """``(H, W)`` int32 ranks in ``[0, 2**30)``, all distinct: random high bits, the flat cell index below.

    Distinct ranks make "the best cell" unique and let :func:`_best_cells`
    find the next best by a threshold, with no scatter; a cell is read back
    from its rank's low bits.
    """
    index_bits = max(1, (config.max_shape[0] * config.max_shape[1] - 1).bit_length())
    index = jnp.arange(scores.size, dtype=jnp.uint32).reshape(scores.shape)
    return ((((scores >> 2) >> index_bits) << index_bits) | index).astype(jnp.int32)


def _cell_of(rank: jax.Array, config: GeneratorConfig) -> jax.Array:
    index_bits = max(1, (config.max_shape[0] * config.max_shape[1] - 1).bit_length())
    flat = rank & ((1 << index_bits) - 1)
    width = config.max_shape[1]
    return jnp.stack([flat // width, flat % width], axis=-1).astype(jnp.int32)


def _best_cells(ranks: jax.Array, count: int, config: GeneratorConfig) -> jax.Array:
    """The ``count`` best cells of distinct ``ranks`` (-1 on excluded cells), best first: ``(count, 2)``.

    ``count`` maxima below a falling threshold. ``lax.top_k`` sorts, and a
    loop of argmax-and-mask scatters; on CPU under ``vmap`` either cost more
    than the rest of the generator together. Positions past the number of
    eligible cells read rank -1 (cell index all ones, clipped by the caller's mask).
    """
    flat = ranks.reshape(-1)

    def take(ceiling, _):
        best = jnp.max(jnp.where(flat < ceiling, flat, -1))
        return best, best

    _, best = jax.lax.scan(take, jnp.int32(2**31 - 1), None, length=count)
    return _cell_of(jnp.maximum(best, 0), config)


def _pick_faces(shelves: jax.Array) -> jax.Array:
    """Cells with a shelf among their four neighbours."""
    padded = jnp.pad(shelves, 1)
    return padded[:-2, 1:-1] | padded[2:, 1:-1] | padded[1:-1, :-2] | padded[1:-1, 2:]


def place(header: jax.Array, scores: jax.Array, floor: Floor, config: GeneratorConfig,
          num_items: jax.Array | None = None) -> tuple[PaddedLayout, jax.Array]:
    """Start, goal and items on a floor; ``(layout, ok)`` where ``ok`` says the draw is acceptable.

    ``scores`` ``(H, W)`` uint32 are uniform words that order the cells
    randomly: the start is the best-scoring free cell, the goal the best
    reached cell after it, the items the next best reached cells (pick faces
    first, if configured), so together they are a uniform draw without
    replacement. The goal and items are drawn only among the cells the start
    reaches, so the layout is solvable whenever ``ok``; unreached free cells
    become shelves. ``num_items`` overrides the drawn item count (the map loader).
    """
    shelves, height, width = floor
    free = in_bounds_mask(height, width, config.max_shape) & ~shelves
    rank = _unique_ranks(scores, config)
    start = _best_cells(jnp.where(free, rank, -1), 1, config)[0]
    reached = flood_fill(free, start)
    if num_items is None:
        num_items = between(header[12], config.min_items, config.max_items)
    num_reached = jnp.sum(reached, dtype=jnp.int32)
    ok = (num_reached >= num_items + 2) & (num_reached >= config.min_reach * jnp.sum(free, dtype=jnp.int32))
    others = reached.at[start[0], start[1]].set(False)
    goal = _best_cells(jnp.where(others, rank, -1), 1, config)[0]
    others = others.at[goal[0], goal[1]].set(False)
    if config.items_on_pick_faces:
        rank = rank + jnp.where(_pick_faces(shelves), jnp.int32(2**30), 0)
    items = _best_cells(jnp.where(others, rank, -1), config.max_items, config)
    items = jnp.where((jnp.arange(config.max_items) < num_items)[:, None], items, items[0])
    layout = PaddedLayout(
        blocked=~reached, height=height, width=width, start=start, goal=goal, items=items, num_items=num_items
    )
    return layout, ok


def generate(key: jax.Array, config: GeneratorConfig) -> PaddedLayout:
    """One solvable layout of ``config.family`` from ``key`` (``jit`` with ``config`` static; ``vmap`` over keys).

    Draws until :func:`place` accepts (``lax.while_loop``); attempt ``a`` uses
    ``fold_in(key, a)``. The last of ``max_attempts`` attempts is the repair:
    the floor it draws has every shelf removed, which :func:`place` always
    accepts. (All attempts side by side, with no loop, was slower at a batch
    of 5,000: most layouts need only the first.)
    """
    return generate_with_attempts(key, config)[0]


def generate_with_attempts(key: jax.Array, config: GeneratorConfig) -> tuple[PaddedLayout, jax.Array]:
    """:func:`generate` and the number of draws it made: ``config.max_attempts`` means the repair was used."""
    draw_floor = FLOORS[config.family]

    def attempt(index):
        header = jax.random.bits(jax.random.fold_in(key, index), (HEADER_WORDS,), jnp.uint32)
        cells, scores = cell_words(header, config.max_shape)
        shelves, height, width = draw_floor(header, cells, config)
        shelves = shelves & (index < config.max_attempts - 1)
        return place(header, scores, (shelves, height, width), config)

    def body(carry):
        index, _, _ = carry
        return (index + 1, *attempt(index))

    def again(carry):
        index, _, ok = carry
        return ~ok & (index < config.max_attempts)

    first, ok = attempt(jnp.int32(0))
    attempts, layout, _ = jax.lax.while_loop(again, body, (jnp.int32(1), first, ok))
    return layout, attempts


def shelf_blocks(key: jax.Array, config: GeneratorConfig = GeneratorConfig()) -> PaddedLayout:
    """A solvable shelf-block warehouse (the ``"shelves"`` family of ``config``)."""
    return generate(key, dataclasses.replace(config, family="shelves"))


def random_obstacles(key: jax.Array, config: GeneratorConfig = GeneratorConfig()) -> PaddedLayout:
    """A solvable random-obstacle floor (the ``"obstacles"`` family of ``config``)."""
    return generate(key, dataclasses.replace(config, family="obstacles"))


def mixture(key: jax.Array, config: GeneratorConfig = GeneratorConfig()) -> PaddedLayout:
    """A solvable layout of either family (the ``"mixture"`` family of ``config``)."""
    return generate(key, dataclasses.replace(config, family="mixture"))


def generate_batch(keys: jax.Array, config: GeneratorConfig) -> PaddedLayout:
    """One layout per key, ``vmap`` of :func:`generate`: every leaf gets a leading ``len(keys)`` axis."""
    return jax.vmap(generate, in_axes=(0, None))(keys, config)
