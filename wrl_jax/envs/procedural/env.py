"""The single-robot pick-and-place MDP of SPEC.md on a per-environment layout drawn from a pool.

Dynamics, rewards, truncation and info flags are SPEC.md's (the study's
warehouse, :mod:`wrl_jax.envs.warehouse.env`), with Manhattan shaping and no collision-bug
switch. What differs is where the layout comes from and what is observed:

- ``reset`` draws a slot of the :class:`~wrl_jax.envs.procedural.pool.LayoutPool`
  in params (one 32-bit word) and an item of that layout (another word),
  copies the layout's floor into the state and gathers the episode's first
  observation, precomputed with the pool (``params.reset_obs``). The floor is
  copied as its walled rows packed in uint32 words (``params.walls``, also
  precomputed per layout: 80 bytes at 16x16, ``V = 2``), and the copy buys two
  things: a pool refresh between updates never changes the floor of an
  episode in flight, and a step reads its own floor without a gather from the pool.
- A layout smaller than the padded shape has off-grid cells around it: a move
  onto one is a wall bump (no obstacle penalty), exactly like a move off the grid.
- The observation is FLEET_SPEC.md's robot observation for one robot
  (:func:`wrl_jax.core.observation.robot_observations` with ``K = 1``): the
  robot's and target's cells divided by ``N - 1`` (``N`` the larger side of
  the padded shape, the same for every layout), the carrying flag, then the
  egocentric window (shelves and off-grid, other robots (always empty here),
  the current target). ``observe_map=True`` appends the full padded map in
  the same three channels. No distance field or planner output is observed.
  ``observe_last_action=True`` appends the robot's own previous action, one-hot
  (four zeros on an episode's first step): a one-step memory that lets a
  feed-forward policy tell where it came from, so that a greedy policy need not
  repeat the two-cell back-and-forth a memoryless one falls into (docs/procedural.md).
  ``observe_visited=True`` appends a fourth window channel: 1.0 on the cells the
  robot stood on since its current target was set (the episode's start, or the
  pickup), kept as packed rows like the floor's (``state.visited``): memory of
  any loop, not only a two-cell one. With ``visit_levels = L > 1`` the channel
  counts the visits to each cell up to ``L`` (value ``min(count, L) / L``): the
  trail of a loop then changes on every lap, so a deterministic policy that
  meets it again is not bound to repeat itself.
  For ``V <= 2`` (and walled rows of at most 32 cells) the window is computed
  from the packed rows as int32 bit masks (:func:`wrl_jax.core.observation.pack_window_rows`,
  then the fleet's :func:`~wrl_jax.core.observation.expand_observations`), bit for bit
  the same observation, many times cheaper under ``vmap`` than the gathers; for larger
  ``V`` (walled rows still of at most 32 cells) the window's rows are read from the
  packed rows and expanded (:func:`~wrl_jax.core.observation.row_window_observation`).
- The state carries the episode's BFS optimum (``optimal``) for evaluation.
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.core.environment import Environment
from wrl_jax.core.gymnax_base import spaces
from wrl_jax.core.observation import (
    RAY_DIRECTIONS,
    observation_size,
    wall_bit,
    wall_words,
    window_size,
)
from wrl_jax.envs.procedural.episode import draw_episode, initial_state
from wrl_jax.envs.procedural.generators import GeneratorConfig
from wrl_jax.envs.procedural.observation import ProceduralObservation, count_visit
from wrl_jax.envs.procedural.pool_params import PoolParams
from wrl_jax.envs.procedural.types import (
    MAX_POOL_SIZE,
    MAX_VISIT_LEVELS,
    NUM_ACTIONS,
    SHAPINGS,
    ProceduralParams,
    ProceduralState,
)
from wrl_jax.envs.warehouse.env import check_action, spec_reward


class ProceduralWarehouse(ProceduralObservation, PoolParams, Environment[ProceduralState, ProceduralParams]):
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
        pool_seed: the seed the initial pool was generated from (``None``: a pool of
            given layouts); refreshes draw from the same seed's training stream.
        pool_refresh: slots of the pool a learner renews before every update
            (:meth:`params_for_update`; 0: the pool never changes while training).
        observe_last_action: append the previous action, one-hot (zeros on an episode's
            first step), after the robot observation (and before the map, if observed).
        observe_visited: append the window's cells visited since the current target was set
            (``(2V+1)^2`` values, after the previous action); needs the packed-row window
            (padded width at most ``32 - 2V``).
        visit_levels: with ``observe_visited``, count visits to each cell up to this many
            (the channel's value ``min(count, L) / L``); 1 marks a cell stood on or not.
        observe_rays: append the free runs from the robot's cell up, down, left and right
            (:func:`~wrl_jax.core.observation.free_runs`, divided by ``N - 1``): a range sensor,
            4 values after the trail (and before the map, if observed).
        shaping: the distance ``d`` of the reward's shaping term ``shaping_coef (d(pos) - d(pos'))``:
            ``"manhattan"`` (SPEC.md's, the default) or ``"bfs"``, the shortest path on the episode's
            floor (FLEET_SPEC.md's default). A training signal only: the BFS tables live in params
            (``params.distances``) and nothing of them is observed, so a policy trained with them still
            sees only its window. Not with ``pool_refresh`` (a refresh would swap the tables of a slot
            under the episodes running on it).
    """

    num_actions = NUM_ACTIONS
    family = "procedural"
    event_metrics = MappingProxyType({"collision": "collisions_sum"})  # training moves into shelves

    def __init__(self, default_params: ProceduralParams | None = None, *, generator: GeneratorConfig,
                 pool_size: int, view_radius: int = 2, observe_map: bool = False, observe_window: bool = True,
                 pool_seed: int | None = None, pool_refresh: int = 0, observe_last_action: bool = False,
                 observe_visited: bool = False, visit_levels: int = 1, observe_rays: bool = False,
                 shaping: str = "manhattan"):
        if not 1 <= int(pool_size) <= MAX_POOL_SIZE:
            raise ValueError(f"pool_size must be in 1..{MAX_POOL_SIZE}, got {pool_size}")
        if not 0 <= int(pool_refresh) <= int(pool_size):
            raise ValueError(f"pool_refresh must be in 0..pool_size={pool_size} slots per update, got {pool_refresh}")
        if int(pool_refresh) and pool_seed is None:
            raise ValueError("pool_refresh needs a generated pool (its seed): a pool of given layouts is not refreshed")
        if int(view_radius) < 0:
            raise ValueError(f"view_radius must be non-negative, got {view_radius}")
        if shaping not in SHAPINGS:
            raise ValueError(f"shaping must be one of {SHAPINGS}, got {shaping!r}")
        if shaping == "bfs" and int(pool_refresh):
            raise ValueError("shaping='bfs' reads each pool slot's distance tables, which pool_refresh would replace "
                             "under the episodes running on the slot: use pool_refresh=0 (or Manhattan shaping)")
        if shaping == "bfs" and generator.max_shape[0] * generator.max_shape[1] > np.iinfo(np.int16).max:
            raise ValueError(f"shaping='bfs' keeps int16 distance tables: max_shape {generator.max_shape} has more "
                             f"than {np.iinfo(np.int16).max} cells")
        self.shaping = shaping
        self.generator = generator
        self.pool_size = int(pool_size)
        self.view_radius = int(view_radius)
        self.observe_map = bool(observe_map)
        self.observe_window = bool(observe_window)
        self.pool_seed = None if pool_seed is None else int(pool_seed)
        self.pool_refresh = int(pool_refresh)
        self.observe_last_action = bool(observe_last_action)
        self.observe_visited = bool(observe_visited)
        self.visit_levels = int(visit_levels)
        self.observe_rays = bool(observe_rays)
        if not 1 <= self.visit_levels <= MAX_VISIT_LEVELS:
            raise ValueError(f"visit_levels must be in 1..{MAX_VISIT_LEVELS}, got {visit_levels}")
        if self.visit_levels > 1 and not self.observe_visited:
            raise ValueError(f"visit_levels={self.visit_levels} counts the visits of the trail channel: it needs "
                             f"observe_visited=True (without the trail, pass --visit-levels 1 with "
                             f"--observe-visited False)")
        if self.observe_visited and not (self.observe_window and self.row_windows):
            raise ValueError(f"observe_visited needs the packed-row window: a padded width of at most "
                             f"{32 - 2 * self.view_radius} at view_radius={self.view_radius} (walled rows of one "
                             f"32-bit word); got max_shape={self.max_shape}, observe_window={self.observe_window}")
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
        return (self.generator, self.pool_size, self.view_radius, self.observe_map, self.observe_window,
                self.pool_seed, self.pool_refresh, self.observe_last_action, self.observe_visited, self.visit_levels,
                self.observe_rays, self.shaping)

    def __repr__(self) -> str:
        return (f"ProceduralWarehouse(max_shape={self.max_shape}, pool_size={self.pool_size}, "
                f"view_radius={self.view_radius}, observe_map={self.observe_map}, "
                f"observe_window={self.observe_window}, pool_refresh={self.pool_refresh}, "
                f"observe_last_action={self.observe_last_action}, observe_visited={self.observe_visited}, "
                f"visit_levels={self.visit_levels}, observe_rays={self.observe_rays}, shaping={self.shaping!r}, "
                f"family={self.generator.family!r})")

    def check_params(self, params: ProceduralParams) -> None:
        """``ValueError`` unless the params' pool and reset observations fit this environment's static shapes."""
        blocked = params.pool.layouts.blocked
        expected = (self.pool_size, *self.max_shape)
        if tuple(blocked.shape[-3:]) != expected or params.pool.layouts.items.shape[-2] != self.generator.max_items:
            raise ValueError(
                f"params hold a pool of shape {tuple(blocked.shape)} with {params.pool.layouts.items.shape[-2]} "
                f"item slots; this environment expects {expected} with {self.generator.max_items}"
            )
        expected_walls = (self.pool_size, self.max_shape[0] + 2 * self.view_radius,
                          wall_words(self.max_shape[1], self.view_radius))
        if tuple(params.walls.shape) != expected_walls:
            raise ValueError(f"params.walls has shape {tuple(params.walls.shape)}, expected {expected_walls} "
                             f"(build params with registration.make_params or env.with_pool)")
        expected_obs = (self.pool_size, self.generator.max_items, self.obs_size)
        if tuple(params.reset_obs.shape) != expected_obs:
            raise ValueError(f"params.reset_obs has shape {tuple(params.reset_obs.shape)}, expected {expected_obs} "
                             f"(build params with registration.make_params or env.with_pool)")
        expected_distances = (self.pool_size, self.distance_rows, *self.max_shape)
        if tuple(params.distances.shape) != expected_distances:
            raise ValueError(f"params.distances has shape {tuple(params.distances.shape)}, expected "
                             f"{expected_distances} for shaping={self.shaping!r} (build params with "
                             f"registration.make_params or env.with_pool)")

    # ------------------------------------------------------------ spaces
    @property
    def obs_size(self) -> int:
        extra = 3 * self.max_shape[0] * self.max_shape[1] if self.observe_map else 0
        extra += NUM_ACTIONS if self.observe_last_action else 0
        extra += window_size(self.view_radius) ** 2 if self.observe_visited else 0
        extra += RAY_DIRECTIONS if self.observe_rays else 0
        return (observation_size(self.view_radius) if self.observe_window else 5) + extra

    def map_observation(self) -> tuple[int, int, int] | None:
        """``(offset, H, W)``: where the full map sits in the observation (3 channels of ``H x W``,
        channel-major: blocked, the robot, the target), ``None`` without ``observe_map``. For networks
        that read the map as a grid (PPO's ``encoder="propagation"``)."""
        if not self.observe_map:
            return None
        height, width = self.max_shape
        return self.obs_size - 3 * height * width, height, width

    def observation_space(self, params: ProceduralParams | None = None) -> spaces.Box:
        return spaces.Box(0.0, 1.0, (self.obs_size,), jnp.float32)

    def action_space(self, params: ProceduralParams | None = None) -> spaces.Discrete:
        return spaces.Discrete(NUM_ACTIONS)

    # ------------------------------------------------------------ reset
    def reset_env(self, key: jax.Array, params: ProceduralParams) -> tuple[jax.Array, ProceduralState]:
        """A fresh episode on a uniformly drawn pool slot, with a uniformly drawn item of that layout.

        The two words are ``jax.random.bits(key, (2,), uint32)``, bit for bit, computed by
        :func:`draw_episode` (the reset is paid on every step: see there for why it is written out).
        """
        layout_index, item_index = draw_episode(key, params.pool.layouts.num_items, self.pool_size)
        state = initial_state(layout_index, item_index, params.pool, params.walls, self.visited_rows,
                              self.visit_levels)
        return params.reset_obs[layout_index, item_index], state

    def reset_to(self, layout_index: jax.Array | int, item_index: jax.Array | int,
                 params: ProceduralParams | None = None) -> tuple[jax.Array, ProceduralState]:
        """A fresh episode on a chosen slot and item (deterministic evaluation)."""
        params = self.default_params if params is None else params
        state = initial_state(jnp.asarray(layout_index, jnp.int32), jnp.asarray(item_index, jnp.int32),
                              params.pool, params.walls, self.visited_rows, self.visit_levels)
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
        # The move as arithmetic on the action (0 up, 1 down, 2 left, 3 right: grid.MOVES), not a table gather.
        d_row = (action == 1).astype(jnp.int32) - (action == 0).astype(jnp.int32)
        d_col = (action == 3).astype(jnp.int32) - (action == 2).astype(jnp.int32)
        proposed = pos + jnp.stack([d_row, d_col])
        limit = jnp.stack([state.height, state.width]) - 1
        on_floor = jnp.all((proposed >= 0) & (proposed <= limit))
        wall_bump = ~on_floor
        # Off the floor, the clipped cell is the robot's own cell (one coordinate moved by one).
        clipped = jnp.clip(proposed, 0, limit)
        collision = on_floor & wall_bit(state.walls, clipped, self.view_radius)
        next_pos = jnp.where(collision, pos, clipped)

        distance_change = None
        if self.shaping == "bfs":  # the target's table: the item's row, or the goal's (the last row) while carrying
            row = jnp.where(state.carrying, params.distances.shape[1] - 1, state.item_index)
            table = params.distances[state.layout_index, row].astype(jnp.int32)
            distance_change = table[pos[0], pos[1]] - table[next_pos[0], next_pos[1]]
        reward, picked_up, delivered = spec_reward(
            params, pos, next_pos, state.carrying, state.item_pos, state.goal, collision, wall_bump, distance_change
        )

        time = state.time + 1
        terminated = delivered
        truncated = (time >= params.max_steps) & ~terminated
        visited = state.visited
        if self.observe_visited:  # a new target (the pickup) starts a new trail
            visited = count_visit(jnp.where(picked_up, jnp.uint32(0), visited), next_pos, self.view_radius,
                                  self.visit_levels)
        next_state = state.replace(pos=next_pos, carrying=state.carrying | picked_up, time=time, last_action=action,
                                   visited=visited)
        info = {"collision": collision, "wall_bump": wall_bump, "picked_up": picked_up, "delivered": delivered}
        return self.observe(next_state), next_state, reward, terminated, truncated, info

    def is_terminated(self, state: ProceduralState, params: ProceduralParams) -> jax.Array:
        return state.carrying & jnp.all(state.pos == state.goal)

    def is_truncated(self, state: ProceduralState, params: ProceduralParams) -> jax.Array:
        return state.time >= params.max_steps

    def optimal_steps(self, state: ProceduralState) -> jax.Array:
        """The BFS optimum of the episode ``state`` belongs to (the yardstick of an evaluation)."""
        return state.optimal


