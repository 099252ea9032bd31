"""``python -m wrl_jax.plan``: run a classical planner on a fleet, or pure pursuit on the continuous warehouse.

Examples::

    python -m wrl_jax.plan --planner pibt --env Fleet-12x12-v0 --num-robots 8 --episodes 32 --json pibt.json
    python -m wrl_jax.plan --planner pursuit --env Continuous-Warehouse-12x12-Dynamic-v0 --episodes 256
    python -m wrl_jax.plan --planner scripted --env rware-tiny-4ag-v2 --episodes 32 --json scripted.json

The planner names the family: ``greedy`` and ``pibt`` plan fleets, ``pursuit`` drives the continuous
warehouse. Fleet: all episodes (shifts of ``--horizon`` steps, default the env's ``max_steps``)
run vmapped in one jitted program (:func:`wrl_jax.envs.fleet.metrics.run_episodes`).
Printed and written: throughput (deliveries per step, all robots) with a 95 %
Student-t interval over episodes, the bound ``K / L*`` (FLEET_SPEC.md
"Metrics"), and per robot the mean deliveries, shelf hits, wall bumps,
robot blocks and waits per shift. Continuous: episode ``e`` takes item ``e mod I``, all vmapped in one
program (:func:`wrl_jax.envs.continuous.yardstick.pursuit_episodes`); printed and written: the delivery
rate, collisions per episode, and per item the mean steps against CONTINUOUS_SPEC.md's yardstick
``D_i / (v_max dt)`` (``--randomize`` for domain randomization). RWARE: ``scripted``, the centralised
fetch-and-return team (:mod:`wrl_jax.envs.rware.scripted`) on the evaluation's fixed episodes
(``--seed 0``: those the training evaluation runs), beside a uniform random team on the same ones;
printed and written: the team return (all agents' rewards over an episode, EPyMARL's number) with a
95 % interval over episodes, and deliveries per episode. Bad flags raise ``ValueError`` before
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
    out.add_argument("--planner", default="pibt",
                     help="greedy or pibt (fleet), pursuit (continuous), scripted (rware); default pibt")
    out.add_argument("--env", default="Fleet-12x12-v0", help="a registered fleet, continuous or rware environment")
    out.add_argument("--num-robots", type=int, default=None, help="fleet: K, 1..number of start cells (default 4)")
    out.add_argument("--episodes", type=int, default=32, help="E shifts, vmapped (default 32)")
    out.add_argument("--horizon", type=int, default=None,
                     help="fleet, rware: steps per shift or episode (default: the env's max_steps)")
    out.add_argument("--randomize", action="store_true", help="continuous: domain randomization (gains, noise)")
    out.add_argument("--seed", type=int, default=0)
    out.add_argument("--json", type=Path, default=None, help="write the full report here")
    out.add_argument("--xla-opt-level", type=int, default=DEFAULT_XLA_OPT_LEVEL,
                     help="XLA CPU backend optimization level; -1 keeps XLA's default")
    return out


def _positive(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return value


PLANNER_FAMILIES = {"greedy": "fleet", "pibt": "fleet", "pursuit": "continuous", "scripted": "rware"}
"""Each planner and the environment family it drives."""


def check_family(planner: str, env_name: str) -> str:
    """The family ``planner`` drives, when ``env_name`` is of it; else a ``ValueError`` saying what fits."""
    from wrl_jax.core import registry

    if planner not in PLANNER_FAMILIES:
        raise ValueError(f"unknown planner {planner!r}; known: greedy, pibt (fleet environments), "
                         f"pursuit (continuous environments), scripted (rware environments)")
    family, found = PLANNER_FAMILIES[planner], registry.entry(env_name).family
    if found != family:
        hint = {"continuous": "; a continuous environment takes --planner pursuit",
                "fleet": "; a fleet takes --planner greedy or pibt",
                "rware": "; an rware environment takes --planner scripted"}.get(found, "")
        names = registry.registered_names(family)
        shortest = ", ".join(sorted(names, key=lambda name: (len(name), name))[:4])
        listed = ", ".join(names) if len(names) <= 12 else f"{len(names)} ids, such as {shortest}"
        article = "an" if family == "rware" else "a"
        raise ValueError(f"--env {env_name!r} is not {article} {family} environment (--planner {planner}){hint}; "
                         f"{family} environments: {listed}")
    return family


def run_plan(planner: str, env_name: str, num_robots: int | None, episodes: int, horizon: int | None = None,
             seed: int = 0) -> dict[str, Any]:
    """Validate, build, run and summarize a fleet planner; the report as a JSON-ready dict."""
    import jax

    from wrl_jax.core import registry
    from wrl_jax.envs.fleet import metrics
    from wrl_jax.envs.fleet.planners import check_planner

    check_planner(planner)
    num_robots = 4 if num_robots is None else num_robots
    _positive("--num-robots", num_robots)
    _positive("--episodes", episodes)
    check_family(planner, env_name)
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


def run_pursuit_plan(env_name: str, episodes: int, seed: int = 0, randomize: bool = False) -> dict[str, Any]:
    """Validate, build, run and summarize pure pursuit on a continuous environment (every item covered)."""
    import jax

    from wrl_jax.core import registry
    from wrl_jax.envs.continuous import yardstick
    from wrl_jax.envs.continuous.pursuit import PursuitConfig, make_plan

    _positive("--episodes", episodes)
    check_family("pursuit", env_name)
    env, params = registry.make(env_name, randomize=randomize)
    config = PursuitConfig()
    plan, bounds = make_plan(params, config), yardstick.item_bounds(params)
    horizon, key = int(params.max_steps), jax.random.key(seed)
    start = time.perf_counter()
    compiled = yardstick.pursuit_episodes.lower(env, params, plan, config, key, episodes, horizon).compile()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    results = jax.device_get(compiled(params, plan, key))
    run_s = time.perf_counter() - start
    report = yardstick.summarize(results, bounds, int(params.num_items))
    report.update(env=env_name, planner="pursuit", family="continuous", seed=seed, randomize=randomize,
                  max_steps=horizon, compile_s=compile_s, run_s=run_s, jax=jax.__version__, machine=cpu_info())
    return report


def run_scripted_plan(env_name: str, episodes: int, horizon: int | None = None, seed: int = 0) -> dict[str, Any]:
    """Validate, build, run and summarize the scripted RWARE team, and a random team on the same episodes."""
    import jax
    import numpy as np

    from wrl_jax.core import registry
    from wrl_jax.envs.rware import evaluation, scripted
    from wrl_jax.stats import mean_ci

    _positive("--episodes", episodes)
    check_family("scripted", env_name)
    env, params = registry.make(env_name)
    horizon = evaluation.horizon_of(env) if horizon is None else _positive("--horizon", horizon)
    static = {"num_episodes": episodes, "horizon": horizon, "seed": seed}
    start = time.perf_counter()
    compiled = evaluation.team_episodes.lower(env, params, team="scripted", **static).compile()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    result = jax.device_get(compiled(params))
    run_s = time.perf_counter() - start
    floor = jax.device_get(evaluation.team_episodes(env, params, team="random", **static))
    returns, deliveries = np.asarray(result.team_return, np.float64), np.asarray(result.deliveries)
    interval = mean_ci(returns)
    return {
        "env": env_name, "planner": "scripted", "family": "rware", "episodes": episodes, "horizon": horizon,
        "seed": seed, "num_agents": env.num_agents,
        "return": interval.mean, "return_ci95": [interval.low, interval.high],
        "return_min": float(returns.min()), "return_max": float(returns.max()),
        "deliveries": float(deliveries.sum(axis=1).mean()),
        "deliveries_per_agent": [float(v) for v in deliveries.mean(axis=0)],
        "agents_delivering": float((deliveries > 0).mean()), "solved": bool(np.all(deliveries > 0)),
        "length": float(np.mean(result.length)),
        "random_return": float(np.mean(floor.team_return)),
        "random_deliveries": float(np.asarray(floor.deliveries).sum(axis=1).mean()),
        "settings": {"explore": scripted.EXPLORE, "blocked_explore": scripted.BLOCKED_EXPLORE, "crowd": scripted.CROWD},
        "unit": "return: all agents' rewards summed over an episode (EPyMARL's RWARE return)",
        "compile_s": compile_s, "run_s": run_s, "agent_steps_per_s": episodes * horizon * env.num_agents / run_s,
        "jax": jax.__version__, "machine": cpu_info(),
    }


def format_scripted_report(report: dict[str, Any]) -> str:
    low, high = report["return_ci95"]
    per_agent = ", ".join(f"{v:.2f}" for v in report["deliveries_per_agent"])
    header = (f"scripted on {report['env']}, {report['num_agents']} agents, {report['episodes']} episodes of "
              f"{report['horizon']} steps (seed {report['seed']}; compile {report['compile_s']:.1f} s, "
              f"run {report['run_s']:.2f} s)")
    returns = (f"team return {report['return']:.2f}, 95% CI [{low:.2f}, {high:.2f}] (episodes "
               f"{report['return_min']:.0f} to {report['return_max']:.0f}); random team {report['random_return']:.2f}")
    deliveries = (f"deliveries per episode {report['deliveries']:.2f} (per agent {per_agent}); every agent delivered "
                  f"in every episode: {'yes' if report['solved'] else 'no'}")
    return f"{header}\n{returns}\n{deliveries}"


def format_pursuit_report(report: dict[str, Any]) -> str:
    hits = report["hits_per_episode"]
    excess = "n/a (nothing delivered)" if report["excess_pct"] is None else f"{report['excess_pct']:+.1f} %"
    lines = [
        f"pursuit on {report['env']}{' (randomized)' if report['randomize'] else ''}, {report['episodes']} episodes "
        f"(seed {report['seed']}; compile {report['compile_s']:.1f} s, run {report['run_s']:.2f} s)",
        f"delivered {100 * report['delivery_rate']:.1f} %, collisions {report['collisions_per_episode']:.2f} "
        f"per episode (shelf {hits['hit_shelf']:.2f}, wall {hits['hit_wall']:.2f}, "
        f"obstacle {hits['hit_obstacle']:.2f}); "
        f"per episode: waits {report['waits_per_episode']:.1f}, steps aside {report['escapes_per_episode']:.2f}, "
        f"guard stops {report['guard_stops_per_episode']:.2f}",
        f"mean steps per item {report['mean_steps_per_item'] or float('nan'):.1f} against the bound D/(v_max dt) "
        f"{report['mean_bound_steps']:.1f}: excess {excess} (mean of the per-item ratios, delivered episodes)",
        "item  episodes  delivered  mean_steps  bound  strict  excess%",
    ]
    for item in report["per_item"]:
        steps = "-" if item["mean_steps"] is None else f"{item['mean_steps']:.1f}"
        excess = "-" if item["excess_pct"] is None else f"{item['excess_pct']:+.1f}"
        lines.append(f"{item['item']:4d}  {item['episodes']:8d}  {item['delivered']:9d}  {steps:>10}  "
                     f"{item['bound_steps']:5.1f}  {item['strict_bound_steps']:6.1f}  {excess:>7}")
    return "\n".join(lines)


def format_report(report: dict[str, Any]) -> str:
    if report.get("family") == "continuous":
        return format_pursuit_report(report)
    if report.get("family") == "rware":
        return format_scripted_report(report)
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
        family = check_family(args.planner, args.env)
        if family == "continuous":
            for flag, value in (("--num-robots", args.num_robots), ("--horizon", args.horizon)):
                if value is not None:
                    raise ValueError(f"{flag} is for fleets; pure pursuit drives one robot for the env's max_steps")
            report = run_pursuit_plan(args.env, args.episodes, args.seed, args.randomize)
        elif family == "rware":
            if args.num_robots is not None:
                raise ValueError("--num-robots is for fleets; an rware id fixes its agent count")
            if args.randomize:
                raise ValueError("--randomize is for continuous environments (--planner pursuit)")
            report = run_scripted_plan(args.env, args.episodes, args.horizon, args.seed)
        else:
            if args.randomize:
                raise ValueError("--randomize is for continuous environments (--planner pursuit)")
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
