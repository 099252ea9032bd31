"""Procedural warehouses (issue 13): generators, solvability, pools, MovingAI loader, environment.

Compiled programs are shared through module fixtures (one 5,000-layout pool
of the default mixture serves the generator, pool and environment tests;
``window_runs`` computes every radius of the window and ray tests in one
program), and every small pool of the default generator has ``HELDOUT`` (64)
slots, the periodic evaluation's count, so their generator compiles once.
"""

from __future__ import annotations

from functools import partial
from types import SimpleNamespace

import fast_compile
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wrl_jax.envs.warehouse import maps
from wrl_jax.core.observation import robot_observations
from wrl_jax.core.registry import make
from wrl_jax.envs.procedural import generators as gen
from wrl_jax.envs.procedural.draws import cell_words
from wrl_jax.envs.procedural.env import ProceduralWarehouse
from wrl_jax.envs.procedural.layout import (
    PaddedLayout,
    from_arrays,
    from_layout,
    is_solvable,
    to_numpy_layout,
)
from wrl_jax.envs.procedural.movingai import load_map, movingai_layout, parse_movingai
from wrl_jax.envs.procedural.pool import (
    bytes_per_layout,
    disjoint_from,
    generate_pool,
    pool_from_layouts,
    pool_from_keys,
    pool_hashes,
    refresh_pool,
    stream_keys,
)
from wrl_jax.envs.procedural.registration import make_from_layouts, make_procedural
from wrl_jax.envs.warehouse.layout import bfs_distances, optimal_route_lengths, parse

NUM_LAYOUTS = 5000
CONFIG = gen.GeneratorConfig()
HELDOUT = 64
"""Slots of every small pool of the default generator here: the periodic evaluation's held-out layouts
(``EVAL_LAYOUTS``), the final report's held-out set, the shaping and window tests' pools; one pool program
for them all."""
LONG_ROUTES = ("serpentine", "spiral", "comb")


def _slot(batch, index):
    return jax.tree.map(lambda leaf: leaf[index], batch)


def _square(blocked: np.ndarray) -> np.ndarray:
    side = max(blocked.shape)
    square = np.ones((side, side), dtype=bool)
    square[: blocked.shape[0], : blocked.shape[1]] = blocked
    return square


@pytest.fixture(scope="module")
def pool():
    return generate_pool(jax.random.key(0), NUM_LAYOUTS, CONFIG)


@pytest.fixture(scope="module")
def numpy_pool(pool):
    return jax.tree.map(np.asarray, pool)


# ---------------------------------------------------------------- generators
def test_generation_is_deterministic_and_keys_differ(pool, env_and_params):
    """Same key, same bits: the module's pool against the one ``make_procedural`` generated on its own from the same
    seed (the environment fixture's: a 5,000-layout generation less than generating it a third time here)."""
    again = env_and_params[1].pool
    for a, b in zip(jax.tree.leaves(pool), jax.tree.leaves(again), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    other = generate_pool(jax.random.key(1), NUM_LAYOUTS, CONFIG)
    assert not np.isin(pool_hashes(other), pool_hashes(pool)).all()
    assert np.mean(np.isin(pool_hashes(other), pool_hashes(pool))) < 0.01


def _numpy_reachable(blocked: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Cells reachable from each start, ``(N, H, W)`` bool: a plain NumPy flood fill over a batch."""
    free = ~blocked
    reached = np.zeros_like(free)
    reached[np.arange(len(starts)), starts[:, 0], starts[:, 1]] = True
    while True:
        grown = reached.copy()
        grown[:, 1:] |= reached[:, :-1]
        grown[:, :-1] |= reached[:, 1:]
        grown[:, :, 1:] |= reached[:, :, :-1]
        grown[:, :, :-1] |= reached[:, :, 1:]
        grown &= free
        if (grown == reached).all():
            return reached
        reached = grown


def test_every_layout_is_solvable_by_numpy(numpy_pool):
    layouts, optimal = numpy_pool.layouts, numpy_pool.optimal
    reached = _numpy_reachable(layouts.blocked, layouts.start)
    rows = np.arange(NUM_LAYOUTS)
    assert reached[rows, layouts.goal[:, 0], layouts.goal[:, 1]].all()
    real = np.arange(CONFIG.max_items)[None, :] < layouts.num_items[:, None]
    items_reached = reached[rows[:, None], layouts.items[..., 0], layouts.items[..., 1]]
    assert items_reached[real].all()
    # Pockets are filled: every free cell is reachable from the start.
    assert (reached == ~layouts.blocked).all()
    for index in range(400):  # wrl_jax.envs.warehouse.layout's BFS: reachability and the JAX BFS optimum
        blocked = _square(layouts.blocked[index])
        start, goal = tuple(layouts.start[index]), tuple(layouts.goal[index])
        items = layouts.items[index][: layouts.num_items[index]]
        from_start, from_goal = bfs_distances(blocked, start), bfs_distances(blocked, goal)
        assert from_start[goal] > 0 and (from_start[items[:, 0], items[:, 1]] > 0).all()
        expected = from_start[items[:, 0], items[:, 1]] + from_goal[items[:, 0], items[:, 1]]
        np.testing.assert_array_equal(optimal[index][: len(items)], expected)


def test_jax_solvability_check_agrees(numpy_pool):
    first = _slot(numpy_pool.layouts, 0)  # NumPy: no eager JAX operation (each would compile a program)
    goal = first.goal
    walled = first.blocked.copy()
    for d_row, d_col in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        row, col = goal[0] + d_row, goal[1] + d_col
        if 0 <= row < 16 and 0 <= col < 16:
            walled[row, col] = True
    batch = jax.tree.map(lambda *leaves: np.stack(leaves), first, first.replace(blocked=walled))
    assert jax.jit(jax.vmap(is_solvable))(batch).tolist() == [True, False]


def test_layouts_respect_the_config(numpy_pool):
    layouts = numpy_pool.layouts
    assert layouts.blocked.shape == (NUM_LAYOUTS, 16, 16)
    for lo, hi, values in ((8, 16, layouts.height), (8, 16, layouts.width), (1, 8, layouts.num_items)):
        assert values.min() == lo and values.max() == hi
    rows, cols = np.arange(16)[None, :, None], np.arange(16)[None, None, :]
    off_grid = (rows >= layouts.height[:, None, None]) | (cols >= layouts.width[:, None, None])
    assert layouts.blocked[off_grid].all()
    for index in range(0, NUM_LAYOUTS, 7):
        count = layouts.num_items[index]
        cells = [tuple(layouts.start[index]), tuple(layouts.goal[index])]
        cells += [tuple(cell) for cell in layouts.items[index][:count]]
        assert len(set(cells)) == count + 2, f"layout {index}: marked cells collide"
        assert (layouts.items[index][count:] == layouts.items[index][0]).all()


def test_distinct_layouts_and_both_families(numpy_pool, pool):
    hashes = pool_hashes(pool)
    assert len(np.unique(hashes)) >= 0.99 * NUM_LAYOUTS
    # The mixture holds both families: shelf floors are mostly shelf blocks (a shelf with a shelf beside
    # it), random floors at these densities mostly isolated or short runs. Both kinds must be common.
    shelves = numpy_pool.layouts.blocked[:, 1:-1, 1:-1] & ~(
        (np.arange(1, 15)[None, :, None] >= numpy_pool.layouts.height[:, None, None] - 1)
        | (np.arange(1, 15)[None, None, :] >= numpy_pool.layouts.width[:, None, None] - 1))
    assert shelves.any(axis=(1, 2)).mean() > 0.9


def test_shelf_floors_are_periodic_blocks_and_obstacle_floors_follow_density():
    no_gaps = gen.GeneratorConfig(gap_rate=(0.0, 0.0))
    dense = gen.GeneratorConfig(density=(0.3, 0.3))

    @jax.jit
    def floors(key):
        headers = jax.random.bits(key, (256, 16), jnp.uint32)
        words = jax.vmap(lambda h: cell_words(h, CONFIG.max_shape)[0])(headers)
        shelf = jax.vmap(lambda h, w: gen.shelf_floor(h, w, no_gaps))(headers, words)
        obstacle = jax.vmap(lambda h, w: gen.obstacle_floor(h, w, dense))(headers, words)
        on_floor = jax.vmap(lambda h, w: gen.in_bounds_mask(h, w, (16, 16)))(*obstacle[1:])
        return shelf, obstacle[0], on_floor

    (shelves, heights, widths), obstacles, on_floor = jax.tree.map(np.asarray, floors(jax.random.key(3)))
    for index in range(len(shelves)):
        floor = shelves[index][: heights[index], : widths[index]]
        # Without gaps every shelf cell belongs to a block at least 2 long: it has a shelf neighbour.
        padded = np.pad(floor, 1)
        neighbour = padded[:-2, 1:-1] | padded[2:, 1:-1] | padded[1:-1, :-2] | padded[1:-1, 2:]
        assert (neighbour[floor]).all()
        # Aisles: some full row or full column of the floor is free.
        assert (~floor).all(axis=1).any() or (~floor).all(axis=0).any()
    assert abs(obstacles[on_floor].mean() - 0.3) < 0.02


def test_bad_generator_config_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown generator family"):
        gen.GeneratorConfig(family="maze")
    with pytest.raises(ValueError, match="no room"):
        gen.GeneratorConfig(min_shape=(2, 2), max_items=8)
    with pytest.raises(ValueError, match="density"):
        gen.GeneratorConfig(density=(0.5, 0.2))
    with pytest.raises(ValueError, match="aisle"):
        gen.GeneratorConfig(aisle=(0, 2))


# ---------------------------------------------------------------- hashing, held-out, pools
def test_layout_hash_sees_every_field_but_not_the_padding(numpy_pool):
    layout = _slot(numpy_pool.layouts, 0)  # the variants built in NumPy: no eager JAX operation
    count = int(layout.num_items)
    blocked, padding = layout.blocked.copy(), layout.items.copy()
    blocked[layout.start[0], layout.start[1]] = True
    padding[count:] = 5
    variants = [
        layout,
        layout.replace(start=layout.goal, goal=layout.start),
        layout.replace(items=layout.items[::-1]),
        layout.replace(num_items=np.int32(count - 1 if count > 1 else count + 1)),
        layout.replace(blocked=blocked),
        layout.replace(items=padding),  # padding only
    ]
    hashes = pool_hashes(jax.tree.map(lambda *leaves: np.stack(leaves), *variants))
    assert len(set(hashes[:5].tolist())) == 5 and hashes[5] == hashes[0]


def test_heldout_stream_is_disjoint_by_hash(pool):
    heldout = generate_pool(jax.random.key(0), NUM_LAYOUTS, CONFIG, stream="heldout")
    train_hashes = pool_hashes(pool)
    assert disjoint_from(heldout, train_hashes).all()
    # The check finds what it should: plant training layouts in the held-out set.
    planted = jax.tree.map(lambda h, t: h.at[:5].set(t[:5]), heldout.layouts, pool.layouts)
    mask = disjoint_from(planted, train_hashes)
    assert not mask[:5].any() and mask[5:].all()


def test_pool_memory_per_layout(pool):
    sizes = bytes_per_layout(pool)
    assert sizes["layout.blocked"] == 256 and sizes["layout.items"] == 8 * 2 * 4 and sizes["optimal"] == 32
    assert sizes["total"] == sum(value for name, value in sizes.items() if name != "total")


def test_study_maps_convert_with_their_bfs_optimum():
    layouts = [parse(maps.WAREHOUSE_8X8), parse(maps.WAREHOUSE_12X12)]
    padded = [from_layout(layout, (16, 16), 20) for layout in layouts]
    study_pool = pool_from_layouts(padded)
    for index, layout in enumerate(layouts):
        expected = optimal_route_lengths(layout)
        np.testing.assert_array_equal(np.asarray(study_pool.optimal[index][: layout.num_items]), expected)
        back = to_numpy_layout(padded[index])
        assert back.shelves[: layout.size, : layout.size].tolist() == layout.shelves.tolist()
    assert float(np.mean(optimal_route_lengths(layouts[0]))) == 14.0
    with pytest.raises(ValueError, match="larger than max_shape"):
        from_layout(layouts[1], (8, 8))


# ---------------------------------------------------------------- environment
@pytest.fixture(scope="module")
def env_and_params(pool):
    env, params = make_procedural(pool_size=NUM_LAYOUTS, max_steps=12)  # the fixture's pool, compiled once
    np.testing.assert_array_equal(np.asarray(params.pool.layouts.blocked), np.asarray(pool.layouts.blocked))
    return env, params


BATCH, HORIZON = 64, 40


@pytest.fixture(scope="module")
def programs(env_and_params):
    """``reset(params, key) -> state`` and ``rollout(params, state, key) -> (final, per-step outputs)``, jitted."""
    env, _ = env_and_params
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def reset(params, key):
        return jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key, BATCH), params)[1]

    def rollout(params, state, key):
        def one(state, key):
            key_action, key_step = jax.random.split(key)
            action = jax.random.randint(key_action, (BATCH,), 0, 4)
            obs, next_state, reward, terminated, truncated, info = step(jax.random.split(key_step, BATCH),
                                                                        state, action, params)
            return next_state, (state, obs, reward, terminated, truncated, info)

        return jax.lax.scan(one, state, jax.random.split(key, HORIZON))

    return jax.jit(reset), jax.jit(rollout)


def test_env_steps_a_batch_on_per_env_layouts_and_resets_from_the_pool(env_and_params, programs):
    env, params = env_and_params
    reset, rollout = programs
    assert env.name == "Procedural-Warehouse-v0" and env.num_actions == 4
    assert env.action_space(params).n == 4
    _, (states, obs, reward, terminated, truncated, info) = rollout(params, reset(params, jax.random.key(6)),
                                                                   jax.random.key(7))
    assert obs.shape == (HORIZON, BATCH, env.obs_size) and env.observation_space(params).contains(obs[0, 0])
    pool = jax.tree.map(np.asarray, params.pool)
    index = np.asarray(states.layout_index)
    assert len(np.unique(index[0])) > 50  # per-env layouts at the first reset
    # Every state's floor is its pool slot's, its optimum the slot's optimum for its item.
    np.testing.assert_array_equal(np.asarray(env.blocked(states)), pool.layouts.blocked[index])
    np.testing.assert_array_equal(np.asarray(states.optimal),
                                  pool.optimal[index, np.asarray(states.item_index)])
    # max_steps=12: every env truncates at least three times in 40 steps and draws new slots.
    done = np.asarray(terminated | truncated)
    assert (done.sum(axis=0) >= 3).all()
    assert (np.asarray(states.time)[1:][done[:-1]] == 0).all()
    starts = pool.layouts.start[index[1:][done[:-1]]]
    np.testing.assert_array_equal(np.asarray(states.pos)[1:][done[:-1]], starts)
    assert (index[1:] != index[:-1]).sum() > 0.9 * done[:-1].sum()
    # final_obs is the reached observation, obs the reset one, on done steps only.
    np.testing.assert_array_equal(np.asarray(info["final_obs"])[~done], np.asarray(obs)[~done])
    assert (np.asarray(info["final_obs"])[done] != np.asarray(obs)[done]).any(axis=-1).mean() > 0.9
    for flag in ("collision", "wall_bump", "picked_up", "delivered"):
        assert info[flag].dtype == jnp.bool_
    assert np.asarray(info["wall_bump"]).any() and np.asarray(info["collision"]).any()
    # Same key, same bits.
    again = rollout(params, reset(params, jax.random.key(6)), jax.random.key(7))[1][2]
    np.testing.assert_array_equal(np.asarray(again), np.asarray(reward))


def test_refresh_keeps_episodes_in_flight_and_new_resets_use_the_new_pool(env_and_params, programs):
    env, params = env_and_params
    reset, rollout = programs
    fresh = env.refresh_pool(jax.random.key(99), params)
    assert not np.isin(pool_hashes(fresh.pool), pool_hashes(params.pool)).any()
    state = reset(params, jax.random.key(1))
    _, (states, _, _, terminated, truncated, _) = rollout(fresh, state, jax.random.key(2))
    done = np.asarray(terminated | truncated)
    first_done = done.argmax(axis=0)
    blocked, index = np.asarray(env.blocked(states)), np.asarray(states.layout_index)
    old, new = np.asarray(params.pool.layouts.blocked), np.asarray(fresh.pool.layouts.blocked)
    for env_index in range(BATCH):
        until = first_done[env_index]
        # Until its first reset an episode runs on the floor it started with, from the old pool ...
        np.testing.assert_array_equal(blocked[: until + 1, env_index], old[index[: until + 1, env_index]])
        # ... and every later episode on a slot of the refreshed pool.
        np.testing.assert_array_equal(blocked[until + 1:, env_index], new[index[until + 1:, env_index]])
    with pytest.raises(ValueError, match="count"):
        refresh_pool(jax.random.key(5), params.pool, env.generator, count=0)


def test_dynamics_match_the_study_env_on_the_padded_12x12_map():
    """SPEC.md's rewards, flags and termination, bit for bit, with the 12x12 map padded to 16x16."""
    layout = parse(maps.WAREHOUSE_12X12)
    env, params = make_from_layouts([from_layout(layout, (16, 16), 20)], max_steps=300)
    study, study_params = make("Warehouse-12x12-v0")

    def ours(item, acts):
        def one(state, action):
            _, state, reward, terminated, truncated, info = env.transition(None, state, action, params)
            return state, (state.pos, reward, terminated, truncated, info["collision"], info["wall_bump"],
                           info["picked_up"], info["delivered"])
        return jax.lax.scan(one, env.reset_to(0, item, params)[1], acts)[1]

    def theirs(item, acts):
        def one(state, action):
            _, state, reward, terminated, truncated, info = study.transition(None, state, action, study_params)
            return state, (state.pos, reward, terminated, truncated, info["collision"], info["wall_bump"],
                           info["picked_up"], info["delivered"])
        return jax.lax.scan(one, study.reset_to_item(item, study_params)[1], acts)[1]

    @jax.jit
    def both(key):  # the random actions drawn in the program too (drawn eagerly, they compile programs of their own)
        items, actions = jnp.arange(20), jax.random.randint(key, (20, 300), 0, 4)
        return jax.vmap(ours)(items, actions), jax.vmap(theirs)(items, actions)

    a, b = both(jax.random.key(0))
    for x, y in zip(a, b):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert np.asarray(a[5]).any() and np.asarray(a[4]).any()  # wall bumps at the padded edge, collisions


def test_bfs_shaping_rewards_the_change_of_the_numpy_bfs_distance():
    """``shaping="bfs"``: SPEC.md's reward with ``d`` the shortest path (NumPy BFS), same dynamics, float32 bits."""
    # 64 slots: the pool size of the module's other small pools of the default generator (one pool program).
    env, params = make_procedural(seed=3, pool_size=HELDOUT, shaping="bfs")
    plain_env, plain_params = make_procedural(seed=3, pool_size=HELDOUT)
    slots, items = np.meshgrid(np.arange(6), np.arange(2), indexing="ij")  # 6 slots, 2 items each
    slots, items = slots.reshape(-1), items.reshape(-1)
    # Toward the target by Manhattan on 70 % of the steps (so items get picked up and delivered), else random.
    steps = 120

    def toward(state):
        delta = jnp.where(state.carrying, state.goal, state.item_pos) - state.pos
        return jnp.where(delta[0] != 0, jnp.where(delta[0] > 0, 1, 0), jnp.where(delta[1] > 0, 3, 2))

    def run(env, params, actions, greedy):
        def episode(slot, item, acts, coins):
            def one(state, step):
                action = jnp.where(step[1], toward(state), step[0])
                _, next_state, reward, _, _, info = env.transition(None, state, action, params)
                return next_state, (state.pos, next_state.pos, state.carrying, reward, info["collision"],
                                    info["picked_up"], info["delivered"])
            return jax.lax.scan(one, env.reset_to(slot, item, params)[1], (acts, coins))[1]
        return jax.vmap(episode)(jnp.asarray(slots), jnp.asarray(items), actions, greedy)

    @jax.jit
    def both(params, plain_params):  # both envs and the random draws in one program
        actions = jax.random.randint(jax.random.key(4), (slots.size, steps), 0, 4)
        greedy = jax.random.bernoulli(jax.random.key(5), 0.7, actions.shape)
        return run(env, params, actions, greedy), run(plain_env, plain_params, actions, greedy)

    shaped, plain = both(params, plain_params)
    pos, next_pos, carrying, reward, collision, picked_up, delivered = map(np.asarray, shaped)
    np.testing.assert_array_equal(next_pos, np.asarray(plain[1]))  # the dynamics do not change
    layouts = jax.tree.map(np.asarray, params.pool.layouts)
    differs = 0
    for e, (slot, item) in enumerate(zip(slots, items)):
        blocked = np.asarray(layouts.blocked[slot])
        to_item = bfs_distances(blocked, tuple(np.asarray(layouts.items[slot, item])))
        to_goal = bfs_distances(blocked, tuple(np.asarray(layouts.goal[slot])))
        for t in range(steps):
            table = to_goal if carrying[e, t] else to_item
            change = int(table[tuple(pos[e, t])]) - int(table[tuple(next_pos[e, t])])
            target = np.asarray(layouts.goal[slot] if carrying[e, t] else layouts.items[slot, item])
            manhattan = int(np.abs(pos[e, t] - target).sum() - np.abs(next_pos[e, t] - target).sum())
            differs += change != manhattan
            expected = np.float32(0.0) if delivered[e, t] else np.float32(-0.5)
            expected = expected + (np.float32(-10.0) if collision[e, t] else np.float32(0.0))
            expected = expected + np.float32(0.0)  # wall_penalty is 0: the term is added all the same, in order
            expected = expected + np.float32(2.0) * np.float32(change)
            expected = expected + (np.float32(50.0) if picked_up[e, t] else np.float32(0.0))
            expected = expected + (np.float32(200.0) if delivered[e, t] else np.float32(0.0))
            assert reward[e, t] == expected, (e, t)
    assert picked_up.any() and delivered.any() and carrying.any()
    assert differs > 0  # shelves made the two distances disagree on some steps, so the test tells them apart
    with pytest.raises(ValueError, match="shaping must be one of"):
        make_procedural(pool_size=HELDOUT, shaping="euclidean")
    with pytest.raises(ValueError, match="pool_refresh"):
        make_procedural(pool_size=HELDOUT, pool_refresh=2, shaping="bfs")
    assert params.distances.shape == (HELDOUT, 9, 16, 16) and plain_params.distances.shape == (HELDOUT, 0, 16, 16)


def test_observation_is_the_fleet_robot_observation_with_off_grid_padding():
    floor = np.zeros((3, 4), dtype=bool)
    floor[1, 1] = True
    layout = from_arrays(floor, (0, 3), (2, 0), [(2, 3)], max_shape=(6, 6), max_items=2)
    env, params = make_from_layouts([layout], view_radius=1, observe_map=True)

    @jax.jit
    def probe(params):
        obs, state = env.reset_to(0, 0, params)
        expected = robot_observations(env.blocked(state), state.pos[None], jnp.array([[2, 3]]), jnp.array([False]), 1, 6)
        _, bumped, _, _, _, info = env.transition(None, state, jnp.int32(3), params)  # right, into the padding
        return obs, expected[0], bumped.pos, info["wall_bump"], info["collision"]

    obs, expected, bumped_pos, wall_bump, collision = probe(params)
    np.testing.assert_array_equal(np.asarray(params.reset_obs[0, 0]), np.asarray(obs))  # the auto-reset's table
    np.testing.assert_array_equal(np.asarray(obs[: expected.shape[0]]), np.asarray(expected))
    np.testing.assert_array_equal(np.asarray(obs[:5]), np.array([0, 3, 2, 3, 0], np.float32) / 5)
    window = np.asarray(obs[5:14]).reshape(3, 3)  # channel 0 around (0, 3): off-grid above and to the right
    np.testing.assert_array_equal(window, [[1, 1, 1], [0, 0, 1], [0, 0, 1]])
    assert obs.shape == (5 + 27 + 3 * 36,)
    full = np.asarray(obs[32:]).reshape(3, 6, 6)
    assert full[1, 0, 3] == 1 and full[1].sum() == 1 and full[2, 2, 3] == 1 and full[0, 1, 1] == 1
    assert bool(wall_bump) and not bool(collision)
    np.testing.assert_array_equal(np.asarray(bumped_pos), [0, 3])


def _corner_layout():
    """A 3x4 floor in a 6x6 padding: start (0, 0), item (0, 1), goal (0, 2), a shelf at (1, 1)."""
    floor = np.zeros((3, 4), dtype=bool)
    floor[1, 1] = True
    return from_arrays(floor, (0, 0), (0, 2), [(0, 1)], max_shape=(6, 6), max_items=1)


def _walk_beside_the_plain_env(env, params, plain_env, plain_params, actions):
    """``(observations, plain observations, the reset table's row)`` of one walk from slot 0, item 0, in both envs."""

    @jax.jit
    def probe(params, plain_params, actions):
        obs, state = env.reset_to(0, 0, params)
        plain_obs, plain_state = plain_env.reset_to(0, 0, plain_params)

        def one(carry, action):  # a scan: one compiled step, whatever the walk's length
            state, plain_state = carry
            obs, state, *_ = env.step(jax.random.key(0), state, action, params)
            plain_obs, plain_state, *_ = plain_env.step(jax.random.key(0), plain_state, action, plain_params)
            return (state, plain_state), (obs, plain_obs)

        _, (seen, plain_seen) = jax.lax.scan(one, (state, plain_state), actions)
        return (jnp.concatenate([obs[None], seen]), jnp.concatenate([plain_obs[None], plain_seen]),
                params.reset_obs[0, 0])

    return tuple(np.asarray(x) for x in probe(params, plain_params, jnp.asarray(actions, jnp.int32)))


def test_last_action_observation_is_the_previous_action_one_hot():
    """``observe_last_action``: the plain observation, then the previous action one-hot (zeros after a reset);
    the auto-reset's reset table and a terminated episode's reset show the zeros too."""
    layout = _corner_layout()
    plain_env, plain_params = make_from_layouts([layout], view_radius=1)
    env, params = make_from_layouts([layout], view_radius=1, observe_last_action=True)
    assert env.obs_size == plain_env.obs_size + 4 and env.observation_space(params).shape == (env.obs_size,)
    assert env.static_config() != plain_env.static_config()

    # down into the floor, right onto the shelf (a collision), up, right onto the item
    seen, plain_seen, reset_row = _walk_beside_the_plain_env(env, params, plain_env, plain_params, (1, 3, 0, 3))
    np.testing.assert_array_equal(seen[:, :-4], plain_seen)  # the rest is the plain observation, bit for bit
    expected = np.zeros((5, 4), np.float32)
    expected[1, 1] = expected[2, 3] = expected[3, 0] = 1  # the last step picked up the item: still shown
    expected[4, 3] = 1
    np.testing.assert_array_equal(seen[:, -4:], expected)
    np.testing.assert_array_equal(reset_row[-4:], np.zeros(4, np.float32))
    np.testing.assert_array_equal(reset_row, seen[0])


def test_visited_channel_marks_the_trail_since_the_current_target_was_set():
    """``observe_visited``: a window channel of the cells stood on since the episode's start or the pickup."""
    layout = _corner_layout()
    plain_env, plain_params = make_from_layouts([layout], view_radius=1)
    env, params = make_from_layouts([layout], view_radius=1, observe_visited=True, observe_last_action=True)
    assert env.obs_size == plain_env.obs_size + 4 + 9

    # down, back up to the start, right onto the item (the pickup)
    seen, plain_seen, reset_row = _walk_beside_the_plain_env(env, params, plain_env, plain_params, (1, 0, 3))
    np.testing.assert_array_equal(seen[:, :plain_env.obs_size], plain_seen)
    visited = seen[:, -9:].reshape(4, 3, 3)
    expected = np.zeros((4, 3, 3), np.float32)
    expected[0, 1, 1] = 1  # the start
    expected[1, 0, 1] = expected[1, 1, 1] = 1  # at (1, 0): the start above, the robot's own cell
    expected[2, 1, 1] = expected[2, 2, 1] = 1  # back at (0, 0): its cell, and (1, 0) below
    expected[3, 1, 1] = 1  # picked up at (0, 1): a new trail, its first cell
    np.testing.assert_array_equal(visited, expected)
    np.testing.assert_array_equal(reset_row, seen[0])

    # A 7x7 window (V = 3, past the int32 masks) reads the same trail: its centre is the 3x3 above.
    wide_plain_env, wide_plain_params = make_from_layouts([layout], view_radius=3)
    wide_env, wide_params = make_from_layouts([layout], view_radius=3, observe_visited=True, observe_last_action=True)
    assert not wide_env.bit_windows and wide_env.row_windows
    seen, plain_seen, _ = _walk_beside_the_plain_env(wide_env, wide_params, wide_plain_env, wide_plain_params,
                                                     (1, 0, 3))
    np.testing.assert_array_equal(seen[:, :wide_plain_env.obs_size], plain_seen)
    wide_expected = np.zeros((4, 7, 7), np.float32)
    wide_expected[:, 2:5, 2:5] = expected
    np.testing.assert_array_equal(seen[:, -49:].reshape(4, 7, 7), wide_expected)
    with pytest.raises(ValueError, match="observe_visited needs the packed-row window"):
        make_from_layouts([layout], view_radius=14, observe_visited=True)  # 6 + 28 walled columns


def test_visit_levels_count_the_laps_of_a_loop():
    """``visit_levels = 3``: the trail channel counts visits (``min(count, 3) / 3``), so two laps of a
    two-cell loop look different; a pickup starts a new count; ``visit_levels = 1`` is the plain trail."""
    layout = _corner_layout()
    plain_env, plain_params = make_from_layouts([layout], view_radius=1)
    env, params = make_from_layouts([layout], view_radius=1, observe_visited=True, visit_levels=3)
    assert env.obs_size == plain_env.obs_size + 9 and env.static_config() != make_from_layouts(
        [layout], view_radius=1, observe_visited=True)[0].static_config()

    # down and up three times between (0, 0) and (1, 0), then right onto the item (the pickup)
    seen, plain_seen, reset_row = _walk_beside_the_plain_env(env, params, plain_env, plain_params,
                                                             (1, 0, 1, 0, 1, 0, 3))
    np.testing.assert_array_equal(seen[:, :plain_env.obs_size], plain_seen)
    counts = np.rint(seen[:, -9:].reshape(8, 3, 3) * 3).astype(int)
    # visits of the start A = (0, 0) and of B = (1, 0) after each step; the robot is on B after odd steps
    counts_a_b = [(1, 0), (1, 1), (2, 1), (2, 2), (3, 2), (3, 3), (3, 3)]
    for step, (count_a, count_b) in enumerate(counts_a_b):
        on_b = step % 2 == 1  # on B, A is above the centre; on A, B is below it
        centre, other = (count_b, count_a) if on_b else (count_a, count_b)
        assert counts[step, 1, 1] == centre and counts[step, 0 if on_b else 2, 1] == other, step
        assert counts[step].sum() == count_a + count_b, step
    np.testing.assert_array_equal(seen[:, -9:], counts.reshape(8, 9).astype(np.float32) * np.float32(1 / 3))
    expected_after_pickup = np.zeros((3, 3), int)
    expected_after_pickup[1, 1] = 1
    np.testing.assert_array_equal(counts[7], expected_after_pickup)
    np.testing.assert_array_equal(reset_row, seen[0])

    # One level is the plain trail, bit for bit.
    binary_env, binary_params = make_from_layouts([layout], view_radius=1, observe_visited=True, visit_levels=1)
    binary, _, _ = _walk_beside_the_plain_env(binary_env, binary_params, plain_env, plain_params,
                                              (1, 0, 1, 0, 1, 0, 3))
    np.testing.assert_array_equal(binary[:, -9:], (counts > 0).reshape(8, 9).astype(np.float32))
    with pytest.raises(ValueError, match="visit_levels=3 counts the visits of the trail channel"):
        make_from_layouts([layout], view_radius=1, visit_levels=3)
    with pytest.raises(ValueError, match="visit_levels must be in 1..255"):
        make_from_layouts([layout], view_radius=1, observe_visited=True, visit_levels=0)


WINDOW_POOL = {"pool_size": HELDOUT}
"""The window tests' pools: the default generator's 64 slots (the module's small-pool program), floors from
8x8 to 16x16 in a 16x16 padding."""
WINDOW_RADII = (0, 1, 2, 3, 4, 9)
RAY_RADII = (0, 2, 3)


def _window_probe(env, params, view_radius, key):
    """A random state of ``env`` anywhere on its real floor (shelves too), either target: its observation and
    ``robot_observations``' gathers for it."""
    key_reset, key_row, key_col, key_carry = jax.random.split(key, 4)
    _, state = env.reset(key_reset, params)
    pos = jnp.stack([jax.random.randint(key_row, (), 0, state.height),
                     jax.random.randint(key_col, (), 0, state.width)])
    state = state.replace(pos=pos, carrying=jax.random.bernoulli(key_carry))
    target = jnp.where(state.carrying, state.goal, state.item_pos)
    floor = params.pool.layouts.blocked[state.layout_index]
    expected = robot_observations(floor, state.pos[None], target[None], state.carrying[None], view_radius, 16)
    return env.observe(state), expected[0], env.blocked(state), floor, state.pos, state.height


def _rays_probe(env, params, plain_env, key):
    """A reset of the rays ``env`` and the robot moved anywhere on its floor, observed with and without rays."""
    key_reset, key_row, key_col = jax.random.split(key, 3)
    reset_obs, state = env.reset(key_reset, params)
    pos = jnp.stack([jax.random.randint(key_row, (), 0, state.height),
                     jax.random.randint(key_col, (), 0, state.width)])
    moved = state.replace(pos=pos)
    return reset_obs, env.observe(state), env.observe(moved), plain_env.observe(moved), moved.pos, moved.layout_index


@pytest.fixture(scope="module")
def window_runs():
    """``{radius: (env, params, probe outputs)}`` of the bit-mask test, and ``{radius: (rays env, params, plain env,
    outputs)}`` of the rays test: every radius of both tests in ONE jitted program (six programs apart cost twice
    as much to compile); each test reads its radius. One pool serves them all (``make_procedural``'s at radius
    2); the other environments' params (walls, reset table: the package's ``with_pool``) are computed inside the
    program too, not in a program per environment."""
    base_env, base = make_procedural(**WINDOW_POOL, view_radius=2)

    def env_of(radius, rays=False):
        return ProceduralWarehouse(generator=base_env.generator, pool_size=HELDOUT, view_radius=radius, pool_seed=0,
                                   observe_rays=rays)

    plain = {radius: env_of(radius) for radius in WINDOW_RADII}
    rays = {radius: env_of(radius, rays=True) for radius in RAY_RADII}

    @jax.jit
    def program(base, window_keys, ray_keys):
        plain_params = {radius: base if radius == 2 else env.with_pool(base, base.pool)
                        for radius, env in plain.items()}
        rays_params = {radius: env.with_pool(base, base.pool) for radius, env in rays.items()}
        windows = {radius: jax.vmap(partial(_window_probe, plain[radius], plain_params[radius], radius))(
            window_keys) for radius in WINDOW_RADII}
        walks = {radius: jax.vmap(partial(_rays_probe, rays[radius], rays_params[radius], plain[radius]))(
            ray_keys) for radius in RAY_RADII}
        return plain_params, rays_params, windows, walks

    plain_params, rays_params, windows, walks = program(base, jax.random.split(jax.random.key(3), 4000),
                                                        jax.random.split(jax.random.key(5), 500))
    for envs, params in ((plain, plain_params), (rays, rays_params)):
        for radius, env in envs.items():
            env.check_params(params[radius])
    return ({radius: (plain[radius], plain_params[radius], windows[radius]) for radius in WINDOW_RADII},
            {radius: (rays[radius], rays_params[radius], plain[radius], walks[radius]) for radius in RAY_RADII})


@pytest.mark.parametrize("view_radius", WINDOW_RADII)
def test_bit_mask_observation_is_robot_observations_bit_for_bit(window_runs, view_radius):
    """The packed-row windows equal the gathers of ``robot_observations`` on random states.

    Layouts from 8x8 to 16x16 in a 16x16 padding, so windows reach off-grid cells of smaller floors
    and the wall ring; positions anywhere on the real floor (shelves too), either target.
    V <= 2 packs the rows into int32 masks; V = 3, 4 read the window's rows unpacked (no 31-bit
    mask); V = 9 (34 walled columns) takes the gathers; all must agree.
    """
    env, params, outputs = window_runs[0][view_radius]
    assert env.bit_windows == (view_radius <= 2) and env.row_windows == (view_radius <= 8)
    obs, expected, unpacked, floor, pos, height = outputs
    np.testing.assert_array_equal(np.asarray(unpacked), np.asarray(floor))
    np.testing.assert_array_equal(np.asarray(obs).view(np.uint32), np.asarray(expected).view(np.uint32))
    side = 2 * view_radius + 1
    shelf = np.asarray(obs)[:, 5:5 + side * side]
    assert 0 < shelf.mean() < 1  # the windows see floor and walls, not one of them only
    # Windows that reach the off-grid rows below a floor shorter than the padding.
    sees_padding = (np.asarray(height) < 16) & (np.asarray(pos)[:, 0] + view_radius >= np.asarray(height))
    assert sees_padding.sum() > (100 if view_radius else -1)


def _numpy_free_runs(floor: np.ndarray, row: int, col: int) -> list[int]:
    """Free cells from ``(row, col)`` up, down, left and right before a blocked cell or the grid's edge."""
    runs = []
    for d_row, d_col in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        count, r, c = 0, row + d_row, col + d_col
        while 0 <= r < floor.shape[0] and 0 <= c < floor.shape[1] and not floor[r, c]:
            count, r, c = count + 1, r + d_row, c + d_col
        runs.append(count)
    return runs


@pytest.mark.parametrize("view_radius", RAY_RADII)
def test_rays_are_the_free_runs_a_walk_would_find(window_runs, view_radius):
    """``observe_rays``: the last 4 values are the free cells up, down, left and right over ``N - 1``,
    walked in NumPy on the floor (shelves, the floor's edge and the off-grid padding of small layouts stop
    a run); the observation before them is the plain one, bit for bit; the reset table holds them too."""
    env, params, plain_env, outputs = window_runs[1][view_radius]
    assert env.obs_size == plain_env.obs_size + 4 and env.static_config() != plain_env.static_config()
    reset_obs, first_obs, obs, plain, pos, slot = (np.asarray(x) for x in outputs)
    np.testing.assert_array_equal(reset_obs, first_obs)
    np.testing.assert_array_equal(obs[:, :-4].view(np.uint32), plain.view(np.uint32))
    floors = np.asarray(params.pool.layouts.blocked)
    expected = np.array([_numpy_free_runs(floors[s], r, c) for s, (r, c) in zip(slot, pos)], np.float32)
    np.testing.assert_array_equal(obs[:, -4:], expected * np.float32(1 / 15))
    assert expected.max() >= 5 and (expected == 0).any()  # long runs and runs stopped at once both occur


def test_packed_wall_rows_agree_with_the_grid_and_the_fleet_masks():
    """``wall_rows`` round-trips (one word and two words a row), ``wall_bit`` reads it, and the row masks
    equal ``window_masks`` at every cell (the fleet's table), off-grid ring included."""
    from wrl_jax.core.observation import (
        pack_window_rows,
        plane_window_rows,
        row_windows_supported,
        unpack_wall_rows,
        wall_bit,
        wall_rows,
        window_masks,
    )

    def probe(floor, cells, radius):  # one jitted program per case (not op by op)
        rows = wall_rows(floor, radius)
        bits = jax.vmap(lambda cell: wall_bit(rows, cell, radius))(cells)
        out = [rows, unpack_wall_rows(rows, floor.shape, radius), bits]
        if rows.shape[1] == 1:
            out += [window_masks(floor, radius), pack_window_rows(plane_window_rows(rows, cells, radius)[..., 0])]
        return out

    grid = np.asarray(jax.random.bernoulli(jax.random.key(4), 0.35, (7, 30)))
    cells = np.stack(np.meshgrid(np.arange(7), np.arange(30), indexing="ij"), axis=-1).reshape(-1, 2)
    for radius, width in ((2, 12), (1, 30), (2, 30)):  # 16, 32 and 34 walled columns: 1, 1 and 2 words
        mine = cells[cells[:, 1] < width]
        rows, unpacked, bits, *masks = jax.jit(probe, static_argnums=2)(grid[:, :width], mine, radius)
        assert rows.shape == (7 + 2 * radius, 1 if width + 2 * radius <= 32 else 2) and rows.dtype == jnp.uint32
        np.testing.assert_array_equal(np.asarray(unpacked), grid[:, :width])
        np.testing.assert_array_equal(np.asarray(bits), grid[mine[:, 0], mine[:, 1]])
        assert row_windows_supported(width, radius) == (rows.shape[1] == 1)
        assert len(masks) == (2 if rows.shape[1] == 1 else 0)
        if rows.shape[1] == 1:
            expected = np.asarray(masks[0])[mine[:, 0], mine[:, 1]]
            np.testing.assert_array_equal(np.asarray(masks[1]), expected)


def test_reset_draws_slot_and_item_from_jax_random_bits(env_and_params):
    """The written-out reset draw is ``jax.random.bits(key, (2,), uint32)`` through Lemire's map, bit for bit."""
    from wrl_jax.envs.procedural.episode import draw_episode
    from wrl_jax.envs.warehouse.env import item_from_word

    _, params = env_and_params
    num_items = params.pool.layouts.num_items
    keys = jax.random.split(jax.random.key(11), 2000)

    def expected(key):
        words = jax.random.bits(key, (2,), jnp.uint32)
        slot = item_from_word(words[0], jnp.int32(NUM_LAYOUTS))
        return slot, item_from_word(words[1], num_items[slot])

    ours = jax.jit(jax.vmap(lambda key: draw_episode(key, num_items, NUM_LAYOUTS)))(keys)
    theirs = jax.jit(jax.vmap(expected))(keys)
    for a, b in zip(ours, theirs):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert len(np.unique(np.asarray(ours[0]))) > 1500 and (np.asarray(ours[1]) < np.asarray(num_items)[ours[0]]).all()


def test_registry_make_returns_env_and_params(env_and_params):
    env, params = make("Procedural-Warehouse-v0", pool_size=NUM_LAYOUTS, max_steps=12)
    assert env.default_params is params and env == env_and_params[0]
    with pytest.raises(ValueError, match="unknown option"):
        make("Procedural-Warehouse-v0", pool_size=4, flavour="x")


# ---------------------------------------------------------------- map files
MOVINGAI = "type octile\nheight 4\nwidth 6\nmap\n..@@..\n......\nT.....\n.....W\n"


def test_movingai_map_loads_with_given_or_drawn_cells(tmp_path):
    path = tmp_path / "small.map"
    path.write_text(MOVINGAI)
    blocked = parse_movingai(MOVINGAI)
    assert blocked.shape == (4, 6) and blocked.sum() == 4 and blocked[0, 2] and blocked[2, 0] and blocked[3, 5]
    given = load_map(path, max_shape=(8, 8), start=(0, 0), goal=(3, 0), items=[(0, 5), (1, 2)])
    assert int(given.num_items) == 2 and np.asarray(given.blocked)[4:].all()
    drawn = load_map(path, max_shape=(8, 8), key=jax.random.key(0), num_items=3)
    dist = bfs_distances(_square(np.asarray(drawn.blocked)), tuple(np.asarray(drawn.start)))
    cells = np.concatenate([np.asarray(drawn.goal)[None], np.asarray(drawn.items)[:3]])
    assert (dist[cells[:, 0], cells[:, 1]] > 0).all()
    again = load_map(path, max_shape=(8, 8), key=jax.random.key(0), num_items=3)
    for a, b in zip(jax.tree.leaves(again), jax.tree.leaves(drawn)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize(("text", "message"), [
    ("height 4\nwidth 6\nmap\n", r"line 1: expected 'type <value>'"),
    ("type hex\nheight 1\nwidth 1\nmap\n.\n", "map type 'hex' is not supported"),
    ("type octile\nheight four\nwidth 6\nmap\n", "line 2: height must be a positive integer"),
    ("type octile\nheight 2\nwidth 2\n..\n..\n", "line 4: expected 'map'"),
    ("type octile\nheight 3\nwidth 2\nmap\n..\n..\n", "height 3 but the map has 2 rows"),
    ("type octile\nheight 2\nwidth 2\nmap\n..\n...\n", "line 6: map row 1 has 3 cells"),
    ("type octile\nheight 2\nwidth 2\nmap\n..\n.#\n", r"line 6, column 2: unknown character '#' at cell \(1, 1\)"),
    ("type octile\nheight 2\n", "ends at line 2"),
])
def test_malformed_movingai_files_are_clear_errors(tmp_path, text, message):
    path = tmp_path / "bad.map"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as error:
        load_map(path, key=jax.random.key(0))
    assert str(path) in str(error.value)


def test_bad_cells_in_a_map_are_clear_errors(tmp_path):
    blocked = parse_movingai("type octile\nheight 3\nwidth 3\nmap\n.@.\n.@.\n.@.\n")
    with pytest.raises(ValueError, match=r"item 0 at cell \(0, 2\) is unreachable"):
        movingai_layout(blocked, start=(0, 0), goal=(2, 0), items=[(0, 2)])
    with pytest.raises(ValueError, match=r"goal at cell \(1, 1\) is on a blocked cell"):
        movingai_layout(blocked, start=(0, 0), goal=(1, 1), items=[(2, 0)])
    with pytest.raises(ValueError, match="give all of start, goal and items"):
        movingai_layout(blocked, start=(0, 0))
    with pytest.raises(ValueError, match="larger than max_shape"):
        movingai_layout(blocked, max_shape=(2, 2), key=jax.random.key(0))


def test_ascii_map_files_load_as_layouts(tmp_path):
    path = tmp_path / "study.txt"
    path.write_text(maps.WAREHOUSE_8X8)
    layout = load_map(path, max_shape=(16, 16), max_items=10)
    assert isinstance(layout, PaddedLayout) and layout.max_shape == (16, 16) and int(layout.num_items) == 10
    bad = tmp_path / "bad.txt"
    bad.write_text("S . ?\n. . G\n0 . .\n")
    with pytest.raises(ValueError, match=r"bad.txt: unknown character '\?'"):
        load_map(bad)


# ---------------------------------------------------------------- evaluation hook
@pytest.fixture(scope="module")
def lean_env_and_params(env_and_params):
    """The module's environment and pool observing the five scalars only (``observe_window=False``): the
    evaluation tests' stand-in policies read nothing else, and their episode loops compile a quarter faster."""
    env, params = env_and_params
    lean = ProceduralWarehouse(generator=env.generator, pool_size=env.pool_size, observe_window=False)
    return lean, lean.with_pool(params, params.pool)


def test_greedy_evaluation_on_heldout_layouts(lean_env_and_params):
    from wrl_jax.core.evaluation import for_env

    env, params = lean_env_and_params
    evaluation = for_env(env)

    def greedy(network_params, obs):  # head for the target (rows first for "seed" 0, columns first for 1)
        d_row, d_col = obs[2] - obs[0], obs[3] - obs[1]
        vertical = jnp.where(d_row < 0, 0, 1)
        horizontal = jnp.where(d_col < 0, 2, 3)
        rows_first = (network_params == 0) & (d_row != 0) | (d_col == 0)
        return jnp.where(rows_first, vertical, horizontal).astype(jnp.int32)

    # LLVM level 0 (fast_compile): the assertions compare the run with itself and with the BFS optimum only.
    result = fast_compile.jit(lambda p: evaluation.evaluate_seeds(greedy, jnp.arange(2), env, p))(
        params.replace(max_steps=jnp.int32(200)))
    result = jax.tree.map(np.asarray, result)
    assert result.delivered.shape == (2, 64, CONFIG.max_items)
    delivered = result.delivered & result.real
    assert delivered.any()
    assert (result.steps[delivered] >= result.optimal_steps[delivered]).all()  # nobody beats the BFS
    assert (result.steps[result.real & ~result.delivered] == 200).all()
    summary = evaluation.summarize(result, [0, 1])
    assert summary["success_rate"] == delivered.sum() / result.real.sum()
    assert "held-out layouts" in evaluation.format_report(summary, "greedy")


def _toward_target(network_params, obs):
    """A stand-in policy: head for the target, rows first for "seed" 0, columns first for 1 (no learning)."""
    d_row, d_col = obs[2] - obs[0], obs[3] - obs[1]
    vertical = jnp.where(d_row < 0, 0, 1)
    horizontal = jnp.where(d_col < 0, 2, 3)
    rows_first = (network_params == 0) & (d_row != 0) | (d_col == 0)
    return jnp.where(rows_first, vertical, horizontal).astype(jnp.int32)


@pytest.fixture(scope="module")
def ood():
    """The out-of-distribution sets for the default generator, 16 layouts each, 3 MovingAI placements.

    ``ood_sets`` builds them with its own keys and generator configs, but the five generated sets come out of
    ONE program compiled at LLVM level 0 (``fast_compile``; five programs at LLVM level 1 cost 2.5 times
    as much to compile): a first pass records the ``generate_pool`` calls, one program runs them all, a second
    pass hands each call its pool. The tests read statistics of these layouts, never their bits.
    """
    from wrl_jax.envs.procedural import layout_sets

    calls = []

    def record(key, count, config, stream="train"):
        calls.append((key, count, config, stream))
        return SimpleNamespace(layouts=None)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(layout_sets, "MOVINGAI_DRAWS", 3)
        patch.setattr(layout_sets, "generate_pool", record)
        layout_sets.ood_sets(CONFIG, ood_layouts=16, names=["dense", "narrow_shelves", *LONG_ROUTES])
        pools = iter(fast_compile.jit(lambda keys: [pool_from_keys(stream_keys(key, stream, count), config)
                                                    for key, (_, count, config, stream) in zip(keys, calls)])(
            [key for key, *_ in calls]))

        def served(key, count, config, stream="train"):
            expected = calls.pop(0)
            assert (count, config, stream) == expected[1:] and np.array_equal(
                jax.random.key_data(key), jax.random.key_data(expected[0]))
            return next(pools)

        patch.setattr(layout_sets, "generate_pool", served)
        sets = layout_sets.ood_sets(CONFIG, ood_layouts=16)
        assert not calls  # every generated set was served
        return sets


def test_final_report_measures_heldout_and_ood_sets(lean_env_and_params, ood, monkeypatch):
    """The final generalization report: sets, sizes, yardsticks, per-seed rows, the hash check, the tables, and
    its one batch over every set (padded to one item capacity) giving the held-out pool's results alone."""
    from wrl_jax.core.evaluation import FinalContext
    from wrl_jax.envs.procedural import evaluation, layout_sets, reports

    monkeypatch.setattr(layout_sets, "FINAL_HELDOUT_LAYOUTS", HELDOUT)

    def ood_sets(generator, ood_layouts=None):  # the fixture's sets (generated once for the module)
        assert generator == CONFIG
        return ood

    monkeypatch.setattr(evaluation, "ood_sets", ood_sets)
    env, params = lean_env_and_params
    params = params.replace(max_steps=jnp.int32(60))
    # A "stochastic" stand-in whose draws are its greedy action: the sampled held-out row must equal the greedy one.
    algo = SimpleNamespace(greedy_action=_toward_target, has_stochastic_policy=True,
                           sample_action=lambda net, obs, key: _toward_target(net, obs), policy_memory=lambda: None)
    context = FinalContext(algo=algo, network_params=jnp.arange(2), env=env, params=params, seeds=[7, 8])
    report = evaluation.final_report(context)
    heldout, ood = report["heldout"], report["ood"]
    sampled = {k: v for k, v in report["heldout_sampled"].items() if k != "description"}
    assert sampled == {k: v for k, v in heldout.items() if k not in ("description", "overlap_with_training")}
    assert heldout["layouts"] == HELDOUT - heldout["overlap_with_training"] and heldout["overlap_with_training"] == 0
    assert set(ood) == {"dense", "narrow_shelves", "serpentine", "spiral", "comb", "study_8x8", "study_12x12",
                        "movingai"}
    assert [ood[name]["layouts"] for name in ("dense", "narrow_shelves", "serpentine", "movingai")] == [16, 16, 16, 3]
    assert ood["study_8x8"]["episodes"] == 2 * 10 and ood["study_12x12"]["episodes"] == 2 * 20
    assert ood["study_8x8"]["bfs_optimum"] == 14.0  # the study's mean optimum (wrl_jax.envs.warehouse.layout's BFS)
    assert ood["movingai"]["episodes"] == 2 * 3 * 8
    for row in [heldout, *ood.values()]:
        assert [entry["seed"] for entry in row["per_seed"]] == [7, 8]
        assert sum(entry["episodes"] for entry in row["per_seed"]) == row["episodes"]
        assert 0.0 <= row["delivery_rate"] <= 1.0 and row["optimal_rate"] <= row["delivery_rate"]
        if row["mean_excess"] is not None:  # nobody beats the BFS optimum
            assert row["mean_excess"] >= 0 and row["excess_fraction"] == row["mean_excess"] / row["mean_optimal"]
    assert 0 < heldout["delivery_rate"] < 1  # the stand-in policy walks into shelves on some floors only
    # One batch over sets (padded to 20 item rows by study_12x12) = the held-out pool evaluated alone.
    heldout_layouts = layout_sets.heldout_set(env.generator, params.pool)[0].layouts
    alone = jax.tree.map(np.asarray, jax.jit(jax.vmap(
        lambda net: evaluation.evaluate_pool(_toward_target, net, env, params, pool_from_layouts(
            [_slot(heldout_layouts, i) for i in range(HELDOUT)]))))(jnp.arange(2)))
    delivered = alone.delivered & alone.real
    assert heldout["episodes"] == alone.real.sum() and ood["study_12x12"]["layouts"] == 1
    assert heldout["delivery_rate"] == delivered.sum() / alone.real.sum()
    assert heldout["per_seed"][1]["delivery_rate"] == delivered[1].sum() / alone.real[1].sum()
    assert report["final_report_seconds"] > 0
    details = reports.format_details(report)
    assert f"| heldout | {HELDOUT} |" in details and "| movingai | 3 |" in details and "seed 8" in details
    assert f"| heldout (sampled policy) | {HELDOUT} |" in details
    summary = {"eval_layouts": HELDOUT // 2, "episodes_per_seed": 1, "success_rate": 1.0, "optimal_rate": 1.0,
               "mean_excess": 0.0, "collisions_per_episode": 0.0, **report}
    headline = reports.format_report(summary, "x")
    assert f"final: {HELDOUT} held-out layouts" in headline and "final, sampled policy: delivered / excess" in headline


def test_final_sets_drop_training_layouts_and_sample_episodes(lean_env_and_params):
    """The held-out set's hash check, sampled episodes, refusals. (That one batch over sets equals each pool
    evaluated alone is checked on the final report's own batch, in the test above; the ``overall`` row, the
    sum of the sets', by tests/cli/test_procedural_cli.py's evaluation on layout files.)"""
    from wrl_jax.envs.procedural import evaluation, layout_sets

    env, params = lean_env_and_params
    params = params.replace(max_steps=jnp.int32(60))
    heldout, overlap = layout_sets.heldout_set(env.generator, params.pool, count=HELDOUT)
    assert overlap == 0 and heldout.size == HELDOUT
    # Plant three of them in a "training pool": the hash check finds and drops exactly those.
    planted = jax.tree.map(lambda t, h: t.at[:3].set(h[:3]), params.pool.layouts, heldout.layouts)
    kept, overlap = layout_sets.heldout_set(env.generator, params.pool.replace(layouts=planted), count=HELDOUT)
    assert overlap == 3 and kept.size == HELDOUT - 3
    # Sampled episodes: the same key, the same episodes; another key, other ones.
    def uniform(net, obs, key):
        return jax.random.randint(key, (), 0, 4)

    sample = jax.jit(lambda key: evaluation.run_episodes(_toward_target, 0, env, params, jnp.arange(48),
                                                         jnp.zeros(48, jnp.int32), uniform, key))
    first, again, other = (jax.tree.map(np.asarray, sample(jax.random.key(k))) for k in (5, 5, 6))
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    assert (first[3] != other[3]).any() and len(np.unique(first[3])) > 1  # collisions differ across keys, episodes
    with pytest.raises(ValueError, match="sampled episodes need a key"):
        evaluation.run_episodes(_toward_target, 0, env, params, jnp.arange(2), jnp.zeros(2, jnp.int32), uniform)
    with pytest.raises(ValueError, match="padded to"):
        evaluation.evaluate_sets(_toward_target, jnp.arange(1), env, params, [layout_sets.LayoutSet(
            "small", "", jax.tree.map(lambda x: x[None], layout_sets.study_layout("8x8", (8, 8))))], [0])


def test_ood_generators_are_out_of_distribution(ood):
    sets = {s.name: s for s in ood}
    assert list(sets) == ["dense", "narrow_shelves", "serpentine", "spiral", "comb", "study_8x8", "study_12x12",
                          "movingai"]
    dense = jax.tree.map(np.asarray, sets["dense"].layouts)
    floor = (np.arange(16)[None, :, None] < dense.height[:, None, None]) & (
        np.arange(16)[None, None, :] < dense.width[:, None, None])
    density = (dense.blocked & floor).sum(axis=(1, 2)) / floor.sum(axis=(1, 2))
    assert np.median(density) > CONFIG.density[1]  # above the training range (unreached cells only add shelves)
    narrow = jax.tree.map(np.asarray, sets["narrow_shelves"].layouts)
    assert (narrow.height == 16).all() and (narrow.width == 16).all()
    assert narrow.blocked.mean() > 0.3
    assert sets["movingai"].layouts.max_shape == (16, 16) and sets["study_12x12"].size == 1
