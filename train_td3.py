"""Train TD3 on a continuous warehouse: ``python train_td3.py --help`` lists every flag.

Defaults: Continuous-Warehouse-12x12-v0, the ``default`` preset (800k steps, the actor's preactivation
penalty 0.001) on every id, 4 seeds at once.
See docs/continuous.md.
"""

import sys

if __name__ == "__main__":
    from wrl_jax.cli import machine  # imports no JAX

    # XLA's flags, host devices (one per core that divides the seeds) and distributed JAX, before JAX starts
    argv = machine.apply_for_command(sys.argv[1:], choose_devices=True, algo="td3")
    from wrl_jax.cli.train import main

    sys.exit(main("td3", argv))
