"""The fleet environment of FLEET_SPEC.md in JAX: K robots, lifelong pick-and-place, one shared shift.

The transition is split in two so the NumPy reference can replay it bit for bit:

- :func:`draw_tasks` turns a key into one candidate task per robot (the only
  randomness): ``jax.random.bits(key, (2, K), uint32)`` modulo
  ``num_items`` (row 0: items) and ``num_stations`` (row 1: stations). Reset
  gives every robot its candidate; a transition only robots that delivered.
- :func:`fleet_transition` and :func:`fleet_reset` are deterministic in the
  drawn tasks.

``Fleet.step`` gives the base class's results bit for bit (``key_step, key_reset =
split(key)``, the transition draws from ``key_step``, the auto-reset on truncation from
``key_reset``; see :func:`step_keys`), computed more cheaply: threefry written out
(:func:`threefry2x32`), the auto-reset only on steps where some env truncates
(:func:`only_where`), observations from int32 bit masks (:func:`observation_parts`).

The conflict rule (steps 1-4: proposals, rounds, who moves) is
:mod:`wrl_jax.envs.fleet.conflicts`; the random words are in :mod:`wrl_jax.core.random`,
the windows in :mod:`wrl_jax.core.observation`. What stays here, the draws, the
transition, the observation hook and the environment class, is the rest of FLEET_SPEC.md's
MDP, which the NumPy reference is checked against bit for bit.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.core.environment import Environment
from wrl_jax.core.gymnax_base import spaces
from wrl_jax.core.grid import MOVES_WITH_WAIT
from wrl_jax.core.observation import (
    bit_windows_supported,
    coordinate_table,
    expand_observations,
    observation_size,
    robot_observation_parts,
    robot_observations,
    seen_masks,
    window_masks,
    window_size,
)
from wrl_jax.core.random import (  # noqa: F401 (threefry re-exported)
    random_words,
    split_key,
    threefry2x32,
    threefry_key_data,
    words_modulo,
)
from wrl_jax.envs.fleet.conflicts import (  # noqa: F401 (propose, resolve_conflicts re-exported)
    propose,
    propose_cells,
    resolve_cells,
    resolve_conflicts,
)
from wrl_jax.envs.fleet.types import FleetParams, FleetState, FleetTasks

NUM_ACTIONS = 5
"""0 up, 1 down, 2 left, 3 right, 4 wait."""

WAIT = 4

MEMORY_SIZE = NUM_ACTIONS + 1
"""Values ``observe_last_action`` appends: the previous action one-hot, then whether it was blocked."""

FLAGS = ("shelf_hit", "wall_bump", "robot_block", "picked_up", "delivered", "waited")
"""Per-robot bool ``(K,)`` entries of a transition's ``info`` (``waited``: action 4, for the metrics)."""


def draw_tasks(key: jax.Array, params: FleetParams, num_robots: int) -> FleetTasks:
    """One uniform candidate ``(item, station)`` per robot from ``key`` (the documented draw method).

    ``jax.random.bits(key, (2, K), uint32)`` (computed by :func:`random_words`,
    the same bits), reduced modulo ``num_items`` (row 0) and ``num_stations``
    (row 1) (:func:`~wrl_jax.core.random.words_modulo`: the remainder without
    integer division). The modulo bias is below ``n / 2**32`` (< 1.5e-8 for the
    62 item markers), far under any sampling noise, and the program is a third of
    ``jax.random.randint``'s, which matters since ``step`` draws twice per
    transition (the tasks and the auto-reset's).
    """
    words = random_words(key, 2 * num_robots).reshape(2, num_robots)
    bounds = jnp.stack([params.num_items, params.num_stations]).astype(jnp.uint32)[:, None]
    drawn = words_modulo(words, bounds)
    return FleetTasks(item=drawn[0].astype(jnp.int32), station=drawn[1].astype(jnp.int32))


def step_keys(key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(transition key, reset key)`` of ``Fleet.step(key, ...)``: ``jax.random.split(key)``, bit for bit."""
    return split_key(key, 0), split_key(key, 1)



def only_where(pred: jax.Array, compute, operand: jax.Array, otherwise):
    """``compute(operand)`` where ``pred``, else ``otherwise`` (same pytree); computed only when needed.

    A ``lax.while_loop`` that runs at most once. Why not ``jnp.where`` or ``lax.cond``: under
    ``vmap`` both evaluate ``compute`` for every env on every step. A batched while runs its body
    only while some env of the batch still needs it (then selects per env), so the auto-reset of
    fleets that share a shift clock (the usual batch: all start together, all truncate together)
    costs one batch-wide test on the steps between truncations. ``operand`` (an unsigned integer
    array, e.g. key data) rides in the loop carry and is changed by the body, so XLA cannot hoist
    ``compute`` out of the loop as loop-invariant (which would run it on every step again).
    """
    def body(carry):
        _, data, _ = carry
        return jnp.zeros((), dtype=bool), data + np.asarray(1, dtype=data.dtype), compute(data)

    return jax.lax.while_loop(lambda carry: carry[0], body, (jnp.asarray(pred), operand, otherwise))[2]


# ----------------------------------------------------------------- deterministic core
def targets(state: FleetState, params: FleetParams) -> jax.Array:
    """Each robot's current target cell ``(K, 2)``: its item while empty, its station while carrying."""
    return jnp.where(state.carrying[:, None], params.stations[state.station], params.items[state.item])


def target_distances(pos: jax.Array, state: FleetState, params: FleetParams) -> jax.Array:
    """``d(pos_i, t_i)`` ``(K,)`` int32 with the targets of ``state``: BFS tables, or Manhattan if switched."""
    rows, cols = pos[:, 0], pos[:, 1]
    bfs = jnp.where(state.carrying, params.station_dist[state.station, rows, cols],
                    params.item_dist[state.item, rows, cols])
    manhattan = jnp.abs(pos - targets(state, params)).sum(axis=1).astype(jnp.int32)
    return jnp.where(params.manhattan_shaping, manhattan, bfs)


def reward_terms(params: FleetParams, flags: dict[str, jax.Array], shaping: jax.Array) -> jax.Array:
    """Step 6: float32 ``(K,)`` rewards, the terms added in FLEET_SPEC.md's order."""
    zero = jnp.zeros_like(params.step_penalty)
    reward = jnp.broadcast_to(params.step_penalty, shaping.shape)
    reward = reward + jnp.where(flags["shelf_hit"], params.obstacle_penalty, zero)
    reward = reward + jnp.where(flags["wall_bump"], params.wall_penalty, zero)
    reward = reward + jnp.where(flags["robot_block"], params.block_penalty, zero)
    reward = reward + params.shaping_coef * shaping.astype(jnp.float32)
    reward = reward + jnp.where(flags["picked_up"], params.pickup_reward, zero)
    reward = reward + jnp.where(flags["delivered"], params.delivery_reward, zero)
    return reward


def _target_index(state: FleetState, params: FleetParams) -> jax.Array:
    """Each robot's target as a row of :func:`_target_cells`: ``item`` while empty, ``I + station`` while carrying."""
    return jnp.where(state.carrying, params.items.shape[0] + state.station, state.item)


def _target_cells(params: FleetParams) -> jax.Array:
    """``(I + G, 2)`` int32: the item rows, then the station rows (one gather finds any robot's target)."""
    return jnp.concatenate([params.items, params.stations], axis=0)


def _distance_rows(params: FleetParams) -> jax.Array:
    """``((I + G) N^2,)`` int32: the item then station BFS tables, flat (one gather finds any ``d(cell, t_i)``)."""
    return jnp.concatenate([params.item_dist, params.station_dist], axis=0).reshape(-1)


def fleet_transition(state: FleetState, action: jax.Array, tasks: FleetTasks, params: FleetParams):
    """One transition without reset (steps 1-8), deterministic in ``tasks``.

    Returns ``(next_state, reward (K,), truncated (), flags)``; ``flags`` maps
    each name of :data:`FLAGS` to a bool ``(K,)``. Each robot's target and its
    distances are read with one index into the stacked item/station tables.
    """
    size = params.shelves.shape[0]
    action = jnp.asarray(action, dtype=jnp.int32)
    row, col = state.pos[:, 0], state.pos[:, 1]
    q_row, q_col, wall_bump, shelf_hit = propose_cells(row, col, action, params.shelves)
    next_row, next_col, robot_block = resolve_cells(row, col, q_row, q_col)
    next_pos = jnp.stack([next_row, next_col], axis=-1)
    target_row = _target_index(state, params)
    target = _target_cells(params)[target_row]
    on_target = jnp.all(next_pos == target, axis=1)
    picked_up = ~state.carrying & on_target
    delivered = state.carrying & on_target
    table = _distance_rows(params)
    base = target_row * (size * size)
    bfs = (table[base + state.pos[:, 0] * size + state.pos[:, 1]]
           - table[base + next_pos[:, 0] * size + next_pos[:, 1]])
    manhattan = (jnp.abs(state.pos - target).sum(axis=1) - jnp.abs(next_pos - target).sum(axis=1)).astype(jnp.int32)
    shaping = jnp.where(params.manhattan_shaping, manhattan, bfs)
    flags = dict(shelf_hit=shelf_hit, wall_bump=wall_bump, robot_block=robot_block, picked_up=picked_up,
                 delivered=delivered, waited=action == WAIT)
    reward = reward_terms(params, flags, shaping)
    time = state.time + 1
    next_state = FleetState(
        pos=next_pos,
        item=jnp.where(delivered, tasks.item, state.item),
        station=jnp.where(delivered, tasks.station, state.station),
        carrying=(state.carrying | picked_up) & ~delivered,
        time=time,
    )
    return next_state, reward, time >= params.max_steps, flags


def fleet_reset(tasks: FleetTasks, params: FleetParams) -> FleetState:
    """A fresh shift: robots on their starts, empty-handed, with the drawn tasks."""
    return FleetState(pos=params.starts, item=tasks.item, station=tasks.station,
                      carrying=jnp.zeros(params.starts.shape[0], dtype=bool), time=jnp.zeros((), jnp.int32))


def fleet_observation(state: FleetState, params: FleetParams, view_radius: int, priority: bool = False,
                      headings: bool = False) -> jax.Array:
    """``(K, 5 + 3 (2V+1)^2)`` float32 observations (FLEET_SPEC.md), through :mod:`wrl_jax.core.observation`.

    For ``V <= 2`` from bit masks (:func:`observation_parts`), the same bits as
    :func:`~wrl_jax.core.observation.robot_observations`, several times cheaper under ``vmap``.
    ``priority`` (``V <= 2``) appends a fourth window channel, ``(K, 5 + 4 (2V+1)^2)``: the other
    robots with a lower index than the observer (:attr:`Fleet.observe_priority`); ``headings`` (``V <= 2``,
    needs ``state.last_action``) one more: the cells the other robots would enter by repeating their
    previous action (:func:`heading_masks`).
    """
    if not bit_windows_supported(view_radius):
        target = _target_cells(params)[_target_index(state, params)]
        return robot_observations(params.shelves, state.pos, target, state.carrying, view_radius)
    return expand_observations(*observation_parts(state, params, view_radius, priority, headings), view_radius)


def observation_parts(state: FleetState, params: FleetParams, view_radius: int,
                      priority: bool = False, headings: bool = False) -> tuple[jax.Array, tuple[jax.Array, ...]]:
    """The observations' compact form ``(scalars (K, 5), masks)``, 3 to 5 ``(K,)`` int32 masks (``V <= 2``; see
    ``robot_observation_parts``; ``headings`` appends :func:`heading_masks`).

    The shelf masks come from a table of the layout (:func:`~wrl_jax.core.observation.window_masks`),
    one gather per robot; with params shared by a batch the table is built once per step.
    """
    size = params.shelves.shape[0]
    target = _target_cells(params)[_target_index(state, params)]
    masks = window_masks(params.shelves, view_radius).reshape(-1)[state.pos[:, 0] * size + state.pos[:, 1]]
    scalars, masks = robot_observation_parts(masks, state.pos, target, state.carrying, view_radius, size, priority)
    if headings:
        masks = (*masks, heading_masks(state.pos, state.last_action, view_radius))
    return scalars, masks


def heading_masks(pos: jax.Array, last_action: jax.Array, view_radius: int) -> jax.Array:
    """``(K,)`` int32 window masks: bit ``w`` of robot ``i`` set on the cell another robot's previous
    action aimed at (the cell it would try again by repeating it, whether or not it got there; its own
    cell if that action was a wait, and at the start of a shift).

    Why: a robot's window shows where the others *are*, not where they go; two robots that step
    into one free cell, or into each other, are both blocked or one of them is (FLEET_SPEC.md step 3).
    In aisles robots mostly keep going, so the repeated move is a cheap guess of the next cell.
    """
    ahead = pos + jnp.asarray(MOVES_WITH_WAIT)[jnp.where(last_action < 0, WAIT, last_action)]
    return seen_masks(pos, ahead, view_radius, ~np.eye(pos.shape[0], dtype=bool))


def global_state(state: FleetState, params: FleetParams) -> jax.Array:
    """A fixed-size view of the whole fleet for centralised critics, ``(4 N^2 + 5 K + 1,)`` float32.

    Four ``N x N`` planes, row-major: shelves; robot occupancy; cells some
    robot is heading to (its current target); cells of carrying robots. Then
    each robot's five observation scalars in robot order (who is where and
    where it goes: the planes alone lose robot identity), then the elapsed
    fraction of the shift ``time / max_steps`` (the value of a truncated
    shift depends on it).
    """
    size = params.shelves.shape[0]
    target = targets(state, params)
    empty = jnp.zeros((size, size), dtype=jnp.float32)
    robots = empty.at[state.pos[:, 0], state.pos[:, 1]].set(1.0)
    heading = empty.at[target[:, 0], target[:, 1]].set(1.0)
    loaded = empty.at[state.pos[:, 0], state.pos[:, 1]].max(state.carrying.astype(jnp.float32))
    table = jnp.asarray(coordinate_table(size))  # the observation's exact scalars
    scalars = jnp.concatenate([table[state.pos], table[target], state.carrying.astype(jnp.float32)[:, None]], axis=1)
    elapsed = state.time.astype(jnp.float32) / params.max_steps.astype(jnp.float32)
    planes = jnp.stack([params.shelves.astype(jnp.float32), robots, heading, loaded])
    return jnp.concatenate([planes.reshape(-1), scalars.reshape(-1), elapsed[None]])


# ----------------------------------------------------------------- spaces
class MultiDiscrete(spaces.Space):
    """``shape`` independent integer choices in ``0..n-1`` (gymnax has no MultiDiscrete)."""

    def __init__(self, n: int, shape: tuple[int, ...]):
        self.n, self.shape, self.dtype = int(n), tuple(shape), jnp.int32

    def sample(self, rng: jax.Array) -> jax.Array:
        return jax.random.randint(rng, self.shape, 0, self.n, dtype=self.dtype)

    def contains(self, x: jax.Array) -> jax.Array:
        x = jnp.asarray(x)
        return jnp.logical_and(x.shape == self.shape, jnp.all((x >= 0) & (x < self.n)))


# ----------------------------------------------------------------- the environment
class Fleet(Environment[FleetState, FleetParams]):
    """K robots on one layout (FLEET_SPEC.md). Build it with :mod:`wrl_jax.envs.fleet.registration`.

    The action is a ``(K,)`` int vector: :meth:`action_space` is the
    per-robot ``Discrete(5)`` (what a shared policy samples for each robot),
    :meth:`multi_action_space` the joint one. ``reward`` is ``(K,)`` float32;
    ``terminated`` (always False) and ``truncated`` are scalars; ``info``
    holds the per-robot flags of :data:`FLAGS` and ``final_global_state``, the
    :func:`global_state` of the state the transition reached (before an
    auto-reset: what a centralised critic bootstraps a truncated shift from; it
    costs nothing where unused, since XLA drops it from a jitted program).

    ``observe_priority=True`` (an option beyond FLEET_SPEC.md, off by default) appends a
    fourth window channel to each robot's observation: 1.0 where another robot with a
    *lower index* stands. The conflict rule lets the lowest index win a free cell that
    several robots enter, and a shared policy cannot otherwise tell which of two robots
    facing one cell will win it: with this channel it can learn to yield.

    ``observe_last_action=True`` (an option beyond FLEET_SPEC.md, off by default) appends six
    values after everything else: the robot's own previous action one-hot (five zeros at the
    start of a shift; an action outside ``0..4`` counts as the wait it acts as) and 1.0 if that
    action was a blocked move (``robot_block``). A one-step memory: without it two robots that
    meet head-on in an aisle see the same window step after step and a deterministic policy
    repeats the refused swap forever; the state keeps it in ``last_action`` and ``last_blocked``.

    ``observe_headings=True`` (beyond FLEET_SPEC.md, off by default, ``V <= 2``) adds a window channel
    after the others: the cells the *other* robots would enter by repeating their previous action
    (:func:`heading_masks`), a guess of where they go next, so a robot can see a contested cell or a
    head-on meeting coming. The state keeps the previous actions for it (as with the last action).
    """

    family = "fleet"

    def __init__(self, params: FleetParams, view_radius: int = 2, name: str = "Fleet", observe_priority: bool = False,
                 observe_last_action: bool = False, observe_headings: bool = False):
        self.size = int(params.shelves.shape[0])
        self.num_robots = int(params.starts.shape[0])
        self.num_agents = self.num_robots
        self.view_radius = int(view_radius)
        self.observe_priority = bool(observe_priority)
        self.observe_last_action = bool(observe_last_action)
        self.observe_headings = bool(observe_headings)
        self.keeps_memory = self.observe_last_action or self.observe_headings
        if self.observe_headings and not bit_windows_supported(self.view_radius):
            raise ValueError(f"observe_headings needs the bit-mask window (view_radius <= 2), got view_radius="
                             f"{self.view_radius}")
        if self.observe_priority and not bit_windows_supported(self.view_radius):
            raise ValueError(f"observe_priority needs the bit-mask window (view_radius <= 2), got view_radius="
                             f"{self.view_radius}")
        self._name = name
        super().__init__(params)

    def static_config(self) -> tuple:
        return (self._name, self.size, self.num_robots, self.view_radius, self.observe_priority,
                self.observe_last_action, self.observe_headings)

    @property
    def name(self) -> str:
        return self._name

    @property
    def num_actions(self) -> int:
        return NUM_ACTIONS

    @property
    def obs_size(self) -> int:
        """FLEET_SPEC.md's ``5 + 3 (2V+1)^2``, plus ``(2V+1)^2`` for each of the priority and heading channels,
        plus 6 with the last action."""
        extra_channels = int(self.observe_priority) + int(self.observe_headings)
        memory = MEMORY_SIZE if self.observe_last_action else 0
        return observation_size(self.view_radius) + extra_channels * window_size(self.view_radius) ** 2 + memory

    def onehot_coordinates(self) -> tuple[int, int, int, int]:
        """Four coordinates (own row and col, target row and col), each ``i / (N - 1)``: ``N`` values."""
        return (4, self.size, 0, self.size - 1)

    def __repr__(self) -> str:
        return (f"Fleet({self._name!r}, size={self.size}, num_robots={self.num_robots}, view_radius={self.view_radius}"
                f"{', observe_priority=True' if self.observe_priority else ''}"
                f"{', observe_last_action=True' if self.observe_last_action else ''}"
                f"{', observe_headings=True' if self.observe_headings else ''})")

    # ---------------------------------------------------------- gymnax hooks
    def reset_env(self, key: jax.Array, params: FleetParams) -> tuple[jax.Array, FleetState]:
        state = self._start_memory(fleet_reset(draw_tasks(key, params, self.num_robots), params))
        return self._observe(state, params), state

    def transition(self, key: jax.Array, state: FleetState, action: Any, params: FleetParams):
        self.check_action(action)
        tasks = draw_tasks(key, params, self.num_robots)
        next_state, reward, truncated, flags = fleet_transition(state, action, tasks, params)
        next_state = self._remember(next_state, action, flags)
        obs = self._observe(next_state, params)
        info = {**flags, "final_global_state": global_state(next_state, params)}
        return obs, next_state, reward, jnp.zeros((), dtype=bool), truncated, info

    def step(self, key: jax.Array, state: FleetState, action: Any, params: FleetParams | None = None):
        """The base class's ``step`` (same keys, draws, outputs and bits), with a cheaper auto-reset.

        The auto-reset (reset key, task draw, fresh observation) runs only on steps where some env
        truncates (:func:`only_where`), and the select of reset against reached observation is
        done on their compact form (:func:`observation_parts`), expanded once per output.
        """
        params = self.default_params if params is None else params
        self.check_action(action)
        tasks = draw_tasks(split_key(key, 0), params, self.num_robots)
        reached, reward, truncated, flags = fleet_transition(state, action, tasks, params)
        reached = self._remember(reached, action, flags)
        compact = bit_windows_supported(self.view_radius)
        observe = partial(observation_parts if compact else fleet_observation, priority=self.observe_priority,
                          headings=self.observe_headings)
        final_parts = observe(reached, params, self.view_radius)
        if compact:  # materialize the 32 bytes a robot: else XLA recomputes masks for each of the 80 columns
            final_parts = jax.lax.optimization_barrier(final_parts)

        typed = jnp.issubdtype(key.dtype, jax.dtypes.prng_key)
        impl = jax.random.key_impl(key) if typed else None

        def reset(data):
            key_reset = split_key(jax.random.wrap_key_data(data, impl=impl) if typed else data, 1)
            fresh = self._start_memory(fleet_reset(draw_tasks(key_reset, params, self.num_robots), params))
            return fresh, observe(fresh, params, self.view_radius)

        data = jax.random.key_data(key) if typed else key
        next_state, parts = only_where(truncated, reset, data, (reached, final_parts))
        if compact:  # the compact form (32 bytes a robot) was selected; expand each output once
            final_obs = expand_observations(*final_parts, self.view_radius)
            obs = expand_observations(*parts, self.view_radius)
        else:
            final_obs, obs = final_parts, parts
        final_obs, obs = self._with_memory(final_obs, reached), self._with_memory(obs, next_state)
        info = {**flags, "final_global_state": global_state(reached, params), "final_obs": final_obs,
                "final_observation": final_obs}
        return obs, next_state, reward, jnp.zeros((), dtype=bool), truncated, info

    def get_obs(self, state: FleetState, params: FleetParams | None = None, key: jax.Array | None = None):
        return self._observe(state, self.default_params if params is None else params)

    def _observe(self, state: FleetState, params: FleetParams) -> jax.Array:
        observation = fleet_observation(state, params, self.view_radius, self.observe_priority, self.observe_headings)
        return self._with_memory(observation, state)

    # ---------------------------------------------------------- the one-step memory (observe_last_action)
    def _start_memory(self, state: FleetState) -> FleetState:
        """``state`` at the start of a shift: no previous action (``-1``), nothing blocked."""
        if not self.keeps_memory:
            return state
        return state.replace(last_action=jnp.full(self.num_robots, -1, dtype=jnp.int32),
                             last_blocked=jnp.zeros(self.num_robots, dtype=bool))

    def _remember(self, state: FleetState, action: jax.Array, flags: dict[str, jax.Array]) -> FleetState:
        """``state`` reached by ``action``, keeping the action (as acted: outside ``0..4`` a wait) and its block."""
        if not self.keeps_memory:
            return state
        action = jnp.asarray(action, dtype=jnp.int32)
        acted = jnp.where((action >= 0) & (action < NUM_ACTIONS), action, WAIT)
        return state.replace(last_action=acted, last_blocked=flags["robot_block"])

    def _with_memory(self, obs: jax.Array, state: FleetState) -> jax.Array:
        """``obs (K, D)`` followed by the previous action one-hot and its block flag (with ``observe_last_action``)."""
        if not self.observe_last_action:
            return obs
        memory = jnp.concatenate([jax.nn.one_hot(state.last_action, NUM_ACTIONS, dtype=jnp.float32),
                                  state.last_blocked.astype(jnp.float32)[:, None]], axis=1)
        return jnp.concatenate([obs, memory], axis=1)

    def global_state(self, state: FleetState, params: FleetParams | None = None) -> jax.Array:
        """See :func:`global_state`."""
        return global_state(state, self.default_params if params is None else params)

    def global_state_size(self) -> int:
        return 4 * self.size**2 + 5 * self.num_robots + 1

    def check_action(self, action: Any) -> None:
        """Raise ``ValueError`` for a concrete action of the wrong shape, dtype or range (no-op on tracers)."""
        if isinstance(action, jax.core.Tracer):
            return
        array = np.asarray(action)
        if array.shape != (self.num_robots,):
            raise ValueError(f"action must have shape ({self.num_robots},), one per robot; got shape {array.shape}")
        if not np.issubdtype(array.dtype, np.integer):
            raise ValueError(f"action must be integers 0..4; got dtype {array.dtype}")
        bad = np.flatnonzero((array < 0) | (array >= NUM_ACTIONS))
        if bad.size:
            raise ValueError(f"action {int(array[bad[0]])} of robot {int(bad[0])} is outside 0..4 "
                             f"(0 up, 1 down, 2 left, 3 right, 4 wait)")

    # ---------------------------------------------------------- spaces
    def action_space(self, params: FleetParams | None = None) -> spaces.Discrete:
        """Per robot: ``Discrete(5)``; the joint action is ``(K,)`` of these (:meth:`multi_action_space`)."""
        return spaces.Discrete(NUM_ACTIONS)

    def multi_action_space(self, params: FleetParams | None = None) -> MultiDiscrete:
        return MultiDiscrete(NUM_ACTIONS, (self.num_robots,))

    def observation_space(self, params: FleetParams | None = None) -> spaces.Box:
        return spaces.Box(0.0, 1.0, (self.num_robots, self.obs_size), jnp.float32)

    def global_state_space(self, params: FleetParams | None = None) -> spaces.Box:
        return spaces.Box(0.0, 1.0, (self.global_state_size(),), jnp.float32)

    def state_space(self, params: FleetParams | None = None) -> spaces.Dict:
        n, k = self.size, self.num_robots
        return spaces.Dict({
            "pos": spaces.Box(0, n - 1, (k, 2), jnp.int32),
            "item": spaces.Box(0, int(self.default_params.num_items) - 1, (k,), jnp.int32),
            "station": spaces.Box(0, int(self.default_params.num_stations) - 1, (k,), jnp.int32),
            "carrying": spaces.Box(0, 1, (k,), jnp.bool_),
            "time": spaces.Discrete(int(self.default_params.max_steps) + 1),
            **({"last_action": spaces.Box(-1, NUM_ACTIONS - 1, (k,), jnp.int32),
                "last_blocked": spaces.Box(0, 1, (k,), jnp.bool_)} if self.keeps_memory else {}),
        })
