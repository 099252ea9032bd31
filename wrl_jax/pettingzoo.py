"""PettingZoo adapters: ``wrl_jax.pettingzoo.parallel_env(name="Fleet-12x12-v0", num_robots=4)``.

The implementation is :mod:`wrl_jax.wrappers.pettingzoo` (needs the ``pettingzoo`` package).
"""

from wrl_jax.wrappers.pettingzoo import FleetParallelEnv, parallel_env

__all__ = ["FleetParallelEnv", "parallel_env"]
