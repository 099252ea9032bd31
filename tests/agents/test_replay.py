"""The JAX replay buffer: circular writes, wrap-around, uniform sampling, pytree behaviour.

Compiling is the cost here: an eager ``jnp`` operation compiles once per operation and shape (hundreds of
tiny programs). So the test batches are built in NumPy, the buffer's ``add``, ``sample`` and
:func:`n_step_sample` run through the module's jitted :data:`add`, :data:`sample` and :data:`n_step`
(one program per shape, shared by every test), and results are read back as NumPy arrays (:func:`to_np`)
before they are indexed. ``test_empty_buffer_shapes_and_dtypes`` and the error tests call the methods
themselves.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wrl_jax.agents.replay import ReplayBuffer, Transition, n_step_sample

add = jax.jit(ReplayBuffer.add)
sample = jax.jit(ReplayBuffer.sample, static_argnums=2)
n_step = jax.jit(n_step_sample, static_argnums=(2, 3, 4))
empty = jax.jit(ReplayBuffer.empty, static_argnums=(0, 1, 2, 3))


def to_np(tree):
    return jax.tree.map(np.asarray, tree)


def batch(start: int, n: int, obs_size: int = 3) -> Transition:
    """``n`` transitions whose every field encodes its id ``start + i`` (NumPy arrays)."""
    ids = np.arange(start, start + n, dtype=np.int32)
    return Transition(
        obs=np.repeat(ids[:, None].astype(np.float32), obs_size, axis=1),
        action=ids % 4,
        reward=ids.astype(np.float32) * np.float32(0.5),
        next_obs=np.repeat(ids[:, None].astype(np.float32) + np.float32(0.25), obs_size, axis=1),
        terminated=(ids % 3) == 0,
    )


def test_empty_buffer_shapes_and_dtypes():
    buf = ReplayBuffer.empty(10, 7)
    assert buf.capacity == 10
    assert buf.data.obs.shape == (10, 7) and buf.data.obs.dtype == jnp.float32
    assert buf.data.next_obs.shape == (10, 7)
    assert buf.data.action.dtype == jnp.int32 and buf.data.terminated.dtype == jnp.bool_
    assert int(buf.size) == 0 and int(buf.position) == 0


@pytest.mark.parametrize("capacity, obs_size", [(0, 7), (5, 0), (-3, 2)])
def test_empty_rejects_bad_sizes(capacity, obs_size):
    with pytest.raises(ValueError, match="positive"):
        ReplayBuffer.empty(capacity, obs_size)


def test_add_rejects_batch_larger_than_capacity():
    with pytest.raises(ValueError, match="capacity 4"):
        empty(4, 3, None, False).add(batch(0, 5))


def test_sequential_adds_fill_in_order():
    buf = empty(8, 3, None, False)
    buf = add(buf, batch(0, 3))
    buf = to_np(add(buf, batch(3, 3)))
    assert int(buf.size) == 6 and int(buf.position) == 6
    np.testing.assert_array_equal(buf.data.obs[:6, 0], np.arange(6))
    np.testing.assert_array_equal(buf.data.action[:6], np.arange(6) % 4)
    np.testing.assert_array_equal(buf.data.terminated[:6], np.arange(6) % 3 == 0)
    # Unfilled rows stay zero.
    assert not np.any(buf.data.obs[6:])


@pytest.mark.parametrize("n", [1, 3, 4])
def test_wrap_around_overwrites_oldest(n):
    """After many adds the buffer holds exactly the newest ``capacity`` transitions, each at id % capacity."""
    capacity, total = 10, 0
    buf = empty(capacity, 2, None, False)
    for _ in range(13):  # 13, 39 or 52 transitions: more than the capacity, not a multiple of it
        buf = add(buf, batch(total, n, obs_size=2))
        total += n
    buf = to_np(buf)
    assert total > capacity and int(buf.size) == capacity
    assert int(buf.position) == total % capacity
    ids = buf.data.obs[:, 0].astype(int)
    newest = set(range(total - capacity, total))
    assert set(ids.tolist()) == newest
    for row, ident in enumerate(ids):
        assert ident % capacity == row  # transition id i lives in row i % capacity
        assert buf.data.next_obs[row, 1] == pytest.approx(ident + 0.25)
        assert float(buf.data.reward[row]) == pytest.approx(0.5 * ident)


def test_batch_straddling_the_end_wraps():
    buf = empty(5, 1, None, False)
    buf = add(buf, batch(0, 4, obs_size=1))
    buf = to_np(add(buf, batch(4, 3, obs_size=1)))  # rows 4, 0, 1
    np.testing.assert_array_equal(buf.data.obs[:, 0], [5, 6, 2, 3, 4])
    assert int(buf.position) == 2 and int(buf.size) == 5


def test_sample_only_from_filled_rows_and_rows_stay_together():
    buf = add(empty(100, 3, None, False), batch(0, 7))
    drawn = to_np(sample(buf, jax.random.PRNGKey(0), 4096))
    ids = drawn.obs[:, 0].astype(int)
    assert set(ids.tolist()) == set(range(7))  # every filled row drawn, no empty row
    # Fields of one sampled row belong to the same transition.
    np.testing.assert_array_equal(drawn.action, ids % 4)
    np.testing.assert_allclose(drawn.next_obs[:, 2], ids + 0.25)
    np.testing.assert_array_equal(drawn.terminated, ids % 3 == 0)


def test_sampling_is_uniform_chi_square():
    """Counts over 20 filled rows from 200,000 draws pass a chi-square test (df 19, p > 0.001)."""
    buf = add(empty(32, 1, None, False), batch(0, 20, obs_size=1))
    drawn = to_np(sample(buf, jax.random.PRNGKey(1), 200_000))
    counts = np.bincount(drawn.obs[:, 0].astype(int), minlength=20)
    assert counts.shape == (20,)
    expected = 200_000 / 20
    chi2 = float(((counts - expected) ** 2 / expected).sum())
    assert chi2 < 43.8, f"chi-square {chi2:.1f} with 19 dof: sampling is not uniform ({counts})"


def test_sampling_after_wrap_covers_the_whole_buffer_uniformly():
    buf = empty(16, 1, None, False)
    for start in range(0, 40, 4):
        buf = add(buf, batch(start, 4, obs_size=1))
    ids = np.asarray(sample(buf, jax.random.PRNGKey(2), 64_000).obs)[:, 0].astype(int)
    assert set(ids.tolist()) == set(range(24, 40))
    counts = np.bincount(ids - 24, minlength=16)
    assert counts.min() > 0.9 * 4000 and counts.max() < 1.1 * 4000


def test_sampling_depends_on_key_and_is_deterministic():
    buf = add(empty(64, 1, None, False), batch(0, 64, obs_size=1))
    a = sample(buf, jax.random.PRNGKey(3), 32)
    b = sample(buf, jax.random.PRNGKey(3), 32)
    c = sample(buf, jax.random.PRNGKey(4), 32)
    np.testing.assert_array_equal(np.asarray(a.obs), np.asarray(b.obs))
    assert not np.array_equal(np.asarray(a.obs), np.asarray(c.obs))


def test_buffer_is_a_pytree_that_vmaps():
    """A batch of buffers (one per seed) adds and samples under vmap, each seed its own rows."""
    seeds = 3
    per_seed = jax.tree.map(lambda x: np.stack([x] * seeds), batch(0, 2, obs_size=2))
    offsets = np.float32(100.0) * np.arange(seeds, dtype=np.float32)
    per_seed = per_seed.replace(obs=per_seed.obs + offsets[:, None, None])

    @jax.jit
    def add_and_sample(per_seed, keys):
        bufs = jax.vmap(lambda _: ReplayBuffer.empty(6, 2))(jnp.arange(seeds))
        bufs = jax.vmap(lambda b, t: b.add(t))(bufs, per_seed)
        return bufs, jax.vmap(lambda b, k: b.sample(k, 50))(bufs, keys)

    bufs, samples = add_and_sample(per_seed, jax.random.split(jax.random.PRNGKey(5), seeds))
    assert bufs.data.obs.shape == (seeds, 6, 2) and bufs.capacity == 6
    np.testing.assert_array_equal(np.asarray(bufs.size), [2, 2, 2])
    sampled_obs = np.asarray(samples.obs)
    for s in range(seeds):
        assert set(sampled_obs[s, :, 0].tolist()) <= {100.0 * s, 100.0 * s + 1}
    leaves = jax.tree.leaves(bufs)
    assert len(leaves) == 7  # five data arrays, position, size


def test_n_step_sample_sums_rewards_of_the_same_env_and_stops_at_episode_ends():
    """Two environments write rows alternately (stride 2). Env 0's rewards are 1, 2, 4, 8, 16 with its
    episode truncated after the second; env 1's are 100, 200, ... never ending."""
    buffer = empty(16, 1, None, True)
    for t in range(5):
        buffer = add(buffer, Transition(
            obs=np.array([[10.0 * t], [10.0 * t + 1]], np.float32), action=np.zeros(2, np.int32),
            reward=np.array([2.0**t, 100.0 * (t + 1)], np.float32),
            next_obs=np.array([[10.0 * t + 5], [10.0 * t + 6]], np.float32),
            terminated=np.zeros(2, bool), truncated=np.array([t == 1, False])))
    batch, discount = n_step(buffer, jax.random.key(0), 256, 3, 2, np.float32(0.5))
    obs, reward, next_obs, discount = (np.asarray(x) for x in (batch.obs, batch.reward, batch.next_obs, discount))
    obs, next_obs = obs[:, 0], next_obs[:, 0]
    expected = {  # first obs -> (n-step reward, next_obs, discount)
        0.0: (1 + 0.5 * 2, 15.0, 0.25),           # stops after the truncation at t = 1
        10.0: (2.0, 15.0, 0.5),                   # the truncated step itself
        20.0: (4 + 0.5 * 8 + 0.25 * 16, 45.0, 0.125),
        30.0: (8 + 0.5 * 16, 45.0, 0.25),         # row t = 5 is not written yet
        40.0: (16.0, 45.0, 0.5),
        1.0: (100 + 0.5 * 200 + 0.25 * 300, 26.0, 0.125),
        41.0: (500.0, 46.0, 0.5),
    }
    assert set(expected) <= set(obs.tolist())
    for first, (total, last, factor) in expected.items():
        rows = obs == first
        np.testing.assert_allclose(reward[rows], total)
        np.testing.assert_allclose(next_obs[rows], last)
        np.testing.assert_allclose(discount[rows], factor)
    one, gamma = n_step(buffer, jax.random.key(0), 8, 1, 2, np.float32(0.5))
    plain = sample(buffer, jax.random.key(0), 8)
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree_util.tree_leaves(one), jax.tree_util.tree_leaves(plain)))
    with pytest.raises(ValueError, match="truncation=True"):
        n_step_sample(empty(4, 1, None, False), jax.random.key(0), 2, 3, 1, jnp.float32(0.5))
