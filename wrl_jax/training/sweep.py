"""Hyperparameter sweeps as one compiled program: ``python -m wrl_jax.sweep``.

A sweep is a grid of values of *traced* fields times a list of seeds, on any
registered environment (the single-robot warehouse, the procedural warehouse,
the multi-robot fleet). Traced fields are the ones an algorithm keeps in its
runner state as arrays, so ``vmap`` can give every batch element its own value:

- the algorithm's traced hyperparameters (``runner.hyper``): for PPO
  ``learning_rate``, ``ent_coef``, ``gamma``, ``gae_lambda``, ``clip_eps``,
  ``vf_coef``, ``max_grad_norm``, ``reward_scale``; for DQN ``learning_rate``,
  the epsilon schedule (``exploration_initial_eps``, ``exploration_final_eps``,
  ``exploration_fraction``), ``gamma``, ``tau``, ``max_grad_norm``,
  ``huber_delta``, ``reward_scale``;
- the environment's scalar params (``runner.env_params``): any option of
  ``wrl_jax.make`` stored as a 0-d array in the environment's params, e.g. the
  reward constants (``shaping_coef``, ``step_penalty``...) and ``max_steps`` of
  every family, the fleet's ``block_penalty``, the warehouse's
  ``collision_bug``. No list of them lives here: a new family's params are
  sweepable as they are.

The grid's points x seeds become one batch (point-major: element
``g * num_seeds + s`` is point ``g``, seed ``s``), trained by the shared driver
in one program compiled once: the same code path as ``train_ppo.py`` with more
seeds. Seed ``s`` gets ``PRNGKey(s)`` at every point, so points differ only by
their values (common random numbers: a fairer comparison of points).

Static fields (network width, number of environments, rollout length,
``total_timesteps``; environment options that fix shapes or live on the
environment object: the fleet's ``num_robots``, ``view_radius`` and
``shaping``, the procedural ``pool_size``, the warehouse's
``observe_carrying``...) fix array shapes or the program's structure; a sweep
over them is one program per value. The sweep refuses them with an error saying
so; set them for the whole sweep with ``--set FIELD=VALUE`` and run one sweep
per value. (The fleet's periodic evaluation runs shifts of the base
environment's ``max_steps``, a scan length, at every point: a grid over the
fleet's ``max_steps`` changes training episodes, not the evaluation's.)

Results come from the family's evaluation hook
(:class:`~wrl_jax.core.evaluation.FamilyEvaluation`): its
``sweep_columns`` name the headline metrics of its per-seed summary (the
warehouse: greedy success, optimal items, steps, return; the fleet:
throughput, ratio to PIBT, blocks per robot per 100 steps; the procedural
warehouse: held-out delivery, optimal rate, excess steps), so this module
knows no family's metrics. The convergence columns are generic: the first
(``first_optimal_step``) and stable (``stable_optimal_step``) step at which
the periodic evaluation met the family's solved criterion (``solved_key``).

Example (the fleet: a grid over the block penalty, two robots):

    python -m wrl_jax.sweep --algo ppo --env Fleet-12x12-v0 --set num_robots=2 \\
        --grid block_penalty=-1,-5 --grid ent_coef=0.05,0.2 --num-seeds 4 --out runs/sweep-fleet

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
from typing import Any

from wrl_jax.training.sweep_columns import (
    default_columns,
    evaluation_values,
    point_row,
    solved_flags,
    summary_rows,
    training_values,
)


class StaticFieldError(ValueError):
    """A grid over a field that fixes shapes or program structure (cannot be a ``vmap`` axis)."""


# ----------------------------------------------------------------- the grid
def traced_fields(algo: Any) -> tuple[str, ...]:
    """Names of the algorithm's traced hyperparameters: the fields of its runner's ``hyper``."""
    import jax

    template = jax.eval_shape(algo.init, jax.random.PRNGKey(0))
    return tuple(f.name for f in dataclasses.fields(template.hyper))


def hyper_for(algo: Any, config: Any, template: Any = None) -> Any:
    """The traced hyperparameters of ``config`` in the algorithm's ``hyper`` type (float32 scalars).

    Relies on the convention both algorithms follow: every field of the runner's
    ``hyper`` is a config field of the same name. ``template``: the runner's
    ``hyper`` shapes, when the caller has them (tracing ``algo.init`` once per
    point costs a fleet sweep seconds).
    """
    import jax
    import jax.numpy as jnp

    if template is None:
        template = jax.eval_shape(algo.init, jax.random.PRNGKey(0)).hyper
    values = {}
    for f in dataclasses.fields(template):
        value = getattr(config, f.name)
        values[f.name] = jnp.asarray(value, getattr(template, f.name).dtype)
    return type(template)(**values)


def is_traced_env_field(params: Any, name: str) -> bool:
    """Whether ``name`` is a scalar (0-d array) leaf of an environment's params.

    Such a value can differ along a ``vmap`` axis of one program: the
    environment reads it from ``params`` at run time. Anything else an
    environment is built from (robot count, view radius, pool size, observation
    switches on the environment object) fixes shapes or code.
    """
    import jax
    import numpy as np

    value = getattr(params, name, None)
    return isinstance(value, (jax.Array, np.ndarray)) and value.ndim == 0


def traced_env_fields(params: Any) -> tuple[str, ...]:
    """The scalar leaves of an environment's params (a dataclass): the candidates of a sweep."""
    return tuple(f.name for f in dataclasses.fields(params) if is_traced_env_field(params, f.name))


def _cli_value(value: Any) -> str:
    """A value as ``--set`` takes it (tuples as ``64,64``)."""
    return ",".join(str(v) for v in value) if isinstance(value, tuple) else str(value)


def _python_value(value: Any) -> Any:
    """A 0-d params leaf as a plain Python number (what ``wrl_jax.make`` takes)."""
    return value.item() if hasattr(value, "item") else value


@dataclasses.dataclass
class Sweep:
    """A validated sweep: every grid point's config and env params, batched for one program.

    Args:
        algo_name: ``"ppo"``, ``"dqn"``, ``"sac"`` or ``"td3"`` (any name in ``wrl_jax.agents.ALGORITHM_MODULES``).
        config: the base config (a preset, with ``--set`` overrides), static for every point.
        env_name: registered environment (any family).
        env_overrides: environment options common to every point: anything
            ``wrl_jax.make(env_name, ...)`` accepts (static ones included).
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
        from wrl_jax import agents

        self.spec = agents.get_spec(self.algo_name)
        self._check_seeds_and_grid()
        self.config.validate()
        env, base_params = self._make({}, f"environment overrides {self.env_overrides}")
        self.base_params = base_params
        self.algo = self.spec.algorithm_cls(self.config, env, base_params)
        self.algo_fields = traced_fields(self.algo)
        self.env_fields: list[str] = []
        for name, values in self.grid.items():
            if name in self.algo_fields:
                continue
            self._check_static_config_field(name, values)
            self._check_env_field(name, values)
            self.env_fields.append(name)
        self.fields = list(self.grid)
        self.points: list[dict[str, Any]] = [
            dict(zip(self.fields, combo)) for combo in itertools.product(*(self.grid[f] for f in self.fields))
        ]
        # Every point validated exactly as a single run with these values would be.
        self.point_configs, self.point_params = [], []
        for point in self.points:
            algo_values = {k: v for k, v in point.items() if k in self.algo_fields}
            env_values = {k: v for k, v in point.items() if k in self.env_fields}
            try:
                config = dataclasses.replace(self.config, **algo_values)
                config.validate()
            except ValueError as exc:
                raise ValueError(f"sweep point {point}: {exc}") from None
            _, params = self._make(env_values, f"sweep point {point}")
            self.point_configs.append(config)
            self.point_params.append(params)

    # ------------------------------------------------------------ validation
    def _check_seeds_and_grid(self) -> None:
        self.seeds = [int(s) for s in self.seeds]
        if not self.seeds:
            raise ValueError("a sweep needs at least one seed")
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"repeated seed values {self.seeds}")
        if any(s < 0 for s in self.seeds):
            raise ValueError(f"seeds must be >= 0, got {self.seeds}")
        if not self.grid:
            raise ValueError("the grid is empty: give at least one FIELD=V1,V2,... (e.g. learning_rate=0.003,0.01)")
        for name, values in self.grid.items():
            if not values:
                raise ValueError(f"sweep field {name!r} has no value")
            if len(set(values)) != len(values):
                raise ValueError(f"sweep field {name!r} repeats a value: {values}")

    def _make(self, values: dict[str, Any], context: str) -> tuple[Any, Any]:
        """``wrl_jax.make`` with the common overrides and ``values``; its ``ValueError`` prefixed by ``context``."""
        import wrl_jax

        try:
            return wrl_jax.make(self.env_name, **{**self.env_overrides, **values})
        except ValueError as exc:
            raise ValueError(f"{context} on {self.env_name}: {exc}") from None

    def _sweepable(self) -> list[str]:
        """Every traced field: the algorithm's and the environment's that ``make`` accepts (for messages)."""
        import wrl_jax

        accepted = []
        for name in traced_env_fields(self.base_params):
            try:
                wrl_jax.make(self.env_name, **{**self.env_overrides,
                                               name: _python_value(getattr(self.base_params, name))})
            except (ValueError, TypeError):
                continue
            accepted.append(name)
        return list(self.algo_fields) + accepted

    def _check_static_config_field(self, name: str, values: list[Any]) -> None:
        """A config field that is not in the runner's ``hyper`` is static: refuse it."""
        if name in {f.name for f in dataclasses.fields(self.config)}:
            raise StaticFieldError(
                f"{self.spec.name} field {name!r} is static (it fixes array shapes or the program's "
                f"structure), so it cannot be a vmap axis of one program: run one sweep per value, "
                f"e.g. --set {name}={_cli_value(values[0])}. Traced fields that can be swept: {self._sweepable()}"
            )

    def _check_env_field(self, name: str, values: list[Any]) -> None:
        """An environment field is traced iff it is a scalar params leaf; else static, or unknown to ``make``.

        A params leaf's values are checked point by point (with the message a
        single run would give); any other name is tried once with ``make``.
        """
        import wrl_jax

        if is_traced_env_field(self.base_params, name):
            return
        try:
            wrl_jax.make(self.env_name, **{**self.env_overrides, name: values[0]})
        except (ValueError, TypeError) as exc:
            raise ValueError(
                f"unknown sweep field {name!r}: not a traced field of {self.spec.name} {list(self.algo_fields)}, "
                f"and {self.env_name} does not take it ({exc}). Traced fields that can be swept: {self._sweepable()}"
            ) from None
        raise StaticFieldError(
            f"environment option {name!r} is static on {self.env_name} (it fixes array shapes or lives on the "
            f"environment object, not in its params): one compiled program per value; run one sweep per value, "
            f"e.g. --set {name}={_cli_value(values[0])}. Traced fields that can be swept: {self._sweepable()}"
        )

    # ------------------------------------------------------------- batching
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

        template = jax.eval_shape(self.algo.init, jax.random.PRNGKey(0)).hyper
        per_point_hyper = [hyper_for(self.algo, c, template) for c in self.point_configs]
        per_element_hyper = [h for h in per_point_hyper for _ in self.seeds]
        per_element_params = [p for p in self.point_params for _ in self.seeds]
        hyper = jax.tree.map(lambda *xs: jnp.stack(xs), *per_element_hyper)
        env_params = jax.tree.map(lambda *xs: jnp.stack(xs), *per_element_params)
        return hyper, env_params

    def describe(self) -> dict[str, Any]:
        from wrl_jax.agents.base import config_to_dict

        return {
            "algo": self.spec.name,
            "env": self.env_name,
            "env_overrides": self.env_overrides,
            "grid": self.grid,
            "seeds": self.seeds,
            "num_points": len(self.points),
            "batch": len(self.points) * len(self.seeds),
            "config": config_to_dict(self.config),
        }


# ------------------------------------------------------------------ running
@dataclasses.dataclass
class SweepResult:
    """What :func:`run_sweep` returns: the driver's result plus the per-point tables.

    ``columns`` (a :class:`~wrl_jax.core.evaluation.SweepColumns`) names the
    family's metrics in ``per_seed`` and ``per_point``; ``solved_definition`` is the
    family's, for the convergence column.
    """

    sweep: Sweep
    run: Any  # training.RunResult
    per_seed: list[dict[str, Any]]  # one row per (point, seed)
    per_point: list[dict[str, Any]]  # aggregates per point
    metric_rows: list[dict[str, Any]]
    timings: dict[str, float]
    columns: Any = None
    solved_definition: str = ""


def run_sweep(
    sweep: Sweep,
    loop: Any = None,
    mesh: Any = None,
) -> SweepResult:
    """Train every point and seed of ``sweep`` in one program and evaluate them greedily.

    Args:
        sweep: the validated sweep.
        loop: a :class:`wrl_jax.training.LoopConfig` (chunking, evaluation cadence, progress).
        mesh: a ``jax.sharding.Mesh`` from :func:`wrl_jax.training.sharding.make_mesh` to shard
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
    evaluation = trainer.evaluation

    n_seeds = len(sweep.seeds)
    steps = trainer.steps_per_update
    first = result.convergence.first_solved_update(len(seeds))
    stable = result.convergence.stable_solved_update(len(seeds))
    last_train: dict[int, dict[str, Any]] = {}
    metric_rows = []
    for i, row in enumerate(result.rows):
        index = i % len(seeds)
        point = sweep.point_of(index)
        last_train[index] = row
        metric_rows.append({"point": point, **sweep.points[point], **row})

    columns = evaluation.sweep_columns
    per_seed, per_point = [], []
    for g, point in enumerate(sweep.points):
        part = jax.tree.map(lambda x: x[g * n_seeds : (g + 1) * n_seeds], episodes)
        seed_rows = summary_rows(evaluation.summarize(part, sweep.seeds),
                                  ("per_seed",) if columns is None else columns.rows)
        if columns is None:
            columns = default_columns(seed_rows)
        solved = solved_flags(evaluation, part)
        rows = []
        for s, seed_row in enumerate(seed_rows):
            index = g * n_seeds + s
            row = {"point": g, **point, "seed": sweep.seeds[s]}
            row.update(evaluation_values(columns, seed_row, solved[s]))
            row["first_optimal_step"] = None if first[index] is None else first[index] * steps
            row["stable_optimal_step"] = None if stable[index] is None else stable[index] * steps
            row.update(training_values(columns, last_train.get(index, {})))
            rows.append(row)
        per_seed.extend(rows)
        per_point.append(point_row(columns, {"point": g, **point, "num_seeds": n_seeds}, rows))
    timings = {
        "init_seconds": batch.init_seconds,
        "compile_seconds": result.compile_seconds,
        "train_seconds": result.train_seconds,
        "eval_seconds": batch.eval_seconds,
        "env_steps_per_element": result.updates_done * steps,
        "env_steps_per_second": result.updates_done * steps * len(seeds) / max(result.train_seconds, 1e-9),
    }
    return SweepResult(sweep, result, per_seed, per_point, metric_rows, timings, columns,
                       evaluation.solved_definition)


__all__ = [
    "StaticFieldError",
    "Sweep",
    "SweepResult",
    "hyper_for",
    "is_traced_env_field",
    "run_sweep",
    "traced_env_fields",
    "traced_fields",
]
