"""Building a continuous warehouse from any layout of SPEC.md (:func:`make_continuous`).

The study's maps take the contract's episode limits (8x8: 300 steps, 12x12: 500); any other layout
names its own. Bad settings are refused here, before anything compiles, with the setting named.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.continuous import geodesic
from wrl_jax.envs.continuous.env import ContinuousWarehouse
from wrl_jax.envs.continuous.safety import SAFETY_MARGIN
from wrl_jax.envs.continuous.types import ContinuousParams
from wrl_jax.envs.procedural.layout import PaddedLayout
from wrl_jax.envs.procedural.movingai import load_map
from wrl_jax.envs.warehouse import maps
from wrl_jax.envs.warehouse.layout import Layout, parse

STUDY_MAX_STEPS = {maps.WAREHOUSE_8X8: 300, maps.WAREHOUSE_12X12: 500}
"""The contract's episode limits on the study's two maps."""


def study_max_steps(layout: Layout) -> int | None:
    """The contract's limit when ``layout`` is one of the study's maps (compared as grids, not text)."""
    for text, steps in STUDY_MAX_STEPS.items():
        study = parse(text)
        if all(np.array_equal(getattr(study, f), getattr(layout, f)) for f in ("shelves", "start", "goal", "items")):
            return steps
    return None

DEFAULTS: dict[str, Any] = {
    "dt": 0.2, "v_max": 1.0, "w_max": 2.0, "robot_radius": 0.3, "reach_radius": 0.35, "lidar_range": 4.0,
    "step_penalty": -0.5, "collision_penalty": -10.0, "shaping_coef": 2.0, "pickup_reward": 50.0,
    "delivery_reward": 200.0, "obstacle_radius": 0.3, "obstacle_speed": 0.5, "randomize": False,
    "gain_low": 0.8, "gain_high": 1.2, "actuation_noise": 0.05, "lidar_noise": 0.02, "lidar_dropout": 0.02,
    "start_jitter": 0.2,
}
"""CONTINUOUS_SPEC.md's parameters (every one an override of :func:`make_continuous`)."""

SHAPINGS = ("manhattan", "geodesic")
"""The shaping term's distance: the contract's, or around the shelves (:mod:`.geodesic`)."""

POSITIVE = ("dt", "v_max", "w_max", "robot_radius", "reach_radius", "lidar_range", "obstacle_radius")


def obstacle_cells(layout: Layout) -> np.ndarray:
    """``(H, W)`` bool: where a moving obstacle may start (free, Manhattan >= 3 from the start, not the goal)."""
    rows, cols = np.indices(layout.shelves.shape)
    far = np.abs(rows - layout.start[0]) + np.abs(cols - layout.start[1]) >= 3
    not_goal = (rows != layout.goal[0]) | (cols != layout.goal[1])
    return ~np.asarray(layout.shelves, bool) & far & not_goal


def as_layout(layout: Layout | str | os.PathLike | PaddedLayout) -> Layout:
    """The grid :class:`Layout` of what :func:`make_continuous` accepts: a layout; an ASCII map; a map file's path (a
    ``pathlib.Path``, or a one-line string naming an existing file), read by
    :func:`~wrl_jax.envs.procedural.load_map` (an ASCII file carries its cells; a MovingAI ``.map`` file does not, so
    load it with its cells or a key and pass the result); or one :class:`PaddedLayout`, cut to its real rows and
    columns and, where those differ in number, padded to a square with shelves (the layouts here are square)."""
    if isinstance(layout, Layout):
        return layout
    if isinstance(layout, str) and "\n" not in layout.strip() and os.path.isfile(layout.strip()):
        layout = Path(layout.strip())
    if isinstance(layout, str):
        return parse(layout)
    if isinstance(layout, os.PathLike):
        layout = load_map(layout)
    if isinstance(layout, PaddedLayout):
        if np.ndim(layout.blocked) != 2:
            raise ValueError(f"make_continuous takes one layout; got a batch of shape {np.shape(layout.blocked)[:-2]} "
                             "(pick one, e.g. wrl_jax.envs.continuous.procedural_layouts.slot_layout(pool, i))")
        height, width, count = int(layout.height), int(layout.width), int(layout.num_items)
        side = max(height, width)
        shelves = np.ones((side, side), bool)
        shelves[:height, :width] = np.asarray(layout.blocked, bool)[:height, :width]
        return Layout(shelves=shelves, start=np.asarray(layout.start, np.int32), goal=np.asarray(layout.goal, np.int32),
                      items=np.asarray(layout.items, np.int32)[:count])
    raise ValueError(f"a continuous warehouse's layout is a Layout, an ASCII map, a map file's path or a "
                     f"PaddedLayout; got {type(layout).__name__}")


def make_continuous(layout: Layout | str | os.PathLike | PaddedLayout, *, max_steps: int | None = None,
                    num_rays: int = 32, num_obstacles: int = 0, name: str = "Continuous-Warehouse",
                    shaping: str = "manhattan",
                    observe_target: bool = False, observe_route: bool = False, observe_obstacles: bool = False,
                    safety_stop: bool = False, safety_margin: float | None = None, escape_after: int | None = None,
                    **overrides: Any) -> tuple[ContinuousWarehouse, ContinuousParams]:
    """``(env, params)`` for ``layout``: a :class:`Layout`, an ASCII map of SPEC.md, a map file's path or a
    MovingAI map loaded by ``load_map`` (:func:`as_layout`).

    ``shaping="geodesic"`` measures the shaping term's distance around the shelves instead of the
    contract's Manhattan distance (:mod:`wrl_jax.envs.continuous.geodesic`); ``observe_target=True``
    appends the target seen from the robot to the observation (:func:`~.env.target_features`);
    ``observe_route=True`` (with geodesic shaping, whose fields it reads) appends the way there
    (:func:`~.geodesic.route_features`); ``observe_obstacles=True`` appends the moving obstacles' ranges and the
    last step's contacts (:func:`~.env.obstacle_features`); ``safety_stop=True`` holds the robot where its forward
    command would come within ``robot_radius + safety_margin`` of what the lidar sees (:mod:`~.safety`; the margin
    0.05 m unless given; with or without randomization) and ``escape_after=K`` turns it fully once it has been held
    ``K`` steps in a row (:func:`~.safety.escape`; 0 or ``None``: no escape). All six are for learners; the registered names are the
    contract's.

    Raises:
        ValueError: naming the problem: an unknown override or shaping, a non-positive length or speed, a
            radius that does not fit a cell, a setting that is not finite, a negative speed or noise, a
            dropout outside ``[0, 1]``, a ``max_steps`` missing for a layout other than the study's, too few
            cells for the obstacles, a gain range that is not ``0 < low <= high``, ``observe_route`` without
            geodesic shaping, a ``safety_margin`` out of ``[0, 1)`` or without ``safety_stop``, or an
            ``escape_after`` that is not an integer >= 0 or is positive without ``safety_stop``.
    """
    layout = as_layout(layout)
    unknown = sorted(set(overrides) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"unknown continuous warehouse setting(s) {unknown}; known: {sorted(DEFAULTS)}")
    if shaping not in SHAPINGS:
        raise ValueError(f"shaping must be one of {SHAPINGS} for a continuous warehouse, got {shaping!r}")
    settings = {**DEFAULTS, **overrides}
    if max_steps is None:
        max_steps = study_max_steps(layout)
        if max_steps is None:
            raise ValueError("max_steps is needed for a layout other than the study's 8x8 and 12x12 maps")
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")
    for field, value in settings.items():
        if field != "randomize" and not np.isfinite(float(value)):
            raise ValueError(f"{field} must be a finite number, got {value!r}")
    for field in POSITIVE:
        if not float(settings[field]) > 0:
            raise ValueError(f"{field} must be positive, got {settings[field]!r}")
    if not float(settings["obstacle_speed"]) >= 0:
        raise ValueError(f"obstacle_speed must be >= 0 (metres per second), got {settings['obstacle_speed']!r}")
    if not 0 < float(settings["gain_low"]) <= float(settings["gain_high"]):
        raise ValueError(f"the gain range must be 0 < gain_low <= gain_high, got "
                         f"{settings['gain_low']!r}..{settings['gain_high']!r}")
    for field in ("robot_radius", "obstacle_radius"):
        if not float(settings[field]) < 0.5:
            raise ValueError(f"{field} {settings[field]!r} does not fit a 1 m cell (it must be below 0.5)")
    for field in ("actuation_noise", "lidar_noise"):
        if not float(settings[field]) >= 0:
            raise ValueError(f"{field} is a standard deviation: it must be >= 0, got {settings[field]!r}")
    if not 0 <= float(settings["lidar_dropout"]) <= 1:
        raise ValueError(f"lidar_dropout is a probability: it must lie in [0, 1], got {settings['lidar_dropout']!r}")
    if not 0 <= float(settings["start_jitter"]) <= 0.5 - float(settings["robot_radius"]):
        raise ValueError(f"start_jitter must lie in [0, 0.5 - robot_radius] so that every randomized start is "
                         f"collision-free in the start cell, got {settings['start_jitter']!r}")
    if num_rays < 1 or num_obstacles < 0:
        raise ValueError(f"num_rays must be >= 1 and num_obstacles >= 0, got {num_rays} and {num_obstacles}")
    eligible = obstacle_cells(layout)
    if int(eligible.sum()) < num_obstacles:
        raise ValueError(f"the layout has {int(eligible.sum())} cells where a moving obstacle may start "
                         f"(free, 3 or more from the start, not the goal), fewer than num_obstacles={num_obstacles}")

    def point(cell) -> np.ndarray:
        return np.array([cell[1] + 0.5, cell[0] + 0.5], np.float32)

    items = np.stack([point(cell) for cell in layout.items])
    f32 = {k: jnp.asarray(v, jnp.float32) for k, v in settings.items() if k != "randomize"}
    params = ContinuousParams(
        **f32, max_steps=jnp.asarray(max_steps, jnp.int32), randomize=jnp.asarray(bool(settings["randomize"])),
        shelves=jnp.asarray(layout.shelves, bool), start=jnp.asarray(point(layout.start)),
        start_cell=jnp.asarray(layout.start, jnp.int32), goal=jnp.asarray(point(layout.goal)),
        goal_cell=jnp.asarray(layout.goal, jnp.int32), items=jnp.asarray(items),
        num_items=jnp.asarray(len(layout.items), jnp.int32), obstacle_cells=jnp.asarray(eligible))
    for flag, value in (("observe_target", observe_target), ("observe_route", observe_route),
                        ("observe_obstacles", observe_obstacles), ("safety_stop", safety_stop)):
        if not isinstance(value, (bool, np.bool_)):
            raise ValueError(f"{flag} must be True or False, got {value!r}")
    geodesic.check_route(shaping, observe_route)
    env = ContinuousWarehouse(params, num_rays=num_rays, num_obstacles=num_obstacles, name=name,
                              observe_target=bool(observe_target), observe_obstacles=bool(observe_obstacles),
                              safety_margin=stop_margin(safety_stop, safety_margin, num_rays),
                              escape_after=stop_escape(safety_stop, escape_after))
    return geodesic.with_fields(env, params, bool(observe_route)) if shaping == "geodesic" else (env, params)


def stop_margin(safety_stop: bool, margin: Any, num_rays: int) -> float | None:
    """The safety stop's margin (``None``: the stop is off), or a ``ValueError`` naming what is wrong.

    The default margin is measured for 32 rays (the gaps between rays shrink with more): with fewer, the
    margin must be given."""
    if margin is not None and (isinstance(margin, bool) or not isinstance(margin, (int, float, np.integer,
                                                                                   np.floating))
                               or not 0 <= float(margin) < 1):
        raise ValueError(f"safety_margin must be metres in [0, 1), got {margin!r}")
    if not safety_stop:
        if margin is not None:
            raise ValueError("safety_margin is the safety stop's: pass safety_stop=True with it (--safety-stop True)")
        return None
    if margin is None and num_rays < 32:
        raise ValueError(f"the safety stop's default margin ({SAFETY_MARGIN} m) covers the gaps between 32 rays or "
                         f"more; with num_rays={num_rays} pass a safety_margin of your own")
    return SAFETY_MARGIN if margin is None else float(margin)


def stop_escape(safety_stop: bool, escape_after: Any) -> int | None:
    """The safety stop's escape: ``None`` for ``None`` and ``0`` (so that a command line can turn a default off), a
    ``ValueError`` for an escape without the stop; the environment class checks the value itself."""
    if escape_after is None or (isinstance(escape_after, (int, np.integer)) and not isinstance(escape_after, bool)
                                and escape_after == 0):
        return None
    if not safety_stop:
        raise ValueError("escape_after is the safety stop's: pass safety_stop=True with it (--safety-stop True), or "
                         "escape_after=0 (--escape-after 0)")
    return escape_after


NAMED_MAPS = {"8x8": maps.WAREHOUSE_8X8, "12x12": maps.WAREHOUSE_12X12}
DYNAMIC_OBSTACLES = 4
"""Moving obstacles of the ``-Dynamic`` variants."""


def make_named(map_name: str, dynamic: bool = False, **overrides: Any) -> tuple[ContinuousWarehouse, ContinuousParams]:
    """The factory of ``Continuous-Warehouse-<map>[-Dynamic]-v0``: the study's map, its limit, 0 or 4 obstacles."""
    overrides.setdefault("num_obstacles", DYNAMIC_OBSTACLES if dynamic else 0)
    name = f"Continuous-Warehouse-{map_name}{'-Dynamic' if dynamic else ''}-v0"
    return make_continuous(NAMED_MAPS[map_name], name=name, **overrides)
