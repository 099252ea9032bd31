"""The NumPy reference on its own: Gymnasium conformance, SPEC.md invariants, errors, seeding, switches."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from wrl_jax.envs.warehouse.layout import MOVES, Layout, bfs_distances, optimal_route_lengths, parse
from wrl_jax.envs.warehouse.reference import WarehouseReferenceEnv, make_reference
from wrl_jax.envs.warehouse.registration import spec

ENV_NAMES = ["Warehouse-8x8-v0", "Warehouse-12x12-v0"]
UP, DOWN, LEFT, RIGHT = range(4)
SMALL = "S.0\n.#.\n..G"  # start (0,0), shelf (1,1), item 0 at (0,2), goal (2,2)


def small(**kwargs) -> WarehouseReferenceEnv:
    kwargs.setdefault("max_steps", 10)
    return WarehouseReferenceEnv(SMALL, **kwargs)


# ------------------------------------------------------------------ Gymnasium
@pytest.mark.parametrize("switches", [{}, {"observe_carrying": False}, {"collision_bug": True}])
@pytest.mark.parametrize("name", ENV_NAMES)
def test_passes_gymnasium_env_checker(name, switches):
    env = make_reference(name, render_mode="ansi", **switches)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any checker warning fails the test, except:
        # only gymnasium.make-built envs have a spec to try other render modes with.
        warnings.filterwarnings("ignore", message=".*not having a spec.*")
        check_env(env, skip_render_check=False)
    assert env.observation_space.shape == ((6,) if switches.get("observe_carrying") is False else (7,))
    assert env.observation_space.dtype == np.float32 and env.action_space.n == 4


def test_step_returns_gymnasium_types():
    env = small()
    obs, info = env.reset(seed=0)
    assert obs.dtype == np.float32 and obs.shape == (7,) and info == {}
    obs, reward, terminated, truncated, info = env.step(RIGHT)
    assert isinstance(reward, np.float32) and isinstance(terminated, bool) and isinstance(truncated, bool)
    assert set(info) == {"collision", "wall_bump", "picked_up", "delivered"}
    assert all(isinstance(flag, bool) for flag in info.values())


def test_render_ansi_shows_robot_shelf_item_goal():
    env = small(render_mode="ansi")
    env.reset(options={"item_index": 0})
    grid = env.render().splitlines()[1:]
    assert grid == ["R . 0", ". # .", ". . G"]
    env.step(RIGHT)
    env.step(RIGHT)  # picks the item up: it is no longer drawn, the robot turns lowercase
    assert env.render().splitlines()[1:] == [". . r", ". # .", ". . G"]
    assert "carrying" in env.render().splitlines()[0]


# --------------------------------------------------------- SPEC.md invariants
def oracle_action(env: WarehouseReferenceEnv, to_item: np.ndarray, to_goal: np.ndarray) -> int:
    """A move that lowers the BFS distance to the current target by one (lowest action index)."""
    dist = to_goal if env.carrying else to_item
    row, col = env.robot_pos
    for action, (d_row, d_col) in enumerate(MOVES.tolist()):
        nr, nc = row + d_row, col + d_col
        if 0 <= nr < env.size and 0 <= nc < env.size and dist[nr, nc] >= 0 and dist[nr, nc] == dist[row, col] - 1:
            return action
    raise AssertionError(f"no shortest-route move from {env.robot_pos}")


@pytest.mark.parametrize("name", ENV_NAMES)
def test_oracle_delivers_every_item_in_the_bfs_optimum_with_closed_form_return(name):
    env = make_reference(name)
    layout = spec(name).layout
    optimal = optimal_route_lengths(layout)
    to_goal = bfs_distances(layout.shelves, tuple(layout.goal))
    for index, item in enumerate(layout.items):
        to_item = bfs_distances(layout.shelves, tuple(item))
        env.reset(options={"item_index": index})
        episode_return, steps, bumps, terminated, truncated = 0.0, 0, 0, False, False
        while not (terminated or truncated):
            obs, reward, terminated, truncated, info = env.step(oracle_action(env, to_item, to_goal))
            episode_return += float(reward)
            steps += 1
            bumps += info["collision"] + info["wall_bump"]
        assert terminated and not truncated and info["delivered"]
        assert steps == optimal[index] and bumps == 0
        manhattan = np.abs(item - layout.start).sum() + np.abs(layout.goal - item).sum()
        assert episode_return == 250.5 - 0.5 * steps + 2.0 * manhattan
        # The delivered final observation still shows the item carried.
        marker = np.float32(-1.0) / np.float32(layout.size - 1)
        assert obs[6] == 1.0 and obs[4] == obs[5] == marker
        assert obs[0] == obs[1] == 1.0  # on the goal, the bottom-right corner
    if name == "Warehouse-8x8-v0":  # SPEC.md: every item on a 14-step route, return 271.5
        assert (optimal == 14).all() and episode_return == 271.5
    else:
        assert (optimal == 22).all()


def test_transition_rewards_follow_spec():
    env = small()
    obs, _ = env.reset(options={"item_index": 0})
    np.testing.assert_array_equal(obs, np.array([0, 0, 1, 1, 0, 1, 0], dtype=np.float32))
    # A wall bump: stays put, no obstacle penalty, only the step penalty (shaping 0).
    obs, reward, terminated, truncated, info = env.step(UP)
    assert env.robot_pos == (0, 0) and reward == np.float32(-0.5)
    assert info == {"collision": False, "wall_bump": True, "picked_up": False, "delivered": False}
    # Moving away from the item: -0.5 - 2.
    _, reward, _, _, _ = env.step(DOWN)
    assert env.robot_pos == (1, 0) and reward == np.float32(-2.5)
    # Into the shelf at (1,1): stays put, collision, -0.5 - 10, distance unchanged.
    obs, reward, _, _, info = env.step(RIGHT)
    assert env.robot_pos == (1, 0) and info["collision"] and not info["wall_bump"]
    assert reward == np.float32(-10.5) and obs[0] == np.float32(0.5) and obs[1] == 0.0
    env.step(UP)
    env.step(RIGHT)
    obs, reward, _, _, info = env.step(RIGHT)  # pickup: -0.5 + 2 + 50
    assert info["picked_up"] and env.carrying and reward == np.float32(51.5)
    assert obs[4] == obs[5] == np.float32(-0.5) and obs[6] == 1.0
    _, reward, terminated, _, _ = env.step(DOWN)  # target is now the goal: closer by one
    assert reward == np.float32(1.5) and not terminated
    obs, reward, terminated, truncated, info = env.step(DOWN)  # delivery: no step penalty
    assert terminated and not truncated and info["delivered"] and reward == np.float32(202.0)
    assert obs[6] == 1.0
    with pytest.raises(RuntimeError, match="call reset"):
        env.step(UP)


def test_goal_without_item_does_nothing_and_truncation():
    env = WarehouseReferenceEnv("S.G\n.#.\n0..", max_steps=3)
    env.reset(options={"item_index": 0})
    _, _, terminated, truncated, info = env.step(RIGHT)
    _, reward, terminated, truncated, info = env.step(RIGHT)  # onto the goal, not carrying
    assert env.robot_pos == (0, 2) and not terminated and not truncated and not any(info.values())
    assert reward == np.float32(-0.5 - 2.0)  # moved away from the item at (2,0)
    _, reward, terminated, truncated, _ = env.step(UP)  # the third step truncates, penalty included
    assert truncated and not terminated and reward == np.float32(-0.5)


def test_delivery_on_the_last_step_terminates_and_does_not_truncate():
    env = small(max_steps=4)
    env.reset(options={"item_index": 0})
    for action in (RIGHT, RIGHT, DOWN):
        env.step(action)
    _, _, terminated, truncated, _ = env.step(DOWN)
    assert terminated and not truncated


def test_reward_is_float32_sum_in_spec_order():
    # 0.3 and -0.7 have no exact float32 form: the sum must be float32 additions, left to right.
    env = small(step_penalty=-0.7, shaping_coef=0.3)
    env.reset(options={"item_index": 0})
    _, reward, _, _, _ = env.step(RIGHT)
    assert reward == np.float32(np.float32(-0.7) + np.float32(0.3))
    assert reward.view(np.uint32) == (np.float32(-0.7) + np.float32(0.3)).view(np.uint32)


# ---------------------------------------------------------------- the switches
def test_observe_carrying_false_drops_index_6_only():
    full, partial = small(), small(observe_carrying=False)
    obs_full, _ = full.reset(options={"item_index": 0})
    obs_partial, _ = partial.reset(options={"item_index": 0})
    assert obs_partial.shape == (6,) and partial.observation_space.shape == (6,)
    for action in (RIGHT, RIGHT, DOWN):
        obs_full, reward_full, *_ = full.step(action)
        obs_partial, reward_partial, *_ = partial.step(action)
        np.testing.assert_array_equal(obs_partial, obs_full[:6])
        assert reward_full == reward_partial
    assert obs_full[6] == 1.0


def test_collision_bug_puts_the_robot_on_the_shelf():
    env = small(collision_bug=True)
    env.reset(options={"item_index": 0})
    env.step(DOWN)
    obs, reward, _, _, info = env.step(RIGHT)  # into the shelf at (1,1)
    assert info["collision"] and env.robot_pos == (1, 1)
    assert obs[0] == obs[1] == np.float32(0.5)
    assert reward == np.float32(-0.5 - 10.0 + 2.0)  # shaping sees the shelf cell: one closer to (0,2)
    _, _, _, _, info = env.step(UP)  # off the shelf again, an ordinary move
    assert env.robot_pos == (0, 1) and not info["collision"]
    fixed = small()
    fixed.reset(options={"item_index": 0})
    fixed.step(DOWN)
    fixed.step(RIGHT)
    assert fixed.robot_pos == (1, 0)


# ------------------------------------------------------------------- seeding
def test_seeded_item_draws_are_reproducible_and_uniform():
    def draws(seed, count=40):
        env = make_reference("Warehouse-8x8-v0")
        env.reset(seed=seed)
        first = [env.item_index]
        for _ in range(count - 1):
            env.reset()
            first.append(env.item_index)
        return first

    assert draws(7) == draws(7)
    assert draws(7) != draws(8)
    env = make_reference("Warehouse-12x12-v0")
    env.reset(seed=0)

    def draw() -> int:
        env.reset()
        return env.item_index

    counts = np.bincount([draw() for _ in range(6000)], minlength=20)
    expected = 6000 / 20
    assert counts.min() > 0 and ((counts - expected) ** 2 / expected).sum() < 3 * 20 + 60


def test_item_index_option_pins_the_item():
    env = make_reference("Warehouse-12x12-v0")
    layout = spec("Warehouse-12x12-v0").layout
    for index in (0, 7, 19):
        obs, _ = env.reset(seed=123, options={"item_index": index})
        assert env.item_pos == tuple(layout.items[index])
        np.testing.assert_array_equal(obs[4:6], layout.items[index].astype(np.float32) / np.float32(11))
    env.reset(options={"item_index": np.int64(3)})
    assert env.item_index == 3


# -------------------------------------------------------------------- errors
@pytest.mark.parametrize("action", [4, -1, 1.5, 2.0, "up", None, True, np.array([1, 2]), 10**20])
def test_bad_actions_raise(action):
    env = small()
    env.reset(options={"item_index": 0})
    with pytest.raises(ValueError, match="action"):
        env.step(action)
    # The environment is untouched by a rejected action.
    assert env.robot_pos == (0, 0) and env.steps == 0


def test_good_action_types_accepted():
    env = small()
    env.reset(options={"item_index": 0})
    for action in (RIGHT, np.int64(LEFT), np.array(DOWN, dtype=np.int32), np.uint8(UP)):
        env.step(action)
    assert env.steps == 4


@pytest.mark.parametrize("index, message", [(1, "item_index 1 is out of range"), (-1, "out of range"),
                                            (0.0, "must be a single integer"), ("0", "must be a single integer")])
def test_bad_item_index_raises(index, message):
    with pytest.raises(ValueError, match=message):
        small().reset(options={"item_index": index})


def test_other_misuse_raises():
    with pytest.raises(ValueError, match="unknown reset option"):
        small().reset(options={"item": 0})
    with pytest.raises(RuntimeError, match="call reset"):
        small().step(UP)
    for max_steps in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="max_steps must be a positive integer"):
            WarehouseReferenceEnv(SMALL, max_steps=max_steps)
    with pytest.raises(ValueError, match="render_mode"):
        small(render_mode="human")
    with pytest.raises(TypeError, match="layout must be"):
        WarehouseReferenceEnv(np.zeros((3, 3)), max_steps=5)


@pytest.mark.parametrize(
    "ascii_map, message",
    [
        ("S.0\n..\n..G", "ragged map"),
        ("..0\n...\n..G", "no start"),
        ("S.0\n.S.\n..G", "2 of start"),
        ("S.0\n.*.\n..G", r"unknown character '\*' at cell \(1, 1\)"),
        ("S.G\n##.\n0#.", r"item 0 at cell \(2, 0\) is unreachable"),
        ("S#.\n#..\n.0G", r"goal at cell \(2, 2\) is unreachable"),
        ("S..\n...\n..G", "no items"),
    ],
)
def test_bad_maps_raise(ascii_map, message):
    with pytest.raises(ValueError, match=message):
        WarehouseReferenceEnv(ascii_map, max_steps=5)


def test_item_on_a_shelf_raises():
    shelves = np.zeros((3, 3), dtype=bool)
    shelves[1, 1] = True
    with pytest.raises(ValueError, match=r"item 0 at cell \(1, 1\) is on a shelf"):
        Layout(shelves=shelves, start=np.array([0, 0]), goal=np.array([2, 2]), items=np.array([[1, 1]]))


def test_make_reference_mirrors_make():
    env = make_reference("Warehouse-8x8-v0")
    assert env.max_steps == 150 and env.size == 8 and len(env.items) == 10
    assert make_reference("Warehouse-12x12-v0").max_steps == 300
    env = make_reference("Warehouse-8x8-v0", shaping_coef=0.0, pickup_reward=0.3, max_steps=7,
                         collision_bug=True, observe_carrying=False, max_items=12)
    assert env.shaping_coef == 0.0 and env.pickup_reward == np.float32(0.3) and env.max_steps == 7
    assert env.collision_bug and env.observation_space.shape == (6,)
    assert parse(env.layout.to_ascii()).to_ascii() == spec("Warehouse-8x8-v0").layout.to_ascii()
    with pytest.raises(ValueError, match="unknown environment"):
        make_reference("Warehouse-9x9-v0")
    with pytest.raises(ValueError, match="unknown override"):
        make_reference("Warehouse-8x8-v0", shaping=1.0)
    with pytest.raises(ValueError, match="max_items=3 is smaller"):
        make_reference("Warehouse-8x8-v0", max_items=3)
    with pytest.raises(ValueError, match="obstacle_penalty must be finite"):
        make_reference("Warehouse-8x8-v0", obstacle_penalty=float("nan"))
