"""The training driver shared by every algorithm (PPO, DQN, SAC, TD3).

Two shapes of the same loop:

- :func:`~wrl_jax.agents.base.make_train` / ``make_train_seeds``: PureJaxRL's shape, beside the
  algorithm contract. ``train(key)`` is ``init`` followed by one ``lax.scan`` of ``update`` over all
  updates, a single pure function to ``jit`` (and ``vmap`` over seeds or sweep points).
- :class:`Trainer` and :func:`run`: the same updates for a batch of seeds, cut
  into *chunks*: one jitted function scans a fixed number of updates (compiled
  once, ahead of time, so compile time is measured apart), and a Python loop
  over chunks updates the progress bar, appends metrics, evaluates, and
  checkpoints. The chunk size changes nothing but how often the host looks:
  updates past the end of training inside the last chunk are skipped by a
  ``lax.cond`` on the (unbatched) update index, so any chunk size gives
  bit-identical parameters and metrics, and a run resumed from any chunk
  boundary finishes exactly like one that never stopped.

Periodic greedy evaluation runs *inside* the compiled chunk, every
``eval_every`` updates and after the last one (a ``lax.cond`` on the update
index, so it costs nothing on the other updates): the greedy policy of every
seed, evaluated by the environment family's hook
(:mod:`wrl_jax.core.evaluation`). Its per-seed results become ``eval_*`` metrics,
and the first update at which a seed *solves* the task (the hook's ``solved_key``)
gives that seed's *convergence step*.

Metric rows, the progress text and convergence are :mod:`~wrl_jax.training.log_rows`.

Why one module of this length: :class:`Trainer` and :func:`run` are one loop
that must stay bit-identical to ``make_train`` (tested for PPO; the off-policy learners' two programs
fuse differently and agree to float rounding), and read best side by side.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from wrl_jax.agents.base import Algorithm, config_to_dict
from wrl_jax.core import evaluation as family_evaluation
from wrl_jax.core.tracing import traced_once
from wrl_jax.training import checkpoint, metrics_io
from wrl_jax.training.loop_config import LoopConfig
from wrl_jax.training.log_rows import Convergence, metric_rows
from wrl_jax.training.log_rows import describe as describe_rows


def seed_keys(seeds: Sequence[int]) -> jax.Array:
    """One PRNG key per seed value: seed ``s`` gets ``PRNGKey(s)`` whatever batch it trains in."""
    if len(seeds) == 0:
        raise ValueError("at least one seed is needed")
    return jnp.stack([jax.random.PRNGKey(int(s)) for s in seeds])


# -------------------------------------------------------------------- Trainer
@struct.dataclass
class LatestEval:
    """The most recent in-training evaluation: after ``update`` updates (0: none yet)."""

    update: jax.Array
    episodes: Any  # the family's evaluation result, leaves (seeds, ...)


class Trainer:
    """A batch of seeds of one algorithm, trained chunk by chunk.

    Args:
        algo: the algorithm (one seed's ``init``/``update``).
        seeds: seed values, one runner each (repeats are allowed, e.g. the same
            seed at several sweep points).
        loop: chunking, evaluation and logging settings.
    """

    def __init__(self, algo: Algorithm, seeds: Sequence[int], loop: LoopConfig | None = None):
        self.algo = algo
        self.seeds = [int(s) for s in seeds]
        if not self.seeds:
            raise ValueError("at least one seed is needed")
        self.num_updates = int(algo.num_updates)
        if self.num_updates < 1:
            raise ValueError(f"{algo.name}: the run has no update (num_updates={self.num_updates})")
        self.loop = (loop or LoopConfig()).resolve(self.num_updates)
        self.steps_per_update = int(algo.steps_per_update)
        self._chunk_jit = jax.jit(self._chunk)
        self._compiled = None
        self._compiled_signature = None
        self.evaluation = family_evaluation.for_env(algo.env)
        # One jitted evaluation, traced once per runner shapes: the loop's evaluations call it inside the chunk, the
        # empty evaluation takes its shapes and ``evaluate`` runs it, from the same trace (the fleet's, with PIBT
        # inside, takes seconds to trace).
        self._evaluate_jit = jax.jit(self._evaluate)
        self._eval_jit = self._evaluate_jit
        # One jitted init per batching of (hyper, env_params), and the evaluation's shapes per runner
        # signature: a trainer run again (a resume, a sweep's points) neither retraces nor recompiles them.
        self._init_jits: dict[tuple[bool, bool], Any] = {}
        self._eval_shapes: dict[tuple, Any] = {}

    # ---------------------------------------------------------------- init
    def init(self, hyper: Any = None, env_params: Any = None) -> Any:
        """Batched runner state, one per seed.

        ``hyper`` / ``env_params``: ``None`` for the algorithm's own, or pytrees
        whose leaves have a leading axis of ``len(seeds)`` (a sweep).
        """
        batched = (hyper is not None, env_params is not None)
        if batched not in self._init_jits:
            in_axes = (0, 0 if batched[0] else None, 0 if batched[1] else None)
            self._init_jits[batched] = jax.jit(jax.vmap(self.algo.init, in_axes=in_axes))
        return self._init_jits[batched](seed_keys(self.seeds), hyper, env_params)

    def template(self, hyper: Any = None, env_params: Any = None) -> Any:
        """Shapes and dtypes of :meth:`init`'s result, without computing it (for checkpoint loading)."""
        return jax.eval_shape(self.init, hyper, env_params)

    # --------------------------------------------------------- compiled chunk
    def _evaluate(self, runners: Any) -> Any:
        network_params = jax.vmap(self.algo.network_params)(runners)
        return self.evaluation.evaluate_seeds(
            self.algo.greedy_action, network_params, self.algo.env, runners.env_params, params_batched=True
        )

    def empty_eval(self, runners: Any) -> LatestEval:
        """A :class:`LatestEval` holding no evaluation yet (``update == 0``); with ``eval_every == 0`` the loop
        never evaluates, so it holds none at all (tracing the evaluation for its shapes would cost seconds)."""
        if not self.loop.eval_every:
            return LatestEval(update=jnp.int32(0), episodes=None)
        signature = _signature(runners)
        if signature not in self._eval_shapes:
            self._eval_shapes[signature] = jax.eval_shape(self._evaluate_jit, runners)
        shapes = self._eval_shapes[signature]
        return LatestEval(update=jnp.int32(0), episodes=jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes))

    def _chunk(self, runners: Any, start: jax.Array, latest: LatestEval) -> tuple[Any, dict, LatestEval]:
        algo, num_updates, eval_every = self.algo, self.num_updates, self.loop.eval_every
        batched_update = jax.vmap(algo.update, in_axes=(0, None))

        def nan_like(shapes):
            return jax.tree.map(lambda s: jnp.full(s.shape, jnp.nan, s.dtype), shapes)

        def evaluate(runners, index, latest):
            episodes = self._evaluate_jit(runners)
            return jax.vmap(self.evaluation.seed_summary)(episodes), LatestEval(update=index + 1, episodes=episodes)

        def active(carry, index):
            runners, latest = carry
            runners, metrics = batched_update(runners, index)
            if eval_every:
                # The summary's shapes from the carried evaluation's (same shapes as a new one): tracing the
                # evaluation once more only for its shapes costs seconds for the fleet's (PIBT inside).
                summary_shapes = jax.eval_shape(jax.vmap(self.evaluation.seed_summary), latest.episodes)
                due = ((index + 1) % eval_every == 0) | (index + 1 == num_updates)
                summary, latest = jax.lax.cond(
                    due, evaluate, lambda r, i, kept: (nan_like(summary_shapes), kept), runners, index, latest
                )
                metrics = {**metrics, **summary}
            return (runners, latest), metrics

        # `active` is traced once: the scan's body, and the shapes of a skipped update's metrics.
        traced_active, out_shapes = traced_once(active, (runners, latest), start)

        def body(carry, offset):
            index = start + offset
            return jax.lax.cond(
                index < num_updates, traced_active, lambda c, i: (c, nan_like(out_shapes[1])), carry, index
            )

        (runners, latest), metrics = jax.lax.scan(
            body, (runners, latest), jnp.arange(self.loop.chunk_updates, dtype=jnp.int32)
        )
        return runners, metrics, latest

    def compile(self, runners: Any, latest: LatestEval | None = None) -> float:
        """Compile the chunk function ahead of time for these runners; returns the seconds it took.

        A second call for runners of the same shapes, dtypes and shardings reuses
        the compiled program and returns 0.
        """
        latest = self.empty_eval(runners) if latest is None else latest
        signature = _signature((runners, latest))
        if self._compiled is not None and signature == self._compiled_signature:
            return 0.0
        t0 = time.perf_counter()
        self._compiled = self._chunk_jit.lower(runners, jnp.int32(0), latest).compile()
        self._compiled_signature = signature
        return time.perf_counter() - t0

    def run_chunk(
        self, runners: Any, start: int, latest: LatestEval | None = None
    ) -> tuple[Any, dict[str, np.ndarray], LatestEval]:
        """Updates ``start .. start + chunk_updates - 1`` (those before ``num_updates``).

        Returns the new runners, the per-update metrics as NumPy arrays of shape
        ``(updates run, seeds)``, and the latest full evaluation (every seed, every item).
        """
        if not 0 <= start < self.num_updates:
            raise ValueError(f"start={start} is outside 0..{self.num_updates - 1}")
        latest = self.empty_eval(runners) if latest is None else latest
        if self._compiled is not None and _signature((runners, latest)) == self._compiled_signature:
            fn = self._compiled
        else:
            fn = self._chunk_jit
        runners, metrics, latest = fn(runners, jnp.int32(start), latest)
        ran = min(self.loop.chunk_updates, self.num_updates - start)
        metrics = {k: np.asarray(v)[:ran] for k, v in jax.device_get(metrics).items()}
        return runners, metrics, latest

    def host_state(self, runners: Any) -> Any:
        """The runner state in a form every process can read for a checkpoint (here: as is).

        ``wrl_jax.training.sharding.ShardedTrainer`` gathers state split across hosts.
        """
        return runners

    # ------------------------------------------------------------- evaluation
    def evaluate(self, runners: Any) -> Any:
        """The family's greedy evaluation of every seed (leaves ``(seeds, ...)``), compiled separately."""
        return self._eval_jit(runners)

    # --------------------------------------------------------------- metrics
    def metric_rows(self, metrics: dict[str, np.ndarray], start: int) -> list[dict[str, Any]]:
        """Per-update metrics of a chunk (from :meth:`run_chunk`) as one row per (log group, seed)."""
        return metric_rows(metrics, start, self.seeds, self.loop.log_every, self.steps_per_update,
                           self.evaluation.train_rates)


def _signature(tree: Any) -> tuple:
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    return (treedef, tuple((x.shape, str(x.dtype), getattr(x, "sharding", None)) for x in leaves))


# ------------------------------------------------------------------ the run
@dataclasses.dataclass
class RunResult:
    """What :func:`run` returns.

    Attributes:
        runners: the batched runner state after the last update run.
        updates_done: updates completed (``num_updates`` unless stopped early).
        finished: whether training reached ``num_updates``.
        rows: the metric rows written by *this* call (all rows are in ``metrics.jsonl``).
        compile_seconds: ahead-of-time compile of the chunk function (this process).
        train_seconds: wall time of the chunks, summed over every resumed segment.
        convergence: evaluation history (first/stable optimal update per seed).
    """

    runners: Any
    updates_done: int
    finished: bool
    rows: list[dict[str, Any]]
    compile_seconds: float
    train_seconds: float
    convergence: Convergence
    metadata: dict[str, Any]
    latest_eval: LatestEval | None = None


def settings_added_later(algo: Any) -> dict[str, Any]:
    """What a config field missing from an older checkpoint stands for: its class default (the behaviour that run
    trained with before the field existed), so adding a setting does not refuse the resume of older runs."""
    config = getattr(algo, "config", None)
    if not dataclasses.is_dataclass(config):
        return {}
    try:
        return {"config": config_to_dict(type(config)())}
    except TypeError:  # a config class with required fields has no defaults to stand in
        return {}


def run(
    trainer: Trainer,
    out_dir: str | os.PathLike | None = None,
    *,
    metadata: dict[str, Any] | None = None,
    resume: bool = False,
    stop_after: int | None = None,
    runners: Any = None,
    describe: Callable[[list[dict[str, Any]]], str] | None = None,
) -> RunResult:
    """Train ``trainer``'s seeds to the end (or to ``stop_after`` updates), chunk by chunk.

    Args:
        trainer: the algorithm, seeds and loop settings.
        out_dir: where metrics and checkpoints go; ``None`` keeps everything in memory.
        metadata: JSON-able description of the run stored in the checkpoint
            (algorithm, env, config...). On ``resume`` every field of it must
            match the checkpoint's, or :class:`checkpoint.CheckpointMismatchError`
            is raised before anything runs.
        resume: continue from ``out_dir``'s checkpoint.
        stop_after: stop (with a checkpoint) once this many updates are done;
            rounded up to a chunk boundary.
        runners: initial runners (default ``trainer.init()``); e.g. a sweep's.
        describe: optional ``rows -> str`` for the progress bar's postfix.

    Ctrl-C between or during chunks stops cleanly: the last completed chunk is
    checkpointed and :class:`KeyboardInterrupt` is re-raised.
    """
    metadata = dict(metadata or {})
    loop = trainer.loop
    run_meta = {
        **metadata,
        "seeds": trainer.seeds,
        "num_updates": trainer.num_updates,
        "steps_per_update": trainer.steps_per_update,
        "log_every": loop.log_every,
        "eval_every": loop.eval_every,
    }
    out = Path(out_dir) if out_dir is not None else None
    start, train_seconds, convergence = 0, 0.0, Convergence(solved_key=trainer.evaluation.solved_key)
    if runners is None:
        runners = trainer.init()
    if resume:
        if out is None:
            raise ValueError("resume needs an output directory holding a checkpoint")
        runners, saved = checkpoint.load(out, jax.eval_shape(lambda: runners), expected=run_meta,
                                         absent=settings_added_later(trainer.algo))
        start = int(saved["updates_done"])
        train_seconds = float(saved.get("train_seconds", 0.0))
        convergence = Convergence.from_json(saved.get("convergence", {}), solved_key=trainer.evaluation.solved_key)
    writer = metrics_io.MetricsWriter(out, resume_after=start if resume else None) if out is not None else None

    latest = trainer.empty_eval(runners)
    compile_seconds = trainer.compile(runners, latest)
    stop = trainer.num_updates if stop_after is None else min(trainer.num_updates, max(int(stop_after), 1))
    all_rows: list[dict[str, Any]] = []
    total_steps = trainer.num_updates * trainer.steps_per_update
    bar = None
    if loop.progress:
        from tqdm.auto import tqdm

        bar = tqdm(
            total=total_steps,
            initial=start * trainer.steps_per_update,
            unit="step",
            unit_scale=True,
            desc=f"{trainer.algo.name} x{len(trainer.seeds)} seeds",
            dynamic_ncols=True,
        )

    def save(updates_done: int) -> None:
        if out is None:
            return
        if writer is not None:
            writer.sync()
        checkpoint.save(
            out,
            trainer.host_state(runners),
            {
                **run_meta,
                "updates_done": updates_done,
                "env_steps_done": updates_done * trainer.steps_per_update,
                "train_seconds": train_seconds,
                "convergence": convergence.to_json(),
            },
        )

    chunks_since_save, last_save = 0, time.perf_counter()
    updates_done = start
    try:
        while updates_done < stop:
            t0 = time.perf_counter()
            # run_chunk fetches the metrics to the host, so the chunk has finished when it returns.
            new_runners, metrics, new_latest = trainer.run_chunk(runners, updates_done, latest)
            elapsed = time.perf_counter() - t0
            runners, latest = new_runners, new_latest
            ran = next(iter(metrics.values())).shape[0]
            train_seconds += elapsed
            rows = trainer.metric_rows(metrics, updates_done)
            convergence.record(metrics, updates_done)
            updates_done += ran
            all_rows.extend(rows)
            if writer is not None:
                writer.append(rows)
            chunks_since_save += 1
            due = chunks_since_save >= loop.checkpoint_every and time.perf_counter() - last_save >= loop.checkpoint_seconds
            if due or updates_done >= stop:
                save(updates_done)
                chunks_since_save, last_save = 0, time.perf_counter()
            if bar is not None:
                bar.update(ran * trainer.steps_per_update)
                steps_per_second = ran * trainer.steps_per_update * len(trainer.seeds) / max(elapsed, 1e-9)
                postfix = describe(rows) if describe is not None else describe_rows(rows, trainer.evaluation)
                bar.set_postfix_str(f"{steps_per_second / 1e3:,.0f}k steps/s (all seeds) | {postfix}", refresh=True)
    except KeyboardInterrupt:
        # ``runners`` and ``updates_done`` still describe the last completed chunk.
        if out is not None and chunks_since_save:
            save(updates_done)
        raise
    finally:
        if bar is not None:
            bar.close()
        if writer is not None:
            writer.close()
    return RunResult(
        runners=runners,
        updates_done=updates_done,
        finished=updates_done >= trainer.num_updates,
        rows=all_rows,
        compile_seconds=compile_seconds,
        train_seconds=train_seconds,
        convergence=convergence,
        metadata=run_meta,
        latest_eval=latest,
    )


def final_evaluation(trainer: Trainer, result: RunResult) -> Any:
    """Every seed's evaluation after training: the in-loop evaluation of the last update when
    there is one (no extra compile), otherwise a separately compiled evaluation."""
    latest = result.latest_eval
    if latest is not None and int(latest.update) == result.updates_done and result.updates_done > 0:
        return latest.episodes
    return trainer.evaluate(result.runners)


def install_sigterm_handler() -> None:
    """Turn SIGTERM into ``KeyboardInterrupt`` so :func:`run` checkpoints before exiting."""

    def handler(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    signal.signal(signal.SIGTERM, handler)
