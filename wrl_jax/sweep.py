"""``python -m wrl_jax.sweep``: one compiled program for a grid of settings x seeds (:mod:`wrl_jax.cli.sweep`)."""

import sys

if __name__ == "__main__":
    from wrl_jax.cli import machine  # imports no JAX

    machine.apply_for_command(sys.argv[1:])  # XLA's flags before JAX starts
    from wrl_jax.cli.sweep import main

    sys.exit(main())
