"""The procedural continuous warehouse's params and state, and one pool slot as the core's layout.

The pool is the procedural family's :class:`~wrl_jax.envs.procedural.layout.PaddedLayout` batch, kept as
it is (so the grid family's hashes, held-out checks and layout sets apply unchanged), beside the one
array the continuous core needs that the layout does not hold: where moving obstacles may start.
:func:`layout_params` turns slot ``k`` into exactly the params the plain continuous environment builds
from that layout (:func:`~wrl_jax.envs.continuous.registration.make_continuous`), so every transition
is the existing deterministic core on the episode's own layout.

Padding: cells outside a layout's real floor are blocked, and the core reads blocked cells as solid
shelf squares. Squares abutting the real floor's edge present the same surface as a wall there (a
disc or a ray meets them at the same place), so a smaller floor inside the padded shape behaves as
that floor walled in; only the flag differs (a contact with the padding is ``hit_shelf``, not
``hit_wall``; both cost ``collision_penalty``).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from wrl_jax.envs.continuous import geodesic
from wrl_jax.envs.continuous.dynamics import cell_centre
from wrl_jax.envs.continuous.types import ContinuousParams, ContinuousState
from wrl_jax.envs.procedural.layout import PaddedLayout
from wrl_jax.envs.warehouse.layout import Layout

OBSTACLE_CLEARANCE = 3
"""Least Manhattan distance (cells) from the start of a moving obstacle's first cell (the contract's)."""


@struct.dataclass
class ProceduralContinuousParams(ContinuousParams):
    """:class:`ContinuousParams` plus the pool; the layout fields hold slot 0 (so shapes read right).

    ``pool``: ``P`` padded layouts (leaves with a leading ``(P,)`` axis); ``pool_obstacle_cells``
    ``(P, H, W)`` bool, each layout's eligible cells for moving obstacles (:func:`obstacle_mask`).
    """

    pool: PaddedLayout
    pool_obstacle_cells: jax.Array


@struct.dataclass
class ProceduralGeodesicParams(ProceduralContinuousParams):
    """The pool with each slot's distance fields, for geodesic shaping and the route.

    ``pool_fields`` ``(P, I + 1, ny, nx)``: per slot, metres to each item row, then to the goal, on a
    lattice of ``(ny - 1) / H`` points per metre (:func:`pool_fields`); ``fields`` holds the current slot's, as
    :class:`~wrl_jax.envs.continuous.geodesic.GeodesicParams` does (:func:`layout_params` writes it).
    """

    fields: jax.Array
    pool_fields: jax.Array


@struct.dataclass
class ProceduralContinuousState(ContinuousState):
    """A continuous episode plus the pool slot it runs on (``layout_index``, int32)."""

    layout_index: jax.Array


def pool_size(params: ProceduralContinuousParams) -> int:
    """The number of pool slots (static: a shape)."""
    return int(params.pool.num_items.shape[-1])


def obstacle_mask(layout: PaddedLayout) -> jax.Array:
    """``(H, W)`` bool: free, at least 3 cells (Manhattan) from the start, not the goal (jittable).

    The same cells as :func:`wrl_jax.envs.continuous.registration.obstacle_cells` on the padded grid.
    """
    rows = jnp.arange(layout.blocked.shape[-2], dtype=jnp.int32)[:, None]
    cols = jnp.arange(layout.blocked.shape[-1], dtype=jnp.int32)[None, :]
    far = jnp.abs(rows - layout.start[0]) + jnp.abs(cols - layout.start[1]) >= OBSTACLE_CLEARANCE
    not_goal = (rows != layout.goal[0]) | (cols != layout.goal[1])
    return ~layout.blocked & far & not_goal


def pool_fields(layouts: PaddedLayout, robot_radius: float, resolution: int) -> jax.Array:
    """``(P, I + 1, ny, nx)`` float32: each layout's distance fields to its item rows and its goal, routes
    keeping ``robot_radius + SPARE`` from shelves, ``resolution`` lattice points per metre (host NumPy and one
    compiled relaxation: :func:`~wrl_jax.envs.continuous.geodesic.pool_distance_fields`)."""
    items = np.asarray(layouts.items)[..., ::-1] + 0.5  # cell centres (x, y), as layout_params writes them
    goals = np.asarray(layouts.goal)[:, None, ::-1] + 0.5
    return jnp.asarray(geodesic.pool_distance_fields(np.asarray(layouts.blocked), np.concatenate([items, goals], 1),
                                                     float(robot_radius) + geodesic.SPARE, resolution))


def with_pool(params: ProceduralContinuousParams, layouts: PaddedLayout) -> ProceduralContinuousParams:
    """``params`` serving ``layouts`` (same padded shape) as its pool, obstacle cells recomputed (jittable), and
    with geodesic params the distance fields too, at the same resolution (on the host: not jittable)."""
    if tuple(layouts.blocked.shape[-2:]) != tuple(params.shelves.shape):
        raise ValueError(f"layouts padded to {tuple(layouts.blocked.shape[-2:])}, the environment's map is "
                         f"{tuple(params.shelves.shape)}")
    params = params.replace(pool=layouts, pool_obstacle_cells=jax.vmap(obstacle_mask)(layouts))
    if isinstance(params, ProceduralGeodesicParams):
        resolution = geodesic.field_resolution(params.pool_fields, params.shelves.shape[-1])
        params = params.replace(pool_fields=pool_fields(layouts, params.robot_radius, resolution))
    return params


def layout_params(params: ProceduralContinuousParams, index: jax.Array) -> ProceduralContinuousParams:
    """``params`` whose layout fields are pool slot ``index``'s (a gather per field; traced ``index`` is fine).

    Points are cell centres in float32 (``col + 0.5, row + 0.5``, exact), as ``make_continuous`` writes
    them; the item rows past ``num_items`` repeat item 0 and are never drawn. Geodesic params get the slot's
    ``fields``.
    """
    layout = jax.tree.map(lambda leaf: leaf[index], params.pool)
    fields = {"fields": params.pool_fields[index]} if isinstance(params, ProceduralGeodesicParams) else {}
    return params.replace(shelves=layout.blocked, start=cell_centre(layout.start), start_cell=layout.start,
                          goal=cell_centre(layout.goal), goal_cell=layout.goal, items=cell_centre(layout.items),
                          num_items=layout.num_items, obstacle_cells=params.pool_obstacle_cells[index], **fields)


def with_layout_index(state: ContinuousState, index: jax.Array) -> ProceduralContinuousState:
    """The core's state of an episode on pool slot ``index``, as the procedural state."""
    fields = {field.name: getattr(state, field.name) for field in dataclasses.fields(ContinuousState)}
    return ProceduralContinuousState(**fields, layout_index=jnp.asarray(index, jnp.int32))


def slot_layout(pool: PaddedLayout, index: int) -> Layout:
    """Pool slot ``index`` as a grid :class:`Layout` of the padded (square) shape, padding as shelves.

    What :func:`~wrl_jax.envs.continuous.registration.make_continuous` builds the plain environment of
    that slot from (the parity tests compare the two).
    """
    blocked = np.asarray(pool.blocked[index], bool)
    count = int(pool.num_items[index])
    return Layout(shelves=blocked, start=np.asarray(pool.start[index], np.int32),
                  goal=np.asarray(pool.goal[index], np.int32), items=np.asarray(pool.items[index], np.int32)[:count])
