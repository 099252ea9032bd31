"""What the procedural robot observes: the fleet's robot observation for one robot, then the
configured memory (previous action, visit counts), range sensor and full map.

:class:`ProceduralObservation` is a mixin of :class:`~wrl_jax.envs.procedural.env.ProceduralWarehouse`:
its methods read the environment's static settings (``view_radius``, ``observe_*``, ``max_shape``).
For ``V <= 2`` (walled rows of at most 32 cells) the window comes from bit masks of the packed rows,
bit for bit the observation the gathers would give and many times cheaper under ``vmap``; for larger
``V`` the window's rows are read from the packed rows and expanded.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.core.observation import (
    coordinate_table,
    expand_observations,
    free_runs,
    pack_window_rows,
    plane_window_rows,
    robot_observation_parts,
    robot_observations,
    row_window_observation,
    row_windows_supported,
    unpack_wall_rows,
    window_row_bits,
    window_rows_supported,
)
from wrl_jax.envs.procedural.types import NUM_ACTIONS, ProceduralState


class ProceduralObservation:
    """The observation methods of :class:`~wrl_jax.envs.procedural.env.ProceduralWarehouse`."""

    def observe(self, state: ProceduralState) -> jax.Array:
        """``(obs_size,)`` float32: the fleet robot observation for one robot, then what is configured.

        After the robot observation: the previous action one-hot (``observe_last_action``),
        the visited cells of the window (``observe_visited``, row-major like the window's
        channels), the free runs up, down, left and right (``observe_rays``), then the full
        map (``observe_map``).

        The map's channels: 0 shelves and off-grid, 1 the robot itself (the
        window has it at its centre; a full map must say where), 2 the target.
        """
        target = jnp.where(state.carrying, state.goal, state.item_pos)
        size = max(self.max_shape)
        if self.observe_window and self.row_windows:
            # The floor and the trail's bit planes side by side: one gather of the window's rows for all.
            planes = state.walls
            if self.observe_visited:
                planes = jnp.concatenate([planes, state.visited[:, :, 0].T], axis=1)
            window = plane_window_rows(planes, state.pos[None], self.view_radius)[0]  # (2V+1, 1 + B)
            trail = window[:, 1:]
        if self.observe_window and self.bit_windows:
            masks = pack_window_rows(window[None, :, 0])
            parts = robot_observation_parts(masks, state.pos[None], target[None], state.carrying[None],
                                            self.view_radius, size)
            obs = expand_observations(*parts, self.view_radius)[0]
        elif self.observe_window and self.row_windows:
            obs = row_window_observation(window[:, 0], state.pos, target, state.carrying, self.view_radius, size)
        elif self.observe_window:
            obs = robot_observations(self.blocked(state), state.pos[None], target[None], state.carrying[None],
                                     self.view_radius, size)[0]
        else:
            table = jnp.asarray(coordinate_table(size))
            obs = jnp.concatenate([table[state.pos], table[target], state.carrying.astype(jnp.float32)[None]])
        if self.observe_last_action:
            # one_hot of -1 (no action yet) is all zeros.
            obs = jnp.concatenate([obs, jax.nn.one_hot(state.last_action, NUM_ACTIONS, dtype=jnp.float32)])
        if self.observe_visited:  # (it needs the packed-row window: checked in __init__)
            obs = jnp.concatenate([obs, self.trail_window(trail)])
        if self.observe_rays:  # free runs in cells, over N - 1 like the coordinates (a float32 product, not a division)
            runs = free_runs(state.walls, state.pos, self.view_radius, self.max_shape[1])
            obs = jnp.concatenate([obs, runs.astype(jnp.float32) * np.float32(1 / max(size - 1, 1))])
        if not self.observe_map:
            return obs
        rows = jnp.arange(self.max_shape[0])[:, None]
        cols = jnp.arange(self.max_shape[1])[None, :]
        robot = (rows == state.pos[0]) & (cols == state.pos[1])
        target_cell = (rows == target[0]) & (cols == target[1])
        full_map = jnp.stack([self.blocked(state), robot, target_cell]).astype(jnp.float32)
        return jnp.concatenate([obs, full_map.reshape(-1)])

    def trail_window(self, trail: jax.Array) -> jax.Array:
        """``((2V+1)^2,)`` float32: the visits to each window cell since the current target was set, times ``1 / L``.

        ``trail``: ``(2V+1, B)``, the window's rows of each bit plane of ``state.visited`` (read with
        the floor's, :func:`~wrl_jax.core.observation.plane_window_rows`); the planes' bits are summed
        with their weights: exact small integers in float32.
        """
        count = 0.0
        for plane in range(trail.shape[1]):
            count = count + window_row_bits(trail[:, plane]) * np.float32(2**plane)
        # times float32(1 / L), written out: XLA turns a division by a constant into this product anyway
        return count if self.visit_levels == 1 else count * np.float32(1 / self.visit_levels)

    @property
    def visited_rows(self) -> int:
        """Rows of ``state.visited``: the walled floor's ``H + 2V`` when observed, else 0 (an empty array)."""
        return self.max_shape[0] + 2 * self.view_radius if self.observe_visited else 0

    @property
    def bit_windows(self) -> bool:
        """True when the window comes from bit masks of the packed rows (``V <= 2``, walled rows of <= 32 cells)."""
        return row_windows_supported(self.max_shape[1], self.view_radius)

    @property
    def row_windows(self) -> bool:
        """True when the window's rows are read from the packed rows (any ``V`` with walled rows of <= 32 cells).

        For ``V <= 2`` the rows are packed once more into the fleet's int32 masks (:attr:`bit_windows`); past
        that, :func:`~wrl_jax.core.observation.row_window_observation` expands the rows directly.
        """
        return window_rows_supported(self.max_shape[1], self.view_radius)

    def blocked(self, state: ProceduralState) -> jax.Array:
        """``(..., H, W)`` bool: the floor of ``state`` (or of a batch of states), shelves and off-grid cells True."""
        return unpack_wall_rows(state.walls, self.max_shape, self.view_radius)


def count_visit(planes: jax.Array, cell: jax.Array, view_radius: int, levels: int) -> jax.Array:
    """``planes`` ``(B, H + 2V, 1)`` (a count per cell, bit ``k`` in plane ``k``) with ``cell``'s count
    raised by one, saturating at ``levels``; the rows are packed like
    :func:`~wrl_jax.core.observation.wall_rows`, one word a row. With ``levels = 1`` it sets the cell's bit.

    Written with a row mask (one elementwise pass over the ``B (H + 2V)`` words) instead of an indexed
    read and write, which ``vmap`` turns into a gather and a scatter; the two measured the same
    (docs/procedural.md), and this form needs no index arithmetic per plane.
    """
    row = jnp.arange(planes.shape[1], dtype=jnp.int32)[None, :, None] == cell[0] + view_radius
    bit = jnp.left_shift(jnp.uint32(1), (cell[1] + view_radius).astype(jnp.uint32))
    weights = np.left_shift(1, np.arange(planes.shape[0])).astype(np.int32)
    has_bit = jnp.any(row & ((planes & bit) != 0), axis=(1, 2))  # (B,): the cell's count, bit by bit
    count = jnp.sum(jnp.where(has_bit, weights, 0))
    set_bit = ((jnp.minimum(count + 1, levels) & weights) != 0)[:, None, None]
    return jnp.where(row, jnp.where(set_bit, planes | bit, planes & ~bit), planes)
