"""The continuous warehouse through Gymnasium: the checker passes, the numbers are the JAX
environment's, bad actions fail clearly, and Stable-Baselines3's SAC trains on it.

The adapter compiles its reset and step once per static configuration (params, such as ``randomize``, do not
count; the last test checks it): the tests share two settings, the 8x8 map as SAC and TD3 train on it
(``TRAINING_8X8``) and the dynamic 12x12 map (``DYNAMIC_12X12``).
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import jax
import numpy as np
import pytest
import commands_level

import wrl_jax  # noqa: F401  (registers the Gymnasium ids)
from wrl_jax.wrappers.gymnasium_continuous import ContinuousGymEnv

CASES = [("wrl_jax/Continuous-Warehouse-8x8-v0", {"shaping": "geodesic", "observe_target": True, "observe_route": True}),
         ("wrl_jax/Continuous-Warehouse-12x12-Dynamic-v0", {})]
"""The 8x8 map with the route alone (SAC's and TD3's view without the safety stop and its held value: the target and
the route after the contract's values), the dynamic one plain."""
TRAINING_8X8 = {"randomize": True, **CASES[0][1]}
DYNAMIC_12X12 = {"randomize": True}


@pytest.mark.parametrize("env_id, kwargs", CASES)
def test_gymnasium_env_checker(env_id, kwargs):
    from gymnasium.utils.env_checker import check_env

    env = gym.make(env_id, randomize=True, **kwargs).unwrapped  # the first case is TRAINING_8X8
    check_env(env, skip_render_check=True)
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    assert env.observation_space.shape == (11 + 32 + (8 if kwargs else 0),)


@commands_level.at_commands_level  # a claim about level-1 programs (tests/commands_level.py)
def test_adapter_is_the_jax_transition_step_by_step():
    env = ContinuousGymEnv("Continuous-Warehouse-12x12-Dynamic-v0", **DYNAMIC_12X12)
    jax_env, params = env.jax_env, env.params
    obs, _ = env.reset(seed=7)
    key, reset_key = jax.random.split(jax.random.key(7))
    reset, transition = jax.jit(jax_env.reset_env), jax.jit(jax_env.transition)  # compiled, as the adapter's
    expected_obs, state = reset(reset_key, params)
    np.testing.assert_array_equal(obs, np.asarray(expected_obs))
    rng = np.random.default_rng(0)
    for _ in range(60):
        action = rng.uniform(-1, 1, 2).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        key, step_key = jax.random.split(key)
        expected_obs, state, expected_reward, term, trunc, jax_info = transition(step_key, state, action, params)
        np.testing.assert_array_equal(obs, np.asarray(expected_obs))
        assert reward == float(expected_reward) and terminated == bool(term) and truncated == bool(trunc)
        assert info["collision"] == bool(jax_info["collision"])
        if terminated or truncated:
            break


def test_seeds_repeat_and_differ():
    env = ContinuousGymEnv("Continuous-Warehouse-12x12-Dynamic-v0", **DYNAMIC_12X12)
    first = [env.reset(seed=s)[0] for s in (1, 1, 2)]
    np.testing.assert_array_equal(first[0], first[1])
    assert not np.array_equal(first[0], first[2])


def test_bad_actions_and_names_fail_clearly():
    env = ContinuousGymEnv("Continuous-Warehouse-8x8-v0", **TRAINING_8X8)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2, np.float32))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="2 numbers"):
        env.step(np.zeros(3, np.float32))
    with pytest.raises(ValueError, match="2 numbers"):
        env.step(np.array(["a", "b"]))
    _, _, _, _, info = env.step(np.array([np.nan, 0.0], np.float32))  # the contract: read as 0, flagged
    assert info["invalid_action"]
    with pytest.raises(ValueError, match="not a continuous warehouse"):
        ContinuousGymEnv("Warehouse-8x8-v0")


def test_stable_baselines3_sac_trains_on_it(tmp_path, monkeypatch):
    sb3 = pytest.importorskip("stable_baselines3")
    import torch

    torch.set_num_threads(1)  # the test workers already use the cores
    env = gym.make("wrl_jax/Continuous-Warehouse-8x8-v0", **TRAINING_8X8)
    model = sb3.SAC("MlpPolicy", env, learning_starts=50, batch_size=32, policy_kwargs={"net_arch": [32, 32]},
                    seed=0, verbose=0)
    model.set_logger(sb3.common.logger.configure(str(tmp_path), []))  # else a log folder in the system temp dir
    model.learn(total_timesteps=120)
    assert model.num_timesteps == 120 and model.replay_buffer.size() == 120
    obs = env.reset(seed=0)[0]
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)
    # bench/sb3_sac.py evaluates SB3's policy with the family's JAX evaluation by reading its actor's weights:
    # the JAX function must act as SB3's own predict.
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2]))
    from bench.sb3_sac import library_kwargs, sb3_actor_params, sb3_deterministic_action

    batch = np.stack([obs, *(env.step(env.action_space.sample())[0] for _ in range(7))])
    expected, _ = model.predict(batch, deterministic=True)
    np.testing.assert_allclose(np.asarray(sb3_deterministic_action(sb3_actor_params(model), batch)), expected,
                               atol=1e-5)
    # ... and its SB3 model has our SAC's settings.
    from wrl_jax.agents.off_policy_config import SAC_DEFAULT

    with pytest.raises(ValueError, match="actor as trained"):  # SB3 has no average of its actor to evaluate
        library_kwargs(SAC_DEFAULT, "sb3")
    config = SAC_DEFAULT.replace(buffer_size=1000, target_entropy=-3.0, actor_average=0.0)
    mapped = sb3.SAC("MlpPolicy", env, seed=0, **library_kwargs(config, "sb3"))
    assert (mapped.learning_starts, mapped.batch_size, mapped.gradient_steps, mapped.train_freq.frequency,
            mapped.buffer_size, mapped.gamma, mapped.tau) == (5000, 256, 2, 1, 1000, 0.99, 0.005)
    assert mapped.target_entropy == -3.0 and float(mapped.log_ent_coef.detach().exp()) == pytest.approx(0.1)
    assert [m.out_features for m in mapped.actor.latent_pi if isinstance(m, torch.nn.Linear)] == [128, 128]
    assert mapped.lr_schedule(1.0) == pytest.approx(1e-3) and mapped.actor.optimizer.defaults["eps"] == 1e-8
    with pytest.raises(ValueError, match="ReLU networks only"):
        library_kwargs(config.replace(activation="tanh"), "sb3")


def test_rgb_array_rendering_draws_the_jax_state():
    import warnings

    from gymnasium.utils.passive_env_checker import env_render_passive_checker

    from wrl_jax.envs.continuous.render import COLORS, lidar_from_obs, render_frame, to_pixel

    env = gym.make("wrl_jax/Continuous-Warehouse-12x12-Dynamic-v0", render_mode="rgb_array", cell_size=8,
                   **DYNAMIC_12X12).unwrapped
    assert env.metadata["render_modes"] == ["rgb_array"] and env.render_mode == "rgb_array"
    with pytest.raises(RuntimeError, match="reset"):
        env.render()
    obs, _ = env.reset(seed=3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # Gymnasium's render checks warn on a problem
        env_render_passive_checker(env)
    frame = env.render()
    assert frame.shape == (96, 96, 3) and frame.dtype == np.uint8
    # The test's own drawing, jitted (eagerly it compiles op by op).
    expected = jax.jit(lambda state, obs: render_frame(state, env.params, lidar_from_obs(obs, env.params,
                                                                                         env.jax_env.num_rays), 8))(
        env._state, jax.numpy.asarray(obs))
    np.testing.assert_array_equal(frame, np.asarray(expected))
    assert tuple(frame[to_pixel(env._state.pos, 8)]) == COLORS["robot"]
    env.step(np.array([1.0, 0.5], np.float32))
    assert not np.array_equal(env.render(), frame)
    with pytest.warns(UserWarning, match="render_mode"):
        assert ContinuousGymEnv("Continuous-Warehouse-8x8-v0").render() is None  # no render_mode: nothing drawn
    with pytest.raises(ValueError, match="render_mode"):
        ContinuousGymEnv("Continuous-Warehouse-8x8-v0", render_mode="human")


def test_environments_that_differ_in_params_share_the_compiled_programs():
    """The adapter's programs take the environment without its default params as their static argument: another
    ``max_steps`` or randomization (params) reuses the compiled reset and step instead of compiling its own."""
    from wrl_jax.wrappers import gymnasium_continuous as adapter

    def use(env):
        env.reset(seed=0)
        env.step(np.zeros(2, np.float32))
        return adapter._reset._cache_size(), adapter._step._cache_size()

    before = use(ContinuousGymEnv("Continuous-Warehouse-12x12-Dynamic-v0", **DYNAMIC_12X12))
    other = ContinuousGymEnv("Continuous-Warehouse-12x12-Dynamic-v0", randomize=False, max_steps=50)
    assert use(other) == before
    assert int(other.params.max_steps) == 50  # the params really differ
