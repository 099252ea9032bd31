"""The JAX continuous warehouse against the independent NumPy reference, one transition at a time.

Each transition starts from the JAX state; the reference takes that state, the same action and the
same random draws (the deterministic cores take draws as inputs), and both must agree as
CONTINUOUS_SPEC.md's Precisions say: the same events, states within 1e-5 m, rewards within 1e-4,
lidar within 1e-4 m, except where a decision lies within 1e-5 m of its threshold (a *tie*, counted
and reported: there the two may legitimately differ). Episodes mix a controller that heads for its
target (pickups, deliveries, shelf and obstacle contacts) with uniform actions (walls, turns), with
moving obstacles, with and without domain randomization, and NaN/inf actions. The recording compiles at LLVM
level 0 (``fast_compile``): it is compared with the reference within tolerances, never bit for bit.
"""

from __future__ import annotations

import dataclasses
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import fast_compile
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from wrl_jax.envs.continuous import reference as ref
from wrl_jax.envs.continuous import reference_geometry as geo
from wrl_jax.envs.continuous import reference_types as rtypes
from wrl_jax.envs.continuous.dynamics import FLAGS as EVENTS
from wrl_jax.envs.continuous.dynamics import reset_core, transition_core
from wrl_jax.envs.continuous.geometry import hits_shelf, hits_wall
from wrl_jax.envs.continuous.registration import make_continuous
from wrl_jax.envs.warehouse.maps import WAREHOUSE_8X8, WAREHOUSE_12X12

STEPS = int(os.environ.get("WRL_CONTINUOUS_PARITY_STEPS", "400"))
"""Transitions per case (``WRL_CONTINUOUS_PARITY_STEPS=5000`` for the long run of docs/continuous.md)."""
TIE = 1e-5  # metres: a decision this close to its threshold may go either way
STATE_TOL = 1e-5
LIDAR_TOL = 1e-4


def controller(key, state, params):
    """Head for the current target (turn toward it, drive when facing it), or act uniformly; now and then NaN/inf."""
    k_mode, k_uniform, k_odd = jax.random.split(key, 3)
    target = jnp.where(state.carrying, params.goal, state.item)
    bearing = jnp.arctan2(target[1] - state.pos[1], target[0] - state.pos[0]) - state.theta
    bearing = jnp.arctan2(jnp.sin(bearing), jnp.cos(bearing))
    seek = jnp.stack([jnp.clip(jnp.cos(bearing), -0.3, 1.0), jnp.clip(2.0 * bearing, -1.0, 1.0)])
    uniform = jax.random.uniform(k_uniform, (2,), minval=-1.2, maxval=1.2)
    action = jnp.where(jax.random.uniform(k_mode) < 0.6, seek, uniform)
    odd = jax.random.uniform(k_odd)
    return jnp.where(odd < 0.01, jnp.array([jnp.nan, 0.5]), jnp.where(odd < 0.02, jnp.array([jnp.inf, -jnp.inf]),
                                                                      action)).astype(jnp.float32)


def place_near_target(key, state, params):
    """Now and then, the robot put within 0.8 m of a target (carrying or not) where it overlaps nothing:
    scripted states that reach pickups, deliveries and the reach radius's edge far more often than driving."""
    k_jump, k_carry, k_offset = jax.random.split(key, 3)
    carrying = jax.random.uniform(k_carry) < 0.5
    target = jnp.where(carrying, params.goal, state.item)
    pos = target + jax.random.uniform(k_offset, (2,), minval=-0.8, maxval=0.8)
    height, width = params.shelves.shape
    gaps = jnp.linalg.norm(state.obstacle_pos - pos, axis=-1)
    free = ~(hits_shelf(pos, params.robot_radius, params.shelves) | hits_wall(pos, params.robot_radius, width, height)
             | jnp.any(gaps < params.robot_radius + params.obstacle_radius))
    jump = free & (jax.random.uniform(k_jump) < 0.15)
    return state.replace(pos=jnp.where(jump, pos, state.pos), carrying=jnp.where(jump, carrying, state.carrying))


def record(env, params, key, steps):
    """``steps`` transitions with auto-reset: every input and output of each."""

    def one(state, key):
        k_act, k_step, k_reset, k_place = jax.random.split(key, 4)
        state = place_near_target(k_place, state, params)
        action = controller(k_act, state, params)
        draws = env.step_draws(k_step, params)
        obs, nxt, reward, terminated, truncated, info = transition_core(state, action, draws, params)
        reset_draws = env.reset_draws(k_reset, params)
        reset_obs, fresh = reset_core(reset_draws, params)
        done = terminated | truncated
        carry = jax.tree.map(lambda a, b: jnp.where(done, a, b), fresh, nxt)
        return carry, (state, action, draws, obs, nxt, reward, terminated, truncated, info, done, reset_draws,
                       reset_obs, fresh)

    _, state = env.reset(jax.random.fold_in(key, 1), params)
    return jax.lax.scan(one, state, jax.random.split(key, steps))[1]


RECORD = fast_compile.jit(record, static_argnums=(0, 3))
"""One jitted :func:`record` for the module: with the environment stripped of its default params (they are passed),
the two 12x12 cases (limits and randomization are params) run one compiled program."""


def reference_params(env, params) -> rtypes.ContinuousParams:
    p = {name: np.asarray(getattr(params, name)).item() for name in (
        "dt", "v_max", "w_max", "robot_radius", "reach_radius", "lidar_range", "step_penalty", "collision_penalty",
        "shaping_coef", "pickup_reward", "delivery_reward", "max_steps", "obstacle_radius", "obstacle_speed",
        "actuation_noise", "lidar_noise", "lidar_dropout", "start_jitter", "randomize")}
    return rtypes.ContinuousParams(**p, gain_range=(float(params.gain_low), float(params.gain_high)),
                                num_rays=env.num_rays, num_obstacles=env.num_obstacles)


def reference_state(states, t) -> rtypes.ContinuousState:
    pick = lambda leaf: np.asarray(leaf[t])  # noqa: E731
    return rtypes.ContinuousState(pos=pick(states.pos).astype(np.float32), theta=np.float32(pick(states.theta)),
                               carrying=bool(pick(states.carrying)), item=pick(states.item).astype(np.float32),
                               time=int(pick(states.time)), obstacle_pos=pick(states.obstacle_pos).astype(np.float32),
                               obstacle_waypoint=pick(states.obstacle_waypoint).astype(np.float32),
                               obstacle_from=pick(states.obstacle_from).astype(np.int32),
                               gains=pick(states.gains).astype(np.float32))


def reference_draws(draws, t) -> rtypes.StepDraws:
    return rtypes.StepDraws(noise=draws.noise[t], waypoint_u=draws.waypoint_u[t], lidar_noise=draws.lidar_noise[t],
                         lidar_drop=draws.lidar_drop[t])


def margins(state: rtypes.ContinuousState, action, layout, params, draws) -> list[float]:
    """How far (metres) each decision of the transition lies from its threshold (small: a tie)."""
    a, _ = geo.read_action(action)
    v = np.float32(np.float32(np.float32(params.v_max) * a[0]) * state.gains[0]) + np.float32(draws.noise[0])
    w = np.float32(np.float32(np.float32(params.w_max) * a[1]) * state.gains[1]) + np.float32(draws.noise[1])
    theta = geo.wrap(np.float32(state.theta + np.float32(w * np.float32(params.dt))))
    q = state.pos + np.float32(v * np.float32(params.dt)) * np.array([np.cos(theta), np.sin(theta)], np.float32)
    out = [q[0] - params.robot_radius, layout.width - q[0] - params.robot_radius,
           q[1] - params.robot_radius, layout.height - q[1] - params.robot_radius]
    for row, col in zip(*np.nonzero(layout.shelves)):
        dx = np.clip(q[0], col, col + 1) - q[0]
        dy = np.clip(q[1], row, row + 1) - q[1]
        out.append(np.hypot(dx, dy) - params.robot_radius)
    gap = params.robot_radius + params.obstacle_radius
    for centre, waypoint in zip(state.obstacle_pos, state.obstacle_waypoint):
        out.append(np.hypot(*(q - centre)) - gap)
        for robot in (q, state.pos):
            d = waypoint - centre
            stride = params.obstacle_speed * params.dt
            length = np.hypot(*d)
            out.append(length - stride)
            moved = waypoint if length <= stride else centre + stride * d / max(length, 1e-12)
            out.append(np.hypot(*(moved - robot)) - gap)
    goal = layout.cell_centre(*layout.goal)
    for robot in (q, state.pos):
        out += [np.hypot(*(robot - state.item)) - params.reach_radius, np.hypot(*(robot - goal)) - params.reach_radius]
    return [abs(float(m)) for m in out]


def lidar_grazes(pos, theta, layout, params, obstacles, ray: int, value: float) -> bool:
    """Whether ray ``ray`` reads ``value`` (metres) at some origin within 1e-5 m of ``pos`` (a grazing ray)."""
    readings = []
    for dx, dy in ((0, 0), (TIE, 0), (-TIE, 0), (0, TIE), (0, -TIE)):
        origin = (pos + np.array([dx, dy], np.float32)).astype(np.float32)
        readings.append(geo.lidar_distances(origin, theta, layout, params, obstacles)[ray])
    return min(readings) - LIDAR_TOL <= value <= max(readings) + LIDAR_TOL


@dataclasses.dataclass
class Tally:
    transitions: int = 0
    resets: int = 0
    ties: int = 0
    events: dict = dataclasses.field(default_factory=dict)


def compare(env, params, layout, rp, rec, tally: Tally) -> None:
    states, actions, draws, obs, nxt, reward, terminated, truncated, info, done, reset_draws, reset_obs, fresh = rec
    for t in range(actions.shape[0]):
        state = reference_state(states, t)
        r_state, r_obs, r_reward, r_term, r_trunc, r_info = ref.step(state, actions[t], layout, rp,
                                                                       reference_draws(draws, t))
        tally.transitions += 1
        flags = {name: bool(info[name][t]) for name in EVENTS}
        flags |= {"terminated": bool(terminated[t]), "truncated": bool(truncated[t])}
        r_flags = {name: bool(r_info[name]) for name in EVENTS} | {"terminated": r_term, "truncated": r_trunc}
        same = (flags == r_flags and np.array_equal(info["obstacle_waited"][t], r_info["obstacle_waited"])
                and np.array_equal(info["obstacle_landed"][t], r_info["obstacle_landed"]))
        if not same:
            assert min(margins(state, actions[t], layout, rp, reference_draws(draws, t))) < TIE, (
                f"transition {t}: events differ away from any threshold: {flags} vs {r_flags}")
            tally.ties += 1
            continue
        for name, value in flags.items():
            tally.events[name] = tally.events.get(name, 0) + int(value)
        tally.events["obstacle_landed"] = tally.events.get("obstacle_landed", 0) + int(r_info["obstacle_landed"].sum())
        tally.events["obstacle_waited"] = tally.events.get("obstacle_waited", 0) + int(r_info["obstacle_waited"].sum())
        for field in ("pos", "obstacle_pos", "obstacle_waypoint"):
            np.testing.assert_allclose(getattr(nxt, field)[t], getattr(r_state, field), atol=STATE_TOL, rtol=0,
                                       err_msg=f"transition {t}: {field}")
        assert abs(float(geo.wrap(np.float32(nxt.theta[t] - r_state.theta)))) <= STATE_TOL, t
        assert bool(nxt.carrying[t]) == r_state.carrying and int(nxt.time[t]) == r_state.time
        np.testing.assert_array_equal(nxt.obstacle_from[t], r_state.obstacle_from, err_msg=f"transition {t}")
        assert abs(float(reward[t]) - float(r_reward)) <= 1e-4, (t, reward[t], r_reward)
        np.testing.assert_allclose(obs[t][:11], r_obs[:11], atol=STATE_TOL, rtol=0, err_msg=f"transition {t}")
        off = np.flatnonzero(np.abs(obs[t][11:] - r_obs[11:]) * rp.lidar_range > LIDAR_TOL)
        for ray in off:  # only a grazing ray may read differently (noise and dropout do not change that)
            assert not draws.lidar_drop[t][ray]
            reading = float(obs[t][11 + ray]) * rp.lidar_range - float(draws.lidar_noise[t][ray])
            assert lidar_grazes(r_state.pos, r_state.theta, layout, rp, r_state.obstacle_pos, ray, reading), (
                f"transition {t}, ray {ray}: {obs[t][11 + ray]} vs {r_obs[11 + ray]}")
            tally.ties += 1
        if done[t]:  # the reset that followed, from the same draws
            rd = jax.tree.map(lambda leaf: leaf[t], reset_draws)
            r_fresh, r_first = ref.reset(layout, rp, int(rd.item_index), rd.obstacle_cells, rd.waypoint_u,
                                         rd.gains, rd.start_offset, float(rd.theta), rd.lidar_noise, rd.lidar_drop)
            tally.resets += 1
            np.testing.assert_allclose(fresh.pos[t], r_fresh.pos, atol=STATE_TOL, rtol=0)
            np.testing.assert_allclose(fresh.obstacle_waypoint[t], r_fresh.obstacle_waypoint, atol=STATE_TOL, rtol=0)
            np.testing.assert_allclose(reset_obs[t], r_first, atol=LIDAR_TOL / rp.lidar_range, rtol=0)


CASES = {
    "12x12, 4 obstacles": (WAREHOUSE_12X12, dict(num_obstacles=4, max_steps=100)),
    "12x12, 4 obstacles, randomized": (WAREHOUSE_12X12, dict(num_obstacles=4, randomize=True)),
    "8x8, no obstacles, short episodes": (WAREHOUSE_8X8, dict(max_steps=40)),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_transitions_match_the_reference(case):
    text, settings = CASES[case]
    env, params = make_continuous(text, **settings)
    layout = rtypes.ContinuousLayout.from_text(text)
    rp = reference_params(env, params)
    key = jax.random.key(sorted(CASES).index(case))
    rec = RECORD(env.without_default_params(), params, key, STEPS)  # one program per map size and obstacle count
    rec = jax.tree.map(np.asarray, rec)
    tally = Tally()
    compare(env, params, layout, rp, rec, tally)
    print(case, tally)
    assert tally.transitions == STEPS and tally.ties <= max(8, STEPS // 50)
    assert tally.events["collision"] > 5 and tally.events["picked_up"] > 3 and tally.events["delivered"] > 3
    if env.num_obstacles:
        assert tally.events["obstacle_landed"] > 10


# Hypothesis over layouts and parameters: random 6x6 maps (3 items, 2 moving obstacles, 16 rays: one compiled
# program for every example, since layouts and parameters are data) and every parameter of the contract drawn
# from a wide range, randomization on or off. WRL_CONTINUOUS_PARITY_EXAMPLES=400 for the long run of the docs.
SIDE, MARKS = 6, "SG012"


@st.composite
def small_maps(draw) -> str:
    """A 6x6 ASCII map of SPEC.md: about one cell in six a shelf, the start, the goal and 3 items on distinct cells
    (the test discards the maps the layout parser refuses: a mark walled off from the start)."""
    cells = draw(st.lists(st.sampled_from(".....#"), min_size=SIDE * SIDE, max_size=SIDE * SIDE))
    for mark, index in zip(MARKS, draw(st.permutations(range(SIDE * SIDE)))[:len(MARKS)]):
        cells[index] = mark
    return "\n".join(" ".join(cells[r * SIDE:(r + 1) * SIDE]) for r in range(SIDE))


def f32s(low: float, high: float):
    return st.floats(float(np.float32(low)), float(np.float32(high)), width=32)


@st.composite
def contract_settings(draw) -> dict:
    """Every parameter of CONTINUOUS_SPEC.md, each over a range well beyond its default."""
    radius = draw(f32s(0.1, 0.45))
    low = draw(f32s(0.5, 1.0))
    return dict(
        dt=draw(f32s(0.05, 0.4)), v_max=draw(f32s(0.2, 2.0)), w_max=draw(f32s(0.5, 4.0)), robot_radius=radius,
        reach_radius=draw(f32s(0.1, 0.8)), lidar_range=draw(f32s(0.5, 6.0)), step_penalty=draw(f32s(-2.0, 0.0)),
        collision_penalty=draw(f32s(-20.0, 0.0)), shaping_coef=draw(f32s(0.0, 5.0)),
        pickup_reward=draw(f32s(0.0, 100.0)), delivery_reward=draw(f32s(0.0, 300.0)),
        obstacle_radius=draw(f32s(0.1, 0.45)), obstacle_speed=draw(f32s(0.1, 1.5)), randomize=draw(st.booleans()),
        gain_low=low, gain_high=draw(f32s(low, 1.5)), actuation_noise=draw(f32s(0.0, 0.2)),
        lidar_noise=draw(f32s(0.0, 0.1)), lidar_dropout=draw(f32s(0.0, 0.3)),
        start_jitter=draw(f32s(0.0, 1.0)) * (0.5 - radius) * 0.999)


@settings(max_examples=int(os.environ.get("WRL_CONTINUOUS_PARITY_EXAMPLES", "20")), deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(text=small_maps(), overrides=contract_settings(), max_steps=st.integers(5, 80), seed=st.integers(0, 2**31 - 1))
def test_random_layouts_and_parameters_match_the_reference(text, overrides, max_steps, seed):
    try:
        env, params = make_continuous(text, max_steps=max_steps, num_rays=16, num_obstacles=2, **overrides)
    except ValueError as error:  # a marked cell walled off, too few cells for 2 obstacles: refused, not a case
        assume("unreachable" not in str(error) and "fewer than num_obstacles" not in str(error))
        raise
    layout = rtypes.ContinuousLayout.from_text(text)
    rec = jax.tree.map(np.asarray, RECORD(env.without_default_params(), params, jax.random.key(seed), 60))
    tally = Tally()
    compare(env, params, layout, reference_params(env, params), rec, tally)
    print(tally)
    assert tally.transitions == 60 and tally.ties <= 8, tally
