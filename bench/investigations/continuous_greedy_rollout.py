"""One greedy episode of a saved continuous run, step by step: where the robot is and what it commands.

    python bench/investigations/continuous_greedy_rollout.py --run DIR --seed-index I [--item K] [--steps N]

Shows what a failing seed does (bench/results/continuous/NOTES.md: TD3's saturated actor, which commands the
same (forward, turn) in every state and circles the start).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import numpy as np

from continuous_greedy_steps import load


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True, help="a training run's output directory")
    parser.add_argument("--seed-index", type=int, default=0, help="position of the seed in the run's seed list")
    parser.add_argument("--item", type=int, default=3)
    parser.add_argument("--steps", type=int, default=120)
    parser.add_argument("--every", type=int, default=8, help="print every this many steps")
    args = parser.parse_args()
    algo, networks = load(args.run)
    env, params = algo.env, algo.env_params
    network = jax.tree.map(lambda x: x[args.seed_index], networks)
    draws = env.reset_draws(jax.random.PRNGKey(0), params).replace(item_index=args.item)
    obs, state = env.reset_with(draws, params)
    act, step = jax.jit(algo.greedy_action), jax.jit(env.transition)
    print(f"item at {np.asarray(state.item)}, goal at {np.asarray(params.goal)}")
    for t in range(args.steps):
        action = act(network, obs)
        obs, state, _, terminated, truncated, _ = step(jax.random.PRNGKey(t), state, action, params)
        if t % args.every == 0:
            print(f"step {t:3d}: position {np.asarray(state.pos).round(2)}, command {np.asarray(action).round(2)}")
        if terminated or truncated:
            break


if __name__ == "__main__":
    main()
