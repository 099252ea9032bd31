"""Procedural warehouses: layouts generated inside ``jit``, always solvable, served from pools.

- :mod:`.layout`: the padded layout pytree, flood fill, JAX BFS optimum, hashing, conversion.
- :mod:`.generators`: shelf-block, random-obstacle and mixture generators (``key -> layout``).
- :mod:`.pool`: layout pools in params, refresh between updates, held-out streams.
- :mod:`.movingai`: MovingAI ``.map`` files and ASCII maps into layouts.
- :mod:`.env`: ``ProceduralWarehouse``, SPEC.md's MDP on a per-environment layout.
- :mod:`.registration`: the factories behind ``Procedural-Warehouse-v0``.
- :mod:`.evaluation`: the family's evaluation hook (held-out layouts in training, the final
  generalization report on held-out and out-of-distribution sets, evaluation on map files).
- :mod:`.render`: layout pictures and recorded episodes.

docs/procedural.md explains the design and its measurements.
"""

from wrl_jax.envs.procedural.env import ProceduralWarehouse
from wrl_jax.envs.procedural.generators import (
    GeneratorConfig,
    generate,
    generate_batch,
    mixture,
    random_obstacles,
    shelf_blocks,
)
from wrl_jax.envs.procedural.layout import (
    PaddedLayout,
    from_layout,
    is_solvable,
    layout_hash,
    optimal_route_lengths,
    to_numpy_layout,
)
from wrl_jax.envs.procedural.movingai import load_map, movingai_layout, parse_movingai
from wrl_jax.envs.procedural.pool import (
    LayoutPool,
    bytes_per_layout,
    disjoint_from,
    generate_pool,
    pool_from_keys,
    pool_from_layouts,
    refresh_pool,
)
from wrl_jax.envs.procedural.registration import make_from_layouts, make_procedural
from wrl_jax.envs.procedural.types import ProceduralParams, ProceduralState

__all__ = [
    "GeneratorConfig", "LayoutPool", "PaddedLayout", "ProceduralParams", "ProceduralState",
    "ProceduralWarehouse", "bytes_per_layout", "disjoint_from", "from_layout", "generate", "generate_batch",
    "generate_pool", "is_solvable", "layout_hash", "load_map", "make_from_layouts", "make_procedural",
    "mixture", "movingai_layout", "optimal_route_lengths", "parse_movingai", "pool_from_keys",
    "pool_from_layouts", "random_obstacles", "refresh_pool", "shelf_blocks", "to_numpy_layout",
]
