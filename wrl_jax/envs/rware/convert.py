"""From a live rware 2.0.0 ``Warehouse`` to this family's state and params (and back to plain arrays).

:func:`from_rware` reads a warehouse (the unwrapped env, after ``reset``; any wrapper is
unwrapped) into :class:`RwareState` and :class:`RwareParams`, so a rware env set up by hand,
as rware's own tests do, can be stepped here. :func:`env_from_rware` builds the matching
environment, with the warehouse's observation type (:func:`observation_settings`: FLATTENED,
DICT, IMAGE or IMAGE_DICT, its image layers and direction flag); :func:`rware_arrays` and
:func:`state_arrays` give both sides as the same plain NumPy dict, the form the parity tests
compare. Nothing here imports rware: the warehouse is read through its attributes.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.rware.env import Rware
from wrl_jax.envs.rware.layout import RwareLayout
from wrl_jax.envs.rware.registration import make_params
from wrl_jax.envs.rware.types import NO_SHELF, RwareParams, RwareState


def _warehouse(warehouse: Any) -> Any:
    inner = getattr(warehouse, "unwrapped", warehouse)
    if not hasattr(inner, "shelfs") or not hasattr(inner, "agents") or not inner.agents:
        raise ValueError("from_rware needs a rware Warehouse that has been reset (it has no agents or shelves yet)")
    return inner


def observation_settings(warehouse: Any) -> dict[str, Any]:
    """The warehouse's ``observation_type`` (by name), ``image_observation_layers`` (names) and
    ``image_observation_directional``, read from the flags rware's constructor sets: ``fast_obs``
    (FLATTENED), ``image_obs`` (IMAGE), ``image_dict_obs`` alone (IMAGE_DICT), none of them (DICT).
    """
    inner = getattr(warehouse, "unwrapped", warehouse)
    if getattr(inner, "fast_obs", None):
        kind = "flattened"
    elif getattr(inner, "image_obs", None):
        kind = "image"
    elif getattr(inner, "image_dict_obs", None):
        kind = "image_dict"
    else:
        kind = "dict"
    settings: dict[str, Any] = {"observation_type": kind}
    if kind in ("image", "image_dict"):
        settings["image_observation_layers"] = tuple(getattr(layer, "name", layer)
                                                     for layer in inner.image_observation_layers)
        settings["image_observation_directional"] = bool(inner.image_observation_directional)
    return settings


def _layout(inner: Any) -> RwareLayout:
    return RwareLayout(highway=np.asarray(inner.highways, dtype=bool), goals=np.asarray(inner.goals, dtype=np.int32))


def rware_arrays(warehouse: Any) -> dict[str, np.ndarray]:
    """A warehouse's state as NumPy arrays named like :class:`RwareState`'s fields (0-based indices)."""
    inner = _warehouse(warehouse)
    shelves = list(inner.shelfs)
    index = {id(shelf): i for i, shelf in enumerate(shelves)}

    def shelf_index(shelf):
        if shelf is None:
            return NO_SHELF
        if id(shelf) not in index:
            raise ValueError("an agent carries a shelf that is not in the warehouse's shelf list")
        return index[id(shelf)]

    agents = inner.agents
    msg_bits = int(inner.msg_bits)
    return {
        "agent_x": np.array([a.x for a in agents], np.int32),
        "agent_y": np.array([a.y for a in agents], np.int32),
        "agent_dir": np.array([a.dir.value for a in agents], np.int32),
        "carrying": np.array([shelf_index(a.carrying_shelf) for a in agents], np.int32),
        "has_delivered": np.array([bool(a.has_delivered) for a in agents], bool),
        "message": np.array([np.asarray(a.message, np.float32) for a in agents], np.float32).reshape(
            len(agents), msg_bits),
        "shelf_x": np.array([s.x for s in shelves], np.int32),
        "shelf_y": np.array([s.y for s in shelves], np.int32),
        "queue": np.array([shelf_index(s) for s in inner.request_queue], np.int32),
        "time": np.asarray(inner._cur_steps, np.int32),
        "inactive": np.asarray(inner._cur_inactive_steps or 0, np.int32),
    }


def state_arrays(state: RwareState) -> dict[str, np.ndarray]:
    """:class:`RwareState` as the NumPy dict of :func:`rware_arrays`."""
    return {name: np.asarray(getattr(state, name)) for name in RwareState.__dataclass_fields__}


def from_rware(warehouse: Any) -> tuple[RwareState, RwareParams]:
    """``(state, params)`` of a reset rware ``Warehouse``: every agent, shelf, the queue and both counters.

    Shelves keep their current cells (a test may have moved them); their reset cells in
    ``params.shelf_home`` are the layout's shelf cells, where rware's ``reset`` puts them.
    """
    inner = _warehouse(warehouse)
    arrays = rware_arrays(inner)
    layout = _layout(inner)
    if len(inner.shelfs) != layout.num_shelves:
        raise ValueError(f"the warehouse has {len(inner.shelfs)} shelves but its layout {layout.num_shelves} "
                         f"shelf cells")
    params = make_params(layout, reward_type=inner.reward_type, max_steps=inner.max_steps or 0,
                         max_inactivity_steps=inner.max_inactivity_steps or 0)
    state = RwareState(**{name: jnp.asarray(value) for name, value in arrays.items()})
    return state, params


def env_from_rware(warehouse: Any, tie_order: str = "set") -> Rware:
    """The :class:`Rware` environment with the warehouse's static settings; its default params are from_rware's.

    ``tie_order`` is ours, not the warehouse's (:mod:`wrl_jax.envs.rware.conflicts`): ``"set"`` matches rware
    as it runs.
    """
    inner = _warehouse(warehouse)
    _, params = from_rware(inner)
    return Rware(params, len(inner.agents), len(inner.request_queue), sensor_range=inner.sensor_range,
                 msg_bits=inner.msg_bits, normalised_coordinates=inner.normalised_coordinates,
                 tie_order=tie_order, name="rware-from-warehouse", **observation_settings(inner))
