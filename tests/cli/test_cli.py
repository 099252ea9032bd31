"""The shared command line: a tiny training run end to end, resume, evaluation command, bad input.

:data:`TINY` is ``test_training.py``'s configuration and loop (7 updates, evaluated every 3, chunks of 2; the
resume chunks by 7, that module's reference run): the two modules share their compiled chunk programs and
evaluation through the session's compilation cache."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from wrl_jax.training import checkpoint
from wrl_jax.training import metrics_io
from wrl_jax.agents.base import config_from_dict, config_to_dict
from wrl_jax.cli import options as cli_options
from wrl_jax.cli import train as cli_train
from wrl_jax.cli.options import build

REPO = Path(__file__).resolve().parents[2]
TINY = [
    "--env", "Warehouse-8x8-v0", "--num-seeds", "2", "--seed", "5", "--total-timesteps", "896",
    "--num-envs", "8", "--num-steps", "16", "--num-minibatches", "2", "--update-epochs", "2",
    "--hidden-sizes", "16", "--chunk-updates", "2", "--eval-every", "3", "--no-progress",
]  # fmt: skip
SUMMARY_FIELDS = {
    "algo", "env", "num_seeds", "total_timesteps", "compile_seconds", "train_seconds", "env_steps_per_second", "eval",
}  # fmt: skip
EVAL_FIELDS = {"success_rate", "mean_steps", "optimal_mean_steps", "collision_free_rate", "mean_return", "rows"}


pytestmark = pytest.mark.usefixtures("geodesic_fields_at_the_commands_level")  # tests/conftest.py


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    assert cli_train.main("ppo", [*TINY, "--out", str(out)]) == 0
    return out


def test_a_run_writes_every_output(finished_run, capsys):
    out = finished_run
    for name in ("summary.json", "metrics.jsonl", "metrics.csv", "learning_curve.png", "checkpoint.msgpack",
                 "evaluation.md", "config.json"):
        assert (out / name).exists(), name
    summary = json.loads((out / "summary.json").read_text())
    assert SUMMARY_FIELDS <= summary.keys() and EVAL_FIELDS <= summary["eval"].keys()
    assert summary["algo"] == "ppo" and summary["env"] == "Warehouse-8x8-v0" and summary["num_seeds"] == 2
    assert summary["seeds"] == [5, 6] and summary["finished"] and summary["updates_done"] == 7
    assert summary["env_steps_per_second"] > 0 and summary["compile_seconds"] > 0
    # FLOP accounting: achieved GFLOP/s against this machine's matmul peak, measured in the run.
    assert 0 < summary["achieved_gflops"] < summary["cpu_peak_gflops"] < 1e5
    assert summary["eval"]["optimal_mean_steps"] == 14.0
    rows = summary["eval"]["rows"]
    assert len(rows) == 2 * 10 and {r["seed"] for r in rows} == {5, 6}
    assert {"delivered", "steps", "optimal_steps", "return", "collisions", "stage_switch"} <= rows[0].keys()
    assert len(summary["convergence"]["first_optimal_step"]) == 2
    assert len(metrics_io.read_jsonl(out)) == 7 * 2
    assert "| Task Completion Rate |" in (out / "evaluation.md").read_text()


@pytest.fixture(scope="module")
def stopped_run(tmp_path_factory):
    """The tiny run stopped after 2 updates (no evaluation yet: a stop right after one is the driver's resume test,
    tests/training): each resume test below continues a copy of it, so the stopped run trains once for the three."""
    out = tmp_path_factory.mktemp("stopped") / "run"
    assert cli_train.main("ppo", [*TINY, "--out", str(out), "--stop-after", "2"]) == 0
    assert not json.loads((out / "summary.json").read_text())["finished"]
    return out


def same_leaves(finished_run, out) -> bool:
    """Whether the checkpoint in ``out`` holds the uninterrupted run's leaves, bit for bit."""
    a = checkpoint.serialization.msgpack_restore((finished_run / "checkpoint.msgpack").read_bytes())["leaves"]
    b = checkpoint.serialization.msgpack_restore((out / "checkpoint.msgpack").read_bytes())["leaves"]
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def test_resume_continues_exactly(finished_run, stopped_run, tmp_path):
    out = shutil.copytree(stopped_run, tmp_path / "split")
    # Only --resume --out: everything else comes from the checkpoint; another chunk size changes nothing.
    assert cli_train.main("ppo", ["--resume", "--out", str(out), "--no-progress", "--chunk-updates", "7"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["finished"] and summary["updates_done"] == 7
    assert same_leaves(finished_run, out)
    assert (finished_run / "metrics.csv").read_text() == (out / "metrics.csv").read_text()


def resumes_to_the_same_bits(finished_run, stopped_run, out, edit) -> bool:
    """Let ``edit`` rewrite the metadata of a copy of the stopped run's checkpoint (as an older version would have
    written it), resume it to the end: whether its leaves equal the uninterrupted run's."""
    shutil.copytree(stopped_run, out)
    path = out / "checkpoint.msgpack"
    payload = checkpoint.serialization.msgpack_restore(path.read_bytes())
    metadata = edit(json.loads(payload["metadata"]))
    path.write_bytes(checkpoint.serialization.msgpack_serialize({**payload, "metadata": json.dumps(metadata)}))
    assert cli_train.main("ppo", ["--resume", "--out", str(out), "--no-progress"]) == 0
    return same_leaves(finished_run, out)


def test_a_run_saved_before_a_setting_existed_still_resumes(finished_run, stopped_run, tmp_path):
    """A checkpoint whose config lacks a field (a setting added since it was written, at its default: the behaviour
    the run trained with) resumes as if the field had been saved, to the uninterrupted run's bits."""
    from wrl_jax.agents.ppo_config import PPOConfig

    defaults = config_to_dict(PPOConfig())

    def drop_a_default_field(metadata):
        added = sorted(name for name, value in metadata["config"].items() if defaults[name] == value)[0]
        del metadata["config"][added]
        return metadata

    assert resumes_to_the_same_bits(finished_run, stopped_run, tmp_path / "older", drop_a_default_field)


def test_a_run_saved_under_a_retired_preset_name_still_resumes(finished_run, stopped_run, tmp_path):
    """The preset a checkpoint records is a label (its config is saved whole): a run saved under a name that is no
    longer a preset (TD3's ``dynamic``, folded into its default) resumes to the uninterrupted run's bits."""
    assert resumes_to_the_same_bits(finished_run, stopped_run, tmp_path / "retired",
                                    lambda metadata: {**metadata, "preset": "retired"})


def test_evaluation_command_loads_the_checkpoint(finished_run, script_runs):
    """``python -m wrl_jax.evaluate --run DIR`` (its ``__main__`` block, in a child of :func:`script_runs`)."""
    code, stdout, stderr = script_runs["evaluate"]
    assert code == 0, stderr
    assert "| Task Completion Rate |" in stdout and "| item |" in stdout
    evaluated = json.loads(script_runs["evaluate_json"].read_text())
    trained = json.loads((finished_run / "summary.json").read_text())["eval"]
    assert evaluated["rows"] == trained["rows"] and evaluated["success_rate"] == trained["success_rate"]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--num-minibatches", "7"], "not divisible into num_minibatches=7"),
        (["--preset", "nope"], "unknown ppo preset 'nope'"),
        (["--env", "Warehouse-9x9-v0"], "unknown environment"),
        (["--num-seeds", "0"], "--num-seeds must be at least 1"),
        (["--gamma", "2"], "gamma must be in"),
        (["--resume"], "no checkpoint at"),
        (["--eval-every", "-1"], "eval_every"),
        (["--reward-type", "global"], "--reward-type: rware options, but --env"),
        (["--env", "rware-tiny-2ag-v2", "--reward-type", "best"], "reward_type"),
    ],
)
def test_bad_commands_fail_clearly_before_compiling(argv, message, capsys, tmp_path):
    assert cli_train.main("ppo", [*TINY, "--out", str(tmp_path / "x"), *argv]) == 2
    assert message in capsys.readouterr().err


def test_resume_needs_an_output_directory(capsys):
    assert cli_train.main("ppo", ["--resume"]) == 2
    assert "--resume needs --out" in capsys.readouterr().err


def test_resume_refuses_changed_settings_and_overwrite_is_explicit(finished_run, capsys):
    assert cli_train.main("ppo", ["--resume", "--out", str(finished_run), "--learning-rate", "0.5", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "config.learning_rate" in err
    assert cli_train.main("ppo", [*TINY, "--out", str(finished_run)]) == 2
    assert "--overwrite" in capsys.readouterr().err


def test_config_round_trip_through_json():
    from wrl_jax.agents import ppo_config

    data = config_to_dict(ppo_config.PAPER)
    assert data["hidden_sizes"] == [256, 256]
    assert config_from_dict(ppo_config.PPOConfig, data) == ppo_config.PAPER
    with pytest.raises(ValueError, match="no field"):
        config_from_dict(ppo_config.PPOConfig, {**data, "bogus": 1})


SCRIPTS = ("train_ppo.py", "train_dqn.py", "train_sac.py", "train_td3.py")
FLAG_CASES = [
    ("train_ppo.py", ["--xla-opt-level", "1"],
     ["--xla_backend_optimization_level=1", "--xla_cpu_use_fusion_emitters=false"]),
    ("train_dqn.py", ["--xla-opt-level", "1"],
     ["--xla_backend_optimization_level=1", "--xla_cpu_use_fusion_emitters=false"]),
    ("train_ppo.py", ["--xla-opt-level", "-1"], []),
    ("train_ppo.py", ["--devices", "4"], ["--xla_backend_optimization_level=1",
                                          "--xla_cpu_use_fusion_emitters=false",
                                          "--xla_force_host_platform_device_count=4"]),
    ("train_dqn.py", ["--devices=2", "--xla-opt-level=-1"], ["--xla_force_host_platform_device_count=2"]),
    ("train_ppo.py", ["--devices", "0"], ["--xla_backend_optimization_level=1", "--xla_cpu_use_fusion_emitters=false"]),
]
DEVICE_CASES = [("train_ppo.py", []), ("train_dqn.py", []), ("train_sac.py", []), ("train_td3.py", []),
                ("train_ppo.py", ["--env", "Procedural-Warehouse-v0"])]

SCRIPT_CHECKS = '''
import contextlib, io, json, os, runpy, sys
sys.path[:0] = [".", "tests"]
import ml_dtypes, numpy, wrl_jax, wrl_jax.cli.machine  # noqa: F401  (what every script loads before JAX; no JAX)
from forked import in_child  # a function in a forked child, its JSON result through a pipe
assert "jax" not in sys.modules, "importing wrl_jax imported JAX"


class JaxImported(BaseException):
    """Raised when JAX's backend module is first imported, with XLA_FLAGS as they are then."""


def flags_at_jax_import(script, argv):
    class Watch:
        def find_spec(self, name, *args):
            if name == "jax._src.xla_bridge":  # seen: report and stop (the rest would only cost seconds)
                raise JaxImported(os.environ.get("XLA_FLAGS", ""))

    sys.argv = [script, *argv, "--help"]
    sys.meta_path.insert(0, Watch())
    try:
        runpy.run_path(script, run_name="__main__")
    except JaxImported as seen:
        return seen.args[0].split()
    return {"error": "JAX was never imported"}


def help_texts(scripts):
    printed = {}
    for script in scripts:
        sys.argv, out = [script, "--help"], io.StringIO()
        with contextlib.redirect_stdout(out):
            try:
                runpy.run_path(script, run_name="__main__")
            except SystemExit as exit:
                printed[script] = (exit.code, out.getvalue())
    return printed


def devices_given(cases):
    os.cpu_count = lambda: 2  # as on the 2-core machine the defaults were measured on
    import wrl_jax.cli.train as train

    calls = []
    train.main = lambda algo, argv=None: calls.append((algo, sys.argv[1:] if argv is None else argv)) or 0
    given = {}
    for script, flags in cases:
        sys.argv = [script, *flags]
        os.environ.pop("XLA_FLAGS", None)
        try:
            runpy.run_path(script, run_name="__main__")
        except SystemExit:
            pass
        given[" ".join([script, *flags])] = calls.pop()
    return given


def module_output(module, argv, xla_flags):
    """``python -m module *argv``'s exit code, standard output and error, with the test session's XLA_FLAGS."""
    os.environ["XLA_FLAGS"] = xla_flags
    sys.argv, out, err = [module, *argv], io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            runpy.run_module(module, run_name="__main__", alter_sys=True)
            code = 0
        except SystemExit as exit:
            code = exit.code
    return code, out.getvalue(), err.getvalue()


flag_cases, scripts, device_cases, evaluate, xla_flags = json.loads(sys.argv[1])
print(json.dumps({"flags": [in_child(flags_at_jax_import, script, argv) for script, argv in flag_cases],
                  "help": in_child(help_texts, scripts), "devices": in_child(devices_given, device_cases),
                  "evaluate": in_child(module_output, "wrl_jax.evaluate", evaluate, xla_flags)}))
'''


@pytest.fixture(scope="module")
def script_runs(finished_run, tmp_path_factory):
    """The training scripts and ``python -m wrl_jax.evaluate`` run as a user runs them, each command in a process
    that has not started JAX: one interpreter loads what every script loads before JAX (NumPy, ml_dtypes,
    ``wrl_jax``: more than a second of CPU) and forks a child per command, instead of a fresh interpreter each.
    No ``XLA_FLAGS`` or ``WRL_DISTRIBUTED``: the training scripts choose their own; the evaluation gets the session's
    flags (its programs from the session's cache) and writes its JSON to ``runs["evaluate_json"]``."""
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "WRL_DISTRIBUTED")}
    evaluate_json = tmp_path_factory.mktemp("evaluate") / "eval.json"
    evaluate = ["--run", str(finished_run), "--json", str(evaluate_json), "--items"]
    cases = [[[script, argv] for script, argv, _ in FLAG_CASES], SCRIPTS, DEVICE_CASES, evaluate,
             os.environ.get("XLA_FLAGS", "")]
    done = subprocess.run([sys.executable, "-c", SCRIPT_CHECKS, json.dumps(cases)], cwd=REPO, capture_output=True,
                          text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stderr[-3000:]
    return {**json.loads(done.stdout.strip().splitlines()[-1]), "evaluate_json": evaluate_json}


def test_the_training_scripts_run_their_command(script_runs):
    """Each ``train_*.py`` as ``python train_*.py --help`` runs it (its ``__main__`` block: XLA flags, then the
    command's parser), in one process for the four."""
    printed = script_runs["help"]
    assert set(printed) == set(SCRIPTS), printed
    for script, (code, text) in printed.items():
        assert code == 0, script
        assert "host devices" not in text, script  # --help chooses no devices
        for flag in ("--env", "--preset", "--num-seeds", "--total-timesteps", "--learning-rate", "--out", "--resume"):
            assert flag in text, (script, flag)
    assert "--critic" in printed["train_ppo.py"][1] and "--buffer-size" in printed["train_dqn.py"][1]


def test_the_training_scripts_choose_devices_for_their_own_algorithm(script_runs):
    """Run as a user runs them, with no flags on 2 cores: ``train_sac.py`` and ``train_td3.py`` hand their command
    ``--devices 2`` on their default map, ``train_ppo.py`` only on the procedural warehouse, ``train_dqn.py`` never
    (each script names its algorithm to :func:`~wrl_jax.cli.machine.apply_for_command`)."""
    given = script_runs["devices"]
    assert given["train_sac.py"] == ["sac", ["--devices", "2"]], given
    assert given["train_td3.py"] == ["td3", ["--devices", "2"]]
    assert given["train_ppo.py"] == ["ppo", []]
    assert given["train_dqn.py"] == ["dqn", []]
    assert given["train_ppo.py --env Procedural-Warehouse-v0"] == [
        "ppo", ["--env", "Procedural-Warehouse-v0", "--devices", "2"]]


@pytest.mark.parametrize("case", range(len(FLAG_CASES)), ids=[f"{s}-{' '.join(a)}" for s, a, _ in FLAG_CASES])
def test_the_scripts_set_xla_flags_before_jax_starts(case, script_runs):
    """XLA reads XLA_FLAGS once, when JAX starts, and importing an environment starts it: ``train_ppo.py`` must set the
    command's settings first (until 2026-12-02 it set them after, so they never took effect). ``--devices N``
    splits the CPU into N host devices there (``--devices 0``, all devices, adds nothing)."""
    script, argv, expected = FLAG_CASES[case]
    assert script_runs["flags"][case] == expected, (script, argv)


def test_an_environment_may_bring_its_own_default_preset(tmp_path):
    """Without --preset, the procedural warehouse trains with PPO's 'procedural' preset (the policy that plans,
    which reads the map); the study's maps with 'default'; 'procedural_mlp' is the MLP without the map."""
    procedural = cli_options.parse("ppo", ["--env", "Procedural-Warehouse-v0", "--out", str(tmp_path / "a")])
    assert procedural.run.preset == "procedural" and procedural.config.obs_encoding == "raw"
    assert (procedural.config.encoder, procedural.config.propagation_rounds) == ("propagation", 0)
    # ... and its environment defaults: the robot's memory and the map, recorded as overrides.
    assert procedural.env.overrides() == {"observe_last_action": True, "observe_visited": True, "visit_levels": 3,
                                          "observe_map": True}
    mlp = cli_options.parse("ppo", ["--env", "Procedural-Warehouse-v0", "--preset", "procedural_mlp",
                                    "--out", str(tmp_path / "m")])
    assert mlp.config.encoder == "mlp" and mlp.env.overrides()["observe_map"] is False
    plain = cli_options.parse("ppo", ["--env", "Procedural-Warehouse-v0", "--observe-last-action", "False",
                              "--observe-visited", "False", "--visit-levels", "1", "--out", str(tmp_path / "e")])
    assert plain.env.overrides() == {"observe_last_action": False, "observe_visited": False, "visit_levels": 1,
                                     "observe_map": True}
    study = cli_options.parse("ppo", ["--out", str(tmp_path / "b")])
    assert study.run.preset == "default" and study.config.obs_encoding == "onehot"
    chosen = cli_options.parse("ppo", ["--env", "Procedural-Warehouse-v0", "--preset", "default", "--out", str(tmp_path / "c")])
    assert chosen.run.preset == "default"
    elsewhere = cli_options.parse("ppo", ["--preset", "procedural_mlp", "--out", str(tmp_path / "f")])  # the study map
    assert "observe_map" not in elsewhere.env.overrides()  # the preset's map setting is the procedural env's only
    with pytest.raises(ValueError, match="unknown environment"):
        cli_options.parse("ppo", ["--env", "Nowhere-v0", "--out", str(tmp_path / "d")])


def test_shaping_flag_reaches_the_procedural_warehouse_and_is_refused_on_the_study_maps(tmp_path):
    command = cli_options.parse("ppo", ["--env", "Procedural-Warehouse-v0", "--shaping", "bfs", "--out", str(tmp_path / "a")])
    assert command.env.overrides()["shaping"] == "bfs"
    with pytest.raises(ValueError, match="--shaping: continuous or fleet or procedural options"):
        cli_options.parse("ppo", ["--env", "Warehouse-8x8-v0", "--shaping", "bfs", "--out", str(tmp_path / "b")])


def test_continuous_learners_see_the_target_unless_told_otherwise(tmp_path):
    """Every learner's command gives the continuous warehouse ``observe_target`` (the study maps and the
    procedural variant); the flag turns it off."""
    for algo, name in (("ppo", "Continuous-Warehouse-8x8-v0"), ("sac", "Continuous-Warehouse-12x12-v0"),
                       ("td3", "Continuous-Warehouse-12x12-Dynamic-v0"), ("ppo", "Continuous-Procedural-Warehouse-v0")):
        command = cli_options.parse(algo, ["--env", name, "--out", str(tmp_path / algo)])
        assert command.env.overrides()["observe_target"] is True, name
    command = cli_options.parse("sac", ["--env", "Continuous-Warehouse-8x8-v0", "--observe-target", "False",
                                        "--out", str(tmp_path / "off")])
    assert command.env.overrides().get("observe_target") is False
    with pytest.raises(ValueError, match="--observe-target: continuous options"):
        cli_options.parse("ppo", ["--env", "Warehouse-8x8-v0", "--observe-target", "True", "--out", str(tmp_path / "x")])


def test_the_continuous_collision_penalty_observed_obstacles_and_off_policy_settings_are_flags(tmp_path):
    command = cli_options.parse("ppo", ["--env", "Continuous-Warehouse-12x12-Dynamic-v0", "--collision-penalty", "-50",
                                        "--observe-obstacles", "False", "--out", str(tmp_path / "c")])
    algo = build(command.spec, command.config, command.env)
    assert float(algo.env_params.collision_penalty) == -50.0
    assert not algo.env.observe_obstacles and algo.env.obs_size == 11 + 32 + 5 + 3  # the route kept
    command = cli_options.parse("td3", ["--env", "Continuous-Warehouse-8x8-v0", "--observe-obstacles", "True",
                                        "--safety-stop", "False", "--out", str(tmp_path / "o")])
    algo = build(command.spec, command.config, command.env)
    assert algo.env.observe_obstacles and algo.env.obs_size == 11 + 32 + 5 + 32 + 2 + 3  # the route last
    assert cli_options.parse("sac", ["--target-entropy", "-4", "--out", str(tmp_path / "t")]).config.target_entropy == -4.0
    for env_name in ("Continuous-Warehouse-12x12-v0", "Continuous-Warehouse-12x12-Dynamic-v0"):  # docs' SAC numbers
        plain = cli_options.parse("sac", ["--env", env_name, "--out", str(tmp_path / "s")]).config
        assert (plain.target_entropy, plain.actor_average) == (-6.0, 0.001)
    unaveraged = cli_options.parse("sac", ["--actor-average", "0", "--out", str(tmp_path / "u")]).config
    assert unaveraged.actor_average == 0.0
    annealed = cli_options.parse("td3", ["--anneal-lr", "--anneal-from", "0.5", "--out", str(tmp_path / "a")]).config
    assert (annealed.anneal_lr, annealed.anneal_from) == (True, 0.5)
    with pytest.raises(ValueError, match="--observe-obstacles: continuous options"):
        cli_options.parse("ppo", ["--env", "Warehouse-8x8-v0", "--observe-obstacles", "True", "--out", str(tmp_path / "o")])
    with pytest.raises(ValueError, match="--collision-penalty: continuous options"):
        cli_options.parse("ppo", ["--env", "Warehouse-8x8-v0", "--collision-penalty", "-5", "--out", str(tmp_path / "x")])


def test_the_safety_stop_is_a_flag_of_the_continuous_warehouse_randomized_or_not(tmp_path):
    dynamic = "Continuous-Warehouse-12x12-Dynamic-v0"
    command = cli_options.parse("ppo", ["--env", dynamic, "--safety-stop", "True", "--out", str(tmp_path / "s")])
    assert build(command.spec, command.config, command.env).env.safety_margin == 0.05
    command = cli_options.parse("sac", ["--env", dynamic, "--safety-stop", "False", "--out", str(tmp_path / "n")])
    assert build(command.spec, command.config, command.env).env.safety_margin is None
    command = cli_options.parse("td3", ["--env", dynamic, "--safety-stop", "True", "--safety-margin", "0.1",
                                        "--out", str(tmp_path / "m")])
    assert build(command.spec, command.config, command.env).env.safety_margin == 0.1
    with pytest.raises(ValueError, match="--safety-stop: continuous options"):
        cli_options.parse("ppo", ["--env", "Warehouse-8x8-v0", "--safety-stop", "True", "--out", str(tmp_path / "w")])
    command = cli_options.parse("ppo", ["--env", dynamic, "--safety-stop", "True", "--randomize", "True",
                                        "--out", str(tmp_path / "r")])
    randomized = build(command.spec, command.config, command.env)
    assert randomized.env.safety_margin == 0.05 and bool(randomized.env_params.randomize)


def test_sac_and_td3_see_the_route_on_the_study_maps_and_every_learner_the_obstacles_where_they_move(tmp_path):
    """SAC's and TD3's commands add geodesic shaping, ``observe_route`` and the safety stop with its held value in
    view on the study's maps (on the procedural variant every learner's command adds them too, under randomization);
    PPO keeps the target alone on the study's maps; on
    the moving obstacles' map every learner also sees the obstacles, and PPO trains for the 3M steps measured there
    (SAC for 800k, as TD3 does everywhere); the flags turn it off, and a route without the fields is refused by name
    when the environment is built, before anything compiles."""
    dynamic = "Continuous-Warehouse-12x12-Dynamic-v0"
    for algo in ("sac", "td3"):
        for name in ("Continuous-Warehouse-8x8-v0", "Continuous-Warehouse-12x12-v0"):
            command = cli_options.parse(algo, ["--env", name, "--out", str(tmp_path / algo)])
            overrides = command.env.overrides()
            assert (overrides["shaping"], overrides["observe_route"], overrides["observe_target"]) == (
                "geodesic", True, True), (algo, name)
            # and the safety stop, with how long it has held the robot in view
            assert (overrides["observe_obstacles"], overrides["safety_stop"]) == (True, True), (algo, name)
            env = build(command.spec, command.config, command.env).env
            assert env.safety_margin == 0.05 and env.observe_held and env.escape_after is None, (algo, name)
    for algo in ("sac", "td3", "ppo"):  # every learner sees each generated layout's route, over the stop
        overrides = cli_options.parse(algo, ["--env", "Continuous-Procedural-Warehouse-v0", "--out",
                                             str(tmp_path / algo)]).env.overrides()
        assert (overrides["shaping"], overrides["observe_route"], overrides["observe_target"]) == (
            "geodesic", True, True), algo
        assert overrides["safety_stop"] and overrides["observe_obstacles"], algo
        assert overrides["escape_after"] == 10, algo  # and the stop's escape from standstills
    # Turning the stop off takes its escape default with it; an escape asked for without the stop is refused by name.
    off = ["--env", "Continuous-Procedural-Warehouse-v0", "--pool-size", "4", "--safety-stop", "False",
           "--observe-obstacles", "False", "--out", str(tmp_path / "off")]
    command = cli_options.parse("ppo", off)
    assert "escape_after" not in command.env.overrides()
    assert build(command.spec, command.config, command.env).env.safety_margin is None
    command = cli_options.parse("ppo", [*off, "--escape-after", "10"])
    with pytest.raises(ValueError, match="escape_after is the safety stop's"):
        build(command.spec, command.config, command.env)
    for algo in ("sac", "td3", "ppo"):
        overrides = cli_options.parse(algo, ["--env", dynamic, "--out", str(tmp_path / algo)]).env.overrides()
        assert (overrides["shaping"], overrides["observe_route"], overrides["observe_target"],
                overrides["observe_obstacles"], overrides["safety_stop"], overrides["escape_after"]) == (
            "geodesic", True, True, True, True, 10), algo
    ppo = cli_options.parse("ppo", ["--env", dynamic, "--out", str(tmp_path / "p")])
    assert ppo.run.preset == "continuous_dynamic" and ppo.config.total_timesteps == 3_000_000
    sac = cli_options.parse("sac", ["--env", dynamic, "--out", str(tmp_path / "sac")])  # twice the static maps'
    assert sac.run.preset == "dynamic" and sac.config.total_timesteps == 800_000
    assert cli_options.parse("sac", ["--out", str(tmp_path / "s12")]).config.total_timesteps == 400_000
    for env_args in (["--env", dynamic], []):  # TD3: one preset, 800k and the penalty everywhere
        td3 = cli_options.parse("td3", [*env_args, "--out", str(tmp_path / "t")])
        assert td3.run.preset == "default" and td3.config.total_timesteps == 800_000, env_args
        assert td3.config.preactivation_penalty == 0.001, env_args
    alone = cli_options.parse("ppo", ["--env", dynamic, "--shaping", "manhattan", "--observe-route", "False",
                                      "--observe-obstacles", "False", "--out", str(tmp_path / "alone")])
    assert build(alone.spec, alone.config, alone.env).env.obs_size == 11 + 32 + 5  # the docs' target-alone rows
    assert "observe_route" not in cli_options.parse("ppo", ["--env", "Continuous-Warehouse-12x12-v0", "--out",
                                                            str(tmp_path / "ppo")]).env.overrides()
    command = cli_options.parse("td3", ["--env", "Continuous-Warehouse-8x8-v0", "--observe-route", "False",
                                        "--out", str(tmp_path / "off")])
    algo = build(command.spec, command.config, command.env)
    assert algo.env.obs_size == 11 + 32 + 5 + (32 + 2 + 1) and not algo.env.observe_route  # the stop kept, no route
    command = cli_options.parse("sac", ["--env", "Continuous-Warehouse-8x8-v0", "--shaping", "manhattan",
                                        "--out", str(tmp_path / "bad")])
    with pytest.raises(ValueError, match="observe_route reads the geodesic shaping's distance fields"):
        build(command.spec, command.config, command.env)


def test_the_continuous_procedural_pool_size_is_a_flag_and_the_study_maps_refuse_it(tmp_path):
    command = cli_options.parse("ppo", ["--env", "Continuous-Procedural-Warehouse-v0", "--pool-size", "8",
                                        "--out", str(tmp_path / "a")])
    algo = build(command.spec, command.config, command.env)
    assert algo.env_params.pool.blocked.shape[0] == 8 and algo.env.observe_target and algo.env.observe_route
    assert algo.env_params.pool_fields.shape[0] == 8  # every slot's distance fields
    with pytest.raises(ValueError, match="--pool-size: procedural options, but --env Continuous-Warehouse-8x8-v0"):
        cli_options.parse("ppo", ["--env", "Continuous-Warehouse-8x8-v0", "--pool-size", "8", "--out", str(tmp_path / "b")])
    with pytest.raises(ValueError, match="--pool-refresh: procedural options"):
        cli_options.parse("ppo", ["--env", "Continuous-Procedural-Warehouse-v0", "--pool-refresh", "4",
                                  "--out", str(tmp_path / "c")])


def test_encoder_flag_builds_the_propagation_policy_and_refuses_an_env_without_a_map(tmp_path):
    """``--encoder propagation`` reaches PPO's config; with ``--observe-map False`` the build (before any
    compilation) names the missing map and the flag that adds it."""
    argv = ["--env", "Procedural-Warehouse-v0", "--encoder", "propagation", "--propagation-rounds", "32",
            "--pool-size", "16"]
    command = cli_options.parse("ppo", [*argv, "--observe-map", "True", "--out", str(tmp_path / "a")])
    assert (command.config.encoder, command.config.propagation_rounds) == ("propagation", 32)
    algo = build(command.spec, command.config, command.env)
    assert algo.map_layout == algo.env.map_observation()
    command = cli_options.parse("ppo", [*argv, "--observe-map", "False", "--out", str(tmp_path / "b")])
    with pytest.raises(ValueError, match="observes none .*--observe-map True"):
        build(command.spec, command.config, command.env)


def test_randomize_flag_builds_the_randomized_warehouse(tmp_path):
    """``--randomize True`` (domain randomization) reaches the continuous warehouse's params; other families refuse it."""
    command = cli_options.parse("sac", ["--env", "Continuous-Warehouse-8x8-v0", "--randomize", "True",
                                        "--out", str(tmp_path / "a")])
    algo = cli_options.build(command.spec, command.config, command.env)  # over SAC's default stop, which reads the gains
    assert bool(algo.env_params.randomize) and algo.env.observe_target and algo.env.safety_margin == 0.05
    plain = cli_options.parse("sac", ["--env", "Continuous-Warehouse-8x8-v0", "--out", str(tmp_path / "b")])
    assert "randomize" not in plain.env.overrides()
    with pytest.raises(ValueError, match="--randomize: continuous options"):
        cli_options.parse("ppo", ["--env", "Warehouse-8x8-v0", "--randomize", "True", "--out", str(tmp_path / "c")])


def test_sac_and_td3_split_the_cpu_on_every_environment_unless_told():
    """``train_sac.py`` and ``train_td3.py`` add ``--devices N`` on any environment (their updates leave a core
    idle on one device); PPO only on the procedural warehouse; a flag, a seed count that does not divide, or one
    core decides otherwise."""
    from wrl_jax.cli.machine import auto_devices

    quiet = {}
    for algo in ("sac", "td3"):
        assert auto_devices([], 2, quiet, algo=algo) == ["--devices", "2"]
        assert auto_devices(["--env", "Continuous-Warehouse-8x8-v0"], 2, quiet, algo=algo) == ["--devices", "2"]
        assert auto_devices(["--num-seeds", "3"], 2, quiet, algo=algo) == []
        assert auto_devices([], 1, quiet, algo=algo) == []
        assert auto_devices(["--devices", "1"], 2, quiet, algo=algo) == []
    assert auto_devices(["--env", "Continuous-Warehouse-12x12-v0"], 2, quiet, algo="ppo") == []
    assert auto_devices([], 2, quiet, algo="dqn") == []
