"""Multi-agent PPO on the fleet (IPPO, and MAPPO's centralized critic): learning, bits, the critic, the CLI.

Programs shared: the module fixture ``fleet_run`` runs ``train_ppo.py``'s command (:data:`FLEET_ARGV`, 3 seeds);
the same-seed test trains the command's configuration and environment in a batch of 3 seeds too, so its
``init`` and chunk programs are the command's (served by the session's compilation cache)."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import commands_level
import fast_compile

import wrl_jax
from wrl_jax import training
from wrl_jax.agents import ppo_config
from wrl_jax.agents.base import make_train_seeds
from wrl_jax.agents.ppo import PPO
from wrl_jax.cli import train as cli_train
from wrl_jax.envs.fleet import evaluation as fleet_evaluation
from wrl_jax.envs.fleet import metrics
from wrl_jax.envs.fleet.observation import global_state

TINY = dataclasses.replace(ppo_config.FLEET, num_envs=4, num_steps=8, num_minibatches=2, update_epochs=1,
                           hidden_sizes=(16, 16), total_timesteps=4 * 8 * 2)


FLEET_ARGV = ["--env", "Fleet-12x12-v0", "--num-robots", "2", "--critic", "centralized", "--num-envs", "4",
              "--num-steps", "8", "--num-minibatches", "2", "--update-epochs", "1", "--hidden-sizes", "16", "16",
              "--total-timesteps", "64", "--num-seeds", "3", "--seed", "3", "--eval-every", "0"]
"""The command of ``fleet_run``: TINY with the centralized critic, the fleet preset's environment, seeds 3, 4, 5."""


def test_same_seed_same_bits_and_seeds_differ(fleet_run):
    """Centralized critic, two robots: a repeated seed reproduces every parameter bit; seeds differ.

    ``fleet_run``'s configuration and environment (``fleet_run`` is requested first so that its programs, the
    same as this batch of 3 seeds', are compiled once)."""
    from wrl_jax.cli.options import parse

    command = parse("ppo", [*FLEET_ARGV, "--out", str(fleet_run[0].parent / "parsed")])
    config = dataclasses.replace(TINY, critic="centralized")
    assert command.config == config
    env, params = wrl_jax.make("Fleet-12x12-v0", **command.env.overrides())
    assert env.num_robots == 2
    trainer = training.Trainer(PPO(config, env, params), [3, 3, 4], training.LoopConfig(eval_every=0, progress=False))
    first = training.run(trainer)
    again = training.run(trainer)  # the same program run again from scratch
    params = np.asarray(first.runners.params)
    np.testing.assert_array_equal(params[0], params[1])
    np.testing.assert_array_equal(params, np.asarray(again.runners.params))
    assert not np.array_equal(params[0], params[2])


def test_centralized_critic_reads_the_global_state_and_the_actor_does_not():
    env, params = wrl_jax.make("Fleet-12x12-v0", num_robots=3)
    local = PPO(TINY, env, params)
    central = PPO(dataclasses.replace(TINY, critic="centralized"), env, params)
    assert central.num_params - local.num_params == env.global_state_size() * TINY.hidden_sizes[0]

    @fast_compile.jit  # shapes and an inequality of values: LLVM level 0 (tests/fast_compile.py) compiles faster
    def outputs(key):
        obs, state = env.reset(jax.random.key(0), params)
        other = state.replace(pos=state.pos[::-1])  # the same robots, placed differently
        networks = central._init_networks(key)
        values = central.forward(networks["critic"], obs, env.global_state(state, params))
        moved = central.forward(networks["critic"], obs, env.global_state(other, params))
        return values, moved, central.forward(networks["actor"], obs)

    values, moved, logits = outputs(jax.random.PRNGKey(0))
    assert values.shape == (3, 1) and not np.allclose(values, moved)
    assert logits.shape == (3, env.num_actions)


def test_the_reached_global_state_is_kept_for_the_bootstrap_of_a_truncated_shift():
    """``info["final_global_state"]`` is the global state of the reached state, also when the shift auto-resets."""
    env, params = wrl_jax.make("Fleet-12x12-v0", num_robots=2, max_steps=2)

    @jax.jit
    def shift():
        """Two steps of a 2-step shift, in one program: per step the reached state's global state, the step's
        info and the global state of the state the step returns."""
        _, state = env.reset(jax.random.key(0), params)
        out = []
        for t in range(2):
            action = jnp.array([1, 3], jnp.int32)
            _, reached, *_ = env.transition(jax.random.key(9), state, action, params)
            _, state, _, _, truncated, info = env.step(jax.random.key(t), state, action, params)
            out.append((global_state(reached, params), info["final_global_state"], truncated,
                        env.global_state(state, params)))
        return out

    for reached_global, final_global, truncated, state_global in jax.device_get(shift()):
        np.testing.assert_array_equal(final_global[:-1], reached_global[:-1])
    assert bool(truncated) and float(final_global[-1]) == 1.0  # the shift's elapsed fraction
    assert float(state_global[-1]) == 0.0  # while the state itself is the fresh shift


def test_bad_fleet_configurations_fail_before_compiling():
    warehouse, params = wrl_jax.make("Warehouse-8x8-v0")
    with pytest.raises(ValueError, match="critic='centralized' needs a multi-agent"):
        PPO(dataclasses.replace(ppo_config.DEFAULT, critic="centralized"), warehouse, params)
    with pytest.raises(ValueError, match="critic must be one of"):
        dataclasses.replace(ppo_config.DEFAULT, critic="global").validate()
    from wrl_jax.agents.dqn import DQN
    from wrl_jax.agents.dqn_config import DEFAULT as DQN_DEFAULT

    fleet, fleet_params = wrl_jax.make("Fleet-12x12-v0", num_robots=2)
    with pytest.raises(ValueError, match="DQN is single-agent"):
        DQN(DQN_DEFAULT, fleet, fleet_params)


@pytest.mark.slow
def test_ippo_learns_a_fleet_far_above_random():
    """Two robots, a CI-sized budget (40 updates of the fleet preset, 4 epochs each, 81,920 env steps), evaluated
    after the last update: the greedy fleet delivers far more than random actions on the same shifts, and a good
    part of what PIBT delivers (the assertion asks 30 %).

    At the commands' LLVM level (``commands_level.jit``): ``make_train``'s one program and the trainer's evaluation
    (with random actions on the same shifts) compiled at level 1, whose longer compile the 40 updates repay (they
    run several times faster than at the session's level 0). Measured at level 1 on seeds 50-61 (same budget):
    0.027-0.059 deliveries per step against PIBT's 0.089, 30-67 % of it (seed 61 the lowest, the others 44 % or
    more; at level 0, seeds 50-57 gave 43-69 %). Seed 7100, used nowhere else: 0.047, 52 %. Random actions: about 0.0001."""
    config = dataclasses.replace(ppo_config.FLEET, update_epochs=4, total_timesteps=40 * ppo_config.FLEET.steps_per_update)
    env, params = wrl_jax.make("Fleet-12x12-v0", num_robots=2)
    trainer = training.Trainer(PPO(config, env, params), [7100], training.LoopConfig(eval_every=0, progress=False))
    runners, train_metrics = commands_level.jit(make_train_seeds(trainer.algo))(training.seed_keys(trainer.seeds))
    keys = jax.random.split(jax.random.key(fleet_evaluation.EVAL_SEED), fleet_evaluation.TRAINING_EPISODES)

    @commands_level.jit
    def evaluate(runners):
        """The trainer's evaluation of the seed (greedy fleet and PIBT) and random actions on the same shifts."""
        summary = jax.vmap(fleet_evaluation.seed_summary)(trainer._evaluate(runners))
        random_counts = jax.vmap(lambda k: metrics.policy_episode_counts(
            env, params, lambda obs, key: jax.random.randint(key, (env.num_robots,), 0, 5), k, 256))(keys)
        return summary, random_counts["delivered"].sum() / (keys.shape[0] * 256)

    summary, random_throughput = jax.device_get(evaluate(runners))
    train_throughput = np.asarray(train_metrics["deliveries_sum"]) / trainer.steps_per_update  # per update
    assert train_throughput.shape == (1, 40) and (0.0 <= train_throughput).all() and (train_throughput < 1.0).all()
    throughput, pibt = float(summary["eval_throughput"][0]), float(summary["eval_pibt_throughput"][0])
    random_throughput = float(random_throughput)
    assert throughput > 50 * max(random_throughput, 1 / (keys.shape[0] * 256)), (throughput, random_throughput)
    assert throughput > 0.3 * pibt, (throughput, pibt)


# ------------------------------------------------------------------ the command line
@pytest.fixture(scope="module")
def fleet_run(tmp_path_factory):
    """``train_ppo.py``'s command, run in this process (``wrl_jax.cli.main``, what the script calls), so the
    re-evaluation below reuses its compiled programs; without the periodic evaluation (the final report is
    what these tests read)."""
    out = tmp_path_factory.mktemp("fleet") / "run"
    argv = [*FLEET_ARGV, "--out", str(out), "--no-progress", "--no-plot"]
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert cli_train.main("ppo", argv) == 0
    return out, printed.getvalue()


def test_a_fleet_run_reports_the_planners_beside_the_policy(fleet_run):
    out, stdout = fleet_run
    summary = json.loads((out / "summary.json").read_text())
    ev = summary["eval"]
    for key in ("throughput", "pibt_throughput", "greedy_throughput", "sampled_throughput", "upper_bound"):
        assert isinstance(ev[key], float) and ev[key] >= 0.0, key
    assert ev["episodes_per_seed"] >= 100 and len(ev["per_seed"]) == 3 and ev["num_robots"] == 2  # 3 seeds
    assert 0.0 < ev["pibt_throughput"] <= ev["upper_bound"] * 1.05
    # The sampled policy's own counts: per seed (their mean is the overall figure), and its seeds at PIBT.
    per_seed_sampled = [row["sampled_throughput"] for row in ev["per_seed"]]
    assert np.mean(per_seed_sampled) == pytest.approx(ev["sampled_throughput"], rel=1e-9)
    assert [row["sampled_vs_pibt"] for row in ev["per_seed"]] == pytest.approx(
        [t / ev["pibt_throughput"] for t in per_seed_sampled])
    assert ev["sampled_seeds_at_least_pibt"] == sum(t >= ev["pibt_throughput"] for t in per_seed_sampled)
    assert ev["sampled_rates"]["blocks_per_100"] == pytest.approx(
        np.mean([row["sampled_blocks_per_100"] for row in ev["per_seed"]]))
    # The planners' numbers are those of `python -m wrl_jax.plan` on the same 100 shifts.
    from wrl_jax.cli.plan import run_plan

    plan = run_plan("pibt", "Fleet-12x12-v0", 2, ev["episodes_per_seed"], seed=ev["episode_seed"])
    assert plan["throughput"]["mean"] == pytest.approx(ev["pibt_throughput"], rel=1e-12)
    assert (out / fleet_evaluation.GIF_NAME).stat().st_size > 0
    report = (out / "evaluation.md").read_text()
    assert "PIBT on the same shifts" in report and "| seed |" in report
    assert "sampled policy: robot blocks per robot per 100 steps" in report
    assert summary["env_overrides"]["num_robots"] == 2 and summary["config"]["critic"] == "centralized"
    assert "PIBT" in stdout


def test_the_evaluation_command_reevaluates_a_fleet_run(fleet_run):
    """``python -m wrl_jax.evaluate --run DIR``'s work, in this process: the final report is reproduced
    to the bit."""
    from wrl_jax.cli.evaluate import evaluate_run

    out, _ = fleet_run
    again = evaluate_run(out)
    saved = json.loads((out / "summary.json").read_text())["eval"]
    assert again["throughput"] == saved["throughput"] and again["pibt_throughput"] == saved["pibt_throughput"]
    assert again["per_seed"] == saved["per_seed"]


@pytest.mark.parametrize("algo, argv, message", [
    ("ppo", ["--env", "Warehouse-8x8-v0", "--num-robots", "2"], "--num-robots: fleet options"),
    ("dqn", ["--env", "Fleet-12x12-v0"], "DQN is single-agent"),
    ("ppo", ["--env", "Fleet-12x12-v0", "--num-robots", "9"], "only 8 start cells"),
])
def test_bad_fleet_commands_fail_clearly_before_compiling(algo, argv, message, tmp_path):
    """What ``train_<algo>.py`` checks before it compiles anything (the script prints it and exits with 2)."""
    from wrl_jax.cli.options import build, parse

    with pytest.raises(ValueError, match=message):
        command = parse(algo, [*argv, "--out", str(tmp_path / "run")])
        build(command.spec, command.config, command.env)
