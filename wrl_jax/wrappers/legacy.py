"""``LegacyStepAPI``: the 5-value ``(obs, state, reward, done, info)`` view of any wrl_jax environment.

Consumers written before gymnax 1.0 split ``done`` into ``terminated`` and
``truncated`` (PureJaxRL, rejax 0.1.3, purejaxql, Stoix's gymnax adapter) call
``env.step`` and unpack five values. This view gives them
``done = terminated | truncated`` (bool) and keeps both flags in ``info``
(``info["terminated"]``, ``info["truncated"]``), plus ``final_obs`` and
``final_observation``.

Caveat: such consumers treat every ``done`` as a terminal state, so they do
not bootstrap a truncated episode (the shift ending, the step limit) from its
last observation; on our warehouses that biases their value targets at the
time limit. Our own PPO and DQN use the 6-value API and bootstrap from
``info["final_obs"]``.

Unlike gymnax 1.0.1's ``LegacyStepAPIWrapper`` (whose ``__getattr__`` recurses
under ``copy.deepcopy``, which rejax applies to its config, env included), this
view copies, pickles and hashes cleanly: attribute forwarding never touches
``__dict__`` lookups for private or dunder names.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp


class LegacyStepAPI:
    """Wrap ``env`` so that ``step`` returns ``(obs, state, reward, done, info)``.

    Everything else (``reset``, ``default_params``, spaces, ``name``,
    ``num_actions``, ...) is the wrapped environment's. Hashable and equal by
    the wrapped environment, so it is a valid ``jit`` static argument.
    """

    def __init__(self, env: Any):
        self._env = env

    @property
    def env(self) -> Any:
        """The wrapped (6-value) environment."""
        return self._env

    def step(self, key: jax.Array, state: Any, action: Any, params: Any = None):
        obs, state, reward, terminated, truncated, info = self._env.step(key, state, action, params)
        done = jnp.logical_or(terminated, truncated)
        info = {**info, "terminated": terminated, "truncated": truncated}
        return obs, state, reward, done, info

    def reset(self, key: jax.Array, params: Any = None):
        return self._env.reset(key, params)

    def __getattr__(self, name: str) -> Any:
        # Called only for names not found normally. During copy/pickle the
        # instance may exist without ``_env`` yet: refuse private names instead
        # of recursing into ``self._env`` (gymnax's wrapper recurses forever).
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self._env, name)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, LegacyStepAPI) and other._env == self._env

    def __hash__(self) -> int:
        return hash(("LegacyStepAPI", self._env))

    def __repr__(self) -> str:
        return f"LegacyStepAPI({self._env!r})"
