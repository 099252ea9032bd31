"""The warehouse step's unrolled reset word is ``jax.random.bits`` bit for bit (issue 12's throughput work).

:func:`wrl_jax.core.random.random_word` replaces JAX's looped CPU
lowering of threefry by the same arithmetic written out, so it must give the
very same words for every key, and fall back to ``jax.random.bits`` for keys
it does not handle; the step built on it must equal the step built on
``jax.random.bits``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wrl_jax
from wrl_jax.core.random import random_word
from wrl_jax.envs.warehouse.env import item_from_word, threefry_word


def bits(key):
    return jax.random.bits(key, (), jnp.uint32)


@pytest.mark.parametrize("impl", ["threefry2x32", "philox4x32"])
def test_random_word_equals_jax_random_bits(impl):
    keys = jax.random.split(jax.random.key(123, impl=impl), 20_000)
    ours = np.asarray(jax.jit(jax.vmap(random_word))(keys))
    np.testing.assert_array_equal(ours, np.asarray(jax.jit(jax.vmap(bits))(keys)))
    assert len(np.unique(ours)) > 19_900  # not a constant or a short cycle
    # Unbatched and outside jit too.
    np.testing.assert_array_equal(random_word(keys[7]), bits(keys[7]))


def test_legacy_raw_keys_fall_back():
    raw = jax.random.PRNGKey(5)  # uint32[2], not a typed key
    assert random_word(raw) == bits(raw)


def test_threefry_word_is_the_unrolled_block():
    key = jax.random.key(9)
    np.testing.assert_array_equal(threefry_word(jax.random.key_data(key)), bits(key))
    # A different key gives a different word (the arithmetic reads both key words).
    data = np.asarray(jax.random.key_data(key)).copy()
    data[1] ^= 1
    assert threefry_word(jnp.asarray(data)) != threefry_word(jax.random.key_data(key))


def test_step_equals_the_step_on_jax_random_bits():
    env, params = wrl_jax.make("Warehouse-8x8-v0")
    batch, horizon = 64, 200  # longer than the 150-step limit, so every environment resets

    def looped_step(key, state, action, params):
        return env.step_to_item(state, action, item_from_word(bits(key), params.num_items), params)

    def rollout(step, key):
        vstep = jax.vmap(step, in_axes=(0, 0, 0, None))
        _, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key, batch), params)

        def body(state, key):
            action_key, step_key = jax.random.split(key)
            actions = jax.random.randint(action_key, (batch,), 0, 4)
            out = vstep(jax.random.split(step_key, batch), state, actions, params)
            return out[1], out[:5] + (out[5]["final_obs"],)

        return jax.lax.scan(body, state, jax.random.split(key, horizon))

    key = jax.random.key(3)
    ours = jax.jit(lambda k: rollout(env.step, k))(key)
    looped = jax.jit(lambda k: rollout(looped_step, k))(key)
    for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(looped)):
        np.testing.assert_array_equal(a, b)
    terminated, truncated = ours[1][3], ours[1][4]
    assert bool((terminated | truncated).any())


@pytest.mark.parametrize("impl", ["threefry2x32", "philox4x32"])
def test_split_keys_and_random_words_equal_jax_random(impl):
    """The unrolled many-key split and word draw give jax.random's own bits (philox falls back to it)."""
    from wrl_jax.core.random import random_words, split_keys

    split = jax.jit(split_keys, static_argnums=1)  # one program per count (eagerly: op by op)
    words = jax.jit(random_words, static_argnums=1)
    for seed in (0, 7, 123):
        key = jax.random.key(seed, impl=impl)
        for count in (1, 3, 1000):
            np.testing.assert_array_equal(jax.random.key_data(split(key, count)),
                                          jax.random.key_data(jax.random.split(key, count)))
        np.testing.assert_array_equal(words(key, 257), jax.random.bits(key, (257,), jnp.uint32))
    keys = jax.random.split(jax.random.key(5, impl=impl), 4)
    assert len({tuple(np.asarray(jax.random.key_data(split(k, 2))).ravel()) for k in keys}) == 4



def test_words_modulo_equals_integer_remainder():
    """The division-free remainder of the fleet's task draw, against NumPy's ``%``: every divisor up to
    4,096, the largest ones it is documented for, on random words, the extremes and words next to
    multiples of the divisor (where a quotient estimate off by one would show)."""
    from wrl_jax.core.random import MAX_MODULUS, words_modulo

    rng = np.random.default_rng(7)
    powers = 2 ** np.arange(12, 24)
    divisors = np.unique(np.concatenate([np.arange(1, 4097), powers - 1, powers, powers + 1,
                                         rng.integers(4097, MAX_MODULUS + 1, 500)]))
    divisors = divisors[divisors <= MAX_MODULUS].astype(np.uint32)
    edges = np.array([0, 1, 2**24 - 1, 2**24, 2**31 - 1, 2**31, 2**32 - 129, 2**32 - 128, 2**32 - 2, 2**32 - 1],
                     dtype=np.uint64)
    words = np.concatenate([rng.integers(0, 2**32, 4000, dtype=np.uint64), edges]).astype(np.uint32)
    got = np.asarray(jax.jit(jax.vmap(words_modulo, in_axes=(None, 0)))(words, divisors))
    np.testing.assert_array_equal(got, words[None, :] % divisors[:, None])
    multiples = rng.integers(0, 2**32, (divisors.size, 16), dtype=np.uint64) // divisors[:, None] * divisors[:, None]
    near = (np.concatenate([multiples - 1, multiples, multiples + 1], axis=1) % 2**32).astype(np.uint32)
    got = np.asarray(jax.jit(jax.vmap(words_modulo))(near, divisors))
    np.testing.assert_array_equal(got, near % divisors[:, None])
