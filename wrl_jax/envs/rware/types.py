"""Typed pytrees of RWARE (rware 2.0.0 in JAX): its state, its params, and the action and direction codes.

Both are ``flax.struct`` dataclasses, so they pass through ``jit``, ``vmap`` and
``lax.scan``. Everything a layout or a setting can change without changing a shape is
an array in :class:`RwareParams`; shapes (grid, agent, shelf, queue and goal counts,
sensor range, message bits) are static and live on the environment object.

Shapes: ``N`` agents, ``S`` shelves, ``R`` request-queue slots, ``G`` goals, ``H x W`` grid,
``M`` message bits. Indices are 0-based (rware's agent and shelf ids are these plus one).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

NUM_ACTIONS = 5
NOOP, FORWARD, LEFT, RIGHT, TOGGLE_LOAD = range(NUM_ACTIONS)
"""rware's ``Action`` values."""

UP, DOWN, LEFT_DIR, RIGHT_DIR = range(4)
"""rware's ``Direction`` values (``LEFT_DIR``/``RIGHT_DIR``: the headings, not the turn actions)."""

GLOBAL, INDIVIDUAL, TWO_STAGE = range(3)
"""rware's ``RewardType`` values."""

NO_SHELF = -1
"""``RwareState.carrying`` of an agent that carries nothing."""


@struct.dataclass
class RwareState:
    """The warehouse between steps.

    Attributes:
        agent_x, agent_y: ``(N,)`` int32 agent cells.
        agent_dir: ``(N,)`` int32 heading (``UP``, ``DOWN``, ``LEFT_DIR``, ``RIGHT_DIR``).
        carrying: ``(N,)`` int32 index of the carried shelf, ``NO_SHELF`` if none.
        has_delivered: ``(N,)`` bool, rware's flag for the two-stage drop bonus.
        message: ``(N, M)`` float32 each agent's last message (``M = 0`` without messages).
        shelf_x, shelf_y: ``(S,)`` int32 shelf cells (a carried shelf moves with its carrier).
        queue: ``(R,)`` int32 requested shelf indices, in rware's slot order.
        time: ``()`` int32 steps taken in this episode (rware's ``_cur_steps``).
        inactive: ``()`` int32 consecutive steps without a delivery (``_cur_inactive_steps``).
    """

    agent_x: jax.Array
    agent_y: jax.Array
    agent_dir: jax.Array
    carrying: jax.Array
    has_delivered: jax.Array
    message: jax.Array
    shelf_x: jax.Array
    shelf_y: jax.Array
    queue: jax.Array
    time: jax.Array
    inactive: jax.Array


@struct.dataclass
class RwareParams:
    """Floor plan, reward type and episode limits.

    Attributes:
        highway: ``(H, W)`` bool, True on highway cells (drops are refused there).
        goals: ``(G, 2)`` int32 goal cells ``(x, y)`` in delivery order.
        shelf_home: ``(S, 2)`` int32 ``(x, y)`` where each shelf stands at reset.
        reward_type: ``()`` int32 ``GLOBAL``, ``INDIVIDUAL`` or ``TWO_STAGE``.
        max_steps: ``()`` int32 episode length; 0 disables it (rware's ``None``).
        max_inactivity_steps: ``()`` int32 steps without a delivery that end an episode; 0 disables it.
    """

    highway: jax.Array
    goals: jax.Array
    shelf_home: jax.Array
    reward_type: jax.Array
    max_steps: jax.Array
    max_inactivity_steps: jax.Array

    @property
    def max_steps_in_episode(self) -> jax.Array:
        """gymnax's name for the episode length (the int32 maximum when disabled)."""
        return jnp.where(self.max_steps > 0, self.max_steps, jnp.iinfo(jnp.int32).max)

    @property
    def grid_size(self) -> tuple[int, int]:
        """``(H, W)`` (static: an array shape)."""
        return self.highway.shape[-2], self.highway.shape[-1]

    @property
    def num_shelves(self) -> int:
        return self.shelf_home.shape[-2]

    @property
    def num_goals(self) -> int:
        return self.goals.shape[-2]
