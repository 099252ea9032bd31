"""``num_envs`` JAX warehouses behind Gymnasium's ``VectorEnv`` API, stepped by one jitted, vmapped call.

The packing, the builders and the reset options are :mod:`wrl_jax.wrappers.gymnasium`'s, so one
environment and many answer the same way; see :class:`WarehouseVectorEnv` for the autoreset layout.
"""

from __future__ import annotations

import functools
from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from wrl_jax.envs.warehouse.env import NUM_ACTIONS, Warehouse
from wrl_jax.envs.warehouse.layout import Layout
from wrl_jax.envs.warehouse.render import DEFAULT_CELL_SIZE, check_cell_size, render_frame
from wrl_jax.envs.warehouse.types import EnvParams, EnvState
from wrl_jax.wrappers.gymnasium import (
    INFO_FLAGS,
    RENDER_FPS,
    build_env,
    check_item_option,
    observation_space_of,
    pack,
    reset_packed,
    seed_from,
)


@functools.partial(jax.jit, static_argnums=(0, 1))
def _reset_vector(env: Warehouse, num_envs: int, key: jax.Array, item_index: jax.Array, params: EnvParams):
    """Reset ``num_envs`` environments; a negative ``item_index[i]`` draws environment i's item."""
    keys = jax.random.split(key, num_envs)
    return jax.vmap(reset_packed, in_axes=(None, 0, 0, None))(env, keys, item_index, params)


@functools.partial(jax.jit, static_argnums=0)
def _step_vector(env: Warehouse, key: jax.Array, states: EnvState, actions: jax.Array, params: EnvParams):
    """Advance every environment by one auto-resetting step.

    Returns ``(key, states, packed)``, packed ``(num_envs, 2 d + 8)``:
    ``[obs (d), final_obs (d), reward, terminated, truncated, *INFO_FLAGS, item_index]``.
    """
    key, step_key = jax.random.split(key)
    keys = jax.random.split(step_key, actions.shape[0])
    obs, states, reward, terminated, truncated, info = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
        keys, states, actions, params
    )
    flags = [info[flag] for flag in INFO_FLAGS]
    scalars = jnp.stack([reward, terminated, truncated, *flags, states.item_index], axis=-1)
    return key, states, pack(obs, info["final_obs"], scalars)


@functools.partial(jax.jit, static_argnums=1)
def _render_batch(states: EnvState, cell_size: int, params: EnvParams) -> jax.Array:
    return jax.vmap(render_frame, in_axes=(0, None, None))(states, params, cell_size)


class WarehouseVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` warehouse environments stepped by one jitted, vmapped JAX call.

    Autoreset follows Gymnasium 1.x's ``AutoresetMode.SAME_STEP`` (the JAX
    ``env.step`` resets in the same call): on a step where environment ``i``
    terminates or truncates, ``obs[i]`` already begins its next episode, and

    - ``info["final_obs"]`` is an object array with the observation the
      transition reached at ``i`` (None elsewhere), masked by ``info["_final_obs"]``;
    - ``info["final_info"]`` holds that transition's flags (each key with its
      ``_key`` mask), masked by ``info["_final_info"]``;
    - the top-level ``info`` of ``i`` is the reset's info (``item_index``),
      exactly as ``gymnasium.vector.SyncVectorEnv`` in ``SAME_STEP`` mode builds it.

    Every key comes with its ``_key`` bool mask, as in Gymnasium's vector infos.
    Arguments are those of :class:`WarehouseGymEnv` plus ``num_envs``.
    ``reset(seed=s)`` derives all item draws (including every auto-reset) from
    ``s``; ``options={"item_index": i}`` pins one item for all (a scalar) or one
    per environment (an array of ``num_envs``).
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": ["rgb_array"], "render_fps": RENDER_FPS}

    def __init__(
        self,
        num_envs: int = 1,
        name: str | None = "Warehouse-8x8-v0",
        *,
        layout: Layout | str | None = None,
        render_mode: str | None = None,
        cell_size: int = DEFAULT_CELL_SIZE,
        **overrides: Any,
    ):
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        self.env, self.params = build_env(None if layout is not None else name, layout, overrides)
        self.name = name if layout is None else None
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array' for the vector env, got {render_mode!r}")
        self.render_mode = render_mode
        self.cell_size = check_cell_size(cell_size)
        self.num_envs = int(num_envs)
        self.num_items = int(self.params.num_items)
        self.max_steps = int(self.params.max_steps)
        self.single_observation_space = observation_space_of(self.env)
        self.single_action_space = spaces.Discrete(NUM_ACTIONS)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._states: EnvState | None = None
        self._key: jax.Array | None = None

    @property
    def states(self) -> EnvState:
        """The batched JAX state (leading axis ``num_envs``)."""
        if self._states is None:
            raise gym.error.ResetNeeded("call reset() before using the vector environment")
        return self._states

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        item_index = check_item_option(options, self.num_items, (self.num_envs,))
        reset_key, self._key = jax.random.split(jax.random.key(seed_from(self.np_random)))
        self._states, packed = _reset_vector(self.env, self.num_envs, reset_key, item_index, self.params)
        packed = np.asarray(packed)
        d = self.env.obs_size
        info = {
            "item_index": packed[:, d].astype(np.int64),
            "_item_index": np.ones(self.num_envs, dtype=bool),
        }
        return packed[:, :d].copy(), info

    def step(self, actions):
        actions = self._check_actions(actions)
        if self._key is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        self._key, self._states, packed = _step_vector(self.env, self._key, self.states, actions, self.params)
        packed = np.asarray(packed)
        d = self.env.obs_size
        obs, final_obs_rows, scalars = packed[:, :d].copy(), packed[:, d : 2 * d], packed[:, 2 * d :]
        reward = scalars[:, 0].astype(np.float64)
        terminated = scalars[:, 1] != 0
        truncated = scalars[:, 2] != 0
        flags = {flag: scalars[:, 3 + k] != 0 for k, flag in enumerate(INFO_FLAGS)}
        items = scalars[:, 3 + len(INFO_FLAGS)].astype(np.int64)
        done = terminated | truncated
        alive = ~done

        # The layout of SyncVectorEnv's SAME_STEP infos (gymnasium/vector/sync_vector_env.py):
        # an environment that ended reports its final transition under final_obs/final_info and
        # its reset's info at the top level; the others report their transition's info.
        infos: dict[str, Any] = {}
        if done.any():
            final_obs = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(done):
                final_obs[i] = final_obs_rows[i].copy()
            final_info: dict[str, Any] = {}
            for flag in INFO_FLAGS:
                final_info[flag] = flags[flag] & done
                final_info[f"_{flag}"] = done.copy()
            infos.update(final_obs=final_obs, _final_obs=done.copy(), final_info=final_info, _final_info=done.copy())
            infos["item_index"] = np.where(done, items, 0)
            infos["_item_index"] = done.copy()
        if alive.any():
            for flag in INFO_FLAGS:
                infos[flag] = flags[flag] & alive
                infos[f"_{flag}"] = alive.copy()
        return obs, reward, terminated, truncated, infos

    def _check_actions(self, actions) -> np.ndarray:
        array = np.asarray(actions)
        if array.shape != (self.num_envs,):
            raise ValueError(f"actions must have shape ({self.num_envs},), one per environment, got {array.shape}")
        if array.dtype.kind not in "iu":
            raise ValueError(f"actions must be integers in 0..{NUM_ACTIONS - 1}, got dtype {array.dtype}")
        bad = np.flatnonzero((array < 0) | (array >= NUM_ACTIONS))
        if bad.size:
            raise ValueError(
                f"action {int(array[bad[0]])} of environment {int(bad[0])} is out of range: "
                f"expected 0 up, 1 down, 2 left or 3 right"
            )
        return array.astype(np.int32)

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array'")
            return None
        frames = np.asarray(_render_batch(self.states, self.cell_size, self.params))
        return tuple(frames[i] for i in range(self.num_envs))

    def __repr__(self) -> str:
        return f"WarehouseVectorEnv({self.name or 'custom layout'}, num_envs={self.num_envs})"
