"""The move graph on its own: ``resolve_moves`` against rware's networkx procedure on dense random crowds.

Agents packed onto small grids, most driving forward, give what random play in a warehouse
rarely does: rotations of four, head-on swaps with queues behind them, and many equal-length
chains into one cell. The reference builds the graph as rware does (``add_edge(start, target)``
agent by agent, components, ``find_cycle`` / ``dag_longest_path`` on the ordered subgraph copy).
"""

from __future__ import annotations

import jax
import numpy as np
import pytest
import rware_oracle as oracle

from wrl_jax.envs.rware.conflicts import resolve_moves

nx = oracle.nx
STEPS = ((0, -1), (0, 1), (-1, 0), (1, 0))


def crowd(rng, side: int, agents: int, cases: int):
    """``cases`` random crowds: distinct cells, random headings, 85% forward (clamped at the edges)."""
    starts, targets = np.zeros((cases, agents), np.int32), np.zeros((cases, agents), np.int32)
    for case in range(cases):
        cells = rng.choice(side * side, agents, replace=False)
        x, y = cells % side, cells // side
        move = np.array(STEPS)[rng.integers(0, 4, agents)] * (rng.random(agents) < 0.85)[:, None]
        tx, ty = np.clip(x + move[:, 0], 0, side - 1), np.clip(y + move[:, 1], 0, side - 1)
        starts[case], targets[case] = cells, ty * side + tx
    return starts, targets


def reference(starts, targets, side: int):
    """rware's verdict (insertion order kept) and the case's kind: which agents are committed."""
    graph = nx.DiGraph()
    for start, target in zip(starts, targets):
        graph.add_edge(divmod(int(start), side)[::-1], divmod(int(target), side)[::-1])
    committed, kinds = set(), set()
    for component in nx.weakly_connected_components(graph):
        sub = oracle.ordered_subgraph(graph, component).copy()
        try:
            cycle = nx.find_cycle(sub)
            if len(cycle) == 2:
                kinds.add("head_on")
                continue
            kinds.add("rotation" if len(cycle) > 2 else "stay")
            committed.update(edge[0] for edge in cycle)
        except nx.NetworkXNoCycle:
            path = nx.dag_longest_path(sub)
            kinds.add("tie" if len(sub) > len(path) and _tied(sub) else "chain")
            committed.update(path)
    return [divmod(int(s), side)[::-1] in committed for s in starts], kinds


def _tied(sub) -> bool:
    depth = {}
    for node in nx.topological_sort(sub):
        depth[node] = 1 + max((depth[u] for u in sub.pred[node]), default=-1)
    node = next(v for v in sub if sub.out_degree(v) == 0)
    while sub.pred[node]:
        tied = [u for u in sub.pred[node] if depth[u] == depth[node] - 1]
        if len(tied) > 1:
            return True
        node = tied[0]
    return False


RESOLVE = jax.jit(jax.vmap(resolve_moves))


ALL_KINDS = {"head_on", "rotation", "tie", "chain", "stay"}


@pytest.mark.parametrize("side, agents, kinds", [
    (4, 12, ALL_KINDS), (5, 19, ALL_KINDS),
    # Up to conflicts.UNROLL_LIMIT agents the graph is written out agent by agent: the same verdicts.
    (2, 2, {"head_on", "tie", "chain", "stay"}), (2, 3, ALL_KINDS), (2, 4, ALL_KINDS), (3, 4, ALL_KINDS),
])
def test_resolve_matches_networkx(side, agents, kinds):
    rng = np.random.default_rng(side * 100 + agents)
    starts, targets = crowd(rng, side, agents, 300)
    ours = np.asarray(RESOLVE(starts, targets))
    seen = set()
    for case in range(len(starts)):
        expected, kinds = reference(starts[case], targets[case], side)
        seen |= kinds
        assert ours[case].tolist() == expected, f"case {case}: starts {starts[case]}, targets {targets[case]}"
    assert kinds <= seen, seen
