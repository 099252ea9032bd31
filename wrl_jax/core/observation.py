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
    num_robots = pos.shape[0]
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
    del num_robots
    return jnp.stack([shelf_channel, robot_channel, target_channel], axis=1)
