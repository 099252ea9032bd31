"""The fleet family's evaluation hook: a learned fleet's throughput, judged against the planners.

Two evaluations, both on the episodes the planners use (``python -m wrl_jax.plan``'s
default ``--seed 0``: episode ``e`` of ``E`` starts from ``split(key(0), E)[e]``, and
the policy sees the same shifts and task draws as a planner would,
:func:`~wrl_jax.envs.fleet.metrics.policy_episode_counts`):

- **periodic**, inside the compiled training loop (:func:`evaluate_policy`):
  the greedy policy on :data:`TRAINING_EPISODES` shifts and PIBT on the same
  shifts, so each evaluation logs ``eval_throughput``, ``eval_vs_pibt`` (the
  ratio) and ``eval_bound_fraction`` (of ``K / L*``). A seed is *solved* once
  its greedy policy delivers at least as much as PIBT.
- **final**, once after training (:func:`final_report`): :data:`FINAL_EPISODES`
  shifts per seed for the greedy and the sampled policy, PIBT and the greedy
  planner on the same shifts (exactly ``python -m wrl_jax.plan --episodes 100``'s
  numbers), throughput with 95 % intervals, blocks, shelf hits and waits per
  robot per 100 steps, and a GIF of the learned fleet (seed 0's greedy policy).
  This is ``summary.json``'s ``eval``: ``throughput``, ``pibt_throughput``,
  ``greedy_throughput``, ``sampled_throughput`` and the rest.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from wrl_jax.core.evaluation import FamilyEvaluation, FinalContext, SweepColumns, SweepMetric, TrainRate
from wrl_jax.envs.fleet import metrics
from wrl_jax.stats import mean_ci

EVAL_SEED = 0
"""``python -m wrl_jax.plan``'s default ``--seed``: the evaluation's shifts are the planners'."""
TRAINING_EPISODES = 32
FINAL_EPISODES = 100
GIF_NAME = "fleet.gif"
GreedyFn = Callable[[Any, jax.Array], jax.Array]


@struct.dataclass
class FleetEval:
    """One seed's periodic evaluation: per-episode per-robot counts of the greedy policy, PIBT's deliveries."""

    counts: dict[str, jax.Array]  # each (E, K) int32, names of metrics.COUNTED
    pibt_deliveries: jax.Array  # (E,) int32: PIBT's deliveries on the same shifts
    bound: jax.Array  # () float32: K / L*
    horizon: jax.Array  # () int32


def horizon_of(env: Any) -> int:
    """The evaluation shift length: the environment's ``max_steps`` (static: it is a scan length)."""
    return int(env.default_params.max_steps)


def _policy_counts(policy, env, params, key: jax.Array, num_episodes: int, horizon: int) -> dict[str, jax.Array]:
    keys = jax.random.split(key, num_episodes)
    return jax.vmap(lambda k: metrics.policy_episode_counts(env, params, policy, k, horizon))(keys)


def evaluate_policy(greedy_action: GreedyFn, network_params: Any, env, params) -> FleetEval:
    """The periodic evaluation of one seed (jittable): greedy policy and PIBT on the same shifts."""
    horizon = horizon_of(env)
    key = jax.random.key(EVAL_SEED)
    counts = _policy_counts(lambda obs, _: greedy_action(network_params, obs), env, params, key,
                            TRAINING_EPISODES, horizon)
    pibt = jax.vmap(lambda k: metrics.episode_counts(env, params, "pibt", k, horizon))(
        jax.random.split(key, TRAINING_EPISODES))
    bound = jnp.float32(env.num_robots) / metrics.mean_round_trip_jax(params)
    return FleetEval(counts=counts, pibt_deliveries=pibt["delivered"].sum(axis=-1), bound=bound,
                     horizon=jnp.int32(horizon))


def _per_100_steps(count: jax.Array, num_robots: int, horizon: jax.Array) -> jax.Array:
    """A per-robot count ``(E, K)`` as events per robot per 100 steps."""
    return 100.0 * count.sum() / (count.shape[0] * num_robots * horizon).astype(jnp.float32)


def seed_summary(result: FleetEval) -> dict[str, jax.Array]:
    """Float32 scalars of one seed's periodic evaluation (jittable)."""
    episodes, num_robots = result.counts["delivered"].shape
    steps = (episodes * result.horizon).astype(jnp.float32)
    throughput = result.counts["delivered"].sum() / steps
    pibt = result.pibt_deliveries.sum() / steps
    out = {
        "eval_throughput": throughput,
        "eval_pibt_throughput": pibt,
        "eval_vs_pibt": throughput / jnp.maximum(pibt, 1e-9),
        "eval_bound_fraction": throughput / result.bound,
        "eval_blocks_per_100": _per_100_steps(result.counts["robot_block"], num_robots, result.horizon),
        "eval_shelf_hits_per_100": _per_100_steps(result.counts["shelf_hit"], num_robots, result.horizon),
        "eval_waits_per_100": _per_100_steps(result.counts["waited"], num_robots, result.horizon),
        "eval_solved": (throughput >= pibt).astype(jnp.float32),
    }
    return {k: jnp.asarray(v, jnp.float32) for k, v in out.items()}


def summarize(result: FleetEval, seeds: Sequence[int] | None = None) -> dict[str, Any]:
    """The last periodic evaluation as plain numbers (``eval.periodic``; the final report adds the rest)."""
    per_seed = jax.device_get(jax.vmap(seed_summary)(result))
    num_seeds = int(np.asarray(result.horizon).shape[0])
    seeds = list(range(num_seeds)) if seeds is None else list(seeds)
    rows = [{"seed": seed, **{k.removeprefix("eval_"): float(v[i]) for k, v in per_seed.items()}}
            for i, seed in enumerate(seeds)]
    return {"periodic": {"episodes": TRAINING_EPISODES, "per_seed": rows}}


# ------------------------------------------------------------------ the final report
def _episode_throughput(counts: dict[str, np.ndarray], horizon: int) -> np.ndarray:
    """Deliveries per step of each episode (leading axes kept, robots summed)."""
    return counts["delivered"].sum(axis=-1) / horizon


def _rates(counts: dict[str, np.ndarray], horizon: int) -> dict[str, float]:
    num_robots = counts["delivered"].shape[-1]
    scale = 100.0 / (counts["delivered"][..., 0].size * num_robots * horizon)
    return {"blocks_per_100": float(counts["robot_block"].sum() * scale),
            "shelf_hits_per_100": float(counts["shelf_hit"].sum() * scale),
            "waits_per_100": float(counts["waited"].sum() * scale),
            "wall_bumps_per_100": float(counts["wall_bump"].sum() * scale)}


def _interval(values: np.ndarray) -> dict[str, Any]:
    interval = mean_ci(np.asarray(values, dtype=np.float64).ravel())
    return {"mean": interval.mean, "ci95": [interval.low, interval.high], "n": interval.n}


def final_report(context: FinalContext) -> dict[str, Any]:
    """The 100-episode evaluation of every seed beside PIBT and the greedy planner; writes the GIF."""
    env, params, algo = context.env, context.params, context.algo
    horizon = horizon_of(env)
    key = jax.random.key(EVAL_SEED)

    stochastic = algo.has_stochastic_policy

    def seed_counts(network_params, sampled):
        # One program for both policies (a vmap over the flag): one compile instead of two.
        def policy(obs, policy_key):
            greedy_action = algo.greedy_action(network_params, obs)
            if not stochastic:
                return greedy_action
            return jnp.where(sampled, algo.sample_action(network_params, obs, policy_key), greedy_action)
        return _policy_counts(policy, env, params, key, FINAL_EPISODES, horizon)

    flags = jnp.array([False, True]) if stochastic else jnp.array([False])
    both = jax.jit(jax.vmap(jax.vmap(seed_counts, in_axes=(None, 0)), in_axes=(0, None)))(
        context.network_params, flags)  # each (S, 1 or 2, E, K)
    both = jax.device_get(both)
    greedy = {k: v[:, 0] for k, v in both.items()}  # each (S, E, K)
    sampled = {k: v[:, 1] for k, v in both.items()} if stochastic else None
    planners = {name: jax.device_get(metrics.run_episodes(env, params, name, key, FINAL_EPISODES, horizon))
                for name in ("pibt", "greedy")}

    per_episode = _episode_throughput(greedy, horizon)  # (S, E)
    seed_means = per_episode.mean(axis=1)
    pibt_episode = _episode_throughput(planners["pibt"], horizon)
    pibt_mean = float(pibt_episode.mean())
    bound = float(env.num_robots / metrics.mean_round_trip(params))
    sampled_means = _episode_throughput(sampled, horizon).mean(axis=1) if sampled is not None else None
    per_seed = []
    for s, seed in enumerate(context.seeds):
        row = {"seed": int(seed), "throughput": _interval(per_episode[s]),
               **_rates({k: v[s] for k, v in greedy.items()}, horizon),
               "vs_pibt": float(seed_means[s] / pibt_mean) if pibt_mean > 0 else None}
        if sampled is not None:
            row["sampled_throughput"] = float(sampled_means[s])
            row["sampled_vs_pibt"] = float(sampled_means[s] / pibt_mean) if pibt_mean > 0 else None
            row["sampled_blocks_per_100"] = _rates({k: v[s] for k, v in sampled.items()}, horizon)["blocks_per_100"]
        per_seed.append(row)
    report: dict[str, Any] = {
        "num_robots": int(env.num_robots),
        "episodes_per_seed": FINAL_EPISODES,
        "horizon": horizon,
        "episode_seed": EVAL_SEED,
        "throughput": float(seed_means.mean()),
        "throughput_ci95_over_seeds": _interval(seed_means)["ci95"],
        "pibt_throughput": pibt_mean,
        "pibt_throughput_ci95": _interval(pibt_episode)["ci95"],
        "greedy_throughput": float(_episode_throughput(planners["greedy"], horizon).mean()),
        "sampled_throughput": (float(_episode_throughput(sampled, horizon).mean()) if sampled is not None else None),
        "upper_bound": bound,
        "vs_pibt": float(seed_means.mean() / pibt_mean) if pibt_mean > 0 else None,
        "seeds_at_least_pibt": int((seed_means >= pibt_mean).sum()),
        "seeds_at_least_95pct_pibt": int((seed_means >= 0.95 * pibt_mean).sum()),
        **_rates(greedy, horizon),
        "pibt_rates": _rates(planners["pibt"], horizon),
        # The sampled policy's own counts: its blocks, and how many seeds reach PIBT with it.
        "sampled_rates": _rates(sampled, horizon) if sampled is not None else None,
        "sampled_seeds_at_least_pibt": int((sampled_means >= pibt_mean).sum()) if sampled is not None else None,
        "sampled_seeds_at_least_95pct_pibt": (int((sampled_means >= 0.95 * pibt_mean).sum())
                                              if sampled is not None else None),
        "per_seed": per_seed,
        "unit": "deliveries per step, all robots; *_per_100: events per robot per 100 steps",
    }
    if context.out_dir is not None:
        report["gif"] = str(_write_gif(context, horizon))
    return report


def _write_gif(context: FinalContext, horizon: int):
    """Seed 0's greedy fleet over one evaluation shift, as ``fleet.gif`` in the run directory."""
    from pathlib import Path

    from wrl_jax.envs.fleet.render import record_shift
    from wrl_jax.envs.warehouse.render import save_gif

    # Sliced in NumPy (an eager slice compiles a program per leaf shape), then JAX arrays again for the policy.
    first = jax.tree.map(lambda x: jnp.asarray(np.asarray(x)[0]), context.network_params)
    greedy_action = context.algo.greedy_action

    def policy(key, obs, state):
        del key, state
        return greedy_action(first, obs)

    recording = record_shift(context.env, context.params, policy, jax.random.key(EVAL_SEED),
                             num_steps=min(horizon, 128))
    return save_gif(recording.frames, Path(context.out_dir) / GIF_NAME, fps=8)


# ------------------------------------------------------------------ reports
def _sampled_rows(summary: dict[str, Any]) -> list[tuple[str, str]]:
    """The sampled policy's seeds at PIBT and blocks (absent from summaries written before they were counted)."""
    rates = summary.get("sampled_rates")
    if not rates:
        return []
    return [("sampled policy: seeds at least PIBT / at least 95 % of it",
             f"{summary['sampled_seeds_at_least_pibt']} / {summary['sampled_seeds_at_least_95pct_pibt']} "
             f"of {len(summary['per_seed'])}"),
            ("sampled policy: robot blocks per robot per 100 steps", f"{rates['blocks_per_100']:.2f}")]


def format_report(summary: dict[str, Any], label: str, convergence_steps: Sequence[int | None] | None = None,
                  study: dict[str, str] | None = None) -> str:
    """A Markdown table: the learned fleet beside PIBT and the greedy planner on the same shifts."""
    del study
    if "throughput" not in summary:  # only the periodic evaluation (no final report ran)
        rows = summary["periodic"]["per_seed"]
        lines = [f"| {label} | throughput | vs PIBT |", "|---|---|---|"]
        lines += [f"| seed {r['seed']} | {r['throughput']:.3f} | {r['vs_pibt']:.0%} |" for r in rows]
        return "\n".join(lines)
    low, high = summary["throughput_ci95_over_seeds"]
    interval = f" [{low:.3f}, {high:.3f}]" if low is not None and high is not None and low != high else ""
    p_low, p_high = summary["pibt_throughput_ci95"]
    rows = [
        ("robots, shifts per seed x steps", f"{summary['num_robots']}, {summary['episodes_per_seed']} x "
                                            f"{summary['horizon']} (the planners' episodes, seed {summary['episode_seed']})"),
        ("throughput, greedy policy (95 % CI over seeds)", f"{summary['throughput']:.3f}{interval}"),
        ("throughput, sampled policy", "n/a" if summary["sampled_throughput"] is None
         else f"{summary['sampled_throughput']:.3f}"),
        ("PIBT on the same shifts", f"{summary['pibt_throughput']:.3f} [{p_low:.3f}, {p_high:.3f}]"),
        ("greedy planner on the same shifts", f"{summary['greedy_throughput']:.3f}"),
        ("learned / PIBT", "n/a" if summary["vs_pibt"] is None else f"{summary['vs_pibt']:.0%}"),
        ("upper bound K / L*", f"{summary['upper_bound']:.3f}"),
        ("seeds at least PIBT / at least 95 % of it",
         f"{summary['seeds_at_least_pibt']} / {summary['seeds_at_least_95pct_pibt']} of {len(summary['per_seed'])}"),
        ("robot blocks per robot per 100 steps", f"{summary['blocks_per_100']:.2f} "
                                                 f"(PIBT {summary['pibt_rates']['blocks_per_100']:.2f})"),
        *_sampled_rows(summary),
        ("shelf hits per robot per 100 steps", f"{summary['shelf_hits_per_100']:.2f}"),
        ("waits per robot per 100 steps", f"{summary['waits_per_100']:.2f} "
                                          f"(PIBT {summary['pibt_rates']['waits_per_100']:.2f})"),
    ]
    if convergence_steps is not None:
        reached = [step for step in convergence_steps if step is not None]
        rows.append(("seeds whose periodic evaluation reached PIBT", f"{len(reached)} of {len(convergence_steps)}"))
    lines = [f"| {label} | |", "|---|---|", *(f"| {name} | {value} |" for name, value in rows)]
    return "\n".join(lines)


def format_details(summary: dict[str, Any]) -> str:
    """Per seed: throughput with its 95 % interval over shifts, the ratio to PIBT, blocks, shelf hits, waits."""
    if "throughput" not in summary:
        return ""
    lines = ["| seed | throughput [95 % CI over shifts] | / PIBT | blocks /100 | shelf hits /100 | waits /100 "
             "| sampled | sampled / PIBT | sampled blocks /100 |",
             "|---|---|---|---|---|---|---|---|---|"]

    def number(value, pattern):
        return "n/a" if value is None else format(value, pattern)

    for row in summary["per_seed"]:
        tp = row["throughput"]
        low, high = tp["ci95"]
        lines.append(f"| {row['seed']} | {tp['mean']:.3f} [{low:.3f}, {high:.3f}] | {number(row['vs_pibt'], '.0%')} | "
                     f"{row['blocks_per_100']:.2f} | {row['shelf_hits_per_100']:.2f} | {row['waits_per_100']:.2f} | "
                     f"{number(row.get('sampled_throughput'), '.3f')} | {number(row.get('sampled_vs_pibt'), '.0%')} | "
                     f"{number(row.get('sampled_blocks_per_100'), '.2f')} |")
    return "\n".join(lines)


EVALUATION = FamilyEvaluation(
    evaluate_policy=evaluate_policy,
    seed_summary=seed_summary,
    solved_key="eval_solved",
    solved_definition="env steps per seed at the first periodic evaluation whose greedy fleet delivered at least "
                      f"as much as PIBT on the same {TRAINING_EPISODES} shifts",
    summarize=summarize,
    format_report=format_report,
    format_details=format_details,
    progress_metric=("eval_vs_pibt", "of PIBT"),
    train_rates=(TrainRate("train_throughput", "deliveries per step (training)", "deliveries_sum", per="step"),),
    final_report=final_report,
    # A sweep reads the periodic evaluation after the last update (the final report's
    # 100-shift evaluation runs only after a single training run).
    sweep_columns=SweepColumns(
        metrics=(
            SweepMetric("throughput", "greedy throughput", digits=3, plot="deliveries per step (greedy fleet)"),
            SweepMetric("vs_pibt", "greedy / PIBT", "ratio", plot="throughput / PIBT's (%)"),
            SweepMetric("at_least_pibt", "seeds >= PIBT", "solved"),
            SweepMetric("bound_fraction", "of bound K / L*", "ratio"),
            SweepMetric("blocks_per_100", "blocks /robot /100 steps", digits=2,
                        plot="robot blocks per robot per 100 steps"),
            SweepMetric("shelf_hits_per_100", "shelf hits /robot /100 steps", digits=2),
            SweepMetric("waits_per_100", "waits /robot /100 steps", digits=2),
            SweepMetric("pibt_throughput", "PIBT throughput", digits=3, table=False),
        ),
        train=(SweepMetric("train_throughput", "train throughput (last log)", digits=3),),
        rows=("periodic", "per_seed"),
        convergence_label="first step >= PIBT",
    ),
)
"""The fleet family's evaluation hook (:mod:`wrl_jax.core.evaluation`)."""
