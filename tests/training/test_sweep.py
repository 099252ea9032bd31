"""Sweeps as one program (wrl_jax.sweep): distinct results per point and seed, equal to the
individual runs with the same values and seeds, static fields refused, outputs written."""

from __future__ import annotations

import dataclasses
import json

import jax
import numpy as np
import pytest
import commands_level

import wrl_jax
from wrl_jax import training
from wrl_jax.agents.dqn import DQN
from wrl_jax.agents.dqn_config import DQNConfig
from wrl_jax.agents.ppo import PPO
from wrl_jax.agents.ppo_config import PPOConfig
from wrl_jax.cli import sweep as sweep_cli
from wrl_jax.envs.continuous import geodesic
from wrl_jax.stats import mean_half_width
from wrl_jax.training import sweep as sw
from wrl_jax.training import sweep_columns, sweep_outputs

ENV = "Warehouse-8x8-v0"
TINY_PPO = PPOConfig(
    num_envs=8, num_steps=16, num_minibatches=2, update_epochs=1, hidden_sizes=(16,), total_timesteps=8 * 16 * 4
)
TINY_DQN = DQNConfig(
    num_envs=4,
    train_freq=1,
    batch_size=16,
    hidden_sizes=(16,),
    buffer_size=256,
    learning_starts=16,
    target_update_interval=8,
    total_timesteps=4 * 24,
)
LOOP = training.LoopConfig(chunk_updates=2, eval_every=2, progress=False)


def element_leaves(runners, index):
    return [np.asarray(x)[index] for x in jax.tree_util.tree_leaves(runners)]


def individual_run(algo, seeds):
    """The point trained on its own: its own config and env (default init path, no sweep machinery).

    Trained in a batch of the sweep's size: XLA on CPU may pick another reduction
    kernel for another batch shape (see docs/scale.md), so a bitwise comparison
    needs the same shapes.
    """
    return training.run(training.Trainer(algo, seeds, LOOP))


@pytest.fixture(scope="module")
def ppo_sweep():
    grid = {"learning_rate": [0.003, 0.03], "ent_coef": [0.0, 0.1], "shaping_coef": [0.0, 2.0]}
    sweep = sw.Sweep("ppo", TINY_PPO, ENV, {}, grid, seeds=[0, 1])
    return sweep, sw.run_sweep(sweep, LOOP)


@pytest.fixture(scope="module")
def dqn_sweep():
    grid = {"exploration_final_eps": [0.05, 0.5], "exploration_fraction": [0.2, 0.6], "shaping_coef": [1.0, 2.0]}
    sweep = sw.Sweep("dqn", TINY_DQN, ENV, {"step_penalty": -1.0}, grid, seeds=[5, 6])
    return sweep, sw.run_sweep(sweep, LOOP)


def test_grid_is_the_product_in_point_major_order(ppo_sweep):
    sweep, result = ppo_sweep
    assert len(sweep.points) == 8 and sweep.points[0] == {"learning_rate": 0.003, "ent_coef": 0.0, "shaping_coef": 0.0}
    assert sweep.points[-1] == {"learning_rate": 0.03, "ent_coef": 0.1, "shaping_coef": 2.0}
    assert sweep.batch_seeds == [0, 1] * 8
    hyper, params = sweep.batched_inputs()
    assert np.asarray(hyper.learning_rate).tolist() == pytest.approx([0.003] * 8 + [0.03] * 8)
    assert np.asarray(params.shaping_coef).tolist() == [0.0, 0.0, 2.0, 2.0] * 4
    # The runner carries exactly those values.
    assert np.array_equal(np.asarray(result.run.runners.hyper.ent_coef), np.asarray(hyper.ent_coef))
    assert len(result.per_seed) == 16 and len(result.per_point) == 8


@pytest.mark.parametrize("fixture", ["ppo_sweep", "dqn_sweep"])
def test_every_point_and_seed_trains_differently(fixture, request):
    sweep, result = request.getfixturevalue(fixture)
    params = jax.tree_util.tree_leaves(result.run.runners.params)
    flat = np.concatenate([np.asarray(x).reshape(len(sweep.batch_seeds), -1) for x in params], axis=1)
    assert len({row.tobytes() for row in flat}) == len(sweep.batch_seeds)  # all distinct
    # The training metrics differ too: each element's trace of every logged metric.
    batch = len(sweep.batch_seeds)
    traces = {}
    for i, row in enumerate(result.run.rows):
        values = [v for k, v in sorted(row.items()) if k not in ("update", "env_steps", "seed") and not np.isnan(v)]
        traces.setdefault(i % batch, []).extend(values)
    assert len({tuple(t) for t in traces.values()}) == batch


def test_ppo_sweep_equals_an_individual_run_bitwise(ppo_sweep):
    sweep, result = ppo_sweep
    point = 6  # learning rate 0.03, entropy 0.1, no shaping: none of the base values
    values = sweep.points[point]
    config = dataclasses.replace(TINY_PPO, learning_rate=values["learning_rate"], ent_coef=values["ent_coef"])
    env, params = wrl_jax.make(ENV, shaping_coef=values["shaping_coef"])
    alone = individual_run(PPO(config, env, params), sweep.batch_seeds)
    n = len(sweep.seeds)
    index = slice(point * n, (point + 1) * n)
    for a, b in zip(element_leaves(alone.runners, index), element_leaves(result.run.runners, index)):
        assert np.array_equal(a, b)
    # Same training metrics, same greedy evaluation.
    rows_alone = [r for i, r in enumerate(alone.rows) if index.start <= i % len(sweep.batch_seeds) < index.stop]
    rows_sweep = [r for r in result.metric_rows if r["point"] == point]
    for a, b in zip(rows_alone, rows_sweep):
        assert all(np.array_equal(a[k], b[k], equal_nan=True) for k in a)
    # Both runs evaluated in the loop after their last update (no trainer needed to read it).
    eval_alone, eval_sweep = training.final_evaluation(None, alone), training.final_evaluation(None, result.run)
    for a, b in zip(element_leaves(eval_alone, index), element_leaves(eval_sweep, index)):
        assert np.array_equal(a, b)


def test_dqn_sweep_equals_an_individual_run_bitwise(dqn_sweep):
    sweep, result = dqn_sweep
    point = 5
    values = sweep.points[point]
    config = TINY_DQN.replace(
        exploration_final_eps=values["exploration_final_eps"], exploration_fraction=values["exploration_fraction"]
    )
    env, params = wrl_jax.make(ENV, step_penalty=-1.0, shaping_coef=values["shaping_coef"])
    alone = individual_run(DQN(config, env, params), sweep.batch_seeds)
    index = slice(point * 2, point * 2 + 2)
    for a, b in zip(element_leaves(alone.runners, index), element_leaves(result.run.runners, index)):
        assert np.array_equal(a, b)


def test_results_table_files_and_ci(ppo_sweep, tmp_path):
    sweep, result = ppo_sweep
    data = sweep_outputs.write_outputs(result, tmp_path, command="python -m wrl_jax.sweep ...")
    for name in ("results.md", "results.csv", "results.json", "metrics.csv", "sweep.png"):
        assert (tmp_path / name).stat().st_size > 0
    table = (tmp_path / "results.md").read_text()
    assert table.count("\n| 0.003 | ") + table.count("\n| 0.03 | ") == 8  # one line per point
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved["sweep"]["grid"] == {k: list(v) for k, v in sweep.grid.items()}
    assert len(saved["per_seed"]) == 16 and data["timings"]["compile_seconds"] > 0
    # Per point: the mean of its seeds' values.
    p = result.per_point[3]
    seeds = [r for r in result.per_seed if r["point"] == 3]
    assert p["success_rate"] == pytest.approx(np.mean([r["success_rate"] for r in seeds]))
    csv_lines = (tmp_path / "results.csv").read_text().splitlines()
    assert len(csv_lines) == 17 and csv_lines[0].startswith("point,learning_rate,ent_coef,shaping_coef,seed")


def test_mean_half_width():
    mean, half, n = mean_half_width([1.0, 2.0, 3.0, None])
    assert (mean, n) == (2.0, 3) and half == pytest.approx(4.302652729911275 * 1.0 / np.sqrt(3))
    assert mean_half_width([5.0]) == (5.0, None, 1)
    assert mean_half_width([None, float("nan")]) == (None, None, 0)


@pytest.mark.parametrize(
    "algo, config, grid, message",
    [
        ("ppo", TINY_PPO, {"hidden_sizes": [(8,), (16,)]}, "'hidden_sizes' is static"),
        ("ppo", TINY_PPO, {"num_envs": [8, 16]}, "'num_envs' is static"),
        ("dqn", TINY_DQN, {"batch_size": [16, 32]}, "'batch_size' is static"),
        ("ppo", TINY_PPO, {"observe_carrying": [True, False]}, "'observe_carrying' is static"),
    ],
)
def test_static_fields_are_refused(algo, config, grid, message):
    with pytest.raises(sw.StaticFieldError, match=message):
        sw.Sweep(algo, config, ENV, {}, grid, seeds=[0])


@pytest.mark.parametrize(
    "grid, seeds, message",
    [
        ({"learning_rate": [0.01, -1.0]}, [0], "sweep point .*learning_rate.* must be > 0"),
        ({"shaping_coef": [float("inf")]}, [0], "shaping_coef must be finite"),
        ({"max_steps": [0]}, [0], "max_steps must be a positive integer"),
        ({"learning_rat": [0.01]}, [0], "unknown sweep field 'learning_rat'"),
        ({"learning_rate": [0.01, 0.01]}, [0], "repeats a value"),
        ({}, [0], "the grid is empty"),
        ({"learning_rate": [0.01]}, [], "at least one seed"),
        ({"learning_rate": [0.01]}, [1, 1], "repeated seed"),
    ],
)
def test_bad_sweeps_raise_clear_errors(grid, seeds, message):
    with pytest.raises(ValueError, match=message):
        sw.Sweep("ppo", TINY_PPO, ENV, {}, grid, seeds=seeds)


def test_grid_and_set_parsing():
    grid = sweep_cli.parse_grid(["learning_rate=0.003,0.01", "max_steps=50,100"], PPOConfig)
    assert grid == {"learning_rate": [0.003, 0.01], "max_steps": [50, 100]}
    assert isinstance(grid["max_steps"][0], int)
    config, env = sweep_cli.parse_sets(["total_timesteps=4096", "hidden_sizes=32,32", "shaping_coef=1.5"], PPOConfig)
    assert config == {"total_timesteps": 4096, "hidden_sizes": (32, 32)} and env == {"shaping_coef": 1.5}
    with pytest.raises(ValueError, match="FIELD=V1,V2"):
        sweep_cli.parse_grid(["learning_rate"], PPOConfig)
    with pytest.raises(ValueError, match="unknown field 'widths'"):
        sweep_cli.parse_sets(["widths=3"], PPOConfig)


def test_command_line_errors_exit_with_status_2(capsys):
    assert sweep_cli.main(["--algo", "ppo", "--grid", "hidden_sizes=8,16", "--no-progress"]) == 2
    assert "is static" in capsys.readouterr().err
    assert sweep_cli.main(["--algo", "nope", "--grid", "learning_rate=0.1"]) == 2
    assert "unknown algorithm" in capsys.readouterr().err
    assert sweep_cli.main(["--algo", "dqn", "--grid", "learning_rate=0.1", "--devices", "64"]) == 2
    assert "devices=64" in capsys.readouterr().err


# ------------------------------------------------------------- other families
FLEET = "Fleet-12x12-v0"
FLEET_OVERRIDES = {"num_robots": 2, "max_steps": 16}
"""Two robots, 16-step shifts: the periodic evaluation (the greedy fleet and PIBT on 32 shifts) stays cheap."""
TINY_FLEET_PPO = PPOConfig(
    num_envs=4, num_steps=8, num_minibatches=2, update_epochs=1, hidden_sizes=(16,), total_timesteps=4 * 8 * 2
)
FLEET_LOOP = training.LoopConfig(eval_every=0, progress=False)  # evaluated once, after the last update


def test_fleet_sweep_trains_each_point_with_its_block_penalty(tmp_path):
    sweep = sw.Sweep("ppo", TINY_FLEET_PPO, FLEET, FLEET_OVERRIDES, {"block_penalty": [-1.0, -5.0]}, seeds=[0, 1])
    assert sweep.env_fields == ["block_penalty"]
    with pytest.raises(sw.StaticFieldError, match="'num_robots' is static"):
        sw.Sweep("ppo", TINY_FLEET_PPO, FLEET, FLEET_OVERRIDES, {"num_robots": [2, 3]}, seeds=[0])
    result = sw.run_sweep(sweep, FLEET_LOOP)
    assert np.asarray(result.run.runners.env_params.block_penalty).tolist() == [-1.0, -1.0, -5.0, -5.0]
    # The penalty is what trains differently: the same seeds at the two points end with other parameters.
    # (That a point is bit for bit its run alone is the warehouse sweep tests' check: one code path.)
    assert not all(np.array_equal(a, b) for a, b in zip(element_leaves(result.run.runners.params, slice(0, 2)),
                                                         element_leaves(result.run.runners.params, slice(2, 4))))
    # The fleet's columns, from its evaluation summary and its multi-agent training rows.
    sweep_outputs.write_outputs(result, tmp_path, plot=False)
    header = (tmp_path / "results.md").read_text().splitlines()[2]
    for label in ("greedy throughput", "greedy / PIBT", "seeds >= PIBT", "blocks /robot /100 steps",
                  "train throughput (last log)", "first step >= PIBT"):
        assert f"| {label} |" in header
    assert "greedy success" not in header
    seeds = [r for r in result.per_seed if r["point"] == 1]
    assert {"throughput", "vs_pibt", "blocks_per_100", "at_least_pibt", "train_throughput"} <= set(seeds[0])
    assert result.per_point[1]["throughput"] == pytest.approx(np.mean([r["throughput"] for r in seeds]))
    assert result.per_point[1]["at_least_pibt_seeds"] == sum(r["at_least_pibt"] for r in seeds)


def test_procedural_fields_are_judged_by_its_params():
    """Reward constants of the procedural warehouse are params leaves (traced); its pool size fixes shapes.

    Pools of 16 layouts, as ``test_cli.py``'s procedural command: one compiled generator for both modules (and
    every ``make`` the checks and their messages call generates 16 layouts, not the default 1,024)."""
    env, config = "Procedural-Warehouse-v0", dataclasses.replace(TINY_PPO, obs_encoding="raw")
    pool = {"pool_size": 16}
    with pytest.raises(sw.StaticFieldError, match="'pool_size' is static"):
        sw.Sweep("ppo", config, env, pool, {"pool_size": [16, 8]}, seeds=[0])
    sweep = sw.Sweep("ppo", config, env, pool, {"shaping_coef": [0.0, 1.0], "step_penalty": [-1.0]}, seeds=[0, 1])
    assert sweep.env_fields == ["shaping_coef", "step_penalty"]
    _, params = sweep.batched_inputs()
    assert np.asarray(params.shaping_coef).tolist() == [0.0, 0.0, 1.0, 1.0]
    assert np.asarray(params.step_penalty).tolist() == [-1.0] * 4
    with pytest.raises(ValueError, match="unknown sweep field 'pool_sise'"):
        sw.Sweep("ppo", config, env, pool, {"pool_sise": [8]}, seeds=[0])


def test_a_family_without_sweep_columns_gets_its_numbers_and_none_for_missing_training_metrics():
    columns = sweep_columns.default_columns([{"seed": 0, "throughput": 0.5, "solved": 1.0, "name": "x"}])
    assert [(m.key, m.kind) for m in columns.metrics] == [("throughput", "number"), ("solved", "solved")]
    assert sweep_columns.training_values(columns, {"update": 1}) == {"train_mean_return": None}


def test_the_documented_fleet_command_parses():
    import shlex
    from pathlib import Path

    from wrl_jax.cli.sweep import FLEET_EXAMPLE

    docs = (Path(__file__).resolve().parents[2] / "docs" / "scale.md").read_text()
    assert FLEET_EXAMPLE in docs
    args = sweep_cli.build_parser().parse_args(shlex.split(FLEET_EXAMPLE)[3:])
    assert (args.algo, args.env, args.num_seeds) == ("ppo", FLEET, 4)
    config, env = sweep_cli.parse_sets(args.set, PPOConfig, args.env)
    assert config == {} and env == {"num_robots": 2} and isinstance(env["num_robots"], int)
    grid = sweep_cli.parse_grid(args.grid, PPOConfig, args.env)
    assert grid == {"block_penalty": [-1.0, -5.0], "ent_coef": [0.05, 0.2]}
    assert all(isinstance(v, float) for v in grid["block_penalty"])
    with pytest.raises(ValueError, match="unknown field 'num_robot'"):
        sweep_cli.parse_sets(["num_robot=2"], PPOConfig, FLEET)


def test_set_checks_environment_options_over_the_learners_defaults(monkeypatch):
    """The safety stop's margin is an option only where the stop is on, as the learners' defaults turn it on with
    moving obstacles: --set is checked over those defaults (the sweep trains over them too).

    The check builds the environment, and so the map's geodesic fields (the package's Bellman-Ford loop, hundreds
    of sweeps): that loop compiled at the commands' LLVM level, which runs it five times faster than the session's
    level 0 (3.5 s of CPU against 0.6 s), with the same bits (adds and minimums round alike at every level)."""
    from wrl_jax.agents import get_spec

    monkeypatch.setattr(geodesic, "_relax", commands_level.jit(geodesic._relax.__wrapped__, static_argnums=3))

    dynamic = "Continuous-Warehouse-12x12-Dynamic-v0"
    spec = get_spec("sac")
    _, env = sweep_cli.parse_sets(["safety_margin=0.1"], spec.config_cls, dynamic, spec.env_defaults_for(dynamic))
    assert env == {"safety_margin": 0.1}
    with pytest.raises(ValueError, match="pass safety_stop=True"):
        sweep_cli.parse_sets(["safety_margin=0.1"], spec.config_cls, dynamic)
    # Where the defaults add the stop's escape, turning the stop off takes the escape default with it.
    escaping = {**spec.env_defaults_for(dynamic), "escape_after": 10}
    _, env = sweep_cli.parse_sets(["safety_stop=False", "observe_obstacles=False"], spec.config_cls, dynamic, escaping)
    assert "escape_after" not in sweep_cli._env_overrides(escaping, env, {})
    assert sweep_cli._env_overrides(escaping, {}, {})["escape_after"] == 10
