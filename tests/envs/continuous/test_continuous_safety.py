"""The safety stop (``safety_margin``): what it stops, what it lets through, and that nothing it lets through
collides on states drawn next to shelves, walls and obstacles.

The states are the 12x12 map with 4 obstacles, the robot anywhere it fits and obstacle 0 within 0.9 m of it,
at full speed forwards or backwards and any turn: one compiled program per margin
(``bench/investigations/continuous_safety_margin.py``, which measures the margins on more draws). The other tests'
resets and steps are jitted, once per environment: eagerly each compiles op by op, seconds a test.
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from wrl_jax.envs.continuous.registration import make_continuous
from wrl_jax.envs.continuous.safety import SAFETY_MARGIN, safety_stop
from wrl_jax.envs.warehouse.maps import WAREHOUSE_12X12


pytestmark = pytest.mark.usefixtures("geodesic_fields_at_the_commands_level")  # tests/conftest.py


@pytest.fixture(scope="module")
def collisions_through():
    """The bench script's measurement (its functions, imported from bench/investigations)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "bench" / "investigations"))
    try:
        from continuous_safety_margin import collisions_through
    finally:
        sys.path.pop(0)
    return collisions_through


@pytest.fixture(scope="module")
def dynamic():
    return make_continuous(WAREHOUSE_12X12, num_obstacles=4, observe_obstacles=True)


@pytest.fixture(scope="module")
def start(dynamic):
    """The state ``dynamic`` resets to from a key, jitted: eagerly the reset compiles op by op (seconds)."""
    env, params = dynamic
    return jax.jit(lambda key: env.reset(key, params)[1])


@pytest.fixture(scope="module")
def steps(dynamic):
    """The same map with the stop, and both environments' transitions (``dynamic``'s params), each jitted once for the
    tests that step them: ``(guarded, plain_step, guarded_step)``, the steps taking ``(key, state, action)``."""
    env, params = dynamic
    guarded, _ = make_continuous(WAREHOUSE_12X12, num_obstacles=4, observe_obstacles=True, safety_stop=True)
    return (guarded, jax.jit(lambda key, state, action: env.transition(key, state, action, params)),
            jax.jit(lambda key, state, action: guarded.transition(key, state, action, params)))


def test_nothing_the_stop_lets_through_collides_and_without_a_margin_something_does(dynamic, collisions_through):
    """Also under domain randomization: the stop checks the step the episode's gains and the step's noise make, and
    holds the robot with the command they cancel (it stays put instead of moving by the noise)."""
    env, params = dynamic
    for randomize in (False, True):
        counts = collisions_through(env, params.replace(randomize=jnp.bool_(randomize)), SAFETY_MARGIN)
        fits, before, after, stops = (counts[name] for name in ("fits", "before", "after", "stops"))
        assert fits > 5_000 and before > 500, randomize  # the draws do meet things
        assert after == 0 and stops >= before, randomize
        assert counts["creep"] < 1e-6, randomize  # measured: 0 both ways (the cancellation rounds exactly here)
    # At margin 0 a shelf corner between two rays slips through: the margin is what covers the rays' spacing.
    assert collisions_through(env, params, 0.0)["after"] > 0


def test_the_stop_drops_the_forward_command_only_and_lets_the_robot_back_away(dynamic, start):
    _, params = dynamic
    state = start(jax.random.key(0))
    wall = state.replace(pos=jnp.array([0.3, 1.5], jnp.float32), theta=jnp.float32(np.pi))  # touching the left wall
    stop = jax.jit(lambda action: safety_stop(wall, action, jnp.zeros(2), 32, SAFETY_MARGIN, params))  # one program, three actions
    action, by_obstacle, by_shelf = stop(jnp.array([0.8, 0.5], jnp.float32))
    assert bool(by_shelf) and not bool(by_obstacle)
    np.testing.assert_array_equal(np.asarray(action), [0.0, 0.5])  # the turn stays
    away, *stops = stop(jnp.array([-0.8, 0.0], jnp.float32))
    assert not any(bool(s) for s in stops) and float(away[0]) == np.float32(-0.8)
    # Turning on the spot is never stopped, however close things are.
    assert not any(bool(s) for s in stop(jnp.array([0.0, 1.0], jnp.float32))[1:])


def test_the_environment_with_the_stop_reports_it_and_otherwise_steps_as_without(dynamic, start, steps):
    env, _ = dynamic
    guarded, plain_step, guarded_step = steps
    assert guarded.safety_margin == SAFETY_MARGIN
    assert guarded.event_metrics["safety_stop"] == "safety_stops_sum" and "safety_stop" not in env.event_metrics
    key = jax.random.key(3)
    state = start(key)
    # Row 1 of the 12x12 map is open: the robot at x 4.85 faces obstacle 0 at x 5.5, 0.05 m beyond contact.
    obstacles = np.array(state.obstacle_pos)
    obstacles[0] = [5.5, 1.5]
    state = state.replace(pos=np.array([4.85, 1.5], np.float32), theta=np.float32(0.0), obstacle_pos=obstacles)
    forward = np.array([1.0, 0.0], np.float32)
    free = np.array([-1.0, 0.0], np.float32)  # backwards, away from the obstacle
    plain = jax.device_get(plain_step(key, state, forward))
    stopped = jax.device_get(guarded_step(key, state, forward))
    assert bool(plain[-1]["collision"]) and bool(plain[-1]["hit_obstacle"])
    info = stopped[-1]
    assert not bool(info["collision"]) and bool(info["safety_stop"]) and bool(info["stop_obstacle"])
    assert float(stopped[0][4]) == 0.0  # the applied command is 0
    assert float(stopped[0][-3]) == 1.0 and float(stopped[0][-1]) == np.float32(0.1)  # blocked by an obstacle, held 1 step
    moved, plain_moved = jax.device_get((guarded_step(key, state, free), plain_step(key, state, free)))
    np.testing.assert_array_equal(moved[0][:-1], plain_moved[0])
    assert float(moved[0][-1]) == 0.0  # and the held value
    for a, b in zip(jax.tree.leaves(moved[1:5]), jax.tree.leaves(plain_moved[1:5]), strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(("settings", "match"), [
    ({"safety_stop": True, "safety_margin": -0.1}, "metres in"), ({"safety_stop": True, "safety_margin": True}, "metres in"),
    ({"safety_stop": True, "safety_margin": "0.05"}, "metres in"), ({"safety_margin": 0.1}, "pass safety_stop=True"),
    ({"safety_stop": 1}, "True or False"),
    ({"safety_stop": True, "num_rays": 16}, "pass a safety_margin of your own"),
    ({"escape_after": 10}, "pass safety_stop=True"), ({"safety_stop": True, "escape_after": -1}, "positive integer"),
    ({"safety_stop": True, "escape_after": 2.5}, "positive integer")])
def test_bad_settings_of_the_stop_are_refused_before_anything_is_built(settings, match):
    with pytest.raises(ValueError, match=match):
        make_continuous(WAREHOUSE_12X12, num_obstacles=4, **settings)


def test_the_procedural_variant_takes_the_stop_randomized_or_not():
    from wrl_jax.envs.continuous.procedural import make_continuous_procedural

    env, _ = make_continuous_procedural(pool_size=4, randomize=False, safety_stop=True, safety_margin=0.1)
    assert env.safety_margin == 0.1 and env.plain.safety_margin == 0.1
    env, params = make_continuous_procedural(pool_size=4, safety_stop=True)
    assert env.safety_margin == SAFETY_MARGIN and bool(params.randomize)


def test_the_view_counts_the_steps_the_robot_is_held_and_forgets_them_once_it_moves(dynamic, start, steps):
    env, params = dynamic
    guarded, plain_step, guarded_step = steps
    assert guarded.obs_size == env.obs_size + 1 and not env.observe_held
    key = jax.random.key(3)
    # The robot faces the left wall on the open row 1, 0.02 m beyond touching it.
    state = start(key).replace(pos=np.array([0.32, 1.5], np.float32), theta=np.float32(np.pi))
    forward, back = np.array([1.0, 0.0], np.float32), np.array([-1.0, 0.0], np.float32)
    space = guarded.observation_space(params)
    state_g = state
    for steps_held in range(1, 13):  # held by the stop
        obs, state_g, *_ = guarded_step(key, state_g, forward)
        # The count exactly; its view within a float32 rounding (compiled, XLA multiplies by 0.1 instead of dividing).
        assert int(state_g.held) == steps_held and float(obs[-1]) == pytest.approx(min(steps_held, 10) / 10, rel=1e-6)
        obs = np.asarray(obs)  # NumPy: eagerly each check compiles
        assert np.all((obs >= space.low) & (obs <= space.high))
    obs, state_g, *_ = guarded_step(key, state_g, back)
    assert int(state_g.held) == 0 and float(obs[-1]) == 0.0
    _, plain, *_, info = plain_step(key, state, forward)  # without the stop nothing reads it
    assert bool(info["hit_wall"]) and int(plain.held) == 0


def test_the_escape_turns_a_held_robot_fully_until_it_moves_and_never_before(dynamic, start):
    """Facing the left wall, a policy that pushes on with a turn swinging between +-0.17 (the traced standstill,
    bench/results/continuous/NOTES.md): held for ever without the escape; with ``escape_after=3`` the turn becomes
    a full one from the fourth held step, the robot turns away and moves, and nothing is touched."""
    env, params = dynamic
    state = start(jax.random.key(3)).replace(pos=np.array([0.32, 1.5], np.float32), theta=np.float32(np.pi))
    guarded = {k: make_continuous(WAREHOUSE_12X12, num_obstacles=4, observe_obstacles=True, safety_stop=True,
                                  escape_after=k)[0] for k in (None, 3)}
    assert guarded[3].escape_after == 3 and "escape_after=3" in repr(guarded[3]) and guarded[None].escape_after is None
    assert make_continuous(WAREHOUSE_12X12, safety_stop=True, escape_after=np.int64(0))[0].escape_after is None  # 0: off
    for bad in (0, True, 2.0):  # the class itself takes None or a positive integer
        with pytest.raises(ValueError, match="positive integer"):
            type(guarded[3])(params, safety_margin=SAFETY_MARGIN, escape_after=bad)

    @jax.jit
    def run(state):
        def one(states, t):
            action = jnp.array([1.0, jnp.where(t % 2 == 0, 0.17, -0.17)], jnp.float32)
            stepped = [guarded[k].transition(jax.random.key(0), s, action, params) for k, s in zip((None, 3), states)]
            return tuple(out[1] for out in stepped), [(out[1].held, out[1].pos, out[0][5], out[-1]["collision"])
                                                      for out in stepped]
        return jax.lax.scan(one, (state, state), jnp.arange(40))[1]

    (held, pos, _, touched), (held_e, pos_e, turn_e, touched_e) = jax.device_get(run(state))
    assert held.tolist() == list(range(1, 41)) and np.allclose(pos, [0.32, 1.5])  # a standstill without it
    assert held_e[:3].tolist() == [1, 2, 3]
    first = int(np.argmax(held_e == 0))  # the first step it moved
    assert 3 < first < 40 and float(np.abs(pos_e[-1] - [0.32, 1.5]).sum()) > 0.1
    # The applied turn (the contract's observation, value 5) is a full turn from the fourth held step until it moves.
    np.testing.assert_array_equal(turn_e[3:first], 1.0)
    assert abs(float(turn_e[2])) == pytest.approx(0.17)
    assert not touched.any() and not touched_e.any()
    # A NaN turn that the escape replaces is still flagged, as the contract flags every NaN action.
    held = state.replace(held=jnp.int32(5))
    info = jax.jit(lambda s: guarded[3].transition(jax.random.key(0), s, jnp.array([1.0, jnp.nan]), params)[-1])(held)
    assert bool(info["invalid_action"]) and bool(info["safety_stop"])


@pytest.mark.parametrize("variant", ["learners_default", "procedural"])
def test_every_variant_steps_through_the_stop_and_its_view_stays_in_its_space(variant):
    """The learners' view on the moving obstacles' map (geodesic shaping, target, obstacles, stop, route) and the
    procedural variant: 300 auto-resetting steps of full speed ahead with a slow turn. The stop acts, nothing is
    touched, every observation lies in the space, and ``held`` starts from 0 after every reset."""
    from wrl_jax.envs.continuous.procedural import make_continuous_procedural

    if variant == "procedural":
        env, params = make_continuous_procedural(pool_size=4, randomize=False, num_obstacles=2, max_steps=60,
                                                 observe_target=True, observe_obstacles=True, safety_stop=True)
    else:
        env, params = make_continuous(WAREHOUSE_12X12, num_obstacles=4, max_steps=60, shaping="geodesic",
                                      observe_target=True, observe_obstacles=True, observe_route=True, safety_stop=True)
    space = env.observation_space(params)

    def one(state, key):
        obs, state, _, terminated, truncated, info = env.step(key, state, jnp.array([1.0, 0.15], jnp.float32), params)
        done = terminated | truncated
        return state, (space.contains(obs), done, state.held, info["safety_stop"], info["collision"])

    @jax.jit  # the reset too (eagerly it compiles op by op)
    def run():
        _, state = env.reset(jax.random.key(0), params)
        return jax.lax.scan(one, state, jax.random.split(jax.random.key(1), 300))[1]

    inside, done, held, stops, collisions = jax.device_get(run())
    assert int(stops.sum()) > 0 and int(collisions.sum()) == 0
    assert int(done.sum()) >= 4 and bool(np.all(np.where(done, held == 0, True)))
    assert int(held.max()) > 1
    assert inside.all()  # every observation, in the program that stepped
