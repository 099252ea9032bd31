"""Typed pytrees of the environment: its state and its params.

Both are ``flax.struct`` dataclasses, so they pass through ``jit``, ``vmap``
and ``lax.scan`` as ordinary pytrees. Everything a layout or a reward setting
can change lives in :class:`EnvParams` as arrays; only shapes (grid size,
item capacity, observation width) are static and live on the environment
object, so one compiled program serves every layout of a size.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class EnvState:
    """One environment's state between transitions.

    Attributes:
        pos: ``(2,)`` int32 robot cell ``(row, col)``.
        item_index: int32 index of this episode's item in ``params.items``.
        item_pos: ``(2,)`` int32 cell of this episode's item; a copy of
            ``params.items[item_index]`` kept so a step needs no gather.
        carrying: bool, True once the item has been picked up.
        time: int32 transitions taken in this episode (wall and shelf bumps count).
    """

    pos: jax.Array
    item_index: jax.Array
    item_pos: jax.Array
    carrying: jax.Array
    time: jax.Array


@struct.dataclass
class EnvParams:
    """Layout, reward constants and switches of one environment (SPEC.md).

    All leaves are arrays, so any of them can be batched with ``vmap`` (a sweep
    over reward constants, or many layouts of one size).

    Attributes:
        shelves: ``(N, N)`` bool, True on shelf cells.
        start: ``(2,)`` int32 start cell.
        goal: ``(2,)`` int32 goal cell.
        items: ``(K_max, 2)`` int32 item cells; rows past ``num_items`` are padding.
        num_items: int32 number of real items (reset draws from the first ``num_items``).
        max_steps: int32 episode length at which an episode is truncated.
        step_penalty: every non-terminating transition (-0.5).
        obstacle_penalty: a move into a shelf (-10).
        wall_penalty: a move off the grid (0).
        shaping_coef: weight of the Manhattan distance shaping (2.0).
        pickup_reward: the transition that picks up the item (+50).
        delivery_reward: the transition that delivers it (+200).
        collision_bug: bool, reproduce the study's "collision state corruption":
            the robot's position is written into the shelf cell before the
            collision check, so a collision leaves it *on* the shelf. Off by
            default; it exists only to reproduce the study's mistake.
    """

    shelves: jax.Array
    start: jax.Array
    goal: jax.Array
    items: jax.Array
    num_items: jax.Array
    max_steps: jax.Array
    step_penalty: jax.Array
    obstacle_penalty: jax.Array
    wall_penalty: jax.Array
    shaping_coef: jax.Array
    pickup_reward: jax.Array
    delivery_reward: jax.Array
    collision_bug: jax.Array

    @property
    def max_steps_in_episode(self) -> jax.Array:
        """gymnax's name for :attr:`max_steps` (gymnax wrappers and rejax read it)."""
        return self.max_steps

    @property
    def size(self) -> int:
        """Grid side ``N`` (static: it is an array shape)."""
        return self.shelves.shape[-1]


REWARD_DEFAULTS = {
    "step_penalty": -0.5,
    "obstacle_penalty": -10.0,
    "wall_penalty": 0.0,
    "shaping_coef": 2.0,
    "pickup_reward": 50.0,
    "delivery_reward": 200.0,
}
"""The reward constants of SPEC.md."""


def as_float32(value) -> jax.Array:
    return jnp.asarray(value, dtype=jnp.float32)
