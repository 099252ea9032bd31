"""The procedural family's numbers and tables: statistics of a set of episodes against their BFS optimum,
the generalization aim, and the Markdown of the periodic and final reports."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np


def _number(value: float) -> float | None:
    """A JSON-safe float: ``None`` for NaN (no delivered episode to average over)."""
    value = float(value)
    return None if math.isnan(value) else value


def episode_stats(delivered: np.ndarray, steps: np.ndarray, optimal: np.ndarray,
                  collisions: np.ndarray) -> dict[str, Any]:
    """The statistics of a set of episodes (1-D arrays), as plain Python numbers (``None`` where undefined).

    ``mean_steps``, ``mean_optimal``, ``mean_excess`` and ``excess_fraction`` are
    over the delivered episodes (an undelivered episode has no route length to
    compare); ``bfs_optimum`` is the mean optimum of all episodes, the yardstick
    of the set; ``excess_fraction = mean_excess / mean_optimal``;
    ``mean_excess_fraction_per_episode`` is the mean of each episode's own fraction.
    """
    delivered = np.asarray(delivered, dtype=bool)
    steps, optimal = np.asarray(steps, dtype=np.float64), np.asarray(optimal, dtype=np.float64)
    collisions = np.asarray(collisions, dtype=np.float64)
    episodes = int(delivered.size)
    if episodes == 0:
        raise ValueError("episode_stats needs at least one episode")
    won = delivered.sum()
    excess = steps[delivered] - optimal[delivered]
    mean_optimal = optimal[delivered].mean() if won else math.nan
    return {
        "episodes": episodes,
        "delivery_rate": float(won / episodes),
        "optimal_rate": float((delivered & (steps == optimal)).sum() / episodes),
        "mean_steps": _number(steps[delivered].mean() if won else math.nan),
        "mean_optimal": _number(mean_optimal),
        "bfs_optimum": float(optimal.mean()),
        "mean_excess": _number(excess.mean() if won else math.nan),
        "excess_fraction": _number(excess.mean() / mean_optimal if won else math.nan),
        "mean_excess_fraction_per_episode": _number((excess / optimal[delivered]).mean() if won else math.nan),
        "collisions_per_episode": float(collisions.mean()),
        "collision_free_rate": float((collisions == 0).mean()),
    }


AIM_DELIVERY = 0.99
AIM_EXCESS = 0.05
"""The generalization aim on held-out layouts: at least 99 % delivered, at most 5 % mean excess over the optimum."""


def seeds_at_aim(entry: dict[str, Any]) -> int:
    """Seeds of a final-report set entry at :data:`AIM_DELIVERY` and :data:`AIM_EXCESS` or better."""
    return sum(1 for row in entry["per_seed"] if row["delivery_rate"] >= AIM_DELIVERY
               and row["excess_fraction"] is not None and row["excess_fraction"] <= AIM_EXCESS)


def _seeds_at_aim(entry: dict[str, Any]) -> str:
    return f"{seeds_at_aim(entry)} of {len(entry['per_seed'])}"


def _percent(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.1%}"


def _steps(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.2f}"


def format_report(summary: dict[str, Any], label: str, convergence_steps: Sequence[int | None] | None = None,
                  study: dict[str, str] | None = None) -> str:
    """A Markdown table of the periodic held-out evaluation, then the final held-out set's headline if present."""
    del study
    rows = [
        ("held-out layouts x items", f"{summary['eval_layouts']} layouts, {summary['episodes_per_seed']} episodes"),
        ("delivered", f"{summary['success_rate']:.1%}"),
        ("at the BFS optimum", f"{summary['optimal_rate']:.1%}"),
        ("mean steps over the optimum (delivered)", f"{summary['mean_excess']:.2f}"),
        ("collisions per episode", f"{summary['collisions_per_episode']:.2f}"),
    ]
    heldout = summary.get("heldout")
    if heldout:
        rows += [
            (f"final: {heldout['layouts']} held-out layouts, delivered", _percent(heldout["delivery_rate"])),
            ("final: mean excess over the optimum",
             f"{_steps(heldout['mean_excess'])} steps ({_percent(heldout['excess_fraction'])})"),
            ("final: seeds at >= 99% delivered and <= 5% excess", _seeds_at_aim(heldout)),
        ]
    sampled = summary.get("heldout_sampled")
    if sampled:
        rows += [
            ("final, sampled policy: delivered / excess",
             f"{_percent(sampled['delivery_rate'])} / {_percent(sampled['excess_fraction'])}"),
            ("final, sampled policy: seeds at >= 99% delivered and <= 5% excess", _seeds_at_aim(sampled)),
        ]
    if convergence_steps is not None:
        solved = [step for step in convergence_steps if step is not None]
        rows.append(("seeds solved", f"{len(solved)} of {len(convergence_steps)}"))
    lines = [f"| {label} | |", "|---|---|", *(f"| {name} | {value} |" for name, value in rows)]
    return "\n".join(lines)


def format_sets(report: dict[str, dict[str, Any]]) -> str:
    """Markdown: one row per set (all seeds), then one row per set with each seed's delivered / excess."""
    if not report:
        return ""
    header = ("| set | layouts | episodes/seed | delivered | at optimum | mean excess (steps) | excess | "
              "collisions/episode |")
    lines = [header, "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for name, row in report.items():
        per_seed_episodes = row["episodes"] // max(len(row["per_seed"]), 1)
        lines.append(f"| {name} | {row['layouts']} | {per_seed_episodes} | {_percent(row['delivery_rate'])} | "
                     f"{_percent(row['optimal_rate'])} | {_steps(row['mean_excess'])} | "
                     f"{_percent(row['excess_fraction'])} | {row['collisions_per_episode']:.3f} |")
    seeds = [entry["seed"] for entry in next(iter(report.values()))["per_seed"]]
    lines += ["", "| set (per seed: delivered / excess) | " + " | ".join(f"seed {seed}" for seed in seeds) + " |",
              "|---|" + "---:|" * len(seeds)]
    for name, row in report.items():
        cells = [f"{_percent(entry['delivery_rate'])} / {_percent(entry['excess_fraction'])}"
                 for entry in row["per_seed"]]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_details(summary: dict[str, Any]) -> str:
    """The final report's sets (held-out, then out-of-distribution) as Markdown tables; empty without one."""
    if "heldout" not in summary:
        return ""
    report = {"heldout": summary["heldout"], **summary.get("ood", {})}
    if "heldout_sampled" in summary:  # the sampled policy's row (PPO), beside the greedy ones
        report["heldout (sampled policy)"] = summary["heldout_sampled"]
    seconds = summary.get("final_report_seconds")
    lines = ["Greedy policy of every seed (the sampled policy's row: actions drawn from it), every real (layout, "
             "item) episode; excess is over delivered episodes, as a fraction of their mean BFS optimum."
             + (f" Final evaluation: {seconds:.1f} s." if seconds is not None else ""), "", format_sets(report), ""]
    lines += [f"- `{name}`: {row['description']}" for name, row in report.items()]
    return "\n".join(lines)
