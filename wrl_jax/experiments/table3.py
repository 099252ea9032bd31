"""The study's Table 3, measured: DQN on 8x8 and PPO on 12x12, many seeds, with CIs.

``python -m wrl_jax.experiments.table3 --out DIR [--quick] [--seeds 8] [--presets paper default]``

For every preset (``paper``: the study's Table 2; ``default``: ours) it trains
DQN on ``Warehouse-8x8-v0`` and PPO on ``Warehouse-12x12-v0`` (one compiled
program per algorithm and preset, all seeds ``vmap``-ped), evaluates every
seed's greedy policy on every item, and reports each Table 3 row as a mean over
seeds with a 95% confidence interval: delivery rate, steps against the BFS
optimum, return, convergence step (first periodic evaluation at which the seed
delivers every item at the optimum), collision-free rate and correct stage
switching. Files: ``table3.md``, ``table3.json``, ``table3.png``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from wrl_jax.agents import dqn_config, ppo_config
from wrl_jax.experiments import common
from wrl_jax.experiments.configs import ENV_8, ENV_12, Setting, build

STUDY = {
    "dqn": dqn_config.STUDY_TABLE3,
    "ppo": ppo_config.STUDY_TABLE3,
}

ROWS = (
    ("Task Completion Rate", "success_rate"),
    ("Items at BFS optimum", "optimal_rate"),
    ("Mean Steps to Complete", "mean_steps"),
    ("Steps over optimum", "excess_steps"),
    ("Mean Episode Reward", "mean_return"),
    ("Convergence Timestep", None),
    ("Obstacle Avoidance", "collision_free_rate"),
    ("Stage Switching", "stage_switch_rate"),
    ("Seeds optimal on every item", "all_optimal"),
)


def settings(presets: list[str], algos: list[str] = ("dqn", "ppo")) -> list[Setting]:
    """DQN on 8x8 and PPO on 12x12 (the study's pairing) for every preset."""
    out = []
    for preset in presets:
        if "dqn" in algos:
            out.append(Setting("dqn", preset, ENV_8))
        if "ppo" in algos:
            out.append(Setting("ppo", preset, ENV_12))
    return out


def cell(key: str | None, res: common.VariantResult, method: str) -> str:
    if key is None:
        conv, done = common.convergence_interval(res.first_optimal_step, method)
        n = len(res.seeds)
        if done == 0:
            return f"never (0/{n} seeds)"
        return f"{conv.fmt(1.0, 0)} steps ({done}/{n} seeds)"
    ci = res.summary(method)[key]
    if key in ("mean_steps", "excess_steps"):
        return ci.fmt(1.0, 2)
    if key == "mean_return":
        return ci.fmt(1.0, 1)
    return common.pct(ci)


def main(argv: list[str] | None = None) -> int:
    parser = common.base_parser(__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["paper", "default"], choices=["paper", "default"])
    parser.add_argument("--algos", nargs="+", default=["dqn", "ppo"], choices=["dqn", "ppo"])
    parser.add_argument("--eval-points", type=int, default=50,
                        help="greedy evaluations per run (the convergence step's resolution)")
    parser.add_argument("--first-seed", type=int, default=0,
                        help="seeds are first-seed .. first-seed + seeds - 1 (e.g. 1000: seeds no preset was tuned on)")
    args = parser.parse_args(argv)
    n_seeds = common.check_seeds(args.seeds, 8, args.quick)
    out = Path(args.out)
    watch = common.Stopwatch()
    seeds = list(range(args.first_seed, args.first_seed + n_seeds))
    results, timings, labels = {}, {}, {}
    for setting in settings(args.presets, args.algos):
        algo, env, params = build(setting, args.quick)
        eval_every = max(1, algo.num_updates // args.eval_points)
        label = setting.label
        print(f"[table3] {label}: {n_seeds} seeds x {algo.num_updates * algo.steps_per_update:,} env steps", flush=True)
        res, timing = common.train_variants(algo, {label: params}, seeds, eval_every=eval_every)
        results[label], timings[label], labels[label] = res[label], timing, setting
        print(f"[table3]   compile {timing.compile_seconds:.1f} s, train {timing.train_seconds:.1f} s, "
              f"delivery {100 * np.mean(res[label].per_seed['success_rate']):.1f}%", flush=True)

    header = ["Metric"] + [f"{lab} ({n_seeds} seeds)" for lab in results]
    studies = [a for a in ("dqn", "ppo") if any(s.algo == a for s in labels.values())]
    header += [f"Study {a.upper()} {'8x8' if a == 'dqn' else '12x12'}" for a in studies]
    rows = []
    for name, key in ROWS:
        row = [name] + [cell(key, res, args.ci) for res in results.values()]
        row += [STUDY[a].get(name, "") for a in studies]
        rows.append(row)
    budget = ["Env steps per seed"] + [f"{timings[lab].env_steps_per_runner:,}" for lab in results]
    budget += ["" for _ in studies]
    wall = ["Compile / train (s)"] + [f"{timings[lab].compile_seconds:.1f} / {timings[lab].train_seconds:.1f}"
                                      for lab in results] + ["" for _ in studies]
    rows += [budget, wall]
    machine = common.machine_info()
    text = (f"# Table 3, measured\n\nSeeds {seeds[0]}-{seeds[-1]}. "
            f"Mean over seeds [95% {args.ci} confidence interval]; every seed's greedy "
            f"policy evaluated once on every item. Steps are over delivered episodes. Convergence: first greedy "
            f"evaluation (every ~1/{args.eval_points} of the run) with every item at the BFS optimum, over the seeds "
            f"that got there.{' QUICK RUN (tiny budgets): not a result.' if args.quick else ''}\n\n"
            + common.markdown_table(header, rows)
            + f"\nBackend: {machine['backend']} ({machine['device']}), load average {machine['load_average']}, "
              f"wall {watch.seconds():.0f} s.\n")
    common.write_text(out / "table3.md", text)
    common.write_json(out / "table3.json", {
        "quick": args.quick,
        "ci_method": args.ci,
        "machine": machine,
        "wall_seconds": watch.seconds(),
        "settings": {lab: {"algo": s.algo, "preset": s.preset, "env": s.env_name,
                           "env_steps_per_seed": timings[lab].env_steps_per_runner,
                           "compile_seconds": timings[lab].compile_seconds,
                           "train_seconds": timings[lab].train_seconds,
                           **common.variant_json(results[lab], args.ci)} for lab, s in labels.items()},
    })
    plot(results, out / "table3.png", n_seeds)
    print(text)
    return 0


def plot(results: dict[str, common.VariantResult], path: Path, n_seeds: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    for ax, key, ylabel in ((axes[0], "delivery_rate", "training episodes delivered"),
                            (axes[1], "eval_optimal_rate", "greedy: items at BFS optimum")):
        for name, res in results.items():
            y, x = res.curves[key], res.curve_steps
            ok = ~np.all(np.isnan(y), axis=0)
            if not ok.any():
                continue
            frac = x[ok] / max(x[-1], 1)
            with np.errstate(all="ignore"):
                (line,) = ax.plot(frac, np.nanmean(y[:, ok], axis=0), lw=2, label=f"{name} ({x[-1]:,} steps)")
                ax.fill_between(frac, np.nanmin(y[:, ok], axis=0), np.nanmax(y[:, ok], axis=0),
                                alpha=0.15, color=line.get_color())
        ax.set_xlabel("fraction of the run")
        ax.set_ylabel(ylabel)
        ax.set_ylim(-0.03, 1.03)
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7, loc="lower right")
    fig.suptitle(f"Table 3 settings, {n_seeds} seeds: mean (line) and min..max (band)", fontsize=10)
    fig.tight_layout()
    common.save_figure(fig, path)


if __name__ == "__main__":
    sys.exit(main())
