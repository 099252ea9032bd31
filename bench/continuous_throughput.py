"""Continuous warehouse throughput: random-action env steps per second, JAX against the NumPy reference.

In one process, interleaved round by round (the same load for both on a shared machine):

* JAX as a learner runs it: ``jax.jit`` of a ``lax.scan`` over time of ``jax.vmap(env.step)`` with
  automatic reset, a key per environment per step (``jax.random.split``, what PureJaxRL-style code
  does), uniform actions drawn in the scan, every output a learner reads folded into a checksum so
  XLA drops nothing; compile apart, one warm-up call, the median of ``--repeats`` timed calls;
* the NumPy reference (:class:`wrl_jax.envs.continuous.reference.ReferenceEnv`): one environment in
  a Python loop with its own draws and ``reset()`` when an episode ends. A batch of ``B`` reference
  environments costs ``B`` times one, so its steps/s is the same at every batch size.

Usage: ``python bench/continuous_throughput.py [--env Continuous-Warehouse-12x12-Dynamic-v0]
[--batches 1 64 1024 4096] [--steps 100] [--reference-steps 2000] [--json OUT]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import wrl_jax
from wrl_jax.envs.continuous import reference
from wrl_jax.envs.continuous import reference_types as rtypes
from wrl_jax.envs.continuous.registration import study_max_steps
from wrl_jax.envs.warehouse import maps
from wrl_jax.envs.warehouse.layout import parse

MAPS = {"8x8": maps.WAREHOUSE_8X8, "12x12": maps.WAREHOUSE_12X12}


def jax_runner(env, params, batch: int, steps: int):
    """A jitted ``(key, state) -> (key, state, checksum)`` of ``steps`` vector steps of ``batch`` envs."""

    def one(carry, _):
        key, state, total = carry
        key, k_act, k_env = jax.random.split(key, 3)
        action = jax.random.uniform(k_act, (batch, 2), minval=-1.0, maxval=1.0)
        obs, state, reward, terminated, truncated, info = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
            jax.random.split(k_env, batch), state, action, params)
        total = total + obs.sum() + info["final_obs"].sum() + reward.sum() + terminated.sum() + truncated.sum()
        return (key, state, total), None

    @jax.jit
    def run(key, state):
        (key, state, total), _ = jax.lax.scan(one, (key, state, jnp.float32(0)), None, length=steps)
        return key, state, total

    return run


def reference_env(env, params, seed: int = 0) -> reference.ReferenceEnv:
    layout_text = MAPS["8x8" if env.height == 8 else "12x12"]
    names = ("dt", "v_max", "w_max", "robot_radius", "reach_radius", "lidar_range", "step_penalty",
             "collision_penalty", "shaping_coef", "pickup_reward", "delivery_reward", "max_steps", "obstacle_radius",
             "obstacle_speed", "actuation_noise", "lidar_noise", "lidar_dropout", "start_jitter", "randomize")
    p = rtypes.ContinuousParams(**{n: np.asarray(getattr(params, n)).item() for n in names},
                                gain_range=(float(params.gain_low), float(params.gain_high)),
                                num_rays=env.num_rays, num_obstacles=env.num_obstacles)
    assert study_max_steps(parse(layout_text)) == int(params.max_steps)
    return reference.ReferenceEnv(rtypes.ContinuousLayout.from_text(layout_text), p, seed=seed)


def reference_steps_per_second(ref: reference.ReferenceEnv, steps: int, rng: np.random.Generator) -> float:
    ref.reset()
    start = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = ref.step(rng.uniform(-1, 1, 2).astype(np.float32))
        if terminated or truncated:
            ref.reset()
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="Continuous-Warehouse-12x12-Dynamic-v0")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 64, 1024, 4096])
    parser.add_argument("--steps", type=int, default=100, help="vector steps per timed JAX call")
    parser.add_argument("--reference-steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    env, params = wrl_jax.make(args.env)
    runners, compile_s = {}, {}
    for batch in args.batches:
        run = jax_runner(env, params, batch, args.steps)
        _, state = env.batch_reset(jax.random.key(0), batch, params)
        start = time.perf_counter()
        compiled = run.lower(jax.random.key(1), state).compile()
        compile_s[batch] = time.perf_counter() - start
        carry = compiled(jax.random.key(1), state)  # warm-up
        jax.block_until_ready(carry)
        runners[batch] = (compiled, carry)
    ref, rng = reference_env(env, params), np.random.default_rng(0)
    jax_times = {batch: [] for batch in args.batches}
    ref_rates = []
    for _ in range(args.repeats):  # interleaved: every configuration sees the same load
        for batch in args.batches:
            compiled, (key, state, _) = runners[batch]
            start = time.perf_counter()
            carry = compiled(key, state)
            jax.block_until_ready(carry)
            jax_times[batch].append(time.perf_counter() - start)
            runners[batch] = (compiled, carry)
        ref_rates.append(reference_steps_per_second(ref, args.reference_steps // args.repeats, rng))
    reference_rate = statistics.median(ref_rates)
    rows = []
    for batch in args.batches:
        rate = batch * args.steps / statistics.median(jax_times[batch])
        rows.append({"batch": batch, "jax_steps_per_s": rate, "compile_s": compile_s[batch],
                     "ratio_to_reference": rate / reference_rate})
    # The reference's loop runs on one core; XLA splits the larger fusions over every core the process may use
    # (`taskset -c 0` before the command pins every side to one).
    cores = len(os.sched_getaffinity(0))
    report = {"env": args.env, "reference_steps_per_s": reference_rate, "rows": rows, "jax": jax.__version__,
              "steps_per_call": args.steps, "repeats": args.repeats, "cores": cores}
    print(f"{args.env}: NumPy reference {reference_rate:,.0f} steps/s (one env, Python loop); {cores} core(s)")
    print("| batch | JAX env steps/s | x reference | compile s |\n|---:|---:|---:|---:|")
    for row in rows:
        print(f"| {row['batch']:,} | {row['jax_steps_per_s']:,.0f} | {row['ratio_to_reference']:,.0f}x | "
              f"{row['compile_s']:.1f} |")
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
