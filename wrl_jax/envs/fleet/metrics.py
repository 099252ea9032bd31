"""Fleet metrics (FLEET_SPEC.md "Metrics"): planner rollouts, per-robot counts, throughput and its bound.

A planner is judged by its throughput (deliveries per step, summed over
robots, over a whole shift) against the upper bound ``K / L*``, where ``L*``
is the mean BFS round trip ``d(station, item) + d(item, station)`` over
uniform items and stations. Episodes run vmapped in one jitted program:
each is one shift of ``horizon`` transitions from a fresh reset (no
auto-reset inside), the planner state reset with it.

Keys: episode ``e`` of :func:`run_episodes` uses ``jax.random.split(key, E)[e]``;
within an episode, ``reset_key, scan_key = split(episode_key)``, and step
``t`` draws its tasks from ``jax.random.split(scan_key, horizon)[t]``.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from wrl_jax.envs.fleet.planners import PibtState, check_planner, compiler_options, next_priorities, pibt_init, plan
from wrl_jax.envs.fleet.types import FleetParams, FleetState

COUNTED = ("delivered", "picked_up", "shelf_hit", "wall_bump", "robot_block", "waited")
"""The env's per-robot ``info`` flags that :func:`run_episodes` counts."""


BLOCK_CAUSES = ("swap", "into a standing robot", "lost a contested cell", "behind a blocked robot")
"""The classes of :func:`block_causes`, in the order a block is put in the first that applies."""


def block_causes(pos: jax.Array, proposal: jax.Array, blocked: jax.Array) -> jax.Array:
    """``(K, 4)`` bool, one-hot over :data:`BLOCK_CAUSES` for each blocked robot (all False for the others).

    The first reason FLEET_SPEC.md step 3 gives for robot ``i``'s block, from the proposals
    ``q`` (step 1's, ``q_i = pos_i`` for a robot that does not try to move): ``swap``, some mover
    ``j`` has ``q_j = pos_i`` and ``q_i = pos_j``; ``into a standing robot``, ``q_i`` is the cell of a
    robot that does not try to move (visible in ``i``'s window before it acted); ``lost a contested
    cell``, a mover ``j < i`` has ``q_j = q_i``; else ``behind a blocked robot``, the robot ``i``
    followed was blocked in an earlier round. What a policy would need to avoid each differs, which is
    why ``bench/fleet_blocks.py`` counts them.
    """
    num_robots = pos.shape[0]
    others = ~np.eye(num_robots, dtype=bool)
    lower = np.tri(num_robots, k=-1, dtype=bool)  # [i, j]: j < i
    mover = jnp.any(proposal != pos, axis=1)

    def same(a, b):  # [i, j]: a_i == b_j
        return jnp.all(a[:, None, :] == b[None, :, :], axis=-1)

    swap = jnp.any(others & mover[None, :] & same(pos, proposal) & same(proposal, pos), axis=1)
    standing = jnp.any(others & ~mover[None, :] & same(proposal, pos), axis=1)
    contested = jnp.any(lower & mover[None, :] & same(proposal, proposal), axis=1)
    first = jnp.stack([swap, standing & ~swap, contested & ~swap & ~standing, ~swap & ~standing & ~contested], axis=1)
    return first & blocked[:, None]


@struct.dataclass
class Step:
    """One recorded transition of :func:`rollout`: the state before it, the actions, the flags."""

    state: FleetState
    action: jax.Array  # (K,) int32
    flags: dict[str, jax.Array]  # each (K,) bool


def planned_transition(env: Any, params: FleetParams, planner: str, state: FleetState, priorities: PibtState,
                       key: jax.Array) -> tuple[FleetState, PibtState, jax.Array, dict[str, jax.Array]]:
    """One transition (no reset) with ``planner``'s actions: next state, next priorities, actions, flags."""
    action = plan(planner, priorities, state, params)
    _, next_state, _, _, _, flags = env.transition(key, state, action, params)
    return next_state, next_priorities(priorities, flags, jnp.zeros((), dtype=bool)), action, flags


def rollout(env: Any, params: FleetParams, planner: str, key: jax.Array, horizon: int) -> tuple[FleetState, Step]:
    """One shift driven by ``planner``: the final state and every :class:`Step` (leaves ``(horizon, ...)``).

    Jittable and vmappable over ``key``; ``planner`` and ``horizon`` are static.
    """
    check_planner(planner)
    reset_key, scan_key = jax.random.split(key)
    _, state = env.reset_env(reset_key, params)

    def one_step(carry, step_key):
        state, priorities = carry
        next_state, priorities, action, flags = planned_transition(env, params, planner, state, priorities, step_key)
        return (next_state, priorities), Step(state=state, action=action, flags=flags)

    carry = (state, pibt_init(env.num_robots))
    (state, _), steps = jax.lax.scan(one_step, carry, jax.random.split(scan_key, horizon))
    return state, steps


def episode_counts(env: Any, params: FleetParams, planner: str, key: jax.Array, horizon: int) -> dict[str, jax.Array]:
    """Per-robot counts ``(K,)`` int32 of each flag of :data:`COUNTED` over one shift (same draws as :func:`rollout`).

    Sums inside the scan instead of recording the trajectory.
    """
    check_planner(planner)
    reset_key, scan_key = jax.random.split(key)
    _, state = env.reset_env(reset_key, params)
    zeros = {name: jnp.zeros(env.num_robots, dtype=jnp.int32) for name in COUNTED}

    def one_step(carry, step_key):
        state, priorities, counts = carry
        state, priorities, _, flags = planned_transition(env, params, planner, state, priorities, step_key)
        counts = {name: counts[name] + flags[name].astype(jnp.int32) for name in COUNTED}
        return (state, priorities, counts), None

    carry = (state, pibt_init(env.num_robots), zeros)
    (_, _, counts), _ = jax.lax.scan(one_step, carry, jax.random.split(scan_key, horizon))
    return counts


def policy_episode_counts(env: Any, params: FleetParams, policy: Any, key: jax.Array,
                          horizon: int) -> dict[str, jax.Array]:
    """:func:`episode_counts` with a learned policy in the planner's place: the same episodes for the same key.

    ``policy(obs (K, D), key) -> actions (K,)``. The environment's draws (the reset and
    each step's tasks) come from ``key`` exactly as in :func:`episode_counts`, so a
    policy and a planner given the same key start the same shifts and are offered the
    same task draws; the policy's own keys (a sampled policy's) are a separate
    stream, ``split(fold_in(key, 1), horizon)``.
    """
    reset_key, scan_key = jax.random.split(key)
    obs, state = env.reset_env(reset_key, params)
    zeros = {name: jnp.zeros(env.num_robots, dtype=jnp.int32) for name in COUNTED}
    step_keys = jax.random.split(scan_key, horizon)
    policy_keys = jax.random.split(jax.random.fold_in(key, 1), horizon)

    def one_step(carry, keys):
        obs, state, counts = carry
        step_key, policy_key = keys
        action = policy(obs, policy_key)
        obs, state, _, _, _, flags = env.transition(step_key, state, action, params)
        counts = {name: counts[name] + flags[name].astype(jnp.int32) for name in COUNTED}
        return (obs, state, counts), None

    (_, _, counts), _ = jax.lax.scan(one_step, (obs, state, zeros), (step_keys, policy_keys))
    return counts


def mean_round_trip_jax(params: FleetParams) -> jax.Array:
    """:func:`mean_round_trip` in float32 inside ``jit`` (padding rows of items and stations masked out)."""
    items, stations = params.items, params.stations
    station_to_item = params.item_dist[:, stations[:, 0], stations[:, 1]]  # [i, g]
    item_to_station = params.station_dist[:, items[:, 0], items[:, 1]].T  # [i, g]
    real = (jnp.arange(items.shape[0])[:, None] < params.num_items) & (
        jnp.arange(stations.shape[0])[None, :] < params.num_stations)
    total = jnp.where(real, station_to_item + item_to_station, 0).sum().astype(jnp.float32)
    return total / (params.num_items * params.num_stations).astype(jnp.float32)


@functools.partial(jax.jit, static_argnames=("env", "planner", "num_episodes", "horizon"),
                   compiler_options=compiler_options())
def run_episodes(env: Any, params: FleetParams, planner: str, key: jax.Array, num_episodes: int,
                 horizon: int) -> dict[str, jax.Array]:
    """:func:`episode_counts` of ``num_episodes`` shifts, vmapped in one program: each count ``(E, K)`` int32.

    Compiled with the planners' :func:`~wrl_jax.envs.fleet.planners.compiler_options` (the classic CPU
    fusion emitter: about 1.15x faster with PIBT, the same counts).
    """
    keys = jax.random.split(key, num_episodes)
    return jax.vmap(episode_counts, in_axes=(None, None, None, 0, None))(env, params, planner, keys, horizon)


# ------------------------------------------------------------------ statistics (NumPy, after the run)
def mean_round_trip(params: FleetParams) -> float:
    """``L*``: the mean of ``d(station, item) + d(item, station)`` over the real items and stations."""
    num_items, num_stations = int(params.num_items), int(params.num_stations)
    items = np.asarray(params.items)[:num_items]
    stations = np.asarray(params.stations)[:num_stations]
    item_dist = np.asarray(params.item_dist)[:num_items]  # [i, r, c]: d((r, c), item i)
    station_dist = np.asarray(params.station_dist)[:num_stations]
    station_to_item = item_dist[:, stations[:, 0], stations[:, 1]]  # [i, g]
    item_to_station = station_dist[:, items[:, 0], items[:, 1]].T  # [i, g]
    return float(np.mean(station_to_item.astype(np.float64) + item_to_station))


def mean_interval(values: np.ndarray, level: float = 0.95) -> tuple[float, float | None, float | None]:
    """Mean and Student-t ``level`` interval of ``values`` (``None`` bounds with a single value)."""
    from scipy import stats

    values = np.asarray(values, dtype=np.float64)
    mean = float(values.mean())
    if values.size < 2:
        return mean, None, None
    half = float(stats.t.ppf(0.5 + level / 2, values.size - 1) * values.std(ddof=1) / math.sqrt(values.size))
    return mean, mean - half, mean + half


def summarize(counts: dict[str, Any], horizon: int, params: FleetParams) -> dict[str, Any]:
    """The JSON-ready report of :func:`run_episodes`' counts: throughput, its interval, the bound, per robot."""
    counts = {name: np.asarray(value) for name, value in counts.items()}
    num_episodes, num_robots = counts["delivered"].shape
    per_episode = counts["delivered"].sum(axis=1) / horizon
    mean, low, high = mean_interval(per_episode)
    round_trip = mean_round_trip(params)
    bound = num_robots / round_trip
    names = {"delivered": "deliveries", "picked_up": "pickups", "shelf_hit": "shelf_hits",
             "wall_bump": "wall_bumps", "robot_block": "robot_blocks", "waited": "waits"}
    return {
        "episodes": int(num_episodes),
        "num_robots": int(num_robots),
        "horizon": int(horizon),
        "throughput": {"mean": mean, "ci95": [low, high], "per_episode": per_episode.tolist(),
                       "unit": "deliveries per step, all robots"},
        "upper_bound": {"mean_round_trip": round_trip, "throughput": bound, "fraction": mean / bound},
        "per_robot": {names[name]: counts[name].mean(axis=0).tolist() for name in COUNTED},
        "per_episode_total": {names[name]: float(counts[name].sum(axis=1).mean()) for name in COUNTED},
    }
