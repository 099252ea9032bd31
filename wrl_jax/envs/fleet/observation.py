"""What a fleet robot observes (FLEET_SPEC.md), and the fleet's global state for centralised critics.

The windows come from :mod:`wrl_jax.core.observation`; for ``V <= 2`` from int32 bit masks
(:func:`observation_parts`), the same bits as the gathers, several times cheaper under ``vmap``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.core.grid import MOVES_WITH_WAIT
from wrl_jax.core.observation import (
    bit_windows_supported,
    coordinate_table,
    expand_observations,
    robot_observation_parts,
    robot_observations,
    seen_masks,
    window_masks,
)
from wrl_jax.envs.fleet.dynamics import NUM_ACTIONS, WAIT, target_cells, target_index, targets
from wrl_jax.envs.fleet.types import FleetParams, FleetState

MEMORY_SIZE = NUM_ACTIONS + 1
"""Values ``observe_last_action`` appends: the previous action one-hot, then whether it was blocked."""


def fleet_observation(state: FleetState, params: FleetParams, view_radius: int, priority: bool = False,
                      headings: bool = False) -> jax.Array:
    """``(K, 5 + 3 (2V+1)^2)`` float32 observations (FLEET_SPEC.md), through :mod:`wrl_jax.core.observation`.

    For ``V <= 2`` from bit masks (:func:`observation_parts`), the same bits as
    :func:`~wrl_jax.core.observation.robot_observations`, several times cheaper under ``vmap``.
    ``priority`` (``V <= 2``) appends a fourth window channel, ``(K, 5 + 4 (2V+1)^2)``: the other
    robots with a lower index than the observer (:attr:`Fleet.observe_priority`); ``headings`` (``V <= 2``,
    needs ``state.last_action``) one more: the cells the other robots would enter by repeating their
    previous action (:func:`heading_masks`).
    """
    if not bit_windows_supported(view_radius):
        target = target_cells(params)[target_index(state, params)]
        return robot_observations(params.shelves, state.pos, target, state.carrying, view_radius)
    return expand_observations(*observation_parts(state, params, view_radius, priority, headings), view_radius)


def observation_parts(state: FleetState, params: FleetParams, view_radius: int,
                      priority: bool = False, headings: bool = False) -> tuple[jax.Array, tuple[jax.Array, ...]]:
    """The observations' compact form ``(scalars (K, 5), masks)``, 3 to 5 ``(K,)`` int32 masks (``V <= 2``; see
    ``robot_observation_parts``; ``headings`` appends :func:`heading_masks`).

    The shelf masks come from a table of the layout (:func:`~wrl_jax.core.observation.window_masks`),
    one gather per robot; with params shared by a batch the table is built once per step.
    """
    size = params.shelves.shape[0]
    target = target_cells(params)[target_index(state, params)]
    masks = window_masks(params.shelves, view_radius).reshape(-1)[state.pos[:, 0] * size + state.pos[:, 1]]
    scalars, masks = robot_observation_parts(masks, state.pos, target, state.carrying, view_radius, size, priority)
    if headings:
        masks = (*masks, heading_masks(state.pos, state.last_action, view_radius))
    return scalars, masks


def heading_masks(pos: jax.Array, last_action: jax.Array, view_radius: int) -> jax.Array:
    """``(K,)`` int32 window masks: bit ``w`` of robot ``i`` set on the cell another robot's previous
    action aimed at (the cell it would try again by repeating it, whether or not it got there; its own
    cell if that action was a wait, and at the start of a shift).

    Why: a robot's window shows where the others *are*, not where they go; two robots that step
    into one free cell, or into each other, are both blocked or one of them is (FLEET_SPEC.md step 3).
    In aisles robots mostly keep going, so the repeated move is a cheap guess of the next cell.
    """
    ahead = pos + jnp.asarray(MOVES_WITH_WAIT)[jnp.where(last_action < 0, WAIT, last_action)]
    return seen_masks(pos, ahead, view_radius, ~np.eye(pos.shape[0], dtype=bool))


def global_state(state: FleetState, params: FleetParams) -> jax.Array:
    """A fixed-size view of the whole fleet for centralised critics, ``(4 N^2 + 5 K + 1,)`` float32.

    Four ``N x N`` planes, row-major: shelves; robot occupancy; cells some
    robot is heading to (its current target); cells of carrying robots. Then
    each robot's five observation scalars in robot order (who is where and
    where it goes: the planes alone lose robot identity), then the elapsed
    fraction of the shift ``time / max_steps`` (the value of a truncated
    shift depends on it).
    """
    size = params.shelves.shape[0]
    target = targets(state, params)
    empty = jnp.zeros((size, size), dtype=jnp.float32)
    robots = empty.at[state.pos[:, 0], state.pos[:, 1]].set(1.0)
    heading = empty.at[target[:, 0], target[:, 1]].set(1.0)
    loaded = empty.at[state.pos[:, 0], state.pos[:, 1]].max(state.carrying.astype(jnp.float32))
    table = jnp.asarray(coordinate_table(size))  # the observation's exact scalars
    scalars = jnp.concatenate([table[state.pos], table[target], state.carrying.astype(jnp.float32)[:, None]], axis=1)
    elapsed = state.time.astype(jnp.float32) / params.max_steps.astype(jnp.float32)
    planes = jnp.stack([params.shelves.astype(jnp.float32), robots, heading, loaded])
    return jnp.concatenate([planes.reshape(-1), scalars.reshape(-1), elapsed[None]])
