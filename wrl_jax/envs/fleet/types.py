"""Typed pytrees of the fleet (FLEET_SPEC.md): its state, its params, and a transition's drawn tasks.

All three are ``flax.struct`` dataclasses, so they pass through ``jit``,
``vmap`` and ``lax.scan``. Everything a layout or a reward setting can change
is an array in :class:`FleetParams` (one compiled program serves every layout
of a size); only shapes (grid side ``N``, robot count ``K``, view radius) are
static and live on the environment object.

Shapes: ``K`` robots, ``N x N`` grid, ``I`` item (pick station) rows,
``G`` delivery station rows.
"""

from __future__ import annotations

import jax
from flax import struct


@struct.dataclass
class FleetState:
    """The fleet between transitions.

    Attributes:
        pos: ``(K, 2)`` int32 robot cells ``(row, col)``; no two rows are equal, ever.
        item: ``(K,)`` int32 index into ``params.items`` of each robot's current pick station.
        station: ``(K,)`` int32 index into ``params.stations`` of each robot's delivery station.
        carrying: ``(K,)`` bool, True between a robot's pickup and its delivery.
        time: ``()`` int32 transitions taken in this shift (shared by the fleet).
        last_action: ``(K,)`` int32 each robot's previous action (``-1`` at the start of a shift), kept
            only by a fleet that observes it (``Fleet.observe_last_action``); ``None`` otherwise.
        last_blocked: ``(K,)`` bool whether that action was a blocked move (``robot_block``); ``None``
            like ``last_action``.
    """

    pos: jax.Array
    item: jax.Array
    station: jax.Array
    carrying: jax.Array
    time: jax.Array
    last_action: jax.Array | None = None
    last_blocked: jax.Array | None = None


@struct.dataclass
class FleetTasks:
    """Tasks drawn for one transition, the random input of the deterministic core.

    Every robot gets a candidate task each step; only robots that deliver take
    theirs (FLEET_SPEC.md step 7). Drawing all ``K`` keeps shapes static and
    lets the NumPy reference replay exactly the same draws.

    Attributes:
        item: ``(K,)`` int32 candidate next item of each robot.
        station: ``(K,)`` int32 candidate next delivery station of each robot.
    """

    item: jax.Array
    station: jax.Array


@struct.dataclass
class FleetParams:
    """Layout, distance tables, reward constants and switches of one fleet (FLEET_SPEC.md).

    Attributes:
        shelves: ``(N, N)`` bool, True on shelf cells.
        starts: ``(K, 2)`` int32 start cell of each robot (the first ``K`` ``S`` cells, row-major).
        items: ``(I, 2)`` int32 pick-station cells in marker order; rows past ``num_items`` are padding.
        stations: ``(G, 2)`` int32 delivery-station cells, row-major; rows past ``num_stations`` are padding.
        num_items: ``()`` int32 number of real items (task draws are uniform over ``0..num_items-1``).
        num_stations: ``()`` int32 number of real stations.
        item_dist: ``(I, N, N)`` int32 BFS distance from every cell to each item
            (``wrl_jax.core.grid.UNREACHABLE`` on shelves and cut-off cells).
        station_dist: ``(G, N, N)`` int32 BFS distance from every cell to each station.
        max_steps: ``()`` int32 shift length; ``truncated = time' >= max_steps``.
        step_penalty, obstacle_penalty, wall_penalty, block_penalty, shaping_coef,
        pickup_reward, delivery_reward: ``()`` float32 reward constants of step 6.
        manhattan_shaping: ``()`` bool, shape with the Manhattan distance (the
            study's choice) instead of the BFS distance (the default).
    """

    shelves: jax.Array
    starts: jax.Array
    items: jax.Array
    stations: jax.Array
    num_items: jax.Array
    num_stations: jax.Array
    item_dist: jax.Array
    station_dist: jax.Array
    max_steps: jax.Array
    step_penalty: jax.Array
    obstacle_penalty: jax.Array
    wall_penalty: jax.Array
    block_penalty: jax.Array
    shaping_coef: jax.Array
    pickup_reward: jax.Array
    delivery_reward: jax.Array
    manhattan_shaping: jax.Array

    @property
    def max_steps_in_episode(self) -> jax.Array:
        """gymnax's name for the shift length."""
        return self.max_steps

    @property
    def size(self) -> int:
        """Grid side ``N`` (static: an array shape)."""
        return self.shelves.shape[-1]

    @property
    def num_robots(self) -> int:
        """``K`` (static: an array shape)."""
        return self.starts.shape[-2]
