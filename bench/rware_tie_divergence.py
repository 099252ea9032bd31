"""How often the JAX RWARE and *unpatched* rware 2.0.0 part ways, because of chain-tie order alone.

rware breaks ties between equally long chains into one cell by networkx's node iteration order,
which for some components is CPython hash-set order (bench/results/rware/NOTES.md 9.1);
wrl_jax.envs.rware uses the graph's insertion order, what networkx does when ``subgraph`` keeps
it (the parity tests patch it so). This runs episodes of plain rware, unpatched, with a random
policy, steps ours from the same state with the same actions and rware's own replacement draws,
and counts the episodes in which the two ever differ (first differing step, and the steps
holding a tie). Each episode starts from rware's seeded reset, converted by ``from_rware``.

Run from the repository root (needs rware 2.0.0 and networkx)::

    .venv/bin/python bench/rware_tie_divergence.py --env rware-tiny-8ag-v2 --episodes 40
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def tie_steps_holder():
    """A counter of steps whose move graph holds two equally long chains into one empty cell."""
    import networkx as nx

    def has_tie(arrays, actions, grid_size) -> bool:
        height, width = grid_size
        cells = {(int(x), int(y)): i for i, (x, y) in enumerate(zip(arrays["agent_x"], arrays["agent_y"]))}
        shelves = set(zip(arrays["shelf_x"].tolist(), arrays["shelf_y"].tolist()))
        steps = {0: (0, -1), 1: (0, 1), 2: (-1, 0), 3: (1, 0)}
        graph = nx.DiGraph()
        for (x, y), i in cells.items():
            target = (x, y)
            if actions[i] == 1:
                dx, dy = steps[int(arrays["agent_dir"][i])]
                target = (min(max(x + dx, 0), width - 1), min(max(y + dy, 0), height - 1))
            occupant = cells.get(target)
            cancel = (arrays["carrying"][i] >= 0 and target != (x, y) and target in shelves
                      and not (occupant is not None and arrays["carrying"][occupant] >= 0))
            graph.add_edge((x, y), (x, y) if cancel else target)
        for component in nx.weakly_connected_components(graph):
            sub = graph.subgraph(component)
            if not nx.is_directed_acyclic_graph(sub):
                continue
            depth = {}
            for node in nx.topological_sort(sub):
                depth[node] = 1 + max((depth[u] for u in sub.pred[node]), default=-1)
            node = next(v for v in sub if sub.out_degree(v) == 0)
            while sub.pred[node]:
                tied = [u for u in sub.pred[node] if depth[u] == depth[node] - 1]
                if len(tied) > 1:
                    return True
                node = tied[0]
        return False

    return has_tie


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="rware-tiny-8ag-v2", help="a registered rware id")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--steps", type=int, default=500, help="steps per episode (rware's limit is 500)")
    parser.add_argument("--seed", type=int, default=0, help="episode e resets rware with seed + e")
    parser.add_argument("--forward", type=float, default=0.2,
                        help="P(FORWARD) of the random policy (0.2: uniform over the 5 actions)")
    parser.add_argument("--json", type=Path, help="also write the counts here")
    args = parser.parse_args(argv)

    import gymnasium as gym
    import jax
    import numpy as np
    import rware  # noqa: F401  (registers the ids)

    import wrl_jax
    from wrl_jax.envs.rware import from_rware, rware_arrays, state_arrays

    warehouse = gym.make(args.env, disable_env_checker=True).unwrapped
    env, _ = wrl_jax.make(args.env)
    step = jax.jit(type(env).transition_with, static_argnums=0)
    env = env.without_default_params()
    has_tie = tie_steps_holder()
    rng = np.random.default_rng(args.seed)
    others = [0, 2, 3, 4]
    episodes = []
    for episode in range(args.episodes):
        warehouse.reset(seed=args.seed + episode)
        state, params = from_rware(warehouse)
        generator, draws = warehouse.np_random, []

        class Recorder:  # rware's replacement draws, as indices among the candidates
            def choice(self, population, *rest, **kwargs):
                chosen = generator.choice(population, *rest, **kwargs)
                draws.append(next(i for i, shelf in enumerate(population) if shelf is chosen))
                return chosen

            def __getattr__(self, name):
                return getattr(generator, name)

        warehouse._np_random = Recorder()
        first, ties = None, 0
        for t in range(args.steps):
            arrays = rware_arrays(warehouse)
            n = len(arrays["agent_x"])
            actions = np.where(rng.random(n) < args.forward, 1, rng.choice(others, n))
            ties += has_tie(arrays, actions, warehouse.grid_size)
            draws.clear()
            obs, rewards, done, _, _ = warehouse.step([int(a) for a in actions])
            replacements = np.zeros(env.num_goals, np.int32)
            replacements[: len(draws)] = draws
            our_obs, state, reward, _, truncated, _ = step(env, state, actions.astype(np.int32), replacements, params)
            theirs, ours = rware_arrays(warehouse), state_arrays(state)
            same = (all(np.array_equal(theirs[k], ours[k]) for k in theirs)
                    and np.array_equal(np.asarray(our_obs), np.stack(obs))
                    and np.array_equal(np.asarray(reward), np.asarray(rewards, np.float32)))
            if not same:
                first = t
                break
        episodes.append({"seed": args.seed + episode, "first_difference": first, "tie_steps_before": ties})
        print(f"episode {episode}: {'differs from step ' + str(first) if first is not None else 'identical'}"
              f" ({ties} tie steps up to there)", flush=True)
    differing = sum(e["first_difference"] is not None for e in episodes)
    summary = {"env": args.env, "episodes": args.episodes, "steps": args.steps, "p_forward": args.forward,
               "differing_episodes": differing, "per_episode": episodes}
    print(f"{differing} of {args.episodes} episodes of {args.env} differ from unpatched rware")
    if args.json:
        args.json.write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
