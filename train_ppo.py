"""Train PPO on a warehouse environment: ``python train_ppo.py --help`` lists every flag.

Defaults: Warehouse-12x12-v0, the tuned ``default`` preset, 4 seeds at once.
``--preset paper`` runs the study's Table 2 setting. See docs/ppo.md.
"""

import importlib.util
import sys
from pathlib import Path


def apply_xla_settings() -> None:
    """The command's XLA settings (``--xla-opt-level``, wrl_jax/cli/machine.py) into ``XLA_FLAGS`` before
    JAX starts: importing wrl_jax starts it, and XLA reads ``XLA_FLAGS`` only then. machine.py is loaded
    by its path for that reason (importing it as ``wrl_jax.cli.machine`` would import the package).
    train_dqn.py calls it too."""
    path = Path(__file__).resolve().parent / "wrl_jax" / "cli" / "machine.py"
    spec = importlib.util.spec_from_file_location("_wrl_jax_machine", path)
    machine = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(machine)
    machine.apply_for_command(sys.argv[1:])


if __name__ == "__main__":
    apply_xla_settings()
    from wrl_jax.cli import main

    sys.exit(main("ppo"))
