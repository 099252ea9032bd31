"""RWARE: rware 2.0.0's multi-robot warehouse (the MARL benchmark) in JAX, step for step.

``wrl_jax.make("rware-tiny-4ag-v2")`` (every id ``import rware`` registers) or
:func:`make_rware` for rware's other settings. Modules: ``types`` (state, params, codes),
``layout`` (floor plans), ``conflicts`` (the move graph), ``dynamics`` (reset, the step
deterministic in its replacement draws), ``observation`` (the flattened vector and the dict),
``observation_image`` (the image types), ``env`` (the JAX environment), ``registration`` (factories),
``convert`` (from a live rware ``Warehouse``), ``evaluation`` (the training hook), ``scripted`` (a
scripted team, the yardstick).
The rules, read from rware's source, are in bench/results/rware/NOTES.md.
"""

from wrl_jax.envs.rware.convert import env_from_rware, from_rware, rware_arrays, state_arrays
from wrl_jax.envs.rware.dynamics import draw_replacements, draw_reset, rware_reset, rware_transition
from wrl_jax.envs.rware.env import Rware
from wrl_jax.envs.rware.layout import RwareLayout, layout_from_params, parse_layout
from wrl_jax.envs.rware.registration import make_named, make_rware, registered_ids
from wrl_jax.envs.rware.types import RwareParams, RwareState

__all__ = [
    "Rware", "RwareLayout", "RwareParams", "RwareState", "draw_replacements", "draw_reset", "env_from_rware",
    "from_rware", "layout_from_params", "make_named", "make_rware", "parse_layout", "registered_ids",
    "rware_arrays", "rware_reset", "rware_transition", "state_arrays",
]
