"""The procedural continuous warehouse (issue 34): a pool of generated layouts under the continuous core.

One small environment (32 layouts of 8x8..12x12, 8 rays, 2 moving obstacles, randomized, 40 steps) serves
most tests, so the file compiles few programs. Programs whose results are compared with tolerances or thresholds
compile at LLVM level 0 (``fast_compile``: the padding comparison, the evaluation, SAC's updates); the batched
rollout and the slot's parity with the plain environment at the commands' level 1 (``commands_level``: the bounds and
collision-free starts are exact at that level, where a start can lie within rounding of a shelf, and the slot's
transition is the plain one's bit for bit); the others at the session's level. Those two are the tests' own programs
(the environments traced into them), so ``commands_level.jit`` compiles them at level 1 in this process: the same
programs, with the same bits, as in a pytest process at that level (compared 2026-12-07), without starting one (its
start-up and its own pool took 6 s of CPU). The pool is layouts, integers and booleans: alike at every level.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import commands_level
import fast_compile

import wrl_jax
from wrl_jax.core.evaluation import FinalContext
from wrl_jax.envs.continuous import evaluation, procedural_evaluation
from wrl_jax.envs.continuous.geometry import hits_shelf, hits_wall, norm, wrap
from wrl_jax.envs.continuous.procedural import default_max_steps, make_continuous_procedural
from wrl_jax.envs.continuous.procedural_layouts import layout_params, slot_layout
from wrl_jax.envs.continuous.registration import make_continuous
from wrl_jax.envs.procedural.layout import stack
from wrl_jax.envs.procedural.layout_sets import LayoutSet, heldout_set, study_layout
from wrl_jax.envs.procedural.pool import pool_hashes
from wrl_jax.envs.warehouse.layout import Layout

SETTINGS = {"pool_size": 32, "seed": 3, "num_rays": 8, "num_obstacles": 2, "max_steps": 40, "observe_target": True}
"""The module's environment (with the target in the robot's frame, as the training commands give it)."""
STEPS = 60


@pytest.fixture(scope="module")
def env_params():
    return make_continuous_procedural(**SETTINGS)


def act(key: jax.Array, state, goal: jax.Array) -> jax.Array:
    """Turn towards the target and drive when facing it, with noise: pickups, contacts and deliveries."""
    target = jnp.where(state.carrying, goal, state.item)
    offset = target - state.pos
    error = wrap(jnp.arctan2(offset[1], offset[0]) - state.theta)
    command = jnp.stack([jnp.cos(error), 2.0 * error]) + 0.3 * jax.random.normal(key, (2,))
    return jnp.clip(command, -1.2, 1.2)


# ------------------------------------------------------------------ the pool and resets
def test_registered_with_the_documented_defaults():
    env, params = wrl_jax.make("Continuous-Procedural-Warehouse-v0", pool_size=SETTINGS["pool_size"])
    assert env.family == "continuous" and env.name == "Continuous-Procedural-Warehouse-v0"
    assert bool(params.randomize) and (env.height, env.width) == (12, 12)
    assert int(params.max_steps) == default_max_steps((12, 12)) == 500
    assert default_max_steps((8, 8)) == 300 and default_max_steps((16, 16)) == 700
    assert env.obs_size == 11 + 32 and params.pool.blocked.shape == (SETTINGS["pool_size"], 12, 12)


def test_the_pool_holds_distinct_solvable_layouts_of_several_sizes(env_params):
    _, params = env_params
    hashes = pool_hashes(params.pool)
    assert np.unique(hashes).size == SETTINGS["pool_size"]
    sizes = set(zip(np.asarray(params.pool.height).tolist(), np.asarray(params.pool.width).tolist()))
    assert len(sizes) > 4 and all(8 <= h <= 12 and 8 <= w <= 12 for h, w in sizes)
    for k in range(SETTINGS["pool_size"]):  # Layout validates: square, cells free and distinct, all reachable
        assert isinstance(slot_layout(params.pool, k), Layout)


def test_batched_rollouts_draw_layouts_by_key_and_start_collision_free(env_params):
    """256 environments under jit and vmap for 60 steps (past the 40-step limit): resets draw a layout per
    key (the same for the same key), every fresh episode is collision-free at its start, and auto-resets
    move environments to other layouts."""
    env, params = env_params
    num_envs, space = 256, env.observation_space()

    def clear(state):
        layout = layout_params(params, state.layout_index)
        gaps = norm(state.pos[None, :] - state.obstacle_pos)
        return (~hits_shelf(state.pos, params.robot_radius, layout.shelves)
                & ~hits_wall(state.pos, params.robot_radius, 12, 12)
                & jnp.all(gaps >= params.robot_radius + params.obstacle_radius))

    def rollout(key):
        reset_key, run_key = jax.random.split(key)
        obs, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(reset_key, num_envs), params)
        goals = jax.vmap(lambda k: layout_params(params, k).goal)(state.layout_index)

        def body(state, key):
            action_key, step_key = jax.random.split(key)
            actions = jax.random.uniform(action_key, (num_envs, 2), minval=-1.0, maxval=1.0)
            obs, state, _, terminated, truncated, info = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                jax.random.split(step_key, num_envs), state, actions, params)
            done = terminated | truncated
            fresh_ok = jnp.all(jax.vmap(clear)(state) | ~done) & jnp.all((state.time == 0) == done)
            return state, (state.layout_index, jnp.all(jax.vmap(space.contains)(obs)), done, info["collision"],
                           fresh_ok)

        _, trace = jax.lax.scan(body, state, jax.random.split(run_key, STEPS))
        return obs, state, goals, jnp.all(jax.vmap(clear)(state)), trace

    program = commands_level.jit(rollout)  # a claim about a level-1 program (tests/commands_level.py)
    obs0, state0, goals, start_ok, (slots, obs_ok, done, collision, fresh_ok) = program(jax.random.key(1))
    again = program(jax.random.key(1))
    assert all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(jax.tree.leaves((obs0, state0, slots)),
                                                                             jax.tree.leaves(again[:2] + again[4][:1])))
    first = np.asarray(state0.layout_index)
    assert np.unique(first).size >= 24  # 256 draws over 32 slots
    # The episode's layout is the slot's: its goal in the observation, its item among the slot's items.
    np.testing.assert_allclose(np.asarray(obs0)[:, 6:8], np.asarray(goals) / 12.0, rtol=1e-6)
    items = np.asarray(params.pool.items)[first][:, :, ::-1] + 0.5
    assert (np.asarray(state0.item)[:, None, :] == items).all(axis=-1).any(axis=-1).all()
    assert bool(start_ok) and np.asarray(fresh_ok).all() and np.asarray(obs_ok).all()
    assert np.asarray(done).sum() >= num_envs and np.asarray(collision).any()
    assert (np.asarray(slots)[-1] != first).sum() > num_envs // 2


# ------------------------------------------------------------------ parity with the plain environment
def test_a_transition_on_slot_k_is_the_plain_env_on_layout_k(env_params):
    """Same key, same state, same action: the plain environment built from the slot's layout (padding as
    shelves) gives the same observation (the target's features included), state, reward, flags and info,
    bit for bit, over 60 steps (a slot whose floor is smaller than the padded map, with its 2 moving
    obstacles, randomized)."""
    env, params = env_params
    slot = int(np.flatnonzero(np.asarray(params.pool.height) * np.asarray(params.pool.width) < 144)[0])
    plain, plain_params = make_continuous(slot_layout(params.pool, slot), max_steps=SETTINGS["max_steps"],
                                          num_rays=SETTINGS["num_rays"], num_obstacles=SETTINGS["num_obstacles"],
                                          randomize=True, observe_target=True)

    def run(key):
        reset_key, run_key = jax.random.split(key)
        ours, theirs = env.reset_to(jnp.int32(slot), reset_key, params), plain.reset_env(reset_key, plain_params)

        def body(carry, key):
            mine, other = carry
            action_key, step_key = jax.random.split(key)
            action = act(action_key, other, plain_params.goal)
            a = env.transition(step_key, mine, action, params)
            b = plain.transition(step_key, other, action, plain_params)
            return (a[1], b[1]), (a, b)

        _, (a, b) = jax.lax.scan(body, (ours[1], theirs[1]), jax.random.split(run_key, STEPS))
        return ours, theirs, a, b

    # A claim about a level-1 program (tests/commands_level.py): both environments' steps compiled in one.
    ours, theirs, a, b = commands_level.jit(jax.vmap(run))(jax.random.split(jax.random.key(slot), 8))
    assert (np.asarray(ours[1].layout_index) == slot).all() and (np.asarray(a[1].layout_index) == slot).all()
    for mine, other in ((ours, theirs), (a, b)):
        mine_obs, mine_state, *rest = mine
        other_obs, other_state, *other_rest = other
        np.testing.assert_array_equal(np.asarray(mine_obs), np.asarray(other_obs))
        for field in vars(other_state):
            np.testing.assert_array_equal(np.asarray(getattr(mine_state, field)),
                                          np.asarray(getattr(other_state, field)))
        for x, y in zip(jax.tree.leaves(rest), jax.tree.leaves(other_rest)):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert np.asarray(a[5]["collision"]).any() and np.asarray(a[5]["obstacle_landed"]).any()


def test_padding_walls_in_a_smaller_floor(env_params):
    """The padded grid of a smaller floor behaves as that floor alone (walls at its edge): positions, rewards,
    contacts and lidar distances agree; only the observation's normalization (by the padded size) differs."""
    _, params = env_params
    heights, widths = np.asarray(params.pool.height), np.asarray(params.pool.width)
    slot = int(np.flatnonzero((heights == widths) & (heights < 12))[0])
    side = int(heights[slot])
    padded = slot_layout(params.pool, slot)
    real = Layout(shelves=padded.shelves[:side, :side], start=padded.start, goal=padded.goal, items=padded.items)
    envs = [make_continuous(layout, max_steps=40, num_rays=8, randomize=True) for layout in (padded, real)]

    def run(key):
        reset_key, run_key = jax.random.split(key)
        starts = [env.reset_env(reset_key, p) for env, p in envs]

        def body(states, key):
            action_key, step_key = jax.random.split(key)
            action = act(action_key, states[1], envs[1][1].goal)
            outs = [env.transition(step_key, s, action, p) for (env, p), s in zip(envs, states)]
            return [o[1] for o in outs], [(o[0], o[1].pos, o[2], o[5]["collision"], o[5]["picked_up"]) for o in outs]

        return jax.lax.scan(body, [s for _, s in starts], jax.random.split(run_key, STEPS))[1]

    big, small = fast_compile.jit(jax.vmap(run))(jax.random.split(jax.random.key(5), 8))  # tolerances: level 0
    np.testing.assert_allclose(np.asarray(big[1]), np.asarray(small[1]), atol=1e-5)
    np.testing.assert_allclose(np.asarray(big[2]), np.asarray(small[2]), atol=1e-4)
    np.testing.assert_array_equal(np.asarray(big[3]), np.asarray(small[3]))
    np.testing.assert_array_equal(np.asarray(big[4]), np.asarray(small[4]))
    assert np.asarray(big[3]).any()
    lidar_range = float(params.lidar_range)
    np.testing.assert_allclose(np.asarray(big[0])[..., 11:] * lidar_range, np.asarray(small[0])[..., 11:] * lidar_range,
                               atol=1e-4)
    np.testing.assert_allclose(np.asarray(big[0])[..., :2] * 12, np.asarray(small[0])[..., :2] * side, atol=1e-5)


# ------------------------------------------------------------------ held-out layouts and evaluation
def test_the_heldout_set_shares_no_layout_with_the_pool(env_params):
    env, params = env_params
    seen = env.training_layout_hashes(params)
    heldout, overlap = heldout_set(env.generator, seen, 32)
    assert heldout.size + overlap == 32 and heldout.size > 0
    assert not np.isin(pool_hashes(heldout.layouts), seen).any()


def test_settings_are_refused_with_the_setting_named(env_params):
    cases = [
        ({"pool_size": 0}, "pool_size"),
        ({"pool_size": 70_000}, "pool_size"),
        ({"pool_size": 2.5}, "pool_size"),
        ({"max_shape": (12, 10)}, "square"),
        ({"max_shape": 12}, "max_shape must be two integers"),
        ({"min_shape": (14, 14)}, "min_shape"),
        ({"wheels": 3}, "unknown option"),
        ({"density": (0.5, 0.2)}, "density"),
        ({"num_obstacles": -1}, "num_obstacles"),
        ({**SETTINGS, "dt": -0.1}, "dt must be positive"),
        ({**SETTINGS, "max_steps": 0}, "max_steps"),
        ({**SETTINGS, "num_obstacles": 60}, "fewer cells where a moving obstacle"),
    ]
    for settings, message in cases:
        with pytest.raises(ValueError, match=message):
            make_continuous_procedural(**settings)


class _Algo:
    """What a final report reads of an algorithm: the greedy action (here: a fixed command per seed)."""

    @staticmethod
    def greedy_action(network_params, obs):
        return jnp.stack([network_params, jnp.float32(0.3)])


def test_the_family_hook_evaluates_pool_layouts_and_heldout_sets(env_params, monkeypatch):
    env, params = env_params

    def evaluate(p):  # the evaluation and its scalars in one program
        result = evaluation.evaluate_policy(_Algo.greedy_action, p, env, params)
        return result, evaluation.seed_summary(result)

    # NumPy: eagerly each op compiles. Level 0: shapes, masks and ranges are checked, no bits.
    result, scalars = jax.device_get(fast_compile.jit(evaluate)(jnp.float32(0.5)))
    assert result.valid.shape == (16, evaluation.OBSTACLE_ROUNDS, 8)  # 16 pool slots x rounds x item rows
    np.testing.assert_array_equal(np.asarray(result.valid[:, 0]),
                                  np.arange(8)[None, :] < np.asarray(params.pool.num_items)[:16, None])
    summary = evaluation.summarize(jax.tree.map(lambda x: x[None], result))
    assert summary["layouts"] == 16 and summary["rounds"] == evaluation.OBSTACLE_ROUNDS
    assert summary["episodes"] == int(np.asarray(params.pool.num_items)[:16].sum()) * evaluation.OBSTACLE_ROUNDS
    assert "16 layouts" in evaluation.format_report(summary, "test")
    assert 0.0 <= float(scalars["eval_success_rate"]) <= 1.0 and float(scalars["eval_collisions"]) > 0
    # The final report: held-out and out-of-distribution layouts, two seeds (sizes shrunk for the test).
    # The generated out-of-distribution sets are the grid family's (tested there); the study maps stand for them.
    monkeypatch.setattr(procedural_evaluation, "HELDOUT_LAYOUTS", 32)
    monkeypatch.setattr(procedural_evaluation, "ood_sets", lambda generator, count, *, long_routes: [
        LayoutSet(f"study_{name}", name, stack([study_layout(name, generator.max_shape)]))
        for name in ("8x8", "12x12")])
    context = FinalContext(algo=_Algo, network_params=jnp.array([0.0, 0.6], jnp.float32), env=env, params=params,
                           seeds=[0, 1])
    report = evaluation.EVALUATION.final_report(context)
    heldout = report["heldout"]
    assert heldout["overlap_with_training"] + heldout["layouts"] + heldout["excluded_layouts"] == 32
    assert heldout["layouts"] > 0 and heldout["rounds"] == evaluation.OBSTACLE_ROUNDS
    assert 0.0 <= heldout["success_rate"] <= 1.0 and [row["seed"] for row in heldout["per_seed"]] == [0, 1]
    assert {"mean_steps", "collisions_per_episode", "collision_free_rate", "mean_return"} <= set(heldout)
    assert set(report["ood"]) == {"study_8x8", "study_12x12"}
    assert report["ood"]["study_12x12"]["episodes_per_seed"] == 20 * evaluation.OBSTACLE_ROUNDS
    # Beside each set, the controller on the same episodes; the bound is left out (randomization voids it).
    for entry in (heldout, *report["ood"].values()):
        assert set(entry["pursuit"]) == {"success_rate", "mean_steps", "collisions_per_episode", "collision_free_rate"}
        assert "bound_steps" not in entry
    assert heldout["pursuit"]["success_rate"] > heldout["success_rate"]  # against a fixed command
    # A fixed layout gets the yardstick on its evaluation's episodes instead (tests/envs/continuous/test_yardstick.py).
    plain, plain_params = wrl_jax.make("Continuous-Warehouse-8x8-v0")
    monkeypatch.setattr(evaluation, "yardstick_report", lambda env, params: {"env": env.name})
    report = evaluation.EVALUATION.final_report(FinalContext(_Algo, None, plain, plain_params, [0]))
    assert report == {"yardstick": {"env": "Continuous-Warehouse-8x8-v0"}}


def test_the_yardstick_beside_the_sets_is_the_fixed_layouts_whatever_the_view():
    """Pursuit and the bound beside the final report's sets: the study's 8x8 map padded into the pool's shape
    gives the plain 8x8 map's controller and bound; on held-out layouts of several items (plans of different
    lengths, padded together) the bound is each layout's own, and the learners' safety stop changes nothing the
    controller does (it drives the contract's environment)."""
    from wrl_jax.envs.continuous.procedural_layouts import with_pool
    from wrl_jax.envs.continuous.yardstick import item_bounds

    settings = {"pool_size": 2, "num_rays": 8, "randomize": False, "max_steps": 300}
    env, params = make_continuous_procedural(**settings)
    guarded, guarded_params = make_continuous_procedural(**settings, safety_stop=True, safety_margin=0.2)
    study = LayoutSet("study_8x8", "8x8", stack([study_layout("8x8", env.generator.max_shape)]))
    heldout, _ = heldout_set(env.generator, env.training_layout_hashes(params), 6)
    reports = [procedural_evaluation.evaluate_layout_sets(_Algo.greedy_action, jnp.array([0.0], jnp.float32), e,
                                                          p, [study, heldout], [0])
               for e, p in ((env, params), (guarded, guarded_params))]
    assert reports[0]["heldout"]["pursuit"] == reports[1]["heldout"]["pursuit"]
    assert reports[0]["study_8x8"]["pursuit"] == reports[1]["study_8x8"]["pursuit"]

    _, plain_params = wrl_jax.make("Continuous-Warehouse-8x8-v0")
    plain_bounds = item_bounds(plain_params)
    entry = reports[0]["study_8x8"]
    assert entry["bound_steps"] == pytest.approx(plain_bounds["steps"].mean(), rel=1e-6)
    assert entry["pursuit"]["success_rate"] == 1.0 and entry["pursuit"]["collisions_per_episode"] == 0.0
    # As on the plain map (tests/envs/continuous/test_yardstick.py): never under the strict bound, within 3 %.
    assert plain_bounds["strict_steps"].mean() <= entry["pursuit"]["mean_steps"] <= 1.03 * entry["bound_steps"]

    layouts = with_pool(params, heldout.layouts)
    counts = np.asarray(heldout.layouts.num_items)
    assert counts.max() > counts.min()  # plans and item rows of different sizes, padded together
    bounds = [item_bounds(layout_params(layouts, k))["steps"] for k in range(heldout.size)]
    assert reports[0]["heldout"]["episodes_per_seed"] == counts.sum()
    assert reports[0]["heldout"]["bound_steps"] == pytest.approx(np.concatenate(bounds).mean(), rel=1e-9)
    assert reports[0]["heldout"]["pursuit"]["success_rate"] == 1.0


def test_the_report_prints_a_row_per_set_with_what_it_measured():
    """The final report's sets in the printed table: the policy, the controller and the bound where measured;
    a set left empty (every layout excluded) prints nothing."""
    outcome = {"success_rate": 0.5, "collisions_per_episode": 1.0, "mean_steps": 80.0}
    summary = {"success_rate": 0.8, "mean_steps": 90.0, "collisions_per_episode": 0.5, "collision_free_rate": 0.5,
               "mean_return": 1.0, "num_items": 5, "rounds": 1, "num_seeds": 1, "layouts": 16,
               "per_seed": [{"success_rate": 0.8, "collision_free_rate": 0.5}],
               "heldout": {"layouts": 250, "episodes_per_seed": 900, **outcome, "bound_steps": 61.25,
                           "pursuit": {**outcome, "success_rate": 1.0, "mean_steps": 70.0}},
               "ood": {"dense": {"layouts": 64, "episodes_per_seed": 100, **outcome},
                       "empty": {"layouts": 0, "episodes_per_seed": 0}}}
    rows = evaluation.format_report(summary, "test").splitlines()
    assert ("| 250 held-out layouts | 50.0% delivered, 1.000 collisions per episode, 80.0 steps; pursuit, same "
            "episodes: 100.0% delivered, 1.000 collisions per episode, 70.0 steps; the contract's bound 61.2 |") in rows
    assert "| 64 dense (out of distribution) | 50.0% delivered, 1.000 collisions per episode, 80.0 steps |" in rows
    assert not any("empty" in row for row in rows)


def test_sac_builds_and_updates_on_it(env_params):
    from wrl_jax.agents.base import make_train
    from wrl_jax.agents.off_policy_config import SACConfig
    from wrl_jax.agents.sac import SAC

    env, params = env_params
    config = SACConfig(num_envs=4, total_timesteps=16, learning_starts=4, batch_size=4, hidden_sizes=(8,),
                       buffer_size=16)
    algo = SAC(config, env, params)
    runner, metrics = fast_compile.jit(make_train(algo, num_updates=3))(jax.random.key(0))  # finite: level 0
    assert all(np.isfinite(np.asarray(v)).all() for v in jax.tree.leaves(metrics))
    assert np.asarray(runner.env_state.layout_index).shape == (4,)
