"""Grid mechanics every family shares: unit moves and BFS distance fields in JAX.

Distance fields work on traced arrays, so they ``jit`` and ``vmap`` over
layouts (generated warehouses, fleets with many targets). Grids may be
rectangular ``(H, W)``; a cell outside the array is off-grid.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

MOVES = np.array([[-1, 0], [1, 0], [0, -1], [0, 1]], dtype=np.int32)
"""Unit moves ``(row, col)`` of actions 0 up, 1 down, 2 left, 3 right."""

MOVES_WITH_WAIT = np.concatenate([MOVES, np.zeros((1, 2), dtype=np.int32)])
"""The four moves, then action 4 wait (FLEET_SPEC.md)."""

UNREACHABLE = int(np.iinfo(np.int32).max // 2)
"""Distance of cells that no free path reaches (and of blocked cells)."""


def distance_map(blocked: jax.Array, target: jax.Array) -> jax.Array:
    """Shortest free-cell distance from every cell to ``target``, ``(H, W)`` int32.

    Blocked and unreachable cells get :data:`UNREACHABLE`. Relaxes all cells at
    once until nothing changes (at most ``H*W`` sweeps, in practice the longest
    shortest path), which vectorizes well and needs no queue.
    """
    height, width = blocked.shape[-2:]
    dist = jnp.full((height, width), UNREACHABLE, dtype=jnp.int32).at[target[0], target[1]].set(0)

    def relax(carry):
        d, _ = carry
        new = jnp.where(blocked, UNREACHABLE, jnp.minimum(d, neighbour_min(d) + 1))
        return new, jnp.any(new != d)

    dist, _ = jax.lax.while_loop(lambda carry: carry[1], relax, (dist, jnp.array(True)))
    return dist


def distance_maps(blocked: jax.Array, targets: jax.Array) -> jax.Array:
    """:func:`distance_map` to each of ``targets`` ``(T, 2)``: ``(T, H, W)`` int32."""
    return jax.vmap(distance_map, in_axes=(None, 0))(blocked, targets)


def neighbour_min(d: jax.Array) -> jax.Array:
    """Per cell, the minimum of its four neighbours' values (off-grid counts as unreachable)."""
    padded = jnp.pad(d, 1, constant_values=UNREACHABLE)
    return jnp.minimum(
        jnp.minimum(padded[:-2, 1:-1], padded[2:, 1:-1]),
        jnp.minimum(padded[1:-1, :-2], padded[1:-1, 2:]),
    )
