"""Variants x seeds in one compiled program: the runner the experiments and the sweep share.

A *batch* is a list of seeds, one runner each, with optional per-runner traced
hyperparameters and environment params (leaves with a leading axis of
``len(seeds)``): the grid points of a sweep, or the variants of an experiment
(reward settings, failure modes), each repeated over the same seeds. One
:class:`~wrl_jax.training.driver.Trainer` trains the whole batch (sharded over a
device mesh if one is given), then the environment family's hook evaluates
every runner's greedy policy.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from typing import Any

import jax

from wrl_jax.agents.base import Algorithm
from wrl_jax.training import driver
from wrl_jax.training.loop_config import LoopConfig


@dataclasses.dataclass
class BatchRun:
    """What :func:`train_batch` returns.

    Attributes:
        trainer: the trainer (its ``evaluation`` is the family hook, its ``seeds`` the batch).
        result: the driver's :class:`~wrl_jax.training.driver.RunResult`.
        episodes: the final evaluation of every runner (leaves ``(len(seeds), ...)``).
        init_seconds: building the batched runner state.
        eval_seconds: the final evaluation (zero extra compile when the last update evaluated).
    """

    trainer: driver.Trainer
    result: driver.RunResult
    episodes: Any
    init_seconds: float
    eval_seconds: float


def train_batch(
    algo: Algorithm,
    seeds: Sequence[int],
    *,
    hyper: Any = None,
    env_params: Any = None,
    loop: LoopConfig | None = None,
    mesh: Any = None,
) -> BatchRun:
    """Train one runner per entry of ``seeds`` in one program and evaluate them all.

    Args:
        algo: the algorithm (its ``env`` fixes shapes and the family).
        seeds: one seed per runner (repeats allowed: the same seeds for every variant).
        hyper, env_params: ``None`` for the algorithm's own, or batched pytrees.
        loop: chunking and evaluation cadence (default: no progress bar).
        mesh: a device mesh (:func:`wrl_jax.training.sharding.make_mesh`) to shard the batch over.
    """
    loop = loop or LoopConfig(progress=False)
    if mesh is None:
        trainer = driver.Trainer(algo, seeds, loop)
    else:
        from wrl_jax.training import sharding

        trainer = sharding.ShardedTrainer(algo, seeds, loop, mesh)
    t0 = time.perf_counter()
    runners = trainer.init(hyper=hyper, env_params=env_params)
    jax.block_until_ready(runners)
    init_seconds = time.perf_counter() - t0
    result = driver.run(trainer, None, runners=runners)
    t0 = time.perf_counter()
    episodes = driver.final_evaluation(trainer, result)
    jax.block_until_ready(episodes)
    eval_seconds = time.perf_counter() - t0
    return BatchRun(trainer, result, episodes, init_seconds, eval_seconds)
