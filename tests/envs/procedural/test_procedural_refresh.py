"""The layout pool renewed while training (issue 13): ``pool_refresh`` slots before every update.

A learner calls ``env.params_for_update(params, update)`` at the start of each update (PPO and
DQN do, for any environment whose ``refreshes_params`` is true). For the procedural warehouse it
replaces the oldest ``pool_refresh`` slots with layouts drawn from the seed's training stream,
a function of the update index alone; these tests check what is replaced, that the precomputed
arrays stay those of a from-scratch pool, that training carries the renewed pool (same bits
again), that the final report can list every layout training saw, and the
errors.

Programs are shared: one compiled refresh (``refresh_step``) serves every test, and every pool of the
default generator here has the fixture's 64 slots (the initial pool, four updates' refreshes regenerated at
once, the held-out set): the pool program of the other procedural modules' 64-layout pools (the session's
cache serves it).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wrl_jax import training
from wrl_jax.agents import ppo_config
from wrl_jax.agents.dqn import DQN
from wrl_jax.agents.dqn_config import DQNConfig
from wrl_jax.agents.ppo import PPO
from wrl_jax.envs.procedural import layout_sets
from wrl_jax.envs.procedural.env import ProceduralWarehouse
from wrl_jax.envs.procedural.pool import generate_pool, pool_hashes, refresh_slots
from wrl_jax.envs.procedural.registration import make_procedural

POOL, REFRESH = 64, 16
SMALL = {"seed": 3, "pool_size": POOL, "pool_refresh": REFRESH, "max_steps": 40}


@pytest.fixture(scope="module")
def small():
    return make_procedural(**SMALL)


@pytest.fixture(scope="module")
def refresh_step(small):
    """``env.params_for_update``, jitted once for the module."""
    return jax.jit(small[0].params_for_update)


@pytest.fixture(scope="module")
def refreshed(small, refresh_step):
    """The params after each of the updates 0..4 (one compiled refresh)."""
    out = [small[1]]
    for update in range(5):
        out.append(refresh_step(out[-1], jnp.int32(update)))
    return out


def _leaves(tree):
    return [np.asarray(leaf) for leaf in jax.tree.leaves(tree)]


def _slot_hashes(params):
    return pool_hashes(params.pool)


def test_a_refresh_renews_the_oldest_slots_and_recomputes_their_arrays(small, refreshed):
    env, params = small
    initial = _slot_hashes(params)
    for update in range(5):
        before, after = _slot_hashes(refreshed[update]), _slot_hashes(refreshed[update + 1])
        slots = np.asarray(refresh_slots(jnp.int32(update), REFRESH, POOL))
        assert sorted(slots) == sorted((update * REFRESH + np.arange(REFRESH)) % POOL)
        kept = np.setdiff1d(np.arange(POOL), slots)
        np.testing.assert_array_equal(after[kept], before[kept])
        assert (after[slots] != before[slots]).mean() > 0.9  # fresh layouts (a tiny floor may repeat)
        assert np.isin(after[slots], initial).mean() < 0.2
    # Update 4 wraps around to the first slots again: the whole pool was renewed once.
    assert np.isin(_slot_hashes(refreshed[4]), initial).mean() < 0.2
    # The walls and first observations of every slot are those of the new pool built from scratch.
    final = refreshed[5]
    scratch = env.with_pool(final, final.pool)
    for a, b in zip(_leaves((final.walls, final.reset_obs)), _leaves((scratch.walls, scratch.reset_obs))):
        np.testing.assert_array_equal(a, b)
    # Fresh layouts are solvable: every real item has a finite BFS route (the generator's guarantee).
    items = np.arange(final.pool.optimal.shape[1])[None, :] < np.asarray(final.pool.layouts.num_items)[:, None]
    optimal = np.asarray(final.pool.optimal)[items]
    assert (optimal > 0).all() and (optimal < 16 * 16 * 2).all()


def test_the_refresh_is_a_function_of_the_update_alone(small, refresh_step, refreshed):
    env, params = small
    again = refresh_step(params, jnp.int32(0))
    for a, b in zip(_leaves(again), _leaves(refreshed[1])):
        np.testing.assert_array_equal(a, b)
    other = refresh_step(params, jnp.int32(1))
    assert not np.array_equal(_slot_hashes(other), _slot_hashes(refreshed[1]))
    # Without pool_refresh the params are returned as they are (no program change for other runs).
    fixed_env, fixed = make_procedural(**{**SMALL, "pool_refresh": 0})
    assert not fixed_env.refreshes_params and fixed_env.params_for_update(fixed, 0) is fixed


def test_training_layout_hashes_list_every_layout_training_saw(small, refreshed):
    env, params = small
    # After 4 updates (4 x 16 = 64 refreshed slots, regenerated in one call of the pool's own program).
    seen = env.training_layout_hashes(refreshed[4], updates=4)
    for state in refreshed[:5]:
        assert np.isin(_slot_hashes(state), seen).all()
    initial = pool_hashes(generate_pool(jax.random.key(SMALL["seed"]), POOL, env.generator))
    assert np.isin(initial, seen).all()
    assert seen.size <= POOL + 4 * REFRESH and seen.size > POOL + 2 * REFRESH
    with pytest.raises(ValueError, match="number of updates"):
        env.training_layout_hashes(params, updates=None)
    # The held-out set drops what training saw, given as hashes.
    heldout, overlap = layout_sets.heldout_set(env.generator, seen, count=POOL)
    assert overlap + heldout.size == POOL and not np.isin(pool_hashes(heldout.layouts), seen).any()


def test_ppo_and_dqn_train_on_the_renewed_pool(small, refreshed):
    env, params = small
    config = dataclasses.replace(ppo_config.PROCEDURAL_MLP, num_envs=4, num_steps=8, num_minibatches=2, update_epochs=1,
                                 hidden_sizes=(16,), total_timesteps=3 * 4 * 8)
    loop = training.LoopConfig(chunk_updates=3, eval_every=0, progress=False)
    result = training.run(training.Trainer(PPO(config, env, params), [0, 1], loop))
    for seed in range(2):  # every seed carries the pool after updates 0, 1 and 2
        pool = jax.tree.map(lambda leaf, s=seed: leaf[s], result.runners.env_params)
        for a, b in zip(_leaves(pool), _leaves(refreshed[3])):
            np.testing.assert_array_equal(a, b)
    # (Chunking and resuming change nothing: the driver's tests cover any runner state, this one included.)
    dqn = DQN(DQNConfig(num_envs=4, train_freq=1, batch_size=8, hidden_sizes=(16,), buffer_size=64,
                        learning_starts=8, total_timesteps=2 * 4), env, params)
    done = training.run(training.Trainer(dqn, [0], loop))
    for a, b in zip(_leaves(jax.tree.map(lambda leaf: leaf[0], done.runners.env_params)), _leaves(refreshed[2])):
        np.testing.assert_array_equal(a, b)


def test_bad_refresh_settings_fail_clearly(small, tmp_path):
    env, _ = small
    with pytest.raises(ValueError, match="pool_refresh must be in 0..pool_size=64"):
        make_procedural(**{**SMALL, "pool_refresh": 65})
    with pytest.raises(ValueError, match="pool_refresh must be in"):
        make_procedural(**{**SMALL, "pool_refresh": -1})
    with pytest.raises(ValueError, match="needs a generated pool"):
        ProceduralWarehouse(generator=env.generator, pool_size=POOL, pool_refresh=4)
    from wrl_jax.cli.options import build, parse

    with pytest.raises(ValueError, match="--pool-refresh: procedural options"):
        parse("ppo", ["--env", "Warehouse-8x8-v0", "--pool-refresh", "4", "--out", str(tmp_path / "a")])
    with pytest.raises(ValueError, match="--view-radius: fleet or procedural options"):
        parse("ppo", ["--env", "Warehouse-8x8-v0", "--view-radius", "1", "--out", str(tmp_path / "b")])
    with pytest.raises(ValueError, match="--observe-last-action: fleet or procedural options"):
        parse("ppo", ["--env", "Warehouse-8x8-v0", "--observe-last-action", "True", "--out", str(tmp_path / "d")])
    fleet = parse("ppo", ["--env", "Fleet-12x12-v0", "--observe-last-action", "True", "--out", str(tmp_path / "g")])
    assert fleet.env.overrides()["observe_last_action"] is True
    with pytest.raises(ValueError, match="--observe-map: procedural options"):
        parse("ppo", ["--env", "Fleet-12x12-v0", "--observe-map", "True", "--out", str(tmp_path / "h")])
    mapped = parse("ppo", ["--env", "Procedural-Warehouse-v0", "--observe-map", "True", "--out", str(tmp_path / "i")])
    assert mapped.env.overrides()["observe_map"] is True
    with pytest.raises(ValueError, match="--observe-rays: procedural options"):
        parse("ppo", ["--env", "Fleet-12x12-v0", "--observe-rays", "True", "--out", str(tmp_path / "j")])
    rays = parse("ppo", ["--env", "Procedural-Warehouse-v0", "--observe-rays", "True", "--pool-size", "64",
                         "--out", str(tmp_path / "k")])  # the pool size of `command` below: one pool program
    assert build(rays.spec, rays.config, rays.env).env.observe_rays
    with pytest.raises(ValueError, match="--visit-levels: procedural options"):
        parse("ppo", ["--env", "Fleet-12x12-v0", "--visit-levels", "3", "--out", str(tmp_path / "e")])
    with pytest.raises(ValueError, match="--observe-priority: fleet options"):
        parse("ppo", ["--env", "Procedural-Warehouse-v0", "--observe-priority", "True", "--out", str(tmp_path / "f")])
    command = parse("ppo", ["--env", "Procedural-Warehouse-v0", "--pool-size", "64", "--pool-refresh", "16",
                            "--view-radius", "1", "--out", str(tmp_path / "c")])
    assert command.env.overrides() == {"pool_size": 64, "pool_refresh": 16, "view_radius": 1,
                                       **ppo_config.PROCEDURAL_ENV_DEFAULTS, "observe_map": True}  # the preset's
    algo = build(command.spec, command.config, command.env)
    assert (algo.env.pool_size, algo.env.pool_refresh, algo.env.view_radius) == (64, 16, 1)
