"""``python -m wrl_jax.evaluate --run DIR``: evaluate a trained run's checkpoint (PPO or DQN).

Every seed's greedy policy on every item index; prints the Table-3-style table
(``--items`` adds the per-item table, ``--json FILE`` writes the full result).
``--layout PATH`` (repeatable) evaluates a procedural-warehouse run on map files instead.
"""

import sys

if __name__ == "__main__":
    from wrl_jax.cli import machine  # imports no JAX

    machine.apply_for_command(sys.argv[1:])  # XLA's flags before JAX starts
    from wrl_jax.cli.evaluate import evaluate_main

    sys.exit(evaluate_main())
