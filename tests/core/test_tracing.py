"""``traced_once``: the replayed trace computes what the function computes, lowers to the same program as
calling the function in the cond, and the function's Python runs once where eval_shape + cond ran it twice."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wrl_jax.core.tracing import traced_once


def _work(calls: list):
    def work(carry, index):
        calls.append(1)  # counts the traces: Python runs once per trace
        total, key = carry
        noise = jax.random.normal(jax.random.fold_in(key, index), (3,))
        return (total + noise.sum() * index, key), {"noise": noise, "index": index}
    return work


def _with_cond(replayed: bool, calls: list):
    work = _work(calls)

    def program(carry, index):
        if replayed:
            branch, shapes = traced_once(work, carry, index)
        else:
            branch, shapes = work, jax.eval_shape(work, carry, index)
        skipped = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes[1])
        return jax.lax.cond(index % 2 == 0, branch, lambda c, i: (c, skipped), carry, index)

    return program


def test_replay_computes_the_function_and_its_shapes():
    calls: list = []
    args = ((jnp.float32(1.5), jax.random.key(3)), jnp.int32(4))
    replay, shapes = traced_once(_work(calls), *args)
    (total, _), out = replay(*args)
    (expected_total, _), expected = _work([])(*args)
    np.testing.assert_array_equal(np.asarray(total), np.asarray(expected_total))
    np.testing.assert_array_equal(np.asarray(out["noise"]), np.asarray(expected["noise"]))
    assert shapes[1]["noise"].shape == (3,) and shapes[1]["index"].dtype == jnp.int32
    assert len(calls) == 1


def test_the_cond_lowers_to_the_same_program_with_one_trace():
    args = ((jnp.float32(0.0), jax.random.key(0)), jnp.int32(0))
    once, twice = [], []
    text_once = jax.jit(_with_cond(True, once)).lower(*args).as_text()
    text_twice = jax.jit(_with_cond(False, twice)).lower(*args).as_text()
    assert text_once == text_twice
    assert len(once) == 1 and len(twice) == 2
    results = [jax.jit(_with_cond(flag, []))((jnp.float32(2.0), jax.random.key(1)), jnp.int32(6)) for flag in (1, 0)]
    for a, b in zip(jax.tree.leaves(results[0]), jax.tree.leaves(results[1])):
        if not jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_replay_refuses_arguments_of_another_structure():
    replay, _ = traced_once(lambda d: d["a"] + d["b"], {"a": jnp.float32(1.0), "b": jnp.float32(2.0)})
    with pytest.raises(TypeError, match="traced with"):
        replay({"a": jnp.float32(1.0), "c": jnp.float32(2.0)})
