"""Agent-steps per second of the JAX RWARE step, against rware 2.0.0's own Python step and Jumanji's RobotWarehouse.

    python bench/rware_throughput.py                                   # tiny-4ag and small-4ag, B = 1 .. 32768
    python bench/rware_throughput.py --batch-sizes 1 32 1024 --seconds 1 --profile
    python bench/rware_throughput.py --jumanji-python /tmp/jumanji-venv/bin/python
    python bench/rware_throughput.py --tie-orders rware-tiny-8ag-v2        # what the exact tie order costs

Ours: ``jit(lax.scan(vmap(env.step)))`` over ``T`` steps of ``B`` environments (auto-reset included), uniform
random actions drawn before the timed call (:func:`actions_before`), as rware's are, our per-environment keys
split inside it as a user's loop splits them, compile time measured apart (``lower().compile()``), two warm-up
calls, then the median of ``--repeats`` timings, each of as many consecutive calls (``block_until_ready`` after
each) as fill at least ``MIN_TIMING_SECONDS``. rware: ``Warehouse.step`` in a Python loop, one environment, the
same random policy (actions drawn beforehand), reset when done, the median of ``--repeats`` loops of
``--seconds``, in a process of its own without JAX. The ratio to rware comes from ``--pairs`` timings of the two
alternated (ours at its best batch of the table), since the machine's speed drifts within a run.

Jumanji (its own virtual environment: ``python -m venv /tmp/jumanji-venv && /tmp/jumanji-venv/bin/pip install
jumanji==1.1.2``): its ``RobotWarehouse`` with the same layout, agents, sensor range and queue, behind
``AutoResetWrapper``, timed as ours, in a child process of that interpreter. Jumanji's warehouse is not rware's
rules (agents move one after another, an episode ends on a collision, rewards are shared): a speed reference only.

Ours is the default ``tie_order="set"`` (ties between equal chains in unpatched rware's order); the same
batch is also timed with ``tie_order="insertion"``, alternated, to say what the exact order costs.
``--profile`` times variants of our step with one part left out, at one batch size, to say what bounds it.
Results: ``--out``/throughput.json and throughput.md; every ratio is from the same run.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

SIZES = {"rware-tiny-4ag-v2": (1, 3, 4, 4), "rware-small-4ag-v2": (2, 3, 4, 4)}
"""id -> (shelf_rows, shelf_columns, agents, request queue): also what Jumanji's generator is given."""
TARGET_ENV_STEPS = 1 << 16
"""Environment steps per timed call (``T = TARGET / B``, kept within 4 .. 4096); the batch is reset before."""
MIN_TIMING_SECONDS = 1.0
"""Each timing spans at least this long (consecutive calls of one compiled scan): a call of 20 ms is at the mercy of
the scheduler, and a best of a few such calls flatters a side against rware's loop of seconds."""
MEMORY_LIMIT_BYTES = 8 << 30
"""Skip a batch whose carried state and observations would exceed this (a rough bound)."""


def steps_for(batch: int) -> int:
    return max(4, min(4096, TARGET_ENV_STEPS // batch))


def compile_scan(make_scan, batch: int) -> tuple:
    """``make_scan(batch, steps) -> (jitted fn, args)`` compiled and warmed up: ``(compiled, args, steps,
    compile seconds, calls)``, where ``calls`` consecutive calls fill at least ``MIN_TIMING_SECONDS``."""
    import jax

    steps = steps_for(batch)
    fn, args = make_scan(batch, steps)
    t0 = time.perf_counter()
    compiled = fn.lower(*args).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(*args))
    t0 = time.perf_counter()
    jax.block_until_ready(compiled(*args))
    return compiled, args, steps, compile_s, max(1, math.ceil(MIN_TIMING_SECONDS / (time.perf_counter() - t0)))


def seconds_per_call(compiled, args, calls: int) -> float:
    """One timing: ``calls`` consecutive calls, each waited for."""
    import jax

    t0 = time.perf_counter()
    for _ in range(calls):
        jax.block_until_ready(compiled(*args))
    return (time.perf_counter() - t0) / calls


def time_scan(make_scan, batch: int, agents: int, repeats: int) -> dict:
    """Compile, warm up and time ``make_scan(batch, steps) -> (jitted fn, args)``; agent-steps per second."""
    compiled, args, steps, compile_s, calls = compile_scan(make_scan, batch)
    per_call = [seconds_per_call(compiled, args, calls) for _ in range(repeats)]
    work = batch * steps * agents
    return {"batch": batch, "steps": steps, "compile_s": round(compile_s, 3), "calls_per_timing": calls,
            "seconds": round(statistics.median(per_call), 5), "agent_steps_per_s": work / statistics.median(per_call),
            "agent_steps_per_s_best": work / min(per_call), "agent_steps_per_s_worst": work / max(per_call)}


def ours_scan(env, params):
    """``make_scan`` for our environment: random actions, ``vmap(env.step)``, the rewards summed (kept live)."""
    import jax
    import jax.numpy as jnp

    def make(batch: int, steps: int):
        start = jax.jit(lambda key: jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key, batch), params))
        obs, state = start(jax.random.key(1))
        actions = actions_before(jax.random.key(0), steps, batch, env.num_agents)

        def run(key, state, obs, actions):
            def body(carry, action):  # the observation is carried, as a learner carries it: it stays computed
                key, state, _, total = carry
                key, keys = step_keys(key, batch)
                obs, state, reward, *_ = jax.vmap(env.step, in_axes=(0, 0, 0, None))(keys, state, action, params)
                return (key, state, obs, total + reward.sum()), None

            (_, _, obs, total), _ = jax.lax.scan(body, (key, state, obs, jnp.zeros(())), actions)
            return obs, total

        return jax.jit(run), (jax.random.key(2), state, obs, actions)

    return make


def step_keys(key, batch: int):
    """One step's keys as a user's loop splits them (PureJaxRL style): the carried key, and one per environment."""
    import jax

    key, sub = jax.random.split(key)
    return key, jax.random.split(sub, batch)


def draws(key, steps: int, batch: int, agents: int):
    """Every step's uniform random actions ``(T, B, N)`` (ours and Jumanji's alike)."""
    import jax
    import jax.numpy as jnp

    return jax.random.randint(key, (steps, batch, agents), 0, 5, dtype=jnp.int32)


def actions_before(key, steps: int, batch: int, agents: int):
    """:func:`draws` before the timed call, as rware's actions are drawn before its loop (for Jumanji alike); our
    per-environment keys are split inside it (:func:`step_keys`), as a user pays for them. Drawing the actions
    inside would add what :func:`action_cost` measures: the harness, not the environment."""
    import functools

    import jax

    return jax.block_until_ready(jax.jit(functools.partial(draws, steps=steps, batch=batch, agents=agents))(key))


def action_cost(agents: int, batch: int, repeats: int) -> float:
    """Microseconds per environment step of drawing the random actions (:func:`draws`) inside a timed call."""
    import jax
    import jax.numpy as jnp

    def make(b: int, steps: int):
        return jax.jit(lambda key: jnp.sum(draws(key, steps, b, agents))), (jax.random.key(0),)

    row = time_scan(make, batch, agents, repeats)
    return 1e6 * row["seconds"] / (batch * row["steps"])


def state_bytes(env, batch: int) -> int:
    per_env = 4 * (env.num_agents * (6 + env.obs_size) + 2 * env.num_shelves + env.queue_size + 2)
    return 4 * batch * per_env  # state, observation, and the copies a step's selects make


def bench_tie_orders(name: str, batch: int, repeats: int) -> dict:
    """Our default ``tie_order="set"`` (unpatched rware's order) against ``"insertion"``, alternated, same batch."""
    import wrl_jax

    speeds = {"set": [], "insertion": []}
    for _ in range(2):
        for order in speeds:
            env, params = wrl_jax.make(name, tie_order=order)
            speeds[order].append(time_scan(ours_scan(env, params), batch, env.num_agents, repeats)["agent_steps_per_s"])
    middle = {order: statistics.median(values) for order, values in speeds.items()}
    print(f"  ours {name} B={batch}: tie_order set {middle['set']:,.0f}, insertion {middle['insertion']:,.0f} "
          f"agent-steps/s", flush=True)
    return {"batch": batch, "agent_steps_per_s": middle, "set_over_insertion": middle["set"] / middle["insertion"]}


def bench_ours(name: str, batches: list[int], repeats: int) -> list[dict]:
    import wrl_jax

    env, params = wrl_jax.make(name)
    rows = []
    for batch in batches:
        if state_bytes(env, batch) > MEMORY_LIMIT_BYTES:
            rows.append({"batch": batch, "skipped": "over the memory bound"})
            continue
        rows.append(time_scan(ours_scan(env, params), batch, env.num_agents, repeats))
        print(f"  ours {name} B={batch}: {rows[-1]['agent_steps_per_s']:,.0f} agent-steps/s "
              f"(compile {rows[-1]['compile_s']:.1f} s)", flush=True)
    return rows


def paired(name: str, batch: int, seconds: float, pairs: int) -> dict:
    """Ours at ``batch`` and rware's loop timed one after the other, ``pairs`` times: the machine's speed drifts
    within a run by tens of percent, which moves both timings of a pair alike, so the median of the pairs' ratios
    is the comparison (the tables' medians are each taken minutes apart)."""
    import wrl_jax

    env, params = wrl_jax.make(name)
    compiled, args, steps, _, calls = compile_scan(ours_scan(env, params), batch)
    ours, theirs = [], []
    for pair in range(pairs):  # ours first in even pairs, rware first in odd ones: neither side always runs second
        for side in ((0, 1) if pair % 2 == 0 else (1, 0)):
            if side == 0:
                ours.append(batch * steps * env.num_agents / seconds_per_call(compiled, args, calls))
            else:
                theirs.append(bench_rware(name, seconds, 1)["agent_steps_per_s"])
    ratios = [a / b for a, b in zip(ours, theirs)]
    return {"batch": batch, "pairs": pairs, "ours": ours, "rware": theirs, "ratios": ratios,
            "median_ratio": statistics.median(ratios)}


def bench_rware(name: str, seconds: float, repeats: int) -> dict:
    """:func:`rware_child` in a fresh process of this interpreter: rware's loop never shares a process with JAX (whose
    CPU threads, started by our timings, may take time from the Python loop)."""
    args = [sys.executable, __file__, "--rware-child", name, "--seconds", str(seconds), "--repeats", str(repeats)]
    done = subprocess.run(args, capture_output=True, text=True, timeout=600, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"the rware timing of {name} failed:\n{done.stderr.strip()[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def rware_child(name: str, seconds: float, repeats: int) -> dict:
    """rware's Python step on one environment, uniform random actions, reset when done: the median of ``repeats``
    loops of ``seconds``, after an untimed warm-up loop of up to half a second."""
    import gymnasium as gym
    import numpy as np
    import rware  # noqa: F401  (registers rware's ids)

    env = gym.make(name, disable_env_checker=True).unwrapped
    env.reset(seed=0)
    actions = np.random.default_rng(0).integers(0, 5, (100_000, env.n_agents)).tolist()
    rates, steps = [], 0
    for timed in [False] + [True] * repeats:
        start, t0 = steps, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            for a in actions[steps % 90_000: steps % 90_000 + 100]:
                _, _, done, _, _ = env.step(a)
                if done:
                    env.reset()
            steps += 100
            if not timed and time.perf_counter() - t0 >= min(seconds, 0.5):
                break
        if timed:
            rates.append((steps - start) * env.n_agents / (time.perf_counter() - t0))
    return {"steps": steps, "seconds_per_timing": seconds, "timings": repeats,
            "agent_steps_per_s": statistics.median(rates), "agent_steps_per_s_best": max(rates),
            "agent_steps_per_s_worst": min(rates)}


def bench_jumanji(python: str, name: str, batches: list[int], repeats: int) -> list[dict] | str:
    """Jumanji's RobotWarehouse, in a child process of its own interpreter; the reason when it cannot run."""
    if not Path(python).exists():
        return f"no interpreter at {python} (install: python -m venv /tmp/jumanji-venv && " \
               f"/tmp/jumanji-venv/bin/pip install jumanji==1.1.2)"
    args = [python, __file__, "--jumanji-child", name, "--repeats", str(repeats), "--batch-sizes", *map(str, batches)]
    done = subprocess.run(args, capture_output=True, text=True, timeout=900, check=False)
    if done.returncode != 0:
        return f"the Jumanji run failed: {done.stderr.strip().splitlines()[-1] if done.stderr else done.returncode}"
    return json.loads(done.stdout.strip().splitlines()[-1])


def jumanji_child(name: str, batches: list[int], repeats: int) -> None:
    """Run in Jumanji's interpreter: its RobotWarehouse with our id's layout, timed as ours."""
    import jax
    import jax.numpy as jnp
    import jumanji
    from jumanji.environments import RobotWarehouse
    from jumanji.environments.routing.robot_warehouse.generator import RandomGenerator
    from jumanji.wrappers import AutoResetWrapper

    rows_, columns, agents, queue = SIZES[name]
    env = AutoResetWrapper(RobotWarehouse(RandomGenerator(shelf_rows=rows_, shelf_columns=columns, column_height=8,
                                                          num_agents=agents, sensor_range=1,
                                                          request_queue_size=queue), time_limit=500))

    def make(batch: int, steps: int):
        state, timestep = jax.jit(lambda key: jax.vmap(env.reset)(jax.random.split(key, batch)))(jax.random.key(1))

        actions = actions_before(jax.random.key(0), steps, batch, agents)  # the same actions as ours, drawn before

        def run(state, view, actions):
            def body(carry, actions):
                state, _, total = carry
                state, timestep = jax.vmap(env.step)(state, actions)
                return (state, timestep.observation.agents_view, total + timestep.reward.sum()), None

            (_, view, total), _ = jax.lax.scan(body, (state, view, jnp.zeros(())), actions)
            return view, total

        return jax.jit(run), (state, timestep.observation.agents_view, actions)

    out = [time_scan(make, batch, agents, repeats) for batch in batches]
    print(json.dumps({"jumanji": jumanji.__version__, "jax": jax.__version__, "rows": out}))


PROFILE_VARIANTS = (
    ("step", "env.step: transition + auto-reset (what a learner runs)"),
    ("transition", "env.transition: no reset"),
    ("dynamics", "the dynamics alone: no observation"),
    ("no_conflicts", "the dynamics, every move committed (no move graph)"),
    ("no_deliveries", "the dynamics, no delivery pass"),
)
"""Variants of our step, each carried through its own scan (a state that changes, so nothing is hoisted)."""


def profile(name: str, batch: int, repeats: int) -> dict:
    """What bounds our step: variants with a part left out, timed as the step; the parts are the differences."""
    import contextlib

    import jax
    import jax.numpy as jnp

    import wrl_jax
    from wrl_jax.envs.rware import dynamics

    env, params = wrl_jax.make(name)
    n = env.num_agents

    @contextlib.contextmanager
    def without(part: str):
        saved = dynamics.resolve_moves, dynamics._deliver
        if part == "no_conflicts":
            dynamics.resolve_moves = lambda start, target, **_: jnp.ones(start.shape, bool)
        if part == "no_deliveries":
            dynamics._deliver = lambda state, reward, *rest: (state, reward, jnp.zeros(n, bool), jnp.zeros((), bool))
        try:
            yield
        finally:
            dynamics.resolve_moves, dynamics._deliver = saved

    def one_step(variant, key, state, obs, action):
        if variant == "step":
            return env.step(key, state, action, params)[:2][::-1]
        if variant == "transition":
            obs, state = env.transition(key, state, action, params)[:2]
            return state, obs
        replacements = dynamics.draw_replacements(key, params, env.queue_size)
        return dynamics.rware_transition(state, action, replacements, params)[0], obs

    times = {}
    for variant, label in PROFILE_VARIANTS:
        def make(b, steps, variant=variant):
            obs, state = jax.jit(lambda key: jax.vmap(env.reset, in_axes=(0, None))(
                jax.random.split(key, b), params))(jax.random.key(2))

            actions = actions_before(jax.random.key(1), steps, b, n)

            def run(key, state, obs, actions):
                def body(carry, action):
                    key, state, obs = carry
                    key, keys = step_keys(key, b)
                    return (key, *jax.vmap(lambda *a: one_step(variant, *a))(keys, state, obs, action)), None

                return jax.lax.scan(body, (key, state, obs), actions)[0]

            return jax.jit(run), (jax.random.key(3), state, obs, actions)

        with without(variant):
            row = time_scan(make, batch, n, repeats)
        times[variant] = 1e6 * row["seconds"] / (batch * row["steps"])
        print(f"  profile {label}: {times[variant]:.3f} us per env-step", flush=True)
    parts = {
        "auto-reset (a batched while: runs only on steps where an episode ends)": times["step"] - times["transition"],
        "observation (lookups of the sensor cells only, then the values as bits)":
            times["transition"] - times["dynamics"],
        "move graph (resolve_moves)": times["dynamics"] - times["no_conflicts"],
        "deliveries (goal by goal, written out)": times["dynamics"] - times["no_deliveries"],
        "rest of the dynamics (targets, cancel pass, cell lookups, shelf moves, draws, counters)":
            times["no_conflicts"] + times["no_deliveries"] - times["dynamics"],
    }
    return {"id": name, "batch": batch, "us_per_env_step": times, "parts_us": parts,
            "labels": dict(PROFILE_VARIANTS), "actions_us": action_cost(n, batch, repeats)}


NOTES = ("Notes. Every number is a median of timings of at least a second each (ours and Jumanji's: consecutive "
         "calls of one compiled scan; rware's: loops of `--seconds`); the JSON has the best and worst beside it. "
         "The machine's speed drifts within a run by tens of percent, so the ratio to rware is taken from timings "
         "of the two alternated (`--pairs`, ours at its best batch of the table): the median of the pairs' ratios, "
         "with their range. "
         "Ours: `jit(lax.scan(vmap(env.step)))`, auto-reset included, compile time apart (in the JSON); "
         "the random actions are drawn before each timed call, for rware and Jumanji alike "
         "(what drawing them inside costs is under the profile when it was run); our per-environment keys are split "
         "inside each step of the timed call, as a user's loop splits them (rware and Jumanji advance their own "
         "generators inside their steps). "
         "rware: its Python `Warehouse.step`, one environment, reset when done, in a process of its own without "
         "JAX. "
         "Jumanji: `python -m venv /tmp/jumanji-venv && /tmp/jumanji-venv/bin/pip install jumanji==1.1.2`, its "
         "`RobotWarehouse` (same layout, agents, sensor range, queue) behind `AutoResetWrapper`, timed as ours; "
         "its rules are not rware's (agents move one after another, a collision ends the episode, rewards are "
         "shared), so it is a speed reference only. One CPU run on a shared machine: expect noise of tens of "
         "percent between runs; the ratios are from the same run.")
"""The fixed text under the tables."""


def cores_sentence(cores: int | None) -> str:
    """What the run could use: rware's loop takes one core whatever the machine; XLA's CPU runtime splits our larger
    fusions over every core the process may run on (``taskset -c 0`` before the command leaves it one)."""
    if cores is None:
        return ""
    if cores == 1:
        return " Every side on one core (the process and its children pinned to it)."
    return (f" The process could use {cores} cores: rware's loop runs on one, XLA splits our larger fusions over "
            f"them (`taskset -c 0` before the command times every side on one core).")


def markdown(report: dict) -> str:
    batches = sorted({row["batch"] for entry in report["ids"].values() for row in entry["ours"]})
    lines = [f"# RWARE throughput ({report['date']}, {report['machine']})", "",
             f"`{report['command']}`", "", "Agent-steps per second (environment steps x 4 agents), random actions."
             + cores_sentence(report.get("cores")),
             "", ("| id | " + " | ".join(f"ours B={b}" for b in batches)
                  + " | rware (Python, 1 env) | ours / rware, alternated | Jumanji at its best batch |"),
             "|---|" + "---|" * (len(batches) + 3)]
    for name, entry in report["ids"].items():
        by_batch = {row["batch"]: row for row in entry["ours"]}
        cells = [f"{by_batch[b]['agent_steps_per_s']:,.0f}" if b in by_batch and "skipped" not in by_batch[b]
                 else "-" for b in batches]
        best = max(row.get("agent_steps_per_s", 0) for row in entry["ours"])
        jumanji = entry["jumanji"]
        jumanji_best = (f"{max(r['agent_steps_per_s'] for r in jumanji['rows']):,.0f}"
                        if isinstance(jumanji, dict) else "not run")
        pairs = entry.get("paired")
        ratio = (f"**{pairs['median_ratio']:,.0f}x** ({min(pairs['ratios']):,.0f}-{max(pairs['ratios']):,.0f}x over "
                 f"{pairs['pairs']} pairs at B={pairs['batch']})" if pairs
                 else f"{best / entry['rware']['agent_steps_per_s']:,.0f}x (best batch over rware, not alternated)")
        lines.append(f"| {name} | {' | '.join(cells)} | {entry['rware']['agent_steps_per_s']:,.0f} | "
                     f"{ratio} | {jumanji_best} |")
    for name, entry in report["ids"].items():
        if isinstance(entry["jumanji"], dict):
            lines += ["", f"Jumanji {entry['jumanji']['jumanji']} RobotWarehouse, layout of {name}: " + ", ".join(
                f"B={r['batch']} {r['agent_steps_per_s']:,.0f}" for r in entry["jumanji"]["rows"])]
    for name, entry in report["ids"].items():
        ties = entry.get("tie_orders")
        if ties:
            speed = ties["agent_steps_per_s"]
            lines += ["", (f"Tie order, {name} at B={ties['batch']}: the default `set` (unpatched rware's order) "
                           f"{speed['set']:,.0f} agent-steps/s, `insertion` {speed['insertion']:,.0f}: "
                           f"{ties['set_over_insertion']:.2f}x.")]
    prof = report.get("profile")
    if prof:
        step = prof["us_per_env_step"]["step"]
        lines += ["", (f"What our step spends, {prof['id']} at B={prof['batch']} (microseconds per environment "
                       "step; each part is the difference of two variants timed alike, so they are rough):"), "",
                  "| part | us / env-step | of the step |", "|---|---|---|"]
        lines += [f"| {part} | {us:.3f} | {us / step:.0%} |" for part, us in prof["parts_us"].items()]
        lines += [f"| whole step | {step:.3f} | 100% |"]
        if "actions_us" in prof:
            lines += ["", (f"Drawing the random actions inside the timed call would add {prof['actions_us']:.3f} us per "
                           f"environment step ({prof['actions_us'] / step:.0%} of the step at this batch); every timing "
                           "here draws them before it, as rware's are. Our per-environment keys are split inside it.")]
    lines += ["", NOTES]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ids", nargs="+", default=list(SIZES))
    parser.add_argument("--batch-sizes", nargs="+", type=int, default=[1, 32, 1024, 4096, 32768])
    parser.add_argument("--repeats", type=int, default=5, help="timings per configuration (the median is kept)")
    parser.add_argument("--seconds", type=float, default=2.0, help="each of rware's timed Python loops, per id")
    parser.add_argument("--pairs", type=int, default=7,
                        help="timings of ours (at its best batch) and rware alternated, per id: the headline ratio")
    parser.add_argument("--jumanji-python", default="/tmp/jumanji-venv/bin/python")
    parser.add_argument("--profile", action="store_true", help="time the parts of our step at --profile-batch")
    parser.add_argument("--profile-batch", type=int, default=1024)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "rware")
    parser.add_argument("--markdown-only", action="store_true", help="rewrite throughput.md from throughput.json")
    parser.add_argument("--tie-orders", nargs="+", metavar="ID",
                        help="only time tie_order 'set' against 'insertion' on these rware ids, at --profile-batch")
    parser.add_argument("--jumanji-child", help=argparse.SUPPRESS)
    parser.add_argument("--rware-child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.tie_orders:
        rows = {name: bench_tie_orders(name, args.profile_batch, args.repeats) for name in args.tie_orders}
        print(json.dumps(rows, indent=1))
        return
    if args.markdown_only:
        (args.out / "throughput.md").write_text(markdown(json.loads((args.out / "throughput.json").read_text())))
        return
    if args.rware_child:
        print(json.dumps(rware_child(args.rware_child, args.seconds, args.repeats)))
        return
    if args.jumanji_child:
        jumanji_child(args.jumanji_child, args.batch_sizes, args.repeats)
        return
    unknown = sorted(set(args.ids) - set(SIZES))
    if unknown:
        parser.error(f"unknown ids {unknown}; known: {list(SIZES)}")
    import jax

    report = {"command": "python bench/rware_throughput.py " + " ".join(sys.argv[1:]),
              "date": time.strftime("%Y-%m-%d"), "machine": f"{platform.machine()}, {jax.devices()[0].device_kind}",
              "jax": jax.__version__, "cores": len(os.sched_getaffinity(0)), "ids": {}}
    for name in args.ids:
        print(name, flush=True)
        entry = {"ours": bench_ours(name, args.batch_sizes, args.repeats),
                 "rware": bench_rware(name, args.seconds, args.repeats),
                 "tie_orders": bench_tie_orders(name, args.profile_batch, args.repeats)}
        print(f"  rware {name}: {entry['rware']['agent_steps_per_s']:,.0f} agent-steps/s", flush=True)
        best = max((row for row in entry["ours"] if "skipped" not in row), key=lambda row: row["agent_steps_per_s"])
        entry["paired"] = paired(name, best["batch"], args.seconds, args.pairs)
        print(f"  ours / rware alternated at B={best['batch']}: median {entry['paired']['median_ratio']:,.0f}x "
              f"({min(entry['paired']['ratios']):,.0f}-{max(entry['paired']['ratios']):,.0f}x)", flush=True)
        entry["jumanji"] = bench_jumanji(args.jumanji_python, name, args.batch_sizes, args.repeats)
        print(f"  jumanji {name}: {entry['jumanji'] if isinstance(entry['jumanji'], str) else 'done'}", flush=True)
        report["ids"][name] = entry
    if args.profile:
        report["profile"] = profile(args.ids[0], args.profile_batch, args.repeats)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "throughput.json").write_text(json.dumps(report, indent=2))
    (args.out / "throughput.md").write_text(markdown(report))
    print(markdown(report))


if __name__ == "__main__":
    main()
