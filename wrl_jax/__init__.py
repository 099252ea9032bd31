"""wrl_jax: warehouse-robot reinforcement learning in pure JAX.

``wrl_jax.make(name, **overrides) -> (env, params)`` builds any registered
environment (``wrl_jax.registered_names()``; the list is :mod:`wrl_jax.envs`).
Every environment is a gymnax 1.0 ``Environment`` (:mod:`wrl_jax.core.environment`).

``import wrl_jax`` registers the built-in names (with wrl_jax, Gymnasium, and gymnax
now if it is loaded, else when it is imported) and does nothing else: it imports
neither JAX nor gymnax, so a command can still set XLA's flags or start distributed
JAX after it.
The other names below load their modules on first use.
"""

import importlib

import wrl_jax.envs  # noqa: F401  (registers the built-in names)
from wrl_jax.core.registry import make, register_with_gymnax, registered_names  # noqa: F401  (in __all__)
from wrl_jax.core.registry import register_with_gymnax_when_imported
from wrl_jax.wrappers.registration import register_gymnasium_envs

register_gymnasium_envs()
register_with_gymnax_when_imported()  # now if gymnax is loaded, else when it is imported

# Public name -> the module that defines it, imported on first access (PEP 562).
_LAZY = {
    "Environment": "wrl_jax.core.environment",
    "ACTION_NAMES": "wrl_jax.envs.warehouse.env",
    "NUM_ACTIONS": "wrl_jax.envs.warehouse.env",
    "Warehouse": "wrl_jax.envs.warehouse.env",
    "make_params": "wrl_jax.envs.warehouse.env",
    "EnvParams": "wrl_jax.envs.warehouse.types",
    "EnvState": "wrl_jax.envs.warehouse.types",
    "Layout": "wrl_jax.envs.warehouse.layout",
    "optimal_route_lengths": "wrl_jax.envs.warehouse.layout",
    "parse": "wrl_jax.envs.warehouse.layout",
    "make_from_layout": "wrl_jax.envs.warehouse.registration",
    "record_episode": "wrl_jax.envs.warehouse.render",
    "render_ascii": "wrl_jax.envs.warehouse.render",
    "render_frame": "wrl_jax.envs.warehouse.render",
    "save_gif": "wrl_jax.envs.warehouse.render",
    "LegacyStepAPI": "wrl_jax.wrappers.legacy",
    "WarehouseGymEnv": "wrl_jax.wrappers.gymnasium",
    "WarehouseVectorEnv": "wrl_jax.wrappers.gymnasium_vector",
}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'wrl_jax' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = sorted(["make", "register_with_gymnax", "registered_names", *_LAZY])
