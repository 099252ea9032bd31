"""The driver's log: a chunk's metrics as rows, the progress bar's text, and each seed's convergence.

Aggregation over a log group of ``log_every`` updates: episode sums (``episodes``,
``terminated``, ``return_sum``, ``length_sum`` and any key ending in ``_sum``) are
added, ``eval_*`` keys take the group's last evaluation, and every other metric is
averaged. Derived per row: ``mean_return`` and ``mean_length`` of the training
episodes that ended in the group, and the family's rates
(:class:`~wrl_jax.core.evaluation.TrainRate`: the warehouse's ``delivery_rate``, the
fleet's ``train_throughput``). Nothing here knows a family's words.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from wrl_jax.agents.base import EpisodeSums
from wrl_jax.core.evaluation import FamilyEvaluation, TrainRate

SUM_METRICS = frozenset(f.name for f in dataclasses.fields(EpisodeSums))
"""Metrics that are sums over episodes; a log group adds them (so do keys ending in ``_sum``)."""


def metric_rows(metrics: dict[str, np.ndarray], start: int, seeds: Sequence[int], log_every: int,
                steps_per_update: int, train_rates: Sequence[TrainRate] = ()) -> list[dict[str, Any]]:
    """A chunk's per-update metrics (leaves ``(updates, seeds)``) as one row per (log group, seed)."""
    ran = next(iter(metrics.values())).shape[0]
    rows = []
    for group_start in range(0, ran, log_every):
        group = {k: v[group_start : group_start + log_every] for k, v in metrics.items()}
        update = start + min(group_start + log_every, ran)
        group_steps = len(next(iter(group.values()))) * steps_per_update
        for s, seed in enumerate(seeds):
            row: dict[str, Any] = {"update": update, "env_steps": update * steps_per_update, "seed": seed}
            for key, values in group.items():
                row[key] = aggregate(key, values[:, s].astype(np.float64))
            episodes = row.get("episodes", math.nan)
            row["mean_return"] = row.get("return_sum", math.nan) / episodes if episodes else math.nan
            row["mean_length"] = row.get("length_sum", math.nan) / episodes if episodes else math.nan
            for rate in train_rates:
                total = row.get(rate.sum_key, math.nan)
                if rate.per == "step":
                    row[rate.name] = total / group_steps
                else:
                    row[rate.name] = total / episodes if episodes else math.nan
            rows.append(row)
    return rows


def aggregate(key: str, values: np.ndarray) -> float:
    if key in SUM_METRICS or key.endswith("_sum"):
        return float(values.sum())
    if key.startswith("eval_"):
        present = values[~np.isnan(values)]
        return float(present[-1]) if present.size else math.nan
    return float(values.mean())


def describe(rows: list[dict[str, Any]], evaluation: FamilyEvaluation) -> str:
    """Progress postfix: the chunk's training return and the family's rates, then its eval metric."""
    episodes = sum(row.get("episodes", 0.0) for row in rows)
    text = "no episode ended"
    if episodes:
        text = f"return {sum(row.get('return_sum', 0.0) for row in rows) / episodes:+.1f}"
    for rate in evaluation.train_rates:
        if rate.progress is None:
            continue
        total = sum(row.get(rate.sum_key, 0.0) for row in rows)
        if rate.per == "episode" and episodes:
            text += f" | {rate.progress} {100 * total / episodes:.0f}%"
        elif rate.per == "step":
            text += f" | {rate.progress} {float(np.mean([row[rate.name] for row in rows])):.3f}"
    key, label = evaluation.progress_metric
    evals = [row[key] for row in rows if not math.isnan(row.get(key, math.nan))]
    if evals:
        latest = float(np.mean(evals[-len(set(r['seed'] for r in rows)):]))
        text += f" | {label} {100 * latest:.0f}%" if evaluation.progress_percent else f" | {label} {latest:.2f}"
    return text


@dataclasses.dataclass
class Convergence:
    """Per-seed history of the periodic evaluations' "solved" flag (the family's ``solved_key``).

    Attributes:
        updates: the update counts (1-based) at which an evaluation ran.
        all_optimal: per evaluation, one solved flag per seed (named so in checkpoints,
            which stay readable across versions).
        solved_key: the metric holding the flag.
    """

    updates: list[int] = dataclasses.field(default_factory=list)
    all_optimal: list[list[bool]] = dataclasses.field(default_factory=list)
    solved_key: str = "eval_all_optimal"

    def record(self, metrics: dict[str, np.ndarray], start: int) -> None:
        flags = metrics.get(self.solved_key)
        if flags is None:
            return
        for offset, row in enumerate(flags):
            if not np.isnan(row).any():
                self.updates.append(start + offset + 1)
                self.all_optimal.append([bool(x == 1.0) for x in row])

    def first_solved_update(self, num_seeds: int) -> list[int | None]:
        """Per seed, the first evaluated update at which the seed solved the task."""
        out: list[int | None] = [None] * num_seeds
        for update, flags in zip(self.updates, self.all_optimal):
            for s, ok in enumerate(flags):
                if ok and out[s] is None:
                    out[s] = update
        return out

    def stable_solved_update(self, num_seeds: int) -> list[int | None]:
        """Per seed, the first evaluated update from which every later evaluation solved it too."""
        out: list[int | None] = [None] * num_seeds
        for s in range(num_seeds):
            for update, flags in zip(reversed(self.updates), reversed(self.all_optimal)):
                if not flags[s]:
                    break
                out[s] = update
        return out

    def to_json(self) -> dict[str, Any]:
        return {"updates": self.updates, "all_optimal": self.all_optimal}

    @classmethod
    def from_json(cls, data: dict[str, Any], solved_key: str = "eval_all_optimal") -> "Convergence":
        return cls(list(data.get("updates", [])), [list(x) for x in data.get("all_optimal", [])], solved_key)
