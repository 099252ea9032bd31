"""Shaping by the distance around the shelves: the contract's MDP with a potential that points past them.

The contract shapes with the Manhattan distance to the target (CONTINUOUS_SPEC.md, as in the study).
Behind a shelf row that distance points into the shelves, and an off-policy learner whose first
data are mostly collisions learns to stand still. :class:`GeodesicShaping` keeps every transition
of the contract (state, observation, events, termination) and replaces only ``d`` in the shaping
term by the length of the shortest way around the shelves, so the optimal policies are unchanged
(a potential-based shaping, Ng et al. 1999) and the signal leads round the rows.

The distances live on a lattice of ``1/resolution`` metres, one field per item slot and one for the
goal, computed once per layout (16-connected shortest paths, within 3 % of the any-angle length),
read at the robot's centre by bilinear interpolation. Routes keep the robot's radius plus
``SPARE`` from shelves and walls, so following the potential does not graze corners; lattice points
closer than that take the value of their best free neighbour plus the step, so the potential rises
towards the shelves instead of leaving holes in the interpolation. A pool of layouts (the procedural
variant) gets every slot's fields in one computation (:func:`pool_distance_fields`), on a coarser lattice.

``observe_route=True`` also shows the learner the way: :func:`route_features` appends the direction
in which the field falls fastest at the robot (in its own frame) and the length of the way left. A
global planner handing its route to a learned local controller, as navigation stacks do: the learner
still drives, avoids and times everything itself, but no longer has to memorise the map's routes
(SAC on the 12x12 map: docs/continuous.md).
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from wrl_jax.envs.continuous.dynamics import manhattan
from wrl_jax.envs.continuous.env import ContinuousWarehouse
from wrl_jax.envs.continuous.geometry import norm
from wrl_jax.envs.continuous.types import ContinuousParams, ContinuousState

RESOLUTION = 10
"""Lattice points per metre."""
SPARE = 0.1
"""Metres the field's routes keep from shelves and walls beyond the robot's radius."""
UNREACHABLE = 1e4
"""The distance read where the target cannot be reached (finite, so differences stay 0, not NaN)."""
FILL_METRES = 0.4
"""Metres over which points off the routes look for a route point (:func:`fill_reach` lattice steps)."""
FILL_CHUNK = 16
"""Layouts filled at a time by :func:`pool_distance_fields`."""
ROUTE_FEATURES = 3
"""Values :func:`route_features` appends: the way's direction (forward, left) and its remaining length."""
ROUTE_STEP = 0.05
"""Metres either side of the robot at which the field is read for its slope (half a lattice step)."""
ROUTE_LENGTH_CAP = 4.0
"""The remaining length is given over the map's longer side and capped here (an unreachable target reads 4)."""
MOVES = tuple((dy, dx) for dy in range(-2, 3) for dx in range(-2, 3)
              if (dy, dx) != (0, 0) and np.gcd(abs(dy), abs(dx)) == 1)
"""The 16 lattice moves: the 8 neighbours and the 8 knight's moves."""


@struct.dataclass
class GeodesicParams(ContinuousParams):
    """The contract's params with ``fields``: ``(I + 1, ny, nx)`` metres to each item slot, then to the goal."""

    fields: jax.Array = None


def free_lattice(shelves: np.ndarray, margin: float, resolution: int = RESOLUTION) -> np.ndarray:
    """``(..., H r + 1, W r + 1)`` bool: lattice points at least ``margin`` from every shelf square and the
    boundary, for one map ``(H, W)`` or a stack of them ``(..., H, W)``."""
    shelves = np.asarray(shelves, bool)
    height, width = shelves.shape[-2:]
    ys, xs = np.meshgrid(np.arange(height * resolution + 1) / resolution,
                         np.arange(width * resolution + 1) / resolution, indexing="ij")
    free = (xs >= margin) & (xs <= width - margin) & (ys >= margin) & (ys <= height - margin)
    rows, cols = np.indices((height, width)).reshape(2, -1, 1, 1)
    dx = np.clip(xs, cols, cols + 1) - xs
    dy = np.clip(ys, rows, rows + 1) - ys
    near = (dx * dx + dy * dy < margin * margin).reshape(height * width, -1)  # (cells, points)
    blocked = shelves.reshape(-1, height * width).astype(np.float32) @ near.astype(np.float32) > 0
    return free & ~blocked.reshape(shelves.shape[:-2] + free.shape)


def _move_allowed(free: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """Where the move ``(dy, dx)`` joins two points on the routes (and, for a knight's move, passes
    between two more); ``free`` is ``(..., ny, nx)``."""
    ny, nx = free.shape[-2:]
    padded = np.pad(free, [(0, 0)] * (free.ndim - 2) + [(2, 2), (2, 2)], constant_values=False)

    def at(oy, ox):  # free[..., y + oy, x + ox] for every (y, x), False off the lattice
        return padded[..., 2 + oy: 2 + oy + ny, 2 + ox: 2 + ox + nx]

    allowed = free & at(dy, dx)
    if abs(dy) == 2:  # a knight's move passes between two points: both must be free
        allowed &= at(dy // 2, 0) & at(dy // 2, dx)
    elif abs(dx) == 2:
        allowed &= at(0, dx // 2) & at(dy, dx // 2)
    return allowed


def distance_fields(shelves: np.ndarray, targets: np.ndarray, margin: float,
                    resolution: int = RESOLUTION) -> np.ndarray:
    """``(K, ny, nx)`` float32: the lattice distance (metres) from every lattice point to each ``targets[k]``.

    Bellman-Ford on the 16-connected lattice, all targets at once, in a compiled ``while`` that stops
    when nothing shortens (at most one pass per lattice point). Routes run over the points at least
    ``margin`` from shelves and walls; the other points only receive. Targets are snapped to the
    nearest lattice point; a target that is not on the routes leaves its field unreachable.

    Remembered per layout, targets and margin (the last 32): every environment made on one map with the
    geodesic shaping (an evaluation, a notebook, a sweep's points) needs the same fields.
    """
    shelves, targets = np.asarray(shelves, bool), np.asarray(targets, np.float64)
    return _distance_fields(shelves.tobytes(), shelves.shape, targets.tobytes(), targets.shape, float(margin),
                            int(resolution)).copy()


@functools.lru_cache(maxsize=32)
def _distance_fields(shelves_bytes: bytes, shelves_shape: tuple, targets_bytes: bytes, targets_shape: tuple,
                     margin: float, resolution: int) -> np.ndarray:
    shelves = np.frombuffer(shelves_bytes, bool).reshape(shelves_shape)
    targets = np.frombuffer(targets_bytes, np.float64).reshape(targets_shape)
    return pool_distance_fields(shelves[None], targets[None], margin, resolution)[0]


def pool_distance_fields(shelves: np.ndarray, targets: np.ndarray, margin: float,
                         resolution: int = RESOLUTION) -> np.ndarray:
    """:func:`distance_fields` of a stack of maps at once: ``shelves`` ``(P, H, W)``, ``targets`` ``(P, K, 2)``
    (``x, y`` metres) -> ``(P, K, ny, nx)`` float32, one compiled relaxation for the whole stack."""
    shelves, targets = np.asarray(shelves, bool), np.asarray(targets, np.float64)
    free = free_lattice(shelves, margin, resolution)  # (P, ny, nx)
    allowed = np.stack([_move_allowed(free, dy, dx) for dy, dx in MOVES])[:, :, None]  # (moves, P, 1, ny, nx)
    lengths = np.array([np.hypot(dy, dx) / resolution for dy, dx in MOVES], np.float32)
    cells = np.rint(targets * resolution).astype(int)  # (P, K, 2): x, y
    x, y = cells[..., 0], cells[..., 1]
    inside = (y >= 0) & (y < free.shape[-2]) & (x >= 0) & (x < free.shape[-1])
    layout = np.broadcast_to(np.arange(len(free))[:, None], inside.shape)
    on_route = inside & free[layout, np.where(inside, y, 0), np.where(inside, x, 0)]
    start = np.full(targets.shape[:2] + free.shape[-2:], np.inf, np.float32)
    pick = np.nonzero(on_route)
    start[pick[0], pick[1], y[pick], x[pick]] = 0.0
    fields = np.asarray(_relax(jnp.asarray(start), jnp.asarray(allowed), jnp.asarray(lengths), int(free[0].size)))
    out = np.empty(fields.shape, np.float32)
    for first in range(0, len(fields), FILL_CHUNK):  # a few layouts at a time: the float64 work stays in cache
        chunk = slice(first, first + FILL_CHUNK)
        filled = _fill_off_routes(fields[chunk], free[chunk, None], resolution, fill_reach(resolution))
        out[chunk] = np.minimum(filled, UNREACHABLE)
    return out


def fill_reach(resolution: int) -> int:
    """Lattice steps of :data:`FILL_METRES` (4 at 10 points per metre)."""
    return max(1, round(FILL_METRES * resolution))


def _fill_off_routes(fields: np.ndarray, free: np.ndarray, resolution: int, reach: int) -> np.ndarray:
    """Points off the routes take the best route point within ``reach`` lattice steps, plus the straight
    distance to it: the potential rises towards shelves and walls instead of leaving holes. ``reach`` is
    far less than a shelf is thick, so no value leaks through a shelf from its other side."""
    ny, nx = free.shape[-2:]
    on_routes = np.where(free, fields, np.inf)
    padded = np.pad(on_routes, [(0, 0)] * (fields.ndim - 2) + [(reach, reach), (reach, reach)],
                    constant_values=np.inf)
    best = on_routes.copy()
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            if 0 < dy * dy + dx * dx <= reach * reach:
                shifted = padded[..., reach + dy: reach + dy + ny, reach + dx: reach + dx + nx]
                best = np.minimum(best, shifted + np.hypot(dy, dx) / resolution)
    return np.where(free, fields, best)


@jax.jit(static_argnums=3)
def _relax(start: jax.Array, allowed: jax.Array, lengths: jax.Array, bound: int) -> jax.Array:
    pad = 2

    def sweep(dist):  # dist (..., ny, nx); allowed (moves, ...) broadcasts against it
        padded = jnp.pad(dist, [(0, 0)] * (dist.ndim - 2) + [(pad, pad), (pad, pad)], constant_values=np.inf)
        ny, nx = dist.shape[-2:]
        best = dist
        for m, (dy, dx) in enumerate(MOVES):
            neighbour = padded[..., pad + dy: pad + dy + ny, pad + dx: pad + dx + nx]
            best = jnp.minimum(best, jnp.where(allowed[m], neighbour + lengths[m], jnp.inf))
        return best

    def cond(carry):
        dist, previous, count = carry
        return (count < bound) & jnp.any(dist != previous)

    def body(carry):
        dist, _, count = carry
        return sweep(dist), dist, count + 1

    dist, _, _ = jax.lax.while_loop(cond, body, (sweep(start), start, 1))
    return dist


def read_field(field: jax.Array, point: jax.Array, resolution: int = RESOLUTION) -> jax.Array:
    """The field's value at ``point`` ``(x, y)`` metres: bilinear between the four lattice points around it."""
    ny, nx = field.shape
    gx = jnp.clip(point[0] * resolution, 0.0, nx - 1.0)
    gy = jnp.clip(point[1] * resolution, 0.0, ny - 1.0)
    x0 = jnp.minimum(jnp.floor(gx), nx - 2).astype(jnp.int32)
    y0 = jnp.minimum(jnp.floor(gy), ny - 2).astype(jnp.int32)
    fx, fy = gx - x0, gy - y0
    top = field[y0, x0] * (1 - fx) + field[y0, x0 + 1] * fx
    bottom = field[y0 + 1, x0] * (1 - fx) + field[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


def field_resolution(field: jax.Array, width: int) -> int:
    """Lattice points per metre of a field over a map ``width`` cells wide (static: from shapes)."""
    return (int(field.shape[-1]) - 1) // int(width)


def target_field(params: GeodesicParams, item: jax.Array, carrying: jax.Array) -> jax.Array:
    """The field towards the current target: the slot of the item at ``item`` (metres), or the goal's while carrying."""
    slot = jnp.argmin(jnp.sum(jnp.abs(params.items - item), axis=-1))
    return params.fields[jnp.where(carrying, params.fields.shape[0] - 1, slot)]


def route_features(obs: jax.Array, params: GeodesicParams, width: int, height: int) -> jax.Array:
    """The way to the target from the contract's observation: ``(forward, left, length)``.

    ``(forward, left)`` is the unit vector, in the robot's frame, against the field's slope at the robot
    (central differences :data:`ROUTE_STEP` either side; ``(0, 0)`` where the field is flat: on the
    target, or where it cannot be reached); ``length`` is the field's value over the map's longer side,
    at most :data:`ROUTE_LENGTH_CAP`. The field is the one the shaping reads (the item's slot, or the
    goal's while carrying), found from observation values 0-3 and 8-10.
    """
    size = jnp.array([width, height], jnp.float32)
    pos = obs[0:2] * size
    field = target_field(params, obs[8:10] * size, obs[10] > 0.5)
    read = functools.partial(read_field, field, resolution=field_resolution(field, width))
    dx, dy = jnp.array([ROUTE_STEP, 0.0]), jnp.array([0.0, ROUTE_STEP])
    down = jnp.stack([read(pos - dx) - read(pos + dx), read(pos - dy) - read(pos + dy)])
    slope = norm(down)
    way = jnp.where(slope > 0, down / jnp.maximum(slope, 1e-12), 0.0)
    cos, sin = obs[2], obs[3]
    scale = jnp.float32(max(width, height))
    length = jnp.minimum(read(pos) / scale, ROUTE_LENGTH_CAP)
    return jnp.stack([way[0] * cos + way[1] * sin, way[1] * cos - way[0] * sin, length])


def check_route(shaping: str, observe_route: Any) -> None:
    """Refuse, by name, an ``observe_route`` that is not a bool or comes without the geodesic fields it reads."""
    if not isinstance(observe_route, (bool, np.bool_)):
        raise ValueError(f"observe_route must be True or False, got {observe_route!r}")
    if observe_route and shaping != "geodesic":
        raise ValueError("observe_route reads the geodesic shaping's distance fields: pass shaping='geodesic' "
                         "with it (--shaping geodesic), or observe_route=False (--observe-route False); "
                         f"got shaping={shaping!r}")


def route_space(space, observe_route: bool):
    """An observation space sized with the route (its values bounded by 1), the route's length in ``[0, cap]``."""
    if not observe_route:
        return space
    high, low = np.asarray(space.high).copy(), np.asarray(space.low).copy()
    high[-1] = ROUTE_LENGTH_CAP
    low[-1] = 0.0
    return type(space)(low=low, high=high, shape=space.shape, dtype=jnp.float32)


def with_route(obs: jax.Array, params: GeodesicParams, width: int, height: int, observe_route: bool) -> jax.Array:
    """``obs`` with :func:`route_features` after every other value, under ``observe_route``."""
    if not observe_route:
        return obs
    return jnp.concatenate([obs, route_features(obs, params, width, height)])


def shaping_change(state: ContinuousState, reached: ContinuousState, params: GeodesicParams, width: int) -> jax.Array:
    """What the geodesic shaping adds to the contract's reward for ``state -> reached``: the shaping term
    with the distance around the shelves in place of the Manhattan distance."""
    field = target_field(params, state.item, state.carrying)
    read = functools.partial(read_field, field, resolution=field_resolution(field, width))
    target = jnp.where(state.carrying, params.goal, state.item)
    contract = manhattan(state.pos, target) - manhattan(reached.pos, target)
    return params.shaping_coef * (read(state.pos) - read(reached.pos) - contract)


class GeodesicShaping(ContinuousWarehouse):
    """The contract's warehouse, the shaping term's distance measured around the shelves (see the module).

    Build it with ``make_continuous(layout, shaping="geodesic")`` or ``wrl_jax.make(name, shaping="geodesic")``;
    ``params`` are :class:`GeodesicParams`. Everything but the reward is the contract's, bit for bit, and
    ``observe_route`` appends :func:`route_features` to the observation, last (after the target's and the
    obstacles' values, if any).
    """

    def __init__(self, params: GeodesicParams, num_rays: int = 32, num_obstacles: int = 0,
                 name: str = "Continuous-Warehouse", observe_target: bool = False, observe_route: bool = False,
                 observe_obstacles: bool = False, safety_margin: float | None = None,
                 escape_after: int | None = None):
        super().__init__(params, num_rays=num_rays, num_obstacles=num_obstacles, name=name,
                         observe_target=observe_target, observe_obstacles=observe_obstacles,
                         safety_margin=safety_margin, escape_after=escape_after)
        self.observe_route = bool(observe_route)

    def static_config(self) -> tuple:
        return super().static_config() + (self.observe_route,)

    @property
    def obs_size(self) -> int:
        return super().obs_size + (ROUTE_FEATURES if self.observe_route else 0)

    def with_route(self, obs: jax.Array, params: GeodesicParams) -> jax.Array:
        """The route after every other value (the observation space's last bound is its length)."""
        return with_route(obs, params, self.width, self.height, self.observe_route)

    def observation_space(self, params: GeodesicParams | None = None):
        return route_space(super().observation_space(params), self.observe_route)

    def __repr__(self) -> str:
        return super().__repr__()[:-1] + f", geodesic shaping, route={'on' if self.observe_route else 'off'})"

    def reset_with(self, draws, params: GeodesicParams):
        obs, state = super().reset_with(draws, params)
        return self.with_route(obs, params), state

    def transition(self, key: jax.Array, state: ContinuousState, action: Any, params: GeodesicParams):
        obs, reached, reward, terminated, truncated, info = super().transition(key, state, action, params)
        return (self.with_route(obs, params), reached, reward + shaping_change(state, reached, params, self.width),
                terminated, truncated, info)


def with_fields(env: ContinuousWarehouse, params: ContinuousParams,
                observe_route: bool = False) -> tuple[GeodesicShaping, GeodesicParams]:
    """``(env, params)`` of :class:`GeodesicShaping` over the same layout and settings."""
    targets = np.concatenate([np.asarray(params.items), np.asarray(params.goal)[None]])
    fields = distance_fields(np.asarray(params.shelves), targets, float(params.robot_radius) + SPARE)
    shaped_params = GeodesicParams(**{f: getattr(params, f) for f in params.__dataclass_fields__},
                                   fields=jnp.asarray(fields))
    shaped = GeodesicShaping(shaped_params, num_rays=env.num_rays, num_obstacles=env.num_obstacles, name=env.name,
                             observe_target=env.observe_target, observe_route=observe_route,
                             observe_obstacles=env.observe_obstacles, safety_margin=env.safety_margin,
                             escape_after=env.escape_after)
    return shaped, shaped_params
