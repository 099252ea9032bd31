"""Pictures for the README: GIFs of trained greedy policies and learning curves.

``python -m wrl_jax.experiments.media --out docs/media [--quick]``

Trains (default presets, 2 seeds each, a minute or two on 2 cores):

- DQN on ``Warehouse-8x8-v0`` together with the study's oscillation setting
  (step penalty -1, no distance shaping), in one program (traced reward constants);
- PPO on ``Warehouse-12x12-v0``;

then records seed 0's greedy policy with :func:`wrl_jax.envs.warehouse.render.record_episode`:
``dqn_8x8.gif``, ``ppo_12x12.gif``, ``failure_oscillation.gif`` (an episode
that the oscillation setting's greedy policy fails to deliver, cut to its first
``--failure-frames`` steps), and ``learning_curves.png``
(greedy items-at-optimum and training delivery rate against env steps).
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import numpy as np

from wrl_jax.core.registry import make
from wrl_jax.envs.warehouse.render import record_episode, save_gif
from wrl_jax.experiments import common
from wrl_jax.experiments.configs import ENV_8, ENV_12, Setting, build

OSCILLATION = "step -1, no shaping"


def greedy_policy(algo, network_params):
    """``policy_fn(obs, state)`` of one seed's greedy network, for ``record_episode``."""
    return lambda obs, state: algo.greedy_action(network_params, obs)


def seed_params(results: common.VariantResult, seed_index: int = 0):
    return jax.tree.map(lambda x: x[seed_index], results.network_params)


def failing_episode(results: common.VariantResult, preferred_item: int) -> tuple[int, int]:
    """(seed index, item) of an undelivered greedy episode, the preferred item first; else (0, preferred)."""
    delivered = np.asarray(results.episodes.delivered) | ~np.asarray(results.episodes.valid)
    for s in range(delivered.shape[0]):
        if not delivered[s, preferred_item]:
            return s, preferred_item
    failed = np.argwhere(~delivered)
    return (int(failed[0][0]), int(failed[0][1])) if failed.size else (0, preferred_item)


def main(argv: list[str] | None = None) -> int:
    parser = common.base_parser(__doc__.splitlines()[0])
    parser.add_argument("--dqn-item", type=int, default=3, help="8x8 item shown (default 3: around the shelf row)")
    parser.add_argument("--ppo-item", type=int, default=17, help="12x12 item shown (default 17: through the corridors)")
    parser.add_argument("--failure-frames", type=int, default=40, help="steps of the failure GIF (it loops to 150)")
    parser.add_argument("--cell-size", type=int, default=32)
    args = parser.parse_args(argv)
    n_seeds = common.check_seeds(args.seeds, 2, args.quick)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    seeds = list(range(n_seeds))
    watch = common.Stopwatch()

    dqn_setting, ppo_setting = Setting("dqn", "default", ENV_8), Setting("ppo", "default", ENV_12)
    dqn, env8, params8 = build(dqn_setting, args.quick)
    variants = {"DQN 8x8 (final reward)": params8,
                f"DQN 8x8, {OSCILLATION}": make(ENV_8, step_penalty=-1.0, shaping_coef=0.0)[1]}
    dqn_results, t1 = common.train_variants(dqn, variants, seeds, eval_every=max(1, dqn.num_updates // 40),
                                            keep_params=True)
    ppo, env12, params12 = build(ppo_setting, args.quick)
    ppo_results, t2 = common.train_variants(ppo, {"PPO 12x12": params12}, seeds,
                                            eval_every=max(1, ppo.num_updates // 40), keep_params=True)
    print(f"[media] trained: DQN {t1.compile_seconds:.0f}+{t1.train_seconds:.0f} s, "
          f"PPO {t2.compile_seconds:.0f}+{t2.train_seconds:.0f} s", flush=True)

    written = {}
    good8 = dqn_results["DQN 8x8 (final reward)"]
    rec = record_episode(env8, params8, greedy_policy(dqn, seed_params(good8)), args.dqn_item, cell_size=args.cell_size)
    written["dqn_8x8.gif"] = (rec, save_gif(rec.frames, out / "dqn_8x8.gif", fps=5))
    rec = record_episode(env12, params12, greedy_policy(ppo, seed_params(ppo_results["PPO 12x12"])), args.ppo_item,
                         cell_size=args.cell_size)
    written["ppo_12x12.gif"] = (rec, save_gif(rec.frames, out / "ppo_12x12.gif", fps=6))
    bad = dqn_results[f"DQN 8x8, {OSCILLATION}"]
    bad_params = variants[f"DQN 8x8, {OSCILLATION}"]
    seed, item = failing_episode(bad, args.dqn_item)
    rec = record_episode(env8, bad_params, greedy_policy(dqn, seed_params(bad, seed)), item, cell_size=args.cell_size)
    written["failure_oscillation.gif"] = (rec, save_gif(rec.frames[: args.failure_frames + 1],
                                                       out / "failure_oscillation.gif", fps=5))

    curves = {**dqn_results, **ppo_results}
    plot(curves, out / "learning_curves.png", n_seeds)
    for name, (rec, path) in written.items():
        size = Path(path).stat().st_size
        print(f"[media] {path}: item {rec.item_index}, {rec.length} steps, delivered {rec.delivered}, "
              f"return {rec.total_return:+.1f}, collisions {rec.collisions}, {size / 1024:.0f} KiB")
        if size > 1 << 20:
            print(f"[media] warning: {path} is over 1 MiB", file=sys.stderr)
    print(f"[media] wall {watch.seconds():.0f} s")
    return 0


def plot(results: dict[str, common.VariantResult], path: Path, n_seeds: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    for ax, key, ylabel in ((axes[0], "delivery_rate", "training episodes delivered"),
                            (axes[1], "eval_optimal_rate", "greedy policy: items at BFS optimum")):
        for name, res in results.items():
            y, x = res.curves[key], res.curve_steps
            ok = ~np.all(np.isnan(y), axis=0)
            if ok.any():
                with np.errstate(all="ignore"):
                    ax.plot(x[ok], np.nanmean(y[:, ok], axis=0), lw=2, label=name)
        ax.set_xlabel("env steps per seed")
        ax.set_ylabel(ylabel)
        ax.set_ylim(-0.03, 1.03)
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7)
    fig.suptitle(f"Learning curves, default presets (mean of {n_seeds} seeds)", fontsize=10)
    fig.tight_layout()
    common.save_figure(fig, path)


if __name__ == "__main__":
    sys.exit(main())
