"""The command lines, one module per job.

- :mod:`~wrl_jax.cli.options`: flags, presets, validation, config (de)serialization;
- :mod:`~wrl_jax.cli.train`: ``train_ppo.py`` / ``train_dqn.py`` (``main(algo)``);
- :mod:`~wrl_jax.cli.evaluate`: ``python -m wrl_jax.evaluate``;
- :mod:`~wrl_jax.cli.plan`: ``python -m wrl_jax.plan`` (the fleet's classical planners);
- :mod:`~wrl_jax.cli.machine`: XLA's CPU optimization level, CPU facts.

The sweep command is :mod:`wrl_jax.training.sweep` (``python -m wrl_jax.sweep``).
The names below are re-exported so ``from wrl_jax.cli import main`` keeps working.
"""

from wrl_jax.agents import ALGORITHM_MODULES, get_spec
from wrl_jax.cli.evaluate import evaluate_main, evaluate_run
from wrl_jax.cli.machine import DEFAULT_XLA_OPT_LEVEL, apply_xla_opt_level
from wrl_jax.cli.options import (
    Command,
    EnvOptions,
    RunOptions,
    build,
    config_from_dict,
    config_to_dict,
    parse,
    validate,
)
from wrl_jax.cli.train import main, report, train

__all__ = [
    "ALGORITHM_MODULES",
    "DEFAULT_XLA_OPT_LEVEL",
    "Command",
    "EnvOptions",
    "RunOptions",
    "apply_xla_opt_level",
    "build",
    "config_from_dict",
    "config_to_dict",
    "evaluate_main",
    "evaluate_run",
    "get_spec",
    "main",
    "parse",
    "report",
    "train",
    "validate",
]
