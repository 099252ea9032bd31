"""Reward sensitivity (the study's section 7.3): each reward term removed or scaled, one at a time.

``python -m wrl_jax.experiments.sensitivity --out DIR [--quick] [--seeds 4] [--scales 0 0.5 2]``

The study says that changing any single reward component "independently causes
complete task failure". Here every term of SPEC.md's reward (step penalty,
obstacle penalty, shaping coefficient, pickup reward, delivery reward) is
multiplied by each scale (0 removes it) with the others at their defaults, and
DQN (``default`` preset, ``Warehouse-8x8-v0``, 160,000 steps per seed) is
trained on every setting. Reward constants are traced environment params, so
all settings x seeds are one compiled program. (The wall penalty is 0 by
default, so scaling it changes nothing and it is left out.)
Files: ``sensitivity.md``, ``sensitivity.json``, ``sensitivity.png`` (heat map).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from wrl_jax.core.registry import make
from wrl_jax.envs.warehouse.types import REWARD_DEFAULTS
from wrl_jax.experiments import common
from wrl_jax.experiments.configs import ENV_8, Setting, build

TERMS = ("step_penalty", "obstacle_penalty", "shaping_coef", "pickup_reward", "delivery_reward")
BASE = Setting("dqn", "default", ENV_8)


def variant_name(term: str, scale: float) -> str:
    return "baseline" if scale == 1.0 else f"{term} x{scale:g}"


def main(argv: list[str] | None = None) -> int:
    parser = common.base_parser(__doc__.splitlines()[0])
    parser.add_argument("--scales", nargs="+", type=float, default=[0.0, 0.5, 2.0])
    args = parser.parse_args(argv)
    if any(not np.isfinite(s) or s < 0 for s in args.scales):
        raise SystemExit(f"error: --scales must be finite and non-negative, got {args.scales}")
    scales = sorted({float(s) for s in args.scales} | {1.0})
    n_seeds = common.check_seeds(args.seeds, 4, args.quick)
    out = Path(args.out)
    watch = common.Stopwatch()
    variants = {"baseline": make(ENV_8)[1]}
    for term in TERMS:
        for scale in scales:
            if scale != 1.0:
                variants[variant_name(term, scale)] = make(ENV_8, **{term: REWARD_DEFAULTS[term] * scale})[1]
    algo, _, _ = build(BASE, args.quick)
    print(f"[sensitivity] {len(variants)} settings x {n_seeds} seeds = {len(variants) * n_seeds} runs", flush=True)
    results, timing = common.train_variants(algo, variants, list(range(n_seeds)),
                                            eval_every=max(1, algo.num_updates // 20))
    print(f"[sensitivity] compile {timing.compile_seconds:.1f} s, train {timing.train_seconds:.1f} s", flush=True)

    grid = {key: np.zeros((len(TERMS), len(scales))) for key in ("success_rate", "optimal_rate")}
    header = ["term (default)"] + [f"x{s:g}" for s in scales]
    rows = []
    for i, term in enumerate(TERMS):
        row = [f"{term} ({REWARD_DEFAULTS[term]:g})"]
        for j, scale in enumerate(scales):
            res = results[variant_name(term, scale)]
            ci = res.summary(args.ci)
            for key in grid:
                grid[key][i, j] = ci[key].mean
            row.append(f"{common.pct(ci['success_rate'])} / {100 * ci['optimal_rate'].mean:.0f}%")
        rows.append(row)
    machine = common.machine_info()
    text = (f"# Reward sensitivity (section 7.3)\n\nDQN default preset on {ENV_8}, "
            f"{timing.env_steps_per_runner:,} env steps per seed, {n_seeds} seeds per setting. Cell: greedy delivery "
            f"rate over every item, mean [95% {args.ci} CI] / items delivered at the BFS optimum. Each term scaled "
            f"alone, the others at their defaults.{' QUICK RUN: not a result.' if args.quick else ''}\n\n"
            + common.markdown_table(header, rows)
            + f"\nCompile {timing.compile_seconds:.1f} s, train {timing.train_seconds:.1f} s ({timing.runners} runs in "
              f"one program); wall {watch.seconds():.0f} s; backend {machine['backend']}, "
              f"load {machine['load_average']}.\n")
    common.write_text(out / "sensitivity.md", text)
    common.write_json(out / "sensitivity.json", {
        "quick": args.quick, "ci_method": args.ci, "machine": machine, "terms": TERMS, "scales": scales,
        "env_steps_per_seed": timing.env_steps_per_runner, "compile_seconds": timing.compile_seconds,
        "train_seconds": timing.train_seconds, "wall_seconds": watch.seconds(),
        "grid": grid, "variants": {k: common.variant_json(v, args.ci) for k, v in results.items()},
    })
    plot(grid, scales, out / "sensitivity.png", n_seeds)
    print(text)
    return 0


def plot(grid: dict[str, np.ndarray], scales: list[float], path: Path, n_seeds: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(1.4 * len(scales) + 3.4, 3.8))
    im = ax.imshow(grid["success_rate"], vmin=0, vmax=1, cmap="RdYlGn", aspect="auto")
    for i in range(len(TERMS)):
        for j in range(len(scales)):
            ax.text(j, i, f"{100 * grid['success_rate'][i, j]:.0f}%\n{100 * grid['optimal_rate'][i, j]:.0f}% opt",
                    ha="center", va="center", fontsize=8)
    ax.set_xticks(range(len(scales)), [f"x{s:g}" for s in scales])
    ax.set_yticks(range(len(TERMS)), TERMS, fontsize=8)
    ax.set_xlabel("scale of the term (others at defaults)")
    fig.colorbar(im, ax=ax, label="greedy delivery rate")
    ax.set_title(f"Reward sensitivity, DQN 8x8 default, {n_seeds} seeds", fontsize=10)
    fig.tight_layout()
    common.save_figure(fig, path)


if __name__ == "__main__":
    sys.exit(main())
