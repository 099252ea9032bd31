"""``python -m wrl_jax.sweep``: parse a grid of traced fields, run it as one program, write the outputs.

Any registered environment: a ``--set``/``--grid`` name that is not a config
field is an option of ``--env`` (what ``wrl_jax.make`` takes there), typed by
the environment's params; the algorithm's environment defaults (the fleet's
``block_penalty``, as ``train_ppo.py`` applies them) hold unless ``--set`` or
``--grid`` changes them.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import functools
import sys
import time
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from wrl_jax.training.sweep import Sweep, run_sweep
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


def _auto_value(text: str) -> Any:
    """An environment option with no params leaf to take a type from (``num_robots``, ``shaping``,
    ``max_shape``...): ``true``/``false``, an int, a float, a comma-separated tuple of those, else the text."""
    if "," in text:
        return tuple(_auto_value(part.strip()) for part in text.split(",") if part.strip())
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def default_env(config_cls: type) -> str | None:
    """The default environment of the algorithm whose config is ``config_cls`` (what ``--env`` defaults to)."""
    from wrl_jax.agents import ALGORITHM_MODULES, get_spec

    for name in ALGORITHM_MODULES:
        spec = get_spec(name)
        if spec.config_cls is config_cls:
            return spec.default_env
    return None


@functools.cache
def env_value_hints(env_name: str | None) -> dict[str, type]:
    """``int``, ``float`` or ``bool`` per scalar params leaf of ``env_name``: the type its values parse to.

    Read from the environment's default params, so ``block_penalty=-1`` is the
    float ``-1.0`` and ``max_steps=50`` the int ``50`` on any family.
    """
    import wrl_jax
    from wrl_jax.training.sweep import traced_env_fields

    if env_name is None:
        return {}
    try:
        _, params = wrl_jax.make(env_name)
    except ValueError:
        return {}
    kinds = {"b": bool, "i": int, "u": int, "f": float}
    return {name: kinds.get(getattr(params, name).dtype.kind, float) for name in traced_env_fields(params)}


def _parse_field(name: str, text: str, config_cls: type, env_name: str | None) -> Any:
    """A value of a config field (its annotated type) or of an environment option (its params dtype, else guessed)."""
    if name in {f.name for f in dataclasses.fields(config_cls)}:
        return parse_value(text, typing.get_type_hints(config_cls).get(name, float))
    hints = env_value_hints(env_name)
    if name in hints:
        return parse_value(text, hints[name])
    return _auto_value(text)


def parse_grid(items: Sequence[str], config_cls: type, env_name: str | None = None) -> dict[str, list[Any]]:
    """``["learning_rate=0.003,0.01", "ent_coef=0.05,0.2"]`` -> ``{"learning_rate": [0.003, 0.01], ...}``.

    ``env_name`` (default: the algorithm's default environment) types the
    environment fields' values; :class:`~wrl_jax.training.sweep.Sweep` judges the fields.
    """
    env_name = env_name or default_env(config_cls)
    grid: dict[str, list[Any]] = {}
    for item in items:
        name, sep, values = item.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or not name or not values.strip():
            raise ValueError(f"--grid expects FIELD=V1,V2,..., got {item!r}")
        if name in grid:
            raise ValueError(f"--grid gives {name!r} twice")
        try:
            grid[name] = [_parse_field(name, v.strip(), config_cls, env_name) for v in values.split(",") if v.strip()]
        except ValueError as exc:
            raise ValueError(f"--grid {name}: {exc}") from None
    return grid


def parse_sets(
    items: Sequence[str], config_cls: type, env_name: str | None = None, env_defaults: dict[str, Any] | None = None
) -> tuple[dict[str, Any], dict[str, Any]]:
    """``--set FIELD=VALUE`` items -> (config overrides, environment overrides).

    A name that is not a config field is an option of ``env_name`` (default:
    the algorithm's default environment): anything ``wrl_jax.make`` accepts
    there (``shaping_coef``, the fleet's ``num_robots``, the procedural
    ``pool_size``...), checked by calling it over the learner's ``env_defaults``
    (a ``safety_margin`` needs the stop those turn on).
    """
    env_name = env_name or default_env(config_cls)
    config_fields = {f.name for f in dataclasses.fields(config_cls)}
    config, env = {}, {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or not name:
            raise ValueError(f"--set expects FIELD=VALUE, got {item!r}")
        try:
            parsed = _parse_field(name, value.strip(), config_cls, env_name)
        except ValueError as exc:
            raise ValueError(f"--set {name}: {exc}") from None
        (config if name in config_fields else env)[name] = parsed
    _check_env_options(env, env_name, config_fields, _defaults_under(env_defaults or {}, env))
    return config, env


def _check_env_options(env: dict[str, Any], env_name: str | None, config_fields: set[str],
                       defaults: dict[str, Any]) -> None:
    """Raise a ``ValueError`` naming the first ``--set`` option that ``wrl_jax.make(env_name, ...)`` rejects
    (over the learner's environment ``defaults``)."""
    import wrl_jax

    if not env or env_name is None:
        return
    try:
        wrl_jax.make(env_name, **{**defaults, **env})
        return
    except (ValueError, TypeError) as exc:
        joint = exc
    for name, value in env.items():
        try:
            wrl_jax.make(env_name, **{**defaults, name: value})
        except (ValueError, TypeError) as exc:
            raise ValueError(f"--set: unknown field {name!r} (not a config field, and {env_name} rejects it: "
                             f"{exc}); config fields: {sorted(config_fields)}") from None
    raise ValueError(f"--set: {env_name} rejects the options {env}: {joint}")


FLEET_EXAMPLE = (
    "python -m wrl_jax.sweep --algo ppo --env Fleet-12x12-v0 --set num_robots=2 --grid block_penalty=-1,-5 "
    "--grid ent_coef=0.05,0.2 --num-seeds 4 --out runs/sweep-fleet"
)
"""The fleet example of ``--help`` and the docs (a test parses it)."""


def _env_overrides(defaults: dict[str, Any], sets: dict[str, Any], grid: dict[str, list[Any]]) -> dict[str, Any]:
    """The sweep's common environment options: the algorithm's defaults for the environment (as
    ``train_ppo.py`` applies them), then ``--set``; a default the grid varies is left out."""
    return {**{k: v for k, v in _defaults_under(defaults, sets).items() if k not in grid}, **sets}


def _defaults_under(defaults: dict[str, Any], sets: dict[str, Any]) -> dict[str, Any]:
    """The learner's environment defaults that still apply under ``--set`` (the stop's escape goes with the stop)."""
    from wrl_jax.cli.options import escape_goes

    if escape_goes(sets.get("safety_stop"), "escape_after" in sets):
        return {k: v for k, v in defaults.items() if k != "escape_after"}
    return defaults


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m wrl_jax.sweep",
        description="A grid of traced hyperparameters x seeds trained as one compiled program; writes a results "
        "table (Markdown, CSV, JSON) and a plot.",
        epilog="Examples: python -m wrl_jax.sweep --algo ppo --env Warehouse-8x8-v0 --grid learning_rate=0.003,0.01 "
        "--grid ent_coef=0.02,0.2 --grid shaping_coef=0,2 --num-seeds 4 --set total_timesteps=60000 --out runs/sweep; "
        f"{FLEET_EXAMPLE}",
    )
    parser.add_argument("--algo", required=True, help="ppo, dqn, sac or td3")
    parser.add_argument("--env", default=None, help="registered environment (default: the algorithm's)")
    parser.add_argument("--preset", default=None, help="base hyperparameter preset (default: the one the training command picks for --env)")
    parser.add_argument("--grid", action="append", default=[], metavar="FIELD=V1,V2,...",
                        help="a traced field and its values (repeat for more fields; the grid is their product): "
                        "a traced hyperparameter or a scalar of the environment's params (reward constants, "
                        "max_steps, the fleet's block_penalty)")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="a value for the whole sweep (static fields such as total_timesteps, hidden_sizes=64,64, "
                        "or any environment option: shaping_coef=1, num_robots=2, pool_size=256)")
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

    from wrl_jax.cli import machine
    from wrl_jax import agents

    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    try:
        spec = agents.get_spec(args.algo)
        preset = args.preset or spec.preset_for(args.env or spec.default_env)
        if preset not in spec.presets:
            raise ValueError(f"unknown {spec.name} preset {preset!r}; choose from {sorted(spec.presets)}")
        env_name = args.env or spec.default_env
        config_sets, env_sets = parse_sets(args.set, spec.config_cls, env_name, spec.env_defaults_for(env_name, preset))
        config = dataclasses.replace(spec.presets[preset], **config_sets)
        grid = parse_grid(args.grid, spec.config_cls, env_name)
        if args.num_seeds < 1:
            raise ValueError(f"--num-seeds must be at least 1, got {args.num_seeds}")
        if args.devices < 0 or args.env_shards < 1:
            raise ValueError("--devices must be >= 0 and --env-shards >= 1")
        machine.apply_xla_opt_level(machine.DEFAULT_XLA_OPT_LEVEL if args.xla_opt_level is None else args.xla_opt_level)
        sweep = Sweep(
            algo_name=spec.name,
            config=config,
            env_name=env_name,
            env_overrides=_env_overrides(spec.env_defaults_for(env_name, preset), env_sets, grid),
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
