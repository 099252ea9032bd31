"""A saved SAC run trained with ``--actor-average``: its actor as trained and its average, evaluated alike.

    python bench/investigations/sac_actor_average_eval.py --run DIR [--out FILE.json]

A TD3 run works too: its average is the target actor (a Polyak average with ``tau``), which TD3 keeps anyway.

Both are read from the same checkpoint (the average does not change training), so the comparison is paired:
the same training, two greedy policies, the family's evaluation (what a run's summary reports).
Results: bench/results/continuous/NOTES.md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from continuous_greedy_steps import load_run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True, help="a run directory of train_sac.py --actor-average R or of train_td3.py")
    parser.add_argument("--out", type=Path, help="write both summaries here as JSON")
    args = parser.parse_args()
    meta, algo, trainer, runners = load_run(args.run)
    if not (algo.averages_actor or algo.uses_actor_target):
        raise SystemExit(f"{args.run}: neither a SAC run with --actor-average nor a TD3 run (algo {meta['algo']!r})")
    report = {}
    for name, params in (("online", runners.actor), ("average", runners.actor_target)):
        result = trainer.evaluation.evaluate_seeds(algo.greedy_action, params, algo.env, runners.env_params,
                                                   params_batched=True)
        report[name] = trainer.evaluation.summarize(result, meta["seeds"])
        print(f"{name}: delivered {report[name]['success_rate']:.4f}, "
              f"contact steps per episode {report[name]['collisions_per_episode']:.3f}")
        for row in report[name]["per_seed"]:
            print(f"  seed {row['seed']}: delivered {row['success_rate']:.3f}, "
                  f"contacts {row['collisions_per_episode']:.2f}, steps {row['mean_steps'] or float('nan'):.1f}")
    if args.out:
        args.out.write_text(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
