"""Pictures of the continuous warehouse: RGB frames and recorded episodes (GIFs through
:func:`wrl_jax.envs.warehouse.render.save_gif`).

:func:`render_frame` paints a palette index per pixel with array operations on a fixed grid of pixel
centres (metres), so it ``jit``s with the cell size static and ``vmap``s over the states of a rollout:
one compiled call draws a whole episode. The picture has the ASCII map's orientation: pixel row
``py`` shows ``y = (py + 0.5) / cell_size``, so row 0 of the map is at the top and ``theta = +pi/2``
(facing ``+y``) points down the picture.

What a frame shows (colours in :data:`COLORS`, shared with the grid renderer where the meaning is):

- floor cells with thin grid lines, shelves as dark brown squares;
- the goal as a green disc of ``reach_radius`` (where a delivery happens);
- the item (before pickup) as an orange square;
- lidar rays, when their distances are given, as thin cyan segments ending where they hit;
- moving obstacles as red discs of ``obstacle_radius``;
- the robot as a blue disc of ``robot_radius`` with a white heading line from near its centre to its
  rim; while carrying it turns purple and holds the orange item at its centre;
- a timer bar along the top edge, as in the grid renderer.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.continuous.dynamics import OBS_SCALARS
from wrl_jax.envs.continuous.geometry import TWO_PI
from wrl_jax.envs.continuous.types import ContinuousParams, ContinuousState
from wrl_jax.envs.warehouse.render import COLORS as GRID_COLORS
from wrl_jax.envs.warehouse.render import check_cell_size

DEFAULT_CELL_SIZE = 32
"""Pixels per metre (one grid cell side) unless told otherwise."""

MIN_CELL_SIZE = 8
"""Below this a 0.3 m robot is under 3 pixels across and its heading line cannot be seen."""

COLORS: dict[str, tuple[int, int, int]] = {
    **GRID_COLORS,
    "heading": (255, 255, 255),
    "obstacle": (210, 45, 45),
    "ray": (0, 185, 215),
}
"""RGB colour of every element; the grid renderer's plus the heading line, obstacles and lidar rays."""

_ORDER = tuple(COLORS)
_INDEX = {name: index for index, name in enumerate(_ORDER)}
_PALETTE = np.array([COLORS[name] for name in _ORDER], dtype=np.uint8)

ITEM_HALF_WIDTH = 0.25
"""Metres: half the side of the item square on the floor."""
PAYLOAD_FRACTION = 0.35
"""Half the side of the carried item square, as a fraction of the robot's radius."""
NOSE_FRACTION = 0.45
"""The heading line runs from this fraction of the robot's radius to its rim (the centre stays robot-coloured)."""
HEADING_HALF_WIDTH_PX = 1.0
RAY_HALF_WIDTH_PX = 0.6
"""Half-widths in pixels, so lines stay one or two pixels wide at every cell size. Not 0.5 for the rays: a
robot on a cell centre (a pixel corner at an even cell size) sends its axis rays between two pixel rows."""


def check_render_cell_size(cell_size: int) -> int:
    """The grid renderer's check (an integer), with this renderer's larger minimum."""
    cell_size = check_cell_size(cell_size)
    if cell_size < MIN_CELL_SIZE:
        raise ValueError(f"cell_size must be at least {MIN_CELL_SIZE} pixels for the continuous warehouse, "
                         f"got {cell_size}")
    return cell_size


def frame_shape(params: ContinuousParams, cell_size: int = DEFAULT_CELL_SIZE) -> tuple[int, int, int]:
    """``(H * cell_size, W * cell_size, 3)`` for a map ``H`` rows high and ``W`` columns wide."""
    cell_size = check_render_cell_size(cell_size)
    height, width = params.shelves.shape[-2:]
    return int(height) * cell_size, int(width) * cell_size, 3


def to_pixel(point, cell_size: int = DEFAULT_CELL_SIZE) -> tuple[int, int]:
    """Pixel ``(row, col)`` holding the point ``(x, y)`` in metres."""
    x, y = (float(v) for v in np.asarray(point))
    return int(np.floor(y * cell_size)), int(np.floor(x * cell_size))


def lidar_from_obs(obs: jax.Array, params: ContinuousParams, num_rays: int) -> jax.Array:
    """The lidar distances in metres ``(..., L)`` an observation holds (what the robot saw, noise included).

    ``num_rays`` is the environment's ``L`` (``env.num_rays``): the rays follow the contract's 11 values;
    the learners' options come after them in this order: ``observe_target``'s 5 values, ``observe_obstacles``'
    ``L + 2`` (``L + 3`` with the safety stop), ``observe_route``'s 3.
    """
    return obs[..., OBS_SCALARS:OBS_SCALARS + num_rays] * params.lidar_range


def render_frame(state: ContinuousState, params: ContinuousParams, lidar: jax.Array | None = None,
                 cell_size: int = DEFAULT_CELL_SIZE) -> jax.Array:
    """An RGB picture of one state, ``uint8 (H * cell_size, W * cell_size, 3)``.

    ``lidar``: ray distances in metres ``(L,)`` (e.g. :func:`lidar_from_obs`), drawn from the robot's centre
    at ``theta + 2 pi k / L`` up to ``min(distance, lidar_range)``; None draws no rays. Jit with
    ``cell_size`` static; ``jax.vmap(render_frame, in_axes=(0, None, 0, None))`` draws a batch of states.
    """
    cell_size = check_render_cell_size(cell_size)
    height, width = params.shelves.shape
    rows_px, cols_px = height * cell_size, width * cell_size
    x = jnp.asarray((np.arange(cols_px, dtype=np.float32) + 0.5) / cell_size)[None, :]
    y = jnp.asarray((np.arange(rows_px, dtype=np.float32) + 0.5) / cell_size)[:, None]
    pixel = 1.0 / cell_size  # metres per pixel

    def paint(index, mask, colour):
        return jnp.where(mask, colour, index)

    def disc(centre, radius):
        return (x - centre[0]) ** 2 + (y - centre[1]) ** 2 <= radius * radius

    def square(centre, half):
        return jnp.maximum(jnp.abs(x - centre[0]), jnp.abs(y - centre[1])) <= half

    # Floor, grid lines on each cell's top and left edge and round the border, shelves over both.
    shelves = jnp.repeat(jnp.repeat(params.shelves, cell_size, axis=0), cell_size, axis=1)
    line_r = (np.arange(rows_px) % cell_size == 0) | (np.arange(rows_px) == rows_px - 1)
    line_c = (np.arange(cols_px) % cell_size == 0) | (np.arange(cols_px) == cols_px - 1)
    index = jnp.where(jnp.asarray(line_r[:, None] | line_c[None, :]), _INDEX["grid"], _INDEX["floor"])
    index = paint(index, shelves, _INDEX["shelf"])
    index = paint(index, disc(params.goal, params.reach_radius), _INDEX["goal"])
    index = paint(index, square(state.item, ITEM_HALF_WIDTH) & ~state.carrying, _INDEX["item"])

    dx, dy = x - state.pos[0], y - state.pos[1]
    if lidar is not None:
        # Each pixel belongs to the ray nearest in angle; it is on it within ``RAY_HALF_WIDTH_PX`` of the segment.
        num_rays = lidar.shape[-1]
        ranges = jnp.minimum(lidar, params.lidar_range)
        turn = jnp.mod(jnp.arctan2(dy, dx) - state.theta, TWO_PI)
        k = jnp.round(turn * (num_rays / TWO_PI)).astype(jnp.int32) % num_rays
        angle = state.theta + (TWO_PI * k.astype(jnp.float32)) / np.float32(num_rays)
        along = dx * jnp.cos(angle) + dy * jnp.sin(angle)
        across = jnp.abs(dx * jnp.sin(angle) - dy * jnp.cos(angle))
        ray = (along >= 0) & (along <= ranges[k]) & (across <= RAY_HALF_WIDTH_PX * pixel)
        index = paint(index, ray, _INDEX["ray"])

    if state.obstacle_pos.shape[0]:
        ox, oy = state.obstacle_pos[:, 0, None, None], state.obstacle_pos[:, 1, None, None]
        gaps = (x[None] - ox) ** 2 + (y[None] - oy) ** 2
        index = paint(index, jnp.any(gaps <= params.obstacle_radius ** 2, axis=0), _INDEX["obstacle"])

    radius = params.robot_radius
    body = jnp.where(state.carrying, _INDEX["robot_carrying"], _INDEX["robot"])
    index = paint(index, dx * dx + dy * dy <= radius * radius, body)
    index = paint(index, square(state.pos, PAYLOAD_FRACTION * radius) & state.carrying, _INDEX["item"])
    cos, sin = jnp.cos(state.theta), jnp.sin(state.theta)
    along, across = dx * cos + dy * sin, jnp.abs(dx * sin - dy * cos)
    nose = (along >= NOSE_FRACTION * radius) & (along <= radius) & (across <= HEADING_HALF_WIDTH_PX * pixel)
    index = paint(index, nose, _INDEX["heading"])

    # The timer bar: ceil(time * width / max_steps) pixels (integers, exact), as in the grid renderer.
    max_steps = params.max_steps
    filled = (jnp.minimum(state.time, max_steps) * cols_px + max_steps - 1) // max_steps
    bar = (jnp.arange(cols_px)[None, :] < filled) & (jnp.arange(rows_px)[:, None] < max(1, cell_size // 10))
    index = paint(index, bar, _INDEX["timer"])
    return jnp.asarray(_PALETTE)[index]


# ------------------------------------------------------------------- episodes
PolicyFn = Callable[[jax.Array, ContinuousState], jax.Array]
"""``policy_fn(obs, state) -> action`` float32 ``(2,)``: a network policy ignores ``state``."""


class ContinuousRecording(NamedTuple):
    """One recorded episode: ``frames`` ``uint8 (length + 1, H, W, 3)``, the first state to the last."""

    frames: np.ndarray
    length: int  # transitions taken
    total_return: float
    delivered: bool
    collisions: int  # shelf, wall and obstacle contacts
    item_index: int


@functools.partial(jax.jit, static_argnums=(0, 1, 2, 3, 4))
def _run_episode(env, policy_fn, num_steps: int, cell_size: int, rays: bool, params, key, item_index):
    """Scan ``num_steps`` transitions, freezing the state once the episode has ended; render every state."""
    reset_key, step_key = jax.random.split(key)
    draws = env.reset_draws(reset_key, params)
    draws = draws.replace(item_index=jnp.where(item_index >= 0, item_index, draws.item_index))
    obs, state = env.reset_with(draws, params)

    def step(carry, _):
        obs, state, done = carry
        action = policy_fn(obs, state)
        next_obs, next_state, reward, terminated, truncated, info = env.transition(
            jax.random.fold_in(step_key, state.time), state, action, params)
        live = ~done
        next_obs, next_state = jax.tree.map(lambda old, new: jnp.where(done, old, new), (obs, state),
                                            (next_obs, next_state))
        out = (next_obs, next_state, reward * live, info["collision"] & live, terminated & live)
        return (next_obs, next_state, done | terminated | truncated), out

    _, (all_obs, states, rewards, collisions, delivered) = jax.lax.scan(
        step, (obs, state, jnp.bool_(False)), None, length=num_steps)
    first_then = lambda first, rest: jnp.concatenate([first[None], rest])  # noqa: E731
    states = jax.tree.map(first_then, state, states)
    lidar = lidar_from_obs(first_then(obs, all_obs), params, env.num_rays) if rays else None
    frames = jax.vmap(render_frame, in_axes=(0, None, 0 if rays else None, None))(states, params, lidar, cell_size)
    # States stop advancing after the end, so the last state's clock is the length.
    return frames, states.time[-1], rewards.sum(), delivered.any(), collisions.sum(), draws.item_index


def record_episode(env, params: ContinuousParams, policy_fn: PolicyFn, key: jax.Array,
                   item_index: int | None = None, max_steps: int | None = None, *,
                   cell_size: int = DEFAULT_CELL_SIZE, rays: bool = True) -> ContinuousRecording:
    """Run one episode in a jitted ``lax.scan`` and render every state it visits with one vmapped call.

    Args:
        env, params: a :class:`~wrl_jax.envs.continuous.env.ContinuousWarehouse` and its params.
        policy_fn: ``policy_fn(obs, state) -> action``, traced inside the scan (static: reuse one
            function object to reuse the compiled episode).
        key: the episode's randomness (reset draws, obstacles, noise).
        item_index: the episode's item; None draws it from ``key``.
        max_steps: record at most this many transitions (default and ceiling: ``params.max_steps``).
        cell_size: pixels per metre; rays: draw the lidar each observation read.

    Returns:
        A :class:`ContinuousRecording`; no frames after the episode ended (delivered or truncated).
    """
    cell_size = check_render_cell_size(cell_size)
    num_items, limit = int(params.num_items), int(params.max_steps)
    if item_index is not None:
        if isinstance(item_index, bool) or not isinstance(item_index, (int, np.integer)):
            raise ValueError(f"item_index must be an integer, got {item_index!r}")
        if not 0 <= item_index < num_items:
            raise ValueError(f"item_index {item_index} is out of range: the layout has {num_items} items")
    if max_steps is not None and (isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer))
                                  or max_steps < 1):
        raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")
    num_steps = limit if max_steps is None else min(int(max_steps), limit)
    forced = jnp.int32(-1 if item_index is None else item_index)
    frames, length, total, delivered, collisions, drawn = _run_episode(
        env, policy_fn, num_steps, cell_size, bool(rays), params, key, forced)
    length = int(length)
    return ContinuousRecording(frames=np.asarray(frames[: length + 1]), length=length, total_return=float(total),
                               delivered=bool(delivered), collisions=int(collisions), item_index=int(drawn))
