"""FLEET_SPEC.md steps 1-4: each robot's proposed cell, then the conflict rounds that decide who moves.

The conflict rule works on all robots at once: ``(K, K)`` relations "robot i's proposal is
robot j's proposal / cell" and "i and j would swap", fixed for the whole step; only the mover set
changes between rounds. Each relation row becomes an int32 mask over ``j`` and the rounds
(exactly ``K``, which reach the fixed point) are unrolled at trace time (:func:`_mover_rounds`);
fleets of more than 31 robots keep boolean tables in a ``lax.while_loop``. Pure array code over
the robots of one fleet (``vmap`` it over fleets), no order dependence. Rows and columns travel
apart (:func:`propose_cells`, :func:`resolve_cells`); :func:`propose` and
:func:`resolve_conflicts` are the same steps on ``(K, 2)`` cells.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def propose(pos: jax.Array, action: jax.Array, shelves: jax.Array):
    """Step 1: proposals ``q (K, 2)`` and the ``wall_bump``, ``shelf_hit`` flags (see :func:`propose_cells`)."""
    q_row, q_col, wall_bump, shelf_hit = propose_cells(pos[:, 0], pos[:, 1], action, shelves)
    return jnp.stack([q_row, q_col], axis=-1), wall_bump, shelf_hit


def propose_cells(row: jax.Array, col: jax.Array, action: jax.Array, shelves: jax.Array):
    """Step 1 on rows and columns apart: ``(q_row, q_col, wall_bump, shelf_hit)``, each ``(K,)``.

    The move is arithmetic on the action (no table gather); inside ``jit``, where actions are not
    checked, anything outside ``0..3`` waits. The shelf test is one scalar gather from the flat grid.
    Rows and columns travel apart through the transition: a trailing axis of 2 is a strided access
    in every fusion that touches it (apart, the conflicts ran 1.6x; docs/fleet_planners.md "Speed").
    """
    size = shelves.shape[0]
    moved_row = row + (action == 1).astype(jnp.int32) - (action == 0).astype(jnp.int32)
    moved_col = col + (action == 3).astype(jnp.int32) - (action == 2).astype(jnp.int32)
    wall_bump = (moved_row < 0) | (moved_row >= size) | (moved_col < 0) | (moved_col >= size)
    inside_row, inside_col = jnp.clip(moved_row, 0, size - 1), jnp.clip(moved_col, 0, size - 1)
    shelf_hit = ~wall_bump & shelves.reshape(-1)[inside_row * size + inside_col]
    stay = wall_bump | shelf_hit
    return jnp.where(stay, row, moved_row), jnp.where(stay, col, moved_col), wall_bump, shelf_hit


MAX_MASK_ROBOTS = 31
"""Most robots whose conflict rounds run on int32 bit masks (:func:`resolve_conflicts`); more use tables."""


def resolve_conflicts(pos: jax.Array, proposal: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Steps 2-4: the robots' next cells ``(K, 2)`` and ``robot_block (K,)`` (see :func:`resolve_cells`)."""
    row, col, robot_block = resolve_cells(pos[:, 0], pos[:, 1], proposal[:, 0], proposal[:, 1])
    return jnp.stack([row, col], axis=-1), robot_block


def resolve_cells(row: jax.Array, col: jax.Array, q_row: jax.Array, q_col: jax.Array):
    """Steps 2-4 on rows and columns apart: ``(next_row, next_col, robot_block)``, each ``(K,)``.

    A mover ``i`` is blocked when another robot ``j`` will be on ``q_i`` this
    round (``f_j = q_i``) and ``j`` stays or has a lower index, or when a mover
    ``j`` would swap cells with ``i``. All blocked movers of a round leave the
    mover set at once; the rounds end with the first one that blocks nobody.
    ``robot_block`` is then exactly the movers that left the set.
    """
    same_q = _same(q_row, q_col, q_row, q_col)  # [i, j]: q_i = q_j
    onto = _same(q_row, q_col, row, col)  # [i, j]: q_i = pos_j
    swap = onto & _same(row, col, q_row, q_col)  # [i, j]: q_i = pos_j and pos_i = q_j
    movers = (q_row != row) | (q_col != col)
    final = _mover_rounds(movers, same_q, onto, swap)
    return jnp.where(final, q_row, row), jnp.where(final, q_col, col), movers & ~final


def _same(a_row: jax.Array, a_col: jax.Array, b_row: jax.Array, b_col: jax.Array) -> jax.Array:
    return (a_row[:, None] == b_row[None, :]) & (a_col[:, None] == b_col[None, :])  # [i, j]: a_i == b_j


def _mover_rounds(movers: jax.Array, same_q: jax.Array, onto: jax.Array, swap: jax.Array) -> jax.Array:
    """The final mover set ``(K,)`` bool of FLEET_SPEC.md step 3, from the round-invariant ``(K, K)`` relations.

    Why masks: the relations never change between rounds, only the mover set does, so each
    relation row becomes an int32 mask over ``j`` once, and a round is a few ops per robot
    (``blocked_i = i moves and (M & claims_i | ~M & stayers_i) != 0`` for the mover mask ``M``)
    instead of a ``(K, K)`` table. Each round that blocks anyone removes at least one of at most
    ``K`` movers, and a round that blocks nobody changes nothing, so exactly ``K`` rounds, unrolled,
    give the fixed point: no loop, nothing for ``vmap`` to turn into a batch-wide ``while``.
    Fleets above :data:`MAX_MASK_ROBOTS` keep boolean tables in a ``lax.while_loop``.
    """
    num_robots = movers.shape[0]
    index = np.arange(num_robots)
    lower = index[None, :] < index[:, None]  # [i, j]: j < i
    if num_robots > MAX_MASK_ROBOTS:
        return _mover_rounds_tables(movers, same_q & lower, onto, swap)
    weights = jnp.asarray(np.left_shift(1, index).astype(np.int32))

    def mask(table):  # [i, j] bool -> (K,) int32 with bit j set where table[i, j]
        return jnp.sum(jnp.where(table, weights[None, :], 0), axis=1)

    claims = mask((same_q & lower) | swap)  # movers j that win q_i or swap with i
    stayers = mask(onto)  # robots j on q_i, which block i whenever j stays
    mover_mask = jnp.sum(jnp.where(movers, weights, 0))
    for _ in range(num_robots):
        moving = (mover_mask & weights) != 0
        blocked = moving & (((mover_mask & claims) | (~mover_mask & stayers)) != 0)
        mover_mask = mover_mask & ~jnp.sum(jnp.where(blocked, weights, 0))
    return (mover_mask & weights) != 0


def _mover_rounds_tables(movers: jax.Array, into_lower: jax.Array, onto: jax.Array, swap: jax.Array) -> jax.Array:
    """:func:`_mover_rounds` for large fleets: ``(K, K)`` tables, rounds in a ``lax.while_loop``."""

    def blocked_movers(movers: jax.Array) -> jax.Array:
        claimed = (movers[None, :] & into_lower) | (~movers[None, :] & onto) | (movers[None, :] & swap)
        return movers & jnp.any(claimed, axis=1)

    def round_(carry):
        movers, blocked = carry
        movers = movers & ~blocked
        return movers, blocked_movers(movers)

    movers, _ = jax.lax.while_loop(lambda carry: jnp.any(carry[1]), round_, (movers, blocked_movers(movers)))
    return movers
