"""Catastrophic forgetting (the study's section 6.4): segmented training vs randomized items.

Part of ``python -m wrl_jax.experiments.failure_modes`` (mode ``forgetting``), also
``python -m wrl_jax.experiments.forgetting --out DIR [--quick] [--seeds 8]``.

The same total budget is cut into one segment per item position. Params are
data: a *segment* is the runner's ``env_params`` swapped for a one-item layout
(every row of ``items`` that item, ``num_items = 1``) while the networks,
optimizer state, replay buffer, schedules (the global update index keeps
counting) and environment states carry on. Variants, trained side by side in
one compiled segment function:

- ``randomized (fix)``: the full layout in every segment, i.e. one ordinary run;
- ``segmented``: item 0's layout, then item 1's, ... (the replay buffer keeps
  what it holds: DQN's 100,000-transition buffer spans ~6 segments of 16,000);
- ``segmented, buffer cleared``: the same, emptying the replay buffer at every
  segment start (a fresh ``model.learn`` with a new buffer would do this).

After every segment each seed's greedy policy is evaluated on *all* items,
which shows what is retained (forgetting: only the latest items are delivered).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.envs.warehouse import evaluation
from wrl_jax.envs.warehouse.types import EnvParams
from wrl_jax.experiments import common
from wrl_jax.experiments.configs import ENV_8, Setting, build

VARIANTS = ("randomized (fix)", "segmented", "segmented, buffer cleared")


def one_item_params(params: EnvParams, item: int) -> EnvParams:
    """``params`` whose layout has only item ``item`` (shapes unchanged: the rows are padded with it)."""
    num_items = int(params.num_items)
    if not 0 <= item < num_items:
        raise ValueError(f"item {item} is out of range: the layout has {num_items} items")
    return params.replace(items=jnp.broadcast_to(params.items[item], params.items.shape),
                          num_items=jnp.asarray(1, params.num_items.dtype))


def make_segment_fn(algo, full_params: EnvParams, segment_updates: int):
    """``segment(runners, env_params, clear, start) -> (runners, train stats, delivered (S, K))``, jitted.

    ``env_params`` (batched) replaces the runners' params for the segment;
    ``clear`` (bool per runner) empties a replay buffer first; updates
    ``start .. start + segment_updates - 1`` run (the global index, so epsilon
    and learning-rate schedules continue); then every runner's greedy policy
    is evaluated on ``full_params`` (every item).
    """
    batched_update = jax.vmap(algo.update, in_axes=(0, None))

    def segment(runners, env_params, clear, start):
        runners = runners.replace(env_params=env_params)
        if hasattr(runners, "buffer"):
            buf = runners.buffer
            runners = runners.replace(buffer=buf.replace(size=jnp.where(clear, 0, buf.size),
                                                         position=jnp.where(clear, 0, buf.position)))
        runners, metrics = jax.lax.scan(lambda r, i: batched_update(r, start + i), runners,
                                        jnp.arange(segment_updates, dtype=jnp.int32))
        episodes = evaluation.evaluate_seeds(algo.greedy_action, jax.vmap(algo.network_params)(runners),
                                             algo.env, full_params)
        stats = {k: metrics[k].sum(axis=0) for k in ("episodes", "terminated", "length_sum")}
        return runners, stats, episodes

    return jax.jit(segment)


def train(setting: Setting, seeds: list[int], quick: bool, variants=VARIANTS) -> dict[str, Any]:
    """Train every variant x seed; returns per-segment evaluations and training stats."""
    algo, env, full = build(setting, quick)
    num_items = int(full.num_items)
    segment_updates = algo.num_updates // num_items
    if segment_updates < 1:
        raise ValueError(f"budget too small: {algo.num_updates} updates for {num_items} segments")
    n = len(seeds)
    runners = training_init(algo, seeds * len(variants), full)
    segment = make_segment_fn(algo, full, segment_updates)
    clear = jnp.asarray([v == "segmented, buffer cleared" for v in variants for _ in seeds])
    delivered = np.zeros((num_items, len(variants), n, num_items), dtype=bool)
    train_delivery = np.zeros((num_items, len(variants), n))
    train_length = np.zeros((num_items, len(variants), n))
    watch = common.Stopwatch()
    compile_seconds = 0.0
    for k in range(num_items):
        per_variant = [full if v.startswith("randomized") else one_item_params(full, k) for v in variants]
        params = common.stack_trees([p for p in per_variant for _ in seeds])
        start = jnp.int32(k * segment_updates)
        if k == 0:
            t0 = common.Stopwatch()
            segment = segment.lower(runners, params, clear, start).compile()
            compile_seconds = t0.seconds()
        runners, stats, episodes = segment(runners, params, clear, start)
        ep = np.asarray(stats["episodes"]).reshape(len(variants), n)
        with np.errstate(invalid="ignore", divide="ignore"):
            train_delivery[k] = np.asarray(stats["terminated"]).reshape(len(variants), n) / ep
            train_length[k] = np.asarray(stats["length_sum"]).reshape(len(variants), n) / ep
        delivered[k] = np.asarray(episodes.delivered).reshape(len(variants), n, -1)[..., :num_items]
        final_episodes = episodes
    seconds = watch.seconds()
    finals = {}
    for v, name in enumerate(variants):
        ep = jax.tree.map(lambda x: np.asarray(x)[v * n:(v + 1) * n], final_episodes)
        finals[name] = common.per_seed_metrics(ep)
    return {"variants": list(variants), "seeds": seeds, "num_items": num_items,
            "segment_steps": segment_updates * algo.steps_per_update,
            "total_steps": num_items * segment_updates * algo.steps_per_update,
            "delivered_after_segment": delivered, "train_delivery": train_delivery, "train_length": train_length,
            "final": finals, "compile_seconds": compile_seconds, "train_seconds": seconds - compile_seconds}


def training_init(algo, seeds: list[int], params: EnvParams):
    from wrl_jax.training import driver as training

    return training.Trainer(algo, seeds=seeds, loop=training.LoopConfig(progress=False)).init(
        env_params=common.stack_trees([params] * len(seeds)))


def run(out: Path, seeds: list[int], quick: bool, method: str = "t",
        setting: Setting = Setting("dqn", "default", ENV_8)) -> tuple[str, dict[str, Any]]:
    """Train, write ``forgetting.png``, return the Markdown section and the JSON data."""
    print(f"[forgetting] {setting.label}: {len(VARIANTS)} variants x {len(seeds)} seeds", flush=True)
    r = train(setting, seeds, quick)
    n, K = len(seeds), r["num_items"]
    header = ["Variant", "delivery rate (final, all items)", "items at optimum", "last segment's item delivered",
              "items delivered from earlier segments", "training episodes delivered (last segment)"]
    rows = []
    for v, name in enumerate(r["variants"]):
        ci = common.intervals(r["final"][name], method)
        last = r["delivered_after_segment"][-1, v]  # (S, K) after the last segment
        earlier = common.mean_ci(last[:, : K - 1].mean(axis=1), method=method, bounds=(0, 1))
        rows.append([name, common.pct(ci["success_rate"]), common.pct(ci["optimal_rate"]),
                     f"{int(last[:, K - 1].sum())}/{n} seeds", common.pct(earlier),
                     common.pct(common.mean_ci(r["train_delivery"][-1, v], method=method, bounds=(0, 1)))])
    text = (f"## Catastrophic forgetting: {K} segments of {r['segment_steps']:,} env steps "
            f"({r['total_steps']:,} per seed in all), {setting.label}, {n} seeds\n\n"
            + common.markdown_table(header, rows)
            + f"\nCompile {r['compile_seconds']:.1f} s, train {r['train_seconds']:.1f} s "
              f"({len(VARIANTS) * n} runs in one program).\n")
    plot(r, out / "forgetting.png", setting.label)
    data = {k: v for k, v in r.items()}
    data["final"] = {name: {"per_seed": m, "ci": common.intervals(m, method)} for name, m in r["final"].items()}
    return text, data


def plot(r: dict[str, Any], path: Path, label: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    variants = r["variants"]
    fig, axes = plt.subplots(1, len(variants), figsize=(4.2 * len(variants), 3.9), squeeze=False)
    for v, name in enumerate(variants):
        ax = axes[0][v]
        frac = r["delivered_after_segment"][:, v].mean(axis=1)  # (segments, items)
        im = ax.imshow(frac, vmin=0, vmax=1, cmap="viridis", aspect="auto")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("evaluated item")
        ax.set_ylabel("after segment (trained on item)" if not name.startswith("randomized") else "after segment")
        ax.set_xticks(range(r["num_items"]))
        ax.set_yticks(range(r["num_items"]))
    fig.colorbar(im, ax=axes[0].tolist(), shrink=0.8, label="fraction of seeds delivering")
    fig.suptitle(f"Greedy delivery of every item after each segment ({label}, {len(r['seeds'])} seeds)", fontsize=10)
    common.save_figure(fig, path)


def main(argv: list[str] | None = None) -> int:
    parser = common.base_parser(__doc__.splitlines()[0])
    args = parser.parse_args(argv)
    n_seeds = common.check_seeds(args.seeds, 8, args.quick)
    out = Path(args.out)
    text, data = run(out, list(range(n_seeds)), args.quick, args.ci)
    common.write_text(out / "forgetting.md", text)
    common.write_json(out / "forgetting.json", {"quick": args.quick, "machine": common.machine_info(), **data})
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
