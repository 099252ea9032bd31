"""RWARE's MDP as functions of arrays: reset, the deterministic step, and the draws that feed both.

The step follows rware 2.0.0's ``Warehouse.step`` (NOTES.md section 4) in its order:
targets, the cancel pass and the move graph (:mod:`wrl_jax.envs.rware.conflicts`), the
actions, deliveries goal by goal, then the counters. rware's grid is read only at the cells a
step needs (:func:`ids_at`), never built whole. Its only randomness is
one replacement draw per delivery, so :func:`rware_transition` takes the draws as input:
``replacements (G,)``, used in order, one per delivery (rware's ``np_random.choice(candidates)``:
an index among the unrequested shelves in id order). Parity tests replay rware's own draws
through it; the environment draws them from the step key (:func:`draw_replacements`).

rware applies the actions agent by agent; here they are applied to all agents at once,
which is the same: a pick-up reads the pre-step grid at the agent's own cell, and no two
agents share a cell, so no agent's action can see another's.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.core.environment import materialise
from wrl_jax.core.random import MAX_MODULUS, random_words, split_key, threefry_key_data, words_modulo
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


REDUCE_LIMIT = 32
"""XLA's CPU compiler rewrites a reduction over more elements into a ``reduce_window`` (a slow scalar loop)."""


def ids_at(cells: jax.Array, positions: jax.Array, keys: jax.Array, bound: int = 1 << 31) -> jax.Array:
    """``cells.shape`` int32: the largest of ``keys`` (all > 0) among the entities on each flat cell, 0 if none.

    rware's ``_recalc_grid`` read at a few cells: the highest id wins a cell, so keys that rise with
    the id (``id``, or ``k id + flag``) return the winner and its flag. Only the cells a step reads
    (targets, own cells, goals, sensor windows) are looked up: building whole grids cost more.
    ``bound`` (static) exceeds every cell, position and key: below 32768 the compares run on int16,
    twice as many per vector instruction. Reductions are cut into pieces of :data:`REDUCE_LIMIT`.
    """
    dtype = jnp.int16 if bound <= 1 << 15 else jnp.int32
    cells, positions, keys = (value.astype(dtype) for value in (cells, positions, keys))
    found = jnp.zeros(cells.shape, dtype)
    for start in range(0, positions.shape[0], REDUCE_LIMIT):
        piece = slice(start, start + REDUCE_LIMIT)
        found = jnp.maximum(found, jnp.max(jnp.where(cells[..., None] == positions[piece], keys[piece], 0), axis=-1))
    return found.astype(jnp.int32)


def requested_mask(queue: jax.Array, num_shelves: int) -> jax.Array:
    """``(S,)`` bool: which shelves are in the request queue (slot by slot for short queues: elementwise)."""
    shelves = jnp.arange(num_shelves, dtype=jnp.int32)
    if queue.shape[0] > UNROLL_QUEUE:
        return jnp.any(queue[None, :] == shelves[:, None], axis=1)
    return _any([queue[j] == shelves for j in range(queue.shape[0])]) & jnp.ones(num_shelves, bool)


def draw_replacements(key: jax.Array, params: RwareParams, queue_size: int) -> jax.Array:
    """``G`` uniform replacement indices in ``0 .. S-R-1``: the k-th delivery of a step uses the k-th.

    ``jax.random.randint(key, (G,), 0, S-R)`` bit for bit, its threefry written out (:mod:`wrl_jax.core.random`):
    JAX's CPU loop of threefry cost a fifth of a step, and XLA's scalar integer division more than the
    graph: the remainders use :func:`~wrl_jax.core.random.words_modulo` (exact below ``2^23``).
    """
    free = max(params.num_shelves - queue_size, 1)
    count = params.num_goals
    if threefry_key_data(key) is None:
        return jax.random.randint(key, (count,), 0, free, dtype=jnp.int32)
    higher, lower = (random_words(split_key(key, index), count) for index in (0, 1))
    span = np.uint32(free)
    multiplier = np.uint32((2 ** 16 % free) ** 2 % 2 ** 32 % free)  # randint's 2^32 mod span
    modulo = (lambda words: words % span) if free > MAX_MODULUS else (lambda words: words_modulo(words, span))
    return materialise(modulo(modulo(higher) * multiplier + modulo(lower)).astype(jnp.int32))  # hashed once


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


def _apply_actions(state: RwareState, action: jax.Array, params: RwareParams, tie_order: str):
    """Steps 2-5: the graph's verdict, then moves, turns, pick-ups and drops. Returns ``(state, reward, moved)``."""
    height, width = params.grid_size
    count, num_shelves = state.agent_x.shape[0], state.shelf_x.shape[0]
    x, y = state.agent_x, state.agent_y
    loaded = state.carrying >= 0
    tx, ty = forward_targets(x, y, state.agent_dir, action, height, width)
    here, there = y * width + x, ty * width + tx
    # The pre-step grid, as rware reads it: the shelf on each target and own cell, the agent on each target.
    shelves = ids_at(jnp.concatenate([there, here]), state.shelf_y * width + state.shelf_x,
                     jnp.arange(1, num_shelves + 1, dtype=jnp.int32))
    occupant = ids_at(there, here, 2 * jnp.arange(1, count + 1, dtype=jnp.int32) + loaded)
    cancelled = cancelled_moves(here != there, loaded, shelves[:count] > 0, (occupant & 1) > 0)
    tx, ty = jnp.where(cancelled, x, tx), jnp.where(cancelled, y, ty)
    committed = resolve_moves(here, jnp.where(cancelled, here, there), grid_size=(height, width),
                              tie_order=tie_order)
    forward = committed & (action == FORWARD) & ~cancelled
    new_x, new_y = jnp.where(forward, tx, x), jnp.where(forward, ty, y)

    heading = state.agent_dir
    heading = jnp.where(action == RIGHT, jnp.asarray(TURN_RIGHT, jnp.int32)[heading], heading)
    heading = jnp.where(action == LEFT, jnp.asarray(TURN_LEFT, jnp.int32)[heading], heading)

    toggle = action == TOGGLE_LOAD
    under = shelves[count:] - 1
    pick = toggle & ~loaded & (under >= 0)
    drop = toggle & loaded & ~params.highway[y, x]
    bonus = drop & state.has_delivered & (params.reward_type == TWO_STAGE)
    reward = jnp.where(bonus, 0.5, 0.0).astype(jnp.float32)

    # A shelf moves to its carrier's new cell, agent by agent as rware writes it (the last carrier wins, were two
    # to share one); elementwise over the shelves (a reduction over the few agents was a scalar loop per shelf).
    shelf_ids = jnp.arange(num_shelves, dtype=jnp.int32)
    shelf_x, shelf_y = state.shelf_x, state.shelf_y
    riding = forward & loaded
    for i in range(count):
        ride = (state.carrying[i] == shelf_ids) & riding[i]
        shelf_x, shelf_y = jnp.where(ride, new_x[i], shelf_x), jnp.where(ride, new_y[i], shelf_y)
    next_state = state.replace(
        agent_x=new_x, agent_y=new_y, agent_dir=heading,
        carrying=jnp.where(pick, under, jnp.where(drop, NO_SHELF, state.carrying)),
        has_delivered=state.has_delivered & ~drop, shelf_x=shelf_x, shelf_y=shelf_y)
    return next_state, reward, forward & ((tx != x) | (ty != y))


UNROLL_GOALS = 8
"""Up to this many goals the delivery pass is written out goal by goal (fused); more run in a ``lax.scan``."""


UNROLL_QUEUE = 16
"""Up to this request-queue length the delivery pass works slot by slot on scalars (elementwise under ``vmap``)."""


def nth_unrequested(queue: jax.Array, pick: jax.Array, num_shelves: int) -> jax.Array:
    """The ``pick``-th shelf (0-based, by id) not in ``queue``, ``pick`` clipped as rware's draw; 0 if none is free.

    rware's ``choice`` over the unrequested shelves, without a cumulative sum over all shelves: with
    the distinct requested ids ``c_0 < c_1 < ...``, the answer is ``pick + #{j : c_j - j <= pick}``
    (``c_j - j`` unrequested shelves lie below ``c_j``). ``R^2`` compares, written out slot by slot
    for short queues: reductions over a few slots were XLA's scalar loops, a quarter of a step.
    """
    size = queue.shape[0]
    if size > UNROLL_QUEUE:
        earlier = np.tril(np.ones((size, size), bool), -1)  # [j, i]: i < j
        first = (queue >= 0) & (queue < num_shelves) & ~jnp.any((queue[:, None] == queue[None, :]) & earlier, axis=1)
        free = num_shelves - jnp.sum(first, dtype=jnp.int32)
        pick = jnp.clip(pick, 0, jnp.maximum(free - 1, 0))
        below = jnp.sum(first[None, :] & (queue[None, :] < queue[:, None]), axis=1, dtype=jnp.int32)  # j's rank
        return jnp.where(free > 0, pick + jnp.sum(first & (queue - below <= pick), dtype=jnp.int32), 0)
    q = [queue[j] for j in range(size)]
    first = [(q[j] >= 0) & (q[j] < num_shelves) & ~_any([q[i] == q[j] for i in range(j)]) for j in range(size)]
    free = num_shelves - _count(first)
    pick = jnp.clip(pick, 0, jnp.maximum(free - 1, 0))
    below = [_count([first[i] & (q[i] < q[j]) for i in range(size)]) for j in range(size)]
    return jnp.where(free > 0, pick + _count([first[j] & (q[j] - below[j] <= pick) for j in range(size)]), 0)


def _any(terms: list) -> jax.Array:
    return functools.reduce(jnp.logical_or, terms, jnp.bool_(False))


def _count(terms: list) -> jax.Array:
    return functools.reduce(jnp.add, [term.astype(jnp.int32) for term in terms], jnp.int32(0))


def _deliver(state: RwareState, reward: jax.Array, replacements: jax.Array, params: RwareParams):
    """Step 7: goal by goal, a requested shelf on the goal is paid for and replaced in its queue slot.

    Returns ``(state, reward, delivered, any_delivery)``: ``delivered (N,)`` flags the agent on each paying goal.
    The queue pass (per goal: hit, replacement, payee) is materialised before the per-agent payments:
    fused into them, XLA recomputed the whole pass for every agent's reward.
    """
    count, num_shelves, size = reward.shape[0], state.shelf_x.shape[0], state.queue.shape[0]
    if size == 0:  # rware's "-hard" 1-agent tasks request nothing
        return state, reward, jnp.zeros(count, bool), jnp.zeros((), bool)
    width = params.grid_size[1]
    agents = jnp.arange(count, dtype=jnp.int32)
    goal_cells = params.goals[:, 1] * width + params.goals[:, 0]
    on_goal = (ids_at(goal_cells, state.shelf_y * width + state.shelf_x,
                      jnp.arange(1, num_shelves + 1, dtype=jnp.int32)) - 1,
               ids_at(goal_cells, state.agent_y * width + state.agent_x, agents + 1))

    def one_goal(carry, goal):
        queue, used = carry
        shelf, agent = goal
        match = queue == shelf
        if size <= UNROLL_QUEUE:
            matches = [match[j] for j in range(size)]
            hit = (shelf >= 0) & _any(matches)
            slot = jnp.stack([matches[j] & ~_any(matches[:j]) for j in range(size)])  # the first match
        else:
            hit = (shelf >= 0) & jnp.any(match)
            slot = jnp.arange(size) == jnp.argmax(match)
        draw = replacements[-1]  # rware's k-th delivery uses the k-th draw (the last, past the end)
        for index in range(replacements.shape[0] - 2, -1, -1):
            draw = jnp.where(used == index, replacements[index], draw)
        hit, new = materialise(hit), materialise(nth_unrequested(queue, draw, num_shelves))  # read by every slot
        queue = jnp.where(hit & slot, new, queue)
        # rware pays rewards[agent_id - 1]: with no agent on the goal, Python's index -1 (the last agent).
        return (queue, used + hit.astype(jnp.int32)), (hit, jnp.where(agent > 0, agent - 1, count - 1))

    carry = (state.queue, jnp.zeros((), jnp.int32))
    if goal_cells.shape[0] <= UNROLL_GOALS:
        outcomes = []
        for goal in range(goal_cells.shape[0]):
            carry, outcome = one_goal(carry, (on_goal[0][goal], on_goal[1][goal]))
            outcomes.append(outcome)
        hits, payees = (jnp.stack(column) for column in zip(*outcomes))
    else:
        carry, (hits, payees) = jax.lax.scan(one_goal, carry, on_goal)
    queue = carry[0]
    delivered, has_delivered = jnp.zeros(count, bool), state.has_delivered
    for goal in range(goal_cells.shape[0]):  # payments in goal order, as rware adds them
        hit, payee = hits[goal], agents == payees[goal]
        gain = jnp.where(params.reward_type == GLOBAL, 1.0,
                         jnp.where(payee, jnp.where(params.reward_type == TWO_STAGE, 0.5, 1.0), 0.0))
        reward = reward + jnp.where(hit, gain, 0.0).astype(jnp.float32)
        has_delivered = has_delivered | (hit & payee & (params.reward_type == TWO_STAGE))
        delivered = delivered | (hit & payee)
    return state.replace(queue=queue, has_delivered=has_delivered), reward, delivered, jnp.any(hits)


def rware_transition(state: RwareState, action: jax.Array, replacements: jax.Array, params: RwareParams,
                     message: jax.Array | None = None, tie_order: str = "set"):
    """One rware step, deterministic in ``replacements`` ``(G,)`` int32 (module docstring).

    ``action`` is ``(N,)`` int32 (rware's ``Action`` values; anything else acts as ``NOOP``),
    ``message`` ``(N, M)`` the agents' new messages (kept as they are when ``None``). Returns
    ``(next_state, reward (N,) float32, done (), info)``; ``done`` is rware's single flag (time
    or inactivity limit), ``info`` holds ``delivered (N,)`` (the agent on each paying goal),
    ``moved (N,)``, ``time_limit ()`` and ``inactivity_limit ()``. ``tie_order``: how equal chains are
    ordered (:mod:`~wrl_jax.envs.rware.conflicts`; ``"set"`` is unpatched rware's order).
    """
    action = jnp.asarray(action, jnp.int32)
    if message is not None:
        state = state.replace(message=jnp.asarray(message, jnp.float32))
    state, reward, moved = _apply_actions(state, action, params, tie_order)
    state, reward, delivered, any_delivery = _deliver(state, reward, replacements, params)
    inactive = jnp.where(any_delivery, 0, state.inactive + 1).astype(jnp.int32)
    time = state.time + 1
    time_limit = (params.max_steps > 0) & (time >= params.max_steps)
    inactivity_limit = (params.max_inactivity_steps > 0) & (inactive >= params.max_inactivity_steps)
    state = state.replace(time=time, inactive=inactive)
    info = {"delivered": delivered, "moved": moved, "time_limit": time_limit, "inactivity_limit": inactivity_limit}
    return state, reward, time_limit | inactivity_limit, info
