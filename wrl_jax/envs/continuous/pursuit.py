"""Pure pursuit through the continuous warehouse: the classical controller of CONTINUOUS_SPEC.md's yardstick.

Plans are made once on the host (:func:`make_plan`): the exact shortest path of a disc a little larger
than the robot (``robot_radius + margin``, :mod:`~wrl_jax.envs.continuous.shortest_path`) for each item's
two legs, start -> item and item -> goal, as padded polylines in a pytree, so the controller is a pure
JAX function (``jit`` and ``vmap`` over episodes, no Python per step).

Each step the controller projects the robot onto the current leg near its last progress, aims at the
point ``lookahead`` metres further along and steers on the pure-pursuit arc ``kappa = 2 sin(alpha) / d``
at the speed the turn rate allows (``v <= w_max / |kappa|``: slow in sharp turns), turning on the spot
when the aim lies far off the heading. A guard refuses a step the map says would touch a shelf or wall
(counted: it never acts on the study's maps without randomization).

It reads the env state, not the observation: pose, carrying, item, and the moving obstacles'
positions ``state.obstacle_pos`` (exactly what the lidar shows, without having to fit discs to rays).
It waits (``v = 0``) while a step would approach an obstacle within a braking distance. An obstacle
never drives into the robot but waits for it, so after waiting ``patience`` steps the robot steps
aside, across the obstacle's line (obstacles travel along grid lines), and holds there a while.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from wrl_jax.envs.continuous.geometry import hits_shelf, hits_wall, wrap
from wrl_jax.envs.continuous.shortest_path import item_legs
from wrl_jax.envs.continuous.types import ContinuousParams, ContinuousState


@dataclasses.dataclass(frozen=True)
class PursuitConfig:
    """The controller's settings (static: hashable, part of the compiled program). Metres, radians, steps."""

    margin: float = 0.12  # the path is planned for robot_radius + margin
    lookahead: float = 0.5  # distance along the leg from the robot's progress to the point it aims at
    turn_in_place: float = 1.0  # |alpha| above which it turns on the spot
    speed: float = 1.0  # fraction of v_max on straight stretches
    window: float = 1.0  # how far ahead of its last progress the projection may jump
    guard_margin: float = 0.01  # the guard refuses steps that bring the disc closer than this to a shelf or wall
    noise_margin: float = 0.05  # added to guard_margin where params.randomize (steps also taken at gain_high)
    brake: float = 0.4  # wait rather than approach an obstacle within robot_radius + obstacle_radius + lateral
    lateral: float = 0.1  # ... of the next `brake` metres of the robot's way
    patience: int = 6  # steps of waiting before stepping aside
    escape_steps: int = 15  # steps spent stepping aside and holding there
    escape_distance: float = 0.7  # how far aside: beyond robot_radius + obstacle_radius off the obstacle's line
    escape_speed: float = 0.5  # fraction of v_max when stepping aside

    def check(self) -> None:
        """Raise ``ValueError`` naming the first setting out of range."""
        for name in ("margin", "lookahead", "turn_in_place", "speed", "window", "escape_distance", "escape_speed"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"pursuit setting {name} must be positive, got {getattr(self, name)!r}")
        for name in ("brake", "lateral", "guard_margin", "noise_margin"):
            if not float(getattr(self, name)) >= 0:
                raise ValueError(f"pursuit setting {name} must be >= 0, got {getattr(self, name)!r}")
        if self.speed > 1 or self.escape_speed > 1:
            raise ValueError("pursuit settings speed and escape_speed are fractions of v_max, at most 1")
        for name in ("patience", "escape_steps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"pursuit setting {name} must be a positive integer, got {value!r}")


@struct.dataclass
class PursuitPlan:
    """Per item, the two legs as polylines padded to ``K`` points by repeating the last one."""

    points: jax.Array  # (I, 2, K, 2) float32: [item, 0] start -> item, [item, 1] item -> goal
    cumlen: jax.Array  # (I, 2, K) float32 arc length at each point (constant over the padding)
    items: jax.Array  # (I, 2) float32 item points: how an episode's item is recognised


@struct.dataclass
class PursuitState:
    """The controller's memory within an episode."""

    item: jax.Array  # int32 item index
    leg: jax.Array  # int32: 0 to the item, 1 to the goal
    progress: jax.Array  # float32 arc length along the leg
    waited: jax.Array  # int32 consecutive steps waiting for a moving obstacle
    escape_left: jax.Array  # int32 steps of stepping aside left (0: following the leg)
    escape_point: jax.Array  # (2,) float32 where it steps aside to
    guarded: jax.Array  # int32 steps the guard refused (a diagnostic: 0 when the pursuit alone is safe)
    seen: jax.Array  # (M, 2) float32 the obstacles' positions at the last step
    course: jax.Array  # (M, 2) float32 the unit direction each obstacle last moved in (0 before it moved)


def make_plan(params: ContinuousParams, config: PursuitConfig = PursuitConfig()) -> PursuitPlan:
    """The padded legs of every item (NumPy on the host, once per layout).

    Raises:
        ValueError: a bad setting, or ``robot_radius + margin`` not below 1/2 (no path through a cell).
    """
    config.check()
    radius = float(params.robot_radius) + config.margin
    if not radius < 0.5:
        raise ValueError(f"robot_radius + margin = {radius} leaves no path through a 1 m cell (must be below 0.5)")
    num_items = int(params.num_items)
    items = np.asarray(params.items, np.float64)[:num_items]
    _, _, routes = item_legs(np.asarray(params.shelves), np.asarray(params.start, np.float64),
                             np.asarray(params.goal, np.float64), items, radius, with_routes=True)
    size = max(len(leg) for legs in routes for leg in legs)
    points = np.zeros((num_items, 2, size, 2), np.float32)
    cumlen = np.zeros((num_items, 2, size), np.float32)
    for i, legs in enumerate(routes):
        for j, leg in enumerate(legs):
            padded = np.concatenate([leg, np.repeat(leg[-1:], size - len(leg), axis=0)])
            points[i, j] = padded
            cumlen[i, j] = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(padded, axis=0).T))])
    return PursuitPlan(points=jnp.asarray(points), cumlen=jnp.asarray(cumlen), items=jnp.asarray(items, jnp.float32))


def pursuit_init(plan: PursuitPlan, env_state: ContinuousState) -> PursuitState:
    """The controller's state at an episode's start (its item recognised from ``env_state.item``)."""
    item = jnp.argmin(jnp.sum((plan.items - env_state.item) ** 2, axis=1)).astype(jnp.int32)
    zero = jnp.int32(0)
    return PursuitState(item=item, leg=zero, progress=jnp.float32(0.0), waited=zero, escape_left=zero,
                        escape_point=jnp.zeros(2, jnp.float32), guarded=zero, seen=env_state.obstacle_pos,
                        course=jnp.zeros_like(env_state.obstacle_pos))


def project(points: jax.Array, cumlen: jax.Array, pos: jax.Array, low: jax.Array, high: jax.Array) -> jax.Array:
    """The arc length of the polyline's point nearest ``pos`` among those with arc length in ``[low, high]``."""
    a, b = points[:-1], points[1:]
    start, length = cumlen[:-1], cumlen[1:] - cumlen[:-1]
    safe = jnp.where(length > 0, length, 1.0)
    t = jnp.sum((pos - a) * (b - a), axis=1) / (safe * safe)
    t_low = jnp.clip((low - start) / safe, 0.0, 1.0)
    t_high = jnp.clip((high - start) / safe, 0.0, 1.0)
    t = jnp.where(length > 0, jnp.clip(t, t_low, t_high), 0.0)
    valid = (start <= high) & (start + length >= low)
    gap = jnp.sum((a + t[:, None] * (b - a) - pos) ** 2, axis=1)
    best = jnp.argmin(jnp.where(valid, gap, jnp.inf))
    return start[best] + t[best] * length[best]


def point_at(points: jax.Array, cumlen: jax.Array, s: jax.Array) -> jax.Array:
    """The polyline's point at arc length ``s`` (clipped to its ends)."""
    s = jnp.clip(s, 0.0, cumlen[-1])
    j = jnp.clip(jnp.searchsorted(cumlen, s, side="right") - 1, 0, cumlen.shape[0] - 2)
    length = cumlen[j + 1] - cumlen[j]
    t = jnp.where(length > 0, (s - cumlen[j]) / jnp.where(length > 0, length, 1.0), 0.0)
    return points[j] + t * (points[j + 1] - points[j])


def clear(point: jax.Array, params: ContinuousParams, margin: float) -> jax.Array:
    """Whether a disc of ``robot_radius + margin`` at ``point`` is free of shelves and walls (the env's own tests)."""
    height, width = params.shelves.shape
    radius = params.robot_radius + margin
    return ~hits_shelf(point, radius, params.shelves) & ~hits_wall(point, radius, width, height)


def steer(pos: jax.Array, heading: jax.Array, target: jax.Array, speed: jax.Array, params: ContinuousParams,
          config: PursuitConfig) -> tuple[jax.Array, jax.Array]:
    """Pure pursuit towards ``target`` for a robot facing ``heading``: ``(v >= 0, w)`` in m/s and rad/s.

    The arc's curvature ``2 sin(alpha) / d`` sets the turn; the speed is cut to what ``w_max`` allows on
    it (slow in sharp turns) and so as not to pass the target; an aim more than ``turn_in_place`` off the
    heading is turned to on the spot. A turn never overshoots the aim within a step.
    """
    offset = target - pos
    distance = jnp.maximum(jnp.sqrt(jnp.sum(offset * offset)), 1e-3)
    alpha = wrap(jnp.arctan2(offset[1], offset[0]) - heading)
    kappa = 2.0 * jnp.sin(alpha) / distance
    v = jnp.minimum(speed * params.v_max, params.w_max / jnp.maximum(jnp.abs(kappa), 1e-6))
    v = jnp.minimum(v, distance / params.dt)
    w = jnp.clip(v * kappa, -jnp.abs(alpha) / params.dt, jnp.abs(alpha) / params.dt)
    spin = jnp.abs(alpha) > config.turn_in_place
    return jnp.where(spin, 0.0, v), jnp.where(spin, alpha / params.dt, w)


def drive(pos: jax.Array, theta: jax.Array, target: jax.Array, speed: jax.Array, reverse: jax.Array,
          params: ContinuousParams, config: PursuitConfig) -> tuple[jax.Array, jax.Array, jax.Array]:
    """:func:`steer` forwards, or backwards (the rear, ``theta + pi``, leads): signed ``v``, ``w``, the unit motion."""
    heading = jnp.where(reverse, wrap(theta + np.float32(np.pi)), theta)
    v, w = steer(pos, heading, target, speed, params, config)
    turned = heading + w * params.dt
    return jnp.where(reverse, -v, v), w, jnp.stack([jnp.cos(turned), jnp.sin(turned)])


def in_the_way(pos: jax.Array, obstacles: jax.Array, motion: jax.Array, step: jax.Array, margin: jax.Array,
               courteous: jax.Array, params: ContinuousParams, config: PursuitConfig) -> jax.Array:
    """Whether a step of ``step`` metres along unit ``motion`` approaches an obstacle to within ``margin`` of
    contact or, when ``courteous``, approaches one lying within ``robot_radius + obstacle_radius + lateral``
    of the next ``brake`` metres.

    Obstacles never drive into the robot, so its own step is all that can collide; a step that does not
    bring it closer to an obstacle is never refused (a robot can always back off or step aside).
    """
    rel = obstacles - pos  # (M, 2)
    along = rel @ motion
    after = jnp.sqrt(jnp.sum((rel - step * motion) ** 2, axis=1))
    contact = params.robot_radius + params.obstacle_radius
    closer = after < jnp.sqrt(jnp.sum(rel * rel, axis=1))
    overlap = closer & (after < contact + margin)
    nearest = rel - jnp.clip(along, 0.0, config.brake)[:, None] * motion
    near = jnp.sqrt(jnp.sum(nearest * nearest, axis=1)) < contact + config.lateral
    return jnp.any(overlap | (courteous & (along > step / 2) & near))


def escape_point(pos: jax.Array, obstacles: jax.Array, course: jax.Array, margin: jax.Array,
                 params: ContinuousParams, config: PursuitConfig) -> jax.Array:
    """Where to step aside to, ``escape_distance`` away (or half of it where the whole is blocked).

    Candidates are 16 directions at both distances; one counts when the disc is clear of shelves, walls
    and obstacles every 0.1 m along it. Preferred, in order: out of every obstacle's way (the metre ahead
    of it along its ``course``, the direction it last moved in: obstacles travel between cell centres),
    across the line to the nearest obstacle rather than along it, the full distance. Stays put where
    none is clear.
    """
    rel = obstacles - pos
    towards = rel[jnp.argmin(jnp.sum(rel * rel, axis=1))]
    towards = towards / jnp.maximum(jnp.sqrt(jnp.sum(towards * towards)), 1e-6)
    angles = jnp.arange(16, dtype=jnp.float32) * np.float32(np.pi / 8)
    units = jnp.tile(jnp.stack([jnp.cos(angles), jnp.sin(angles)], axis=1), (2, 1))  # (32, 2)
    reach = jnp.repeat(jnp.array([1.0, 0.5], jnp.float32) * config.escape_distance, 16)  # (32,)
    samples = max(1, int(np.ceil(config.escape_distance / 0.1)))
    fractions = jnp.arange(1, samples + 1, dtype=jnp.float32) / samples
    points = pos + (reach[:, None, None] * fractions[None, :, None]) * units[:, None, :]  # (32, n, 2)
    free = jax.vmap(jax.vmap(lambda p: clear(p, params, margin)))(points).all(axis=1)
    gaps = jnp.sqrt(jnp.sum((points[:, :, None, :] - obstacles[None, None]) ** 2, axis=-1))  # (32, n, M)
    contact = params.robot_radius + params.obstacle_radius
    free = free & jnp.all(gaps >= contact + margin, axis=(1, 2))
    # Distance of each end point to each obstacle's next metre of travel.
    ends = points[:, -1, None, :] - obstacles[None]  # (32, M, 2)
    ahead = jnp.clip(jnp.sum(ends * course[None], axis=-1), 0.0, 1.0)
    sweep = jnp.sqrt(jnp.sum((ends - ahead[..., None] * course[None]) ** 2, axis=-1))
    in_way = jnp.any(sweep < contact + config.lateral, axis=1)
    cosine = units @ towards
    score = (jnp.where(free, 0.0, 10.0) + jnp.where(in_way, 2.0, 0.0) + jnp.abs(cosine)
             + jnp.where(cosine > 0.3, 1.0, 0.0) + jnp.where(reach < config.escape_distance, 0.5, 0.0))
    best = jnp.argmin(score)
    return jnp.where(free[best], points[best, -1], pos)


def guarded_step(pos: jax.Array, theta: jax.Array, command: tuple, points: jax.Array, cumlen: jax.Array,
                 progress: jax.Array, speed: jax.Array, follows: jax.Array, margin: jax.Array, gain: jax.Array,
                 params: ContinuousParams, config: PursuitConfig) -> tuple[tuple, jax.Array]:
    """The guard: a ``command`` ``(v, w, motion)`` whose step the map says would come within ``margin`` of a shelf
    or wall is replaced, when following the leg, by one back to the leg (to its nearest point, backwards if
    that lies behind; along it when already on it), else by turning only. Returns the command and whether
    the guard acted."""
    v, w, motion = command
    unsafe = ~clear(pos + (jnp.abs(v) * params.dt * gain) * motion, params, margin)
    off = point_at(points, cumlen, progress) - pos
    on_leg = jnp.sum(off * off) < 0.05 ** 2
    back = point_at(points, cumlen, progress + jnp.where(on_leg, 0.15, 0.0))
    behind = ~on_leg & (jnp.abs(wrap(jnp.arctan2(off[1], off[0]) - theta)) > np.float32(np.pi / 2))
    back_v, back_w, back_motion = drive(pos, theta, back, speed, behind, params, config)
    recover = unsafe & follows & clear(pos + (jnp.abs(back_v) * params.dt * gain) * back_motion, params, margin)
    v = jnp.where(recover, back_v, jnp.where(unsafe, 0.0, v))
    return (v, jnp.where(recover, back_w, w), jnp.where(recover, back_motion, motion)), unsafe


def pursuit_act(plan: PursuitPlan, state: PursuitState, env_state: ContinuousState, params: ContinuousParams,
                config: PursuitConfig = PursuitConfig()) -> tuple[jax.Array, PursuitState]:
    """One step: the action (``(2,)`` in ``[-1, 1]``) and the controller's next state. Jittable, vmappable."""
    pos, theta, obstacles = env_state.pos, env_state.theta, env_state.obstacle_pos
    leg = env_state.carrying.astype(jnp.int32)
    fresh = leg != state.leg
    progress = jnp.where(fresh, 0.0, state.progress)
    waited = jnp.where(fresh, 0, state.waited)
    escaping = ~fresh & (state.escape_left > 0)
    moved = obstacles - state.seen
    distance = jnp.sqrt(jnp.sum(moved * moved, axis=1, keepdims=True))
    course = jnp.where(distance > 1e-6, moved / jnp.maximum(distance, 1e-6), state.course)
    points, cumlen = plan.points[state.item, leg], plan.cumlen[state.item, leg]
    progress = project(points, cumlen, pos, progress - config.lookahead, progress + config.window)
    # Follow the leg, or drive (forwards or backwards, whichever faces it) to the escape point and hold there.
    target = jnp.where(escaping, state.escape_point, point_at(points, cumlen, progress + config.lookahead))
    offset = target - pos
    reverse = escaping & (jnp.abs(wrap(jnp.arctan2(offset[1], offset[0]) - theta)) > np.float32(np.pi / 2))
    speed = jnp.where(escaping, config.escape_speed, config.speed)
    v, w, motion = drive(pos, theta, target, speed, reverse, params, config)
    arrived = escaping & (jnp.sum(offset * offset) < 0.05 ** 2)
    v, w = jnp.where(arrived, 0.0, v), jnp.where(arrived, 0.0, w)
    # Randomized gains and noise: steps are checked as taken at gain_high, with noise_margin more room.
    gain = jnp.where(params.randomize, params.gain_high, 1.0)
    margin = config.guard_margin + jnp.where(params.randomize, config.noise_margin, 0.0)
    (v, w, motion), unsafe = guarded_step(pos, theta, (v, w, motion), points, cumlen, progress, speed, ~escaping,
                                          margin, gain, params, config)
    # Moving obstacles: wait while one is in the way (turning on the spot is harmless); step aside after a while.
    # While stepping aside, to a point checked clear of them, obstacles are only kept from being touched.
    blocked = (v != 0) & in_the_way(pos, obstacles, motion, jnp.abs(v) * params.dt * gain,
                                    jnp.where(escaping, margin - config.guard_margin + 1e-3, margin), ~escaping,
                                    params, config)
    v = jnp.where(blocked, 0.0, v)
    waited = jnp.where(blocked & ~escaping, waited + 1, 0)
    trigger = waited >= config.patience
    escape = state.escape_point
    if obstacles.shape[0]:  # static: without moving obstacles nothing ever blocks
        escape = jnp.where(trigger, escape_point(pos, obstacles, course, margin, params, config), escape)
    escape_left = jnp.where(trigger, config.escape_steps, jnp.where(escaping, state.escape_left - 1, 0))
    next_state = PursuitState(item=state.item, leg=leg, progress=progress.astype(jnp.float32),
                              waited=jnp.where(trigger, 0, waited).astype(jnp.int32),
                              escape_left=escape_left.astype(jnp.int32), escape_point=escape.astype(jnp.float32),
                              guarded=state.guarded + unsafe.astype(jnp.int32), seen=obstacles, course=course)
    action = jnp.stack([v / params.v_max, w / params.w_max])
    return jnp.clip(action, -1.0, 1.0).astype(jnp.float32), next_state
