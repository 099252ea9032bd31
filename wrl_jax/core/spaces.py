"""Spaces gymnax lacks, on its ``Space`` base: what multi-agent families declare."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from wrl_jax.core.gymnax_base import spaces


class MultiDiscrete(spaces.Space):
    """``shape`` independent integer choices in ``0..n-1`` (one action per agent; gymnax has no MultiDiscrete)."""

    def __init__(self, n: int, shape: tuple[int, ...]):
        self.n, self.shape, self.dtype = int(n), tuple(shape), jnp.int32

    def sample(self, rng: jax.Array) -> jax.Array:
        return jax.random.randint(rng, self.shape, 0, self.n, dtype=self.dtype)

    def contains(self, x: jax.Array) -> jax.Array:
        x = jnp.asarray(x)
        return jnp.logical_and(x.shape == self.shape, jnp.all((x >= 0) & (x < self.n)))


class TreeDict(spaces.Dict):
    """gymnax's ``Dict`` space for observations that are dicts (gymnax's ``contains`` reads attributes)."""

    def contains(self, x: Any) -> jax.Array:
        inside = jnp.ones((), bool)
        for key, space in self.spaces.items():
            inside = inside & jnp.asarray(space.contains(x[key]))
        return inside
