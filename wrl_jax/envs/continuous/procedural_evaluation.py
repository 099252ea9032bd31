"""Evaluating a policy of the procedural continuous warehouse: on pool layouts while it trains, and on
layouts it never saw afterwards (the generalization measurement).

- **Periodic** (the family hook's ``evaluate_policy`` comes here, :func:`evaluate_pool_sample`): the first
  :data:`EVAL_POOL_LAYOUTS` pool slots (the pool holds independent draws, so its first slots are a
  uniform sample of it), every item, ``rounds(env)`` rounds, from fixed keys. A seed has *solved* when
  every one of these episodes delivers without a contact: the training task, not generalization.
- **Final** (:func:`final_report`, run once after training): the grid family's held-out set
  (:func:`~wrl_jax.envs.procedural.layout_sets.heldout_set`: its own key stream, checked by hash
  against the pool) and its out-of-distribution sets (denser floors, narrow aisles, the study's maps
  padded), every real (layout, item) pair for ``rounds(env)`` rounds, every seed in one compiled
  program (:func:`evaluate_layout_sets`); per set the continuous summary: delivery rate, steps of
  delivered episodes, collisions per episode, collision-free rate, return, per seed; and beside it the
  pure-pursuit controller on the same episodes (each layout's plan made on the host, :func:`pursuit_plans`)
  and, without randomization, the lower bound: what a planner does on layouts the policy never saw.

Episodes run on the plain environment with the layout's params (``episode_start`` and ``episode_step`` of
:mod:`~wrl_jax.envs.continuous.evaluation`), so they are the episodes the plain hook would run there.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.core.evaluation import number_text as _num
from wrl_jax.core.evaluation import percent_text as _pct
from wrl_jax.envs.continuous.evaluation import (EVAL_SEED, PURSUIT_FIELDS, ContinuousEval, contract_env, rounds,
                                                episode_start, episode_step, run_episodes, summarize)
from wrl_jax.envs.continuous.procedural_layouts import layout_params, pool_size, with_pool
from wrl_jax.envs.procedural.layout_sets import LayoutSet, heldout_set, ood_sets, pad_items

EVAL_POOL_LAYOUTS = 16
"""Pool slots of the periodic evaluation (all of a smaller pool)."""
HELDOUT_LAYOUTS = 256
"""Held-out layouts of the final report (drawn before the ones the pool shares by hash are dropped)."""
OOD_LAYOUTS = 64
"""Layouts of each generated out-of-distribution set of the final report."""

Act = Callable[[jax.Array, Any], jax.Array]
GreedyFn = Callable[[Any, jax.Array], jax.Array]


def evaluate_pool_sample(act: Act, env, params, count: int | None = None) -> ContinuousEval:
    """``act(obs, state)`` on every (slot, round, item) of the first ``count`` pool slots (jittable).

    Leaves ``(count, rounds, I)``; ``valid`` masks item rows past each layout's ``num_items``. The
    episodes are :func:`run_pairs`'s, from fixed keys: the same at every evaluation, for every seed.
    """
    count = min(EVAL_POOL_LAYOUTS, pool_size(params)) if count is None else int(count)
    shape = (count, rounds(env), int(params.pool.items.shape[-2]))
    slots, round_of, items = (jnp.asarray(a.reshape(-1), jnp.int32) for a in np.indices(shape))
    delivered, steps, ret, collisions, pickup_step = (
        x.reshape(shape) for x in run_pairs(act, env, params, slots, items, round_of))
    valid = (items < params.pool.num_items[slots]).reshape(shape)
    return ContinuousEval(valid=valid, delivered=delivered & valid, steps=steps, episode_return=ret,
                          collisions=collisions, pickup_step=pickup_step)


def run_pairs(act: Act | None, env, params, slots: jax.Array, items: jax.Array, rounds_of: jax.Array,
              plans: Any = None, controller_env: Any = None) -> tuple:
    """Episodes ``(slot, item, round)`` of ``params``' pool, all at once: ``run_episodes``' outputs ``(E,)``.

    ``act(obs, state)`` is a policy on ``env.plain``; with ``act=None`` the pure-pursuit controller drives
    ``controller_env`` (:func:`~wrl_jax.envs.continuous.evaluation.contract_env`) instead, each episode on its
    slot's plan (``plans``: :func:`pursuit_plans` of every pool slot). Episode keys are ``fold_in`` of
    :data:`EVAL_SEED` with the slot, the item and the round, the same for both (jittable).
    """
    from wrl_jax.envs.continuous.pursuit import PursuitConfig, pursuit_act, pursuit_init

    if act is None and (plans is None or controller_env is None):
        raise ValueError("run_pairs: the controller (act=None) needs plans and controller_env")
    root = jax.random.PRNGKey(EVAL_SEED)

    def episode(slot, item):  # the policy (or the slot's controller), its environment and the slot's params
        layout = layout_params(params, slot)
        if act is not None:
            return act, env.plain, layout, None
        plan = jax.tree.map(lambda leaf: leaf[slot], plans)
        drive = lambda obs, state, control: pursuit_act(plan, control, state, layout, PursuitConfig())  # noqa: E731
        return drive, controller_env, layout, lambda state: pursuit_init(plan, state)

    def begin(slot, item, round_index):
        key = jax.random.fold_in(jax.random.fold_in(jax.random.fold_in(root, slot), item), round_index)
        policy, episode_env, layout, start = episode(slot, item)
        return episode_start(policy, episode_env, layout, key, item, start)

    def step(carry, slot, item, round_index):
        policy, episode_env, layout, start = episode(slot, item)
        return episode_step(policy, episode_env, layout, carry, start)

    return run_episodes(begin, step, (slots, items, rounds_of))


def pursuit_plans(params, slots: np.ndarray) -> tuple[Any, np.ndarray]:
    """``(plans, bounds)`` for the pool slots ``slots``: the pursuit plans, padded to one shape and stacked
    (item rows past a layout's count far away, so the controller never takes one for its item), and each
    (slot, item)'s lower bound in steps, ``(len(slots), I)`` with NaN past the layout's items. Host NumPy
    throughout (no program per layout): about 70 ms a layout on the 2-core development CPU.

    Raises:
        ValueError: from :func:`~wrl_jax.envs.continuous.pursuit.make_plan` (a robot too wide for its margin).
    """
    from wrl_jax.envs.continuous.pursuit import make_plan
    from wrl_jax.envs.continuous.yardstick import item_bounds

    def centre(cells: np.ndarray) -> np.ndarray:  # layout_params' points, in NumPy: (col + 0.5, row + 0.5)
        return (cells[..., ::-1] + 0.5).astype(np.float32)

    pool = jax.tree.map(np.asarray, params.pool)
    capacity = int(pool.items.shape[-2])
    plans, bounds = [], np.full((len(slots), capacity), np.nan)
    for row, slot in enumerate(slots):
        layout = params.replace(shelves=pool.blocked[slot], start=centre(pool.start[slot]), goal=centre(pool.goal[slot]),
                                items=centre(pool.items[slot]), num_items=pool.num_items[slot])
        plans.append(jax.tree.map(np.asarray, make_plan(layout)))
        bounds[row, : int(layout.num_items)] = item_bounds(layout)["steps"]
    size = max(plan.points.shape[2] for plan in plans)

    def padded(plan):
        more, items = size - plan.points.shape[2], capacity - plan.items.shape[0]
        points = np.concatenate([plan.points, np.repeat(plan.points[:, :, -1:], more, 2)], 2)
        cumlen = np.concatenate([plan.cumlen, np.repeat(plan.cumlen[:, :, -1:], more, 2)], 2)
        return plan.replace(points=np.pad(points, ((0, items), (0, 0), (0, 0), (0, 0))),
                            cumlen=np.pad(cumlen, ((0, items), (0, 0), (0, 0))),
                            items=np.pad(plan.items, ((0, items), (0, 0)), constant_values=1e6))

    return jax.tree.map(lambda *leaves: jnp.asarray(np.stack(leaves)), *[padded(plan) for plan in plans]), bounds


def evaluate_layout_sets(greedy_action: GreedyFn, network_params: Any, env, params, sets: Sequence[LayoutSet],
                         seeds: Sequence[int], yardstick: bool = True, overall: str | None = None) -> dict[str, Any]:
    """Every seed's greedy policy (leading axis of ``network_params``) on every real (layout, item) of ``sets``.

    The sets are padded to one item capacity and run as one pool, in one compiled program. With
    moving obstacles, a layout with fewer eligible cells than the obstacles is left out (counted in
    ``excluded_layouts``). Returns ``{set name: summary}``, each :func:`evaluation.summarize`'s
    numbers (``success_rate``, ``mean_steps``, ``collisions_per_episode``, ``collision_free_rate``,
    ``mean_return``, ``per_seed``) with ``description``, ``layouts``, ``excluded_layouts``,
    ``episodes_per_seed`` and ``rounds``; under ``yardstick`` also ``pursuit`` (the controller on the same
    episodes: ``success_rate``, ``mean_steps``, ``collisions_per_episode``, ``collision_free_rate``) and,
    without randomization, ``bound_steps`` (the lower bound's mean over the set's episodes). With ``overall``, the
    same numbers over every set's episodes together under that name (``description`` "every set together").

    Raises:
        ValueError: no sets, or a set padded to another shape than the environment's map.
    """
    if not sets:
        raise ValueError("evaluate_layout_sets needs at least one set of layouts")
    for layout_set in sets:
        if layout_set.layouts.max_shape != (env.height, env.width):
            raise ValueError(f"set {layout_set.name!r} is padded to {layout_set.layouts.max_shape}, the "
                             f"environment's map is {(env.height, env.width)}")
    capacity = max(layout_set.layouts.max_items for layout_set in sets)
    batch = jax.tree.map(lambda *leaves: jnp.concatenate(leaves),
                         *[pad_items(layout_set.layouts, capacity) for layout_set in sets])
    eval_params = with_pool(params, batch)
    usable = np.asarray(eval_params.pool_obstacle_cells.sum(axis=(1, 2))) >= env.num_obstacles
    real = np.arange(capacity)[None, :] < np.asarray(batch.num_items)[:, None]
    slots, items = np.nonzero(real & usable[:, None])
    num_rounds = rounds(env)
    slots, items = np.repeat(slots, num_rounds), np.repeat(items, num_rounds)
    round_of = np.tile(np.arange(num_rounds), slots.size // num_rounds)

    def seed_episodes(net, params, slots, items, round_of):
        return run_pairs(lambda obs, state: greedy_action(net, obs), env, params, slots, items, round_of)

    program = jax.jit(jax.vmap(seed_episodes, in_axes=(0, None, None, None, None)))
    outcome = program(network_params, eval_params, *(jnp.asarray(a, jnp.int32) for a in (slots, items, round_of)))
    delivered, steps, ret, collisions, pickup_step = (np.asarray(x) for x in outcome)
    set_of_slot = np.repeat(np.arange(len(sets)), [layout_set.size for layout_set in sets])
    unavailable = None
    if yardstick:
        try:
            plans, bounds = pursuit_plans(eval_params, np.arange(set_of_slot.size))
        except ValueError as error:  # after training: say why, do not lose the run's report
            yardstick, unavailable = False, str(error)
    if yardstick:
        pairs = (jnp.asarray(a, jnp.int32) for a in (slots, items, round_of))
        driven = [np.asarray(x) for x in _pursuit_pairs(contract_env(env.plain, env.default_params), eval_params,
                                                        plans, *pairs)]
        randomized = bool(params.randomize)
    groups = [(layout_set.name, layout_set.description, set_of_slot == index) for index, layout_set in enumerate(sets)]
    if overall is not None:
        groups.append((overall, "every set together", np.ones(set_of_slot.size, bool)))
    report = {}
    for name, description, members in groups:  # members: the group's slots
        mine = members[slots]
        if not mine.any():
            report[name] = {"description": description, "layouts": 0, "excluded_layouts": int(members.sum()),
                            "episodes_per_seed": 0}
            continue
        result = ContinuousEval(valid=np.ones_like(delivered[:, None, mine]), delivered=delivered[:, None, mine],
                                steps=steps[:, None, mine], episode_return=ret[:, None, mine],
                                collisions=collisions[:, None, mine], pickup_step=pickup_step[:, None, mine])
        summary = summarize(result, seeds)
        for key in ("num_items", "rounds", "episodes"):
            summary.pop(key)
        excluded = int((~usable[members]).sum())
        report[name] = {"description": description, "layouts": int(members.sum()) - excluded,
                        "excluded_layouts": excluded, "episodes_per_seed": int(mine.sum()), "rounds": num_rounds,
                        **summary}
        if yardstick:
            report[name].update(_yardstick(driven, mine, None if randomized else bounds[slots, items]))
        elif unavailable:
            report[name]["pursuit_unavailable"] = unavailable
    return report


@functools.partial(jax.jit, static_argnames=("controller_env",))
def _pursuit_pairs(controller_env: Any, params: Any, plans: Any, slots: jax.Array, items: jax.Array,
                   rounds_of: jax.Array) -> tuple:
    """:func:`run_pairs` with the controller: one program per contract environment, whatever view trained."""
    return run_pairs(None, None, params, slots, items, rounds_of, plans=plans, controller_env=controller_env)


def _yardstick(driven: list[np.ndarray], mine: np.ndarray, bounds: np.ndarray | None) -> dict[str, Any]:
    """The controller's numbers on a set's episodes (``mine``) and, where it holds, the bound's mean there."""
    delivered, steps, ret, collisions, pickup_step = (x[None, None, mine] for x in driven)
    result = summarize(ContinuousEval(valid=np.ones_like(delivered), delivered=delivered, steps=steps,
                                      episode_return=ret, collisions=collisions, pickup_step=pickup_step))
    out = {"pursuit": {name: result[name] for name in PURSUIT_FIELDS}}
    if bounds is not None:
        out["bound_steps"] = float(bounds[mine].mean())
    return out


def format_layout_sets(report: dict[str, dict[str, Any]]) -> str:
    """Markdown: one row per set of :func:`evaluate_layout_sets` (every seed), the controller beside it and the
    lower bound where it holds (without randomization), then each seed's delivery and contacts per set."""
    if not report:
        return ""
    bound = any("bound_steps" in row for row in report.values())
    lines = ["| set | layouts | episodes/seed | delivered | collisions/episode | collision-free | mean steps | "
             "pursuit, same episodes (delivered, collisions/episode, steps) |" + (" bound (steps) |" if bound else ""),
             "|---|---:|---:|---:|---:|---:|---:|---|" + ("---:|" if bound else "")]
    for name, row in report.items():
        if not row.get("episodes_per_seed"):
            lines.append(f"| {name} | 0 | 0 | left out: fewer free cells than moving obstacles | | | | |"
                         + (" |" if bound else ""))
            continue
        pursuit = row.get("pursuit")
        beside = (f"{_pct(pursuit['success_rate'])}, {pursuit['collisions_per_episode']:.3f}, "
                  f"{_num(pursuit['mean_steps'])}" if pursuit else row.get("pursuit_unavailable", "n/a"))
        lines.append(f"| {name} | {row['layouts']} | {row['episodes_per_seed']} | {_pct(row['success_rate'])} | "
                     f"{row['collisions_per_episode']:.3f} | {_pct(row['collision_free_rate'])} | "
                     f"{_num(row['mean_steps'])} | {beside} |" + (f" {_num(row.get('bound_steps'))} |" if bound else ""))
    measured = {name: row for name, row in report.items() if row.get("episodes_per_seed")}
    if measured:
        seeds = [entry["seed"] for entry in next(iter(measured.values()))["per_seed"]]
        lines += ["", "| set (per seed: delivered / collisions per episode) | "
                  + " | ".join(f"seed {seed}" for seed in seeds) + " |", "|---|" + "---:|" * len(seeds)]
        for name, row in measured.items():
            cells = [f"{_pct(entry['success_rate'])} / {entry['collisions_per_episode']:.3f}" for entry in row["per_seed"]]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def generalization_sets(env, params, heldout_layouts: int | None = None,
                        ood_layouts: int | None = None) -> tuple[list[LayoutSet], int]:
    """``(sets, overlap)``: the held-out set (``overlap`` of its layouts were in the pool, dropped), then
    the out-of-distribution sets that fit the map (generated ones of ``ood_layouts`` layouts each; not the
    grid family's long-route sets)."""
    heldout_layouts = HELDOUT_LAYOUTS if heldout_layouts is None else int(heldout_layouts)
    ood_layouts = OOD_LAYOUTS if ood_layouts is None else int(ood_layouts)
    heldout, overlap = heldout_set(env.generator, env.training_layout_hashes(params), heldout_layouts)
    return [heldout, *ood_sets(env.generator, ood_layouts, long_routes=False)], overlap


def final_report(context, heldout_layouts: int | None = None, ood_layouts: int | None = None) -> dict[str, Any]:
    """The generalization measurement: ``{"heldout": {...}, "ood": {set: {...}}, "final_report_seconds"}``.

    Every seed's greedy policy on :func:`generalization_sets`, with :func:`evaluate_layout_sets`;
    ``heldout.overlap_with_training`` counts the held-out draws the pool held (dropped).
    """
    tic = time.perf_counter()
    sets, overlap = generalization_sets(context.env, context.params, heldout_layouts, ood_layouts)
    report = evaluate_layout_sets(context.algo.greedy_action, context.network_params, context.env,
                                  context.params, sets, context.seeds)
    heldout = {**report.pop("heldout"), "overlap_with_training": overlap}
    return {"heldout": heldout, "ood": report, "final_report_seconds": time.perf_counter() - tic}
