"""``python -m wrl_jax.plan --planner {greedy,pibt} --env Fleet-12x12-v0 --num-robots K --episodes E --json OUT``.

Runs a classical fleet planner and reports its throughput; see :mod:`wrl_jax.cli.plan`.
"""

import sys

from wrl_jax.cli.plan import main

if __name__ == "__main__":
    sys.exit(main())
