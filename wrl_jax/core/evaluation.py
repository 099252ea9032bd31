"""The evaluation hook: what the training driver and the CLI ask of an environment family.

The driver knows nothing of items, deliveries or BFS optima. It asks the
family of the environment being trained (``env.family``, e.g. ``"warehouse"``)
for a :class:`FamilyEvaluation`: how to run the greedy policy of one seed
(jittable, inside the compiled training loop), which per-seed scalars to log,
which of them says a seed has *solved* its task (its first occurrence is the
seed's convergence step), and how to summarize and print the final result.
Each family registers its evaluation once in :mod:`wrl_jax.envs`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import jax

from wrl_jax.core import registry

GreedyFn = Callable[[Any, jax.Array], jax.Array]
"""``greedy_action(network_params, obs) -> action`` for one observation."""


@dataclasses.dataclass(frozen=True)
class PolicyMemory:
    """A policy that keeps something between the steps of a batch of episodes (batch-level functions).

    PPO's propagation encoder keeps each episode's propagated values until its leg (map and target)
    changes, so an evaluation propagates once per leg instead of once per step. ``init(network_params,
    obs)`` gives the memory of a batch ``(B, obs_size)``; ``greedy(network_params, memory, obs)`` and
    ``sample(network_params, memory, obs, keys)`` (one key per row) give ``(actions (B,), memory)``,
    the same actions as :meth:`~wrl_jax.agents.base.Algorithm.greedy_action` and ``sample_action`` row by row
    (an evaluation given a memory uses it instead of those). ``sample`` may be ``None`` for a policy without
    a sampled form.
    """

    init: Callable[[Any, jax.Array], Any]
    greedy: Callable[[Any, Any, jax.Array], tuple[jax.Array, Any]]
    sample: Callable[[Any, Any, jax.Array, jax.Array], tuple[jax.Array, Any]] | None = None


METRIC_KINDS = ("percent", "ratio", "number", "solved")
"""How a :class:`SweepMetric` is shown: ``percent`` a rate in [0, 1] (shown in %, plotted on
0-100 %), ``ratio`` a ratio shown in % but unbounded (e.g. throughput over PIBT's), ``number``
a plain number, ``solved`` the family's solved criterion (:attr:`FamilyEvaluation.solved_key`)
at the final evaluation: a flag per seed, counted per point."""


@dataclasses.dataclass(frozen=True)
class SweepMetric:
    """One column of a sweep's results (``python -m wrl_jax.sweep``).

    Attributes:
        key: the key in the family's per-seed summary rows (see :class:`SweepColumns`),
            or in the training metric rows for :attr:`SweepColumns.train`; for kind
            ``solved``, the name of the per-seed flag in the sweep's outputs.
        label: the column title in ``results.md``.
        kind: one of :data:`METRIC_KINDS`.
        digits: decimals shown in ``results.md``.
        table: shown in ``results.md`` (otherwise only in the CSV and JSON files).
        plot: the y-axis label of a panel of ``sweep.png`` (``None``: no panel).
        aggregate: averaged per point (mean and 95 % interval over seeds) in ``results.json``.
    """

    key: str
    label: str
    kind: str = "number"
    digits: int = 1
    table: bool = True
    plot: str | None = None
    aggregate: bool = True

    def __post_init__(self) -> None:
        if self.kind not in METRIC_KINDS:
            raise ValueError(f"SweepMetric {self.key!r}: kind must be one of {METRIC_KINDS}, got {self.kind!r}")


@dataclasses.dataclass(frozen=True)
class TrainRate:
    """A rate of the training log, derived per log group from a sum the training loop counted.

    Attributes:
        name: the metric's key in the log rows (``delivery_rate``, ``train_throughput``).
        label: its name on a learning-curve panel.
        sum_key: the summed metric it divides: ``terminated`` (episodes that ended by
            termination, :class:`~wrl_jax.agents.base.EpisodeSums`) or an event sum the
            environment declares (:attr:`~wrl_jax.core.environment.Environment.event_metrics`).
        per: ``"episode"`` (over the group's ended episodes; shown in %) or ``"step"``
            (over the group's environment steps per seed).
        progress: its label on the progress bar (``None``: not shown there).
    """

    name: str
    label: str
    sum_key: str
    per: str = "episode"
    progress: str | None = None

    def __post_init__(self) -> None:
        if self.per not in ("episode", "step"):
            raise ValueError(f"TrainRate {self.name!r}: per must be 'episode' or 'step', got {self.per!r}")


@dataclasses.dataclass(frozen=True)
class SweepColumns:
    """What a sweep reports for one family: its headline metrics, in table order.

    A sweep evaluates every point's seeds with :attr:`FamilyEvaluation.summarize`
    and reads one row of numbers per seed from it; this says where those rows
    are and which of their keys are worth a column, so the sweep itself knows no
    family's metrics.

    Attributes:
        metrics: per-seed metrics of the final greedy evaluation (table order).
        train: metrics of each seed's last training log row (``delivery_rate``,
            ``train_throughput``...); a missing key is ``None``.
        rows: the path of keys in ``summarize``'s result to its list of per-seed rows.
        convergence_label: the title of the convergence column (the first step at
            which the periodic evaluation met the solved criterion).
        convergence_note: what that column means, under the table (default:
            :attr:`FamilyEvaluation.solved_definition`).
    """

    metrics: tuple[SweepMetric, ...]
    train: tuple[SweepMetric, ...] = ()
    rows: tuple[str, ...] = ("per_seed",)
    convergence_label: str = "first solved step"
    convergence_note: str | None = None


@dataclasses.dataclass(frozen=True)
class FamilyEvaluation:
    """How one environment family evaluates a policy.

    Attributes:
        evaluate_policy: ``(greedy_action, network_params, env, params) -> result``,
            a pytree of arrays for one seed; jittable (runs inside training).
        seed_summary: ``result -> {"eval_<name>": float32 scalar}``, jittable;
            the per-seed metrics logged at every periodic evaluation.
        solved_key: the ``seed_summary`` key that is 1.0 when a seed's policy
            solves the task (convergence is its first occurrence).
        solved_definition: what "solved" means, in words (for ``summary.json``).
        summarize: ``(batched result, seeds) -> dict``: plain Python numbers for
            ``summary.json``'s ``eval`` (the leading axis of the result is seeds).
        format_report: ``(summary, label, convergence_steps, study) -> str``: the
            Markdown table printed after training and written to ``evaluation.md``.
        format_details: ``summary -> str``: a second, detailed table (may be empty).
        progress_metric: ``(seed_summary key, label)`` shown on the progress bar and
            plotted beside the training curves.
        progress_percent: the progress metric is a rate, shown as a percentage (``False``: a
            number such as a return, shown as it is).
        train_rates: the family's :class:`TrainRate` s, derived in every log row
            (the driver itself derives only ``mean_return`` and ``mean_length``).
        final_report: optional ``FinalContext -> dict``, run once after training
            (and by ``python -m wrl_jax.evaluate``) on the host: evaluations too
            large or too different to run inside the training loop (held-out
            sets, planners beside the policy, the sampled policy, media). Its
            result is merged into ``summary.json``'s ``eval`` before
            ``format_report`` and ``format_details`` see the summary.
        sweep_columns: optional :class:`SweepColumns`: the columns of a sweep's
            results (``python -m wrl_jax.sweep``); ``None``: every number of the
            per-seed rows of ``summarize``, in their order.
    """

    evaluate_policy: Callable[..., Any]
    seed_summary: Callable[[Any], dict[str, jax.Array]]
    solved_key: str
    solved_definition: str
    summarize: Callable[[Any, Sequence[int] | None], dict[str, Any]]
    format_report: Callable[..., str]
    format_details: Callable[[dict[str, Any]], str]
    progress_metric: tuple[str, str] = ("eval_success_rate", "eval success")
    progress_percent: bool = True
    train_rates: tuple[TrainRate, ...] = ()
    final_report: Callable[["FinalContext"], dict[str, Any]] | None = None
    sweep_columns: SweepColumns | None = None

    def evaluate_seeds(
        self, greedy_action: GreedyFn, network_params: Any, env: Any, params: Any, params_batched: bool = False
    ) -> Any:
        """:attr:`evaluate_policy` over a leading seed axis of ``network_params``.

        ``params`` is shared by every seed unless ``params_batched`` (a sweep over
        environment constants, or a runner's per-seed copy of them).
        """
        return jax.vmap(
            lambda p, e: self.evaluate_policy(greedy_action, p, env, e), in_axes=(0, 0 if params_batched else None)
        )(network_params, params)


@dataclasses.dataclass(frozen=True)
class FinalContext:
    """What a family's :attr:`FamilyEvaluation.final_report` gets.

    Attributes:
        algo: the trained :class:`~wrl_jax.agents.base.Algorithm` (``greedy_action``,
            and ``sample_action`` where the algorithm has a stochastic policy).
        network_params: every seed's policy parameters (leading axis: seeds).
        env: the environment trained on.
        params: the environment params of the first seed (a sweep's per-seed
            constants are not re-evaluated here).
        seeds: the seed values, in the order of ``network_params``.
        out_dir: the run directory (for media), or ``None``.
        updates_done: the updates trained (what an environment whose params change
            between updates needs to list what training saw), or ``None`` if unknown.
    """

    algo: Any
    network_params: Any
    env: Any
    params: Any
    seeds: Sequence[int]
    out_dir: Any = None
    updates_done: int | None = None


def run_final_report(evaluation: FamilyEvaluation, trainer: Any, runners: Any, out_dir: Any = None,
                     updates_done: int | None = None) -> dict[str, Any]:
    """``evaluation.final_report`` of a trainer's runners (``{}`` when the family has none)."""
    if evaluation.final_report is None:
        return {}
    network_params = jax.vmap(trainer.algo.network_params)(runners)
    params = jax.tree.map(lambda x: x[0], runners.env_params)
    context = FinalContext(algo=trainer.algo, network_params=network_params, env=trainer.algo.env, params=params,
                           seeds=list(trainer.seeds), out_dir=out_dir, updates_done=updates_done)
    return evaluation.final_report(context)


def percent_text(x: float | None) -> str:
    """A rate in [0, 1] as report text (``"97.5%"``); ``"n/a"`` when there is none."""
    return "n/a" if x is None else f"{100.0 * x:.1f}%"


def number_text(x: float | None, fmt: str = "{:.1f}") -> str:
    """A number as report text in ``fmt``; ``"n/a"`` when there is none."""
    return "n/a" if x is None else fmt.format(x)


def for_env(env: Any) -> FamilyEvaluation:
    """The evaluation of ``env``'s family (``env.family``), registered in :mod:`wrl_jax.envs`."""
    family = getattr(env, "family", None)
    if family is None:
        raise ValueError(f"{env!r} declares no environment family (a 'family' class attribute)")
    return registry.evaluation(family)
