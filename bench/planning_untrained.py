"""What the planning policy does before any training: the final report's sets, greedy and sampled.

Why this exists: the procedural preset's network propagates values over the map with shelves as walls
(wrl_jax/agents/propagation.py), and its actor adds the resulting per-action features to its logits
from the start. So its untrained greedy policy already walks shortest routes, and docs/procedural.md says
so; what training adds is measured against this: the sampled policy (which PPO trains) and the critic.
This runs the untrained networks of ``--seeds`` on every set of the final report (the held-out layouts of
the training generator and every out-of-distribution set), greedy and sampled, as the report does.

    .venv/bin/python bench/planning_untrained.py --json bench/results/procedural_ppo/planning_untrained.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from wrl_jax.agents import ppo, ppo_config  # noqa: E402
from wrl_jax.core.registry import make  # noqa: E402
from wrl_jax.envs.procedural import layout_sets  # noqa: E402
from wrl_jax.envs.procedural.evaluation import evaluate_sets  # noqa: E402
from wrl_jax.envs.procedural.reports import format_sets  # noqa: E402
from wrl_jax.training import seed_keys  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    env, params = make("Procedural-Warehouse-v0", **ppo_config.PROCEDURAL_ENV_DEFAULTS,
                       **ppo_config.PRESET_ENV_DEFAULTS["procedural"]["Procedural-Warehouse-v0"])
    algo = ppo.PPO(ppo_config.PROCEDURAL, env, params)
    networks = jax.vmap(lambda key: algo.network_params(algo.init(key)))(seed_keys(args.seeds))
    heldout, _ = layout_sets.heldout_set(env.generator, params.pool)
    sets = [heldout, *layout_sets.ood_sets(env.generator)]
    memory = algo.policy_memory()
    greedy = evaluate_sets(algo.greedy_action, networks, env, params, sets, args.seeds, memory=memory)
    sampled = evaluate_sets(algo.greedy_action, networks, env, params, sets, args.seeds,
                            sample_action=algo.sample_action, key=jax.random.key(layout_sets.EVAL_SEED),
                            memory=memory)
    print("untrained, greedy\n" + format_sets(greedy) + "\n\nuntrained, sampled\n" + format_sets(sampled))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"greedy": greedy, "sampled": sampled, "seeds": args.seeds}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
