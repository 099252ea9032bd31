"""``python -m wrl_jax.plan``: run a classical planner on a fleet and report its throughput.

Example::

    python -m wrl_jax.plan --planner pibt --env Fleet-12x12-v0 --num-robots 8 --episodes 32 --json pibt.json

All episodes (shifts of ``--horizon`` steps, default the env's ``max_steps``)
run vmapped in one jitted program (:func:`wrl_jax.envs.fleet.metrics.run_episodes`).
Printed and written: throughput (deliveries per step, all robots) with a 95 %
Student-t interval over episodes, the bound ``K / L*`` (FLEET_SPEC.md
"Metrics"), and per robot the mean deliveries, shelf hits, wall bumps,
robot blocks and waits per shift. Bad flags raise ``ValueError`` before
anything compiles; the command prints it and exits with status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from wrl_jax.cli.machine import DEFAULT_XLA_OPT_LEVEL, apply_xla_opt_level, cpu_info


def parser() -> argparse.ArgumentParser:
    out = argparse.ArgumentParser(prog="python -m wrl_jax.plan", description=__doc__.split("\n\n")[0])
    out.add_argument("--planner", default="pibt", help="greedy or pibt (default pibt)")
    out.add_argument("--env", default="Fleet-12x12-v0", help="a registered fleet environment")
    out.add_argument("--num-robots", type=int, default=4, help="K, 1..number of start cells (default 4)")
    out.add_argument("--episodes", type=int, default=32, help="E shifts, vmapped (default 32)")
    out.add_argument("--horizon", type=int, default=None, help="steps per shift (default: the env's max_steps)")
    out.add_argument("--seed", type=int, default=0)
    out.add_argument("--json", type=Path, default=None, help="write the full report here")
    out.add_argument("--xla-opt-level", type=int, default=DEFAULT_XLA_OPT_LEVEL,
                     help="XLA CPU backend optimization level; -1 keeps XLA's default")
    return out


def _positive(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return value


def run_plan(planner: str, env_name: str, num_robots: int, episodes: int, horizon: int | None = None,
             seed: int = 0) -> dict[str, Any]:
    """Validate, build, run and summarize; the report as a JSON-ready dict."""
    import jax

    from wrl_jax.core import registry
    from wrl_jax.envs.fleet import metrics
    from wrl_jax.envs.fleet.planners import check_planner

    check_planner(planner)
    _positive("--num-robots", num_robots)
    _positive("--episodes", episodes)
    if registry.entry(env_name).family != "fleet":
        raise ValueError(f"--env {env_name!r} is not a fleet environment; fleet environments: "
                         f"{', '.join(registry.registered_names('fleet'))}")
    env, params = registry.make(env_name, num_robots=num_robots)
    horizon = int(params.max_steps) if horizon is None else _positive("--horizon", horizon)

    start = time.perf_counter()
    compiled = metrics.run_episodes.lower(env, params, planner, jax.random.key(seed), episodes, horizon).compile()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    counts = jax.block_until_ready(compiled(params, jax.random.key(seed)))
    run_s = time.perf_counter() - start
    report = metrics.summarize(counts, horizon, params)
    report.update(env=env_name, planner=planner, seed=seed, compile_s=compile_s, run_s=run_s,
                  robot_steps_per_s=episodes * horizon * num_robots / run_s, jax=jax.__version__, machine=cpu_info())
    return report


def format_report(report: dict[str, Any]) -> str:
    tp, bound = report["throughput"], report["upper_bound"]
    low, high = tp["ci95"]
    interval = "n/a (one episode)" if low is None else f"[{low:.4f}, {high:.4f}]"
    lines = [
        f"{report['planner']} on {report['env']}, K={report['num_robots']}, {report['episodes']} shifts of "
        f"{report['horizon']} steps (seed {report['seed']}; compile {report['compile_s']:.1f} s, "
        f"run {report['run_s']:.2f} s)",
        f"throughput {tp['mean']:.4f} deliveries/step, 95% CI {interval}",
        f"bound K/L* = {bound['throughput']:.4f} (L* = {bound['mean_round_trip']:.2f}), "
        f"{100 * bound['fraction']:.1f} % of it",
        "robot  deliveries  shelf_hits  wall_bumps  robot_blocks  waits   (means per shift)",
    ]
    per = report["per_robot"]
    for i in range(report["num_robots"]):
        lines.append(f"{i:5d}  {per['deliveries'][i]:10.2f}  {per['shelf_hits'][i]:10.2f}  "
                     f"{per['wall_bumps'][i]:10.2f}  {per['robot_blocks'][i]:12.2f}  {per['waits'][i]:6.2f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    apply_xla_opt_level(args.xla_opt_level)
    try:
        report = run_plan(args.planner, args.env, args.num_robots, args.episodes, args.horizon, args.seed)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(format_report(report))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0
