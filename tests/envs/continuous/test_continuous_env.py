"""The JAX continuous warehouse's own contract: clear errors before compiling, the gymnax interface,
the same bits from the same key, and moving obstacles that really move.

The 12x12 map with 4 obstacles runs one compiled program (``drive``: a reset and 50 steps of one action, the
environment without its default params a static argument), with and without randomization.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wrl_jax.envs.continuous.registration import make_continuous
from wrl_jax.envs.procedural import load_map
from wrl_jax.envs.warehouse.maps import WAREHOUSE_8X8, WAREHOUSE_12X12


pytestmark = pytest.mark.usefixtures("geodesic_fields_at_the_commands_level")  # tests/conftest.py


@pytest.fixture(scope="module")
def dynamic():
    return make_continuous(WAREHOUSE_12X12, num_obstacles=4)


@functools.partial(jax.jit, static_argnums=0)
def drive(env, params, key, action):
    """A reset and 50 steps of ``action``: the first observation and state, then each step's observation, reward
    and obstacle positions. Pass ``env.without_default_params()``: one program for every params of the map."""
    obs, state = env.reset(key, params)

    def one(state, k):
        obs, state, reward, *_ = env.step(k, state, action, params)
        return state, (obs, reward, state.obstacle_pos)

    return obs, state, jax.lax.scan(one, state, jax.random.split(key, 50))[1]


def test_the_study_maps_take_the_contract_limits_and_other_layouts_name_theirs():
    assert int(make_continuous(WAREHOUSE_8X8)[1].max_steps) == 300
    assert int(make_continuous(WAREHOUSE_12X12)[1].max_steps) == 500
    custom = WAREHOUSE_8X8.replace("G", ".", 1).replace(".", "G", 1)
    with pytest.raises(ValueError, match="max_steps is needed"):
        make_continuous(custom)


@pytest.mark.parametrize("overrides, message", [
    ({"v_max": 0.0}, "v_max must be positive"),
    ({"robot_radius": 0.6}, "robot_radius 0.6 does not fit a 1 m cell"),
    ({"obstacle_radius": 0.5}, "obstacle_radius 0.5 does not fit a 1 m cell .* below 0.5"),
    ({"collision_penalty": float("nan")}, "collision_penalty must be a finite number"),
    ({"delivery_reward": float("inf")}, "delivery_reward must be a finite number"),
    ({"actuation_noise": -0.1}, "actuation_noise is a standard deviation"),
    ({"lidar_noise": -1e-3}, "lidar_noise is a standard deviation"),
    ({"lidar_dropout": 2.0}, "lidar_dropout is a probability"),
    ({"obstacle_speed": -0.5}, "obstacle_speed must be >= 0"),
    ({"v_max": float("inf")}, "v_max must be a finite number"),
    ({"gain_low": 1.3}, "gain range"),
    ({"lidar_rang": 3.0}, "unknown continuous warehouse setting"),
    ({"num_obstacles": 200}, "fewer than num_obstacles=200"),
    ({"max_steps": 0}, "max_steps must be a positive integer"),
])
def test_bad_settings_are_refused_with_the_setting_named(overrides, message):
    with pytest.raises(ValueError, match=message):
        make_continuous(WAREHOUSE_12X12, **overrides)


def test_actions_of_the_wrong_shape_or_kind_are_refused(dynamic):
    env, params = dynamic
    _, state, _ = drive(env.without_default_params(), params, jax.random.key(0), jnp.zeros(2))  # the shared program
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        env.step(jax.random.key(1), state, jnp.zeros(3), params)
    with pytest.raises(ValueError, match="two floats"):
        env.step(jax.random.key(1), state, np.array(["a", "b"]), params)
    for action, message in ((jnp.zeros((1, 2)), r"shape \(2,\)"), (jnp.zeros((3, 2)), r"shape \(2,\)"),
                            (jnp.zeros(2, bool), "two floats")):
        with pytest.raises(ValueError, match=message):  # under jit too: shapes and dtypes are known when tracing
            jax.jit(env.step).trace(jax.random.key(1), state, action, params)
    assert env.action_space(params).shape == (2,) and env.observation_space(params).shape == (43,)


MAP_ROWS = ["....", ".@@.", "....", "...."]


def test_map_files_and_movingai_layouts_build_the_same_environment_as_their_ascii_map(tmp_path):
    """A MovingAI map (its cells given to ``load_map``), an ASCII map file's path and the ASCII text: one layout."""
    ascii_map = "S . . 0\n. # # .\n. . . 1\n. . . G"
    (tmp_path / "floor.txt").write_text(ascii_map)
    (tmp_path / "floor.map").write_text("type octile\nheight 4\nwidth 4\nmap\n" + "\n".join(MAP_ROWS) + "\n")
    movingai = load_map(tmp_path / "floor.map", start=(0, 0), goal=(3, 3), items=[(0, 3), (2, 3)])
    built = [make_continuous(layout, max_steps=50)[1] for layout in (ascii_map, tmp_path / "floor.txt", movingai)]
    for params in built[1:]:
        for field in ("shelves", "start", "goal", "items", "num_items", "obstacle_cells"):
            np.testing.assert_array_equal(getattr(params, field), getattr(built[0], field), err_msg=field)
    padded = load_map(tmp_path / "floor.map", start=(0, 0), goal=(3, 3), items=[(0, 3), (2, 3)], max_shape=(6, 6))
    np.testing.assert_array_equal(make_continuous(padded, max_steps=50)[1].shelves, built[0].shelves)  # cut to 4x4
    assert make_continuous(str(tmp_path / "floor.txt"), max_steps=50)[1].shelves.shape == (4, 4)  # a path as text
    (tmp_path / "wide.map").write_text("type octile\nheight 2\nwidth 3\nmap\n...\n.@.\n")
    wide = make_continuous(load_map(tmp_path / "wide.map", start=(0, 0), goal=(0, 2), items=[(1, 2)]), max_steps=20)
    np.testing.assert_array_equal(wide[1].shelves, [[0, 0, 0], [0, 1, 0], [1, 1, 1]])  # squared with shelves
    with pytest.raises(ValueError, match="no start, goal and items given"):
        make_continuous(tmp_path / "floor.map", max_steps=50)
    with pytest.raises(ValueError, match="layout is a Layout, an ASCII map"):
        make_continuous(42, max_steps=50)


def test_same_key_same_bits_other_keys_differ_and_obstacles_move(dynamic):
    env, params = dynamic
    action = jnp.array([0.6, 0.3])
    first, again, other = (drive(env.without_default_params(), params, jax.random.key(k), action)[2]
                           for k in (3, 3, 4))
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(again)))
    assert not np.array_equal(first[2], other[2])
    travelled = np.abs(np.diff(first[2], axis=0)).sum()
    assert travelled > 4 * 50 * 0.5 * 0.2 * 0.5  # four obstacles at 0.1 m a step, moving most of the time


def test_registered_names_build_and_dqn_refuses_them_clearly():
    import wrl_jax
    from wrl_jax.agents.dqn import DQN
    from wrl_jax.agents.dqn_config import DQNConfig
    from wrl_jax.agents.ppo import PPO
    from wrl_jax.agents.ppo_config import PPOConfig

    env, params = wrl_jax.make("Continuous-Warehouse-12x12-Dynamic-v0")
    assert (env.num_obstacles, int(params.max_steps), env.name) == (4, 500, "Continuous-Warehouse-12x12-Dynamic-v0")
    assert wrl_jax.make("Continuous-Warehouse-8x8-v0")[0].num_obstacles == 0
    with pytest.raises(ValueError, match="acts in a discrete action space; .* takes continuous actions"):
        DQN(DQNConfig(), env, params)
    with pytest.raises(ValueError, match="obs_encoding='raw' and encoder='mlp'"):  # PPO acts in boxes, with raw inputs
        PPO(PPOConfig(obs_encoding="onehot"), env, params)


def test_the_lidar_reads_closed_squares_at_corners_and_along_grid_lines():
    """A ray along a grid line touches the squares on both sides; one through a corner, all three cells there.
    (Only angle 0 runs exactly along a line in float32: cos(pi/2) and sin(pi) are not 0 there.)"""
    from wrl_jax.envs.continuous.geometry import ray_grid

    ray_grid = jax.jit(ray_grid)  # one program for the four rays (eagerly each call compiles its scan)
    shelves = jnp.zeros((8, 8), bool).at[2, 3].set(True)  # the square x in [3, 4], y in [2, 3]
    along_bottom_edge = ray_grid(jnp.array([0.5, 3.0]), jnp.array([0.0]), shelves)  # y = 3: the shelf's top edge
    along_top_edge = ray_grid(jnp.array([0.5, 2.0]), jnp.array([0.0]), shelves)
    corner = ray_grid(jnp.array([1.0, 0.0 + 1e-7]), jnp.array([np.pi / 4]), jnp.zeros((8, 8), bool).at[1, 2].set(True))
    np.testing.assert_allclose([float(along_bottom_edge[0]), float(along_top_edge[0])], [2.5, 2.5], atol=1e-6)
    np.testing.assert_allclose(float(corner[0]), np.sqrt(2.0), atol=1e-5)  # touches (1, 2)'s corner at (2, 1)
    away = ray_grid(jnp.array([0.5, 3.5]), jnp.array([0.0]), shelves)  # a row clear of the shelf: the wall at 7.5
    np.testing.assert_allclose(float(away[0]), 7.5, atol=1e-6)


def test_randomized_observations_lie_in_the_space():
    """Randomized gains and noise take the applied command past 1: the space says so, every other value stays in [-1, 1]."""
    env, params = make_continuous(WAREHOUSE_12X12, num_obstacles=4, randomize=True)
    space = env.observation_space(params)
    first, _, (observations, _, _) = jax.device_get(drive(env.without_default_params(), params, jax.random.key(5),
                                                          jnp.ones(2)))
    inside = lambda obs: np.all((obs >= space.low) & (obs <= space.high))  # noqa: E731  (NumPy: eagerly ops compile)
    assert inside(first) and inside(observations)
    assert float(np.abs(observations[:, 4:6]).max()) > 1.0  # the gains and noise really pass 1


def obstacle_ranges_numpy(pos, theta, obstacles, num_rays, radius):
    """Float64 distances along the contract's rays to the nearest disc ahead (inf if none): ``|pos + t d - o| = R``."""
    angles = (np.float32(theta) + np.float32(2 * np.pi) * np.arange(num_rays, dtype=np.float32)
              / np.float32(num_rays)).astype(np.float64)  # the contract's float32 angles, then exact geometry
    d = np.stack([np.cos(angles), np.sin(angles)], -1)[:, None, :]  # (L, 1, 2)
    f = (pos - obstacles)[None, :, :]  # (1, M, 2)
    b = (f * d).sum(-1)
    c = (f * f).sum(-1) - radius * radius
    disc = b * b - c
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    return np.where((disc >= 0) & (t >= 0), t, np.inf).min(-1)


def test_observed_obstacles_are_the_rays_to_the_obstacles_alone_and_the_last_contacts():
    """``observe_obstacles``: after the contract's values (and the target's), ``L`` ranges to the moving obstacles
    alone, never nearer than the contract's lidar, and the step's two contact flags (0 after a reset)."""
    env, params = make_continuous(WAREHOUSE_12X12, num_obstacles=4, observe_target=True, observe_obstacles=True)
    rays, tail = env.num_rays, env.num_rays + 2
    assert env.obs_size == 11 + rays + 5 + tail and env.observation_space(params).shape == (env.obs_size,)

    @jax.jit
    def rollout(key):
        obs, state = env.reset(key, params)

        def one(state, k):
            act_key, step_key = jax.random.split(k)
            action = jax.random.uniform(act_key, (2,), minval=-1.0, maxval=1.0) * jnp.array([1.0, 0.3])
            obs, next_state, _, terminated, truncated, info = env.step(step_key, state, action, params)
            return next_state, (obs, next_state.pos, next_state.theta, next_state.obstacle_pos,
                                info["hit_obstacle"], info["hit_shelf"] | info["hit_wall"], terminated | truncated)

        return obs, jax.lax.scan(one, state, jax.random.split(key, 400))[1]

    first, (obs, pos, theta, obstacles, hit_obstacle, hit_other, done) = jax.tree.map(
        np.asarray, rollout(jax.random.key(11)))
    np.testing.assert_array_equal(first[-2:], 0.0)
    assert not done.any()  # no reset inside: every observation is the state's
    assert hit_obstacle.sum() > 0 and hit_other.sum() > 0  # both flags were exercised
    np.testing.assert_array_equal(obs[:, -2], hit_obstacle.astype(np.float32))
    np.testing.assert_array_equal(obs[:, -1], hit_other.astype(np.float32))
    lidar_range = float(params.lidar_range)
    for t in range(len(obs)):
        expected = np.minimum(obstacle_ranges_numpy(pos[t].astype(np.float64), float(theta[t]),
                                                    obstacles[t].astype(np.float64), rays,
                                                    float(params.obstacle_radius)), lidar_range) / lidar_range
        np.testing.assert_allclose(obs[t, -tail:-2], expected, atol=1e-4 / lidar_range)
    contract = obs[:, 11:11 + rays]
    assert (obs[:, -tail:-2] >= contract - 1e-6).all()  # shelves may be nearer; obstacles never hide behind them
    assert (np.isclose(obs[:, -tail:-2], contract, atol=1e-6) & (contract < 1)).any()  # an obstacle is the nearest


def test_an_episodes_last_contacts_stay_in_final_obs_and_the_route_stays_last():
    """Driving straight ahead until the limit (into a shelf, a wall or an obstacle, whichever comes first): the
    truncating step's observation (``final_obs``) holds its contact flags, the next episode's first observation none;
    with the target and the route too, the route's 3 values come last and every observation lies in the space."""
    from wrl_jax.envs.continuous.geodesic import route_features

    env, params = make_continuous(WAREHOUSE_12X12, num_obstacles=4, max_steps=70, shaping="geodesic",
                                  observe_target=True, observe_obstacles=True, observe_route=True)
    assert env.obs_size == 11 + 32 + 5 + 32 + 2 + 3
    space = env.observation_space(params)

    @jax.jit
    def rollout(key):  # with the route read back from each final observation and the space's check
        _, state = env.reset(key, params)

        def one(state, k):
            obs, state, _, _, truncated, info = env.step(k, state, jnp.array([1.0, 0.0]), params)
            flags = jnp.stack([info["hit_obstacle"], info["hit_shelf"] | info["hit_wall"]]).astype(jnp.float32)
            return state, (obs, info["final_obs"], truncated, flags)

        obs, final_obs, truncated, flags = jax.lax.scan(one, state, jax.random.split(key, 70))[1]
        route = jax.vmap(lambda o: route_features(o, params, env.width, env.height))(final_obs)
        return obs, final_obs, truncated, flags, route, jax.vmap(space.contains)(final_obs)

    obs, final_obs, truncated, flags, route, inside = jax.device_get(rollout(jax.random.key(2)))
    assert truncated[-1] and flags[-1].any()  # 70 steps of 0.2 m cross any 12 m map: the last one pushes
    np.testing.assert_array_equal(final_obs[:, -5:-3], flags)  # the two flags, before the route's 3 values
    np.testing.assert_array_equal(obs[-1, -5:-3], 0.0)
    np.testing.assert_array_equal(final_obs[:-1], obs[:-1])
    np.testing.assert_allclose(final_obs[:, -3:], route, atol=1e-4)  # a difference of field reads: not bits
    assert inside.all() and float(space.low[-5]) == 0.0
