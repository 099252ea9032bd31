"""The RWARE evaluation hook: a scripted team that delivers solves, an idle one does not, returns are summed
over agents as EPyMARL sums them; and a tiny PPO run through ``train_ppo.py``'s command reports the hook's numbers."""

from __future__ import annotations

import contextlib
import inspect
import io
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import fast_compile

from wrl_jax.cli import options as cli_options
from wrl_jax.cli import train as cli_train
from wrl_jax.core import registry
from wrl_jax.envs.rware import evaluation, make_rware
from wrl_jax.envs.rware.registration import reward_code
from wrl_jax.envs.rware.types import FORWARD, LEFT_DIR, NOOP, RIGHT, RIGHT_DIR, TOGGLE_LOAD

ROW = "xgx"
"""One shelf each side of a goal: the scripted agent below fetches whichever is requested."""

CENTER, LEFT_CELL, RIGHT_CELL = 8 + 7 * 4, 8 + 7 * 3, 8 + 7 * 5
"""Offsets of sensor cells in rware's observation (sensor range 1): the own cell, left and right neighbours;
each ``has_agent, heading (4), has_shelf, requested``."""


def scripted(obs: jax.Array) -> jax.Array:
    """One agent on a row ``x g x`` (the same row repeated): pick up a requested shelf, bring it onto the goal,
    take it back home, drop it, fetch the next. A function of the observation only, as a greedy policy is."""
    carrying, heading, highway = obs[2] > 0, jnp.argmax(obs[3:7]), obs[7] > 0
    requested_here = obs[CENTER + 6] > 0
    x = obs[0]
    toward_goal = jnp.where(x < 1, RIGHT_DIR, LEFT_DIR)
    empty_side = jnp.where(obs[LEFT_CELL + 5] > 0, RIGHT_DIR, LEFT_DIR)  # the carried shelf's home
    requested_side = jnp.where(obs[LEFT_CELL + 6] > 0, LEFT_DIR, RIGHT_DIR)
    wanted = jnp.where(highway, jnp.where(carrying, empty_side, requested_side), toward_goal)
    toggle = ~highway & (carrying != requested_here)  # pick up a requested shelf, drop an unrequested one
    idle = highway & ~carrying & (obs[LEFT_CELL + 6] + obs[RIGHT_CELL + 6] == 0)
    move = jnp.where(heading == wanted, FORWARD, RIGHT)
    return jnp.where(toggle, TOGGLE_LOAD, jnp.where(idle, NOOP, move)).astype(jnp.int32)


def greedy_action(scripted_team: jax.Array, obs: jax.Array) -> jax.Array:
    """The hook's ``greedy_action(network_params, obs)``: the scripted team, or all NOOP (one program for both)."""
    return jnp.where(scripted_team, jax.vmap(scripted)(obs), NOOP)


@pytest.fixture(scope="module")
def evaluate():
    """The hook and its ``seed_summary``, jitted together (one program per environment; eagerly, each of the
    summary's operations would compile on its own), compiled at LLVM level 0 (``fast_compile``)."""
    def evaluate_and_summarize(greedy_action, scripted_team, env, params):
        result = evaluation.evaluate_policy(greedy_action, scripted_team, env, params)
        return result, evaluation.seed_summary(result)

    return fast_compile.jit(evaluate_and_summarize, static_argnums=(0, 2))


def test_a_delivering_team_solves_and_an_idle_one_does_not(evaluate):
    env, params = make_rware(1, layout=ROW, request_queue_size=1)  # 500 steps, as the registered ids
    delivering, good = evaluate(greedy_action, jnp.bool_(True), env, params)
    idle, bad = evaluate(greedy_action, jnp.bool_(False), env, params.replace(max_inactivity_steps=jnp.int32(20)))
    assert delivering.team_return.shape == (evaluation.TRAINING_EPISODES,)
    np.testing.assert_array_equal(delivering.team_return, delivering.deliveries[:, 0])  # individual, 1 agent
    assert float(good["eval_deliveries"]) > 20 and float(good["eval_solved"]) == 1.0
    assert float(good["eval_length"]) == 500
    assert float(bad["eval_return"]) == 0 and float(bad["eval_solved"]) == 0 and float(bad["eval_length"]) == 20


def test_returns_are_summed_over_agents(evaluate):
    env, params = make_rware(2, layout=f"{ROW}\n{ROW}", request_queue_size=2, reward_type="global", max_steps=200)
    both, _ = evaluate(greedy_action, jnp.bool_(True), env, params)
    team_deliveries = np.asarray(both.deliveries).sum(axis=1)
    assert team_deliveries.sum() > 0
    np.testing.assert_array_equal(both.team_return, 2 * team_deliveries)  # global: every agent paid per delivery
    single, _ = evaluate(greedy_action, jnp.bool_(True), env, params.replace(reward_type=jnp.int32(1)))
    np.testing.assert_array_equal(single.team_return, np.asarray(single.deliveries).sum(axis=1))


def test_summary_and_report_of_two_seeds():
    result = evaluation.RwareEval(team_return=jnp.array([[2.0, 4.0], [0.0, 1.0]]),
                                  deliveries=jnp.array([[[1, 1], [3, 1]], [[0, 0], [1, 0]]], jnp.int32),
                                  length=jnp.full((2, 2), 500, jnp.int32))
    summary = evaluation.summarize(result, seeds=[7, 8])
    first, second = summary["per_seed"]
    assert (first["seed"], first["return"], first["deliveries"], first["solved"]) == (7, 3.0, 3.0, True)
    assert (second["agents_delivering"], second["episodes_with_delivery"], second["solved"]) == (0.25, 0.5, False)
    assert summary["return"] == 1.75 and summary["seeds_solved"] == 1
    json.dumps(summary)
    report = evaluation.format_report(summary, "PPO x", [1024, None])
    assert "1 of 2" in report and "median 1,024 steps (1/2 seeds)" in report
    assert evaluation.format_details(summary).count("\n") == 3
    assert registry.evaluation("rware") is evaluation.EVALUATION
    with pytest.raises(ValueError, match="msg_bits"):
        env, params = make_rware(1, layout=ROW, request_queue_size=1, msg_bits=1)
        evaluation.evaluate_policy(greedy_action, True, env, params)


def test_train_ppo_on_rware_reports_the_hooks_numbers(tmp_path):
    """``train_ppo.py``'s command on rware-tiny-2ag-v2 (the ``rware`` preset unless told otherwise), MAPPO's
    centralized critic, evaluated in the loop, with rware's settings as flags: it runs and reports; no learning
    is claimed at this size."""
    out = tmp_path / "run"
    settings = ["--reward-type", "global", "--sensor-range", "2", "--max-inactivity-steps", "400",
                "--tie-order", "insertion"]
    argv = ["--env", "rware-tiny-2ag-v2", "--critic", "centralized", "--num-envs", "4", "--num-steps", "8",
            "--num-minibatches", "2", "--update-epochs", "1", "--hidden-sizes", "16", "16", "--total-timesteps", "64",
            "--num-seeds", "1", "--eval-every", "2", "--out", str(out), "--no-progress", "--no-plot", *settings]
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert cli_train.main("ppo", argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    ev = summary["eval"]
    assert ev["episodes"] == evaluation.TRAINING_EPISODES and ev["num_agents"] == 2
    assert ev["return"] >= 0 and ev["deliveries"] >= 0
    # --max-inactivity-steps 400: a team that delivers nothing stops there, before rware's 500.
    assert ev["per_seed"][0]["length"] == 400 if ev["deliveries"] == 0 else 400 <= ev["per_seed"][0]["length"] <= 500
    assert summary["convergence"]["definition"] == evaluation.SOLVED_DEFINITION
    assert summary["preset"] == "rware" and summary["config"]["learning_rate"] == 1e-3  # the family's preset
    assert summary["config"]["normalize_advantages"] is False and summary["config"]["ent_coef"] == 3e-3
    overrides = json.loads((out / "config.json").read_text())["env_overrides"]
    assert overrides == {"reward_type": "global", "sensor_range": 2, "max_inactivity_steps": 400,
                         "tie_order": "insertion"}
    command = cli_options.parse("ppo", argv)  # the command's own path from flags to its learner
    algo = cli_options.build(command.spec, command.config, command.env)
    assert algo.env.obs_size == 8 + 25 * 7 and algo.env.tie_order == "insertion"
    assert int(algo.env_params.max_inactivity_steps) == 400
    assert int(algo.env_params.reward_type) == reward_code("global")
    assert "episode return, all agents" in printed.getvalue()
    # Beside the team, the scripted team on the same episodes and settings (the final report's yardstick).
    direct = evaluation.team_episodes(algo.env, algo.env_params)
    defaults = inspect.signature(evaluation.team_episodes).parameters  # the learner's episodes: its count and its key
    assert (defaults["num_episodes"].default, defaults["seed"].default) == (evaluation.TRAINING_EPISODES,
                                                                          evaluation.EVAL_SEED)
    assert ev["scripted"]["return"] == pytest.approx(float(np.mean(direct.team_return))) and ev["scripted"]["return"] > 0
    assert f"| scripted team, same episodes: return (95 % CI over episodes), deliveries | {ev['scripted']['return']:.2f}" \
        in printed.getvalue()
    rows = (out / "metrics.csv").read_text().splitlines()
    assert {"eval_return", "eval_solved", "train_throughput"} <= set(rows[0].split(","))


def test_progress_shows_the_return_as_a_number_not_a_percentage():
    """The progress bar's latest greedy return is the team's mean return over the seeds (12.5 and 7.5: 10.00)."""
    from wrl_jax.training.log_rows import describe

    rows = [{"seed": s, "episodes": 1.0, "return_sum": 2.0, "train_throughput": 0.01, "eval_return": r}
            for s, r in ((0, 12.5), (1, 7.5))]
    text = describe(rows, evaluation.EVALUATION)
    assert text.endswith("| eval return 10.00"), text


def test_every_rware_id_takes_the_rware_preset_and_ppo_refuses_other_observation_types():
    """The preset (IPPO) follows the family, with or without gymnax's prefix; PPO's MLP reads the flattened
    vector only."""
    from wrl_jax.agents import ppo

    for name in ("rware-tiny-2ag-v2", "wrl_jax/rware-small-4ag-v2", "rware-large-19ag-hard-v2"):
        assert ppo.SPEC.preset_for(name) == "rware", name
    assert ppo.SPEC.preset_for("wrl_jax/Fleet-12x12-v0") == "fleet"
    assert ppo.SPEC.preset_for("Warehouse-8x8-v0") == ppo.SPEC.preset_for("no-such-env") == "default"
    without_flags = cli_options.parse("ppo", ["--env", "rware-tiny-2ag-v2"]).config  # IPPO unless told otherwise
    assert without_flags.critic == "local" and without_flags.ent_coef == 3e-3
    env, params = make_rware(2, shelf_columns=3, shelf_rows=1, request_queue_size=2, observation_type="image")
    with pytest.raises(ValueError, match="observation_type='image'"):
        ppo.PPO(ppo.PRESETS["rware"], env, params)


def test_the_rware_preset_leaves_a_team_that_earns_nothing_near_where_it_started():
    """Before a team's first delivery every reward is 0. Standardized, the critic's leftover noise becomes
    advantages of scale 1 and steers the policy anyway (on small-4ag some seeds settled into standing still and
    never delivered); the preset's raw advantages leave it near uniform. Rewards scaled to nothing stand for a
    team that never delivers; both arms are the preset but for that switch, with the step size held, over 50
    small updates (8 envs x 16 steps) of IPPO, four seeds. The last 10 updates' entropy on seeds 0-15 (LLVM level
    1): raw 1.58-1.60, standardized 0.93-1.46, and the means of any four seeds part the arms by 0.156 or more (the
    assertion asks 0.08; seeds 0-3 here: 1.589 raw, 1.400 standardized). A smaller batch drifts the standardized
    arm faster: 8 x 32 over 60 updates parted any four seeds by 0.12 or more, at 2.4 times the run time."""
    import dataclasses
    import math

    from wrl_jax import make, training
    from wrl_jax.agents import ppo
    from wrl_jax.agents.base import make_train_seeds

    env, params = make("rware-tiny-2ag-v2")
    preset = ppo.PRESETS["rware"]
    final_entropy = {}
    for standardized in (False, True):
        config = dataclasses.replace(preset, reward_scale=1e-12, normalize_advantages=standardized, critic="local",
                                     num_envs=8, num_steps=16, hidden_sizes=(32, 32), anneal_lr=False,
                                     total_timesteps=8 * 16 * 50)
        _, metrics = jax.jit(make_train_seeds(ppo.PPO(config, env, params)))(training.seed_keys([0, 1, 2, 3]))
        final_entropy[standardized] = np.asarray(metrics["entropy"])[:, -10:].mean(1)
    assert not preset.normalize_advantages
    assert final_entropy[False].mean() > math.log(5) - 0.08, final_entropy  # near uniform over rware's 5 actions
    assert final_entropy[True].mean() < final_entropy[False].mean() - 0.08, final_entropy
