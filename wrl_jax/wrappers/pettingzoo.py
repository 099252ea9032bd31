"""The fleet as a PettingZoo ``ParallelEnv``: agents ``robot_0`` ... ``robot_{K-1}``, all acting at once.

For multi-agent code written against PettingZoo's parallel API (and its
``parallel_api_test``). Each call runs one jitted JAX transition of the whole
fleet (:class:`~wrl_jax.envs.fleet.env.Fleet`): the conflict rule, rewards and
observations are exactly the JAX environment's. The shift is shared: when it
ends (``truncations`` all True; fleet episodes never terminate) ``agents``
becomes empty, as the API asks, and ``reset`` starts a new shift. For speed,
train on the JAX environment itself (vmapped, scanned); this adapter is for
compatibility.

Randomness: ``reset(seed=s)`` seeds a NumPy generator from which every JAX key
of the shift is drawn, so the same seed replays the same shift.
"""

from __future__ import annotations

import functools
from typing import Any

import gymnasium
import jax
import numpy as np

from wrl_jax.core import registry
from wrl_jax.envs.fleet.dynamics import FLAGS
from wrl_jax.envs.fleet.env import Fleet
from wrl_jax.envs.fleet.render import render_ascii, render_frame
from wrl_jax.wrappers.parallel_base import SharedSpacesParallelEnv


@functools.partial(jax.jit, static_argnums=0)
def _reset(env: Fleet, key: jax.Array, params: Any):
    return env.reset_env(key, params)


@functools.partial(jax.jit, static_argnums=0)
def _transition(env: Fleet, key: jax.Array, state: Any, action: jax.Array, params: Any):
    return env.transition(key, state, action, params)


@functools.partial(jax.jit, static_argnums=0)
def _global_state(env: Fleet, state: Any, params: Any):
    return env.global_state(state, params)


class FleetParallelEnv(SharedSpacesParallelEnv):
    """A registered fleet environment (or any :class:`Fleet` and its params) as a ``ParallelEnv``.

    Args:
        name: a registered fleet name (``"Fleet-12x12-v0"``, ``"Fleet-32x32-v0"``).
        num_robots: robots of the fleet (static).
        render_mode: ``None``, ``"rgb_array"`` (an RGB frame) or ``"ansi"`` (text).
        env, params: instead of ``name``: an environment and its params.
        **overrides: the fleet factory's overrides (``max_steps``, reward constants, ...).
    """

    metadata = {"name": "wrl_jax_fleet_v0", "render_modes": ["rgb_array", "ansi"], "is_parallelizable": True}

    def __init__(
        self,
        name: str | None = "Fleet-12x12-v0",
        num_robots: int = 4,
        render_mode: str | None = None,
        *,
        env: Fleet | None = None,
        params: Any = None,
        **overrides: Any,
    ):
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None, 'rgb_array' or 'ansi', got {render_mode!r}")
        if env is None:
            family = registry.entry(name).family
            if family != "fleet":
                raise ValueError(f"{name!r} is a {family} environment; the PettingZoo adapter serves fleets")
            env, params = registry.make(name, num_robots=num_robots, **overrides)
        elif params is None:
            params = env.default_params
        self.fleet, self.params = env.without_default_params(), params
        self.render_mode = render_mode
        self.possible_agents = [f"robot_{i}" for i in range(env.num_robots)]
        self.agents: list[str] = []
        self._obs_space = gymnasium.spaces.Box(0.0, 1.0, (env.obs_size,), np.float32)
        self._action_space = gymnasium.spaces.Discrete(env.num_actions)
        # The documented global state (wrl_jax.envs.fleet.observation.global_state).
        self._state_space = gymnasium.spaces.Box(0.0, 1.0, (env.global_state_size(),), np.float32)
        self._rng = np.random.default_rng()
        self._state = None

    # ------------------------------------------------------------ API
    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        obs, self._state = _reset(self.fleet, self._next_key(), self.params)
        self.agents = list(self.possible_agents)
        obs = np.asarray(obs)
        return {agent: obs[i] for i, agent in enumerate(self.agents)}, {agent: {} for agent in self.agents}

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise ValueError("the shift has ended (no agents left): call reset() first")
        missing = [agent for agent in self.agents if agent not in actions]
        unknown = sorted(set(actions) - set(self.agents))
        if missing or unknown:
            raise ValueError(f"actions must name every live agent once: missing {missing}, unknown {unknown}")
        joint = np.asarray([actions[agent] for agent in self.agents])
        if joint.dtype.kind not in "iu":
            raise ValueError(f"actions must be integers 0..4, got {[actions[a] for a in self.agents]}")
        self.fleet.check_action(joint.astype(np.int32))
        obs, self._state, reward, terminated, truncated, info = jax.device_get(
            _transition(self.fleet, self._next_key(), self._state, joint.astype(np.int32), self.params)
        )
        agents = self.agents
        observations = {agent: obs[i] for i, agent in enumerate(agents)}
        rewards = {agent: float(reward[i]) for i, agent in enumerate(agents)}
        terminations = {agent: bool(terminated) for agent in agents}
        truncations = {agent: bool(truncated) for agent in agents}
        infos = {agent: {flag: bool(info[flag][i]) for flag in FLAGS if flag in info} for i, agent in enumerate(agents)}
        if terminated or truncated:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        """The fleet's global state (for centralised critics), float32."""
        self._require_state()
        return np.asarray(_global_state(self.fleet, self._state, self.params))

    def render(self):
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'ansi'")
            return None
        self._require_state()
        if self.render_mode == "ansi":
            return render_ascii(self._state, self.params)
        return np.asarray(render_frame(self._state, self.params))

    # ------------------------------------------------------------ helpers
    def _next_key(self) -> jax.Array:
        return jax.random.key(int(self._rng.integers(0, 2**31 - 1)))


    def _require_state(self) -> None:
        if self._state is None:
            raise ValueError("call reset() first")


def parallel_env(name: str = "Fleet-12x12-v0", num_robots: int = 4, render_mode: str | None = None, **overrides):
    """``wrl_jax.wrappers.pettingzoo.parallel_env(name="Fleet-12x12-v0", num_robots=4)``: a :class:`FleetParallelEnv`."""
    return FleetParallelEnv(name, num_robots=num_robots, render_mode=render_mode, **overrides)
