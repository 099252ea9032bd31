"""The RWARE family's surface: its 228 names, layouts, input checks, and the random environment under jit.

Only the tests that compare with rware's own registry or warehouse need rware installed.
"""

from __future__ import annotations

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import fast_compile

import wrl_jax
from wrl_jax.core import registry
from wrl_jax.envs.rware import from_rware, layout_from_params, make_rware, parse_layout
from wrl_jax.envs.rware.registration import registered_ids

TINY = """
..........
.XX....XX.
.XX....XX.
.XX....XX.
.XX....XX.
.XX....XX.
.XX....XX.
.XX....XX.
.XX....XX.
..........
....gg....
"""


def test_every_rware_id_is_registered_with_rware_kwargs():
    pytest.importorskip("rware")  # registers rware's ids with Gymnasium
    ours = registry.registered_names("rware")
    theirs = sorted(name for name in gym.registry if name.startswith("rware-"))
    assert ours == theirs == sorted(registered_ids()) and len(ours) == 228
    for name in ours:
        kwargs = gym.spec(name).kwargs
        if kwargs["request_queue_size"] >= 32 and name.startswith("rware-tiny"):  # more requests than shelves
            with pytest.raises(ValueError, match="rware 2.0.0 cannot run it either"):
                wrl_jax.make(name)
            continue
        env, params = wrl_jax.make(name)
        rows, columns, height = kwargs["shelf_rows"], kwargs["shelf_columns"], kwargs["column_height"]
        assert env.family == "rware" and env.name == name
        assert params.grid_size == ((height + 1) * rows + 2, 3 * columns + 1)
        assert (env.num_agents, env.queue_size) == (kwargs["n_agents"], kwargs["request_queue_size"])
        assert (env.sensor_range, env.msg_bits, env.obs_size) == (kwargs["sensor_range"], kwargs["msg_bits"], 71)
        assert int(params.max_steps) == kwargs["max_steps"] and int(params.max_inactivity_steps) == 0
        assert int(params.reward_type) == kwargs["reward_type"].value


def test_sizes_and_layouts():
    for name, (height, width, shelves) in {"tiny": (11, 10, 32), "small": (20, 10, 80), "medium": (20, 16, 144),
                                           "large": (29, 16, 224)}.items():
        _, params = wrl_jax.make(f"rware-{name}-2ag-v2")
        assert params.grid_size == (height, width) and params.num_shelves == shelves
        assert np.asarray(params.goals).tolist() == [[width // 2 - 1, height - 1], [width // 2, height - 1]]
    tiny = layout_from_params(3, 1, 8)
    parsed = parse_layout(TINY.replace("..", ". ."))  # spaces are ignored, as in rware
    np.testing.assert_array_equal(tiny.highway, parsed.highway)
    np.testing.assert_array_equal(tiny.goals, parsed.goals)
    assert parse_layout("xG\n.X").goals.tolist() == [[1, 0]]  # case-insensitive


@pytest.mark.parametrize("call, message", [
    (lambda: wrl_jax.make("rware-tiny-20ag-v2"), "unknown environment"),
    (lambda: wrl_jax.make("rware-tiny-2ag-v2", reward_type="shared"), "reward_type"),
    (lambda: wrl_jax.make("rware-tiny-2ag-v2", num_agents=3), "fixed by the id"),
    (lambda: wrl_jax.make("rware-tiny-2ag-v2", speed=2), "unknown rware override"),
    (lambda: make_rware(2, layout="x.g\nx."), "rectangular"),
    (lambda: make_rware(2, layout="x.g\nx.?"), "not one of"),
    (lambda: make_rware(2, layout="x..\nx.."), "goal"),
    (lambda: make_rware(2, shelf_columns=2), "odd"),
    (lambda: make_rware(2, shelf_columns=1, shelf_rows=1), "request_queue_size"),
    (lambda: make_rware(2, request_queue_size=32, shelf_columns=3, shelf_rows=1), "below the layout"),
    (lambda: make_rware(0), "num_agents"),
    (lambda: make_rware(111, shelf_columns=3, shelf_rows=1), "does not fit"),
    (lambda: make_rware(2, observation_type="pixels"), "observation_type"),
    (lambda: make_rware(2, max_steps=-1), "max_steps"),
    (lambda: make_rware(2, sensor_range=-1), "sensor_range"),
    (lambda: wrl_jax.make("rware-tiny-4ag-v2", tie_order="lowest-id"), "tie_order"),
    (lambda: make_rware(120, shelf_columns=9, shelf_rows=3), "use tie_order='insertion'"),
])
def test_bad_input_is_a_clear_value_error(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_tie_order_is_static_and_defaults_to_rwares_own():
    exact, _ = wrl_jax.make("rware-tiny-4ag-v2")
    inserted, _ = wrl_jax.make("rware-tiny-4ag-v2", tie_order="insertion")
    assert exact.tie_order == "set" and inserted.tie_order == "insertion"
    assert exact.static_config() != inserted.static_config()  # two programs, never one cache entry


def test_bad_actions_and_warehouses():
    env, params = wrl_jax.make("rware-tiny-2ag-v2")
    for action, message in ((np.zeros(3, np.int32), "shape"), (np.zeros(2, np.float32), "integers"),
                            (np.array([0, 5], np.int32), "outside 0..4")):
        with pytest.raises(ValueError, match=message):  # checked before anything is traced
            env.transition(jax.random.key(1), None, action, params)
    _, state = env.reset(jax.random.key(0), params)
    for action, message in ((jnp.zeros(3, jnp.int32), "shape"), (jnp.zeros((1, 2), jnp.int32), "shape"),
                            (jnp.zeros(2, jnp.float32), "integers"), (jnp.zeros(2, bool), "integers")):
        with pytest.raises(ValueError, match=message):  # under jit too: shapes and dtypes are known when tracing
            jax.jit(env.step).trace(jax.random.key(1), state, action, params)
    warehouse = pytest.importorskip("rware.warehouse")
    with pytest.raises(ValueError, match="reset"):
        from_rware(warehouse.Warehouse(3, 8, 1, 2, 0, 1, 2, None, 500, warehouse.RewardType.INDIVIDUAL))


def test_random_episodes_under_jit():
    """Two batched episodes (``vmap`` over keys) of the random env: auto-reset at 500 steps (truncated, never
    terminated), float32 (N, 71) observations, same seed same bits, and the state stays valid: distinct agent
    cells, distinct requests, carried shelves under their carriers."""
    env, params = wrl_jax.make("rware-tiny-3ag-easy-v2")
    n = env.num_agents

    @fast_compile.jit  # LLVM level 0: a short run, compiling is its time
    @jax.vmap
    def rollout(key):
        obs, state = env.reset(key)

        def one(state, key):
            key_action, key_step = jax.random.split(key)
            action = jax.random.randint(key_action, (n,), 0, 5)
            obs, next_state, reward, terminated, truncated, info = env.step(key_step, state, action)
            return next_state, (obs, state, reward, terminated, truncated, info["delivered"])

        return jax.lax.scan(one, state, jax.random.split(key, 510))[1]

    keys = jax.random.split(jax.random.key(3), 2)
    outputs = rollout(keys)
    for a, b in zip(jax.tree.leaves(rollout(keys)), jax.tree.leaves(outputs)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    obs, states, reward, terminated, truncated, delivered = jax.tree.map(np.asarray, outputs)
    assert obs.shape == (2, 510, n, 71) and obs.dtype == np.float32 and reward.dtype == np.float32
    assert not terminated.any() and [np.flatnonzero(t).tolist() for t in truncated] == [[499], [499]]
    assert (states.time[:, 500] == 0).all() and (states.time[:, 499] == 499).all()
    assert not np.array_equal(states.agent_x[0], states.agent_x[1])  # the two keys drew different episodes
    assert set(np.unique(reward)) <= {0.0, 1.0} and (reward == delivered).all()
    states = jax.tree.map(lambda leaf: leaf.reshape(leaf.shape[0] * leaf.shape[1], *leaf.shape[2:]), states)
    cells = states.agent_y * 10 + states.agent_x
    assert all(len(set(row)) == n for row in cells)
    assert all(len(set(row)) == env.queue_size for row in states.queue)
    loaded = states.carrying >= 0
    carried = np.where(loaded, states.carrying, 0)
    assert (np.take_along_axis(states.shelf_x, carried, 1) == states.agent_x)[loaded].all()
    assert (np.take_along_axis(states.shelf_y, carried, 1) == states.agent_y)[loaded].all()


def test_spaces():
    env, params = wrl_jax.make("rware-tiny-3ag-easy-v2")
    assert env.observation_space().shape == (3, 71) and env.action_space().n == 5
    assert env.multi_action_space().shape == (3,)
    assert env.obs_size == 71 and env.num_actions == 5 and env.num_agents == 3
