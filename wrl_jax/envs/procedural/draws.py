"""The random words of the procedural generators and the helpers that turn them into integers, fractions and
thresholds (shared by :mod:`~wrl_jax.envs.procedural.generators` and :mod:`~wrl_jax.envs.procedural.route_floors`).

One attempt draws a small block of uint32 words with jax.random.bits (threefry):
a header of :data:`HEADER_WORDS` words (sizes, block dimensions, family, rates, item
count, and two seeds). The per-cell words (one for the floor, thresholded, one
for the placement scores) are a counter-based hash of the cell index under
those seeds (murmur3's finalizer, applied twice): threefry for 2 * H * W words
per attempt made the random numbers the largest cost of generation on CPU.
The cell words are uniform-looking and differ with the key; they are meant for
layout variety, not for statistics or cryptography.
"""

from __future__ import annotations

from typing import Protocol

import jax
import jax.numpy as jnp

from wrl_jax.envs.procedural.layout import fmix32

Floor = tuple[jax.Array, jax.Array, jax.Array]
"""``(shelves (H, W) bool, height, width)`` of one drawn floor, before placement."""


class FloorSettings(Protocol):
    """What a floor function reads of its generator's settings (a ``GeneratorConfig`` has them all)."""

    min_shape: tuple[int, int]
    max_shape: tuple[int, int]
    aisle: tuple[int, int]


HEADER_WORDS = 16


def cell_words(header: jax.Array, shape: tuple[int, int]) -> tuple[jax.Array, jax.Array]:
    """``(floor words, score words)``, each ``shape`` uint32, hashed from the cell index and two seeds."""
    index = jnp.arange(2 * shape[0] * shape[1], dtype=jnp.uint32)
    words = fmix32(fmix32(index * jnp.uint32(0x9E3779B9) + header[14]) ^ header[15])
    return words.reshape(2, *shape)[0], words.reshape(2, *shape)[1]


def below(word: jax.Array, count: jax.Array) -> jax.Array:
    """An integer uniform in ``0..count-1`` from a uint32 word (``count < 2**16``, bias below 2**-16)."""
    return (((word >> 16) * jnp.asarray(count, dtype=jnp.uint32)) >> 16).astype(jnp.int32)


def between(word: jax.Array, low: int | jax.Array, high: int | jax.Array) -> jax.Array:
    """An integer uniform in ``low..high`` (inclusive) from a uint32 word."""
    return jnp.asarray(low, dtype=jnp.int32) + below(word, jnp.asarray(high) - jnp.asarray(low) + 1)


def fraction(word: jax.Array, low: float, high: float) -> jax.Array:
    """A float32 uniform in ``[low, high)`` from a uint32 word (24-bit resolution)."""
    unit = (word >> 8).astype(jnp.float32) * jnp.float32(2.0**-24)
    return jnp.float32(low) + unit * jnp.float32(high - low)


def threshold(probability: jax.Array) -> jax.Array:
    """The uint32 below which a uniform word falls with ``probability`` (< 1)."""
    return (probability * jnp.float32(2.0**32)).astype(jnp.uint32)


def floor_size(header: jax.Array, config: FloorSettings,
               min_shape: tuple[int, int] | None = None) -> tuple[jax.Array, jax.Array]:
    """``(height, width)`` of a real floor, uniform per axis in ``min_shape`` (``config.min_shape``) ``..max_shape``."""
    (low_h, low_w), (high_h, high_w) = min_shape or config.min_shape, config.max_shape
    return between(header[0], low_h, high_h), between(header[1], low_w, high_w)
