"""wrl_jax: warehouse-robot reinforcement learning in pure JAX.

``wrl_jax.make(name, **overrides) -> (env, params)`` builds any registered
environment (every family; also ``gymnax.make("wrl_jax/<name>")``); the names
are listed in :mod:`wrl_jax.envs`. Every environment is a gymnax 1.0
``Environment`` (:mod:`wrl_jax.core.environment`).
"""

# A multi-host run initializes JAX's distributed runtime before anything creates the backend
# (importing gymnax does): see wrl_jax/_distributed.py.
from wrl_jax import _distributed

_distributed.initialize_if_requested()

# Registration of every built-in name, with wrl_jax and with gymnax: one explicit place.
import wrl_jax.envs  # noqa: F401  (registers)
from wrl_jax.core.environment import Environment
from wrl_jax.core.registry import make, registered_names
from wrl_jax.envs.warehouse.env import ACTION_NAMES, NUM_ACTIONS, Warehouse, make_params
from wrl_jax.envs.warehouse.layout import Layout, optimal_route_lengths, parse
from wrl_jax.envs.warehouse.registration import make_from_layout
from wrl_jax.envs.warehouse.render import record_episode, render_ascii, render_frame, save_gif
from wrl_jax.envs.warehouse.types import EnvParams, EnvState
from wrl_jax.wrappers.legacy import LegacyStepAPI

# The module names the package had before the move (``wrl_jax.registry.spec(...)``, ``wrl_jax.env.Warehouse``...).
from wrl_jax import env, gym_env, layout, registry, render, routes, types  # noqa: E402,F401

# Registers the Gymnasium ids wrl_jax/Warehouse-8x8-v0 and wrl_jax/Warehouse-12x12-v0.
from wrl_jax.wrappers.gymnasium import WarehouseGymEnv, WarehouseVectorEnv  # noqa: E402

__all__ = [
    "ACTION_NAMES",
    "NUM_ACTIONS",
    "EnvParams",
    "EnvState",
    "Environment",
    "LegacyStepAPI",
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
