"""Where the JAX PIBT's time goes: its loop's iteration counts and the share of the work before the loop.

PIBT alone (``wrl_jax.envs.fleet.planners.plan("pibt", ...)``) jitted and vmapped over fleet
states recorded from PIBT shifts (the planner-alone states of ``bench/fleet_throughput.py``):

* the ``lax.while_loop``'s iterations per state (mean, percentiles, max): under ``vmap`` every
  state of a batch runs as many iterations as the slowest one, so their spread is what vmap costs;
* the time of the candidate distances and preference lists (the work before the loop) against
  the whole planner, median of ``--repeats`` calls after a warm-up, compile time apart, compiled with
  the planners' XLA options (``planners.compiler_options()``), and the whole planner again with XLA's
  default options.

``--baseline FILE`` (an older copy of ``wrl_jax/envs/fleet/planners.py``) adds the whole planner of that
file on the same states, timed interleaved with the current one, its moves checked equal, and the ratio.

Run from the repository root::

    .venv/bin/python bench/investigations/pibt_profile.py --robots 4 8 --batch 4096
    git show 37682ab:wrl_jax/envs/fleet/planners.py > /tmp/planners_before.py
    .venv/bin/python bench/investigations/pibt_profile.py --robots 8 --batch 32768 --baseline /tmp/planners_before.py
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: host_split


def _median_seconds(fns, args, repeats: int) -> list[float]:
    """Median seconds of each of ``fns`` on ``args``, timed interleaved (one call of each per round)."""
    import jax

    for fn in fns:
        jax.block_until_ready(fn(*args))
    times = [[] for _ in fns]
    for _ in range(repeats):
        for fn, mine in zip(fns, times):
            start = time.perf_counter()
            jax.block_until_ready(fn(*args))
            mine.append(time.perf_counter() - start)
    return [statistics.median(mine) for mine in times]


def load_planners(path: str):
    """An older ``planners.py`` as a module (it imports only JAX, flax and the package's grid and types)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("pibt_profile_baseline_planners", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def profile(num_robots: int, batch: int, repeats: int, baseline: str | None = None) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from fleet_throughput import ENV, recorded_states
    from wrl_jax import make
    from wrl_jax.envs.fleet import planners

    _, params = make(ENV, num_robots=num_robots)
    recorded = recorded_states(num_robots, batch, seed=0)
    state = jax.tree.map(jnp.asarray, recorded["state"])
    prio = jax.tree.map(jnp.asarray, recorded["prio"])
    size = int(params.shelves.shape[-1])

    real_while = jax.lax.while_loop

    def counted(p, s):  # the planner with its while_loop wrapped to count iterations
        count = {}

        def while_loop(cond, body, init):
            final, n = real_while(lambda c: cond(c[0]), lambda c: (body(c[0]), c[1] + 1), (init, jnp.int32(0)))
            count["n"] = n
            return final

        planners.jax.lax.while_loop = while_loop
        try:
            action = planners.plan("pibt", p, s, params)
        finally:
            planners.jax.lax.while_loop = real_while
        return action, count["n"]

    _, iterations = jax.jit(jax.vmap(counted))(prio, state)
    iterations = np.asarray(iterations)

    def before_loop(p, s):
        keys = planners.preference_keys(planners.candidate_ids(s.pos, size), planners.fleet_candidate_distances(s, params))
        return jnp.sum(keys % 8) + jnp.sum(planners.pibt_priorities(p))

    options = planners.compiler_options()  # as the library compiles its planner programs
    whole = jax.jit(jax.vmap(lambda p, s: planners.plan("pibt", p, s, params)), compiler_options=options)
    whole_defaults = jax.jit(jax.vmap(lambda p, s: planners.plan("pibt", p, s, params)))
    before = jax.jit(jax.vmap(before_loop), compiler_options=options)
    fns = [whole, whole_defaults, before]
    if baseline:
        old = load_planners(baseline)
        old_whole = jax.jit(jax.vmap(lambda p, s: old.plan("pibt", old.PibtState(age=p.age, tiebreak=p.tiebreak), s,
                                                            params)), compiler_options=options)
        if not np.array_equal(np.asarray(old_whole(prio, state)), np.asarray(whole(prio, state))):
            raise AssertionError(f"{baseline} plans other moves than the current PIBT")
        fns.append(old_whole)
    times = _median_seconds(fns, (prio, state), repeats)
    whole_s, defaults_s, before_s = times[:3]
    extra = {"baseline": baseline, "baseline_planner_ms": times[3] * 1e3,
             "current_vs_baseline": times[3] / whole_s} if baseline else {}
    return {**extra,
        "num_robots": num_robots, "batch": batch,
        "iterations_mean": float(iterations.mean()), "iterations_max": int(iterations.max()),
        "iterations_p50_p90_p99": [float(x) for x in np.percentile(iterations, [50, 90, 99])],
        "compiler_options": options, "planner_ms": whole_s * 1e3, "before_loop_ms": before_s * 1e3,
        "robot_decisions_per_s": batch * num_robots / whole_s,
        "planner_ms_xla_defaults": defaults_s * 1e3,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", type=int, nargs="+", default=[4, 8])
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--baseline", default=None, help="an older copy of wrl_jax/envs/fleet/planners.py")
    args = parser.parse_args(argv)
    rows = [profile(k, args.batch, args.repeats, args.baseline) for k in args.robots]
    for row in rows:
        print(f"K={row['num_robots']} batch={row['batch']}: loop iterations mean {row['iterations_mean']:.2f}, "
              f"max {row['iterations_max']}; planner {row['planner_ms']:.2f} ms, before the loop "
              f"{row['before_loop_ms']:.2f} ms; {row['robot_decisions_per_s'] / 1e6:.2f} M decisions/s "
              f"(with XLA's default options {row['planner_ms_xla_defaults']:.2f} ms)"
              + (f"; baseline {row['baseline_planner_ms']:.2f} ms, current {row['current_vs_baseline']:.2f}x faster, "
                 f"same moves" if args.baseline else ""))
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "command": " ".join(sys.argv)}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
