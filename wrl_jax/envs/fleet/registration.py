"""Factories of the fleet: params from a layout, named maps, and any layout with enough starts.

``wrl_jax.core.registry.make("Fleet-12x12-v0", num_robots=K)`` reaches
:func:`make_named`; :func:`make_fleet` builds a fleet on any layout. All
checks (robot count, reward constants, unknown overrides, layout errors) run
here, in Python, before anything compiles.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from wrl_jax.core.grid import UNREACHABLE
from wrl_jax.envs.fleet import maps
from wrl_jax.envs.fleet.env import Fleet
from wrl_jax.envs.fleet.layout import FleetLayout, parse_fleet
from wrl_jax.envs.fleet.types import FleetParams
from wrl_jax.envs.warehouse.layout import bfs_distances

REWARD_DEFAULTS = {
    "step_penalty": -0.5,
    "obstacle_penalty": -10.0,
    "wall_penalty": 0.0,
    "block_penalty": -1.0,
    "shaping_coef": 2.0,
    "pickup_reward": 50.0,
    "delivery_reward": 200.0,
}
"""FLEET_SPEC.md step 6's constants."""

SHAPINGS = ("bfs", "manhattan")


def make_params(layout: FleetLayout, num_robots: int, *, max_steps: int, shaping: str = "bfs",
                max_items: int | None = None, max_stations: int | None = None, **rewards: float) -> FleetParams:
    """:class:`FleetParams` for ``num_robots`` robots on ``layout`` (BFS tables computed once, here).

    ``max_items`` / ``max_stations`` pad the item and station arrays (and
    their distance tables) to a fixed row count, so layouts with different
    counts share one compiled program (batched layouts, property tests); the
    padding rows repeat row 0 and are never drawn.
    """
    if isinstance(num_robots, bool) or not isinstance(num_robots, (int, np.integer)) or num_robots < 1:
        raise ValueError(f"num_robots must be a positive integer, got {num_robots!r}")
    if num_robots > layout.num_starts:
        raise ValueError(f"num_robots={num_robots} but the layout has only {layout.num_starts} start cells 'S'")
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")
    if shaping not in SHAPINGS:
        raise ValueError(f"shaping must be one of {SHAPINGS}, got {shaping!r}")
    unknown = sorted(set(rewards) - set(REWARD_DEFAULTS))
    if unknown:
        raise ValueError(f"unknown fleet override(s) {unknown}; known: num_robots, max_steps, view_radius, "
                         f"observe_priority, observe_last_action, observe_headings, shaping, name, max_items, max_stations, {', '.join(REWARD_DEFAULTS)}")
    constants = {**REWARD_DEFAULTS, **rewards}
    for key, value in constants.items():
        if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or not np.isfinite(value):
            raise ValueError(f"{key} must be a finite number, got {value!r}")
    shelves = jnp.asarray(layout.shelves)
    items = jnp.asarray(_padded(layout.items, max_items, "max_items"))
    stations = jnp.asarray(_padded(layout.stations, max_stations, "max_stations"))
    return FleetParams(
        shelves=shelves,
        starts=jnp.asarray(layout.starts[:num_robots], dtype=jnp.int32),
        items=items,
        stations=stations,
        num_items=jnp.asarray(layout.num_items, jnp.int32),
        num_stations=jnp.asarray(layout.num_stations, jnp.int32),
        item_dist=jnp.asarray(distance_tables(layout.shelves, np.asarray(items))),
        station_dist=jnp.asarray(distance_tables(layout.shelves, np.asarray(stations))),
        max_steps=jnp.asarray(max_steps, jnp.int32),
        manhattan_shaping=jnp.asarray(shaping == "manhattan"),
        **{key: jnp.asarray(value, jnp.float32) for key, value in constants.items()},
    )


def distance_tables(shelves: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """BFS distance from every cell to each of ``cells``, ``(T, N, N)`` int32, ``UNREACHABLE`` where cut off.

    NumPy, once per params: the same fields as ``wrl_jax.core.grid.distance_maps``
    without compiling a ``while_loop`` for every new ``(T, N)`` shape.
    """
    tables = [bfs_distances(shelves, (int(row), int(col))) for row, col in cells]
    return np.where(np.stack(tables) < 0, UNREACHABLE, np.stack(tables)).astype(np.int32)


def _padded(cells: np.ndarray, rows: int | None, name: str) -> np.ndarray:
    if rows is None:
        return cells.astype(np.int32)
    if rows < len(cells):
        raise ValueError(f"{name}={rows} is smaller than the layout's {len(cells)} cells")
    return np.concatenate([cells, np.repeat(cells[:1], rows - len(cells), axis=0)]).astype(np.int32)


def make_fleet(layout: FleetLayout | str, num_robots: int = 4, *, max_steps: int = 256, view_radius: int = 2,
               name: str = "Fleet", observe_priority: bool = False, observe_last_action: bool = False,
               observe_headings: bool = False, **overrides) -> tuple[Fleet, FleetParams]:
    """``(env, params)`` for any layout (a :class:`FleetLayout` or an ASCII map) with enough ``S`` cells.

    ``observe_priority``: a fourth window channel of the other robots with a lower index
    (:attr:`Fleet.observe_priority`); ``observe_last_action``: each robot's previous action one-hot and
    whether it was blocked, after the rest; ``observe_headings``: a window channel of the cells the other
    robots would enter by repeating their previous action (both: :class:`Fleet`). Overrides: ``shaping`` (``"bfs"`` or ``"manhattan"``),
    ``max_items`` and ``max_stations`` (padding, see :func:`make_params`) and the reward
    constants of :data:`REWARD_DEFAULTS`.

    Example:
        >>> env, params = make_fleet("S S 0\\n. # .\\nS . G", num_robots=2, max_steps=32)
        >>> env.num_robots
        2
    """
    if isinstance(layout, str):
        layout = parse_fleet(layout)
    if isinstance(view_radius, bool) or not isinstance(view_radius, (int, np.integer)) or view_radius < 0:
        raise ValueError(f"view_radius must be a non-negative integer, got {view_radius!r}")
    params = make_params(layout, num_robots, max_steps=max_steps, **overrides)
    env = Fleet(params, view_radius=view_radius, name=name, observe_priority=observe_priority,
                observe_last_action=observe_last_action, observe_headings=observe_headings)
    return env, params


def make_named(map_name: str, num_robots: int = 4, **overrides) -> tuple[Fleet, FleetParams]:
    """The factory of ``Fleet-<map_name>-v0``: the built-in map with its shift length."""
    if map_name not in maps.MAPS:
        raise ValueError(f"unknown fleet map {map_name!r}; known: {', '.join(maps.MAPS)}")
    overrides.setdefault("max_steps", maps.MAX_STEPS[map_name])
    return make_fleet(parse_fleet(maps.MAPS[map_name]), num_robots, name=f"Fleet-{map_name}-v0", **overrides)
