"""The RWARE step's fast paths: its auto-reset gives the base class's bits, its reset draws are uniform.

Programs: each test's own, compiled at LLVM level 0 (``fast_compile``); the step test's resets, actions and both
rollouts are one program per key type."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import fast_compile

from wrl_jax.core.environment import Environment
from wrl_jax.envs.rware import make_rware
from wrl_jax.envs.rware.dynamics import SEQUENTIAL_LIMIT, distinct


@pytest.mark.parametrize("typed", [True, False])
def test_the_step_is_the_base_class_step_bit_for_bit(typed):
    """Four environments out of step with each other (inactivity and time limits end them at different
    steps), so the batched auto-reset runs for some and not others; every output equals the base class's."""
    env, params = make_rware(2, layout="x.x\ng.g", request_queue_size=1, max_steps=7, max_inactivity_steps=3)
    make_key = jax.random.key if typed else jax.random.PRNGKey

    @fast_compile.jit  # the resets, the actions and both rollouts: one program
    def rollouts():
        keys = jax.vmap(make_key)(jnp.arange(4))
        _, state = jax.vmap(env.reset)(keys)
        state = state.replace(time=jnp.array([0, 2, 4, 6], jnp.int32))
        actions = jax.random.randint(make_key(9), (12, 4, 2), 0, 5, dtype=jnp.int32)

        def rollout(step):
            def body(state, inputs):
                key, action = inputs
                out = jax.vmap(step, in_axes=(0, 0, 0, None))(jax.vmap(jax.random.fold_in, in_axes=(0, None))(
                    keys, key), state, action, params)
                return out[1], out

            return jax.lax.scan(body, state, (jnp.arange(12), actions))[1]

        return rollout(env.step), rollout(lambda *a: Environment.step(env, *a))

    ours, base = rollouts()
    assert jax.tree.structure(ours) == jax.tree.structure(base)
    for got, want in zip(jax.tree.leaves(ours), jax.tree.leaves(base), strict=True):
        np.testing.assert_array_equal(got, want)
    done = np.asarray(ours[4])
    assert done.any() and not done.all(axis=1).any(), "some environments reset at a step, others not"


def test_reset_draws_are_uniform_ordered_samples_without_replacement():
    """``distinct`` (the reset's cells and queue): every ordered triple of 6 values equally likely, no repeats,
    on both its paths (one by one up to SEQUENTIAL_LIMIT draws, ``top_k`` above)."""
    keys = jax.random.split(jax.random.key(0), 60_000)
    triples = np.asarray(fast_compile.jit(jax.vmap(lambda k: distinct(k, 6, 3)))(keys))
    counts = np.unique(triples, axis=0, return_counts=True)[1]
    assert len(counts) == 120 and triples.min() >= 0 and triples.max() < 6
    assert all(len(set(row)) == 3 for row in triples[:1000])
    chi2 = ((counts - 500) ** 2 / 500).sum()
    assert chi2 < 180, chi2  # 119 degrees of freedom: p < 0.0003 above 180
    for population, count in ((110, 19), (300, SEQUENTIAL_LIMIT + 1)):
        draws = np.asarray(fast_compile.jit(jax.vmap(lambda k, p=population, c=count: distinct(k, p, c)))(keys[:64]))
        assert all(len(set(row)) == count for row in draws) and draws.min() >= 0 and draws.max() < population
