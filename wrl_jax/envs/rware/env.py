"""The RWARE environment class: rware 2.0.0's multi-robot warehouse as a wrl_jax (gymnax 1.0) environment.

The MDP is :mod:`wrl_jax.envs.rware.dynamics` (reset, the step deterministic in its
replacement draws), the move graph :mod:`wrl_jax.envs.rware.conflicts`, the observation
:mod:`wrl_jax.envs.rware.observation`; this module wraps them. Build it with
:func:`wrl_jax.envs.rware.registration.make_rware` or ``wrl_jax.make("rware-tiny-4ag-v2")``.

Conventions against rware's Gymnasium surface: one ``(N,)`` int32 action vector (with
messages ``(N, 1 + M)``: the action, then the bits), ``(N, D)`` float32 observations
(rware's FLATTENED, the default; ``observation_type`` picks rware's others, each with a leading
agent axis: :func:`~wrl_jax.envs.rware.observation.observe`), ``(N,)`` float32 rewards, and
rware's single ``done`` reported as ``truncated`` (its time and inactivity limits are cut-offs,
not terminal states), ``terminated`` always False.

For multi-agent learners: :meth:`Rware.global_state` is EPyMARL's RWARE state (every agent's
observation, concatenated), what MAPPO's centralized critic reads (``info["final_global_state"]``
holds the reached one), and :meth:`Rware.onehot_coordinates` lets PPO one-hot the own cell.
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.core.environment import Environment, only_where
from wrl_jax.core.gymnax_base import spaces
from wrl_jax.core.random import split_key
from wrl_jax.core.spaces import MultiDiscrete, TreeDict
from wrl_jax.envs.rware.conflicts import check_tie_order
from wrl_jax.envs.rware.dynamics import draw_replacements, draw_reset, rware_reset, rware_transition
from wrl_jax.envs.rware.observation import (
    DEFAULT_IMAGE_LAYERS,
    directional_flag,
    flat_observation,
    flat_size,
    image_layer_names,
    observation_type_name,
    observe,
)
from wrl_jax.envs.rware.observation_image import FEATURES_SIZE, image_high, image_shape
from wrl_jax.envs.rware.set_order import MAX_SET_SIZE, longest_set_order_component
from wrl_jax.envs.rware.types import NUM_ACTIONS, RwareParams, RwareState


class Rware(Environment[RwareState, RwareParams]):
    """``N`` robots fetching requested shelves to goal cells (rware 2.0.0).

    Static configuration: the grid, shelf and goal counts (from ``params``), ``num_agents``,
    ``queue_size`` (rware's ``request_queue_size``), ``sensor_range``, ``msg_bits``,
    ``normalised_coordinates``, ``observation_type`` (``"flattened"``, ``"dict"``, ``"image"``,
    ``"image_dict"``), for the image types ``image_observation_layers`` (names) and
    ``image_observation_directional``, and ``tie_order`` (``"set"``: ties between equal chains as
    unpatched rware orders them; ``"insertion"``: the graph's insertion order). ``info`` holds
    ``delivered`` (per agent: it stood on a goal that paid), ``moved``, ``time_limit`` and
    ``inactivity_limit``.
    """

    family = "rware"
    event_metrics = MappingProxyType({"delivered": "deliveries_sum"})

    def __init__(self, params: RwareParams, num_agents: int, queue_size: int, *, sensor_range: int = 1,
                 msg_bits: int = 0, normalised_coordinates: bool = False, observation_type: Any = "flattened",
                 image_observation_layers: Any = DEFAULT_IMAGE_LAYERS, image_observation_directional: bool = True,
                 tie_order: str = "set", name: str = "rware"):
        self.height, self.width = (int(v) for v in params.highway.shape)
        self.num_shelves = int(params.shelf_home.shape[0])
        self.num_goals = int(params.goals.shape[0])
        self.num_agents = int(num_agents)
        self.queue_size = int(queue_size)
        self.sensor_range = int(sensor_range)
        self.msg_bits = int(msg_bits)
        self.normalised_coordinates = bool(normalised_coordinates)
        self.observation_type = observation_type_name(observation_type)
        image = self.observation_type in ("image", "image_dict")
        self.image_observation_layers = image_layer_names(image_observation_layers, needed=image)
        self.image_observation_directional = directional_flag(image_observation_directional)
        self.tie_order = check_tie_order(tie_order)
        if tie_order == "set" and longest_set_order_component(self.num_agents) > MAX_SET_SIZE:
            raise ValueError(f"tie_order='set' emulates CPython's set tables up to {MAX_SET_SIZE} keys, which "
                             f"{self.num_agents} agents may exceed; use tie_order='insertion'")
        self._name = name
        super().__init__(params)

    def static_config(self) -> tuple:
        """The shapes and switches of the programs; not the name, so ids of one shape share their programs."""
        base = (self.height, self.width, self.num_shelves, self.num_goals, self.num_agents, self.queue_size,
                self.sensor_range, self.msg_bits, self.normalised_coordinates)
        if self.tie_order != "set":
            base = (*base, self.tie_order)
        if self.observation_type == "flattened":
            return base
        if self.observation_type == "dict":
            return (*base, "dict")
        return (*base, self.observation_type, self.image_observation_layers, self.image_observation_directional)

    @property
    def name(self) -> str:
        return self._name

    @property
    def num_robots(self) -> int:
        """The fleet's name for :attr:`num_agents`, read by tools written for multi-robot fleets."""
        return self.num_agents

    @property
    def num_actions(self) -> int:
        return NUM_ACTIONS

    @property
    def obs_size(self) -> int:
        """One agent's observation length: FLATTENED's ``D``; for the other types, once flattened (:meth:`flat_obs`)."""
        return flat_size(self.observation_type, self.sensor_range, self.msg_bits, self.image_observation_layers)

    def __repr__(self) -> str:
        return (f"Rware({self._name!r}, grid={self.height}x{self.width}, num_agents={self.num_agents}, "
                f"shelves={self.num_shelves}, queue_size={self.queue_size}, sensor_range={self.sensor_range}, "
                f"msg_bits={self.msg_bits}"
                + ("" if self.observation_type == "flattened" else f", observation_type={self.observation_type!r}")
                + ")")

    # ---------------------------------------------------------- gymnax hooks
    def reset_env(self, key: jax.Array, params: RwareParams) -> tuple[jax.Array, RwareState]:
        cells, headings, queue = draw_reset(key, params, self.num_agents, self.queue_size)
        state = rware_reset(cells, headings, queue, params, self.msg_bits)
        return self.get_obs(state, params), state

    def transition(self, key: jax.Array, state: RwareState, action: Any, params: RwareParams):
        self.check_action(action)
        return self.transition_with(state, action, draw_replacements(key, params, self.queue_size), params)

    def step(self, key: jax.Array, state: RwareState, action: Any, params: RwareParams | None = None):
        """The base class's ``step`` (same keys, draws, outputs and bits), with the reset run only when needed.

        Under ``vmap`` the base class computes a fresh episode (its draws and observation) for every
        environment on every step and selects; that was three quarters of a step. Here it runs inside a
        batched ``while`` that iterates only while some environment of the batch ended (:func:`~wrl_jax.core.environment.only_where`):
        environments started together end together (rware's 500 steps), so one step in 500 pays for it.
        """
        params = self.default_params if params is None else params
        obs, reached, reward, terminated, truncated, info = self.transition(split_key(key, 0), state, action, params)
        typed = jnp.issubdtype(key.dtype, jax.dtypes.prng_key)
        impl = jax.random.key_impl(key) if typed else None

        def reset(data: jax.Array):
            fresh_obs, fresh = self.reset_env(split_key(jax.random.wrap_key_data(data, impl=impl) if typed else data, 1),
                                              params)
            return fresh, fresh_obs

        data = jax.random.key_data(key) if typed else key
        next_state, next_obs = only_where(terminated | truncated, reset, data, (reached, obs))
        info = {**info, "final_obs": obs, "final_observation": obs}
        return next_obs, next_state, reward, terminated, truncated, info

    def transition_with(self, state: RwareState, action: Any, replacements: jax.Array, params: RwareParams):
        """:meth:`transition` with the replacement draws given (``(G,)`` int32, see :mod:`.dynamics`).

        The deterministic core: parity tests feed it the draws rware made.
        """
        self.check_action(action)
        action = jnp.asarray(action, jnp.int32)
        message = None
        if self.msg_bits:
            action, message = action[:, 0], action[:, 1:].astype(jnp.float32)
        replacements = jnp.asarray(replacements, jnp.int32)
        state, reward, done, info = rware_transition(state, action, replacements, params, message, self.tie_order)
        obs = self._observe(state, params)
        info = {**info, "final_global_state": self.flat_obs(obs).reshape(-1)}
        return obs, state, reward, jnp.zeros((), bool), done, info

    def _observe(self, state: RwareState, params: RwareParams):
        return observe(state, params, self.observation_type, self.sensor_range, self.normalised_coordinates,
                       self.image_observation_layers, self.image_observation_directional)

    def get_obs(self, state: RwareState, params: RwareParams | None = None, key: jax.Array | None = None):
        params = self.default_params if params is None else params
        return self._observe(state, params)

    def flat_obs(self, obs: Any) -> jax.Array:
        """``(N, obs_size)`` float32: an observation of this env's type, each agent's flattened as
        ``gymnasium.spaces.flatten`` flattens rware's (the observation itself for FLATTENED)."""
        return flat_observation(obs, self.observation_type)

    def global_state(self, state: RwareState, params: RwareParams | None = None) -> jax.Array:
        """``(N * D,)`` float32: every agent's (flattened) observation, concatenated in agent order.

        EPyMARL's state for RWARE (its Gymnasium wrapper concatenates the observations), so a
        centralized critic here sees what MAPPO's sees in the published tables.
        """
        return self.flat_obs(self.get_obs(state, params)).reshape(-1)

    def global_state_size(self) -> int:
        return self.num_agents * self.obs_size

    def onehot_coordinates(self) -> tuple[int, int, int, int] | None:
        """The own ``x, y`` (raw cell indices, ``max(H, W)`` values each), for PPO's ``obs_encoding="onehot"``.

        ``None`` with ``normalised_coordinates`` (x and y then have different scales), or when the
        observation is not FLATTENED's vector: use ``"raw"``.
        """
        if self.normalised_coordinates or self.observation_type != "flattened":
            return None
        return (2, max(self.height, self.width), 0, 1)

    def is_truncated(self, state: RwareState, params: RwareParams) -> jax.Array:
        time_up = (params.max_steps > 0) & (state.time >= params.max_steps)
        idle = (params.max_inactivity_steps > 0) & (state.inactive >= params.max_inactivity_steps)
        return time_up | idle

    def check_action(self, action: Any) -> None:
        """Raise ``ValueError`` for an action of the wrong shape or dtype (traced or not: both are known when
        tracing) or, for a concrete one, out of range."""
        traced = isinstance(action, jax.core.Tracer)
        array = action if traced else np.asarray(action)
        shape = (self.num_agents, 1 + self.msg_bits) if self.msg_bits else (self.num_agents,)
        if array.shape != shape:
            what = "an action and its message bits" if self.msg_bits else "one action"
            raise ValueError(f"action must have shape {shape}, {what} per agent; got shape {array.shape}")
        if not np.issubdtype(array.dtype, np.integer):
            raise ValueError(f"action must be integers; got dtype {array.dtype}")
        if traced:
            return
        moves = array[:, 0] if self.msg_bits else array
        bad = np.flatnonzero((moves < 0) | (moves >= NUM_ACTIONS))
        if bad.size:
            raise ValueError(f"action {int(moves[bad[0]])} of agent {int(bad[0])} is outside 0..4 "
                             f"(0 noop, 1 forward, 2 left, 3 right, 4 toggle load)")
        if self.msg_bits and np.any((array[:, 1:] < 0) | (array[:, 1:] > 1)):
            raise ValueError("message bits must be 0 or 1")

    # ---------------------------------------------------------- spaces
    def action_space(self, params: RwareParams | None = None) -> spaces.Discrete:
        """Per agent: ``Discrete(5)`` (without messages); the joint action is :meth:`multi_action_space`."""
        return spaces.Discrete(NUM_ACTIONS)

    def multi_action_space(self, params: RwareParams | None = None) -> MultiDiscrete:
        if self.msg_bits:
            raise ValueError("with msg_bits > 0 the action is (N, 1 + msg_bits): 0..4, then bits 0..1")
        return MultiDiscrete(NUM_ACTIONS, (self.num_agents,))

    def observation_space(self, params: RwareParams | None = None) -> spaces.Box | TreeDict:
        """rware's per-agent space with a leading agent axis ``N``.

        FLATTENED: ``Box(-inf, inf, (N, D), float32)``. IMAGE: ``Box(0, high, (N, L, 2r+1, 2r+1), float32)``,
        ``high`` 4 on ``agent_direction`` channels, else 1. IMAGE_DICT: ``Dict(features: Box(-inf, inf, (N, 6)),
        image: that Box)``. DICT: nested :class:`TreeDict` s of int32 ``Box`` es, one per leaf of
        :func:`~wrl_jax.envs.rware.observation.dict_observation` (rware's ``Discrete(4)`` directions are
        ``Box(0, 3)``, its ``MultiBinary`` s ``Box(0, 1)``; the location ``Box(0, max(H, W))`` as rware's, or
        ``Box(0, 1)`` with ``normalised_coordinates``, where rware's values are ints 0 or 1).
        """
        n = self.num_agents
        if self.observation_type == "flattened":
            return spaces.Box(-jnp.inf, jnp.inf, (n, self.obs_size), jnp.float32)
        if self.observation_type in ("image", "image_dict"):
            shape = image_shape(self.sensor_range, self.image_observation_layers)
            high = np.broadcast_to(image_high(self.image_observation_layers)[None, :, None, None], (n, *shape))
            image = spaces.Box(0.0, jnp.asarray(high), (n, *shape), jnp.float32)
            if self.observation_type == "image":
                return image
            return TreeDict({"features": spaces.Box(-jnp.inf, jnp.inf, (n, FEATURES_SIZE), jnp.float32),
                             "image": image})
        cells = (2 * self.sensor_range + 1) ** 2
        i32 = jnp.int32
        location_high = 1 if self.normalised_coordinates else max(self.height, self.width)
        own = TreeDict({"location": spaces.Box(0, location_high, (n, 2), i32),
                        "carrying_shelf": spaces.Box(0, 1, (n, 1), i32), "direction": spaces.Box(0, 3, (n,), i32),
                        "on_highway": spaces.Box(0, 1, (n, 1), i32)})
        sensors = {"has_agent": spaces.Box(0, 1, (n, cells, 1), i32), "direction": spaces.Box(0, 3, (n, cells), i32)}
        if self.msg_bits:
            sensors["local_message"] = spaces.Box(0, 1, (n, cells, self.msg_bits), i32)
        sensors["has_shelf"] = spaces.Box(0, 1, (n, cells, 1), i32)
        sensors["shelf_requested"] = spaces.Box(0, 1, (n, cells, 1), i32)
        return TreeDict({"self": own, "sensors": TreeDict(sensors)})

    def global_state_space(self, params: RwareParams | None = None) -> spaces.Box:
        return spaces.Box(-jnp.inf, jnp.inf, (self.global_state_size(),), jnp.float32)

    def state_space(self, params: RwareParams | None = None) -> spaces.Dict:
        n, s = self.num_agents, self.num_shelves
        return spaces.Dict({
            "agent_x": spaces.Box(0, self.width - 1, (n,), jnp.int32),
            "agent_y": spaces.Box(0, self.height - 1, (n,), jnp.int32),
            "agent_dir": spaces.Box(0, 3, (n,), jnp.int32),
            "carrying": spaces.Box(-1, s - 1, (n,), jnp.int32),
            "has_delivered": spaces.Box(0, 1, (n,), jnp.bool_),
            "message": spaces.Box(0, 1, (n, self.msg_bits), jnp.float32),
            "shelf_x": spaces.Box(0, self.width - 1, (s,), jnp.int32),
            "shelf_y": spaces.Box(0, self.height - 1, (s,), jnp.int32),
            "queue": spaces.Box(0, s - 1, (self.queue_size,), jnp.int32),
            "time": spaces.Discrete(np.iinfo(np.int32).max),
            "inactive": spaces.Discrete(np.iinfo(np.int32).max),
        })
