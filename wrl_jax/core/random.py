"""Random words and key splits with ``jax.random``'s exact bits, computed without its CPU loop.

JAX lowers threefry on CPU as a 5-iteration ``while`` loop (a smaller
program). Under ``vmap`` every draw of an environment step then runs a
batch-sized loop outside the step's fusions, with its own copies of the
data: the largest single cost of a step (docs/throughput.md, docs/fleet.md).
Written out (20 rounds, 5 key injections) threefry is plain elementwise
integer arithmetic that XLA fuses into the step. For JAX's default keys
(typed threefry2x32 keys in the default partitionable mode) these functions
return exactly ``jax.random.bits`` / ``jax.random.split``; any other key
falls back to ``jax.random`` itself. ``tests/envs/warehouse/test_step_rng.py`` and
``tests/envs/fleet/test_fleet_env.py`` check the bits.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

_THREEFRY_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))


def threefry2x32(k0: jax.Array, k1: jax.Array, c0: jax.Array, c1: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Threefry-2x32 (20 rounds, 5 key injections) of counters ``(c0, c1)`` under key ``(k0, k1)``, uint32.

    The hash of ``jax.random``, written out (see the module docstring for why).
    """
    injected = (k0, k1, k0 ^ k1 ^ np.uint32(0x1BD11BDA))
    x0, x1 = c0 + k0, c1 + k1
    for block in range(5):
        for rotation in _THREEFRY_ROTATIONS[block % 2]:
            x0 = x0 + x1
            x1 = (x1 << np.uint32(rotation)) | (x1 >> np.uint32(32 - rotation))
            x1 = x0 ^ x1
        x0 = x0 + injected[(block + 1) % 3]
        x1 = x1 + injected[(block + 2) % 3] + np.uint32(block + 1)
    return x0, x1


def threefry_key_data(key: jax.Array) -> jax.Array | None:
    """``(2,)`` uint32 data of a typed threefry key under JAX's default partitionable mode, else ``None``.

    Only there are :func:`threefry2x32` of counters ``(0, n)`` the bits ``jax.random`` draws; other
    keys (legacy ``uint32[2]``, other implementations, the non-partitionable mode) use ``jax.random``.
    """
    if (jnp.issubdtype(key.dtype, jax.dtypes.prng_key) and str(jax.random.key_impl(key)) == "threefry2x32"
            and jax.config.jax_threefry_partitionable):
        return jax.random.key_data(key)
    return None


def random_words(key: jax.Array, count: int) -> jax.Array:
    """``jax.random.bits(key, (count,), jnp.uint32)``, bit for bit; unrolled for threefry keys."""
    data = threefry_key_data(key)
    if data is None:
        return jax.random.bits(key, (count,), jnp.uint32)
    x0, x1 = threefry2x32(data[0], data[1], np.uint32(0), jnp.arange(count, dtype=jnp.uint32))
    return x0 ^ x1



def random_word(key: jax.Array) -> jax.Array:
    """``jax.random.bits(key, (), jnp.uint32)``, bit for bit (one word: counter ``(0, 0)``)."""
    data = threefry_key_data(key)
    if data is None:
        return jax.random.bits(key, (), jnp.uint32)
    x0, x1 = threefry2x32(data[0], data[1], np.uint32(0), np.uint32(0))
    return x0 ^ x1


def split_key(key: jax.Array, index: int) -> jax.Array:
    """``jax.random.split(key)[index]``, bit for bit: for threefry keys one hash of counter ``(0, index)``.

    Why one half alone: the fleet's ``step`` needs the reset key only on the rare steps that truncate.
    """
    data = threefry_key_data(key)
    if data is None:
        return jax.random.split(key)[index]
    x0, x1 = threefry2x32(data[0], data[1], np.uint32(0), np.uint32(index))
    return jax.random.wrap_key_data(jnp.stack([x0, x1], axis=-1), impl="threefry2x32")


def split_keys(key: jax.Array, count: int) -> jax.Array:
    """``jax.random.split(key, count)``, bit for bit: for threefry keys one hash per new key, unrolled.

    Why: a program that draws a key for each of a batch of environments on every step (a rollout
    with random actions, a benchmark) otherwise runs ``jax.random``'s CPU loop of threefry on every
    step, a batch-sized ``while`` outside the step's fusions. Key ``n`` is the hash of counter
    ``(0, n)``, as :func:`split_key` computes for one index.
    """
    data = threefry_key_data(key)
    if data is None:
        return jax.random.split(key, count)
    x0, x1 = threefry2x32(data[0], data[1], np.uint32(0), jnp.arange(count, dtype=jnp.uint32))
    return jax.random.wrap_key_data(jnp.stack([x0, x1], axis=-1), impl="threefry2x32")


MAX_MODULUS = 1 << 23
"""Largest divisor :func:`words_modulo` is exact for (item and station counts are far below it)."""


def words_modulo(words: jax.Array, divisor: jax.Array) -> jax.Array:
    """``words % divisor`` for uint32 ``words`` and a uint32 ``divisor`` in ``1..MAX_MODULUS``, bit for bit.

    Why: the divisor of a task draw is data (a layout's item or station count), and x86 has no
    vector integer division, so XLA's CPU backend ran a scalar ``div`` per word: 6 to 8 % of a
    K = 8 fleet step (``bench/investigations/fleet_step_profile.py --trace``). Here the quotient is estimated with
    float32 reciprocal multiplies and corrected with integer arithmetic, all vector instructions.

    Exactness: ``f32(x) * f32(1/d)`` is three roundings from ``x / d`` (relative error just over
    ``3 * 2**-24``), so for ``x < 2**32`` the residual ``x - trunc(...) d`` (computed mod 2**32, read
    as int32) lies in ``(-769, 769 + d)``: an int32, and exact in float32 while ``d <= 2**23``. A
    second estimate on that residual is off by at most one, which two compares fix.
    ``tests/envs/warehouse/test_step_rng.py`` checks every divisor up to 4,096, powers of two and their neighbours
    up to ``MAX_MODULUS`` and random ones, against NumPy, on edge and random words and the words
    next to multiples of the divisor.
    """
    words = jnp.asarray(words, dtype=jnp.uint32)
    divisor = jnp.asarray(divisor, dtype=jnp.uint32)
    inverse = np.float32(1.0) / divisor.astype(jnp.float32)
    # float32(words) may round up to 2**32, which does not convert to uint32: cap at the largest float below it.
    estimate = jnp.minimum(words.astype(jnp.float32) * inverse, np.float32(4294967040.0))
    residual = jax.lax.bitcast_convert_type(words - estimate.astype(jnp.uint32) * divisor, jnp.int32)
    signed_divisor = divisor.astype(jnp.int32)
    residual = residual - jnp.floor(residual.astype(jnp.float32) * inverse).astype(jnp.int32) * signed_divisor
    residual = jnp.where(residual < 0, residual + signed_divisor, residual)
    residual = jnp.where(residual >= signed_divisor, residual - signed_divisor, residual)
    return residual.astype(jnp.uint32)
