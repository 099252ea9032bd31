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
times (one ``lax.scan``, no loop over agents in Python). Tie-breaking follows the order in
which rware inserts nodes (agent ``i``'s cell at ``2i``, its target at ``2i + 1``, a cell
keeping its first rank): what ``networkx`` gives when ``subgraph`` keeps that order.
Unpatched ``networkx`` may iterate some components in hash-set order instead (NOTES.md 9.1),
which this module does not emulate.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

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
"""Up to this many agents the graph is written out agent by agent (:func:`_resolve_unrolled`)."""


def resolve_moves(start: jax.Array, target: jax.Array) -> jax.Array:
    """The committed agents ``(N,)`` bool of rware's graph, from flat start and target cells ``(N,)`` int32.

    Cancelled and stationary agents must come with ``target == start`` (their self-loop). A
    committed agent moves to its target; an uncommitted one (only ever a mover) stays.
    """
    if start.shape[0] <= UNROLL_LIMIT:
        return _resolve_unrolled(start, target)
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
    key = depth * (2 * count + 3) - rank  # longer chain first, then earlier in insertion order
    rivals = (target[:, None] == target[None, :]) & in_tree[None, :]  # [i, j]: tree agents sharing i's target
    best = key >= jnp.max(jnp.where(rivals, key[None, :], jnp.iinfo(jnp.int32).min), axis=1)
    chosen = in_tree & best
    # On the longest path: every agent from here to the sink was chosen.
    on_longest = in_tree & ~jnp.any(visits[:count] & ~chosen[None, None, :], axis=(0, 2))
    return (on_cycle & ~head_on) | on_longest


def _resolve_unrolled(start: jax.Array, target: jax.Array) -> jax.Array:
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
    key = []
    for i in agents:
        rank = jnp.int32(2 * i)
        for k in agents:
            rank = jnp.where(onto[k][i], jnp.minimum(rank, 2 * k + 1), rank)
        key.append(depth[i] * (2 * count + 3) - rank)
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
