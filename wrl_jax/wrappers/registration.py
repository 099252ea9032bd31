"""Gymnasium ids for the single-robot warehouses: ``gymnasium.make("wrl_jax/Warehouse-8x8-v0")``, and the
continuous ones (``"wrl_jax/Continuous-Warehouse-12x12-v0"``: :mod:`wrl_jax.wrappers.gymnasium_continuous`)
and rware's ids with rware's own API (``"wrl_jax/rware-tiny-4ag-v2"``: :mod:`wrl_jax.wrappers.rware_gymnasium`).

Registration stores entry-point strings only, so it imports Gymnasium and nothing of JAX;
``import wrl_jax`` calls it. The adapters themselves are :mod:`wrl_jax.wrappers.gymnasium`.
"""

from __future__ import annotations

import gymnasium as gym

from wrl_jax.core.registry import registered_names

GYM_NAMESPACE = "wrl_jax"
SINGLE_ENTRY = "wrl_jax.wrappers.gymnasium:WarehouseGymEnv"
VECTOR_ENTRY = "wrl_jax.wrappers.gymnasium_vector:WarehouseVectorEnv"
CONTINUOUS_ENTRY = "wrl_jax.wrappers.gymnasium_continuous:ContinuousGymEnv"
RWARE_ENTRY = "wrl_jax.wrappers.rware_gymnasium:RwareGymEnv"


def gym_id(name: str) -> str:
    """The Gymnasium id of a registered name: ``wrl_jax/<name>``."""
    return f"{GYM_NAMESPACE}/{name}"


def register_gymnasium_envs() -> list[str]:
    """Register the single-robot, continuous and rware environments with Gymnasium (idempotent); returns the ids.

    Both entry points are registered: ``gymnasium.make(id, **overrides)`` builds a
    ``WarehouseGymEnv``, ``gymnasium.make_vec(id, num_envs=n,
    vectorization_mode="vector_entry_point", **overrides)`` a ``WarehouseVectorEnv``.
    ``max_episode_steps`` stays None: the environment truncates at its own ``max_steps``.
    """
    ids = []
    for name in registered_names(family="warehouse"):
        env_id = gym_id(name)
        if env_id not in gym.registry:
            gym.register(
                id=env_id,
                entry_point=SINGLE_ENTRY,
                vector_entry_point=VECTOR_ENTRY,
                kwargs={"name": name},
                max_episode_steps=None,
                nondeterministic=False,
            )
        ids.append(env_id)
    for name in registered_names(family="continuous"):  # single environments (Box actions)
        env_id = gym_id(name)
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=CONTINUOUS_ENTRY, kwargs={"name": name}, max_episode_steps=None,
                         nondeterministic=False)
        ids.append(env_id)
    for name in registered_names(family="rware"):  # rware's API: Tuple spaces, a reward list, one done
        env_id = gym_id(name)
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=RWARE_ENTRY, kwargs={"name": name}, max_episode_steps=None,
                         nondeterministic=False)
        ids.append(env_id)
    return ids
