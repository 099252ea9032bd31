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

from wrl_jax.core.grid import UNREACHABLE, distance_map  # noqa: F401 (re-exported)
from wrl_jax.envs.warehouse.layout import MOVES
from wrl_jax.envs.warehouse.types import EnvParams, EnvState


@struct.dataclass
class RouteTables:
    """BFS distances to every target of a layout.

    Attributes:
        to_goal: ``(N, N)`` int32 distance from each cell to the goal.
        to_items: ``(K_max, N, N)`` int32 distance from each cell to each item.
    """

    to_goal: jax.Array
    to_items: jax.Array


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
