"""The JAX environment and the NumPy reference agree to the bit, step by step.

The JAX side runs as it runs in training: jitted, ``vmap``-ped over episodes
and ``lax.scan``-ned over time, with ``env.step``'s automatic reset. Its actions
(random, mixed with oracle moves so that episodes also deliver) are recorded,
then replayed one by one in :class:`~wrl_jax.envs.warehouse.reference.WarehouseReferenceEnv`,
which is reset, whenever its own episode ends, to the item the JAX key drew.
Every observation (the reset one, the final one kept in ``info["final_obs"]``
and the one after the automatic reset), reward, ``terminated``, ``truncated``
and info flag must be identical; floats are compared as bit patterns, so a
``-0.0`` against ``0.0`` or a last-bit difference fails.
"""

from __future__ import annotations

import functools
import os
import zlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import wrl_jax
from wrl_jax.envs.warehouse import routes
from wrl_jax.envs.warehouse.env import Warehouse, draw_item, make_params
from wrl_jax.envs.warehouse.layout import Layout, bfs_distances
from wrl_jax.envs.warehouse.reference import DEFAULT_REWARDS, WarehouseReferenceEnv, make_reference
from wrl_jax.envs.warehouse.types import REWARD_DEFAULTS

ENV_NAMES = ["Warehouse-8x8-v0", "Warehouse-12x12-v0"]
FLAGS = ("collision", "wall_bump", "picked_up", "delivered")


# --------------------------------------------------------------------- JAX side
def _episode_stream(env: Warehouse, params, key, item_index, random_actions, use_oracle):
    """One environment over ``T`` steps of ``env.step`` (auto-reset), starting at ``item_index``.

    The action at step ``t`` is the oracle's when ``use_oracle[t]``, else ``random_actions[t]``;
    the taken actions are returned so that the reference can replay them.
    """
    tables = routes.route_tables(params)
    reset_obs, state = env.reset_to_item(item_index, params)

    def body(state, inputs):
        step_key, random_action, oracle = inputs
        action = jnp.where(oracle, routes.oracle_action(state, params, tables), random_action)
        obs, state, reward, terminated, truncated, info = env.step(step_key, state, action, params)
        out = {
            "action": action,
            "obs": obs,
            "final_obs": info["final_obs"],
            "reward": reward,
            "terminated": terminated,
            "truncated": truncated,
            "next_item": state.item_index,
            **{flag: info[flag] for flag in FLAGS},
        }
        return state, out

    keys = jax.random.split(key, random_actions.shape[0])
    _, stream = jax.lax.scan(body, state, (keys, random_actions, use_oracle))
    return reset_obs, stream


_BATCHED_ROLLOUTS: dict[tuple, object] = {}


def batched_rollout(env: Warehouse):
    """``jit(vmap(...))`` of :func:`_episode_stream` over episodes, one compile per env shape.

    Keyed by the environment's static configuration, not the environment: two environments made with other
    reward constants differ only in their default params (so they are unequal, and a cache keyed by them
    would compile once per configuration), and the rollout reads only the params it is passed (it runs on the
    environment without default params, so reading them would fail loudly).
    """
    key = env.static_config()
    if key not in _BATCHED_ROLLOUTS:
        _BATCHED_ROLLOUTS[key] = jax.jit(jax.vmap(functools.partial(_episode_stream, env.without_default_params()),
                                                  in_axes=(None, 0, 0, 0, 0)))
    return _BATCHED_ROLLOUTS[key]


@functools.lru_cache(maxsize=None)
def single_rollout(env: Warehouse):
    """``jit`` of :func:`_episode_stream` for one episode stream (the hypothesis tests)."""
    return jax.jit(functools.partial(_episode_stream, env))


# --------------------------------------------------------------- reference side
def replay(ref: WarehouseReferenceEnv, item_index: int, actions, next_items) -> tuple[np.ndarray, dict]:
    """Replay ``actions`` in the reference, resetting to ``next_items[t]`` when its episode ends."""
    reset_obs, _ = ref.reset(options={"item_index": int(item_index)})
    rows: dict[str, list] = {name: [] for name in ("obs", "final_obs", "reward", "terminated", "truncated", *FLAGS)}
    for action, next_item in zip(np.asarray(actions).tolist(), np.asarray(next_items).tolist()):
        obs, reward, terminated, truncated, info = ref.step(action)
        rows["final_obs"].append(obs)
        if terminated or truncated:
            obs, _ = ref.reset(options={"item_index": next_item})
        rows["obs"].append(obs)
        rows["reward"].append(reward)
        rows["terminated"].append(terminated)
        rows["truncated"].append(truncated)
        for flag in FLAGS:
            rows[flag].append(info[flag])
    stream = {name: np.array(values) for name, values in rows.items()}
    stream["reward"] = stream["reward"].astype(np.float32)
    return reset_obs, stream


# ------------------------------------------------------------------ comparison
def assert_bitwise_equal(name: str, jax_values, ref_values) -> None:
    """Equal as float32 values *and* as bit patterns; a clear message at the first difference."""
    got = np.asarray(jax_values)
    want = np.asarray(ref_values)
    assert got.shape == want.shape, f"{name}: shape {got.shape} (JAX) vs {want.shape} (reference)"
    if want.dtype == np.float32 or got.dtype == np.float32:
        assert got.dtype == np.float32 and want.dtype == np.float32, f"{name}: dtypes {got.dtype} vs {want.dtype}"
        differ = got.view(np.uint32) != want.view(np.uint32)
        values_equal = np.array_equal(got, want)
    else:
        differ = got.astype(bool) != want.astype(bool)
        values_equal = not differ.any()
    if differ.any():
        where = tuple(int(i) for i in np.argwhere(differ)[0])
        a, b = got[where], want[where]
        bits = f" (bits {a.view(np.uint32):#010x} vs {b.view(np.uint32):#010x})" if got.dtype == np.float32 else ""
        raise AssertionError(
            f"{name} differs at index {where}: JAX {a!r} vs reference {b!r}{bits}; "
            f"{int(differ.sum())} differing entries; values equal ignoring bits: {values_equal}"
        )


def assert_streams_equal(jax_reset_obs, jax_stream: dict, ref_reset_obs, ref_stream: dict, label: str = "") -> None:
    assert_bitwise_equal(f"{label}reset obs", jax_reset_obs, ref_reset_obs)
    for name in ("reward", "final_obs", "obs", "terminated", "truncated", *FLAGS):
        assert_bitwise_equal(f"{label}{name}", jax_stream[name], ref_stream[name])


# ------------------------------------------------------ the registered layouts
CONFIGS = {
    "default": {},
    "no_carrying_flag": {"observe_carrying": False},
    "collision_bug": {"collision_bug": True},
    # Constants not exactly representable in float32, a wall penalty, and a
    # short horizon so that truncations are frequent.
    "odd_constants": {
        "step_penalty": -0.7,
        "obstacle_penalty": -3.3,
        "wall_penalty": -0.3,
        "shaping_coef": 0.3,
        "pickup_reward": 7.1,
        "delivery_reward": 99.9,
        "max_steps": 37,
    },
    "bug_and_no_flag_odd_constants": {
        "observe_carrying": False,
        "collision_bug": True,
        "step_penalty": -0.1,
        "shaping_coef": 1.0 / 3.0,
        "obstacle_penalty": -0.7,
        "wall_penalty": 0.3,
    },
}


@pytest.mark.parametrize("config", sorted(CONFIGS))
@pytest.mark.parametrize("name", ENV_NAMES)
def test_random_episodes_match_reference(name, config):
    overrides = CONFIGS[config]
    env, params = wrl_jax.make(name, **overrides)
    ref = make_reference(name, **overrides)
    episodes, horizon = 16, 320
    rng = np.random.default_rng(zlib.crc32(f"{name}/{config}".encode()))
    # Half of the episodes act at random; the other half follow the oracle 80% of the time,
    # so that pickups and deliveries happen as well as truncations.
    oracle_share = np.where(np.arange(episodes) < episodes // 2, 0.0, 0.8)[:, None]
    use_oracle = rng.random((episodes, horizon)) < oracle_share
    random_actions = rng.integers(0, 4, (episodes, horizon), dtype=np.int32)
    items = rng.integers(0, int(params.num_items), episodes, dtype=np.int32)
    keys = jax.random.split(jax.random.key(int(rng.integers(2**31))), episodes)

    reset_obs, stream = batched_rollout(env)(params, keys, items, random_actions, use_oracle)
    reset_obs, stream = np.asarray(reset_obs), jax.tree.map(np.asarray, stream)

    for e in range(episodes):
        ref_reset, ref_stream = replay(ref, items[e], stream["action"][e], stream["next_item"][e])
        assert_streams_equal(reset_obs[e], {k: v[e] for k, v in stream.items()}, ref_reset, ref_stream,
                             label=f"episode stream {e}: ")

    # The comparison above is only as strong as what the episodes did: make sure they did it all.
    assert stream["collision"].any() and stream["wall_bump"].any(), "no collision or wall bump to compare"
    assert stream["picked_up"].any() and stream["terminated"].any(), "no pickup or delivery to compare"
    assert stream["truncated"].any(), "no truncation to compare"
    assert len(np.unique(stream["next_item"])) > 1, "the automatic resets never changed the item"


@pytest.mark.parametrize("value", [1e-31, -1e-40, 1e-45, 1e39, -1e39, float("inf"), float("nan")])
def test_both_reject_reward_constants_that_break_float32_parity(value):
    """Subnormal-making or non-float32-finite constants: both sides refuse them alike."""
    layout = wrl_jax.parse("S.0\n.#.\n..G")
    with pytest.raises(ValueError, match="pickup_reward"):
        make_params(layout, max_steps=5, pickup_reward=value)
    with pytest.raises(ValueError, match="pickup_reward"):
        WarehouseReferenceEnv(layout, 5, pickup_reward=value)
    # The boundary itself is accepted by both.
    make_params(layout, max_steps=5, pickup_reward=1e-30)
    WarehouseReferenceEnv(layout, 5, pickup_reward=1e-30)


def test_reference_defaults_match_jax_defaults():
    """The reference writes SPEC.md's constants down itself; they must be the JAX env's."""
    assert DEFAULT_REWARDS == REWARD_DEFAULTS
    for name in ENV_NAMES:
        env, params = wrl_jax.make(name)
        ref = make_reference(name)
        assert ref.max_steps == int(params.max_steps)
        assert ref.observation_space.shape == (env.obs_size,)
        for constant in DEFAULT_REWARDS:
            assert getattr(ref, constant) == np.asarray(getattr(params, constant))
        np.testing.assert_array_equal(ref.shelves, params.shelves)
        np.testing.assert_array_equal(np.array(ref.items), params.items)


def test_auto_reset_observation_is_a_reference_reset():
    """On the step that ends an episode, ``obs`` is the reference's reset to the drawn item."""
    env, params = wrl_jax.make("Warehouse-8x8-v0", max_steps=3)
    ref = make_reference("Warehouse-8x8-v0", max_steps=3)
    step = jax.jit(env.step)
    draw = jax.jit(draw_item)  # eagerly, each of the 40 draws would run op by op
    _, state = env.reset_to_item(0, params)
    ref.reset(options={"item_index": 0})
    drawn = set()
    for t in range(3 * 40):
        key = jax.random.key(t)
        obs, state, reward, terminated, truncated, info = step(key, state, t % 4, params)
        ref_obs, ref_reward, ref_terminated, ref_truncated, _ = ref.step(t % 4)
        assert_bitwise_equal("final_obs", info["final_obs"], ref_obs)
        assert_bitwise_equal("reward", reward, ref_reward)
        assert bool(truncated) == ref_truncated == (t % 3 == 2)
        if ref_truncated:
            # The JAX key drew this item; the reference reset to it must give the same observation.
            expected_item = int(draw(key, params))
            assert int(state.item_index) == expected_item
            ref_reset, _ = ref.reset(options={"item_index": expected_item})
            assert_bitwise_equal("auto-reset obs", obs, ref_reset)
            drawn.add(expected_item)
    assert len(drawn) > 3


# ------------------------------------------------------- random valid layouts
SIZES = (2, 3, 5, 8)
ITEM_CAPACITY = 6
HORIZON = 48

# Reward constants: the defaults, values with no exact float32 form, signed
# zeros, the smallest accepted magnitude (1e-30: below it XLA on CPU would flush
# float32 subnormals to zero, so both implementations reject it) and magnitudes
# near float32's maximum, whose sums overflow to the same infinities.
SPECIAL_CONSTANTS = [0.0, -0.0, 0.3, -0.7, 0.1, -0.1, 1.0 / 3.0, -0.5, 2.0, 50.0, 200.0, -10.0, 1e-3, 123.456,
                     1e-30, -1e-30, 1.5e-30, 3e38, -3e38, float(np.finfo(np.float32).max), 3.0e-7]
magnitudes = st.one_of(st.floats(min_value=1e-30, max_value=1e4), st.floats(min_value=1e-30, max_value=3e38))
constants = st.one_of(
    st.sampled_from(SPECIAL_CONSTANTS),
    st.builds(lambda magnitude, negative: -magnitude if negative else magnitude, magnitudes, st.booleans()),
)


@st.composite
def layouts(draw) -> Layout:
    """A random valid layout: start, goal and items on cells reachable from the start."""
    size = draw(st.sampled_from(SIZES))
    shelf_cells = draw(st.lists(st.sampled_from([False, False, False, True]), min_size=size * size,
                                max_size=size * size))
    shelves = np.array(shelf_cells, dtype=bool).reshape(size, size)
    free = [tuple(cell) for cell in np.argwhere(~shelves).tolist()]
    assume(len(free) >= 3)
    start = draw(st.sampled_from(free))
    reachable = bfs_distances(shelves, start) >= 0
    others = [cell for cell in free if reachable[cell] and cell != start]
    assume(len(others) >= 2)
    others = draw(st.permutations(others))
    num_items = draw(st.integers(1, min(ITEM_CAPACITY, len(others) - 1)))
    return Layout(
        shelves=shelves,
        start=np.array(start, dtype=np.int32),
        goal=np.array(others[0], dtype=np.int32),
        items=np.array(others[1 : 1 + num_items], dtype=np.int32),
    )


# WRL_PARITY_EXAMPLES=5000 for a long hunt; the default keeps the file well under a minute.
@settings(max_examples=int(os.environ.get("WRL_PARITY_EXAMPLES", "150")), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    layout=layouts(),
    rewards=st.fixed_dictionaries({name: constants for name in DEFAULT_REWARDS}),
    max_steps=st.integers(1, 30),
    observe_carrying=st.booleans(),
    collision_bug=st.booleans(),
    item_seed=st.integers(0, 2**31 - 1),
    random_actions=st.lists(st.integers(0, 3), min_size=HORIZON, max_size=HORIZON),
    use_oracle=st.lists(st.booleans(), min_size=HORIZON, max_size=HORIZON),
)
def test_random_layouts_match_reference(layout, rewards, max_steps, observe_carrying, collision_bug, item_seed,
                                        random_actions, use_oracle):
    env = Warehouse(layout.size, max_items=ITEM_CAPACITY, observe_carrying=observe_carrying)
    params = make_params(layout, max_steps=max_steps, max_items=ITEM_CAPACITY, collision_bug=collision_bug,
                         **rewards)
    ref = WarehouseReferenceEnv(layout, max_steps, observe_carrying=observe_carrying, collision_bug=collision_bug,
                                **rewards)
    item = item_seed % layout.num_items
    reset_obs, stream = single_rollout(env)(
        params, jax.random.key(item_seed), jnp.int32(item),
        jnp.asarray(random_actions, dtype=jnp.int32), jnp.asarray(use_oracle))
    stream = jax.tree.map(np.asarray, stream)
    ref_reset, ref_stream = replay(ref, item, stream["action"], stream["next_item"])
    assert_streams_equal(reset_obs, stream, ref_reset, ref_stream)
