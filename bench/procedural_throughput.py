"""Procedural warehouses: generation speed, 100,000-layout solvability, and stepping speed vs the fixed map.

Measures, in one process (compile time reported apart; one warm-up call,
then ``--repeats`` timed calls, each ``block_until_ready``-ed, median reported):

1. **Layouts per second**: ``generate_batch`` alone and ``generate_pool``
   (layouts plus their BFS optima, what a pool refresh costs), per family, at
   ``--gen-batch`` layouts per call.
2. **Solvability at scale**: ``--check`` layouts (default 100,000) of the
   default mixture, generated in chunks by one compiled program and checked
   by a plain NumPy flood fill (goal and every item reachable from the start);
   distinct layouts counted by their 64-bit hash.
3. **Environment steps per second**, interleaved round by round so that each
   configuration sees the same load: ``jit`` of a ``lax.scan`` over
   ``--horizon`` steps of ``vmap(env.step)`` over ``--batch`` environments,
   random actions, a key per environment per step, auto-reset, and obs,
   final_obs, reward, terminated and truncated summed into a checksum:
   * ``fixed``: ``wrl_jax.make("Warehouse-12x12-v0")`` (the study's map, 7-value observation);
   * ``procedural-1``: ``ProceduralWarehouse`` on a pool of ONE layout, the 12x12 map padded
     to 16x16 (the same observation as below, no per-env layouts: the observation's cost alone);
   * ``procedural``: ``ProceduralWarehouse`` on a pool of ``--pool-size`` generated layouts,
     each environment on its own layout, with the 80-value fleet robot observation (its window
     from bit masks of the episode's packed floor rows);
   * ``procedural-scalars``: the same with ``observe_window=False`` (the five scalars only): per-env
     layouts without the window, to separate the two costs;
   * ``procedural-memory``: ``procedural`` with PPO's preset observation (``ppo_config.PROCEDURAL_ENV_DEFAULTS``:
     the previous action and the trail channel counting visits, 109 values), what ``train_ppo.py`` steps;
   * ``procedural-last-action`` and ``procedural-trail``: ``procedural`` with the previous action alone, and
     with the yes/no trail alone, to separate what each part of the memory costs.
4. The pool's memory per layout, and a refresh's cost against a rollout's.

Run from the repository root::

    .venv/bin/python bench/procedural_throughput.py            # writes bench/results/procedural_throughput.json
    .venv/bin/python bench/procedural_throughput.py --quick    # a smoke run
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import jax
import jax.numpy as jnp
import numpy as np

import wrl_jax
from wrl_jax.envs.warehouse import maps
from wrl_jax.agents.ppo_config import PROCEDURAL_ENV_DEFAULTS
from wrl_jax.envs.procedural import generators
from wrl_jax.envs.procedural.layout import from_layout
from wrl_jax.envs.procedural.pool import (
    bytes_per_layout,
    generate_pool,
    pool_from_keys,
    pool_hashes,
    stream_keys,
)
from wrl_jax.envs.procedural.registration import make_from_layouts, make_procedural

RESULTS = ROOT / "bench" / "results"


def timed(fn: Callable, *args, repeats: int) -> tuple[float, list[float], object]:
    """``(compile_s, run times, last output)`` of ``jax.jit(fn)`` on ``args``."""
    start = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - start
    out = jax.block_until_ready(compiled(*args))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - start)
    return compile_s, times, out


# ------------------------------------------------------------------ 1. generation
def bench_generation(batch: int, repeats: int) -> list[dict]:
    rows = []
    for family in generators.FAMILIES:
        config = generators.GeneratorConfig(family=family)
        keys = stream_keys(jax.random.key(0), "train", batch)
        for what, fn in (("layouts", lambda k, c=config: generators.generate_batch(k, c)),
                         ("layouts+optimum", lambda k, c=config: pool_from_keys(k, c))):
            compile_s, times, _ = timed(fn, keys, repeats=repeats)
            median = statistics.median(times)
            rows.append({"family": family, "what": what, "batch": batch, "compile_s": round(compile_s, 2),
                         "median_s": median, "layouts_per_s": batch / median})
            print(f"generate {family:9s} {what:16s} batch={batch}: {batch / median:,.0f} layouts/s "
                  f"(compile {compile_s:.1f} s)", flush=True)
    return rows


# ------------------------------------------------------------------ 2. solvability
def numpy_reachable(blocked: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Cells reachable from each start, ``(N, H, W)``: a NumPy flood fill, independent of the JAX code."""
    free = ~blocked
    reached = np.zeros_like(free)
    reached[np.arange(len(starts)), starts[:, 0], starts[:, 1]] = True
    while True:
        grown = reached.copy()
        grown[:, 1:] |= reached[:, :-1]
        grown[:, :-1] |= reached[:, 1:]
        grown[:, :, 1:] |= reached[:, :, :-1]
        grown[:, :, :-1] |= reached[:, :, 1:]
        grown &= free
        if (grown == reached).all():
            return reached
        reached = grown


def check_solvability(total: int, chunk: int) -> dict:
    config = generators.GeneratorConfig()
    hashes, unsolvable, empty, seconds = [], 0, 0, 0.0
    for start in range(0, total, chunk):
        tic = time.perf_counter()
        pool = jax.block_until_ready(generate_pool(jax.random.fold_in(jax.random.key(2026), start), chunk, config))
        seconds += time.perf_counter() - tic
        layouts = jax.tree.map(np.asarray, pool.layouts)
        reached = numpy_reachable(layouts.blocked, layouts.start)
        rows = np.arange(chunk)
        goal_ok = reached[rows, layouts.goal[:, 0], layouts.goal[:, 1]]
        real = np.arange(config.max_items)[None, :] < layouts.num_items[:, None]
        items_ok = (reached[rows[:, None], layouts.items[..., 0], layouts.items[..., 1]] | ~real).all(axis=1)
        unsolvable += int((~(goal_ok & items_ok)).sum())
        on_floor = ((np.arange(16)[None, :, None] < layouts.height[:, None, None])
                    & (np.arange(16)[None, None, :] < layouts.width[:, None, None]))
        empty += int((~(layouts.blocked & on_floor).any(axis=(1, 2))).sum())
        hashes.append(pool_hashes(pool))
    distinct = len(np.unique(np.concatenate(hashes)))
    result = {"layouts": total, "unsolvable_numpy": unsolvable, "distinct": distinct,
              "without_any_shelf": empty, "generation_s_incl_first_compile": round(seconds, 2)}
    print(f"solvability: {total:,} layouts, {unsolvable} unsolvable (NumPy flood fill), {distinct:,} distinct, "
          f"{empty} without any shelf", flush=True)
    return result


# ------------------------------------------------------------------ 3. stepping
def make_rollout(env, batch: int, horizon: int) -> Callable:
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def rollout(params, state, key, checksum):
        def one(carry, _):
            state, key, checksum = carry
            key, key_action, key_env = jax.random.split(key, 3)
            action = jax.random.randint(key_action, (batch,), 0, 4)
            obs, state, reward, terminated, truncated, info = step(jax.random.split(key_env, batch), state,
                                                                   action, params)
            checksum = (checksum + jnp.sum(obs) + jnp.sum(info["final_obs"]) + jnp.sum(reward)
                        + jnp.sum(terminated.astype(jnp.float32)) + 2.0 * jnp.sum(truncated.astype(jnp.float32)))
            return (state, key, checksum), None

        return jax.lax.scan(one, (state, key, checksum), None, length=horizon)[0]

    return rollout


def bench_steps(batch: int, horizon: int, repeats: int, pool_size: int) -> tuple[list[dict], dict]:
    fixed_env, fixed_params = wrl_jax.make("Warehouse-12x12-v0")
    study = from_layout(wrl_jax.parse(maps.WAREHOUSE_12X12), (16, 16), 20)
    one_env, one_params = make_from_layouts([study])
    gen_env, gen_params = make_procedural(pool_size=pool_size)
    scalar_env, scalar_params = make_procedural(pool_size=pool_size, observe_window=False)
    cases = {"fixed": (fixed_env, fixed_params), "procedural-1": (one_env, one_params),
             "procedural": (gen_env, gen_params), "procedural-scalars": (scalar_env, scalar_params),
             "procedural-memory": make_procedural(pool_size=pool_size, **PROCEDURAL_ENV_DEFAULTS),
             "procedural-last-action": make_procedural(pool_size=pool_size, observe_last_action=True),
             "procedural-trail": make_procedural(pool_size=pool_size, observe_visited=True)}
    runs = {}
    for name, (env, params) in cases.items():
        keys = jax.random.split(jax.random.key(1), batch)
        state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(keys, params)[1]
        carry = (state, jax.random.key(2), jnp.float32(0.0))
        tic = time.perf_counter()
        compiled = jax.jit(make_rollout(env, batch, horizon)).lower(params, *carry).compile()
        compile_s = time.perf_counter() - tic
        carry = jax.block_until_ready(compiled(params, *carry))
        runs[name] = {"fn": compiled, "params": params, "carry": carry, "compile_s": compile_s, "times": []}
    for _ in range(repeats):  # interleaved rounds
        for run in runs.values():
            tic = time.perf_counter()
            run["carry"] = jax.block_until_ready(run["fn"](run["params"], *run["carry"]))
            run["times"].append(time.perf_counter() - tic)
    rows = []
    fixed_rate = batch * horizon / statistics.median(runs["fixed"]["times"])
    for name, run in runs.items():
        rate = batch * horizon / statistics.median(run["times"])
        rows.append({"env": name, "batch": batch, "horizon": horizon, "compile_s": round(run["compile_s"], 2),
                     "median_s": statistics.median(run["times"]), "steps_per_s": rate,
                     "ratio_to_fixed": rate / fixed_rate})
        print(f"steps {name:22s} batch={batch}: {rate / 1e6:.2f} M steps/s, {rate / fixed_rate:.2f}x fixed "
              f"(compile {run['compile_s']:.1f} s)", flush=True)
    # A refresh of the whole pool, against one rollout of the generated-layout case.
    compile_s, times, _ = timed(lambda key, params: gen_env.refresh_pool(key, params), jax.random.key(3),
                                gen_params, repeats=repeats)
    refresh = {"pool_size": pool_size, "compile_s": round(compile_s, 2), "median_s": statistics.median(times),
               "rollout_median_s": statistics.median(runs["procedural"]["times"]),
               "bytes_per_layout": bytes_per_layout(gen_params.pool),
               "pool_bytes": bytes_per_layout(gen_params.pool)["total"] * pool_size,
               "walls_bytes_per_layout": int(gen_params.walls.nbytes) // pool_size,
               "reset_obs_bytes_per_layout": int(gen_params.reset_obs.nbytes) // pool_size}
    refresh["refresh_over_rollout"] = refresh["median_s"] / refresh["rollout_median_s"]
    print(f"refresh of {pool_size} layouts: {refresh['median_s'] * 1e3:.1f} ms = "
          f"{refresh['refresh_over_rollout']:.2f} of one {batch}x{horizon} rollout; "
          f"{refresh['bytes_per_layout']['total']} bytes per layout", flush=True)
    return rows, refresh


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, a smoke run")
    parser.add_argument("--gen-batch", type=int, default=8192)
    parser.add_argument("--check", type=int, default=100_000, help="layouts checked for solvability")
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--horizon", type=int, default=128)
    parser.add_argument("--pool-size", type=int, default=1024)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=RESULTS / "procedural_throughput.json")
    args = parser.parse_args()
    if args.quick:
        args.gen_batch, args.check, args.batch, args.horizon, args.repeats = 1024, 10_000, 1024, 32, 3
    chunk = min(10_000, args.check)
    result = {
        "command": " ".join([Path(sys.executable).name, *sys.argv]),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "jax": jax.__version__,
                    "load_average_at_start": os.getloadavg()},
        "generation": bench_generation(args.gen_batch, args.repeats),
        "solvability": check_solvability(args.check, chunk),
    }
    result["steps"], result["pool"] = bench_steps(args.batch, args.horizon, args.repeats, args.pool_size)
    result["machine"]["load_average_at_end"] = os.getloadavg()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
