"""RWARE as a PettingZoo ParallelEnv: PettingZoo's own API test, agreement with the JAX environment, errors."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

import wrl_jax
from wrl_jax.wrappers.rware_gymnasium import next_key, reset_jit, transition_jit
from wrl_jax.wrappers.rware_pettingzoo import RwareParallelEnv, parallel_env


@pytest.mark.filterwarnings("ignore:.*precision lowered by casting:UserWarning")  # rware's normalised Box
@pytest.mark.parametrize("overrides", [
    {}, {"msg_bits": 2}, {"observation_type": "dict", "msg_bits": 2, "normalised_coordinates": True},
    {"observation_type": "image_dict", "image_observation_directional": False, "sensor_range": 2,
     "image_observation_layers": ["accessible", "shelves", "accessible"]},
])
def test_parallel_api_test_passes(overrides):
    # tiny-4ag, as the Gymnasium adapter's tests (the dict and image_dict settings are those of
    # test_rware_observation_types.py::test_gymnasium_adapter_has_rwares_surface): the programs are shared when
    # they run in one process, and the session's compilation cache serves the compiles in another.
    env = parallel_env("rware-tiny-4ag-v2", max_steps=150, **overrides)
    assert env.possible_agents == ["agent_0", "agent_1", "agent_2", "agent_3"]
    parallel_api_test(env, num_cycles=200)  # past the episode's end: agents empty, then reset


def test_steps_are_the_jax_environments_and_the_episode_ends_for_all():
    """Agent order, keys, rewards, flags and the end of the episode, against the JAX transition from the same
    keys (its jitted form, which the Gymnasium adapter's test checks against the plain ``env.transition``)."""
    env = parallel_env("rware-tiny-4ag-v2", max_steps=12)
    obs, infos = env.reset(seed=3)
    jax_env, params = wrl_jax.make("rware-tiny-4ag-v2", max_steps=12)
    jax_env = jax_env.without_default_params()
    rng = np.random.default_rng(3)  # the adapter's generator, seeded the same way
    first, state = reset_jit(jax_env, next_key(rng), params)
    np.testing.assert_array_equal(np.stack([obs[a] for a in env.possible_agents]), np.asarray(first))
    assert env.state().shape == env.state_space.shape == (4 * 71,)
    np.testing.assert_array_equal(env.state(), np.asarray(first).reshape(-1))  # EPyMARL's state
    actions = {"agent_0": 1, "agent_1": 3, "agent_2": 4, "agent_3": 2}
    for t in range(12):
        obs, rewards, terms, truncs, infos = env.step(actions)
        state, want_obs, want_reward, want_done, delivered = transition_jit(
            jax_env, next_key(rng), state, np.array(list(actions.values()), np.int32), params)
        np.testing.assert_array_equal(np.stack([obs[a] for a in env.possible_agents]), np.asarray(want_obs))
        assert [rewards[a] for a in env.possible_agents] == np.asarray(want_reward).tolist()
        assert not any(terms.values()) and set(truncs.values()) == {bool(want_done)} == {t == 11}
        assert [infos[a]["delivered"] for a in env.possible_agents] == np.asarray(delivered).tolist()
    assert env.agents == []
    with pytest.raises(ValueError, match="episode has ended"):
        env.step(actions)


def test_bad_input_is_a_clear_error():
    env = RwareParallelEnv("rware-tiny-4ag-v2", render_mode="ansi")
    with pytest.raises(ValueError, match="call reset"):
        env.state()
    env.reset(seed=0)
    assert env.render().splitlines()[-1].startswith("agents 0:")
    with pytest.raises(ValueError, match="missing \\['agent_3'\\]"):
        env.step({"agent_0": 0, "agent_1": 0, "agent_2": 0})
    with pytest.raises(ValueError, match="unknown \\['agent_9'\\]"):
        env.step({**{f"agent_{i}": 0 for i in range(4)}, "agent_9": 1})
    with pytest.raises(ValueError, match="action 5 of agent 2 is outside 0..4"):
        env.step({"agent_0": 0, "agent_1": 0, "agent_2": 5, "agent_3": 0})
    with pytest.raises(ValueError, match="unknown agent"):
        env.observation_space("robot_0")
    with pytest.raises(ValueError, match="serves the rware ids"):
        RwareParallelEnv("Fleet-12x12-v0")
