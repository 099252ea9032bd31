"""The JAX fleet (FLEET_SPEC.md): layouts and their errors, the conflict rule case by case, rewards,
observations, auto-reset, invariants on long vmapped rollouts, determinism, registry and spaces."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import fast_compile

import wrl_jax.envs  # noqa: F401  (registers the built-in names)
from wrl_jax.core import random as core_random
from wrl_jax.core import registry
from wrl_jax.core.grid import MOVES_WITH_WAIT, UNREACHABLE
from wrl_jax.core.observation import observation_size
from wrl_jax.envs.fleet import conflicts as fleet_conflicts
from wrl_jax.envs.fleet import dynamics, maps
from wrl_jax.envs.fleet.dynamics import draw_tasks, targets
from wrl_jax.envs.fleet.layout import parse_fleet
from wrl_jax.envs.fleet.reference import REWARD_NAMES, FleetReference, RefState
from wrl_jax.envs.fleet.registration import make_fleet
from wrl_jax.envs.fleet.types import FleetState, FleetTasks

# Jitted once per shape: eager dispatch would compile every primitive separately.
fleet_transition = jax.jit(dynamics.fleet_transition)
resolve_conflicts = jax.jit(fleet_conflicts.resolve_conflicts)


# ----------------------------------------------------------------- layouts
def test_parse_fleet_12x12():
    layout = parse_fleet(maps.FLEET_12X12)
    assert (layout.size, layout.num_starts, layout.num_items, layout.num_stations) == (12, 8, 20, 1)
    assert layout.starts[:5].tolist() == [[0, 0], [0, 1], [0, 2], [0, 3], [1, 0]]  # row-major
    assert layout.items[0].tolist() == [0, 4] and layout.items[10].tolist() == [6, 1]  # '0', 'a'
    assert parse_fleet(layout.to_ascii()).to_ascii() == layout.to_ascii()


def test_fleet_32x32_map():
    layout = parse_fleet(maps.FLEET_32X32)
    assert layout.size == 32 and layout.num_starts >= 64 and layout.num_stations >= 4 and layout.num_items >= 32
    shelves = layout.shelves
    for row, col in layout.items:  # every pick station faces a shelf
        neighbours = [(row + dr, col + dc) for dr, dc in MOVES_WITH_WAIT[:4]]
        assert any(0 <= r < 32 and 0 <= c < 32 and shelves[r, c] for r, c in neighbours), (row, col)


@pytest.mark.parametrize("ascii_map, message", [
    ("", "empty map"),
    ("S . 0\n. . G", "ragged|square"),
    ("S . 0\n. .\n. . G", "ragged map: row 1"),
    ("S . 0\n. * .\n. . G", r"unknown character '\*' at cell \(1, 1\)"),
    (". . 0\n. . .\n. . G", "no start"),
    ("S . 0\n. . .\n. . .", "no delivery station"),
    ("S . .\n. . .\n. . G", "no item"),
    ("S 0 0\n. . .\n. . G", r"'0' appears twice: at \(0, 1\) and at \(0, 2\)"),
    ("S 0 2\n. . .\n. . G", "'1' is missing"),
    ("S . #\n. . #\nG # 0", r"item '0' at cell \(2, 2\) is unreachable from start 0 at cell \(0, 0\)"),
    ("S . 0\n# # .\nS # G", r"station 0 at cell \(2, 2\) is unreachable from start 1 at cell \(2, 0\)"),
])
def test_layout_errors_name_the_problem(ascii_map, message):
    with pytest.raises(ValueError, match=message):
        parse_fleet(ascii_map)


def test_make_errors():
    with pytest.raises(ValueError, match="only 8 start cells"):
        registry.make("Fleet-12x12-v0", num_robots=9)
    with pytest.raises(ValueError, match="positive integer"):
        registry.make("Fleet-12x12-v0", num_robots=0)
    with pytest.raises(ValueError, match="unknown fleet override"):
        registry.make("Fleet-12x12-v0", shaping_coeff=1.0)
    with pytest.raises(ValueError, match="shaping must be one of"):
        registry.make("Fleet-12x12-v0", shaping="euclid")
    with pytest.raises(ValueError, match="max_steps"):
        registry.make("Fleet-12x12-v0", max_steps=0)
    with pytest.raises(ValueError, match="view_radius"):
        registry.make("Fleet-12x12-v0", view_radius=-1)
    with pytest.raises(ValueError, match="pickup_reward must be a finite number"):
        registry.make("Fleet-12x12-v0", pickup_reward=float("nan"))
    with pytest.raises(ValueError, match="max_items=2 is smaller"):
        registry.make("Fleet-12x12-v0", max_items=2)


def test_registry_and_spaces():
    env, params = registry.make("Fleet-12x12-v0", num_robots=3)
    assert env.default_params is params and env.num_robots == 3 and int(params.max_steps) == 256
    assert env.num_actions == 5 and env.name == "Fleet-12x12-v0"
    assert env.action_space().n == 5
    assert env.observation_space().shape == (3, observation_size(2)) == (3, 80)
    joint = env.multi_action_space()
    sample = joint.sample(jax.random.key(0))
    assert sample.shape == (3,) and bool(joint.contains(sample)) and not bool(joint.contains(jnp.array([0, 5, 1])))
    big, big_params = registry.make("Fleet-32x32-v0", num_robots=64)
    assert big.num_robots == 64 and int(big_params.max_steps) == 512
    assert big_params.item_dist.shape == (40, 32, 32) and big_params.station_dist.shape == (8, 32, 32)
    # Equal configuration, equal (and equally hashed) env; another robot count, another env.
    again, _ = registry.make("Fleet-12x12-v0", num_robots=3)
    other, _ = registry.make("Fleet-12x12-v0", num_robots=4)
    assert again == env and hash(again) == hash(env) and other != env
    import gymnax

    gym_env, gym_params = gymnax.make("wrl_jax/Fleet-12x12-v0", num_robots=2)
    assert gym_env.num_robots == 2 and gym_env.default_params is gym_params


def test_action_errors():
    env, params = make_fleet(maps.FLEET_12X12, 2)
    _, state = jax.jit(env.reset)(jax.random.key(0))
    for bad, message in [(jnp.zeros(3, jnp.int32), r"shape \(2,\)"), (jnp.zeros(2, jnp.float32), "integers"),
                         (jnp.array([0, 5]), "action 5 of robot 1"), (np.array([-1, 0]), "action -1 of robot 0")]:
        with pytest.raises(ValueError, match=message):
            env.step(jax.random.key(0), state, bad)


# ----------------------------------------------------------------- the conflict rule, case by case
def resolve_both(pos, proposal):
    """JAX and reference resolution of one step 3; they must agree. Returns (next positions, blocked)."""
    pos, proposal = np.array(pos, np.int32), np.array(proposal, np.int32)
    next_pos, blocked = jax.device_get(resolve_conflicts(jnp.asarray(pos), jnp.asarray(proposal)))
    ref = FleetReference(np.zeros((6, 6), bool), pos, [[5, 5]], [[5, 4]], max_steps=9,
                         rewards=dict.fromkeys(REWARD_NAMES, 0.0))
    movers, ref_blocked = ref.resolve([tuple(p) for p in pos.tolist()], [tuple(q) for q in proposal.tolist()])
    ref_next = [proposal[i] if i in movers else pos[i] for i in range(len(pos))]
    np.testing.assert_array_equal(next_pos, np.array(ref_next))
    np.testing.assert_array_equal(blocked, np.array(ref_blocked))
    assert len({tuple(p) for p in next_pos.tolist()}) == len(pos), "two robots share a cell"
    return next_pos.tolist(), blocked.tolist()


def test_same_cell_lowest_index_wins():
    nxt, blocked = resolve_both([[0, 0], [0, 2], [1, 1]], [[0, 1], [0, 1], [0, 1]])
    assert nxt == [[0, 1], [0, 2], [1, 1]] and blocked == [False, True, True]


def test_mover_into_a_stayer_is_blocked():
    nxt, blocked = resolve_both([[0, 0], [0, 1]], [[0, 1], [0, 1]])
    assert nxt == [[0, 0], [0, 1]] and blocked == [True, False]


def test_swap_is_refused():
    nxt, blocked = resolve_both([[0, 0], [0, 1], [3, 3]], [[0, 1], [0, 0], [3, 4]])
    assert nxt == [[0, 0], [0, 1], [3, 4]] and blocked == [True, True, False]


def test_following_is_allowed():
    nxt, blocked = resolve_both([[0, 0], [0, 1], [0, 2]], [[0, 1], [0, 2], [0, 3]])
    assert nxt == [[0, 1], [0, 2], [0, 3]] and blocked == [False] * 3


def test_a_blocked_head_stops_the_chain_over_rounds():
    # Robot 3 stays on (0, 3): 2 is blocked in round 1, 1 in round 2, 0 in round 3.
    nxt, blocked = resolve_both([[0, 0], [0, 1], [0, 2], [0, 3]], [[0, 1], [0, 2], [0, 3], [0, 3]])
    assert nxt == [[0, 0], [0, 1], [0, 2], [0, 3]] and blocked == [True, True, True, False]


def test_rotation_of_four_is_allowed():
    pos = [[0, 0], [0, 1], [1, 1], [1, 0]]
    nxt, blocked = resolve_both(pos, [[0, 1], [1, 1], [1, 0], [0, 0]])
    assert nxt == [[0, 1], [1, 1], [1, 0], [0, 0]] and blocked == [False] * 4


def test_an_intruder_with_a_lower_index_breaks_the_rotation():
    # Robot 0 (outside) and robot 4 (in the cycle) both enter (0, 1); 0 has the lower index, so 4 is
    # blocked, the cycle behind it stops round by round, and 0 finally finds (0, 1) still occupied.
    pos = [[0, 2], [0, 1], [1, 1], [1, 0], [0, 0]]
    nxt, blocked = resolve_both(pos, [[0, 1], [1, 1], [1, 0], [0, 0], [0, 1]])
    assert nxt == pos and blocked == [True] * 5


def test_contested_cell_loser_stays_blocked_even_if_the_winner_is_refused():
    # 0 and 2 both enter (0, 1), whose robot 1 swaps with 0: the swap refuses 0 and 1, and 2 lost the
    # cell to 0 in the same round (the rule removes all blocked movers of a round at once).
    nxt, blocked = resolve_both([[0, 0], [0, 1], [0, 2]], [[0, 1], [0, 0], [0, 1]])
    assert nxt == [[0, 0], [0, 1], [0, 2]] and blocked == [True, True, True]


@pytest.mark.parametrize(("pos", "proposal", "expected"), [
    ([[0, 0], [0, 2], [1, 1]], [[0, 1], [0, 1], [0, 1]], [None, 2, 2]),  # the lowest index wins the cell
    ([[0, 0], [0, 1]], [[0, 1], [0, 1]], [1, None]),  # into a robot that stays
    ([[0, 0], [0, 1], [3, 3]], [[0, 1], [0, 0], [3, 4]], [0, 0, None]),  # a refused swap
    ([[0, 0], [0, 1], [0, 2], [0, 3]], [[0, 1], [0, 2], [0, 3], [0, 3]], [3, 3, 1, None]),  # a chain behind
    ([[0, 0], [0, 1], [0, 2]], [[0, 1], [0, 0], [0, 1]], [0, 0, 2]),  # swap, and the cell's loser
])
def test_block_causes_name_the_first_reason_of_each_block(pos, proposal, expected):
    from wrl_jax.envs.fleet.metrics import BLOCK_CAUSES, block_causes

    _, blocked = resolve_both(pos, proposal)
    # One program per robot count (eagerly, each operation compiles on its own); integer logic: LLVM level 0.
    causes = np.asarray(fast_compile.jit(block_causes)(np.asarray(pos), np.asarray(proposal), np.asarray(blocked)))
    assert causes.shape == (len(pos), len(BLOCK_CAUSES)) and (causes.sum(axis=1) == np.asarray(blocked)).all()
    assert [int(np.argmax(row)) if row.any() else None for row in causes] == expected


# ----------------------------------------------------------------- rewards, tasks, observations
TINY = """
S . 0
S # .
G . 1
"""


def tiny_state(pos, item, station, carrying):
    return FleetState(pos=jnp.array(pos, jnp.int32), item=jnp.array(item, jnp.int32),
                      station=jnp.array(station, jnp.int32), carrying=jnp.array(carrying), time=jnp.int32(0))


def test_flags_rewards_and_reassignment():
    env, params = make_fleet(TINY, 2, max_steps=10)
    # Robot 0 at (0, 1) steps right onto its item 0 (0, 2); robot 1 carrying, at (2, 1), steps left onto G.
    state = tiny_state([[0, 1], [2, 1]], [0, 1], [0, 0], [False, True])
    tasks = FleetTasks(item=jnp.array([1, 0], jnp.int32), station=jnp.array([0, 0], jnp.int32))
    nxt, reward, truncated, flags = fleet_transition(state, jnp.array([3, 2]), tasks, params)
    assert flags["picked_up"].tolist() == [True, False] and flags["delivered"].tolist() == [False, True]
    assert reward.tolist() == [-0.5 + 2.0 + 50.0, -0.5 + 2.0 + 200.0]
    assert nxt.carrying.tolist() == [True, False] and nxt.item.tolist() == [0, 0]  # robot 1 took its new task
    assert not bool(truncated) and int(nxt.time) == 1
    # Shelf, wall, block: robot 0 at (0, 1) down into the shelf, robot 1 at (0, 0) up off the grid; then
    # robot 1 at (1, 0) up into robot 0 at (0, 0) who waits.
    state = tiny_state([[0, 1], [0, 0]], [0, 0], [0, 0], [False, False])
    _, reward, _, flags = fleet_transition(state, jnp.array([1, 0]), tasks, params)
    assert flags["shelf_hit"].tolist() == [True, False] and flags["wall_bump"].tolist() == [False, True]
    assert reward.tolist() == [-10.5, -0.5]
    state = tiny_state([[0, 0], [1, 0]], [0, 0], [0, 0], [False, False])
    _, reward, _, flags = fleet_transition(state, jnp.array([4, 0]), tasks, params)
    assert flags["robot_block"].tolist() == [False, True] and flags["waited"].tolist() == [True, False]
    assert reward.tolist() == [-0.5, -1.5]


def test_bfs_and_manhattan_shaping_differ_around_a_shelf():
    # From (0, 0), item 0 at (2, 0) lies 8 steps away around the shelf row, 2 by Manhattan. A step right
    # shortens the true path (8 -> 7) and lengthens the Manhattan distance (2 -> 3).
    u_map = "S . . .\n# # # .\n0 . . .\n. . . G"
    for shaping, expected in (("bfs", -0.5 + 2.0 * (8 - 7)), ("manhattan", -0.5 + 2.0 * (2 - 3))):
        _, params = make_fleet(u_map, 1, shaping=shaping)
        state = tiny_state([[0, 0]], [0], [0], [False])
        tasks = FleetTasks(jnp.array([0]), jnp.array([0]))
        _, reward, _, _ = fleet_transition(state, jnp.array([3]), tasks, params)
        assert reward.tolist() == [expected], shaping


def test_observation_by_hand():
    env, params = make_fleet(TINY, 2, view_radius=1)
    obs, state = jax.jit(env.reset)(jax.random.key(3))
    obs = np.asarray(obs)
    assert obs.shape == (2, 5 + 27) and obs.dtype == np.float32
    target = np.asarray(targets(state, params))
    np.testing.assert_array_equal(obs[0, :5], [0.0, 0.0, target[0, 0] / 2, target[0, 1] / 2, 0.0])
    window = obs[0, 5:].reshape(3, 3, 3)
    np.testing.assert_array_equal(window[0], [[1, 1, 1], [1, 0, 0], [1, 0, 1]])  # off-grid and the shelf (1, 1)
    np.testing.assert_array_equal(window[1], [[0, 0, 0], [0, 0, 0], [0, 1, 0]])  # robot 1 at (1, 0)
    assert window[2].sum() == 0.0  # both items lie outside robot 0's window


@functools.partial(jax.jit, static_argnums=0)
def feature_rollout(env, params):
    """64 steps of 4 robots under random actions, from the same keys for every env (the observation-feature tests
    compare an env with a feature against the plain one, whose rollout they share): per step the observation,
    ``final_obs``, positions, actions, blocks, rewards and truncation."""

    def step(state, key):
        action = jax.random.randint(key, (4,), 0, 5)
        obs, state, reward, _, truncated, info = env.step(key, state, action, params)
        return state, (obs, info["final_obs"], state.pos, action, info["robot_block"], reward, truncated)

    _, state = env.reset(jax.random.key(4), params)
    return jax.lax.scan(step, state, jax.random.split(jax.random.key(5), 64))[1]


@functools.partial(jax.jit, static_argnums=0)
def reset_and_observe(env, params):
    """A reset (:func:`feature_rollout`'s key) and ``get_obs`` of its state, in one program (eagerly, each of their
    operations would compile on its own)."""
    obs, state = env.reset(jax.random.key(4), params)
    return obs, state, env.get_obs(state, params)


def test_priority_channel_shows_the_robots_with_a_lower_index():
    """``observe_priority``: FLEET_SPEC's observation unchanged, then a channel of the lower-index robots in view,
    on the vmapped step (compact masks, auto-reset included) and on ``get_obs``; it changes nothing else."""
    plain_env, params = make_fleet(maps.FLEET_12X12, 4, max_steps=20)
    env, _ = make_fleet(maps.FLEET_12X12, 4, max_steps=20, observe_priority=True)
    assert env.obs_size == plain_env.obs_size + 25 and env.static_config() != plain_env.static_config()
    assert env.observation_space(params).shape == (4, env.obs_size)

    obs, final_obs, pos, _, _, reward, truncated = jax.device_get(feature_rollout(env, params))
    plain = jax.device_get(feature_rollout(plain_env, params))
    np.testing.assert_array_equal(obs[..., :plain_env.obs_size], plain[0])
    np.testing.assert_array_equal(final_obs[..., :plain_env.obs_size], plain[1])
    np.testing.assert_array_equal(reward, plain[5])
    assert truncated.sum() == 3  # auto-resets happened in the rollout
    priority = obs[..., plain_env.obs_size:].reshape(64, 4, 5, 5)
    expected = np.zeros_like(priority)
    for t in range(64):
        for i in range(4):
            for j in range(i):  # the robots that win a cell both enter
                d_row, d_col = pos[t, j] - pos[t, i]
                if abs(d_row) <= 2 and abs(d_col) <= 2:
                    expected[t, i, d_row + 2, d_col + 2] = 1
    np.testing.assert_array_equal(priority, expected)
    assert expected.sum() > 20 and not priority[:, 0].any()
    robots = obs[..., 5 + 25:5 + 50].reshape(64, 4, 5, 5)
    assert (robots >= priority).all() and (robots > priority).any()  # a subset of the robot channel
    first_obs, _, observed = reset_and_observe(env, params)
    np.testing.assert_array_equal(np.asarray(observed), np.asarray(first_obs))
    with pytest.raises(ValueError, match="observe_priority needs the bit-mask window"):
        make_fleet(maps.FLEET_12X12, 4, view_radius=3, observe_priority=True)


def test_last_action_memory_is_the_previous_action_and_its_block():
    """``observe_last_action``: FLEET_SPEC's observation unchanged, then the previous action one-hot and whether
    it was blocked, on the vmapped step (auto-reset: zeros again), ``final_obs``, ``transition`` and ``get_obs``."""
    plain_env, params = make_fleet(maps.FLEET_12X12, 4, max_steps=20)
    env, _ = make_fleet(maps.FLEET_12X12, 4, max_steps=20, observe_last_action=True)
    assert env.obs_size == plain_env.obs_size + 6 and env.static_config() != plain_env.static_config()
    assert "last_action" in env.state_space(params).spaces and "observe_last_action=True" in repr(env)

    obs, final_obs, _, action, blocked, reward, truncated = jax.device_get(feature_rollout(env, params))
    plain = jax.device_get(feature_rollout(plain_env, params))
    np.testing.assert_array_equal(obs[..., :plain_env.obs_size], plain[0])
    np.testing.assert_array_equal(final_obs[..., :plain_env.obs_size], plain[1])
    np.testing.assert_array_equal(reward, plain[5])
    expected_final = np.concatenate([np.eye(5, dtype=np.float32)[action], blocked[..., None]], axis=-1)
    np.testing.assert_array_equal(final_obs[..., plain_env.obs_size:], expected_final)
    expected = np.where(truncated[:, None, None], 0.0, expected_final)  # a new shift remembers nothing
    np.testing.assert_array_equal(obs[..., plain_env.obs_size:], expected)
    assert truncated.sum() == 3 and blocked.sum() > 0  # auto-resets and blocks happened in the rollout
    first_obs, first_state, observed = reset_and_observe(env, params)
    assert not np.asarray(first_obs)[:, plain_env.obs_size:].any()
    np.testing.assert_array_equal(np.asarray(observed), np.asarray(first_obs))
    move = jnp.array([3, 7, 0, 4], jnp.int32)  # 7 is outside 0..4: inside jit it waits, and is remembered as a wait
    obs, state, *_ = jax.jit(env.transition)(jax.random.key(6), first_state, move, params)
    np.testing.assert_array_equal(np.asarray(state.last_action), [3, 4, 0, 4])
    np.testing.assert_array_equal(np.asarray(obs)[:, plain_env.obs_size:plain_env.obs_size + 5],
                                  np.eye(5)[[3, 4, 0, 4]])


def test_heading_channel_shows_where_the_others_would_go_by_repeating_their_last_action():
    """``observe_headings``: after the plain window channels, a channel of each other robot's cell plus its
    previous move (its own cell after a wait or at the start of a shift), on the vmapped step with auto-resets."""
    plain_env, params = make_fleet(maps.FLEET_12X12, 4, max_steps=20)
    env, _ = make_fleet(maps.FLEET_12X12, 4, max_steps=20, observe_headings=True)
    assert env.obs_size == plain_env.obs_size + 25 and "observe_headings=True" in repr(env)

    obs, _, pos, action, _, reward, truncated = jax.device_get(feature_rollout(env, params))
    plain = jax.device_get(feature_rollout(plain_env, params))
    np.testing.assert_array_equal(obs[..., :plain_env.obs_size], plain[0])
    np.testing.assert_array_equal(reward, plain[5])
    headings = obs[..., plain_env.obs_size:].reshape(64, 4, 5, 5)
    expected = np.zeros_like(headings)
    for t in range(64):
        move = np.zeros((4, 2), int) if truncated[t] else MOVES_WITH_WAIT[action[t]]  # a new shift: no last move
        for i in range(4):
            for j in range(4):
                d_row, d_col = pos[t, j] + move[j] - pos[t, i]
                if j != i and abs(d_row) <= 2 and abs(d_col) <= 2:
                    expected[t, i, d_row + 2, d_col + 2] = 1
    np.testing.assert_array_equal(headings, expected)
    robots = obs[..., 5 + 25:5 + 50].reshape(64, 4, 5, 5)
    assert expected.sum() > 20 and (headings != robots).any() and truncated.sum() == 3
    with pytest.raises(ValueError, match="observe_headings needs the bit-mask window"):
        make_fleet(maps.FLEET_12X12, 4, view_radius=3, observe_headings=True)


def test_global_state_layout():
    env, params = make_fleet(maps.FLEET_12X12, 4)
    obs, state = jax.jit(env.reset)(jax.random.key(1))
    g = np.asarray(jax.jit(env.global_state)(state))
    n = 12
    assert g.shape == (env.global_state_size(),) == (4 * n * n + 5 * 4 + 1,)
    planes = g[: 4 * n * n].reshape(4, n, n)
    np.testing.assert_array_equal(planes[0], np.asarray(params.shelves, np.float32))
    assert planes[1].sum() == 4 and planes[1][0, :4].tolist() == [1, 1, 1, 1] and planes[3].sum() == 0
    np.testing.assert_array_equal(g[4 * n * n: -1].reshape(4, 5), np.asarray(obs)[:, :5])
    assert g[-1] == 0.0


# ----------------------------------------------------------------- rollouts
def noisy_greedy(key, state, params):
    """Greedy along the BFS tables with 20 % uniform random actions: traffic that delivers and collides."""
    size = params.shelves.shape[0]
    cells = jnp.clip(state.pos[:, None, :] + jnp.asarray(MOVES_WITH_WAIT)[None, :4], 0, size - 1)
    table = jnp.where(state.carrying[:, None, None], params.station_dist[state.station], params.item_dist[state.item])
    dist = jax.vmap(lambda t, c: t[c[:, 0], c[:, 1]])(table, cells)
    greedy = jnp.argmin(dist, axis=1).astype(jnp.int32)
    key_coin, key_action = jax.random.split(key)
    random = jax.random.randint(key_action, greedy.shape, 0, 5, dtype=jnp.int32)
    return jnp.where(jax.random.uniform(key_coin, greedy.shape) < 0.2, random, greedy)


@functools.partial(jax.jit, static_argnums=(0, 3, 4))
def vmapped_rollout(env, params, key, num_envs, num_steps):
    """``num_envs`` shifts in one program: per-step event sums and every env's final state.

    Events, summed over envs and steps: collisions (pairs of robots sharing a cell), robots on
    shelves, deliveries, truncations.
    """

    def one_env(key):
        key_reset, key_run = jax.random.split(key)
        _, state = env.reset(key_reset, params)

        def body(state, key):
            key_policy, key_env = jax.random.split(key)
            action = noisy_greedy(key_policy, state, params)
            _, state, reward, _, truncated, info = env.step(key_env, state, action, params)
            same = jnp.all(state.pos[:, None] == state.pos[None, :], axis=-1)
            collisions = (same.sum() - env.num_robots) // 2
            on_shelf = params.shelves[state.pos[:, 0], state.pos[:, 1]].sum()
            return state, jnp.stack([collisions, on_shelf, info["delivered"].sum(), truncated.astype(jnp.int32)])

        final, events = jax.lax.scan(body, state, jax.random.split(key_run, num_steps))
        return events.sum(axis=0), final

    events, final = jax.vmap(one_env)(jax.random.split(key, num_envs))
    return events.sum(axis=0), final


def test_jit_vmap_1024_envs_invariants_and_determinism():
    """1,024 fleets of 8 robots, 100 steps (two shifts of 48) in one program: no two robots ever share a
    cell or stand on a shelf; the same key gives the same bits, another key another rollout."""
    env, params = registry.make("Fleet-12x12-v0", num_robots=8, max_steps=48)
    num_envs, num_steps = 1024, 100
    (events, final), (events_again, final_again), (_, final_other) = (
        jax.device_get(vmapped_rollout(env, params, jax.random.key(seed), num_envs, num_steps)) for seed in (5, 5, 6))
    collisions, on_shelf, deliveries, truncations = events.tolist()
    print(f"12x12 K=8, {num_envs} envs x {num_steps} steps: {deliveries} deliveries")
    assert collisions == 0 and on_shelf == 0 and deliveries > 0 and truncations == 2 * num_envs
    assert final.pos.shape == (num_envs, 8, 2) and final.time.tolist() == [num_steps - 2 * 48] * num_envs
    for field in ("pos", "item", "station", "carrying", "time"):
        np.testing.assert_array_equal(getattr(final, field), getattr(final_again, field))
    np.testing.assert_array_equal(events, events_again)
    assert not np.array_equal(final.pos, final_other.pos) and not np.array_equal(final.item, final_other.item)


@pytest.mark.slow
def test_no_two_robots_share_a_cell_on_the_32x32_map():
    """32 robots, 520 steps (a whole 512-step shift and the next one's start) on Fleet-32x32-v0."""
    env, params = registry.make("Fleet-32x32-v0", num_robots=32)
    # Invariants of integer logic, no bit-identity claim: compiled at LLVM level 0 (tests/fast_compile.py).
    rollout = fast_compile.fast(vmapped_rollout, static_argnums=(0, 3, 4))
    events, final = jax.device_get(rollout(env, params, jax.random.key(0), 4, 520))
    collisions, on_shelf, deliveries, truncations = events.tolist()
    print(f"32x32 K=32: {deliveries} deliveries over 4 envs")
    assert collisions == 0 and on_shelf == 0 and deliveries > 0 and truncations == 4
    assert final.time.tolist() == [8] * 4


def test_auto_reset_keeps_final_obs():
    env, params = make_fleet(maps.FLEET_12X12, 2, max_steps=2)
    step = jax.jit(env.step)
    obs, state = jax.jit(env.reset)(jax.random.key(0))
    action = jnp.array([3, 3])
    obs, state, _, terminated, truncated, info = step(jax.random.key(1), state, action)
    assert not bool(truncated) and np.array_equal(info["final_obs"], obs)
    obs, state, _, terminated, truncated, info = step(jax.random.key(2), state, action)
    assert bool(truncated) and not bool(terminated) and int(state.time) == 0
    np.testing.assert_array_equal(state.pos, params.starts)
    assert not np.array_equal(info["final_obs"], obs) and np.array_equal(info["final_obs"], info["final_observation"])
    assert np.asarray(info["final_obs"])[0, 1] == np.float32(2) / np.float32(11)  # robot 0 reached column 2


def test_padding_never_changes_a_rollout():
    env, params = make_fleet(maps.FLEET_12X12, 4, max_steps=8)
    _, padded = make_fleet(maps.FLEET_12X12, 4, max_steps=8, max_items=24, max_stations=3)
    # Both draws in one program (eagerly, each operation compiles on its own); integer draws: LLVM level 0.
    tasks, padded_tasks = fast_compile.jit(lambda key: (draw_tasks(key, params, 4), draw_tasks(key, padded, 4)))(
        jax.random.key(9))
    np.testing.assert_array_equal(tasks.item, padded_tasks.item)
    np.testing.assert_array_equal(tasks.station, padded_tasks.station)
    assert padded.items.shape == (24, 2) and padded.item_dist.shape == (24, 12, 12)
    assert int(np.asarray(padded.item_dist)[23].min()) == 0 and int(np.asarray(params.item_dist).max()) == UNREACHABLE


def test_reference_state_roundtrip_matches_jax_reset():
    env, params = make_fleet(maps.FLEET_12X12, 3)
    key = jax.random.key(4)
    (obs, state), tasks = jax.jit(lambda k: (env.reset(k), draw_tasks(k, params, 3)))(key)  # one program
    ref_obs, ref_state = FleetReference.from_params(params).reset(np.asarray(tasks.item), np.asarray(tasks.station))
    assert isinstance(ref_state, RefState)
    np.testing.assert_array_equal(np.asarray(obs).view(np.uint32), ref_obs.view(np.uint32))
    np.testing.assert_array_equal(state.item, ref_state.item)


# ----------------------------------------------------------------- pictures
def test_render_frame_ascii_and_gif(tmp_path):
    from wrl_jax.envs.fleet import render

    env, params = make_fleet(TINY, 2, max_steps=4)
    state = tiny_state([[0, 0], [2, 1]], [0, 1], [0, 0], [False, True])  # robot 1 carries, heads for G (2, 0)
    cell = 8
    frame = np.asarray(jax.jit(render.render_frame, static_argnums=2)(state, params, cell))
    assert frame.shape == (24, 24, 3) and frame.dtype == np.uint8
    colours = render.robot_colors(2)
    assert len({tuple(c) for c in colours}) == 2
    centre = lambda r, c: tuple(frame[r * cell + cell // 2 - 1, c * cell + cell // 2 - 1])  # noqa: E731
    assert centre(0, 0) == tuple(colours[0])  # robot 0's disc
    assert centre(2, 1) == render.COLORS["item"]  # robot 1 carries: the item at its centre
    assert tuple(frame[1 * cell + 1, 1 * cell + 3]) == render.COLORS["shelf"]
    assert tuple(frame[0 * cell + 1, 2 * cell + 3]) == tuple(colours[0])  # robot 0's target ring on item 0
    assert tuple(frame[2 * cell + 1, 0 * cell + 3]) == tuple(colours[1])  # robot 1's ring on station (2, 0)
    assert tuple(frame[2 * cell + 4, 0 * cell + 4]) == render.COLORS["station"]
    text = render.render_ascii(state, params)
    assert text.splitlines()[1:4] == ["a . *", ". # .", "G B *"] and "robot 1 at (2, 1) carrying" in text

    def policy(key, obs, state):
        return jax.random.randint(key, (2,), 0, 5, dtype=jnp.int32)

    recording = render.record_shift(env, params, policy, jax.random.key(0), cell_size=cell)
    assert recording.frames.shape == (5, 24, 24, 3) and recording.deliveries.shape == (2,)
    path = render.save_gif(recording.frames, tmp_path / "shift.gif")
    assert (tmp_path / "shift.gif").stat().st_size > 0 and path.endswith("shift.gif")
    with pytest.raises(ValueError, match="num_steps"):
        render.record_shift(env, params, policy, jax.random.key(0), num_steps=5)


# ----------------------------------------------------------------- the fast step against the generic one
def test_fast_draws_are_jax_random_bits():
    """The unrolled threefry of env.py gives ``jax.random.split`` and ``jax.random.bits`` bit for bit."""
    keys = jax.random.split(jax.random.key(3), 64)

    def both(key):
        split = jax.random.split(key)
        fast = (core_random.split_key(key, 0), core_random.split_key(key, 1))
        words = (jax.random.bits(key, (16,), jnp.uint32), core_random.random_words(key, 16))
        return [jax.random.key_data(k) for k in (split[0], split[1], *fast)], words

    # Integer bits only: LLVM level 0 (tests/fast_compile.py) computes them as the session's level does.
    (split0, split1, fast0, fast1), (bits, fast_bits) = jax.device_get(fast_compile.jit(jax.vmap(both))(keys))
    np.testing.assert_array_equal(split0, fast0)
    np.testing.assert_array_equal(split1, fast1)
    np.testing.assert_array_equal(bits, fast_bits)


@functools.partial(jax.jit, static_argnums=(0, 2))
def fast_and_generic_rollouts(env, params, typed_keys):
    """``Fleet.step`` and the base class's ``Environment.step`` on the same fleets, keys and actions, in one
    program (the set-up inside it too: eagerly, each of its operations would compile on its own)."""
    from wrl_jax.core.environment import Environment

    num_envs, num_steps = 24, 30
    make_key = jax.random.key if typed_keys else jax.random.PRNGKey
    _, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(make_key(0), num_envs), params)
    state = state.replace(time=jnp.arange(num_envs, dtype=jnp.int32) % 12)
    actions = jax.random.randint(make_key(1), (num_steps, num_envs, 8), 0, 5, dtype=jnp.int32)
    keys = jax.random.split(make_key(2), num_steps * num_envs).reshape(num_steps, num_envs, -1)
    keys = keys[..., 0] if typed_keys else keys

    def rollout(step):
        def body(state, xs):
            obs, state, reward, terminated, truncated, info = jax.vmap(step, in_axes=(0, 0, 0, None))(
                xs[0], state, xs[1], params)
            return state, (obs, reward, terminated, truncated, info)

        return jax.lax.scan(body, state, (keys, actions))

    return rollout(env.step), rollout(functools.partial(Environment.step, env))


@pytest.mark.parametrize("typed_keys", [True, False], ids=["typed", "legacy"])
def test_vmapped_step_is_the_generic_step_bit_for_bit(typed_keys):
    """``Fleet.step`` (unrolled draws, lazy auto-reset, compact observation select) against the base
    class's ``Environment.step`` (``jax.random.split``, ``reset_env``, ``jnp.where`` on observations),
    vmapped over fleets whose shift clocks differ, so that some truncate while others go on."""
    num_envs = 24
    env, params = make_fleet(maps.FLEET_12X12, 8, max_steps=12)
    fast, generic = jax.device_get(fast_and_generic_rollouts(env, params, typed_keys))
    assert int(np.asarray(fast[1][3]).sum()) >= num_envs  # truncations happened, at different steps
    for a, b in zip(jax.tree.leaves(fast), jax.tree.leaves(generic)):
        a, b = np.asarray(a), np.asarray(b)
        assert a.dtype == b.dtype and np.array_equal(a.view(np.uint32) if a.dtype == np.float32 else a,
                                                     b.view(np.uint32) if b.dtype == np.float32 else b)


@pytest.mark.parametrize("num_robots", [3, 8, 20, 31])
def test_mask_rounds_equal_the_table_rounds(num_robots):
    """The unrolled int32-mask rounds give the ``while_loop`` table rounds' result on crowded random fleets."""
    rng = np.random.default_rng(num_robots)
    side = int(np.ceil(np.sqrt(num_robots * 1.3)))
    pos, proposal = [], []
    for _ in range(200):
        cells = rng.choice(side * side, num_robots, replace=False)
        here = np.stack([cells // side, cells % side], axis=1)
        pos.append(here)
        proposal.append(here + MOVES_WITH_WAIT[rng.integers(0, 5, num_robots)])
    pos, proposal = jnp.asarray(np.array(pos), jnp.int32), jnp.asarray(np.array(proposal), jnp.int32)

    def both(pos, proposal):
        row, col, q_row, q_col = pos[:, 0], pos[:, 1], proposal[:, 0], proposal[:, 1]
        same_q, onto = fleet_conflicts._same(q_row, q_col, q_row, q_col), fleet_conflicts._same(q_row, q_col, row, col)
        swap = onto & fleet_conflicts._same(row, col, q_row, q_col)
        movers = jnp.any(proposal != pos, axis=1)
        lower = np.arange(num_robots)[None, :] < np.arange(num_robots)[:, None]
        return (fleet_conflicts._mover_rounds(movers, same_q, onto, swap),
                fleet_conflicts._mover_rounds_tables(movers, same_q & lower, onto, swap))

    # Boolean and integer logic only: compiled at LLVM level 0 (tests/fast_compile.py), same results.
    masks, tables = jax.device_get(fast_compile.jit(jax.vmap(both))(pos, proposal))
    np.testing.assert_array_equal(masks, tables)
    assert (masks != np.any(np.asarray(proposal) != np.asarray(pos), axis=2)).any()  # some robots were blocked
