"""rware's IMAGE observation and IMAGE_DICT's features, as rware 2.0.0 computes them (``Warehouse._make_img_obs``).

IMAGE, per agent: ``(L, 2r+1, 2r+1)`` float32, one channel per entry of ``image_observation_layers``
(rware's ``ImageLayer``; duplicates allowed), the ``(2r+1)^2`` cells around the agent (row ``dy``,
column ``dx``, ``-r..r``), cells off the map 0. With ``image_observation_directional`` (rware's
default) the crop is turned by ``np.rot90(k, axes=(1, 2))``: ``k = 2`` facing down, ``3`` left, ``1``
right, none up. Here the turn is a static table of where each output pixel looks
(:func:`image_offsets`), so nothing is rotated at run time. The layers (NOTES.md section 5):

- ``shelves``: 1 where any shelf stands, carried ones included;
- ``requests``: 1 where a requested shelf is (any of the shelves there; rware loops over the queue);
- ``agents``: 1 where an agent is;
- ``agent_direction``: heading + 1 (1 up, 2 down, 3 left, 4 right), **transposed**: rware writes
  ``layer[agent.x, agent.y]`` into its ``(H, W)`` grid, so pixel (row ``Y``, column ``X``) shows the
  agent standing at ``x = Y, y = X``. Where that index is outside ``(H, W)`` (an agent with
  ``y >= W`` or ``x >= H``: on rware's tiny map, any agent on the bottom row) rware raises
  ``IndexError``; here that agent is left out. On a square grid it never happens;
- ``agent_load``: 1 where a loaded agent is, transposed as ``agent_direction``;
- ``goals``: 1 on goal cells (not transposed: rware's loop names ``x`` and ``y`` the other way round
  twice);
- ``accessible``: 1 on cells of the map without an agent (shelves are accessible), 0 off the map.

Every channel is looked up only at the ``N (2r+1)^2`` cells the agents see
(:func:`~wrl_jax.envs.rware.dynamics.ids_at`), as the flattened observation does.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.rware.dynamics import ids_at, requested_mask
from wrl_jax.envs.rware.types import RwareParams, RwareState

IMAGE_LAYERS = ("shelves", "requests", "agents", "agent_direction", "agent_load", "goals", "accessible")
"""rware's ``ImageLayer`` names, in the order of its values 0..6."""

DEFAULT_IMAGE_LAYERS = ("shelves", "requests", "agents", "goals", "accessible")
"""rware's default ``image_observation_layers``."""

HEADING_TURNS = (0, 2, 3, 1)
"""``np.rot90``'s ``k`` by heading (up, down, left, right), as rware turns a directional image."""

FEATURES_SIZE = 6
"""IMAGE_DICT's ``features``: heading one-hot (up, down, left, right), on highway, carrying."""


def image_shape(sensor_range: int, layers: tuple[str, ...]) -> tuple[int, int, int]:
    side = 2 * sensor_range + 1
    return (len(layers), side, side)


def image_high(layers: tuple[str, ...]) -> np.ndarray:
    """``(L,)`` float32 upper bound per channel, as rware's space: 4 for ``agent_direction``, else 1."""
    return np.array([4.0 if layer == "agent_direction" else 1.0 for layer in layers], np.float32)


def image_offsets(sensor_range: int, directional: bool) -> np.ndarray:
    """``(4, 2, (2r+1)^2)`` int32: per heading, the ``(dy, dx)`` each output pixel (row-major) looks at."""
    side = 2 * sensor_range + 1
    base = np.arange(side, dtype=np.int32) - sensor_range
    dy, dx = np.meshgrid(base, base, indexing="ij")
    turns = HEADING_TURNS if directional else (0, 0, 0, 0)
    return np.stack([np.stack([np.rot90(dy, k).reshape(-1), np.rot90(dx, k).reshape(-1)]) for k in turns])


def rware_image(state: RwareState, params: RwareParams, sensor_range: int, layers: tuple[str, ...],
                directional: bool) -> jax.Array:
    """``(N, L, 2r+1, 2r+1)`` float32: each agent's IMAGE observation (the layers by name, see the module)."""
    height, width = params.grid_size
    count, num_shelves = state.agent_x.shape[0], state.shelf_x.shape[0]
    offsets = image_offsets(sensor_range, directional)
    if directional:
        turned = jnp.asarray(offsets)[jnp.clip(state.agent_dir, 0, 3)]  # (N, 2, K)
        dy, dx = turned[:, 0], turned[:, 1]
    else:
        dy, dx = jnp.asarray(offsets[0, 0])[None, :], jnp.asarray(offsets[0, 1])[None, :]
    x = state.agent_x[:, None] + dx
    y = state.agent_y[:, None] + dy
    inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
    cells = jnp.where(inside, y * width + x, -1)
    side = max(height, width)  # transposed cells: pixel (Y, X) is Y side + X; the agent at (x, y) is x side + y
    bound = max(side * side, 4 * count + 4, height * width, 2) + 1
    agent_cell = state.agent_y * width + state.agent_x
    shelf_cell = state.shelf_y * width + state.shelf_x
    ones = jnp.ones((count,), jnp.int32)
    cache: dict[str, jax.Array] = {}

    def agents():
        if "agents" not in cache:
            cache["agents"] = ids_at(cells, agent_cell, ones, bound) > 0
        return cache["agents"]

    def transposed(keys):
        return ids_at(jnp.where(inside, y * side + x, -1), state.agent_x * side + state.agent_y, keys, bound)

    def layer(name: str) -> jax.Array:
        if name == "shelves":
            return ids_at(cells, shelf_cell, jnp.ones((num_shelves,), jnp.int32), bound) > 0
        if name == "requests":
            return ids_at(cells, shelf_cell, requested_mask(state.queue, num_shelves).astype(jnp.int32), bound) > 0
        if name == "agents":
            return agents()
        if name == "agent_direction":  # the highest id wins a cell, as rware's loop overwrites in id order
            key = transposed(4 * jnp.arange(1, count + 1, dtype=jnp.int32) + jnp.clip(state.agent_dir, 0, 3))
            return jnp.where(key > 0, (key & 3) + 1, 0)
        if name == "agent_load":
            return transposed((state.carrying >= 0).astype(jnp.int32)) > 0
        if name == "goals":
            goal_cell = params.goals[:, 1] * width + params.goals[:, 0]
            return ids_at(cells, goal_cell, jnp.ones(goal_cell.shape, jnp.int32), bound) > 0
        if name == "accessible":
            return inside & ~agents()
        raise ValueError(f"unknown image layer {name!r}")

    values = {name: layer(name).astype(jnp.float32) for name in dict.fromkeys(layers)}
    side_length = 2 * sensor_range + 1
    return jnp.stack([values[name] for name in layers], axis=1).reshape(count, len(layers), side_length, side_length)


def image_features(state: RwareState, params: RwareParams) -> jax.Array:
    """``(N, 6)`` float32 IMAGE_DICT ``features``: heading one-hot, own cell is highway, carrying."""
    highway = params.highway[state.agent_y, state.agent_x].astype(jnp.float32)
    carrying = (state.carrying >= 0).astype(jnp.float32)
    return jnp.concatenate([jax.nn.one_hot(state.agent_dir, 4, dtype=jnp.float32), highway[:, None],
                            carrying[:, None]], axis=1)
