"""Train PPO on a warehouse environment: ``python train_ppo.py --help`` lists every flag.

Defaults: Warehouse-12x12-v0, the tuned ``default`` preset, 4 seeds at once.
``--preset paper`` runs the study's Table 2 setting. See docs/ppo.md.
"""

import sys

from wrl_jax.cli import main

if __name__ == "__main__":
    sys.exit(main("ppo"))
