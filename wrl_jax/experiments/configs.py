"""The training settings the experiments start from, and how to build them.

A *setting* is (algorithm, preset, environment, budget). ``build`` turns one
into an :class:`~wrl_jax.agents.base.Algorithm` plus its environment params;
the experiments then vary environment params (traced: one program) or the
environment object (a different observation: another program).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from wrl_jax.agents import dqn, dqn_config, ppo, ppo_config
from wrl_jax.core.registry import make
from wrl_jax.envs.warehouse.env import Warehouse
from wrl_jax.envs.warehouse.types import EnvParams

ENV_8 = "Warehouse-8x8-v0"
ENV_12 = "Warehouse-12x12-v0"

# Tiny budgets for --quick (checks the pipeline, not learning).
QUICK_STEPS = {("dqn", "default"): 3_200, ("dqn", "paper"): 2_000, ("ppo", "default"): 4_096, ("ppo", "paper"): 8_192}


@dataclasses.dataclass(frozen=True)
class Setting:
    """One training setting. ``total_timesteps=None`` keeps the preset's budget."""

    algo: str  # "dqn" or "ppo"
    preset: str  # "default" or "paper"
    env_name: str
    total_timesteps: int | None = None
    overrides: tuple[tuple[str, Any], ...] = ()  # extra config fields

    @property
    def label(self) -> str:
        size = self.env_name.split("-")[1]
        return f"{self.algo.upper()} {size} {self.preset}"

    def config(self, quick: bool = False):
        presets = dqn_config.PRESETS if self.algo == "dqn" else ppo_config.PRESETS
        if self.preset not in presets:
            raise ValueError(f"unknown {self.algo} preset {self.preset!r}; known: {sorted(presets)}")
        changes = dict(self.overrides)
        if quick:
            changes["total_timesteps"] = QUICK_STEPS[(self.algo, self.preset)]
        elif self.total_timesteps is not None:
            changes["total_timesteps"] = int(self.total_timesteps)
        return dataclasses.replace(presets[self.preset], **changes)


def build(setting: Setting, quick: bool = False, env: Warehouse | None = None,
          params: EnvParams | None = None, **env_overrides: Any):
    """``(algo, env, params)`` for a setting; ``env``/``params`` replace the registered ones."""
    if env is None:
        env, params = make(setting.env_name, **env_overrides)
    elif params is None:
        raise ValueError("pass params together with env")
    config = setting.config(quick)
    if setting.algo == "dqn":
        algo = dqn.DQN(config, env, params)
    elif setting.algo == "ppo":
        algo = ppo.PPO(config, env, params)
    else:
        raise ValueError(f"unknown algorithm {setting.algo!r}; use 'dqn' or 'ppo'")
    return algo, env, params


def env_params(env_name: str, **overrides: Any) -> EnvParams:
    """Params of a registered environment with reward constants / switches overridden."""
    return make(env_name, **overrides)[1]
