"""What a procedural run's greedy policy does on the held-out episodes it does not deliver.

Why this exists: the final report counts undelivered episodes; to choose what to change next one
needs their shape. For one seed of a saved run (``--seed-index``), every real (layout, item) episode
of the final report's held-out set is run greedily for the episode length with positions recorded
(one ``lax.scan`` of ``env.transition`` over all episodes, inside ``jit``), and each undelivered one is
put in a class by what it did in its last ``--tail`` steps:

* ``two-cell loop``: it stood on exactly two cells (the back-and-forth a memoryless policy falls into);
* ``short loop``: three to eight cells;
* ``stuck``: one cell (pushing into a shelf or the edge, or waiting);
* ``wandering``: more than eight cells;

and by stage (still looking for its item, or carrying it to the goal). The delivered episodes' excess
over the BFS optimum is broken down too (``excess``: how many episodes took 0, 1-2, 3-5, 6-10, 11-20,
21-50 and more than 50 extra steps, and each bucket's share of the total excess), to tell a policy that
detours a little everywhere from one whose mean is made by a few long searches. Run from the repository
root::

    .venv/bin/python bench/procedural_failures.py --run runs/ppo-procedural --json OUT
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from wrl_jax.agents import get_spec  # noqa: E402
from wrl_jax.agents.base import config_from_dict  # noqa: E402
from wrl_jax.cli.options import EnvOptions, build  # noqa: E402
from wrl_jax.envs.procedural import layout_sets  # noqa: E402
from wrl_jax.envs.procedural.pool import pool_of  # noqa: E402
from wrl_jax.training import Trainer, LoopConfig, checkpoint  # noqa: E402


def classify(cells_in_tail: np.ndarray) -> np.ndarray:
    """Class names of undelivered episodes from the number of distinct cells of their last steps."""
    return np.select([cells_in_tail == 1, cells_in_tail == 2, cells_in_tail <= 8],
                     ["stuck", "two-cell loop", "short loop"], "wandering")


EXCESS_BUCKETS = ((0, 0), (1, 2), (3, 5), (6, 10), (11, 20), (21, 50), (51, None))


def excess_breakdown(excess: np.ndarray, optimal: np.ndarray) -> dict:
    """Delivered episodes by extra steps over the optimum: count, and share of the total excess, per bucket.

    ``excess_fraction`` is the final report's (mean excess over mean optimum); ``without_over_20`` is the
    same for the episodes with at most 20 extra steps, the policy's routing without its long searches.
    """
    total = max(int(excess.sum()), 1)
    buckets = {}
    for low, high in EXCESS_BUCKETS:
        mine = (excess >= low) & (excess <= (high if high is not None else excess.max(initial=0)))
        name = str(low) if low == high else (f"{low}-{high}" if high is not None else f">{low - 1}")
        buckets[name] = {"episodes": int(mine.sum()), "share_of_excess": float(excess[mine].sum() / total)}
    short = excess <= 20
    return {"delivered": int(excess.size), "excess_fraction": float(excess.mean() / optimal.mean()),
            "without_over_20": float(excess[short].mean() / optimal[short].mean()), "buckets": buckets}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True, help="a Procedural-Warehouse-v0 run directory")
    parser.add_argument("--seed-index", type=int, default=0, help="which of the run's seeds (position)")
    parser.add_argument("--tail", type=int, default=50, help="steps at the end of an episode looked at")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)

    meta = checkpoint.read_metadata(args.run)
    spec = get_spec(meta["algo"])
    algo = build(spec, config_from_dict(spec.config_cls, meta["config"]),
                 EnvOptions(env=meta["env"], **meta.get("env_overrides", {})))
    env = algo.env
    trainer = Trainer(algo, meta["seeds"], LoopConfig(progress=False))
    runners, _ = checkpoint.load(args.run, trainer.template())
    network = jax.tree.map(lambda x: x[args.seed_index], jax.vmap(algo.network_params)(runners))
    params = jax.tree.map(lambda x: x[0], runners.env_params)
    heldout, _ = layout_sets.heldout_set(env.generator, env.training_layout_hashes(params, meta["updates_done"]))
    eval_params = env.with_pool(params, jax.jit(pool_of)(heldout.layouts))
    num_items = np.asarray(heldout.layouts.num_items)
    slots, items = np.nonzero(np.arange(heldout.layouts.max_items)[None, :] < num_items[:, None])
    horizon = int(params.max_steps)

    @jax.jit
    def trajectories(slots, items):
        def episode(slot, item):
            obs, state = env.reset_to(slot, item, eval_params)

            def one(carry, _):
                obs, state, done = carry
                action = algo.greedy_action(network, obs)
                obs2, state2, _, terminated, truncated, _ = env.transition(None, state, action, eval_params)
                keep = lambda new, old: jnp.where(done, old, new)  # noqa: E731
                state2 = jax.tree.map(keep, state2, state)
                return (keep(obs2, obs), state2, done | terminated | truncated), (state2.pos, state2.carrying)

            (_, last, _), (pos, carrying) = jax.lax.scan(one, (obs, state, jnp.array(False)), None, length=horizon)
            delivered = last.carrying & jnp.all(last.pos == last.goal)
            return delivered, pos, carrying, last.time, last.optimal

        return jax.vmap(episode)(slots, items)

    delivered, pos, carrying, steps, optimal = (np.asarray(x) for x in trajectories(
        jnp.asarray(slots, jnp.int32), jnp.asarray(items, jnp.int32)))
    failed = np.flatnonzero(~delivered)
    tail = pos[failed, -args.tail:]
    cells = np.array([len({tuple(cell) for cell in episode}) for episode in tail], dtype=np.int32)
    classes = classify(cells)
    stage = np.where(carrying[failed, -1], "carrying to the goal", "looking for the item")
    counts = {name: int((classes == name).sum()) for name in ("two-cell loop", "short loop", "stuck", "wandering")}
    by_stage = {name: int((stage == name).sum()) for name in ("looking for the item", "carrying to the goal")}
    result = {"run": str(args.run), "seed": int(meta["seeds"][args.seed_index]), "episodes": int(delivered.size),
              "undelivered": int(failed.size), "tail_steps": args.tail, "classes": counts, "stages": by_stage,
              "distinct_cells_in_tail": {str(k): int(v) for k, v in zip(*np.unique(cells, return_counts=True))},
              "excess": excess_breakdown(steps[delivered] - optimal[delivered], optimal[delivered])}
    print(json.dumps(result, indent=2))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
