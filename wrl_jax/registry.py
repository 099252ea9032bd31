"""Named environments: ``wrl_jax.make(name, **overrides) -> (env, params)``."""

from __future__ import annotations

import dataclasses

from wrl_jax import maps
from wrl_jax.env import Warehouse, make_params
from wrl_jax.layout import Layout, parse


@dataclasses.dataclass(frozen=True)
class EnvSpec:
    """A registered environment: its map and episode limit."""

    ascii_map: str
    max_steps: int

    @property
    def layout(self) -> Layout:
        return parse(self.ascii_map)


REGISTRY: dict[str, EnvSpec] = {
    "Warehouse-8x8-v0": EnvSpec(maps.WAREHOUSE_8X8, max_steps=150),
    "Warehouse-12x12-v0": EnvSpec(maps.WAREHOUSE_12X12, max_steps=300),
}


def registered_names() -> list[str]:
    return sorted(REGISTRY)


def spec(name: str) -> EnvSpec:
    if name not in REGISTRY:
        raise ValueError(f"unknown environment {name!r}; registered: {', '.join(registered_names())}")
    return REGISTRY[name]


def make(name: str, **overrides) -> tuple[Warehouse, object]:
    """Build a registered environment and its params.

    Overrides reach every reward constant (``step_penalty``, ``obstacle_penalty``,
    ``wall_penalty``, ``shaping_coef``, ``pickup_reward``, ``delivery_reward``),
    ``max_steps``, ``max_items``, and the two failure-mode switches
    ``observe_carrying`` (default True) and ``collision_bug`` (default False).

    Example:
        >>> env, params = make("Warehouse-8x8-v0", shaping_coef=0.0)
    """
    entry = spec(name)
    overrides.setdefault("max_steps", entry.max_steps)
    return make_from_layout(entry.layout, **overrides)


def make_from_layout(layout: Layout | str, *, max_steps: int, observe_carrying: bool = True, **overrides):
    """Build an environment for any layout (a :class:`Layout` or an ASCII map)."""
    if isinstance(layout, str):
        layout = parse(layout)
    params = make_params(layout, max_steps=max_steps, **overrides)
    env = Warehouse(layout.size, max_items=params.items.shape[0], observe_carrying=observe_carrying)
    return env, params
