"""The fleet family (FLEET_SPEC.md): several robots, lifelong pick-and-place, one shared shift.

``wrl_jax.core.registry.make("Fleet-12x12-v0", num_robots=4)`` or
:func:`make_fleet` for any layout. Modules: ``types`` (state, params),
``layout`` (parser), ``maps``, ``dynamics`` (the MDP's draw, transition, reset),
``conflicts`` (who moves), ``observation``, ``env`` (the JAX environment), ``reference`` (NumPy),
``render``, ``registration`` (factories), ``planners`` (greedy, PIBT),
``metrics`` (vmapped shifts, throughput against ``K / L*``).
"""

from wrl_jax.envs.fleet.dynamics import draw_tasks, fleet_reset, fleet_transition, targets
from wrl_jax.envs.fleet.env import Fleet
from wrl_jax.envs.fleet.layout import FleetLayout, parse_fleet
from wrl_jax.envs.fleet.observation import global_state
from wrl_jax.envs.fleet.registration import make_fleet, make_params
from wrl_jax.envs.fleet.types import FleetParams, FleetState, FleetTasks

__all__ = [
    "Fleet", "FleetLayout", "FleetParams", "FleetState", "FleetTasks", "draw_tasks", "fleet_reset",
    "fleet_transition", "global_state", "make_fleet", "make_params", "parse_fleet", "targets",
]
