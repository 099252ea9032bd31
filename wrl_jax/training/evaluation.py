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
    """

    evaluate_policy: Callable[..., Any]
    seed_summary: Callable[[Any], dict[str, jax.Array]]
    solved_key: str
    solved_definition: str
    summarize: Callable[[Any, Sequence[int] | None], dict[str, Any]]
    format_report: Callable[..., str]
    format_details: Callable[[dict[str, Any]], str]
    progress_metric: tuple[str, str] = ("eval_success_rate", "eval success")

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


def for_env(env: Any) -> FamilyEvaluation:
    """The evaluation of ``env``'s family (``env.family``), registered in :mod:`wrl_jax.envs`."""
    family = getattr(env, "family", None)
    if family is None:
        raise ValueError(f"{env!r} declares no environment family (a 'family' class attribute)")
    return registry.evaluation(family)
