"""The command lines, one module per job; the only package that reads ``sys.argv``.

- :mod:`~wrl_jax.cli.options`: flags, presets, validation, config (de)serialization;
- :mod:`~wrl_jax.cli.train`: ``train_ppo.py`` / ``train_dqn.py`` (``main(algo)``);
- :mod:`~wrl_jax.cli.evaluate`: ``python -m wrl_jax.evaluate``;
- :mod:`~wrl_jax.cli.plan`: ``python -m wrl_jax.plan`` (the fleet's classical planners, the continuous pursuit controller);
- :mod:`~wrl_jax.cli.sweep`: ``python -m wrl_jax.sweep``;
- :mod:`~wrl_jax.cli.machine`: the process's start-up (XLA's flags, distributed JAX), CPU facts.

This package imports nothing, so a command can import :mod:`~wrl_jax.cli.machine` and set
XLA's flags before JAX starts.
"""
