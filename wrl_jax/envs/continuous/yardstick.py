"""CONTINUOUS_SPEC.md's yardstick: the per-item lower bound, and pure pursuit measured against it.

``D_i`` is the exact shortest length of the robot's disc from the start through item ``i`` to the goal
(:mod:`~wrl_jax.envs.continuous.shortest_path`); ``D_i / (v_max dt)`` steps is the contract's bound.
It passes through the points, while the env picks up and delivers within ``reach_radius`` (``rho``) of
them, so a policy may beat it (pure pursuit does, on some items) by up to ``3 rho`` of path: ``rho`` on
the way in to the item, ``2 rho`` between item and goal. ``strict_steps`` is the bound no policy beats:
``(max(d_si - rho, 0) + max(d_ig - 2 rho, 0)) / (v_max dt)`` with the two legs' shortest lengths, valid as the
geodesic from a point within ``rho`` of a free cell's centre to the centre is the straight segment
(``rho + robot_radius <= sqrt(2) / 2``, as with the contract's values; otherwise the straight-line legs
stand in). Randomization (gains above 1, noise, a jittered start) voids both bounds.

:func:`run_pursuit` runs ``E`` episodes of the pure-pursuit controller vmapped in one jitted scan;
episode ``e`` takes item ``e mod I``, so every item is covered.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.continuous.dynamics import reset_core
from wrl_jax.envs.continuous.pursuit import PursuitConfig, PursuitPlan, make_plan, pursuit_act, pursuit_init
from wrl_jax.envs.continuous.shortest_path import item_legs
from wrl_jax.envs.continuous.types import ContinuousParams

COUNTED = ("collision", "hit_shelf", "hit_wall", "hit_obstacle")
"""The env's flags counted per episode."""


def item_bounds(params: ContinuousParams) -> dict[str, np.ndarray]:
    """Per item ``(I,)`` float64: ``to_item``, ``to_goal``, ``length`` ``D_i`` (m), ``steps`` and ``strict_steps``."""
    num_items = int(params.num_items)
    to_item, to_goal = item_legs(np.asarray(params.shelves), np.asarray(params.start, np.float64),
                                 np.asarray(params.goal, np.float64),
                                 np.asarray(params.items, np.float64)[:num_items], float(params.robot_radius))
    length = to_item + to_goal
    stride = float(params.v_max) * float(params.dt)
    reach = float(params.reach_radius)
    first, second = to_item, to_goal
    if reach + float(params.robot_radius) > np.sqrt(0.5):  # the geodesic near a point may bend: straight lines
        items = np.asarray(params.items, np.float64)[:num_items]
        first = np.hypot(*(items - np.asarray(params.start, np.float64)).T)
        second = np.hypot(*(items - np.asarray(params.goal, np.float64)).T)
    strict = np.maximum(first - reach, 0.0) + np.maximum(second - 2 * reach, 0.0)
    return {"to_item": to_item, "to_goal": to_goal, "length": length, "steps": length / stride,
            "strict_steps": strict / stride}


def pursuit_episode(env: Any, params: ContinuousParams, plan: PursuitPlan, config: PursuitConfig, key: jax.Array,
                    item_index: jax.Array, horizon: int) -> dict[str, jax.Array]:
    """One episode with the item forced to ``item_index``: event counts, and the step of delivery (-1 if none).

    ``horizon`` transitions from a reset, without auto-reset; after the episode ends nothing changes or counts.
    """
    reset_key, scan_key = jax.random.split(key)
    draws = env.reset_draws(reset_key, params).replace(item_index=item_index.astype(jnp.int32))
    _, state = reset_core(draws, params)
    zero = jnp.int32(0)
    counts = {name: zero for name in (*COUNTED, "waits", "escapes")}

    def one_step(carry, step_key):
        state, control, done, counts, delivered_at = carry
        action, next_control = pursuit_act(plan, control, state, params, config)
        _, next_state, _, terminated, truncated, info = env.transition(step_key, state, action, params)
        live = ~done
        events = {**{name: info[name] for name in COUNTED}, "waits": next_control.waited > 0,
                  "escapes": next_control.escape_left == config.escape_steps}
        counts = {name: counts[name] + (live & events[name]).astype(jnp.int32) for name in counts}
        delivered_at = jnp.where(live & terminated, next_state.time, delivered_at)
        state, control = jax.tree.map(lambda new, old: jnp.where(live, new, old), (next_state, next_control),
                                      (state, control))
        return (state, control, done | terminated | truncated, counts, delivered_at), None

    carry = (state, pursuit_init(plan, state), jnp.bool_(False), counts, zero - 1)
    (_, control, _, counts, delivered_at), _ = jax.lax.scan(one_step, carry, jax.random.split(scan_key, horizon))
    return {**counts, "delivered_at": delivered_at, "guarded": control.guarded}


@functools.partial(jax.jit, static_argnames=("env", "config", "episodes", "horizon"))
def pursuit_episodes(env: Any, params: ContinuousParams, plan: PursuitPlan, config: PursuitConfig, key: jax.Array,
                     episodes: int, horizon: int) -> dict[str, jax.Array]:
    """:func:`pursuit_episode` on keys ``split(key, E)``, episode ``e`` on item ``e mod I``: each ``(E,)``."""
    keys = jax.random.split(key, episodes)
    items = jnp.arange(episodes, dtype=jnp.int32) % params.num_items
    run = jax.vmap(pursuit_episode, in_axes=(None, None, None, None, 0, 0, None))
    return run(env, params, plan, config, keys, items, horizon)


def summarize(results: dict[str, Any], bounds: dict[str, np.ndarray], num_items: int) -> dict[str, Any]:
    """The JSON-ready report: delivery rate, collisions per episode, per-item steps against the bounds."""
    results = {name: np.asarray(value) for name, value in results.items()}
    episodes = results["delivered_at"].shape[0]
    item = np.arange(episodes) % num_items
    delivered = results["delivered_at"] >= 0
    per_item = []
    for i in range(num_items):
        mine = (item == i) & delivered
        steps = float(results["delivered_at"][mine].mean()) if mine.any() else None
        per_item.append({
            "item": i, "episodes": int((item == i).sum()), "delivered": int(mine.sum()), "mean_steps": steps,
            "length_m": float(bounds["length"][i]), "bound_steps": float(bounds["steps"][i]),
            "strict_bound_steps": float(bounds["strict_steps"][i]),
            "excess_pct": None if steps is None else 100.0 * (steps / bounds["steps"][i] - 1.0),
            "min_steps": int(results["delivered_at"][mine].min()) if mine.any() else None})
    ratio = [p["mean_steps"] / p["bound_steps"] for p in per_item if p["mean_steps"] is not None]
    return {
        "episodes": int(episodes),
        "delivery_rate": float(delivered.mean()),
        "collisions_per_episode": float(results["collision"].mean()),
        "hits_per_episode": {name: float(results[name].mean()) for name in COUNTED[1:]},
        "waits_per_episode": float(results["waits"].mean()),
        "escapes_per_episode": float(results["escapes"].mean()),
        "guard_stops_per_episode": float(results["guarded"].mean()),
        "mean_steps_per_item": float(np.mean([p["mean_steps"] for p in per_item if p["mean_steps"] is not None]))
        if ratio else None,
        "mean_bound_steps": float(np.mean(bounds["steps"])),
        "excess_pct": 100.0 * (float(np.mean(ratio)) - 1.0) if ratio else None,
        "per_item": per_item,
    }


def run_pursuit(env: Any, params: ContinuousParams, episodes: int, seed: int = 0,
                config: PursuitConfig = PursuitConfig()) -> dict[str, Any]:
    """Plan, run ``episodes`` vmapped pure-pursuit episodes (every item covered) and summarize.

    Raises:
        ValueError: a non-positive ``episodes``, or a bad setting (from :func:`make_plan`), before compiling.
    """
    if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) or episodes < 1:
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    plan = make_plan(params, config)
    bounds = item_bounds(params)
    results = pursuit_episodes(env, params, plan, config, jax.random.key(seed), int(episodes), int(params.max_steps))
    return summarize(jax.device_get(results), bounds, int(params.num_items))
