"""Training infrastructure every algorithm and environment family shares.

- :mod:`~wrl_jax.training.driver`: the chunked
  :class:`Trainer` and :func:`run` (progress, metrics, checkpoints, exact resume);
- :mod:`~wrl_jax.training.loop_config`: :class:`LoopConfig` (chunks, evaluation and logging cadence);
- :mod:`~wrl_jax.training.log_rows`: metric rows, progress text, convergence;
- :mod:`~wrl_jax.training.metrics_io`: JSONL/CSV/TensorBoard metrics and plots;
- :mod:`~wrl_jax.training.checkpoint`: atomic checkpoints;
- :mod:`~wrl_jax.training.sharding`, :mod:`~wrl_jax.training.sweep`: devices and sweeps.

The driver's public names and :class:`LoopConfig` are re-exported here (``wrl_jax.training.Trainer``...).
"""

from wrl_jax.training.driver import (
    LatestEval,
    RunResult,
    Trainer,
    final_evaluation,
    install_sigterm_handler,
    run,
    seed_keys,
)
from wrl_jax.training.log_rows import SUM_METRICS, Convergence
from wrl_jax.training.loop_config import LoopConfig

__all__ = [
    "SUM_METRICS",
    "Convergence",
    "LatestEval",
    "LoopConfig",
    "RunResult",
    "Trainer",
    "final_evaluation",
    "install_sigterm_handler",
    "run",
    "seed_keys",
]
