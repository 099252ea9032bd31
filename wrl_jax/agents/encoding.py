"""What a policy network sees: an environment's observation as a vector, raw or with its grid
coordinates one-hot (``PPOConfig.obs_encoding``), per agent for a multi-agent environment.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from wrl_jax.agents.base import observation_size
from wrl_jax.core.environment import Environment


def agent_observation_size(env: Environment) -> int:
    """Width of one agent's flat observation: the whole observation for a single-agent env."""
    if getattr(env, "num_agents", None) is None:
        return observation_size(env)
    return int(math.prod(env.observation_space().shape[1:]))


def onehot_coordinates(env: Environment, encoding: str) -> tuple[int, int, int, int] | None:
    """The env's cell coordinates (``env.onehot_coordinates()``) for ``"onehot"``; ``None`` for ``"raw"``."""
    if encoding == "raw":
        return None
    coordinates = env.onehot_coordinates() if hasattr(env, "onehot_coordinates") else None
    if coordinates is None:
        raise ValueError(
            f"obs_encoding='onehot' one-hot encodes an observation's grid coordinates; {env.name} (a "
            f"{getattr(env, 'family', '?')!r} environment) does not declare any: use obs_encoding='raw'"
        )
    return coordinates


def encoded_size(env: Environment, encoding: str) -> int:
    """Width of :func:`encode_observation`'s output (per agent)."""
    size = agent_observation_size(env)
    if encoding == "raw":
        return size
    count, values, _, _ = onehot_coordinates(env, encoding)
    return count * values + (size - count)


def encode_observation(obs: jax.Array, env: Environment, encoding: str) -> jax.Array:
    """The network input as a vector: ``"raw"``: ``obs`` itself; ``"onehot"``: every
    coordinate one-hot over its values (for the warehouse ``i / (N - 1)``, ``i`` in
    -1..N-1, over N + 1 values), then the rest of the observation unchanged.
    ``PPO.forward`` computes the first layer on it without building it."""
    if encoding == "raw":
        return obs
    coordinates = onehot_coordinates(env, encoding)
    count, values = coordinates[0], coordinates[1]
    onehot = jax.nn.one_hot(onehot_rows(obs, coordinates), count * values, dtype=jnp.float32).sum(axis=-2)
    return jnp.concatenate([onehot, obs[..., count:]], axis=-1)


def onehot_rows(obs: jax.Array, coordinates: tuple[int, int, int, int]) -> jax.Array:
    """Where the 1s of :func:`encode_observation` are: ``(..., count)`` int32 indices.

    ``coordinates = (count, values, offset, scale)`` (``env.onehot_coordinates()``).
    Coordinate ``c`` with cell index ``i`` lands at ``c * values + i + offset``; for
    the warehouse (``offset`` 1 for a picked-up item's ``-1``) ``round(x * (N - 1))``
    recovers ``i`` exactly: the observation is the float32 nearest to ``i / (N - 1)``.
    """
    count, values, offset, scale = coordinates
    cells = jnp.round(obs[..., :count] * scale).astype(jnp.int32) + offset
    return cells + jnp.arange(count, dtype=jnp.int32) * values
