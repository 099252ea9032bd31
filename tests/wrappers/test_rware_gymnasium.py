"""rware's Gymnasium API on the JAX environment: one script, run against rware and against ours, sees the
same surface; every adapter step is the JAX transition's; bad actions are clear errors."""

from __future__ import annotations

import functools
import warnings

import gymnasium as gym
import jax
import numpy as np
import pytest

import wrl_jax  # noqa: F401  (registers wrl_jax/rware-*)
from wrl_jax.envs.rware import make_rware
from wrl_jax.wrappers.rware_gymnasium import RwareGymEnv, next_key

SMALL_LAYOUT = "x.x\ng.g"
"""Two shelves over two goals: a floor small enough for random actions to deliver now and then."""


def describe(env: gym.Env, steps: int) -> dict:
    """What code written for rware sees: spaces, types, shapes, attributes, warnings; not the values."""

    def kind(value):
        if isinstance(value, (tuple, list)):
            return (type(value).__name__, [kind(v) for v in value])
        if isinstance(value, np.ndarray):
            return ("ndarray", str(value.dtype), value.shape, value.flags.writeable)
        return type(value).__name__

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = {"action_space": repr(env.action_space), "observation_space": repr(env.observation_space),
               "spaces": (env.action_space, env.observation_space),  # Gymnasium's space equality
               "wrappers": [type(w).__name__ for w in _wrappers(env)], "max_episode_steps": env.spec.max_episode_steps}
        obs, info = env.reset(seed=1)
        out["reset"] = (kind(obs), info, env.observation_space.contains(obs))
        env.action_space.seed(2)
        for t in range(steps):
            obs, rewards, done, truncated, info = env.step(env.action_space.sample())
            out.setdefault("step", (kind(obs), kind(rewards), kind(done), truncated, info))
            assert env.observation_space.contains(obs)
        env.step([1] * len(env.action_space) if not env.unwrapped.msg_bits else
                 [np.array([1] + [0] * env.unwrapped.msg_bits)] * len(env.action_space))
        u = env.unwrapped
        out["attributes"] = (u.n_agents, u.msg_bits, u.sensor_range, u.request_queue_size, u.grid_size,
                             [tuple(int(v) for v in g) for g in u.goals], u.max_steps, u.max_inactivity_steps,
                             u.reward_range)
    out["warnings"] = sorted({str(w.message) for w in caught})
    return out


def _wrappers(env):
    while isinstance(env, gym.Wrapper):
        yield env
        env = env.env


@pytest.mark.parametrize("kwargs", [{}, {"msg_bits": 2}])
def test_a_script_for_rware_sees_the_same_surface_on_ours(kwargs):
    pytest.importorskip("rware")
    theirs = describe(gym.make("rware-tiny-4ag-v2", **kwargs), steps=5)
    ours = describe(gym.make("wrl_jax/rware-tiny-4ag-v2", **kwargs), steps=5)
    assert ours == theirs
    assert ours["step"][1] == ("list", ["float64"] * 4) and ours["step"][2] == "bool"
    assert ours["wrappers"] == ["OrderEnforcing", "PassiveEnvChecker"]


@pytest.fixture(scope="module")
def small():
    env, params = make_rware(2, layout=SMALL_LAYOUT, request_queue_size=1, max_steps=40)
    return env, params


def test_every_adapter_step_is_the_jax_transition_from_the_same_keys(small):
    env, params = small
    adapter = RwareGymEnv(env=env, params=params)
    steps = 60
    actions = np.random.default_rng(0).integers(0, 5, (steps, env.num_agents)).astype(np.int32)
    for seed in range(40):  # the first seed whose episode pays for a delivery (rewards other than 0 compared)
        obs, _ = adapter.reset(seed=seed)
        got = [adapter.step(list(a)) for a in actions]  # Python ints, as rware code passes them
        if sum(map(sum, (g[1] for g in got))) >= 1:
            break
    else:
        pytest.fail("no delivery in 40 episodes of 60 random steps on a two-shelf floor")

    rng = np.random.default_rng(seed)  # Gymnasium seeds its generator exactly so
    first_key = next_key(rng)
    keys = jax.numpy.stack([next_key(rng) for _ in range(steps)])

    def body(state, inputs):
        key, action = inputs
        obs, state, reward, _, truncated, _ = env.transition(key, state, action, params)
        return state, (obs, reward, truncated)

    # The reset and the steps in one program, compiled at LLVM level 0 (a short run: compiling is its time).
    @functools.partial(jax.jit, compiler_options={"xla_backend_optimization_level": 0})
    def replay(first_key, keys):
        first_obs, state = env.reset(first_key, params)
        return first_obs, jax.lax.scan(body, state, (keys, actions))[1]

    first_obs, (want_obs, want_reward, want_done) = replay(first_key, keys)
    np.testing.assert_array_equal(np.stack(obs), np.asarray(first_obs))
    np.testing.assert_array_equal(np.stack([np.stack(g[0]) for g in got]), np.asarray(want_obs))
    np.testing.assert_array_equal(np.array([g[1] for g in got]), np.asarray(want_reward, np.float64))
    done = [g[2] for g in got]
    assert done == np.asarray(want_done).tolist() and done.index(True) == 39 and all(done[39:])  # rware: stays done
    assert all(g[3] is False and g[4] == {} for g in got)


def test_seeds_replay_episodes_and_the_text_map_shows_them(small):
    env, params = small
    adapter = RwareGymEnv(env=env, params=params, render_mode="ansi")
    first = adapter.reset(seed=5)[0]
    np.testing.assert_array_equal(np.stack(first), np.stack(adapter.reset(seed=5)[0]))
    assert any(not np.array_equal(np.stack(first), np.stack(adapter.reset(seed=s)[0])) for s in (6, 7, 8))
    text = adapter.render()
    lines = text.splitlines()
    assert len(lines) == 3 and lines[-1].startswith("agents 0:") and lines[-1].endswith("t=0")
    assert sum(lines[0].count(c) + lines[1].count(c) for c in "^v<>A") == 2


def test_rware_action_values_and_arrays_are_accepted(small):
    rware = pytest.importorskip("rware.warehouse")
    env, params = small
    adapter = RwareGymEnv(env=env, params=params)
    adapter.reset(seed=0)
    adapter.step([rware.Action.FORWARD, rware.Action.TOGGLE_LOAD])  # rware's own enum
    adapter.step(np.array([2, 3]))
    adapter.step((np.int64(0), 4))


@pytest.mark.parametrize("actions, message", [
    ([1, 1, 1], "one action per agent: 2 expected, got 3"),
    ([1, 7], "action 7 of agent 1 is outside 0..4"),
    ([1, -1], "action -1 of agent 1 is outside 0..4"),
    ([1.0, 1], "action of agent 0 must be an integer 0..4"),
    ([[1, 0], 1], "action of agent 0 must be an integer 0..4"),
    (3, "sequence of 2 per-agent actions"),
])
def test_bad_actions_are_clear_errors(small, actions, message):
    env, params = small
    adapter = RwareGymEnv(env=env, params=params)
    with pytest.raises(gym.error.ResetNeeded):
        adapter.step([0, 0])
    adapter.reset(seed=0)
    with pytest.raises(ValueError, match=message):
        adapter.step(actions)


def test_message_bits_and_bad_constructions():
    env = gym.make("wrl_jax/rware-tiny-4ag-v2", msg_bits=2).unwrapped  # the surface test's program
    env.reset(seed=0)
    with pytest.raises(ValueError, match="must be \\[action 0..4, 2 bits 0/1\\]"):
        env.step([1, 1, 1, 1])
    with pytest.raises(ValueError, match="message bits of agent 3 must be 0 or 1"):
        env.step([[1, 0, 0]] * 3 + [[1, 2, 0]])
    with pytest.raises(ValueError, match="serves the rware ids"):
        RwareGymEnv("Warehouse-8x8-v0")
    with pytest.raises(ValueError, match="render_mode"):
        RwareGymEnv("rware-tiny-2ag-v2", render_mode="human")
    with pytest.raises(ValueError, match="unknown rware override"):
        gym.make("wrl_jax/rware-tiny-2ag-v2", n_agents=3)  # the agent count is the id's
