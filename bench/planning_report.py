"""The planning policy's final-report sets, for untrained networks or a run's, with shelves as walls or not.

Why this exists: two claims of docs/procedural.md need a command of their own.

* The procedural preset's network propagates values over the map with shelves as walls
  (wrl_jax/agents/propagation.py) and its actor adds the resulting per-action features to its logits
  from the start, so its *untrained* greedy policy already walks shortest routes; what training adds is
  measured against this (the sampled policy, which PPO trains). Without ``--run``: the untrained
  networks of ``--seeds``.
* Why walls: a run trained with learned shelf costs (``train_ppo.py ... --no-propagation-walls``) lets the
  field cut through shelves on floors with long detours. ``--run DIR --walls True`` evaluates that run's
  very parameters with shelves as walls, nothing retrained.

Every set of the final report (the held-out layouts of the training generator and every
out-of-distribution set), greedy and sampled, as the report runs them::

    .venv/bin/python bench/planning_report.py --json bench/results/procedural_ppo/planning_untrained.json
    python train_ppo.py --env Procedural-Warehouse-v0 --no-propagation-walls --out runs/shelf-costs
    .venv/bin/python bench/planning_report.py --run runs/shelf-costs               # as trained
    .venv/bin/python bench/planning_report.py --run runs/shelf-costs --walls True  # the same, walls
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import jax

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from wrl_jax import training  # noqa: E402
from wrl_jax.agents import get_spec, ppo, ppo_config  # noqa: E402
from wrl_jax.agents.base import config_from_dict  # noqa: E402
from wrl_jax.cli.options import EnvOptions, build  # noqa: E402
from wrl_jax.core.registry import make  # noqa: E402
from wrl_jax.envs.procedural import layout_sets  # noqa: E402
from wrl_jax.envs.procedural.evaluation import evaluate_sets  # noqa: E402
from wrl_jax.envs.procedural.reports import format_sets  # noqa: E402
from wrl_jax.training import checkpoint  # noqa: E402


def untrained(seeds: list[int], walls: bool | None):
    env, params = make("Procedural-Warehouse-v0", **ppo_config.PROCEDURAL_ENV_DEFAULTS,
                       **ppo_config.PRESET_ENV_DEFAULTS["procedural"]["Procedural-Warehouse-v0"])
    config = ppo_config.PROCEDURAL if walls is None else dataclasses.replace(ppo_config.PROCEDURAL,
                                                                             propagation_walls=walls)
    algo = ppo.PPO(config, env, params)
    networks = jax.vmap(lambda key: algo.network_params(algo.init(key)))(training.seed_keys(seeds))
    return algo, networks, params, seeds, params.pool


def from_run(run_dir: str, walls: bool | None):
    meta = checkpoint.read_metadata(run_dir)
    spec = get_spec(meta["algo"])
    config = config_from_dict(spec.config_cls, meta["config"])
    trained = build(spec, config, EnvOptions(env=meta["env"], **meta.get("env_overrides", {})))
    if getattr(trained, "map_layout", None) is None:
        raise ValueError(f"{run_dir} is not a run of PPO's propagation encoder on a procedural warehouse")
    trainer = training.Trainer(trained, meta["seeds"], training.LoopConfig(progress=False))
    runners, meta = checkpoint.load(run_dir, trainer.template())
    algo = trained if walls is None else ppo.PPO(dataclasses.replace(config, propagation_walls=walls),
                                                 trained.env, trained.env_params)
    params = jax.tree.map(lambda x: x[0], runners.env_params)
    seen = trained.env.training_layout_hashes(params, meta["updates_done"])
    return algo, jax.vmap(trained.network_params)(runners), params, meta["seeds"], seen


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", default=None, help="a run directory (default: untrained networks)")
    parser.add_argument("--walls", default=None, choices=["True", "False"],
                        help="evaluate with shelves as walls or not (default: as configured)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3], help="untrained networks' seeds")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    walls = None if args.walls is None else args.walls == "True"
    algo, networks, params, seeds, training_layouts = (
        from_run(args.run, walls) if args.run else untrained(args.seeds, walls))
    env = algo.env
    heldout, _ = layout_sets.heldout_set(env.generator, training_layouts)
    sets = [heldout, *layout_sets.ood_sets(env.generator)]
    memory = algo.policy_memory()
    greedy = evaluate_sets(algo.greedy_action, networks, env, params, sets, seeds, memory=memory)
    sampled = evaluate_sets(algo.greedy_action, networks, env, params, sets, seeds,
                            sample_action=algo.sample_action, key=jax.random.key(layout_sets.EVAL_SEED),
                            memory=memory)
    what = f"{args.run or 'untrained'}, walls {algo.config.propagation_walls}"
    print(f"{what}, greedy\n" + format_sets(greedy) + f"\n\n{what}, sampled\n" + format_sets(sampled))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"greedy": greedy, "sampled": sampled, "seeds": seeds, "run": args.run,
                                         "walls": algo.config.propagation_walls}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
