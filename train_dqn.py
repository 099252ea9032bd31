"""Train DQN on a warehouse environment: ``python train_dqn.py --help`` lists every flag.

Defaults: Warehouse-8x8-v0, the tuned ``default`` preset, 4 seeds at once.
``--preset paper`` runs the study's Table 2 setting and reports, per seed, the
first step at which the greedy policy delivers every item at the optimum.
See docs/dqn.md.
"""

import sys

if __name__ == "__main__":
    from wrl_jax.cli import machine  # imports no JAX

    machine.apply_for_command(sys.argv[1:])  # XLA's flags and distributed JAX, before JAX starts
    from wrl_jax.cli.train import main

    sys.exit(main("dqn"))
