"""The single-robot warehouse's named environments and its layout factory.

``wrl_jax.make(name, **overrides)`` (:mod:`wrl_jax.core.registry`) reaches
:func:`make_named` for the names :mod:`wrl_jax.envs` registers;
:func:`make_from_layout` builds the environment for any layout.
"""

from __future__ import annotations

import dataclasses

from wrl_jax.envs.warehouse import maps
from wrl_jax.envs.warehouse.env import Warehouse, make_params
from wrl_jax.envs.warehouse.layout import Layout, parse
from wrl_jax.envs.warehouse.types import EnvParams


@dataclasses.dataclass(frozen=True)
class EnvSpec:
    """A registered environment: its map and episode limit."""

    ascii_map: str
    max_steps: int

    @property
    def layout(self) -> Layout:
        return parse(self.ascii_map)


MAPS: dict[str, EnvSpec] = {
    "8x8": EnvSpec(maps.WAREHOUSE_8X8, max_steps=150),
    "12x12": EnvSpec(maps.WAREHOUSE_12X12, max_steps=300),
}

REGISTRY: dict[str, EnvSpec] = {f"Warehouse-{key}-v0": value for key, value in MAPS.items()}
"""The study's two maps by registered name (the warehouse family's names)."""


def registered_names() -> list[str]:
    """Every registered environment name, of every family."""
    from wrl_jax.core import registry

    return registry.registered_names()


def spec(name: str) -> EnvSpec:
    if name not in REGISTRY:
        known = ", ".join(sorted(REGISTRY))
        raise ValueError(f"unknown environment {name!r}; registered warehouse environments: {known}")
    return REGISTRY[name]


def make(name: str, **overrides):
    """Build any registered environment and its params (see :func:`wrl_jax.core.registry.make`).

    For the warehouse, overrides reach every reward constant (``step_penalty``,
    ``obstacle_penalty``, ``wall_penalty``, ``shaping_coef``, ``pickup_reward``,
    ``delivery_reward``), ``max_steps``, ``max_items``, and the two failure-mode
    switches ``observe_carrying`` (default True) and ``collision_bug`` (default False).

    Example:
        >>> env, params = make("Warehouse-8x8-v0", shaping_coef=0.0)
    """
    from wrl_jax.core import registry

    return registry.make(name, **overrides)


def make_named(map_name: str, **overrides) -> tuple[Warehouse, EnvParams]:
    """The factory of ``Warehouse-<map_name>-v0``: the study's map with its episode limit."""
    entry = MAPS[map_name]
    overrides.setdefault("max_steps", entry.max_steps)
    return make_from_layout(entry.layout, name=f"Warehouse-{map_name}-v0", **overrides)


def make_from_layout(
    layout: Layout | str, *, max_steps: int, observe_carrying: bool = True, name: str | None = None, **overrides
) -> tuple[Warehouse, EnvParams]:
    """Build an environment for any layout (a :class:`Layout` or an ASCII map): ``(env, params)``.

    ``env.default_params`` are the returned params, so gymnax-style code may omit them.
    """
    if isinstance(layout, str):
        layout = parse(layout)
    params = make_params(layout, max_steps=max_steps, **overrides)
    env = Warehouse(
        layout.size,
        max_items=params.items.shape[0],
        observe_carrying=observe_carrying,
        default_params=params,
        name=name,
    )
    return env, params
