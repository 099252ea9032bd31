"""DQN: learning, truncation bootstrapping, seeds, determinism, checkpoints, config checks, CLI.

Compiles are the cost here, so the tests share a few small programs
(module-scoped fixtures) on tiny layouts; the truncation test's two trainings, whose Q-values are compared
with tolerances, the learning test's greedy evaluation and the schedule test's updates compile at LLVM level 0
(``fast_compile``).
"""

import copy
import dataclasses
import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import fast_compile

import wrl_jax
from wrl_jax import training
from wrl_jax.agents.base import make_train, make_train_seeds
from wrl_jax.envs.warehouse import evaluation
from wrl_jax.agents.dqn import DQN, make_algorithm
from wrl_jax.agents.dqn_config import PRESETS, DQNConfig
from wrl_jax.agents.replay import Transition
from wrl_jax.cli import train as cli_train


SMALL_MAP = """
S . 0
. # .
1 . G
"""

SMALL = DQNConfig(
    total_timesteps=3_000,
    num_envs=8,
    train_freq=1,
    batch_size=64,
    hidden_sizes=(32, 32),
    buffer_size=4_000,
    learning_starts=200,
    target_update_interval=8,
    tau=0.05,
    gamma=0.8,
    learning_rate=1e-2,
    exploration_fraction=0.2,
    exploration_final_eps=0.5,
    anneal_lr=True,
)


def tree_equal(a, b) -> bool:
    return all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))


@pytest.fixture(scope="module")
def small_env():
    return wrl_jax.make_from_layout(SMALL_MAP, max_steps=30)


@pytest.fixture(scope="module")
def small_runs(small_env):
    """Four seeds (0, 1, 2, 0) of SMALL trained in one program, and a second call of the same program."""
    env, params = small_env
    algo = DQN(SMALL, env, params)
    train = jax.jit(make_train_seeds(algo))
    keys = training.seed_keys([0, 1, 2, 0])
    first = train(keys)
    second = train(keys)
    return algo, first, second


# ------------------------------------------------------------------ learning
def test_short_run_learns_small_case_to_full_delivery(small_runs, small_env):
    algo, (runners, metrics), _ = small_runs
    env, params = small_env
    # One program for the greedy episodes (eagerly, each operation of their loops compiled on its own), at LLVM
    # level 0: what is asserted is what the greedy policy does, not its last bits.
    result = fast_compile.jit(lambda p: evaluation.evaluate_seeds(algo.greedy_action, p, env, params))(runners.params)
    summary = evaluation.summarize(result)
    assert summary["success_rate"] == 1.0, summary["per_seed"]
    assert summary["mean_steps"] == summary["optimal_mean_steps"] == 4.0
    assert summary["collision_free_rate"] == 1.0
    # Training really happened: the loss is recorded once learning starts, epsilon decays.
    loss = np.asarray(metrics["loss"])
    assert np.all(loss[:, 0] == 0.0) and np.all(loss[:, -1] > 0.0)
    eps = np.asarray(metrics["epsilon"][0])
    assert eps[0] == 1.0 and eps[-1] == pytest.approx(0.5)


def test_seeds_in_one_program_differ(small_runs):
    _, (runners, metrics), _ = small_runs
    kernels = np.asarray(runners.params["params"]["Dense_0"]["kernel"])
    assert not np.array_equal(kernels[0], kernels[1])
    assert not np.array_equal(kernels[1], kernels[2])
    assert not np.array_equal(np.asarray(metrics["return_sum"][0]), np.asarray(metrics["return_sum"][1]))
    buffers = np.asarray(runners.buffer.data.obs)
    assert not np.array_equal(buffers[0], buffers[1])


def test_same_seed_is_bit_identical(small_runs):
    _, (runners_a, metrics_a), (runners_b, metrics_b) = small_runs
    assert tree_equal(runners_a, runners_b)
    assert tree_equal(metrics_a, metrics_b)


# ---------------------------------------------------------------- truncation
TRUNCATION_MAP = """
S 0
. G
"""


def test_target_bootstraps_through_truncation():
    """A case built for it: episodes of 2 steps, so half the transitions end in a truncation.

    On the 2x2 map, ``right`` picks the item up (+51.5) and ``down`` then
    delivers (+202, terminal), so ``Q*(start, right) = 51.5 + g * 202``.
    ``up`` bumps the wall and stays at the start (-0.5): ``Q*(start, up) =
    -0.5 + g * Q*(start, right)``, and half of its samples are the second
    step of an episode, cut by the time limit. Bootstrapping through the
    truncation learns that value; treating the truncation as terminal pulls
    it towards -0.5 (about half-way down).
    """
    env, params = wrl_jax.make_from_layout(TRUNCATION_MAP, max_steps=2)
    gamma = 0.9
    config = DQNConfig(
        total_timesteps=4_000,
        num_envs=8,
        train_freq=1,
        batch_size=64,
        hidden_sizes=(32, 32),
        buffer_size=2_000,
        learning_starts=200,
        target_update_interval=8,
        tau=0.05,
        gamma=gamma,
        learning_rate=3e-3,
        loss="mse",
        reward_scale=0.01,  # Q-values of order 1: a few thousand steps fit them to within 1 %
        exploration_initial_eps=1.0,
        exploration_final_eps=1.0,  # uniform behaviour: every action from every state
        anneal_lr=True,
    )

    class TruncationAsTermination(type(env)):
        """The mistake this test guards against: the learner's steps report a truncation as a termination."""

        def batch_step(self, key, state, action, env_params):
            obs, st, reward, terminated, truncated, info = super().batch_step(key, state, action, env_params)
            return obs, st, reward, terminated | truncated, jnp.zeros_like(truncated), info

    wrong_env = copy.copy(env)
    wrong_env.__class__ = TruncationAsTermination

    start_obs, _ = env.reset_to_item(0, params)
    q_right = 51.5 + gamma * 202.0
    q_up = -0.5 + gamma * q_right  # 209.5
    q_up_if_terminal = 0.5 * (q_up + -0.5)  # about 104.5
    learned = {}
    for name, learner_env in (("bootstrapped", env), ("truncation as termination", wrong_env)):
        algo = DQN(config, learner_env, params)
        runner, _ = fast_compile.jit(make_train(algo))(jax.random.PRNGKey(0))
        learned[name] = np.asarray(algo.q_values(runner.params, start_obs)) / config.reward_scale
    up, _, _, right = learned["bootstrapped"]
    assert right == pytest.approx(q_right, rel=0.02)
    assert up == pytest.approx(q_up, rel=0.02), learned["bootstrapped"]
    wrong_up = learned["truncation as termination"][0]
    assert wrong_up < 0.75 * q_up and wrong_up == pytest.approx(q_up_if_terminal, rel=0.25), learned


def test_truncated_transition_stores_the_observation_before_the_reset(small_env):
    """``next_obs`` of a transition that ended the episode is ``final_obs``; only delivery is terminal."""
    env, params = wrl_jax.make_from_layout(SMALL_MAP, max_steps=3)
    config = dataclasses.replace(SMALL, total_timesteps=64, num_envs=4, buffer_size=64, learning_starts=10_000)
    algo = DQN(config, env, params)
    runner = jax.jit(algo.init)(jax.random.PRNGKey(3))
    step = jax.jit(algo._env_step)
    step_env = jax.jit(jax.vmap(functools.partial(env.transition, None), in_axes=(0, 0, None)))
    rows = []
    for t in range(12):
        before = runner.env_state
        runner, _ = step(runner, jnp.int32(t * config.num_envs))
        data = jax.tree.map(np.asarray, runner.buffer.data)
        written = (np.arange(config.num_envs) + t * config.num_envs) % config.buffer_size
        reached_obs, _, reward, terminated, truncated, _ = jax.tree.map(
            np.asarray, step_env(before, jnp.asarray(data.action[written]), params)
        )
        np.testing.assert_array_equal(data.next_obs[written], reached_obs)
        np.testing.assert_array_equal(data.terminated[written], terminated)
        np.testing.assert_array_equal(data.reward[written], reward)
        for e in range(config.num_envs):
            rows.append((bool(terminated[e]), bool(truncated[e]), np.asarray(runner.obs[e]), reached_obs[e]))
    truncations = [r for r in rows if r[1]]
    assert truncations, "the case must contain truncations"
    # After a truncation the runner's observation is a fresh episode's, not the stored one.
    assert any(not np.array_equal(np.asarray(new), np.asarray(reached)) for _, _, new, reached in truncations)
    assert all(not terminated for terminated, truncated, _, _ in truncations)


def test_td_target_stops_only_at_termination(small_env):
    env, params = small_env
    algo = DQN(dataclasses.replace(SMALL, loss="mse"), env, params)
    # Double DQN picks the bootstrap action with the online network, values it with the target.
    double = DQN(dataclasses.replace(SMALL, loss="mse", double_dqn=True), env, params)
    hyper = algo.config.hyper(gamma=0.9, reward_scale=0.5)

    @jax.jit
    def losses_and_q_values():
        """Both losses and every Q-value the expectations need, in one program (eagerly: dozens of compiles)."""
        batch = Transition(
            obs=jax.random.uniform(jax.random.PRNGKey(2), (2, env.obs_size)),
            action=jnp.array([1, 2], jnp.int32),
            reward=jnp.array([4.0, 4.0]),
            next_obs=jax.random.uniform(jax.random.PRNGKey(3), (2, env.obs_size)),
            terminated=jnp.array([False, True]),
        )
        online = algo.init_network(jax.random.PRNGKey(0))
        target = algo.init_network(jax.random.PRNGKey(1))
        return {
            "loss": algo.loss_fn(online, target, hyper, batch)[0],
            "loss_double": double.loss_fn(online, target, hyper, batch)[0],
            "q": algo.q_values(online, batch.obs),
            "next_target": algo.q_values(target, batch.next_obs[0]),
            "next_online_double": double.q_values(online, batch.next_obs[0]),
            "next_target_double": double.q_values(target, batch.next_obs[0]),
        }

    out = jax.tree.map(np.asarray, losses_and_q_values())
    q = out["q"][[0, 1], [1, 2]]
    bootstrap = out["next_target"].max()
    expected_target = np.array([0.5 * 4.0 + 0.9 * bootstrap, 0.5 * 4.0])
    assert float(out["loss"]) == pytest.approx(float(np.mean(0.5 * (q - expected_target) ** 2)), rel=1e-5)

    chosen = int(out["next_online_double"].argmax())
    bootstrap_double = out["next_target_double"][chosen]
    expected_double = np.array([0.5 * 4.0 + 0.9 * bootstrap_double, 0.5 * 4.0])
    assert float(out["loss_double"]) == pytest.approx(float(np.mean(0.5 * (q - expected_double) ** 2)), rel=1e-5)


def test_schedules_learning_starts_and_target_updates(small_env):
    """No gradient step before ``learning_starts``; the target moves only when an interval is crossed."""
    env, params = small_env
    config = dataclasses.replace(SMALL, num_envs=4, learning_starts=16, target_update_interval=12, tau=1.0)
    algo = DQN(config, env, params)
    # LLVM level 0 (``fast_compile``): the schedule is integer logic, and a tau = 1 copy is exact at any level.
    update = fast_compile.jit(algo.update)
    runner = fast_compile.jit(algo.init)(jax.random.PRNGKey(0))
    trained, target_moved = [], []
    for index in range(10):  # 4 transitions per update
        before = runner
        runner, metrics = update(runner, jnp.int32(index))
        trained.append(not tree_equal(before.params, runner.params))
        target_moved.append(not tree_equal(before.target_params, runner.target_params))
        assert (float(metrics["learning_rate"]) > 0) == trained[-1]
        if index in (2, 5, 8):  # a multiple of 12 transitions was crossed: tau = 1 copies the online net
            assert tree_equal(runner.target_params, runner.params)
        else:
            assert not tree_equal(runner.target_params, runner.params) or not trained[-1]
    # Updates 0..3 end at 4, 8, 12, 16 transitions: SB3 trains once more than 16 were collected.
    assert trained == [False] * 4 + [True] * 6
    # The copy at 12 transitions finds the nets still equal; those at 24 and 36 move the target.
    assert target_moved == [i in (5, 8) for i in range(10)]
    assert algo.epsilon(runner.hyper, jnp.int32(0)) == 1.0  # random before learning starts
    assert float(algo.epsilon(runner.hyper, jnp.int32(config.total_timesteps))) == pytest.approx(0.5)


# ---------------------------------------------------------- checkpoint/resume
def test_checkpoint_round_trip_and_exact_resume(tmp_path, small_env):
    env, params = small_env
    config = dataclasses.replace(SMALL, total_timesteps=640, buffer_size=512, learning_starts=64)
    algo = DQN(config, env, params)
    # No in-loop evaluation: it would only add compile time here.
    loop = training.LoopConfig(chunk_updates=20, eval_every=0, log_every=10, progress=False)
    seeds = [0, 5]
    meta = {"algo": "dqn", "config": dataclasses.asdict(config)}

    trainer = training.Trainer(algo, seeds, loop)
    straight = training.run(trainer, tmp_path / "straight", metadata=meta)
    assert straight.finished

    stopped = training.run(trainer, tmp_path / "resumed", metadata=meta, stop_after=40)
    assert not stopped.finished and stopped.updates_done == 40
    # The checkpoint is all the resumed run reads: a fresh Trainer, as a new process would build (the session's
    # compilation cache serves its programs' compile).
    resumed = training.run(training.Trainer(algo, seeds, loop), tmp_path / "resumed", metadata=meta, resume=True)
    assert resumed.finished
    # The replay buffer, optimizer, target network, env states and keys all round-trip: bit-identical.
    assert tree_equal(straight.runners, resumed.runners)
    rows_a = [json.loads(line) for line in (tmp_path / "straight" / "metrics.jsonl").read_text().splitlines()]
    rows_b = [json.loads(line) for line in (tmp_path / "resumed" / "metrics.jsonl").read_text().splitlines()]
    assert rows_a == rows_b

    # The checkpoint on disk holds the final state.
    from wrl_jax.training import checkpoint

    loaded, saved = checkpoint.load(tmp_path / "straight", jax.eval_shape(lambda: straight.runners))
    assert saved["updates_done"] == algo.num_updates
    assert tree_equal(loaded, straight.runners)


# ------------------------------------------------------------ invalid configs
@pytest.mark.parametrize(
    "changes, message",
    [
        (dict(total_timesteps=0), "total_timesteps"),
        (dict(num_envs=0), "num_envs"),
        (dict(batch_size=-1), "batch_size"),
        (dict(train_freq=1.5), "train_freq"),
        (dict(learning_starts=-1), "learning_starts"),
        (dict(buffer_size=4, num_envs=8), "buffer_size"),
        (dict(total_timesteps=10, num_envs=4, train_freq=4), "less than one update"),
        (dict(hidden_sizes=()), "hidden_sizes"),
        (dict(hidden_sizes=(64, 0)), "hidden_sizes"),
        (dict(loss="l1"), "loss"),
        (dict(activation="gelu"), "activation"),
        (dict(learning_rate=0.0), "learning_rate"),
        (dict(gamma=1.5), "gamma"),
        (dict(tau=0.0), "tau"),
        (dict(exploration_final_eps=-0.1), "exploration_final_eps"),
        (dict(exploration_fraction=0.0), "exploration_fraction"),
        (dict(max_grad_norm=0.0), "max_grad_norm"),
        (dict(reward_scale=-1.0), "reward_scale"),
        (dict(learning_rate=float("nan")), "learning_rate"),
    ],
)
def test_invalid_config_raises_clear_error(changes, message):
    with pytest.raises(ValueError, match=message):
        dataclasses.replace(SMALL, **changes).validate()


def test_invalid_sweep_hyper_raises():
    with pytest.raises(ValueError, match="learning_rate"):
        SMALL.hyper(learning_rate=np.array([1e-3, -1.0]))
    with pytest.raises(ValueError, match="unknown DQN hyperparameter"):
        SMALL.hyper(num_envs=3)


def test_presets():
    paper = PRESETS["paper"]
    # The study's Table 2 for DQN on 8x8.
    assert paper.learning_rate == 1e-3 and paper.hidden_sizes == (256, 256) and paper.gamma == 0.99
    assert paper.buffer_size == 100_000 and paper.batch_size == 128 and paper.num_envs == 1
    assert (paper.exploration_initial_eps, paper.exploration_final_eps) == (1.0, 0.02)
    assert paper.total_timesteps == 500_000
    # SB3 defaults for what the table omits.
    assert (paper.train_freq, paper.gradient_steps, paper.target_update_interval) == (4, 1, 10_000)
    assert paper.loss == "huber" and paper.max_grad_norm == 10.0 and paper.exploration_fraction == 0.1
    algo = make_algorithm(paper)
    assert algo.num_updates == 125_000 and algo.steps_per_update == 4
    # ~52.5 MFLOP forward+backward and 17.5 MFLOP target forward per update.
    assert algo.gradient_flops_per_update() == pytest.approx(70.0e6, rel=0.01)
    assert "default" in PRESETS and PRESETS["default"].total_timesteps < paper.total_timesteps


# ------------------------------------------------------------------------ CLI
def test_cli_smoke(tmp_path, capsys):
    """``train_dqn.py``'s main in this process (the script's own ``__main__`` block runs in tests/cli/test_cli.py)."""
    out = tmp_path / "run"
    assert cli_train.main("dqn", ["--total-timesteps", "512", "--num-seeds", "2", "--out", str(out), "--no-progress"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    fields = ("algo", "env", "num_seeds", "total_timesteps", "compile_seconds", "train_seconds", "env_steps_per_second")
    for key in fields:
        assert key in summary, key
    assert summary["algo"] == "dqn" and summary["env"] == "Warehouse-8x8-v0" and summary["num_seeds"] == 2
    for key in ("success_rate", "mean_steps", "optimal_mean_steps", "collision_free_rate", "mean_return"):
        assert key in summary["eval"], key
    assert len(summary["eval"]["rows"]) == 2 * 10
    assert "Task Completion Rate" in capsys.readouterr().out


def test_cli_rejects_invalid_config_before_compiling(tmp_path, capsys):
    assert cli_train.main("dqn", ["--gamma", "2", "--out", str(tmp_path / "bad")]) == 2
    assert "gamma must be in [0, 1]" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
