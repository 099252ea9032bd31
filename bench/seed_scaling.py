"""Seeds trained per minute: N seeds in one program (vmap) vs a Python loop of single-seed programs.

For DQN and PPO (their default presets, and DQN's paper preset with one
environment per seed, each with a small fixed budget per seed), and N in 1, 8,
32, 128:

- *one program*: ``jax.jit(make_train_seeds(algo))`` on N keys, the
  whole training run of every seed in one XLA program (init, then a
  ``lax.scan`` over updates of the ``vmap``-ped update). Compiled ahead of time
  (``lower().compile()``, timed apart), then run once and timed to
  ``block_until_ready``.
- *one by one*: ``jax.jit(make_train(algo))`` compiled once (timed
  apart), then called for seed 0, 1, ..., N-1 in a Python loop, each call
  waited for. Loops longer than ``--loop-max`` seeds are not run: their time is
  N times the mean single-seed time measured on the first ``--loop-max``
  seeds (marked ``extrapolated`` in the output); every seed costs the same
  program, so the loop is linear in N.

Seeds per minute = N / run seconds * 60 (compile excluded from both; reported
apart). The machine is shared: every number comes with the load average, and
the comparison is a ratio measured in the same run.

    python bench/seed_scaling.py                       # both algorithms, N = 1 8 32 128
    python bench/seed_scaling.py --algos ppo --seeds 1 8 --out /tmp/x

Outputs: ``bench/results/seed_scaling.json``, ``.md`` and ``.png``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from wrl_jax.cli import machine  # noqa: E402

machine.apply_xla_opt_level(machine.DEFAULT_XLA_OPT_LEVEL)

import jax  # noqa: E402
import numpy as np  # noqa: E402

import wrl_jax  # noqa: E402
from wrl_jax import training  # noqa: E402
from wrl_jax.agents.base import config_to_dict, make_train, make_train_seeds  # noqa: E402
from wrl_jax.agents import dqn, dqn_config, ppo, ppo_config  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def bench_configs(ppo_updates: int, dqn_updates: int, dqn_paper_updates: int) -> dict:
    """The default presets (and DQN's paper preset), cut to a fixed number of updates per seed."""
    p = ppo_config.DEFAULT
    p = dataclasses.replace(p, total_timesteps=ppo_updates * p.steps_per_update)
    d = dqn_config.DEFAULT
    total = dqn_updates * d.steps_per_update
    # The replay buffer holds the whole run (it never wraps: the same algorithm as
    # with 100,000) so that 128 seeds' buffers are not mostly unused memory.
    d = d.replace(total_timesteps=total, buffer_size=total)
    # The study's DQN: one environment, one gradient step on 128 samples every 4 steps.
    # Little work per kernel, so batching seeds is where the gain is.
    dp = dqn_config.PAPER
    total = dqn_paper_updates * dp.steps_per_update
    dp = dp.replace(total_timesteps=total, buffer_size=total)
    return {
        "ppo": (p, "Warehouse-12x12-v0", ppo.PPO),
        "dqn": (d, "Warehouse-8x8-v0", dqn.DQN),
        "dqn_paper": (dp, "Warehouse-8x8-v0", dqn.DQN),
    }


def load() -> list[float]:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return []


def time_call(fn, *args) -> float:
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    return time.perf_counter() - t0


def one_program(algo, n: int) -> dict:
    keys = training.seed_keys(list(range(n)))
    t0 = time.perf_counter()
    compiled = jax.jit(make_train_seeds(algo)).lower(keys).compile()
    compile_s = time.perf_counter() - t0
    load_before = load()
    run_s = time_call(compiled, keys)
    return {"compile_seconds": compile_s, "run_seconds": run_s, "load_before": load_before, "load_after": load()}


def one_by_one(algo, n: int, loop_max: int, single: dict) -> dict:
    """A Python loop over single-seed programs (the single-seed program compiled once, in ``single``)."""
    if "compiled" not in single:
        key = jax.random.PRNGKey(0)
        t0 = time.perf_counter()
        single["compiled"] = jax.jit(make_train(algo)).lower(key).compile()
        single["compile_seconds"] = time.perf_counter() - t0
        single["times"] = []
    compiled, times = single["compiled"], single["times"]
    load_before = load()
    while len(times) < min(n, loop_max):  # seeds 0, 1, ... as far as measured so far
        times.append(time_call(compiled, jax.random.PRNGKey(len(times))))
    measured = min(n, loop_max)
    run_s = float(sum(times[:measured]))
    extrapolated = n > measured
    if extrapolated:
        run_s = n * float(np.mean(times[:measured]))
    return {
        "compile_seconds": single["compile_seconds"],
        "run_seconds": run_s,
        "measured_seeds": measured,
        "extrapolated": extrapolated,
        "single_seed_seconds_mean": float(np.mean(times[:measured])),
        "load_before": load_before,
        "load_after": load(),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--algos", nargs="+", default=["dqn", "ppo", "dqn_paper"], choices=["dqn", "ppo", "dqn_paper"],
                        help="dqn, ppo: default presets; dqn_paper: the study's DQN (1 env per seed)")
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 8, 32, 128])
    parser.add_argument("--ppo-updates", type=int, default=8, help="PPO updates per seed (2,048 env steps each)")
    parser.add_argument("--dqn-updates", type=int, default=250, help="DQN updates per seed (32 env steps each)")
    parser.add_argument("--dqn-paper-updates", type=int, default=500,
                        help="paper-preset DQN updates (4 env steps each)")
    parser.add_argument("--loop-max", type=int, default=32, help="longest one-by-one loop actually run")
    parser.add_argument("--out", default=str(RESULTS / "seed_scaling"), help="output path without extension")
    args = parser.parse_args(argv)
    budgets = (args.loop_max, args.ppo_updates, args.dqn_updates, args.dqn_paper_updates)
    if any(n < 1 for n in args.seeds) or min(budgets) < 1:
        parser.error("--seeds, --loop-max and the update budgets must be positive")

    configs = bench_configs(args.ppo_updates, args.dqn_updates, args.dqn_paper_updates)
    results: dict = {
        "command": "python bench/seed_scaling.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(), "load_at_start": load(),
                    "xla_flags": os.environ.get("XLA_FLAGS", ""), "devices": [str(d) for d in jax.devices()]},
        "versions": {"jax": jax.__version__},
        "algos": {},
    }
    for name in args.algos:
        config, env_name, cls = configs[name]
        env, params = wrl_jax.make(env_name)
        algo = cls(config, env, params)
        steps = algo.num_updates * algo.steps_per_update
        entry = {"env": env_name, "config": config_to_dict(config), "env_steps_per_seed": steps,
                 "num_updates": algo.num_updates, "rows": []}
        single: dict = {}
        for n in args.seeds:
            program = one_program(algo, n)
            loop = one_by_one(algo, n, args.loop_max, single)
            row = {
                "seeds": n,
                "one_program": program,
                "one_by_one": loop,
                "seeds_per_minute_one_program": 60.0 * n / program["run_seconds"],
                "seeds_per_minute_one_by_one": 60.0 * n / loop["run_seconds"],
                "env_steps_per_second_one_program": n * steps / program["run_seconds"],
                "speedup": loop["run_seconds"] / program["run_seconds"],
                # Derived, not run: a fresh process per seed pays the single-seed compile each time.
                "seeds_per_minute_process_per_seed": 60.0 * n / (loop["run_seconds"] + n * loop["compile_seconds"]),
            }
            entry["rows"].append(row)
            print(
                f"{name} N={n:4d}: one program {row['seeds_per_minute_one_program']:8.1f} seeds/min "
                f"(compile {program['compile_seconds']:.1f} s, run {program['run_seconds']:.2f} s) | one by one "
                f"{row['seeds_per_minute_one_by_one']:7.1f} seeds/min (run {loop['run_seconds']:.2f} s"
                f"{', extrapolated' if loop['extrapolated'] else ''}) | x{row['speedup']:.1f} | load {load()}",
                flush=True,
            )
        entry["single_seed_compile_seconds"] = single.get("compile_seconds")
        results["algos"][name] = entry
    results["machine"]["load_at_end"] = load()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(results, indent=2))
    out.with_suffix(".md").write_text(markdown(results))
    plot(results, out.with_suffix(".png"))
    print(markdown(results))
    return 0


def markdown(results: dict) -> str:
    lines = [f"`{results['command']}` (load average at start {results['machine']['load_at_start']}, "
             f"at end {results['machine']['load_at_end']}, {results['machine']['cpu_count']} CPUs)", ""]
    for name, entry in results["algos"].items():
        lines += [
            f"**{name.upper()}** on {entry['env']}, {entry['env_steps_per_seed']:,} env steps per seed "
            f"({entry['num_updates']} updates); one-by-one compile {entry['single_seed_compile_seconds']:.1f} s",
            "",
            "| seeds | one program: seeds/min | run s | compile s | env steps/s | one by one: seeds/min | run s "
            "| speed-up | a process per seed (+compile each): seeds/min |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for row in entry["rows"]:
            p, l = row["one_program"], row["one_by_one"]
            lines.append(
                f"| {row['seeds']} | {row['seeds_per_minute_one_program']:,.1f} | {p['run_seconds']:.2f} | "
                f"{p['compile_seconds']:.1f} | {row['env_steps_per_second_one_program'] / 1e3:,.0f}k | "
                f"{row['seeds_per_minute_one_by_one']:,.1f} | {l['run_seconds']:.2f}"
                f"{' (extrapolated from ' + str(l['measured_seeds']) + ')' if l['extrapolated'] else ''} | "
                f"x{row['speedup']:.1f} | {row['seeds_per_minute_process_per_seed']:,.1f} |"
            )
        lines.append("")
    return "\n".join(lines)


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    for (name, entry), color in zip(results["algos"].items(), ("C0", "C1", "C2")):
        n = [r["seeds"] for r in entry["rows"]]
        ax.plot(n, [r["seeds_per_minute_one_program"] for r in entry["rows"]], "o-", color=color,
                label=f"{name.upper()}: N seeds in one program")
        ax.plot(n, [r["seeds_per_minute_one_by_one"] for r in entry["rows"]], "s--", color=color, alpha=0.6,
                label=f"{name.upper()}: one by one (Python loop)")
        ax.plot(n, [r["seeds_per_minute_process_per_seed"] for r in entry["rows"]], ":", color=color, alpha=0.5,
                label=f"{name.upper()}: a process per seed (compile each; derived)")
        ax2.plot(n, [r["speedup"] for r in entry["rows"]], "o-", color=color, label=name.upper())
    for a in (ax, ax2):
        a.set_xscale("log", base=2)
        a.set_xlabel("seeds")
        a.grid(alpha=0.3, which="both")
    ax.set_yscale("log")
    ax.set_ylabel("seeds trained per minute (compile excluded)")
    ax.legend(fontsize="small")
    ax2.set_ylabel("speed-up of one program over the loop")
    ax2.legend(fontsize="small")
    fig.suptitle(f"Seed scaling on {results['machine']['cpu_count']} CPU cores (shared machine)")
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
