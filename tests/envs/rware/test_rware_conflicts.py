"""The move graph on its own: ``resolve_moves`` against rware's networkx procedure on dense random crowds.

Agents packed onto small grids, most driving forward, give what random play in a warehouse
rarely does: rotations of four, head-on swaps with queues behind them, and many equal-length
chains into one cell. The reference builds the graph as rware does (``add_edge(start, target)``
agent by agent, components, ``find_cycle`` / ``dag_longest_path`` on the subgraph copy): unpatched
networkx for ``tie_order="set"`` (its node order is CPython's hash-set order in small components),
the insertion-ordered copy for ``tie_order="insertion"``.

Programs: one per grid, tie order and agent count (:func:`resolver`, cached, compiled at LLVM level 0 by
``fast_compile``); ``test_unrolled_rotation``'s cases reuse the crowds' programs.
"""

from __future__ import annotations

import functools

import jax
import numpy as np
import pytest
import fast_compile
import rware_oracle as oracle

from wrl_jax.envs.rware.conflicts import resolve_moves

nx = oracle.nx
STEPS = ((0, -1), (0, 1), (-1, 0), (1, 0))


def crowd(rng, side: int, agents: int, cases: int, height: int | None = None):
    """``cases`` random crowds: distinct cells, random headings, 85% forward (clamped at the edges).

    The grid is ``height`` x ``side`` (square by default); cells are ``y * side + x``.
    """
    height = side if height is None else height
    starts, targets = np.zeros((cases, agents), np.int32), np.zeros((cases, agents), np.int32)
    for case in range(cases):
        cells = rng.choice(height * side, agents, replace=False)
        x, y = cells % side, cells // side
        move = np.array(STEPS)[rng.integers(0, 4, agents)] * (rng.random(agents) < 0.85)[:, None]
        tx, ty = np.clip(x + move[:, 0], 0, side - 1), np.clip(y + move[:, 1], 0, height - 1)
        starts[case], targets[case] = cells, ty * side + tx
    return starts, targets


def reference(starts, targets, side: int, tie_order: str = "insertion"):
    """rware's verdict (networkx unpatched for ``"set"``, insertion order kept otherwise) and the case's kinds."""
    graph = nx.DiGraph()
    for start, target in zip(starts, targets):
        graph.add_edge(divmod(int(start), side)[::-1], divmod(int(target), side)[::-1])
    committed, kinds = set(), set()
    for component in nx.weakly_connected_components(graph):
        sub = (graph.subgraph(component) if tie_order == "set" else oracle.ordered_subgraph(graph, component)).copy()
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


@functools.cache
def resolver(side: int, tie_order: str, height: int | None = None):
    """One jitted function per grid and tie order (each agent count its own program), shared by the tests."""
    grid_size = (side if height is None else height, side)
    return fast_compile.jit(jax.vmap(functools.partial(resolve_moves, grid_size=grid_size, tie_order=tie_order)))


CASES = 300
"""Crowds per test case (one batch, one program per size)."""
ALL_KINDS = {"head_on", "rotation", "tie", "chain", "stay"}


CROWDS = [
    (4, 8, ALL_KINDS), (4, 12, ALL_KINDS), (5, 19, ALL_KINDS),
    # Up to conflicts.UNROLL_LIMIT agents the graph is written out agent by agent: the same verdicts.
    # (The grid's cycles have even length: 3 agents on 2x2 cells cannot rotate; 4 fill it, so no chain
    # ends in an empty cell. Random crowds of 4 rarely line up a rotation: test_unrolled_rotation has one.)
    (2, 2, {"head_on", "tie", "chain", "stay"}), (2, 3, {"head_on", "tie", "chain", "stay"}),
    (2, 4, {"head_on", "stay"}), (3, 4, {"head_on", "tie", "chain", "stay"}),
]
"""(grid side, agents, the conflict kinds their crowds must show)."""


@pytest.mark.parametrize("side, agents, kinds, tie_order",
                         [(*crowd_, "set") for crowd_ in CROWDS]
                         # insertion order (each size its own program): one array-form crowd, and 3 and 4 agents
                         # unrolled; not the 4 filling the 2 x 2 grid: every cell taken, each component holds a
                         # cycle, no chain ends in an empty cell, so no tie for the orders to part
                         + [(*crowd_, "insertion") for crowd_ in CROWDS if crowd_[:2] in ((4, 12), (2, 3), (3, 4))])
def test_resolve_matches_networkx(side, agents, kinds, tie_order):
    rng = np.random.default_rng(side * 100 + agents)
    starts, targets = crowd(rng, side, agents, CASES)
    ours = np.asarray(resolver(side, tie_order)(starts, targets))
    other_order = "insertion" if tie_order == "set" else "set"
    seen, orders_differ = set(), 0
    for case in range(len(starts)):
        expected, case_kinds = reference(starts[case], targets[case], side, tie_order)
        orders_differ += expected != reference(starts[case], targets[case], side, other_order)[0]
        seen |= case_kinds
        assert ours[case].tolist() == expected, f"case {case}: starts {starts[case]}, targets {targets[case]}"
    assert kinds <= seen, seen
    if side >= 3 and agents >= 4:  # (smaller crowds never hold a component networkx orders by a hash set)
        assert orders_differ > 0  # the two tie orders really part on these crowds


@pytest.mark.parametrize("tie_order", ["set", "insertion"])
def test_unrolled_rotation(tie_order):
    """Four agents rotating around a 2x2 block all move; one more queued behind the cycle (array form) waits.

    Each case repeated to the crowds' batch, so both reuse programs of test_resolve_matches_networkx: the four
    on the 3 x 3 grid (``[3-4-...]``), and the queued five on the 4 x 4 grid beside seven agents that stay
    (``[4-12-...]``, the size both tie orders run)."""
    side = 3
    cycle_starts, cycle_targets = [0, 1, 4, 3], [1, 4, 3, 0]  # (0,0) -> (1,0) -> (1,1) -> (0,1) -> (0,0)
    batch = np.array([cycle_starts] * CASES), np.array([cycle_targets] * CASES)
    ours = np.asarray(resolver(side, tie_order)(*batch))[0]
    assert ours.tolist() == [True] * 4 == reference(cycle_starts, cycle_targets, side, tie_order)[0]
    side = 4  # the same cycle, cells y * 4 + x, and (0,2) driving into the cycle's (0,1)
    starts, targets = [0, 1, 5, 4, 8], [1, 5, 4, 0, 4]
    stay = [3, 7, 10, 11, 13, 14, 15]  # seven agents away from the cycle, each on its own cell
    starts, targets = starts + stay, targets + stay
    batch = np.array([starts] * CASES), np.array([targets] * CASES)
    ours = np.asarray(resolver(side, tie_order)(*batch))[0]
    assert ours.tolist() == [True] * 4 + [False] + [True] * 7 == reference(starts, targets, side, tie_order)[0]


@pytest.mark.parametrize("height, side, agents", [(4, 4, 4), (3, 5, 4), (7, 4, 8)])
def test_set_order_ties_on_square_and_oblong_grids(height, side, agents):
    """Set-order ties, also where height and width differ (the hash is of (x, y)): many crowds to find some.

    Up to 4 agents (the unrolled graph) they are rare: 1,500 crowds of 4.
    """
    starts, targets = crowd(np.random.default_rng(44), side, agents, 1500 if agents == 4 else 300, height)
    ours = np.asarray(resolver(side, "set", height)(starts, targets))
    orders_differ = 0
    for case in range(len(starts)):
        expected = reference(starts[case], targets[case], side, "set")[0]
        orders_differ += expected != reference(starts[case], targets[case], side, "insertion")[0]
        assert ours[case].tolist() == expected, f"case {case}: starts {starts[case]}, targets {targets[case]}"
    assert orders_differ >= 5, orders_differ
