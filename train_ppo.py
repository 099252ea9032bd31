"""Train PPO on a warehouse environment: ``python train_ppo.py --help`` lists every flag.

Defaults: Warehouse-12x12-v0, the tuned ``default`` preset, 4 seeds at once.
``--preset paper`` runs the study's Table 2 setting. See docs/ppo.md.
"""

import sys

if __name__ == "__main__":
    from wrl_jax.cli import machine  # imports no JAX

    machine.apply_for_command(sys.argv[1:])  # XLA's flags and distributed JAX, before JAX starts
    from wrl_jax.cli.train import main

    sys.exit(main("ppo"))
