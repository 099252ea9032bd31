"""``python -m wrl_jax.evaluate --run DIR [--layout PATH ...]``: evaluate a saved run's greedy policy.

Without ``--layout``, with the run's family hook (what training reports). With
``--layout`` (repeatable), on the given map files instead, every item of each:
only for runs of a procedural environment, whose policies read any floor up to
the padded shape they trained on (the grid's egocentric window; the continuous
variant's lidar, target and route, the route computed for each file's floor).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from wrl_jax.agents import get_spec
from wrl_jax.cli.machine import DEFAULT_XLA_OPT_LEVEL, apply_xla_opt_level
from wrl_jax.agents.base import config_from_dict
from wrl_jax.cli.options import EnvOptions, build


def evaluate_run(run_dir: str | os.PathLike) -> dict[str, Any]:
    """Load a run's checkpoint (any algorithm) and evaluate every seed on every item.

    Returns the evaluation summary (as in ``summary.json``'s ``eval``) plus
    ``table`` and ``items`` texts.
    """
    from wrl_jax import training
    from wrl_jax.training import checkpoint
    from wrl_jax.core import evaluation as family_evaluation

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
    summary.update(family_evaluation.run_final_report(family, trainer, runners, updates_done=meta["updates_done"]))
    conv = training.Convergence.from_json(meta.get("convergence", {}), solved_key=family.solved_key)
    first = [None if u is None else u * trainer.steps_per_update for u in conv.first_solved_update(len(trainer.seeds))]
    label = (
        f"{spec.name.upper()} {meta['env']} ({meta.get('preset', '?')}, {len(trainer.seeds)} seeds, "
        f"{meta['updates_done'] * trainer.steps_per_update:,} steps)"
    )
    study = dict(spec.study) if spec.study and meta["env"] == spec.default_env else None
    summary["table"] = family.format_report(summary, label, first, study=study)
    summary["items"] = family.format_details(summary)
    summary["updates_done"] = meta["updates_done"]
    return summary


LAYOUT_FAMILIES = ("procedural",)
"""Families whose policies can be evaluated on arbitrary layout files (``--layout``)."""
LAYOUT_ENVS = ("Continuous-Procedural-Warehouse-v0",)
"""Environments of other families whose policies can be (the continuous procedural variant)."""


def evaluate_layouts(run_dir: str | os.PathLike, paths: list[str]) -> dict[str, Any]:
    """A run's greedy policy (every seed) on map files: per file and ``overall`` statistics, and a ``table``.

    Refuses (``ValueError`` naming the run or the file) a run whose environment
    is not a procedural one, and a layout larger than the padded shape of the
    run's environment; both before any checkpoint is loaded. On the continuous
    variant the pursuit controller runs the same episodes and its numbers stand
    beside the policy's, as in the training report.
    """
    import jax

    from wrl_jax import training
    from wrl_jax.core import registry
    from wrl_jax.training import checkpoint

    run_dir = Path(run_dir)
    meta = checkpoint.read_metadata(run_dir)
    family = registry.entry(meta["env"]).family
    if family not in LAYOUT_FAMILIES and meta["env"] not in LAYOUT_ENVS:
        raise ValueError(f"--layout needs a run of a procedural environment (Procedural-Warehouse-v0 or "
                         f"Continuous-Procedural-Warehouse-v0: their policies read any floor up to their padded "
                         f"shape); {run_dir} holds a {meta['algo']} run on {meta['env']} (family {family!r})")
    from wrl_jax.envs.continuous import procedural_evaluation as continuous_evaluation
    from wrl_jax.envs.procedural import evaluation as procedural_evaluation
    from wrl_jax.envs.procedural import layout_sets, reports

    spec = get_spec(meta["algo"])
    config = config_from_dict(spec.config_cls, meta["config"])
    algo = build(spec, config, EnvOptions(env=meta["env"], **meta.get("env_overrides", {})))
    env, grid = algo.env, family in LAYOUT_FAMILIES
    sets = layout_sets.layout_file_sets(paths, env.max_shape if grid else (env.height, env.width),
                                        env.generator.max_items)
    trainer = training.Trainer(algo, meta["seeds"], training.LoopConfig(progress=False))
    runners, meta = checkpoint.load(run_dir, trainer.template())
    network_params = jax.vmap(algo.network_params)(runners)
    params = jax.tree.map(lambda x: x[0], runners.env_params)
    if grid:
        report = procedural_evaluation.evaluate_sets(algo.greedy_action, network_params, env, params, sets,
                                                     trainer.seeds, overall="overall", memory=algo.policy_memory())
    else:
        report = continuous_evaluation.evaluate_layout_sets(algo.greedy_action, network_params, env, params, sets,
                                                            trainer.seeds, overall="overall")
    overall = report.pop("overall")
    label = (f"{spec.name.upper()} {meta['env']} ({meta.get('preset', '?')}, {len(trainer.seeds)} seeds, "
             f"{meta['updates_done'] * trainer.steps_per_update:,} steps) on {len(sets)} layout file(s)")
    table = (reports.format_sets if grid else continuous_evaluation.format_layout_sets)({**report, "overall": overall})
    return {"run": str(run_dir), "env": meta["env"], "seeds": list(trainer.seeds), "layouts": report,
            "overall": overall, "updates_done": meta["updates_done"], "table": f"{label}\n\n{table}", "items": ""}


def evaluate_main(argv: list[str] | None = None) -> int:
    """``python -m wrl_jax.evaluate --run DIR [--layout PATH ...] [--json FILE] [--items]``."""
    parser = argparse.ArgumentParser(
        prog="python -m wrl_jax.evaluate",
        description="Greedy evaluation of a trained run (any algorithm) on every item for every seed.",
    )
    parser.add_argument("--run", required=True, help="run directory holding checkpoint.msgpack")
    parser.add_argument("--json", default=None, help="also write the evaluation (with per-seed per-item rows) here")
    parser.add_argument("--items", action="store_true", help="print the per-item table too")
    parser.add_argument("--layout", action="append", default=None, metavar="PATH",
                        help="evaluate on this map file instead (ASCII or MovingAI .map; repeat for several); "
                             "only for runs of Procedural-Warehouse-v0 or Continuous-Procedural-Warehouse-v0")
    parser.add_argument("--xla-opt-level", type=int, default=DEFAULT_XLA_OPT_LEVEL)
    args = parser.parse_args(argv)
    from wrl_jax.training import checkpoint

    apply_xla_opt_level(args.xla_opt_level)
    try:
        summary = evaluate_layouts(args.run, args.layout) if args.layout else evaluate_run(args.run)
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
