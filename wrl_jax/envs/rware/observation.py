"""rware's FLATTENED observation (its default): ``8 + (2r+1)^2 (7 + M)`` float32 values per agent.

Layout (NOTES.md section 5): own ``x, y`` (raw, or divided by ``W-1`` and ``H-1`` with
``normalised_coordinates``), carrying, heading one-hot ``[up, down, left, right]``, own cell is
highway; then the ``(2r+1)^2`` cells around the agent, row-major in the absolute frame, each
``has_agent``, that agent's heading one-hot, its message (``M`` values), ``has_shelf``,
``shelf_requested``. A cell with no agent, or off the map, shows heading "up" (rware writes
``[1, 0, 0, 0]`` there) and a zero message. Built from the post-step state and queue.

rware's other observation types (DICT, IMAGE, IMAGE_DICT) are not implemented.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.rware.dynamics import grids, requested_mask
from wrl_jax.envs.rware.types import RwareParams, RwareState

SELF_SIZE = 8
"""Values about the agent itself, before the sensor cells."""


def cell_size(msg_bits: int) -> int:
    """Values per sensor cell: has_agent, heading (4), message, has_shelf, shelf_requested."""
    return 7 + msg_bits


def observation_size(sensor_range: int, msg_bits: int) -> int:
    """``8 + (2r+1)^2 (7 + M)``: 71 at rware's defaults."""
    return SELF_SIZE + (2 * sensor_range + 1) ** 2 * cell_size(msg_bits)


def cell_features(state: RwareState, params: RwareParams, sensor_range: int, layers=None) -> jax.Array:
    """``(H + 2r, W + 2r, 7 + M)`` float32: every cell's sensor values, the map padded by ``r`` empty cells.

    ``layers``: the state's :func:`~wrl_jax.envs.rware.dynamics.grids`, if already computed.
    """
    agent_ids, shelf_ids = grids(state, params) if layers is None else layers
    agent_ids, shelf_ids = jnp.pad(agent_ids, sensor_range), jnp.pad(shelf_ids, sensor_range)
    has_agent = agent_ids > 0
    index = jnp.maximum(agent_ids - 1, 0)
    heading = jnp.where(has_agent, state.agent_dir[index], 0)
    message = jnp.where(has_agent[..., None], state.message[index], 0.0)
    has_shelf = shelf_ids > 0
    requested = has_shelf & requested_mask(state.queue, state.shelf_x.shape[0])[jnp.maximum(shelf_ids - 1, 0)]
    return jnp.concatenate([
        has_agent[..., None].astype(jnp.float32),
        jax.nn.one_hot(heading, 4, dtype=jnp.float32),
        message.astype(jnp.float32),
        has_shelf[..., None].astype(jnp.float32),
        requested[..., None].astype(jnp.float32),
    ], axis=-1)


def rware_observation(state: RwareState, params: RwareParams, sensor_range: int,
                      normalised_coordinates: bool = False, layers=None) -> jax.Array:
    """``(N, observation_size)`` float32, each agent's FLATTENED observation (``layers``: see :func:`cell_features`)."""
    height, width = params.grid_size
    features = cell_features(state, params, sensor_range, layers)
    side = 2 * sensor_range + 1

    def window(x, y):  # padded coordinates: the window's corner is the agent's own cell
        return jax.lax.dynamic_slice(features, (y, x, 0), (side, side, features.shape[-1])).reshape(-1)

    sensors = jax.vmap(window)(state.agent_x, state.agent_y)
    x = state.agent_x.astype(jnp.float32)
    y = state.agent_y.astype(jnp.float32)
    if normalised_coordinates:  # rware divides in float64, then stores float32: a table of exactly those values
        x = jnp.asarray((np.arange(width) / (width - 1)).astype(np.float32))[state.agent_x]
        y = jnp.asarray((np.arange(height) / (height - 1)).astype(np.float32))[state.agent_y]
    own = jnp.stack([x, y, (state.carrying >= 0).astype(jnp.float32)], axis=1)
    heading = jax.nn.one_hot(state.agent_dir, 4, dtype=jnp.float32)
    highway = params.highway[state.agent_y, state.agent_x].astype(jnp.float32)[:, None]
    return jnp.concatenate([own, heading, highway, sensors], axis=1)
