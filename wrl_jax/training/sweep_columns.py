"""What a sweep reports per seed and per point: the family's columns (or every number it gives),
each seed's values (``None`` where missing, never an error) and a point's mean and 95 % interval."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from wrl_jax.core.evaluation import SweepColumns, SweepMetric
from wrl_jax.stats import mean_half_width


def default_columns(seed_rows: list[dict[str, Any]]) -> SweepColumns:
    """The columns of a family that declares none: every number of its per-seed rows, then "solved".

    A new family's sweep works before anyone chooses its headline metrics.
    """
    first = seed_rows[0] if seed_rows else {}
    keys = [k for k, v in first.items()
            if k not in ("seed", "solved") and isinstance(v, (int, float)) and not isinstance(v, bool)]
    metrics = [SweepMetric(k, k.replace("_", " "), plot=k.replace("_", " ") if i < 3 else None)
               for i, k in enumerate(keys)]
    return SweepColumns(
        metrics=(*metrics, SweepMetric("solved", "seeds solved", "solved")),
        train=(SweepMetric("mean_return", "train return (last log)", table=False, aggregate=False),),
    )


def train_column(metric: Any) -> str:
    """The per-seed column of a training metric: ``train_<key>`` (a key already ``train_...`` kept)."""
    return metric.key if metric.key.startswith("train_") else f"train_{metric.key}"


def summary_rows(summary: dict[str, Any], path: Sequence[str]) -> list[dict[str, Any]]:
    """The per-seed rows of a family summary, at ``path`` (``SweepColumns.rows``)."""
    rows: Any = summary
    for key in path:
        rows = rows[key]
    return rows


def solved_flags(evaluation: Any, episodes: Any) -> list[bool]:
    """Per seed, the family's solved criterion on the final evaluation (its ``seed_summary[solved_key]``)."""
    import jax
    import numpy as np

    flags = jax.vmap(evaluation.seed_summary)(episodes)[evaluation.solved_key]
    return [bool(x == 1.0) for x in np.asarray(flags)]


def evaluation_values(columns: Any, seed_row: dict[str, Any], solved: bool) -> dict[str, Any]:
    """One seed's evaluation metrics (``None`` where missing or NaN), then its solved flags."""
    out = {m.key: _finite(seed_row.get(m.key)) for m in columns.metrics if m.kind != "solved"}
    out.update({m.key: solved for m in columns.metrics if m.kind == "solved"})
    return out


def training_values(columns: Any, train_row: dict[str, Any]) -> dict[str, Any]:
    """One seed's last training log row, as the family's training columns.

    A metric the algorithm does not log for this environment (a multi-agent
    fleet has no per-episode delivery rate) is ``None``, never an error.
    """
    return {train_column(m): _finite(train_row.get(m.key)) for m in columns.train}


def point_row(columns: Any, head: dict[str, Any], rows: list[dict[str, Any]]) -> dict[str, Any]:
    """A point's row: mean and 95 % half-width over seeds of each metric, convergence, solved counts.

    ``first_optimal_step`` is the first step at which the family's solved criterion held (the
    warehouse's: every item optimal); the column keeps that name in results files already written."""
    aggregate = dict(head)
    keys = [m.key for m in columns.metrics if m.kind != "solved" and m.aggregate]
    keys += [train_column(m) for m in columns.train if m.aggregate]
    for key in keys + ["first_optimal_step"]:
        mean, half, _ = mean_half_width([r[key] for r in rows])
        aggregate[key] = mean
        aggregate[f"{key}_ci95"] = half
    aggregate["converged_seeds"] = mean_half_width([r["first_optimal_step"] for r in rows])[2]
    for m in columns.metrics:
        if m.kind == "solved":
            aggregate[f"{m.key}_seeds"] = sum(bool(r[m.key]) for r in rows)
    return aggregate


def _finite(value: Any) -> float | None:
    """A metric as a float, or ``None`` when missing or NaN (no episode to average over)."""
    if value is None:
        return None
    value = float(value)
    return None if math.isnan(value) else value
