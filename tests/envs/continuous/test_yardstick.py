"""CONTINUOUS_SPEC.md's yardstick: the exact any-angle lower bound and pure pursuit against it.

The bound is checked against geometry worked by hand, against the straight line (below it) and against a
brute-force Dijkstra on a fine 16-connected lattice whose edges are all collision-free (a real path, so
never shorter than the true one). The controller must deliver every item of both study maps without a
collision, never beat the bound a policy cannot beat, wait for a moving obstacle ahead and then step aside.
The controller's programs compile at LLVM level 0 (``fast_compile``): their results are read against thresholds
and bounds, never compared bit for bit.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra
import fast_compile

from wrl_jax.envs.continuous import evaluation
from wrl_jax.envs.continuous import shortest_path as spath
from wrl_jax.envs.continuous import yardstick
from wrl_jax.envs.continuous.pursuit import PursuitConfig, in_the_way, make_plan, pursuit_act, pursuit_init
from wrl_jax.envs.continuous.registration import make_continuous
from wrl_jax.envs.continuous.types import ContinuousState
from wrl_jax.envs.warehouse.layout import Layout
from wrl_jax.envs.warehouse.maps import WAREHOUSE_8X8, WAREHOUSE_12X12

R = 0.3
CONFIG = PursuitConfig()
pursuit_episodes = fast_compile.fast(yardstick.pursuit_episodes, static_argnums=(0, 3, 5, 6))
"""The package's :func:`yardstick.pursuit_episodes` (the same static arguments) at LLVM level 0."""


def centre(cell) -> np.ndarray:
    return np.array([cell[1] + 0.5, cell[0] + 0.5])


def legs(shelves, start, goal, items, radius=R):
    return spath.item_legs(np.asarray(shelves, bool), centre(start), centre(goal),
                           np.array([centre(c) for c in items]), radius)


# ------------------------------------------------------------------ brute force: a fine lattice
def clearance(points: np.ndarray, shelves: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest shelf square or the outside of the map."""
    height, width = shelves.shape
    wall = np.minimum.reduce([points[:, 0], points[:, 1], width - points[:, 0], height - points[:, 1]])
    lows = np.stack(np.nonzero(shelves)[::-1], axis=1).astype(float)
    if not len(lows):
        return wall
    gap = np.maximum(np.maximum(lows[None] - points[:, None], points[:, None] - lows[None] - 1.0), 0.0)
    return np.minimum(wall, np.hypot(gap[..., 0], gap[..., 1]).min(axis=1))


def lattice_lengths(shelves: np.ndarray, sources, targets, radius: float, h: float = 0.05) -> np.ndarray:
    """Shortest 16-connected lattice paths (spacing ``h``) whose every edge is collision-free.

    An edge of length ``l`` is kept when both its ends clear the shelves and walls by ``radius + l / 2``:
    every point of it lies within ``l / 2`` of an end, and clearance is 1-Lipschitz. So each lattice path is
    a real path of the disc, and its length bounds the true shortest one from above.
    """
    height, width = shelves.shape
    n = round(1 / h)
    rows, cols = height * n + 1, width * n + 1
    ys, xs = np.mgrid[0:rows, 0:cols]
    clear = clearance(np.stack([xs.ravel(), ys.ravel()], axis=1) * h, shelves).reshape(rows, cols)
    index = np.arange(rows * cols).reshape(rows, cols)
    heads, tails, lengths = [], [], []
    for dx, dy in [(1, 0), (0, 1), (1, 1), (1, -1), (2, 1), (1, 2), (2, -1), (1, -2)]:
        a = (slice(max(0, -dy), rows - max(0, dy)), slice(0, cols - dx))
        b = (slice(a[0].start + dy, a[0].stop + dy), slice(dx, cols))
        step = h * math.hypot(dx, dy)
        ok = np.minimum(clear[a], clear[b]) - step / 2 >= radius
        heads.append(index[a][ok])
        tails.append(index[b][ok])
        lengths.append(np.full(int(ok.sum()), step))
    graph = sp.csr_matrix((np.concatenate(lengths), (np.concatenate(heads), np.concatenate(tails))),
                          shape=(rows * cols,) * 2)

    def node(point):
        return round(point[1] / h) * cols + round(point[0] / h)

    found = dijkstra(graph, directed=False, indices=[node(p) for p in sources])
    return found[:, [node(p) for p in targets]]


def check_against_lattice(shelves, start, goal, items):
    to_item, to_goal = legs(shelves, start, goal, items)
    points = [centre(c) for c in items]
    grid = lattice_lengths(np.asarray(shelves, bool), [centre(start), centre(goal)], points, R)
    straight = [np.hypot(*(p - centre(start))) + np.hypot(*(p - centre(goal))) for p in points]
    exact = to_item + to_goal
    assert np.all(exact >= np.array(straight) - 1e-9)
    assert np.all(exact <= grid[0] + grid[1] + 1e-9), "the exact length exceeds a real path's"
    # The lattice's directions are 26.6 degrees apart at most (2.8 % longer) and it keeps extra clearance.
    assert np.all(grid[0] + grid[1] <= 1.04 * exact + 0.1), "the exact length is far below every real path"


# ------------------------------------------------------------------ the bound
def test_an_open_room_is_the_straight_line():
    to_item, to_goal = legs(np.zeros((5, 5)), (0, 0), (4, 4), [(3, 1), (2, 2)])
    np.testing.assert_allclose(to_item, [math.hypot(1, 3), math.hypot(2, 2)], rtol=1e-12)
    np.testing.assert_allclose(to_goal, [math.hypot(3, 1), math.hypot(2, 2)], rtol=1e-12)


def test_one_shelf_between_is_tangent_arc_side_arc_tangent():
    # 3 x 5 room, shelf in the middle of row 1: from the item (1.5, 1.5) round the shelf [2, 3] x [1, 2] to
    # the goal (3.5, 1.5). Tangent from the item to the circle of radius R round the corner (2, 2): length
    # sqrt(d^2 - R^2), d = |(0.5, 0.5)|; it touches at angle 5 pi / 4 - acos(R / d) and the arc runs to pi / 2
    # (the top); the side (3 - 2 = 1 m) and the mirror image to the goal.
    shelves = np.zeros((3, 5), bool)
    shelves[1, 2] = True
    to_item, to_goal = legs(shelves, (1, 0), (1, 3), [(1, 1)])
    d = math.sqrt(0.5)
    around = 2 * (math.sqrt(d * d - R * R) + R * (3 * math.pi / 4 - math.acos(R / d))) + 1.0
    assert to_item[0] == pytest.approx(1.0, abs=1e-12)
    assert to_goal[0] == pytest.approx(around, abs=1e-9)
    assert around == pytest.approx(3.0148, abs=1e-4)


def test_shelves_meeting_at_a_corner_close_the_gap_and_radii_must_fit_a_cell():
    shelves = np.zeros((3, 3), bool)
    shelves[0, 1] = shelves[1, 0] = True  # the start cell's only way out is the point where they meet
    with pytest.raises(ValueError, match="cannot be reached"):
        legs(shelves, (0, 0), (2, 2), [(2, 0)])
    with pytest.raises(ValueError, match=r"radius must lie in \(0, 0.5\)"):
        legs(np.zeros((3, 3)), (0, 0), (2, 2), [(1, 1)], radius=0.5)


@pytest.mark.parametrize("text", [WAREHOUSE_8X8, WAREHOUSE_12X12], ids=["8x8", "12x12"])
def test_the_study_maps_lie_between_the_straight_line_and_a_fine_lattice(text):
    _, params = make_continuous(text)
    cells = np.floor(np.asarray(params.items)[:int(params.num_items), ::-1]).astype(int)
    check_against_lattice(np.asarray(params.shelves), np.asarray(params.start_cell), np.asarray(params.goal_cell),
                          cells)


def test_random_layouts_lie_between_the_straight_line_and_a_fine_lattice():
    rng = np.random.default_rng(7)
    checked = 0
    while checked < 6:
        size = int(rng.integers(4, 8))
        shelves = rng.random((size, size)) < 0.3
        free = np.argwhere(~shelves)
        if len(free) < 5:
            continue
        cells = free[rng.choice(len(free), 5, replace=False)]
        try:
            Layout(shelves=shelves, start=cells[0], goal=cells[1], items=cells[2:])
        except ValueError:  # not 4-connected
            continue
        check_against_lattice(shelves, cells[0], cells[1], cells[2:])  # 4-connected cells pass a disc of R < 1/2
        checked += 1


def test_routes_are_clear_of_the_grown_shelves_and_as_long_as_the_bound():
    _, params = make_continuous(WAREHOUSE_12X12)
    shelves = np.asarray(params.shelves)
    items = np.asarray(params.items, float)[:int(params.num_items)]
    radius = R + CONFIG.margin
    to_item, to_goal, routes = spath.item_legs(shelves, np.asarray(params.start, float),
                                               np.asarray(params.goal, float), items, radius, with_routes=True)
    lows = np.stack(np.nonzero(shelves)[::-1], axis=1).astype(float)
    for (first, second), a, b in zip(routes, to_item, to_goal):
        for route, length in ((first, a), (second, b)):
            assert spath.segment_clearance(route[:-1], route[1:], lows).min() >= radius - 1e-9
            # Arcs become tangent polygons, 22.5 degrees a side: at most tan(x) / x - 1 = 1.3 % longer.
            assert length - 1e-9 <= spath.polyline_length(route) <= length + 0.013 * np.pi / 2 * radius * len(route)


# ------------------------------------------------------------------ pure pursuit
@pytest.fixture(scope="module", params=[WAREHOUSE_8X8, WAREHOUSE_12X12], ids=["8x8", "12x12"])
def static_run(request):
    env, params = make_continuous(request.param)
    plan, bounds = make_plan(params, CONFIG), yardstick.item_bounds(params)
    episodes = int(params.num_items)  # one per item
    results = pursuit_episodes(env, params, plan, CONFIG, jax.random.key(0), episodes, int(params.max_steps))
    return env, params, plan, bounds, jax.device_get(results)


def test_pursuit_delivers_every_item_of_the_study_maps_without_a_collision(static_run):
    _, params, _, bounds, results = static_run
    steps = results["delivered_at"]
    assert np.all(steps > 0), f"undelivered items: {np.nonzero(steps < 0)[0]}"
    for flag in yardstick.COUNTED:
        assert results[flag].sum() == 0, flag
    assert results["guarded"].sum() == 0, "the guard acted: the pursuit alone came too close to a shelf"
    # No policy beats the strict bound (pickup and delivery within reach_radius of the points) ...
    assert np.all(steps >= np.ceil(bounds["strict_steps"] - 1e-9))
    # ... and pursuit stays within a few per cent of the contract's bound D_i / (v_max dt).
    assert np.mean(steps / bounds["steps"]) < 1.03


def test_randomized_pursuit_runs_and_delivers(static_run):
    env, params, plan, _, _ = static_run
    params = params.replace(randomize=jnp.bool_(True))  # the same program: randomization is a parameter
    results = pursuit_episodes(env, params, plan, CONFIG, jax.random.key(1), int(params.num_items),
                                         int(params.max_steps))
    assert np.mean(np.asarray(results["delivered_at"]) > 0) >= 0.9


LEARNERS_VIEW = {"shaping": "geodesic", "observe_route": True, "observe_target": True, "observe_obstacles": True,
                 "safety_stop": True}
"""What SAC and TD3 train on by default: the yardstick beside them must not see any of it."""


@pytest.mark.parametrize("static_run", [WAREHOUSE_12X12], ids=["12x12"], indirect=True)
def test_the_training_report_runs_pursuit_on_the_evaluations_episodes(static_run):
    """The final report's yardstick (``evaluation.final_report``): the controller on the episodes every policy is
    evaluated on, in the contract's environment whatever view the learner had, and the items' mean bound."""
    _, params, _, bounds, results = static_run
    env, view_params = make_continuous(WAREHOUSE_12X12, **LEARNERS_VIEW)
    got = jax.device_get(evaluation.evaluate_pursuit(env, view_params))
    items = int(params.num_items)
    assert got.delivered[0, :items].all() and got.collisions[0, :items].sum() == 0
    # The static maps have one episode per item, the yardstick's own run too: the same steps, item by item
    # (within a step: the two programs may fuse a multiply-add differently).
    assert np.abs(got.steps[0, :items] - results["delivered_at"]).max() <= 1

    report = evaluation.yardstick_report(env, view_params)
    assert report["bound_steps"] == pytest.approx(bounds["steps"].mean())
    assert report["strict_bound_steps"] == pytest.approx(bounds["strict_steps"].mean())
    assert report["pursuit"]["mean_steps"] == pytest.approx(got.steps[0, :items].mean())
    assert report["pursuit"]["success_rate"] == 1.0 and report["pursuit"]["collisions_per_episode"] == 0.0
    # Randomization voids the bound: the report leaves it out (the same program: randomize is a parameter).
    assert "bound_steps" not in evaluation.yardstick_report(env, view_params.replace(randomize=jnp.bool_(True)))

    # The report prints them beside the policy's steps (here the controller's own, as a policy's would be).
    summary = {**evaluation.summarize(jax.tree.map(lambda x: x[None], got)), "yardstick": report}
    text = evaluation.format_report(summary, "pursuit")
    bound, pursuit = report["bound_steps"], report["pursuit"]["mean_steps"]
    excess = 100 * (summary["mean_steps"] / bound - 1)
    assert (f"(the contract's bound {bound:.1f}: {excess:+.1f} %, strict {report['strict_bound_steps']:.1f}; "
            f"pursuit {pursuit:.1f}) |") in text
    # A policy that leaves an item undelivered gets no excess: its mean runs over fewer, other items.
    partial = {**summary, "success_rate": 0.95}
    assert f"(the contract's bound {bound:.1f}, strict" in evaluation.format_report(partial, "pursuit")
    assert f"| Pursuit controller (same episodes) | 100.0% delivered, 0.000 collisions per episode, {pursuit:.1f} " \
           "steps |" in text


def test_the_yardstick_meets_the_policies_episodes_whatever_their_view():
    """With moving obstacles the episodes are the evaluation's keys (resets and steps): the controller driven
    through the policies' own loop (``evaluate_episodes``) in the learners' view without the stop, and
    ``evaluate_pursuit`` called with the learners' view over the stop, give the same episodes, step for step."""
    view = {name: value for name, value in LEARNERS_VIEW.items() if name != "safety_stop"}
    env, params = make_continuous(WAREHOUSE_12X12, num_obstacles=4, **view)
    guarded, guarded_params = make_continuous(WAREHOUSE_12X12, num_obstacles=4, **LEARNERS_VIEW)
    plan = make_plan(params, CONFIG)

    def through_the_policy_loop(params):
        act = lambda obs, state, control: pursuit_act(plan, control, state, params, CONFIG)  # noqa: E731
        return evaluation.evaluate_episodes(act, env, params, start=lambda state: pursuit_init(plan, state))

    mine = jax.device_get(fast_compile.jit(through_the_policy_loop)(params))
    theirs = jax.device_get(evaluation.evaluate_pursuit(guarded, guarded_params))
    assert mine.steps.shape == (evaluation.OBSTACLE_ROUNDS, 20)
    np.testing.assert_array_equal(mine.delivered, theirs.delivered)
    # Within a step: the two programs may fuse a multiply-add differently (never seen here).
    assert np.abs(mine.steps - theirs.steps).max() <= 1 and np.array_equal(mine.collisions, theirs.collisions)
    assert len(np.unique(theirs.steps)) > 20  # the rounds' obstacle draws differ


@pytest.fixture(scope="module")
def dynamic():
    env, params = make_continuous(WAREHOUSE_12X12, num_obstacles=4)
    return env, params, make_plan(params, CONFIG)


def scripted(pos, item, obstacles) -> ContinuousState:
    """A robot at ``pos`` facing +x, not carrying, with obstacles standing at ``obstacles`` (their waypoints)."""
    obstacles = jnp.asarray(obstacles, jnp.float32)
    return ContinuousState(pos=jnp.asarray(pos, jnp.float32), theta=jnp.float32(0.0), carrying=jnp.bool_(False),
                           item=item, time=jnp.int32(0), obstacle_pos=obstacles, obstacle_waypoint=obstacles,
                           obstacle_from=jnp.floor(obstacles[:, ::-1]).astype(jnp.int32), gains=jnp.ones(2),
                           held=jnp.int32(0))


def test_pursuit_waits_for_an_obstacle_ahead_only_and_then_steps_aside(dynamic):
    env, params, plan = dynamic
    act = fast_compile.jit(lambda control, state: pursuit_act(plan, control, state, params, CONFIG))
    far = jnp.array([[8.5, 8.5], [9.5, 9.5], [10.5, 10.5], [11.5, 11.5]], jnp.float32)
    # Item 0 is at (4.5, 0.5): its leg runs straight along the bottom row; the robot, 2 m along it, faces it.
    state = scripted([2.5, 0.5], plan.items[0], far)
    control = pursuit_init(plan, state).replace(progress=jnp.float32(2.0))
    free, _ = act(control, state)
    assert float(free[0]) == 1.0 and float(free[1]) == 0.0
    for where, waits in [((3.5, 0.5), True), ((3.0, 1.1), True), ((1.5, 0.5), False), ((2.5, 1.5), False),
                         ((6.5, 0.5), False)]:
        placed = state.replace(obstacle_pos=far.at[0].set(jnp.array(where, jnp.float32)))
        action, _ = act(control, placed)
        assert (float(action[0]) == 0.0) == waits, (where, action)
    # Held up for `patience` steps by an obstacle that waits for it too, it steps aside, off the obstacle's row.
    blocked = far.at[0].set(jnp.array([3.5, 0.5], jnp.float32))
    state = state.replace(obstacle_pos=blocked)
    control = pursuit_init(plan, state).replace(progress=jnp.float32(2.0))
    for _ in range(CONFIG.patience):
        action, control = act(control, state)
        assert float(action[0]) == 0.0
    assert int(control.escape_left) == CONFIG.escape_steps
    aside = np.asarray(control.escape_point)
    assert abs(aside[1] - 0.5) >= 0.6 and np.hypot(*(aside - [3.5, 0.5])) >= 0.6, aside
    transition = fast_compile.jit(lambda key, state, action: env.transition(key, state, action, params))
    for _ in range(10):  # the obstacle pinned where it waits
        action, control = act(control, state)
        _, state, _, _, _, info = transition(jax.random.key(0), state, action)
        state = state.replace(obstacle_pos=blocked)
        assert not bool(info["collision"])
    assert np.hypot(*(np.asarray(state.pos) - aside)) < np.hypot(*(aside - [2.5, 0.5])) - 0.3


def test_a_step_away_from_a_touching_obstacle_is_never_refused():
    _, params = make_continuous(WAREHOUSE_12X12, num_obstacles=4)
    pos, obstacle = jnp.array([5.0, 5.0]), jnp.array([[5.6, 5.0]])
    # Jitted: one program for the three motions (eagerly each operation compiles on its own).
    check = jax.jit(lambda motion: in_the_way(pos, obstacle, motion, jnp.float32(0.2), jnp.float32(0.01),
                                              jnp.bool_(True), params, CONFIG))
    for motion, refused in [((1.0, 0.0), True), ((-1.0, 0.0), False), ((0.0, 1.0), False)]:
        got = check(jnp.array(motion))
        assert bool(got) == refused, motion


def test_dynamic_pursuit_delivers_without_touching_an_obstacle(dynamic):
    env, params, plan = dynamic
    report = yardstick.summarize(
        jax.device_get(pursuit_episodes(env, params, plan, CONFIG, jax.random.key(3), 20, 500)),
        yardstick.item_bounds(params), int(params.num_items))
    assert report["collisions_per_episode"] == 0.0
    assert report["delivery_rate"] >= 0.85


def test_bad_settings_are_refused_before_compiling():
    env, params = make_continuous(WAREHOUSE_8X8)
    with pytest.raises(ValueError, match="episodes must be a positive integer"):
        yardstick.run_pursuit(env, params, 0)
    with pytest.raises(ValueError, match="leaves no path through a 1 m cell"):
        make_plan(params, PursuitConfig(margin=0.25))
    with pytest.raises(ValueError, match="patience must be a positive integer"):
        make_plan(params, PursuitConfig(patience=0))
