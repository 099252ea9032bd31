"""RWARE as a PettingZoo ``ParallelEnv``: agents ``agent_0`` ... ``agent_{N-1}``, all acting at once.

For multi-agent code written against PettingZoo's parallel API. A sibling of the fleet's
adapter (:mod:`wrl_jax.wrappers.pettingzoo`) rather than a generalisation of it: the two differ in
agent names, action spaces (rware's message bits), global state and infos, and share only the
pattern. Each step is one jitted JAX transition (:mod:`wrl_jax.wrappers.rware_gymnasium`'s, so
the Gymnasium and PettingZoo adapters of a configuration share one compiled program).

The episode is shared: rware's single ``done`` (its time limit, or the inactivity limit) sets
every agent's ``truncations`` (a cut-off, as the JAX environment reports it; ``terminations``
stay False), and ``agents`` then becomes empty, as the API asks. ``state()`` is EPyMARL's RWARE
state, every observation concatenated (:meth:`~wrl_jax.envs.rware.env.Rware.global_state`).
Each agent's ``info`` holds ``delivered``: it stood on a goal that paid this step.

Randomness: ``reset(seed=s)`` seeds a NumPy generator from which every JAX key of the episode is
drawn (one per reset and per step), so the same seed replays the same episode.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import jax
import numpy as np

from wrl_jax.envs.rware.env import Rware
from wrl_jax.envs.rware.types import RwareParams
from wrl_jax.wrappers.parallel_base import SharedSpacesParallelEnv
from wrl_jax.wrappers.rware_gymnasium import (
    agent_action_space,
    agent_observation_space,
    agent_observations,
    build_rware,
    joint_action,
    next_key,
    render_text,
    reset_jit,
    transition_jit,
)


class RwareParallelEnv(SharedSpacesParallelEnv):
    """A registered rware id (or any :class:`Rware` and its params) as a ``ParallelEnv``.

    Args:
        name: a registered id (``"rware-tiny-4ag-v2"``).
        render_mode: ``None`` or ``"ansi"`` (a text map).
        env, params: instead of ``name``: an environment and its params (e.g. from ``make_rware``).
        **overrides: rware's settings the id leaves open (``reward_type``, ``max_steps``,
            ``max_inactivity_steps``, ``sensor_range``, ``msg_bits``, ``normalised_coordinates``).
    """

    metadata = {"name": "wrl_jax_rware_v2", "render_modes": ["ansi"], "is_parallelizable": True}

    def __init__(self, name: str | None = "rware-tiny-4ag-v2", render_mode: str | None = None, *,
                 env: Rware | None = None, params: RwareParams | None = None, **overrides: Any):
        if render_mode not in (None, "ansi"):
            raise ValueError(f"render_mode must be None or 'ansi', got {render_mode!r}")
        self.rware, self.params = build_rware(None if env is not None else name, env, params, overrides)
        self.render_mode = render_mode
        self.possible_agents = [f"agent_{i}" for i in range(self.rware.num_agents)]
        self.agents: list[str] = []
        self._obs_space = agent_observation_space(self.rware)
        self._action_space = agent_action_space(self.rware)
        # EPyMARL's RWARE state: every agent's observation, concatenated.
        self._state_space = gymnasium.spaces.Box(-np.inf, np.inf, (self.rware.global_state_size(),), np.float32)
        self._rng = np.random.default_rng()
        self._state = None
        self._obs: tuple | None = None  # one per agent, as rware gives them (any observation_type)
        self._flat: np.ndarray | None = None

    # ------------------------------------------------------------ API
    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        obs, self._state = reset_jit(self.rware, next_key(self._rng), self.params)
        self._keep(obs)
        self.agents = list(self.possible_agents)
        return {agent: self._obs[i] for i, agent in enumerate(self.agents)}, {agent: {} for agent in self.agents}

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise ValueError("the episode has ended (no agents left): call reset() first")
        missing = [agent for agent in self.agents if agent not in actions]
        unknown = sorted(set(actions) - set(self.agents))
        if missing or unknown:
            raise ValueError(f"actions must name every live agent once: missing {missing}, unknown {unknown}")
        joint = joint_action(self.rware, [actions[agent] for agent in self.agents])
        self._state, obs, reward, done, delivered = jax.device_get(
            transition_jit(self.rware, next_key(self._rng), self._state, joint, self.params))
        self._keep(obs)
        agents, done = self.agents, bool(done)
        observations = {agent: self._obs[i] for i, agent in enumerate(agents)}
        rewards = {agent: float(reward[i]) for i, agent in enumerate(agents)}
        terminations = {agent: False for agent in agents}
        truncations = {agent: done for agent in agents}
        infos = {agent: {"delivered": bool(delivered[i])} for i, agent in enumerate(agents)}
        if done:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def _keep(self, obs) -> None:
        self._obs = agent_observations(self.rware, obs)
        self._flat = np.asarray(self.rware.flat_obs(obs), np.float32)

    def state(self) -> np.ndarray:
        """The global state (for centralised critics): the agents' last observations, flattened and concatenated."""
        if self._flat is None:
            raise ValueError("call reset() first")
        return self._flat.reshape(-1).copy()

    def render(self):
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='ansi'")
            return None
        if self._state is None:
            raise ValueError("call reset() first")
        return render_text(self.rware, self._state, self.params)



def parallel_env(name: str = "rware-tiny-4ag-v2", render_mode: str | None = None, **overrides: Any) -> RwareParallelEnv:
    """``wrl_jax.wrappers.rware_pettingzoo.parallel_env("rware-tiny-4ag-v2")``: a :class:`RwareParallelEnv`."""
    return RwareParallelEnv(name, render_mode=render_mode, **overrides)
