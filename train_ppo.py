"""Train PPO on a warehouse environment: ``python train_ppo.py --help`` lists every flag.

Defaults: Warehouse-12x12-v0, the tuned ``default`` preset, 4 seeds at once.
``--preset paper`` runs the study's Table 2 setting. See docs/ppo.md.
"""

import sys

if __name__ == "__main__":
    from wrl_jax.cli import machine  # imports no JAX

    # XLA's flags, host devices and distributed JAX, before JAX starts
    argv = machine.apply_for_command(sys.argv[1:], choose_devices=True)
    from wrl_jax.cli.train import main

    sys.exit(main("ppo", argv))
