"""``python -m wrl_jax.evaluate --run DIR``: evaluate a trained run's checkpoint (PPO or DQN).

Every seed's greedy policy on every item index; prints the Table-3-style table
(``--items`` adds the per-item table, ``--json FILE`` writes the full result).
``--layout PATH`` (repeatable) evaluates a procedural-warehouse run on map files instead.
"""

import sys

from wrl_jax.cli.evaluate import evaluate_main

if __name__ == "__main__":
    sys.exit(evaluate_main())
