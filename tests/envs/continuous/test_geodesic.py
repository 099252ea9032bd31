"""Geodesic shaping (wrl_jax.envs.continuous.geodesic): the contract's MDP with the shaping distance measured
around the shelves.

The fields must be the length of the way around the shelves (checked against the exact any-angle
lengths of the yardstick), the environment must be the contract's in everything but the reward, and the
reward must differ from the contract's by exactly the change of potential (so a whole episode's shaping
telescopes to the distance covered). The route-following controller's evaluation, read against thresholds,
compiles at LLVM level 0 (``fast_compile``); the programs whose results are compared bit for bit at the session's.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import fast_compile

from wrl_jax.envs.continuous import geodesic
from wrl_jax.envs.continuous import shortest_path as spath
from wrl_jax.envs.continuous.registration import make_continuous, make_named


pytestmark = pytest.mark.usefixtures("geodesic_fields_at_the_commands_level")  # tests/conftest.py


@pytest.fixture(scope="module")
def study_12x12():
    return make_named("12x12"), make_named("12x12", shaping="geodesic")


def test_fields_are_the_way_around_the_shelves_within_three_percent(study_12x12):
    (_, params), (_, shaped) = study_12x12
    clearance = float(params.robot_radius) + geodesic.SPARE
    to_item, to_goal = spath.item_legs(np.asarray(params.shelves), np.asarray(params.start), np.asarray(params.goal),
                                       np.asarray(params.items), clearance)
    items = int(params.num_items)
    read, fields = jax.jit(geodesic.read_field), np.asarray(shaped.fields)  # eagerly: op by op compiles
    points = np.asarray(params.items)
    field_to_item = np.array([float(read(fields[k], params.start)) for k in range(items)])
    field_to_goal = np.array([float(read(fields[-1], points[k])) for k in range(items)])
    # The exact any-angle length at the field's clearance: the lattice's 16 directions make it a little longer
    # (a little shorter where a route rounds a corner between lattice points).
    for lattice, exact in ((field_to_item, to_item), (field_to_goal, to_goal)):
        assert np.all(np.abs(lattice / exact - 1) < 0.03), np.round(lattice / exact, 3)
    # ... which is metres longer than the straight line where shelf rows stand between.
    straight = np.linalg.norm(np.asarray(params.items) - np.asarray(params.goal), axis=-1)[:items]
    assert np.max(field_to_goal - straight) > 2.0


def test_routes_keep_their_margin_the_potential_rises_off_them_and_an_enclosed_target_is_unreachable():
    shelves = np.zeros((3, 5), bool)
    shelves[:, 2] = True  # a full column: the right half cannot be reached from the left
    margin = 0.4
    free = geodesic.free_lattice(shelves, margin)
    xs = np.arange(free.shape[1]) / geodesic.RESOLUTION
    assert not free[:, (xs > 2 - margin) & (xs < 3 + margin)].any() and not free[:, xs < margin].any()
    assert free[15, 5] and free[15, 45]
    fields = geodesic.distance_fields(shelves, np.array([[0.5, 1.5], [4.5, 1.5]]), margin)
    assert fields[0, 15, 5] == 0.0 and fields[0, 15, 45] == geodesic.UNREACHABLE
    assert fields[1, 15, 45] == 0.0 and fields[1, 15, 5] == geodesic.UNREACHABLE
    np.testing.assert_allclose(fields[0, 15, 15], 1.0, atol=1e-6)  # 1 m straight along a row
    # Off the routes (closer than the margin to the shelf column) the distance keeps growing towards it.
    row = fields[0, 15, 16:20]
    np.testing.assert_allclose(np.diff(row), 0.1, atol=1e-6)


def test_everything_but_the_reward_is_the_contracts_and_the_shaping_telescopes(study_12x12):
    """Both environments reset with one key, then step together from the shaped rollout's state: the resets and every
    step's observation, next state, flags and info are the contract's bit for bit (so, step by step, a rollout of
    the contract is the shaped rollout), and the reward differs by the change of potential. One program at the
    session's level: the two steps' shared work is compiled once."""
    (plain, params), (shaped, shaped_params) = study_12x12
    steps = 120
    key = jax.random.key(3)

    @jax.jit
    def rollout():
        resets = plain.reset(key, params), shaped.reset(key, shaped_params)

        def body(state, t):
            action = jax.random.uniform(jax.random.fold_in(key, t), (2,), minval=-1.0, maxval=1.0)
            action = action.at[0].set(jnp.abs(action[0]))  # mostly forward: the robot travels
            k = jax.random.fold_in(key, 1000 + t)
            ours, theirs = shaped.step(k, state, action, shaped_params), plain.step(k, state, action, params)
            return ours[1], (ours, theirs, state)

        return resets, jax.lax.scan(body, resets[1][1], jnp.arange(steps))[1]

    resets, (ours, theirs, before_state) = jax.device_get(rollout())
    for a, b in zip(jax.tree.leaves(resets[0]), jax.tree.leaves(resets[1])):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(jax.tree.leaves((ours[:2], ours[3:])), jax.tree.leaves((theirs[:2], theirs[3:]))):
        np.testing.assert_array_equal(a, b)
    after, reward, ended = ours[1].pos, ours[2], ours[3] | ours[4]
    before, carrying, item = before_state.pos, before_state.carrying, before_state.item
    live = ~ended  # where an episode ended, the carried state is the next episode's start, not the point reached
    assert live.sum() > 50
    # Per step: the shaped reward minus the contract's is shaping_coef * (the potential's change minus Manhattan's).
    target = np.where(carrying[:, None], np.asarray(params.goal)[None], item)
    index = np.where(carrying, shaped_params.fields.shape[0] - 1,
                     np.argmin(np.abs(np.asarray(params.items)[None] - item[:, None]).sum(-1), axis=1))
    read = jax.jit(jax.vmap(lambda k, p: geodesic.read_field(shaped_params.fields[k], p)))  # eagerly: op by op
    around = np.asarray(read(index, before)) - np.asarray(read(index, after))
    manhattan = np.abs(before - target).sum(-1) - np.abs(after - target).sum(-1)
    expected = np.asarray(theirs[2]) + float(params.shaping_coef) * (around - manhattan)
    np.testing.assert_allclose(reward[live], expected[live], atol=1e-4)
    assert np.abs(around - manhattan)[live].max() > 0.01  # the two distances really differ on this rollout


def test_geodesic_shaping_is_refused_where_it_is_not_built():
    with pytest.raises(ValueError, match="shaping must be one of"):
        make_continuous(". . .\nS 0 G\n. . .", max_steps=20, shaping="bfs")


def test_observe_target_appends_the_target_in_the_robots_frame():
    """The contract's values unchanged, then forward/left/distance over the map's side and the bearing."""
    plain, params = make_named("8x8")
    seen, seen_params = make_named("8x8", observe_target=True)
    assert seen.obs_size == plain.obs_size + 5 and seen.observation_space().shape == (seen.obs_size,)
    turn = jnp.array([0.0, 1.0])  # turn on the spot: the target's bearing rotates with the robot

    @jax.jit  # both resets and the steps in one program (eagerly they compile op by op)
    def run(key):
        (obs, state), (obs0, _) = seen.reset(key, seen_params), plain.reset(key, params)

        def one(state, t):
            obs, state, *_ = seen.step(jax.random.key(t), state, turn, seen_params)
            return state, (obs, state)

        return obs, obs0, jax.lax.scan(one, state, jnp.arange(3))[1]

    obs, obs0, (observations, states) = jax.device_get(run(jax.random.key(0)))
    np.testing.assert_array_equal(obs[: plain.obs_size], obs0)
    for t in range(3):
        obs, state = observations[t], jax.tree.map(lambda x, t=t: x[t], states)
        target = np.asarray(state.item)  # not carrying: the item
        offset = target - np.asarray(state.pos)
        theta = float(state.theta)
        forward = offset[0] * np.cos(theta) + offset[1] * np.sin(theta)
        left = -offset[0] * np.sin(theta) + offset[1] * np.cos(theta)
        distance = np.hypot(*offset)
        expected = [forward / 8, left / 8, distance / 8, forward / distance, left / distance]
        np.testing.assert_allclose(np.asarray(obs[plain.obs_size:]), expected, atol=1e-5)
    with pytest.raises(ValueError, match="observe_target must be True or False"):
        make_named("8x8", observe_target="yes")


def test_observe_route_points_down_the_field_in_the_robots_frame(study_12x12):
    """The contract's values unchanged, then the way's direction (forward, left) and its length over the side."""
    (plain, params), _ = study_12x12
    routed, routed_params = make_named("12x12", shaping="geodesic", observe_route=True)
    assert routed.obs_size == plain.obs_size + geodesic.ROUTE_FEATURES
    high = np.asarray(routed.observation_space().high)
    assert routed.observation_space().shape == high.shape == (routed.obs_size,) and high[-1] == geodesic.ROUTE_LENGTH_CAP
    # With the target too (SAC's and TD3's training view): the target's 5 values first, then the route's 3.
    both, both_params = make_named("12x12", shaping="geodesic", observe_target=True, observe_route=True)
    target, target_params = make_named("12x12", observe_target=True)
    turn = jnp.array([0.3, 1.0])

    @jax.jit  # every reset of the test and the steps in one program (eagerly they compile op by op)
    def run(key):
        obs, state = routed.reset(key, routed_params)

        def one(state, t):
            obs, state, *_ = routed.step(jax.random.key(t), state, turn, routed_params)
            return state, (obs, state)

        others = [env.reset(key, p)[0] for env, p in ((plain, params), (both, both_params), (target, target_params))]
        return obs, others, jax.lax.scan(one, state, jnp.arange(4))[1]

    obs, (obs0, obs_both, obs_target), (observations, states) = jax.device_get(run(jax.random.key(0)))
    np.testing.assert_array_equal(obs[: plain.obs_size], obs0)
    np.testing.assert_array_equal(obs_both, np.concatenate([obs_target, obs[plain.obs_size:]]))
    read, fields = jax.jit(geodesic.read_field), np.asarray(routed_params.fields)  # eagerly: op by op compiles
    for t in range(4):
        obs, state = observations[t], jax.tree.map(lambda x, t=t: x[t], states)
        forward, left, length = np.asarray(obs[plain.obs_size:])
        assert np.all(np.abs(np.asarray(obs)) <= high)
        assert abs(np.hypot(forward, left) - 1) < 1e-5
        field = fields[int(np.argmin(np.abs(np.asarray(params.items) - np.asarray(state.item)).sum(-1)))]
        theta = float(state.theta)
        way = np.array([forward * np.cos(theta) - left * np.sin(theta), forward * np.sin(theta) + left * np.cos(theta)])
        here = float(read(field, state.pos))
        np.testing.assert_allclose(length, here / 12, rtol=1e-5)
        # 0.1 m along the way the field falls by nearly 0.1 m (the way is the steepest descent), and it rises the other way.
        assert here - float(read(field, state.pos + 0.1 * way)) > 0.09
        assert float(read(field, state.pos - 0.1 * way)) > here
    with pytest.raises(ValueError, match="observe_route reads the geodesic shaping's distance fields"):
        make_named("12x12", observe_route=True)
    from wrl_jax.envs.continuous.procedural import make_continuous_procedural
    with pytest.raises(ValueError, match="observe_route reads the geodesic shaping's distance fields"):
        make_continuous_procedural(observe_route=True)
    with pytest.raises(ValueError, match="observe_route must be True or False"):
        make_named("12x12", shaping="geodesic", observe_route=1)


def test_a_controller_that_steers_along_the_route_delivers_every_item_of_12x12(study_12x12, monkeypatch):
    """The route's three values are enough to drive: turn towards the way, go when facing it (the rule of
    bench/investigations/continuous_route_rule.py, which docs/continuous.md cites). What the learner still has
    to do is find this, keep off corners, and time it."""
    from wrl_jax.envs.continuous import evaluation

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[3] / "bench" / "investigations"))
    from continuous_route_rule import follow_route

    routed, routed_params = make_named("12x12", shaping="geodesic", observe_route=True)
    follow = follow_route(routed.obs_size - geodesic.ROUTE_FEATURES)
    result = fast_compile.jit(lambda p: evaluation.evaluate_episodes(follow, routed, p))(routed_params)
    valid = np.asarray(result.valid)
    assert np.asarray(result.delivered)[valid].all()
    assert np.asarray(result.collisions)[valid].sum() == 0
