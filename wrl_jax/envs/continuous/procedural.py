"""The procedural continuous warehouse (issue 34): CONTINUOUS_SPEC.md's MDP on generated layouts.

``Continuous-Procedural-Warehouse-v0`` (:func:`make_continuous_procedural`). A pool of layouts from the
procedural family's generators (:mod:`wrl_jax.envs.procedural.generators`, training key stream of
``seed``) is made once and stacked in params; ``reset`` draws a slot (one ``randint``, then a gather per
layout field), the state remembers it (``layout_index``), and every transition reads that slot's
arrays. Everything else is the continuous core unchanged (:mod:`~wrl_jax.envs.continuous.dynamics`),
so a transition on slot ``k`` equals the plain environment's on layout ``k`` bit for bit (tested), and
the core's parity with the NumPy reference carries over. Why a pool: ``reset`` runs on every step
under auto-reset, so it must not generate; the pool is generated once, before anything compiles.

Decisions:

- **Sizes.** Real floors are drawn in ``min_shape..max_shape`` and padded to the static square
  ``max_shape`` with blocked cells, which the core reads as shelf squares: a smaller floor behaves as
  walled in at its edge (:mod:`~wrl_jax.envs.continuous.procedural_layouts`). One shape, so one
  program serves the pool; observations are normalized by ``max_shape`` (one frame for every layout),
  and a contact with the padding is flagged ``hit_shelf`` (not ``hit_wall``; the same penalty).
- **A fixed pool.** Not refreshed while training: an index in the state is enough, and a held-out set
  is checked against the pool's hashes alone (:meth:`training_layout_hashes`).
- **Episode length.** One ``max_steps`` for the pool, from ``max_shape``: ``25 (H + W) - 100``, the
  line through the contract's two fixed points (8x8: 300, 12x12: 500); 16x16 gives 700. One value,
  because gymnax consumers truncate at ``params.max_steps_in_episode``; a smaller floor has time to spare.
- **Randomization** is on by default (``randomize=True``): gains, noise, start jitter and heading.
- **The way around the shelves** (``shaping="geodesic"``, ``observe_route``; :class:`ProceduralRouteWarehouse`):
  every slot's distance fields are computed with the pool, on a lattice of :data:`ROUTE_RESOLUTION` points
  per metre, so the geodesic shaping and the route work on every layout as on a fixed map.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.continuous import geodesic, procedural_evaluation
from wrl_jax.envs.continuous.dynamics import reset_core
from wrl_jax.envs.continuous.env import ContinuousWarehouse
from wrl_jax.envs.continuous.geometry import norm
from wrl_jax.envs.continuous.procedural_layouts import (
    ProceduralContinuousParams,
    ProceduralContinuousState,
    ProceduralGeodesicParams,
    layout_params,
    obstacle_mask,
    pool_fields,
    pool_size,
    slot_layout,
    with_layout_index,
)
from wrl_jax.envs.continuous.registration import DEFAULTS, make_continuous
from wrl_jax.envs.procedural.generators import GeneratorConfig
from wrl_jax.envs.procedural.pool import generate_pool, pool_hashes

NAME = "Continuous-Procedural-Warehouse-v0"
GENERATOR_FIELDS = ("family", "max_items", "min_items", "density", "gap_rate", "aisle", "shelf_mix",
                    "items_on_pick_faces", "min_reach", "max_attempts")
"""The :class:`GeneratorConfig` fields :func:`make_continuous_procedural` takes as overrides."""
MAX_POOL_SIZE = 2**16 - 1
ROUTE_RESOLUTION = 4
"""Lattice points per metre of the pool's distance fields (the fixed maps' 10 would take 1,024 layouts' fields
from about 90 MB to 540 MB and their computation from seconds to minutes). Even, so that cell centres are lattice
points. A rule that only follows the route at 4 per metre delivers every item of the pool's first 32 layouts
(without randomization, without a contact) in about 2 % more steps than at 10."""
_obstacle_masks = jax.jit(jax.vmap(obstacle_mask))


def default_max_steps(max_shape: tuple[int, int]) -> int:
    """``25 (H + W) - 100``: the contract's 300 steps at 8x8 and 500 at 12x12, linear in the side between."""
    return 25 * (int(max_shape[0]) + int(max_shape[1])) - 100


class ProceduralContinuousWarehouse(ContinuousWarehouse):
    """The continuous warehouse over a pool of layouts; build it with :func:`make_continuous_procedural`.

    Static configuration: the plain environment's (padded map, rays, obstacles, item slots) and the
    generator (what held-out layouts are drawn from). ``plain`` is the plain environment of the same
    shapes: given :func:`layout_params` of a slot, it runs that slot's episodes (the evaluation does).
    """

    def __init__(self, params: ProceduralContinuousParams, generator: GeneratorConfig, pool_seed: int = 0,
                 num_rays: int = 32, num_obstacles: int = 0, name: str = NAME, observe_target: bool = False,
                 observe_obstacles: bool = False, safety_margin: float | None = None,
                 escape_after: int | None = None):
        super().__init__(params, num_rays=num_rays, num_obstacles=num_obstacles, name=name,
                         observe_target=observe_target, observe_obstacles=observe_obstacles,
                         safety_margin=safety_margin, escape_after=escape_after)
        self.generator = generator
        self.pool_seed = int(pool_seed)
        self.plain = ContinuousWarehouse(params, num_rays=num_rays, num_obstacles=num_obstacles, name=name,
                                         observe_target=observe_target,
                                         observe_obstacles=observe_obstacles, safety_margin=safety_margin,
                                         escape_after=escape_after).without_default_params()

    def static_config(self) -> tuple:
        return (*super().static_config(), self.generator)

    def __repr__(self) -> str:
        return (f"ProceduralContinuousWarehouse({self.name}, {self.height}x{self.width} padded, "
                f"rays={self.num_rays}, obstacles={self.num_obstacles}, family={self.generator.family})")

    # ------------------------------------------------------------ the MDP on the episode's layout
    def reset_env(self, key: jax.Array, params: ProceduralContinuousParams):
        slot_key, episode_key = jax.random.split(key)
        index = jax.random.randint(slot_key, (), 0, pool_size(params), dtype=jnp.int32)
        return self.reset_to(index, episode_key, params)

    def reset_to(self, index: jax.Array, key: jax.Array, params: ProceduralContinuousParams):
        """A fresh episode on pool slot ``index``: the plain environment's reset on that layout, from ``key``."""
        layout = layout_params(params, index)
        obs, state = reset_core(self.reset_draws(key, layout), layout)
        return self.observation(obs, state, None, layout), with_layout_index(state, index)

    def transition(self, key: jax.Array, state: ProceduralContinuousState, action: Any,
                   params: ProceduralContinuousParams):
        self.check_action(action)
        layout = layout_params(params, state.layout_index)
        obs, reached, reward, terminated, truncated, info = self.contract_step(key, state, action, layout)
        return self.observation(obs, reached, info, layout), reached, reward, terminated, truncated, info

    def is_terminated(self, state: ProceduralContinuousState, params: ProceduralContinuousParams) -> jax.Array:
        goal = layout_params(params, state.layout_index).goal
        return state.carrying & (norm(state.pos - goal) <= params.reach_radius)

    def episode_params(self, state: ProceduralContinuousState,
                       params: ProceduralContinuousParams) -> ProceduralContinuousParams:
        """The params of ``state``'s own layout: what rendering or a controller should read (not slot 0)."""
        return layout_params(params, state.layout_index)

    # ------------------------------------------------------------ the family's evaluation hook
    def evaluation_episodes(self, act, params: ProceduralContinuousParams):
        """The periodic evaluation's episodes (:func:`procedural_evaluation.evaluate_pool_sample`)."""
        return procedural_evaluation.evaluate_pool_sample(act, self, params)

    def generalization_report(self, context) -> dict[str, Any]:
        """After training: held-out and out-of-distribution layouts (:func:`procedural_evaluation.final_report`)."""
        return procedural_evaluation.final_report(context)

    def training_layout_hashes(self, params: ProceduralContinuousParams) -> np.ndarray:
        """uint64 hashes of the pool (fixed while training): what a held-out set must not contain."""
        return pool_hashes(params.pool)


class ProceduralRouteWarehouse(ProceduralContinuousWarehouse):
    """The procedural warehouse with geodesic shaping and, under ``observe_route``, the route, on every slot.

    What :class:`~wrl_jax.envs.continuous.geodesic.GeodesicShaping` is to a fixed map: each pool slot has
    its distance fields (``params.pool_fields``, :func:`~.procedural_layouts.pool_fields`), and a transition
    on slot ``k`` is the geodesic plain environment's on that slot's params (``plain``, which the evaluation
    runs). Build it with ``make_continuous_procedural(shaping="geodesic", observe_route=...)``.
    """

    def __init__(self, params: ProceduralGeodesicParams, generator: GeneratorConfig, pool_seed: int = 0,
                 num_rays: int = 32, num_obstacles: int = 0, name: str = NAME, observe_target: bool = False,
                 observe_obstacles: bool = False, safety_margin: float | None = None, observe_route: bool = False,
                 escape_after: int | None = None):
        super().__init__(params, generator, pool_seed=pool_seed, num_rays=num_rays, num_obstacles=num_obstacles,
                         name=name, observe_target=observe_target, observe_obstacles=observe_obstacles,
                         safety_margin=safety_margin, escape_after=escape_after)
        self.observe_route = bool(observe_route)
        self.plain = geodesic.GeodesicShaping(params, num_rays=num_rays, num_obstacles=num_obstacles, name=name,
                                              observe_target=observe_target, observe_route=observe_route,
                                              observe_obstacles=observe_obstacles, safety_margin=safety_margin,
                                              escape_after=escape_after).without_default_params()

    def static_config(self) -> tuple:
        return (*super().static_config(), self.observe_route)

    @property
    def obs_size(self) -> int:
        return super().obs_size + (geodesic.ROUTE_FEATURES if self.observe_route else 0)

    def observation_space(self, params: ProceduralGeodesicParams | None = None):
        return geodesic.route_space(super().observation_space(params), self.observe_route)

    def __repr__(self) -> str:
        return super().__repr__()[:-1] + f", geodesic shaping, route={'on' if self.observe_route else 'off'})"

    def reset_to(self, index: jax.Array, key: jax.Array, params: ProceduralGeodesicParams):
        obs, state = super().reset_to(index, key, params)
        return geodesic.with_route(obs, layout_params(params, index), self.width, self.height,
                                   self.observe_route), state

    def transition(self, key: jax.Array, state: ProceduralContinuousState, action: Any,
                   params: ProceduralGeodesicParams):
        obs, reached, reward, terminated, truncated, info = super().transition(key, state, action, params)
        layout = layout_params(params, state.layout_index)
        obs = geodesic.with_route(obs, layout, self.width, self.height, self.observe_route)
        return obs, reached, reward + geodesic.shaping_change(state, reached, layout, self.width), terminated, \
            truncated, info


def _check_int(name: str, value: Any, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low or (
            high is not None and value > high):
        bound = f"in {low}..{high}" if high is not None else f">= {low}"
        raise ValueError(f"{name} must be an integer {bound}, got {value!r}")
    return int(value)


def _shape(name: str, value: Any) -> tuple[int, int]:
    if not (isinstance(value, (tuple, list)) and len(value) == 2 and all(
            isinstance(n, (int, np.integer)) and not isinstance(n, bool) for n in value)):
        raise ValueError(f"{name} must be two integers (rows, cols), got {value!r}")
    return int(value[0]), int(value[1])


def make_continuous_procedural(*, seed: int = 0, pool_size: int = 1024, max_shape: tuple[int, int] = (12, 12),
                               min_shape: tuple[int, int] = (8, 8), num_rays: int = 32, num_obstacles: int = 0,
                               max_steps: int | None = None, randomize: bool = True, name: str = NAME,
                               observe_target: bool = False, observe_obstacles: bool = False,
                               safety_stop: bool = False, safety_margin: float | None = None,
                               escape_after: int | None = None, shaping: str = "manhattan", observe_route: bool = False,
                               route_resolution: int = ROUTE_RESOLUTION,
                               **overrides: Any) -> tuple[ProceduralContinuousWarehouse, ProceduralContinuousParams]:
    """``(env, params)``: ``pool_size`` generated layouts of ``min_shape..max_shape`` from ``seed``.

    Overrides: any other :class:`GeneratorConfig` field (``family`` ``"mixture"`` by default,
    ``max_items`` 8, ``density``...) and any constant of the contract (``make_continuous``'s, e.g.
    ``dt``, ``collision_penalty``). ``max_steps`` defaults to :func:`default_max_steps` of ``max_shape``.
    ``observe_target`` and ``observe_obstacles`` append the target and the moving obstacles seen from the robot,
    as on the plain environment; ``safety_stop`` turns on the safety stop (``escape_after``: its escape).
    ``shaping="geodesic"`` computes every pool slot's distance fields (``route_resolution`` lattice points per
    metre; about 10 s for 1,024 layouts of 12x12 at 4 on a 2-core CPU) for the geodesic shaping and, under
    ``observe_route``, the route (:class:`ProceduralRouteWarehouse`).

    Raises:
        ValueError: naming the setting: an unknown override, ``observe_route`` without geodesic shaping, a
            ``route_resolution`` that is not an even integer of 2 or more, a pool size outside 1..65535, a
            non-square ``max_shape`` (the contract's layouts are square), a bad generator range or
            contract constant, or a pool layout with fewer cells for moving obstacles than ``num_obstacles``.
    """
    if shaping not in ("manhattan", "geodesic"):
        raise ValueError(f"shaping must be 'manhattan' or 'geodesic' for {NAME}, got {shaping!r}")
    geodesic.check_route(shaping, observe_route)
    route_resolution = _check_int("route_resolution", route_resolution, 2)
    if route_resolution % 2:
        raise ValueError(f"route_resolution must be even (cell centres must be lattice points), got {route_resolution}")
    unknown = sorted(set(overrides) - set(GENERATOR_FIELDS) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"unknown option(s) {unknown} for {NAME}; known: generator fields "
                         f"{sorted(GENERATOR_FIELDS)} and contract settings {sorted(DEFAULTS)}")
    pool_size = _check_int("pool_size", pool_size, 1, MAX_POOL_SIZE)
    seed = _check_int("seed", seed, 0)
    num_obstacles = _check_int("num_obstacles", num_obstacles, 0)
    max_shape, min_shape = _shape("max_shape", max_shape), _shape("min_shape", min_shape)
    if max_shape[0] != max_shape[1]:
        raise ValueError(f"max_shape must be square (the contract's layouts are), got {max_shape}")
    generator_kwargs = {field: overrides.pop(field) for field in GENERATOR_FIELDS if field in overrides}
    for field in ("density", "gap_rate", "aisle"):
        if field in generator_kwargs:
            generator_kwargs[field] = tuple(generator_kwargs[field])
    generator = GeneratorConfig(max_shape=max_shape, min_shape=min_shape, **generator_kwargs)
    max_steps = default_max_steps(max_shape) if max_steps is None else max_steps
    pool = generate_pool(jax.random.key(seed), pool_size, generator)
    # The template checks and builds every contract constant from slot 0 (the layout fields are then the pool's)
    # and the safety stop's margin.
    template_env, template = make_continuous(slot_layout(pool.layouts, 0), max_steps=max_steps, num_rays=num_rays,
                                             num_obstacles=0, randomize=randomize, observe_target=observe_target,
                                             observe_obstacles=observe_obstacles, safety_stop=safety_stop,
                                             safety_margin=safety_margin, escape_after=escape_after, **overrides)
    eligible = _obstacle_masks(pool.layouts)
    if num_obstacles:
        counts = np.asarray(eligible.sum(axis=(1, 2)))
        short = np.flatnonzero(counts < num_obstacles)
        if short.size:
            raise ValueError(f"{short.size} of {pool_size} pool layouts have fewer cells where a moving obstacle "
                             f"may start than num_obstacles={num_obstacles} (the first: slot {int(short[0])}, "
                             f"{int(counts[short[0]])} cells); use fewer obstacles, a larger min_shape or another seed")
    fields = {field.name: getattr(template, field.name) for field in dataclasses.fields(template)}
    options = dict(pool_seed=seed, num_rays=num_rays, num_obstacles=num_obstacles, name=name,
                   observe_target=observe_target, observe_obstacles=observe_obstacles,
                   safety_margin=template_env.safety_margin, escape_after=template_env.escape_after)
    if shaping == "manhattan":
        params = layout_params(ProceduralContinuousParams(**fields, pool=pool.layouts, pool_obstacle_cells=eligible), 0)
        return ProceduralContinuousWarehouse(params, generator, **options), params
    distances = pool_fields(pool.layouts, template.robot_radius, route_resolution)
    params = layout_params(ProceduralGeodesicParams(**fields, pool=pool.layouts, pool_obstacle_cells=eligible,
                                                    fields=distances[0], pool_fields=distances), 0)
    return ProceduralRouteWarehouse(params, generator, observe_route=observe_route, **options), params
