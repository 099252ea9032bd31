"""Pictures of the fleet: RGB frames, ASCII maps, recorded shifts and GIFs.

:func:`render_frame` is ``jax.numpy`` with the cell size static, like the
single robot's (:mod:`wrl_jax.envs.warehouse.render`): jit it and ``vmap`` it
over a rollout's states to draw a whole shift in one call. Every pixel is a
lookup into one palette, so tests check frames by colour.

What a frame shows:

- floor: light grey cells with thin grid lines; shelves: dark brown cells;
- delivery stations ``G``: green cells; pick stations (items): pale orange cells;
- robot ``i``: a disc in its own colour (:func:`robot_colors`: hues spaced by
  the golden angle, distinct for any ``K``); while carrying, an orange square
  (the item) sits at the disc's centre;
- each robot's current target: a square outline in the robot's colour along
  the target cell's border (where several robots share a target, the highest
  index is drawn);
- time: a bar along the top edge grows with ``time / max_steps``.
"""

from __future__ import annotations

import colorsys
import functools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.fleet.dynamics import targets
from wrl_jax.envs.fleet.env import Fleet
from wrl_jax.envs.fleet.types import FleetParams, FleetState
from wrl_jax.envs.warehouse.render import check_cell_size, save_gif

DEFAULT_CELL_SIZE = 24

COLORS: dict[str, tuple[int, int, int]] = {
    "floor": (236, 236, 236),
    "grid": (190, 190, 190),
    "shelf": (110, 74, 40),
    "station": (46, 170, 80),
    "pick": (250, 214, 170),
    "item": (245, 140, 30),
    "timer": (90, 90, 90),
}
"""RGB of every non-robot element; robots take :func:`robot_colors`."""

_ORDER = tuple(COLORS)
_INDEX = {name: index for index, name in enumerate(_ORDER)}

ROBOT_RADIUS = 0.38
PAYLOAD_HALF_WIDTH = 0.16
RING_WIDTH = 0.15


def robot_colors(num_robots: int) -> np.ndarray:
    """``(K, 3)`` uint8 robot colours: saturated hues spaced by the golden angle, all distinct."""
    hues = (np.arange(num_robots) * 0.618033988749895) % 1.0
    values = np.where(np.arange(num_robots) % 2 == 0, 0.85, 0.6)  # alternate brightness: neighbours in hue differ
    rgb = [colorsys.hsv_to_rgb(h, 0.85, v) for h, v in zip(hues, values)]
    return np.round(np.array(rgb).reshape(-1, 3) * 255).astype(np.uint8)


def palette(num_robots: int) -> np.ndarray:
    """``(len(COLORS) + K, 3)`` uint8: the named colours, then robot ``i`` at ``len(COLORS) + i``."""
    return np.concatenate([np.array([COLORS[name] for name in _ORDER], np.uint8), robot_colors(num_robots)])


@functools.lru_cache(maxsize=None)
def _masks(cell_size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """In-cell pixel masks ``(c, c)``: robot disc, payload square, target outline."""
    offsets = np.arange(cell_size) - (cell_size - 1) / 2.0
    dy, dx = np.meshgrid(offsets, offsets, indexing="ij")
    chebyshev = np.maximum(np.abs(dy), np.abs(dx))
    disc = dy**2 + dx**2 <= (ROBOT_RADIUS * cell_size) ** 2
    payload = chebyshev <= PAYLOAD_HALF_WIDTH * cell_size
    ring = chebyshev >= (0.5 - RING_WIDTH) * cell_size - 0.5
    return disc, payload, ring


def render_frame(state: FleetState, params: FleetParams, cell_size: int = DEFAULT_CELL_SIZE) -> jax.Array:
    """An RGB picture of one fleet state, ``uint8 (N * cell_size, N * cell_size, 3)`` (jit with cell_size static)."""
    cell_size = check_cell_size(cell_size)
    size, num_robots = params.shelves.shape[-1], state.pos.shape[0]
    side = size * cell_size
    disc, payload, ring = _masks(cell_size)
    robot_ids = jnp.arange(num_robots, dtype=jnp.int32)

    def owner(cells: jax.Array, valid: jax.Array | None = None) -> jax.Array:
        """(N, N) int32: highest robot index whose cell is here, -1 if none."""
        values = robot_ids if valid is None else jnp.where(valid, robot_ids, -1)
        return jnp.full((size, size), -1, jnp.int32).at[cells[:, 0], cells[:, 1]].max(values)

    num_items = params.items.shape[0]
    item_valid = jnp.arange(num_items) < params.num_items
    picks = jnp.zeros((size, size), bool).at[params.items[:, 0], params.items[:, 1]].max(item_valid)
    station_valid = jnp.arange(params.stations.shape[0]) < params.num_stations
    stations = jnp.zeros((size, size), bool).at[params.stations[:, 0], params.stations[:, 1]].max(station_valid)
    base = jnp.select([params.shelves, stations, picks], [_INDEX["shelf"], _INDEX["station"], _INDEX["pick"]],
                      _INDEX["floor"])
    robot_at = owner(state.pos)
    target_of = owner(targets(state, params))
    carried = jnp.zeros((size, size), bool).at[state.pos[:, 0], state.pos[:, 1]].max(state.carrying)

    def spread(per_cell: jax.Array) -> jax.Array:
        return per_cell[:, None, :, None]

    def inside(mask: np.ndarray) -> jax.Array:
        return jnp.asarray(mask)[None, :, None, :]

    first_robot = len(_ORDER)
    index = jnp.broadcast_to(spread(base), (size, cell_size, size, cell_size))
    index = jnp.where(spread(target_of >= 0) & inside(ring), first_robot + spread(target_of), index)
    index = jnp.where(spread(robot_at >= 0) & inside(disc), first_robot + spread(robot_at), index)
    index = jnp.where(spread(carried) & inside(payload), _INDEX["item"], index)
    index = index.reshape(side, side)

    pixel = np.arange(side)
    line = (pixel % cell_size == 0) | (pixel == side - 1)
    index = jnp.where(jnp.asarray(line[:, None] | line[None, :]), _INDEX["grid"], index)
    filled = (jnp.minimum(state.time, params.max_steps) * side + params.max_steps - 1) // params.max_steps
    timer = (jnp.arange(side)[None, :] < filled) & (jnp.arange(side)[:, None] < max(1, cell_size // 10))
    index = jnp.where(timer, _INDEX["timer"], index)
    return jnp.asarray(palette(num_robots))[index]


def render_ascii(state: FleetState, params: FleetParams) -> str:
    """A terminal picture of one fleet state, then one line per robot.

    Map legend: ``.`` floor, ``#`` shelf, ``G`` delivery station, ``*`` pick
    station, robot ``i`` as the ``i``-th lowercase letter while empty and
    uppercase while carrying (``@`` past 26 robots).
    """
    shelves, pos = np.asarray(params.shelves), np.asarray(state.pos)
    if shelves.ndim != 2 or pos.ndim != 2:
        raise ValueError(f"render_ascii draws one fleet; got shelves {shelves.shape}, pos {pos.shape}")
    items = np.asarray(params.items)[: int(params.num_items)]
    stations = np.asarray(params.stations)[: int(params.num_stations)]
    grid = np.where(shelves, "#", ".").astype(object)
    grid[items[:, 0], items[:, 1]] = "*"
    grid[stations[:, 0], stations[:, 1]] = "G"
    carrying, goal = np.asarray(state.carrying), np.asarray(targets(state, params))
    lines = []
    for i, (row, col) in enumerate(pos):
        letter = chr(ord("a") + i) if i < 26 else "@"
        grid[row, col] = letter.upper() if carrying[i] else letter
        task = f"station {int(state.station[i])}" if carrying[i] else f"item {int(state.item[i])}"
        lines.append(f"{letter} robot {i} at ({row}, {col}) {'carrying' if carrying[i] else 'empty'}"
                     f" -> {task} at ({goal[i, 0]}, {goal[i, 1]})")
    header = f"step {int(state.time)}/{int(params.max_steps)}"
    return "\n".join([header] + [" ".join(row) for row in grid] + lines)


# ------------------------------------------------------------------- shifts
FleetPolicy = Callable[[jax.Array, jax.Array, FleetState], jax.Array]
"""``policy(key, obs (K, D), state) -> actions (K,)`` int32."""


class ShiftRecording(NamedTuple):
    """One recorded shift: ``frames uint8 (T + 1, H, W, 3)`` (the start, then each reached state), the
    per-robot ``deliveries (K,)`` and the summed ``total_return``."""

    frames: np.ndarray
    deliveries: np.ndarray
    total_return: float


def record_shift(env: Fleet, params: FleetParams, policy: FleetPolicy, key: jax.Array, *, num_steps: int | None = None,
                 cell_size: int = DEFAULT_CELL_SIZE) -> ShiftRecording:
    """Run one shift (``num_steps <= max_steps`` transitions, default all) in a jitted scan; draw every state.

    One shift never auto-resets, so the scan uses ``env.transition`` and the
    frames run from the first state to the last reached one.
    """
    cell_size = check_cell_size(cell_size)
    steps = int(params.max_steps) if num_steps is None else num_steps
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or not 1 <= steps <= int(params.max_steps):
        raise ValueError(f"num_steps must be an integer in 1..max_steps={int(params.max_steps)}, got {num_steps!r}")
    frames, deliveries, total = _record(env, policy, int(steps), cell_size, params, key)
    return ShiftRecording(np.asarray(frames), np.asarray(deliveries), float(total))


@functools.partial(jax.jit, static_argnums=(0, 1, 2, 3))
def _record(env: Fleet, policy: FleetPolicy, num_steps: int, cell_size: int, params: FleetParams, key: jax.Array):
    key_reset, key_run = jax.random.split(key)
    obs, state = env.reset(key_reset, params)

    def body(carry, key):
        obs, state = carry
        key_policy, key_env = jax.random.split(key)
        action = policy(key_policy, obs, state)
        obs, state, reward, _, _, info = env.transition(key_env, state, action, params)
        return (obs, state), (state, reward.sum(), info["delivered"])

    _, (reached, rewards, delivered) = jax.lax.scan(body, (obs, state), jax.random.split(key_run, num_steps))
    states = jax.tree.map(lambda first, rest: jnp.concatenate([first[None], rest]), state, reached)
    frames = jax.vmap(render_frame, in_axes=(0, None, None))(states, params, cell_size)
    return frames, delivered.sum(axis=0), rewards.sum()


__all__ = ["COLORS", "ShiftRecording", "palette", "record_shift", "render_ascii", "render_frame", "robot_colors",
           "save_gif"]
