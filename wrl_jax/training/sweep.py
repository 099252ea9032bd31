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

import dataclasses
import itertools
import math
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
    from wrl_jax.training.variants import train_batch

    loop = loop or training.LoopConfig()
    seeds = sweep.batch_seeds
    hyper, env_params = sweep.batched_inputs()
    batch = train_batch(sweep.algo, seeds, hyper=hyper, env_params=env_params, loop=loop, mesh=mesh)
    trainer, result, episodes = batch.trainer, batch.result, batch.episodes
    init_seconds, eval_seconds = batch.init_seconds, batch.eval_seconds

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


# The outputs and the command line live in their own modules; re-exported for ``wrl_jax.sweep`` users.
from wrl_jax.training.sweep_outputs import plot_sweep, results_markdown, write_outputs  # noqa: E402
from wrl_jax.cli.sweep import build_parser, main, parse_grid, parse_sets, parse_value  # noqa: E402

__all__ = [
    "StaticFieldError",
    "Sweep",
    "SweepResult",
    "build_parser",
    "hyper_for",
    "main",
    "parse_grid",
    "parse_sets",
    "parse_value",
    "plot_sweep",
    "results_markdown",
    "run_sweep",
    "traced_fields",
    "write_outputs",
]
