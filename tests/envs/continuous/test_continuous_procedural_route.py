"""The way around the shelves on the procedural continuous warehouse: every pool slot's distance fields, the
geodesic shaping and the observed route (``make_continuous_procedural(shaping="geodesic", observe_route=True)``).

One small environment (16 layouts, 8 rays, randomized, the route's lattice at 4 points per metre). Programs
judged by tolerances and thresholds compile at LLVM level 0 (``fast_compile``).
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import fast_compile

from wrl_jax.envs.continuous import geodesic, procedural_evaluation
from wrl_jax.envs.continuous.procedural import ROUTE_RESOLUTION, make_continuous_procedural
from wrl_jax.envs.continuous.procedural_layouts import layout_params, pool_fields, with_pool
from wrl_jax.envs.procedural.layout_sets import heldout_set

SETTINGS = {"pool_size": 16, "seed": 5, "num_rays": 8, "observe_target": True, "shaping": "geodesic",
            "observe_route": True}
STEPS = 40


@pytest.fixture(scope="module")
def route_env():
    return make_continuous_procedural(**SETTINGS)


def test_each_slot_has_its_own_fields_and_the_plain_maps_path_gives_them_alone(route_env):
    """The pool's fields are computed together (one relaxation for every slot); each slot's equal the
    single-map computation on that slot's layout, so nothing leaks between layouts; the goal's field is 0 at
    the goal's centre and positive elsewhere."""
    env, params = route_env
    side = env.width * ROUTE_RESOLUTION + 1
    assert params.pool_fields.shape == (16, env.max_items + 1, side, side)
    margin = float(params.robot_radius) + geodesic.SPARE
    for slot in (0, 7, 15):
        layout = layout_params(params, slot)
        targets = np.concatenate([np.asarray(layout.items), np.asarray(layout.goal)[None]])
        alone = geodesic.distance_fields(np.asarray(layout.shelves), targets, margin, ROUTE_RESOLUTION)
        np.testing.assert_array_equal(np.asarray(params.pool_fields[slot]), alone)
        np.testing.assert_array_equal(np.asarray(layout.fields), alone)
        x, y = (np.asarray(layout.goal) * ROUTE_RESOLUTION).astype(int)
        goal_field = alone[-1]
        assert goal_field[y, x] == 0.0 and (goal_field > 0).sum() == goal_field.size - 1


def test_a_transition_on_slot_k_is_the_geodesic_plain_env_on_slot_k(route_env):
    """Same key, state and action: the procedural route environment and its plain geodesic environment on the
    slot's params (what the evaluation runs) give the same observation (the route last), state, reward and
    events; the reward differs from the contract's procedural one by exactly the shaping change, and
    the route is a unit vector in the robot's frame."""
    env, params = route_env
    contract, contract_params = make_continuous_procedural(**{**SETTINGS, "shaping": "manhattan",
                                                              "observe_route": False})
    slot = 3
    layout = layout_params(params, slot)

    def run(key):
        reset_key, run_key = jax.random.split(key)
        ours = env.reset_to(jnp.int32(slot), reset_key, params)
        theirs = env.plain.reset_env(reset_key, layout)

        def body(carry, key):
            mine, other = carry
            action_key, step_key = jax.random.split(key)
            action = jax.random.uniform(action_key, (2,), minval=-1.0, maxval=1.0).at[0].add(0.5)
            a = env.transition(step_key, mine, action, params)
            b = env.plain.transition(step_key, other, action, layout)
            c = contract.transition(step_key, mine, action, contract_params)
            return (a[1], b[1]), (a, b, c[2], geodesic.shaping_change(mine, a[1], layout, env.width))

        _, steps = jax.lax.scan(body, (ours[1], theirs[1]), jax.random.split(run_key, STEPS))
        return ours, theirs, steps

    ours, theirs, (a, b, contract_reward, change) = fast_compile.jit(jax.vmap(run))(
        jax.random.split(jax.random.key(slot), 4))
    # Two programs' worth of arithmetic fused into one: XLA may round a ray or a reward differently in the last
    # bit (1.8e-7 seen), so values are compared to 1e-5 (the contract's tolerance for states) and events exactly.
    for mine, other in ((ours, theirs), (a[:3], b[:3])):
        np.testing.assert_allclose(np.asarray(mine[0]), np.asarray(other[0]), atol=1e-5)
        for field in vars(other[1]):
            np.testing.assert_allclose(np.asarray(getattr(mine[1], field)), np.asarray(getattr(other[1], field)),
                                       atol=1e-5)
    for flag in ("collision", "picked_up", "delivered"):
        np.testing.assert_array_equal(np.asarray(a[5][flag]), np.asarray(b[5][flag]))
    assert np.asarray(a[5]["collision"]).any()
    assert (np.asarray(a[1].layout_index) == slot).all()
    np.testing.assert_allclose(np.asarray(a[2]), np.asarray(b[2]), atol=1e-5)
    np.testing.assert_allclose(np.asarray(a[2]), np.asarray(contract_reward + change), atol=1e-5)
    assert np.abs(np.asarray(change)).max() > 0.01  # the shaping is not the contract's
    obs = np.asarray(a[0])
    assert obs.shape[-1] == env.obs_size == contract.obs_size + geodesic.ROUTE_FEATURES
    way = np.hypot(obs[..., -3], obs[..., -2])
    assert np.all((np.abs(way - 1) < 1e-5) | (way == 0)) and (way > 0).mean() > 0.9
    assert np.all(obs[..., -1] >= 0) and env.observation_space(params).shape == (env.obs_size,)


def test_a_rule_that_follows_the_route_delivers_on_layouts_it_never_saw(route_env, monkeypatch):
    """The route leads round every layout's shelves: the hand-written rule (turn towards it, drive when facing
    it) delivers nearly every item of held-out layouts, whose fields ``with_pool`` computes for the report
    (the same as computing them for those layouts directly)."""
    env, params = route_env
    heldout, _ = heldout_set(env.generator, env.training_layout_hashes(params), 8)
    eval_params = with_pool(params, heldout.layouts)
    np.testing.assert_array_equal(np.asarray(eval_params.pool_fields),
                                  np.asarray(pool_fields(heldout.layouts, params.robot_radius, ROUTE_RESOLUTION)))
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[3] / "bench" / "investigations"))
    from continuous_route_rule import follow_route  # the rule bench/results/continuous/NOTES.md measures with

    rule = follow_route(env.obs_size - geodesic.ROUTE_FEATURES)
    result = fast_compile.jit(lambda p: procedural_evaluation.evaluate_pool_sample(rule, env, p, count=8))(eval_params)
    valid = np.asarray(result.valid)
    delivered = np.asarray(result.delivered)[valid]
    assert valid.sum() >= 8 and delivered.mean() >= 0.95
    assert np.asarray(result.collisions)[valid].mean() < 0.5


def test_the_route_settings_are_checked_before_any_field_is_computed():
    cases = [
        ({"observe_route": True}, "observe_route reads the geodesic shaping's distance fields"),
        ({"shaping": "bfs"}, "shaping must be 'manhattan' or 'geodesic'"),
        ({"shaping": "geodesic", "route_resolution": 3}, "route_resolution must be even"),
        ({"shaping": "geodesic", "route_resolution": 0}, "route_resolution must be an integer"),
        ({"shaping": "geodesic", "observe_route": 1}, "observe_route must be True or False"),
    ]
    for settings, message in cases:
        with pytest.raises(ValueError, match=message):
            make_continuous_procedural(pool_size=1, **settings)
