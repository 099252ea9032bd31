"""Floors whose routes are long: serpentine, spiral and comb warehouses (generator families of the same names).

What they are for: out-of-distribution tests of planning policies. The training families
(:mod:`~wrl_jax.envs.procedural.generators`: shelf blocks, random obstacles and their mixture) keep
start-to-target routes short, at most about 43 moves at 16x16, because their floors are open in two
directions. A policy that learned to plan, rather than to head straight for the target, should also
deliver when the only way is several times longer; these floors force that:

- :func:`serpentine_floor`: parallel walls with one opening each, at alternating ends, so the free floor
  is one long snake;
- :func:`spiral_floor`: a rectangular spiral corridor winding into the centre;
- :func:`comb_floor`: a main corridor (the spine) with long dead-end teeth, mostly hairpins, on one or both
  sides.

Walls are whole (no knocked-out cells: a gap would be a shortcut). The floors are large: each axis is
uniform in ``max(min_shape, ceil(3/4 max_shape))..max_shape`` (12..16 at the default 16x16), since the
routes grow with the floor. Every floor is connected by construction (up to a few one-cell notches next
to a wall opening, which are reachable too), so :func:`~wrl_jax.envs.procedural.generators.place`
accepts practically every first draw (none rejected in 4,000 draws of each family at 16x16) and the repair
(an empty floor) is practically never used. Like those, they are pure ``jnp`` on the static
``config.max_shape`` and ``jit`` and ``vmap``.
The header words they read (2..11) are their own; the size (0, 1), item count (12) and seeds (14, 15)
are shared with every family.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from wrl_jax.envs.procedural.draws import Floor, FloorSettings, between, floor_size, threshold
from wrl_jax.envs.procedural.layout import in_bounds_mask


def long_floor_size(header: jax.Array, config: FloorSettings) -> tuple[jax.Array, jax.Array]:
    """``(height, width)``, each uniform in ``max(min_shape, ceil(3/4 max_shape))..max_shape``."""
    low = tuple(min(high, max(low, -(-3 * high // 4))) for low, high in zip(config.min_shape, config.max_shape))
    return floor_size(header, config, low)


def _grid(config: FloorSettings) -> tuple[jax.Array, jax.Array]:
    rows = jnp.arange(config.max_shape[0], dtype=jnp.int32)[:, None]
    cols = jnp.arange(config.max_shape[1], dtype=jnp.int32)[None, :]
    return rows, cols


def _bit(word: jax.Array, bit: int) -> jax.Array:
    return (word >> bit) & 1 == 1


def serpentine_floor(header: jax.Array, cells: jax.Array, config: FloorSettings) -> Floor:
    """Parallel one-cell walls (rows or columns), each with a single one-cell opening at alternating ends.

    Corridor ``k`` (before wall ``k``) is ``1..config.aisle[1]`` wide, drawn per corridor; walls follow
    while at least one free line is left after them, so the free floor is one snake from the first
    corridor to the last. The orientation and the end of the first opening are drawn.
    """
    height, width = long_floor_size(header, config)
    vertical, flip = _bit(header[2], 31), _bit(header[2], 30)
    rows, cols = _grid(config)
    across, along = jnp.where(vertical, cols, rows), jnp.where(vertical, rows, cols)
    across_size, along_size = jnp.where(vertical, width, height), jnp.where(vertical, height, width)
    count = max(config.max_shape)  # more walls than fit; the ones past the floor are dropped
    widths = between(cells.reshape(-1)[:count], 1, config.aisle[1])
    walls = jnp.cumsum(widths + 1) - 1  # the position of wall k across the floor
    hit = (across[..., None] == walls) & (walls <= across_size - 2)  # (H, W, count)
    wall_index = jnp.argmax(hit, axis=-1)
    far = (wall_index + flip.astype(jnp.int32)) % 2 == 1
    opening = jnp.where(far, along == along_size - 1, along == 0)
    shelves = hit.any(axis=-1) & ~opening
    return shelves & in_bounds_mask(height, width, config.max_shape), height, width


def spiral_floor(header: jax.Array, cells: jax.Array, config: FloorSettings) -> Floor:
    """A rectangular spiral corridor, ``w`` (``1..min(2, config.aisle[1])``) wide, walls one cell thick.

    Concentric rings by distance ``d`` to the floor's edge: ``d % (w + 1) < w`` corridor, else wall. Each
    corridor ring is cut by a one-cell barrier just after its top-left corner, and the wall inside it has
    an opening just past that barrier, so the rings join into one corridor from the outer corner to the
    centre. Barriers only where a wall ring lies inside (the innermost free block is never cut), openings
    only where a corridor lies behind them. Mirrored and transposed at random.
    """
    height, width = long_floor_size(header, config)
    aisle = between(header[3], 1, min(2, config.aisle[1]))
    period = aisle + 1
    rows, cols = _grid(config)
    rows = jnp.where(_bit(header[4], 31), height - 1 - rows, rows)
    cols = jnp.where(_bit(header[4], 30), width - 1 - cols, cols)
    transpose = _bit(header[4], 29)
    a, b = jnp.where(transpose, cols, rows), jnp.where(transpose, rows, cols)
    size_a, size_b = jnp.where(transpose, width, height), jnp.where(transpose, height, width)
    ring = jnp.minimum(jnp.minimum(a, b), jnp.minimum(size_a - 1 - a, size_b - 1 - b))
    innermost = (jnp.minimum(size_a, size_b) - 1) // 2
    layer = ring // period
    wall = ring % period == aisle
    top = a == ring  # on the top side of its ring (the corner included)
    barrier = ~wall & top & (b == layer * period + aisle) & (layer * period + aisle <= innermost)
    inner = (layer + 1) * period  # where the corridor inside wall `layer` begins
    opening = wall & top & (b >= inner) & (b < inner + aisle) & (inner <= innermost)
    shelves = wall & ~opening | barrier
    return shelves & in_bounds_mask(height, width, config.max_shape), height, width


def comb_floor(header: jax.Array, cells: jax.Array, config: FloorSettings) -> Floor:
    """A spine corridor along the floor with dead-end teeth between one-cell walls on one or both sides.

    The spine (``1..config.aisle[1]`` wide) lies on an edge of the floor (teeth on one side, as deep as
    the floor less the spine) with probability 3/4, else in the middle third (teeth on both sides). The
    teeth run from the spine to the floor's edge, which closes them; with probability 1/4 they are
    straight (``1..config.aisle[1]`` wide), else hairpins: one lane in, a divider open only at the far
    end, one lane back that is closed at the spine (a dead end twice as deep, whose tip is two cells
    from its entrance). The orientation, the edge, the direction along the spine and the phase of the
    teeth are drawn.
    """
    height, width = long_floor_size(header, config)
    vertical = _bit(header[5], 31)
    rows, cols = _grid(config)
    across, along = jnp.where(vertical, cols, rows), jnp.where(vertical, rows, cols)
    across_size, along_size = jnp.where(vertical, width, height), jnp.where(vertical, height, width)
    along = jnp.where(_bit(header[5], 30), along_size - 1 - along, along)
    spine_width, tooth = between(header[6], 1, config.aisle[1]), between(header[7], 1, config.aisle[1])
    one_sided = header[8] >= threshold(jnp.float32(0.25))
    edge = jnp.where(_bit(header[9], 31), 0, across_size - spine_width)
    middle = between(header[9], across_size // 3, jnp.maximum(across_size // 3, (2 * across_size) // 3 - spine_width))
    spine_start = jnp.where(one_sided, edge, middle)
    spine_end = spine_start + spine_width
    spine = (across >= spine_start) & (across < spine_end)
    # Depth into a tooth (0 next to the spine) and the teeth's length on this cell's side.
    before = across < spine_start
    depth = jnp.where(before, spine_start - 1 - across, across - spine_end)
    length = jnp.where(before, spine_start, across_size - spine_end)
    straight = (along + between(header[10], 0, tooth)) % (tooth + 1) == tooth
    # Hairpins, period 4 along the spine: lane in, divider (open at the far end), lane back (closed at the
    # spine), separating wall. The phase is 0 or 3, so every tooth has its lane in (partial ones come last).
    lane = (along + 3 * _bit(header[10], 0).astype(jnp.int32)) % 4
    hairpin = (lane == 3) | (lane == 1) & (depth < length - 1) | (lane == 2) & (depth == 0)
    shelves = ~spine & jnp.where(header[11] >= threshold(jnp.float32(0.25)), hairpin, straight)
    return shelves & in_bounds_mask(height, width, config.max_shape), height, width
