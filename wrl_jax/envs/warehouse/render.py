"""Pictures of the warehouse: RGB frames, ASCII maps, recorded episodes and GIFs.

:func:`render_frame` is written in ``jax.numpy`` with the cell size static, so
it can be ``jit``-ed and ``vmap``-ped over every state of a rollout at once:
a whole episode is rendered by one compiled call, not a Python loop over steps.
Every drawing decision is a lookup into one small palette, so the pixels of a
frame are exactly predictable and the tests check them by colour.

What a frame shows (colours in :data:`COLORS`):

- floor: light grey cells separated by thin grid lines;
- shelves: dark brown filled cells;
- goal: a green filled cell;
- the item (before pickup): an orange square inside its cell;
- the robot: a blue disc; while carrying, the disc turns purple and holds the
  orange item square at its centre, so the carrying stage is visible;
- time: a thin bar along the top edge grows with ``state.time / max_steps``,
  so a step that bumped a shelf or a wall (the robot stays put) still changes
  the frame, as long as the frame is at least ``max_steps`` pixels wide
  (``N * cell_size >= max_steps``: true for both registered layouts at the
  default cell size).
"""

from __future__ import annotations

import functools
import os
import tempfile
from collections.abc import Callable, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.warehouse.env import draw_item
from wrl_jax.envs.warehouse.layout import ITEM_MARKERS
from wrl_jax.envs.warehouse.types import EnvParams, EnvState

DEFAULT_CELL_SIZE = 32
"""Pixels per grid cell side of :func:`render_frame` unless told otherwise."""

MIN_CELL_SIZE = 4
"""Below this the shapes inside a cell cannot be told apart."""

COLORS: dict[str, tuple[int, int, int]] = {
    "floor": (236, 236, 236),
    "grid": (190, 190, 190),
    "shelf": (110, 74, 40),
    "goal": (46, 170, 80),
    "item": (245, 140, 30),
    "robot": (30, 90, 210),
    "robot_carrying": (150, 40, 170),
    "timer": (90, 90, 90),
}
"""RGB colour of every element of a frame; all distinct."""

_PALETTE_ORDER = ("floor", "grid", "shelf", "goal", "item", "robot", "robot_carrying", "timer")
_INDEX = {name: index for index, name in enumerate(_PALETTE_ORDER)}
_PALETTE = np.array([COLORS[name] for name in _PALETTE_ORDER], dtype=np.uint8)

# Shape sizes as fractions of the cell side: the robot disc's radius and the
# half-widths of the item square on the floor and of the carried item inside the robot.
ROBOT_RADIUS = 0.38
ITEM_HALF_WIDTH = 0.26
PAYLOAD_HALF_WIDTH = 0.16


class _CellMasks(NamedTuple):
    robot: np.ndarray  # (c, c) bool: the robot disc
    item: np.ndarray  # (c, c) bool: the item square on the floor
    payload: np.ndarray  # (c, c) bool: the carried item inside the robot


@functools.lru_cache(maxsize=None)
def _cell_masks(cell_size: int) -> _CellMasks:
    """Pixel masks of the shapes drawn inside one cell (NumPy, computed once per size)."""
    centre = (cell_size - 1) / 2.0
    offsets = np.arange(cell_size) - centre
    dy, dx = np.meshgrid(offsets, offsets, indexing="ij")
    radius = ROBOT_RADIUS * cell_size
    robot = dy**2 + dx**2 <= radius**2
    item = np.maximum(np.abs(dy), np.abs(dx)) <= ITEM_HALF_WIDTH * cell_size
    payload = np.maximum(np.abs(dy), np.abs(dx)) <= PAYLOAD_HALF_WIDTH * cell_size
    return _CellMasks(robot=robot, item=item, payload=payload)


def check_cell_size(cell_size: int) -> int:
    if isinstance(cell_size, bool) or not isinstance(cell_size, (int, np.integer)):
        raise ValueError(f"cell_size must be an integer number of pixels, got {cell_size!r}")
    if cell_size < MIN_CELL_SIZE:
        raise ValueError(f"cell_size must be at least {MIN_CELL_SIZE} pixels, got {cell_size}")
    return int(cell_size)


def frame_shape(grid_size: int, cell_size: int = DEFAULT_CELL_SIZE) -> tuple[int, int, int]:
    """Shape ``(H, W, 3)`` of a frame of an ``N x N`` grid: ``H = W = N * cell_size``."""
    side = int(grid_size) * check_cell_size(cell_size)
    return side, side, 3


def cell_center(cell: Sequence[int], cell_size: int = DEFAULT_CELL_SIZE) -> tuple[int, int]:
    """Pixel ``(y, x)`` at the centre of grid cell ``(row, col)`` in a frame."""
    return int(cell[0]) * cell_size + cell_size // 2, int(cell[1]) * cell_size + cell_size // 2


def render_frame(state: EnvState, params: EnvParams, cell_size: int = DEFAULT_CELL_SIZE) -> jax.Array:
    """An RGB picture of one state, ``uint8 (N * cell_size, N * cell_size, 3)``.

    Pure ``jax.numpy``: jit it with ``cell_size`` static, and ``vmap`` it over
    a batch of states (``jax.vmap(render_frame, in_axes=(0, None))``) to draw a
    whole rollout in one call. Any grid size works; the cell size must be at
    least :data:`MIN_CELL_SIZE` pixels.
    """
    cell_size = check_cell_size(cell_size)
    size = params.shelves.shape[-1]
    side = size * cell_size
    masks = _cell_masks(cell_size)

    rows = jnp.arange(size)[:, None]
    cols = jnp.arange(size)[None, :]

    def at(cell: jax.Array) -> jax.Array:
        return (rows == cell[0]) & (cols == cell[1])

    # Per cell, (N, N): what fills it and which shapes sit in it.
    base = jnp.where(params.shelves, _INDEX["shelf"], jnp.where(at(params.goal), _INDEX["goal"], _INDEX["floor"]))
    item_cell = at(state.item_pos) & ~state.carrying
    robot_cell = at(state.pos)
    robot_colour = jnp.where(state.carrying, _INDEX["robot_carrying"], _INDEX["robot"])

    # Per pixel, viewed as (N, c, N, c): a cell's flag broadcast against the in-cell masks.
    def spread(per_cell: jax.Array) -> jax.Array:
        return per_cell[:, None, :, None]

    def inside(mask: np.ndarray) -> jax.Array:
        return jnp.asarray(mask)[None, :, None, :]

    index = jnp.broadcast_to(spread(base), (size, cell_size, size, cell_size))
    index = jnp.where(spread(item_cell) & inside(masks.item), _INDEX["item"], index)
    index = jnp.where(spread(robot_cell) & inside(masks.robot), robot_colour, index)
    index = jnp.where(spread(robot_cell & state.carrying) & inside(masks.payload), _INDEX["item"], index)
    index = index.reshape(side, side)

    # Grid lines at every cell's top/left edge and round the outer border.
    pixel = np.arange(side)
    line_1d = (pixel % cell_size == 0) | (pixel == side - 1)
    grid_line = line_1d[:, None] | line_1d[None, :]
    index = jnp.where(jnp.asarray(grid_line), _INDEX["grid"], index)

    # The timer bar along the top edge, ceil(time * side / max_steps) pixels long
    # (integer arithmetic, so exact): one pixel or more as soon as time > 0, and
    # one pixel or more per step wherever side >= max_steps.
    bar_height = max(1, cell_size // 10)
    max_steps = params.max_steps
    filled = (jnp.minimum(state.time, max_steps) * side + max_steps - 1) // max_steps
    timer = (jnp.arange(side)[None, :] < filled) & (jnp.arange(side)[:, None] < bar_height)
    index = jnp.where(timer, _INDEX["timer"], index)

    return jnp.asarray(_PALETTE)[index]


def render_ascii(state: EnvState, params: EnvParams) -> str:
    """A terminal picture of one state (one environment, not a batch).

    Legend: ``.`` floor, ``#`` shelf, ``G`` goal, the item's marker (its index
    in the layout's item list: ``0-9a-zA-Z``) before pickup, ``R`` the robot,
    ``C`` the robot carrying the item. A header line gives the step count.
    """
    shelves = np.asarray(params.shelves)
    if shelves.ndim != 2:
        raise ValueError(f"render_ascii draws one environment; got params with shelves of shape {shelves.shape}")
    pos = np.asarray(state.pos)
    if pos.shape != (2,):
        raise ValueError(f"render_ascii draws one environment; got a state with pos of shape {pos.shape}")
    goal, item_pos = np.asarray(params.goal), np.asarray(state.item_pos)
    carrying, item_index = bool(state.carrying), int(state.item_index)
    time, max_steps = int(state.time), int(params.max_steps)

    grid = np.where(shelves, "#", ".").astype(object)
    grid[goal[0], goal[1]] = "G"
    if not carrying:
        grid[item_pos[0], item_pos[1]] = ITEM_MARKERS[item_index]
    grid[pos[0], pos[1]] = "C" if carrying else "R"
    stage = "carrying the item" if carrying else f"fetching item {item_index}"
    header = f"step {time}/{max_steps}, {stage}"
    return "\n".join([header] + [" ".join(row) for row in grid])


# ------------------------------------------------------------------- episodes
PolicyFn = Callable[[jax.Array, EnvState], jax.Array]
"""``policy_fn(obs, state) -> action``: a network policy ignores ``state``."""


class EpisodeRecording(NamedTuple):
    """One recorded episode.

    Attributes:
        frames: ``uint8 (L + 1, H, W, 3)``, the initial state then one frame per
            transition, ending with the episode's final state.
        length: ``L``, transitions taken (at most ``max_steps``).
        total_return: undiscounted sum of the ``L`` rewards.
        delivered: the episode ended by delivering the item (terminated).
        collisions: shelf collisions in the episode.
        item_index: the item of the episode.
    """

    frames: np.ndarray
    length: int
    total_return: float
    delivered: bool
    collisions: int
    item_index: int


def oracle_policy(params: EnvParams) -> PolicyFn:
    """The BFS oracle (:func:`wrl_jax.envs.warehouse.routes.oracle_action`) as a ``policy_fn`` for :func:`record_episode`."""
    from wrl_jax.envs.warehouse.routes import oracle_action, route_tables

    tables = route_tables(params)

    def policy(obs: jax.Array, state: EnvState) -> jax.Array:
        del obs
        return oracle_action(state, params, tables)

    return policy


@functools.partial(jax.jit, static_argnums=(0, 1, 2, 3))
def _run_episode(env, policy_fn, num_steps: int, cell_size: int, item_index, params):
    """Scan one episode of ``num_steps`` transitions; freeze the state once it has ended."""
    obs, state = env.reset_to_item(item_index, params)

    def step(carry, _):
        obs, state, done = carry
        action = policy_fn(obs, state)
        next_obs, next_state, reward, terminated, truncated, info = env.transition(None, state, action, params)
        keep = lambda old, new: jnp.where(done, old, new)  # noqa: E731
        next_state = jax.tree.map(keep, state, next_state)
        next_obs = keep(obs, next_obs)
        live = ~done
        out = (next_state, reward * live, info["collision"] & live, terminated & live)
        return (next_obs, next_state, done | terminated | truncated), out

    (_, _, _), (states, rewards, collisions, delivered) = jax.lax.scan(
        step, (obs, state, jnp.zeros((), dtype=bool)), None, length=num_steps
    )
    all_states = jax.tree.map(lambda first, rest: jnp.concatenate([first[None], rest]), state, states)
    frames = jax.vmap(render_frame, in_axes=(0, None, None))(all_states, params, cell_size)
    # States stop advancing after the end, so the time counter of the last state is the length.
    length = all_states.time[-1]
    return frames, length, rewards.sum(), delivered.any(), collisions.sum()


def record_episode(
    env,
    params: EnvParams,
    policy_fn: PolicyFn,
    item_index: int | None = None,
    *,
    key: jax.Array | None = None,
    cell_size: int = DEFAULT_CELL_SIZE,
) -> EpisodeRecording:
    """Run one episode in a jitted ``lax.scan`` and render every state it visits.

    Args:
        env: a :class:`wrl_jax.Warehouse`.
        params: its params (one environment, not a batch).
        policy_fn: ``policy_fn(obs, state) -> action`` (int32 scalar), traced
            inside the scan; e.g. ``lambda obs, _: jnp.argmax(q(obs))`` for a
            greedy network, or :func:`oracle_policy`. A deterministic policy
            gives a deterministic episode.
        item_index: the episode's item; if None it is drawn from ``key``.
        key: PRNG key for the item draw when ``item_index`` is None.
        cell_size: pixels per cell side (static).

    Returns:
        An :class:`EpisodeRecording` whose frames run from the initial state to
        the final state of the episode (no frames after it ended).
    """
    cell_size = check_cell_size(cell_size)
    num_items = int(params.num_items)
    if item_index is None:
        if key is None:
            raise ValueError("record_episode needs an item_index or a PRNG key to draw one")
        item_index = int(draw_item(key, params))
    if isinstance(item_index, bool) or not isinstance(item_index, (int, np.integer)):
        raise ValueError(f"item_index must be an integer, got {item_index!r}")
    if not 0 <= item_index < num_items:
        raise ValueError(f"item_index {item_index} is out of range: the layout has {num_items} items")
    num_steps = int(params.max_steps)
    frames, length, total, delivered, collisions = _run_episode(
        env, policy_fn, num_steps, cell_size, jnp.int32(item_index), params
    )
    length = int(length)
    return EpisodeRecording(
        frames=np.asarray(frames[: length + 1]),
        length=length,
        total_return=float(total),
        delivered=bool(delivered),
        collisions=int(collisions),
        item_index=int(item_index),
    )


def save_gif(frames: np.ndarray | Sequence[np.ndarray], path: str | os.PathLike, fps: float = 6.0,
             end_pause: float = 1.0) -> str:
    """Write frames as a looping animated GIF, atomically (temp file, then ``os.replace``).

    Args:
        frames: ``uint8 (T, H, W, 3)`` (or a sequence of ``(H, W, 3)`` frames).
        path: where to write; its folder must exist.
        fps: frames per second.
        end_pause: extra seconds the last frame stays up before the loop restarts.

    Returns:
        The path written, as a string.

    Note:
        The GIF writer merges identical consecutive frames (adding their
        durations, so the timing stays right). Frames from :func:`render_frame`
        do not repeat within an episode when ``N * cell_size >= max_steps``
        (the timer bar), so the GIF then keeps one image per state.
    """
    from PIL import Image

    array = np.asarray(frames)
    if array.ndim != 4 or array.shape[-1] != 3 or array.shape[0] == 0:
        raise ValueError(f"frames must be a non-empty (T, H, W, 3) array, got shape {array.shape}")
    if array.dtype != np.uint8:
        raise ValueError(f"frames must be uint8 RGB, got dtype {array.dtype}")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if end_pause < 0:
        raise ValueError(f"end_pause must be non-negative, got {end_pause}")
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise ValueError(f"cannot write {path!r}: folder {folder!r} does not exist")

    frame_ms = max(20, int(round(1000.0 / fps)))  # GIF delays are in 10 ms units; browsers clamp below 20 ms.
    durations = [frame_ms] * len(array)
    durations[-1] += int(round(1000.0 * end_pause))
    images = [Image.fromarray(frame) for frame in array]

    handle, temp_path = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=".gif")
    os.close(handle)
    try:
        images[0].save(
            temp_path, format="GIF", save_all=True, append_images=images[1:], duration=durations, loop=0
        )
        os.replace(temp_path, path)
    except BaseException:
        if os.path.exists(temp_path):
            os.remove(temp_path)
        raise
    return path
