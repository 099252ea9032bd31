"""``train_ppo.py`` / ``train_dqn.py``: train, evaluate with the family's hook, write every output, print.

A run writes to ``--out`` (default ``runs/<algo>-<env>-<time>``): ``metrics.jsonl``,
``metrics.csv`` and TensorBoard event files (per update and seed),
``learning_curve.png``, ``checkpoint.msgpack`` (resumable with ``--resume --out
DIR``, which reuses the checkpoint's settings), ``evaluation.md`` (the
environment family's report: for the warehouse the Table-3-style table and the
per-item table) and ``summary.json``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from typing import Any

from wrl_jax.cli.machine import CHOSEN_DEVICES_VARIABLE, apply_xla_opt_level, cpu_info
from wrl_jax.agents.base import config_to_dict
from wrl_jax.cli.options import Command, build, parse

def train(command: Command) -> dict[str, Any]:
    """Train, evaluate and write every output of a parsed command; returns the summary."""
    import jax
    import numpy as np

    from wrl_jax import training
    from wrl_jax.training import checkpoint, metrics_io
    from wrl_jax.core import evaluation as family_evaluation
    from wrl_jax.agents.networks import measured_matmul_peak_gflops

    wall_start = time.perf_counter()
    load_at_start = cpu_info()
    spec, run, out = command.spec, command.run, command.out_dir
    if not run.resume and (out / checkpoint.CHECKPOINT_NAME).exists() and not run.overwrite:
        raise ValueError(f"{out} already holds a run; pass --resume to continue it or --overwrite to start over")
    apply_xla_opt_level(run.xla_opt_level)
    if run.distributed:
        from wrl_jax.training import sharding

        sharding.initialize_distributed()
    algo = build(spec, command.config, command.env)
    loop = training.LoopConfig(
        chunk_updates=run.chunk_updates,
        eval_every=run.eval_every,
        log_every=run.log_every,
        checkpoint_every=run.checkpoint_every,
        checkpoint_seconds=run.checkpoint_seconds,
        progress=run.progress,
    )
    if os.environ.get(CHOSEN_DEVICES_VARIABLE) == str(run.devices) and jax.default_backend() != "cpu":
        run = dataclasses.replace(run, devices=1)  # the command split the CPU; this machine runs elsewhere
        print(f"one {jax.default_backend()} device (the host-device split applies to CPUs)", file=sys.stderr)
    if run.devices != 1 or run.env_shards != 1 or run.distributed:
        from wrl_jax.training import sharding

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
    checkpoint.atomic_write_text(out / "config.json", json.dumps(
        {**metadata, "seeds": run.seeds(), "devices": run.devices, "env_shards": run.env_shards}, indent=2))
    t0 = time.perf_counter()
    runners = trainer.init()
    jax.block_until_ready(runners)
    init_seconds = time.perf_counter() - t0
    result = training.run(
        trainer, out, metadata=metadata, resume=run.resume, stop_after=run.stop_after, runners=runners
    )

    t0 = time.perf_counter()
    episodes = training.final_evaluation(trainer, result)
    family = trainer.evaluation
    eval_summary = family.summarize(episodes, trainer.seeds)
    eval_summary.update(family_evaluation.run_final_report(family, trainer, result.runners, out,
                                                           updates_done=result.updates_done))
    eval_seconds = time.perf_counter() - t0
    first = result.convergence.first_solved_update(len(trainer.seeds))
    stable = result.convergence.stable_solved_update(len(trainer.seeds))
    steps = trainer.steps_per_update
    first_steps = [None if u is None else u * steps for u in first]
    stable_steps = [None if u is None else u * steps for u in stable]

    label = f"{spec.name.upper()} {command.env.env} ({run.preset}, {len(trainer.seeds)} seeds)"
    study = dict(spec.study) if spec.study and command.env.env == spec.default_env else None
    table = family.format_report(eval_summary, label, first_steps, study=study)
    items = family.format_details(eval_summary)
    checkpoint.atomic_write_text(out / "evaluation.md", f"{table}\n\n{items}\n" if items else f"{table}\n")

    rows = metrics_io.read_jsonl(out / metrics_io.JSONL_NAME)
    if run.plot and rows:
        panels = [(rate.name, rate.label) for rate in family.train_rates]
        panels.append((family.progress_metric[0], f"greedy eval: {family.progress_metric[1]}"))
        metrics_io.plot_learning_curves(rows, out / metrics_io.PLOT_NAME, title=label, panels=panels)

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
            "definition": family.solved_definition,
        },
        "eval": {k: v for k, v in eval_summary.items()},
        "config": config_to_dict(command.config),
        "versions": {"wrl_jax": checkpoint.wrl_jax_version(), "jax": jax.__version__, "numpy": np.__version__},
        "machine": {"at_start": load_at_start, "at_end": cpu_info(), "xla_flags": os.environ.get("XLA_FLAGS", "")},
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
        f"{_rate(sps or 0)} env steps/s (all seeds)"
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




def _rate(per_second: float) -> str:
    """``38k``, ``1.2k``, ``640``: a rate with the digits that matter (a slow learner is not ``0k``)."""
    if per_second >= 10_000:
        return f"{per_second / 1e3:,.0f}k"
    if per_second >= 1_000:
        return f"{per_second / 1e3:.1f}k"
    return f"{per_second:.0f}"
