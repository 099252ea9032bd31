"""A learned fleet policy run at other fleet sizes: throughput against PIBT for each K.

IPPO's parameters do not depend on the number of robots (each robot's observation is a row of
the batch), so a policy trained at one K can run a fleet of any size on the same map. For
every K and every seed of a saved run, the greedy policy runs the planners' shifts
(``python -m wrl_jax.plan --seed 0 --episodes E``), PIBT beside it::

    python bench/fleet_sizes.py --run runs/ppo-Fleet-12x12-v0-... --sizes 1 2 4 8 --json OUT

Writes a JSON report and prints a Markdown table (throughput, its ratio to PIBT, blocks per
robot per 100 steps). Compile time is apart from the timings.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", required=True, type=Path, help="a fleet run directory (checkpoint.msgpack)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 2, 4, 8])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)

    import jax
    import numpy as np

    import wrl_jax
    from wrl_jax import training
    from wrl_jax.agents import get_spec
    from wrl_jax.agents.base import config_from_dict
    from wrl_jax.cli.options import EnvOptions, build
    from wrl_jax.envs.fleet import metrics
    from wrl_jax.envs.fleet.evaluation import EVAL_SEED
    from wrl_jax.training import checkpoint

    meta = checkpoint.read_metadata(args.run)
    spec = get_spec(meta["algo"])
    overrides = dict(meta.get("env_overrides", {}))
    algo = build(spec, config_from_dict(spec.config_cls, meta["config"]), EnvOptions(env=meta["env"], **overrides))
    if getattr(algo.env, "family", None) != "fleet":
        print(f"error: {args.run} is a {algo.env.family!r} run, not a fleet run", file=sys.stderr)
        return 2
    trainer = training.Trainer(algo, meta["seeds"], training.LoopConfig(progress=False))
    runners, _ = checkpoint.load(args.run, trainer.template())
    network_params = jax.vmap(algo.network_params)(runners)
    trained_k = algo.env.num_robots
    overrides.pop("num_robots", None)

    rows = []
    for k in args.sizes:
        env, params = wrl_jax.make(meta["env"], num_robots=k, **overrides)
        horizon = int(params.max_steps)
        key = jax.random.key(EVAL_SEED)
        keys = jax.random.split(key, args.episodes)

        def seed_counts(p, env=env, params=params, horizon=horizon, keys=keys):
            policy = lambda obs, _: algo.greedy_action(p, obs)  # noqa: E731
            return jax.vmap(lambda k_: metrics.policy_episode_counts(env, params, policy, k_, horizon))(keys)

        evaluate = jax.jit(jax.vmap(seed_counts)).lower(network_params).compile()
        start = time.perf_counter()
        counts = jax.device_get(evaluate(network_params))  # each (S, E, K)
        seconds = time.perf_counter() - start
        pibt = jax.device_get(metrics.run_episodes(env, params, "pibt", key, args.episodes, horizon))
        learned = counts["delivered"].sum(axis=-1).mean(axis=-1) / horizon  # per seed
        pibt_tp = float(pibt["delivered"].sum(axis=-1).mean() / horizon)
        blocks = 100.0 * counts["robot_block"].sum(axis=(1, 2)) / (args.episodes * k * horizon)
        rows.append({"num_robots": k, "trained_at": trained_k, "throughput_per_seed": learned.tolist(),
                     "throughput": float(learned.mean()), "pibt_throughput": pibt_tp,
                     "vs_pibt_per_seed": (learned / pibt_tp).tolist(), "blocks_per_100_per_seed": blocks.tolist(),
                     "bound": float(k / metrics.mean_round_trip(params)), "eval_seconds": seconds})
        print(f"K={k}: learned {learned.mean():.3f} (seeds {np.round(learned, 3).tolist()}), PIBT {pibt_tp:.3f}",
              file=sys.stderr)

    print(f"| K (trained at {trained_k}) | learned (mean of {len(meta['seeds'])} seeds) | seeds | PIBT | learned / PIBT "
          f"| blocks per robot per 100 steps |")
    print("|---:|---:|---|---:|---:|---:|")
    for row in rows:
        seeds = ", ".join(f"{x:.3f}" for x in row["throughput_per_seed"])
        blocks = sum(row["blocks_per_100_per_seed"]) / len(row["blocks_per_100_per_seed"])
        print(f"| {row['num_robots']} | {row['throughput']:.3f} | {seeds} | {row['pibt_throughput']:.3f} | "
              f"{row['throughput'] / row['pibt_throughput']:.0%} | {blocks:.2f} |")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"run": str(args.run), "env": meta["env"], "episodes": args.episodes,
                                         "episode_seed": EVAL_SEED, "rows": rows, "jax": jax.__version__}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
