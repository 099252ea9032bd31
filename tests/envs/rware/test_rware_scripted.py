"""The scripted RWARE team (``wrl_jax.envs.rware.scripted``): its parts, that it delivers far above a random team
on the evaluation's episodes, that it plays by the rules (valid actions, no bump into a shelf, no wasted toggle),
and ``python -m wrl_jax.plan --planner scripted``.

Programs: the tests' own (the rules' episodes, the two state-policy runs in one program) and small-4ag's teams
(``TEAM_EPISODES``) compile at LLVM level 0 (``fast_compile``); tiny-4ag's teams (``team_and_random``) compile as the
plan command compiles them, and its test runs that environment: the command's programs come from the caches."""

from __future__ import annotations

import collections
import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import fast_compile

from wrl_jax.cli import plan as plan_cli
from wrl_jax.core import registry
from wrl_jax.envs.rware import evaluation, make_rware, scripted
from wrl_jax.envs.rware.types import FORWARD, NUM_ACTIONS, TOGGLE_LOAD

STEP_X, STEP_Y = np.array(scripted.STEP_X), np.array(scripted.STEP_Y)
TEAM_EPISODES = fast_compile.fast(evaluation.team_episodes, (0,), ("num_episodes", "horizon", "seed", "team"))
"""``evaluation.team_episodes`` compiled at LLVM level 0 (``fast_compile``); the same numbers, in less compile time."""


def python_bfs(seed: np.ndarray, passable: np.ndarray) -> np.ndarray:
    height, width = seed.shape
    dist = np.full(seed.shape, scripted.UNREACHABLE, np.int64)
    queue = collections.deque(zip(*np.nonzero(seed)))
    dist[seed] = 0
    while queue:
        y, x = queue.popleft()
        for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            ny, nx = y + dy, x + dx
            if 0 <= ny < height and 0 <= nx < width and passable[ny, nx] and dist[ny, nx] > dist[y, x] + 1:
                dist[ny, nx] = dist[y, x] + 1
                queue.append((ny, nx))
    return dist


def test_distance_field_is_bfs_through_passable_cells():
    rng = np.random.default_rng(0)
    for _ in range(5):
        passable = rng.random((7, 9)) < 0.7
        seed = np.zeros((7, 9), bool)
        cells = rng.integers(0, (7, 9), size=(2, 2))
        seed[cells[:, 0], cells[:, 1]] = True
        field = scripted.distance_field(jnp.asarray(seed), jnp.asarray(passable), jnp.zeros((7, 9), jnp.int32))
        np.testing.assert_array_equal(np.asarray(field), python_bfs(seed, passable))


def test_distance_field_charges_the_crowd_penalty_on_entry():
    seed = np.zeros((1, 5), bool)
    seed[0, 0] = True
    crowd = jnp.zeros((1, 5), jnp.int32).at[0, 2].set(8)
    field = scripted.distance_field(jnp.asarray(seed), jnp.ones((1, 5), bool), crowd)
    assert np.asarray(field).tolist() == [[0, 1, 2, 11, 12]]  # leaving cell 2 toward the seed costs 1, entering it 9


def test_assignment_is_greedy_and_one_agent_per_shelf():
    barred = 1 << 30
    cost = jnp.array([[3, 1, 5], [2, 1, 9], [barred, barred, barred], [4, 6, 7]], jnp.int32)
    assigned = np.asarray(scripted.assign_shelves(cost))
    # (0, 1) costs 1 and comes first; then (1, 0) at 2; agent 2 may have none; agent 3 gets the last, shelf 2.
    assert assigned.tolist() == [1, 0, -1, 2]


def test_a_state_policy_leaves_the_environment_draws_alone():
    """``sees_state`` changes only what the policy reads: the same actions give the same episodes, bit for bit."""
    env, params = registry.make("rware-tiny-2ag-v2")
    forward = jnp.full(env.num_agents, FORWARD, jnp.int32)

    @fast_compile.jit  # both runs in one program
    def both(params):
        return (evaluation.run_episodes(lambda obs: forward, env, params, 2, 40),
                evaluation.run_episodes(lambda key, state: forward, env, params, 2, 40, sees_state=True))

    by_obs, by_state = both(params)
    for a, b in zip(jax.tree.leaves(by_obs), jax.tree.leaves(by_state)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


PLAN_ENV, PLAN_EPISODES = "rware-tiny-4ag-v2", 4
"""The plan command's test runs these: its programs are those of the delivery test's tiny-4ag team."""


@functools.cache
def team_and_random(name: str):
    """The scripted and the random team on the evaluation's first 4 episodes (500 steps) of ``name``, as NumPy.

    For the plan command's environment, compiled as the command compiles (its own calls, at the session's level),
    so that the command's programs come from the compilation caches; for the others, at LLVM level 0."""
    env, params = registry.make(name)
    if name == PLAN_ENV:
        static = {"num_episodes": PLAN_EPISODES, "horizon": 500, "seed": 0}
        team = evaluation.team_episodes.lower(env, params, team="scripted", **static).compile()(params)
        random = evaluation.team_episodes(env, params, team="random", **static)
    else:
        team = TEAM_EPISODES(env, params, num_episodes=4)
        random = TEAM_EPISODES(env, params, num_episodes=4, team="random")
    return jax.device_get((team, random))


@pytest.mark.parametrize("name, floor", [("rware-tiny-4ag-v2", 40.0), ("rware-small-4ag-v2", 28.0)])
def test_the_scripted_team_delivers_far_above_a_random_team(name, floor):
    """On the evaluation's first 4 episodes (on its 32: 29.8, 57.9, 41.0, worst 27, 54, 37; random 0.03 to 0.06)."""
    team, random = team_and_random(name)
    assert team.team_return.min() >= floor, team.team_return
    assert team.team_return.mean() >= random.team_return.mean() + floor
    assert np.all(team.deliveries > 0)  # every agent delivers in every episode: the evaluation's "solved"
    np.testing.assert_array_equal(team.team_return, team.deliveries.sum(axis=1))  # 1 per delivery
    assert random.team_return.mean() < 2


def test_it_plays_by_the_rules():
    """Over two episodes of tiny-4ag: actions in 0..4, no loaded FORWARD into a resting shelf (rware would refuse it)
    or off the grid, and every TOGGLE_LOAD picks a shelf up or puts one down (none is wasted)."""
    env, params = registry.make("rware-tiny-4ag-v2")
    height, width = params.grid_size

    @fast_compile.jit
    def episode(key):
        state = env.reset(key, params)[1]

        def body(state, t):
            actions = scripted.scripted_actions(jax.random.fold_in(key, t), state, params, env)
            reached = env.transition(jax.random.fold_in(jax.random.fold_in(key, 1), t), state, actions, params)[1]
            return reached, (state, actions, reached.carrying)

        return jax.lax.scan(body, state, jnp.arange(500))[1]

    states, actions, carried_after = jax.device_get(jax.vmap(episode)(jax.random.split(jax.random.key(3), 2)))
    assert actions.dtype == np.int32 and actions.shape == (2, 500, env.num_agents)
    assert actions.min() >= 0 and actions.max() < NUM_ACTIONS
    highway = np.asarray(params.highway)
    loaded_forwards = toggles = 0
    for e, t in np.ndindex(2, 500):
        s = jax.tree.map(lambda leaf, e=e, t=t: leaf[e, t], states)
        carried = set(s.carrying[s.carrying >= 0].tolist())
        resting = {(int(x), int(y)) for i, (x, y) in enumerate(zip(s.shelf_x, s.shelf_y)) if i not in carried}
        for i, action in enumerate(actions[e, t]):
            loaded = s.carrying[i] >= 0
            if action == FORWARD and loaded:
                ahead = (s.agent_x[i] + STEP_X[s.agent_dir[i]], s.agent_y[i] + STEP_Y[s.agent_dir[i]])
                assert 0 <= ahead[0] < width and 0 <= ahead[1] < height, (e, t, i)
                assert (int(ahead[0]), int(ahead[1])) not in resting, (e, t, i)
                loaded_forwards += 1
            if action == TOGGLE_LOAD:
                cell = (int(s.agent_x[i]), int(s.agent_y[i]))
                assert (not highway[cell[1], cell[0]]) if loaded else cell in resting, (e, t, i)
                assert (carried_after[e, t, i] >= 0) != loaded, (e, t, i)
                toggles += 1
    assert loaded_forwards > 500 and toggles > 40  # the checks above saw many fetches, deliveries and returns


def test_plan_runs_the_scripted_team_and_reports(tmp_path, capsys):
    """tiny-4ag, 4 episodes: the delivery test's programs (``team_and_random``), served by the caches."""
    team, random = team_and_random(PLAN_ENV)
    out = tmp_path / "scripted.json"
    argv = ["--planner", "scripted", "--env", PLAN_ENV, "--episodes", str(PLAN_EPISODES), "--json", str(out),
            "--xla-opt-level", "-1"]
    assert plan_cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert "scripted on rware-tiny-4ag-v2, 4 agents, 4 episodes of 500 steps" in printed
    assert "team return" in printed and "random team" in printed and "deliveries per episode" in printed
    report = json.loads(out.read_text())
    assert report["planner"] == "scripted" and report["episodes"] == 4 and report["horizon"] == 500
    assert report["return"] == report["deliveries"] >= 20 > report["random_return"]
    assert report["solved"] and len(report["deliveries_per_agent"]) == 4
    assert report["return"] == float(team.team_return.mean()) and report["random_return"] == random.team_return.mean()


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--planner", "scripted"], "'Fleet-12x12-v0' is not an rware environment (--planner scripted)"),
        (["--planner", "scripted", "--env", "Continuous-Warehouse-8x8-v0"], "a continuous environment takes"),
        (["--planner", "pursuit", "--env", "rware-tiny-4ag-v2"], "an rware environment takes --planner scripted"),
        (["--planner", "pibt", "--env", "rware-tiny-4ag-v2"], "an rware environment takes --planner scripted"),
        (["--planner", "scripted", "--env", "rware-tiny-4ag-v2", "--num-robots", "4"], "--num-robots is for fleets"),
        (["--planner", "scripted", "--env", "rware-tiny-4ag-v2", "--randomize"], "--randomize is for continuous"),
        (["--planner", "scripted", "--env", "rware-tiny-4ag-v2", "--episodes", "0"], "--episodes must be a positive"),
        (["--planner", "scripted", "--env", "rware-tiny-4ag-v2", "--horizon", "0"], "--horizon must be a positive"),
        (["--planner", "scripted", "--env", "rware-tiny-5ag-v3"], "unknown environment 'rware-tiny-5ag-v3'"),
    ],
)
def test_bad_combinations_exit_2_with_the_reason(argv, message, capsys):
    assert plan_cli.main([*argv, "--xla-opt-level", "-1"]) == 2
    assert message in capsys.readouterr().err


def test_bad_team_and_messages_are_value_errors():
    env, params = registry.make("rware-tiny-2ag-v2")
    with pytest.raises(ValueError, match="unknown team 'greedy'"):
        evaluation.team_episodes(env, params, 1, team="greedy")
    env, params = make_rware(2, msg_bits=1)
    with pytest.raises(ValueError, match="msg_bits > 0 is not supported"):
        evaluation.team_episodes(env, params, 1)
