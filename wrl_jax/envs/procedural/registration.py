"""Factories of the procedural warehouse: ``wrl_jax.core.registry.make("Procedural-Warehouse-v0", ...)``.

:func:`make_procedural` generates the initial pool from ``seed`` (training key
stream, :func:`wrl_jax.envs.procedural.pool.stream_keys`);
:func:`make_from_layouts` builds the same environment over given layouts (the
study's maps, MovingAI maps), e.g. to evaluate a policy trained on generated
warehouses on the study's 12x12 map.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp

from wrl_jax.envs.procedural.env import ProceduralWarehouse
from wrl_jax.envs.procedural.generators import GeneratorConfig
from wrl_jax.envs.procedural.layout import PaddedLayout
from wrl_jax.envs.procedural.pool import LayoutPool, generate_pool, pool_from_layouts
from wrl_jax.envs.procedural.pool_params import pool_arrays
from wrl_jax.envs.procedural.types import ProceduralParams
from wrl_jax.envs.warehouse.types import REWARD_DEFAULTS

DEFAULT_MAX_STEPS = 300
"""Episode length (the study's 12x12 uses 300; a 16x16 route is at most a few dozen steps longer)."""

ENV_OPTIONS = ("seed", "pool_size", "pool_refresh", "max_shape", "view_radius", "observe_map", "observe_window",
               "observe_last_action", "observe_visited", "visit_levels", "observe_rays", "shaping", "max_steps")

GENERATOR_FIELDS = ("family", "min_shape", "max_items", "min_items", "density", "gap_rate", "aisle", "shelf_mix",
                    "items_on_pick_faces", "min_reach", "max_attempts")


def make_params(env: ProceduralWarehouse, pool: LayoutPool, *, max_steps: int = DEFAULT_MAX_STEPS,
                **rewards: float) -> ProceduralParams:
    """Params of ``env`` over ``pool`` with SPEC.md's reward constants, any of them overridden."""
    unknown = sorted(set(rewards) - set(REWARD_DEFAULTS))
    if unknown:
        raise ValueError(f"unknown reward parameter(s) {unknown}; known: {sorted(REWARD_DEFAULTS)}")
    if int(max_steps) < 1:
        raise ValueError(f"max_steps must be a positive integer, got {max_steps}")
    values = {**REWARD_DEFAULTS, **rewards}
    walls, reset_obs, distances = pool_arrays(env, pool)
    return ProceduralParams(
        pool=pool,
        walls=walls,
        reset_obs=reset_obs,
        distances=distances,
        max_steps=jnp.asarray(int(max_steps), dtype=jnp.int32),
        **{name: jnp.asarray(value, dtype=jnp.float32) for name, value in values.items()},
    )


def make_procedural(*, seed: int = 0, pool_size: int = 1024, pool_refresh: int = 0,
                    max_shape: tuple[int, int] = (16, 16), view_radius: int = 2, observe_map: bool = False,
                    observe_window: bool = True, observe_last_action: bool = False, observe_visited: bool = False,
                    visit_levels: int = 1, observe_rays: bool = False, shaping: str = "manhattan",
                    max_steps: int = DEFAULT_MAX_STEPS, **overrides) -> tuple[ProceduralWarehouse, ProceduralParams]:
    """``(env, params)``: a pool of ``pool_size`` generated layouts, drawn from ``seed``.

    ``pool_refresh``: slots a learner renews before every update, from the same seed's
    training stream (:meth:`ProceduralWarehouse.params_for_update`; 0: a fixed pool).
    ``observe_last_action``: the previous action, one-hot, in the observation; ``observe_visited``:
    the window's cells visited since the current target was set (``visit_levels``: counted up to
    that many visits); ``observe_rays``: the free runs from the robot up, down, left and right;
    ``shaping``: ``"manhattan"`` (SPEC.md) or ``"bfs"`` (the reward's shaping by shortest paths).

    Overrides: any :class:`GeneratorConfig` field (``family``, ``min_shape``,
    ``max_items``, ``density``, ...), ``max_steps`` and SPEC.md's reward constants.
    """
    generator_kwargs = {name: overrides.pop(name) for name in GENERATOR_FIELDS if name in overrides}
    for name in ("min_shape", "density", "gap_rate", "aisle"):
        if name in generator_kwargs:
            generator_kwargs[name] = tuple(generator_kwargs[name])
    unknown = sorted(set(overrides) - set(REWARD_DEFAULTS))
    if unknown:
        known = sorted((*GENERATOR_FIELDS, *REWARD_DEFAULTS, *ENV_OPTIONS))
        raise ValueError(f"unknown option(s) {unknown} for Procedural-Warehouse-v0; known: {known}")
    generator = GeneratorConfig(max_shape=tuple(max_shape), **generator_kwargs)
    if not 1 <= int(pool_size) <= 2**16 - 1:
        raise ValueError(f"pool_size must be in 1..65535, got {pool_size}")
    pool = generate_pool(jax.random.key(int(seed)), int(pool_size), generator)
    env = ProceduralWarehouse(generator=generator, pool_size=int(pool_size), view_radius=view_radius,
                              observe_map=observe_map, observe_window=observe_window, pool_seed=int(seed),
                              pool_refresh=int(pool_refresh), observe_last_action=observe_last_action,
                              observe_visited=observe_visited, visit_levels=visit_levels,
                              observe_rays=observe_rays, shaping=shaping)
    params = make_params(env, pool, max_steps=max_steps, **overrides)
    env.check_params(params)
    return env.with_default_params(params), params


def make_from_layouts(layouts: Sequence[PaddedLayout], *, pool_size: int | None = None, view_radius: int = 2,
                      observe_map: bool = False, observe_window: bool = True, observe_last_action: bool = False,
                      observe_visited: bool = False, visit_levels: int = 1, observe_rays: bool = False,
                      shaping: str = "manhattan", max_steps: int = DEFAULT_MAX_STEPS, generator: GeneratorConfig | None = None,
                      **rewards: float) -> tuple[ProceduralWarehouse, ProceduralParams]:
    """``(env, params)`` over given layouts (all of one padded shape), cycled to ``pool_size`` slots.

    ``generator`` is what :meth:`ProceduralWarehouse.refresh_pool` would draw
    from; by default a mixture of the layouts' shape and item capacity.
    """
    pool = pool_from_layouts(layouts, pool_size)
    shape = tuple(pool.layouts.blocked.shape[-2:])
    max_items = int(pool.layouts.items.shape[-2])
    if generator is None:
        generator = GeneratorConfig(max_shape=shape, min_shape=shape, max_items=max_items,
                                    min_items=min(max_items, 1))
    env = ProceduralWarehouse(generator=generator, pool_size=pool.size, view_radius=view_radius,
                              observe_map=observe_map, observe_window=observe_window,
                              observe_last_action=observe_last_action, observe_visited=observe_visited,
                              visit_levels=visit_levels, observe_rays=observe_rays, shaping=shaping)
    params = make_params(env, pool, max_steps=max_steps, **rewards)
    env.check_params(params)
    return env.with_default_params(params), params
