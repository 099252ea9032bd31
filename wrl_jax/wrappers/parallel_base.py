"""What every wrl_jax PettingZoo parallel environment shares: one observation and one action space for
all agents (shared-parameter policies see the same shapes), a global state, and clear errors."""

from __future__ import annotations

import gymnasium
from pettingzoo import ParallelEnv


class SharedSpacesParallelEnv(ParallelEnv):
    """A ``ParallelEnv`` whose agents all have ``_obs_space`` and ``_action_space``; ``_state_space`` is
    the global state's. Subclasses set those three and ``possible_agents``."""

    _obs_space: gymnasium.spaces.Space
    _action_space: gymnasium.spaces.Space
    _state_space: gymnasium.spaces.Box

    def observation_space(self, agent: str) -> gymnasium.spaces.Space:
        self._check_agent(agent)
        return self._obs_space

    def action_space(self, agent: str) -> gymnasium.spaces.Space:
        self._check_agent(agent)
        return self._action_space

    @property
    def state_space(self) -> gymnasium.spaces.Box:
        """The global state's space (what a centralized critic reads)."""
        return self._state_space

    def close(self) -> None:
        self._state = None

    def _check_agent(self, agent: str) -> None:
        if agent not in self.possible_agents:
            first, last = self.possible_agents[0], self.possible_agents[-1]
            raise ValueError(f"unknown agent {agent!r}; agents are {first} .. {last}")
