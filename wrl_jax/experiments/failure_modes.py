"""The study's Table 4, measured: each failure mode as a setting, against its fix.

``python -m wrl_jax.experiments.failure_modes --out DIR [--quick] [--seeds 8]
[--modes stage oscillation collision forgetting]``

Every mode is trained with the otherwise-working configuration (DQN, ``default``
preset, ``Warehouse-8x8-v0``, 160,000 env steps per seed: 8/8 and 96/96 seeds
optimal in docs/dqn.md), across seeds, and judged by the greedy policy on every
item:

1. **Task-stage ignorance** (section 6.1): no carrying flag in the observation
   (``observe_carrying=False``), no pickup reward (``pickup_reward=0``), and both.
   Without the flag the item coordinates still turn to ``-1/(N-1)`` after pickup
   (SPEC.md), so the stage stays observable; a fourth observation,
   :class:`StageBlindWarehouse`, hides it for real (no flag, item coordinates
   unchanged after pickup: the "identical input vectors" the study describes).
2. **Oscillation** (6.2): the study's initial step penalty -1 without distance
   shaping (``shaping_coef=0``), and the two changes of its fix one at a time.
3. **Collision state corruption** (6.3): ``collision_bug=True``; its policies are
   evaluated in the buggy environment they were trained in and in the fixed one.
4. **Catastrophic forgetting** (6.4): :mod:`wrl_jax.experiments.forgetting`.

Variants that differ only in environment constants share one compiled program
(``vmap`` over variants x seeds); a different observation needs its own.
Files: ``table4.md``, ``table4.json``, ``table4.png`` (+ the forgetting files).
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.core.registry import make
from wrl_jax.envs.warehouse import evaluation
from wrl_jax.envs.warehouse.env import Warehouse
from wrl_jax.envs.warehouse.types import EnvParams, EnvState
from wrl_jax.experiments import common, forgetting
from wrl_jax.experiments.configs import ENV_8, Setting, build

BASE = Setting("dqn", "default", ENV_8)
MODES = ("stage", "oscillation", "collision", "forgetting")


class StageBlindWarehouse(Warehouse):
    """The warehouse with the task stage hidden from the observation.

    6 values: robot, goal and item coordinates, and the item coordinates stay
    those of the item's cell after pickup (SPEC.md's observation turns them to
    ``-1/(N-1)``). Pre- and post-pickup states at the same cell give identical
    inputs: what section 6.1 says the missing flag does. Dynamics and rewards
    are :class:`Warehouse`'s.
    """

    # Not equal to a plain Warehouse of the same shapes (the base class compares
    # types), so jit caches keyed on the env never mix the two.
    def __init__(self, size: int, max_items: int, default_params: EnvParams | None = None):
        super().__init__(size, max_items, observe_carrying=False, default_params=default_params)

    def get_obs(self, state: EnvState, params: EnvParams | None = None, key: jax.Array | None = None) -> jax.Array:
        params = self.default_params if params is None else params
        table = jnp.asarray(self._coordinate_table)
        return jnp.concatenate([table[state.pos + 1], table[params.goal + 1], table[state.item_pos + 1]])


def stage_blind(env_name: str = ENV_8, **overrides) -> tuple[StageBlindWarehouse, EnvParams]:
    base, params = make(env_name, observe_carrying=False, **overrides)
    return StageBlindWarehouse(base.size, base.max_items, default_params=params), params


# Each group: (observation, {variant label: env overrides}). Labels say what is *removed*.
def groups(modes: list[str]) -> list[tuple[str, dict[str, dict]]]:
    out: list[tuple[str, dict[str, dict]]] = []
    traced: dict[str, dict] = {"fixed (final setting)": {}}
    if "stage" in modes:
        traced["no pickup reward"] = {"pickup_reward": 0.0}
    if "oscillation" in modes:
        traced["step -1, no shaping (initial)"] = {"step_penalty": -1.0, "shaping_coef": 0.0}
        traced["step -0.5, no shaping"] = {"step_penalty": -0.5, "shaping_coef": 0.0}
        traced["step -1, shaping 2"] = {"step_penalty": -1.0}
    if "collision" in modes:
        traced["collision bug"] = {"collision_bug": True}
    out.append(("flag", traced))
    if "stage" in modes:
        out.append(("noflag", {"no carrying flag": {}, "no flag, no pickup reward": {"pickup_reward": 0.0}}))
        out.append(("blind", {"stage hidden (no flag, item coords kept)": {},
                              "stage hidden, no pickup reward": {"pickup_reward": 0.0}}))
    return out


MODE_OF = {
    "fixed (final setting)": "all (the fix)",
    "no pickup reward": "1 stage ignorance",
    "no carrying flag": "1 stage ignorance",
    "no flag, no pickup reward": "1 stage ignorance (study's failure)",
    "stage hidden (no flag, item coords kept)": "1 stage ignorance",
    "stage hidden, no pickup reward": "1 stage ignorance",
    "step -1, no shaping (initial)": "2 oscillation (study's failure)",
    "step -0.5, no shaping": "2 oscillation",
    "step -1, shaping 2": "2 oscillation",
    "collision bug": "3 collision corruption (study's failure)",
    "collision bug, evaluated without the bug": "3 collision corruption",
}


def run_groups(modes: list[str], seeds: list[int], quick: bool):
    results: dict[str, common.VariantResult] = {}
    timings = {}
    for observation, variants in groups(modes):
        if observation == "blind":
            env, base_params = stage_blind()
        else:
            env, base_params = make(ENV_8, observe_carrying=(observation == "flag"))
        observe_carrying = observation == "flag"
        params = {label: make(ENV_8, observe_carrying=observe_carrying, **ov)[1] for label, ov in variants.items()}
        algo, _, _ = build(BASE, quick, env=env, params=base_params)
        print(f"[table4] {observation}: {len(variants)} variants x {len(seeds)} seeds", flush=True)
        res, timing = common.train_variants(algo, params, seeds, eval_every=max(1, algo.num_updates // 40),
                                            keep_params="collision bug" in variants)
        timings[observation] = timing
        print(f"[table4]   compile {timing.compile_seconds:.1f} s, train {timing.train_seconds:.1f} s", flush=True)
        results.update(res)
        if "collision bug" in res:
            # The bug-trained policies, deployed where shelves really block (the fixed environment).
            fixed = make(ENV_8)[1]
            bug = res["collision bug"]
            # One program (called eagerly, the evaluation would compile its operations one by one).
            episodes = jax.jit(lambda p: evaluation.evaluate_seeds(algo.greedy_action, p, env, fixed))(
                bug.network_params)
            label = "collision bug, evaluated without the bug"
            results[label] = common.VariantResult(label, bug.seeds, episodes, common.per_seed_metrics(episodes),
                                                  [None] * len(seeds), bug.curve_steps,
                                                  {k: np.full_like(v, np.nan) for k, v in bug.curves.items()})
    return results, timings


def main(argv: list[str] | None = None) -> int:
    parser = common.base_parser(__doc__.splitlines()[0])
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    args = parser.parse_args(argv)
    n_seeds = common.check_seeds(args.seeds, 8, args.quick)
    out = Path(args.out)
    watch = common.Stopwatch()
    seeds = list(range(n_seeds))
    results, timings = run_groups(args.modes, seeds, args.quick)

    header = ["Failure mode", "Variant", "delivery rate", "items at optimum", "steps over optimum",
              "collision-free", "correct stage switching", "seeds optimal on all items"]
    rows = []
    for label, res in results.items():
        ci = res.summary(args.ci)
        rows.append([MODE_OF.get(label, ""), label, common.pct(ci["success_rate"]), common.pct(ci["optimal_rate"]),
                     ci["excess_steps"].fmt(1.0, 2), common.pct(ci["collision_free_rate"]),
                     common.pct(ci["stage_switch_rate"]), f"{int(res.per_seed['all_optimal'].sum())}/{n_seeds}"])
    machine = common.machine_info()
    steps = next(iter(timings.values())).env_steps_per_runner
    text = (f"# Table 4, measured: failure modes against the fix\n\nDQN default preset on {ENV_8}, "
            f"{steps:,} env steps per seed, {n_seeds} seeds per variant; mean [95% {args.ci} CI] of the final greedy "
            f"policy on every item.{' QUICK RUN: not a result.' if args.quick else ''}\n\n"
            + common.markdown_table(header, rows)
            + "\nCompile / train seconds per program: "
            + ", ".join(f"{k}: {t.compile_seconds:.1f} / {t.train_seconds:.1f} ({t.runners} runs)"
                        for k, t in timings.items())
            + f".\nBackend: {machine['backend']}, load {machine['load_average']}.\n")
    data = {"quick": args.quick, "ci_method": args.ci, "machine": machine, "env_steps_per_seed": steps,
            "timings": {k: vars(t) for k, t in timings.items()},
            "variants": {lab: {"mode": MODE_OF.get(lab, ""), **common.variant_json(res, args.ci)}
                         for lab, res in results.items()}}
    if "forgetting" in args.modes:
        ftext, fdata = forgetting.run(out, seeds, args.quick, args.ci)
        text += "\n" + ftext
        data["forgetting"] = fdata
    text += f"\nWall time of the whole experiment: {watch.seconds():.0f} s.\n"
    data["wall_seconds"] = watch.seconds()
    common.write_text(out / "table4.md", text)
    common.write_json(out / "table4.json", data)
    plot(results, out / "table4.png", n_seeds)
    print(text)
    return 0


def plot(results: dict[str, common.VariantResult], path: Path, n_seeds: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(results)
    fig, axes = plt.subplots(1, 2, figsize=(12, 0.45 * len(labels) + 1.6), sharey=True)
    y = np.arange(len(labels))
    panels = ((axes[0], "success_rate", "delivery rate"), (axes[1], "optimal_rate", "items at BFS optimum"))
    for ax, key, title in panels:
        cis = [results[lab].summary()[key] for lab in labels]
        means = np.array([c.mean for c in cis])
        err = np.array([[c.mean - c.low, c.high - c.mean] for c in cis]).T
        colors = ["tab:green" if lab.startswith("fixed") else "tab:red" if "study" in MODE_OF.get(lab, "")
                  else "tab:blue" for lab in labels]
        ax.barh(y, means, xerr=np.nan_to_num(err), color=colors, alpha=0.8, capsize=3)
        for s in range(n_seeds):
            ax.scatter([results[lab].per_seed[key][s] for lab in labels], y, s=6, color="black", zorder=3)
        ax.set_xlim(0, 1.05)
        ax.set_title(f"{title} (mean, 95% CI, dots: seeds)", fontsize=9)
        ax.grid(axis="x", alpha=0.3)
    axes[0].set_yticks(y, labels, fontsize=8)
    axes[0].invert_yaxis()
    fig.suptitle("Table 4 failure modes (red: the study's failing setting; green: the fix)", fontsize=10)
    fig.tight_layout()
    common.save_figure(fig, path)


if __name__ == "__main__":
    sys.exit(main())
