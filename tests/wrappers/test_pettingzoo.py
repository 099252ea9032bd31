"""The fleet as a PettingZoo ParallelEnv: PettingZoo's own API test, and agreement with the JAX fleet."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

import wrl_jax
from wrl_jax.wrappers.pettingzoo import parallel_env


def test_parallel_api_test_passes():
    env = parallel_env(name="Fleet-12x12-v0", num_robots=4, render_mode=None, max_steps=60)
    assert env.possible_agents == ["robot_0", "robot_1", "robot_2", "robot_3"]
    parallel_api_test(env, num_cycles=200)


def test_steps_are_the_jax_fleets_and_the_shift_ends():
    env = parallel_env(num_robots=2, max_steps=12)
    obs, infos = env.reset(seed=3)
    jax_env, params = wrl_jax.make("Fleet-12x12-v0", num_robots=2, max_steps=12)
    # The same first key (the adapter's generator, seeded the same way) gives the same first observation.
    key = jax.random.key(int(np.random.default_rng(3).integers(0, 2**31 - 1)))
    first, state = jax.jit(jax_env.reset)(key, params)  # eagerly, the fleet's reset compiles op by op
    np.testing.assert_array_equal(np.stack([obs["robot_0"], obs["robot_1"]]), np.asarray(first))
    steps, ended = 0, False
    while not ended:
        obs, rewards, terms, truncs, infos = env.step({"robot_0": 1, "robot_1": 3})
        steps += 1
        assert set(rewards) == {"robot_0", "robot_1"} and not any(terms.values())
        assert set(infos["robot_0"]) >= {"shelf_hit", "wall_bump", "robot_block", "picked_up", "delivered"}
        ended = all(truncs.values())
    assert steps == 12 and env.agents == []
    with pytest.raises(ValueError, match="shift has ended"):
        env.step({"robot_0": 0, "robot_1": 0})
    assert env.state().shape == env.state_space.shape


def test_seeds_replay_and_differ():
    def first_obs(seed):
        return parallel_env(num_robots=4).reset(seed=seed)[0]["robot_3"]

    np.testing.assert_array_equal(first_obs(5), first_obs(5))
    assert any(not np.array_equal(first_obs(5), first_obs(s)) for s in (6, 7, 8))


def test_bad_input_is_a_clear_error():
    env = parallel_env(num_robots=2, render_mode="ansi")
    env.reset(seed=0)
    assert "robot" in env.render() or "\n" in env.render()
    with pytest.raises(ValueError, match="missing"):
        env.step({"robot_0": 0})
    with pytest.raises(ValueError, match="outside 0..4"):
        env.step({"robot_0": 0, "robot_1": 7})
    with pytest.raises(ValueError, match="integers"):
        env.step({"robot_0": 0.5, "robot_1": 1})
    with pytest.raises(ValueError, match="unknown agent"):
        env.observation_space("robot_9")
    with pytest.raises(ValueError, match="single robot|serves fleets"):
        parallel_env(name="Warehouse-8x8-v0")
    with pytest.raises(ValueError, match="render_mode"):
        parallel_env(render_mode="human")
