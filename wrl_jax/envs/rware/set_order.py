"""The node order of rware's component copies where networkx iterates a hash set, emulated in JAX.

rware runs ``dag_longest_path`` on ``G.subgraph(c).copy()`` for each weakly connected component
``c`` of its move graph, and equal chains are told apart by that copy's node order. networkx
3.6.1 copies ``G``'s insertion order only when ``2 * len(c) >= len(G)``; for a smaller component
``FilterAtlas.__iter__`` walks ``show_nodes.nodes = set(c)`` (filled from ``c``'s own iteration),
where ``c`` is the set ``_plain_bfs`` filled in BFS order. Both are CPython sets of ``(x, y)``
tuples, so their order is a hash-table layout. This module computes it without Python objects:

- :func:`tuple_hash`: CPython's xxHash-style tuple hash (3.8+) in 32-bit halves (no x64);
- :func:`set_positions` / :func:`copy_positions`: a set's table, insertion by insertion, with
  CPython 3.11's probing (``LINEAR_PROBES = 9``, ``PERTURB_SHIFT = 5``) and resizes (table
  ``8 -> 32 -> 128`` once ``fill * 5 >= mask * 3``, re-inserting in old-table order);
- :func:`component_rank`: the BFS that orders ``c``, then both sets, per component;
- :func:`probe_table` and :func:`first_precedes_in_triple`: the one case up to 4 agents (three keys
  in an 8-slot table), written out elementwise from probe sequences computed with Python's ``hash``;
  :func:`triple_table` evaluates it once per grid for every such case, so a step only looks it up.

Every loop is a ``lax.while_loop`` whose trip count is zero when no component needs set order:
BFS levels, then one trip per probe run, all of an environment's components in a row. Under
``vmap`` the batch runs its longest count (N = 8, 1024 crowded envs, tie agents only: about 36
trips). The caller (:mod:`~wrl_jax.envs.rware.conflicts`) runs it only on steps that need it.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

_MASK32 = 0xFFFFFFFF
_XXPRIME_1 = 11400714785074694791
_XXPRIME_2 = 14029467366897019727
_XXPRIME_5 = 2870177450012600261
_LENGTH_2 = 2 ^ (_XXPRIME_5 ^ 3527539)  # tupleobject.c adds ``len ^ (XXPRIME_5 ^ 3527539)``
_MINUS_ONE_HASH = 1546275796  # what a tuple hashes to when the sum is -1

LINEAR_PROBES = 9
PERTURB_SHIFT = 5
STAGES = ((8, 5), (32, 19), (128, 77))
"""Table sizes and the fill that outgrows each: inserting the 5th key resizes 8 slots to 32, the 19th to 128."""
MAX_SET_SIZE = 76
"""The largest set emulated (the 77th key would resize the table to 512)."""


def longest_set_order_component(agents: int) -> int:
    """The most cells a component can have while ``2 * len(c) < len(G)``: 3 for 4 agents, 5 for 8, 13 for 19.

    ``k`` agents span at most ``k + 1`` cells and the others at most two each, so ``len(c) <=
    min(k + 1, 2 * (agents - k) - 1)``: up to 19 agents (rware's most) a 32-slot table always suffices.
    """
    return max([min(k + 1, 2 * (agents - k) - 1) for k in range(1, agents + 1)] + [1])


U64 = tuple[jax.Array, jax.Array]  # (high, low) uint32 halves of a 64-bit unsigned value


def _constant(value: int) -> U64:
    return jnp.uint32(value >> 32), jnp.uint32(value & _MASK32)


def _mul_wide(a: jax.Array, b: jax.Array) -> U64:
    """The full 64-bit product of two uint32, from 16-bit pieces."""
    a0, a1, b0, b1 = a & 0xFFFF, a >> 16, b & 0xFFFF, b >> 16
    low, cross_a, cross_b = a0 * b0, a0 * b1, a1 * b0
    middle = (low >> 16) + (cross_a & 0xFFFF) + (cross_b & 0xFFFF)
    return a1 * b1 + (cross_a >> 16) + (cross_b >> 16) + (middle >> 16), (middle << 16) | (low & 0xFFFF)


def _mul(a: U64, b: U64) -> U64:
    high, low = _mul_wide(a[1], b[1])
    return high + a[0] * b[1] + a[1] * b[0], low


def _add(a: U64, b: U64) -> U64:
    low = a[1] + b[1]
    return a[0] + b[0] + (low < a[1]).astype(jnp.uint32), low


def tuple_hash(x: jax.Array, y: jax.Array) -> U64:
    """``hash((x, y)) & (2**64 - 1)`` as ``(high, low)`` uint32, for ints ``0 <= x, y < 2**31`` (``hash(int) == int``).

    CPython's ``tuplehash`` (Objects/tupleobject.c, 3.8 and later): per item ``acc += lane *
    XXPRIME_2; acc = rotl(acc, 31); acc *= XXPRIME_1``, then the length term; 64-bit wrapping.
    """
    acc = _constant(_XXPRIME_5)
    for lane in (x, y):
        acc = _add(acc, _mul((jnp.zeros_like(lane, jnp.uint32), lane.astype(jnp.uint32)), _constant(_XXPRIME_2)))
        acc = (acc[0] << 31) | (acc[1] >> 1), (acc[1] << 31) | (acc[0] >> 1)  # rotate left by 31
        acc = _mul(acc, _constant(_XXPRIME_1))
    high, low = _add(acc, _constant(_LENGTH_2))
    minus_one = (high == jnp.uint32(_MASK32)) & (low == jnp.uint32(_MASK32))
    return jnp.where(minus_one, jnp.uint32(0), high), jnp.where(minus_one, jnp.uint32(_MINUS_ONE_HASH), low)


SMALL_TABLE_PROBES = 22
"""Probes that always place a key in an 8-slot table holding at most two: the first, 13 while ``perturb``
is nonzero (64 bits shifted by 5), then ``i -> 5 i + 1`` visits all eight slots."""


def probe_table(height: int, width: int) -> np.ndarray:
    """``(H W, 22)`` int32: the slots CPython's ``set_add_entry`` tries, in order, for cell ``y W + x``'s key
    ``(x, y)`` in an 8-slot table. Built at trace time from Python's own ``hash``, so it is exact by construction.

    With ``mask = 7`` no linear run fits (``i + 9 > mask``), so each probe checks one slot, then
    ``perturb >>= 5; i = (5 i + 1 + perturb) & 7``: a sequence of the key alone, not of the table.
    """
    table = np.zeros((height * width, SMALL_TABLE_PROBES), np.int32)
    for cell in range(height * width):
        perturb = hash((cell % width, cell // width)) & (2**64 - 1)
        slot = perturb & 7
        for probe in range(SMALL_TABLE_PROBES):
            table[cell, probe] = slot
            perturb >>= PERTURB_SHIFT
            slot = (slot * 5 + 1 + perturb) & 7
    return table


def _place(occupied: jax.Array, probes: jax.Array) -> jax.Array:
    """The first probed slot that ``occupied`` (a bit per slot) leaves free."""
    free = ((occupied[..., None] >> probes.astype(jnp.uint32)) & 1) == 0
    return jnp.take_along_axis(probes, jnp.argmax(free, axis=-1)[..., None], axis=-1)[..., 0]


def first_precedes_in_triple(first: jax.Array, middle: jax.Array, last: jax.Array) -> jax.Array:
    """Whether ``first`` comes before ``last`` in ``list(set(iter(s)))`` where ``s`` got ``first, middle, last``.

    Each key is given by its probe sequence (a row of :func:`probe_table`). The only set-order
    component up to 4 agents: two agents driving into one empty cell (rware's ``_plain_bfs`` adds
    the earlier agent's cell, the empty cell, then the later agent's cell; networkx copies that set
    once more). Three keys never resize an 8-slot table; a set iterates by slot.
    """
    probes = (first, middle, last)
    occupied, slots = jnp.zeros(first.shape[:-1], jnp.uint32), []
    for sequence in probes:
        slots.append(_place(occupied, sequence))
        occupied = occupied | (jnp.uint32(1) << slots[-1].astype(jnp.uint32))
    # The copy adds them in the first table's slot order.
    order = [sum((slots[j] < slots[i]).astype(jnp.int32) for j in range(3) if j != i) for i in range(3)]
    occupied, copied = jnp.zeros(first.shape[:-1], jnp.uint32), [jnp.zeros(first.shape[:-1], jnp.int32)] * 3
    for turn in range(3):
        sequence = sum(jnp.where((order[i] == turn)[..., None], probes[i], 0) for i in range(3))
        slot = _place(occupied, sequence)
        occupied = occupied | (jnp.uint32(1) << slot.astype(jnp.uint32))
        copied = [jnp.where(order[i] == turn, slot, copied[i]) for i in range(3)]
    return copied[0] < copied[2]


NEIGHBOURS = ((1, 0), (-1, 0), (0, 1), (0, -1))
"""The four cells next to a cell, as ``(dx, dy)``: the index of :func:`triple_table`'s directions."""


@functools.lru_cache(maxsize=None)
def triple_table(height: int, width: int) -> np.ndarray:
    """``(H W, 4, 4)`` bool: :func:`first_precedes_in_triple` for every case two agents can make.

    ``[t, a, b]``: the earlier agent's cell is the neighbour ``a`` of the empty cell ``t``, the later
    agent's the neighbour ``b``. Up to 4 agents that is the only set-order tie, so the step reads one
    entry of a table computed once per grid at trace time, instead of emulating the sets per step
    (entries off the grid or with ``a == b`` are never read). Exactly the emulation's result.
    """
    probes = probe_table(height, width)
    t, a, b = np.meshgrid(np.arange(height * width), np.arange(4), np.arange(4), indexing="ij")
    x, y = t % width, t // width
    shift = np.array(NEIGHBOURS)

    def neighbour(d):
        return np.clip(y + shift[d, 1], 0, height - 1) * width + np.clip(x + shift[d, 0], 0, width - 1)

    with jax.ensure_compile_time_eval():  # concrete even when called while a step is traced
        # One compiled program, not one per operation (eagerly, each of its dozens of operations compiles alone).
        first = jax.jit(first_precedes_in_triple)(probes[neighbour(a)], probes[t], probes[neighbour(b)])
    table = np.array(first, bool)
    table.flags.writeable = False  # shared by every caller (cached)
    return table


def triple_index(first: jax.Array, middle: jax.Array, later: jax.Array, width: int) -> jax.Array:
    """The flat index into ``triple_table(H, W).reshape(-1)`` of the case ``(middle, first's side, later's side)``."""
    return middle * 16 + triple_direction(first, middle, width) * 4 + triple_direction(later, middle, width)


def triple_direction(cell: jax.Array, centre: jax.Array, width: int) -> jax.Array:
    """Which of :data:`NEIGHBOURS` ``cell`` is of ``centre`` (cells ``y W + x``; 3 for anything else).

    From the coordinates, not the flat difference: on a grid one cell wide ``+1`` is the cell below.
    """
    dx = cell % width - centre % width
    dy = cell // width - centre // width
    return jnp.where(dx == 1, 0, jnp.where(dx == -1, 1, jnp.where(dy == 1, 2, 3))).astype(jnp.int32)


def _free_slots(occupied: jax.Array, slot: jax.Array, mask: int) -> jax.Array:
    """Bit ``j`` set when slot ``slot + j`` is free and probed: ten slots if ``slot + 9 <= mask``, else one.

    ``occupied`` holds the table as ``(size // 32,)`` uint32 words (one word for 8 slots too).
    """
    words = occupied.shape[0]
    shift = slot.astype(jnp.uint32)
    if words == 1:
        bits = occupied[0] >> shift
    else:
        word, offset = slot >> 5, shift & 31
        bits = occupied[word] >> offset
        above = occupied[jnp.minimum(word + 1, words - 1)] << ((32 - offset) & 31)
        bits = bits | jnp.where(offset == 0, jnp.uint32(0), above)
    span = jnp.where(slot + LINEAR_PROBES <= mask, jnp.uint32(0x3FF), jnp.uint32(1))
    return ~bits & span


def _lowest_bit(bits: jax.Array) -> jax.Array:
    """Index of the lowest set bit of a nonzero uint32."""
    return (31 - lax.clz(bits & (~bits + 1))).astype(jnp.int32)


def _insert(high: jax.Array, low: jax.Array, group: jax.Array, turn: jax.Array, groups: int,
            size: int) -> tuple[jax.Array, jax.Array]:
    """Add the elements to empty ``size``-slot tables, one per group: element ``e`` at trip ``turn[e]`` (no resize).

    Turns run ``0, 1, ...`` over all groups (a group's keys in a row, in their order); elements
    with ``turn < 0`` are not added. ``set_add_entry`` and ``set_insert_clean`` (Objects/setobject.c)
    probe alike: a run of slots from ``i`` (ten if ``i + 9 <= mask``, else one), then ``perturb >>=
    5; i = (5 i + 1 + perturb) & mask``, ``perturb`` starting as the hash. One trip probes one run,
    so the trip count is the number of runs probed. Returns each element's slot (-1 if not added)
    and the tables' occupied words ``(groups, max(size // 32, 1))``.
    """
    mask, words = size - 1, max(size // 32, 1)

    def body(state):
        k, run, slot, perturb_high, perturb_low, occupied, slots = state
        current = turn == k

        def pick(values):
            return jnp.sum(jnp.where(current, values, jnp.zeros_like(values)), dtype=values.dtype)

        fresh, table, key_low = run == 0, pick(group), pick(low)
        slot = jnp.where(fresh, (key_low & mask).astype(jnp.int32), slot)  # a new key starts at its home slot
        perturb_high, perturb_low = jnp.where(fresh, pick(high), perturb_high), jnp.where(fresh, key_low, perturb_low)
        free = _free_slots(occupied[table], slot, mask)
        found = free != 0
        chosen = slot + _lowest_bit(jnp.where(found, free, jnp.uint32(1)))
        slots = jnp.where(found & current, chosen, slots)
        mark = found & (jnp.arange(groups)[:, None] == table) & (jnp.arange(words)[None, :] == chosen >> 5)
        occupied = jnp.where(mark, occupied | (jnp.uint32(1) << (chosen & 31).astype(jnp.uint32)), occupied)
        perturb_low = (perturb_low >> PERTURB_SHIFT) | (perturb_high << (32 - PERTURB_SHIFT))
        perturb_high = perturb_high >> PERTURB_SHIFT
        step = (slot * 5 + 1 + (perturb_low & mask).astype(jnp.int32)) & mask
        return (k + found.astype(jnp.int32), jnp.where(found, 0, run + 1), step, perturb_high, perturb_low,
                occupied, slots)

    init = (jnp.int32(0), jnp.int32(0), jnp.int32(0), jnp.uint32(0), jnp.uint32(0),
            jnp.zeros((groups, words), jnp.uint32), jnp.full(turn.shape, -1, jnp.int32))
    *_, occupied, slots = lax.while_loop(lambda state: state[0] <= jnp.max(turn), body, init)
    return slots, occupied


def _iteration_positions(slots: jax.Array, occupied: jax.Array) -> jax.Array:
    """Each element's index in its table's order (occupied slots below its own); ``len(slots)`` if absent.

    ``occupied``: each element's table, ``(L, words)``.
    """
    below = jnp.maximum(slots, 0)
    word = jnp.arange(occupied.shape[1])[None, :]
    lower = jnp.where(word < (below >> 5)[:, None], occupied, 0)
    partial = jnp.where(word == (below >> 5)[:, None], occupied, 0)
    partial = jnp.sum(partial, axis=1, dtype=jnp.uint32) & ((jnp.uint32(1) << (below & 31).astype(jnp.uint32)) - 1)
    position = jnp.sum(lax.population_count(lower), axis=1) + lax.population_count(partial)
    return jnp.where(slots >= 0, position.astype(jnp.int32), slots.shape[0])


def set_positions(high: jax.Array, low: jax.Array, count: jax.Array, turn: jax.Array | None = None,
                  group: jax.Array | None = None, most: int | None = None) -> jax.Array:
    """Where each element comes when iterating the CPython 3.11 set it was ``add``-ed to, key by key.

    ``high``/``low`` (L,): the elements' hashes (:func:`tuple_hash`), distinct within a set.
    Element ``e`` is the ``turn[e]``-th key (default ``e``) of set ``group[e]`` (default 0);
    set ``g`` takes the elements with ``turn < count[g]`` (``count``: (G,), or a scalar for one
    set). ``most`` (static, default ``min(L, 76)``) bounds ``count``: tables it cannot fill are not
    compiled. Returns (L,) int32: each added element's index in ``list(its_set)``, ``L`` for the
    others. A resize re-inserts the old table's keys in table order, then insertion goes on.
    """
    length = high.shape[0]
    turn = jnp.arange(length, dtype=jnp.int32) if turn is None else turn
    group = jnp.zeros(length, jnp.int32) if group is None else group
    count = jnp.reshape(count, (-1,))
    groups, most = count.shape[0], min(length, MAX_SET_SIZE) if most is None else most
    mine = group[:, None] == jnp.arange(groups)[None, :]  # [element, set]
    previous, positions = 0, jnp.full(length, length, jnp.int32)
    for size, outgrown in STAGES:
        if most < previous:  # no set this long reaches this table
            break
        taken = jnp.where(count >= previous, jnp.minimum(count, outgrown), 0)  # keys this table gets, per set
        turn = jnp.where(positions < previous, positions, turn)  # the old table's keys first, in its order
        within = jnp.any(mine & (turn[:, None] < taken[None, :]), axis=1)
        offset = jnp.sum(jnp.where(mine, (jnp.cumsum(taken) - taken)[None, :], 0), axis=1)  # the sets in a row
        slots, occupied = _insert(high, low, group, jnp.where(within, offset + turn, -1), groups, size)
        tables = jnp.sum(jnp.where(mine[:, :, None], occupied[None, :, :], jnp.uint32(0)), axis=1, dtype=jnp.uint32)
        grown = jnp.any(mine & (count >= previous)[None, :], axis=1)
        positions = jnp.where(grown, _iteration_positions(slots, tables), positions)
        previous = outgrown
    return positions


def copy_positions(high: jax.Array, low: jax.Array, count: jax.Array, turn: jax.Array | None = None,
                   group: jax.Array | None = None, most: int | None = None) -> jax.Array:
    """:func:`set_positions` of ``set(s)`` for each set ``s`` that :func:`set_positions` describes.

    ``set(iterable)`` adds the keys one by one in ``s``'s order, so its table can differ from
    ``s``'s (a key displaced in ``s`` may find its home slot free): the layout is computed again.
    """
    return set_positions(high, low, count, set_positions(high, low, count, turn, group, most), group, most)


def component_rank(start: jax.Array, target: jax.Array, width: int, needed: jax.Array | None = None) -> jax.Array:
    """Each agent's start cell's index in ``list(G.subgraph(c).copy())`` for its component ``c`` of rware's graph.

    ``start``/``target`` (N,) int32 flat cells ``y * width + x`` (starts distinct, ``target ==
    start`` for an agent that stays); ``G`` gets ``add_edge(start[i], target[i])`` for i in order.
    Components with ``2 * len(c) >= len(G)`` keep ``G``'s insertion order; smaller ones follow
    :func:`copy_positions` of the BFS order of ``c``. ``needed`` (N,) bool, optional: components
    holding no needed agent skip the emulation and get their insertion-order index (exact only
    where networkx keeps insertion order); all loops then run zero times when nothing is needed.
    """
    count, length = start.shape[0], longest_set_order_component(start.shape[0])
    if length > MAX_SET_SIZE:
        raise ValueError(f"{count} agents: a set-order component may outgrow the emulated tables")
    slots, agents = 2 * count, jnp.arange(count, dtype=jnp.int32)
    ids = jnp.arange(slots, dtype=jnp.int32)
    cell = jnp.stack([start, target], axis=1).reshape(slots)  # G's insertion: start 2i, then target 2i + 1
    node = jnp.argmax(cell[:, None] == cell[None, :], axis=1).astype(jnp.int32)  # a cell's first slot
    is_node = node == ids
    tail, head = node[0::2], node[1::2]  # agent i's edge, as nodes
    leaves, enters = tail[None, :] == ids[:, None], head[None, :] == ids[:, None]  # [node, agent]

    # Components: follow the out-edge (one per start cell) by doubling; a tree ends at its sink
    # or stationary cell, a cycle is named by its least node.
    jump = jnp.where(jnp.any(leaves, axis=1), jnp.max(jnp.where(leaves, head[None, :], 0), axis=1), ids)
    least = ids
    for _ in range(max(int(np.ceil(np.log2(slots))), 1)):
        least, jump = jnp.minimum(least, least[jump]), jump[jump]
    label = least[jump]
    same = (label[:, None] == label[None, :]) & is_node[None, :]  # [x, y]: node y is in x's component
    size = jnp.sum(same, axis=1)
    wanted = jnp.ones(count, bool) if needed is None else needed
    wanted = jnp.any((label[:, None] == label[tail][None, :]) & wanted[None, :], axis=1)
    active = is_node & wanted & (2 * size < jnp.sum(is_node))  # FilterAtlas: 2 * len(nodes) < len(G)
    earlier = same & (ids[None, :] < ids[:, None])
    source = active & ~jnp.any(earlier, axis=1)  # the component's first node in G

    # _plain_bfs from there; a node lists its successor, then its predecessors by agent. Level by
    # level: a new node's key is (its first discoverer's position, its index in that one's list).
    def visit(state):
        position, frontier = state
        fresh, none = position < 0, slots * (count + 1)
        key_head = jnp.where(frontier[tail] & fresh[head], position[tail] * (count + 1), none)
        key_tail = jnp.where(frontier[head] & fresh[tail], position[head] * (count + 1) + 1 + agents, none)
        key = jnp.minimum(jnp.min(jnp.where(enters, key_head[None, :], none), axis=1),
                          jnp.min(jnp.where(leaves, key_tail[None, :], none), axis=1))
        new = key < none
        placed = jnp.sum(same & ~fresh[None, :], axis=1)
        before = jnp.sum(same & new[None, :] & (key[None, :] < key[:, None]), axis=1)
        return jnp.where(new, placed + before, position).astype(jnp.int32), new

    position, _ = lax.while_loop(lambda state: jnp.any(active & (state[0] < 0)), visit,
                                 (jnp.where(source, 0, -1).astype(jnp.int32), source))

    # Both sets for every such component at once, each named by its first agent, keys in BFS turn.
    high, low = tuple_hash(cell % width, cell // width)
    lane = jnp.min(jnp.where(label[tail][None, :] == label[:, None], agents[None, :], count), axis=1)
    lane = jnp.where(active, lane, count)
    found = jnp.sum(lane[None, :] == agents[:, None], axis=1)
    copied = copy_positions(high, low, found, position, lane, most=length)

    inserted = jnp.sum(earlier, axis=1)
    return jnp.where(active, copied, inserted)[tail].astype(jnp.int32)
