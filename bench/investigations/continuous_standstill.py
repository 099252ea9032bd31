"""The procedural policy's failed held-out episodes: standstills under the safety stop, and a turn that ends them.

    python bench/investigations/continuous_standstill.py --run DIR [--randomize] [--rounds N] [--escape-after 10 20]
        [--trace]

A saved run of ``Continuous-Procedural-Warehouse-v0`` (over the stop, with the held value in view), every seed's
greedy policy on the final report's held-out layouts, every item, ``--rounds`` episodes each (fixed keys),
without randomization unless ``--randomize``. Prints, per seed, the delivered share; how many failed episodes
end in a standstill (the robot's path over its last 200 steps under 0.01 m); then the same episodes with an
escape added to the policy at evaluation time: where the robot has been held ``K`` steps in a row
(``state.held``), the turn command becomes a full turn. Why: without noise a held robot whose turn command swings
back and forth repeats the same observations for the rest of the episode (bench/results/continuous/NOTES.md).
``--trace`` lists the failed episodes (seed, layout, item, pick-up step) and prints the first one every 25 steps.
A run whose environment has the stop's own escape (``escape_after``, the procedural default since 2026-12-08) has
it in every line: the script is for runs without it, or to try another ``K`` on top.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from continuous_greedy_steps import load_run
from wrl_jax.envs.continuous.evaluation import EVAL_SEED, episode_start, episode_step
from wrl_jax.envs.continuous.procedural_evaluation import HELDOUT_LAYOUTS, run_pairs
from wrl_jax.envs.continuous.procedural_layouts import layout_params, with_pool
from wrl_jax.envs.procedural.layout_sets import heldout_set, pad_items

STILL_STEPS = 200
"""A failed episode is a standstill when the robot's path over its last this many steps is under 0.01 m."""


def policy(algo, network, escape_after: int):
    """The greedy policy; with ``escape_after > 0`` a full turn wherever the robot has been held that long."""
    def act(obs, state):
        action = algo.greedy_action(network, obs)
        if escape_after <= 0:
            return action
        return action.at[1].set(jnp.where(state.held >= escape_after, 1.0, action[1]))
    return act


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True)
    parser.add_argument("--randomize", action="store_true", help="evaluate with the contract's randomization")
    parser.add_argument("--rounds", type=int, default=1, help="episodes per (layout, item)")
    parser.add_argument("--escape-after", type=int, nargs="*", default=[10, 20])
    parser.add_argument("--trace", action="store_true", help="list the failures and print the first one's steps")
    args = parser.parse_args()
    meta, algo, _, runners = load_run(args.run)
    if not algo.env.observe_held:
        raise SystemExit(f"{args.run}: the run's view has no held count (train over the stop with observe_obstacles)")
    networks = jax.vmap(algo.network_params)(runners)
    params = jax.tree.map(lambda x: x[0], runners.env_params).replace(randomize=jnp.asarray(args.randomize))
    env = algo.env
    heldout, _ = heldout_set(env.generator, env.training_layout_hashes(params), HELDOUT_LAYOUTS)
    pool = with_pool(params, pad_items(heldout.layouts, heldout.layouts.max_items))
    counts = np.asarray(heldout.layouts.num_items)
    slots, items = np.nonzero(np.arange(heldout.layouts.max_items)[None] < counts[:, None])
    slots, items = np.repeat(slots, args.rounds), np.repeat(items, args.rounds)
    rounds = np.tile(np.arange(args.rounds), slots.size // args.rounds)
    pairs = tuple(jnp.asarray(a, jnp.int32) for a in (slots, items, rounds))
    root = jax.random.PRNGKey(EVAL_SEED)

    def replay(seed, slot, item, round_index):  # one greedy episode: positions, headings and commands per step
        act = policy(algo, jax.tree.map(lambda x: x[seed], networks), 0)
        layout = layout_params(pool, slot)
        key = jax.random.fold_in(jax.random.fold_in(jax.random.fold_in(root, slot), item), round_index)
        carry = episode_start(act, env.plain, layout, key, item)

        def body(carry, _):
            command = act(carry[1], carry[2])
            carry = episode_step(act, env.plain, layout, carry)
            return carry, (carry[2].pos, carry[2].theta, command)
        return jax.lax.scan(body, carry, None, length=int(params.max_steps))[1]

    def path_at_the_end(*episode):  # the path length over the last steps
        positions = replay(*episode)[0]
        return jnp.abs(jnp.diff(positions[-STILL_STEPS:], axis=0)).sum()

    print(f"{meta['env']}, seeds {meta['seeds']}, {slots.size} episodes per seed, randomize={args.randomize}")
    for escape_after in [0, *args.escape_after]:
        program = jax.jit(jax.vmap(lambda net, *pair: run_pairs(policy(algo, net, escape_after), env, pool, *pair),
                                   in_axes=(0, None, None, None)))
        delivered, steps, _, collisions, pickup = (np.asarray(x) for x in program(networks, *pairs))
        line = (f"escape after {escape_after or 'never'}: delivered per seed {np.round(delivered.mean(1), 4).tolist()}, "
                f"steps per delivery {steps[delivered].mean():.2f}, contact steps per episode {collisions.mean():.4f}")
        if escape_after == 0 and (~delivered).any():
            seed, episode = np.nonzero(~delivered)
            paths = np.asarray(jax.jit(jax.vmap(path_at_the_end))(
                jnp.asarray(seed, jnp.int32), *(pair[episode] for pair in pairs)))
            line += f"; failed {seed.size}, of them standstills {int((paths < 0.01).sum())}"
            if args.trace:
                print("failed (seed index, layout, item, pick-up step or -1):",
                      [(int(k), int(slots[e]), int(items[e]), int(pickup[k, e])) for k, e in zip(seed, episode)])
                first = (jnp.int32(seed[0]), *(pair[episode[0]] for pair in pairs))
                positions, headings, commands = (np.asarray(x) for x in jax.jit(replay)(*first))
                for t in range(0, positions.shape[0], 25):
                    print(f"  step {t:3d}: position {positions[t].round(3)}, heading {headings[t] % (2 * np.pi):.3f}, "
                          f"command {commands[t].round(2)}")
        print(line, flush=True)


if __name__ == "__main__":
    main()
