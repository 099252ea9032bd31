"""PPO's ``encoder="propagation"`` (wrl_jax/agents/propagation.py): the learned distance field over the
observed map, its hand-written gradient, how PPO wires it, its refusals, and that it learns.

The propagation must be a shortest path when its costs say so (checked against a BFS written here over
generated layouts), its custom backward pass must be the gradient (checked by finite differences), and
training must make shelves dear by itself (the costs start equal everywhere).

Compiled programs are shared: the module's environment (``map_env``, a 64-layout pool) is also the one
PPO trains on, its observations are 48 rows of its reset table (``map_obs``: the tests take slices), every
check runs its JAX work in one jitted call (``_gradients`` serves the three seeds of the gradient check and
the converged one), and the learning test trains and evaluates in one program; no test runs eager ``jnp``
operations op by op.
"""

from __future__ import annotations

import collections
import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import commands_level

from wrl_jax.agents.base import make_train
from wrl_jax.agents import ppo, ppo_config, propagation
from wrl_jax.core.registry import make


def numpy_bfs(blocked: np.ndarray, source: tuple[int, int]) -> np.ndarray:
    """Moves from every free cell to ``source`` (-1: unreachable), 4-connected."""
    height, width = blocked.shape
    distance = np.full((height, width), -1)
    distance[source] = 0
    queue = collections.deque([source])
    while queue:
        row, col = queue.popleft()
        for d_row, d_col in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            r, c = row + d_row, col + d_col
            if 0 <= r < height and 0 <= c < width and not blocked[r, c] and distance[r, c] < 0:
                distance[r, c] = distance[row, col] + 1
                queue.append((r, c))
    return distance


@pytest.fixture(scope="module")
def map_env():
    env, params = make("Procedural-Warehouse-v0", pool_size=64, seed=5, observe_map=True)
    return env, params


@pytest.fixture(scope="module")
def map_obs(map_env):
    """``(obs, grids)``: 48 first observations of ``map_env`` and their map channels ``(48, 3, H, W)``: item 0 of
    the pool's first 48 layouts, read from the params' reset table (what ``reset`` returns; no program)."""
    env, params = map_env
    count = 48
    obs = np.asarray(params.reset_obs)[:count, 0]
    offset, height, width = env.map_observation()
    return obs, np.asarray(obs[:, offset:]).reshape(count, 3, height, width)


_propagate = jax.jit(propagation.propagate, static_argnums=2)


def test_with_dear_shelves_the_values_are_minus_the_bfs_distance(map_obs):
    _, grids = map_obs
    scale = propagation.COST_PARAMETER_SCALE  # logit = scale x (kernel * blocked + bias): floor 1, shelves ~60
    dear_shelves = {"kernel": jnp.zeros((3, 3)).at[1, 1].set(60.0 / scale),
                    "bias": jnp.asarray(np.log(np.e - 1.0) / scale)}
    values = np.asarray(jax.jit(lambda costs, blocked, target: propagation.propagate(
        propagation.cost_map(costs, blocked), target, 64))(dear_shelves, grids[:, 0], grids[:, 2]))
    checked = 0
    for blocked, target, value in zip(grids[:, 0] > 0.5, grids[:, 2], values):
        distance = numpy_bfs(blocked, tuple(int(v) for v in np.argwhere(target > 0.5)[0]))
        reached = distance >= 0
        np.testing.assert_allclose(-value[reached], distance[reached], atol=1e-3)
        assert (value[~blocked & ~reached] == -propagation.BIG).all()
        checked += int(reached.sum())
    assert checked > 48 * 30


def test_rounds_bound_the_path_length(map_obs):
    grids = map_obs[1][:16]
    cost = np.ones(grids.shape[:1] + grids.shape[2:], np.float32)  # unit cost everywhere: Manhattan distance
    values = np.asarray(_propagate(cost, grids[:, 2], 5))
    rows, cols = np.indices(grids.shape[2:])
    for target, value in zip(grids[:, 2], values):
        t_row, t_col = np.argwhere(target > 0.5)[0]
        manhattan = np.abs(rows - t_row) + np.abs(cols - t_col)
        np.testing.assert_array_equal(value[manhattan <= 5], -manhattan[manhattan <= 5])
        assert (value[manhattan > 5] == -propagation.BIG).all()


def plain_propagation(cost: jax.Array, target: jax.Array, rounds: int) -> jax.Array:
    """The same rounds written naively (pad and slice), differentiated by JAX's autodiff through the loop
    (a ``fori_loop`` of a static length: a scan, which reverse-mode autodiff unrolls no differently)."""
    def one_round(_, values):
        padded = jnp.pad(values, ((0, 0), (1, 1), (1, 1)), constant_values=-propagation.BIG)
        best = jnp.maximum(jnp.maximum(padded[:, :-2, 1:-1], padded[:, 2:, 1:-1]),
                           jnp.maximum(padded[:, 1:-1, :-2], padded[:, 1:-1, 2:]))
        return jnp.maximum(values, best - cost)

    return jax.lax.fori_loop(0, rounds, one_round, jnp.where(target > 0.5, 0.0, -propagation.BIG))


@partial(jax.jit, static_argnums=(3, 4))
def _gradients(cost, target, weights, rounds: int, plain_rounds: int):
    """``(ours, plain)`` gradients of ``sum(values * weights)`` in ``cost``, then ``(ours, plain)`` values."""
    ours = jax.grad(lambda c: (propagation.propagate(c, target, rounds) * weights).sum())(cost)
    plain = jax.grad(lambda c: (plain_propagation(c, target, plain_rounds) * weights).sum())(cost)
    return ours, plain, propagation.propagate(cost, target, rounds), plain_propagation(cost, target, plain_rounds)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_custom_gradient_is_autodiff_of_the_plain_loop(seed):
    rng = np.random.default_rng(seed)
    count, size = 6, 7
    blocked = rng.random((count, size, size)) < 0.25
    target = np.zeros((count, size, size), np.float32)
    target[np.arange(count), rng.integers(0, size, count), rng.integers(0, size, count)] = 1.0
    # generic costs (paths tie with probability ~0), shelves dear
    cost = np.asarray(rng.uniform(0.5, 2.0, (count, size, size)) + 5.0 * blocked, np.float32)
    weights = np.asarray(rng.normal(size=(count, size, size)), np.float32)
    rounds = 12  # fewer than some paths need: cells left at -BIG must get no gradient either way

    ours, plain, values, plain_values = _gradients(cost, target, weights, rounds, rounds)  # one program, 3 seeds
    np.testing.assert_allclose(np.asarray(ours), np.asarray(plain), atol=1e-4)
    np.testing.assert_array_equal(values, plain_values)
    assert np.abs(np.asarray(ours)).sum() > 1.0  # the gradient is not trivially zero


def serpentine(size: int = 15) -> np.ndarray:
    """A ``size x size`` floor of full-width walls on every other row, each open at alternate ends: one snake."""
    blocked = np.zeros((size, size), bool)
    for wall, row in enumerate(range(1, size - 1, 2)):
        blocked[row, :] = True
        blocked[row, size - 1 if wall % 2 == 0 else 0] = False
    return blocked


def test_converged_values_reach_routes_of_any_length():
    """A snake whose far end is about 110 moves from the target: within 48 rounds (the old default) the
    cells farther than 48 moves see only paths through the walls, the converged propagation gives every
    free cell minus its BFS distance."""
    blocked = serpentine()
    target = np.zeros(blocked.shape, np.float32)
    target[0, 0] = 1.0
    distance = numpy_bfs(blocked, (0, 0))
    assert distance.max() > 100
    cost = np.where(blocked, 60.0, 1.0).astype(np.float32)[None]
    # the gradient of the converged values: autodiff of a plain loop run long enough to converge too
    weights = np.random.default_rng(0).normal(size=(1, *blocked.shape)).astype(np.float32)
    ours, plain, converged, _ = _gradients(cost, target[None], weights, 0, blocked.size)
    converged = np.asarray(converged)[0]
    np.testing.assert_allclose(-converged[~blocked], distance[~blocked], atol=1e-3)
    short = np.asarray(_propagate(cost, target[None], 48))[0]
    # the network's own costs at initialization: 1 on floor cells, walls on shelves (or, walls=False, 1 there too)
    init, grid = propagation.init_propagation(), blocked.astype(np.float32)
    with_walls, without = jax.jit(lambda init, grid: (propagation.cost_map(init, grid),
                                                      propagation.cost_map(init, grid, walls=False)))(init, grid)
    np.testing.assert_allclose(with_walls, np.where(blocked, propagation.BIG, 1.0), rtol=1e-6)
    np.testing.assert_allclose(without, 1.0, rtol=1e-6)
    far = ~blocked & (distance > 48)
    assert far.sum() > 40 and (short[far] < -distance[far] - 10).all()  # through a wall (cost 60)
    np.testing.assert_allclose(np.asarray(ours), np.asarray(plain), rtol=1e-5, atol=1e-3)


def test_runs_and_cache_propagate_each_leg_once_with_the_same_result(map_env, map_obs):
    """The update's one propagation per run of rows with the same map and target, and the rollout's cache
    (only the rows whose leg changed), give exactly the features of propagating every row, and the same
    gradient (up to the order of float sums)."""
    env, _ = map_env
    layout = env.map_observation()
    obs = map_obs[0][:12]
    costs = {**propagation.init_propagation(), "kernel": jnp.zeros((3, 3)).at[1, 1].set(0.7)}

    @jax.jit
    def check(costs, obs):  # every computation below in one program
        rows = jnp.repeat(obs, jnp.asarray([1, 3, 5, 1, 2, 7, 1, 1, 4, 2, 3, 2]), axis=0, total_repeat_length=32)
        by_run = propagation.map_features_by_run(costs, rows, layout, chunk=4)
        by_row = propagation.map_features(costs, rows, layout)
        grads = [jax.grad(lambda p, f=f: jnp.square(f(p, rows, layout)).sum())(costs)
                 for f in (propagation.map_features_by_run, propagation.map_features)]
        # the cache: first everything is stale; then a batch where only some rows moved to a new leg
        first, cache = propagation.map_features_cached(costs, obs, layout, propagation.init_leg_cache(obs, layout))
        moved = obs.at[::3].set(obs[::-1][::3])  # rows 0, 3, 6, 9 get another row's map and target
        again, (key, _) = propagation.map_features_cached(costs, moved, layout, cache, chunk=3)
        plain = (propagation.map_features(costs, obs, layout), propagation.map_features(costs, moved, layout))
        return (by_run, by_row), grads, (first, again), plain, (key, propagation.leg_key(moved, layout))

    (by_run, by_row), (grad_runs, grad_rows), cached, plain, (key, moved_key) = check(costs, obs)
    np.testing.assert_array_equal(by_run, by_row)
    for name in ("kernel", "bias"):
        np.testing.assert_allclose(grad_runs[name], grad_rows[name], rtol=1e-4)
        assert np.abs(np.asarray(grad_rows[name])).max() > 1.0
    for features, expected in zip(cached, plain):
        np.testing.assert_array_equal(features, expected)
    np.testing.assert_array_equal(key, moved_key)


def test_robot_features_rank_the_moves():
    values = np.asarray([[-4.0, -3.0, -2.0], [-5.0, -4.0, -1.0], [-6.0, -5.0, 0.0]], np.float32)  # target (2, 2)
    robots = np.zeros((2, 3, 3), np.float32)
    robots[0, 1, 1] = 1.0  # in the middle
    robots[1, 0, 0] = 1.0  # in a corner: off the map reads -BIG, clipped at -CLIP
    features, at_corner = np.asarray(jax.jit(jax.vmap(propagation.robot_features, in_axes=(None, 0)))(values, robots))
    # up -3, down -5, left -5, right -1: right is best, the others relative to it; own value -4 / 64
    np.testing.assert_allclose(features, [-2.0, -4.0, -4.0, 0.0, -4.0 / propagation.VALUE_SCALE])
    np.testing.assert_allclose(at_corner[:4], [-propagation.CLIP, -2.0, -propagation.CLIP, 0.0])  # down -5, right -3


def test_ppo_wires_one_propagation_for_actor_and_critic(map_env, map_obs):
    env, params = map_env
    config = dataclasses.replace(ppo_config.PROCEDURAL, encoder="propagation", propagation_rounds=8)
    algo = ppo.PPO(config, env, params)
    obs = map_obs[0][:8]

    @jax.jit
    def probe(key, obs):  # one program for the networks and their passes
        networks = algo.unflatten(algo.flatten(algo._init_networks(key)))
        inputs = algo.network_inputs(networks["actor"], obs)
        return networks, inputs, algo.forward(networks["critic"], obs, inputs=inputs), algo.forward(
            networks["actor"], obs)

    networks, inputs, value, logits = probe(jax.random.key(0), obs)
    assert set(networks["actor"]["propagation"]) == {"kernel", "bias", "prior"}
    assert "propagation" not in networks["critic"]
    offset = env.map_observation()[0]
    assert algo.num_features == offset + propagation.NUM_FEATURES
    assert inputs.shape == (8, algo.num_features)
    np.testing.assert_array_equal(inputs[:, :offset], obs[:, :offset])
    with pytest.raises(ValueError, match="critic reads the actor's propagation"):
        jax.eval_shape(algo.forward, networks["critic"], obs)  # refused while tracing: nothing compiles
    assert value.shape == (8, 1)
    # the actor's logits are its MLP plus prior x the action features (the output layer starts near zero)
    assert np.abs(np.asarray(logits - inputs[:, offset : offset + 4])).max() < 0.1
    longer = ppo.PPO(dataclasses.replace(config, propagation_rounds=16), env, params)
    assert longer.flops_per_update() > algo.flops_per_update()  # the rounds are counted


@pytest.mark.parametrize(
    "change, message",
    [
        ({"encoder": "vin"}, "encoder must be one of"),
        ({"encoder": "propagation", "obs_encoding": "onehot"}, "needs obs_encoding='raw'"),
        ({"encoder": "propagation", "propagation_rounds": -1}, "propagation_rounds"),
    ],
)
def test_bad_encoder_settings_are_refused(change, message):
    with pytest.raises(ValueError, match=message):
        dataclasses.replace(ppo_config.PROCEDURAL, **change).validate()


def test_propagation_needs_a_map_in_the_observation():
    env, params = make("Procedural-Warehouse-v0", pool_size=64)  # map_env's pool size: its pool program
    assert env.map_observation() is None
    with pytest.raises(ValueError, match="observe-map True"):
        ppo.PPO(dataclasses.replace(ppo_config.PROCEDURAL, encoder="propagation"), env, params)


def test_training_sharpens_the_planning_policy_on_held_out_layouts(map_env):
    """25 updates of 1,024 steps on the module's 64-layout pool. Shelves are walls to the propagation, so the
    untrained network's greedy policy already walks shortest routes; its sampled policy does not (the prior's
    logits leave about a fifth of the probability to worse moves). Training must make the sampled policy take
    the best move (optimal episodes), keep the greedy one there, and teach the critic."""
    from wrl_jax.envs.procedural.evaluation import run_episodes
    from wrl_jax.envs.procedural.layout_sets import EVAL_SEED
    from wrl_jax.envs.procedural.pool import generate_pool
    from wrl_jax.envs.procedural.reports import episode_stats

    env, params = map_env
    # 25 updates (measured: greedy 0.987, sampled 0.958 from 0.055, explained variance 0.72 over the last 10).
    config = dataclasses.replace(ppo_config.PROCEDURAL, num_envs=32, total_timesteps=25 * 1024, hidden_sizes=(64, 64))
    algo = ppo.PPO(config, env, params)
    train = make_train(algo)
    # 64 held-out layouts, every real item of each: the episodes evaluate_sets runs for one set.
    heldout = generate_pool(jax.random.key(EVAL_SEED), 64, env.generator, stream="heldout")
    real = np.arange(heldout.layouts.max_items)[None, :] < np.asarray(heldout.layouts.num_items)[:, None]
    slots, items = (jnp.asarray(index, jnp.int32) for index in np.nonzero(real))

    @commands_level.jit  # a long run measured at level 1, which runs it faster (tests/commands_level.py)
    def train_and_evaluate(key, pool):
        """Training, then the trained and the untrained network (two "seeds") greedy and sampled on ``pool``:
        one program (run_episodes as evaluate_sets runs it, without a program per policy kind)."""
        runner, metrics = train(key)
        network = jax.tree.map(lambda *x: jnp.stack(x), algo.network_params(runner),
                               algo.network_params(algo.init(key)))
        eval_params = env.with_pool(params, pool)

        def episodes(net, sample_action=None, sample_key=None):
            return run_episodes(algo.greedy_action, net, env, eval_params, slots, items, sample_action, sample_key,
                                algo.policy_memory())

        return metrics, jax.vmap(episodes)(network), jax.vmap(
            lambda net: episodes(net, algo.sample_action, jax.random.key(1)))(network)

    metrics, *outcomes = train_and_evaluate(jax.random.key(0), heldout)
    (greedy, greedy_0), (sampled, sampled_0) = ([episode_stats(*(np.asarray(x)[seed] for x in outcome))["optimal_rate"]
                                                 for seed in (0, 1)] for outcome in outcomes)
    print(f"at the optimum, greedy: {greedy:.3f} (untrained {greedy_0:.3f}); sampled {sampled:.3f} ({sampled_0:.3f})")
    assert greedy_0 > 0.95 and greedy > 0.95, (greedy_0, greedy)
    assert sampled > sampled_0 + 0.3, (sampled, sampled_0)
    assert float(np.asarray(metrics["explained_variance"])[-10:].mean()) > 0.5
