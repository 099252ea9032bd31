"""Where a run's greedy policy loses steps against pure pursuit: steps per item, per seed (issue 34).

Loads a saved continuous-warehouse run on one of the study's static maps (``--run DIR``), plays every
seed's deterministic policy on the evaluation's episodes, runs the pursuit controller on the same map and
prints, per item, the bound in steps (``item_bounds``: the disc's shortest path, and the strict bound that
lets the pick-up and drop happen at ``reach_radius``), pursuit's steps, and each seed's steps with the step
of its pick-up; then each seed's two legs (to the pick-up, then to the delivery) and the per-item gap to
pursuit averaged over the seeds.

    python bench/investigations/continuous_per_item_steps.py --run /tmp/sac_default

Recorded in bench/results/continuous/NOTES.md ("SAC against pursuit, item by item").
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import numpy as np
from continuous_greedy_steps import load_run

import wrl_jax
from wrl_jax.envs.continuous.evaluation import evaluate_policy
from wrl_jax.envs.continuous.yardstick import item_bounds, run_pursuit


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", type=Path, required=True, help="a training run's output directory (a static map)")
    args = parser.parse_args()
    meta, algo, _, runners = load_run(args.run)
    networks = jax.vmap(algo.network_params)(runners)
    env, params = algo.env, algo.env_params
    if env.num_obstacles:
        raise ValueError(f"{args.run}: a map with moving obstacles; the per-item comparison needs a static map")
    result = jax.jit(jax.vmap(lambda n: evaluate_policy(algo.greedy_action, n, env, params)))(networks)
    items = int(params.num_items)
    steps = np.asarray(result.steps)[:, 0, :items]  # (seeds, items): one round on a static map
    pickup = np.asarray(result.pickup_step)[:, 0, :items]
    plain_env, plain_params = wrl_jax.make(meta["env"])  # pursuit on the contract's map, as docs/continuous.md
    pursuit = np.array([p["mean_steps"] for p in run_pursuit(plain_env, plain_params, episodes=items)["per_item"]])
    bounds = item_bounds(params)
    print("item  bound  strict  pursuit | each seed: steps (pick-up step)")
    for i in range(items):
        print(f"{i:4d} {bounds['steps'][i]:6.1f} {bounds['strict_steps'][i]:6.1f} {pursuit[i]:7.1f} | "
              + "  ".join(f"{steps[s, i]:4d} ({pickup[s, i]:3d})" for s in range(steps.shape[0])))
    print(f"means: bound {bounds['steps'].mean():.2f}, strict bound {bounds['strict_steps'].mean():.2f}, pursuit "
          f"{pursuit.mean():.2f}, seeds {np.round(steps.mean(1), 2).tolist()}")
    for s in range(steps.shape[0]):
        print(f"seed {s}: the pick-up leg {pickup[s].mean():.2f} steps per item, the delivery leg "
              f"{(steps[s] - pickup[s]).mean():.2f}")
    gap = steps.mean(0) - pursuit
    print(f"per item, the seeds' mean minus pursuit: {np.round(gap, 2).tolist()}; items where a seed is below "
          f"pursuit: {int((steps < pursuit).any(0).sum())} of {items}")


if __name__ == "__main__":
    main()
