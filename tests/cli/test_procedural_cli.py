"""``python -m wrl_jax.evaluate --layout`` on layout files the test writes (ASCII and MovingAI): per file and
overall statistics of every seed's greedy policy (on the grid's and the continuous procedural warehouse), and clear
refusals of layouts the run cannot observe, of bad files and of runs of other environments.

Each run is a checkpoint of an untrained 2-seed PPO written as training writes it (training a procedural run,
even a tiny one, costs about a minute of compilation on two cores; the evaluation does not care how good the
policy is). The final generalization report of a training run is tested in tests/envs/procedural/test_procedural.py.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from wrl_jax import training
from wrl_jax.envs.warehouse import maps
from wrl_jax.cli import evaluate as cli_evaluate
from wrl_jax.agents import get_spec, ppo_config
from wrl_jax.agents.base import config_to_dict
from wrl_jax.cli.options import EnvOptions, build
from wrl_jax.envs.warehouse.layout import optimal_route_lengths, parse
from wrl_jax.training import checkpoint

SMALL_ASCII = "S . . #\n. # 0 .\n. . . G\n. . # .\n"
MOVINGAI = "type octile\nheight 6\nwidth 9\nmap\n.........\n.@@@.@@@.\n.........\n.@@@.@@@.\n.........\nTT.......\n"


@pytest.fixture(scope="module")
def procedural_run(tmp_path_factory):
    """A run directory holding the checkpoint of an untrained PPO on Procedural-Warehouse-v0, seeds 3 and 4."""
    spec = get_spec("ppo")
    config = dataclasses.replace(ppo_config.PROCEDURAL_MLP, hidden_sizes=(16,), num_envs=8, num_steps=16, num_minibatches=2,
                                 update_epochs=1, total_timesteps=256)
    # The preset's observation (the previous action too): evaluate must rebuild it from env_overrides. A pool of
    # 64 layouts (--pool-size 64): the pool program the procedural tests of other modules compile too.
    overrides = {"pool_size": 64, **ppo_config.PROCEDURAL_ENV_DEFAULTS}
    algo = build(spec, config, EnvOptions(env="Procedural-Warehouse-v0", **overrides))
    assert algo.env.observe_last_action and algo.env.observe_visited and algo.env.visit_levels == 3
    trainer = training.Trainer(algo, [3, 4], training.LoopConfig(progress=False))
    out = tmp_path_factory.mktemp("procedural-run")
    checkpoint.save(out, trainer.host_state(trainer.init()), {
        "algo": "ppo", "env": "Procedural-Warehouse-v0", "env_overrides": overrides, "preset": "procedural",
        "config": config_to_dict(config), "seeds": [3, 4], "num_updates": trainer.num_updates,
        "steps_per_update": trainer.steps_per_update, "updates_done": 0, "env_steps_done": 0,
        "train_seconds": 0.0,
    })
    return out


@pytest.fixture
def layout_files(tmp_path):
    files = {"study": tmp_path / "study8.txt", "small": tmp_path / "small.txt", "movingai": tmp_path / "shelves.map"}
    files["study"].write_text(maps.WAREHOUSE_8X8)
    files["small"].write_text(SMALL_ASCII)
    files["movingai"].write_text(MOVINGAI)
    return files


def test_evaluate_on_layout_files(procedural_run, layout_files, tmp_path, capsys):
    out = tmp_path / "layouts.json"
    paths = [str(layout_files[name]) for name in ("study", "small", "movingai")]
    argv = ["--run", str(procedural_run), "--json", str(out)]
    for path in paths:
        argv += ["--layout", path]
    assert cli_evaluate.evaluate_main(argv) == 0
    printed = capsys.readouterr().out
    result = json.loads(out.read_text())
    assert list(result["layouts"]) == paths and result["seeds"] == [3, 4]
    study, small, movingai = (result["layouts"][path] for path in paths)
    # Every item of every file, for each of the 2 seeds; the yardstick is the NumPy BFS of wrl_jax.envs.warehouse.layout.
    assert study["episodes"] == 2 * 10 and study["bfs_optimum"] == 14.0
    assert small["episodes"] == 2 * 1
    assert small["bfs_optimum"] == float(optimal_route_lengths(parse(SMALL_ASCII))[0])
    assert movingai["episodes"] == 2 * 8 and movingai["description"].startswith("MovingAI map, 6x9")
    assert result["overall"]["episodes"] == study["episodes"] + small["episodes"] + movingai["episodes"]
    for row in (study, small, movingai, result["overall"]):
        assert 0.0 <= row["delivery_rate"] <= 1.0 and row["collisions_per_episode"] >= 0
        assert row["mean_steps"] is None or row["mean_steps"] >= row["mean_optimal"]
        assert sum(entry["episodes"] for entry in row["per_seed"]) == row["episodes"]
    delivered = np.mean([entry["delivery_rate"] for entry in result["overall"]["per_seed"]])
    assert result["overall"]["delivery_rate"] == pytest.approx(delivered)
    assert f"| {paths[1]} | 1 | 1 |" in printed and "| overall |" in printed


@pytest.fixture(scope="module")
def continuous_procedural_run(tmp_path_factory, geodesic_fields_at_the_commands_level):
    """A run directory holding the checkpoint of an untrained PPO on Continuous-Procedural-Warehouse-v0 (the command's
    default view: the target and each layout's route), a pool of 8 layouts (the pool program tests/cli/test_cli.py
    compiles too), seed 3."""
    spec = get_spec("ppo")
    config = dataclasses.replace(ppo_config.PPOConfig(), hidden_sizes=(16,), num_envs=8, num_steps=16,
                                 num_minibatches=2, update_epochs=1, total_timesteps=256, obs_encoding="raw")
    overrides = {"pool_size": 8, **spec.env_defaults_for("Continuous-Procedural-Warehouse-v0")}
    algo = build(spec, config, EnvOptions(env="Continuous-Procedural-Warehouse-v0", **overrides))
    assert algo.env.observe_route and algo.env.observe_target
    trainer = training.Trainer(algo, [3], training.LoopConfig(progress=False))
    out = tmp_path_factory.mktemp("continuous-procedural-run")
    checkpoint.save(out, trainer.host_state(trainer.init()), {
        "algo": "ppo", "env": "Continuous-Procedural-Warehouse-v0", "env_overrides": overrides, "preset": "default",
        "config": config_to_dict(config), "seeds": [3], "num_updates": trainer.num_updates,
        "steps_per_update": trainer.steps_per_update, "updates_done": 0, "env_steps_done": 0, "train_seconds": 0.0,
    })
    return out


def test_evaluate_a_continuous_procedural_run_on_layout_files(continuous_procedural_run, layout_files, tmp_path,
                                                               capsys):
    """The continuous variant's policy on map files: every item of each file (the route computed for its floor), the
    pursuit controller on the same episodes beside it, ``overall`` over both files. Small files: an untrained policy
    drives each episode to its time limit. (Files are read and refused as for the grid's runs, above.)"""
    out = tmp_path / "layouts.json"
    serpentine = tmp_path / "serpentine.txt"
    serpentine.write_text("S . 0 . .\n# # # # .\n. . . . .\n. # # # #\n1 . . . G\n")
    paths = [str(layout_files["small"]), str(serpentine)]
    argv = ["--run", str(continuous_procedural_run), "--json", str(out), "--layout", paths[0], "--layout", paths[1]]
    assert cli_evaluate.evaluate_main(argv) == 0
    printed = capsys.readouterr().out
    result = json.loads(out.read_text())
    assert list(result["layouts"]) == paths and result["seeds"] == [3]
    small, two, overall = result["layouts"][paths[0]], result["layouts"][paths[1]], result["overall"]
    # The variant randomizes and has no moving obstacles: one round of every item, no bound.
    assert (small["episodes_per_seed"], two["episodes_per_seed"], overall["episodes_per_seed"]) == (1, 2, 3)
    assert small["rounds"] == 1 and overall["layouts"] == 2 and "bound_steps" not in small
    # The controller delivers every item of both floors without a contact: each file's own layout and items.
    for row in (small, two, overall):
        assert row["pursuit"]["success_rate"] == 1.0 and row["pursuit"]["collisions_per_episode"] == 0.0
        assert 0.0 <= row["success_rate"] <= 1.0 and row["collisions_per_episode"] >= 0
        assert [entry["seed"] for entry in row["per_seed"]] == [3]
    assert two["pursuit"]["mean_steps"] > small["pursuit"]["mean_steps"]  # the serpentine's second item lies further
    for key in ("success_rate", "collisions_per_episode"):  # overall: the two files' episodes together
        assert overall[key] == pytest.approx((small[key] + 2 * two[key]) / 3), key
    assert f"| {paths[0]} | 1 | 1 |" in printed and "| overall | 2 | 3 |" in printed


def test_evaluate_refuses_a_layout_larger_than_the_runs_observation(procedural_run, layout_files, tmp_path, capsys):
    big = tmp_path / "big.map"
    big.write_text("type octile\nheight 17\nwidth 4\nmap\n" + "....\n" * 17)
    argv = ["--run", str(procedural_run), "--layout", str(layout_files["small"]), "--layout", str(big)]
    assert cli_evaluate.evaluate_main(argv) == 2
    err = capsys.readouterr().err
    assert f"{big} is 17x4, larger than max_shape 16x16" in err and "observation covers floors of at most 16x16" in err
    missing = tmp_path / "nowhere.txt"
    assert cli_evaluate.evaluate_main(["--run", str(procedural_run), "--layout", str(missing)]) == 2
    assert f"--layout {missing}: no such file" in capsys.readouterr().err
    broken = tmp_path / "broken.txt"
    broken.write_text("S . ?\n. . G\n0 . .\n")
    assert cli_evaluate.evaluate_main(["--run", str(procedural_run), "--layout", str(broken)]) == 2
    assert f"{broken}: unknown character '?'" in capsys.readouterr().err


def test_evaluate_refuses_layouts_for_a_run_of_another_environment(tmp_path, layout_files, capsys):
    run = tmp_path / "fleet-run"
    checkpoint.save(run, {"x": np.zeros(1, np.float32)},
                    {"algo": "ppo", "env": "Fleet-12x12-v0", "config": {}, "seeds": [0], "updates_done": 0})
    assert cli_evaluate.evaluate_main(["--run", str(run), "--layout", str(layout_files["small"])]) == 2
    err = capsys.readouterr().err
    assert "needs a run of a procedural environment" in err
    assert "Fleet-12x12-v0 (family 'fleet')" in err
    run = tmp_path / "continuous-run"  # the continuous family's fixed maps: no layout of their own to swap
    checkpoint.save(run, {"x": np.zeros(1, np.float32)},
                    {"algo": "sac", "env": "Continuous-Warehouse-8x8-v0", "config": {}, "seeds": [0], "updates_done": 0})
    assert cli_evaluate.evaluate_main(["--run", str(run), "--layout", str(layout_files["small"])]) == 2
    assert "Continuous-Warehouse-8x8-v0 (family 'continuous')" in capsys.readouterr().err


def test_the_procedural_command_splits_the_cpu_unless_told(tmp_path):
    """``train_ppo.py --env Procedural-Warehouse-v0`` adds ``--devices N`` (N: cores, dividing the seeds) when
    the user chose nothing; never on other environments or when a flag or the environment decides."""
    from wrl_jax.cli.machine import auto_devices

    argv = ["--env", "Procedural-Warehouse-v0"]
    quiet = {}  # no WRL_DISTRIBUTED, no XLA_FLAGS
    assert auto_devices(argv, 2, quiet) == ["--devices", "2"] and auto_devices(argv, 16, quiet) == ["--devices", "4"]
    assert auto_devices(argv, 1, quiet) == []
    assert auto_devices([*argv, "--num-seeds", "3"], 2, quiet) == []  # 3 seeds do not split over 2 devices
    assert auto_devices([*argv, "--num_seeds", "3"], 2, quiet) == []  # tyro's other spelling
    assert auto_devices([*argv, "--num-seeds=6"], 4, quiet) == ["--devices", "3"]
    assert auto_devices(["--env=Procedural-Warehouse-v0"], 2, quiet) == ["--devices", "2"]
    for chosen in (["--devices", "1"], ["--devices=4"], ["--distributed"], ["--env_shards", "2"]):
        assert auto_devices([*argv, *chosen], 2, quiet) == []
    assert auto_devices(argv, 2, {"WRL_DISTRIBUTED": "1"}) == []
    assert auto_devices(argv, 2, {"XLA_FLAGS": "--xla_force_host_platform_device_count=1"}) == []
    assert auto_devices(["--env", "Warehouse-12x12-v0"], 2, quiet) == [] and auto_devices([], 2, quiet) == []
    # a resumed run keeps the devices and environment shards it recorded (a missing run: nothing added)
    (tmp_path / "config.json").write_text('{"devices": 2, "env_shards": 2}')
    assert auto_devices(["--resume", "--out", str(tmp_path)], 16, quiet) == ["--devices", "2", "--env-shards", "2"]
    assert auto_devices(["--resume", "--out", str(tmp_path / "missing")], 16, quiet) == []
