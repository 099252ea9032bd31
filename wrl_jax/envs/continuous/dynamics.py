"""CONTINUOUS_SPEC.md's MDP as a deterministic core: a reset and a transition that take their random
draws as inputs (:class:`~wrl_jax.envs.continuous.types.ResetDraws`, ``StepDraws``).

The environment class draws and calls these; the parity tests give the NumPy reference the same
draws. The order of the contract is kept line by line: 1 action, 2 kinematics, 3 collision,
4 moving obstacles, 5 pickup and delivery, 6 the clock, then the reward and the observation.

A moving obstacle that lands on its waypoint picks the next one with a draw ``u`` in [0, 1): the
centres of the free 4-neighbours of its cell, in the order up, down, left, right (the actions'
order), leaving out the cell it came from, and the ``min(floor(u n), n - 1)``-th of the ``n``
left; back to the cell it came from only when no other is free.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from wrl_jax.envs.continuous.geometry import hits_shelf, hits_wall, lidar, norm, wrap
from wrl_jax.envs.continuous.types import ContinuousParams, ContinuousState, ResetDraws, StepDraws

NEIGHBOURS = ((-1, 0), (1, 0), (0, -1), (0, 1))
"""Up, down, left, right, as ``(row, col)`` offsets: the order a waypoint draw counts in."""

OBS_SCALARS = 11
"""Observation values before the lidar: position, heading, command, goal, item, carrying."""

FLAGS = ("collision", "hit_shelf", "hit_wall", "hit_obstacle", "picked_up", "delivered", "invalid_action")
"""Scalar bool entries of a transition's ``info``; ``obstacle_waited`` and ``obstacle_landed`` are ``(M,)``."""


def cell_centre(cell: jax.Array) -> jax.Array:
    """``(..., 2)`` int (row, col) -> ``(..., 2)`` float32 point (x, y) = (col + 0.5, row + 0.5)."""
    return jnp.stack([cell[..., 1].astype(jnp.float32) + 0.5, cell[..., 0].astype(jnp.float32) + 0.5], axis=-1)


def next_waypoint(cell: jax.Array, came_from: jax.Array, u: jax.Array, shelves: jax.Array) -> jax.Array:
    """The cell (row, col) an obstacle standing on ``cell`` heads to next (see the module docstring).

    For the first leg ``came_from`` is ``cell`` itself, which is no neighbour: nothing is left out.
    """
    height, width = shelves.shape
    candidates = cell[None, :] + jnp.asarray(NEIGHBOURS, jnp.int32)
    rows, cols = candidates[:, 0], candidates[:, 1]
    inside = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
    free = inside & ~shelves[jnp.clip(rows, 0, height - 1), jnp.clip(cols, 0, width - 1)]
    back = jnp.all(candidates == came_from[None, :], axis=1)
    eligible = free & ~back
    count = eligible.sum()
    index = jnp.minimum(jnp.floor(u * count.astype(jnp.float32)).astype(jnp.int32), count - 1)
    chosen = jnp.argmax(eligible & (jnp.cumsum(eligible) - 1 == index))
    return jnp.where(count > 0, candidates[chosen], came_from)


def manhattan(point: jax.Array, target: jax.Array) -> jax.Array:
    """The contract's shaping distance ``d``: ``|px - tx| + |py - ty|`` in float32."""
    return jnp.abs(point[0] - target[0]) + jnp.abs(point[1] - target[1])


def observe(pos: jax.Array, theta: jax.Array, command: jax.Array, carrying: jax.Array, item: jax.Array,
            ranges: jax.Array, params: ContinuousParams) -> jax.Array:
    """The ``11 + L`` float32 values of the contract's table; ``ranges`` the lidar distances (metres)."""
    height, width = params.shelves.shape
    size = jnp.array([width, height], jnp.float32)
    item_slots = jnp.where(carrying, jnp.float32(-1.0), item / size)
    reading = jnp.minimum(ranges, params.lidar_range) / params.lidar_range
    scalars = jnp.concatenate([pos / size, jnp.stack([jnp.cos(theta), jnp.sin(theta)]),
                               command / jnp.stack([params.v_max, params.w_max]), params.goal / size, item_slots,
                               carrying.astype(jnp.float32)[None]])
    return jnp.concatenate([scalars, reading])


def read_lidar(pos: jax.Array, theta: jax.Array, obstacles: jax.Array, draws: StepDraws,
               params: ContinuousParams) -> jax.Array:
    """Lidar distances in metres, with the randomized noise and dropout where ``params.randomize``."""
    ranges = lidar(pos, theta, draws.lidar_noise.shape[0], params.shelves, obstacles, params.obstacle_radius)
    noisy = jnp.where(draws.lidar_drop, params.lidar_range,
                      jnp.clip(ranges + draws.lidar_noise, 0.0, params.lidar_range))
    return jnp.where(params.randomize, noisy, ranges)


def reset_core(draws: ResetDraws, params: ContinuousParams) -> tuple[jax.Array, ContinuousState]:
    """The first state and observation of an episode from its draws."""
    item = params.items[draws.item_index]
    cells = draws.obstacle_cells.astype(jnp.int32)
    num_obstacles = cells.shape[0]
    waypoints = jax.vmap(next_waypoint, in_axes=(0, 0, 0, None))(cells, cells, draws.waypoint_u, params.shelves)
    state = ContinuousState(
        pos=params.start + draws.start_offset,
        theta=wrap(draws.theta.astype(jnp.float32)),
        carrying=jnp.bool_(False),
        item=item,
        time=jnp.int32(0),
        obstacle_pos=cell_centre(cells).reshape(num_obstacles, 2),
        obstacle_waypoint=cell_centre(waypoints).reshape(num_obstacles, 2),
        obstacle_from=cells,
        gains=draws.gains.astype(jnp.float32),
        held=jnp.int32(0),
    )
    reading = StepDraws(noise=jnp.zeros(2, jnp.float32), waypoint_u=draws.waypoint_u,
                        lidar_noise=draws.lidar_noise, lidar_drop=draws.lidar_drop)
    ranges = read_lidar(state.pos, state.theta, state.obstacle_pos, reading, params)
    obs = observe(state.pos, state.theta, jnp.zeros(2, jnp.float32), state.carrying, item, ranges, params)
    return obs, state


def move_obstacles(state: ContinuousState, robot: jax.Array, draws: StepDraws, params: ContinuousParams):
    """Step 4 for every obstacle (independent of each other): ``(pos, waypoint, from, waited, landed)``."""
    stride = params.obstacle_speed * params.dt
    gap = params.robot_radius + params.obstacle_radius

    def one(pos, waypoint, came_from, u):
        d = waypoint - pos
        distance = norm(d)
        lands = distance <= stride
        moved = jnp.where(lands, waypoint, pos + stride * (d / jnp.where(lands, 1.0, distance)))
        waits = norm(moved - robot) < gap
        here = jnp.stack([jnp.floor(waypoint[1]), jnp.floor(waypoint[0])]).astype(jnp.int32)
        after = next_waypoint(here, came_from, u, params.shelves)
        landed = lands & ~waits
        return (jnp.where(waits, pos, moved), jnp.where(landed, cell_centre(after), waypoint),
                jnp.where(landed, here, came_from), waits, landed)

    return jax.vmap(one)(state.obstacle_pos, state.obstacle_waypoint, state.obstacle_from, draws.waypoint_u)


def transition_core(state: ContinuousState, action: jax.Array, draws: StepDraws, params: ContinuousParams):
    """One transition without reset: ``(obs, next_state, reward, terminated, truncated, info)``."""
    height, width = params.shelves.shape
    action = jnp.asarray(action, jnp.float32)
    invalid = jnp.isnan(action)
    a = jnp.where(invalid, 0.0, jnp.clip(action, -1.0, 1.0))
    # 1-2: the command (gains, then noise) and the kinematics.
    v = (params.v_max * a[0]) * state.gains[0] + draws.noise[0]
    w = (params.w_max * a[1]) * state.gains[1] + draws.noise[1]
    theta = wrap(state.theta + (w * params.dt))
    heading = jnp.stack([jnp.cos(theta), jnp.sin(theta)])
    q = state.pos + (v * params.dt) * heading
    # 3: collisions against the obstacles where they stood before this step.
    hit_shelf = hits_shelf(q, params.robot_radius, params.shelves)
    hit_wall = hits_wall(q, params.robot_radius, width, height)
    gaps = norm(q[None, :] - state.obstacle_pos)
    hit_obstacle = jnp.any(gaps < params.robot_radius + params.obstacle_radius)
    collision = hit_shelf | hit_wall | hit_obstacle
    pos = jnp.where(collision, state.pos, q)
    # 4: the moving obstacles.
    obstacle_pos, waypoint, came_from, waited, landed = move_obstacles(state, pos, draws, params)
    # 5-6: pickup, delivery, the clock.
    picked_up = ~state.carrying & (norm(pos - state.item) <= params.reach_radius)
    delivered = state.carrying & (norm(pos - params.goal) <= params.reach_radius)
    time = state.time + 1
    truncated = (time >= params.max_steps) & ~delivered
    # The reward, terms in the contract's order.
    target = jnp.where(state.carrying, params.goal, state.item)
    before, after = manhattan(state.pos, target), manhattan(pos, target)
    reward = jnp.where(delivered, jnp.float32(0.0), params.step_penalty)
    reward = reward + jnp.where(collision, params.collision_penalty, 0.0)
    reward = reward + params.shaping_coef * (before - after)
    reward = reward + jnp.where(picked_up, params.pickup_reward, 0.0)
    reward = reward + jnp.where(delivered, params.delivery_reward, 0.0)
    carrying = state.carrying | picked_up  # a delivery ends the episode; nothing is put down
    next_state = state.replace(pos=pos, theta=theta, carrying=carrying, time=time, obstacle_pos=obstacle_pos,
                               obstacle_waypoint=waypoint, obstacle_from=came_from)
    ranges = read_lidar(pos, theta, obstacle_pos, draws, params)
    obs = observe(pos, theta, jnp.stack([v, w]), carrying, state.item, ranges, params)
    info = {"collision": collision, "hit_shelf": hit_shelf, "hit_wall": hit_wall, "hit_obstacle": hit_obstacle,
            "picked_up": picked_up, "delivered": delivered, "invalid_action": jnp.any(invalid),
            "obstacle_waited": waited, "obstacle_landed": landed}
    return obs, next_state, reward, delivered, truncated, info
