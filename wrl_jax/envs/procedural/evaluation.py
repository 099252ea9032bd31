"""Greedy evaluation on held-out generated warehouses: the procedural family's evaluation hook.

One greedy episode per (held-out layout, item): ``EVAL_LAYOUTS`` layouts drawn
from the *held-out* key stream of :data:`EVAL_SEED` (disjoint by construction
from the training stream the pool is drawn from; ``pool.disjoint_from`` checks
the layouts by hash), every real item of each. The episode runs until delivery
or ``max_steps`` (a ``lax.while_loop`` that stops when all have ended), and is
judged against its BFS optimum, so the numbers mean the same on every floor:

- ``success_rate``: delivered episodes / episodes;
- ``optimal_rate``: delivered at exactly the BFS optimum;
- ``mean_excess``: mean ``steps - optimum`` over delivered episodes (NaN if none).

"Solved" is ``optimal_rate == 1``. Everything is jittable: the held-out pool is
generated inside the program (64 layouts: negligible next to training).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from wrl_jax.envs.procedural.pool import generate_pool
from wrl_jax.training.evaluation import FamilyEvaluation

EVAL_SEED = 2026
EVAL_LAYOUTS = 64
GreedyFn = Callable[[Any, jax.Array], jax.Array]


@struct.dataclass
class EpisodeEval:
    """One greedy episode per (layout, item); leaves ``(..., EVAL_LAYOUTS, I)``; ``real`` masks padding items."""

    real: jax.Array
    delivered: jax.Array
    steps: jax.Array
    optimal_steps: jax.Array
    collisions: jax.Array


def evaluate_policy(greedy_action: GreedyFn, network_params: Any, env, params) -> EpisodeEval:
    """Greedy episodes on the held-out layouts, with ``params``' rewards and ``max_steps`` (jittable)."""
    pool = generate_pool(jax.random.key(EVAL_SEED), EVAL_LAYOUTS, env.generator, stream="heldout")
    eval_params = env.with_pool(params, pool)
    num_items = pool.layouts.items.shape[-2]
    slots, items = jnp.meshgrid(jnp.arange(EVAL_LAYOUTS), jnp.arange(num_items), indexing="ij")

    def episode(slot, item):
        obs, state = env.reset_to(slot, item, eval_params)

        def running(carry):
            _, state, done, _ = carry
            return ~done & (state.time < params.max_steps)

        def one(carry):
            obs, state, _, collisions = carry
            action = greedy_action(network_params, obs)
            obs, state, _, terminated, truncated, info = env.transition(None, state, action, eval_params)
            return obs, state, terminated | truncated, collisions + info["collision"].astype(jnp.int32)

        _, state, _, collisions = jax.lax.while_loop(running, one, (obs, state, jnp.array(False), jnp.int32(0)))
        delivered = state.carrying & jnp.all(state.pos == state.goal)
        return delivered, state.time, state.optimal, collisions

    delivered, steps, optimal, collisions = jax.vmap(jax.vmap(episode))(slots, items)
    real = items < pool.layouts.num_items[:, None]
    return EpisodeEval(real=real, delivered=delivered, steps=steps, optimal_steps=optimal, collisions=collisions)


def _rates(result: EpisodeEval, xp) -> dict[str, Any]:
    real = result.real
    count = xp.sum(real)
    delivered = result.delivered & real
    optimal = delivered & (result.steps == result.optimal_steps)
    excess = xp.where(delivered, result.steps - result.optimal_steps, 0)
    num_delivered = xp.sum(delivered)
    return {
        "success_rate": xp.sum(delivered) / count,
        "optimal_rate": xp.sum(optimal) / count,
        "mean_excess": xp.where(num_delivered > 0, xp.sum(excess) / xp.maximum(num_delivered, 1), xp.nan),
        "collisions_per_episode": xp.sum(xp.where(real, result.collisions, 0)) / count,
    }


def seed_summary(result: EpisodeEval) -> dict[str, jax.Array]:
    """Float32 scalars of one seed's evaluation, jittable; ``eval_solved`` is 1.0 when every episode was optimal."""
    rates = {f"eval_{name}": jnp.asarray(value, jnp.float32) for name, value in _rates(result, jnp).items()}
    rates["eval_solved"] = (rates["eval_optimal_rate"] == 1.0).astype(jnp.float32)
    return rates


def summarize(result: EpisodeEval, seeds: Sequence[int] | None = None) -> dict[str, Any]:
    """Aggregates over seeds (leading axis) and per-seed rates, as plain Python numbers."""
    result = jax.tree.map(np.asarray, result)
    num_seeds = result.delivered.shape[0]
    seeds = list(range(num_seeds)) if seeds is None else list(seeds)
    per_seed = [{"seed": seed, **{k: float(v) for k, v in _rates(jax.tree.map(lambda x, i=i: x[i], result),
                                                                  np).items()}}
                for i, seed in enumerate(seeds)]
    overall = {k: float(v) for k, v in _rates(result, np).items()}
    return {**overall, "num_seeds": num_seeds, "eval_layouts": EVAL_LAYOUTS,
            "episodes_per_seed": int(result.real[0].sum()), "per_seed": per_seed}


def format_report(summary: dict[str, Any], label: str, convergence_steps: Sequence[int | None] | None = None,
                  study: dict[str, str] | None = None) -> str:
    """A Markdown table of the held-out evaluation (no study column: the study had no generated layouts)."""
    del study
    rows = [
        ("held-out layouts x items", f"{summary['eval_layouts']} layouts, {summary['episodes_per_seed']} episodes"),
        ("delivered", f"{summary['success_rate']:.1%}"),
        ("at the BFS optimum", f"{summary['optimal_rate']:.1%}"),
        ("mean steps over the optimum (delivered)", f"{summary['mean_excess']:.2f}"),
        ("collisions per episode", f"{summary['collisions_per_episode']:.2f}"),
    ]
    if convergence_steps is not None:
        solved = [step for step in convergence_steps if step is not None]
        rows.append(("seeds solved", f"{len(solved)} of {len(convergence_steps)}"))
    lines = [f"| {label} | |", "|---|---|", *(f"| {name} | {value} |" for name, value in rows)]
    return "\n".join(lines)


EVALUATION = FamilyEvaluation(
    evaluate_policy=evaluate_policy,
    seed_summary=seed_summary,
    solved_key="eval_solved",
    solved_definition="env steps per seed at the first periodic greedy evaluation delivering every held-out "
                      "(layout, item) episode at its BFS optimum",
    summarize=summarize,
    format_report=format_report,
    format_details=lambda summary: "",
    progress_metric=("eval_success_rate", "held-out delivered"),
)
