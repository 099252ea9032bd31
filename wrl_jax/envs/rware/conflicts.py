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


def cancelled_moves(x: jax.Array, y: jax.Array, tx: jax.Array, ty: jax.Array, carrying: jax.Array,
                    agent_grid: jax.Array, shelf_grid: jax.Array) -> jax.Array:
    """rware's cancel pass (on the pre-step grid): ``(N,)`` bool, True for a loaded agent heading into a shelf.

    A loaded agent cannot drive into a cell that shows a shelf, unless that cell holds an
    agent that is itself loaded (which may drive away this step; the graph decides).
    Unloaded agents are never cancelled: they pass under shelves.
    """
    loaded = carrying >= 0
    moving = (tx != x) | (ty != y)
    occupant = agent_grid[ty, tx]
    occupant_loaded = (occupant > 0) & loaded[jnp.maximum(occupant - 1, 0)]
    return loaded & moving & (shelf_grid[ty, tx] > 0) & ~occupant_loaded


def resolve_moves(start: jax.Array, target: jax.Array) -> jax.Array:
    """The committed agents ``(N,)`` bool of rware's graph, from flat start and target cells ``(N,)`` int32.

    Cancelled and stationary agents must come with ``target == start`` (their self-loop). A
    committed agent moves to its target; an uncommitted one (only ever a mover) stays.
    """
    count = start.shape[0]
    agents = jnp.arange(count, dtype=jnp.int32)
    onto = target[:, None] == start[None, :]  # [i, j]: agent i heads for agent j's cell
    sink = jnp.int32(count)  # the empty cell a chain ends in (one index for all: chains are told apart by target)
    successor = jnp.where(jnp.any(onto, axis=1), jnp.argmax(onto, axis=1).astype(jnp.int32), sink)
    extended = jnp.append(successor, sink)

    def follow(node, _):
        node = extended[node]
        return node, node

    _, walked = jax.lax.scan(follow, agents, None, length=count)  # walked[k] = next^(k+1)
    paths = jnp.concatenate([agents[None, :], walked], axis=0)  # (N+1, N): paths[k, i] = next^k(i)

    on_cycle = jnp.any(walked == agents[None, :], axis=0)
    head_on = (successor != agents) & (successor < sink) & (extended[successor] == agents)
    in_tree = paths[count] == sink

    # Chain length into each agent: the most steps any agent needs to reach it (trees only).
    steps = jnp.arange(count + 1, dtype=jnp.int32)[:, None, None]
    depth = jnp.max(jnp.where(paths[:, :, None] == agents[None, None, :], steps, 0), axis=(0, 1))
    # rware's node order: agent i's cell is inserted at 2i unless an earlier agent's target put it at 2k+1.
    as_target = jnp.where(onto, 2 * agents[:, None] + 1, 2 * count + 2)  # [k, i]: agent k targets i's cell
    rank = jnp.minimum(2 * agents, jnp.min(as_target, axis=0))
    key = depth * (2 * count + 3) - rank  # longer chain first, then earlier in insertion order
    rivals = (target[:, None] == target[None, :]) & in_tree[None, :]  # [i, j]: tree agents sharing i's target
    best = key >= jnp.max(jnp.where(rivals, key[None, :], jnp.iinfo(jnp.int32).min), axis=1)
    chosen = jnp.append(in_tree & best, True)
    on_longest = in_tree & jnp.all(chosen[paths[:count]], axis=0)  # every agent from here to the sink was chosen
    return (on_cycle & ~head_on) | on_longest
