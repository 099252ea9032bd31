"""wrl_jax: warehouse-robot reinforcement learning in pure JAX."""

from wrl_jax.env import ACTION_NAMES, NUM_ACTIONS, Warehouse, make_params
from wrl_jax.layout import Layout, optimal_route_lengths, parse
from wrl_jax.registry import make, make_from_layout, registered_names
from wrl_jax.types import EnvParams, EnvState
from wrl_jax.render import record_episode, render_ascii, render_frame, save_gif

# Registers the Gymnasium ids wrl_jax/Warehouse-8x8-v0 and wrl_jax/Warehouse-12x12-v0.
from wrl_jax.gym_env import WarehouseGymEnv, WarehouseVectorEnv  # noqa: E402

__all__ = [
    "ACTION_NAMES",
    "NUM_ACTIONS",
    "EnvParams",
    "EnvState",
    "Layout",
    "Warehouse",
    "WarehouseGymEnv",
    "WarehouseVectorEnv",
    "make",
    "make_from_layout",
    "make_params",
    "optimal_route_lengths",
    "parse",
    "record_episode",
    "registered_names",
    "render_ascii",
    "render_frame",
    "save_gif",
]
