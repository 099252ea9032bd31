"""The continuous NumPy reference against docs/CONTINUOUS_SPEC.md, value by value, worked out by hand.

Every expected number below comes from the contract's formulas evaluated in float32 (one rounding
per written operation), not from the reference itself; where an exact float32 value is asserted,
the comment says why it is exact.
"""

from __future__ import annotations

import numpy as np
import pytest

from wrl_jax.envs.continuous import reference as ref
from wrl_jax.envs.continuous.reference import ReferenceEnv, next_waypoint_cell, reset, step
from wrl_jax.envs.continuous.reference_geometry import PI as geo_PI
from wrl_jax.envs.continuous.reference_geometry import (
    collision_flags,
    lidar_distances,
    lidar_values,
    ray_distance,
    wrap,
)
from wrl_jax.envs.continuous.reference_types import ContinuousLayout, ContinuousParams, StepDraws, study_max_steps
from wrl_jax.envs.warehouse.maps import WAREHOUSE_8X8, WAREHOUSE_12X12

F = np.float32
HALF_PI = F(np.pi / 2)
LAY8 = ContinuousLayout.from_text(WAREHOUSE_8X8)
# 6x6: shelves (2,2) (2,4) (3,2) (3,4) (4,2) (4,3) (4,4) make (3,3), the item, a dead end below (2,3).
POCKET = ContinuousLayout.from_text("""
S . . . . .
. . . . . .
. . # . # .
. . # 0 # .
. . # # # .
. . . . . G
""")


def start(layout=LAY8, item=0, cells=(), us=(), **kw):
    params = ContinuousParams(num_obstacles=len(cells), **kw)
    state, obs = reset(layout, params, item, np.array(cells, np.int32).reshape(-1, 2), np.array(us, F))
    return params, state, obs


def at(state, x, y, theta=0.0, **changes):
    return state.replace(pos=np.array([x, y], F), theta=F(theta), **changes)


def go(state, action, layout=LAY8, params=None, **draws):
    params = params or ContinuousParams(num_obstacles=len(state.obstacle_pos))
    zero = StepDraws.zeros(params)
    d = StepDraws(**{f: np.asarray(draws.get(f, getattr(zero, f))) for f in
                     ("noise", "waypoint_u", "lidar_noise", "lidar_drop")})
    return step(state, np.asarray(action, F), layout, params, d)


# ------------------------------------------------------------------ kinematics
def test_wrap_maps_into_minus_pi_pi():
    assert wrap(F(0)) == 0
    assert wrap(geo_PI) == -geo_PI  # pi + pi = 2pi exactly, floor(1) = 1, pi - 2pi = -pi exactly
    assert wrap(-geo_PI) == -geo_PI
    np.testing.assert_allclose(wrap(F(4.0)), 4.0 - 2 * np.pi, atol=1e-6)
    np.testing.assert_allclose(wrap(F(-4.0)), 2 * np.pi - 4.0, atol=1e-6)
    for t in np.linspace(-20, 20, 401, dtype=F):
        assert -geo_PI <= wrap(t) <= geo_PI


def test_straight_drive_advances_exactly_v_dt():
    params, s, _ = start()
    assert s.pos.tolist() == [0.5, 0.5] and s.theta == 0
    for _ in range(5):
        x = s.pos[0]
        s2, obs, reward, term, trunc, info = go(s, [1.0, 0.0])
        # cos 0 = 1, sin 0 = 0: x + (1 * 0.2f) * 1, y + 0.2f * 0 exactly.
        assert s2.pos[0] == F(x + F(0.2)) and s2.pos[1] == F(0.5) and s2.theta == 0
        shaping = F(F(2.0) * F(F(F(6.5) - x) - F(F(6.5) - s2.pos[0])))  # towards item 0 at (6.5, 0.5)
        assert reward == F(F(-0.5) + shaping)
        np.testing.assert_allclose(reward, -0.1, atol=1e-5)
        assert obs[4] == 1 and obs[5] == 0 and obs[2] == 1 and obs[3] == 0 and obs[0] == F(s2.pos[0] / F(8))
        assert not (term or trunc or info["collision"])
        s = s2


def test_turn_only_step():
    _, s, _ = start()
    s2, obs, reward, _, _, info = go(s, [0.0, 1.0])
    assert s2.theta == F(0.4)  # w dt = 2 * 0.2f = 0.4f exactly (a doubling); floor((0.4 + pi) / 2pi) = 0
    assert s2.pos.tolist() == [0.5, 0.5] and reward == F(-0.5) and not info["collision"]
    assert obs[5] == 1 and obs[4] == 0
    np.testing.assert_allclose(obs[2:4], [np.cos(0.4), np.sin(0.4)], atol=1e-7)
    for _ in range(7):
        s2, *_ = go(s2, [0.0, 1.0])
    np.testing.assert_allclose(s2.theta, 3.2 - 2 * np.pi, atol=1e-5)  # 8 turns of 0.4 wrap past pi


def test_gains_and_noise_shape_the_command():
    _, s, _ = start()
    s = s.replace(gains=np.array([1.2, 0.8], F))
    s2, obs, *_ = go(s, [1.0, 0.5], noise=np.array([0.05, -0.1], F))
    v = F(F(F(1.0) * F(1.0)) * F(1.2)) + F(0.05)
    w = F(F(F(2.0) * F(0.5)) * F(0.8)) + F(-0.1)
    assert obs[4] == v and obs[5] == F(w / F(2))
    np.testing.assert_allclose([obs[4], obs[5]], [1.25, 0.35], atol=1e-6)
    assert s2.theta == wrap(F(F(0) + F(w * F(0.2))))
    assert s2.pos[0] == F(F(0.5) + F(F(v * F(0.2)) * F(np.cos(np.float64(s2.theta)))))


# ------------------------------------------------------------------ collisions
def test_drive_into_shelf_keeps_centre_turns_and_pays():
    _, s, _ = start()
    s = at(s, 1.5, 1.6, HALF_PI)  # 0.4 m above shelf (2,1), whose square starts at y = 2
    s2, obs, reward, _, _, info = go(s, [1.0, 0.1])
    assert s2.pos.tolist() == s.pos.tolist()
    np.testing.assert_allclose(s2.theta, np.pi / 2 + 0.04, atol=1e-6)
    assert info["collision"] and info["hit_shelf"] and not info["hit_wall"] and not info["hit_obstacle"]
    assert reward == F(-10.5)  # -0.5 - 10 + 2 * 0 (p' = p)
    assert obs[4] == 1 and obs[5] == F(0.1)  # the applied commands, also on a collision step


def test_wall_may_be_touched_exactly_then_hit():
    _, s, _ = start()
    s = at(s, 7.5, 0.5)
    s2, obs, reward, _, _, info = go(s, [1.0, 0.0])
    # qx = 7.5 + 0.2f = 7.7f and 7.7f + 0.3f rounds to exactly 8: not > W, a touch is allowed.
    assert s2.pos[0] == F(7.5) + F(0.2) and F(s2.pos[0] + F(0.3)) == 8 and not info["collision"]
    np.testing.assert_allclose(obs[11], 0.3 / 4.0, atol=1e-6)  # a robot touching a wall reads rr / range
    s3, _, reward, _, _, info = go(s2, [1.0, 0.0])
    assert info["hit_wall"] and info["collision"] and not info["hit_shelf"]
    assert s3.pos.tolist() == s2.pos.tolist() and reward == F(-10.5)


def test_boundary_inequalities_as_written():
    params = ContinuousParams()
    none = np.zeros((0, 2), F)
    qx = np.nextafter(F(7.7), F(9))  # qx + rr rounds to 8 (not > W), though qx > W - rr
    assert F(qx + F(0.3)) == 8 and qx > F(F(8) - F(0.3))
    assert collision_flags(np.array([qx, 4.5], F), LAY8, params, none) == (False, False, False)
    assert collision_flags(np.array([7.71, 4.5], F), LAY8, params, none)[1]
    assert collision_flags(np.array([0.3, 4.5], F), LAY8, params, none) == (False, False, False)
    assert collision_flags(np.array([np.nextafter(F(0.3), F(0)), 4.5], F), LAY8, params, none)[1]
    assert collision_flags(np.array([4.5, 7.7], F), LAY8, params, none) == (False, False, False)
    assert collision_flags(np.array([4.5, 0.29], F), LAY8, params, none)[1]


# ------------------------------------------------------------------ pickup, delivery, truncation
def test_pickup_at_reach_radius_and_not_beyond():
    _, s, _ = start(item=1)  # item 1 at cell (1,3): point (3.5, 1.5)
    # 3.5 - x is exact for x in [1.75, 7] (Sterbenz) and sqrt(fl(d*d)) = d: the test reads d itself.
    x_in = F(3.15)
    while F(F(3.5) - x_in) > F(0.35):
        x_in = np.nextafter(x_in, F(4))
    x_out = np.nextafter(x_in, F(0))
    assert F(F(3.5) - x_in) <= F(0.35) < F(F(3.5) - x_out)
    s2, obs, reward, *_ , info = go(at(s, x_in, 1.5), [0.0, 0.0])
    assert info["picked_up"] and s2.carrying and reward == F(49.5)  # -0.5 + 0 shaping + 50
    assert obs[8] == -1 and obs[9] == -1 and obs[10] == 1
    assert s2.item.tolist() == [3.5, 1.5]  # the item point is kept
    s3, obs, reward, *_, info = go(at(s, x_out, 1.5), [0.0, 0.0])
    assert not info["picked_up"] and not s3.carrying and reward == F(-0.5)
    assert obs[8] == F(F(3.5) / F(8)) and obs[10] == 0
    # A binary reach radius makes the tie exact: |p' - item| == reach_radius picks up (<=).
    params = ContinuousParams(reach_radius=0.375)
    _, _, _, _, _, info = go(at(s, 3.125, 1.5), [0.0, 0.0], LAY8, params)
    assert info["picked_up"]
    _, _, _, _, _, info = go(at(s, np.nextafter(F(3.125), F(0)), 1.5), [0.0, 0.0], LAY8, params)
    assert not info["picked_up"]


def test_delivery_terminates_without_step_penalty():
    _, s, _ = start()
    s = at(s, 7.5, 7.3, HALF_PI, carrying=True)
    s2, obs, reward, term, trunc, info = go(s, [1.0, 0.0])
    assert term and info["delivered"] and not trunc and not info["picked_up"]
    goal = F(7.5)
    d_p = F(abs(F(s.pos[0] - goal)) + abs(F(s.pos[1] - goal)))
    d_q = F(abs(F(s2.pos[0] - goal)) + abs(F(s2.pos[1] - goal)))
    assert reward == F(F(F(0) + F(F(2) * F(d_p - d_q))) + F(200))
    np.testing.assert_allclose(reward, 200.4, atol=1e-4)


def test_carrying_shapes_towards_goal():
    _, s, _ = start()
    s = at(s, 2.5, 0.5, 0.0, carrying=True)  # goal (7.5, 7.5): one step east gains 0.2 m
    _, _, reward, *_ = go(s, [1.0, 0.0])
    np.testing.assert_allclose(reward, -0.5 + 0.4, atol=1e-5)


def test_truncation_at_max_steps_and_obstacles_still_move():
    params, s, _ = start(POCKET, cells=[(1, 3)], us=[0.3], max_steps=5)
    s = s.replace(time=4)
    s2, _, _, term, trunc, _ = go(s, [0.0, 0.0], POCKET, params, waypoint_u=np.zeros(1, F))
    assert s2.time == 5 and trunc and not term
    assert s2.obstacle_pos[0, 1] > s.obstacle_pos[0, 1]
    _, _, _, term, trunc, _ = go(s.replace(time=2), [0.0, 0.0], POCKET, params, waypoint_u=np.zeros(1, F))
    assert not trunc and not term
    # Delivered on the last step: terminated, not truncated.
    params8 = ContinuousParams(max_steps=5)
    _, _, _, term, trunc, _ = go(at(s, 7.5, 7.4, 0.0, carrying=True, time=4, obstacle_pos=np.zeros((0, 2), F),
                                    obstacle_waypoint=np.zeros((0, 2), F),
                                    obstacle_from=np.zeros((0, 2), np.int32)), [0.0, 0.0], LAY8, params8)
    assert term and not trunc


def test_invalid_actions():
    _, s, _ = start()
    s2, obs, _, _, _, info = go(s, [np.nan, 1.0])
    assert info["invalid_action"] and s2.pos.tolist() == [0.5, 0.5] and s2.theta == F(0.4) and obs[4] == 0
    _, obs, _, _, _, info = go(s, [np.inf, -np.inf])
    assert not info["invalid_action"] and obs[4] == 1 and obs[5] == -1
    params = ContinuousParams()
    with pytest.raises(ValueError, match=r"\(3,\)"):
        step(s, np.zeros(3, F), LAY8, params, StepDraws.zeros(params))
    with pytest.raises(ValueError, match=r"\(1, 2\)"):
        step(s, np.zeros((1, 2), F), LAY8, params, StepDraws.zeros(params))


# ------------------------------------------------------------------ moving obstacles
def test_waypoint_rule_branches():
    # (4,2) of the 8x8 map: up (3,2), down (5,2), left (4,1), right (4,3) are all free.
    assert next_waypoint_cell(LAY8, (4, 2), None, 0.0) == (3, 2)  # first waypoint: no exclusion
    came = (3, 2)  # eligible: down, left, right
    assert next_waypoint_cell(LAY8, (4, 2), came, 0.0) == (5, 2)
    assert next_waypoint_cell(LAY8, (4, 2), came, 0.5) == (4, 1)  # floor(1.5) = 1
    assert next_waypoint_cell(LAY8, (4, 2), came, np.nextafter(F(1), F(0))) == (4, 3)
    assert next_waypoint_cell(LAY8, (4, 2), came, 1.0) == (4, 3)  # the min(., n - 1) guard
    assert next_waypoint_cell(LAY8, (0, 7), None, 0.5) == (0, 6)  # map edge: [down, left]
    assert next_waypoint_cell(LAY8, (1, 2), None, 0.4) == (1, 1)  # shelf (2,2) skipped: [up, left, right]
    assert next_waypoint_cell(POCKET, (3, 3), (2, 3), 0.7) == (2, 3)  # dead end: back where it came from
    lonely = ContinuousLayout.from_text("S . # .\n. . . #\n. . . .\n. 0 . G")  # (0,3) has no free neighbour
    assert next_waypoint_cell(lonely, (0, 3), None, 0.5) == (0, 3)


def test_obstacle_travels_lands_exactly_and_replans():
    params, s, _ = start(POCKET, cells=[(1, 3)], us=[0.3])
    # From (1,3): [up, down, left, right], floor(0.3 * 4) = 1 -> down (2,3).
    assert s.obstacle_waypoint.tolist() == [[3.5, 2.5]] and s.obstacle_from.tolist() == [[1, 3]]
    s_speed = F(F(0.5) * F(0.2))
    for _ in range(12):
        y = s.obstacle_pos[0, 1]
        s, _, _, _, _, info = go(s, [0.0, 0.0], POCKET, params, waypoint_u=np.zeros(1, F))
        if info["obstacle_landed"][0]:
            break
        assert s.obstacle_pos[0].tolist() == [3.5, F(y + s_speed)]  # d / |d| = (0, 1) exactly
    assert info["obstacle_landed"][0] and not info["obstacle_waited"][0]
    assert F(F(2.5) - y) <= s_speed and s.obstacle_pos[0].tolist() == [3.5, 2.5]
    # At (2,3) came from (1,3): only down (3,3) is eligible. u = 0 would pick up (1,3) without the exclusion.
    assert s.obstacle_waypoint.tolist() == [[3.5, 3.5]] and s.obstacle_from.tolist() == [[2, 3]]
    for _ in range(12):
        s, _, _, _, _, info = go(s, [0.0, 0.0], POCKET, params, waypoint_u=np.full(1, 0.9, F))
        if info["obstacle_landed"][0]:
            break
    # (3,3) is a dead end: back to (2,3), whatever u says.
    assert s.obstacle_pos[0].tolist() == [3.5, 3.5]
    assert s.obstacle_waypoint.tolist() == [[3.5, 2.5]] and s.obstacle_from.tolist() == [[3, 3]]


def test_obstacle_waits_for_the_robot():
    params, s, _ = start(POCKET, cells=[(1, 3)], us=[0.3])  # heading down to (3.5, 2.5)
    s = at(s, 3.5, 2.15)  # 0.65 from the obstacle now, 0.55 after its move: it waits
    s2, _, _, _, _, info = go(s, [0.0, 0.0], POCKET, params, waypoint_u=np.zeros(1, F))
    assert info["obstacle_waited"][0] and not info["obstacle_landed"][0] and not info["collision"]
    assert s2.obstacle_pos.tolist() == s.obstacle_pos.tolist()
    assert s2.obstacle_waypoint.tolist() == s.obstacle_waypoint.tolist()
    s3, _, _, _, _, info = go(at(s, 3.5, 2.3), [0.0, 0.0], POCKET, params, waypoint_u=np.zeros(1, F))
    assert not info["obstacle_waited"][0] and s3.obstacle_pos[0, 1] > s.obstacle_pos[0, 1]
    # About to land but the landing point is 0.56 from the robot: wait, keep waypoint and came-from cell.
    s = at(s, 3.5, 3.06, obstacle_pos=np.array([[3.5, 2.45]], F))
    s4, _, _, _, _, info = go(s, [0.0, 0.0], POCKET, params, waypoint_u=np.zeros(1, F))
    assert info["obstacle_waited"][0] and not info["obstacle_landed"][0] and not info["collision"]
    assert s4.obstacle_pos.tolist() == [[3.5, F(2.45)]] and s4.obstacle_from.tolist() == [[1, 3]]


def test_robot_hits_obstacle_where_it_was_before_the_step():
    params, s, _ = start(POCKET, cells=[(1, 3)], us=[0.0])  # heading up to (3.5, 0.5), away from the robot
    s = at(s, 3.5, 2.25, -HALF_PI)
    s2, _, reward, _, _, info = go(s, [1.0, 0.0], POCKET, params, waypoint_u=np.zeros(1, F))
    # q = (3.5, 2.05): 0.55 from the obstacle before the step (hit), 0.65 from where it goes (no hit).
    assert info["hit_obstacle"] and info["collision"] and not info["hit_shelf"] and not info["hit_wall"]
    assert s2.pos.tolist() == s.pos.tolist() and reward == F(-10.5)
    np.testing.assert_allclose(s2.obstacle_pos[0], [3.5, 1.4], atol=1e-6)


# ------------------------------------------------------------------ lidar
def test_lidar_exact_shelf_and_boundary_distances():
    params, s, _ = start(num_rays=4)
    s = at(s, 0.5, 2.5)  # cell (2,0); shelf (2,1) starts at x = 1
    _, obs, *_ = go(s, [0.0, 0.0], LAY8, params)
    assert obs[11] == 0.125  # 0.5 / 4 exactly: ray (1, 0)
    np.testing.assert_allclose(obs[11:], [0.125, 1.0, 0.125, 0.625], atol=1e-6)  # east, +y (clipped), west, -y
    assert obs.shape == (15,) and obs.dtype == np.float32


def test_lidar_edges_and_corners_are_closed():
    params = ContinuousParams()
    none = np.zeros((0, 2), F)
    # Along the top edge y = 2 of shelf (2,1): hits at x = 1.
    assert ray_distance((0.5, 2.0), (1.0, 0.0), LAY8, params, none) == 0.5
    assert lidar_distances(np.array([0.5, 2.0], F), F(0), LAY8, params, none)[0] == 0.5
    # Through the corner (4, 6) of shelf (5,4) only: t = 2; a hair off it, the wall at y = 8 (t = 4 / 1.001).
    assert ray_distance((2.0, 4.0), (1.0, 1.0), LAY8, params, none) == 2.0
    np.testing.assert_allclose(ray_distance((2.0, 4.0), (1.0, 1.001), LAY8, params, none), 4 / 1.001, rtol=1e-6)


def test_lidar_reads_obstacles_after_they_move():
    params, s, obs = start(POCKET, cells=[(0, 3)], us=[0.0])  # from (0,3): [down, left, right] -> down
    np.testing.assert_allclose(obs[11], (3.0 - 0.3) / 4.0, atol=1e-6)  # |o - p| - obstacle_radius
    s2, obs, *_ = go(s, [0.0, 0.0], POCKET, params, waypoint_u=np.zeros(1, F))
    assert s2.obstacle_pos[0].tolist() == [3.5, F(F(0.5) + F(0.1))]
    np.testing.assert_allclose(obs[11], (3.0 - np.sqrt(0.09 - 0.01)) / 4.0, atol=1e-6)


def test_lidar_tangent_hits_and_range_clips():
    params = ContinuousParams(obstacle_radius=0.25)  # exact binary values: a r^2 - h^2 = 0 exactly
    assert ray_distance((0.5, 0.5), (1.0, 0.0), LAY8, params, np.array([[3.5, 0.75]], F)) == 3.0
    assert ray_distance((0.5, 0.5), (1.0, 0.0), LAY8, params, np.array([[3.5, 0.7500001]], F)) == 7.5
    assert lidar_values(np.array([7.5, 4.0, 3.0], F), params).tolist() == [1.0, 1.0, 0.75]


def test_randomized_lidar_noise_clip_and_dropout():
    params = ContinuousParams()
    t = np.array([0.5, 0.5, 0.5, 3.99, 0.5], F)
    noise = np.array([0.1, -1.0, 0.0, 0.5, 0.0], F)
    drop = np.array([False, False, False, False, True])
    got = lidar_values(t, params, noise, drop)
    assert got.tolist() == [F(F(0.5) + F(0.1)) / F(4), 0.0, 0.125, 1.0, 1.0]
    _, s, _ = start()
    _, obs, *_ = go(s, [0.0, 0.0], lidar_drop=np.ones(32, bool))
    assert (obs[11:] == 1.0).all()


# ------------------------------------------------------------------ reset, maps, smoke
@pytest.mark.parametrize("cells, match", [
    ([(0, 1)], "Manhattan"), ([(2, 2)], "free"), ([(9, 9)], "free"), ([(5, 5)], "goal"),
    ([(1, 3), (1, 3)], "distinct"),
])
def test_reset_validation_names_the_problem(cells, match):
    params = ContinuousParams(num_obstacles=len(cells))
    with pytest.raises(ValueError, match=match):
        reset(POCKET, params, 0, np.array(cells), np.zeros(len(cells), F))


def test_reset_validation_other_arguments():
    params = ContinuousParams(num_obstacles=1)
    with pytest.raises(ValueError, match="expected 1 obstacle"):
        reset(POCKET, params, 0, np.zeros((0, 2), int), np.zeros(0, F))
    with pytest.raises(ValueError, match="item_index"):
        reset(POCKET, params, 3, np.array([(1, 3)]), np.zeros(1, F))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        reset(POCKET, params, 0, np.array([(1, 3)]), np.array([1.5], F))
    with pytest.raises(ValueError, match="start_jitter"):
        reset(POCKET, params, 0, np.array([(1, 3)]), np.zeros(1, F), start_offset=(0.3, 0.0))
    with pytest.raises(ValueError, match="eligible obstacle cells"):
        ReferenceEnv(POCKET, ContinuousParams(max_steps=10, num_obstacles=40))


def test_study_maps_load_with_their_step_limits():
    lay12 = ContinuousLayout.from_text(WAREHOUSE_12X12)
    assert (LAY8.width, LAY8.height, lay12.width, lay12.height) == (8, 8, 12, 12)
    assert study_max_steps(WAREHOUSE_8X8) == 300 and study_max_steps(lay12) == 500
    assert study_max_steps(POCKET) is None
    assert ContinuousParams.for_layout(WAREHOUSE_12X12).max_steps == 500
    assert ContinuousParams.for_layout(POCKET, max_steps=77).max_steps == 77
    with pytest.raises(ValueError, match="max_steps"):
        ContinuousParams.for_layout(POCKET)
    for layout in (LAY8, lay12):
        cells = ref.eligible_obstacle_cells(layout)[:4]
        params = ContinuousParams.for_layout(layout, num_obstacles=4)
        _, obs = reset(layout, params, 0, cells, np.full(4, 0.5, F))
        n = F(layout.width)
        assert obs.shape == (43,) and obs[0] == F(F(0.5) / n) and obs[6] == F((n - F(0.5)) / n)
        assert obs[8:10].tolist() == [F(F(layout.items[0][1] + 0.5) / n), F(F(layout.items[0][0] + 0.5) / n)]
        assert obs[4] == 0 and obs[5] == 0 and obs[2] == 1 and obs[10] == 0
    assert LAY8.cell_centre(2, 5).tolist() == [5.5, 2.5]


def test_random_play_keeps_the_invariants():
    layout = ContinuousLayout.from_text(WAREHOUSE_12X12)
    params = ContinuousParams.for_layout(layout, num_obstacles=4, randomize=True, num_rays=8)
    env = ReferenceEnv(layout, params, seed=3)
    env.reset()
    rng = np.random.default_rng(0)
    for _ in range(250):
        obs, reward, term, trunc, info = env.step(rng.uniform(-1.2, 1.2, 2))
        s = env.state
        assert obs.shape == (19,) and np.isfinite(obs).all() and reward.dtype == np.float32
        assert ((obs[11:] >= 0) & (obs[11:] <= 1)).all()
        assert not any(collision_flags(s.pos, layout, params, s.obstacle_pos))
        assert (obs[8] == -1) == s.carrying
        for o, w, c in zip(s.obstacle_pos, s.obstacle_waypoint, s.obstacle_from):
            origin = layout.cell_centre(*c)
            assert abs(abs(o - origin).sum() + abs(w - o).sum() - abs(w - origin).sum()) < 1e-5
            assert abs(w - origin).sum() in (0.0, 1.0) and layout.is_free(*c)
