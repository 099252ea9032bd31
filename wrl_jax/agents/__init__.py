"""Hand-written RL algorithms (PPO, DQN, SAC, TD3) and the contract the training driver uses.

The algorithm registry lives here: a name -> the module defining its ``SPEC``
(an :class:`~wrl_jax.agents.base.AlgoSpec`), imported on first use.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from wrl_jax.agents.base import AlgoSpec

ALGORITHM_MODULES = {
    "ppo": "wrl_jax.agents.ppo",
    "dqn": "wrl_jax.agents.dqn",
    "sac": "wrl_jax.agents.sac",
    "td3": "wrl_jax.agents.td3",
}
"""Algorithm name -> module defining ``SPEC`` (an :class:`~wrl_jax.agents.base.AlgoSpec`)."""


def get_spec(name: str) -> AlgoSpec:
    """The :class:`AlgoSpec` of a registered algorithm."""
    if name not in ALGORITHM_MODULES:
        raise ValueError(f"unknown algorithm {name!r}; known: {sorted(ALGORITHM_MODULES)}")
    return importlib.import_module(ALGORITHM_MODULES[name]).SPEC


