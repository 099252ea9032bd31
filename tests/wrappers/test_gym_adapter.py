"""The Gymnasium adapter: registration, API conformance, parity with the JAX env, vector env, SB3."""

from __future__ import annotations

import functools
import os

import gymnasium as gym
import jax
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env, data_equivalence
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import wrl_jax
from wrl_jax.envs.warehouse.render import render_frame
from wrl_jax.envs.warehouse.routes import oracle_action, route_tables
from wrl_jax.wrappers import gymnasium as gym_env
from wrl_jax.wrappers.gymnasium import INFO_FLAGS, WarehouseGymEnv
from wrl_jax.wrappers.gymnasium_vector import WarehouseVectorEnv

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # in case pygame is installed: no window needed

IDS = ["wrl_jax/Warehouse-8x8-v0", "wrl_jax/Warehouse-12x12-v0"]
RENDER = jax.jit(render_frame, static_argnums=2)
"""The expected frames, one program per shape for every rendering test (eagerly, each frame compiles op by op)."""

# A 4x4 layout with ONE item: every reset is the same, whatever the random stream,
# so a Gymnasium SyncVectorEnv of single envs must match the vector env exactly.
ONE_ITEM = """
S . . .
. # 0 .
. # . .
. . . G
"""


# ---------------------------------------------------------------- registration
@pytest.mark.parametrize("env_id", IDS)
def test_registered_without_a_second_time_limit(env_id):
    assert env_id in gym.registry
    assert gym.spec(env_id).max_episode_steps is None
    env = gym.make(env_id)
    wrapper = env
    while isinstance(wrapper, gym.Wrapper):
        assert not isinstance(wrapper, gym.wrappers.TimeLimit)
        wrapper = wrapper.env
    assert isinstance(env.unwrapped, WarehouseGymEnv)
    size = env.unwrapped.env.size
    assert env.observation_space.shape == (7,) and env.observation_space.dtype == np.float32
    assert env.observation_space.low[0] == np.float32(-1) / np.float32(size - 1)
    assert np.all(env.observation_space.high == 1.0)
    assert env.action_space == gym.spaces.Discrete(4)


def test_make_kwargs_reach_the_environment():
    env = gym.make(IDS[0], max_steps=5, step_penalty=-1.0, shaping_coef=0.0, observe_carrying=False)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (6,) and env.observation_space.shape == (6,)
    for t in range(1, 6):
        obs, reward, terminated, truncated, _ = env.step(2)  # left from the start: a wall bump
        assert reward == -1.0 and not terminated
        assert truncated == (t == 5)  # the environment's own max_steps truncates


@pytest.mark.parametrize("env_id", IDS)
@pytest.mark.parametrize("observe_carrying", [True, False])
def test_gymnasium_env_checker(env_id, observe_carrying):
    env = gym.make(env_id, observe_carrying=observe_carrying)
    check_env(env.unwrapped)  # also renders every declared render mode via the spec
    env.close()


# -------------------------------------------------------------- single env parity
def _jax_transitions(env, params):
    return jax.jit(functools.partial(env.transition, None)), jax.jit(env.reset_to_item)


@pytest.mark.parametrize("name, max_steps", [("Warehouse-8x8-v0", 40), ("Warehouse-12x12-v0", 60)])
def test_adapter_matches_the_jax_env_step_by_step(name, max_steps):
    gym_env_ = WarehouseGymEnv(name, max_steps=max_steps)
    env, params = wrl_jax.make(name, max_steps=max_steps)
    step, reset = _jax_transitions(env, params)
    oracle = jax.jit(oracle_action)
    tables = route_tables(params)
    rng = np.random.default_rng(0)
    seen = {flag: False for flag in INFO_FLAGS} | {"truncated": False}
    for episode in range(6):
        item = episode % int(params.num_items)
        obs, info = gym_env_.reset(options={"item_index": item})
        raw_obs, state = reset(item, params)
        assert info == {"item_index": item}
        np.testing.assert_array_equal(obs, np.asarray(raw_obs))
        for _ in range(max_steps):
            # Half the episodes follow the oracle (deliveries), half act at random (bumps, truncations).
            action = int(oracle(state, params, tables)) if episode % 2 else int(rng.integers(4))
            obs, reward, terminated, truncated, info = gym_env_.step(action)
            raw_obs, state, raw_reward, raw_term, raw_trunc, raw_info = step(state, action, params)
            assert obs.dtype == np.float32 and type(reward) is float
            assert type(terminated) is bool and type(truncated) is bool
            np.testing.assert_array_equal(obs, np.asarray(raw_obs))
            assert reward == float(raw_reward)
            assert (terminated, truncated) == (bool(raw_term), bool(raw_trunc))
            assert info == {flag: bool(raw_info[flag]) for flag in INFO_FLAGS}
            for flag in INFO_FLAGS:
                seen[flag] |= info[flag]
            seen["truncated"] |= truncated
            if terminated or truncated:
                break
    assert all(seen.values()), f"the run should cover every kind of transition: {seen}"


def test_item_index_option_pins_the_item():
    env = WarehouseGymEnv("Warehouse-8x8-v0")
    items = np.asarray(env.params.items)
    for item in range(env.num_items):
        obs, info = env.reset(seed=123, options={"item_index": item})
        assert info["item_index"] == item
        np.testing.assert_array_equal(obs[4:6], items[item].astype(np.float32) / np.float32(7))
    for bad in (-1, 10, 2.0):
        with pytest.raises(ValueError, match="item_index"):
            env.reset(options={"item_index": bad})
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(options={"item": 1})


def test_seeding_is_reproducible_and_seeds_differ():
    env = WarehouseGymEnv("Warehouse-8x8-v0")

    def run(seed):
        out = [env.reset(seed=seed)[1]["item_index"]]
        out += [env.reset()[1]["item_index"] for _ in range(5)]
        return out

    assert run(7) == run(7)
    firsts = {env.reset(seed=seed)[1]["item_index"] for seed in range(20)}
    assert len(firsts) > 3
    assert len(set(run(11))) > 1  # later unseeded resets draw fresh items


def test_bad_actions_raise_clear_errors():
    env = WarehouseGymEnv("Warehouse-8x8-v0")
    with pytest.raises(gym.error.ResetNeeded):
        env.step(0)
    env.reset(seed=0)
    for bad in (4, -1, np.int64(7)):
        with pytest.raises(ValueError, match="out of range"):
            env.step(bad)
    for bad in (1.5, "up", True):
        with pytest.raises(ValueError, match="integer"):
            env.step(bad)
    with pytest.raises(ValueError, match="scalar"):
        env.step(np.array([1]))
    obs, *_ = env.step(np.int64(1))  # every integer type of a valid action works
    assert obs[0] == np.float32(1) / np.float32(7)


def test_collision_bug_override():
    env = WarehouseGymEnv("Warehouse-8x8-v0", collision_bug=True)
    env.reset(seed=0, options={"item_index": 0})
    env.step(1)
    env.step(3)  # (1, 1); down is the shelf at (2, 1)
    obs, reward, _, _, info = env.step(1)
    assert info["collision"] and reward < -5
    np.testing.assert_array_equal(obs[:2], np.array([2, 1], dtype=np.float32) / np.float32(7))


def test_custom_layout_and_argument_errors():
    env = WarehouseGymEnv(layout=ONE_ITEM, max_steps=9, delivery_reward=10.0)
    assert env.observation_space.shape == (7,) and env.max_steps == 9
    with pytest.raises(ValueError, match="max_steps"):
        WarehouseGymEnv(layout=ONE_ITEM)
    with pytest.raises(ValueError, match="unknown environment"):
        WarehouseGymEnv("Warehouse-9x9-v0")
    with pytest.raises(ValueError, match="unknown reward"):
        WarehouseGymEnv("Warehouse-8x8-v0", step_reward=1.0)
    with pytest.raises(ValueError, match="render_mode"):
        WarehouseGymEnv("Warehouse-8x8-v0", render_mode="video")


def test_jitted_functions_are_compiled_once_per_configuration():
    first = WarehouseGymEnv("Warehouse-8x8-v0")
    first.reset(seed=0)
    first.step(1)
    sizes = (gym_env._reset_single._cache_size(), gym_env._step_single._cache_size())
    # Another instance of the same size, other rewards and max_steps: no new compilation.
    second = WarehouseGymEnv("Warehouse-8x8-v0", step_penalty=-1.0, max_steps=20)
    for _ in range(3):
        second.reset()
        for action in (0, 1, 2, 3):
            second.step(action)
    assert (gym_env._reset_single._cache_size(), gym_env._step_single._cache_size()) == sizes


# ------------------------------------------------------------------- rendering
def test_render_modes():
    env = WarehouseGymEnv("Warehouse-8x8-v0", render_mode="rgb_array", cell_size=8)
    env.reset(seed=0, options={"item_index": 2})
    env.step(1)
    frame = env.render()
    assert frame.shape == (64, 64, 3) and frame.dtype == np.uint8
    np.testing.assert_array_equal(frame, np.asarray(RENDER(env.state, env.params, 8)))
    text = WarehouseGymEnv("Warehouse-8x8-v0", render_mode="ansi")
    text.reset(options={"item_index": 2})
    assert text.render().splitlines()[2].split()[0] == "."
    assert "R" in text.render() and "2" in text.render()


def test_human_mode_needs_pygame():
    try:
        import pygame  # noqa: F401
    except ImportError:
        assert "human" not in WarehouseGymEnv.metadata["render_modes"]
        with pytest.raises(gym.error.DependencyNotInstalled, match="pygame"):
            WarehouseGymEnv("Warehouse-8x8-v0", render_mode="human")
    else:
        env = WarehouseGymEnv("Warehouse-8x8-v0", render_mode="human", cell_size=8)
        env.reset(seed=0)
        env.step(1)
        shown = pygame.surfarray.array3d(pygame.display.get_surface()).swapaxes(0, 1)
        expected = RENDER(env.state, env.params, 8)
        np.testing.assert_array_equal(shown, np.asarray(expected))
        env.close()
        env.close()  # closing twice is allowed


# ------------------------------------------------------------------ vector env
def test_vector_env_spaces_and_metadata():
    venv = gym.make_vec(IDS[1], num_envs=3, vectorization_mode="vector_entry_point", max_steps=50)
    assert isinstance(venv, WarehouseVectorEnv)
    assert venv.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert venv.max_steps == 50 and venv.num_envs == 3
    assert venv.single_observation_space == WarehouseGymEnv("Warehouse-12x12-v0").observation_space
    assert venv.observation_space.shape == (3, 7)
    assert venv.action_space == gym.spaces.MultiDiscrete([4, 4, 4])
    obs, info = venv.reset(seed=0)
    assert obs.shape == (3, 7) and obs.dtype == np.float32 and obs in venv.observation_space
    assert info["item_index"].shape == (3,) and info["_item_index"].all()


def test_vector_env_equals_gymnasium_sync_vector_env():
    """Same transitions AND the same info layout as Gymnasium's own SAME_STEP vectorizer."""
    num_envs, max_steps = 4, 12
    ours = WarehouseVectorEnv(num_envs, layout=ONE_ITEM, max_steps=max_steps)
    theirs = SyncVectorEnv(
        [lambda: WarehouseGymEnv(layout=ONE_ITEM, max_steps=max_steps) for _ in range(num_envs)],
        autoreset_mode=AutoresetMode.SAME_STEP,
    )
    assert ours.metadata["autoreset_mode"] == theirs.metadata["autoreset_mode"]
    assert ours.observation_space == theirs.observation_space and ours.action_space == theirs.action_space
    assert data_equivalence(ours.reset(seed=1), theirs.reset(seed=1), exact=True)
    rng = np.random.default_rng(0)
    ended = {"terminated": 0, "truncated": 0}
    for _ in range(80):
        actions = rng.choice(4, size=num_envs, p=[0.1, 0.4, 0.1, 0.4])  # drift towards the goal
        mine, reference = ours.step(actions), theirs.step(actions)
        assert data_equivalence(mine, reference, exact=True), (mine, reference)
        ended["terminated"] += int(mine[2].sum())
        ended["truncated"] += int(mine[3].sum())
    assert ended["terminated"] > 0 and ended["truncated"] > 0


def test_vector_env_equals_single_envs_and_exposes_final_obs():
    # A small open layout, so random drift delivers often and episodes end at different steps.
    num_envs, max_steps, layout = 4, 12, "S . 0 .\n. . . 1\n. # . .\n2 . . G"
    venv = WarehouseVectorEnv(num_envs, layout=layout, max_steps=max_steps)
    singles = [WarehouseGymEnv(layout=layout, max_steps=max_steps) for _ in range(num_envs)]
    obs, info = venv.reset(seed=5)
    for i, single in enumerate(singles):
        single_obs, _ = single.reset(options={"item_index": int(info["item_index"][i])})
        np.testing.assert_array_equal(obs[i], single_obs)
    rng = np.random.default_rng(1)
    resets = mixed = 0
    for _ in range(80):
        actions = rng.choice(4, size=num_envs, p=[0.1, 0.4, 0.1, 0.4])  # drift towards the goal
        obs, reward, terminated, truncated, info = venv.step(actions)
        done = terminated | truncated
        mixed += int(done.any() and not done.all())
        for i, single in enumerate(singles):
            s_obs, s_reward, s_term, s_trunc, s_info = single.step(int(actions[i]))
            assert (reward[i], terminated[i], truncated[i]) == (s_reward, s_term, s_trunc)
            if s_term or s_trunc:
                resets += 1
                # The observation the transition reached, and its info, are in final_obs / final_info.
                assert info["_final_obs"][i] and info["_final_info"][i]
                np.testing.assert_array_equal(info["final_obs"][i], s_obs)
                assert {flag: bool(info["final_info"][flag][i]) for flag in INFO_FLAGS} == s_info
                # obs[i] already begins the next episode, whose item the reset info names.
                assert info["_item_index"][i] and not info.get("_collision", np.zeros(num_envs, bool))[i]
                s_obs, _ = single.reset(options={"item_index": int(info["item_index"][i])})
            else:
                assert info["_collision"][i] and not info.get("_final_obs", np.zeros(num_envs, bool))[i]
                assert {flag: bool(info[flag][i]) for flag in INFO_FLAGS} == s_info
            np.testing.assert_array_equal(obs[i], s_obs)
    assert resets >= num_envs and mixed > 0  # steps where some environments ended and others went on


def test_vector_env_seeding_and_item_pinning():
    venv = WarehouseVectorEnv(8, "Warehouse-8x8-v0", max_steps=10)
    actions = np.random.default_rng(2).integers(0, 4, (25, 8))

    def run(seed):
        out = [venv.reset(seed=seed)]
        out += [venv.step(a) for a in actions]
        return out

    assert data_equivalence(run(3), run(3), exact=True)
    first_items = venv.reset(seed=3)[1]["item_index"]
    assert len(set(first_items.tolist())) > 1  # environments of one batch draw different items
    assert not np.array_equal(first_items, venv.reset(seed=4)[1]["item_index"])
    _, info = venv.reset(seed=0, options={"item_index": 6})
    np.testing.assert_array_equal(info["item_index"], np.full(8, 6))
    pinned = np.arange(8)
    obs, info = venv.reset(options={"item_index": pinned})
    np.testing.assert_array_equal(info["item_index"], pinned)
    np.testing.assert_array_equal(obs[:, 4:6], np.asarray(venv.params.items)[pinned].astype(np.float32) / np.float32(7))
    with pytest.raises(ValueError, match="shape"):
        venv.reset(options={"item_index": np.arange(3)})


def test_vector_env_bad_actions_and_render():
    venv = WarehouseVectorEnv(3, "Warehouse-8x8-v0", render_mode="rgb_array", cell_size=8)
    with pytest.raises(gym.error.ResetNeeded):
        venv.step(np.zeros(3, dtype=np.int64))
    venv.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        venv.step(np.zeros(2, dtype=np.int64))
    with pytest.raises(ValueError, match="environment 1 is out of range"):
        venv.step(np.array([0, 4, 1]))
    with pytest.raises(ValueError, match="integers"):
        venv.step(np.array([0.0, 1.0, 2.0]))
    venv.step(np.array([1, 3, 0]))
    frames = venv.render()
    assert len(frames) == 3
    for i, frame in enumerate(frames):
        state = jax.tree.map(lambda leaf: np.asarray(leaf)[i], venv.states)
        np.testing.assert_array_equal(frame, np.asarray(RENDER(state, venv.params, 8)))
    with pytest.raises(ValueError, match="num_envs"):
        WarehouseVectorEnv(0)


def test_sync_vectorization_of_the_registered_id():
    venv = gym.make_vec(IDS[0], num_envs=2, vectorization_mode="sync")
    obs, _ = venv.reset(seed=0)
    assert obs.shape == (2, 7)
    obs, reward, *_ = venv.step(np.array([1, 3]))
    assert obs.shape == (2, 7) and reward.shape == (2,)
    venv.close()


# ------------------------------------------------------------ Stable-Baselines3
def test_stable_baselines3_trains_and_evaluates(tmp_path):
    sb3 = pytest.importorskip("stable_baselines3")
    torch = pytest.importorskip("torch")
    from stable_baselines3.common.env_checker import check_env as sb3_check_env
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.monitor import Monitor

    torch.set_num_threads(1)
    sb3_check_env(WarehouseGymEnv("Warehouse-8x8-v0"), warn=True)
    env = Monitor(gym.make(IDS[0], max_steps=40))
    model = sb3.PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu")
    # SB3 otherwise creates a log folder under the system temp directory on every learn().
    model.set_logger(sb3.common.logger.configure(str(tmp_path), []))
    model.learn(total_timesteps=128)
    assert model.num_timesteps >= 128
    mean_return, _ = evaluate_policy(model, env, n_eval_episodes=2, deterministic=True)
    # Every episode ends within 40 steps: its return is bounded by the reward constants.
    assert -0.5 * 40 - 10 * 40 - 2 * 14 <= mean_return <= 271.5
    action, _ = model.predict(env.reset(seed=0)[0], deterministic=True)
    assert env.action_space.contains(int(action))
