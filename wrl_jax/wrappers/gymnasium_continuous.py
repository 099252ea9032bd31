"""The continuous warehouse behind the Gymnasium API: ``gymnasium.make("wrl_jax/Continuous-Warehouse-12x12-v0")``.

For trainers that bring their own loop (Stable-Baselines3's SAC, CleanRL...). The transition is the
JAX one (:class:`~wrl_jax.envs.continuous.env.ContinuousWarehouse`), compiled once per configuration
and shared by every instance (the environment is a static argument, the params ordinary arrays).
A Gymnasium single environment does not auto-reset, so ``step`` is the non-resetting transition.

Randomness: ``reset(seed=s)`` starts a JAX key from ``s`` (or from Gymnasium's ``np_random`` when
no seed is given); the reset and every step split it, so an episode is a function of its seed and
its actions, and the same key sequence through :meth:`ContinuousWarehouse.transition` gives the same
numbers (``tests/wrappers/test_gymnasium_continuous.py``).

``render_mode="rgb_array"``: ``render()`` draws the current state with the lidar of the last observation
(:func:`wrl_jax.envs.continuous.render.render_frame`), one compiled call per frame.
"""

from __future__ import annotations

import functools
from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces

from wrl_jax.core import registry
from wrl_jax.envs.continuous.dynamics import FLAGS
from wrl_jax.envs.continuous.env import ContinuousWarehouse
from wrl_jax.envs.continuous.render import DEFAULT_CELL_SIZE, check_render_cell_size, lidar_from_obs, render_frame
from wrl_jax.envs.continuous.types import ContinuousParams


@functools.partial(jax.jit, static_argnums=0)
def _reset(env: ContinuousWarehouse, key: jax.Array, params: ContinuousParams):
    key, reset_key = jax.random.split(key)
    obs, state = env.reset_env(reset_key, params)
    return key, obs, state


@functools.partial(jax.jit, static_argnums=0)
def _step(env: ContinuousWarehouse, key: jax.Array, state: Any, action: jax.Array, params: ContinuousParams):
    key, step_key = jax.random.split(key)
    obs, state, reward, terminated, truncated, info = env.transition(step_key, state, action, params)
    flags = jnp.stack([info[name] for name in FLAGS])
    return key, obs, state, reward, terminated, truncated, flags


@functools.partial(jax.jit, static_argnums=(0, 1))
def _render(cell_size: int, num_rays: int, state: Any, obs: jax.Array, params: ContinuousParams) -> jax.Array:
    return render_frame(state, params, lidar_from_obs(obs, params, num_rays), cell_size)


class ContinuousGymEnv(gym.Env):
    """One continuous warehouse as a ``gymnasium.Env`` (float32 observations, ``Box(-1, 1, (2,))`` actions).

    Args:
        name: a registered continuous environment (``Continuous-Warehouse-12x12-Dynamic-v0``...).
        render_mode: None or ``"rgb_array"`` (``render()`` returns a ``uint8 (H, W, 3)`` frame).
        cell_size: pixels per metre of the rendered frames.
        **overrides: the family's overrides (``randomize=True``, ``max_steps``...), as ``wrl_jax.make``.

    ``info`` holds the contract's flags as Python bools (``collision``, ``picked_up``, ``delivered``...).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}  # 5 steps per second: dt = 0.2 s, real time

    def __init__(self, name: str = "Continuous-Warehouse-12x12-v0", render_mode: str | None = None,
                 cell_size: int = DEFAULT_CELL_SIZE, **overrides: Any):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.cell_size = check_render_cell_size(cell_size)
        if registry.entry(name).family != "continuous":
            raise ValueError(f"{name} is not a continuous warehouse; ContinuousGymEnv takes one of "
                             f"{registry.registered_names('continuous')}")
        self.jax_env, self.params = registry.make(name, **overrides)
        # The programs' static argument: equal for every layout and parameter value of this configuration, so
        # environments that differ only in params (randomize, max_steps...) share the compiled reset and step.
        self._static_env = self.jax_env.without_default_params()
        space = self.jax_env.observation_space(self.params)
        self.observation_space = spaces.Box(low=np.asarray(space.low, np.float32), high=np.asarray(space.high, np.float32),
                                            shape=space.shape, dtype=np.float32)
        self.action_space = spaces.Box(low=-1.0, high=1.0, shape=(2,), dtype=np.float32)
        self._key = None
        self._state = None
        self._obs = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        start = seed if seed is not None else int(self.np_random.integers(0, 2**31 - 1))
        self._key, obs, self._state = _reset(self._static_env, jax.random.key(start), self.params)
        self._obs = obs
        return np.asarray(obs, np.float32), {}

    def step(self, action: Any):
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        action = np.asarray(action)
        if action.shape != (2,) or not (np.issubdtype(action.dtype, np.floating) or np.issubdtype(action.dtype, np.integer)):
            raise ValueError(f"action must be 2 numbers (v, w) in [-1, 1], got shape {action.shape} dtype {action.dtype}")
        self._key, obs, self._state, reward, terminated, truncated, flags = _step(
            self._static_env, self._key, self._state, jnp.asarray(action, jnp.float32), self.params)
        self._obs = obs
        info = {name: bool(flag) for name, flag in zip(FLAGS, np.asarray(flags))}
        return np.asarray(obs, np.float32), float(reward), bool(terminated), bool(truncated), info

    def render(self):
        """The current state as an RGB frame (``render_mode="rgb_array"``), the last observation's lidar drawn."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array'")
            return None
        if self._state is None:
            raise RuntimeError("call reset() before render()")
        return np.array(_render(self.cell_size, self.jax_env.num_rays, self._state, self._obs, self.params))
