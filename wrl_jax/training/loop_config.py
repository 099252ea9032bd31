"""How the host drives a run's compiled updates: chunk size, evaluation and logging cadence, checkpoints.

Apart from :mod:`~wrl_jax.training.driver` because it is the host's side: of its fields only the chunk size
(the updates one call scans) and ``eval_every`` (the evaluation's cadence inside the chunk) reach the compiled
program, and the driver reads best without the rest.
"""

from __future__ import annotations

import dataclasses
import math


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    """How the host drives the compiled updates. ``None`` picks a value from the run length.

    Attributes:
        chunk_updates: updates per compiled call (a multiple of ``log_every``);
            default about 1/20 of the run. Changes nothing in the results.
        eval_every: greedy evaluation every this many updates (and after the
            last); ``0`` disables it. Default: about 50 evaluations per run.
        log_every: updates aggregated into one metrics row per seed; default
            so that a run writes at most about 500 rows per seed.
        checkpoint_every: chunks between checkpoints (when writing to a directory).
        checkpoint_seconds: at least this many seconds between two checkpoints before the last (0: every
            ``checkpoint_every`` chunks). An off-policy runner holds its replay buffer (SAC's default: 570 MB,
            about 7 s to write), which every chunk would spend again; the last chunk, ``stop_after``, Ctrl-C
            and SIGTERM always checkpoint.
        progress: show a tqdm progress bar.
    """

    chunk_updates: int | None = None
    eval_every: int | None = None
    log_every: int | None = None
    checkpoint_every: int = 1
    checkpoint_seconds: float = 120.0
    progress: bool = True

    def resolve(self, num_updates: int) -> "LoopConfig":
        """Concrete values for a run of ``num_updates`` updates; raises ``ValueError`` on bad ones."""
        for name in ("chunk_updates", "log_every"):
            value = getattr(self, name)
            if value is not None and int(value) < 1:
                raise ValueError(f"{name} must be a positive integer, got {value}")
        if self.eval_every is not None and int(self.eval_every) < 0:
            raise ValueError(f"eval_every must be >= 0 (0 disables evaluation), got {self.eval_every}")
        if int(self.checkpoint_every) < 1:
            raise ValueError(f"checkpoint_every must be a positive integer, got {self.checkpoint_every}")
        seconds = self.checkpoint_seconds
        if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not 0 <= seconds < math.inf:
            raise ValueError(f"checkpoint_seconds must be a finite number of seconds >= 0, got {seconds!r}")
        log_every = self.log_every if self.log_every is not None else max(1, math.ceil(num_updates / 500))
        eval_every = self.eval_every if self.eval_every is not None else max(1, math.ceil(num_updates / 50))
        chunk = self.chunk_updates
        if chunk is None:
            chunk = max(1, math.ceil(num_updates / 20))
            chunk = log_every * math.ceil(chunk / log_every)
        if chunk % log_every:
            raise ValueError(f"chunk_updates={chunk} must be a multiple of log_every={log_every} "
                             "(a metrics row never straddles two chunks)")
        return dataclasses.replace(self, chunk_updates=int(chunk), eval_every=int(eval_every), log_every=int(log_every))
