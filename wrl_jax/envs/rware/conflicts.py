"""Who moves in an RWARE step: rware 2.0.0's move graph, resolved with array operations.

rware (NOTES.md section 4, steps 2-4) builds a ``networkx.DiGraph`` with an edge from each
agent's cell to its target cell (a self-loop for every agent that does not move), splits it
into weakly connected components and commits, per component:

- with a cycle: the agents on the cycle, unless it is a head-on swap (length 2), which
  commits nobody; agents queued behind a cycle never move;
- without a cycle (a tree into one empty cell): the agents on ``dag_longest_path``, the
  longest chain; at each cell going back from the empty one, the first predecessor of
  maximal chain length in the component's predecessor order.

Each cell holds at most one agent, so every node has at most one out-edge: the graph is a
partial function ``next`` on agents, and everything above follows from walking it ``N``
times (one ``lax.scan``, no loop over agents in Python).

Ties (two equally long chains into one cell) go to the predecessor that comes first in the
component copy's node order. ``tie_order="set"`` (the default) is the order unpatched rware
really iterates: the graph's insertion order (agent ``i``'s cell at ``2i``, its target at
``2i + 1``, a cell keeping its first rank) for a component holding at least half the graph's
nodes, CPython's hash-set order for a smaller one (:mod:`~wrl_jax.envs.rware.set_order`: up to 4
agents one entry of a table computed at trace time, from 5 on emulated only on steps where some
environment of the batch has such a tie).
``tie_order="insertion"`` uses insertion order everywhere: what ``networkx`` gives when
``subgraph`` keeps that order.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from wrl_jax.core.environment import materialise, only_where
from wrl_jax.envs.rware.set_order import component_rank, triple_index, triple_table
from wrl_jax.envs.rware.types import DOWN, FORWARD, LEFT_DIR, RIGHT_DIR, UP


def forward_targets(x: jax.Array, y: jax.Array, heading: jax.Array, action: jax.Array, height: int,
                    width: int) -> tuple[jax.Array, jax.Array]:
    """Each agent's requested cell ``(tx, ty)``: one cell ahead for ``FORWARD`` (clamped to the grid), else its own."""
    forward = action == FORWARD
    dx = (heading == RIGHT_DIR).astype(jnp.int32) - (heading == LEFT_DIR).astype(jnp.int32)
    dy = (heading == DOWN).astype(jnp.int32) - (heading == UP).astype(jnp.int32)
    tx = jnp.where(forward, jnp.clip(x + dx, 0, width - 1), x)
    ty = jnp.where(forward, jnp.clip(y + dy, 0, height - 1), y)
    return tx, ty


def cancelled_moves(moving: jax.Array, loaded: jax.Array, shelf_there: jax.Array,
                    occupant_loaded: jax.Array) -> jax.Array:
    """rware's cancel pass (on the pre-step grid): ``(N,)`` bool, True for a loaded agent heading into a shelf.

    A loaded agent cannot drive into a cell that shows a shelf, unless that cell holds an
    agent that is itself loaded (which may drive away this step; the graph decides).
    Unloaded agents are never cancelled: they pass under shelves. The inputs are per agent:
    it moves, it is loaded, its target shows a shelf, its target holds a loaded agent.
    """
    return loaded & moving & shelf_there & ~occupant_loaded


UNROLL_LIMIT = 4
"""Up to this many agents the graph is written out agent by agent (:func:`_resolve_unrolled`).

Not above 4: its set-order ties (:func:`_small_pair_ranks`) know the one shape 4 agents allow."""

TIE_ORDERS = ("set", "insertion")
"""How ties between equal chains are ordered (module docstring): rware's real order, or insertion order."""


def check_tie_order(tie_order: str) -> str:
    if tie_order not in TIE_ORDERS:
        raise ValueError(f"tie_order must be one of {TIE_ORDERS} ('set': unpatched rware's node order, "
                         f"'insertion': the graph's insertion order), got {tie_order!r}")
    return tie_order


def _tie_rank(start: jax.Array, target: jax.Array, width: int, tied: jax.Array, insertion: jax.Array) -> jax.Array:
    """Each agent's start cell's place in its component's node order, as unpatched networkx iterates it.

    ``tied`` (N,) marks the agents whose rank decides something (an equally deep rival for the same
    cell); the emulation runs in a batched ``while`` only while some environment has one, else
    ``insertion`` (the insertion rank) is kept as it is. The two scales (a position within the
    component, or G's ``2i``/``2k+1``) mix safely: only rivals for one cell, always in one component,
    are compared, and every rank stays below the key's ``2 N + 3``.
    """
    count = start.shape[0]

    def emulate(data: jax.Array) -> jax.Array:  # reads its inputs from the loop's carry: XLA cannot hoist it
        cells = data.astype(jnp.int32)
        return component_rank(cells[:count], cells[count:2 * count], width, needed=cells[2 * count:] > 0)

    inputs = jnp.concatenate([start, target, tied.astype(jnp.int32)]).astype(jnp.uint32)
    return only_where(jnp.any(tied), emulate, inputs, insertion.astype(jnp.int32))


def resolve_moves(start: jax.Array, target: jax.Array, *, grid_size: tuple[int, int], tie_order: str) -> jax.Array:
    """The committed agents ``(N,)`` bool of rware's graph, from flat start and target cells ``(N,)`` int32.

    Cancelled and stationary agents must come with ``target == start`` (their self-loop); every other
    target is one of the start's four neighbours (rware moves one cell: the 4-agent set-order lookup
    relies on it). A committed agent moves to its target; an uncommitted one (only ever a mover) stays.
    ``grid_size`` is ``(H, W)``: cells are ``y W + x``, and ``tie_order="set"`` hashes ``(x, y)``.
    """
    check_tie_order(tie_order)
    height, width = (int(v) for v in grid_size)
    if start.shape[0] <= UNROLL_LIMIT:
        return _resolve_unrolled(start, target, (height, width), tie_order)
    count = start.shape[0]
    agents = jnp.arange(count, dtype=jnp.int32)
    sink = count  # the empty cell a chain ends in (one index for all: chains are told apart by target)
    onto = target[:, None] == start[None, :]  # [i, j]: agent i heads for agent j's cell
    successor = jnp.min(jnp.where(onto, agents[None, :], sink), axis=1)  # the first such j, as argmax
    extended = jnp.append(successor, sink)

    paths = [agents]  # paths[k][i] = next^k(i), k = 0 .. N
    for _ in range(count):
        paths.append(extended[paths[-1]])
    walk = jnp.stack(paths)
    visits = walk[:, :, None] == agents[None, None, :]  # [k, i, j]: the walk from i is at j after k

    on_cycle = jnp.any(walk[1:] == agents[None, :], axis=0)
    head_on = (paths[1] != agents) & (paths[1] < sink) & (paths[2] == agents)
    in_tree = paths[count] == sink

    # Chain length into each agent: the most steps any agent needs to reach it (trees only).
    steps = jnp.arange(count + 1, dtype=jnp.int32)[:, None, None]
    depth = jnp.max(jnp.where(visits, steps, 0), axis=(0, 1))
    # rware's node order: agent i's cell is inserted at 2i unless an earlier agent's target put it at 2k+1.
    rank = jnp.minimum(2 * agents, jnp.min(jnp.where(onto, 2 * agents[:, None] + 1, 2 * count + 2), axis=0))
    rivals = (target[:, None] == target[None, :]) & in_tree[None, :]  # [i, j]: tree agents sharing i's target
    if tie_order == "set":  # only a tie in a component small enough for networkx to iterate a set needs it
        equal = rivals & (depth[None, :] == depth[:, None]) & (agents[None, :] != agents[:, None])
        last = jnp.take_along_axis(walk, jnp.sum(walk < sink, axis=0, keepdims=True) - 1, axis=0)[0]
        end = target[last]  # the empty cell the agent's chain ends in (trees only)
        nodes = jnp.sum(in_tree[None, :] & (end[None, :] == end[:, None]), axis=1) + 1  # its component's size
        empty = successor == sink
        earlier = agents[None, :] < agents[:, None]
        fresh = empty & ~jnp.any(earlier & (target[None, :] == target[:, None]), axis=1)
        small = 2 * nodes < count + jnp.sum(fresh)  # FilterAtlas: 2 * len(c) < len(G)
        rank = _tie_rank(start, target, width, in_tree & small & jnp.any(equal, axis=1), rank)
    key = depth * (2 * count + 3) - rank  # longer chain first, then earlier in the component's node order
    best = key >= jnp.max(jnp.where(rivals, key[None, :], jnp.iinfo(jnp.int32).min), axis=1)
    chosen = in_tree & best
    # On the longest path: every agent from here to the sink was chosen.
    on_longest = in_tree & ~jnp.any(visits[:count] & ~chosen[None, None, :], axis=(0, 2))
    return (on_cycle & ~head_on) | on_longest


def _resolve_unrolled(start: jax.Array, target: jax.Array, grid_size: tuple[int, int], tie_order: str) -> jax.Array:
    """:func:`resolve_moves` for a few agents, as scalars: every ``[i, j]`` term its own elementwise op.

    Why: under ``vmap`` each scalar is a batch-long vector, so the whole graph fuses into elementwise
    loops over the batch; the array form reduced over axes of length ``N`` (a scalar loop per
    element) in a dozen small fusions, a quarter of a step at ``N = 4``.
    """
    count = start.shape[0]
    agents = range(count)
    sink = count
    cell = [start[j] for j in agents]
    goal = [target[i] for i in agents]
    onto = [[goal[i] == cell[j] for j in agents] for i in agents]  # agent i heads for agent j's cell
    successor = []
    for i in agents:  # the first such j (argmax), else the sink
        node = jnp.int32(sink)
        for j in reversed(agents):
            node = jnp.where(onto[i][j], j, node)
        successor.append(node)

    def follow(node):
        step = jnp.int32(sink)
        for j in agents:
            step = jnp.where(node == j, successor[j], step)
        return step

    paths = [[jnp.int32(i) for i in agents], successor]  # paths[k][i] = next^k(i)
    for _ in range(max(count - 1, 1)):  # (at least next^2, for the head-on swap)
        paths.append([follow(node) for node in paths[-1]])
    in_tree = [paths[count][i] == sink for i in agents]
    # Chain length into each agent (trees only), rware's insertion rank, then the sort key of the longest path.
    depth = [jnp.int32(0)] * count
    for k in range(1, count + 1):
        for i in agents:
            for j in agents:
                depth[j] = jnp.where(paths[k][i] == j, jnp.maximum(depth[j], k), depth[j])
    rank = []
    for i in agents:
        rank.append(jnp.int32(2 * i))
        for k in agents:
            rank[i] = jnp.where(onto[k][i], jnp.minimum(rank[i], 2 * k + 1), rank[i])
    if tie_order == "set":
        rank = _small_pair_ranks(cell, goal, successor, depth, rank, grid_size)
    key = [depth[i] * (2 * count + 3) - rank[i] for i in agents]
    chosen = []
    for i in agents:
        best = jnp.bool_(True)
        for j in agents:
            best = best & ~((goal[i] == goal[j]) & in_tree[j] & (key[j] > key[i]))
        chosen.append(in_tree[i] & best)
    committed = []
    for i in agents:
        on_cycle = functools.reduce(jnp.logical_or, [paths[k][i] == i for k in range(1, count + 1)])
        head_on = (successor[i] != i) & (successor[i] < sink) & (paths[2][i] == i)
        blocked = functools.reduce(jnp.logical_or, [(paths[k][i] == j) & ~chosen[j] for k in agents for j in agents])
        committed.append((on_cycle & ~head_on) | (in_tree[i] & ~blocked))
    return jnp.stack(committed)


def _small_pair_ranks(cell: list, goal: list, successor: list, depth: list, rank: list,
                      grid_size: tuple[int, int]) -> list:
    """:func:`_resolve_unrolled`'s ranks with unpatched networkx's order where it differs (up to 4 agents).

    A component networkx iterates as a hash set has ``2 * len(c) < len(G) <= 2 N``: up to 4 agents,
    a tie there is two agents ``i < j`` with nobody behind them driving into one empty cell, while
    the others reach at least two more empty cells (``len(G) >= 7``). Whichever of the two comes
    later in the set's order (:func:`~wrl_jax.envs.rware.set_order.first_precedes_in_triple`) is
    given the last rank, so the other wins; read from :func:`~wrl_jax.envs.rware.set_order.triple_table`.
    """
    count, sink = len(cell), len(cell)
    if 2 * count < 7:  # len(G) <= 2 N: with 3 agents or fewer networkx always keeps insertion order
        return list(rank)
    assert count == 4, "with 5 agents two such pairs can coexist, and from 6 longer ties: use _tie_rank"
    empty = [successor[i] == sink for i in range(count)]  # heads for a cell no agent stands on
    fresh = [empty[i] & functools.reduce(jnp.logical_and, [goal[j] != goal[i] for j in range(i)], jnp.bool_(True))
             for i in range(count)]
    nodes = count + sum(f.astype(jnp.int32) for f in fresh)  # len(G): the agents' cells and the empty targets
    pairs = [(i, j) for i in range(count) for j in range(i + 1, count)]
    found = [empty[i] & (goal[i] == goal[j]) & (depth[i] == 0) & (depth[j] == 0) & (2 * 3 < nodes) for i, j in pairs]
    # The flags, the lookup and the ranks are materialised: fused into their consumers, XLA rebuilt the graph
    # above them per use and per element (bench/results/rware/NOTES.md has the measurement).
    packed = materialise(sum(hit.astype(jnp.int32) << k for k, hit in enumerate(found)))
    found = [((packed >> k) & 1) == 1 for k in range(len(pairs))]
    # At most one such pair: the three cells are picked by sums; the set order is one entry of a table.
    first, middle = [sum(jnp.where(hit, values[i], 0) for hit, (i, _) in zip(found, pairs)) for values in (cell, goal)]
    later = sum(jnp.where(hit, cell[j], 0) for hit, (_, j) in zip(found, pairs))
    table = jnp.asarray(triple_table(*grid_size).reshape(-1))  # every case, from Python's own hash, at trace time
    index = triple_index(first, middle, later, grid_size[1])
    i_first = materialise(jnp.take(table, materialise(index), mode="clip"))
    rank = list(rank)
    for hit, (i, j) in zip(found, pairs):
        rank[i] = jnp.where(hit & ~i_first, 2 * count + 2, rank[i])
        rank[j] = jnp.where(hit & i_first, 2 * count + 2, rank[j])
    return list(materialise(jnp.stack(rank)))
