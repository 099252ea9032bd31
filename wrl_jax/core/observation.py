"""Robot-centred observations shared by the fleet and the procedural warehouses.

FLEET_SPEC.md's observation of robot ``i``: five values (own row and col,
target row and col, each divided by ``N - 1``, then the carrying flag), then
an egocentric window of side ``2V + 1`` with three channels (0: shelves and
off-grid, 1: another robot, 2: this robot's target cell), channel-major then
row-major. A single robot on a generated layout gets exactly this observation
(with no other robot), from this same code.

Coordinates are read from an exact table of ``float32(i) / float32(N - 1)``:
XLA on CPU compiles a float division into a reciprocal multiply, which can
differ from the true float32 quotient in the last bit, and the NumPy
references divide.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def coordinate_table(size: int) -> np.ndarray:
    """``float32(i) / float32(size - 1)`` for ``i`` in ``0..size-1`` (float32, exact quotients)."""
    return np.arange(size, dtype=np.float32) / np.float32(max(size - 1, 1))


def window_size(view_radius: int) -> int:
    return 2 * int(view_radius) + 1


def observation_size(view_radius: int) -> int:
    """Width of one robot's observation: ``5 + 3 (2V+1)^2``."""
    return 5 + 3 * window_size(view_radius) ** 2


def robot_observations(
    blocked: jax.Array,
    pos: jax.Array,
    target: jax.Array,
    carrying: jax.Array,
    view_radius: int,
    size: int | None = None,
) -> jax.Array:
    """Every robot's observation, ``(K, 5 + 3 (2V+1)^2)`` float32.

    Args:
        blocked: ``(H, W)`` bool, True on shelves (and on padding cells of a
            layout smaller than its array, which count as off-grid).
        pos: ``(K, 2)`` int32 robot cells.
        target: ``(K, 2)`` int32 each robot's current target cell.
        carrying: ``(K,)`` bool.
        view_radius: ``V`` (static).
        size: ``N`` of the ``/ (N - 1)`` scaling (static); defaults to ``H``.
    """
    height, width = blocked.shape
    table = jnp.asarray(coordinate_table(height if size is None else size))
    scalars = jnp.concatenate(
        [table[pos], table[target], carrying.astype(jnp.float32)[:, None]], axis=1
    )
    windows = egocentric_windows(blocked, pos, target, view_radius)
    return jnp.concatenate([scalars, windows.reshape(pos.shape[0], -1)], axis=1)


def egocentric_windows(blocked: jax.Array, pos: jax.Array, target: jax.Array, view_radius: int) -> jax.Array:
    """The three-channel windows ``(K, 3, 2V+1, 2V+1)`` float32 of FLEET_SPEC.md."""
    radius = int(view_radius)
    side = window_size(radius)
    # Off-grid cells read as blocked: pad the grid with True, V cells on each side.
    walls = jnp.pad(blocked, radius, constant_values=True)
    occupancy = jnp.zeros(walls.shape, dtype=jnp.int32).at[pos[:, 0] + radius, pos[:, 1] + radius].add(1)

    def window(grid, cell):
        return jax.lax.dynamic_slice(grid, (cell[0], cell[1]), (side, side))

    shelf_channel = jax.vmap(window, in_axes=(None, 0))(walls, pos).astype(jnp.float32)
    robots_seen = jax.vmap(window, in_axes=(None, 0))(occupancy, pos)
    # A robot does not see itself: remove its own count at the window's centre.
    robots_seen = robots_seen.at[:, radius, radius].add(-1)
    robot_channel = (robots_seen > 0).astype(jnp.float32)
    offsets = jnp.arange(side, dtype=jnp.int32) - radius
    rows = pos[:, 0, None] + offsets[None, :]  # (K, side)
    cols = pos[:, 1, None] + offsets[None, :]
    target_channel = (
        (rows[:, :, None] == target[:, 0, None, None]) & (cols[:, None, :] == target[:, 1, None, None])
    ).astype(jnp.float32)
    return jnp.stack([shelf_channel, robot_channel, target_channel], axis=1)


# ----------------------------------------------------------------- the same windows, as bit masks
MAX_BIT_WINDOW = 31
"""Most window cells a mask holds: bits 0..30 of an int32 (so ``V <= 2``; larger radii use the gathers above,
or :func:`plane_window_rows` on packed floors)."""


def bit_windows_supported(view_radius: int) -> bool:
    """True when a ``(2V+1)^2`` window fits one int32 mask (``V <= 2``): the mask functions below apply."""
    return window_size(view_radius) ** 2 <= MAX_BIT_WINDOW


def window_masks(blocked: jax.Array, view_radius: int) -> jax.Array:
    """``(H, W)`` int32: bit ``w`` of cell ``c`` is set when window cell ``w`` around ``c`` is blocked or off-grid.

    Why: every robot's shelf channel then costs one scalar gather from this table instead of a
    ``(2V+1)^2`` gather; the table depends on the layout alone, so a batch of fleets sharing a layout
    (``vmap`` with unbatched params) builds it once per step, from ``(2V+1)^2`` static slices of the
    padded grid. Window cell ``w = row * (2V+1) + col`` is the offset ``(row - V, col - V)``.
    """
    radius = int(view_radius)
    side = window_size(radius)
    height, width = blocked.shape
    walls = jnp.pad(blocked, radius, constant_values=True).astype(jnp.int32)
    masks = jnp.zeros((height, width), dtype=jnp.int32)
    for row in range(side):
        for col in range(side):
            masks = masks | (walls[row:row + height, col:col + width] << (row * side + col))
    return masks


def offset_masks(d_row: jax.Array, d_col: jax.Array, view_radius: int) -> jax.Array:
    """int32 ``1 << w`` of the window cell at offset ``(d_row, d_col)`` from the centre, 0 outside the window.

    The offsets come as two arrays (rows, columns), not as one ``(..., 2)`` array: a trailing axis
    of 2 is a strided read that XLA's CPU loop emitter does not vectorize.
    """
    radius = int(view_radius)
    side = window_size(radius)
    inside = (jnp.abs(d_row) <= radius) & (jnp.abs(d_col) <= radius)
    index = jnp.where(inside, (d_row + radius) * side + d_col + radius, 0)
    return jnp.where(inside, jnp.left_shift(jnp.int32(1), index), 0)


def seen_masks(pos: jax.Array, cells: jax.Array, view_radius: int, keep: np.ndarray) -> jax.Array:
    """``(K,)`` int32: robot ``i``'s window mask of the cells ``cells[j]`` of the robots ``j`` with ``keep[i, j]``.

    ``pos``, ``cells``: ``(K, 2)`` int32; ``keep``: a static ``(K, K)`` bool array (e.g. ``j != i``: a
    robot does not see itself). Why ``K`` static terms, one per robot ``j`` and each elementwise
    over the observers ``i``, and not a ``(K, K)`` table ORed over ``j``: XLA compiles the terms
    to vector instructions over the batch, while the table's OR became a scalar loop inside the
    fusion that consumed it; the window masks ran 2x faster (docs/fleet_planners.md "Speed"). The
    terms are cheap elementwise code, so XLA fuses them into their consumer unless the masks are
    materialized first: the fleet's ``step`` does (they ride in its auto-reset loop), while an
    observation expanded straight from a state (``reset``, ``get_obs``) recomputes them per window
    column and runs about 0.85x what the ``(K, K)`` form did.
    """
    rows, cols = pos[:, 0], pos[:, 1]
    masks = jnp.zeros(pos.shape[:1], dtype=jnp.int32)
    for j in range(cells.shape[0]):
        if keep[:, j].any():
            bits = offset_masks(cells[j, 0] - rows, cells[j, 1] - cols, view_radius)
            masks = masks | (bits if keep[:, j].all() else jnp.where(keep[:, j], bits, 0))
    return masks


def robot_observation_parts(
    shelf_masks: jax.Array,
    pos: jax.Array,
    target: jax.Array,
    carrying: jax.Array,
    view_radius: int,
    size: int,
    priority: bool = False,
) -> tuple[jax.Array, tuple[jax.Array, ...]]:
    """A compact form of every robot's observation: ``(scalars (K, 5) float32, masks)``, three ``(K,)`` int32 masks.

    Why: a fleet step needs two observations (the reached one, ``final_obs``, and the auto-reset's)
    and selects between them; selecting 32 bytes per robot and expanding once writes the float32
    observation (320 bytes per robot at ``V = 2``) only where it is an output. The masks hold one
    channel each (bit ``w`` = window cell ``w``): the shelf mask is read from :func:`window_masks`,
    the robot mask ORs ``1 << w`` over the other robots whose offset lands in the window
    (:func:`seen_masks`, ``K x K`` work, tiny for a fleet), the target mask is one offset.
    :func:`expand_observations` makes the observation of :func:`robot_observations` from them, bit
    for bit. Needs :func:`bit_windows_supported`. A tuple of channels, not a ``(K, 3)`` stack:
    stacking made XLA interleave the three channels' computations element by element (a trailing
    axis of 3) instead of vectorizing each.

    Args:
        shelf_masks: ``(K,)`` int32, :func:`window_masks` of the blocked grid read at each robot's cell.
        pos, target: ``(K, 2)`` int32 robot cells and target cells; carrying: ``(K,)`` bool.
        view_radius: ``V`` (static); size: ``N`` of the ``/ (N - 1)`` scaling (static).
        priority: append a fourth mask: the robots of the robot mask with a lower
            index than the observer (those that win a free cell both enter, FLEET_SPEC.md step 3).
    """
    radius = int(view_radius)
    if not bit_windows_supported(radius):
        raise ValueError(f"view_radius {radius} does not fit a {MAX_BIT_WINDOW}-bit window mask")
    num_robots = pos.shape[0]
    table = jnp.asarray(coordinate_table(size))
    scalars = jnp.concatenate([table[pos], table[target], carrying.astype(jnp.float32)[:, None]], axis=1)
    robot_masks = seen_masks(pos, pos, radius, ~np.eye(num_robots, dtype=bool))  # j seen by i, j != i
    target_masks = offset_masks(target[:, 0] - pos[:, 0], target[:, 1] - pos[:, 1], radius)
    channels = [shelf_masks, robot_masks, target_masks]
    if priority:
        channels.append(seen_masks(pos, pos, radius, np.tri(num_robots, k=-1, dtype=bool)))  # j < i
    return scalars, tuple(channels)


def expand_observations(scalars: jax.Array, masks: tuple[jax.Array, ...], view_radius: int) -> jax.Array:
    """``(..., 5 + C (2V+1)^2)`` float32 observations from :func:`robot_observation_parts`' compact form.

    The scalars are copied and followed by the window columns. Window column ``c`` (channel ``k``,
    cell ``w``) is 1.0 where ``masks[k]`` (shape ``(...)``) has bit ``w`` set. Each window column reads every
    channel's mask ANDed with a constant, ``1 << w`` in the column's own channel and 0 in the others,
    and ORs the results: one AND per channel, the ORs and one compare for every column, no
    per-column choice of channel. XLA's CPU loop emitter turns that into a few vector instructions
    per 8 or 16 columns with the constants as memory operands; the chain of ``where`` calls on the
    column's channel it replaced compiled to a byte-mask conversion and a blend per select, and the
    observation ran 1.38x slower (``bench/investigations/fleet_step_profile.py --parts obs``; docs/fleet_planners.md
    "Speed"). The expression is elementwise, so XLA fuses it into whatever consumes the observation.
    ``C = len(masks)``, the channel count (3, or 4 with the priority channel, 5 with headings too).
    """
    cells = window_size(view_radius) ** 2
    num_channels = len(masks)
    channel, cell = np.divmod(np.arange(num_channels * cells), cells)
    seen = None
    for index in range(num_channels):
        column_bits = np.where(channel == index, np.left_shift(1, cell), 0).astype(np.int32)
        term = masks[index][..., None] & column_bits
        seen = term if seen is None else seen | term
    window = jnp.where(seen != 0, np.float32(1.0), np.float32(0.0))
    return jnp.concatenate([scalars, window], axis=-1)


def robot_observations_from_bits(
    shelf_masks: jax.Array,
    pos: jax.Array,
    target: jax.Array,
    carrying: jax.Array,
    view_radius: int,
    size: int,
) -> jax.Array:
    """:func:`robot_observations`, bit for bit, from each robot's shelf mask (:func:`window_masks` at its cell).

    Why: the gathers of :func:`egocentric_windows` (a ``(2V+1)^2`` dynamic slice per robot and
    channel, plus a scatter of the occupancy grid) dominated a fleet step under ``vmap``; here each
    channel is one int32 mask per robot (:func:`robot_observation_parts`), expanded elementwise.
    """
    scalars, masks = robot_observation_parts(shelf_masks, pos, target, carrying, view_radius, size)
    return expand_observations(scalars, masks, view_radius)


# ----------------------------------------------------------------- per-episode floors as packed rows
WORD_BITS = 32


def wall_words(width: int, view_radius: int) -> int:
    """uint32 words per row of :func:`wall_rows`: ``ceil((W + 2V) / 32)``."""
    return -(-(int(width) + 2 * int(view_radius)) // WORD_BITS)


def row_windows_supported(width: int, view_radius: int) -> bool:
    """True when :func:`pack_window_rows` makes the fleet's int32 mask of a window read by :func:`plane_window_rows`:
    the window fits a mask and a walled row fits one word."""
    return bit_windows_supported(view_radius) and wall_words(width, view_radius) == 1


def window_rows_supported(width: int, view_radius: int) -> bool:
    """True when :func:`plane_window_rows` applies: a walled row of ``W + 2V`` cells fits one word (any ``V``)."""
    return wall_words(width, view_radius) == 1


def wall_rows(blocked: jax.Array, view_radius: int) -> jax.Array:
    """``(H + 2V, wall_words(W, V))`` uint32: the grid walled with ``V`` blocked cells, each row packed in words.

    Why: an environment whose every episode has its own floor (a batch of generated layouts)
    cannot share :func:`window_masks`' ``(H, W)`` int32 table between episodes, and copying a
    table into every state costs 4 bytes a cell at every auto-reset. The walled rows are
    ``4 (H + 2V)`` bytes (80 at 16x16, ``V = 2``: less than the floor as a bool grid), and one
    robot's shelf mask is ``2V + 1`` words shifted and masked (:func:`plane_window_rows`). Bit ``b``
    of word ``k`` of row ``r`` is walled cell ``(r, 32 k + b)``, i.e. floor cell
    ``(r - V, 32 k + b - V)``: set when it is blocked or off the grid; bits past the walled width are 0.
    """
    radius = int(view_radius)
    height, width = blocked.shape
    words = wall_words(width, radius)
    walled = jnp.pad(blocked.astype(bool), radius, constant_values=True)
    walled = jnp.pad(walled, ((0, 0), (0, words * WORD_BITS - (width + 2 * radius))))
    weights = jnp.left_shift(jnp.uint32(1), jnp.arange(WORD_BITS, dtype=jnp.uint32))
    bits = walled.reshape(height + 2 * radius, words, WORD_BITS)
    return jnp.sum(jnp.where(bits, weights, jnp.uint32(0)), axis=-1, dtype=jnp.uint32)


def unpack_wall_rows(rows: jax.Array, shape: tuple[int, int], view_radius: int) -> jax.Array:
    """The ``(..., H, W)`` bool grid (True: blocked or off-grid) of :func:`wall_rows`' output ``(..., H + 2V, words)``."""
    radius = int(view_radius)
    height, width = shape
    columns = np.arange(width) + radius
    words = rows[..., radius:radius + height, :][..., columns // WORD_BITS]
    return ((words >> (columns % WORD_BITS).astype(np.uint32)) & 1).astype(bool)


def wall_bit(rows: jax.Array, cell: jax.Array, view_radius: int) -> jax.Array:
    """bool: floor cell ``cell (2,)`` is blocked or off-grid, read from :func:`wall_rows` (one word)."""
    radius = int(view_radius)
    col = cell[1] + radius
    word = rows[cell[0] + radius, col // WORD_BITS]
    return ((word >> (col % WORD_BITS).astype(jnp.uint32)) & 1).astype(bool)


def plane_window_rows(planes: jax.Array, pos: jax.Array, view_radius: int) -> jax.Array:
    """``(K, 2V+1, P)`` uint32: the window rows around each robot in each of ``P`` planes ``(H + 2V, P)``.

    Each column of ``planes`` is a grid of one-word walled rows packed like :func:`wall_rows` (the
    floor, a trail's bit planes; :func:`window_rows_supported`). Window row ``r`` of a plane is its
    walled row ``pos_r + r`` shifted right by ``pos_c`` and cut to ``2V + 1`` bits: bit ``c`` is the
    offset ``(r - V, c - V)``. The ``2V + 1`` rows are gathered once for every plane (a gather costs
    per index, not per word).
    """
    radius = int(view_radius)
    side = window_size(radius)
    offsets = np.arange(side)
    words = planes[pos[:, 0, None] + offsets[None, :]]  # (K, side, P): the walled rows the windows cover
    return (words >> pos[:, 1, None, None].astype(jnp.uint32)) & np.uint32((1 << side) - 1)


def pack_window_rows(rows: jax.Array) -> jax.Array:
    """``(K,)`` int32 of one plane's window rows ``(K, side)``: row ``r`` at bits ``r side .. r side + side - 1``.

    For ``V <= 2`` this is :func:`window_masks` read at the robot's cell (the fleet's shelf mask).
    """
    side = rows.shape[-1]
    shifted = rows << (np.arange(side) * side).astype(np.uint32)
    return jax.lax.reduce(shifted, np.uint32(0), jax.lax.bitwise_or, (1,)).astype(jnp.int32)


def window_row_bits(rows: jax.Array) -> jax.Array:
    """``(..., side * side)`` float32 of one plane's window rows ``(..., side)``: one window channel, row-major."""
    side = rows.shape[-1]
    bits = (rows[..., :, None] >> np.arange(side, dtype=np.uint32)) & np.uint32(1)
    return bits.astype(jnp.float32).reshape(*rows.shape[:-1], side * side)


def row_window_observation(window: jax.Array, pos: jax.Array, target: jax.Array, carrying: jax.Array,
                           view_radius: int, size: int) -> jax.Array:
    """One robot's :func:`robot_observations` (``K = 1``, no other robot), bit for bit, from its window's rows.

    For radii past the one-int32 mask of :func:`robot_observation_parts` (``V >= 3``): the shelf
    channel from the window's rows (``window``: ``(2V+1,)`` uint32, :func:`plane_window_rows` of the
    floor's :func:`wall_rows` for this robot), an empty robot channel, the target channel by
    comparing the window's cells with the target. ``pos``, ``target``: ``(2,)`` int32; ``carrying``: bool.
    """
    radius = int(view_radius)
    side = window_size(radius)
    table = jnp.asarray(coordinate_table(size))
    scalars = jnp.concatenate([table[pos], table[target], carrying.astype(jnp.float32)[None]])
    shelves = window_row_bits(window)
    offsets = np.arange(side) - radius
    target_cell = (pos[0] + offsets[:, None] == target[0]) & (pos[1] + offsets[None, :] == target[1])
    robots = jnp.zeros(side * side, jnp.float32)
    return jnp.concatenate([scalars, shelves, robots, target_cell.astype(jnp.float32).reshape(-1)])


RAY_DIRECTIONS = 4
"""Free runs a robot measures: up, down, left, right (the order of the moves)."""


def free_runs(rows: jax.Array, pos: jax.Array, view_radius: int, floor_width: int) -> jax.Array:
    """``(4,)`` int32: free cells in a straight line from ``pos`` up, down, left and right, read from :func:`wall_rows`.

    What a range sensor on the robot measures: the run stops at the first shelf or off-grid cell
    (the walled ring, or the grid's edge when ``V = 0``). ``floor_width``: ``W`` of the rows'
    floor (their words hold ``W + 2V`` cells and zeros after). Any number of words per row.
    """
    radius = int(view_radius)
    walled_row, walled_col = pos[0] + radius, pos[1] + radius
    bit_index = np.arange(WORD_BITS, dtype=np.uint32)
    row_bits = ((rows[walled_row][:, None] >> bit_index[None, :]) & 1).reshape(-1) > 0  # (32 words,) cells
    col_bits = ((rows[:, walled_col // WORD_BITS] >> (walled_col % WORD_BITS).astype(jnp.uint32)) & 1) > 0
    length = rows.shape[0]
    width = int(floor_width) + 2 * radius
    along_col, along_row = np.arange(length), np.arange(width)
    above = jnp.max(jnp.where(col_bits & (along_col < walled_row), along_col, -1))
    below = jnp.min(jnp.where(col_bits & (along_col > walled_row), along_col, length))
    row_bits = row_bits[:width]
    left = jnp.max(jnp.where(row_bits & (along_row < walled_col), along_row, -1))
    right = jnp.min(jnp.where(row_bits & (along_row > walled_col), along_row, width))
    return jnp.stack([walled_row - above - 1, below - walled_row - 1,
                      walled_col - left - 1, right - walled_col - 1]).astype(jnp.int32)
