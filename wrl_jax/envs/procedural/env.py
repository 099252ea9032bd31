"""The single-robot pick-and-place MDP of SPEC.md on a per-environment layout drawn from a pool.

Dynamics, rewards, truncation and info flags are SPEC.md's (the study's
warehouse, :mod:`wrl_jax.env`), with Manhattan shaping and no collision-bug
switch. What differs is where the layout comes from and what is observed:

- ``reset`` draws a slot of the :class:`~wrl_jax.envs.procedural.pool.LayoutPool`
  in params (one 32-bit word) and an item of that layout (another word),
  copies the layout's floor into the state and gathers the episode's first
  observation, precomputed with the pool (``params.reset_obs``). The copy costs an ``(H, W)`` bool
  per environment, and buys two things: a pool refresh between updates never
  changes the floor of an episode in flight, and a step reads its own floor
  without a gather from the pool.
- A layout smaller than the padded shape has off-grid cells around it: a move
  onto one is a wall bump (no obstacle penalty), exactly like a move off the grid.
- The observation is FLEET_SPEC.md's robot observation for one robot
  (:func:`wrl_jax.core.observation.robot_observations` with ``K = 1``): the
  robot's and target's cells divided by ``N - 1`` (``N`` the larger side of
  the padded shape, the same for every layout), the carrying flag, then the
  egocentric window (shelves and off-grid, other robots (always empty here),
  the current target). ``observe_map=True`` appends the full padded map in
  the same three channels. No distance field or planner output is observed.
- The state carries the episode's BFS optimum (``optimal``) for evaluation.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct
from gymnax.environments import spaces

from wrl_jax.core.environment import Environment
from wrl_jax.core.grid import MOVES
from wrl_jax.core.observation import coordinate_table, observation_size, robot_observations
from wrl_jax.envs.procedural.generators import GeneratorConfig
from wrl_jax.envs.procedural.pool import LayoutPool, refresh_pool
from wrl_jax.envs.warehouse.env import check_action, item_from_word, spec_reward

NUM_ACTIONS = 4
MAX_POOL_SIZE = 2**16 - 1
"""Slot bound of the 32-bit slot draw (:func:`wrl_jax.env.item_from_word`)."""


@struct.dataclass
class ProceduralParams:
    """The layout pool, its reset observations, episode length and SPEC.md's six reward constants (all arrays).

    ``reset_obs`` ``(P, I, obs_size)`` is the first observation of every
    (slot, item) episode, computed with the pool (:meth:`ProceduralWarehouse.with_pool`):
    the auto-reset of every step then gathers it instead of computing a second
    egocentric window per environment, which measured the largest cost of a
    step (docs/procedural.md).
    """

    pool: LayoutPool
    reset_obs: jax.Array
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
    """One episode. ``blocked`` ``(H, W)`` is this episode's floor (shelves and off-grid), a copy from the pool."""

    blocked: jax.Array
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


class ProceduralWarehouse(Environment[ProceduralState, ProceduralParams]):
    """SPEC.md's pick-and-place on layouts drawn at reset from a pool of generated warehouses.

    Args:
        default_params: params with a pool of ``pool_size`` layouts of the
            generator's shape (``registration.make_procedural`` builds them).
        generator: the generator whose layouts the pool holds (fixes the
            padded shape and item capacity; :meth:`refresh_pool` draws from it).
        pool_size: slots of the pool (static).
        view_radius: ``V`` of the egocentric window.
        observe_map: append the full padded map (3 channels) to the observation.
        observe_window: ``False`` keeps only the five scalars of the robot
            observation (no window): not a generalizing observation, but it
            isolates the cost of per-environment layouts from the window's in
            bench/procedural_throughput.py.
    """

    num_actions = NUM_ACTIONS
    family = "procedural"

    def __init__(self, default_params: ProceduralParams | None = None, *, generator: GeneratorConfig,
                 pool_size: int, view_radius: int = 2, observe_map: bool = False, observe_window: bool = True):
        if not 1 <= int(pool_size) <= MAX_POOL_SIZE:
            raise ValueError(f"pool_size must be in 1..{MAX_POOL_SIZE}, got {pool_size}")
        if int(view_radius) < 0:
            raise ValueError(f"view_radius must be non-negative, got {view_radius}")
        self.generator = generator
        self.pool_size = int(pool_size)
        self.view_radius = int(view_radius)
        self.observe_map = bool(observe_map)
        self.observe_window = bool(observe_window)
        if default_params is not None:
            self.check_params(default_params)
        super().__init__(default_params)

    @property
    def name(self) -> str:
        return "Procedural-Warehouse-v0"

    @property
    def max_shape(self) -> tuple[int, int]:
        return tuple(self.generator.max_shape)

    def static_config(self) -> tuple:
        return (self.generator, self.pool_size, self.view_radius, self.observe_map, self.observe_window)

    def __repr__(self) -> str:
        return (f"ProceduralWarehouse(max_shape={self.max_shape}, pool_size={self.pool_size}, "
                f"view_radius={self.view_radius}, observe_map={self.observe_map}, "
                f"observe_window={self.observe_window}, family={self.generator.family!r})")

    def check_params(self, params: ProceduralParams) -> None:
        """``ValueError`` unless the params' pool and reset observations fit this environment's static shapes."""
        blocked = params.pool.layouts.blocked
        expected = (self.pool_size, *self.max_shape)
        if tuple(blocked.shape[-3:]) != expected or params.pool.layouts.items.shape[-2] != self.generator.max_items:
            raise ValueError(
                f"params hold a pool of shape {tuple(blocked.shape)} with {params.pool.layouts.items.shape[-2]} "
                f"item slots; this environment expects {expected} with {self.generator.max_items}"
            )
        expected_obs = (self.pool_size, self.generator.max_items, self.obs_size)
        if tuple(params.reset_obs.shape) != expected_obs:
            raise ValueError(f"params.reset_obs has shape {tuple(params.reset_obs.shape)}, expected {expected_obs} "
                             f"(build params with registration.make_params or env.with_pool)")

    # ------------------------------------------------------------ spaces
    @property
    def obs_size(self) -> int:
        extra = 3 * self.max_shape[0] * self.max_shape[1] if self.observe_map else 0
        return (observation_size(self.view_radius) if self.observe_window else 5) + extra

    def observation_space(self, params: ProceduralParams | None = None) -> spaces.Box:
        return spaces.Box(0.0, 1.0, (self.obs_size,), jnp.float32)

    def action_space(self, params: ProceduralParams | None = None) -> spaces.Discrete:
        return spaces.Discrete(NUM_ACTIONS)

    # ------------------------------------------------------------ reset
    def reset_env(self, key: jax.Array, params: ProceduralParams) -> tuple[jax.Array, ProceduralState]:
        """A fresh episode on a uniformly drawn pool slot, with a uniformly drawn item of that layout."""
        words = jax.random.bits(key, (2,), jnp.uint32)
        layout_index = item_from_word(words[0], jnp.int32(self.pool_size))
        item_index = item_from_word(words[1], params.pool.layouts.num_items[layout_index])
        state = initial_state(layout_index, item_index, params.pool)
        return params.reset_obs[layout_index, item_index], state

    def reset_to(self, layout_index: jax.Array | int, item_index: jax.Array | int,
                 params: ProceduralParams | None = None) -> tuple[jax.Array, ProceduralState]:
        """A fresh episode on a chosen slot and item (deterministic evaluation)."""
        params = self.default_params if params is None else params
        state = initial_state(jnp.asarray(layout_index, jnp.int32), jnp.asarray(item_index, jnp.int32), params.pool)
        return self.observe(state), state

    # ------------------------------------------------------------ step
    def step(self, key: jax.Array, state: ProceduralState, action: Any,
             params: ProceduralParams | None = None):
        """The base class's ``step`` (transition, then auto-reset), with the reset drawn from ``key`` itself.

        The transition is deterministic and uses no key, so the base's key
        split (a threefry call per environment per step) is skipped.
        """
        params = self.default_params if params is None else params
        obs, reached, reward, terminated, truncated, info = self.transition(key, state, action, params)
        reset_obs, reset_state = self.reset_env(key, params)
        done = terminated | truncated
        next_state = jax.tree.map(lambda fresh, cont: jnp.where(done, fresh, cont), reset_state, reached)
        info = {**info, "final_obs": obs, "final_observation": obs}
        return jnp.where(done, reset_obs, obs), next_state, reward, terminated, truncated, info

    def transition(self, key: jax.Array, state: ProceduralState, action: Any, params: ProceduralParams):
        """One SPEC.md transition, no reset; ``info``: ``collision``, ``wall_bump``, ``picked_up``, ``delivered``.

        ``key`` is unused (nothing is drawn); pass ``None``.
        """
        del key
        if not isinstance(action, jax.core.Tracer):
            check_action(action)
        action = jnp.asarray(action, dtype=jnp.int32)
        pos = state.pos
        proposed = pos + jnp.asarray(MOVES)[action]
        limit = jnp.stack([state.height, state.width]) - 1
        on_floor = jnp.all((proposed >= 0) & (proposed <= limit))
        wall_bump = ~on_floor
        # Off the floor, the clipped cell is the robot's own cell (one coordinate moved by one).
        clipped = jnp.clip(proposed, 0, limit)
        collision = on_floor & state.blocked[clipped[0], clipped[1]]
        next_pos = jnp.where(collision, pos, clipped)

        reward, picked_up, delivered = spec_reward(
            params, pos, next_pos, state.carrying, state.item_pos, state.goal, collision, wall_bump
        )

        time = state.time + 1
        terminated = delivered
        truncated = (time >= params.max_steps) & ~terminated
        next_state = state.replace(pos=next_pos, carrying=state.carrying | picked_up, time=time)
        info = {"collision": collision, "wall_bump": wall_bump, "picked_up": picked_up, "delivered": delivered}
        return self.observe(next_state), next_state, reward, terminated, truncated, info

    def is_terminated(self, state: ProceduralState, params: ProceduralParams) -> jax.Array:
        return state.carrying & jnp.all(state.pos == state.goal)

    def is_truncated(self, state: ProceduralState, params: ProceduralParams) -> jax.Array:
        return state.time >= params.max_steps

    # ------------------------------------------------------------ observation
    def observe(self, state: ProceduralState) -> jax.Array:
        """``(obs_size,)`` float32: the fleet robot observation for one robot, then the map if configured.

        The map's channels: 0 shelves and off-grid, 1 the robot itself (the
        window has it at its centre; a full map must say where), 2 the target.
        """
        target = jnp.where(state.carrying, state.goal, state.item_pos)
        size = max(self.max_shape)
        if self.observe_window:
            obs = robot_observations(state.blocked, state.pos[None], target[None], state.carrying[None],
                                     self.view_radius, size)[0]
        else:
            table = jnp.asarray(coordinate_table(size))
            obs = jnp.concatenate([table[state.pos], table[target], state.carrying.astype(jnp.float32)[None]])
        if not self.observe_map:
            return obs
        rows = jnp.arange(self.max_shape[0])[:, None]
        cols = jnp.arange(self.max_shape[1])[None, :]
        robot = (rows == state.pos[0]) & (cols == state.pos[1])
        target_cell = (rows == target[0]) & (cols == target[1])
        full_map = jnp.stack([state.blocked, robot, target_cell]).astype(jnp.float32)
        return jnp.concatenate([obs, full_map.reshape(-1)])

    # ------------------------------------------------------------ pool
    def reset_observations(self, pool: LayoutPool) -> jax.Array:
        """``(P, I, obs_size)``: :meth:`observe` of the first state of every (slot, item) episode."""
        slots = jnp.arange(pool.size, dtype=jnp.int32)[:, None]
        items = jnp.arange(pool.layouts.items.shape[-2], dtype=jnp.int32)[None, :]
        slots, items = jnp.broadcast_arrays(slots, items)
        first = jax.vmap(jax.vmap(initial_state, in_axes=(0, 0, None)), in_axes=(0, 0, None))(slots, items, pool)
        return jax.vmap(jax.vmap(self.observe))(first)

    def with_pool(self, params: ProceduralParams, pool: LayoutPool) -> ProceduralParams:
        """``params`` serving ``pool`` (its reset observations recomputed)."""
        return params.replace(pool=pool, reset_obs=_reset_observations(self, pool))

    def refresh_pool(self, key: jax.Array, params: ProceduralParams, count: int | None = None) -> ProceduralParams:
        """Params with the pool (or ``count`` slots of it) regenerated from ``key``; call between updates."""
        return self.with_pool(params, refresh_pool(key, params.pool, self.generator, count))

    def optimal_steps(self, state: ProceduralState) -> jax.Array:
        """The BFS optimum of the episode ``state`` belongs to (the yardstick of an evaluation)."""
        return state.optimal


def initial_state(layout_index: jax.Array, item_index: jax.Array, pool: LayoutPool) -> ProceduralState:
    """The first state of the episode on pool slot ``layout_index`` with its item ``item_index``."""
    layout = jax.tree.map(lambda leaf: leaf[layout_index], pool.layouts)
    return ProceduralState(
        blocked=layout.blocked,
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
    )


@partial(jax.jit, static_argnums=0)
def _reset_observations(env: ProceduralWarehouse, pool: LayoutPool) -> jax.Array:
    return env.reset_observations(pool)
