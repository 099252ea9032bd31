"""Greedy evaluation on held-out and out-of-distribution warehouses: the procedural family's evaluation hook.

Every episode is one (layout, item) pair, run greedily until delivery or
``max_steps`` and judged against its BFS optimum, so the numbers mean the
same on every floor:

- ``success_rate`` / ``delivery_rate``: delivered episodes / episodes;
- ``optimal_rate``: delivered at exactly the BFS optimum;
- ``mean_excess``: mean ``steps - optimum`` over delivered episodes (NaN if none),
  and ``excess_fraction``: that excess over the delivered episodes' mean optimum.

Two evaluations use it:

- **Periodic**, inside the compiled training loop (:func:`evaluate_policy`):
  ``EVAL_LAYOUTS`` (64) layouts of the *held-out* key stream of
  :data:`EVAL_SEED`, generated inside the program, every real item of each.
  "Solved" is ``optimal_rate == 1``.
- **Final**, once on the host after training (:func:`final_report`, also run by
  ``python -m wrl_jax.evaluate``): the held-out and out-of-distribution sets of
  :mod:`~wrl_jax.envs.procedural.layout_sets`, padded to one item capacity and run
  as one compiled program (:func:`evaluate_sets`: a loop of episodes per set, every seed
  at once); results are split per set and seed. The statistics and tables are
  :mod:`~wrl_jax.envs.procedural.reports`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from wrl_jax.core.evaluation import FamilyEvaluation, FinalContext, PolicyMemory, SweepColumns, SweepMetric, TrainRate
from wrl_jax.envs.procedural.layout_sets import EVAL_SEED, LayoutSet, heldout_set, ood_sets, pad_items
from wrl_jax.envs.procedural.pool import LayoutPool, generate_pool, pool_of
from wrl_jax.envs.procedural.reports import episode_stats, format_details, format_report

EVAL_LAYOUTS = 64
"""Held-out layouts of the periodic evaluation (generated inside the training program)."""
GreedyFn = Callable[[Any, jax.Array], jax.Array]
SampleFn = Callable[[Any, jax.Array, jax.Array], jax.Array]


@struct.dataclass
class EpisodeEval:
    """One greedy episode per (layout, item); leaves ``(..., L, I)`` or ``(..., E)``; ``real`` masks padding items."""

    real: jax.Array
    delivered: jax.Array
    steps: jax.Array
    optimal_steps: jax.Array
    collisions: jax.Array


def run_episodes(greedy_action: GreedyFn, network_params: Any, env, params, slots: jax.Array,
                 items: jax.Array, sample_action: SampleFn | None = None,
                 key: jax.Array | None = None, memory: PolicyMemory | None = None,
                 episode_offset: int = 0) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """Greedy episodes ``(slot, item)`` of ``params``' pool: ``(delivered, steps, optimum, collisions)`` (jittable).

    One batched ``lax.while_loop`` over all episodes, stopping when every one has
    delivered or reached ``params.max_steps``; ``env.transition`` (no auto-reset).
    With ``sample_action`` and ``key``, the policy's actions are drawn instead:
    episode ``e`` draws step ``t``'s action from ``fold_in(fold_in(key, e), t)`` (``e`` counted
    from ``episode_offset``). With ``memory`` (the algorithm's :meth:`policy_memory`) the policy runs on the whole
    batch and keeps its memory across steps: the same actions, computed more cheaply.
    """
    sampled = sample_action is not None
    if sampled and key is None:
        raise ValueError("sampled episodes need a key")
    if memory is not None:
        return _run_batch(memory, network_params, env, params, slots, items, key if sampled else None,
                          episode_offset)

    def episode(slot, item, episode_index):
        obs, state = env.reset_to(slot, item, params)
        episode_key = jax.random.fold_in(key, episode_index) if sampled else None

        def running(carry):
            _, state, done, _ = carry
            return ~done & (state.time < params.max_steps)

        def one(carry):
            obs, state, _, collisions = carry
            if sampled:
                action = sample_action(network_params, obs, jax.random.fold_in(episode_key, state.time))
            else:
                action = greedy_action(network_params, obs)
            obs, state, _, terminated, truncated, info = env.transition(None, state, action, params)
            return obs, state, terminated | truncated, collisions + info["collision"].astype(jnp.int32)

        _, state, _, collisions = jax.lax.while_loop(running, one, (obs, state, jnp.array(False), jnp.int32(0)))
        delivered = state.carrying & jnp.all(state.pos == state.goal)
        return delivered, state.time, state.optimal, collisions

    return jax.vmap(episode)(slots, items, episode_offset + jnp.arange(slots.shape[0], dtype=jnp.int32))


def _run_batch(memory: PolicyMemory, network_params: Any, env, params, slots: jax.Array, items: jax.Array,
               key: jax.Array | None, episode_offset: int) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """:func:`run_episodes` written over the batch (what ``vmap`` makes of it), with the policy's memory."""
    obs, state = jax.vmap(env.reset_to, in_axes=(0, 0, None))(slots, items, params)
    episode_keys = None if key is None else jax.vmap(jax.random.fold_in, in_axes=(None, 0))(
        key, episode_offset + jnp.arange(slots.shape[0], dtype=jnp.int32))
    transition = jax.vmap(env.transition, in_axes=(None, 0, 0, None))

    def running(state, done):
        return ~done & (state.time < params.max_steps)

    def one(carry):
        obs, state, done, collisions, kept = carry
        active = running(state, done)
        if episode_keys is None:
            action, kept = memory.greedy(network_params, kept, obs)
        else:
            step_keys = jax.vmap(jax.random.fold_in)(episode_keys, state.time)
            action, kept = memory.sample(network_params, kept, obs, step_keys)
        new_obs, new_state, _, terminated, truncated, info = transition(None, state, action, params)

        def keep(new, old):  # finished episodes stay as they ended
            return jnp.where(active.reshape(active.shape + (1,) * (new.ndim - 1)), new, old)

        obs, state = jax.tree.map(keep, (new_obs, new_state), (obs, state))
        done = done | (active & (terminated | truncated))
        return obs, state, done, collisions + (active & info["collision"]).astype(jnp.int32), kept

    done = jnp.zeros(slots.shape, bool)
    carry = (obs, state, done, jnp.zeros(slots.shape, jnp.int32), memory.init(network_params, obs))
    _, state, _, collisions, _ = jax.lax.while_loop(lambda c: jnp.any(running(c[1], c[2])), one, carry)
    delivered = state.carrying & jnp.all(state.pos == state.goal, axis=-1)
    return delivered, state.time, state.optimal, collisions


def evaluate_pool(greedy_action: GreedyFn, network_params: Any, env, params, pool: LayoutPool) -> EpisodeEval:
    """Every (layout, item) slot of ``pool``, with ``params``' rewards and ``max_steps``; leaves ``(L, I)`` (jittable)."""
    eval_params = env.with_pool(params, pool)
    num_layouts, num_items = pool.layouts.items.shape[-3:-1]
    slots, items = jnp.meshgrid(jnp.arange(num_layouts), jnp.arange(num_items), indexing="ij")
    outcome = run_episodes(greedy_action, network_params, env, eval_params, slots.reshape(-1), items.reshape(-1))
    delivered, steps, optimal, collisions = (x.reshape(num_layouts, num_items) for x in outcome)
    real = items < pool.layouts.num_items[:, None]
    return EpisodeEval(real=real, delivered=delivered, steps=steps, optimal_steps=optimal, collisions=collisions)


def evaluate_policy(greedy_action: GreedyFn, network_params: Any, env, params) -> EpisodeEval:
    """The periodic evaluation: the 64 held-out layouts of :data:`EVAL_SEED` (generated inside the program)."""
    pool = generate_pool(jax.random.key(EVAL_SEED), EVAL_LAYOUTS, env.generator, stream="heldout")
    return evaluate_pool(greedy_action, network_params, env, params, pool)


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


def evaluate_sets(greedy_action: GreedyFn, network_params: Any, env, params, sets: Sequence[LayoutSet],
                  seeds: Sequence[int], overall: str | None = None, sample_action: SampleFn | None = None,
                  key: jax.Array | None = None, memory: PolicyMemory | None = None) -> dict[str, Any]:
    """Every real (layout, item) episode of every set, for every seed (leading axis of ``network_params``).

    The sets are padded to one item capacity and concatenated into one pool, and
    only real episodes are run: one compiled program for everything, a batched loop per set. Returns
    ``{set name: {description, layouts, **episode_stats, per_seed: [...]}}``, plus
    the statistics of all sets' episodes together under ``overall`` if given.
    ``sample_action`` and ``key``: the sampled policy instead of the greedy one
    (:func:`run_episodes`; every seed's policy meets the same draws); ``memory``: the
    algorithm's :meth:`policy_memory`, the same episodes computed more cheaply.
    """
    if not sets:
        raise ValueError("evaluate_sets needs at least one set of layouts")
    for layout_set in sets:
        if layout_set.layouts.max_shape != env.max_shape:
            raise ValueError(f"set {layout_set.name!r} is padded to {layout_set.layouts.max_shape}, "
                             f"the environment observes {env.max_shape}")
    capacity = max(layout_set.layouts.max_items for layout_set in sets)
    batch = jax.tree.map(lambda *leaves: jnp.concatenate(leaves),
                         *[pad_items(layout_set.layouts, capacity) for layout_set in sets])
    pool = jax.jit(pool_of)(batch)
    num_items = np.asarray(batch.num_items)
    slots, items = np.nonzero(np.arange(capacity)[None, :] < num_items[:, None])
    eval_params = env.with_pool(params, pool)
    set_of_layout = np.repeat(np.arange(len(sets)), [layout_set.size for layout_set in sets])[slots]
    bounds = np.searchsorted(set_of_layout, np.arange(len(sets) + 1))  # each set's episodes, in order

    def run_sets(net, params, slot, item):
        # One loop per set, one after the other: a loop lasts as long as its longest episode, and the
        # long-route sets would otherwise keep every other set's finished episodes stepping.
        parts = [run_episodes(greedy_action, net, env, params, slot[lo:hi], item[lo:hi], sample_action,
                              key, memory, episode_offset=int(lo))
                 for lo, hi in zip(bounds[:-1], bounds[1:]) if hi > lo]
        return jax.tree.map(lambda *x: jnp.concatenate(x), *parts)

    program = jax.jit(jax.vmap(run_sets, in_axes=(0, None, None, None)))
    outcome = jax.tree.map(np.asarray, program(
        network_params, eval_params, jnp.asarray(slots, jnp.int32), jnp.asarray(items, jnp.int32)))

    def entry(mine: np.ndarray, description: str, layouts: int) -> dict[str, Any]:
        stats = episode_stats(*(x[:, mine].reshape(-1) for x in outcome))
        per_seed = [{"seed": int(seed), **episode_stats(*(x[i, mine] for x in outcome))}
                    for i, seed in enumerate(seeds)]
        return {"description": description, "layouts": layouts, **stats, "per_seed": per_seed}

    report = {layout_set.name: entry(set_of_layout == index, layout_set.description, layout_set.size)
              for index, layout_set in enumerate(sets)}
    if overall is not None:
        report[overall] = entry(np.ones_like(set_of_layout, dtype=bool), "every set together",
                                sum(layout_set.size for layout_set in sets))
    return report


def final_report(context: FinalContext) -> dict[str, Any]:
    """The generalization measurement after training: ``{"heldout": ..., "ood": {set: ...}, ...}`` (host, once).

    Every seed's greedy policy on the held-out set (:func:`heldout_set`) and on
    :func:`ood_sets`, in one program (:func:`evaluate_sets`); for a stochastic policy (PPO)
    also its sampled policy on the held-out set (``heldout_sampled``, draws from
    :data:`EVAL_SEED`); ``final_report_seconds`` is its cost (generation, compilation and
    the episodes).
    """
    tic = time.perf_counter()
    env, params = context.env, context.params
    seen = env.training_layout_hashes(params, context.updates_done)
    heldout, overlap = heldout_set(env.generator, seen)
    sets = [heldout, *ood_sets(env.generator)]
    memory = context.algo.policy_memory()
    report = evaluate_sets(context.algo.greedy_action, context.network_params, env, params, sets, context.seeds,
                           memory=memory)
    result = {"heldout": {**report.pop("heldout"), "overlap_with_training": overlap},
              "training_layouts": int(seen.size), "ood": report}
    if context.algo.has_stochastic_policy:
        sampled = evaluate_sets(context.algo.greedy_action, context.network_params, env, params, [heldout],
                                context.seeds, sample_action=context.algo.sample_action,
                                key=jax.random.fold_in(jax.random.key(EVAL_SEED), 5), memory=memory)
        result["heldout_sampled"] = sampled["heldout"]
    return {**result, "final_report_seconds": time.perf_counter() - tic}


EVALUATION = FamilyEvaluation(
    evaluate_policy=evaluate_policy,
    seed_summary=seed_summary,
    solved_key="eval_solved",
    solved_definition="env steps per seed at the first periodic greedy evaluation delivering every held-out "
                      "(layout, item) episode at its BFS optimum",
    summarize=summarize,
    format_report=format_report,
    format_details=format_details,
    progress_metric=("eval_success_rate", "held-out delivered"),
    train_rates=(TrainRate("delivery_rate", "delivery rate (training episodes)", "terminated",
                           progress="delivered"),),
    final_report=final_report,
    # A sweep reads the periodic evaluation after the last update (EVAL_LAYOUTS held-out layouts).
    sweep_columns=SweepColumns(
        metrics=(
            SweepMetric("success_rate", "held-out delivered", "percent", plot="held-out episodes delivered (%)"),
            SweepMetric("optimal_rate", "at the BFS optimum", "percent", plot="at the BFS optimum (%)"),
            SweepMetric("all_optimal", "seeds all-optimal", "solved"),
            SweepMetric("mean_excess", "mean excess steps (delivered)", digits=2,
                        plot="mean steps over the optimum (delivered)"),
            SweepMetric("collisions_per_episode", "collisions / episode", digits=2),
        ),
        train=(
            SweepMetric("delivery_rate", "train delivery (last log)", "percent"),
            SweepMetric("mean_return", "train return (last log)", table=False, aggregate=False),
        ),
        convergence_label="first optimal step",
    ),
)
