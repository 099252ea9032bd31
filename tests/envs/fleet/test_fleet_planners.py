"""Fleet planners: JAX PIBT and greedy against plain NumPy versions written here from the paper.

The NumPy PIBT below is the recursive pseudocode of Okumura et al. (IJCAI 2019,
Algorithm 1) with sets for UNDECIDED and OCCUPIED, written independently of
``wrl_jax.envs.fleet.planners`` (which uses an explicit stack); both follow the
documented rules: candidates by (distance to target, action index), priority
by (steps since the target was last reached, then lower robot index). The
distance fields here come from a NumPy BFS of this file as well.
"""

from __future__ import annotations

import functools
import json
from collections import deque

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wrl_jax.cli import plan
from wrl_jax.core.grid import UNREACHABLE
from wrl_jax.core.registry import make
from wrl_jax.envs.fleet import metrics, planners
from wrl_jax.envs.fleet.conflicts import resolve_conflicts

STEPS = [(-1, 0), (1, 0), (0, -1), (0, 1), (0, 0)]  # actions 0 up, 1 down, 2 left, 3 right, 4 wait
HORIZON = 256
EPISODES = 4

FAST_COMPILE = {"xla_backend_optimization_level": 0}
"""Test programs are compiled for compile time: they run for milliseconds, compiling them takes seconds."""

recorded_rollouts = jax.jit(jax.vmap(metrics.rollout, in_axes=(None, None, None, 0, None)), static_argnums=(0, 2, 4),
                            compiler_options=FAST_COMPILE)
"""Recorded shifts, one per key, vmapped; one module-level jit so equal calls share the compiled program."""


# ---------------------------------------------------------------- NumPy planners (independent)
def bfs(blocked: np.ndarray, target) -> np.ndarray:
    size = blocked.shape[0]
    dist = np.full(blocked.shape, UNREACHABLE, dtype=np.int64)
    dist[tuple(target)] = 0
    queue = deque([tuple(target)])
    while queue:
        r, c = queue.popleft()
        for dr, dc in STEPS[:4]:
            v = (r + dr, c + dc)
            if 0 <= v[0] < size and 0 <= v[1] < size and not blocked[v] and dist[v] == UNREACHABLE:
                dist[v] = dist[r, c] + 1
                queue.append(v)
    return dist


def neighbours(cell, blocked):
    """Free cells reachable by each action, with the action: [(action, cell)]."""
    size = blocked.shape[0]
    out = []
    for action, (dr, dc) in enumerate(STEPS):
        v = (cell[0] + dr, cell[1] + dc)
        if 0 <= v[0] < size and 0 <= v[1] < size and not blocked[v]:
            out.append((action, v))
    return out


def numpy_pibt(pos, blocked, fields, priority, stats=None):
    """Algorithm 1 of the paper; ``priority[i]`` any comparable values, distinct. Returns the actions."""
    num = len(pos)
    here = [tuple(int(x) for x in p) for p in pos]
    standing = {cell: i for i, cell in enumerate(here)}
    nxt = [None] * num
    undecided, occupied = set(range(num)), set()

    def search(i, j):
        undecided.discard(i)
        ranked = sorted(neighbours(here[i], blocked), key=lambda av: (fields[i][av[1]], av[0]))
        options = [v for _, v in ranked if v not in occupied and (j is None or v != here[j])]
        while options:
            v = options.pop(0)
            occupied.add(v)
            k = standing.get(v)
            if k is not None and k in undecided:
                if search(k, i):
                    nxt[i] = v
                    return True
                if stats is not None:
                    stats["backtracks"] += 1
                options = [u for u in options if u not in occupied]
            else:
                nxt[i] = v
                return True
        nxt[i] = here[i]
        return False

    while undecided:
        search(max(undecided, key=lambda k: priority[k]), None)
    return np.array([STEPS.index((n[0] - h[0], n[1] - h[1])) for n, h in zip(nxt, here)])


def numpy_greedy(pos, blocked, fields):
    actions = []
    for i, cell in enumerate(pos):
        cell = tuple(int(x) for x in cell)
        better = [a for a, v in neighbours(cell, blocked) if a < 4 and fields[i][v] == fields[i][cell] - 1]
        actions.append(better[0] if better else 4)
    return np.array(actions)


# ---------------------------------------------------------------- random fleet states
def random_states(rng, size, num_robots, count):
    """``count`` random connected grids with robots on distinct free cells and random targets."""
    out = []
    while len(out) < count:
        shelves = rng.random((size, size)) < 0.3
        free = np.argwhere(~shelves)
        if len(free) == 0:
            continue
        component = bfs(shelves, free[rng.integers(len(free))]) < UNREACHABLE
        free = np.argwhere(component)
        if len(free) < num_robots + 1:
            continue
        blocked = ~component  # cells cut off from the robots count as shelves
        pos = free[rng.choice(len(free), num_robots, replace=False)]
        goals = free[rng.integers(len(free), size=num_robots)]
        fields = np.stack([bfs(blocked, g) for g in goals])
        out.append((blocked, pos, fields, rng.permutation(num_robots)))
    return out


@functools.partial(jax.jit, static_argnames="size", compiler_options=FAST_COMPILE)
def jax_planners_on_states(pos, fields, priority, size):
    """Both planners on a batch of states given per-robot distance fields (as item tables, nobody carrying)."""
    def one(pos, fields, priority):
        k = pos.shape[0]
        index = jnp.arange(k)
        cand_dist = planners.candidate_distances(pos, index, index, jnp.zeros(k, bool), fields, fields)
        return planners.greedy_actions(cand_dist), planners.pibt_actions(pos, cand_dist, priority, size)

    return jax.vmap(one)(pos, fields, priority)


@functools.lru_cache(maxsize=None)
def planned_random_states():
    """400 dense random states (12 robots on ~30 free cells of a 7x7 grid) and both JAX planners' actions."""
    rng = np.random.default_rng(14)
    size, num_robots = 7, 12
    states = random_states(rng, size, num_robots, 400)
    stack = lambda idx: jnp.asarray(np.stack([s[idx] for s in states]).astype(np.int32))  # noqa: E731
    greedy, pibt = jax.device_get(jax_planners_on_states(stack(1), stack(2), stack(3), size))
    return states, greedy, pibt


def test_planners_match_numpy_on_random_states():
    states, greedy, pibt = planned_random_states()
    stats = {"backtracks": 0}
    moved = 0
    for b, (blocked, pos, fields, priority) in enumerate(states):
        np.testing.assert_array_equal(pibt[b], numpy_pibt(pos, blocked, fields, priority, stats), err_msg=f"state {b}")
        np.testing.assert_array_equal(greedy[b], numpy_greedy(pos, blocked, fields), err_msg=f"state {b}")
        moved += int(np.sum(pibt[b] != 4))
    assert stats["backtracks"] > 20, "the random states should exercise PIBT's backtracking"
    assert moved > len(states)


def test_pibt_moves_pass_the_conflict_rule_on_random_states():
    states, _, actions = planned_random_states()
    pos = np.stack([s[1] for s in states]).astype(np.int32)
    nxt = pos + np.asarray(STEPS)[actions]
    _, blocked = jax.jit(jax.vmap(resolve_conflicts), compiler_options=FAST_COMPILE)(pos, nxt)
    assert not bool(np.any(blocked)), "FLEET_SPEC's rule blocked a PIBT move"
    for b, (grid, p, _, _) in enumerate(states):
        cells = {tuple(c) for c in nxt[b]}
        assert len(cells) == len(p), f"state {b}: two robots in one cell"
        assert not any(grid[c] for c in cells), f"state {b}: a robot on a shelf"
        moves = {(tuple(a), tuple(c)) for a, c in zip(p, nxt[b]) if tuple(a) != tuple(c)}
        assert not any((c, a) in moves for a, c in moves), f"state {b}: a swap"


# ---------------------------------------------------------------- whole episodes on Fleet-12x12
@functools.lru_cache(maxsize=None)
def episodes(num_robots: int, planner: str):
    """``EPISODES`` recorded shifts of ``planner`` on Fleet-12x12-v0 (vmapped, one program)."""
    env, params = make("Fleet-12x12-v0", num_robots=num_robots)
    keys = jax.random.split(jax.random.key(2026), EPISODES)
    _, steps = recorded_rollouts(env, params, planner, keys, HORIZON)
    return env, params, jax.device_get(steps)


@functools.lru_cache(maxsize=None)
def layout_fields():
    """NumPy BFS fields of Fleet-12x12-v0's items and stations (this file's BFS, not the env's tables)."""
    _, params = make("Fleet-12x12-v0", num_robots=1)
    shelves = np.asarray(params.shelves)
    items = np.stack([bfs(shelves, c) for c in np.asarray(params.items)[: int(params.num_items)]])
    stations = np.stack([bfs(shelves, c) for c in np.asarray(params.stations)[: int(params.num_stations)]])
    return shelves, np.asarray(params.items), np.asarray(params.stations), items, stations


@pytest.mark.parametrize("num_robots", [1, 2, 4, 8])
def test_pibt_long_rollouts_never_block(num_robots):
    _, _, steps = episodes(num_robots, "pibt")
    for flag in ("robot_block", "shelf_hit", "wall_bump"):
        assert int(steps.flags[flag].sum()) == 0, flag
    assert int(steps.flags["delivered"].sum()) >= 4 * EPISODES * num_robots  # they do work, not just wait


@pytest.mark.parametrize("planner", ["pibt", "greedy"])
def test_planners_match_numpy_move_for_move_over_episodes(planner):
    """Every step of K=8 shifts: the NumPy planner on the recorded state, priorities tracked here."""
    _, _, steps = episodes(8, planner)
    shelves, item_cells, station_cells, item_fields, station_fields = layout_fields()
    followed = 0
    for e in range(EPISODES):
        age = np.zeros(8, dtype=np.int64)
        for t in range(HORIZON):
            pos = steps.state.pos[e, t]
            carrying = steps.state.carrying[e, t]
            item, station = steps.state.item[e, t], steps.state.station[e, t]
            fields = np.where(carrying[:, None, None], station_fields[station], item_fields[item])
            if planner == "pibt":
                expected = numpy_pibt(pos, shelves, fields, [(age[i], -i) for i in range(8)])
            else:
                expected = numpy_greedy(pos, shelves, fields)
            np.testing.assert_array_equal(steps.action[e, t], expected, err_msg=f"episode {e} step {t}")
            target = np.where(carrying[:, None], station_cells[station], item_cells[item])
            after = steps.state.pos[e, t + 1] if t + 1 < HORIZON else None
            if after is not None:
                age = np.where((after == target).all(axis=1), 0, age + 1)
                vacated = {tuple(c) for c, a in zip(pos, after) if tuple(c) != tuple(a)}
                followed += sum(tuple(a) in vacated for a in after)
    if planner == "pibt":
        assert followed > 0, "PIBT rollouts should include robots following one another"


def test_pibt_beats_greedy_at_eight_robots():
    per_step = {p: episodes(8, p)[2].flags["delivered"].sum(axis=(1, 2)) / HORIZON for p in ("pibt", "greedy")}
    # Measured (seed 2026, 4 shifts): PIBT ~0.32 deliveries/step (bound K/L* = 0.38), greedy ~0.01 (deadlocks).
    assert per_step["pibt"].min() > 3 * per_step["greedy"].max() + 0.05, per_step
    _, params, _ = episodes(8, "pibt")
    assert per_step["pibt"].max() <= 8 / metrics.mean_round_trip(params) * 1.1  # the bound is (nearly) a bound


def test_planner_programs_compile_with_the_classic_emitter_and_count_the_same():
    """``run_episodes`` is compiled with ``planners.compiler_options()`` (on CPU the classic fusion emitter,
    faster for PIBT's loop); XLA's default options give the same counts, bit for bit.

    The plan command's program below (K = 8, the same shifts and key): one compile serves both tests (the
    session's compilation cache)."""
    assert planners.compiler_options() == {"xla_cpu_use_fusion_emitters": False}  # the suite runs on CPU
    env, params = make("Fleet-12x12-v0", num_robots=8)
    key = jax.random.key(2026)
    lowered = metrics.run_episodes.lower(env, params, "pibt", key, EPISODES, HORIZON)
    mine = jax.device_get(metrics.run_episodes(env, params, "pibt", key, EPISODES, HORIZON))
    defaults = jax.device_get(lowered.compile(compiler_options={"xla_cpu_use_fusion_emitters": True})(params, key))
    assert mine["delivered"].sum() > 0
    for name in metrics.COUNTED:
        np.testing.assert_array_equal(mine[name], defaults[name], err_msg=name)


# ---------------------------------------------------------------- priorities and rollout plumbing
@functools.partial(jax.jit, compiler_options=FAST_COMPILE)
def priority_cases():
    """The priority updates of the next test, in one program (eager calls would compile one by one)."""
    state = planners.pibt_init(4)
    first = planners.pibt_priorities(state)
    state = planners.pibt_update(state, jnp.array([False, True, False, False]))
    flags = {"picked_up": jnp.array([True, False, False, False]), "delivered": jnp.array([False, False, True, False])}
    old = state.replace(age=jnp.full(4, 2**29, jnp.int32))
    return dict(
        first=first, age=state.age, priority=planners.pibt_priorities(state),
        after_flags=planners.next_priorities(state, flags, jnp.array(False)).age,
        after_done=planners.next_priorities(state, flags, jnp.array(True)).age,
        saturated=planners.pibt_priorities(planners.pibt_update(old, jnp.zeros(4, bool))),
        shuffled=planners.pibt_init(6, jax.random.key(3)).tiebreak,
    )


def test_priorities_are_a_total_order_that_resets_on_reaching_the_target():
    got = jax.device_get(priority_cases())
    np.testing.assert_array_equal(got["first"], [3, 2, 1, 0])  # ages 0: robot 0 first
    np.testing.assert_array_equal(got["age"], [1, 0, 1, 1])
    np.testing.assert_array_equal(got["priority"], [7, 2, 5, 4])
    np.testing.assert_array_equal(got["after_flags"], [0, 1, 0, 2])
    np.testing.assert_array_equal(got["after_done"], [0, 0, 0, 0])
    assert 0 < int(got["saturated"].max()) < 2**31 - 1 and len(set(got["saturated"].tolist())) == 4
    assert sorted(got["shuffled"].tolist()) == list(range(6))
    with pytest.raises(ValueError, match="num_robots"):
        planners.pibt_init(0)
    with pytest.raises(ValueError, match="unknown planner 'astar'"):
        planners.check_planner("astar")


def test_plan_command_counts_equal_the_recorded_flags(tmp_path):
    """``python -m wrl_jax.plan`` (vmapped counts, no trajectory) against the recorded shifts of the same keys
    (K = 8: the emitter test's program, and the recorded shifts the move-for-move test replays)."""
    out = tmp_path / "pibt.json"
    argv = ["--planner", "pibt", "--num-robots", "8", "--episodes", str(EPISODES), "--seed", "2026",
            "--json", str(out), "--xla-opt-level", "-1"]
    assert plan.main(argv) == 0
    report = json.loads(out.read_text())
    _, _, steps = episodes(8, "pibt")
    np.testing.assert_allclose(report["throughput"]["per_episode"],
                               steps.flags["delivered"].sum(axis=(1, 2)) / HORIZON)
    names = {"delivered": "deliveries", "shelf_hit": "shelf_hits", "wall_bump": "wall_bumps",
             "robot_block": "robot_blocks", "waited": "waits"}
    for flag, name in names.items():
        np.testing.assert_allclose(report["per_robot"][name], steps.flags[flag].sum(axis=1).mean(axis=0), err_msg=name)
    tp = report["throughput"]
    assert tp["ci95"][0] < tp["mean"] < tp["ci95"][1]
    assert report["upper_bound"]["throughput"] == pytest.approx(8 / mean_round_trip_here())
    assert 0.5 < report["upper_bound"]["fraction"] < 1.1


def mean_round_trip_here() -> float:
    """``L*`` of Fleet-12x12-v0 from this file's BFS: mean over items i, stations g of d(g, i) + d(i, g)."""
    shelves, item_cells, station_cells, item_fields, station_fields = layout_fields()
    trips = [station_fields[g][tuple(i)] + item_fields[k][tuple(station_cells[g])]
             for k, i in enumerate(item_cells[: len(item_fields)]) for g in range(len(station_fields))]
    return float(np.mean(trips))


def test_seeds_matter_and_reruns_repeat():
    env, params, steps = episodes(2, "pibt")
    again = recorded_rollouts(env, params, "pibt", jax.random.split(jax.random.key(2027), EPISODES), HORIZON)[1]
    assert not np.array_equal(jax.device_get(again.action), steps.action)
    rerun = episodes.__wrapped__(2, "pibt")[2]
    np.testing.assert_array_equal(rerun.action, steps.action)
