"""The fleet environment of FLEET_SPEC.md in JAX: K robots, lifelong pick-and-place, one shared shift.

The MDP is :mod:`wrl_jax.envs.fleet.dynamics` (the task draw, the transition, the reset),
the observation :mod:`wrl_jax.envs.fleet.observation`, the conflict rule
:mod:`wrl_jax.envs.fleet.conflicts`; this module is the environment class around them.

``Fleet.step`` gives the base class's results bit for bit (``key_step, key_reset =
split(key)``, the transition draws from ``key_step``, the auto-reset on truncation from
``key_reset``; see :func:`~wrl_jax.envs.fleet.dynamics.step_keys`), computed more cheaply:
threefry written out, the auto-reset only on steps where some env truncates
(:func:`~wrl_jax.core.environment.only_where`), observations from int32 bit masks.
"""

from __future__ import annotations

from functools import partial
from types import MappingProxyType
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.core.environment import Environment, only_where
from wrl_jax.core.gymnax_base import spaces
from wrl_jax.core.observation import (
    bit_windows_supported,
    expand_observations,
    observation_size,
    window_size,
)
from wrl_jax.core.random import split_key
from wrl_jax.core.spaces import MultiDiscrete
from wrl_jax.envs.fleet.dynamics import NUM_ACTIONS, WAIT, draw_tasks, fleet_reset, fleet_transition
from wrl_jax.envs.fleet.observation import MEMORY_SIZE, fleet_observation, global_state, observation_parts
from wrl_jax.envs.fleet.types import FleetParams, FleetState


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
    event_metrics = MappingProxyType({"delivered": "deliveries_sum", "robot_block": "robot_blocks_sum",
                                      "shelf_hit": "shelf_hits_sum"})

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
        truncates (:func:`~wrl_jax.core.environment.only_where`), and the select of reset against reached observation is
        done on their compact form (:func:`~wrl_jax.envs.fleet.observation.observation_parts`), expanded once per output.
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
