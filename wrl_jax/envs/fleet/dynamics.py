"""FLEET_SPEC.md's MDP as functions: the task draw, the transition and the reset.

The transition is split in two so the NumPy reference can replay it bit for bit:

- :func:`draw_tasks` turns a key into one candidate task per robot (the only
  randomness): ``jax.random.bits(key, (2, K), uint32)`` modulo
  ``num_items`` (row 0: items) and ``num_stations`` (row 1: stations). Reset
  gives every robot its candidate; a transition only robots that delivered.
- :func:`fleet_transition` and :func:`fleet_reset` are deterministic in the
  drawn tasks.

The conflict rule (steps 1-4: proposals, rounds, who moves) is
:mod:`wrl_jax.envs.fleet.conflicts`; the random words are :mod:`wrl_jax.core.random`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from wrl_jax.core.random import random_words, split_key, words_modulo
from wrl_jax.envs.fleet.conflicts import propose_cells, resolve_cells
from wrl_jax.envs.fleet.types import FleetParams, FleetState, FleetTasks

NUM_ACTIONS = 5
"""0 up, 1 down, 2 left, 3 right, 4 wait."""

WAIT = 4

FLAGS = ("shelf_hit", "wall_bump", "robot_block", "picked_up", "delivered", "waited")
"""Per-robot bool ``(K,)`` entries of a transition's ``info`` (``waited``: action 4, for the metrics)."""


def draw_tasks(key: jax.Array, params: FleetParams, num_robots: int) -> FleetTasks:
    """One uniform candidate ``(item, station)`` per robot from ``key`` (the documented draw method).

    ``jax.random.bits(key, (2, K), uint32)`` (computed by :func:`random_words`,
    the same bits), reduced modulo ``num_items`` (row 0) and ``num_stations``
    (row 1) (:func:`~wrl_jax.core.random.words_modulo`: the remainder without
    integer division). The modulo bias is below ``n / 2**32`` (< 1.5e-8 for the
    62 item markers), far under any sampling noise, and the program is a third of
    ``jax.random.randint``'s, which matters since ``step`` draws twice per
    transition (the tasks and the auto-reset's).
    """
    words = random_words(key, 2 * num_robots).reshape(2, num_robots)
    bounds = jnp.stack([params.num_items, params.num_stations]).astype(jnp.uint32)[:, None]
    drawn = words_modulo(words, bounds)
    return FleetTasks(item=drawn[0].astype(jnp.int32), station=drawn[1].astype(jnp.int32))


def step_keys(key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(transition key, reset key)`` of ``Fleet.step(key, ...)``: ``jax.random.split(key)``, bit for bit."""
    return split_key(key, 0), split_key(key, 1)


def targets(state: FleetState, params: FleetParams) -> jax.Array:
    """Each robot's current target cell ``(K, 2)``: its item while empty, its station while carrying."""
    return jnp.where(state.carrying[:, None], params.stations[state.station], params.items[state.item])


def target_distances(pos: jax.Array, state: FleetState, params: FleetParams) -> jax.Array:
    """``d(pos_i, t_i)`` ``(K,)`` int32 with the targets of ``state``: BFS tables, or Manhattan if switched."""
    rows, cols = pos[:, 0], pos[:, 1]
    bfs = jnp.where(state.carrying, params.station_dist[state.station, rows, cols],
                    params.item_dist[state.item, rows, cols])
    manhattan = jnp.abs(pos - targets(state, params)).sum(axis=1).astype(jnp.int32)
    return jnp.where(params.manhattan_shaping, manhattan, bfs)


def reward_terms(params: FleetParams, flags: dict[str, jax.Array], shaping: jax.Array) -> jax.Array:
    """Step 6: float32 ``(K,)`` rewards, the terms added in FLEET_SPEC.md's order."""
    zero = jnp.zeros_like(params.step_penalty)
    reward = jnp.broadcast_to(params.step_penalty, shaping.shape)
    reward = reward + jnp.where(flags["shelf_hit"], params.obstacle_penalty, zero)
    reward = reward + jnp.where(flags["wall_bump"], params.wall_penalty, zero)
    reward = reward + jnp.where(flags["robot_block"], params.block_penalty, zero)
    reward = reward + params.shaping_coef * shaping.astype(jnp.float32)
    reward = reward + jnp.where(flags["picked_up"], params.pickup_reward, zero)
    reward = reward + jnp.where(flags["delivered"], params.delivery_reward, zero)
    return reward


def target_index(state: FleetState, params: FleetParams) -> jax.Array:
    """Each robot's target as a row of :func:`target_cells`: ``item`` while empty, ``I + station`` while carrying."""
    return jnp.where(state.carrying, params.items.shape[0] + state.station, state.item)


def target_cells(params: FleetParams) -> jax.Array:
    """``(I + G, 2)`` int32: the item rows, then the station rows (one gather finds any robot's target)."""
    return jnp.concatenate([params.items, params.stations], axis=0)


def distance_rows(params: FleetParams) -> jax.Array:
    """``((I + G) N^2,)`` int32: the item then station BFS tables, flat (one gather finds any ``d(cell, t_i)``)."""
    return jnp.concatenate([params.item_dist, params.station_dist], axis=0).reshape(-1)


def fleet_transition(state: FleetState, action: jax.Array, tasks: FleetTasks, params: FleetParams):
    """One transition without reset (steps 1-8), deterministic in ``tasks``.

    Returns ``(next_state, reward (K,), truncated (), flags)``; ``flags`` maps
    each name of :data:`FLAGS` to a bool ``(K,)``. Each robot's target and its
    distances are read with one index into the stacked item/station tables.
    """
    size = params.shelves.shape[0]
    action = jnp.asarray(action, dtype=jnp.int32)
    row, col = state.pos[:, 0], state.pos[:, 1]
    q_row, q_col, wall_bump, shelf_hit = propose_cells(row, col, action, params.shelves)
    next_row, next_col, robot_block = resolve_cells(row, col, q_row, q_col)
    next_pos = jnp.stack([next_row, next_col], axis=-1)
    target_row = target_index(state, params)
    target = target_cells(params)[target_row]
    on_target = jnp.all(next_pos == target, axis=1)
    picked_up = ~state.carrying & on_target
    delivered = state.carrying & on_target
    table = distance_rows(params)
    base = target_row * (size * size)
    bfs = (table[base + state.pos[:, 0] * size + state.pos[:, 1]]
           - table[base + next_pos[:, 0] * size + next_pos[:, 1]])
    manhattan = (jnp.abs(state.pos - target).sum(axis=1) - jnp.abs(next_pos - target).sum(axis=1)).astype(jnp.int32)
    shaping = jnp.where(params.manhattan_shaping, manhattan, bfs)
    flags = dict(shelf_hit=shelf_hit, wall_bump=wall_bump, robot_block=robot_block, picked_up=picked_up,
                 delivered=delivered, waited=action == WAIT)
    reward = reward_terms(params, flags, shaping)
    time = state.time + 1
    next_state = FleetState(
        pos=next_pos,
        item=jnp.where(delivered, tasks.item, state.item),
        station=jnp.where(delivered, tasks.station, state.station),
        carrying=(state.carrying | picked_up) & ~delivered,
        time=time,
    )
    return next_state, reward, time >= params.max_steps, flags


def fleet_reset(tasks: FleetTasks, params: FleetParams) -> FleetState:
    """A fresh shift: robots on their starts, empty-handed, with the drawn tasks."""
    return FleetState(pos=params.starts, item=tasks.item, station=tasks.station,
                      carrying=jnp.zeros(params.starts.shape[0], dtype=bool), time=jnp.zeros((), jnp.int32))
