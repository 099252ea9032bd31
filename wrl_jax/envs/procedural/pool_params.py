"""The pool's life in params: what is precomputed per layout (walls, first observations, BFS tables)
and the refresh that renews slots between updates, inside ``jit``.

:class:`PoolParams` is a mixin of :class:`~wrl_jax.envs.procedural.env.ProceduralWarehouse`; the pool
itself (generation, hashes, refresh keys and slots) is :mod:`wrl_jax.envs.procedural.pool`.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.core.grid import distance_maps
from wrl_jax.core.observation import wall_rows
from wrl_jax.envs.procedural.episode import initial_state
from wrl_jax.envs.procedural.generators import generate_batch
from wrl_jax.envs.procedural.pool import (
    LayoutPool,
    generate_pool,
    pool_from_keys,
    pool_hashes,
    pool_of,
    refresh_keys,
    refresh_pool,
    refresh_slots,
)
from wrl_jax.envs.procedural.types import ProceduralParams


class PoolParams:
    """The pool methods of :class:`~wrl_jax.envs.procedural.env.ProceduralWarehouse`."""

    def pool_walls(self, pool: LayoutPool) -> jax.Array:
        """``(P, H + 2V, words)`` uint32: every layout's floor as :meth:`blocked` reads it (``params.walls``)."""
        return jax.vmap(wall_rows, in_axes=(0, None))(pool.layouts.blocked, self.view_radius)

    def reset_observations(self, pool: LayoutPool, walls: jax.Array | None = None) -> jax.Array:
        """``(P, I, obs_size)``: :meth:`observe` of the first state of every (slot, item) episode."""
        walls = self.pool_walls(pool) if walls is None else walls
        slots = jnp.arange(pool.size, dtype=jnp.int32)[:, None]
        items = jnp.arange(pool.layouts.items.shape[-2], dtype=jnp.int32)[None, :]
        slots, items = jnp.broadcast_arrays(slots, items)
        first_state = partial(initial_state, visited_rows=self.visited_rows, visit_levels=self.visit_levels)
        first = jax.vmap(jax.vmap(first_state, in_axes=(0, 0, None, None)),
                         in_axes=(0, 0, None, None))(slots, items, pool, walls)
        return jax.vmap(jax.vmap(self.observe))(first)

    @property
    def distance_rows(self) -> int:
        """Tables per layout in ``params.distances``: every item row and the goal with BFS shaping, else none."""
        return self.generator.max_items + 1 if self.shaping == "bfs" else 0

    def pool_distances(self, pool: LayoutPool) -> jax.Array:
        """``(P, distance_rows, H, W)`` int16: BFS distances from every cell to each item row, then the goal.

        Computed with the pool (a relaxation per target, :func:`wrl_jax.core.grid.distance_maps`),
        so a step reads two entries instead of searching; cells the target cannot be reached from
        (shelves, off-grid, closed pockets: never a robot's cell) hold int16's maximum.
        """
        if self.shaping != "bfs":
            return jnp.zeros((pool.size, 0, *self.max_shape), dtype=jnp.int16)
        layouts = pool.layouts
        targets = jnp.concatenate([layouts.items, layouts.goal[:, None, :]], axis=1)
        tables = jax.vmap(distance_maps)(layouts.blocked, targets)
        return jnp.minimum(tables, np.iinfo(np.int16).max).astype(jnp.int16)

    def with_pool(self, params: ProceduralParams, pool: LayoutPool) -> ProceduralParams:
        """``params`` serving ``pool`` (its walls, reset observations and distance tables recomputed)."""
        walls, reset_obs, distances = pool_arrays(self, pool)
        return params.replace(pool=pool, walls=walls, reset_obs=reset_obs, distances=distances)

    def refresh_pool(self, key: jax.Array, params: ProceduralParams, count: int | None = None) -> ProceduralParams:
        """Params with the pool (or ``count`` slots of it) regenerated from ``key``; call between updates."""
        return self.with_pool(params, refresh_pool(key, params.pool, self.generator, count))

    @property
    def refreshes_params(self) -> bool:
        return self.pool_refresh > 0

    def params_for_update(self, params: ProceduralParams, update_index: jax.Array) -> ProceduralParams:
        """``params`` with ``pool_refresh`` slots renewed before update ``update_index`` (inside ``jit``).

        The fresh layouts come from the training stream of ``pool_seed``
        (:func:`~wrl_jax.envs.procedural.pool.refresh_keys`) and replace the oldest slots
        (:func:`~wrl_jax.envs.procedural.pool.refresh_slots`); their walls and reset
        observations are computed for the new slots only. A function of ``update_index``
        alone: every seed of a run trains on the same layout stream, a resumed run continues
        it exactly, and :meth:`training_layout_hashes` can list every layout a run saw.
        """
        if not self.refreshes_params:
            return params
        keys = refresh_keys(jax.random.key(self.pool_seed), update_index, self.pool_refresh)
        fresh = pool_of(generate_batch(keys, self.generator))
        walls = self.pool_walls(fresh)
        reset_obs = self.reset_observations(fresh, walls)
        slots = refresh_slots(update_index, self.pool_refresh, self.pool_size)

        def put(old, new):
            return old.at[slots].set(new)

        return params.replace(pool=jax.tree.map(put, params.pool, fresh), walls=put(params.walls, walls),
                              reset_obs=put(params.reset_obs, reset_obs),
                              distances=put(params.distances, self.pool_distances(fresh)))

    def training_layout_hashes(self, params: ProceduralParams, updates: int | None) -> np.ndarray:
        """uint64 hashes of every layout training on ``params`` for ``updates`` updates could have drawn.

        ``params``' own pool, plus (when the pool is refreshed) the initial pool of ``pool_seed``
        and every refresh before updates ``0 .. updates - 1``, regenerated: what a held-out set
        must not contain. ``updates=None`` with refreshes: ``ValueError`` (unknown).
        """
        seen = [pool_hashes(params.pool)]
        if self.refreshes_params:
            if updates is None:
                raise ValueError("the pool was refreshed while training: pass the number of updates trained")
            seen.append(pool_hashes(generate_pool(jax.random.key(self.pool_seed), self.pool_size, self.generator)))
            batch = max(1, 8192 // self.pool_refresh)  # updates regenerated per call
            for first in range(0, int(updates), batch):
                count = min(batch, int(updates) - first)
                keys = jax.vmap(lambda u: refresh_keys(jax.random.key(self.pool_seed), u, self.pool_refresh))(
                    jnp.arange(first, first + count))
                seen.append(pool_hashes(pool_from_keys(keys.reshape(-1), self.generator)))
        return np.unique(np.concatenate(seen))


@partial(jax.jit, static_argnums=0)
def pool_arrays(env: PoolParams, pool: LayoutPool) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(walls, reset_obs, distances)`` of ``pool`` for ``env``'s params (one compiled program per env and pool shape)."""
    walls = env.pool_walls(pool)
    return walls, env.reset_observations(pool, walls), env.pool_distances(pool)
