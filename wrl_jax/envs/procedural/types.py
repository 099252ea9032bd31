"""The procedural warehouse's params (the layout pool and what is precomputed per layout) and state."""

from __future__ import annotations

import jax
from flax import struct

from wrl_jax.envs.procedural.pool import LayoutPool

NUM_ACTIONS = 4
SHAPINGS = ("manhattan", "bfs")
"""Distances the reward's shaping term can use (``shaping=``)."""
MAX_POOL_SIZE = 2**16 - 1
"""Slot bound of the 32-bit slot draw (:func:`wrl_jax.envs.warehouse.env.item_from_word`)."""
MAX_VISIT_LEVELS = 255
"""Largest visit count the trail channel tells apart (8 bit planes)."""



@struct.dataclass
class ProceduralParams:
    """The layout pool, what is precomputed per layout, episode length and SPEC.md's six reward constants.

    Both per-layout arrays are computed with the pool (:meth:`ProceduralWarehouse.with_pool`), so
    the auto-reset of every step gathers them instead of computing them per environment:

    - ``walls`` ``(P, H + 2V, words)`` uint32: each floor's walled rows packed in words
      (:func:`wrl_jax.core.observation.wall_rows`), what a state carries as its floor;
    - ``reset_obs`` ``(P, I, obs_size)``: the first observation of every (slot, item) episode
      (a second egocentric window per environment per step, for the reset branch of the
      auto-reset select, measured the largest cost of a step: docs/procedural.md).

    With ``shaping="bfs"`` a third: ``distances`` ``(P, I + 1, H, W)`` int16, the BFS distance from
    every cell to each item row and (last) to the goal (:meth:`ProceduralWarehouse.pool_distances`),
    read by the reward's shaping term and never observed; ``(P, 0, H, W)`` (nothing) with Manhattan shaping.
    """

    pool: LayoutPool
    walls: jax.Array
    reset_obs: jax.Array
    distances: jax.Array
    max_steps: jax.Array
    step_penalty: jax.Array
    obstacle_penalty: jax.Array
    wall_penalty: jax.Array
    shaping_coef: jax.Array
    pickup_reward: jax.Array
    delivery_reward: jax.Array

    @property
    def max_steps_in_episode(self) -> jax.Array:
        """gymnax's name for :attr:`max_steps` (gymnax wrappers and rejax read it)."""
        return self.max_steps


@struct.dataclass
class ProceduralState:
    """One episode. ``walls`` ``(H + 2V, words)`` uint32 is this episode's floor, a copy from ``params.walls``.

    ``last_action`` is the action of the previous step (-1 on an episode's first). ``visited``
    ``(B, H + 2V, 1)`` uint32, ``B`` bit planes in the floor's packed layout, counts the visits to each
    cell since the current target was set, saturating at ``visit_levels`` (bit ``k`` of a cell's count
    in plane ``k``; ``B = 1`` for the plain trail; ``(1, 0, 1)``, nothing, unless the environment
    observes it).

    The floor's walled rows packed in words (:func:`wrl_jax.core.observation.wall_rows`: shelves,
    off-grid padding and a ``V``-cell wall ring set); :meth:`ProceduralWarehouse.blocked` unpacks it.
    """

    walls: jax.Array
    height: jax.Array
    width: jax.Array
    goal: jax.Array
    pos: jax.Array
    item_pos: jax.Array
    layout_index: jax.Array
    item_index: jax.Array
    carrying: jax.Array
    time: jax.Array
    optimal: jax.Array
    last_action: jax.Array
    visited: jax.Array
