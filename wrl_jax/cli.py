"""The command line shared by ``train_ppo.py``, ``train_dqn.py`` and ``python -m wrl_jax.evaluate``.

A training command is ``main("ppo")``: flags come from three dataclasses,
flattened by tyro into one flag namespace:

- :class:`EnvOptions`: ``--env`` and every environment override (reward
  constants, ``--max-steps``, the two failure-mode switches);
- :class:`RunOptions`: ``--preset``, ``--num-seeds``, ``--seed``, ``--out``,
  ``--resume``, chunking/evaluation/logging cadence, progress;
- the algorithm's config dataclass: every hyperparameter (``--learning-rate``,
  ``--total-timesteps``...). ``--preset NAME`` picks the defaults the other flags
  override.

Everything is validated before anything is compiled: a bad value raises
``ValueError`` naming it (the command prints it and exits with status 2).

A run writes to ``--out`` (default ``runs/<algo>-<env>-<time>``): ``metrics.jsonl``
and ``metrics.csv`` (per update and seed), ``learning_curve.png``,
``checkpoint.msgpack`` (resumable with ``--resume --out DIR``, which reuses the
checkpoint's settings), ``evaluation.md`` (the Table-3-style table and the
per-item table) and ``summary.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import importlib
import json
import os
import platform
import sys
import time
import typing
from pathlib import Path
from typing import Any

from wrl_jax.agents.base import AlgoSpec

ALGORITHM_MODULES = {"ppo": "wrl_jax.agents.ppo", "dqn": "wrl_jax.agents.dqn"}
"""Algorithm name -> module defining ``SPEC`` (an :class:`~wrl_jax.agents.base.AlgoSpec`)."""

DEFAULT_XLA_OPT_LEVEL = 1
"""LLVM optimization level for XLA's CPU code (``--xla_backend_optimization_level``).

XLA's default (3) spends about twice the compile time for no measurable speed-up
on these small kernels (docs/training.md has the measurement); on a one-minute
run compile time is a real share. Set ``--xla-opt-level -1`` to keep XLA's default,
or put the flag in ``XLA_FLAGS`` yourself (that wins)."""


def get_spec(name: str) -> AlgoSpec:
    """The :class:`AlgoSpec` of a registered algorithm."""
    if name not in ALGORITHM_MODULES:
        raise ValueError(f"unknown algorithm {name!r}; known: {sorted(ALGORITHM_MODULES)}")
    return importlib.import_module(ALGORITHM_MODULES[name]).SPEC


# -------------------------------------------------------------------- options
@dataclasses.dataclass
class EnvOptions:
    """The environment and its overrides (``None`` keeps the registered value)."""

    env: str = "Warehouse-12x12-v0"
    """registered environment name"""
    max_steps: int | None = None
    """episode length before truncation"""
    step_penalty: float | None = None
    obstacle_penalty: float | None = None
    wall_penalty: float | None = None
    shaping_coef: float | None = None
    pickup_reward: float | None = None
    delivery_reward: float | None = None
    observe_carrying: bool = True
    """include the carrying flag in the observation (False: the study's failure mode)"""
    collision_bug: bool = False
    """reproduce the study's collision bug"""

    def overrides(self) -> dict[str, Any]:
        """Keyword overrides for ``wrl_jax.make``: only what differs from the registered environment."""
        out = {
            f.name: getattr(self, f.name)
            for f in dataclasses.fields(self)
            if f.name not in ("env", "observe_carrying", "collision_bug") and getattr(self, f.name) is not None
        }
        if not self.observe_carrying:
            out["observe_carrying"] = False
        if self.collision_bug:
            out["collision_bug"] = True
        return out


@dataclasses.dataclass
class RunOptions:
    """Seeds, output and how the host drives training."""

    preset: str = "default"
    """hyperparameter preset the other flags override (e.g. default, paper)"""
    num_seeds: int = 4
    """independent seeds trained at once (vmapped)"""
    seed: int = 0
    """first seed; the run trains seeds seed .. seed + num_seeds - 1"""
    out: Path | None = None
    """output directory (default runs/<algo>-<env>-<time>)"""
    resume: bool = False
    """continue the checkpoint in --out (its settings are reused)"""
    overwrite: bool = False
    """start over in an --out that already holds a checkpoint"""
    stop_after: int | None = None
    """stop (with a checkpoint) after this many updates; --resume continues"""
    chunk_updates: int | None = None
    """updates per compiled call (progress/checkpoint granularity; results do not depend on it)"""
    eval_every: int | None = None
    """greedy evaluation on every item every this many updates and after the last (0: only the final one)"""
    log_every: int | None = None
    """updates aggregated per metrics row"""
    checkpoint_every: int = 1
    """chunks between checkpoints"""
    progress: bool = True
    """show a progress bar"""
    plot: bool = True
    """write learning_curve.png"""
    xla_opt_level: int = DEFAULT_XLA_OPT_LEVEL
    """XLA CPU backend optimization level (-1: XLA's default)"""
    devices: int = 1
    """shard the seeds over this many devices (0: all, every host's; 1: no sharding); docs/scale.md"""
    env_shards: int = 1
    """of those devices, how many split each seed's environments"""
    distributed: bool = False
    """multi-host: call jax.distributed.initialize first (WRL_COORDINATOR, WRL_NUM_PROCESSES, WRL_PROCESS_ID)"""

    def seeds(self) -> list[int]:
        return list(range(self.seed, self.seed + self.num_seeds))


def config_to_dict(config: Any) -> dict[str, Any]:
    """A config dataclass as JSON-able data (tuples become lists)."""
    return json.loads(json.dumps(dataclasses.asdict(config)))


def config_from_dict(cls: type, data: dict[str, Any]) -> Any:
    """Rebuild a config dataclass from :func:`config_to_dict`'s output (lists back to tuples)."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ValueError(f"{cls.__name__} has no field(s) {unknown}")
    values = {}
    for name, value in data.items():
        if isinstance(value, list) and typing.get_origin(hints[name]) is tuple:
            value = tuple(value)
        values[name] = value
    return cls(**values)


# --------------------------------------------------------------------- parse
@dataclasses.dataclass
class Command:
    """A parsed and validated training command."""

    spec: AlgoSpec
    env: EnvOptions
    run: RunOptions
    config: Any

    @property
    def out_dir(self) -> Path:
        assert self.run.out is not None
        return self.run.out


def parse(algo: str, argv: list[str] | None = None) -> Command:
    """Parse and validate a training command line (raises ``ValueError``; ``--help`` exits)."""
    import tyro

    from wrl_jax import checkpoint

    spec = get_spec(algo)
    argv = list(sys.argv[1:] if argv is None else argv)
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--preset", default=spec.default_preset)
    pre.add_argument("--out", default=None)
    pre.add_argument("--resume", action="store_true")
    known, _ = pre.parse_known_args(argv)

    env_defaults = EnvOptions(env=spec.default_env)
    run_defaults = RunOptions(preset=spec.default_preset, num_seeds=spec.default_num_seeds)
    if known.resume:
        if known.out is None:
            raise ValueError("--resume needs --out DIR, the directory of the run to continue")
        saved = checkpoint.read_metadata(known.out)
        if saved.get("algo") != spec.name:
            raise ValueError(f"{known.out} holds a {saved.get('algo')!r} run, not {spec.name!r}")
        config_defaults = config_from_dict(spec.config_cls, saved["config"])
        env_defaults = EnvOptions(env=saved["env"], **saved.get("env_overrides", {}))
        seeds = saved["seeds"]
        run_defaults = dataclasses.replace(
            run_defaults, preset=saved.get("preset", spec.default_preset), num_seeds=len(seeds), seed=seeds[0]
        )
        if "log_every" in saved:
            run_defaults = dataclasses.replace(
                run_defaults, log_every=saved["log_every"], eval_every=saved["eval_every"]
            )
    else:
        if known.preset not in spec.presets:
            raise ValueError(f"unknown {spec.name} preset {known.preset!r}; choose from {sorted(spec.presets)}")
        config_defaults = spec.presets[known.preset]
        run_defaults = dataclasses.replace(run_defaults, preset=known.preset)

    args_cls = dataclasses.make_dataclass(
        f"{spec.name.upper()}Args",
        [("env", EnvOptions), ("run", RunOptions), ("algo", spec.config_cls)],
    )
    defaults = args_cls(env=env_defaults, run=run_defaults, algo=config_defaults)
    parsed = tyro.cli(
        args_cls,
        default=defaults,
        args=argv,
        prog=f"train_{spec.name}.py",
        description=f"Train {spec.name.upper()} on a warehouse environment (wrl_jax). "
        f"Presets: {', '.join(sorted(spec.presets))}.",
        config=(tyro.conf.OmitArgPrefixes,),
    )
    command = Command(spec=spec, env=parsed.env, run=parsed.run, config=parsed.algo)
    validate(command)
    return command


def validate(command: Command) -> None:
    """Raise ``ValueError`` for anything wrong with a command, before anything is compiled."""
    from wrl_jax import registry

    run, spec = command.run, command.spec
    if run.preset not in spec.presets:
        raise ValueError(f"unknown {spec.name} preset {run.preset!r}; choose from {sorted(spec.presets)}")
    registry.spec(command.env.env)  # unknown environment -> ValueError
    if run.num_seeds < 1:
        raise ValueError(f"--num-seeds must be at least 1, got {run.num_seeds}")
    if run.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {run.seed}")
    if run.stop_after is not None and run.stop_after < 1:
        raise ValueError(f"--stop-after must be a positive number of updates, got {run.stop_after}")
    if run.resume and run.overwrite:
        raise ValueError("--resume and --overwrite contradict each other")
    if run.devices < 0 or run.env_shards < 1:
        raise ValueError(f"--devices must be >= 0 (0: all) and --env-shards >= 1, got {run.devices}, {run.env_shards}")
    command.config.validate()
    if run.out is None:
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        run.out = Path("runs") / f"{spec.name}-{command.env.env}-{stamp}"
    run.out = Path(run.out)


# ------------------------------------------------------------------- building
def build(spec: AlgoSpec, config: Any, env_options: EnvOptions):
    """The algorithm object for a config and environment options."""
    import wrl_jax

    env, env_params = wrl_jax.make(env_options.env, **env_options.overrides())
    return spec.algorithm_cls(config, env, env_params)


def apply_xla_opt_level(level: int) -> None:
    """Set XLA's CPU backend optimization level unless ``XLA_FLAGS`` already sets it.

    Effective only before JAX compiles anything in this process.
    """
    if level < 0:
        return
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_backend_optimization_level" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} --xla_backend_optimization_level={int(level)}".strip()


def _cpu_info() -> dict[str, Any]:
    info: dict[str, Any] = {"machine": platform.machine(), "cpu_count": os.cpu_count()}
    try:
        info["load_average"] = list(os.getloadavg())
    except OSError:
        pass
    return info


# ------------------------------------------------------------------------ run
def train(command: Command) -> dict[str, Any]:
    """Train, evaluate and write every output of a parsed command; returns the summary."""
    import jax
    import numpy as np

    from wrl_jax import checkpoint, evaluation, metrics_io, training
    from wrl_jax.agents.networks import measured_matmul_peak_gflops

    wall_start = time.perf_counter()
    load_at_start = _cpu_info()
    spec, run, out = command.spec, command.run, command.out_dir
    if not run.resume and (out / checkpoint.CHECKPOINT_NAME).exists() and not run.overwrite:
        raise ValueError(f"{out} already holds a run; pass --resume to continue it or --overwrite to start over")
    apply_xla_opt_level(run.xla_opt_level)
    if run.distributed:
        from wrl_jax import sharding

        sharding.initialize_distributed()
    algo = build(spec, command.config, command.env)
    loop = training.LoopConfig(
        chunk_updates=run.chunk_updates,
        eval_every=run.eval_every,
        log_every=run.log_every,
        checkpoint_every=run.checkpoint_every,
        progress=run.progress,
    )
    if run.devices != 1 or run.env_shards != 1 or run.distributed:
        from wrl_jax import sharding

        # Multi-host: every host's devices unless --devices says otherwise.
        devices = 0 if run.distributed and run.devices == 1 else run.devices
        mesh = sharding.make_mesh(devices, run.env_shards)
        trainer = sharding.ShardedTrainer(algo, run.seeds(), loop, mesh)
        print(f"sharding over {sharding.describe(mesh)}", file=sys.stderr)
    else:
        trainer = training.Trainer(algo, run.seeds(), loop)
    out.mkdir(parents=True, exist_ok=True)
    metadata = {
        "algo": spec.name,
        "env": command.env.env,
        "env_overrides": command.env.overrides(),
        "preset": run.preset,
        "config": config_to_dict(command.config),
    }
    checkpoint.atomic_write_text(out / "config.json", json.dumps({**metadata, "seeds": run.seeds()}, indent=2))
    t0 = time.perf_counter()
    runners = trainer.init()
    jax.block_until_ready(runners)
    init_seconds = time.perf_counter() - t0
    result = training.run(trainer, out, metadata=metadata, resume=run.resume, stop_after=run.stop_after, runners=runners)

    t0 = time.perf_counter()
    episodes = training.final_evaluation(trainer, result)
    eval_summary = evaluation.summarize(episodes, trainer.seeds)
    eval_seconds = time.perf_counter() - t0
    first = result.convergence.first_optimal_update(len(trainer.seeds))
    stable = result.convergence.stable_optimal_update(len(trainer.seeds))
    steps = trainer.steps_per_update
    first_steps = [None if u is None else u * steps for u in first]
    stable_steps = [None if u is None else u * steps for u in stable]

    label = f"{spec.name.upper()} {command.env.env} ({run.preset}, {len(trainer.seeds)} seeds)"
    study = dict(spec.study) if spec.study and command.env.env == spec.default_env else None
    table = evaluation.format_table3(eval_summary, label, first_steps, study=study)
    items = evaluation.format_items(eval_summary)
    checkpoint.atomic_write_text(out / "evaluation.md", f"{table}\n\n{items}\n")

    rows = metrics_io.read_jsonl(out / metrics_io.JSONL_NAME)
    if run.plot and rows:
        metrics_io.plot_learning_curves(rows, out / metrics_io.PLOT_NAME, title=label)

    env_steps_per_seed = result.updates_done * steps
    env_steps_all = env_steps_per_seed * len(trainer.seeds)
    flops = algo.flops_per_update()
    summary: dict[str, Any] = {
        "algo": spec.name,
        "env": command.env.env,
        "env_overrides": command.env.overrides(),
        "preset": run.preset,
        "num_seeds": len(trainer.seeds),
        "seeds": trainer.seeds,
        "total_timesteps": command.config.total_timesteps,
        "num_updates": trainer.num_updates,
        "updates_done": result.updates_done,
        "finished": result.finished,
        "steps_per_update": steps,
        "env_steps_per_seed": env_steps_per_seed,
        "init_seconds": init_seconds,
        "compile_seconds": result.compile_seconds,
        "train_seconds": result.train_seconds,
        "eval_seconds": eval_seconds,
        "env_steps_per_second": env_steps_all / result.train_seconds if result.train_seconds > 0 else None,
        "flops_per_update_per_seed": flops,
        "achieved_gflops": (flops * result.updates_done * len(trainer.seeds) / result.train_seconds / 1e9)
        if flops and result.train_seconds > 0
        else None,
        "cpu_peak_gflops": measured_matmul_peak_gflops() if flops else None,  # measured after training
        "convergence": {
            "first_optimal_step": first_steps,
            "stable_optimal_step": stable_steps,
            "eval_every_updates": trainer.loop.eval_every,
            "definition": "env steps per seed at the first periodic greedy evaluation delivering every item at "
            "the BFS optimum (stable: from which every later evaluation did too)",
        },
        "eval": {k: v for k, v in eval_summary.items()},
        "config": config_to_dict(command.config),
        "versions": {"wrl_jax": checkpoint.wrl_jax_version(), "jax": jax.__version__, "numpy": np.__version__},
        "machine": {"at_start": load_at_start, "at_end": _cpu_info(), "xla_flags": os.environ.get("XLA_FLAGS", "")},
        "out": str(out),
    }
    summary["wall_seconds"] = time.perf_counter() - wall_start
    checkpoint.atomic_write_text(out / "summary.json", json.dumps(summary, indent=2))
    summary["_table"] = table
    summary["_items"] = items
    return summary


def report(summary: dict[str, Any]) -> str:
    """The text printed after training: timings and the Table-3-style evaluation."""
    sps = summary["env_steps_per_second"]
    gflops = summary.get("achieved_gflops")
    lines = [
        "",
        f"{summary['algo'].upper()} on {summary['env']}: {summary['num_seeds']} seeds x "
        f"{summary['env_steps_per_seed']:,} env steps ({summary['updates_done']}/{summary['num_updates']} updates)",
        f"compile {summary['compile_seconds']:.1f} s | train {summary['train_seconds']:.1f} s | "
        f"{(sps or 0) / 1e3:,.0f}k env steps/s (all seeds)"
        + (
            f" | {gflops:.1f} GFLOP/s = {gflops / summary['cpu_peak_gflops']:.0%} of this machine's "
            f"{summary['cpu_peak_gflops']:.0f} GFLOP/s matmul"
            if gflops
            else ""
        )
        + f" | wall {summary['wall_seconds']:.1f} s",
        "",
        summary["_table"],
        "",
        f"outputs in {summary['out']}/ (summary.json, metrics.csv, learning_curve.png, checkpoint.msgpack)",
    ]
    return "\n".join(lines)


def main(algo: str, argv: list[str] | None = None) -> int:
    """Entry point of ``train_<algo>.py``: parse, train, print; status 2 on a bad command."""
    try:
        command = parse(algo, argv)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    from wrl_jax import training

    training.install_sigterm_handler()
    try:
        summary = train(command)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(
            f"\ninterrupted; the last completed chunk is checkpointed. Continue with:\n"
            f"  python train_{algo}.py --resume --out {command.out_dir}",
            file=sys.stderr,
        )
        return 130
    print(report(summary))
    if not summary["finished"]:
        print(f"stopped after {summary['updates_done']} updates; continue with --resume --out {summary['out']}")
    return 0


# ----------------------------------------------------------------- evaluation
def evaluate_run(run_dir: str | os.PathLike) -> dict[str, Any]:
    """Load a run's checkpoint (any algorithm) and evaluate every seed on every item.

    Returns the evaluation summary (as in ``summary.json``'s ``eval``) plus
    ``table`` and ``items`` texts.
    """
    from wrl_jax import checkpoint, evaluation, training

    run_dir = Path(run_dir)
    meta = checkpoint.read_metadata(run_dir)
    spec = get_spec(meta["algo"])
    config = config_from_dict(spec.config_cls, meta["config"])
    env_options = EnvOptions(env=meta["env"], **meta.get("env_overrides", {}))
    algo = build(spec, config, env_options)
    trainer = training.Trainer(algo, meta["seeds"], training.LoopConfig(progress=False))
    runners, meta = checkpoint.load(run_dir, trainer.template())
    summary = evaluation.summarize(trainer.evaluate(runners), trainer.seeds)
    conv = training.Convergence.from_json(meta.get("convergence", {}))
    first = [None if u is None else u * trainer.steps_per_update for u in conv.first_optimal_update(len(trainer.seeds))]
    label = (
        f"{spec.name.upper()} {meta['env']} ({meta.get('preset', '?')}, {len(trainer.seeds)} seeds, "
        f"{meta['updates_done'] * trainer.steps_per_update:,} steps)"
    )
    study = dict(spec.study) if spec.study and meta["env"] == spec.default_env else None
    summary["table"] = evaluation.format_table3(summary, label, first, study=study)
    summary["items"] = evaluation.format_items(summary)
    summary["updates_done"] = meta["updates_done"]
    return summary


def evaluate_main(argv: list[str] | None = None) -> int:
    """``python -m wrl_jax.evaluate --run DIR [--json FILE] [--items]``."""
    parser = argparse.ArgumentParser(
        prog="python -m wrl_jax.evaluate",
        description="Greedy evaluation of a trained run (any algorithm) on every item for every seed.",
    )
    parser.add_argument("--run", required=True, help="run directory holding checkpoint.msgpack")
    parser.add_argument("--json", default=None, help="also write the evaluation (with per-seed per-item rows) here")
    parser.add_argument("--items", action="store_true", help="print the per-item table too")
    parser.add_argument("--xla-opt-level", type=int, default=DEFAULT_XLA_OPT_LEVEL)
    args = parser.parse_args(argv)
    from wrl_jax import checkpoint

    apply_xla_opt_level(args.xla_opt_level)
    try:
        summary = evaluate_run(args.run)
    except (ValueError, checkpoint.CheckpointError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(summary["table"])
    if args.items:
        print()
        print(summary["items"])
    if args.json:
        data = {k: v for k, v in summary.items() if k not in ("table", "items")}
        checkpoint.atomic_write_text(args.json, json.dumps(data, indent=2))
    return 0
