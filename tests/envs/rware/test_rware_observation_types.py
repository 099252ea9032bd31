"""rware's DICT, IMAGE and IMAGE_DICT observations, step for step against rware 2.0.0 itself.

As the parity tests (``test_rware_parity.py``): rware is reset with a seed and converted
(``env_from_rware`` reads its observation type, layers and direction flag; ``from_rware`` the state),
then both are stepped with the same actions (random, forward-biased and crowding policies), ours
replaying rware's replacement draws. At every step and after every reset the observation must equal
rware's (our arrays against rware's per-agent dicts and tuples, stacked), and so must the rewards,
done and the whole state; the flat form (``info["final_global_state"]``) must equal
``gymnasium.spaces.flatten`` of rware's observations, and the Gymnasium adapter's conversion
(:func:`~wrl_jax.wrappers.rware_gymnasium.agent_observations`) must give rware's very objects: the
same types, key order and values. The configurations cover each type at sensor ranges 1 and 2,
directional on and off, custom layer lists (every layer, with a repeat), 2 and 4 agents, messages,
normalised coordinates, the tiny map and custom ones (square for the transposed layers, where rware
does not fail).

Programs: one step and one observation per configuration (``rware_oracle.STEP``, ``OBSERVE``), one batched
episode per type in the jit-and-vmap test, all compiled at LLVM level 0 (``fast_compile``).

Knobs: ``WRL_RWARE_OBS_STEPS`` (steps per configuration, default 45) and ``WRL_RWARE_OBS_ALL=1``
(every combination of type, range, direction, layers, agent count and messages).
"""

from __future__ import annotations

import itertools
import json
import os
import warnings

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import fast_compile
import rware_oracle as oracle
from rware.warehouse import ImageLayer, ObservationType

import wrl_jax  # also registers wrl_jax/rware-* with Gymnasium
from wrl_jax.envs.rware import from_rware, make_rware
from wrl_jax.envs.rware.convert import observation_settings
from wrl_jax.wrappers.rware_gymnasium import agent_observation_space, agent_observations

STEPS = int(os.environ.get("WRL_RWARE_OBS_STEPS", "45"))
ALL = os.environ.get("WRL_RWARE_OBS_ALL", "") == "1"

SQUARE = """
x.xx.xx.
x.xx.xx.
........
.xx..xx.
.xx..xx.
........
x......x
...gg...
"""
"""8 x 8: rware's transposed layers (agent_direction, agent_load) index inside the grid everywhere."""

WIDE = oracle.CUSTOM_LAYOUT

EVERY_LAYER = ["agent_direction", "agent_load", "shelves", "requests", "agents", "goals", "accessible", "requests"]
TRANSPOSED = ("agent_direction", "agent_load")


def config(kind, agents, sensor_range, *, directional=True, layers=None, msg_bits=0, layout=None,
           normalised=False, reward="INDIVIDUAL", queue=None):
    """rware's ``Warehouse`` keyword arguments (``layout`` None: the tiny map)."""
    kwargs = dict(shelf_columns=3, column_height=8, shelf_rows=1, n_agents=agents, msg_bits=msg_bits,
                  sensor_range=sensor_range, request_queue_size=queue or agents, max_inactivity_steps=None,
                  max_steps=30, reward_type=oracle.RewardType[reward], layout=layout,
                  observation_type=ObservationType[kind.upper()], normalised_coordinates=normalised)
    if kind in ("image", "image_dict"):
        kwargs["image_observation_directional"] = directional
        if layers is not None:
            kwargs["image_observation_layers"] = [ImageLayer[name.upper()] for name in layers]
    return kwargs


CONFIGS = {
    "image-2ag-r1-directional": config("image", 2, 1),
    "image-4ag-r2-flat-every-layer-square-msg": config("image", 4, 2, directional=False, layers=EVERY_LAYER,
                                                       msg_bits=1, layout=SQUARE),
    "image-2ag-r1-directional-transposed-square": config("image", 2, 1, layers=["agent_load", "agent_direction",
                                                                                "goals"], layout=SQUARE),
    "image_dict-4ag-r2-directional-msg": config("image_dict", 4, 2, msg_bits=2, reward="TWO_STAGE"),
    "image_dict-2ag-r1-flat-custom-square": config("image_dict", 2, 1, directional=False,
                                                   layers=["accessible", "agent_direction", "shelves"],
                                                   layout=SQUARE),
    "dict-2ag-r1": config("dict", 2, 1),
    "dict-4ag-r2-msg-normalised": config("dict", 4, 2, msg_bits=2, layout=WIDE, normalised=True, reward="GLOBAL"),
    "dict-4ag-r1-msg3": config("dict", 4, 1, msg_bits=3, queue=2),
}

if ALL:  # every combination, on the square map (every layer defined there)
    for kind, agents, sensor_range, directional, custom, msg_bits in itertools.product(
            ("image", "image_dict", "dict"), (2, 4), (1, 2), (True, False), (False, True), (0, 2)):
        if kind == "dict" and (not directional or custom):
            continue  # DICT has no layers or direction flag
        name = f"all-{kind}-{agents}ag-r{sensor_range}-{'dir' if directional else 'flat'}-" \
               f"{'custom' if custom else 'default'}-msg{msg_bits}"
        CONFIGS[name] = config(kind, agents, sensor_range, directional=directional,
                               layers=EVERY_LAYER if custom else None, msg_bits=msg_bits, layout=SQUARE,
                               normalised=kind == "dict" and agents == 4)


# ------------------------------------------------------------------ rware's observations as our arrays
def stacked(obs, kind):
    """rware's per-agent observations in our layout: a leading agent axis, DICT's sensors stacked on axis 1."""
    if kind == "image":
        return np.stack(obs)
    if kind == "image_dict":
        return {"features": np.stack([o["features"] for o in obs]), "image": np.stack([o["image"] for o in obs])}
    own = {key: np.stack([np.asarray(o["self"][key]) for o in obs]) for key in obs[0]["self"]}
    keys = [key for key, value in obs[0]["sensors"][0].items() if value is not None]  # local_message None: no bits
    sensors = {key: np.stack([np.stack([np.asarray(s[key]) for s in o["sensors"]]) for o in obs]) for key in keys}
    return {"self": own, "sensors": sensors}


def assert_same_arrays(ours, theirs, kind):
    ours = jax.tree.map(np.asarray, ours)
    ours_leaves, theirs_leaves = (dict(jax.tree_util.tree_flatten_with_path(t)[0]) for t in (ours, theirs))
    assert ours_leaves.keys() == theirs_leaves.keys()
    for path, value in ours_leaves.items():
        assert value.dtype == (np.int32 if kind == "dict" else np.float32), path
        np.testing.assert_array_equal(value, theirs_leaves[path], err_msg=jax.tree_util.keystr(path))


def assert_same_objects(ours, theirs, where="obs"):
    """The same Python objects: types, key order (rware's ``None`` values aside), lengths, dtypes, values."""
    if isinstance(theirs, dict):
        assert isinstance(ours, dict), where
        assert list(ours) == [key for key, value in theirs.items() if value is not None], where
        for key in ours:
            assert_same_objects(ours[key], theirs[key], f"{where}[{key!r}]")
    elif isinstance(theirs, (tuple, list)):
        assert type(ours) is type(theirs) and len(ours) == len(theirs), where
        for i, (a, b) in enumerate(zip(ours, theirs)):
            assert_same_objects(a, b, f"{where}[{i}]")
    elif isinstance(theirs, np.ndarray):
        assert isinstance(ours, np.ndarray) and ours.dtype == theirs.dtype and ours.shape == theirs.shape, where
        np.testing.assert_array_equal(ours, theirs, err_msg=where)
    else:
        assert type(ours) is type(theirs) and ours == theirs, (where, ours, theirs)


def flattened(warehouse, obs):
    return np.stack([gym.spaces.flatten(space, o) for space, o in zip(warehouse.observation_space, obs)])


# ------------------------------------------------------------------ parity
TOTALS: dict[str, int] = {}


def run(warehouse, steps, seed):
    """Step rware and ours side by side, comparing everything; the counts seen."""
    kind = observation_settings(warehouse)["observation_type"]
    rng = np.random.default_rng(seed)
    layout = (np.asarray(warehouse.highways, bool), np.asarray(warehouse.goals))
    counts = {"transitions": 0, "resets": 1, "deliveries": 0}

    def compare_reset(obs, env, state, params):
        ours = oracle.OBSERVE(env, state, params)
        assert_same_arrays(ours, stacked(obs, kind), kind)
        assert_same_objects(agent_observations(env, ours), obs)

    # rware runs unpatched: our default tie order is its own.
    obs, _ = warehouse.reset(seed=seed)
    env, state, params = oracle.ours(warehouse)
    compare_reset(obs, env, state, params)
    recorder = oracle.record_draws(warehouse)
    for t in range(steps):
        arrays = oracle.rware_arrays(warehouse)
        policy = oracle.POLICIES[("random", "biased", "crowding", "crowding")[rng.integers(4)]]
        actions = oracle.with_messages(policy(arrays, layout, rng), rng, warehouse.msg_bits)
        recorder.draws.clear()
        obs, rewards, done, _, _ = warehouse.step([a.tolist() if np.ndim(a) else int(a) for a in actions])
        replacements = np.zeros(env.num_goals, np.int32)
        replacements[: len(recorder.draws)] = recorder.draws
        ours, state, reward, terminated, truncated, info = oracle.STEP(
            env, state, np.asarray(actions, np.int32), replacements, params)
        where = f"step {t}"
        assert_same_arrays(ours, stacked(obs, kind), kind)  # right away: rware's dicts alias the messages
        assert_same_objects(agent_observations(env, ours), obs, where)
        np.testing.assert_array_equal(np.asarray(info["final_global_state"]).reshape(len(obs), -1),
                                      flattened(warehouse, obs).astype(np.float32), err_msg=where)
        np.testing.assert_array_equal(np.asarray(reward), np.asarray(rewards, np.float32), err_msg=where)
        assert not bool(terminated) and bool(truncated) == done, where
        theirs, mine = oracle.rware_arrays(warehouse), oracle.state_arrays(state)
        assert [name for name in theirs if not np.array_equal(theirs[name], mine[name])] == [], where
        counts["transitions"] += 1
        counts["deliveries"] += len(recorder.draws)
        if done:
            obs, _ = warehouse.reset()
            state, _ = from_rware(warehouse)
            compare_reset(obs, env, state, params)
            recorder = oracle.record_draws(warehouse)
            counts["resets"] += 1
    return counts


@pytest.mark.filterwarnings("ignore:.*precision lowered by casting:UserWarning")  # rware's normalised Box
@pytest.mark.parametrize("name", list(CONFIGS))
def test_observations_equal_rware_at_every_step(name):
    kwargs = CONFIGS[name]
    warehouse = oracle.Warehouse(**kwargs)
    warehouse.reset(seed=3)
    env, state, params = oracle.ours(warehouse)
    # make_rware with rware's settings (enum members) gives the converter's static configuration.
    ours_kwargs = {("num_agents" if key == "n_agents" else key): value for key, value in kwargs.items()}
    if ours_kwargs["layout"] is not None:
        for unused in ("shelf_columns", "column_height", "shelf_rows"):
            ours_kwargs.pop(unused)
    made, made_params = make_rware(**ours_kwargs)
    assert made.static_config() == env.static_config()
    assert made.without_default_params().with_default_params(params) == made
    assert agent_observation_space(env) == warehouse.observation_space[0]  # Gymnasium's space equality
    assert env.obs_size == gym.spaces.flatdim(warehouse.observation_space[0])
    counts = run(warehouse, STEPS, seed=len(name))
    assert counts["resets"] >= 1 + STEPS // 30  # max_steps 30: reset observations compared after episodes too
    for key, value in counts.items():
        TOTALS[key] = TOTALS.get(key, 0) + value
    TOTALS["agent_steps"] = TOTALS.get("agent_steps", 0) + env.num_agents * counts["transitions"]


def test_agent_direction_and_load_where_rware_fails():
    """rware writes these layers at ``[agent.x, agent.y]`` of its ``(H, W)`` grid: on the tiny map (11 x 10)
    an agent on the bottom row (y = 10) raises ``IndexError``. Ours leaves that agent out of the two layers
    (and keeps every other value): checked against rware's loop with the index guarded."""
    warehouse = oracle.Warehouse(**config("image", 3, 2, directional=False,
                                          layers=["agent_direction", "agent_load", "agents"]))
    warehouse.reset(seed=0)
    placed = [(4, 10, oracle.Direction.LEFT), (5, 9, oracle.Direction.DOWN), (9, 6, oracle.Direction.RIGHT)]
    for agent, (x, y, heading) in zip(warehouse.agents, placed):
        agent.x, agent.y, agent.dir = x, y, heading
    warehouse.agents[1].carrying_shelf = warehouse.shelfs[0]
    warehouse.shelfs[0].x, warehouse.shelfs[0].y = 5, 9
    warehouse._recalc_grid()
    with pytest.raises(IndexError):
        warehouse._make_obs(warehouse.agents[0])
    env, state, params = oracle.ours(warehouse)
    ours = np.asarray(oracle.OBSERVE(env, state, params))
    height, width = warehouse.grid_size
    direction, load = np.zeros((height, width), np.float32), np.zeros((height, width), np.float32)
    for agent in warehouse.agents:
        if agent.x < height and agent.y < width:  # rware's write, minus the agents it fails on
            direction[agent.x, agent.y] = agent.dir.value + 1
            load[agent.x, agent.y] = float(agent.carrying_shelf is not None)
    r = warehouse.sensor_range
    for i, agent in enumerate(warehouse.agents):
        for channel, layer in enumerate((direction, load)):
            window = np.pad(layer, r)[agent.y: agent.y + 2 * r + 1, agent.x: agent.x + 2 * r + 1]
            np.testing.assert_array_equal(ours[i, channel], window)
    assert ours[:, 0].max() == 4 and ours[:, 1].max() == 1  # agent 2's heading and agent 1's load are seen


# ------------------------------------------------------------------ the JAX surface: spaces, jit, vmap
def shapes(space):
    return {key: shapes(sub) for key, sub in space.spaces.items()} if hasattr(space, "spaces") else space.shape


def test_spaces_shapes_and_batches_under_jit_and_vmap():
    for kind, layers in (("image", ["goals", "agent_direction"]), ("image_dict", None), ("dict", None)):
        extra = {} if layers is None else {"image_observation_layers": layers}
        env, params = wrl_jax.make("rware-tiny-2ag-v2", observation_type=kind, msg_bits=2 if kind == "dict" else 0,
                                   sensor_range=2, **extra)
        space = env.observation_space(params)
        action = np.zeros((3, 2, 3) if kind == "dict" else (3, 2), np.int32)

        @fast_compile.jit  # the batched reset and three batched steps: one program per type
        def episode(params, env=env, action=action, space=space):
            _, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(jax.random.key(0), 3), params)

            def step(state, t):
                obs, state, _, _, _, info = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                    jax.random.split(jax.random.key(t + 1), 3), state, action, params)
                # Each single observation in the space, checked here (eagerly, every check compiled its operations).
                return state, (obs, info["final_global_state"], jax.vmap(space.contains)(obs))

            return jax.lax.scan(step, state, jnp.arange(3))[1]

        observations, global_states, contained = jax.tree.map(np.asarray, episode(params))
        assert contained.shape == (3, 3) and contained.all()
        for t in range(3):
            for b in range(3):
                single = jax.tree.map(lambda leaf: leaf[t, b], observations)
                assert jax.tree.map(lambda leaf: leaf.shape, single) == shapes(space)
        info = {"final_global_state": global_states[-1]}
        assert info["final_global_state"].shape == (3, 2 * env.obs_size)
        assert env.onehot_coordinates() is None
        if kind == "image":
            assert space.shape == (2, 2, 5, 5) and float(space.high[0, 1].max()) == 4.0
            assert env.obs_size == 2 * 25
        elif kind == "image_dict":
            assert space.spaces["image"].shape == (2, 5, 5, 5) and space.spaces["features"].shape == (2, 6)
            assert env.obs_size == 6 + 5 * 25
        else:
            sensors = space.spaces["sensors"].spaces
            assert sensors["local_message"].shape == (2, 25, 2) and sensors["direction"].shape == (2, 25)
            assert env.obs_size == 8 + 25 * 9


@pytest.mark.parametrize("call, message", [
    (lambda: make_rware(2, observation_type="pixels"), "observation_type='pixels'"),
    (lambda: make_rware(2, observation_type=7), "observation_type=7"),
    (lambda: wrl_jax.make("rware-tiny-2ag-v2", observation_type="rgb"), "observation_type"),
    (lambda: make_rware(2, observation_type="image", image_observation_layers=["shelfs"]), "image_observation_layers"),
    (lambda: make_rware(2, observation_type="image", image_observation_layers=[]), "image_observation_layers"),
    (lambda: make_rware(2, observation_type="image", image_observation_layers="shelves"), "image_observation_layers"),
    (lambda: make_rware(2, observation_type="image_dict", image_observation_layers=[7]), "image_observation_layers"),
    (lambda: make_rware(2, observation_type="image", image_observation_directional="yes"),
     "image_observation_directional"),
    (lambda: gym.make("wrl_jax/rware-tiny-2ag-v2", observation_type="image", image_observation_layers=[None]),
     "image_observation_layers"),
])
def test_bad_settings_are_clear_value_errors(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_names_enums_and_values_are_accepted():
    env, _ = make_rware(2, observation_type=ObservationType.IMAGE_DICT,
                        image_observation_layers=[ImageLayer.GOALS, 6, "Agent_Load"], image_observation_directional=False)
    assert (env.observation_type, env.image_observation_layers, env.image_observation_directional) == (
        "image_dict", ("goals", "accessible", "agent_load"), False)
    assert make_rware(2, observation_type="image-dict")[0].observation_type == "image_dict"
    assert make_rware(2, observation_type=0)[0].observation_type == "dict"  # rware's ObservationType.DICT value
    flat, _ = make_rware(2, image_observation_layers=[])  # ignored by the other types, as rware ignores it
    assert flat.static_config() == make_rware(2)[0].static_config() and flat.obs_size == 71


# ------------------------------------------------------------------ the Gymnasium adapter against gym.make("rware-...")
def surface(env, steps=3):
    """What code written for rware sees: spaces, the objects' types and shapes, and the env checker's warnings
    (episodes differ, rware's draws being NumPy's: the kinds of a tuple's items are compared as a set)."""

    def kind(value):
        if isinstance(value, dict):
            return ("dict", [(key, kind(v)) for key, v in value.items()])
        if isinstance(value, tuple):  # agents, sensors: which kinds occur (an empty cell's message is a list)
            return ("tuple", len(value), sorted({repr(kind(v)) for v in value}))
        if isinstance(value, list):
            return ("list", [kind(v) for v in value])
        if isinstance(value, np.ndarray):
            return ("ndarray", str(value.dtype), value.shape, value.flags.writeable)
        return type(value).__name__

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = {"spaces": (env.action_space, env.observation_space)}
        obs, _ = env.reset(seed=1)
        out["reset"] = (kind(obs), env.observation_space.contains(obs))
        env.action_space.seed(2)
        for _ in range(steps):
            obs, *_ = env.step(env.action_space.sample())
            out.setdefault("step", kind(obs))
    out["warnings"] = sorted({str(w.message) for w in caught})
    return out


@pytest.mark.filterwarnings("ignore:.*precision lowered by casting:UserWarning")
@pytest.mark.parametrize("kwargs", [
    dict(observation_type=ObservationType.DICT, msg_bits=2, normalised_coordinates=True),
    dict(observation_type=ObservationType.IMAGE_DICT, image_observation_directional=False, sensor_range=2,
         image_observation_layers=[ImageLayer.ACCESSIBLE, ImageLayer.SHELVES, ImageLayer.ACCESSIBLE]),
])
def test_gymnasium_adapter_has_rwares_surface(kwargs):
    theirs = surface(gym.make("rware-tiny-4ag-v2", **kwargs))
    ours = surface(gym.make("wrl_jax/rware-tiny-4ag-v2", **kwargs))
    assert ours == theirs


@pytest.mark.filterwarnings("ignore:.*was expecting a numpy array:UserWarning")  # rware's lists, ours alike
def test_rware_dict_without_messages_fails_gymnasiums_checker_and_ours_does_not():
    """rware's DICT sensors hold ``local_message: None`` without messages, a key its space lacks: Gymnasium's
    env checker stops rware's first reset. The adapter leaves the key out (documented), so it runs."""
    with pytest.raises(AssertionError, match="keys"):
        gym.make("rware-tiny-2ag-v2", observation_type=ObservationType.DICT).reset(seed=0)
    env = gym.make("wrl_jax/rware-tiny-2ag-v2", observation_type=ObservationType.DICT)
    obs, _ = env.reset(seed=0)
    assert "local_message" not in obs[0]["sensors"][0] and env.observation_space.contains(obs)


def test_totals():
    """The compared counts (after the parity runs, in file order); ``WRL_RWARE_OBS_REPORT=path.json`` writes them."""
    if not TOTALS:
        pytest.skip("no parity run in this session")
    if os.environ.get("WRL_RWARE_OBS_REPORT"):
        with open(os.environ["WRL_RWARE_OBS_REPORT"], "w") as report:
            json.dump({"steps_per_config": STEPS, "configs": len(CONFIGS), **TOTALS}, report, indent=1)
    assert TOTALS["transitions"] > 0
