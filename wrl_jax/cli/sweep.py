"""``python -m wrl_jax.sweep``: parse a grid of traced fields, run it as one program, write the outputs."""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import sys
import time
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from wrl_jax.training.sweep import ENV_FIELDS, Sweep, run_sweep
from wrl_jax.training.sweep_outputs import results_markdown, write_outputs


def parse_value(text: str, hint: Any = float) -> Any:
    """A ``--grid``/``--set`` value as the field's type (``int``, ``float``, ``bool``, ``str``, ``tuple[int, ...]``)."""
    origin = typing.get_origin(hint)
    if origin is tuple:
        (item,) = {a for a in typing.get_args(hint) if a is not Ellipsis}
        return tuple(parse_value(part, item) for part in text.replace("x", ",").split(",") if part)
    if hint is bool:
        if text.lower() in ("1", "true", "yes"):
            return True
        if text.lower() in ("0", "false", "no"):
            return False
        raise ValueError(f"expected true or false, got {text!r}")
    if hint is int:
        return int(text)
    if hint is float:
        return float(text)
    if typing.get_origin(hint) is typing.Literal or hint is str:
        return text
    return float(text)


def _field_hint(config_cls: type, name: str) -> Any:
    if name == "max_steps":
        return int
    hints = typing.get_type_hints(config_cls)
    return hints.get(name, float)


def parse_grid(items: Sequence[str], config_cls: type) -> dict[str, list[Any]]:
    """``["learning_rate=0.003,0.01", "ent_coef=0.05,0.2"]`` -> ``{"learning_rate": [0.003, 0.01], ...}``."""
    grid: dict[str, list[Any]] = {}
    for item in items:
        name, sep, values = item.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or not name or not values.strip():
            raise ValueError(f"--grid expects FIELD=V1,V2,..., got {item!r}")
        if name in grid:
            raise ValueError(f"--grid gives {name!r} twice")
        hint = _field_hint(config_cls, name)
        try:
            grid[name] = [parse_value(v.strip(), hint) for v in values.split(",") if v.strip()]
        except ValueError as exc:
            raise ValueError(f"--grid {name}: {exc}") from None
    return grid


def parse_sets(items: Sequence[str], config_cls: type) -> tuple[dict[str, Any], dict[str, Any]]:
    """``--set FIELD=VALUE`` items -> (config overrides, environment overrides)."""
    config_fields = {f.name for f in dataclasses.fields(config_cls)}
    config, env = {}, {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or not name:
            raise ValueError(f"--set expects FIELD=VALUE, got {item!r}")
        if name in ENV_FIELDS:
            env[name] = parse_value(value.strip(), int if name == "max_steps" else float)
        elif name == "observe_carrying":
            env[name] = parse_value(value.strip(), bool)
        elif name in config_fields:
            try:
                config[name] = parse_value(value.strip(), _field_hint(config_cls, name))
            except ValueError as exc:
                raise ValueError(f"--set {name}: {exc}") from None
        else:
            raise ValueError(f"--set: unknown field {name!r}; config fields: {sorted(config_fields)}; "
                             f"environment: {list(ENV_FIELDS) + ['observe_carrying']}")
    return config, env


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m wrl_jax.sweep",
        description="A grid of traced hyperparameters x seeds trained as one compiled program; writes a results "
        "table (Markdown, CSV, JSON) and a plot.",
        epilog="Example: python -m wrl_jax.sweep --algo ppo --env Warehouse-8x8-v0 --grid learning_rate=0.003,0.01 "
        "--grid ent_coef=0.02,0.2 --grid shaping_coef=0,2 --num-seeds 4 --set total_timesteps=60000 --out runs/sweep",
    )
    parser.add_argument("--algo", required=True, help="ppo or dqn")
    parser.add_argument("--env", default=None, help="registered environment (default: the algorithm's)")
    parser.add_argument("--preset", default=None, help="base hyperparameter preset (default: the algorithm's)")
    parser.add_argument("--grid", action="append", default=[], metavar="FIELD=V1,V2,...",
                        help="a traced field and its values (repeat for more fields; the grid is their product)")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="a value for the whole sweep (static fields such as total_timesteps, hidden_sizes=64,64, "
                        "or environment constants)")
    parser.add_argument("--num-seeds", type=int, default=4, help="seeds per grid point")
    parser.add_argument("--seed", type=int, default=0, help="first seed (seeds seed .. seed + num_seeds - 1)")
    parser.add_argument("--out", default=None, help="output directory (default runs/sweep-<algo>-<time>)")
    parser.add_argument("--eval-every", type=int, default=None, help="greedy evaluation every N updates (0: last only)")
    parser.add_argument("--chunk-updates", type=int, default=None)
    parser.add_argument("--log-every", type=int, default=None)
    parser.add_argument("--devices", type=int, default=1,
                        help="shard the batch of points x seeds over this many devices (0: all; 1: no sharding)")
    parser.add_argument("--env-shards", type=int, default=1,
                        help="of those devices, how many split each run's environments")
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument("--no-plot", action="store_true")
    parser.add_argument("--xla-opt-level", type=int, default=None, help="XLA CPU optimization level (default 1)")
    return parser


def main(argv: list[str] | None = None) -> int:
    """``python -m wrl_jax.sweep``; status 2 with ``error: ...`` on a bad sweep."""

    from wrl_jax import cli

    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    try:
        spec = cli.get_spec(args.algo)
        preset = args.preset or spec.preset_for(args.env or spec.default_env)
        if preset not in spec.presets:
            raise ValueError(f"unknown {spec.name} preset {preset!r}; choose from {sorted(spec.presets)}")
        config_sets, env_sets = parse_sets(args.set, spec.config_cls)
        config = dataclasses.replace(spec.presets[preset], **config_sets)
        grid = parse_grid(args.grid, spec.config_cls)
        if args.num_seeds < 1:
            raise ValueError(f"--num-seeds must be at least 1, got {args.num_seeds}")
        if args.devices < 0 or args.env_shards < 1:
            raise ValueError("--devices must be >= 0 and --env-shards >= 1")
        cli.apply_xla_opt_level(cli.DEFAULT_XLA_OPT_LEVEL if args.xla_opt_level is None else args.xla_opt_level)
        sweep = Sweep(
            algo_name=spec.name,
            config=config,
            env_name=args.env or spec.default_env,
            env_overrides=env_sets,
            grid=grid,
            seeds=list(range(args.seed, args.seed + args.num_seeds)),
        )
        from wrl_jax.training import driver as training

        loop = training.LoopConfig(
            chunk_updates=args.chunk_updates,
            eval_every=args.eval_every,
            log_every=args.log_every,
            progress=not args.no_progress,
        )
        loop.resolve(sweep.algo.num_updates)
        mesh = None
        if args.devices != 1 or args.env_shards != 1:
            from wrl_jax.training import sharding

            mesh = sharding.make_mesh(args.devices, args.env_shards)
            sharding.check_layout(len(sweep.batch_seeds), getattr(config, "num_envs", None), mesh)
            print(f"sharding over {sharding.describe(mesh)}", file=sys.stderr)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else Path("runs") / (
        f"sweep-{spec.name}-{datetime.datetime.now().strftime('%Y%m%d-%H%M%S')}"
    )
    wall = time.perf_counter()
    result = run_sweep(sweep, loop, mesh)
    result.timings["wall_seconds"] = time.perf_counter() - wall
    command = "python -m wrl_jax.sweep " + " ".join(argv)
    write_outputs(result, out, command, plot=not args.no_plot)
    print(results_markdown(result))
    plot_name = "" if args.no_plot else ", sweep.png"
    print(f"outputs in {out}/ (results.md, results.csv, results.json, metrics.csv{plot_name})")
    return 0
