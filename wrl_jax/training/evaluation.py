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
        progress_metric: ``(seed_summary key, label)`` shown on the progress bar.
        final_report: optional ``FinalContext -> dict``, run once after training
            (and by ``python -m wrl_jax.evaluate``) on the host: evaluations too
            large or too different to run inside the training loop (held-out
            sets, planners beside the policy, the sampled policy, media). Its
            result is merged into ``summary.json``'s ``eval`` before
            ``format_report`` and ``format_details`` see the summary.
    """

    evaluate_policy: Callable[..., Any]
    seed_summary: Callable[[Any], dict[str, jax.Array]]
    solved_key: str
    solved_definition: str
    summarize: Callable[[Any, Sequence[int] | None], dict[str, Any]]
    format_report: Callable[..., str]
    format_details: Callable[[dict[str, Any]], str]
    progress_metric: tuple[str, str] = ("eval_success_rate", "eval success")
    final_report: Callable[["FinalContext"], dict[str, Any]] | None = None

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
    """

    algo: Any
    network_params: Any
    env: Any
    params: Any
    seeds: Sequence[int]
    out_dir: Any = None


def run_final_report(evaluation: FamilyEvaluation, trainer: Any, runners: Any, out_dir: Any = None) -> dict[str, Any]:
    """``evaluation.final_report`` of a trainer's runners (``{}`` when the family has none)."""
    if evaluation.final_report is None:
        return {}
    network_params = jax.vmap(trainer.algo.network_params)(runners)
    params = jax.tree.map(lambda x: x[0], runners.env_params)
    context = FinalContext(algo=trainer.algo, network_params=network_params, env=trainer.algo.env, params=params,
                           seeds=list(trainer.seeds), out_dir=out_dir)
    return evaluation.final_report(context)


def for_env(env: Any) -> FamilyEvaluation:
    """The evaluation of ``env``'s family (``env.family``), registered in :mod:`wrl_jax.envs`."""
    family = getattr(env, "family", None)
    if family is None:
        raise ValueError(f"{env!r} declares no environment family (a 'family' class attribute)")
    return registry.evaluation(family)
