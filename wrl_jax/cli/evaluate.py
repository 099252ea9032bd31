"""``python -m wrl_jax.evaluate --run DIR``: evaluate a saved run's greedy policy with its family's hook."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from wrl_jax.agents import get_spec
from wrl_jax.cli.machine import DEFAULT_XLA_OPT_LEVEL, apply_xla_opt_level
from wrl_jax.cli.options import EnvOptions, build, config_from_dict

def evaluate_run(run_dir: str | os.PathLike) -> dict[str, Any]:
    """Load a run's checkpoint (any algorithm) and evaluate every seed on every item.

    Returns the evaluation summary (as in ``summary.json``'s ``eval``) plus
    ``table`` and ``items`` texts.
    """
    from wrl_jax import training
    from wrl_jax.training import checkpoint
    from wrl_jax.training import evaluation as family_evaluation

    run_dir = Path(run_dir)
    meta = checkpoint.read_metadata(run_dir)
    spec = get_spec(meta["algo"])
    config = config_from_dict(spec.config_cls, meta["config"])
    env_options = EnvOptions(env=meta["env"], **meta.get("env_overrides", {}))
    algo = build(spec, config, env_options)
    trainer = training.Trainer(algo, meta["seeds"], training.LoopConfig(progress=False))
    runners, meta = checkpoint.load(run_dir, trainer.template())
    family = trainer.evaluation
    summary = family.summarize(trainer.evaluate(runners), trainer.seeds)
    summary.update(family_evaluation.run_final_report(family, trainer, runners))
    conv = training.Convergence.from_json(meta.get("convergence", {}), solved_key=family.solved_key)
    first = [None if u is None else u * trainer.steps_per_update for u in conv.first_optimal_update(len(trainer.seeds))]
    label = (
        f"{spec.name.upper()} {meta['env']} ({meta.get('preset', '?')}, {len(trainer.seeds)} seeds, "
        f"{meta['updates_done'] * trainer.steps_per_update:,} steps)"
    )
    study = dict(spec.study) if spec.study and meta["env"] == spec.default_env else None
    summary["table"] = family.format_report(summary, label, first, study=study)
    summary["items"] = family.format_details(summary)
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
    from wrl_jax.training import checkpoint

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
