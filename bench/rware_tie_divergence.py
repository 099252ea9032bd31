"""How often the JAX RWARE and *unpatched* rware 2.0.0 part ways, because of chain-tie order alone.

rware breaks ties between equally long chains into one cell by networkx's node iteration order,
which for some components is CPython hash-set order (bench/results/rware/NOTES.md 9.1).
wrl_jax.envs.rware's default ``tie_order="set"`` emulates it (expect no split); ``--tie-order
insertion`` measures the graph's insertion order instead, what networkx does when ``subgraph`` keeps
it. This runs episodes of plain rware, unpatched, with a random
policy, steps ours from the same state with the same actions and rware's own replacement draws,
and counts the episodes in which the two ever differ (first differing step, and the steps
holding a tie). Each episode starts from rware's seeded reset, converted by ``from_rware``.

With ``--run DIR`` the actions are a trained run's instead (``train_ppo.py --out DIR`` on the same id):
seed 0's policy, sampled (``--greedy``: its argmax), from the observations rware gives.

Run from the repository root (needs rware 2.0.0 and networkx)::

    .venv/bin/python bench/rware_tie_divergence.py --env rware-tiny-8ag-v2 --episodes 40
    .venv/bin/python bench/rware_tie_divergence.py --env rware-tiny-4ag-v2 --run runs/ippo-tiny-4ag --episodes 40
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


def trained_policy(run_dir: Path, env_name: str, greedy: bool):
    """``policy(obs (N, D), key) -> (N,)`` actions of seed 0 of a ``train_ppo.py`` run on ``env_name``."""
    import jax

    from wrl_jax import training
    from wrl_jax.agents import get_spec
    from wrl_jax.agents.base import config_from_dict
    from wrl_jax.cli.options import EnvOptions, build
    from wrl_jax.training import checkpoint

    meta = checkpoint.read_metadata(run_dir)
    if meta["env"] != env_name:
        raise SystemExit(f"--run {run_dir} trained on {meta['env']}, not on --env {env_name}")
    spec = get_spec(meta["algo"])
    algo = build(spec, config_from_dict(spec.config_cls, meta["config"]),
                 EnvOptions(env=meta["env"], **meta.get("env_overrides", {})))
    trainer = training.Trainer(algo, meta["seeds"], training.LoopConfig(progress=False))
    runners, _ = checkpoint.load(run_dir, trainer.template())
    params = algo.network_params(jax.tree.map(lambda leaf: leaf[0], runners))
    if greedy:
        return jax.jit(lambda obs, key: algo.greedy_action(params, obs))
    return jax.jit(lambda obs, key: algo.sample_action(params, obs, key))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="rware-tiny-8ag-v2", help="a registered rware id")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--steps", type=int, default=500, help="steps per episode (rware's limit is 500)")
    parser.add_argument("--seed", type=int, default=0, help="episode e resets rware with seed + e")
    parser.add_argument("--forward", type=float, default=0.2,
                        help="P(FORWARD) of the random policy (0.2: uniform over the 5 actions)")
    parser.add_argument("--run", type=Path, help="act with this trained run's policy (seed 0) instead")
    parser.add_argument("--greedy", action="store_true", help="with --run: the policy's argmax, not a draw")
    parser.add_argument("--json", type=Path, help="also write the counts here")
    parser.add_argument("--tie-order", default="set", choices=["set", "insertion"], help="ours (rware is unpatched)")
    args = parser.parse_args(argv)

    import gymnasium as gym
    import jax
    import numpy as np
    import rware  # noqa: F401  (registers the ids)

    import wrl_jax
    from wrl_jax.envs.rware import from_rware, rware_arrays, state_arrays

    warehouse = gym.make(args.env, disable_env_checker=True).unwrapped
    env, _ = wrl_jax.make(args.env, tie_order=args.tie_order)
    step = jax.jit(type(env).transition_with, static_argnums=0)
    env = env.without_default_params()
    has_tie = tie_steps_holder()
    rng = np.random.default_rng(args.seed)
    policy = None if args.run is None else trained_policy(args.run, args.env, args.greedy)
    policy_key = jax.random.key(args.seed)
    others = [0, 2, 3, 4]
    episodes = []
    for episode in range(args.episodes):
        obs, _ = warehouse.reset(seed=args.seed + episode)
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
        first, ties, team_return = None, 0, 0.0
        for t in range(args.steps):
            arrays = rware_arrays(warehouse)
            n = len(arrays["agent_x"])
            if policy is None:
                actions = np.where(rng.random(n) < args.forward, 1, rng.choice(others, n))
            else:
                key = jax.random.fold_in(jax.random.fold_in(policy_key, episode), t)
                actions = np.asarray(policy(np.stack(obs).astype(np.float32), key))
            ties += has_tie(arrays, actions, warehouse.grid_size)
            draws.clear()
            obs, rewards, done, _, _ = warehouse.step([int(a) for a in actions])
            team_return += float(sum(rewards))
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
        episodes.append({"seed": args.seed + episode, "first_difference": first, "tie_steps_before": ties,
                         "rware_return_until_then": team_return})
        print(f"episode {episode}: {'differs from step ' + str(first) if first is not None else 'identical'}"
              f" ({ties} tie steps, team return {team_return:g} in rware up to there)", flush=True)
    differing = sum(e["first_difference"] is not None for e in episodes)
    acting = ("uniform random" if args.forward == 0.2 and args.run is None else f"P(FORWARD) {args.forward}"
              if args.run is None else f"{'greedy' if args.greedy else 'sampled'} policy of {args.run}")
    summary = {"env": args.env, "tie_order": args.tie_order, "episodes": args.episodes, "steps": args.steps,
               "actions": acting,
               "p_forward": args.forward,
               "differing_episodes": differing, "per_episode": episodes}
    print(f"{differing} of {args.episodes} episodes of {args.env} differ from unpatched rware")
    if args.json:
        args.json.write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
