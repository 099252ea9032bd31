"""The JAX environment: SPEC.md semantics, auto-reset, batching, switches, errors.

Compiling is the cost here: the tests step through :func:`jitted` (one program per static configuration and
method, shared by every test; eagerly, each call compiled its operations one by one) and read the results as
NumPy arrays. ``test_bad_action_and_item_index_raise`` calls the methods themselves (their checks run before
any operation).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import wrl_jax
from wrl_jax.envs.warehouse import registration, routes

UP, DOWN, LEFT, RIGHT = range(4)
_JITTED: dict = {}


def jitted(env, method: str):
    """``jax.jit(env.<method>)``, one per static configuration (size, item capacity, carrying flag) and method.

    Environments made with other constants differ only in their default params, which these methods do not
    read (every call passes ``params``), so one program serves them all. The method is bound to the environment
    without its default params, so a method that did read them would fail loudly instead of using the first's.
    """
    key = (env.static_config(), method)
    if key not in _JITTED:
        _JITTED[key] = jax.jit(getattr(env.without_default_params(), method))
    return _JITTED[key]


def transition(env, state, action, params):
    return jitted(env, "transition")(None, state, action, params)


def small():
    # S at (0,0), shelf at (1,1), item 0 at (0,2), goal at (2,2).
    return wrl_jax.make_from_layout("S.0\n.#.\n..G", max_steps=5)


def test_registered_names_and_unknown_name():
    assert wrl_jax.registered_names(family="warehouse") == ["Warehouse-12x12-v0", "Warehouse-8x8-v0"]
    assert set(wrl_jax.registered_names()) >= {"Warehouse-12x12-v0", "Warehouse-8x8-v0", "Fleet-12x12-v0"}
    with pytest.raises(ValueError, match="unknown environment 'Warehouse-9x9-v0'"):
        wrl_jax.make("Warehouse-9x9-v0")


def test_overrides_reach_params():
    env, params = wrl_jax.make("Warehouse-8x8-v0", shaping_coef=0.0, pickup_reward=0.0, max_steps=7,
                               step_penalty=-1.0, collision_bug=True, observe_carrying=False)
    assert float(params.shaping_coef) == 0.0 and float(params.pickup_reward) == 0.0
    assert float(params.step_penalty) == -1.0 and int(params.max_steps) == 7
    assert bool(params.collision_bug) and env.obs_size == 6
    with pytest.raises(ValueError, match="unknown reward parameter"):
        wrl_jax.make("Warehouse-8x8-v0", shaping=1.0)
    with pytest.raises(ValueError, match="max_steps must be a positive integer"):
        wrl_jax.make("Warehouse-8x8-v0", max_steps=0)


def test_reset_observation(env_and_params):
    env, params = env_and_params
    n = env.size - 1
    obs, state = jitted(env, "reset_to_item")(1, params)
    item = np.asarray(params.items)[1]
    expected = np.array([0, 0, n, n, item[0], item[1]], dtype=np.float32) / np.float32(n)
    obs = np.asarray(obs)
    np.testing.assert_array_equal(obs[:6], expected)
    assert obs.dtype == jnp.float32 and obs.shape == (7,) and obs[6] == 0.0
    assert int(state.time) == 0 and not bool(state.carrying)


def test_pick_and_deliver_rewards():
    env, params = small()
    _, state = jitted(env, "reset_to_item")(0, params)
    obs, state, reward, term, trunc, info = transition(env, state, RIGHT, params)
    assert float(reward) == -0.5 + 2.0  # one step closer to the item
    obs, state, reward, term, trunc, info = transition(env, state, RIGHT, params)
    assert bool(info["picked_up"]) and bool(state.carrying)
    assert float(reward) == -0.5 + 2.0 + 50.0
    assert obs[4] == obs[5] == np.float32(-1.0) / np.float32(2.0) and obs[6] == 1.0
    obs, state, reward, term, trunc, info = transition(env, state, DOWN, params)
    assert float(reward) == -0.5 + 2.0 and not bool(term)
    obs, state, reward, term, trunc, info = transition(env, state, DOWN, params)
    assert bool(term) and not bool(trunc) and bool(info["delivered"])
    assert float(reward) == 2.0 + 200.0  # no step penalty on the terminating transition
    assert obs[6] == 1.0 and obs[4] == np.float32(-0.5)  # final obs still shows the item carried


def test_collision_and_wall_bump():
    env, params = small()
    _, state = jitted(env, "reset_to_item")(0, params)
    _, state, reward, _, _, info = transition(env, state, UP, params)
    assert bool(info["wall_bump"]) and not bool(info["collision"])
    assert float(reward) == -0.5 and tuple(state.pos) == (0, 0)
    _, state, _, _, _, _ = transition(env, state, DOWN, params)
    _, state, reward, _, _, info = transition(env, state, RIGHT, params)  # into the shelf at (1,1)
    assert bool(info["collision"]) and tuple(state.pos) == (1, 0)
    # target is the item at (0,2): distance unchanged, so -0.5 - 10
    assert float(reward) == -10.5


def test_wall_penalty_parameter():
    env, params = wrl_jax.make_from_layout("S.0\n.#.\n..G", max_steps=5, wall_penalty=-3.0)
    _, state = jitted(env, "reset_to_item")(0, params)
    _, _, reward, _, _, _ = transition(env, state, LEFT, params)
    assert float(reward) == -3.5


def test_collision_bug_puts_robot_on_the_shelf():
    env, params = wrl_jax.make_from_layout("S.0\n.#.\n..G", max_steps=5, collision_bug=True)
    _, state = jitted(env, "reset_to_item")(0, params)
    _, state, _, _, _, _ = transition(env, state, DOWN, params)
    _, state, reward, _, _, info = transition(env, state, RIGHT, params)
    assert bool(info["collision"]) and tuple(state.pos) == (1, 1)
    # shaping now sees the shelf cell: one step closer to the item at (0,2)
    assert float(reward) == -0.5 - 10.0 + 2.0


def test_truncation_and_time():
    env, params = small()
    _, state = jitted(env, "reset_to_item")(0, params)
    for t in range(1, 6):
        _, state, _, term, trunc, _ = transition(env, state, UP, params)
        assert int(state.time) == t and not bool(term)
        assert bool(trunc) == (t == 5)


def test_delivery_on_last_step_is_terminated_not_truncated():
    env, params = wrl_jax.make_from_layout("S.0\n.#.\n..G", max_steps=4)
    _, state = jitted(env, "reset_to_item")(0, params)
    for action in (RIGHT, RIGHT, DOWN, DOWN):
        _, state, _, term, trunc, _ = transition(env, state, action, params)
    assert bool(term) and not bool(trunc)


def test_auto_reset_keeps_final_observation():
    env, params = small()
    _, state = jitted(env, "reset_to_item")(0, params)
    step = jitted(env, "step")
    key = jax.random.key(0)
    for action in (RIGHT, RIGHT, DOWN):
        obs, state, *_ = step(key, state, action, params)
    obs, state, reward, term, trunc, info = step(key, state, DOWN, params)
    assert bool(term)
    assert info["final_obs"][6] == 1.0 and tuple(np.asarray(info["final_obs"][:2])) == (1.0, 1.0)
    assert obs[6] == 0.0 and tuple(np.asarray(obs[:2])) == (0.0, 0.0)  # a fresh episode
    assert int(state.time) == 0 and not bool(state.carrying)


def test_reset_draws_every_item_uniformly(env_and_params):
    env, params = env_and_params
    _, states = jax.jit(lambda key: jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key, 20_000), params))(
        jax.random.key(3))
    states = jax.tree.map(np.asarray, states)
    counts = np.bincount(states.item_index, minlength=int(params.num_items))
    k = int(params.num_items)
    assert len(counts) == k and counts.min() > 0
    # chi-square against uniform, generous bound (p << 1e-6 to fail by chance)
    expected = 20_000 / k
    assert ((counts - expected) ** 2 / expected).sum() < 3 * k + 60
    np.testing.assert_array_equal(states.item_pos, np.asarray(params.items)[states.item_index])


def test_bad_action_and_item_index_raise():
    env, params = small()
    _, state = jitted(env, "reset_to_item")(0, params)
    for bad in (4, -1, 1.5, 2.0, True, "up", 10**20):
        with pytest.raises(ValueError, match="action"):
            env.transition(None, state, bad, params)
    with pytest.raises(ValueError, match="item_index 3 is out of range"):
        env.reset_to_item(3, params)


def test_vmap_scan_over_many_envs(env_and_params):
    env, params = env_and_params
    batch, horizon = 256, 400

    @jax.jit
    def rollout(key):
        reset_key, run_key = jax.random.split(key)
        _, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(reset_key, batch), params)

        def body(state, key):
            action_key, step_key = jax.random.split(key)
            actions = jax.random.randint(action_key, (batch,), 0, 4)
            obs, state, reward, term, trunc, info = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                jax.random.split(step_key, batch), state, actions, params)
            return state, (obs, reward, term, trunc, info["collision"], state.time)

        return jax.lax.scan(body, state, jax.random.split(run_key, horizon))

    state, (obs, reward, term, trunc, collision, time) = rollout(jax.random.key(0))
    assert obs.shape == (horizon, batch, 7)
    assert bool(jnp.any(trunc)) and bool(jnp.any(collision))
    assert int(time.max()) < int(params.max_steps)  # auto-reset keeps every episode in range
    # observations stay inside the grid after normalization (or the -1/(N-1) sentinel)
    assert obs.min() >= np.float32(-1.0) / np.float32(env.size - 1) and obs.max() <= 1.0


def test_same_program_serves_every_layout_of_a_size():
    env_a, params_a = wrl_jax.make("Warehouse-8x8-v0")
    other = "S . . . . . . .\n. # # # # # # .\n. 0 . . . . . .\n. . . . . . . .\n" \
            ". . . . . . . .\n. . . . . . . .\n. 1 . . . . . .\n. . . . . . . G"
    env_b, params_b = wrl_jax.make_from_layout(other, max_steps=150, max_items=10)
    # Same static configuration; they differ only in their default params (the
    # layout ``params=None`` means), so they are not interchangeable as jit
    # static arguments, but one program serves both layouts' params.
    assert env_a.static_config() == env_b.static_config()
    assert env_a != env_b and env_a.default_params is params_a and env_b.default_params is params_b
    traces = []

    @jax.jit
    def first_step(params):
        traces.append(1)
        _, state = env_a.reset_to_item(1, params)
        return env_a.transition(None, state, DOWN, params)[0]

    first_step(params_a)
    obs_b = first_step(params_b)
    assert len(traces) == 1
    assert tuple(np.asarray(obs_b[4:6]) * 7) == (6.0, 1.0)


@pytest.mark.parametrize("name", ["Warehouse-8x8-v0", "Warehouse-12x12-v0"])
def test_oracle_delivers_every_item_optimally(name):
    env, params = wrl_jax.make(name)
    layout = registration.spec(name).layout

    def episode(item_index, tables):
        _, state = env.reset_to_item(item_index, params)

        def body(carry, _):
            state, done, ret, steps, collisions = carry
            action = routes.oracle_action(state, params, tables)
            _, nxt, reward, term, _, info = env.transition(None, state, action, params)
            live = ~done
            state = jax.tree.map(lambda a, b: jnp.where(live, a, b), nxt, state)
            return (state, done | term, ret + jnp.where(live, reward, 0.0), steps + live,
                    collisions + (live & info["collision"])), None

        init = (state, jnp.array(False), jnp.float32(0), jnp.int32(0), jnp.int32(0))
        (state, done, ret, steps, collisions), _ = jax.lax.scan(body, init, None, length=int(params.max_steps))
        return done, ret, steps, collisions

    @jax.jit
    def oracle_episodes():
        """The route tables, their optimal lengths and every item's oracle episode: one program."""
        tables = routes.route_tables(params)
        episodes = jax.vmap(episode, in_axes=(0, None))(jnp.arange(layout.num_items), tables)
        return routes.optimal_lengths(params, tables), episodes

    optimal, (done, ret, steps, collisions) = jax.tree.map(np.asarray, oracle_episodes())
    np.testing.assert_array_equal(optimal, wrl_jax.optimal_route_lengths(layout))
    assert bool(done.all()) and int(collisions.sum()) == 0
    np.testing.assert_array_equal(steps, optimal)
    # closed form of SPEC.md: 250.5 - 0.5 L + 2 (M(start, item) + M(item, goal))
    start, goal, items = layout.start, layout.goal, layout.items
    manhattan = np.abs(items - start).sum(1) + np.abs(goal - items).sum(1)
    np.testing.assert_array_equal(ret, 250.5 - 0.5 * optimal + 2.0 * manhattan)


def test_jax_bfs_agrees_with_numpy_bfs(env_and_params):
    env, params = env_and_params
    from wrl_jax.envs.warehouse.layout import bfs_distances
    tables = routes.route_tables(params)
    reference = bfs_distances(np.asarray(params.shelves), tuple(np.asarray(params.goal)))
    jax_map = np.asarray(tables.to_goal)
    np.testing.assert_array_equal(np.where(reference < 0, -1, jax_map), reference)
    assert (jax_map[reference < 0] == routes.UNREACHABLE).all()


def test_draw_item_is_exact_multiply_shift():
    """draw_item maps one 32-bit word u to floor(u * k / 2**32), computed without 64-bit integers."""
    from wrl_jax.envs.warehouse.env import draw_item

    keys = jax.random.split(jax.random.key(11), 4096)
    words = np.asarray(jax.vmap(lambda k: jax.random.bits(k, (), jnp.uint32))(keys)).astype(np.uint64)
    words = np.concatenate([words, [0, 2**32 - 1, 2**31, 2**16 - 1]]).astype(np.uint64)
    draw = jax.jit(jax.vmap(draw_item, in_axes=(0, None)))  # one program for every count (its params are traced)
    edges = jax.jit(lambda w, c: ((w >> 16) * c + (((w & 0xFFFF) * c) >> 16)) >> 16)
    for count in (1, 2, 7, 10, 20, 62, 2**16 - 1):
        _, params = wrl_jax.make("Warehouse-8x8-v0")
        params = params.replace(num_items=np.asarray(count, np.int32))
        drawn = np.asarray(draw(keys, params))
        np.testing.assert_array_equal(drawn, (words[:4096] * count) >> 32)
        # the edge words, through the same arithmetic on uint32 arrays
        edge = edges(words[4096:].astype(np.uint32), np.uint32(count))
        np.testing.assert_array_equal(np.asarray(edge), (words[4096:] * count) >> 32)


def test_step_to_item_pins_the_next_episode():
    env, params = small()
    _, state = jitted(env, "reset_to_item")(0, params)
    for action in (RIGHT, RIGHT, DOWN):
        _, state, *_ = jitted(env, "step_to_item")(state, action, 0, params)
    obs, state, _, term, _, info = jitted(env, "step_to_item")(state, DOWN, 0, params)
    assert bool(term) and int(state.item_index) == 0 and int(state.time) == 0
    keyed = jitted(env, "step")(jax.random.key(5), state, UP, params)
    pinned = jitted(env, "step_to_item")(state, UP, 0, params)
    for a, b in zip(jax.tree.leaves(keyed), jax.tree.leaves(pinned)):
        np.testing.assert_array_equal(a, b)  # no episode end: the key changes nothing


def test_draw_items_gives_each_env_its_own_uniform_item():
    """draw_items: one key, one word per environment, the same multiply-shift as draw_item."""
    from wrl_jax.envs.warehouse.env import draw_items

    _, params = wrl_jax.make("Warehouse-12x12-v0")
    key = jax.random.key(5)
    items = np.asarray(draw_items(key, 20_000, params))
    words = np.asarray(jax.random.bits(key, (20_000,), jnp.uint32)).astype(np.uint64)
    np.testing.assert_array_equal(items, (words * 20) >> 32)
    counts = np.bincount(items, minlength=20)
    assert counts.shape == (20,) and ((counts - 1000) ** 2 / 1000).sum() < 3 * 20 + 60
    # Another key draws other items.
    assert (np.asarray(draw_items(jax.random.key(6), 20_000, params)) != items).mean() > 0.9
