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
  ``python -m wrl_jax.evaluate``): ``FINAL_HELDOUT_LAYOUTS`` (1,024) held-out
  layouts, checked by hash against the training pool (any shared layout is
  dropped and counted), and out-of-distribution sets (:func:`ood_sets`):
  denser obstacle floors than training, full shelf floors at the maximum shape
  with one-cell aisles, the study's 8x8 and 12x12 maps padded, and a MovingAI
  ``.map`` warehouse (:data:`MOVINGAI_WAREHOUSE`) with drawn cells. All sets
  are padded to one item capacity and run as ONE batch of episodes (one
  compiled program, every seed at once); results are split per set and seed.

:func:`evaluate_layouts` runs the same measurement on any given layouts (the
``--layout`` files of ``python -m wrl_jax.evaluate``).

Why one module of this length: the periodic, final and file evaluations are one
measurement (the same episode, rates and tables) on three sets of layouts, and
read best beside the sets they run on.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from wrl_jax.envs.procedural.layout import PaddedLayout, from_layout, stack
from wrl_jax.envs.procedural.movingai import is_movingai, load_map, movingai_layout, parse_movingai
from wrl_jax.envs.procedural.pool import LayoutPool, disjoint_from, generate_pool, pool_hashes, pool_of
from wrl_jax.envs.warehouse.layout import parse
from wrl_jax.envs.warehouse.maps import WAREHOUSE_8X8, WAREHOUSE_12X12
from wrl_jax.core.evaluation import FamilyEvaluation, FinalContext, SweepColumns, SweepMetric

EVAL_SEED = 2026
EVAL_LAYOUTS = 64
FINAL_HELDOUT_LAYOUTS = 1024
"""Held-out layouts of the final evaluation (the key stream of ``fold_in(key(EVAL_SEED), 1)``)."""
OOD_LAYOUTS = 256
"""Layouts of each generated out-of-distribution set."""
MOVINGAI_DRAWS = 32
"""Start, goal and item placements drawn on :data:`MOVINGAI_WAREHOUSE` (one layout each)."""
GreedyFn = Callable[[Any, jax.Array], jax.Array]
SampleFn = Callable[[Any, jax.Array, jax.Array], jax.Array]

MOVINGAI_WAREHOUSE = """type octile
height 15
width 16
map
................
.@@@@@@..@@@@@@.
.@@@@@@..@@@@@@.
................
.@@@@@@..@@@@@@.
.@@@@@@..@@@@@@.
................
.@@@@@@..@@@@@@.
.@@@@@@..@@@@@@.
................
..TT........TT..
................
.@@@@@@@@@@@@@@.
................
................
"""
"""A small warehouse in MovingAI's format (15x16: four double-depth shelf rows, pillars ``T``, a long rack).

Written here rather than downloaded (MovingAI's warehouse maps are far larger than a 16x16 policy can see).
"""


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
                 key: jax.Array | None = None) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """Greedy episodes ``(slot, item)`` of ``params``' pool: ``(delivered, steps, optimum, collisions)`` (jittable).

    One batched ``lax.while_loop`` over all episodes, stopping when every one has
    delivered or reached ``params.max_steps``; ``env.transition`` (no auto-reset).
    With ``sample_action`` and ``key``, the policy's actions are drawn instead:
    episode ``e`` draws step ``t``'s action from ``fold_in(fold_in(key, e), t)``.
    """
    sampled = sample_action is not None
    if sampled and key is None:
        raise ValueError("sampled episodes need a key")

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

    return jax.vmap(episode)(slots, items, jnp.arange(slots.shape[0], dtype=jnp.int32))


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


# ------------------------------------------------------------------ episode statistics
def _number(value: float) -> float | None:
    """A JSON-safe float: ``None`` for NaN (no delivered episode to average over)."""
    value = float(value)
    return None if math.isnan(value) else value


def episode_stats(delivered: np.ndarray, steps: np.ndarray, optimal: np.ndarray,
                  collisions: np.ndarray) -> dict[str, Any]:
    """The statistics of a set of episodes (1-D arrays), as plain Python numbers (``None`` where undefined).

    ``mean_steps``, ``mean_optimal``, ``mean_excess`` and ``excess_fraction`` are
    over the delivered episodes (an undelivered episode has no route length to
    compare); ``bfs_optimum`` is the mean optimum of all episodes, the yardstick
    of the set; ``excess_fraction = mean_excess / mean_optimal``;
    ``mean_excess_fraction_per_episode`` is the mean of each episode's own fraction.
    """
    delivered = np.asarray(delivered, dtype=bool)
    steps, optimal = np.asarray(steps, dtype=np.float64), np.asarray(optimal, dtype=np.float64)
    collisions = np.asarray(collisions, dtype=np.float64)
    episodes = int(delivered.size)
    if episodes == 0:
        raise ValueError("episode_stats needs at least one episode")
    won = delivered.sum()
    excess = steps[delivered] - optimal[delivered]
    mean_optimal = optimal[delivered].mean() if won else math.nan
    return {
        "episodes": episodes,
        "delivery_rate": float(won / episodes),
        "optimal_rate": float((delivered & (steps == optimal)).sum() / episodes),
        "mean_steps": _number(steps[delivered].mean() if won else math.nan),
        "mean_optimal": _number(mean_optimal),
        "bfs_optimum": float(optimal.mean()),
        "mean_excess": _number(excess.mean() if won else math.nan),
        "excess_fraction": _number(excess.mean() / mean_optimal if won else math.nan),
        "mean_excess_fraction_per_episode": _number((excess / optimal[delivered]).mean() if won else math.nan),
        "collisions_per_episode": float(collisions.mean()),
        "collision_free_rate": float((collisions == 0).mean()),
    }


# ------------------------------------------------------------------ sets of layouts
@dataclasses.dataclass(frozen=True)
class LayoutSet:
    """A named batch of layouts to evaluate on (``layouts``: a :class:`PaddedLayout` with a leading axis)."""

    name: str
    description: str
    layouts: PaddedLayout

    @property
    def size(self) -> int:
        return int(self.layouts.num_items.shape[0])


def pad_items(layouts: PaddedLayout, capacity: int) -> PaddedLayout:
    """A batch of layouts with ``capacity`` item rows (extra rows repeat item 0, as padding items do)."""
    extra = capacity - layouts.max_items
    if extra < 0:
        raise ValueError(f"layouts hold {layouts.max_items} item rows, more than the capacity {capacity}")
    if extra == 0:
        return layouts
    filler = jnp.repeat(layouts.items[:, :1], extra, axis=1)
    return layouts.replace(items=jnp.concatenate([layouts.items, filler], axis=1))


STUDY_MAPS = {"8x8": WAREHOUSE_8X8, "12x12": WAREHOUSE_12X12}


def study_layout(name: str, max_shape: tuple[int, int]) -> PaddedLayout:
    """The study's ``"8x8"`` or ``"12x12"`` map padded to ``max_shape``, every one of its items."""
    if name not in STUDY_MAPS:
        raise ValueError(f"unknown study map {name!r}; expected one of {sorted(STUDY_MAPS)}")
    return from_layout(parse(STUDY_MAPS[name]), max_shape)


def movingai_layouts(max_shape: tuple[int, int], draws: int | None = None, num_items: int = 8) -> PaddedLayout:
    """``draws`` (:data:`MOVINGAI_DRAWS`) placements of start, goal and items on :data:`MOVINGAI_WAREHOUSE`, padded."""
    draws = MOVINGAI_DRAWS if draws is None else int(draws)
    blocked = parse_movingai(MOVINGAI_WAREHOUSE, "MOVINGAI_WAREHOUSE")
    key = jax.random.fold_in(jax.random.key(EVAL_SEED), 2)
    return stack([movingai_layout(blocked, max_shape=max_shape, max_items=num_items, num_items=num_items,
                                  key=jax.random.fold_in(key, draw), source="MOVINGAI_WAREHOUSE")
                  for draw in range(draws)])


def ood_sets(generator, ood_layouts: int | None = None) -> list[LayoutSet]:
    """The out-of-distribution sets for a policy trained on ``generator``'s layouts (skipping what does not fit).

    - ``dense``: obstacle floors of a density above the training range (its top to 10 points over it);
    - ``narrow_shelves``: shelf floors at the maximum shape, one-cell aisles, no knocked-out shelves;
    - ``study_8x8``, ``study_12x12``: the study's maps, padded, every item;
    - ``movingai``: :data:`MOVINGAI_WAREHOUSE` with :data:`MOVINGAI_DRAWS` drawn placements.
    """
    ood_layouts = OOD_LAYOUTS if ood_layouts is None else int(ood_layouts)
    key = jax.random.fold_in(jax.random.key(EVAL_SEED), 3)
    top = generator.density[1]
    dense = dataclasses.replace(generator, family="obstacles", density=(top, min(top + 0.1, 0.95)))
    narrow = dataclasses.replace(generator, family="shelves", min_shape=generator.max_shape, aisle=(1, 1),
                                 gap_rate=(0.0, 0.0))
    sets = [
        LayoutSet("dense", f"obstacle floors, density {dense.density[0]:.2f}..{dense.density[1]:.2f} "
                           f"(training {generator.density[0]:.2f}..{top:.2f})",
                  generate_pool(jax.random.fold_in(key, 0), ood_layouts, dense, stream="heldout").layouts),
        LayoutSet("narrow_shelves", f"shelf floors at {generator.max_shape[0]}x{generator.max_shape[1]}, "
                                    "one-cell aisles, no gaps",
                  generate_pool(jax.random.fold_in(key, 1), ood_layouts, narrow, stream="heldout").layouts),
    ]
    height, width = generator.max_shape
    for name, side in (("8x8", 8), ("12x12", 12)):
        if side <= min(height, width):
            sets.append(LayoutSet(f"study_{name}", f"the study's {name} map, padded, every item",
                                  stack([study_layout(name, generator.max_shape)])))
    rows, cols = parse_movingai(MOVINGAI_WAREHOUSE).shape
    if rows <= height and cols <= width:
        items = min(generator.max_items, 8)
        placements = movingai_layouts(generator.max_shape, num_items=items)
        sets.append(LayoutSet("movingai", f"a {rows}x{cols} MovingAI .map warehouse, {placements.num_items.shape[0]} "
                                          f"drawn placements of start, goal and {items} items", placements))
    return sets


def evaluate_sets(greedy_action: GreedyFn, network_params: Any, env, params, sets: Sequence[LayoutSet],
                  seeds: Sequence[int], overall: str | None = None, sample_action: SampleFn | None = None,
                  key: jax.Array | None = None) -> dict[str, Any]:
    """Every real (layout, item) episode of every set, for every seed (leading axis of ``network_params``).

    The sets are padded to one item capacity and concatenated into one pool, and
    only real episodes are run: one compiled program for everything. Returns
    ``{set name: {description, layouts, **episode_stats, per_seed: [...]}}``, plus
    the statistics of all sets' episodes together under ``overall`` if given.
    ``sample_action`` and ``key``: the sampled policy instead of the greedy one
    (:func:`run_episodes`; every seed's policy meets the same draws).
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
    program = jax.jit(jax.vmap(lambda net, params, slot, item: run_episodes(
        greedy_action, net, env, params, slot, item, sample_action, key), in_axes=(0, None, None, None)))
    delivered, steps, optimal, collisions = jax.tree.map(np.asarray, program(
        network_params, eval_params, jnp.asarray(slots, jnp.int32), jnp.asarray(items, jnp.int32)))
    set_of_layout = np.repeat(np.arange(len(sets)), [layout_set.size for layout_set in sets])[slots]
    outcome = (delivered, steps, optimal, collisions)

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


def layout_file_sets(paths: Sequence[str], max_shape: tuple[int, int], num_items: int = 8) -> list[LayoutSet]:
    """One :class:`LayoutSet` per map file, padded to ``max_shape`` (the run's observation), checked.

    ASCII maps carry their start, goal and items; a MovingAI map gets ``num_items``
    items (fewer if it is small) and a start and goal drawn from a fixed key.

    Raises:
        ValueError: naming the file: a missing file, a malformed map, or a floor
            larger than ``max_shape``, which the run's observation cannot represent.
    """
    sets = []
    for index, name in enumerate(paths):
        path = Path(name)
        if not path.is_file():
            raise ValueError(f"--layout {path}: no such file")
        text = path.read_text()
        try:
            if is_movingai(path, text):
                blocked = parse_movingai(text, str(path))
                if blocked.shape[0] > max_shape[0] or blocked.shape[1] > max_shape[1]:
                    raise ValueError(f"{path} is {blocked.shape[0]}x{blocked.shape[1]}, larger than max_shape "
                                     f"{max_shape[0]}x{max_shape[1]}")
                items = max(1, min(num_items, int((~blocked).sum()) - 2))
                layout = load_map(path, max_shape=max_shape, max_items=items, num_items=items,
                                  key=jax.random.fold_in(jax.random.key(EVAL_SEED), 4))
            else:
                layout = load_map(path, max_shape=max_shape)
        except ValueError as error:
            message = str(error)
            if "larger than max_shape" in message:
                message += (f"; the run's observation covers floors of at most {max_shape[0]}x{max_shape[1]} "
                            "(its environment's padded shape)")
            raise ValueError(message if str(path) in message else f"{path}: {message}") from None
        sets.append(LayoutSet(str(path) if str(path) not in {s.name for s in sets} else f"{path}#{index}",
                              f"{'MovingAI' if is_movingai(path, text) else 'ASCII'} map, "
                              f"{int(layout.height)}x{int(layout.width)}, {int(layout.num_items)} items",
                              stack([layout])))
    return sets


def heldout_set(generator, training: LayoutPool | np.ndarray, count: int | None = None) -> tuple[LayoutSet, int]:
    """``(set, overlap)``: ``count`` (:data:`FINAL_HELDOUT_LAYOUTS`) held-out layouts minus any training saw.

    ``training``: the training pool, or the hashes of every layout training saw (a refreshed pool:
    :meth:`~wrl_jax.envs.procedural.env.ProceduralWarehouse.training_layout_hashes`). ``overlap``
    counts the generated layouts whose hash is among them (dropped).
    """
    count = FINAL_HELDOUT_LAYOUTS if count is None else int(count)
    pool = generate_pool(jax.random.fold_in(jax.random.key(EVAL_SEED), 1), count, generator, stream="heldout")
    seen = pool_hashes(training) if isinstance(training, LayoutPool) else np.asarray(training, dtype=np.uint64)
    keep = disjoint_from(pool, seen)
    layouts = jax.tree.map(lambda leaf: leaf[np.flatnonzero(keep)], pool.layouts)
    overlap = int((~keep).sum())
    return LayoutSet("heldout", f"{int(keep.sum())} held-out layouts of the training generator "
                                f"(key stream disjoint from training; {overlap} shared by hash, dropped)",
                     layouts), overlap


def final_report(context: FinalContext) -> dict[str, Any]:
    """The generalization measurement after training: ``{"heldout": ..., "ood": {set: ...}, ...}`` (host, once).

    Every seed's greedy policy on the held-out set (:func:`heldout_set`) and on
    :func:`ood_sets`, in one batch (:func:`evaluate_sets`); for a stochastic policy (PPO)
    also its sampled policy on the held-out set (``heldout_sampled``, draws from
    :data:`EVAL_SEED`); ``final_report_seconds`` is its cost (generation, compilation and
    the episodes).
    """
    tic = time.perf_counter()
    env, params = context.env, context.params
    seen = env.training_layout_hashes(params, context.updates_done)
    heldout, overlap = heldout_set(env.generator, seen)
    sets = [heldout, *ood_sets(env.generator)]
    report = evaluate_sets(context.algo.greedy_action, context.network_params, env, params, sets, context.seeds)
    result = {"heldout": {**report.pop("heldout"), "overlap_with_training": overlap},
              "training_layouts": int(seen.size), "ood": report}
    if context.algo.has_stochastic_policy:
        sampled = evaluate_sets(context.algo.greedy_action, context.network_params, env, params, [heldout],
                                context.seeds, sample_action=context.algo.sample_action,
                                key=jax.random.fold_in(jax.random.key(EVAL_SEED), 5))
        result["heldout_sampled"] = sampled["heldout"]
    return {**result, "final_report_seconds": time.perf_counter() - tic}


# ------------------------------------------------------------------ reports
AIM_DELIVERY = 0.99
AIM_EXCESS = 0.05
"""The generalization aim on held-out layouts: at least 99 % delivered, at most 5 % mean excess over the optimum."""


def seeds_at_aim(entry: dict[str, Any]) -> int:
    """Seeds of a final-report set entry at :data:`AIM_DELIVERY` and :data:`AIM_EXCESS` or better."""
    return sum(1 for row in entry["per_seed"] if row["delivery_rate"] >= AIM_DELIVERY
               and row["excess_fraction"] is not None and row["excess_fraction"] <= AIM_EXCESS)


def _seeds_at_aim(entry: dict[str, Any]) -> str:
    return f"{seeds_at_aim(entry)} of {len(entry['per_seed'])}"


def _percent(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.1%}"


def _steps(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.2f}"


def format_report(summary: dict[str, Any], label: str, convergence_steps: Sequence[int | None] | None = None,
                  study: dict[str, str] | None = None) -> str:
    """A Markdown table of the periodic held-out evaluation, then the final held-out set's headline if present."""
    del study
    rows = [
        ("held-out layouts x items", f"{summary['eval_layouts']} layouts, {summary['episodes_per_seed']} episodes"),
        ("delivered", f"{summary['success_rate']:.1%}"),
        ("at the BFS optimum", f"{summary['optimal_rate']:.1%}"),
        ("mean steps over the optimum (delivered)", f"{summary['mean_excess']:.2f}"),
        ("collisions per episode", f"{summary['collisions_per_episode']:.2f}"),
    ]
    heldout = summary.get("heldout")
    if heldout:
        rows += [
            (f"final: {heldout['layouts']} held-out layouts, delivered", _percent(heldout["delivery_rate"])),
            ("final: mean excess over the optimum",
             f"{_steps(heldout['mean_excess'])} steps ({_percent(heldout['excess_fraction'])})"),
            ("final: seeds at >= 99% delivered and <= 5% excess", _seeds_at_aim(heldout)),
        ]
    sampled = summary.get("heldout_sampled")
    if sampled:
        rows += [
            ("final, sampled policy: delivered / excess",
             f"{_percent(sampled['delivery_rate'])} / {_percent(sampled['excess_fraction'])}"),
            ("final, sampled policy: seeds at >= 99% delivered and <= 5% excess", _seeds_at_aim(sampled)),
        ]
    if convergence_steps is not None:
        solved = [step for step in convergence_steps if step is not None]
        rows.append(("seeds solved", f"{len(solved)} of {len(convergence_steps)}"))
    lines = [f"| {label} | |", "|---|---|", *(f"| {name} | {value} |" for name, value in rows)]
    return "\n".join(lines)


def format_sets(report: dict[str, dict[str, Any]]) -> str:
    """Markdown: one row per set (all seeds), then one row per set with each seed's delivered / excess."""
    if not report:
        return ""
    header = ("| set | layouts | episodes/seed | delivered | at optimum | mean excess (steps) | excess | "
              "collisions/episode |")
    lines = [header, "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for name, row in report.items():
        per_seed_episodes = row["episodes"] // max(len(row["per_seed"]), 1)
        lines.append(f"| {name} | {row['layouts']} | {per_seed_episodes} | {_percent(row['delivery_rate'])} | "
                     f"{_percent(row['optimal_rate'])} | {_steps(row['mean_excess'])} | "
                     f"{_percent(row['excess_fraction'])} | {row['collisions_per_episode']:.3f} |")
    seeds = [entry["seed"] for entry in next(iter(report.values()))["per_seed"]]
    lines += ["", "| set (per seed: delivered / excess) | " + " | ".join(f"seed {seed}" for seed in seeds) + " |",
              "|---|" + "---:|" * len(seeds)]
    for name, row in report.items():
        cells = [f"{_percent(entry['delivery_rate'])} / {_percent(entry['excess_fraction'])}"
                 for entry in row["per_seed"]]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_details(summary: dict[str, Any]) -> str:
    """The final report's sets (held-out, then out-of-distribution) as Markdown tables; empty without one."""
    if "heldout" not in summary:
        return ""
    report = {"heldout": summary["heldout"], **summary.get("ood", {})}
    if "heldout_sampled" in summary:  # the sampled policy's row (PPO), beside the greedy ones
        report["heldout (sampled policy)"] = summary["heldout_sampled"]
    seconds = summary.get("final_report_seconds")
    lines = ["Greedy policy of every seed (the sampled policy's row: actions drawn from it), every real (layout, "
             "item) episode; excess is over delivered episodes, as a fraction of their mean BFS optimum."
             + (f" Final evaluation: {seconds:.1f} s." if seconds is not None else ""), "", format_sets(report), ""]
    lines += [f"- `{name}`: {row['description']}" for name, row in report.items()]
    return "\n".join(lines)


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
