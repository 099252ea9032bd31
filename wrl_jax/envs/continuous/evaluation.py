"""Deterministic evaluation of a policy on every item of a continuous warehouse, for every seed.

One episode per (round, item index): the environment is reset to that item (the other reset draws
from a fixed key, so every evaluation sees the same episodes) and the deterministic policy acts
until the item is delivered or the episode is truncated. With moving obstacles one round is too few
episodes to see rare collisions, so such warehouses run :data:`OBSTACLE_ROUNDS` rounds. Everything
is one jitted program: one ``lax.while_loop`` over time for the batch of (round, item) episodes, which
stops once every episode has ended (:func:`run_episodes`).

The family's hook for the training driver and the CLI (:data:`EVALUATION`): a seed has *solved* its
warehouse when every episode delivers without touching anything. After training, the pure-pursuit
controller runs on the same episodes and the report prints it and the bounds beside the policy's steps
(:func:`yardstick_report`): a number of steps means little without what a planner does there. The
procedural variant (a pool of layouts) brings its own episodes and a final generalization report through
two methods the hook asks for (:mod:`~wrl_jax.envs.continuous.procedural_evaluation`); every other
environment is unaffected.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from wrl_jax.core.evaluation import FamilyEvaluation, FinalContext, TrainRate
from wrl_jax.core.evaluation import number_text as _num
from wrl_jax.core.evaluation import percent_text as _pct
from wrl_jax.envs.continuous.env import ContinuousWarehouse
from wrl_jax.envs.continuous.types import ContinuousParams

GreedyFn = Callable[[Any, jax.Array], jax.Array]

OBSTACLE_ROUNDS = 8
"""Episodes per item where obstacles move (one where nothing does: the episode is then fixed)."""

EVAL_SEED = 20_261_204
"""The key every evaluation draws its episodes from: the same episodes for every seed and checkpoint."""

SOLVED_DEFINITION = ("env steps per seed at the first periodic evaluation in which the deterministic policy "
                     "delivered every item without a collision")


@struct.dataclass
class ContinuousEval:
    """Episodes of one policy; leaves have shape ``(rounds, I_max)`` (rows past ``num_items`` are padding)."""

    valid: jax.Array  # bool: item index < num_items
    delivered: jax.Array  # bool
    steps: jax.Array  # int32 (max_steps when not delivered)
    episode_return: jax.Array  # float32
    collisions: jax.Array  # int32: shelf, wall and obstacle contacts
    pickup_step: jax.Array  # int32, -1 if never picked up


def rounds(env: ContinuousWarehouse) -> int:
    return OBSTACLE_ROUNDS if env.num_obstacles else 1


def episode_start(act: Callable[..., Any], env: ContinuousWarehouse, params: ContinuousParams, key: jax.Array,
                  item_index: jax.Array, start: Callable[[Any], Any] | None = None) -> tuple:
    """The first carry of one episode from ``key`` with the item forced (:func:`run_episodes`).

    ``act(obs, state)`` is a policy, or, given ``start(state) -> memory``, a controller that keeps a memory
    between steps: ``act(obs, state, memory) -> (action, memory)`` (the pure-pursuit controller).
    """
    reset_key, step_key = jax.random.split(key)
    draws = env.reset_draws(reset_key, params).replace(item_index=jnp.asarray(item_index, jnp.int32))
    obs, state = env.reset_with(draws, params)
    memory = () if start is None else start(state)
    zero = jnp.zeros((), jnp.int32)
    return (jnp.zeros((), bool), obs, state, memory, step_key, jnp.zeros((), bool), jnp.zeros((), jnp.float32), zero,
            zero - 1)


def episode_step(act: Callable[..., Any], env: ContinuousWarehouse, params: ContinuousParams, carry: tuple,
                 start: Callable[[Any], Any] | None = None) -> tuple:
    """One transition of an episode's carry (:func:`episode_start`): ``(ended, obs, state, memory, step key,
    delivered, return, collisions, pickup step)``."""
    _, obs, state, memory, step_key, _, ret, collisions, pickup_step = carry
    action, memory = (act(obs, state), ()) if start is None else act(obs, state, memory)
    obs, state, reward, terminated, truncated, info = env.transition(
        jax.random.fold_in(step_key, state.time), state, action, params)
    pickup_step = jnp.where(info["picked_up"], state.time, pickup_step)
    return (terminated | truncated, obs, state, memory, step_key, terminated, ret + reward,
            collisions + info["collision"].astype(jnp.int32), pickup_step)


def run_episodes(begin: Callable[..., tuple], step: Callable[..., tuple], args: Sequence[jax.Array],
                 depth: int = 1) -> tuple[jax.Array, ...]:
    """Episodes over the leading ``depth`` axes of ``args``, until every one has ended: one ``lax.while_loop`` for
    the batch, in which an episode that has ended keeps its carry (what ``vmap`` makes of a loop per episode,
    written out: JAX's batching rule for a loop would batch its body several times at every ``vmap`` level, most
    of the evaluation's tracing time). ``begin(*arg)`` is :func:`episode_start` of one episode, ``step(carry,
    *arg)`` :func:`episode_step`. Returns ``(delivered, steps, return, collisions, pickup_step)``.
    """
    def batched(fn):
        for _ in range(depth):
            fn = jax.vmap(fn)
        return fn

    step_all = batched(step)

    def body(carry):
        running = ~carry[0]
        new = step_all(carry, *args)
        return jax.tree.map(lambda n, o: jnp.where(running.reshape(running.shape + (1,) * (n.ndim - running.ndim)),
                                                   n, o), new, carry)

    carry = jax.lax.while_loop(lambda c: jnp.any(~c[0]), body, batched(begin)(*args))
    _, _, state, _, _, delivered, ret, collisions, pickup_step = carry
    return delivered, state.time, ret, collisions, pickup_step


def evaluate_episodes(act: Callable[..., Any], env: ContinuousWarehouse, params: ContinuousParams,
                      num_rounds: int | None = None, start: Callable[[Any], Any] | None = None) -> ContinuousEval:
    """``act`` on every (round, item): the evaluation's fixed episodes (shape ``(rounds, I_max)``); ``act`` and
    ``start`` as in :func:`episode_start`."""
    num_rounds = rounds(env) if num_rounds is None else int(num_rounds)
    items = jnp.arange(params.items.shape[0], dtype=jnp.int32)
    keys = jax.random.split(jax.random.PRNGKey(EVAL_SEED), num_rounds * items.shape[0])
    keys = keys.reshape(num_rounds, items.shape[0], *keys.shape[1:])
    delivered, steps, ret, collisions, pickup_step = run_episodes(
        lambda key, item: episode_start(act, env, params, key, item, start),
        lambda carry, key, item: episode_step(act, env, params, carry, start),
        (keys, jnp.broadcast_to(items, keys.shape[:2])), depth=2)
    valid = jnp.broadcast_to(items < params.num_items, delivered.shape)
    return ContinuousEval(valid=valid, delivered=delivered & valid, steps=steps, episode_return=ret,
                          collisions=collisions, pickup_step=pickup_step)


def evaluate_policy(greedy_action: GreedyFn, network_params: Any, env: ContinuousWarehouse,
                    params: ContinuousParams) -> ContinuousEval:
    """The deterministic policy on the evaluation's episodes.

    An environment with an ``evaluation_episodes(act, params)`` method (the procedural variant: a pool
    of layouts) chooses its own episodes; its leaves then carry a leading layout axis.
    """
    act = lambda obs, state: greedy_action(network_params, obs)  # noqa: E731
    own = getattr(env, "evaluation_episodes", None)
    return evaluate_episodes(act, env, params) if own is None else own(act, params)


PURSUIT_FIELDS = ("success_rate", "mean_steps", "collisions_per_episode", "collision_free_rate")
"""What a report keeps of the controller's :func:`summarize` (its return is not compared: no shaping there)."""


def contract_env(env: ContinuousWarehouse, params: ContinuousParams) -> ContinuousWarehouse:
    """``env``'s map shape, rays, moving obstacles and item slots with nothing added: no extra observations, no
    safety stop, no shaping (``params`` only sizes it). What the yardstick drives, whatever view a learner had."""
    return ContinuousWarehouse(params, num_rays=env.num_rays, num_obstacles=env.num_obstacles,
                               name=env.name).without_default_params()


def evaluate_pursuit(env: ContinuousWarehouse, params: ContinuousParams) -> ContinuousEval:
    """The pure-pursuit controller on the evaluation's episodes (the same resets and step keys as every policy's),
    in :func:`contract_env` (it has its own guard; rewards are not compared).

    Raises:
        ValueError: from :func:`~wrl_jax.envs.continuous.pursuit.make_plan` (a robot too wide for its margin).
    """
    from wrl_jax.envs.continuous.pursuit import PursuitConfig, make_plan

    config = PursuitConfig()
    return _pursuit_on_episodes(contract_env(env, params), params, make_plan(params, config), config)


@functools.partial(jax.jit, static_argnames=("env", "config"))
def _pursuit_on_episodes(env: ContinuousWarehouse, params: ContinuousParams, plan: Any, config: Any) -> ContinuousEval:
    from wrl_jax.envs.continuous.pursuit import pursuit_act, pursuit_init

    act = lambda obs, state, control: pursuit_act(plan, control, state, params, config)  # noqa: E731
    return evaluate_episodes(act, env, params, start=lambda state: pursuit_init(plan, state))


def yardstick_report(env: ContinuousWarehouse, params: ContinuousParams) -> dict[str, Any]:
    """The pursuit controller on the evaluation's episodes and, without randomization (which voids it), the
    contract's lower bound and the strict bound, in steps per item (every item counts once)."""
    try:
        pursuit = summarize(jax.tree.map(lambda x: x[None], evaluate_pursuit(env, params)))
        report = {"pursuit": {name: pursuit[name] for name in PURSUIT_FIELDS}}
    except ValueError as error:  # after training: say why, do not lose the run's report
        report = {"pursuit_unavailable": str(error)}
    if not bool(params.randomize):
        from wrl_jax.envs.continuous.yardstick import item_bounds

        bounds = item_bounds(params)
        report.update(bound_steps=float(bounds["steps"].mean()), strict_bound_steps=float(bounds["strict_steps"].mean()))
    return report


# ---------------------------------------------------------------- in training
def seed_summary(result: ContinuousEval) -> dict[str, jax.Array]:
    """Float32 scalars of one seed's evaluation, jittable; ``eval_solved`` is 1.0 when every
    episode delivered without a collision."""
    valid = result.valid
    n = valid.sum().astype(jnp.float32)
    delivered = result.delivered & valid
    n_delivered = delivered.sum().astype(jnp.float32)
    clean = delivered & (result.collisions == 0)
    return {
        "eval_success_rate": n_delivered / n,
        "eval_mean_steps": jnp.where(n_delivered > 0, jnp.where(delivered, result.steps, 0).sum() / n_delivered,
                                     jnp.nan),
        "eval_collisions": jnp.where(valid, result.collisions, 0).sum() / n,
        "eval_mean_return": jnp.where(valid, result.episode_return, 0.0).sum() / n,
        "eval_solved": (clean.sum() == valid.sum()).astype(jnp.float32),
    }


# ------------------------------------------------------------- final report
def _mean(values: np.ndarray, mask: np.ndarray) -> float | None:
    return float(values[mask].mean()) if mask.any() else None


def summarize(result: ContinuousEval, seeds: Sequence[int] | None = None) -> dict[str, Any]:
    """Aggregates over seeds, rounds and items, and one row per seed; plain numbers for JSON.

    ``success_rate`` (delivered / episodes), ``mean_steps`` (of delivered episodes),
    ``collisions_per_episode``, ``collision_free_rate``, ``mean_return``, ``all_seeds_solved``.
    """
    r = jax.tree.map(np.asarray, result)
    num_seeds = r.valid.shape[0]
    seeds = list(range(num_seeds)) if seeds is None else [int(s) for s in seeds]
    if len(seeds) != num_seeds:
        raise ValueError(f"got {len(seeds)} seed labels for {num_seeds} evaluated seeds")
    valid = r.valid.astype(bool)
    delivered = r.delivered & valid

    def block(s: slice | int) -> dict[str, Any]:
        v, d = valid[s], delivered[s]
        return {
            "success_rate": float(d.sum() / v.sum()),
            "mean_steps": _mean(r.steps[s], d),
            "collisions_per_episode": float(r.collisions[s][v].sum() / v.sum()),
            "collision_free_rate": float(((r.collisions[s] == 0) & v).sum() / v.sum()),
            "mean_return": _mean(r.episode_return[s], v),
        }

    # Leaves (seeds, rounds, I), or (seeds, layouts, rounds, I) for a pool of layouts.
    layouts = int(valid.shape[1]) if valid.ndim == 4 else None
    first_round = valid[0, :, 0] if layouts else valid[0, 0]
    summary = {"num_seeds": num_seeds, "num_items": int(first_round.sum()), "rounds": int(valid.shape[-2]),
               "episodes": int(valid.sum()), **block(slice(None))}
    if layouts:
        summary["layouts"] = layouts
    summary["per_seed"] = [{"seed": seed, **block(i)} for i, seed in enumerate(seeds)]
    summary["all_seeds_solved"] = bool(
        all(row["success_rate"] == 1.0 and row["collision_free_rate"] == 1.0 for row in summary["per_seed"]))
    return summary


def format_report(summary: dict[str, Any], label: str, convergence_steps: Sequence[int | None] | None = None,
                  study: dict[str, str] | None = None) -> str:
    """A Markdown table: delivery, steps, collisions, return, first solved step."""
    solved = sum(1 for row in summary["per_seed"] if row["success_rate"] == 1.0 and row["collision_free_rate"] == 1.0)
    reached = [c for c in (convergence_steps or []) if c is not None]
    conv = (f"median {int(np.median(reached)):,} steps ({len(reached)}/{len(convergence_steps)} seeds)"
            if reached else "never" if convergence_steps else "not measured")
    where = f"{summary['layouts']} layouts, " if "layouts" in summary else ""
    rows = [
        ("Delivered", f"{_pct(summary['success_rate'])} ({where}{summary['num_items']} items x {summary['rounds']} "
                      f"rounds x {summary['num_seeds']} seeds; {solved}/{summary['num_seeds']} seeds solve it)"),
        ("Mean steps (delivered)", _num(summary["mean_steps"]) + _beside_yardstick(summary)),
        ("Collisions per episode", _num(summary["collisions_per_episode"], "{:.3f}")),
        ("Collision-free episodes", _pct(summary["collision_free_rate"])),
        ("Mean return", _num(summary["mean_return"], "{:+.1f}")),
        ("First solved", conv),
    ]
    pursuit = summary.get("yardstick", {}).get("pursuit")
    if pursuit:
        rows.append(("Pursuit controller (same episodes)", _outcome(pursuit)))
    sets = {"held-out layouts": summary["heldout"]} if "heldout" in summary else {}
    sets.update((f"{name} (out of distribution)", entry) for name, entry in summary.get("ood", {}).items())
    for name, entry in sets.items():
        if entry.get("episodes_per_seed"):
            beside = f"; pursuit, same episodes: {_outcome(entry['pursuit'])}" if "pursuit" in entry else ""
            bound = f"; the contract's bound {entry['bound_steps']:.1f}" if "bound_steps" in entry else ""
            rows.append((f"{entry['layouts']} {name}", _outcome(entry) + beside + bound))
    lines = [f"| Metric | {label} |", "|---|---|"] + [f"| {name} | {value} |" for name, value in rows]
    return "\n".join(lines)


def _outcome(entry: dict[str, Any]) -> str:
    """Delivery, contacts and steps of a summary (a policy's or the controller's) as one report cell."""
    return (f"{_pct(entry['success_rate'])} delivered, {entry['collisions_per_episode']:.3f} collisions per episode, "
            f"{_num(entry['mean_steps'])} steps")


def _beside_yardstick(summary: dict[str, Any]) -> str:
    """`` (the contract's bound B: +x %, strict S; pursuit P)`` after the policy's steps, as far as measured.

    The bound is the items' mean, so the excess is printed only when the policy delivered every episode (a
    mean over fewer, shorter items would flatter it). The contract's bound passes through the points; a policy
    may beat it by picking up and dropping within ``reach_radius`` of them, never the strict one."""
    yardstick, steps = summary.get("yardstick", {}), summary.get("mean_steps")
    parts = []
    if "bound_steps" in yardstick:
        excess = f": {100.0 * (steps / yardstick['bound_steps'] - 1.0):+.1f} %" if summary["success_rate"] == 1 else ""
        parts.append(f"the contract's bound {yardstick['bound_steps']:.1f}{excess}, strict "
                     f"{yardstick['strict_bound_steps']:.1f}")
    if yardstick.get("pursuit", {}).get("mean_steps") is not None:
        parts.append(f"pursuit {yardstick['pursuit']['mean_steps']:.1f}")
    return f" ({'; '.join(parts)})" if parts else ""


def format_seeds(summary: dict[str, Any]) -> str:
    lines = ["| seed | delivered | mean steps | collisions / episode |", "|---|---|---|---|"]
    for row in summary["per_seed"]:
        lines.append(f"| {row['seed']} | {_pct(row['success_rate'])} | {_num(row['mean_steps'])} | "
                     f"{row['collisions_per_episode']:.3f} |")
    return "\n".join(lines)


def final_report(context: FinalContext) -> dict[str, Any]:
    """After training, what the environment measures beyond the periodic episodes: on a fixed layout the
    yardstick on the same episodes (:func:`yardstick_report`), which the report prints beside the policy.

    An environment with a ``generalization_report(context)`` method (the procedural variant: held-out and
    out-of-distribution layouts) is asked for that instead.
    """
    own = getattr(context.env, "generalization_report", None)
    return {"yardstick": yardstick_report(context.env, context.params)} if own is None else own(context)


EVALUATION = FamilyEvaluation(
    evaluate_policy=evaluate_policy,
    seed_summary=seed_summary,
    solved_key="eval_solved",
    solved_definition=SOLVED_DEFINITION,
    summarize=summarize,
    format_report=format_report,
    format_details=format_seeds,
    progress_metric=("eval_success_rate", "eval delivered"),
    train_rates=(TrainRate("delivery_rate", "delivery rate (training episodes)", "terminated", progress="delivered"),),
    final_report=final_report,
)
