"""Train DQN on a warehouse environment: ``python train_dqn.py --help`` lists every flag.

Defaults: Warehouse-8x8-v0, the tuned ``default`` preset, 4 seeds at once.
``--preset paper`` runs the study's Table 2 setting and reports, per seed, the
first step at which the greedy policy delivers every item at the optimum.
See docs/dqn.md.
"""

import sys

if __name__ == "__main__":
    from train_ppo import apply_xla_settings  # the script's directory is on sys.path; it imports no JAX

    apply_xla_settings()
    from wrl_jax.cli import main

    sys.exit(main("dqn"))
