"""Independent NumPy reference of the continuous warehouse (docs/CONTINUOUS_SPEC.md).

Written from the contract alone, to be compared transition by transition with the JAX
environment: shared mistakes are what it exists to catch, so it reads like the contract
(float32, one rounding per written operation, in the written order) and not like fast code.
The core (:func:`reset`, :func:`step`) draws nothing: every random number comes in as an
argument, so a parity test replays the JAX draws. :class:`ReferenceEnv` adds its own NumPy
draws and auto-reset for hand-play and smoke tests.

Decisions where the contract is silent (keep the JAX side equal):
- cos/sin are the float32 roundings of the float64 values (one rounding each);
- the ray of lidar index k has angle ``theta' + ((2pi * k) / L)``, each operation in float32;
- a waypoint draw ``u`` in [0, 1) picks, among n candidates, index ``min(floor(u * n), n - 1)``
  with ``u * n`` in float32 (see :func:`next_waypoint_cell`);
- ``obstacle_from`` is the origin cell of the obstacle's current leg (see :func:`move_obstacles`);
- a ray meets a disc where ``a r^2 - h^2 >= 0``, ``h`` the cross product (see :func:`ray_distance`);
- the reset observation takes lidar noise and dropout draws too (zeros unless randomized).
"""

from __future__ import annotations

import numpy as np

from wrl_jax.envs.continuous.reference_geometry import (
    collision_flags,
    cos32,
    lidar_distances,
    lidar_values,
    norm,
    read_action,
    sin32,
    wrap,
)
from wrl_jax.envs.continuous.reference_types import (
    ContinuousLayout,
    ContinuousParams,
    ContinuousState,
    StepDraws,
)

F32 = np.float32
NEIGHBOURS = ((-1, 0), (1, 0), (0, -1), (0, 1))
"""Waypoint candidates in this order: up (row-1), down (row+1), left (col-1), right (col+1)."""


def next_waypoint_cell(layout: ContinuousLayout, cell, came_from, u) -> tuple[int, int]:
    """The next waypoint cell of an obstacle standing on ``cell``.

    Candidates: the 4-neighbours in the order up, down, left, right; eligible = free (inside,
    not shelf) and not ``came_from`` (None for the first waypoint: no exclusion). With n > 0
    eligible, index ``min(int(floor(float32(u) * float32(n))), n - 1)``. With none: back to
    ``came_from`` if it is free, else the obstacle's own cell (an isolated free cell: it stays).
    """
    row, col = int(cell[0]), int(cell[1])
    back = None if came_from is None else (int(came_from[0]), int(came_from[1]))
    eligible = [(row + dr, col + dc) for dr, dc in NEIGHBOURS
                if layout.is_free(row + dr, col + dc) and (row + dr, col + dc) != back]
    if eligible:
        n = len(eligible)
        return eligible[min(int(np.floor(F32(F32(u) * F32(n)))), n - 1)]
    if back is not None and layout.is_free(*back):
        return back
    return row, col


def observe(state: ContinuousState, layout: ContinuousLayout, params: ContinuousParams,
            v: np.float32, w: np.float32, lidar_noise=None, lidar_drop=None) -> np.ndarray:
    """The ``11 + L`` float32 observation of ``state``, with the commands applied this step."""
    W, H = F32(layout.width), F32(layout.height)
    goal = layout.cell_centre(*layout.goal)
    item = (F32(-1), F32(-1)) if state.carrying else (F32(state.item[0] / W), F32(state.item[1] / H))
    fixed = [state.pos[0] / W, state.pos[1] / H, cos32(state.theta), sin32(state.theta),
             F32(v) / F32(params.v_max), F32(w) / F32(params.w_max), goal[0] / W, goal[1] / H,
             item[0], item[1], F32(1) if state.carrying else F32(0)]
    t = lidar_distances(state.pos, state.theta, layout, params, state.obstacle_pos)
    return np.concatenate([np.array(fixed, F32), lidar_values(t, params, lidar_noise, lidar_drop)]).astype(F32)


def eligible_obstacle_cells(layout: ContinuousLayout) -> np.ndarray:
    """Free cells at Manhattan distance >= 3 from the start and not the goal, row-major, (N, 2) int32."""
    cells = [(r, c) for r in range(layout.height) for c in range(layout.width)
             if layout.is_free(r, c) and (r, c) != layout.goal
             and abs(r - layout.start[0]) + abs(c - layout.start[1]) >= 3]
    return np.array(cells, dtype=np.int32).reshape(-1, 2)


def reset(layout: ContinuousLayout, params: ContinuousParams, item_index: int, obstacle_cells,
          waypoint_u, gains=(1.0, 1.0), start_offset=(0.0, 0.0), theta0: float = 0.0,
          lidar_noise=None, lidar_drop=None) -> tuple[ContinuousState, np.ndarray]:
    """The first state and observation, from the caller's draws (validated: ValueError names the problem)."""
    M = params.num_obstacles
    if not 0 <= int(item_index) < len(layout.items):
        raise ValueError(f"item_index {item_index} is out of range for {len(layout.items)} items")
    cells = np.asarray(np.zeros((0, 2)) if obstacle_cells is None else obstacle_cells).reshape(-1, 2)
    us = np.asarray(waypoint_u, F32).reshape(-1)
    if cells.shape != (M, 2) or us.shape != (M,):
        raise ValueError(f"expected {M} obstacle cells and waypoint draws, got shapes {cells.shape}, {us.shape}")
    if np.any((us < 0) | (us > 1)):
        raise ValueError(f"waypoint draws must lie in [0, 1] (1 is read as just below 1), got {us}")
    cells = [(int(r), int(c)) for r, c in cells]
    for cell in cells:
        if not layout.is_free(*cell):
            raise ValueError(f"obstacle cell {cell} is not a free cell of the map")
        if cell == layout.goal:
            raise ValueError(f"obstacle cell {cell} is the goal cell")
        if abs(cell[0] - layout.start[0]) + abs(cell[1] - layout.start[1]) < 3:
            raise ValueError(f"obstacle cell {cell} is closer than Manhattan distance 3 to the start cell")
    if len(set(cells)) != len(cells):
        raise ValueError(f"obstacle cells must be distinct, got {cells}")
    offset = np.asarray(start_offset, F32)
    if norm(offset[0], offset[1]) > F32(params.start_jitter):
        raise ValueError(f"start offset {offset} is farther than start_jitter {params.start_jitter}")
    pos = (layout.cell_centre(*layout.start) + offset).astype(F32)
    centres = np.array([layout.cell_centre(*c) for c in cells], F32).reshape(-1, 2)
    if any(collision_flags(pos, layout, params, centres)):
        raise ValueError(f"start position {pos} overlaps a shelf, the boundary or an obstacle")
    waypoints = [layout.cell_centre(*next_waypoint_cell(layout, c, None, u)) for c, u in zip(cells, us)]
    state = ContinuousState(
        pos=pos, theta=F32(theta0), carrying=False,
        item=layout.cell_centre(*layout.items[int(item_index)]), time=0,
        obstacle_pos=centres, obstacle_waypoint=np.array(waypoints, F32).reshape(-1, 2),
        obstacle_from=np.array(cells, np.int32).reshape(-1, 2), gains=np.asarray(gains, F32).reshape(2))
    return state, observe(state, layout, params, F32(0), F32(0), lidar_noise, lidar_drop)


def move_obstacles(state: ContinuousState, robot: np.ndarray, layout: ContinuousLayout,
                   params: ContinuousParams, waypoint_u: np.ndarray) -> tuple:
    """Step 4, obstacle by obstacle. Returns ``(pos, waypoint, from, waited, landed)``.

    ``obstacle_from`` holds the origin cell of the current leg (the centre it last stood on).
    On landing, the next waypoint excludes that origin (the cell it came from), and then the
    landed cell becomes the new origin. A waiting obstacle changes nothing and reads no draw.
    """
    pos, wps, came = state.obstacle_pos.copy(), state.obstacle_waypoint.copy(), state.obstacle_from.copy()
    M = len(pos)
    waited, landed = np.zeros(M, bool), np.zeros(M, bool)
    s = F32(F32(params.obstacle_speed) * F32(params.dt))
    reach = F32(F32(params.robot_radius) + F32(params.obstacle_radius))
    for m in range(M):
        dx, dy = F32(wps[m, 0] - pos[m, 0]), F32(wps[m, 1] - pos[m, 1])
        length = norm(dx, dy)
        lands = bool(length <= s)
        if lands:
            new = wps[m].copy()
        else:
            new = np.array([pos[m, 0] + F32(s * F32(dx / length)), pos[m, 1] + F32(s * F32(dy / length))], F32)
        if norm(F32(new[0] - robot[0]), F32(new[1] - robot[1])) < reach:
            waited[m] = True
            continue
        pos[m] = new
        if lands:
            landed[m] = True
            here = (int(np.floor(new[1])), int(np.floor(new[0])))
            wps[m] = layout.cell_centre(*next_waypoint_cell(layout, here, came[m], waypoint_u[m]))
            came[m] = here
    return pos, wps, came, waited, landed


def step(state: ContinuousState, action, layout: ContinuousLayout, params: ContinuousParams,
         draws: StepDraws) -> tuple[ContinuousState, np.ndarray, np.float32, bool, bool, dict]:
    """One transition, "One step" 1-6 in order, then the reward and observation. No auto-reset."""
    M, L = params.num_obstacles, params.num_rays
    if (np.shape(draws.noise), np.shape(draws.waypoint_u), np.shape(draws.lidar_noise),
            np.shape(draws.lidar_drop)) != ((2,), (M,), (L,), (L,)):
        raise ValueError("draws must have shapes noise (2,), waypoint_u (M,), lidar_noise (L,), lidar_drop (L,)")
    a, invalid = read_action(action)
    noise = np.asarray(draws.noise, F32)
    dt = F32(params.dt)
    v = F32(F32(F32(params.v_max) * a[0]) * state.gains[0]) + noise[0]
    w = F32(F32(F32(params.w_max) * a[1]) * state.gains[1]) + noise[1]
    theta = wrap(F32(state.theta + F32(w * dt)))
    vdt = F32(v * dt)
    q = np.array([state.pos[0] + F32(vdt * cos32(theta)), state.pos[1] + F32(vdt * sin32(theta))], F32)
    hit_shelf, hit_wall, hit_obstacle = collision_flags(q, layout, params, state.obstacle_pos)
    collision = hit_shelf or hit_wall or hit_obstacle
    pos = state.pos.copy() if collision else q
    obs_pos, obs_wp, obs_from, waited, landed = move_obstacles(
        state, pos, layout, params, np.asarray(draws.waypoint_u, F32))

    reach = F32(params.reach_radius)
    goal = layout.cell_centre(*layout.goal)
    picked_up = not state.carrying and norm(F32(pos[0] - state.item[0]), F32(pos[1] - state.item[1])) <= reach
    delivered = state.carrying and norm(F32(pos[0] - goal[0]), F32(pos[1] - goal[1])) <= reach
    time = state.time + 1
    terminated = bool(delivered)
    truncated = bool(time >= params.max_steps and not terminated)

    target = goal if state.carrying else state.item

    def dist(p: np.ndarray) -> np.float32:
        return F32(abs(F32(p[0] - target[0])) + abs(F32(p[1] - target[1])))

    reward = F32(0)
    if not terminated:
        reward = F32(reward + F32(params.step_penalty))
    if collision:
        reward = F32(reward + F32(params.collision_penalty))
    reward = F32(reward + F32(F32(params.shaping_coef) * F32(dist(state.pos) - dist(pos))))
    if picked_up:
        reward = F32(reward + F32(params.pickup_reward))
    if terminated:
        reward = F32(reward + F32(params.delivery_reward))

    next_state = state.replace(pos=pos, theta=theta, carrying=bool(state.carrying or picked_up), time=time,
                               obstacle_pos=obs_pos, obstacle_waypoint=obs_wp, obstacle_from=obs_from)
    obs = observe(next_state, layout, params, v, w, draws.lidar_noise, draws.lidar_drop)
    info = dict(collision=bool(collision), hit_shelf=hit_shelf, hit_wall=hit_wall, hit_obstacle=hit_obstacle,
                picked_up=bool(picked_up), delivered=bool(delivered), invalid_action=invalid,
                obstacle_waited=waited, obstacle_landed=landed)
    return next_state, obs, reward, terminated, truncated, info


class ReferenceEnv:
    """The core with its own NumPy draws and auto-reset, for hand-play and smoke tests.

    Draws: item uniform; obstacle cells uniform without replacement among
    :func:`eligible_obstacle_cells`; waypoint ``u`` float32 uniform in [0, 1). Randomized: gains
    uniform in ``gain_range``, start offset uniform in the ``start_jitter`` disc (redrawn until
    collision-free), ``theta`` uniform, Gaussian actuation and lidar noise, Bernoulli dropout.
    """

    def __init__(self, layout: ContinuousLayout, params: ContinuousParams, seed: int = 0) -> None:
        self.layout, self.params = layout, params
        self.eligible = eligible_obstacle_cells(layout)
        if len(self.eligible) < params.num_obstacles:
            raise ValueError(f"layout has {len(self.eligible)} eligible obstacle cells, fewer than "
                             f"num_obstacles={params.num_obstacles}")
        self.rng = np.random.default_rng(seed)
        self.state: ContinuousState | None = None

    def _lidar_draws(self) -> tuple[np.ndarray, np.ndarray]:
        p, L = self.params, self.params.num_rays
        if not p.randomize:
            return np.zeros(L, F32), np.zeros(L, bool)
        return (self.rng.normal(size=L) * p.lidar_noise).astype(F32), self.rng.random(L) < p.lidar_dropout

    def reset(self, item_index: int | None = None) -> np.ndarray:
        p, layout = self.params, self.layout
        item = int(self.rng.integers(len(layout.items))) if item_index is None else item_index
        cells = self.eligible[self.rng.choice(len(self.eligible), p.num_obstacles, replace=False)]
        us = self.rng.random(p.num_obstacles, dtype=F32)
        gains, offset, theta0 = np.ones(2, F32), np.zeros(2, F32), F32(0)
        if p.randomize:
            gains = self.rng.uniform(*p.gain_range, size=2).astype(F32)
            theta0 = wrap(F32(self.rng.uniform(-np.pi, np.pi)))
            centres = np.array([layout.cell_centre(*c) for c in cells], F32).reshape(-1, 2)
            for _ in range(100):
                radius, angle = p.start_jitter * np.sqrt(self.rng.random()), self.rng.uniform(0, 2 * np.pi)
                candidate = np.array([radius * np.cos(angle), radius * np.sin(angle)], F32)
                start = layout.cell_centre(*layout.start) + candidate
                if (norm(candidate[0], candidate[1]) <= F32(p.start_jitter)
                        and not any(collision_flags(start, layout, p, centres))):
                    offset = candidate
                    break
        self.state, obs = reset(layout, p, item, cells, us, gains, offset, theta0, *self._lidar_draws())
        return obs

    def step(self, action) -> tuple[np.ndarray, np.float32, bool, bool, dict]:
        p = self.params
        noise = np.zeros(2, F32)
        if p.randomize:
            noise = (self.rng.normal(size=2) * [p.actuation_noise * p.v_max, p.actuation_noise * p.w_max]).astype(F32)
        draws = StepDraws(noise, self.rng.random(p.num_obstacles, dtype=F32), *self._lidar_draws())
        self.state, obs, reward, terminated, truncated, info = step(self.state, action, self.layout, p, draws)
        if terminated or truncated:
            info["final_obs"] = obs
            obs = self.reset()
        return obs, reward, terminated, truncated, info
