"""Environment families, one folder each, and the one place that names the built-in environments.

Each line registers a name with :mod:`wrl_jax.core.registry` (and so with
gymnax as ``"wrl_jax/<name>"``); the factory module is imported only when the
name is made.
"""

from wrl_jax.core.registry import register

register("Warehouse-8x8-v0", "wrl_jax.envs.warehouse.registration:make_named", family="warehouse",
         map_name="8x8")
register("Warehouse-12x12-v0", "wrl_jax.envs.warehouse.registration:make_named", family="warehouse",
         map_name="12x12")
register("Fleet-12x12-v0", "wrl_jax.envs.fleet.registration:make_named", family="fleet", map_name="12x12")
register("Fleet-32x32-v0", "wrl_jax.envs.fleet.registration:make_named", family="fleet", map_name="32x32")
