"""Shared machinery of the experiments: batched training of variants x seeds,
per-seed metrics, confidence intervals, and the files every experiment writes.

Why one helper trains everything: a variant that differs from another only in
*traced* values (reward constants, the collision-bug switch, traced
hyperparameters) is the same XLA program with other numbers in it. So
:func:`train_variants` stacks ``variants x seeds`` runners along one batch axis
(``Trainer`` with the seed list repeated per variant and batched
``env_params``/``hyper``) and trains all of them in one compiled program. Only
what changes a shape or a function (the observation size, a different
observation function, a different network) needs a second program.

Confidence intervals are across seeds: a seed is one independent training run,
and its metric is the greedy evaluation of its final policy on every item.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.agents.base import Algorithm
from wrl_jax.envs.warehouse import evaluation
from wrl_jax.envs.warehouse.types import EnvParams
from wrl_jax.stats import Interval, mean_ci, t_quantile  # noqa: F401 (re-exported for the experiments)
from wrl_jax.training import driver as training
from wrl_jax.training.variants import train_batch

# ------------------------------------------------------------- per-seed metrics
METRICS = (
    # key, label, bounds for the CI (None: unbounded)
    ("success_rate", "delivery rate", (0.0, 1.0)),
    ("optimal_rate", "items at BFS optimum", (0.0, 1.0)),
    ("excess_steps", "steps over optimum (delivered)", None),
    ("mean_steps", "mean steps (delivered)", None),
    ("mean_return", "greedy return", None),
    ("collision_free_rate", "collision-free episodes", (0.0, 1.0)),
    ("stage_switch_rate", "correct stage switching", (0.0, 1.0)),
    ("all_optimal", "seed optimal on every item", (0.0, 1.0)),
)
BOUNDS = {key: bounds for key, _, bounds in METRICS}


def per_seed_metrics(episodes: evaluation.EpisodeEval) -> dict[str, np.ndarray]:
    """One value per seed of every metric in :data:`METRICS` (leaves of ``episodes``: ``(S, K_max)``).

    Rates are over the layout's items; ``mean_steps`` / ``excess_steps`` are over
    the delivered items (NaN for a seed that delivered none).
    """
    r = jax.tree.map(np.asarray, episodes)
    valid = r.valid.astype(bool)
    n = valid.sum(axis=1)
    delivered = r.delivered.astype(bool) & valid
    optimal = delivered & (r.steps == r.optimal_steps)
    nd = delivered.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_steps = np.where(nd > 0, (r.steps * delivered).sum(axis=1) / nd, np.nan)
        excess = np.where(nd > 0, ((r.steps - r.optimal_steps) * delivered).sum(axis=1) / nd, np.nan)
    return {
        "success_rate": delivered.sum(axis=1) / n,
        "optimal_rate": optimal.sum(axis=1) / n,
        "excess_steps": excess,
        "mean_steps": mean_steps,
        "mean_return": (r.episode_return * valid).sum(axis=1) / n,
        "collision_free_rate": ((r.collisions == 0) & valid).sum(axis=1) / n,
        "stage_switch_rate": (r.stage_switch.astype(bool) & valid).sum(axis=1) / n,
        "all_optimal": (optimal.sum(axis=1) == n).astype(np.float64),
    }


def intervals(per_seed: dict[str, np.ndarray], method: str = "t") -> dict[str, Interval]:
    """:func:`mean_ci` of every per-seed metric."""
    return {k: mean_ci(v, method=method, bounds=BOUNDS.get(k)) for k, v in per_seed.items()}


# ------------------------------------------------------------ batched training
@dataclasses.dataclass
class VariantResult:
    """One variant's seeds after training: final greedy evaluation and history."""

    name: str
    seeds: list[int]
    episodes: evaluation.EpisodeEval  # leaves (S, K_max)
    per_seed: dict[str, np.ndarray]
    first_optimal_step: list[int | None]
    curve_steps: np.ndarray  # (T,) env steps per seed at each logged row
    curves: dict[str, np.ndarray]  # key -> (S, T): training delivery rate, return, eval optimal rate
    network_params: Any = None  # batched over seeds (leading axis S)

    def summary(self, method: str = "t") -> dict[str, Interval]:
        return intervals(self.per_seed, method)


@dataclasses.dataclass
class BatchTiming:
    compile_seconds: float
    train_seconds: float
    runners: int
    env_steps_per_runner: int


def stack_trees(trees: Sequence[Any]) -> Any:
    """Stack pytrees of the same structure along a new leading axis.

    Stacked in NumPy (an eager ``jnp.stack`` compiles a program per leaf shape and count), each leaf first made
    a JAX array so that Python numbers get JAX's dtypes (float32, int32; not weakly typed after stacking). For
    concrete trees, outside ``jit``."""
    return jax.tree.map(lambda *xs: jnp.asarray(np.stack([np.asarray(jnp.asarray(x)) for x in xs])), *trees)


def train_variants(
    algo: Algorithm,
    variants: dict[str, EnvParams],
    seeds: Sequence[int],
    *,
    hypers: dict[str, Any] | None = None,
    eval_every: int | None = None,
    keep_params: bool = False,
) -> tuple[dict[str, VariantResult], BatchTiming]:
    """Train every (variant, seed) pair of one algorithm in one compiled program.

    Args:
        algo: the algorithm (its ``env`` fixes the observation function and shapes).
        variants: name -> environment params (same shapes; values may differ).
        seeds: seed values, the same for every variant (seed ``s`` gets
            ``PRNGKey(s)`` in each, so variants are compared on common seeds).
        hypers: optional name -> the algorithm's traced hyperparameters per variant.
        eval_every: greedy evaluation cadence in updates (default: ~50 per run);
            the convergence step is resolved to it.
        keep_params: also return each variant's trained network parameters.
    """
    names = list(variants)
    seeds = [int(s) for s in seeds]
    all_seeds = [s for _ in names for s in seeds]
    env_params = stack_trees([variants[name] for name in names for _ in seeds])
    hyper = None
    if hypers is not None:
        hyper = stack_trees([hypers[name] for name in names for _ in seeds])
    loop = training.LoopConfig(eval_every=eval_every, progress=False)
    batch = train_batch(algo, all_seeds, hyper=hyper, env_params=env_params, loop=loop)
    trainer, result, episodes = batch.trainer, batch.result, batch.episodes
    first = result.convergence.first_solved_update(len(all_seeds))
    steps_per_update = trainer.steps_per_update

    # Rows come per log group, one per runner in batch order.
    rows = result.rows
    total = len(all_seeds)
    groups = len(rows) // total
    keys = ("delivery_rate", "mean_return", "mean_length", "eval_optimal_rate", "eval_success_rate")
    table = {k: np.array([[rows[g * total + i].get(k, math.nan) for g in range(groups)] for i in range(total)],
                         dtype=np.float64) for k in keys}
    curve_steps = np.array([rows[g * total]["env_steps"] for g in range(groups)], dtype=np.int64)
    net = jax.vmap(algo.network_params)(result.runners) if keep_params else None

    out = {}
    for v, name in enumerate(names):
        sl = slice(v * len(seeds), (v + 1) * len(seeds))
        ep = jax.tree.map(lambda x: np.asarray(x)[sl], episodes)
        out[name] = VariantResult(
            name=name,
            seeds=seeds,
            episodes=ep,
            per_seed=per_seed_metrics(ep),
            first_optimal_step=[None if u is None else u * steps_per_update for u in first[sl]],
            curve_steps=curve_steps,
            curves={k: v_[sl] for k, v_ in table.items()},
            network_params=None if net is None else jax.tree.map(lambda x: x[sl], net),
        )
    timing = BatchTiming(result.compile_seconds, result.train_seconds, total, trainer.num_updates * steps_per_update)
    return out, timing


def convergence_interval(steps: Sequence[int | None], method: str = "t") -> tuple[Interval, int]:
    """CI of the convergence step over the seeds that converged, and how many did."""
    done = [s for s in steps if s is not None]
    return mean_ci(done, method=method), len(done)


# ------------------------------------------------------------------- outputs
def base_parser(description: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--out", required=True, help="output directory (created if missing)")
    parser.add_argument("--quick", action="store_true", help="tiny budgets and 2 seeds: checks that it runs")
    parser.add_argument("--seeds", type=int, default=None, help="seeds per variant (default: the experiment's)")
    parser.add_argument("--ci", choices=("t", "bootstrap"), default="t", help="confidence interval method")
    return parser


def check_seeds(seeds: int | None, default: int, quick: bool) -> int:
    n = (2 if quick else default) if seeds is None else int(seeds)
    if n < 2:
        raise SystemExit(f"error: --seeds must be at least 2 (a confidence interval needs two seeds), got {n}")
    return n


def machine_info() -> dict[str, Any]:
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    devices = jax.devices()
    return {
        "backend": jax.default_backend(),
        "device": str(devices[0].device_kind) if devices else None,
        "cpu_count": os.cpu_count(),
        "load_average": load,
        "python": platform.python_version(),
        "jax": jax.__version__,
        "host": platform.node(),
    }


def write_json(path: Path, data: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(_jsonable(data), indent=1, sort_keys=False) + "\n")
    os.replace(tmp, path)


def write_text(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def _jsonable(x: Any) -> Any:
    if isinstance(x, Interval):
        return x.to_json()
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return None if not math.isfinite(float(x)) else float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def variant_json(result: VariantResult, method: str) -> dict[str, Any]:
    conv, converged = convergence_interval(result.first_optimal_step, method)
    return {
        "seeds": result.seeds,
        "per_seed": result.per_seed,
        "ci": result.summary(method),
        "first_optimal_step": result.first_optimal_step,
        "convergence_ci": conv,
        "seeds_converged": converged,
    }


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def pct(interval: Interval) -> str:
    return interval.fmt(100.0, 1, "%")


def plot_curves(results: dict[str, VariantResult], path: Path, key: str, ylabel: str, title: str) -> None:
    """One line per variant (mean over seeds, shaded min..max) of a logged curve."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    for name, res in results.items():
        y = res.curves[key]
        x = res.curve_steps
        ok = ~np.all(np.isnan(y), axis=0)
        if not ok.any():
            continue
        with np.errstate(all="ignore"):
            mean = np.nanmean(y[:, ok], axis=0)
            lo, hi = np.nanmin(y[:, ok], axis=0), np.nanmax(y[:, ok], axis=0)
        (line,) = ax.plot(x[ok], mean, lw=2, label=name)
        ax.fill_between(x[ok], lo, hi, alpha=0.15, color=line.get_color())
    ax.set_xlabel("env steps per seed")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


def save_figure(fig: Any, path: Path) -> None:
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.png")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    os.replace(tmp, path)


class Stopwatch:
    """Wall time of the whole experiment (imports excluded)."""

    def __init__(self) -> None:
        self.t0 = time.perf_counter()

    def seconds(self) -> float:
        return time.perf_counter() - self.t0
