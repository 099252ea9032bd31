"""The continuous warehouse of CONTINUOUS_SPEC.md in JAX: a disc robot with unicycle kinematics,
an exact lidar, moving obstacles and domain randomization, on any layout of SPEC.md.

The class draws the randomness (:meth:`ContinuousWarehouse.reset_draws`, :meth:`step_draws`) and
hands it to the deterministic core (:mod:`wrl_jax.envs.continuous.dynamics`), so the NumPy
reference replays a JAX episode from its draws. ``step`` is the base class's: transition, then
the auto-reset where the episode ended.

``observe_target=True`` appends :func:`target_features` to the contract's observation: the target's
offset in the robot's own frame, computed from the observation itself (so it adds no information).
A network reads "the item is 2 m ahead, 1 m to the left" directly instead of having to learn a
rotation of a difference of coordinates; PPO learns the 8x8 map with it and not without it
(docs/continuous.md).

``observe_obstacles=True`` appends (after the target's values, before a route's) what a robot with a
people detector and odometry knows beyond its lidar: the range along each ray to the nearest moving
obstacle alone (shelves do not hide them; no noise) and whether the last step was blocked, by an
obstacle or by a shelf or wall. With the lidar alone a moving obstacle reads like a shelf, and a
blocked robot sees what it saw before it pushed.

``safety_margin=m`` (``make(..., safety_stop=True)``) puts a reflex under the policy
(:mod:`~wrl_jax.envs.continuous.safety`): a forward command the robot's lidar says would come within
``robot_radius + m`` of something is replaced before the contract's step by one that holds the robot (0; under
randomization, the one the episode's gain and the step's noise cancel) (``info["safety_stop"]``). With
``observe_obstacles`` the flags then say blocked too, and one more value says for how many steps in a row the
robot has been held: a policy without memory can then tell a standstill that lasts from one that has just
begun, and back out of it. ``escape_after=K`` (with the stop) turns the robot fully once it has been held ``K``
steps in a row (:func:`~wrl_jax.envs.continuous.safety.escape`).
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.core.environment import Environment
from wrl_jax.core.gymnax_base import spaces
from wrl_jax.envs.continuous.dynamics import OBS_SCALARS, reset_core, transition_core
from wrl_jax.envs.continuous.geometry import PI, norm, ray_angles, ray_discs
from wrl_jax.envs.continuous.safety import escape, safety_stop
from wrl_jax.envs.continuous.types import ContinuousParams, ContinuousState, ResetDraws, StepDraws

TARGET_FEATURES = 5
"""Values :func:`target_features` appends: forward and left offsets, distance, and the bearing's cosine and sine."""


OBSTACLE_FLAGS = 2
"""Values :func:`obstacle_features` appends after its rays: the last step blocked by an obstacle, by a shelf or wall."""

HELD_STEPS = 10
"""With the safety stop and ``observe_obstacles``, the held value reads ``min(held, HELD_STEPS) / HELD_STEPS``."""


def obstacle_features(state: ContinuousState, info: dict[str, jax.Array] | None, num_rays: int,
                      params: ContinuousParams) -> jax.Array:
    """The moving obstacles seen from ``state`` (after the step): ``L`` ranges over ``lidar_range`` along the
    contract's rays to the nearest obstacle alone (1 where none is in range), then whether the step was
    blocked, by an obstacle or by a shelf or wall: a contact, or the safety stop where it is on (0 at a
    reset, ``info=None``)."""
    ranges = ray_discs(state.pos, ray_angles(state.theta, num_rays), state.obstacle_pos, params.obstacle_radius)
    reading = jnp.minimum(ranges, params.lidar_range) / params.lidar_range
    if info is None:
        flags = jnp.zeros((OBSTACLE_FLAGS,), jnp.float32)
    else:
        by_obstacle, by_shelf = info["hit_obstacle"], info["hit_shelf"] | info["hit_wall"]
        if "stop_obstacle" in info:
            by_obstacle, by_shelf = by_obstacle | info["stop_obstacle"], by_shelf | info["stop_shelf"]
        flags = jnp.stack([by_obstacle, by_shelf]).astype(jnp.float32)
    return jnp.concatenate([reading, flags])


def target_features(obs: jax.Array, width: int, height: int) -> jax.Array:
    """The target (the item, or the goal while carrying) seen from the robot, from the contract's observation.

    ``(forward, left, distance)`` in metres over the map's longer side, then ``(cos, sin)`` of the
    bearing (0, 0 on the target). Exact functions of observation values 0-3 and 6-10.
    """
    size = jnp.array([width, height], jnp.float32)
    offset = jnp.where(obs[10] > 0.5, obs[6:8], obs[8:10]) * size - obs[0:2] * size
    cos, sin = obs[2], obs[3]
    forward = offset[0] * cos + offset[1] * sin
    left = offset[1] * cos - offset[0] * sin
    distance = norm(offset)
    bearing = jnp.where(distance > 0, jnp.stack([forward, left]) / jnp.maximum(distance, 1e-12), 0.0)
    scale = jnp.float32(max(width, height))
    return jnp.concatenate([jnp.stack([forward, left, distance]) / scale, bearing])


class ContinuousWarehouse(Environment[ContinuousState, ContinuousParams]):
    """CONTINUOUS_SPEC.md's MDP; build it with :func:`wrl_jax.envs.continuous.registration.make_continuous`.

    Static configuration: the map's ``height`` x ``width``, ``num_rays`` (L), ``num_obstacles`` (M)
    and the item slots; everything else is in params. Action: float32 ``(2,)`` in ``[-1, 1]``
    (forward speed, turn rate, as fractions of ``v_max`` and ``w_max``).
    """

    family = "continuous"
    event_metrics = MappingProxyType({"collision": "collisions_sum"})

    def __init__(self, params: ContinuousParams, num_rays: int = 32, num_obstacles: int = 0,
                 name: str = "Continuous-Warehouse", observe_target: bool = False,
                 observe_obstacles: bool = False, safety_margin: float | None = None,
                 escape_after: int | None = None):
        super().__init__(params)
        self.height, self.width = (int(n) for n in params.shelves.shape)
        self.num_rays, self.num_obstacles = int(num_rays), int(num_obstacles)
        self.max_items = int(params.items.shape[0])
        self.observe_target = bool(observe_target)
        self.observe_obstacles = bool(observe_obstacles)
        self.safety_margin = None if safety_margin is None else float(safety_margin)
        if self.safety_margin is not None:
            self.event_metrics = MappingProxyType({**self.event_metrics, "safety_stop": "safety_stops_sum"})
        if escape_after is not None and (isinstance(escape_after, bool) or not isinstance(escape_after, (int, np.integer))
                                         or escape_after < 1 or self.safety_margin is None):
            raise ValueError(f"escape_after must be a positive integer (held steps in a row; make() and the commands "
                             f"read 0 as off) with the safety stop on, got {escape_after!r} with "
                             f"safety_margin={self.safety_margin!r}")
        self.escape_after = None if escape_after is None else int(escape_after)
        self._name = name

    def static_config(self) -> tuple:
        return (self.height, self.width, self.num_rays, self.num_obstacles, self.max_items, self.observe_target,
                self.observe_obstacles, self.safety_margin, self.escape_after)

    @property
    def name(self) -> str:
        return self._name

    @property
    def observe_held(self) -> bool:
        """Whether the view ends its obstacles' values with how long the robot has been held (the stop's)."""
        return self.observe_obstacles and self.safety_margin is not None

    @property
    def obs_size(self) -> int:
        return (OBS_SCALARS + self.num_rays + (TARGET_FEATURES if self.observe_target else 0)
                + (self.num_rays + OBSTACLE_FLAGS if self.observe_obstacles else 0) + int(self.observe_held))

    def observation(self, obs: jax.Array, state: ContinuousState, info: dict[str, jax.Array] | None,
                    params: ContinuousParams) -> jax.Array:
        """The contract's observation, then :func:`target_features` under ``observe_target`` and
        :func:`obstacle_features` under ``observe_obstacles`` (``info`` is ``None`` at a reset)."""
        parts = [obs]
        if self.observe_target:
            parts.append(target_features(obs, self.width, self.height))
        if self.observe_obstacles:
            parts.append(obstacle_features(state, info, self.num_rays, params))
        if self.observe_held:
            parts.append((jnp.minimum(state.held, HELD_STEPS).astype(jnp.float32) / HELD_STEPS)[None])
        return jnp.concatenate(parts) if len(parts) > 1 else obs

    @property
    def num_actions(self) -> int:
        """The action's length (two continuous commands)."""
        return 2

    def __repr__(self) -> str:
        safety = "" if self.safety_margin is None else f", safety_margin={self.safety_margin}"
        safety += "" if self.escape_after is None else f", escape_after={self.escape_after}"
        return (f"ContinuousWarehouse({self._name}, {self.height}x{self.width}, rays={self.num_rays}, "
                f"obstacles={self.num_obstacles}{safety})")

    # ------------------------------------------------------------ draws
    def reset_draws(self, key: jax.Array, params: ContinuousParams) -> ResetDraws:
        """A reset's randomness: item, obstacle cells and first waypoints, and the randomized start."""
        k_item, k_cells, k_way, k_gain, k_offset, k_theta, k_lidar = jax.random.split(key, 7)
        item_index = jax.random.randint(k_item, (), 0, params.num_items)
        if self.num_obstacles:
            weights = params.obstacle_cells.reshape(-1).astype(jnp.float32)
            flat = jax.random.choice(k_cells, weights.shape[0], (self.num_obstacles,), replace=False,
                                     p=weights / weights.sum())
            cells = jnp.stack([flat // self.width, flat % self.width], axis=-1).astype(jnp.int32)
        else:
            cells = jnp.zeros((0, 2), jnp.int32)
        waypoint_u = jax.random.uniform(k_way, (self.num_obstacles,))
        gains = jax.random.uniform(k_gain, (2,), minval=params.gain_low, maxval=params.gain_high)
        radius_u, angle_u = jax.random.uniform(k_offset, (2,))
        angle = (2.0 * PI) * angle_u
        offset = (params.start_jitter * jnp.sqrt(radius_u)) * jnp.stack([jnp.cos(angle), jnp.sin(angle)])
        theta = jax.random.uniform(k_theta, (), minval=-PI, maxval=PI)
        on = params.randomize
        reading = self.step_draws(k_lidar, params)
        return ResetDraws(item_index=item_index, obstacle_cells=cells, waypoint_u=waypoint_u,
                          gains=jnp.where(on, gains, 1.0), start_offset=jnp.where(on, offset, 0.0),
                          theta=jnp.where(on, theta, 0.0), lidar_noise=reading.lidar_noise,
                          lidar_drop=reading.lidar_drop)

    def step_draws(self, key: jax.Array, params: ContinuousParams) -> StepDraws:
        """A step's randomness: actuation and lidar noise, dropout, the waypoint draws."""
        k_noise, k_way, k_lidar, k_drop = jax.random.split(key, 4)
        on = params.randomize
        scale = params.actuation_noise * jnp.stack([params.v_max, params.w_max])
        noise = jax.random.normal(k_noise, (2,)) * scale
        lidar_noise = jax.random.normal(k_lidar, (self.num_rays,)) * params.lidar_noise
        drop = jax.random.uniform(k_drop, (self.num_rays,)) < params.lidar_dropout
        return StepDraws(noise=jnp.where(on, noise, 0.0), waypoint_u=jax.random.uniform(k_way, (self.num_obstacles,)),
                         lidar_noise=jnp.where(on, lidar_noise, 0.0), lidar_drop=on & drop)

    # ------------------------------------------------------------ the MDP
    def reset_env(self, key: jax.Array, params: ContinuousParams) -> tuple[jax.Array, ContinuousState]:
        return self.reset_with(self.reset_draws(key, params), params)

    def reset_with(self, draws: ResetDraws, params: ContinuousParams) -> tuple[jax.Array, ContinuousState]:
        """The reset from given draws (evaluation and rendering force the item)."""
        obs, state = reset_core(draws, params)
        return self.observation(obs, state, None, params), state

    def transition(self, key: jax.Array, state: ContinuousState, action: Any, params: ContinuousParams):
        self.check_action(action)
        obs, reached, reward, terminated, truncated, info = self.contract_step(key, state, action, params)
        return self.observation(obs, reached, info, params), reached, reward, terminated, truncated, info

    def contract_step(self, key: jax.Array, state: ContinuousState, action: Any, params: ContinuousParams):
        """The contract's transition from this step's draws, behind the safety stop where it is on, and the
        count of steps the robot has been held (``state.held``: a contact or the stop, in a row) where the view
        or the escape reads it (0 elsewhere: the other programs stay the ones measured)."""
        draws = self.step_draws(key, params)
        if self.safety_margin is None:
            return transition_core(state, action, draws, params)
        invalid = jnp.any(jnp.isnan(jnp.asarray(action, jnp.float32)))  # the policy's NaN, whatever replaces it
        action = escape(state.held, action, self.escape_after)
        action, stop_obstacle, stop_shelf = safety_stop(state, action, draws.noise, self.num_rays, self.safety_margin,
                                                        params)
        obs, reached, reward, terminated, truncated, info = transition_core(state, action, draws, params)
        info = {**info, "safety_stop": stop_obstacle | stop_shelf, "stop_obstacle": stop_obstacle,
                "stop_shelf": stop_shelf, "invalid_action": info["invalid_action"] | invalid}
        if self.observe_held or self.escape_after is not None:
            held = info["collision"] | info["safety_stop"]
            reached = reached.replace(held=jnp.where(held, state.held + 1, 0).astype(jnp.int32))
        return obs, reached, reward, terminated, truncated, info

    def get_obs(self, state: ContinuousState, params: ContinuousParams | None = None, key=None) -> jax.Array:
        raise NotImplementedError("the observation holds the applied command: read it from reset or step")

    def is_terminated(self, state: ContinuousState, params: ContinuousParams) -> jax.Array:
        return state.carrying & (norm(state.pos - params.goal) <= params.reach_radius)

    # ------------------------------------------------------------ checks and spaces
    def check_action(self, action: Any) -> None:
        """An action of the wrong shape or kind is refused, traced or not (both are known when tracing); NaN is
        read as 0 and flagged (the contract)."""
        array = action if isinstance(action, jax.core.Tracer) else np.asarray(action)
        if array.shape != (2,):
            raise ValueError(f"a continuous warehouse action has shape (2,) (speed, turn), got shape {array.shape}")
        if not (jnp.issubdtype(array.dtype, jnp.floating) or jnp.issubdtype(array.dtype, jnp.integer)):
            raise ValueError(f"a continuous warehouse action is two floats in [-1, 1], got dtype {array.dtype}")

    def action_space(self, params: ContinuousParams | None = None) -> spaces.Box:
        return spaces.Box(low=-1.0, high=1.0, shape=(2,), dtype=jnp.float32)

    def observation_space(self, params: ContinuousParams | None = None) -> spaces.Box:
        """Every value in [-1, 1] but the applied command (4, 5): randomized gains and noise take it past 1
        (and the target's offset and distance, at most the map's diagonal over its longer side)."""
        high = np.ones(self.obs_size, np.float32)
        high[4:6] = np.inf
        if self.observe_target:
            high[OBS_SCALARS + self.num_rays:][:3] = np.sqrt(2.0)
        low = -high
        if self.observe_obstacles:  # the obstacles' ranges and the contact flags lie in [0, 1]
            start = OBS_SCALARS + self.num_rays + (TARGET_FEATURES if self.observe_target else 0)
            low[start:start + self.num_rays + OBSTACLE_FLAGS + int(self.observe_held)] = 0.0
        return spaces.Box(low=low, high=high, shape=(self.obs_size,), dtype=jnp.float32)

    def state_space(self, params: ContinuousParams | None = None) -> spaces.Dict:
        raise NotImplementedError("the continuous warehouse has no state space")
