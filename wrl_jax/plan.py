"""``python -m wrl_jax.plan --planner {greedy,pibt} --env Fleet-12x12-v0 --num-robots K --episodes E --json OUT``,
``--planner pursuit --env Continuous-Warehouse-12x12-Dynamic-v0``, or ``--planner scripted --env rware-tiny-4ag-v2``.

Runs a classical fleet planner (throughput), the continuous warehouse's pure-pursuit controller
(delivery, collisions, steps against the yardstick) or RWARE's scripted team (team return); see
:mod:`wrl_jax.cli.plan`.
"""

import sys

if __name__ == "__main__":
    from wrl_jax.cli import machine  # imports no JAX

    machine.apply_for_command(sys.argv[1:])  # XLA's flags before JAX starts
    from wrl_jax.cli.plan import main

    sys.exit(main())
