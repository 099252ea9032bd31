"""Deterministic evaluation of a greedy policy on every item, for every seed.

One episode per (seed, item index): the environment is reset to that item
(``Warehouse.reset_to_item``) and the greedy policy acts until the item is
delivered or the episode is truncated at ``max_steps``. Everything runs in one
jitted program: ``vmap`` over seeds and items, a ``lax.while_loop`` over time
that stops as soon as every episode has ended (the result is the same as a
``lax.scan`` over ``max_steps`` with finished episodes frozen, only cheaper).

What one episode records (:class:`EpisodeEval`) and how it is judged:

- ``delivered``: the episode terminated (the item reached the goal) before truncation.
- ``steps``: transitions taken (``max_steps`` when not delivered).
- ``optimal_steps``: the BFS optimum start -> item -> goal (``wrl_jax.envs.warehouse.routes``).
- ``optimal``: delivered in exactly ``optimal_steps`` (so also without collisions
  or wall bumps, which cost a step without moving).
- ``collisions``: moves into a shelf. ``collision_free``: none.
- ``stage_switch``: *correct stage switching*, defined as: the item was picked up
  before delivery (the environment enforces that order) **and** from the step of
  pickup the policy went to the goal along a shortest route, i.e.
  ``steps - pickup_step == BFS(item, goal)``. It measures the study's claim that
  "immediately upon picking up the item, the navigation target transitioned to
  the goal", separately from how well the first leg was driven.

This is the warehouse family's evaluation hook (:data:`EVALUATION`, see
:mod:`wrl_jax.core.evaluation`): the training driver and the CLI reach it
through ``env.family`` and know nothing of items. The same function serves the
periodic evaluation inside the compiled training
loop (:func:`seed_summary`, per-seed scalars) and the final report
(:func:`summarize`, aggregates and per-seed per-item rows, and
:func:`format_table3`, a text table shaped like the study's Table 3).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from wrl_jax.core.evaluation import FamilyEvaluation, SweepColumns, SweepMetric, TrainRate
from wrl_jax.core.evaluation import number_text as _num
from wrl_jax.core.evaluation import percent_text as _pct
from wrl_jax.envs.warehouse import routes
from wrl_jax.envs.warehouse.env import Warehouse
from wrl_jax.envs.warehouse.types import EnvParams

GreedyFn = Callable[[Any, jax.Array], jax.Array]
"""``greedy_action(network_params, obs) -> action`` for one observation."""

SOLVED_DEFINITION = (
    "env steps per seed at the first periodic greedy evaluation delivering every item at the BFS optimum "
    "(stable: from which every later evaluation did too)"
)


@struct.dataclass
class EpisodeEval:
    """One greedy episode per item index; leaves have shape ``(..., K_max)``.

    Rows past ``num_items`` (padding of ``params.items``) have ``valid`` False
    and are ignored by every aggregate.
    """

    valid: jax.Array  # bool: item index < num_items
    delivered: jax.Array  # bool
    steps: jax.Array  # int32
    optimal_steps: jax.Array  # int32, BFS start -> item -> goal
    episode_return: jax.Array  # float32, undiscounted
    collisions: jax.Array  # int32
    wall_bumps: jax.Array  # int32
    pickup_step: jax.Array  # int32, step count at pickup, -1 if never picked up
    stage_switch: jax.Array  # bool, see the module docstring

    @property
    def optimal(self) -> jax.Array:
        return self.delivered & (self.steps == self.optimal_steps)


def evaluate_policy(greedy_action: GreedyFn, network_params: Any, env: Warehouse, params: EnvParams) -> EpisodeEval:
    """Greedy episodes of one policy on every item index of ``params`` (shape ``(K_max,)``)."""
    tables = routes.route_tables(params)
    optimal = routes.optimal_lengths(params, tables)
    item_to_goal = tables.to_goal[params.items[:, 0], params.items[:, 1]]
    item_indices = jnp.arange(params.items.shape[0], dtype=jnp.int32)
    valid = item_indices < params.num_items
    # Padding rows duplicate item 0 (a valid cell), so running them is harmless.
    episodes = jax.vmap(lambda i: _greedy_episode(greedy_action, network_params, env, params, i))(item_indices)
    delivered, steps, episode_return, collisions, wall_bumps, pickup_step = episodes
    stage_switch = delivered & (pickup_step >= 0) & (steps - pickup_step == item_to_goal)
    return EpisodeEval(
        valid=valid,
        delivered=delivered & valid,
        steps=steps,
        optimal_steps=optimal,
        episode_return=episode_return,
        collisions=collisions,
        wall_bumps=wall_bumps,
        pickup_step=pickup_step,
        stage_switch=stage_switch & valid,
    )


def evaluate_seeds(
    greedy_action: GreedyFn, network_params: Any, env: Warehouse, params: EnvParams, params_batched: bool = False
) -> EpisodeEval:
    """:func:`evaluate_policy` for a leading seed axis of ``network_params`` (shape ``(S, K_max)``).

    ``params`` is shared by every seed unless ``params_batched`` (a sweep over
    environment constants, or a runner's per-seed copy of them).
    """
    return jax.vmap(
        lambda p, e: evaluate_policy(greedy_action, p, env, e), in_axes=(0, 0 if params_batched else None)
    )(network_params, params)


def _greedy_episode(greedy_action: GreedyFn, network_params: Any, env: Warehouse, params: EnvParams, item_index):
    obs, state = env.reset_to_item(item_index, params)
    zero_i = jnp.zeros((), jnp.int32)
    # carry: obs, state, done, delivered, return, collisions, wall bumps, pickup step
    init = (obs, state, jnp.zeros((), bool), jnp.zeros((), bool), jnp.zeros((), jnp.float32), zero_i, zero_i, -1 + zero_i)

    def cond(carry):
        return ~carry[2]

    def body(carry):
        obs, state, _, _, ret, collisions, bumps, pickup_step = carry
        action = greedy_action(network_params, obs)
        next_obs, next_state, reward, terminated, truncated, info = env.transition(None, state, action, params)
        pickup_step = jnp.where(info["picked_up"], next_state.time, pickup_step)
        return (
            next_obs,
            next_state,
            terminated | truncated,
            terminated,
            ret + reward,
            collisions + info["collision"].astype(jnp.int32),
            bumps + info["wall_bump"].astype(jnp.int32),
            pickup_step,
        )

    _, state, _, delivered, ret, collisions, bumps, pickup_step = jax.lax.while_loop(cond, body, init)
    return delivered, state.time, ret, collisions, bumps, pickup_step


# ---------------------------------------------------------------- in training
SEED_SUMMARY_KEYS = (
    "eval_success_rate",
    "eval_optimal_rate",
    "eval_mean_steps",
    "eval_collision_free_rate",
    "eval_mean_return",
    "eval_all_optimal",
)


def seed_summary(result: EpisodeEval) -> dict[str, jax.Array]:
    """Float32 scalars of one seed's evaluation (leaves of shape ``(K_max,)``), jittable.

    ``eval_mean_steps`` is over delivered episodes (NaN if none);
    ``eval_all_optimal`` is 1.0 when every item was delivered at the BFS optimum:
    the event whose first occurrence is a seed's *convergence step*.
    """
    valid = result.valid
    n = valid.sum().astype(jnp.float32)
    delivered = result.delivered & valid
    n_delivered = delivered.sum().astype(jnp.float32)
    optimal_rate = (result.optimal & valid).sum() / n
    return {
        "eval_success_rate": n_delivered / n,
        "eval_optimal_rate": optimal_rate,
        "eval_mean_steps": jnp.where(n_delivered > 0, jnp.where(delivered, result.steps, 0).sum() / n_delivered, jnp.nan),
        "eval_collision_free_rate": ((result.collisions == 0) & valid).sum() / n,
        "eval_mean_return": jnp.where(valid, result.episode_return, 0.0).sum() / n,
        "eval_all_optimal": (optimal_rate == 1.0).astype(jnp.float32),
    }


# ------------------------------------------------------------- final report
def summarize(result: EpisodeEval, seeds: Sequence[int] | None = None) -> dict[str, Any]:
    """Aggregates over every seed and item, plus per-seed summaries and per-(seed, item) rows.

    ``result`` has leaves of shape ``(S, K_max)``. Plain Python numbers, ready for JSON:

    - ``success_rate``: delivered episodes / episodes.
    - ``mean_steps``: mean steps of the delivered episodes (the study's "mean steps
      to complete"; ``None`` if nothing was delivered). Read it with ``success_rate``.
    - ``optimal_mean_steps``: mean BFS optimum over the same items.
    - ``excess_steps``: mean of (steps - optimum) over delivered episodes.
    - ``optimal_rate``: episodes delivered at exactly the optimum.
    - ``collision_free_rate``, ``stage_switch_rate``, ``mean_return``.
    - ``all_seeds_optimal``: every seed delivers every item at the optimum.
    """
    r = jax.tree.map(np.asarray, result)
    num_seeds = r.valid.shape[0]
    seeds = list(range(num_seeds)) if seeds is None else [int(s) for s in seeds]
    if len(seeds) != num_seeds:
        raise ValueError(f"got {len(seeds)} seed labels for {num_seeds} evaluated seeds")
    valid = r.valid.astype(bool)
    delivered = r.delivered & valid
    optimal = delivered & (r.steps == r.optimal_steps)

    def _mean(values, mask):
        return float(values[mask].mean()) if mask.any() else None

    summary: dict[str, Any] = {
        "num_seeds": num_seeds,
        "num_items": int(valid[0].sum()),
        "episodes": int(valid.sum()),
        "success_rate": float(delivered.sum() / valid.sum()),
        "mean_steps": _mean(r.steps, delivered),
        "optimal_mean_steps": _mean(r.optimal_steps, valid),
        "excess_steps": _mean(r.steps - r.optimal_steps, delivered),
        "optimal_rate": float(optimal.sum() / valid.sum()),
        "collision_free_rate": float(((r.collisions == 0) & valid).sum() / valid.sum()),
        "stage_switch_rate": float((r.stage_switch & valid).sum() / valid.sum()),
        "mean_return": _mean(r.episode_return, valid),
        "all_seeds_optimal": bool(optimal.sum() == valid.sum()),
    }
    per_seed = []
    rows = []
    for s, seed in enumerate(seeds):
        v = valid[s]
        per_seed.append(
            {
                "seed": seed,
                "success_rate": float(delivered[s].sum() / v.sum()),
                "mean_steps": _mean(r.steps[s], delivered[s]),
                "optimal_rate": float(optimal[s].sum() / v.sum()),
                "collision_free_rate": float(((r.collisions[s] == 0) & v).sum() / v.sum()),
                "mean_return": _mean(r.episode_return[s], v),
            }
        )
        for i in np.flatnonzero(v):
            rows.append(
                {
                    "seed": seed,
                    "item": int(i),
                    "delivered": bool(delivered[s, i]),
                    "steps": int(r.steps[s, i]),
                    "optimal_steps": int(r.optimal_steps[s, i]),
                    "return": float(r.episode_return[s, i]),
                    "collisions": int(r.collisions[s, i]),
                    "wall_bumps": int(r.wall_bumps[s, i]),
                    "pickup_step": int(r.pickup_step[s, i]),
                    "stage_switch": bool(r.stage_switch[s, i]),
                }
            )
    summary["per_seed"] = per_seed
    summary["rows"] = rows
    return summary


def format_table3(
    summary: dict[str, Any],
    label: str,
    convergence_steps: Sequence[int | None] | None = None,
    study: dict[str, str] | None = None,
) -> str:
    """A Markdown table shaped like the study's Table 3 (one column, optionally the study's beside it).

    ``convergence_steps`` are the per-seed first env steps at which the greedy
    policy delivered every item at the optimum (``None`` for a seed that never did).
    """
    n_items, n_seeds = summary["num_items"], summary["num_seeds"]
    seeds_ok = sum(1 for s in summary["per_seed"] if s["success_rate"] == 1.0)
    conv = "not measured"
    if convergence_steps is not None:
        reached = [c for c in convergence_steps if c is not None]
        if reached:
            conv = f"median {int(np.median(reached)):,} (min {min(reached):,}, max {max(reached):,}) steps"
            if len(reached) < len(convergence_steps):
                conv += f"; {len(convergence_steps) - len(reached)}/{len(convergence_steps)} seeds never"
        else:
            conv = f"never ({len(convergence_steps)} seeds)"
    rows = [
        ("Task Completion Rate", f"{_pct(summary['success_rate'])} ({n_items} items x {n_seeds} seeds; "
         f"{seeds_ok}/{n_seeds} seeds deliver all)"),
        ("Mean Steps to Complete", f"{_num(summary['mean_steps'], '{:.2f}')} (BFS optimum "
         f"{_num(summary['optimal_mean_steps'], '{:.2f}')}; at optimum {_pct(summary['optimal_rate'])})"),
        ("Mean Episode Reward", _num(summary["mean_return"], "{:+.1f}")),
        ("Convergence Timestep", conv),
        ("Obstacle Avoidance", f"{_pct(summary['collision_free_rate'])} of episodes collision-free"),
        ("Stage Switching", f"{_pct(summary['stage_switch_rate'])} shortest route to goal after pickup"),
    ]
    header = ["Metric", label] + (["Study"] if study else [])
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for name, value in rows:
        cells = [name, value] + ([study.get(name, "")] if study else [])
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_items(summary: dict[str, Any]) -> str:
    """Per-item table: delivered seeds, mean steps against the optimum, collisions."""
    rows = summary["rows"]
    items = sorted({row["item"] for row in rows})
    lines = ["| item | delivered | mean steps | optimum | collisions |", "|---|---|---|---|---|"]
    for item in items:
        mine = [row for row in rows if row["item"] == item]
        done = [row for row in mine if row["delivered"]]
        steps = f"{np.mean([row['steps'] for row in done]):.2f}" if done else "n/a"
        lines.append(
            f"| {item} | {len(done)}/{len(mine)} | {steps} | {mine[0]['optimal_steps']} | "
            f"{sum(row['collisions'] for row in mine)} |"
        )
    return "\n".join(lines)


EVALUATION = FamilyEvaluation(
    evaluate_policy=evaluate_policy,
    seed_summary=seed_summary,
    solved_key="eval_all_optimal",
    solved_definition=SOLVED_DEFINITION,
    summarize=summarize,
    format_report=format_table3,
    format_details=format_items,
    progress_metric=("eval_optimal_rate", "eval optimal"),
    train_rates=(TrainRate("delivery_rate", "delivery rate (training episodes)", "terminated",
                           progress="delivered"),),
    sweep_columns=SweepColumns(
        metrics=(
            SweepMetric("success_rate", "greedy success", "percent", plot="greedy success rate (%)"),
            SweepMetric("optimal_rate", "greedy optimal items", "percent", plot="items at the BFS optimum (%)"),
            SweepMetric("all_optimal", "seeds all-optimal", "solved"),
            SweepMetric("mean_steps", "mean steps (delivered)", digits=2, plot="mean steps (delivered)"),
            SweepMetric("mean_return", "greedy return"),
            SweepMetric("collision_free_rate", "collision-free episodes", "percent", table=False),
        ),
        train=(
            SweepMetric("delivery_rate", "train delivery (last log)", "percent"),
            SweepMetric("mean_return", "train return (last log)", table=False, aggregate=False),
        ),
        convergence_label="first optimal step",
        convergence_note="env steps per seed at the first periodic greedy evaluation with every item at the BFS "
                         "optimum",
    ),
)
"""The warehouse family's evaluation hook (:mod:`wrl_jax.core.evaluation`)."""
