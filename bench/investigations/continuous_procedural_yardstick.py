"""The pursuit controller on the procedural continuous warehouse's generalization sets (issue 34).

The final report of a training run on ``Continuous-Procedural-Warehouse-v0`` puts the controller beside every
held-out and out-of-distribution set, on the same episodes. Those episodes do not depend on the policy, so
this script runs the same final report with a policy that stands still and prints only the controller's
numbers: the column beside a run trained before the report had it (docs/continuous.md, "Generalization").
``--study-copies N`` also runs the study's 12x12 map N times over (other keys, the same map), with and without
randomization, to show how much the controller's steps move with the draws.

    python bench/investigations/continuous_procedural_yardstick.py            # about a minute
"""

from __future__ import annotations

import argparse
import time

import jax.numpy as jnp

import wrl_jax
from wrl_jax.agents.off_policy_config import CONTINUOUS_ENV_DEFAULTS
from wrl_jax.core.evaluation import FinalContext
from wrl_jax.envs.continuous import procedural_evaluation
from wrl_jax.envs.procedural.layout import stack
from wrl_jax.envs.procedural.layout_sets import LayoutSet, study_layout


class StandStill:
    """A policy that never moves: the report's policy columns are not read here."""

    @staticmethod
    def greedy_action(network_params, obs):
        return jnp.zeros(2, jnp.float32) * network_params


def line(name: str, entry: dict) -> str:
    if "pursuit" not in entry:
        return f"{name:>16}: {entry['layouts']:4d} layouts; no pursuit: {entry.get('pursuit_unavailable', 'no episodes')}"
    pursuit = entry["pursuit"]
    steps = "n/a" if pursuit["mean_steps"] is None else f"{pursuit['mean_steps']:.1f}"
    bound = f", bound {entry['bound_steps']:.2f}" if "bound_steps" in entry else ""
    return (f"{name:>16}: {entry['layouts']:4d} layouts, {entry['episodes_per_seed']:5d} episodes; pursuit "
            f"{100 * pursuit['success_rate']:.1f} % delivered, {pursuit['collisions_per_episode']:.3f} collisions "
            f"per episode, {steps} steps{bound}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study-copies", type=int, default=12, help="copies of the study's 12x12 map (0: none)")
    args = parser.parse_args()
    env, params = wrl_jax.make("Continuous-Procedural-Warehouse-v0", **CONTINUOUS_ENV_DEFAULTS)
    start = time.perf_counter()
    context = FinalContext(algo=StandStill, network_params=jnp.ones((1,), jnp.float32), env=env, params=params,
                           seeds=[0])
    report = procedural_evaluation.final_report(context)
    print(f"final report's sets ({time.perf_counter() - start:.0f} s):")
    print(line("heldout", report["heldout"]))
    for name, entry in report["ood"].items():
        print(line(name, entry))
    if args.study_copies > 0:
        copies = LayoutSet("study_12x12", "12x12", stack([study_layout("12x12", env.generator.max_shape)]
                                                         * args.study_copies))
        for randomize in (True, False):
            entry = procedural_evaluation.evaluate_layout_sets(
                StandStill.greedy_action, jnp.ones((1,), jnp.float32), env,
                params.replace(randomize=jnp.bool_(randomize)), [copies], [0])["study_12x12"]
            print(line(f"12x12 x{args.study_copies}" + (", randomized" if randomize else ""), entry))


if __name__ == "__main__":
    main()
