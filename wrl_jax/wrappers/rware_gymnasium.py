"""RWARE behind rware 2.0.0's own Gymnasium surface: ``gymnasium.make("wrl_jax/rware-tiny-4ag-v2")``.

So that code written for ``gymnasium.make("rware-tiny-4ag-v2")`` (EPyMARL's wrapper, scripts,
notebooks) runs on the JAX environment unchanged: the same spaces (a ``Tuple`` of ``Discrete(5)``,
or of ``MultiDiscrete([5, 2, ...])`` with messages, and a ``Tuple`` of rware's per-agent observation
space: ``Box(-inf, inf, (D,), float32)`` by default, and rware's own spaces and Python types for
``observation_type="dict"``, ``"image"`` and ``"image_dict"``, :func:`agent_observation_space` and
:func:`agent_observations`), ``reset(seed) -> (obs tuple, {})`` and ``step(actions) -> (obs tuple, rewards list of
np.float64, done, False, {})`` with rware's types, and rware's attribute names on the unwrapped
env (``n_agents``, ``grid_size``, ``goals``, ...). rware's single ``done`` (its time limit, or
inactivity limit) is reported as rware reports it: ``terminated=done``, ``truncated=False``
(the JAX environment itself calls it truncation). Stepping after ``done`` goes on, as in rware.

Each step is one jitted call of the JAX transition (the environment a static argument, its params
ordinary arrays, so every instance of a configuration shares one program). Its keys come from
the Gymnasium generator: ``reset(seed=s)`` seeds it, then each reset and each step draws one key
(:func:`next_key`), so a seed replays an episode. rware's own random draws (numpy's) cannot be
reproduced in JAX: the same seed gives another episode than rware's, with the same rules.
"""

from __future__ import annotations

import functools
from collections import OrderedDict
from typing import Any

import gymnasium as gym
import jax
import numpy as np
from gymnasium import spaces

from wrl_jax.core import registry
from wrl_jax.envs.rware.env import Rware
from wrl_jax.envs.rware.observation_image import image_high
from wrl_jax.envs.rware.types import NUM_ACTIONS, RwareParams, RwareState
from wrl_jax.wrappers.registration import GYM_NAMESPACE

ACTION_NAMES = ("NOOP", "FORWARD", "LEFT", "RIGHT", "TOGGLE_LOAD")
HEADINGS = "^v<>"
"""Agent glyphs of the ``ansi`` render, by heading: up, down, left, right."""


# ------------------------------------------------------------------ jitted calls (shared with PettingZoo)
@functools.partial(jax.jit, static_argnums=0)
def reset_jit(env: Rware, key: jax.Array, params: RwareParams):
    """``(obs (N, D), state)`` of a fresh episode."""
    return env.reset_env(key, params)


@functools.partial(jax.jit, static_argnums=0)
def transition_jit(env: Rware, key: jax.Array, state: RwareState, action: jax.Array, params: RwareParams):
    """One non-resetting transition: ``(state, obs (N, D), reward (N,), done (), delivered (N,))``."""
    obs, state, reward, _, truncated, info = env.transition(key, state, action, params)
    return state, obs, reward, truncated, info["delivered"]


def next_key(rng: np.random.Generator) -> jax.Array:
    """A JAX key drawn from a Gymnasium generator (one draw per reset and per step)."""
    return jax.random.key(int(rng.integers(0, 2**32, dtype=np.uint64)))


def build_rware(name: str | None, env: Rware | None, params: RwareParams | None,
                overrides: dict[str, Any]) -> tuple[Rware, RwareParams]:
    """A registered rware id (with ``make_named``'s overrides), or a given environment and params."""
    if env is not None:
        if name is not None or overrides:
            raise ValueError("give either a registered rware id (with overrides) or env and params, not both")
        return env.without_default_params(), env.default_params if params is None else params
    if name is None:
        raise ValueError("give a registered rware id (e.g. 'rware-tiny-4ag-v2') or env and params")
    name = name.removeprefix(GYM_NAMESPACE + "/")
    family = registry.entry(name).family
    if family != "rware":
        raise ValueError(f"{name!r} is a {family} environment; this adapter serves the rware ids")
    env, params = registry.make(name, **overrides)
    return env.without_default_params(), params


def agent_action_space(env: Rware) -> spaces.Space:
    """rware's per-agent action space: ``Discrete(5)``, or ``MultiDiscrete([5, 2, ...])`` with message bits."""
    if env.msg_bits:
        return spaces.MultiDiscrete([NUM_ACTIONS, *[2] * env.msg_bits])
    return spaces.Discrete(NUM_ACTIONS)


def agent_observation_space(env: Rware) -> spaces.Space:
    """rware's per-agent observation space for the env's ``observation_type``, built as rware builds it."""
    kind = env.observation_type
    if kind == "flattened":
        return spaces.Box(low=-float("inf"), high=float("inf"), shape=(env.obs_size,), dtype=np.float32)
    side = 2 * env.sensor_range + 1
    if kind in ("image", "image_dict"):  # rware's _use_image_obs: bounds per layer, 4 for agent_direction
        high = np.broadcast_to(image_high(env.image_observation_layers)[:, None, None],
                               (len(env.image_observation_layers), side, side)).copy()
        image = spaces.Box(np.zeros_like(high), high, dtype=np.float32)
        if kind == "image":
            return image
        features = spaces.Box(low=-float("inf"), high=float("inf"), shape=(6,), dtype=np.float32)
        return spaces.Dict({"image": image, "features": features})  # Gymnasium sorts the keys, as rware's
    if env.normalised_coordinates:  # rware's _use_slow_obs
        location = spaces.Box(low=np.zeros(2), high=np.ones(2), shape=(2,), dtype=np.float32)
    else:
        location = spaces.Box(low=np.zeros(2), high=np.ones(2) * max(env.height, env.width), shape=(2,),
                              dtype=np.int32)
    own = spaces.Dict(OrderedDict({"location": location, "carrying_shelf": spaces.MultiBinary(1),
                                   "direction": spaces.Discrete(4), "on_highway": spaces.MultiBinary(1)}))
    sensor = OrderedDict({"has_agent": spaces.MultiBinary(1), "direction": spaces.Discrete(4)})
    if env.msg_bits:
        sensor["local_message"] = spaces.MultiBinary(env.msg_bits)
    sensor.update({"has_shelf": spaces.MultiBinary(1), "shelf_requested": spaces.MultiBinary(1)})
    return spaces.Dict(OrderedDict({"self": own, "sensors": spaces.Tuple(side * side * (spaces.Dict(sensor),))}))


def agent_observations(env: Rware, obs: Any) -> tuple:
    """The JAX observation (any type, leading agent axis) as rware returns it: a tuple, one per agent.

    FLATTENED and IMAGE: writable float32 arrays; IMAGE_DICT: ``{"image", "features"}``; DICT: rware's
    nested dicts with its Python types (lists of ints for the ``MultiBinary(1)`` values, ints for
    directions, an int32 location, a float64 message of an agent and ``[0] * M`` of an empty cell). One
    difference: without messages rware's sensor dicts also hold ``"local_message": None``, a key its
    space lacks (Gymnasium's env checker then fails rware's first ``reset``); here the key is left out.
    """
    obs = jax.device_get(obs)
    count = env.num_agents
    if env.observation_type in ("flattened", "image"):
        return tuple(np.array(row, dtype=np.float32) for row in np.asarray(obs))
    if env.observation_type == "image_dict":
        return tuple({"image": np.array(obs["image"][i], np.float32),
                      "features": np.array(obs["features"][i], np.float32)} for i in range(count))
    own, sensors = jax.tree.map(np.asarray, obs["self"]), jax.tree.map(np.asarray, obs["sensors"])
    agents = []
    for i in range(count):
        cells = []
        for k in range(sensors["direction"].shape[1]):
            has_agent = int(sensors["has_agent"][i, k, 0])
            cell = {"has_agent": [has_agent], "direction": int(sensors["direction"][i, k])}
            if env.msg_bits:
                cell["local_message"] = (sensors["local_message"][i, k].astype(np.float64) if has_agent
                                         else env.msg_bits * [0])
            cell["has_shelf"] = [int(sensors["has_shelf"][i, k, 0])]
            cell["shelf_requested"] = [int(sensors["shelf_requested"][i, k, 0])]
            cells.append(cell)
        agents.append({"self": {"location": np.array(own["location"][i], dtype=np.int32),
                                "carrying_shelf": [int(own["carrying_shelf"][i, 0])],
                                "direction": int(own["direction"][i]),
                                "on_highway": [int(own["on_highway"][i, 0])]},
                       "sensors": tuple(cells)})
    return tuple(agents)


def joint_action(env: Rware, actions: Any) -> np.ndarray:
    """rware's ``step`` argument (one action per agent; with messages, ``[action, bit, ...]`` each) as the
    JAX action: ``(N,)`` or ``(N, 1 + M)`` int32. rware's ``Action`` members are taken by value.

    Raises ``ValueError`` naming the agent for a wrong count, a non-integer or an out-of-range value.
    """
    try:
        items = list(actions)
    except TypeError:
        raise ValueError(f"actions must be a sequence of {env.num_agents} per-agent actions, got {actions!r}") from None
    if len(items) != env.num_agents:
        raise ValueError(f"actions must hold one action per agent: {env.num_agents} expected, got {len(items)}")
    width = 1 + env.msg_bits
    rows = []
    for i, item in enumerate(items):
        value = np.asarray([getattr(v, "value", v) for v in np.ravel(np.asarray(item, dtype=object))])
        if value.dtype.kind not in "iu" or value.shape != (width,):
            what = f"[action 0..4, {env.msg_bits} bits 0/1]" if env.msg_bits else "an integer 0..4"
            raise ValueError(f"action of agent {i} must be {what}, got {item!r}")
        if not 0 <= value[0] < NUM_ACTIONS:
            raise ValueError(f"action {int(value[0])} of agent {i} is outside 0..4 ({', '.join(ACTION_NAMES)})")
        if np.any((value[1:] < 0) | (value[1:] > 1)):
            raise ValueError(f"message bits of agent {i} must be 0 or 1, got {value[1:].tolist()}")
        rows.append(value)
    joint = np.stack(rows).astype(np.int32)
    return joint if env.msg_bits else joint[:, 0]


def render_text(env: Rware, state: RwareState, params: RwareParams) -> str:
    """A text map: ``.`` highway, ``g`` goal, ``x`` shelf, ``X`` requested shelf, ``^v<>`` an agent by heading,
    ``A`` a loaded agent; then a line with each agent's heading (``*``: loaded) and the step count."""
    s = jax.tree.map(np.asarray, jax.device_get(state))
    highway, goals = np.asarray(params.highway), np.asarray(params.goals)
    grid = np.where(highway, ".", " ").astype("<U1")
    grid[goals[:, 1], goals[:, 0]] = "g"
    requested = set(s.queue.tolist())
    for i, (x, y) in enumerate(zip(s.shelf_x, s.shelf_y)):
        grid[y, x] = "X" if i in requested else "x"
    legend = []
    for i, (x, y, d, c) in enumerate(zip(s.agent_x, s.agent_y, s.agent_dir, s.carrying)):
        grid[y, x] = "A" if c >= 0 else HEADINGS[d]
        legend.append(f"{i}:{HEADINGS[d]}{'*' if c >= 0 else ''}")
    return "\n".join("".join(row) for row in grid) + f"\nagents {' '.join(legend)} (* loaded)  t={int(s.time)}"


class RwareGymEnv(gym.Env):
    """An rware id (or any :class:`~wrl_jax.envs.rware.env.Rware`) with rware 2.0.0's Gymnasium API.

    Args:
        name: a registered id (``"rware-tiny-4ag-v2"``, with or without the ``wrl_jax/`` namespace).
        render_mode: ``None`` or ``"ansi"`` (a text map; rware's pyglet viewer is not ported).
        env, params: instead of ``name``: an environment and its params (e.g. from ``make_rware``).
        **overrides: ``make_named``'s overrides, by rware's names: ``reward_type``, ``max_steps``,
            ``max_inactivity_steps``, ``sensor_range``, ``msg_bits``, ``normalised_coordinates``,
            ``observation_type``, ``image_observation_layers``, ``image_observation_directional`` (rware's
            enum members accepted by name).
    """

    metadata = {"render_modes": ["ansi"], "render_fps": 10}

    def __init__(self, name: str | None = None, *, render_mode: str | None = None, env: Rware | None = None,
                 params: RwareParams | None = None, **overrides: Any):
        if render_mode not in (None, "ansi"):
            raise ValueError(f"render_mode must be None or 'ansi' (rware's pyglet viewer is not ported), "
                             f"got {render_mode!r}")
        self.env, self.params = build_rware(name, env, params, overrides)
        self.name = name if env is None else self.env.name
        self.render_mode = render_mode
        self.action_space = spaces.Tuple(tuple(agent_action_space(self.env) for _ in range(self.env.num_agents)))
        self.observation_space = spaces.Tuple(
            tuple(agent_observation_space(self.env) for _ in range(self.env.num_agents)))
        # rware's attribute names, read by code written for it (EPyMARL reads env.unwrapped.n_agents).
        self.n_agents = self.env.num_agents
        self.msg_bits = self.env.msg_bits
        self.sensor_range = self.env.sensor_range
        self.request_queue_size = self.env.queue_size
        self.grid_size = (self.env.height, self.env.width)
        self.goals = [tuple(int(v) for v in goal) for goal in np.asarray(self.params.goals)]
        self.max_steps = int(self.params.max_steps) or None
        self.max_inactivity_steps = int(self.params.max_inactivity_steps) or None
        self.reward_type = int(self.params.reward_type)  # rware's RewardType value: 0 global, 1 individual, 2 two-stage
        self.normalised_coordinates = self.env.normalised_coordinates
        self.observation_type = self.env.observation_type  # a name: "flattened", "dict", "image", "image_dict"
        if self.observation_type in ("image", "image_dict"):
            self.image_observation_layers = list(self.env.image_observation_layers)  # names
            self.image_observation_directional = self.env.image_observation_directional
        self.reward_range = (0, 1)
        self._state: RwareState | None = None

    @property
    def state(self) -> RwareState:
        """The JAX state of the current episode (call ``reset`` first)."""
        if self._state is None:
            raise gym.error.ResetNeeded("call reset() before using the environment")
        return self._state

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed, options=options)
        obs, self._state = reset_jit(self.env, next_key(self.np_random), self.params)
        return self._split(obs), {}

    def step(self, actions):
        joint = joint_action(self.env, actions)
        self._state, obs, reward, done, _ = jax.device_get(
            transition_jit(self.env, next_key(self.np_random), self.state, joint, self.params))
        return self._split(obs), list(np.asarray(reward, np.float64)), bool(done), False, {}

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='ansi'")
            return None
        return render_text(self.env, self.state, self.params)

    def _split(self, obs) -> tuple:
        """rware's observation: a tuple, one per agent (writable float32 vectors by default)."""
        return agent_observations(self.env, obs)

    def __repr__(self) -> str:
        return f"RwareGymEnv({self.name or 'custom'}, n_agents={self.n_agents}, obs={self.env.obs_size})"
