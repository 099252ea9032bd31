"""An episode's start: which pool slot and item (drawn on every step under auto-reset, so written
for speed), and the first state on them."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from wrl_jax.core.random import random_words, threefry2x32, threefry_key_data
from wrl_jax.envs.procedural.observation import count_visit
from wrl_jax.envs.procedural.pool import LayoutPool
from wrl_jax.envs.procedural.types import ProceduralState
from wrl_jax.envs.warehouse.env import item_from_word


def draw_episode(key: jax.Array, num_items: jax.Array, pool_size: int) -> tuple[jax.Array, jax.Array]:
    """``(slot, item)`` of a fresh episode from two words ``jax.random.bits(key, (2,), uint32)`` (same bits).

    Why a one-trip ``lax.while_loop``: the reset is drawn on every step of every environment,
    and XLA fuses an elementwise producer into each consumer. Without the loop, threefry's 20
    rounds were recomputed inside every gather and select that reads the indices (10 fusions,
    some for each of the 80 observation values); ``lax.optimization_barrier`` does not stop it
    on CPU. The loop's counter is threefry's first counter word (0 on its only trip), so the
    body cannot be hoisted out as loop-invariant.
    """
    data = threefry_key_data(key)
    if data is None:
        words = random_words(key, 2)
        layout_index = item_from_word(words[0], jnp.int32(pool_size))
        return layout_index, item_from_word(words[1], num_items[layout_index])

    def body(carry):
        _, counter, _ = carry
        x0, x1 = threefry2x32(data[0], data[1], counter, jnp.arange(2, dtype=jnp.uint32))
        return jnp.bool_(False), counter + 1, x0 ^ x1

    start = (jnp.bool_(True), jnp.uint32(0), jnp.zeros(2, dtype=jnp.uint32))
    words = jax.lax.while_loop(lambda carry: carry[0], body, start)[2]
    layout_index = item_from_word(words[0], jnp.int32(pool_size))
    return layout_index, item_from_word(words[1], num_items[layout_index])


def initial_state(layout_index: jax.Array, item_index: jax.Array, pool: LayoutPool,
                  walls: jax.Array, visited_rows: int = 0, visit_levels: int = 1) -> ProceduralState:
    """The first state of the episode on pool slot ``layout_index`` with its item ``item_index``.

    ``walls`` is the pool's :meth:`ProceduralWarehouse.pool_walls` (``params.walls``);
    ``visited_rows`` and ``visit_levels`` (static) are :attr:`ProceduralWarehouse.visited_rows` and
    ``visit_levels``: with rows, the start is the trail's first cell.
    """
    layout = jax.tree.map(lambda leaf: leaf[layout_index], pool.layouts)
    view_radius = (walls.shape[-2] - pool.layouts.blocked.shape[-2]) // 2
    visited = jnp.zeros((int(visit_levels).bit_length(), visited_rows, 1), dtype=jnp.uint32)
    if visited_rows:
        visited = count_visit(visited, layout.start, view_radius, visit_levels)
    return ProceduralState(
        walls=walls[layout_index],
        height=layout.height,
        width=layout.width,
        goal=layout.goal,
        pos=layout.start,
        item_pos=layout.items[item_index],
        layout_index=layout_index,
        item_index=item_index,
        carrying=jnp.zeros((), dtype=bool),
        time=jnp.zeros((), dtype=jnp.int32),
        optimal=pool.optimal[layout_index, item_index],
        last_action=jnp.int32(-1),
        visited=visited,
    )
