"""The JAX warehouse behind the Gymnasium API: a single ``gymnasium.Env`` (the ``VectorEnv`` is
:mod:`wrl_jax.wrappers.gymnasium_vector`, on the same packing and helpers).

For users who bring a Gymnasium-based trainer (Stable-Baselines3, CleanRL, ...).
The transition is the JAX one (:class:`wrl_jax.Warehouse`), compiled once per
grid size and observation width and shared by every instance: the jitted
functions below take the environment as a static argument (``Warehouse`` hashes
by its shape configuration) and the params (layout, rewards, ``max_steps``) as
ordinary array arguments, so changing a reward constant or the layout of a
size never recompiles.

- :class:`WarehouseGymEnv`: one environment; ``step`` is the non-resetting
  ``env.transition`` (Gymnasium single environments do not auto-reset) and
  returns NumPy values: float32 observation, Python float reward, Python bools.
- :class:`~wrl_jax.wrappers.gymnasium_vector.WarehouseVectorEnv`: ``num_envs``
  environments advanced by one jitted, vmapped call of the auto-resetting ``env.step``,
  with Gymnasium 1.x's ``SAME_STEP`` autoreset convention (``final_obs`` / ``final_info``).

Importing :mod:`wrl_jax` registers ``wrl_jax/Warehouse-8x8-v0`` and
``wrl_jax/Warehouse-12x12-v0`` with both entry points, so ``gymnasium.make`` and
``gymnasium.make_vec(..., vectorization_mode="vector_entry_point")`` work.
"""

from __future__ import annotations

import functools
import importlib.util
import os
from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces

from wrl_jax.core import registry
from wrl_jax.core.registry import make
from wrl_jax.envs.warehouse.env import ACTION_NAMES, NUM_ACTIONS, Warehouse, draw_item
from wrl_jax.envs.warehouse.layout import Layout
from wrl_jax.envs.warehouse.registration import make_from_layout
from wrl_jax.envs.warehouse.render import DEFAULT_CELL_SIZE, check_cell_size, render_ascii, render_frame
from wrl_jax.envs.warehouse.types import EnvParams, EnvState
from wrl_jax.wrappers.registration import GYM_NAMESPACE, register_gymnasium_envs

INFO_FLAGS = ("collision", "wall_bump", "picked_up", "delivered")
"""Bool flags of one transition, in every step's ``info``."""


def _pygame_available() -> bool:
    return importlib.util.find_spec("pygame") is not None


# ``human`` is only offered when the optional pygame extra is installed, so that
# ``gymnasium.utils.env_checker.check_env`` (which tries every declared mode) passes without it.
_RENDER_MODES = ["rgb_array", "ansi"] + (["human"] if _pygame_available() else [])
RENDER_FPS = 8


# ----------------------------------------------------------- jitted transitions
# One cache per function, keyed on the (hashable, shape-only) Warehouse: every
# instance of a configuration shares one compiled program. Each call returns
# the new state (kept on the device) and ONE packed float32 array of what the
# host needs, because every separate device-to-host transfer costs more than the
# transition itself. All packed values are exact in float32: the float32
# observation and reward, bools as 0/1, small item indices.
def pack(*columns: jax.Array) -> jax.Array:
    """Concatenate scalars and vectors (with any leading batch axes) along the last axis as float32."""
    return jnp.concatenate([jnp.atleast_1d(column).astype(jnp.float32) for column in columns], axis=-1)


def reset_packed(env: Warehouse, key: jax.Array, item_index: jax.Array, params: EnvParams):
    """Reset to ``item_index``, or to an item drawn from ``key`` when it is negative.

    Packed: ``[obs (d), item_index]``.
    """
    drawn = draw_item(key, params)
    obs, state = env.reset_to_item(jnp.where(item_index < 0, drawn, item_index), params)
    return state, pack(obs, state.item_index[..., None])


_reset_single = functools.partial(jax.jit, static_argnums=0)(reset_packed)


@functools.partial(jax.jit, static_argnums=0)
def _step_single(env: Warehouse, state: EnvState, action: jax.Array, params: EnvParams):
    """One non-resetting transition. Packed: ``[obs (d), reward, terminated, truncated, *INFO_FLAGS]``."""
    obs, state, reward, terminated, truncated, info = env.transition(None, state, action, params)
    flags = [info[flag] for flag in INFO_FLAGS]
    return state, pack(obs, jnp.stack([reward, terminated, truncated, *flags]))


@functools.partial(jax.jit, static_argnums=1)
def _render_one(state: EnvState, cell_size: int, params: EnvParams) -> jax.Array:
    return render_frame(state, params, cell_size)


# --------------------------------------------------------------------- helpers
def build_env(name: str | None, layout: Layout | str | None, overrides: dict[str, Any]) -> tuple[Warehouse, EnvParams]:
    """``wrl_jax.make`` for a registered name, ``make_from_layout`` for a layout."""
    if layout is not None:
        if name is not None:
            raise ValueError("give either a registered name or a layout, not both")
        if "max_steps" not in overrides:
            raise ValueError("a custom layout needs max_steps (the episode length at which it is truncated)")
        env, params = make_from_layout(layout, **overrides)
    else:
        if name is None:
            raise ValueError("give a registered name (e.g. 'Warehouse-8x8-v0') or a layout")
        if name.startswith(GYM_NAMESPACE + "/"):
            name = name[len(GYM_NAMESPACE) + 1 :]
        family = registry.entry(name).family
        if family != "warehouse":
            raise ValueError(f"{name!r} is a {family} environment; the Gymnasium adapter serves the single robot")
        env, params = make(name, **overrides)
    # The jitted functions below take the env as a static argument and params
    # explicitly: without default params, one compilation serves every layout.
    return env.without_default_params(), params


def observation_space_of(env: Warehouse) -> spaces.Box:
    # The lowest value is the "picked up" item coordinate -1/(N-1), taken from
    # the environment's own exact table so the bound equals it to the bit.
    low = float(env._coordinate_table[0])
    return spaces.Box(low=low, high=1.0, shape=(env.obs_size,), dtype=np.float32)


def seed_from(rng: np.random.Generator) -> int:
    """A JAX PRNG seed drawn from a Gymnasium generator (so it derives from the reset seed)."""
    return int(rng.integers(0, 2**32, dtype=np.uint64))


def _check_single_action(action: Any) -> int:
    array = np.asarray(action)
    if array.ndim != 0:
        raise ValueError(
            f"action must be a scalar integer in 0..{NUM_ACTIONS - 1}, got an array of shape {array.shape}"
        )
    if array.dtype.kind not in "iu":
        raise ValueError(f"action must be an integer in 0..{NUM_ACTIONS - 1} {ACTION_NAMES}, got {action!r}")
    value = int(array)
    if not 0 <= value < NUM_ACTIONS:
        raise ValueError(
            f"action {value} is out of range: expected 0 up, 1 down, 2 left or 3 right (Discrete({NUM_ACTIONS}))"
        )
    return value


def check_item_option(options: dict[str, Any] | None, num_items: int, shape: tuple[int, ...]) -> np.ndarray:
    """The ``options["item_index"]`` of a reset as an int32 array of ``shape`` (-1: draw it)."""
    options = {} if options is None else options
    if not isinstance(options, dict):
        raise ValueError(f"options must be a dict, got {type(options).__name__}")
    unknown = sorted(set(options) - {"item_index"})
    if unknown:
        raise ValueError(f"unknown reset option(s) {unknown}; the only option is 'item_index'")
    value = options.get("item_index")
    if value is None:
        return np.full(shape, -1, dtype=np.int32)
    array = np.asarray(value)
    if array.dtype.kind not in "iu":
        raise ValueError(f"item_index must be an integer, got {value!r}")
    if array.ndim != 0 and array.shape != shape:
        raise ValueError(f"item_index must be a scalar or have shape {shape}, got shape {array.shape}")
    if np.any((array < 0) | (array >= num_items)):
        raise ValueError(f"item_index {value!r} is out of range: the layout has {num_items} items (0..{num_items - 1})")
    return np.broadcast_to(array, shape).astype(np.int32)


# ------------------------------------------------------------------ single env
class WarehouseGymEnv(gym.Env):
    """One warehouse environment with the Gymnasium API, backed by the jitted JAX transition.

    Args:
        name: a registered name (``"Warehouse-8x8-v0"``, ``"Warehouse-12x12-v0"``, with or
            without the ``wrl_jax/`` namespace); ignored when ``layout`` is given.
        layout: a :class:`wrl_jax.Layout` or an ASCII map instead of a registered name
            (then ``max_steps`` is required).
        render_mode: ``"rgb_array"`` (an RGB ``uint8`` frame), ``"ansi"`` (a text map), or
            ``"human"`` (a pygame window; needs the optional ``pygame`` extra).
        cell_size: pixels per grid cell of the rendered frames.
        **overrides: as for :func:`wrl_jax.make`: reward constants (``step_penalty``,
            ``obstacle_penalty``, ``wall_penalty``, ``shaping_coef``, ``pickup_reward``,
            ``delivery_reward``), ``max_steps``, ``observe_carrying``, ``collision_bug``.

    The episode limit is the environment's own ``max_steps`` (it sets ``truncated``);
    the Gymnasium registration declares no ``max_episode_steps``, so no second
    ``TimeLimit`` wrapper disagrees with it.

    ``reset(seed=..., options={"item_index": i})`` pins the item; without the
    option the item is drawn from a JAX key derived from the seed. Each step's
    ``info`` holds the transition's bool flags ``collision``, ``wall_bump``,
    ``picked_up``, ``delivered``; ``reset``'s ``info`` holds ``item_index``.
    """

    metadata = {"render_modes": _RENDER_MODES, "render_fps": RENDER_FPS}

    def __init__(
        self,
        name: str | None = "Warehouse-8x8-v0",
        *,
        layout: Layout | str | None = None,
        render_mode: str | None = None,
        cell_size: int = DEFAULT_CELL_SIZE,
        **overrides: Any,
    ):
        self.env, self.params = build_env(None if layout is not None else name, layout, overrides)
        self.name = name if layout is None else None
        if render_mode is not None and render_mode not in ("rgb_array", "ansi", "human"):
            raise ValueError(f"render_mode must be None, 'rgb_array', 'ansi' or 'human', got {render_mode!r}")
        if render_mode == "human" and not _pygame_available():
            raise gym.error.DependencyNotInstalled(
                "render_mode='human' needs pygame: pip install 'wrl_jax[pygame]' "
                "(or use render_mode='rgb_array' and save frames with wrl_jax.envs.warehouse.render.save_gif)"
            )
        self.render_mode = render_mode
        self.cell_size = check_cell_size(cell_size)
        self.observation_space = observation_space_of(self.env)
        self.action_space = spaces.Discrete(NUM_ACTIONS)
        self.num_items = int(self.params.num_items)
        self.max_steps = int(self.params.max_steps)
        self._state: EnvState | None = None
        self._window = None
        self._clock = None

    @property
    def state(self) -> EnvState:
        """The JAX state of the current episode (call ``reset`` first)."""
        if self._state is None:
            raise gym.error.ResetNeeded("call reset() before using the environment")
        return self._state

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        item_index = check_item_option(options, self.num_items, ())
        # Drawn on every reset, pinned or not, so the n-th reset after a seed always sees the same key.
        key = jax.random.key(seed_from(self.np_random))
        self._state, packed = _reset_single(self.env, key, item_index, self.params)
        packed = np.asarray(packed)
        if self.render_mode == "human":
            self._render_human()
        d = self.env.obs_size
        return packed[:d].copy(), {"item_index": int(packed[d])}

    def step(self, action):
        action = _check_single_action(action)
        self._state, packed = _step_single(self.env, self.state, np.int32(action), self.params)
        packed = np.asarray(packed)
        if self.render_mode == "human":
            self._render_human()
        d = self.env.obs_size
        reward, terminated, truncated, *flags = packed[d:].tolist()
        info = {flag: bool(value) for flag, value in zip(INFO_FLAGS, flags, strict=True)}
        return packed[:d].copy(), float(reward), bool(terminated), bool(truncated), info

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'ansi'")
            return None
        if self.render_mode == "ansi":
            return render_ascii(self.state, self.params)
        if self.render_mode == "rgb_array":
            return np.array(_render_one(self.state, self.cell_size, self.params))
        self._render_human()
        return None

    def _render_human(self) -> None:
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        import pygame  # optional extra: imported only when a window is asked for

        frame = np.asarray(_render_one(self.state, self.cell_size, self.params))
        if self._window is None:
            pygame.display.init()  # the display only: no audio device needed
            pygame.display.set_caption(f"wrl_jax {self.name or 'warehouse'}")
            self._window = pygame.display.set_mode((frame.shape[1], frame.shape[0]))
            self._clock = pygame.time.Clock()
        pygame.event.pump()
        self._window.blit(pygame.surfarray.make_surface(frame.swapaxes(0, 1)), (0, 0))
        pygame.display.flip()
        self._clock.tick(self.metadata["render_fps"])

    def close(self) -> None:
        if self._window is not None:
            import pygame

            pygame.display.quit()
            self._window = None
            self._clock = None

    def __repr__(self) -> str:
        return f"WarehouseGymEnv({self.name or 'custom layout'}, size={self.env.size}, obs={self.env.obs_size})"


GYM_IDS = register_gymnasium_envs()
