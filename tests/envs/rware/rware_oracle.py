"""The rware 2.0.0 oracle of the RWARE parity tests: its graph order, its draws, policies and comparisons.

rware decides equal-length chain ties by ``networkx``'s node iteration order, which for some
components is hash-set order (NOTES.md 9.1): our default ``tie_order="set"`` emulates it, so
rware runs unpatched; :func:`insertion_order` patches ``DiGraph.subgraph`` to keep the graph's
insertion order, the rule of ``tie_order="insertion"``.
:class:`DrawRecorder` stands in for a warehouse's generator and records each replacement draw
as the index rware picked among the candidates, the form ``transition_with`` replays.
"""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
import fast_compile

nx = pytest.importorskip("networkx")
pytest.importorskip("rware")

from rware.warehouse import Action, Direction, RewardType, Warehouse  # noqa: E402

from wrl_jax.envs.rware import env_from_rware, from_rware, rware_arrays, state_arrays  # noqa: E402
from wrl_jax.envs.rware.env import Rware  # noqa: E402

__all__ = ["Action", "Direction", "RewardType", "Warehouse"]

STEP = fast_compile.jit(Rware.transition_with, static_argnums=0)
"""One compiled step per static configuration (the env is a static argument, its params explicit), compiled at
LLVM level 0 (``fast_compile``: these runs are a few hundred steps, compiling is their time)."""
OBSERVE = fast_compile.jit(Rware.get_obs, static_argnums=0)

CUSTOM_LAYOUT = """
g..x.x..g
.xx.x.xx.
.xx...xx.
.........
X.xx.xx.X
x.xx.xx.x
....G....
"""
"""A custom rware layout string (goals in three rows, shelves by the walls): upper and lower case alike."""


def ordered_subgraph(graph, nodes):
    """``graph.subgraph(nodes)`` as a new DiGraph whose nodes and edges keep ``graph``'s insertion order."""
    keep = set(nodes)
    sub = nx.DiGraph()
    sub.add_nodes_from(node for node in graph if node in keep)
    sub.add_edges_from((u, v) for u, targets in graph.adj.items() if u in keep for v in targets if v in keep)
    return sub


def tie_rule(tie_order: str):
    """The context rware runs in to follow ``tie_order``: unpatched for ``"set"``, :func:`insertion_order` otherwise."""
    return contextlib.nullcontext() if tie_order == "set" else insertion_order()


@contextlib.contextmanager
def insertion_order():
    """Within the block, rware's ``G.subgraph(c).copy()`` keeps G's insertion order (NOTES.md 9.1)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(nx.DiGraph, "subgraph", ordered_subgraph)
        yield


class DrawRecorder:
    """A warehouse's ``np_random`` that records each ``choice(candidates)`` as the chosen index."""

    def __init__(self, generator):
        self.generator = generator
        self.draws: list[int] = []

    def choice(self, population, *args, **kwargs):
        chosen = self.generator.choice(population, *args, **kwargs)
        if isinstance(population, list) and not args and not kwargs:  # rware's replacement draw
            self.draws.append(next(i for i, shelf in enumerate(population) if shelf is chosen))
        return chosen

    def __getattr__(self, name):
        return getattr(self.generator, name)


def record_draws(warehouse) -> DrawRecorder:
    recorder = DrawRecorder(warehouse.np_random)
    warehouse._np_random = recorder
    return recorder


def ours(warehouse, tie_order: str = "set"):
    """``(env, state, params)`` of a reset warehouse: the env without default params (one program per shape)."""
    env = env_from_rware(warehouse, tie_order).without_default_params()
    state, params = from_rware(warehouse)
    return env, state, params


def step(env, state, params, actions, draws=()):
    """One step of ours: ``(obs, state, reward, terminated, truncated, info)`` as NumPy, replaying ``draws``."""
    replacements = np.zeros(env.num_goals, np.int32)
    replacements[: len(draws)] = draws
    obs, state, reward, terminated, truncated, info = STEP(env, state, np.asarray(actions, np.int32), replacements,
                                                           params)
    return np.asarray(obs), state, np.asarray(reward), bool(terminated), bool(truncated), info


def mismatches(warehouse, rware_out, state, our_out) -> list[str]:
    """What differs between rware's step result and ours: observations, rewards, done, every state field."""
    obs, rewards, done = rware_out
    our_obs, our_reward, terminated, truncated = our_out
    bad = []
    if not np.array_equal(our_obs, np.stack(obs)):
        bad.append("obs")
    if not np.array_equal(our_reward, np.asarray(rewards, np.float32)):
        bad.append("reward")
    if terminated or truncated != bool(done):
        bad.append("done")
    theirs, mine = rware_arrays(warehouse), state_arrays(state)
    bad += [name for name in theirs if not np.array_equal(theirs[name], mine[name])]
    return bad


# ------------------------------------------------------------------ policies (NumPy, on the state arrays)
HEADINGS = np.array([[0, -1], [0, 1], [-1, 0], [1, 0]])  # up, down, left, right as (dx, dy)
RIGHT_OF = np.array([3, 2, 0, 1])
LEFT_OF = np.array([2, 3, 1, 0])


def random_policy(arrays, layout, rng, msg_bits=0):
    count = len(arrays["agent_x"])
    return rng.integers(0, 5, count)


def biased_policy(arrays, layout, rng, msg_bits=0):
    """Mostly forward (60%), the rest spread over the other actions: long chains and queues."""
    count = len(arrays["agent_x"])
    return np.where(rng.random(count) < 0.6, 1, rng.choice([0, 2, 3, 4], count))


def crowding_policy(arrays, layout, rng, msg_bits=0, noise=0.1, rush=0.3):
    """Fetch requested shelves and drive them to the goals (some empty agents rush the goals too).

    Unloaded agents head for the nearest standing requested shelf and pick it up; loaded agents
    with a requested shelf head for the nearest goal, with another shelf take it home and drop
    it there (or on any non-highway cell on the way). Greedy on Manhattan distance, turning toward
    the chosen heading, so many agents meet at the goals: chains, queues and equal-length chains
    into one cell.
    """
    highway, goals = layout
    height, width = highway.shape
    x, y, heading, carrying = arrays["agent_x"], arrays["agent_y"], arrays["agent_dir"], arrays["carrying"]
    carried = np.zeros(len(arrays["shelf_x"]), bool)
    carried[carrying[carrying >= 0]] = True
    standing = np.zeros((height, width), bool)
    standing[arrays["shelf_y"][~carried], arrays["shelf_x"][~carried]] = True
    requested = np.zeros(len(carried), bool)
    requested[arrays["queue"]] = True
    wanted = np.flatnonzero(requested & ~carried)
    homes = np.stack(np.nonzero(~highway)[::-1], axis=1)  # shelf i's reset cell (x, y), row-major
    actions = rng.integers(0, 5, len(x))
    for i in range(len(x)):
        if rng.random() < noise:
            continue
        if carrying[i] < 0 and rng.random() < rush:
            tx, ty = goals[rng.integers(len(goals))]
        elif carrying[i] >= 0 and requested[carrying[i]]:
            tx, ty = goals[np.argmin(np.abs(goals - [x[i], y[i]]).sum(1))]
        elif carrying[i] >= 0:
            if not highway[y[i], x[i]]:
                actions[i] = 4
                continue
            tx, ty = homes[carrying[i]]
        elif len(wanted):
            k = wanted[np.argmin(np.abs(arrays["shelf_x"][wanted] - x[i]) + np.abs(arrays["shelf_y"][wanted] - y[i]))]
            tx, ty = arrays["shelf_x"][k], arrays["shelf_y"][k]
        else:
            continue
        if (tx, ty) == (x[i], y[i]):
            actions[i] = 4 if carrying[i] < 0 else 0
            continue
        options = []
        for h, (dx, dy) in enumerate(HEADINGS):
            nx_, ny_ = x[i] + dx, y[i] + dy
            closer = abs(tx - nx_) + abs(ty - ny_) < abs(tx - x[i]) + abs(ty - y[i])
            if 0 <= nx_ < width and 0 <= ny_ < height and closer and not (carrying[i] >= 0 and standing[ny_, nx_]):
                options.append(h)
        if not options:
            actions[i] = rng.choice([1, 2, 3])
            continue
        want = heading[i] if heading[i] in options else options[rng.integers(len(options))]
        actions[i] = 1 if want == heading[i] else 3 if RIGHT_OF[heading[i]] == want else 2
    return actions


POLICIES = {"random": random_policy, "biased": biased_policy, "crowding": crowding_policy}


def with_messages(actions, rng, msg_bits):
    """rware's MultiDiscrete action ``[a, bit, bit, ...]`` per agent when messages are on."""
    if not msg_bits:
        return actions
    return np.concatenate([actions[:, None], rng.integers(0, 2, (len(actions), msg_bits))], axis=1)


# ------------------------------------------------------------------ the move graph, counted (for coverage)
def graph_events(arrays, actions, grid_size) -> dict[str, int]:
    """Which conflict cases a step's move graph holds: ties between equal chains (and how many of them
    networkx orders by a hash set, ``set_order_tie``), head-on swaps, rotations.

    Built the way rware builds it (targets, cancel pass) in plain Python, to show that the
    parity runs exercise the cases the conflict rule exists for.
    """
    height, width = grid_size
    cells = {(int(x), int(y)): i for i, (x, y) in enumerate(zip(arrays["agent_x"], arrays["agent_y"]))}
    shelf_cells = set(zip(arrays["shelf_x"].tolist(), arrays["shelf_y"].tolist()))
    moves = {0: (0, -1), 1: (0, 1), 2: (-1, 0), 3: (1, 0)}
    graph = nx.DiGraph()
    for (x, y), i in cells.items():
        target = (x, y)
        if actions[i] == 1:
            dx, dy = moves[int(arrays["agent_dir"][i])]
            target = (min(max(x + dx, 0), width - 1), min(max(y + dy, 0), height - 1))
        occupant = cells.get(target)
        blocked = (arrays["carrying"][i] >= 0 and target != (x, y) and target in shelf_cells
                   and not (occupant is not None and arrays["carrying"][occupant] >= 0))
        graph.add_edge((x, y), (x, y) if blocked else target)
    events = {"tie": 0, "set_order_tie": 0, "head_on": 0, "rotation": 0}
    for component in nx.weakly_connected_components(graph):
        sub = graph.subgraph(component)
        try:
            cycle = nx.find_cycle(sub)
            events["head_on"] += len(cycle) == 2
            events["rotation"] += len(cycle) > 2
        except nx.NetworkXNoCycle:
            depth = {}
            for node in nx.topological_sort(sub):
                depth[node] = 1 + max((depth[u] for u in sub.pred[node]), default=-1)
            node = next(v for v in sub if sub.out_degree(v) == 0)  # the empty cell the chains end in
            while sub.pred[node]:  # back along a longest chain: a tie is two predecessors of equal depth
                tied = [u for u in sub.pred[node] if depth[u] == depth[node] - 1]
                if len(tied) > 1:
                    events["tie"] += 1
                    events["set_order_tie"] += 2 * len(component) < len(graph)  # networkx iterates a hash set
                    break
                node = tied[0]
    return events
