"""CPython's set order in JAX (``set_order``) against the interpreter itself and networkx's component copies.

rware breaks ties between equal chains by the node order of ``G.subgraph(c).copy()``, which for a
component with fewer than half of ``G``'s nodes is the iteration order of a set of ``(x, y)``
tuples (networkx 3.6.1, CPython 3.11). The emulation is held to real objects: the tuple hash,
sets filled one key at a time and refilled from another set (as networkx does), and whole move
graphs with crowds, chains, stationary agents and cycles.

Programs: compiled at LLVM level 0 (``fast_compile``); ``component_rank`` one per grid width and agent count
(:func:`compiled`), the largest-component cases on the grids of ``test_component_rank_is_networkx_component_copy_order``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import fast_compile

from wrl_jax.envs.rware.set_order import (
    NEIGHBOURS,
    component_rank,
    copy_positions,
    first_precedes_in_triple,
    longest_set_order_component,
    probe_table,
    set_positions,
    triple_direction,
    triple_table,
    tuple_hash,
)

nx = pytest.importorskip("networkx")
WORD = 2**32


def halves(values: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """64-bit unsigned ints as (high, low) uint32 arrays."""
    values = np.array([value & (2**64 - 1) for value in values], np.uint64)
    return (values >> np.uint64(32)).astype(np.uint32), (values & np.uint64(WORD - 1)).astype(np.uint32)


def test_tuple_hash_is_pythons_on_every_pair_up_to_200():
    x, y = (grid.ravel() for grid in np.meshgrid(np.arange(201), np.arange(201), indexing="ij"))
    high, low = fast_compile.jit(tuple_hash)(x.astype(np.int32), y.astype(np.int32))
    got = (np.asarray(high, np.uint64) << np.uint64(32)) | np.asarray(low, np.uint64)
    expected = np.array([hash((int(a), int(b))) & (2**64 - 1) for a, b in zip(x, y)], np.uint64)
    assert got.dtype == np.uint64 and np.array_equal(got, expected)


LENGTH = 40


def random_sets(seed: int, cases: int):
    """``cases`` lists of 1..40 distinct tuples from 0..200, their hashes (padded to 40) and their lengths."""
    rng = np.random.default_rng(seed)
    keys = []
    high, low = np.zeros((cases, LENGTH), np.uint32), np.zeros((cases, LENGTH), np.uint32)
    for case in range(cases):
        cells = rng.choice(201 * 201, rng.integers(1, LENGTH + 1), replace=False)
        keys.append([(int(cell) % 201, int(cell) // 201) for cell in cells])
        high[case, :len(cells)], low[case, :len(cells)] = halves([hash(key) for key in keys[-1]])
    return keys, high, low, np.array([len(case) for case in keys], np.int32)


def assert_positions(positions: np.ndarray, keys: list, built: list[set]):
    for case, (row, elements, the_set) in enumerate(zip(positions, keys, built)):
        expected = [list(the_set).index(key) for key in elements]
        assert row[:len(elements)].tolist() == expected, (case, elements)
        assert (row[len(elements):] == LENGTH).all()


def filled(keys: list) -> set:
    """A set that got ``keys`` one ``add`` at a time, as ``_plain_bfs`` fills ``seen``."""
    the_set = set()
    for key in keys:
        the_set.add(key)
    return the_set


def test_set_positions_follow_a_set_filled_key_by_key():
    keys, high, low, counts = random_sets(seed=0, cases=1200)
    positions = np.asarray(fast_compile.jit(jax.vmap(set_positions))(high, low, counts))
    built = [filled(elements) for elements in keys]
    assert_positions(positions, keys, built)

    def home(key, size):  # the slot a key hashes to in the final table
        return hash(key) & ((8 if size < 5 else 32 if size < 19 else 128) - 1)

    displaced = sum(list(the_set) != sorted(elements, key=lambda key: home(key, len(elements)))
                    for elements, the_set in zip(keys, built))
    assert displaced > 100  # probing moved keys off their home slots, not just sorting by hash
    assert {len(elements) for elements in keys} == set(range(1, LENGTH + 1))


def test_copy_positions_follow_a_set_built_from_another_set():
    keys, high, low, counts = random_sets(seed=1, cases=1200)
    positions = np.asarray(fast_compile.jit(jax.vmap(copy_positions))(high, low, counts))
    inner = [filled(elements) for elements in keys]
    built = [set(iter(the_set)) for the_set in inner]  # as show_nodes: set() of a generator over the BFS set
    assert_positions(positions, keys, built)
    assert sum(list(a) != list(b) for a, b in zip(inner, built)) > 0  # refilling can reorder: a case of its own


def test_several_sets_at_once_are_each_their_own_set():
    """Groups of keys in one call (as component_rank runs every component's sets), in scrambled turns."""
    rng = np.random.default_rng(2)
    cases, length, groups = 300, 36, 3
    high, low = np.zeros((cases, length), np.uint32), np.zeros((cases, length), np.uint32)
    group, turn = np.full((cases, length), groups, np.int32), np.full((cases, length), -1, np.int32)
    count, expected = np.zeros((cases, groups), np.int32), np.full((2, cases, length), length, np.int32)
    for case in range(cases):
        sizes = rng.integers(0, 13, groups)
        cells = rng.choice(201 * 201, sizes.sum(), replace=False)
        keys = [(int(cell) % 201, int(cell) // 201) for cell in cells]
        slots = rng.permutation(length)[:len(keys)]  # where each key sits among the elements
        high[case, slots], low[case, slots] = halves([hash(key) for key in keys])
        count[case] = sizes
        first = 0
        for number, size in enumerate(sizes):
            members = slots[first:first + size]
            group[case, members], turn[case, members] = number, np.arange(size)
            the_set = filled(keys[first:first + size])
            for built, kind in ((the_set, 0), (set(iter(the_set)), 1)):
                expected[kind, case, members] = [list(built).index(key) for key in keys[first:first + size]]
            first += size
    for kind, function in enumerate((set_positions, copy_positions)):
        got = fast_compile.jit(jax.vmap(function))(high, low, count, turn, group)
        assert np.array_equal(np.asarray(got), expected[kind]), kind


def scenario(rng: np.random.Generator, agents: int, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Distinct starts; each agent stays, follows another's cell, joins a crowd or drives anywhere; some cycles."""
    starts = rng.choice(width * height, agents, replace=False).astype(np.int32)
    targets = starts.copy()
    hot = rng.choice(width * height, rng.integers(1, 4))
    modes = rng.choice(4, agents, p=rng.dirichlet(np.ones(4)))
    for agent, mode in enumerate(modes):
        if mode == 1:
            targets[agent] = starts[rng.integers(agents)]
        elif mode == 2:
            targets[agent] = rng.choice(hot)
        elif mode == 3:
            targets[agent] = rng.integers(width * height)
    if agents >= 2 and rng.random() < 0.3:
        ring = rng.choice(agents, rng.integers(2, min(agents, 5) + 1), replace=False)
        targets[ring] = starts[np.roll(ring, -1)]
    return starts, targets


def networkx_ranks(starts: np.ndarray, targets: np.ndarray, width: int) -> tuple[list[int], list[int], list[int]]:
    """Per agent: its start's index in its component copy (rware's graph), in ``G``'s insertion order, its component."""
    graph = nx.DiGraph()
    for start, target in zip(starts.tolist(), targets.tolist()):
        graph.add_edge((start % width, start // width), (target % width, target // width))
    inserted = {node: index for index, node in enumerate(graph)}
    copied, kept, label = {}, {}, {}
    for number, component in enumerate(nx.weakly_connected_components(graph)):
        for index, node in enumerate(graph.subgraph(component).copy()):
            copied[node] = index
        for index, node in enumerate(sorted(component, key=inserted.get)):
            kept[node], label[node] = index, number
    cells = [(start % width, start // width) for start in starts.tolist()]
    return [copied[cell] for cell in cells], [kept[cell] for cell in cells], [label[cell] for cell in cells]


@functools.cache
def compiled(width: int):
    """``component_rank`` over a batch of graphs, ``needed`` optional."""
    def rank(start, target, needed=None):
        return component_rank(start, target, width, needed)
    return fast_compile.jit(jax.vmap(rank))


RANK_GRIDS = {4: (5, 4), 8: (7, 6), 19: (16, 14)}
"""Agents: the grid's (width, height). Each count its own program: a few, and the largest (test_rware_conflicts.py
runs 5 to 19 end to end); test_the_largest_set_order_components reuses the programs of 8 and 19."""


@pytest.mark.parametrize("agents, width, height", [(agents, *grid) for agents, grid in RANK_GRIDS.items()])
def test_component_rank_is_networkx_component_copy_order(agents, width, height):
    rng = np.random.default_rng(agents)
    cases = [scenario(rng, agents, width, height) for _ in range(300)]
    starts, targets = (np.stack(part) for part in zip(*cases))
    ranks = np.asarray(compiled(width)(starts, targets))
    differs = 0
    for case, (start, target) in enumerate(cases):
        copied, kept, _ = networkx_ranks(start, target, width)
        assert ranks[case].tolist() == copied, (case, start.tolist(), target.tolist())
        differs += copied != kept
    if agents >= 4:
        assert differs > 0  # some components really come in set order, unlike G's insertion order


def test_components_without_needed_agents_keep_insertion_order():
    agents, width, height = 12, 10, 9
    rng = np.random.default_rng(7)
    cases = [scenario(rng, agents, width, height) for _ in range(200)]
    starts, targets = (np.stack(part) for part in zip(*cases))
    needed = rng.random((len(cases), agents)) < 0.2
    rank = compiled(width)
    some, none = (np.asarray(rank(starts, targets, mask)) for mask in (needed, np.zeros_like(needed)))
    emulated = 0
    for case, (start, target) in enumerate(cases):
        copied, kept, label = networkx_ranks(start, target, width)
        assert none[case].tolist() == kept
        wanted = {label[agent] for agent in range(agents) if needed[case, agent]}
        expected = [copied[agent] if label[agent] in wanted else kept[agent] for agent in range(agents)]
        assert some[case].tolist() == expected, case
        emulated += expected != kept
    assert emulated > 0


@pytest.mark.parametrize("agents", [8, 19])
def test_the_largest_set_order_components(agents):
    """A tree of ``k`` agents into one empty cell, every other agent into a fresh cell: the most cells in set order."""
    (width, height), longest = RANK_GRIDS[agents], longest_set_order_component(agents)
    tree = next(k for k in range(1, agents + 1) if min(k + 1, 2 * (agents - k) - 1) == longest)
    rng = np.random.default_rng(agents)
    cases = []
    for _ in range(300):  # the rank test's batch: its program
        cells = rng.choice(width * height, 2 * agents, replace=False).astype(np.int32)
        starts, targets, members = cells[:agents], cells[agents:].copy(), rng.permutation(agents)[:tree]
        for place, agent in enumerate(members[:-1]):  # each joins a later member: one tree, sink at the last
            targets[agent] = starts[members[rng.integers(place + 1, tree)]]
        cases.append((starts, targets))
    starts, targets = (np.stack(part) for part in zip(*cases))
    ranks = np.asarray(compiled(width)(starts, targets))
    for case, (start, target) in enumerate(cases):
        assert ranks[case].tolist() == networkx_ranks(start, target, width)[0], case
        assert 2 * (tree + 1) < len(set(start.tolist()) | set(target.tolist()))  # set order, with `longest` cells
    assert tree + 1 == longest


def test_probe_table_is_pythons_hash_and_first_precedes_in_triple_is_pythons_order():
    """The closed form of 4 agents' only set-order case: three keys added to a set, then the set copied."""
    height, width = 40, 40
    table = probe_table(height, width)
    assert table[7 * width + 3, 0] == hash((3, 7)) & 7  # row y W + x holds (x, y)'s home slot first
    cells = np.random.default_rng(3).integers(0, height * width, size=(6000, 3))
    cells = cells[[len(set(row)) == 3 for row in cells]]
    ours = np.asarray(fast_compile.jit(first_precedes_in_triple)(*(jnp.asarray(table)[cells[:, k]] for k in range(3))))
    expected = []
    for row in cells:
        first, middle, last = ((int(c) % width, int(c) // width) for c in row)
        filled = set()
        for key in (first, middle, last):
            filled.add(key)
        copied = list(set(iter(filled)))
        expected.append(copied.index(first) < copied.index(last))
    assert ours.tolist() == expected
    assert 0.2 < np.mean(expected) < 0.8  # both outcomes occur


@pytest.mark.parametrize("height, width", [(7, 11), (12, 1), (1, 12)])
def test_triple_table_is_pythons_order_for_every_cell_and_pair_of_neighbours(height, width):
    """What a 4-agent step reads: for each cell and two of its neighbours (earlier agent's, later agent's), whether the
    earlier one comes first in the copied set; checked against CPython's own sets on an oblong grid and on grids one
    cell wide and one high (where a flat difference of 1 is a row, not a column), every entry."""
    table = triple_table(height, width)
    assert table.shape == (height * width, 4, 4)
    checked, directions = [], []  # directions: (cell, centre, expected direction), checked in one call below
    for middle_cell in range(height * width):
        x, y = middle_cell % width, middle_cell // width
        for a, (ax, ay) in enumerate(NEIGHBOURS):
            for b, (bx, by) in enumerate(NEIGHBOURS):
                first, last = (x + ax, y + ay), (x + bx, y + by)
                if a == b or not all(0 <= px < width and 0 <= py < height for px, py in (first, last)):
                    continue
                filled = set()
                for key in (first, (x, y), last):
                    filled.add(key)
                copied = list(set(iter(filled)))
                assert table[middle_cell, a, b] == (copied.index(first) < copied.index(last)), (x, y, a, b)
                for cell, direction in ((first, a), (last, b)):
                    directions.append((cell[1] * width + cell[0], middle_cell, direction))
                checked.append(bool(table[middle_cell, a, b]))
    cells, centres, expected = np.array(directions, np.int32).T
    got = np.asarray(fast_compile.jit(triple_direction, static_argnums=2)(cells, centres, width))
    for cell, centre, direction, ours in zip(cells, centres, expected, got):
        assert ours == direction, (cell % width, cell // width, centre % width, centre // width)
    assert len(checked) >= 2 * (max(height, width) - 2)
    if min(height, width) > 1:
        assert 0.2 < np.mean(checked) < 0.8  # both outcomes occur
