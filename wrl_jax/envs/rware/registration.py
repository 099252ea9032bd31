"""Factories of RWARE: rware 2.0.0's 228 registered ids and :func:`make_rware` for its other settings.

``wrl_jax.make("rware-tiny-4ag-v2")`` reaches :func:`make_named` (the ids are listed in
:mod:`wrl_jax.envs`, the one place that names built-in environments); :func:`make_rware`
takes rware's ``Warehouse`` arguments by the same names. All checks run here, in Python,
before anything compiles.
"""

from __future__ import annotations

import itertools

import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.rware.conflicts import check_tie_order
from wrl_jax.envs.rware.env import Rware
from wrl_jax.envs.rware.layout import RwareLayout, layout_from_params, parse_layout
from wrl_jax.envs.rware.observation import OBSERVATION_TYPES as OBSERVATION_TYPES  # rware's types, by name
from wrl_jax.envs.rware.observation import directional_flag, image_layer_names, observation_type_name
from wrl_jax.envs.rware.observation_image import DEFAULT_IMAGE_LAYERS
from wrl_jax.envs.rware.observation_image import IMAGE_LAYERS as IMAGE_LAYERS  # rware's ImageLayer names
from wrl_jax.envs.rware.types import GLOBAL, INDIVIDUAL, TWO_STAGE, RwareParams

SIZES = {"tiny": (1, 3), "small": (2, 3), "medium": (2, 5), "large": (3, 5)}
"""rware's sizes: ``(shelf_rows, shelf_columns)``, with ``column_height`` 8."""

DIFFICULTIES = {"-easy": 2.0, "": 1.0, "-hard": 0.5}
"""Request-queue size per agent: ``request_queue_size = int(num_agents * d)``."""

AGENT_COUNTS = range(1, 20)

REWARD_TYPES = {"global": GLOBAL, "individual": INDIVIDUAL, "two_stage": TWO_STAGE}
"""rware's ``RewardType`` by name (``"two-stage"``, ``"twostage"`` and rware's enum members are accepted too)."""


def rware_id(size: str, num_agents: int, difficulty: str) -> str:
    return f"rware-{size}-{num_agents}ag{difficulty}-v2"


def registered_ids() -> list[str]:
    """The 228 ids ``import rware`` registers, in rware's order."""
    return [rware_id(size, agents, difficulty)
            for size, difficulty, agents in itertools.product(SIZES, DIFFICULTIES, AGENT_COUNTS)]


def reward_code(reward_type: object) -> int:
    """rware's ``RewardType`` value from a name (``"individual"``...), an enum member with such a name, or a value."""
    if isinstance(reward_type, (int, np.integer)) and not isinstance(reward_type, bool) and 0 <= reward_type < 3:
        return int(reward_type)
    name = getattr(reward_type, "name", reward_type)
    key = str(name).lower().replace("-", "_") if isinstance(name, str) else None
    key = "two_stage" if key == "twostage" else key
    if key not in REWARD_TYPES:
        raise ValueError(f"unknown reward_type {reward_type!r}; expected one of {', '.join(REWARD_TYPES)}")
    return REWARD_TYPES[key]


def _limit(name: str, value: object) -> int:
    """rware's optional step limits: ``None`` or 0 disables (rware tests their truthiness)."""
    if value is None:
        return 0
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f"{name} must be None or a non-negative integer, got {value!r}")
    return int(value)


def _count(name: str, value: object, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def make_params(layout: RwareLayout, *, reward_type: object = "individual", max_steps: int | None = 500,
                max_inactivity_steps: int | None = None) -> RwareParams:
    """:class:`RwareParams` of a layout: its highways, goals and shelf homes, the reward type and the limits."""
    return RwareParams(
        highway=jnp.asarray(layout.highway),
        goals=jnp.asarray(layout.goals, jnp.int32),
        shelf_home=jnp.asarray(layout.shelf_cells, jnp.int32),
        reward_type=jnp.asarray(reward_code(reward_type), jnp.int32),
        max_steps=jnp.asarray(_limit("max_steps", max_steps), jnp.int32),
        max_inactivity_steps=jnp.asarray(_limit("max_inactivity_steps", max_inactivity_steps), jnp.int32),
    )


def make_rware(num_agents: int = 4, *, shelf_columns: int = 3, column_height: int = 8, shelf_rows: int = 1,
               layout: str | RwareLayout | None = None, request_queue_size: int | None = None,
               sensor_range: int = 1, msg_bits: int = 0, max_inactivity_steps: int | None = None,
               max_steps: int | None = 500, reward_type: object = "individual",
               observation_type: object = "flattened", normalised_coordinates: bool = False,
               image_observation_layers: object = DEFAULT_IMAGE_LAYERS, image_observation_directional: bool = True,
               tie_order: str = "set", name: str | None = None) -> tuple[Rware, RwareParams]:
    """``(env, params)`` for any rware warehouse, with rware's argument names and defaults.

    ``layout`` (a custom layout string or :class:`RwareLayout`) replaces ``shelf_columns``,
    ``shelf_rows`` and ``column_height``, as in rware. ``request_queue_size`` defaults to
    ``num_agents`` and must be below the shelf count (rware fails drawing a replacement
    otherwise: so do four of its registered ids, ``rware-tiny-{16..19}ag-easy-v2``, refused here).
    ``reward_type``: ``"individual"`` (default), ``"global"`` or ``"two_stage"``.
    ``observation_type``: ``"flattened"`` (default), ``"dict"``, ``"image"`` or ``"image_dict"`` (or
    rware's ``ObservationType``); the image types read ``image_observation_layers`` (rware's
    ``ImageLayer`` names or members, :data:`IMAGE_LAYERS`) and ``image_observation_directional``
    (see :mod:`wrl_jax.envs.rware.observation_image`), which the others ignore, as rware does.
    ``tie_order`` (not rware's: ours): ``"set"`` (default) breaks ties between equal chains as unpatched
    rware does (CPython's hash-set order where networkx iterates one), ``"insertion"`` by the graph's
    insertion order everywhere (:mod:`wrl_jax.envs.rware.conflicts`).

    Example:
        >>> env, params = make_rware(2, layout="x.x\\n...\\n.g.", request_queue_size=1)
        >>> env.obs_size
        71
    """
    observation_type = observation_type_name(observation_type)
    image_observation_layers = image_layer_names(image_observation_layers,
                                                 needed=observation_type in ("image", "image_dict"))
    image_observation_directional = directional_flag(image_observation_directional)
    check_tie_order(tie_order)
    if layout is None or (isinstance(layout, str) and not layout):  # rware: `if not layout`
        layout = layout_from_params(shelf_columns, shelf_rows, column_height)
    elif isinstance(layout, str):
        layout = parse_layout(layout)
    elif not isinstance(layout, RwareLayout):
        raise ValueError(f"layout must be a layout string or an RwareLayout, got {type(layout).__name__}")
    num_agents = _count("num_agents", num_agents, 1)
    height, width = layout.grid_size
    if num_agents > height * width:
        raise ValueError(f"num_agents={num_agents} does not fit the {height * width} cells of the grid")
    request_queue_size = num_agents if request_queue_size is None else request_queue_size
    request_queue_size = _count("request_queue_size", request_queue_size, 0)
    if request_queue_size >= layout.num_shelves:
        fails = ("its reset fails: it draws that many distinct shelves" if request_queue_size > layout.num_shelves
                 else "it fails at the first delivery: no unrequested shelf is left to draw")
        raise ValueError(f"{name or 'make_rware'}: request_queue_size={request_queue_size} must be below the layout's "
                         f"{layout.num_shelves} shelves; rware 2.0.0 cannot run it either ({fails})")
    sensor_range = _count("sensor_range", sensor_range, 0)
    msg_bits = _count("msg_bits", msg_bits, 0)
    if normalised_coordinates and min(height, width) < 2:
        raise ValueError("normalised_coordinates needs a grid at least 2 cells high and wide")
    params = make_params(layout, reward_type=reward_type, max_steps=max_steps,
                         max_inactivity_steps=max_inactivity_steps)
    env = Rware(params, num_agents, request_queue_size, sensor_range=sensor_range, msg_bits=msg_bits,
                normalised_coordinates=normalised_coordinates, observation_type=observation_type,
                image_observation_layers=image_observation_layers,
                image_observation_directional=image_observation_directional, tie_order=tie_order,
                name=name or "rware-custom")
    return env, params


FIXED_BY_ID = ("num_agents", "request_queue_size", "shelf_columns", "shelf_rows", "column_height", "layout")


def make_named(size: str, agents: int, difficulty: str = "", **overrides) -> tuple[Rware, RwareParams]:
    """The factory of ``rware-{size}-{N}ag{difficulty}-v2``: rware's registered kwargs, plus overrides.

    Overrides are :func:`make_rware`'s other arguments (``reward_type``, ``max_steps``,
    ``max_inactivity_steps``, ``sensor_range``, ``msg_bits``, ``normalised_coordinates``,
    ``observation_type``, ``image_observation_layers``, ``image_observation_directional``, and our
    ``tie_order``); the layout, agent count and queue size are fixed by the id.
    """
    num_agents = agents
    if size not in SIZES:
        raise ValueError(f"unknown rware size {size!r}; known: {', '.join(SIZES)}")
    if difficulty not in DIFFICULTIES:
        raise ValueError(f"unknown rware difficulty {difficulty!r}; known: {list(DIFFICULTIES)}")
    fixed = sorted(set(overrides) & set(FIXED_BY_ID))
    if fixed:
        raise ValueError(f"{fixed} are fixed by the id {rware_id(size, num_agents, difficulty)!r}; "
                         f"use wrl_jax.envs.rware.make_rware for other values")
    known = {"reward_type", "max_steps", "max_inactivity_steps", "sensor_range", "msg_bits",
             "normalised_coordinates", "observation_type", "image_observation_layers",
             "image_observation_directional", "tie_order", "name"}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ValueError(f"unknown rware override(s) {unknown}; known: {', '.join(sorted(known))}")
    rows, columns = SIZES[size]
    overrides.setdefault("name", rware_id(size, num_agents, difficulty))
    return make_rware(num_agents, shelf_columns=columns, column_height=8, shelf_rows=rows,
                      request_queue_size=int(num_agents * DIFFICULTIES[difficulty]), **overrides)
