"""What a trained RWARE team does: each seed's share of each action, its deliveries, and time spent carrying.

    python bench/investigations/rware_action_mix.py --run DIR [--episodes 16]

``DIR`` is a ``train_ppo.py --out DIR`` run on an ``rware-*`` id. Each seed's policy is sampled (as in training)
for ``--episodes`` episodes of the run's environment, all seeds and episodes in one jitted call. A team that never
delivers shows here as one that stopped moving forward. Results: bench/results/rware/NOTES.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from continuous_greedy_steps import load

ACTIONS = ("NOOP", "FORWARD", "LEFT", "RIGHT", "TOGGLE_LOAD")


def episode(algo, network, key):
    """One episode of the sampled policy: actions ``(T, N)``, the team's reward and whether each agent carries."""
    env, params = algo.env, algo.env_params
    reset_key, key = jax.random.split(key)
    obs, state = env.reset(reset_key, params)

    def step(carry, step_key):
        obs, state = carry
        act_key, env_key = jax.random.split(step_key)
        action = algo.sample_action(network, obs, act_key)
        obs, state, reward, _, _, _ = env.step(env_key, state, action, params)
        return (obs, state), (action, reward.sum(), state.carrying >= 0)

    _, record = jax.lax.scan(step, (obs, state), jax.random.split(key, int(params.max_steps)))
    return record


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True, help="a train_ppo.py run directory on an rware-* id")
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument("--seed", type=int, default=7, help="key of the episodes")
    args = parser.parse_args()
    algo, networks = load(args.run)
    keys = jax.random.split(jax.random.key(args.seed), args.episodes)
    per_seed = jax.vmap(lambda network: jax.vmap(lambda key: episode(algo, network, key))(keys))
    actions, rewards, carrying = jax.jit(per_seed)(networks)
    for index in range(actions.shape[0]):
        share = np.bincount(np.asarray(actions[index]).ravel(), minlength=len(ACTIONS)) / actions[index].size
        mix = ", ".join(f"{name} {100 * value:.0f} %" for name, value in zip(ACTIONS, share))
        print(f"seed index {index}: {mix}; return per episode {float(rewards[index].sum()) / args.episodes:.2f}; "
              f"carrying {100 * float(jnp.mean(carrying[index])):.0f} % of agent-steps")


if __name__ == "__main__":
    main()
