"""A safety stop for learners: the forward command is dropped when the robot's own lidar says the step
would bring its disc within ``margin`` of something and closer to it than it is now.

Why: a learned policy grazes moving obstacles and shelves now and then, and a deterministic one may push
into a waiting obstacle for the rest of an episode. A real robot with proximity sensors has such a
reflex below its policy; here it is part of the environment a learner trains in (``safety_margin``), so
the policy learns to turn and go around where the reflex holds it, and the contract's collision check
(step 3) still judges every step that is taken.

What it reads is what the observation's lidar shows before the step, without its noise: the ``L`` rays
from the robot's centre, each return a point ``h`` on a shelf, the boundary or a moving obstacle where
it stood before this step (where the collision check looks). The step ``q`` is the contract's step 2 for the
command the contract will apply: times the episode's gains, plus this step's actuation noise (both 1 and 0
without randomization). Stopping sets the forward command to the one whose gain and noise cancel
(``-noise_v / (v_max gain_v)``, 0 without randomization), so a held robot stays where it is, to float
rounding, under randomization too. Turning is never stopped: it does not move the disc. Between two rays a
shelf corner can come closer than either return, so ``margin`` must cover the rays' spacing near the robot
(``tests`` measure it).

An escape (``escape_after=K``, :func:`escape`): once the robot has been held ``K`` steps in a row, the turn
command becomes a full (left) turn for as long as the stop or a contact holds it. Why: without noise, a held robot
whose policy swings its turn command back and forth sees the same observations for the rest of the episode; a full
turn shows it a new view and a way out (the procedural policy's held-out failures were such standstills; docs/continuous.md).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from wrl_jax.envs.continuous.geometry import norm, ray_angles, ray_discs, ray_grid, wrap
from wrl_jax.envs.continuous.types import ContinuousParams, ContinuousState

SAFETY_MARGIN = 0.05
"""The default margin, metres beyond the robot's radius, for the 32 rays' spacing near the robot: of 7,212 steps
that would collide among 100,000 states drawn next to things, 1 gets through (137 at margin 0;
bench/investigations/continuous_safety_margin.py)."""


def escape(held: jax.Array, action: jax.Array, escape_after: int | None) -> jax.Array:
    """``action`` with a full turn where the robot has been held ``escape_after`` steps in a row (``None``: off)."""
    if escape_after is None:
        return action
    action = jnp.asarray(action, jnp.float32)
    return action.at[1].set(jnp.where(held >= escape_after, 1.0, action[1]))


def approached(pos: jax.Array, q: jax.Array, angles: jax.Array, ranges: jax.Array, reach: jax.Array,
               lidar_range: jax.Array) -> jax.Array:
    """Whether moving from ``pos`` to ``q`` comes closer than ``reach`` to a return of the rays (and closer
    to it than ``pos`` is). Returns beyond ``lidar_range`` are not seen."""
    seen = ranges <= lidar_range
    points = pos[None, :] + jnp.where(seen, ranges, 0.0)[:, None] * jnp.stack([jnp.cos(angles), jnp.sin(angles)], 1)
    gap = norm(q[None, :] - points)
    return jnp.any(seen & (gap < reach) & (gap < ranges))


def safety_stop(state: ContinuousState, action: jax.Array, noise: jax.Array, num_rays: int, margin: float,
                params: ContinuousParams) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(action, stopped_by_obstacle, stopped_by_shelf_or_wall)``: ``action`` with its forward command replaced by
    the holding one where the step would come within ``robot_radius + margin`` of a return of the lidar.

    ``noise`` ``(2,)``: this step's actuation noise (the step's draws, zeros without randomization). A noise larger
    than the gained command's reach (``|noise_v| > v_max gain_v``, sixteen standard deviations at the contract's
    ranges) cannot be cancelled by a command in [-1, 1]: the step is then only reported as stopped."""
    action = jnp.asarray(action, jnp.float32)
    a = jnp.where(jnp.isnan(action), 0.0, jnp.clip(action, -1.0, 1.0))
    v = (params.v_max * a[0]) * state.gains[0] + noise[0]
    w = (params.w_max * a[1]) * state.gains[1] + noise[1]
    theta = wrap(state.theta + (w * params.dt))
    q = state.pos + (v * params.dt) * jnp.stack([jnp.cos(theta), jnp.sin(theta)])
    angles = ray_angles(state.theta, num_rays)
    reach = params.robot_radius + jnp.float32(margin)
    shelf = approached(state.pos, q, angles, ray_grid(state.pos, angles, params.shelves), reach, params.lidar_range)
    obstacle = approached(state.pos, q, angles, ray_discs(state.pos, angles, state.obstacle_pos,
                                                          params.obstacle_radius), reach, params.lidar_range)
    moving = v != 0
    shelf, obstacle = moving & shelf, moving & obstacle
    hold = jnp.where(params.randomize, -noise[0] / (params.v_max * state.gains[0]), 0.0)  # gains > 0: checked at build
    return action.at[0].set(jnp.where(shelf | obstacle, hold, action[0])), obstacle, shelf
