"""A sweep's outputs: the results table, CSV, JSON and the plot (:func:`write_outputs`).

Which metrics they show is the environment family's choice (its evaluation's
``sweep_columns``, carried by :class:`~wrl_jax.training.sweep.SweepResult`), so
one writer serves the warehouse, the fleet and any later family.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from wrl_jax.training.sweep_columns import train_column

if TYPE_CHECKING:
    from wrl_jax.training.sweep import SweepResult


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def _fmt_ci(mean: float | None, half: float | None, percent: bool = False, digits: int = 1) -> str:
    if mean is None:
        return "n/a"
    scale, unit = (100.0, "%") if percent else (1.0, "")
    text = f"{scale * mean:,.{digits}f}{unit}"
    if half is not None:
        text += f" ± {scale * half:,.{digits}f}"
    return text


def _metric_cell(metric: Any, point: dict[str, Any], num_seeds: int, key: str | None = None) -> str:
    """One cell of the table: a rate in %, a number, or the count of seeds that solved the task."""
    key = key or metric.key
    if metric.kind == "solved":
        return f"{point[f'{key}_seeds']}/{num_seeds}"
    percent = metric.kind in ("percent", "ratio")
    return _fmt_ci(point.get(key), point.get(f"{key}_ci95"), percent=percent, digits=metric.digits)


def results_markdown(result: SweepResult) -> str:
    """The per-point table: greedy evaluation after training, mean ± 95 % CI over seeds.

    The columns are the family's (:class:`~wrl_jax.core.evaluation.SweepColumns`):
    its evaluation metrics, its training metrics, then the generic convergence column.
    """

    sweep, columns = result.sweep, result.columns
    n = len(sweep.seeds)
    metrics = [m for m in columns.metrics if m.table]
    train = [m for m in columns.train if m.table]
    header = sweep.fields + [m.label for m in metrics] + [m.label for m in train] + [columns.convergence_label]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for p in result.per_point:
        conv = p["converged_seeds"]
        first = "none"
        if conv:
            first = f"{_fmt_ci(p['first_optimal_step'], p['first_optimal_step_ci95'], digits=0)} ({conv}/{n})"
        cells = [_fmt(p[f]) for f in sweep.fields]
        cells += [_metric_cell(m, p, n) for m in metrics]
        cells += [_metric_cell(m, p, n, train_column(m)) for m in train]
        lines.append("| " + " | ".join(cells + [first]) + " |")
    t = result.timings
    d = sweep.describe()
    title = (
        f"{d['algo'].upper()} sweep on {d['env']}: {d['num_points']} points x {n} seeds = {d['batch']} runs "
        f"in one program, {t['env_steps_per_element']:,} env steps each; compile {t['compile_seconds']:.1f} s, "
        f"train {t['train_seconds']:.1f} s ({t['env_steps_per_second'] / 1e3:,.0f}k env steps/s)"
    )
    definition = columns.convergence_note or result.solved_definition
    note = f"± is the 95 % Student-t confidence interval over seeds; '{columns.convergence_label}': {definition} " \
        "(mean over the seeds that got there)."
    return f"{title}\n\n" + "\n".join(lines) + f"\n\n{note}\n"


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    keys: list[str] = []
    for row in rows:
        keys.extend(k for k in row if k not in keys)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: "" if row.get(k) is None else row.get(k) for k in keys})


def _plot_panels(columns: Any) -> list[tuple[str, str, float, bool]]:
    """``(key, y label, scale, bounded)`` per panel: the family's metrics with a plot label.

    ``bounded``: a rate, drawn on 0-100 % (the CI of a few seeds can reach past it);
    a family that names no panel gets its first evaluation metric.
    """
    metrics = [m for m in columns.metrics if m.kind != "solved" and m.aggregate]
    chosen = [m for m in metrics if m.plot] or metrics[:1]
    return [(m.key, m.plot or m.label, 100.0 if m.kind in ("percent", "ratio") else 1.0, m.kind == "percent")
            for m in chosen]


def plot_sweep(result: SweepResult, path: Path) -> None:
    """The family's headline metrics (e.g. the warehouse's success rate, optimal-item rate and mean
    steps; the fleet's throughput, ratio to PIBT and blocks) against the first grid field."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sweep = result.sweep
    x_field, others = sweep.fields[0], sweep.fields[1:]
    xs = sweep.grid[x_field]
    numeric = all(isinstance(v, (int, float)) for v in xs)
    log_x = numeric and all(v > 0 for v in xs) and max(xs) / min(xs) >= 10
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for p in result.per_point:
        groups.setdefault(tuple(p[f] for f in others), []).append(p)
    panels = _plot_panels(result.columns)
    if not panels:
        return
    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 4), constrained_layout=True, squeeze=False)
    axes = axes[0]
    for ax, (key, label, scale, bounded) in zip(axes, panels):
        for combo, points in groups.items():
            name = ", ".join(f"{f}={_fmt(v)}" for f, v in zip(others, combo)) or None
            x = [p[x_field] for p in points]
            y = [math.nan if p[key] is None else scale * p[key] for p in points]
            err = [0.0 if p[f"{key}_ci95"] is None else scale * p[f"{key}_ci95"] for p in points]
            ax.errorbar(x if numeric else range(len(x)), y, yerr=err, marker="o", capsize=3, label=name)
        if log_x:
            ax.set_xscale("log")
        if bounded:
            ax.set_ylim(-5, 105)  # a rate: the CI of a few seeds can reach past 0-100 %
        if not numeric:
            ax.set_xticks(range(len(xs)), [str(v) for v in xs])
        ax.set_xlabel(x_field)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    if others:
        axes[0].legend(fontsize="small")
    d = sweep.describe()
    fig.suptitle(
        f"{d['algo'].upper()} on {d['env']}: mean ± 95% CI over {len(sweep.seeds)} seeds, "
        f"{result.timings['env_steps_per_element']:,} steps each"
    )
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_outputs(result: SweepResult, out: Path, command: str | None = None, plot: bool = True) -> dict[str, Any]:
    """``results.md``, ``results.csv``, ``results.json``, ``metrics.csv`` and ``sweep.png`` in ``out``."""
    import jax
    import numpy as np

    from wrl_jax.training import checkpoint

    out.mkdir(parents=True, exist_ok=True)
    table = results_markdown(result)
    checkpoint.atomic_write_text(out / "results.md", table)
    _write_csv(out / "results.csv", result.per_seed)
    _write_csv(out / "metrics.csv", result.metric_rows)
    data = {
        "command": command,
        "sweep": result.sweep.describe(),
        "timings": result.timings,
        "per_point": result.per_point,
        "per_seed": result.per_seed,
        "devices": [str(d) for d in jax.devices()],
        "versions": {"wrl_jax": checkpoint.wrl_jax_version(), "jax": jax.__version__, "numpy": np.__version__},
    }
    checkpoint.atomic_write_text(out / "results.json", json.dumps(data, indent=2))
    if plot:
        plot_sweep(result, out / "sweep.png")
    return data


