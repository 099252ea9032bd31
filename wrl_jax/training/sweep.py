"""Hyperparameter sweeps as one compiled program: ``python -m wrl_jax.sweep``.

A sweep is a grid of values of *traced* fields times a list of seeds. Traced
fields are the ones an algorithm keeps in its runner state as arrays, so
``vmap`` can give every batch element its own value:

- the algorithm's traced hyperparameters (``runner.hyper``): for PPO
  ``learning_rate``, ``ent_coef``, ``gamma``, ``gae_lambda``, ``clip_eps``,
  ``vf_coef``, ``max_grad_norm``, ``reward_scale``; for DQN ``learning_rate``,
  the epsilon schedule (``exploration_initial_eps``, ``exploration_final_eps``,
  ``exploration_fraction``), ``gamma``, ``tau``, ``max_grad_norm``,
  ``huber_delta``, ``reward_scale``;
- the environment's reward constants and episode limit (``runner.env_params``):
  ``shaping_coef``, ``step_penalty``, ``obstacle_penalty``, ``wall_penalty``,
  ``pickup_reward``, ``delivery_reward``, ``max_steps``.

The grid's points x seeds become one batch (point-major: element
``g * num_seeds + s`` is point ``g``, seed ``s``), trained by the shared driver
in one program compiled once: the same code path as ``train_ppo.py`` with more
seeds. Seed ``s`` gets ``PRNGKey(s)`` at every point, so points differ only by
their values (common random numbers: a fairer comparison of points).

Static fields (network width, number of environments, rollout length,
``total_timesteps``...) fix array shapes or the program's structure; a sweep over
them is one program per value. The sweep refuses them with an error saying so;
set them for the whole sweep with ``--set FIELD=VALUE`` and run one sweep per value.

Outputs in ``--out``: ``results.md`` (a table: mean and 95 % confidence interval
over seeds per point), ``results.csv`` (one row per point and seed),
``results.json`` (everything, with timings and the command), ``metrics.csv``
(training metrics per logged update, point and seed) and ``sweep.png``
(final greedy metrics against the first grid field, one line per combination
of the others, 95 % CI error bars).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import itertools
import json
import math
import sys
import time
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from wrl_jax.stats import mean_half_width

ENV_FIELDS = (
    "step_penalty",
    "obstacle_penalty",
    "wall_penalty",
    "shaping_coef",
    "pickup_reward",
    "delivery_reward",
    "max_steps",
)
"""Environment params a sweep may vary (arrays in ``EnvParams``; ``max_steps`` is an integer)."""

STATIC_ENV_OPTIONS = ("observe_carrying", "max_items")
"""Environment options that change shapes (observation width, item capacity): static."""


class StaticFieldError(ValueError):
    """A grid over a field that fixes shapes or program structure (cannot be a ``vmap`` axis)."""


# ----------------------------------------------------------------- the grid
def traced_fields(algo: Any) -> tuple[str, ...]:
    """Names of the algorithm's traced hyperparameters: the fields of its runner's ``hyper``."""
    import jax

    template = jax.eval_shape(algo.init, jax.random.PRNGKey(0))
    return tuple(f.name for f in dataclasses.fields(template.hyper))


def hyper_for(algo: Any, config: Any) -> Any:
    """The traced hyperparameters of ``config`` in the algorithm's ``hyper`` type (float32 scalars).

    Relies on the convention both algorithms follow: every field of the runner's
    ``hyper`` is a config field of the same name.
    """
    import jax
    import jax.numpy as jnp

    template = jax.eval_shape(algo.init, jax.random.PRNGKey(0)).hyper
    values = {}
    for f in dataclasses.fields(template):
        value = getattr(config, f.name)
        values[f.name] = jnp.asarray(value, getattr(template, f.name).dtype)
    return type(template)(**values)


def _cli_value(value: Any) -> str:
    """A value as ``--set`` takes it (tuples as ``64,64``)."""
    return ",".join(str(v) for v in value) if isinstance(value, tuple) else str(value)


@dataclasses.dataclass
class Sweep:
    """A validated sweep: every grid point's config and env params, batched for one program.

    Args:
        algo_name: ``"ppo"`` or ``"dqn"`` (any name in ``wrl_jax.cli.ALGORITHM_MODULES``).
        config: the base config (a preset, with ``--set`` overrides), static for every point.
        env_name: registered environment.
        env_overrides: environment overrides common to every point.
        grid: field -> values; the sweep is their Cartesian product (in the given order).
        seeds: seed values, trained at every point.
    """

    algo_name: str
    config: Any
    env_name: str
    env_overrides: dict[str, Any]
    grid: dict[str, list[Any]]
    seeds: list[int]

    def __post_init__(self) -> None:
        import wrl_jax
        from wrl_jax import cli

        self.spec = cli.get_spec(self.algo_name)
        self.seeds = [int(s) for s in self.seeds]
        if not self.seeds:
            raise ValueError("a sweep needs at least one seed")
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"repeated seed values {self.seeds}")
        if any(s < 0 for s in self.seeds):
            raise ValueError(f"seeds must be >= 0, got {self.seeds}")
        if not self.grid:
            raise ValueError("the grid is empty: give at least one FIELD=V1,V2,... (e.g. learning_rate=0.003,0.01)")
        for key in self.env_overrides:
            if key in STATIC_ENV_OPTIONS or key == "collision_bug":
                continue
            if key not in ENV_FIELDS:
                raise ValueError(f"unknown environment override {key!r}; known: {list(ENV_FIELDS)}")
        self.config.validate()
        env, base_params = wrl_jax.make(self.env_name, **self.env_overrides)
        self.algo = self.spec.algorithm_cls(self.config, env, base_params)
        self.algo_fields = traced_fields(self.algo)
        config_fields = {f.name for f in dataclasses.fields(self.config)}
        for name, values in self.grid.items():
            if name in STATIC_ENV_OPTIONS:
                raise StaticFieldError(
                    f"environment option {name!r} is static (it fixes the observation width or the item "
                    "capacity): one compiled program per value; run one sweep per value"
                )
            if name not in self.algo_fields and name not in ENV_FIELDS:
                if name in config_fields:
                    raise StaticFieldError(
                        f"{self.spec.name} field {name!r} is static (it fixes array shapes or the program's "
                        f"structure), so it cannot be a vmap axis of one program: run one sweep per value, "
                        f"e.g. --set {name}={_cli_value(values[0])}. Traced fields that can be swept: "
                        f"{list(self.algo_fields) + list(ENV_FIELDS)}"
                    )
                raise ValueError(
                    f"unknown sweep field {name!r}; traced fields of {self.spec.name}: "
                    f"{list(self.algo_fields)}; environment: {list(ENV_FIELDS)}"
                )
            if not values:
                raise ValueError(f"sweep field {name!r} has no value")
            if len(set(values)) != len(values):
                raise ValueError(f"sweep field {name!r} repeats a value: {values}")
        self.fields = list(self.grid)
        self.points: list[dict[str, Any]] = [
            dict(zip(self.fields, combo)) for combo in itertools.product(*(self.grid[f] for f in self.fields))
        ]
        # Every point validated exactly as a single run with these values would be.
        self.point_configs, self.point_params = [], []
        for point in self.points:
            algo_values = {k: v for k, v in point.items() if k in self.algo_fields}
            env_values = {k: v for k, v in point.items() if k in ENV_FIELDS}
            try:
                config = dataclasses.replace(self.config, **algo_values)
                config.validate()
                _, params = wrl_jax.make(self.env_name, **{**self.env_overrides, **env_values})
            except ValueError as exc:
                raise ValueError(f"sweep point {point}: {exc}") from None
            self.point_configs.append(config)
            self.point_params.append(params)

    @property
    def batch_seeds(self) -> list[int]:
        """The seed of every batch element (point-major)."""
        return [seed for _ in self.points for seed in self.seeds]

    def point_of(self, index: int) -> int:
        """The grid point of batch element ``index``."""
        return index // len(self.seeds)

    def batched_inputs(self) -> tuple[Any, Any]:
        """``(hyper, env_params)`` with a leading axis of ``len(points) * len(seeds)``."""
        import jax
        import jax.numpy as jnp

        per_element_hyper = [hyper_for(self.algo, c) for c in self.point_configs for _ in self.seeds]
        per_element_params = [p for p in self.point_params for _ in self.seeds]
        hyper = jax.tree.map(lambda *xs: jnp.stack(xs), *per_element_hyper)
        env_params = jax.tree.map(lambda *xs: jnp.stack(xs), *per_element_params)
        return hyper, env_params

    def describe(self) -> dict[str, Any]:
        from wrl_jax import cli

        return {
            "algo": self.spec.name,
            "env": self.env_name,
            "env_overrides": self.env_overrides,
            "grid": self.grid,
            "seeds": self.seeds,
            "num_points": len(self.points),
            "batch": len(self.points) * len(self.seeds),
            "config": cli.config_to_dict(self.config),
        }


# ------------------------------------------------------------------ running
@dataclasses.dataclass
class SweepResult:
    """What :func:`run_sweep` returns: the driver's result plus the per-point tables."""

    sweep: Sweep
    run: Any  # training.RunResult
    per_seed: list[dict[str, Any]]  # one row per (point, seed)
    per_point: list[dict[str, Any]]  # aggregates per point
    metric_rows: list[dict[str, Any]]
    timings: dict[str, float]


SUMMARY_METRICS = ("success_rate", "optimal_rate", "mean_steps", "mean_return", "collision_free_rate")
"""Final greedy-evaluation metrics aggregated per point (mean and 95 % CI over seeds)."""


def run_sweep(
    sweep: Sweep,
    loop: Any = None,
    mesh: Any = None,
) -> SweepResult:
    """Train every point and seed of ``sweep`` in one program and evaluate them greedily.

    Args:
        sweep: the validated sweep.
        loop: a :class:`wrl_jax.training.LoopConfig` (chunking, evaluation cadence, progress).
        mesh: a ``jax.sharding.Mesh`` from :func:`wrl_jax.sharding.make_mesh` to shard
            the batch over devices; ``None`` trains on the default device.
    """
    import jax

    from wrl_jax.training import driver as training

    loop = loop or training.LoopConfig()
    seeds = sweep.batch_seeds
    if mesh is None:
        trainer = training.Trainer(sweep.algo, seeds, loop)
    else:
        from wrl_jax.training import sharding

        trainer = sharding.ShardedTrainer(sweep.algo, seeds, loop, mesh)
    t0 = time.perf_counter()
    hyper, env_params = sweep.batched_inputs()
    runners = trainer.init(hyper, env_params)
    jax.block_until_ready(runners)
    init_seconds = time.perf_counter() - t0
    result = training.run(trainer, None, runners=runners)
    t0 = time.perf_counter()
    episodes = training.final_evaluation(trainer, result)
    eval_seconds = time.perf_counter() - t0

    n_seeds = len(sweep.seeds)
    steps = trainer.steps_per_update
    first = result.convergence.first_optimal_update(len(seeds))
    stable = result.convergence.stable_optimal_update(len(seeds))
    last_train: dict[int, dict[str, Any]] = {}
    metric_rows = []
    for i, row in enumerate(result.rows):
        index = i % len(seeds)
        point = sweep.point_of(index)
        last_train[index] = row
        metric_rows.append({"point": point, **sweep.points[point], **row})

    per_seed, per_point = [], []
    for g, point in enumerate(sweep.points):
        part = jax.tree.map(lambda x: x[g * n_seeds : (g + 1) * n_seeds], episodes)
        summary = trainer.evaluation.summarize(part, sweep.seeds)
        for s, seed_summary in enumerate(summary["per_seed"]):
            index = g * n_seeds + s
            train_row = last_train.get(index, {})
            per_seed.append(
                {
                    "point": g,
                    **point,
                    "seed": sweep.seeds[s],
                    **{k: seed_summary[k] for k in SUMMARY_METRICS},
                    "all_optimal": seed_summary["optimal_rate"] == 1.0,
                    "first_optimal_step": None if first[index] is None else first[index] * steps,
                    "stable_optimal_step": None if stable[index] is None else stable[index] * steps,
                    "train_delivery_rate": _finite(train_row.get("delivery_rate")),
                    "train_mean_return": _finite(train_row.get("mean_return")),
                }
            )
        rows = per_seed[-n_seeds:]
        aggregate: dict[str, Any] = {"point": g, **point, "num_seeds": n_seeds}
        for key in SUMMARY_METRICS + ("train_delivery_rate", "first_optimal_step"):
            mean, half, count = mean_half_width([r[key] for r in rows])
            aggregate[key] = mean
            aggregate[f"{key}_ci95"] = half
            if key == "first_optimal_step":
                aggregate["converged_seeds"] = count
        aggregate["all_optimal_seeds"] = sum(bool(r["all_optimal"]) for r in rows)
        per_point.append(aggregate)
    timings = {
        "init_seconds": init_seconds,
        "compile_seconds": result.compile_seconds,
        "train_seconds": result.train_seconds,
        "eval_seconds": eval_seconds,
        "env_steps_per_element": result.updates_done * steps,
        "env_steps_per_second": result.updates_done * steps * len(seeds) / max(result.train_seconds, 1e-9),
    }
    return SweepResult(sweep, result, per_seed, per_point, metric_rows, timings)


def _finite(value: Any) -> float | None:
    return None if value is None or (isinstance(value, float) and math.isnan(value)) else float(value)


# ------------------------------------------------------------------ outputs
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


def results_markdown(result: SweepResult) -> str:
    """The per-point table: greedy evaluation after training, mean ± 95 % CI over seeds."""
    sweep = result.sweep
    n = len(sweep.seeds)
    header = (
        sweep.fields
        + [
            "greedy success",
            "greedy optimal items",
            "seeds all-optimal",
            "mean steps (delivered)",
            "greedy return",
            "train delivery (last log)",
            "first optimal step",
        ]
    )
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for p in result.per_point:
        conv = p["converged_seeds"]
        first = "none"
        if conv:
            first = f"{_fmt_ci(p['first_optimal_step'], p['first_optimal_step_ci95'], digits=0)} ({conv}/{n})"
        cells = [_fmt(p[f]) for f in sweep.fields] + [
            _fmt_ci(p["success_rate"], p["success_rate_ci95"], percent=True),
            _fmt_ci(p["optimal_rate"], p["optimal_rate_ci95"], percent=True),
            f"{p['all_optimal_seeds']}/{n}",
            _fmt_ci(p["mean_steps"], p["mean_steps_ci95"], digits=2),
            _fmt_ci(p["mean_return"], p["mean_return_ci95"]),
            _fmt_ci(p["train_delivery_rate"], p["train_delivery_rate_ci95"], percent=True),
            first,
        ]
        lines.append("| " + " | ".join(cells) + " |")
    t = result.timings
    d = sweep.describe()
    title = (
        f"{d['algo'].upper()} sweep on {d['env']}: {d['num_points']} points x {n} seeds = {d['batch']} runs "
        f"in one program, {t['env_steps_per_element']:,} env steps each; compile {t['compile_seconds']:.1f} s, "
        f"train {t['train_seconds']:.1f} s ({t['env_steps_per_second'] / 1e3:,.0f}k env steps/s)"
    )
    note = "± is the 95 % Student-t confidence interval over seeds; 'first optimal step': env steps per seed at the " \
        "first periodic greedy evaluation with every item at the BFS optimum (mean over the seeds that got there)."
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


def plot_sweep(result: SweepResult, path: Path) -> None:
    """Final greedy success rate, optimal-item rate and mean steps against the first grid field."""
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
    panels = [
        ("success_rate", "greedy success rate (%)", 100.0),
        ("optimal_rate", "items at the BFS optimum (%)", 100.0),
        ("mean_steps", "mean steps (delivered)", 1.0),
    ]
    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 4), constrained_layout=True)
    for ax, (key, label, scale) in zip(axes, panels):
        for combo, points in groups.items():
            name = ", ".join(f"{f}={_fmt(v)}" for f, v in zip(others, combo)) or None
            x = [p[x_field] for p in points]
            y = [math.nan if p[key] is None else scale * p[key] for p in points]
            err = [0.0 if p[f"{key}_ci95"] is None else scale * p[f"{key}_ci95"] for p in points]
            ax.errorbar(x if numeric else range(len(x)), y, yerr=err, marker="o", capsize=3, label=name)
        if log_x:
            ax.set_xscale("log")
        if scale == 100.0:
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


# ---------------------------------------------------------------- command line
def parse_value(text: str, hint: Any = float) -> Any:
    """A ``--grid``/``--set`` value as the field's type (``int``, ``float``, ``bool``, ``str``, ``tuple[int, ...]``)."""
    origin = typing.get_origin(hint)
    if origin is tuple:
        (item,) = {a for a in typing.get_args(hint) if a is not Ellipsis}
        return tuple(parse_value(part, item) for part in text.replace("x", ",").split(",") if part)
    if hint is bool:
        if text.lower() in ("1", "true", "yes"):
            return True
        if text.lower() in ("0", "false", "no"):
            return False
        raise ValueError(f"expected true or false, got {text!r}")
    if hint is int:
        return int(text)
    if hint is float:
        return float(text)
    if typing.get_origin(hint) is typing.Literal or hint is str:
        return text
    return float(text)


def _field_hint(config_cls: type, name: str) -> Any:
    if name == "max_steps":
        return int
    hints = typing.get_type_hints(config_cls)
    return hints.get(name, float)


def parse_grid(items: Sequence[str], config_cls: type) -> dict[str, list[Any]]:
    """``["learning_rate=0.003,0.01", "ent_coef=0.05,0.2"]`` -> ``{"learning_rate": [0.003, 0.01], ...}``."""
    grid: dict[str, list[Any]] = {}
    for item in items:
        name, sep, values = item.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or not name or not values.strip():
            raise ValueError(f"--grid expects FIELD=V1,V2,..., got {item!r}")
        if name in grid:
            raise ValueError(f"--grid gives {name!r} twice")
        hint = _field_hint(config_cls, name)
        try:
            grid[name] = [parse_value(v.strip(), hint) for v in values.split(",") if v.strip()]
        except ValueError as exc:
            raise ValueError(f"--grid {name}: {exc}") from None
    return grid


def parse_sets(items: Sequence[str], config_cls: type) -> tuple[dict[str, Any], dict[str, Any]]:
    """``--set FIELD=VALUE`` items -> (config overrides, environment overrides)."""
    config_fields = {f.name for f in dataclasses.fields(config_cls)}
    config, env = {}, {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or not name:
            raise ValueError(f"--set expects FIELD=VALUE, got {item!r}")
        if name in ENV_FIELDS:
            env[name] = parse_value(value.strip(), int if name == "max_steps" else float)
        elif name == "observe_carrying":
            env[name] = parse_value(value.strip(), bool)
        elif name in config_fields:
            try:
                config[name] = parse_value(value.strip(), _field_hint(config_cls, name))
            except ValueError as exc:
                raise ValueError(f"--set {name}: {exc}") from None
        else:
            raise ValueError(f"--set: unknown field {name!r}; config fields: {sorted(config_fields)}; "
                             f"environment: {list(ENV_FIELDS) + ['observe_carrying']}")
    return config, env


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m wrl_jax.sweep",
        description="A grid of traced hyperparameters x seeds trained as one compiled program; writes a results "
        "table (Markdown, CSV, JSON) and a plot.",
        epilog="Example: python -m wrl_jax.sweep --algo ppo --env Warehouse-8x8-v0 --grid learning_rate=0.003,0.01 "
        "--grid ent_coef=0.02,0.2 --grid shaping_coef=0,2 --num-seeds 4 --set total_timesteps=60000 --out runs/sweep",
    )
    parser.add_argument("--algo", required=True, help="ppo or dqn")
    parser.add_argument("--env", default=None, help="registered environment (default: the algorithm's)")
    parser.add_argument("--preset", default=None, help="base hyperparameter preset (default: the algorithm's)")
    parser.add_argument("--grid", action="append", default=[], metavar="FIELD=V1,V2,...",
                        help="a traced field and its values (repeat for more fields; the grid is their product)")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="a value for the whole sweep (static fields such as total_timesteps, hidden_sizes=64,64, "
                        "or environment constants)")
    parser.add_argument("--num-seeds", type=int, default=4, help="seeds per grid point")
    parser.add_argument("--seed", type=int, default=0, help="first seed (seeds seed .. seed + num_seeds - 1)")
    parser.add_argument("--out", default=None, help="output directory (default runs/sweep-<algo>-<time>)")
    parser.add_argument("--eval-every", type=int, default=None, help="greedy evaluation every N updates (0: last only)")
    parser.add_argument("--chunk-updates", type=int, default=None)
    parser.add_argument("--log-every", type=int, default=None)
    parser.add_argument("--devices", type=int, default=1,
                        help="shard the batch of points x seeds over this many devices (0: all; 1: no sharding)")
    parser.add_argument("--env-shards", type=int, default=1,
                        help="of those devices, how many split each run's environments")
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument("--no-plot", action="store_true")
    parser.add_argument("--xla-opt-level", type=int, default=None, help="XLA CPU optimization level (default 1)")
    return parser


def main(argv: list[str] | None = None) -> int:
    """``python -m wrl_jax.sweep``; status 2 with ``error: ...`` on a bad sweep."""
    import datetime

    from wrl_jax import cli

    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    try:
        spec = cli.get_spec(args.algo)
        preset = args.preset or spec.default_preset
        if preset not in spec.presets:
            raise ValueError(f"unknown {spec.name} preset {preset!r}; choose from {sorted(spec.presets)}")
        config_sets, env_sets = parse_sets(args.set, spec.config_cls)
        config = dataclasses.replace(spec.presets[preset], **config_sets)
        grid = parse_grid(args.grid, spec.config_cls)
        if args.num_seeds < 1:
            raise ValueError(f"--num-seeds must be at least 1, got {args.num_seeds}")
        if args.devices < 0 or args.env_shards < 1:
            raise ValueError("--devices must be >= 0 and --env-shards >= 1")
        cli.apply_xla_opt_level(cli.DEFAULT_XLA_OPT_LEVEL if args.xla_opt_level is None else args.xla_opt_level)
        sweep = Sweep(
            algo_name=spec.name,
            config=config,
            env_name=args.env or spec.default_env,
            env_overrides=env_sets,
            grid=grid,
            seeds=list(range(args.seed, args.seed + args.num_seeds)),
        )
        from wrl_jax.training import driver as training

        loop = training.LoopConfig(
            chunk_updates=args.chunk_updates,
            eval_every=args.eval_every,
            log_every=args.log_every,
            progress=not args.no_progress,
        )
        loop.resolve(sweep.algo.num_updates)
        mesh = None
        if args.devices != 1 or args.env_shards != 1:
            from wrl_jax.training import sharding

            mesh = sharding.make_mesh(args.devices, args.env_shards)
            sharding.check_layout(len(sweep.batch_seeds), getattr(config, "num_envs", None), mesh)
            print(f"sharding over {sharding.describe(mesh)}", file=sys.stderr)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else Path("runs") / (
        f"sweep-{spec.name}-{datetime.datetime.now().strftime('%Y%m%d-%H%M%S')}"
    )
    wall = time.perf_counter()
    result = run_sweep(sweep, loop, mesh)
    result.timings["wall_seconds"] = time.perf_counter() - wall
    command = "python -m wrl_jax.sweep " + " ".join(argv)
    write_outputs(result, out, command, plot=not args.no_plot)
    print(results_markdown(result))
    plot_name = "" if args.no_plot else ", sweep.png"
    print(f"outputs in {out}/ (results.md, results.csv, results.json, metrics.csv{plot_name})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
