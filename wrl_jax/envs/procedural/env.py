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

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from wrl_jax.core.environment import Environment
from wrl_jax.core.gymnax_base import spaces
from wrl_jax.core.grid import distance_maps
from wrl_jax.core.observation import (
    RAY_DIRECTIONS,
    coordinate_table,
    expand_observations,
    free_runs,
    observation_size,
    pack_window_rows,
    plane_window_rows,
    robot_observation_parts,
    robot_observations,
    row_window_observation,
    row_windows_supported,
    unpack_wall_rows,
    wall_bit,
    wall_rows,
    wall_words,
    window_row_bits,
    window_rows_supported,
    window_size,
)
from wrl_jax.core.random import random_words, threefry2x32, threefry_key_data
from wrl_jax.envs.procedural.generators import GeneratorConfig, generate_batch
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
from wrl_jax.envs.warehouse.env import check_action, item_from_word, spec_reward

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

    # ------------------------------------------------------------ observation
    def observe(self, state: ProceduralState) -> jax.Array:
        """``(obs_size,)`` float32: the fleet robot observation for one robot, then what is configured.

        After the robot observation: the previous action one-hot (``observe_last_action``),
        the visited cells of the window (``observe_visited``, row-major like the window's
        channels), the free runs up, down, left and right (``observe_rays``), then the full
        map (``observe_map``).

        The map's channels: 0 shelves and off-grid, 1 the robot itself (the
        window has it at its centre; a full map must say where), 2 the target.
        """
        target = jnp.where(state.carrying, state.goal, state.item_pos)
        size = max(self.max_shape)
        if self.observe_window and self.row_windows:
            # The floor and the trail's bit planes side by side: one gather of the window's rows for all.
            planes = state.walls
            if self.observe_visited:
                planes = jnp.concatenate([planes, state.visited[:, :, 0].T], axis=1)
            window = plane_window_rows(planes, state.pos[None], self.view_radius)[0]  # (2V+1, 1 + B)
            trail = window[:, 1:]
        if self.observe_window and self.bit_windows:
            masks = pack_window_rows(window[None, :, 0])
            parts = robot_observation_parts(masks, state.pos[None], target[None], state.carrying[None],
                                            self.view_radius, size)
            obs = expand_observations(*parts, self.view_radius)[0]
        elif self.observe_window and self.row_windows:
            obs = row_window_observation(window[:, 0], state.pos, target, state.carrying, self.view_radius, size)
        elif self.observe_window:
            obs = robot_observations(self.blocked(state), state.pos[None], target[None], state.carrying[None],
                                     self.view_radius, size)[0]
        else:
            table = jnp.asarray(coordinate_table(size))
            obs = jnp.concatenate([table[state.pos], table[target], state.carrying.astype(jnp.float32)[None]])
        if self.observe_last_action:
            # one_hot of -1 (no action yet) is all zeros.
            obs = jnp.concatenate([obs, jax.nn.one_hot(state.last_action, NUM_ACTIONS, dtype=jnp.float32)])
        if self.observe_visited:  # (it needs the packed-row window: checked in __init__)
            obs = jnp.concatenate([obs, self.trail_window(trail)])
        if self.observe_rays:  # free runs in cells, over N - 1 like the coordinates (a float32 product, not a division)
            runs = free_runs(state.walls, state.pos, self.view_radius, self.max_shape[1])
            obs = jnp.concatenate([obs, runs.astype(jnp.float32) * np.float32(1 / max(size - 1, 1))])
        if not self.observe_map:
            return obs
        rows = jnp.arange(self.max_shape[0])[:, None]
        cols = jnp.arange(self.max_shape[1])[None, :]
        robot = (rows == state.pos[0]) & (cols == state.pos[1])
        target_cell = (rows == target[0]) & (cols == target[1])
        full_map = jnp.stack([self.blocked(state), robot, target_cell]).astype(jnp.float32)
        return jnp.concatenate([obs, full_map.reshape(-1)])

    def trail_window(self, trail: jax.Array) -> jax.Array:
        """``((2V+1)^2,)`` float32: the visits to each window cell since the current target was set, times ``1 / L``.

        ``trail``: ``(2V+1, B)``, the window's rows of each bit plane of ``state.visited`` (read with
        the floor's, :func:`~wrl_jax.core.observation.plane_window_rows`); the planes' bits are summed
        with their weights: exact small integers in float32.
        """
        count = 0.0
        for plane in range(trail.shape[1]):
            count = count + window_row_bits(trail[:, plane]) * np.float32(2**plane)
        # times float32(1 / L), written out: XLA turns a division by a constant into this product anyway
        return count if self.visit_levels == 1 else count * np.float32(1 / self.visit_levels)

    @property
    def visited_rows(self) -> int:
        """Rows of ``state.visited``: the walled floor's ``H + 2V`` when observed, else 0 (an empty array)."""
        return self.max_shape[0] + 2 * self.view_radius if self.observe_visited else 0

    @property
    def bit_windows(self) -> bool:
        """True when the window comes from bit masks of the packed rows (``V <= 2``, walled rows of <= 32 cells)."""
        return row_windows_supported(self.max_shape[1], self.view_radius)

    @property
    def row_windows(self) -> bool:
        """True when the window's rows are read from the packed rows (any ``V`` with walled rows of <= 32 cells).

        For ``V <= 2`` the rows are packed once more into the fleet's int32 masks (:attr:`bit_windows`); past
        that, :func:`~wrl_jax.core.observation.row_window_observation` expands the rows directly.
        """
        return window_rows_supported(self.max_shape[1], self.view_radius)

    def blocked(self, state: ProceduralState) -> jax.Array:
        """``(..., H, W)`` bool: the floor of ``state`` (or of a batch of states), shelves and off-grid cells True."""
        return unpack_wall_rows(state.walls, self.max_shape, self.view_radius)

    # ------------------------------------------------------------ pool
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

    def optimal_steps(self, state: ProceduralState) -> jax.Array:
        """The BFS optimum of the episode ``state`` belongs to (the yardstick of an evaluation)."""
        return state.optimal


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


def count_visit(planes: jax.Array, cell: jax.Array, view_radius: int, levels: int) -> jax.Array:
    """``planes`` ``(B, H + 2V, 1)`` (a count per cell, bit ``k`` in plane ``k``) with ``cell``'s count
    raised by one, saturating at ``levels``; the rows are packed like
    :func:`~wrl_jax.core.observation.wall_rows`, one word a row. With ``levels = 1`` it sets the cell's bit.

    Written with a row mask (one elementwise pass over the ``B (H + 2V)`` words) instead of an indexed
    read and write, which ``vmap`` turns into a gather and a scatter; the two measured the same
    (docs/procedural.md), and this form needs no index arithmetic per plane.
    """
    row = jnp.arange(planes.shape[1], dtype=jnp.int32)[None, :, None] == cell[0] + view_radius
    bit = jnp.left_shift(jnp.uint32(1), (cell[1] + view_radius).astype(jnp.uint32))
    weights = np.left_shift(1, np.arange(planes.shape[0])).astype(np.int32)
    has_bit = jnp.any(row & ((planes & bit) != 0), axis=(1, 2))  # (B,): the cell's count, bit by bit
    count = jnp.sum(jnp.where(has_bit, weights, 0))
    set_bit = ((jnp.minimum(count + 1, levels) & weights) != 0)[:, None, None]
    return jnp.where(row, jnp.where(set_bit, planes | bit, planes & ~bit), planes)


@partial(jax.jit, static_argnums=0)
def pool_arrays(env: ProceduralWarehouse, pool: LayoutPool) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(walls, reset_obs, distances)`` of ``pool`` for ``env``'s params (one compiled program per env and pool shape)."""
    walls = env.pool_walls(pool)
    return walls, env.reset_observations(pool, walls), env.pool_distances(pool)
