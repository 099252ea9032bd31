"""Classical fleet planners in JAX: greedy descent and PIBT (Okumura et al., IJCAI 2019).

Both are pure functions of arrays, jittable and vmappable, so a batch of
fleets is planned inside the same compiled program that steps them.

The planners see a robot's world through ``cand_dist (K, 5)``: the BFS
distance to the robot's current target (its item while not carrying, else its
station) of the cell that each action ``a`` (0 up, 1 down, 2 left, 3 right,
4 wait; :data:`wrl_jax.core.grid.MOVES_WITH_WAIT`) would reach, with
:data:`~wrl_jax.core.grid.UNREACHABLE` where that cell is off the grid or a
shelf. PIBT also needs ``cand_cell (K, 5)``: an integer id of each such cell
(equal ids are the same cell), so the core below knows nothing about grids.

**Greedy** (:func:`greedy_actions`): the lowest-index move whose cell is one
step closer to the target; wait when on the target or when no move helps.
It ignores the other robots, so the environment's conflict rule blocks it.

**PIBT** (:func:`pibt_actions`). Each step, robots are planned in decreasing
priority; a robot takes its most preferred candidate cell that nobody has
reserved for the next step and that is not its pusher's current cell (no
swaps); if a lower-priority undecided robot stands there, that robot is
pushed (it inherits the priority) and must move away, recursively; if it
cannot, the pusher tries its next candidate (backtracking); a robot that runs
out of candidates stays. Rules where the paper leaves a choice:

- candidates are the five actions ordered by ``(distance to target, action
  index)``, shelves and off-grid cells excluded; on a grid a neighbour's
  distance is the robot's own plus or minus one, so this is: the moves one
  step closer (in action order), then waiting, then the moves away;
- priority (:class:`PibtState`): ``age * K + tiebreak``, where ``age`` counts
  the steps since the robot last reached a target (0 at reset and at every
  pickup or delivery) and ``tiebreak`` is a permutation of ``0..K-1``
  (``K - 1 - i`` for robot ``i`` by default, so robot 0 wins ties; or a
  random permutation from a key, kept for the whole run). Integers, unique
  per robot: a total order. ``age`` saturates well below ``int32`` overflow.

The paper's recursion becomes an explicit stack driven by one
``lax.while_loop`` (:func:`pibt_choices`): fewer than ``3K`` iterations of
``O(K)`` vector work per step, no Python loop over robots. The moves it
emits never put two robots in one cell and never swap two robots, so
FLEET_SPEC.md's conflict rule accepts all of them in its first round
(following a robot that leaves, and rotations of four or more robots, are
allowed there and may occur here).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from wrl_jax.core.grid import MOVES_WITH_WAIT, UNREACHABLE
from wrl_jax.envs.fleet.types import FleetParams, FleetState

NUM_CANDIDATES = 5
"""Actions a robot chooses from: four moves, then wait."""
WAIT = 4

PLANNERS = ("greedy", "pibt")
"""The planner names :func:`plan` knows."""

CPU_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}
"""XLA options for programs whose hot part is PIBT, on the CPU backend (:func:`compiler_options`).

PIBT's ``lax.while_loop`` of small ``(K,)``-wide selects and gathers runs faster when XLA's CPU
backend emits its fusions with the classic elemental emitter instead of the newer MLIR fusion
emitters: PIBT alone on 4,096 recorded states 1.3x at K = 8 and 1.2x at K = 4 (``bench/investigations/pibt_profile.py``,
timed interleaved; 1.3-1.35x at K = 8 in three runs of ``bench/fleet_throughput.py``), the vmapped
fleet step with PIBT actions 1.3x, :func:`wrl_jax.envs.fleet.metrics.run_episodes` 1.15x; the same
moves bit for bit (tested). The step with random actions goes the other way (2x slower with
the classic emitter), so this is set per program, not for the process."""


def compiler_options() -> dict[str, bool]:
    """``jax.jit(..., compiler_options=...)`` for a program dominated by PIBT: :data:`CPU_COMPILER_OPTIONS` on CPU."""
    return dict(CPU_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else {}


# ------------------------------------------------------------------ candidates
def candidate_cells(pos: jax.Array, size: int) -> tuple[jax.Array, jax.Array]:
    """The five cells the actions reach, ``(K, 5, 2)`` int32, and whether each is on the grid ``(K, 5)``."""
    cells = pos[:, None, :] + jnp.asarray(MOVES_WITH_WAIT)[None, :, :]
    on_grid = jnp.all((cells >= 0) & (cells < size), axis=-1)
    return cells, on_grid


def candidate_distances(
    pos: jax.Array, item: jax.Array, station: jax.Array, carrying: jax.Array,
    item_dist: jax.Array, station_dist: jax.Array,
) -> jax.Array:
    """``cand_dist (K, 5)``: the BFS distance to each robot's current target of each action's cell.

    Reads only the five entries per robot from the ``(I, N, N)`` and
    ``(G, N, N)`` tables (no ``(K, N, N)`` field is gathered). Off-grid cells
    get ``UNREACHABLE``; shelves already have it in the tables.
    """
    size = item_dist.shape[-1]
    cells, on_grid = candidate_cells(pos, size)
    rows, cols = jnp.clip(cells[..., 0], 0, size - 1), jnp.clip(cells[..., 1], 0, size - 1)
    # One gather from the item tables stacked on the station tables (under vmap with shared
    # params the stack is built once per batch), not one from each and a select.
    tables = jnp.concatenate([item_dist, station_dist], axis=0)
    target_row = jnp.where(carrying, item_dist.shape[0] + station, item)
    dist = tables[target_row[:, None], rows, cols]
    return jnp.where(on_grid, dist, UNREACHABLE).astype(jnp.int32)


def candidate_ids(pos: jax.Array, size: int) -> jax.Array:
    """``cand_cell (K, 5)``: the row-major index of each action's cell, ``-2`` off the grid."""
    cells, on_grid = candidate_cells(pos, size)
    return jnp.where(on_grid, cells[..., 0] * size + cells[..., 1], -2).astype(jnp.int32)


# ------------------------------------------------------------------ greedy
def greedy_actions(cand_dist: jax.Array) -> jax.Array:
    """Per robot, the lowest-index move one step closer to its target, else wait: ``(K,)`` int32."""
    here = cand_dist[:, WAIT:WAIT + 1]
    closer = (cand_dist[:, :WAIT] == here - 1) & (here > 0)
    return _first_action(closer)


def _first_action(allowed: jax.Array) -> jax.Array:
    """``(K,)`` int32: per row of ``allowed (K, 4)`` the lowest move index set, else wait.

    A ``min`` over ``where(allowed, index, WAIT)``: one plain reduction, where ``argmax`` is a
    reduction over (value, index) pairs that XLA's CPU backend compiles to a slow loop.
    """
    moves = jnp.arange(WAIT, dtype=jnp.int32)
    return jnp.min(jnp.where(allowed, moves[None, :], WAIT), axis=1).astype(jnp.int32)


# ------------------------------------------------------------------ PIBT priorities
@struct.dataclass
class PibtState:
    """PIBT's lifelong priorities, carried across steps and reset with the episode.

    Attributes:
        age: ``(K,)`` int32 steps since each robot last reached its target.
        tiebreak: ``(K,)`` int32 a permutation of ``0..K-1``; the higher wins among equal ages.
    """

    age: jax.Array
    tiebreak: jax.Array


def pibt_init(num_robots: int, key: jax.Array | None = None) -> PibtState:
    """Fresh priorities: all ages 0; tie-break by robot index (robot 0 first), or a random permutation."""
    if num_robots < 1:
        raise ValueError(f"num_robots must be at least 1, got {num_robots}")
    if key is None:
        tiebreak = jnp.arange(num_robots - 1, -1, -1, dtype=jnp.int32)
    else:
        tiebreak = jax.random.permutation(key, num_robots).astype(jnp.int32)
    return PibtState(age=jnp.zeros(num_robots, dtype=jnp.int32), tiebreak=tiebreak)


def pibt_priorities(state: PibtState) -> jax.Array:
    """``age * K + tiebreak``, ``(K,)`` int32: unique, larger is more urgent."""
    return state.age * state.age.shape[0] + state.tiebreak


def pibt_update(state: PibtState, reached: jax.Array) -> PibtState:
    """After a transition: ages of robots that reached their target (picked up or delivered) go to 0, others grow.

    Ages saturate at ``(2**31 - 1) // K - 1`` so that the priority never overflows.
    """
    cap = (2**31 - 1) // state.age.shape[0] - 1
    age = jnp.where(reached, 0, jnp.minimum(state.age + 1, cap)).astype(jnp.int32)
    return state.replace(age=age)


# ------------------------------------------------------------------ PIBT core
_FAR = 1 << 20
"""Caps distances in the preference keys (distances on any grid here are far below it)."""

NO_ENTRY = jnp.iinfo(jnp.int32).max
"""The preference key of a cell a robot may not enter (:func:`preference_keys`): above every other key."""


@struct.dataclass
class _Search:
    """The explicit stack of one PIBT step (see :func:`pibt_choices`), kept as parent links."""

    next_cell: jax.Array  # (K,) int32 cell reserved for t+1, -1 while undecided
    floor: jax.Array  # (K,) int32 least preference key the robot may still take (its reserved one while it holds it)
    pusher: jax.Array  # (K,) int32 the robot that pushed it (its parent frame), -1 for a root
    top: jax.Array  # () int32 the robot searching now (top of the stack), -1 when the stack is empty


def preference_keys(cand_cell: jax.Array, cand_dist: jax.Array) -> jax.Array:
    """Each robot's candidates in action order as preference keys ``(K, 5)`` int32: less is preferred.

    The key orders a robot's candidates as PIBT prefers them: ``distance * 8 + action``, so by
    distance to the target, ties by action index; a cell it may not enter (a shelf, off the grid)
    gets :data:`NO_ENTRY`, above every other key. Keys are unique per robot, so "the preferred
    open candidate" is the open one with the least key, "the candidates after the one it holds"
    are those with a larger key, and a key's low three bits are its action: the search never
    needs the lists sorted.
    """
    key = jnp.minimum(cand_dist, _FAR) * 8 + jnp.arange(NUM_CANDIDATES, dtype=jnp.int32)
    enterable = (cand_dist < UNREACHABLE) & (cand_cell >= 0)
    return jnp.where(enterable, key, NO_ENTRY).astype(jnp.int32)


def pibt_choices(cand_cell: jax.Array, cand_dist: jax.Array, priority: jax.Array) -> jax.Array:
    """PIBT's next cell per robot, as the chosen action ``(K,)`` int32 (4 = stay).

    One ``lax.while_loop`` iteration is one try of the robot on top of the
    stack (with an empty stack, of the most urgent undecided robot, which
    becomes a root): it reserves its preferred candidate (least key of
    :func:`preference_keys`) among those at or after its floor that it may enter,
    not reserved, and not its pusher's cell. Then
    either an undecided robot stands there (push it: it searches next), or
    nobody does (success: every pusher returns valid as soon as its child
    does, so the whole stack is done at once), or there was no such cell (it
    stays; its pusher drops the reservation and raises its floor past it).
    Every robot is pushed at most once and gives up at most once, and each
    success ends a root's search, so a step takes fewer than ``3K`` iterations. The body uses only
    ``(K,)``- and ``(5,)``-wide selects and ``(5, K)`` comparisons (no scatter, no sort), which is
    what makes it cheap under ``vmap``; who stands on a cell is looked up for the one cell taken.

    Args:
        cand_cell: ``(K, 5)`` int32 cell id of each action's cell (negative
            off the grid); column 4 is the robot's own cell, the own cells distinct.
        cand_dist: ``(K, 5)`` int32 distance to the robot's target of each
            action's cell, ``>= UNREACHABLE`` for cells it may not enter.
        priority: ``(K,)`` distinct int32, larger first.
    """
    num_robots = cand_cell.shape[0]
    robots = jnp.arange(num_robots, dtype=jnp.int32)
    pref_key = preference_keys(cand_cell, cand_dist)
    here = cand_cell[:, WAIT]
    lowest = jnp.iinfo(jnp.int32).min

    def running(s: _Search) -> jax.Array:
        return (s.top >= 0) | jnp.any(s.next_cell < 0)

    def try_once(s: _Search) -> _Search:
        undecided = s.next_cell < 0
        at_root = s.top < 0
        most_urgent = jnp.max(jnp.where(undecided, priority, lowest))  # priorities are distinct
        root = jnp.max(jnp.where(undecided & (priority == most_urgent), robots, 0))
        i = jnp.where(at_root, root, s.top).astype(jnp.int32)
        parent = jnp.where(at_root, -1, s.pusher[i])
        cells, keys = cand_cell[i], pref_key[i]
        open_ = (
            (keys >= s.floor[i])
            & ~jnp.any(cells[:, None] == s.next_cell[None, :], axis=1)
            & ((parent < 0) | (cells != here[jnp.maximum(parent, 0)]))  # never into the pusher's cell: no swap
        )
        best = jnp.min(jnp.where(open_, keys, NO_ENTRY))
        found = best < NO_ENTRY
        cell = cells[jnp.where(found, best % 8, WAIT)]  # a key's low three bits are its action
        holder = jnp.max(jnp.where(here == cell, robots, -1))  # own cells are distinct: one at most
        push = found & (holder >= 0) & (holder != i) & undecided[jnp.maximum(holder, 0)]

        is_i, is_parent = robots == i, (robots == parent) & ~found
        next_cell = jnp.where(is_i, jnp.where(found, cell, here[i]), s.next_cell)
        next_cell = jnp.where(is_parent, -1, next_cell)  # i stays on the cell its pusher had reserved
        floor = jnp.where(is_i & found, best, jnp.where(is_parent, s.floor + 1, s.floor))
        pusher = jnp.where((robots == holder) & push, i, s.pusher)
        top = jnp.where(push, holder, jnp.where(found, -1, parent))
        return _Search(next_cell=next_cell, floor=floor, pusher=pusher, top=top.astype(jnp.int32))

    init = _Search(
        next_cell=jnp.full(num_robots, -1, dtype=jnp.int32),
        floor=jnp.zeros(num_robots, dtype=jnp.int32),
        pusher=jnp.full(num_robots, -1, dtype=jnp.int32),
        top=jnp.full((), -1, dtype=jnp.int32),
    )
    final = jax.lax.while_loop(running, try_once, init)
    chosen = (final.next_cell[:, None] == cand_cell[:, :WAIT]) & (cand_dist[:, :WAIT] < UNREACHABLE)
    return _first_action(chosen)


def pibt_actions(pos: jax.Array, cand_dist: jax.Array, priority: jax.Array, size: int) -> jax.Array:
    """PIBT actions ``(K,)`` int32 for robots at ``pos (K, 2)`` on an ``size x size`` grid."""
    return pibt_choices(candidate_ids(pos, size), cand_dist, priority)


# ------------------------------------------------------------------ on a fleet
def check_planner(name: str) -> str:
    """``name`` if it is a known planner, else a ``ValueError`` listing them."""
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; known: {', '.join(PLANNERS)}")
    return name


def fleet_candidate_distances(state: FleetState, params: FleetParams) -> jax.Array:
    """:func:`candidate_distances` of a fleet state: ``(K, 5)`` int32, BFS distance to each robot's target."""
    return candidate_distances(state.pos, state.item, state.station, state.carrying,
                               params.item_dist, params.station_dist)


def plan(name: str, priorities: PibtState, state: FleetState, params: FleetParams) -> jax.Array:
    """The ``(K,)`` int32 actions of planner ``name`` (static) in ``state``; greedy ignores the priorities."""
    cand_dist = fleet_candidate_distances(state, params)
    if check_planner(name) == "greedy":
        return greedy_actions(cand_dist)
    return pibt_actions(state.pos, cand_dist, pibt_priorities(priorities), params.shelves.shape[-1])


def next_priorities(priorities: PibtState, flags: dict[str, jax.Array], done: jax.Array) -> PibtState:
    """Priorities after a transition with ``flags`` (the env's ``info``); all ages 0 when the episode ended.

    A robot reached its target when it picked up or delivered (FLEET_SPEC.md
    step 5). The tie-break permutation is kept across episodes.
    """
    updated = pibt_update(priorities, flags["picked_up"] | flags["delivered"])
    return updated.replace(age=jnp.where(done, 0, updated.age))
