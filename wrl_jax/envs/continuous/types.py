"""The continuous warehouse's params, state and random draws (CONTINUOUS_SPEC.md).

Every constant of the contract is a 0-d array in :class:`ContinuousParams`, beside the layout, so
one compiled program serves every setting and every layout of a shape; the shapes (map ``H x W``,
``L`` rays, ``M`` obstacles, ``I`` item slots) are the environment's static configuration.

The random draws of a reset and of a step are pytrees of their own (:class:`ResetDraws`,
:class:`StepDraws`): the deterministic core takes them as inputs, so the NumPy reference replays
exactly the draws the JAX environment made.
"""

from __future__ import annotations

import jax
from flax import struct


@struct.dataclass
class ContinuousParams:
    """Constants and layout (metres, seconds, radians; float32 unless said)."""

    dt: jax.Array
    v_max: jax.Array
    w_max: jax.Array
    robot_radius: jax.Array
    reach_radius: jax.Array
    lidar_range: jax.Array
    step_penalty: jax.Array
    collision_penalty: jax.Array
    shaping_coef: jax.Array
    pickup_reward: jax.Array
    delivery_reward: jax.Array
    max_steps: jax.Array  # int32
    obstacle_radius: jax.Array
    obstacle_speed: jax.Array
    randomize: jax.Array  # bool: draw gains, noise, start jitter and heading per episode
    gain_low: jax.Array
    gain_high: jax.Array
    actuation_noise: jax.Array  # standard deviation, a fraction of v_max and w_max
    lidar_noise: jax.Array  # standard deviation, metres
    lidar_dropout: jax.Array  # probability per ray
    start_jitter: jax.Array  # metres: the randomized start lies within this distance of the start point
    # The layout.
    shelves: jax.Array  # (H, W) bool
    start: jax.Array  # (2,) float32 point (x, y)
    start_cell: jax.Array  # (2,) int32 (row, col)
    goal: jax.Array  # (2,) float32 point
    goal_cell: jax.Array  # (2,) int32 (row, col)
    items: jax.Array  # (I, 2) float32 points; slots past num_items repeat item 0
    num_items: jax.Array  # int32
    obstacle_cells: jax.Array  # (H, W) bool: where a moving obstacle may start (free, >= 3 from start, not goal)

    @property
    def max_steps_in_episode(self) -> jax.Array:
        return self.max_steps


@struct.dataclass
class ContinuousState:
    """One episode's state: the names of the contract's issue, float32 metres and radians."""

    pos: jax.Array  # (2,) robot centre (x, y)
    theta: jax.Array  # heading in [-pi, pi)
    carrying: jax.Array  # bool
    item: jax.Array  # (2,) the episode's item point (kept after the pickup)
    time: jax.Array  # int32 steps taken
    obstacle_pos: jax.Array  # (M, 2)
    obstacle_waypoint: jax.Array  # (M, 2) the centre it travels to
    obstacle_from: jax.Array  # (M, 2) int32 (row, col): the centre it last stood on
    gains: jax.Array  # (2,) gain_v, gain_w (1, 1 unless randomized)
    held: jax.Array  # int32 steps in a row a command to move left the robot in place (a contact or the safety
    # stop); not the contract's: kept where the learners' view reads it (env.py), 0 elsewhere


@struct.dataclass
class ResetDraws:
    """A reset's randomness. ``waypoint_u`` in [0, 1) picks each obstacle's first waypoint."""

    item_index: jax.Array  # int32
    obstacle_cells: jax.Array  # (M, 2) int32 (row, col), distinct eligible cells
    waypoint_u: jax.Array  # (M,) float32
    gains: jax.Array  # (2,)
    start_offset: jax.Array  # (2,) metres
    theta: jax.Array  # initial heading
    lidar_noise: jax.Array  # (L,) metres: the first observation is read like every other
    lidar_drop: jax.Array  # (L,) bool


@struct.dataclass
class StepDraws:
    """A step's randomness (zeros and False where randomization is off)."""

    noise: jax.Array  # (2,) actuation noise in m/s and rad/s, added to v and w
    waypoint_u: jax.Array  # (M,) float32 in [0, 1): the next waypoint of an obstacle that lands
    lidar_noise: jax.Array  # (L,) metres
    lidar_drop: jax.Array  # (L,) bool
