"""rware's FLATTENED observation (its default): ``8 + (2r+1)^2 (7 + M)`` float32 values per agent.

Layout (NOTES.md section 5): own ``x, y`` (raw, or divided by ``W-1`` and ``H-1`` with
``normalised_coordinates``), carrying, heading one-hot ``[up, down, left, right]``, own cell is
highway; then the ``(2r+1)^2`` cells around the agent, row-major in the absolute frame, each
``has_agent``, that agent's heading one-hot, its message (``M`` values), ``has_shelf``,
``shelf_requested``. A cell with no agent, or off the map, shows heading "up" (rware writes
``[1, 0, 0, 0]`` there) and a zero message. Built from the post-step state and queue.

Only the ``N (2r+1)^2`` cells the agents see are looked up (:func:`~wrl_jax.envs.rware.dynamics.ids_at`),
not the whole grid: building every cell's features and slicing windows was half of a step.

rware's other observation types (``observation_type``): ``"dict"`` (:func:`dict_observation`, here),
``"image"`` and ``"image_dict"`` (:mod:`wrl_jax.envs.rware.observation_image`); :func:`observe` picks
one, :func:`flat_observation` flattens any of them as ``gymnasium.spaces.flatten`` flattens rware's.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.core.environment import materialise
from wrl_jax.envs.rware.dynamics import ids_at, requested_mask
from wrl_jax.envs.rware.observation_image import (
    DEFAULT_IMAGE_LAYERS,
    FEATURES_SIZE,
    IMAGE_LAYERS,
    image_features,
    image_shape,
    rware_image,
)
from wrl_jax.envs.rware.types import RwareParams, RwareState

OBSERVATION_TYPES = ("flattened", "dict", "image", "image_dict")
"""rware's ``ObservationType`` s by name (its values: DICT 0, FLATTENED 1, IMAGE 2, IMAGE_DICT 3)."""

_OBSERVATION_VALUES = {0: "dict", 1: "flattened", 2: "image", 3: "image_dict"}

SELF_SIZE = 8
"""Values about the agent itself, before the sensor cells."""


def cell_size(msg_bits: int) -> int:
    """Values per sensor cell: has_agent, heading (4), message, has_shelf, shelf_requested."""
    return 7 + msg_bits


def observation_size(sensor_range: int, msg_bits: int) -> int:
    """``8 + (2r+1)^2 (7 + M)``: 71 at rware's defaults."""
    return SELF_SIZE + (2 * sensor_range + 1) ** 2 * cell_size(msg_bits)


def window_cells(state: RwareState, params: RwareParams, sensor_range: int) -> jax.Array:
    """``(N, (2r+1)^2)`` int32 flat cells ``y W + x`` each agent sees, row-major; -1 off the map (matches nothing)."""
    height, width = params.grid_size
    offsets = np.arange(-sensor_range, sensor_range + 1, dtype=np.int32)
    dy, dx = (a.reshape(-1) for a in np.meshgrid(offsets, offsets, indexing="ij"))
    x = state.agent_x[:, None] + dx[None, :]
    y = state.agent_y[:, None] + dy[None, :]
    inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
    return jnp.where(inside, y * width + x, -1)


def cell_keys(state: RwareState, params: RwareParams, sensor_range: int) -> tuple[jax.Array, jax.Array]:
    """``(N, (2r+1)^2)`` int32 each, per sensor cell: its agent's ``4 id + heading``, its shelf's ``2 id + requested``.

    Keys rise with the id, so the max over a cell's entities (:func:`ids_at`) is rware's grid (the highest
    id wins a cell) and carries that entity's heading or flag; 0 where the cell is empty or off the map.
    """
    width = params.grid_size[1]
    cells = window_cells(state, params, sensor_range)
    count, num_shelves = state.agent_x.shape[0], state.shelf_x.shape[0]
    agent_key = 4 * jnp.arange(1, count + 1, dtype=jnp.int32) + state.agent_dir
    shelf_key = (2 * jnp.arange(1, num_shelves + 1, dtype=jnp.int32)
                 + requested_mask(state.queue, num_shelves).astype(jnp.int32))
    cell_bound = params.grid_size[0] * width
    return (ids_at(cells, state.agent_y * width + state.agent_x, agent_key, max(cell_bound, 4 * count + 4)),
            ids_at(cells, state.shelf_y * width + state.shelf_x, shelf_key, max(cell_bound, 2 * num_shelves + 2)))


def _packed(state: RwareState, params: RwareParams, sensor_range: int, x: jax.Array, y: jax.Array) -> jax.Array:
    """The observation without messages: every 0/1 value a bit of ``ceil(D / 32)`` uint32 words per agent.

    Why: the values written out by concatenating one-hot pieces cost as much as the rest of the step
    (XLA's CPU loop for a nested concatenate works element by element); here one elementwise pass
    over the ``(N, D)`` output reads each column's bit from a word chosen by static compares.
    """
    agent, shelf = cell_keys(state, params, sensor_range)
    u = jnp.uint32
    # A cell's 7 bits: has_agent, heading one-hot (heading 0, "up", where empty), has_shelf, requested.
    code = ((agent > 0).astype(u) | (u(2) << (agent & 3).astype(u)) | ((shelf > 0).astype(u) << 5)
            | ((shelf & 1).astype(u) << 6))
    direction = state.agent_dir
    heading = jnp.where((direction >= 0) & (direction < 4), u(8) << jnp.clip(direction, 0, 3).astype(u), u(0))
    highway = params.highway[state.agent_y, state.agent_x]
    own = ((state.carrying >= 0).astype(u) << 2) | heading | (highway.astype(u) << 7)
    size = code.shape[1] * 7 + SELF_SIZE
    words = [own] + [jnp.zeros_like(own)] * ((size - 1) // 32)
    for cell in range(code.shape[1]):
        for index in range(len(words)):
            shift = SELF_SIZE + 7 * cell - 32 * index  # where the cell's bits start in this word
            if 0 <= shift < 32:
                words[index] = words[index] | (code[:, cell] << u(shift))
            elif -7 < shift < 0:
                words[index] = words[index] | (code[:, cell] >> u(-shift))
    words = list(materialise(jnp.stack(words, axis=1)).T)  # else rebuilt for each of the D columns
    column = np.arange(size)
    word = words[-1][:, None]
    for index in range(len(words) - 2, -1, -1):
        word = jnp.where(column < 32 * (index + 1), words[index][:, None], word)
    bits = ((word >> (column % 32).astype(np.uint32)) & 1).astype(jnp.float32)
    return jnp.where(column == 0, x[:, None], jnp.where(column == 1, y[:, None], bits))


def rware_observation(state: RwareState, params: RwareParams, sensor_range: int,
                      normalised_coordinates: bool = False) -> jax.Array:
    """``(N, observation_size)`` float32, each agent's FLATTENED observation."""
    height, width = params.grid_size
    x = state.agent_x.astype(jnp.float32)
    y = state.agent_y.astype(jnp.float32)
    if normalised_coordinates:  # rware divides in float64, then stores float32: a table of exactly those values
        x = jnp.asarray((np.arange(width) / (width - 1)).astype(np.float32))[state.agent_x]
        y = jnp.asarray((np.arange(height) / (height - 1)).astype(np.float32))[state.agent_y]
    if not state.message.shape[-1]:
        return _packed(state, params, sensor_range, x, y)
    agent, shelf = cell_keys(state, params, sensor_range)
    has_agent = agent > 0
    message = jnp.where(has_agent[..., None], state.message[jnp.maximum((agent >> 2) - 1, 0)], 0.0)
    sensors = jnp.concatenate([has_agent[..., None].astype(jnp.float32), jax.nn.one_hot(agent & 3, 4),
                               message.astype(jnp.float32), (shelf > 0)[..., None].astype(jnp.float32),
                               (shelf & 1)[..., None].astype(jnp.float32)], axis=-1)
    own = jnp.stack([x, y, (state.carrying >= 0).astype(jnp.float32)], axis=1)
    heading = jax.nn.one_hot(state.agent_dir, 4, dtype=jnp.float32)
    highway = params.highway[state.agent_y, state.agent_x].astype(jnp.float32)[:, None]
    return jnp.concatenate([own, heading, highway, sensors.reshape(sensors.shape[0], -1)], axis=1)


# ---------------------------------------------------------------------------------- settings, by name
def observation_type_name(value: object) -> str:
    """``"flattened"``, ``"dict"``, ``"image"`` or ``"image_dict"`` from a name (any case, ``-`` or ``_``,
    ``"imagedict"``), rware's ``ObservationType`` member or its value; ``ValueError`` naming the setting otherwise.

    (rware itself compares with its enum: a string there silently gives DICT.)
    """
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool) and int(value) in _OBSERVATION_VALUES:
        return _OBSERVATION_VALUES[int(value)]
    name = getattr(value, "name", value)
    key = name.lower().replace("-", "_") if isinstance(name, str) else None
    key = "image_dict" if key == "imagedict" else key
    if key not in OBSERVATION_TYPES:
        raise ValueError(f"observation_type={value!r} is not one of rware's observation types: 'flattened' "
                         f"(the default), 'dict', 'image', 'image_dict' (or rware's ObservationType members)")
    return key


def image_layer_names(layers: object, *, needed: bool = True) -> tuple[str, ...]:
    """rware's ``image_observation_layers`` as names (:data:`IMAGE_LAYERS`), from names (any case), rware's
    ``ImageLayer`` members or their values 0..6. ``needed`` (an image type): the list may not be empty (rware
    fails stacking no layers). ``ValueError`` naming the setting for anything else.
    """
    if isinstance(layers, (str, bytes)) or not hasattr(layers, "__iter__"):
        raise ValueError(f"image_observation_layers must be a list of rware's ImageLayer names or members "
                         f"({', '.join(IMAGE_LAYERS)}), got {layers!r}")
    names = []
    for layer in layers:
        if isinstance(layer, (int, np.integer)) and not isinstance(layer, bool) and 0 <= layer < len(IMAGE_LAYERS):
            names.append(IMAGE_LAYERS[int(layer)])
            continue
        name = getattr(layer, "name", layer)
        key = name.lower() if isinstance(name, str) else None
        if key not in IMAGE_LAYERS:
            raise ValueError(f"image_observation_layers: unknown layer {layer!r}; rware's ImageLayer has "
                             f"{', '.join(IMAGE_LAYERS)}")
        names.append(key)
    if needed and not names:
        raise ValueError("image_observation_layers must name at least one layer (rware 2.0.0 fails stacking "
                         "an empty list)")
    return tuple(names)


def directional_flag(value: object) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"image_observation_directional must be True or False, got {value!r}")
    return bool(value)


# ---------------------------------------------------------------------------------- DICT
def dict_observation(state: RwareState, params: RwareParams, sensor_range: int,
                     normalised_coordinates: bool = False) -> dict:
    """rware's DICT observation, every leaf int32 with a leading agent axis ``N`` (``K = (2r+1)^2`` sensors):

    ``{"self": {"location": (N, 2), "carrying_shelf": (N, 1), "direction": (N,), "on_highway": (N, 1)},
    "sensors": {"has_agent": (N, K, 1), "direction": (N, K), "local_message": (N, K, M), "has_shelf":
    (N, K, 1), "shelf_requested": (N, K, 1)}}``: agent ``n`` 's rware dict is ``[n]`` of every leaf, its
    sensor ``k`` (rware's tuple, row-major in the absolute frame) ``[n, k]`` of the sensor leaves.
    ``local_message`` only with messages (rware writes ``None`` there without). An empty cell shows
    direction 0. With ``normalised_coordinates`` rware casts ``x / (W-1)`` to int32: the location is
    0 or 1 (1 only on the last column or row), and so it is here.
    """
    height, width = params.grid_size
    x, y = state.agent_x, state.agent_y
    if normalised_coordinates:
        x, y = x // (width - 1), y // (height - 1)
    agent, shelf = cell_keys(state, params, sensor_range)
    has_agent = agent > 0
    i32 = jnp.int32
    own = {"location": jnp.stack([x, y], axis=1).astype(i32),
           "carrying_shelf": (state.carrying >= 0)[:, None].astype(i32),
           "direction": state.agent_dir.astype(i32),
           "on_highway": params.highway[state.agent_y, state.agent_x][:, None].astype(i32)}
    sensors = {"has_agent": has_agent[..., None].astype(i32), "direction": agent & 3}
    if state.message.shape[-1]:
        message = state.message[jnp.maximum((agent >> 2) - 1, 0)]
        sensors["local_message"] = jnp.where(has_agent[..., None], message, 0.0).astype(i32)
    sensors["has_shelf"] = (shelf > 0)[..., None].astype(i32)
    sensors["shelf_requested"] = (shelf & 1)[..., None].astype(i32)
    return {"self": own, "sensors": sensors}


# ---------------------------------------------------------------------------------- any type
def observe(state: RwareState, params: RwareParams, observation_type: str, sensor_range: int,
            normalised_coordinates: bool = False, layers: tuple[str, ...] = DEFAULT_IMAGE_LAYERS,
            directional: bool = True):
    """The observation of ``observation_type`` (a name of :data:`OBSERVATION_TYPES`), leading axis ``N``.

    ``"flattened"``: ``(N, D)`` float32 (:func:`rware_observation`); ``"dict"``: :func:`dict_observation`;
    ``"image"``: ``(N, L, 2r+1, 2r+1)`` float32; ``"image_dict"``: ``{"features": (N, 6), "image": (N, L,
    2r+1, 2r+1)}`` float32 (rware's keys; its space sorts them, features first).
    """
    if observation_type == "flattened":
        return rware_observation(state, params, sensor_range, normalised_coordinates)
    if observation_type == "dict":
        return dict_observation(state, params, sensor_range, normalised_coordinates)
    image = rware_image(state, params, sensor_range, layers, directional)
    if observation_type == "image":
        return image
    if observation_type == "image_dict":
        return {"features": image_features(state, params), "image": image}
    raise ValueError(f"unknown observation_type {observation_type!r}")


def flat_size(observation_type: str, sensor_range: int, msg_bits: int,
              layers: tuple[str, ...] = DEFAULT_IMAGE_LAYERS) -> int:
    """One agent's observation length once flattened (rware's ``gymnasium.spaces.flatdim``)."""
    if observation_type in ("flattened", "dict"):
        return observation_size(sensor_range, msg_bits)
    pixels = int(np.prod(image_shape(sensor_range, layers)))
    return pixels + (FEATURES_SIZE if observation_type == "image_dict" else 0)


def flat_observation(obs, observation_type: str) -> jax.Array:
    """``(N, D)`` float32: each agent's observation as ``gymnasium.spaces.flatten`` flattens rware's.

    DICT: the FLATTENED layout (the directions one-hot), with rware's int location; IMAGE: the pixels,
    channel by channel; IMAGE_DICT: the features, then the pixels (Gymnasium sorts the keys).
    """
    if observation_type == "flattened":
        return obs
    if observation_type == "image":
        return obs.reshape(obs.shape[0], -1)
    if observation_type == "image_dict":
        image = obs["image"]
        return jnp.concatenate([obs["features"], image.reshape(image.shape[0], -1)], axis=1)
    own, sensors = obs["self"], obs["sensors"]
    f32 = jnp.float32
    cells = [sensors["has_agent"].astype(f32), jax.nn.one_hot(sensors["direction"], 4, dtype=f32)]
    if "local_message" in sensors:
        cells.append(sensors["local_message"].astype(f32))
    cells += [sensors["has_shelf"].astype(f32), sensors["shelf_requested"].astype(f32)]
    cells = jnp.concatenate(cells, axis=-1)
    return jnp.concatenate([own["location"].astype(f32), own["carrying_shelf"].astype(f32),
                            jax.nn.one_hot(own["direction"], 4, dtype=f32), own["on_highway"].astype(f32),
                            cells.reshape(cells.shape[0], -1)], axis=1)
