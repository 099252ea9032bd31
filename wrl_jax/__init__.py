"""wrl_jax: warehouse-robot reinforcement learning in pure JAX."""

from wrl_jax.env import ACTION_NAMES, NUM_ACTIONS, Warehouse, make_params
from wrl_jax.layout import Layout, optimal_route_lengths, parse
from wrl_jax.registry import make, make_from_layout, registered_names
from wrl_jax.types import EnvParams, EnvState

__all__ = [
    "ACTION_NAMES",
    "NUM_ACTIONS",
    "EnvParams",
    "EnvState",
    "Layout",
    "Warehouse",
    "make",
    "make_from_layout",
    "make_params",
    "optimal_route_lengths",
    "parse",
    "registered_names",
]
