"""RWARE's MDP as functions of arrays: reset, the deterministic step, and the draws that feed both.

The step follows rware 2.0.0's ``Warehouse.step`` (NOTES.md section 4) in its order:
targets, the cancel pass and the move graph (:mod:`wrl_jax.envs.rware.conflicts`), the
actions, a fresh grid, deliveries goal by goal, then the counters. Its only randomness is
one replacement draw per delivery, so :func:`rware_transition` takes the draws as input:
``replacements (G,)``, used in order, one per delivery (rware's ``np_random.choice(candidates)``:
an index among the unrequested shelves in id order). Parity tests replay rware's own draws
through it; the environment draws them from the step key (:func:`draw_replacements`).

rware applies the actions agent by agent; here they are applied to all agents at once,
which is the same: a pick-up reads the pre-step grid at the agent's own cell, and no two
agents share a cell, so no agent's action can see another's.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from wrl_jax.envs.rware.conflicts import cancelled_moves, forward_targets, resolve_moves
from wrl_jax.envs.rware.types import (
    FORWARD,
    GLOBAL,
    LEFT,
    NO_SHELF,
    RIGHT,
    TOGGLE_LOAD,
    TWO_STAGE,
    RwareParams,
    RwareState,
)

TURN_RIGHT = (3, 2, 0, 1)
"""Heading after a right turn, by heading: up -> right, down -> left, left -> up, right -> down."""
TURN_LEFT = (2, 3, 1, 0)
"""Heading after a left turn: up -> left, down -> right, left -> down, right -> up."""


COMPARE_LIMIT = 64
"""Up to this many entities, grids and masks are built by comparison (fused, and quick to compile: a
scatter becomes a loop of its own on CPU); more (the shelves of a large warehouse) use a scatter."""


def occupancy(x: jax.Array, y: jax.Array, height: int, width: int) -> jax.Array:
    """``(H, W)`` int32 grid of ids (index + 1, 0 = empty), as rware's ``_recalc_grid``: the highest id wins a cell."""
    count = x.shape[0]
    ids = jnp.arange(1, count + 1, dtype=jnp.int32)
    flat = y * width + x
    if count <= COMPARE_LIMIT:
        cells = jnp.arange(height * width, dtype=jnp.int32)[:, None]
        return jnp.max(jnp.where(flat[None, :] == cells, ids[None, :], 0), axis=1, initial=0).reshape(height, width)
    return jnp.zeros(height * width, jnp.int32).at[flat].max(ids).reshape(height, width)


def requested_mask(queue: jax.Array, num_shelves: int) -> jax.Array:
    """``(S,)`` bool: which shelves are in the request queue."""
    return jnp.any(queue[None, :] == jnp.arange(num_shelves, dtype=jnp.int32)[:, None], axis=1)


def draw_replacements(key: jax.Array, params: RwareParams, queue_size: int) -> jax.Array:
    """``G`` uniform replacement indices in ``0 .. S-R-1``: the k-th delivery of a step uses the k-th."""
    free = max(params.num_shelves - queue_size, 1)
    return jax.random.randint(key, (params.num_goals,), 0, free, dtype=jnp.int32)


SEQUENTIAL_LIMIT = 64
"""Up to this many draws, :func:`distinct` samples one by one (no sort); more use ``top_k``."""


def distinct(key: jax.Array, population: int, count: int) -> jax.Array:
    """``count`` distinct uniform draws from ``0 .. population-1``, in random order (``choice`` without replacement).

    Draw ``i`` is uniform among the ``population - i`` values not drawn yet: its index ``r`` among them
    becomes the value ``r + #{j : c_j - j <= r}`` over the values ``c_0 < c_1 < ...`` drawn so far (kept
    sorted). ``count`` steps of ``count`` comparisons, no sort: the reset runs on every step under
    auto-reset, and a ``top_k`` over the whole grid (the ``count`` largest of ``population`` random words,
    used above :data:`SEQUENTIAL_LIMIT` draws) cost three quarters of a step on CPU.
    """
    if count > SEQUENTIAL_LIMIT:
        return jax.lax.top_k(jax.random.bits(key, (population,), jnp.uint32), count)[1].astype(jnp.int32)
    index = jnp.arange(count, dtype=jnp.int32)
    ranks = jax.random.randint(key, (count,), 0, population - index, dtype=jnp.int32)

    def draw(drawn_sorted, r):
        value = r + jnp.sum(drawn_sorted - index <= r, dtype=jnp.int32)  # unset slots hold a sentinel above all
        position = jnp.sum(drawn_sorted < value, dtype=jnp.int32)
        shifted = jnp.where(index > position, jnp.roll(drawn_sorted, 1), drawn_sorted)
        return jnp.where(index == position, value, shifted), value

    sentinel = jnp.full(count, population + count, jnp.int32)
    return jax.lax.scan(draw, sentinel, ranks)[1]


def draw_reset(key: jax.Array, params: RwareParams, num_agents: int, queue_size: int):
    """rware's three reset draws: distinct agent cells (flat ``y W + x``), headings, distinct requested shelves."""
    height, width = params.grid_size
    key_cells, key_dirs, key_queue = jax.random.split(key, 3)
    cells = distinct(key_cells, height * width, num_agents)
    headings = jax.random.randint(key_dirs, (num_agents,), 0, 4, dtype=jnp.int32)
    return cells, headings, distinct(key_queue, params.num_shelves, queue_size)


def rware_reset(cells: jax.Array, headings: jax.Array, queue: jax.Array, params: RwareParams,
                msg_bits: int) -> RwareState:
    """A fresh episode from the reset draws: shelves home, agents unloaded on ``cells``, silent."""
    width = params.grid_size[1]
    count = cells.shape[0]
    return RwareState(
        agent_x=cells % width, agent_y=cells // width, agent_dir=headings,
        carrying=jnp.full(count, NO_SHELF, jnp.int32), has_delivered=jnp.zeros(count, bool),
        message=jnp.zeros((count, msg_bits), jnp.float32),
        shelf_x=params.shelf_home[:, 0], shelf_y=params.shelf_home[:, 1], queue=queue,
        time=jnp.zeros((), jnp.int32), inactive=jnp.zeros((), jnp.int32))


def _apply_actions(state: RwareState, action: jax.Array, params: RwareParams):
    """Steps 2-5: the graph's verdict, then moves, turns, pick-ups and drops. Returns ``(state, reward, moved)``."""
    height, width = params.grid_size
    x, y = state.agent_x, state.agent_y
    agent_grid = occupancy(x, y, height, width)
    shelf_grid = occupancy(state.shelf_x, state.shelf_y, height, width)
    tx, ty = forward_targets(x, y, state.agent_dir, action, height, width)
    cancelled = cancelled_moves(x, y, tx, ty, state.carrying, agent_grid, shelf_grid)
    tx, ty = jnp.where(cancelled, x, tx), jnp.where(cancelled, y, ty)
    committed = resolve_moves(y * width + x, ty * width + tx)
    forward = committed & (action == FORWARD) & ~cancelled
    new_x, new_y = jnp.where(forward, tx, x), jnp.where(forward, ty, y)

    heading = state.agent_dir
    heading = jnp.where(action == RIGHT, jnp.asarray(TURN_RIGHT, jnp.int32)[heading], heading)
    heading = jnp.where(action == LEFT, jnp.asarray(TURN_LEFT, jnp.int32)[heading], heading)

    loaded = state.carrying >= 0
    toggle = action == TOGGLE_LOAD
    under = shelf_grid[y, x] - 1  # the pre-step grid, as rware reads it
    pick = toggle & ~loaded & (under >= 0)
    drop = toggle & loaded & ~params.highway[y, x]
    bonus = drop & state.has_delivered & (params.reward_type == TWO_STAGE)
    reward = jnp.where(bonus, 0.5, 0.0).astype(jnp.float32)

    shelves = jnp.arange(state.shelf_x.shape[0], dtype=jnp.int32)[:, None]
    rides = (state.carrying[None, :] == shelves) & (forward & loaded)[None, :]  # [s, i]: agent i moves shelf s
    moved_shelf = jnp.any(rides, axis=1)
    next_state = state.replace(
        agent_x=new_x, agent_y=new_y, agent_dir=heading,
        carrying=jnp.where(pick, under, jnp.where(drop, NO_SHELF, state.carrying)),
        has_delivered=state.has_delivered & ~drop,
        shelf_x=jnp.where(moved_shelf, jnp.max(jnp.where(rides, new_x[None, :], 0), axis=1), state.shelf_x),
        shelf_y=jnp.where(moved_shelf, jnp.max(jnp.where(rides, new_y[None, :], 0), axis=1), state.shelf_y))
    return next_state, reward, forward & ((tx != x) | (ty != y))


def grids(state: RwareState, params: RwareParams) -> tuple[jax.Array, jax.Array]:
    """rware's ``grid``: the ``(H, W)`` agent-id and shelf-id layers of a state (ids are index + 1, 0 = empty)."""
    height, width = params.grid_size
    return (occupancy(state.agent_x, state.agent_y, height, width),
            occupancy(state.shelf_x, state.shelf_y, height, width))


def _deliver(state: RwareState, reward: jax.Array, replacements: jax.Array, params: RwareParams,
             agent_grid: jax.Array, shelf_grid: jax.Array):
    """Step 7: goal by goal, a requested shelf on the goal is paid for and replaced in its queue slot.

    Returns ``(state, reward, delivered, any_delivery)``: ``delivered (N,)`` flags the agent on each paying goal.
    """
    count, num_shelves = reward.shape[0], state.shelf_x.shape[0]
    delivered = jnp.zeros(count, bool)
    if state.queue.shape[0] == 0:  # rware's "-hard" 1-agent tasks request nothing
        return state, reward, delivered, jnp.zeros((), bool)
    agents = jnp.arange(count)

    def one_goal(carry, goal):
        queue, reward, has_delivered, delivered, used = carry
        shelf = shelf_grid[goal[1], goal[0]] - 1
        requested = requested_mask(queue, num_shelves)
        hit = (shelf >= 0) & requested[jnp.maximum(shelf, 0)]
        free = ~requested
        pick = jnp.clip(replacements[jnp.minimum(used, replacements.shape[0] - 1)], 0,
                        jnp.maximum(free.sum() - 1, 0))
        new = jnp.argmax(jnp.cumsum(free) > pick).astype(jnp.int32)  # the pick-th unrequested shelf by id
        slot = jnp.argmax(queue == shelf)
        queue = jnp.where(hit, queue.at[slot].set(new), queue)
        # rware pays rewards[agent_id - 1]: with no agent on the goal, Python's index -1 (the last agent).
        payee = agents == (agent_grid[goal[1], goal[0]] - 1) % count
        gain = jnp.where(params.reward_type == GLOBAL, 1.0,
                         jnp.where(payee, jnp.where(params.reward_type == TWO_STAGE, 0.5, 1.0), 0.0))
        reward = reward + jnp.where(hit, gain, 0.0).astype(jnp.float32)
        has_delivered = has_delivered | (hit & payee & (params.reward_type == TWO_STAGE))
        return (queue, reward, has_delivered, delivered | (hit & payee), used + hit.astype(jnp.int32)), hit

    carry = (state.queue, reward, state.has_delivered, delivered, jnp.zeros((), jnp.int32))
    (queue, reward, has_delivered, delivered, _), hits = jax.lax.scan(one_goal, carry, params.goals)
    return state.replace(queue=queue, has_delivered=has_delivered), reward, delivered, jnp.any(hits)


def rware_transition(state: RwareState, action: jax.Array, replacements: jax.Array, params: RwareParams,
                     message: jax.Array | None = None):
    """One rware step, deterministic in ``replacements``: :func:`transition_and_grids` without the grids."""
    return transition_and_grids(state, action, replacements, params, message)[:4]


def transition_and_grids(state: RwareState, action: jax.Array, replacements: jax.Array, params: RwareParams,
                         message: jax.Array | None = None):
    """One rware step and the grids it ends on; deterministic in ``replacements`` ``(G,)`` int32 (module docstring).

    ``action`` is ``(N,)`` int32 (rware's ``Action`` values; anything else acts as ``NOOP``),
    ``message`` ``(N, M)`` the agents' new messages (kept as they are when ``None``). Returns
    ``(next_state, reward (N,) float32, done (), info)``; ``done`` is rware's single flag (time
    or inactivity limit), ``info`` holds ``delivered (N,)`` (the agent on each paying goal),
    ``moved (N,)``, ``time_limit ()`` and ``inactivity_limit ()``; then the post-step :func:`grids`
    (which the observation reads too).
    """
    action = jnp.asarray(action, jnp.int32)
    if message is not None:
        state = state.replace(message=jnp.asarray(message, jnp.float32))
    state, reward, moved = _apply_actions(state, action, params)
    layers = grids(state, params)
    state, reward, delivered, any_delivery = _deliver(state, reward, replacements, params, *layers)
    inactive = jnp.where(any_delivery, 0, state.inactive + 1).astype(jnp.int32)
    time = state.time + 1
    time_limit = (params.max_steps > 0) & (time >= params.max_steps)
    inactivity_limit = (params.max_inactivity_steps > 0) & (inactive >= params.max_inactivity_steps)
    state = state.replace(time=time, inactive=inactive)
    info = {"delivered": delivered, "moved": moved, "time_limit": time_limit, "inactivity_limit": inactivity_limit}
    return state, reward, time_limit | inactivity_limit, info, layers
