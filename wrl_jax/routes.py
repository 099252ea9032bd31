"""Shortest routes in JAX: BFS distance maps, optimal route lengths, an oracle.

These work on traced params, so they can be ``jit``-ed and ``vmap``-ped over
layouts, and they are the yardstick of every evaluation: a policy is judged by
its excess over :func:`optimal_lengths`. The NumPy BFS in ``layout.py`` checks
maps at parse time; the tests check that the two agree.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from wrl_jax.layout import MOVES
from wrl_jax.types import EnvParams, EnvState

UNREACHABLE = jnp.iinfo(jnp.int32).max // 2
"""Distance of cells that no free path reaches (and of shelf cells)."""


@struct.dataclass
class RouteTables:
    """BFS distances to every target of a layout.

    Attributes:
        to_goal: ``(N, N)`` int32 distance from each cell to the goal.
        to_items: ``(K_max, N, N)`` int32 distance from each cell to each item.
    """

    to_goal: jax.Array
    to_items: jax.Array


def distance_map(shelves: jax.Array, target: jax.Array) -> jax.Array:
    """Shortest free-cell distance from every cell to ``target``, ``(N, N)`` int32.

    Shelf and unreachable cells get :data:`UNREACHABLE`. Relaxes all cells at
    once until nothing changes (at most ``N*N`` sweeps), which vectorizes well
    and needs no queue.
    """
    size = shelves.shape[-1]
    dist = jnp.full((size, size), UNREACHABLE, dtype=jnp.int32).at[target[0], target[1]].set(0)

    def neighbour_min(d):
        padded = jnp.pad(d, 1, constant_values=UNREACHABLE)
        return jnp.minimum(
            jnp.minimum(padded[:-2, 1:-1], padded[2:, 1:-1]),
            jnp.minimum(padded[1:-1, :-2], padded[1:-1, 2:]),
        )

    def relax(carry):
        d, _ = carry
        new = jnp.where(shelves, UNREACHABLE, jnp.minimum(d, neighbour_min(d) + 1))
        return new, jnp.any(new != d)

    dist, _ = jax.lax.while_loop(lambda carry: carry[1], relax, (dist, jnp.array(True)))
    return dist


def route_tables(params: EnvParams) -> RouteTables:
    """Distance maps to the goal and to every item of ``params``."""
    to_items = jax.vmap(distance_map, in_axes=(None, 0))(params.shelves, params.items)
    return RouteTables(to_goal=distance_map(params.shelves, params.goal), to_items=to_items)


def optimal_lengths(params: EnvParams, tables: RouteTables | None = None) -> jax.Array:
    """BFS optimum of each item's route start -> item -> goal, ``(K_max,)`` int32.

    Entries past ``params.num_items`` describe padding and mean nothing.
    """
    tables = route_tables(params) if tables is None else tables
    start_to_item = tables.to_items[:, params.start[0], params.start[1]]
    item_to_goal = tables.to_goal[params.items[:, 0], params.items[:, 1]]
    return start_to_item + item_to_goal


def oracle_action(state: EnvState, params: EnvParams, tables: RouteTables) -> jax.Array:
    """An action on a shortest route to the current target (item, then goal).

    Among the moves that reduce the BFS distance by one, the lowest action
    index wins, so the oracle is deterministic.
    """
    size = params.shelves.shape[-1]
    dist = jnp.where(state.carrying, tables.to_goal, tables.to_items[state.item_index])
    neighbours = state.pos[None, :] + jnp.asarray(MOVES)
    on_grid = jnp.all((neighbours >= 0) & (neighbours < size), axis=-1)
    clipped = jnp.clip(neighbours, 0, size - 1)
    neighbour_dist = jnp.where(on_grid, dist[clipped[:, 0], clipped[:, 1]], UNREACHABLE)
    return jnp.argmin(neighbour_dist).astype(jnp.int32)
