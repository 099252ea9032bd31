"""SAC and TD3: settings refused before compiling, the squashed Gaussian's density, the replay of a
truncation, exact repeats, and learned behaviour on a warehouse small enough for CI.

The learning runs share one compiled program per algorithm (module fixtures, three seeds vmapped). SAC's
(``sac_run``) serves five tests: its learning, its start and seeds, the driver's chunks and resume (which must
give its bits), and its replay buffer (truncations, and the warm-up's independent uniform actions for the
correlated-exploration test). The nine learned actors (SAC's, TD3's and PPO's, three seeds each) are evaluated by
one program (``evaluations``: the corridor's episodes traced and compiled once, each row acting with its own
algorithm's greedy action). Programs whose results are only compared with thresholds (TD3's and PPO's learning
runs, the evaluation, the correlated collection) compile at LLVM level 0 (``fast_compile``); SAC's training,
whose bits are compared with its own chunked and resumed runs, at the session's level (tests/conftest.py). The tests
that update step by step (the annealed step size, the preactivation penalty) share small learners' jitted init and
update (``stepwise``).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import fast_compile

from wrl_jax import training
from wrl_jax.agents.base import make_train_seeds
from wrl_jax.agents.off_policy_config import SAC_DEFAULT, TD3_DEFAULT, SACConfig, TD3Config
from wrl_jax.agents.sac import SAC
from wrl_jax.agents.td3 import TD3
from wrl_jax.core.gymnax_base import spaces
from wrl_jax.core.registry import make
from wrl_jax.envs.continuous.evaluation import evaluate_policy, seed_summary
from wrl_jax.envs.continuous.registration import make_continuous

CORRIDOR = """
. . .
S 0 G
. . .
"""
"""Item and goal straight ahead of the start: driving forward delivers in 9 steps."""

SEEDS = [0, 1, 2]


def tiny(config_cls, **changes):
    return config_cls(num_envs=8, total_timesteps=8_000, learning_starts=500, batch_size=64, hidden_sizes=(64, 64),
                      buffer_size=20_000, gradient_steps=2, learning_rate=1e-3, reward_scale=0.1, **changes)


@pytest.fixture(scope="module")
def corridor():
    return make_continuous(CORRIDOR, max_steps=60, num_rays=8)


def train_seeds(algo):
    """The seeds' runners and metrics: read against thresholds only, so compiled at LLVM level 0."""
    return fast_compile.jit(make_train_seeds(algo))(training.seed_keys(SEEDS))


@pytest.fixture(scope="module")
def sac_run(corridor):
    """SAC's learning run through the driver in one chunk (``Trainer``): its algorithm, start, runners and metrics
    (seeds first). Its bits are the chunked and resumed runs'."""
    env, params = corridor
    algo = SAC(tiny(SACConfig, initial_alpha=0.1), env, params)
    trainer = training.Trainer(algo, SEEDS, training.LoopConfig(chunk_updates=algo.num_updates, eval_every=0,
                                                                progress=False))
    start = trainer.init()
    runners, metrics, _ = trainer.run_chunk(start, 0)
    return algo, start, runners, {k: v.T for k, v in metrics.items()}


@pytest.fixture(scope="module")
def td3_run(corridor):
    env, params = corridor
    algo = TD3(tiny(TD3Config), env, params)
    return algo, train_seeds(algo)[0]


@pytest.fixture(scope="module")
def ppo_run(corridor):
    """PPO with a box of actions on the corridor (its test reads the evaluation and the actors' Gaussian)."""
    from wrl_jax.agents.ppo import PPO
    from wrl_jax.agents.ppo_config import PPOConfig

    env, params = corridor
    config = PPOConfig(num_envs=16, num_steps=32, num_minibatches=4, update_epochs=4, hidden_sizes=(64, 64),
                       total_timesteps=16 * 32 * 40, learning_rate=3e-3, ent_coef=0.0, gamma=0.99, obs_encoding="raw")
    algo = PPO(config, env, params)
    return algo, train_seeds(algo)[0]


@pytest.fixture(scope="module")
def evaluations(corridor, sac_run, td3_run, ppo_run):
    """Each algorithm's evaluation (``seed_summary`` per seed, as NumPy) from one program at LLVM level 0 (thresholds
    only): a row per (algorithm, seed) holds every algorithm's actor of its seed and acts with its own algorithm's
    greedy action (the others' are computed and dropped), so the episodes are traced and compiled once, not thrice."""
    env, params = corridor
    named = {"sac": (sac_run[0], sac_run[2]), "td3": td3_run, "ppo": ppo_run}
    algos = [algo for algo, _ in named.values()]

    def greedy(row, obs):
        which, nets = row
        return jnp.stack([algo.greedy_action(net, obs) for algo, net in zip(algos, nets)])[which]

    @fast_compile.jit
    def evaluate(all_runners):
        actors = [jax.vmap(algo.network_params)(runners) for algo, runners in zip(algos, all_runners)]
        rows = (np.repeat(np.arange(len(algos)), len(SEEDS)),  # row a * len(SEEDS) + s: algorithm a, seed s
                [jax.tree.map(lambda x: jnp.concatenate([x] * len(algos)), nets) for nets in actors])
        return jax.vmap(lambda row: seed_summary(evaluate_policy(greedy, row, env, params)))(rows)

    summary = evaluate([runners for _, runners in named.values()])
    summary = jax.tree.map(lambda x: np.asarray(x).reshape(len(algos), len(SEEDS)), summary)
    return {name: {k: v[a] for k, v in summary.items()} for a, name in enumerate(named)}


def test_sac_learns_to_deliver_without_collisions(sac_run, evaluations):
    metrics, evaluation = sac_run[3], evaluations["sac"]
    print({k: v.tolist() for k, v in evaluation.items()})
    assert evaluation["eval_solved"].tolist() == [1.0] * len(SEEDS)  # measured: 3/3, 9 steps each
    assert np.all(evaluation["eval_mean_steps"] <= 12)
    # Training deliveries rise: the last quarter's episodes deliver far more often than the first's.
    episodes, delivered = np.asarray(metrics["episodes"]), np.asarray(metrics["terminated"])
    quarter = episodes.shape[1] // 4
    first = delivered[:, :quarter].sum() / episodes[:, :quarter].sum()
    last = delivered[:, -quarter:].sum() / episodes[:, -quarter:].sum()
    assert last > 0.9 and last > first + 0.4, (first, last)
    # The temperature was learned: it moved away from where it started.
    assert not np.allclose(np.asarray(metrics["alpha"])[:, -1], 0.1)


def test_td3_learns_to_deliver(evaluations):
    evaluation = evaluations["td3"]
    print({k: v.tolist() for k, v in evaluation.items()})
    assert (evaluation["eval_success_rate"] == 1.0).sum() >= 2  # measured: 2/3 seeds solve it in 8,000 steps


def test_same_seeds_start_alike_and_seeds_differ(sac_run):
    """A second trainer's start from the same seeds is ``sac_run``'s bit for bit, and seeds differ. (The updates run
    again give the same bits too: test_sac_chunks_and_resume_give_the_same_bits runs them in chunks of 250 and through
    a checkpoint, a separate program, and compares every bit.)"""
    algo, start, runners, _ = sac_run
    again = training.Trainer(algo, SEEDS, training.LoopConfig(progress=False)).init()
    leaves, again_leaves = jax.tree_util.tree_leaves(start), jax.tree_util.tree_leaves(again)
    assert len(leaves) == len(again_leaves) and all(
        np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(leaves, again_leaves))
    kernels = np.asarray(runners.actor["params"]["Dense_0"]["kernel"])
    assert not np.array_equal(kernels[0], kernels[1]) and not np.array_equal(kernels[1], kernels[2])


def test_truncation_is_stored_with_the_reached_observation(sac_run):
    """Episodes of the corridor end by truncation at 60 steps early in training: the stored ``next_obs``
    of such a transition is where the robot got to (one step from ``obs``), not the next episode's start,
    and ``terminated`` is False there, so the target bootstraps from it."""
    algo, _, runners, _ = sac_run
    data = jax.tree.map(lambda x: np.asarray(x)[0], runners.buffer.data)  # NumPy: eager slices compile
    env = algo.env
    step = float(algo.env_params.v_max * algo.env_params.dt) * 1.25  # a gain may stretch a step
    moved = np.abs(data.next_obs[:, :2] - data.obs[:, :2]) * np.array([env.width, env.height])
    assert np.all(moved.max(axis=1) <= step + 1e-5)
    filled = int(np.asarray(runners.buffer.size)[0])
    # Rows are written num_envs at a time; the row of env e at vector step t+1 follows it by num_envs rows.
    follows = np.abs(data.obs[algo.config.num_envs:filled, :2] - data.next_obs[: filled - algo.config.num_envs, :2])
    resets = follows.max(axis=1) > 1e-6
    assert resets.sum() > 0  # episodes did end inside the buffer
    ended_without_delivery = resets & ~data.terminated[: filled - algo.config.num_envs]
    assert ended_without_delivery.sum() > 0  # truncations, stored as not terminated


def test_squashed_gaussian_density_counts_tanh_and_the_box(corridor):
    """log pi(a) of an action in a box of half-width 2 is the Gaussian's log-density, minus the log of
    tanh's derivative, minus log 2 per dimension (computed here in float64 from the formulas)."""
    env, params = corridor

    class WideBox(type(env)):
        def action_space(self, params=None):
            return spaces.Box(low=-2.0, high=2.0, shape=(2,), dtype=jnp.float32)

    wide = WideBox(params, num_rays=8)
    algo = SAC(tiny(SACConfig), wide, params)

    @fast_compile.jit  # one program (eagerly the networks' init and the density compile op by op); a tolerance: level 0
    def draw(obs):
        actor, _ = algo.init_networks(jax.random.key(3))
        unit, log_prob = algo.sample_unit(actor, obs, jax.random.key(4))
        return unit, log_prob, algo.gaussian(actor, obs), algo.to_env(unit)

    obs = jnp.linspace(-1, 1, 5 * 19, dtype=jnp.float32).reshape(5, 19)
    unit, log_prob, gaussian_params, in_box = draw(obs)
    mean, log_std = (np.asarray(x, np.float64) for x in gaussian_params)
    u = np.arctanh(np.clip(np.asarray(unit, np.float64), -1 + 1e-7, 1 - 1e-7))
    gaussian = -0.5 * ((u - mean) / np.exp(log_std)) ** 2 - log_std - 0.5 * math.log(2 * math.pi)
    expected = (gaussian - np.log(1 - np.tanh(u) ** 2)).sum(axis=1) - 2 * math.log(2.0)
    np.testing.assert_allclose(np.asarray(log_prob), expected, atol=2e-3)
    np.testing.assert_allclose(np.asarray(in_box), 2 * np.asarray(unit), rtol=1e-6)
    assert algo.target_entropy == -2.0
    assert SAC(dataclasses.replace(tiny(SACConfig), target_entropy=-5.0), wide, params).target_entropy == -5.0


@pytest.mark.parametrize("config_cls,changes,message", [
    (SACConfig, {"batch_size": 0}, "batch_size must be a positive integer"),
    (SACConfig, {"learning_rate": -1.0}, "learning_rate must be > 0"),
    (SACConfig, {"initial_alpha": 0.0}, "initial_alpha must be > 0"),
    (SACConfig, {"activation": "gelu"}, "activation must be one of"),
    (SACConfig, {"target_entropy": float("nan")}, "target_entropy must be a finite number or None"),
    (SACConfig, {"target_entropy": 2.0}, "largest entropy of an action"),
    (SACConfig, {"buffer_size": 4, "num_envs": 8}, "buffer_size"),
    (TD3Config, {"policy_delay": 0}, "policy_delay must be a positive integer"),
    (TD3Config, {"noise_clip": -0.1}, "noise_clip must be >= 0"),
    (SACConfig, {"anneal_from": 1.0}, "anneal_from must be in \\[0, 1\\)"),
    (TD3Config, {"anneal_lr": 1}, "anneal_lr must be True or False"),
    (SACConfig, {"anneal_from": 0.5}, "needs anneal_lr=True"),
    (SACConfig, {"actor_average": 1.5}, "actor_average must be in \\[0, 1\\]"),
    (TD3Config, {"greedy_target": 1}, "greedy_target must be True or False"),
])
def test_bad_settings_are_refused_before_compiling(corridor, config_cls, changes, message):
    env, params = corridor
    algo_cls = SAC if config_cls is SACConfig else TD3
    with pytest.raises(ValueError, match=message):
        algo_cls(dataclasses.replace(tiny(config_cls), **changes), env, params)


def test_annealed_learning_rate_is_constant_then_falls_towards_zero_at_the_last_step(corridor):
    env, params = corridor
    config = tiny(SACConfig, anneal_lr=True, anneal_from=0.5)  # 1,000 updates x 2 gradient steps
    hyper = config.hyper()
    rates = [float(SAC(config, env, params).learning_rate(hyper, jnp.int32(i))) for i in (0, 999, 1000, 1500, 1999)]
    np.testing.assert_allclose(rates, [1e-3, 1e-3, 1e-3, 0.5e-3, 1e-6], rtol=1e-4)
    constant = TD3(tiny(TD3Config), env, params)
    assert float(constant.learning_rate(constant.config.hyper(), jnp.int32(1999))) == pytest.approx(1e-3)


@pytest.fixture(scope="module")
def stepwise(corridor):
    """Small SAC and TD3 learners on the corridor, updated one jitted update at a time from a jitted init (eagerly
    the init compiles op by op): ``stepwise(name)`` is ``(algo, init, update)``, built once per name. One SAC config
    with its actor averaged at rates 0 (none), 0.05 and 1, and TD3 with and without ``preactivation_penalty``, their
    learning rates annealed over the run (400 and 1,600 steps), serve the annealed step size, the actor average and
    the penalty tests: plain SAC and TD3 share their programs with the last two."""
    env, params = corridor
    built = {}

    def build(name):
        if name not in built:
            if name.startswith("sac"):
                rate = {"sac": 0.0, "sac_average": 0.05, "sac_whole": 1.0}[name]
                config = SACConfig(num_envs=4, total_timesteps=400, learning_starts=0, batch_size=8, hidden_sizes=(8,),
                                   buffer_size=64, gradient_steps=2, anneal_lr=True, actor_average=rate)
                algo = SAC(config, env, params)
            else:
                config = TD3Config(num_envs=4, total_timesteps=1_600, learning_starts=0, batch_size=32,
                                   hidden_sizes=(16,), buffer_size=1_600, gradient_steps=2, policy_delay=1,
                                   learning_rate=1e-2, anneal_lr=True,
                                   preactivation_penalty=0.01 if name == "td3_penalty" else 0.0)
                algo = TD3(config, env, params)
            built[name] = algo, fast_compile.jit(algo.init), fast_compile.jit(algo.update)
        return built[name]

    return build


def test_the_actor_average_is_the_greedy_policy_and_leaves_training_alone(stepwise):
    """``actor_average``: the actor and critics train alike with or without it over 50 updates (up to float rounding:
    the extra update changes XLA's fusions); the evaluated parameters are the average (at rate 1 the actor itself,
    below it something else)."""
    runs = {}
    for name in ("sac", "sac_average", "sac_whole"):
        algo, init, update = stepwise(name)
        runner = init(jax.random.key(0))
        for index in range(50):  # half the run: the annealed step size still moves the actor away from its average
            runner, _ = update(runner, jnp.int32(index))
        runs[name] = (runner, algo.network_params(runner))
    plain, averaged, whole = (runs[name][0] for name in ("sac", "sac_average", "sac_whole"))
    for other in (averaged, whole):
        for got, want in zip(jax.tree.leaves((other.actor, other.critic, other.buffer.data.obs)),
                             jax.tree.leaves((plain.actor, plain.critic, plain.buffer.data.obs)), strict=True):
            np.testing.assert_allclose(got, want, atol=1e-5)
    assert plain.actor_target == {} and runs["sac"][1] is not None
    for got, want in zip(jax.tree.leaves(runs["sac_whole"][1]), jax.tree.leaves(whole.actor), strict=True):
        np.testing.assert_array_equal(got, want)
    gaps = [np.abs(np.asarray(a) - np.asarray(b)).max()
            for a, b in zip(jax.tree.leaves(runs["sac_average"][1]), jax.tree.leaves(averaged.actor), strict=True)]
    assert max(gaps) > 1e-3, max(gaps)  # the average lags the actor (measured: 3e-3)


def test_td3_greedy_target_evaluates_the_target_actor_and_trains_alike(stepwise):
    """``greedy_target``: the greedy parameters are the target actor, which lags the actor; the update is the same
    program (its jaxpr, traced, not compiled)."""
    algo, init, update = stepwise("td3")
    runner = init(jax.random.key(0))
    for index in range(5):
        runner, _ = update(runner, jnp.int32(index))
    target = TD3(dataclasses.replace(algo.config, greedy_target=True), algo.env, algo.env_params)
    assert not algo.averages_actor and target.averages_actor
    assert algo.network_params(runner) is runner.actor and target.network_params(runner) is runner.actor_target
    gaps = [np.abs(np.asarray(a) - np.asarray(b)).max()
            for a, b in zip(jax.tree.leaves(runner.actor_target), jax.tree.leaves(runner.actor), strict=True)]
    assert max(gaps) > 1e-4, max(gaps)
    trace = lambda a: str(jax.make_jaxpr(a.update)(runner, jnp.int32(5)))  # noqa: E731
    assert trace(target) == trace(algo)


@pytest.mark.parametrize("name", ["sac", "td3"])
def test_every_network_takes_the_annealed_step_size(stepwise, name):
    """An update past the run's end (where the schedule is 0) leaves every learned array as it was; the first
    learning update moves them, and both log the step size they used (the mean of the update's 2 steps)."""
    algo, init, update = stepwise(name)
    config = algo.config
    runner = init(jax.random.key(0))
    learned = lambda r: jax.tree.leaves((r.actor, r.critic, r.log_alpha))  # noqa: E731
    moved, first = update(runner, jnp.int32(0))
    stayed, past = update(runner, jnp.int32(config.num_updates + 1))
    assert all(np.array_equal(a, b) for a, b in zip(learned(stayed), learned(runner)))
    assert not all(np.array_equal(a, b) for a, b in zip(learned(moved), learned(runner)))
    steps = config.num_updates * config.gradient_steps
    assert float(past["learning_rate"]) == 0.0
    assert float(first["learning_rate"]) == pytest.approx(config.learning_rate * (1 - 0.5 / steps))


def test_td3_preactivation_penalty_draws_a_saturated_actor_out_of_the_squash(corridor, stepwise):
    """An actor deep in its tanh (outputs of 20, where tanh' is 0 in float32) gets no gradient through it: without
    the penalty 200 actor steps leave its outputs where they were; with ``preactivation_penalty`` they shrink (Adam
    moves each weight about one step size per step, whatever the gradient's scale). The setting is refused below 0."""
    env, params = corridor
    algo, init, _ = stepwise("td3")
    runner = init(jax.random.key(0))
    last = runner.actor["params"]["Dense_1"]
    saturated = {"params": {**runner.actor["params"], "Dense_1": {"kernel": np.zeros_like(last["kernel"]),
                                                                  "bias": np.full_like(last["bias"], 20.0)}}}
    start = runner.replace(actor=saturated)  # the runner does not depend on the penalty: one start for both
    actors = {}
    for name in ("td3", "td3_penalty"):
        runner, update = start, stepwise(name)[2]
        for index in range(100):
            runner, _ = update(runner, jnp.int32(index))
        actors[name] = runner.actor
    obs = np.asarray(runner.buffer.data.obs)[: int(runner.buffer.size)]  # the 400 states the penalized run visited
    before_squash = {name: float(jnp.abs(algo.actor_forward(actor, obs)).mean()) for name, actor in actors.items()}
    print(before_squash)
    assert before_squash["td3"] > 19.9  # stuck (measured: 20.0)
    assert before_squash["td3_penalty"] < 19.0  # measured: 2.6
    for bad in (-0.1, float("nan"), float("inf"), True, "0.1"):
        with pytest.raises(ValueError, match="preactivation_penalty must be a finite number >= 0"):
            TD3(dataclasses.replace(tiny(TD3Config), preactivation_penalty=bad), env, params)


def test_discrete_environments_and_wrong_configs_are_refused(corridor):
    env, params = corridor
    warehouse, warehouse_params = make("Warehouse-8x8-v0")
    with pytest.raises(ValueError, match="continuous action space"):
        SAC(SAC_DEFAULT, warehouse, warehouse_params)
    with pytest.raises(TypeError, match="TD3Config"):
        TD3(SAC_DEFAULT, env, params)
    assert TD3_DEFAULT.hyper().policy_noise == pytest.approx(0.2)
    assert TD3_DEFAULT.hyper().exploration_noise == pytest.approx(0.3)  # the continuous warehouse's (NOTES)
    assert TD3(TD3_DEFAULT, env, params).averages_actor  # the default's greedy policy is its target actor (NOTES)


def test_flops_count_both_phases(corridor):
    env, params = corridor
    sac, td3 = SAC(tiny(SACConfig), env, params), TD3(tiny(TD3Config), env, params)
    actor, critic = sac.network_flops()
    assert actor == 2 * (19 * 64 + 64 * 64 + 64 * 4) and critic == 2 * (21 * 64 + 64 * 64 + 64)
    assert sac.flops_per_update() == 2 * 64 * (4 * actor + 14 * critic) + 8 * actor
    assert 0 < td3.gradient_step_flops() < sac.gradient_step_flops()


def lag1_correlation(actions: np.ndarray) -> float:
    """The mean lag-1 autocorrelation of ``(steps, envs, A)`` actions over every env and dimension."""
    _, envs, dims = actions.shape
    return float(np.mean([np.corrcoef(actions[:-1, e, d], actions[1:, e, d])[0, 1]
                          for e in range(envs) for d in range(dims)]))


def test_correlated_exploration_keeps_its_direction(corridor, sac_run):
    """Warm-up actions: with ``noise_correlation`` 0.9 each env's action follows the last one (lag-1
    correlation near 0.9, still spread over the whole box); with 0 they are independent (read from
    ``sac_run``'s buffer: its first 62 vector steps, before learning starts at 500 transitions, every seed)."""
    env, params = corridor
    algo = SAC(tiny(SACConfig, noise_correlation=0.9), env, params)
    # The collection alone (the gradient step is not compiled): 200 vector steps, all before learning starts.
    collect = fast_compile.jit(lambda key: jax.lax.scan(algo._env_step, algo.init(key), jnp.zeros(200, jnp.int32))[0])
    runner = collect(jax.random.key(0))
    actions = np.asarray(runner.buffer.data.action)[: 8 * 200].reshape(200, 8, 2)
    lag1 = lag1_correlation(actions)
    assert lag1 > 0.75, lag1
    assert actions.min() < -0.9 and actions.max() > 0.9
    # rho = 0: independent uniform actions.
    independent_algo, _, independent_runners, _ = sac_run
    assert independent_algo.config.noise_correlation == 0.0 and independent_algo.config.learning_starts == 500
    assert independent_algo.config.num_envs == 8  # 62 vector steps of 8 envs: the 496 warm-up rows
    warm_up = np.asarray(independent_runners.buffer.data.action)[:, : 8 * 62].reshape(len(SEEDS), 62, 8, 2)
    lag1 = [lag1_correlation(seed_actions) for seed_actions in warm_up]
    print("rho 0.9:", lag1_correlation(actions), "rho 0, per seed:", lag1)
    assert max(abs(x) for x in lag1) < 0.15, lag1
    assert warm_up.min() < -0.9 and warm_up.max() > 0.9


def test_ppo_gaussian_policy_learns_the_corridor(ppo_run, evaluations):
    """PPO with a box of actions: a diagonal Gaussian (learned state-independent spread), the sample's
    density in the ratio, the mean clipped to the box as the greedy action."""
    algo, runners = ppo_run
    evaluation = evaluations["ppo"]
    assert algo.action_kind == "continuous"
    actors = jax.vmap(algo.network_params)(runners)
    print({k: v.tolist() for k, v in evaluation.items()})
    assert (evaluation["eval_solved"] == 1.0).sum() >= 2
    first = jax.tree.map(lambda x: np.asarray(x)[0], actors)

    @jax.jit  # one program (eagerly each operation compiles on its own)
    def log_prob_one_std_away(actor):
        mean = algo.forward(actor, jnp.zeros((3, algo.num_features)))
        return algo.gaussian_log_prob(actor, mean, mean + 1.0)

    log_prob = log_prob_one_std_away(first)
    std = np.exp(np.asarray(actors["log_std"], np.float64)[0])
    expected = (-0.5 / std**2 - np.log(std) - 0.5 * math.log(2 * math.pi)).sum()
    np.testing.assert_allclose(np.asarray(log_prob), expected, rtol=1e-5)


def same_bits(a, b) -> bool:
    """Two pytrees with the same structure and every leaf equal bit for bit."""
    leaves_a, leaves_b = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    return len(leaves_a) == len(leaves_b) and all(
        np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(leaves_a, leaves_b))


def test_td3_stopped_and_resumed_gives_the_same_bits(corridor, tmp_path):
    """TD3 through the driver: a run of 48 updates in chunks of 8, stopped after the first chunk with a checkpoint
    and resumed, gives the run never stopped bit for bit (one chunk program for both: that chunks give a single
    chunk's bits is the driver's, checked with SAC below). The actor's delay (3) straddles the stop, so the update
    counter, the target actor and the replay buffer must all travel in the checkpoint."""
    env, params = corridor
    algo = TD3(TD3Config(num_envs=4, total_timesteps=4 * 48, learning_starts=0, batch_size=16, hidden_sizes=(16,),
                         buffer_size=128, gradient_steps=2, policy_delay=3), env, params)
    assert algo.num_updates == 48
    trainer = training.Trainer(algo, SEEDS, training.LoopConfig(chunk_updates=8, eval_every=0, progress=False))
    start = trainer.init()
    whole = training.run(trainer, runners=start)
    assert whole.finished and whole.updates_done == 48
    meta = {"algo": "td3", "config": {"note": "test"}}
    first = training.run(trainer, tmp_path, metadata=meta, stop_after=8, runners=start)
    assert first.updates_done == 8 and not first.finished and not same_bits(first.runners, whole.runners)
    resumed = training.run(trainer, tmp_path, metadata=meta, resume=True, runners=start)
    assert resumed.finished and resumed.updates_done == 48 and same_bits(resumed.runners, whole.runners)


def test_sac_chunks_and_resume_give_the_same_bits(sac_run, tmp_path):
    """The off-policy loop through the driver: chunks of 250 updates and a resume from a checkpoint give ``sac_run``'s
    run in one chunk of 1,000 bit for bit (the replay buffer, the targets and the temperature are in the checkpoint).
    The resumed run is both: a first chunk of 250, then three more from the checkpoint."""
    algo, start, whole, _ = sac_run
    assert algo.num_updates == 1000
    in_pieces = training.Trainer(algo, SEEDS, training.LoopConfig(chunk_updates=250, eval_every=0, progress=False))

    # sac_run's start: one init program for both trainers (and the resume's template, replaced by the checkpoint).
    meta = {"algo": "sac", "config": {"note": "test"}}
    first = training.run(in_pieces, tmp_path, metadata=meta, stop_after=250, runners=start)
    assert first.updates_done == 250 and not first.finished
    resumed = training.run(in_pieces, tmp_path, metadata=meta, resume=True, runners=start)
    assert resumed.finished and same_bits(resumed.runners, whole)
