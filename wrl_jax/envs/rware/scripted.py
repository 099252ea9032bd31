"""A scripted fetch-and-return team for RWARE: the classical yardstick a learned team should beat.

One centralised controller sees the whole :class:`~wrl_jax.envs.rware.types.RwareState` and gives
every agent a task, a target set of cells and the move toward it:

- **fetch** (carries nothing): a requested shelf that nobody carries, assigned greedily by distance
  (the closest agent-shelf pair first, ties to the lower agent index), so no two agents chase one
  shelf; on it, ``TOGGLE_LOAD``. An unloaded agent passes under shelves, so its distance is Manhattan's.
- **deliver** (carries a requested shelf): the nearest goal; the delivery itself is passive (rware
  pays a requested shelf on a goal at the end of the step), so nothing is toggled there.
- **return** (carries a shelf no longer requested, i.e. after its delivery): the nearest free shelf
  spot (a non-highway cell with no shelf); there, ``TOGGLE_LOAD`` drops it.
- **park** (carries nothing, no shelf left to fetch: more idle agents than open requests): under the
  nearest resting unrequested shelf, off the highways the loaded agents need (they cannot enter it).

Distances are BFS fields to each agent's target set (:func:`distance_field`): a bounded
``lax.while_loop`` of 4-neighbour minima, vmapped over agents. A loaded agent's field avoids resting
shelves (rware cancels a loaded move into one), so it never bumps into a shelf.

Deadlocks: rware never commits a head-on swap, and in a 1-wide aisle two loaded agents cannot pass.
What we chose, and why (measured on tiny-2ag, tiny-4ag, small-4ag):

- an agent's field charges :data:`CROWD` extra for the cells of the agents with the right of way over
  it (:func:`outranked_by`), so it plans around them; charging every agent made two agents detour
  around each other in step, forever;
- two agents that still want each other's cells: the lower one steps to a free neighbour, and one that
  has none (in an aisle) asks its other neighbours to make room, recursively. With pure chance instead
  (a random move now and then) a pair in an aisle stayed stuck for hundreds of steps;
- chance stays as a safety net for jams no rule sees (queues, cycles of three): a uniform ``FORWARD``/
  ``LEFT``/``RIGHT`` with probability :data:`EXPLORE` (:data:`BLOCKED_EXPLORE` when driving into an
  agent), never into a shelf or a robot, and never in place of ``TOGGLE_LOAD`` (it would undo work). It
  cost 1-2 % of the deliveries when tuned (on other episodes than the evaluation's).

On the evaluation's 32 episodes (``python -m wrl_jax.plan --planner scripted``) the team returns 29.8
(tiny-2ag), 57.9 (tiny-4ag) and 41.0 (small-4ag), its worst episode within 11 % of the mean; a
uniform random team 0.03 to 0.06.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from wrl_jax.envs.rware.dynamics import TURN_LEFT, TURN_RIGHT, requested_mask
from wrl_jax.envs.rware.types import FORWARD, LEFT, NOOP, RIGHT, TOGGLE_LOAD, RwareParams, RwareState

FETCH, DELIVER, RETURN, PARK = range(4)
"""An agent's task (module docstring)."""

EXPLORE = 0.01
"""Chance of a random move on any step (module docstring: a safety net for jams the rules miss)."""
BLOCKED_EXPLORE = 0.1
"""Chance of a random move when driving into another agent."""

STEP_X = (0, 0, -1, 1)
STEP_Y = (-1, 1, 0, 0)
"""The cell ahead, by heading ``UP, DOWN, LEFT_DIR, RIGHT_DIR`` (y grows downward)."""
OPPOSITE = (1, 0, 3, 2)
CROWD = 8
"""Extra cost of entering a cell that an agent with the right of way holds: a detour of up to 8 steps beats it."""
UNREACHABLE = 1 << 20
"""The cost of cells no path reaches (above any path's: grids of up to ~10^5 cells, crowd penalties included)."""


def distance_field(seed: jax.Array, passable: jax.Array, crowd: jax.Array) -> jax.Array:
    """``(H, W)`` int32 cost from every cell to the nearest ``seed`` cell through ``passable`` cells.

    Entering a cell costs ``1 + crowd`` there (0 everywhere: BFS steps); unreachable and impassable cells
    hold :data:`UNREACHABLE`. Bellman-Ford relaxation of the 4-neighbour minimum until nothing changes (at
    most ``H W`` rounds, in practice a longest path's length), whole-grid array operations; vmapped.
    """
    height, width = seed.shape
    far = UNREACHABLE
    open_cells = passable & ~seed

    def relax(carry):
        field, _, count = carry
        padded = jnp.pad(jnp.minimum(field + 1 + crowd, far), 1, constant_values=far)
        nearest = jnp.minimum(jnp.minimum(padded[:-2, 1:-1], padded[2:, 1:-1]),
                              jnp.minimum(padded[1:-1, :-2], padded[1:-1, 2:]))
        relaxed = jnp.where(open_cells, jnp.minimum(field, nearest), field)
        return relaxed, jnp.any(relaxed != field), count + 1

    start = (jnp.where(seed, 0, far).astype(jnp.int32), jnp.ones((), bool), jnp.zeros((), jnp.int32))
    return jax.lax.while_loop(lambda carry: carry[1] & (carry[2] < height * width), relax, start)[0]


def assign_shelves(cost: jax.Array) -> jax.Array:
    """``(N,)`` int32 shelf per agent from a ``(N, S)`` cost (``>= 2^30``: not allowed), -1 for none.

    Greedy: the cheapest remaining agent-shelf pair, then its row and column are struck out, ``N``
    times (a ``fori_loop``). Not optimal, but stable from step to step as agents close in.
    """
    count, num_shelves = cost.shape
    barred = jnp.int32(1 << 30)
    rows, columns = jnp.arange(count)[:, None], jnp.arange(num_shelves)[None, :]

    def pick(_, carry):
        cost, assigned = carry
        flat = jnp.argmin(cost)
        agent, shelf = flat // num_shelves, flat % num_shelves
        ok = cost[agent, shelf] < barred
        assigned = jnp.where(ok & (jnp.arange(count) == agent), shelf, assigned)
        return jnp.where(ok & ((rows == agent) | (columns == shelf)), barred, cost), assigned

    start = (jnp.minimum(cost, barred).astype(jnp.int32), jnp.full(count, -1, jnp.int32))
    return jax.lax.fori_loop(0, count, pick, start)[1]


def outranked_by(task: jax.Array, loaded: jax.Array) -> jax.Array:
    """``(N, N)`` bool, ``[i, j]``: agent ``j`` has the right of way over ``i``.

    Delivering, then returning, then unloaded agents (which can duck under shelves); then the lower
    index. A strict total order, so two agents never both give way (nor both insist).
    """
    count = task.shape[0]
    rank = (2 * (task == DELIVER) + (task == RETURN) + 2 * loaded) * count + count - 1 - jnp.arange(count)
    return rank[None, :] > rank[:, None]


def plan(state: RwareState, params: RwareParams,
         crowd: float | jax.Array = CROWD) -> tuple[jax.Array, ...]:
    """Each agent's ``task (N,)``; its cost field, crowd penalty and ``passable`` mask ``(N, H, W)``; :func:`outranked_by`.

    The crowd penalty is on the cells of the agents that have the right of way over it: the ranking
    breaks the symmetric dance of two agents that each detour around the other, in step.
    """
    height, width = params.grid_size
    count, num_shelves = state.agent_x.shape[0], state.shelf_x.shape[0]
    cells = jnp.arange(height * width, dtype=jnp.int32)
    here = state.agent_y * width + state.agent_x
    loaded = state.carrying >= 0
    carried = jnp.any(state.carrying[:, None] == jnp.arange(num_shelves)[None, :], axis=0)
    requested = requested_mask(state.queue, num_shelves)
    open_request = requested & ~carried

    def on_cells(where: jax.Array, weight: jax.Array) -> jax.Array:
        return jnp.zeros(height * width, jnp.int32).at[where].add(weight.astype(jnp.int32))

    shelf_cell = state.shelf_y * width + state.shelf_x
    shelves_on, resting_on = on_cells(shelf_cell, jnp.ones(num_shelves)), on_cells(shelf_cell, ~carried)
    open_on = on_cells(shelf_cell, open_request)
    highway = params.highway.reshape(-1)
    goal = jnp.zeros(height * width, bool).at[params.goals[:, 1] * width + params.goals[:, 0]].set(True)

    # Unloaded agents pass under everything: their BFS distance to a shelf is the Manhattan distance.
    distance = jnp.abs(state.agent_x[:, None] - state.shelf_x) + jnp.abs(state.agent_y[:, None] - state.shelf_y)
    shelf = assign_shelves(jnp.where(~loaded[:, None] & open_request[None, :], distance, 1 << 30))
    carries_request = loaded & requested[jnp.maximum(state.carrying, 0)]
    task = jnp.where(loaded, jnp.where(carries_request, DELIVER, RETURN), jnp.where(shelf >= 0, FETCH, PARK))

    mine = cells[None, :] == here[:, None]  # (N, HW): the own cell (and the carried shelf, under its carrier)
    seed = jnp.select(
        [task[:, None] == FETCH, task[:, None] == DELIVER, task[:, None] == RETURN],
        [cells[None, :] == shelf_cell[jnp.maximum(shelf, 0)][:, None], goal[None, :],
         ~highway[None, :] & (shelves_on[None, :] - (mine & loaded[:, None]) == 0)],
        (~highway & (resting_on > 0) & (open_on == 0))[None, :])
    passable = ~loaded[:, None] | (resting_on[None, :] == 0)
    outranked = outranked_by(task, loaded)
    others = jnp.round(crowd * jnp.sum(outranked[:, :, None] & mine[None, :, :], axis=1)).astype(jnp.int32)
    shape = (count, height, width)
    field = jax.vmap(distance_field)(seed.reshape(shape), passable.reshape(shape), others.reshape(shape))
    return task, field, others.reshape(shape), passable.reshape(shape), outranked


def _steer(direction: jax.Array, heading: jax.Array, around: jax.Array) -> jax.Array:
    """The action toward ``direction``: ``FORWARD`` when facing it, else the turn, the cheaper side when behind."""
    count = heading.shape[0]
    left, right = jnp.asarray(TURN_LEFT)[heading], jnp.asarray(TURN_RIGHT)[heading]
    behind = jnp.where(around[jnp.arange(count), left] <= around[jnp.arange(count), right], LEFT, RIGHT)
    turn = jnp.where(direction == left, LEFT, jnp.where(direction == right, RIGHT, behind))
    return jnp.where(direction == heading, FORWARD, turn)


def scripted_actions(key: jax.Array, state: RwareState, params: RwareParams, env: Any,
                     explore: float | jax.Array = EXPLORE, blocked_explore: float | jax.Array = BLOCKED_EXPLORE,
                     crowd: float | jax.Array = CROWD) -> jax.Array:
    """``(N,)`` int32 actions of the scripted team (module docstring); jittable, ``env`` only for its shapes.

    The move: toward a neighbour on a cheapest path, preferring the fewest turns (``FORWARD`` when
    facing one; ``LEFT``/``RIGHT``, the nearer way round); ``TOGGLE_LOAD`` on a fetch or return target.
    Two agents that want each other's cells (a head-on swap, which rware never commits) settle it by
    rank: the lower one steps to a free neighbour instead, the fewest turns first.
    """
    task, field, others, passable, outranked = plan(state, params, crowd)
    count, width = env.num_agents, env.width
    agents = jnp.arange(count)
    x, y, heading = state.agent_x, state.agent_y, state.agent_dir
    here = y * width + x
    step_x, step_y = jnp.asarray(STEP_X, jnp.int32), jnp.asarray(STEP_Y, jnp.int32)
    near_x, near_y = x[:, None] + step_x, y[:, None] + step_y  # (N, 4) by heading
    via = jnp.pad(jnp.minimum(field + 1 + others, UNREACHABLE), ((0, 0), (1, 1), (1, 1)), constant_values=UNREACHABLE)
    around = via[agents[:, None], near_y + 1, near_x + 1]
    at = field[agents, y, x]

    directions = jnp.arange(4)[None, :]
    turns = jnp.where(directions == heading[:, None], 0,
                      jnp.where(directions == jnp.asarray(OPPOSITE)[heading][:, None], 2, 1))
    cheapest = (around <= at[:, None]) & (around < UNREACHABLE)
    best = jnp.argmin(jnp.where(cheapest, turns, 3), axis=1)
    moving = (at > 0) & jnp.any(cheapest, axis=1)
    toggle = (at == 0) & ((task == FETCH) | (task == RETURN))
    action = jnp.where(toggle, TOGGLE_LOAD, jnp.where(moving, _steer(best, heading, around), NOOP))

    # Head-on: i wants j's cell and j wants i's (possible when a detour costs more than the crowd penalty).
    want = jnp.where(moving, (y + step_y[best]) * width + x + step_x[best], -1)
    facing = want[:, None] == here[None, :]  # [i, j]: i wants j's cell
    gives_way = facing & facing.T & outranked  # [i, j]: i steps aside for j
    inside = (near_x >= 0) & (near_x < width) & (near_y >= 0) & (near_y < env.height)
    flat = jnp.clip(near_y, 0, env.height - 1) * width + jnp.clip(near_x, 0, width - 1)
    free = inside & passable.reshape(count, -1)[agents[:, None], flat] & ~jnp.any(
        flat[:, :, None] == here[None, None, :], axis=2)
    # One with no free neighbour (in a 1-wide aisle, say) asks its other neighbours to make room, and so on.
    next_to = jnp.abs(x[:, None] - x[None, :]) + jnp.abs(y[:, None] - y[None, :]) == 1

    def make_room(_, gives_way):
        yielding = jnp.any(gives_way, axis=1)
        stuck = yielding & ~jnp.any(free, axis=1)
        return gives_way | (stuck[None, :] & next_to & ~gives_way.T & ~yielding[:, None])

    yields = jnp.any(jax.lax.fori_loop(0, count - 1, make_room, gives_way), axis=1)
    aside = jnp.argmin(jnp.where(free, turns * UNREACHABLE + around, 4 * UNREACHABLE), axis=1)
    dodge = jnp.where(jnp.any(free, axis=1), _steer(aside, heading, around), NOOP)
    action = jnp.where(yields & (action != TOGGLE_LOAD), dodge, action)

    ahead = flat[agents, heading]
    someone_ahead = inside[agents, heading] & jnp.any(ahead[:, None] == here[None, :], axis=1)
    chance = jnp.where((action == FORWARD) & someone_ahead, blocked_explore, explore)
    key_draw, key_move = jax.random.split(key)
    shake = (jax.random.uniform(key_draw, (count,)) < chance) & (action != TOGGLE_LOAD)
    random_move = jax.random.randint(key_move, (count,), FORWARD, RIGHT + 1, dtype=jnp.int32)
    random_move = jnp.where((random_move == FORWARD) & ~free[agents, heading], LEFT, random_move)  # no bumps
    return jnp.where(shake, random_move, action).astype(jnp.int32)


def scripted_policy(env: Any, params: RwareParams, explore: float | jax.Array = EXPLORE,
                    blocked_explore: float | jax.Array = BLOCKED_EXPLORE,
                    crowd: float | jax.Array = CROWD) -> Callable[[jax.Array, RwareState], jax.Array]:
    """``policy(key, state) -> actions`` for :func:`~wrl_jax.envs.rware.evaluation.run_episodes` (``sees_state``);
    :func:`~wrl_jax.envs.rware.evaluation.team_episodes` runs it on the evaluation's episodes."""
    return lambda key, state: scripted_actions(key, state, params, env, explore, blocked_explore, crowd)
