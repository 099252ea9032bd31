"""Training-command options: flags from dataclasses, presets, resume defaults, validation, config (de)serialization.

A training command's flags come from three dataclasses, flattened by tyro into
one namespace: :class:`EnvOptions` (``--env`` and the environment's overrides),
:class:`RunOptions` (seeds, output, cadence, devices) and the algorithm's
config dataclass (every hyperparameter; ``--preset NAME`` picks the defaults
the other flags override). Everything is validated before anything compiles:
a bad value raises ``ValueError`` naming it.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import sys
from pathlib import Path
from typing import Any

from wrl_jax.agents import get_spec
from wrl_jax.agents.base import AlgoSpec, config_from_dict
from wrl_jax.cli.machine import DEFAULT_XLA_OPT_LEVEL

@dataclasses.dataclass
class EnvOptions:
    """The environment and its overrides (``None`` keeps the registered value)."""

    env: str = "Warehouse-12x12-v0"
    """registered environment name"""
    max_steps: int | None = None
    """episode length before truncation"""
    step_penalty: float | None = None
    obstacle_penalty: float | None = None
    wall_penalty: float | None = None
    shaping_coef: float | None = None
    pickup_reward: float | None = None
    delivery_reward: float | None = None
    observe_carrying: bool = True
    """include the carrying flag in the observation (False: the study's failure mode)"""
    collision_bug: bool = False
    """reproduce the study's collision bug"""
    num_robots: int | None = None
    """fleet environments: robots K (default 4 on Fleet-12x12-v0)"""
    block_penalty: float | None = None
    """fleet environments: reward for a blocked move"""
    observe_priority: bool | None = None
    """fleet environments: a window channel of the robots with a lower index (they win a contested cell)"""
    observe_headings: bool | None = None
    """fleet environments: a window channel of the cells the other robots would enter by repeating their last action"""
    view_radius: int | None = None
    """fleet and procedural environments: radius V of each robot's egocentric window"""
    shaping: str | None = None
    """distance of the shaping term: bfs or manhattan (fleet, procedural), manhattan or geodesic (continuous)"""
    pool_size: int | None = None
    """procedural environments: layouts in the pool episodes reset from"""
    pool_refresh: int | None = None
    """procedural environments: pool slots renewed with fresh layouts before every update (0: never)"""
    observe_last_action: bool | None = None
    """procedural and fleet environments: the previous action, one-hot, in the observation (a one-step memory;
    the fleet adds whether it was blocked)"""
    observe_map: bool | None = None
    """procedural environments: the whole padded map (3 channels) in the observation, after the window"""
    observe_visited: bool | None = None
    """procedural environments: a window channel of the cells visited since the current target was set"""
    visit_levels: int | None = None
    """procedural environments: the visited channel counts visits up to this many (1: visited or not)"""
    observe_target: bool | None = None
    """continuous environments: the target seen from the robot (offset, distance, bearing) after the contract's values"""
    observe_route: bool | None = None
    """continuous environments on fixed layouts: the way to the target around the shelves (its direction in the
    robot's frame, its length); needs --shaping geodesic"""
    observe_obstacles: bool | None = None
    """continuous environments: the ranges to the moving obstacles alone and whether the last step was blocked (by
    an obstacle, by a shelf or wall), after the target's values and before the route's"""
    safety_stop: bool | None = None
    """continuous environments: drop a forward command the robot's lidar says would bring it within the margin of a
    shelf, wall or moving obstacle (a reflex under the policy, with or without --randomize); with
    --observe-obstacles the view gains one value, the steps the robot has been held"""
    safety_margin: float | None = None
    """continuous environments with --safety-stop True: the margin in metres beyond the robot's radius (0.05)"""
    escape_after: int | None = None
    """continuous environments with --safety-stop True: a full turn once the stop has held the robot this many steps
    in a row (0: no escape; 10 by default on the procedural variant)"""
    collision_penalty: float | None = None
    """continuous environments: added to the reward of a step that touches a shelf, wall or obstacle (the contract's
    -10; the run's evaluation keeps the value, so its returns are not the contract's)"""
    randomize: bool | None = None
    """continuous environments: domain randomization (gains, start pose per episode; actuation, lidar noise per step)"""
    reward_type: str | None = None
    """rware environments: individual (default), global or two_stage"""
    sensor_range: int | None = None
    """rware environments: cells seen in each direction (the flattened observation grows with it)"""
    max_inactivity_steps: int | None = None
    """rware environments: end the episode after this many steps without a delivery (default: never)"""
    tie_order: str | None = None
    """rware environments: set (unpatched rware's order, default) or insertion (networkx's insertion order)"""
    observe_rays: bool | None = None
    """procedural environments: the free runs from the robot up, down, left and right (a range sensor)"""

    def overrides(self) -> dict[str, Any]:
        """Keyword overrides for ``wrl_jax.make``: only what differs from the registered environment."""
        out = {
            f.name: getattr(self, f.name)
            for f in dataclasses.fields(self)
            if f.name not in ("env", "observe_carrying", "collision_bug") and getattr(self, f.name) is not None
        }
        if not self.observe_carrying:
            out["observe_carrying"] = False
        if self.collision_bug:
            out["collision_bug"] = True
        return out


@dataclasses.dataclass
class RunOptions:
    """Seeds, output and how the host drives training."""

    preset: str = "default"
    """hyperparameter preset the other flags override (e.g. default, paper)"""
    num_seeds: int = 4
    """independent seeds trained at once (vmapped)"""
    seed: int = 0
    """first seed; the run trains seeds seed .. seed + num_seeds - 1"""
    out: Path | None = None
    """output directory (default runs/<algo>-<env>-<time>)"""
    resume: bool = False
    """continue the checkpoint in --out (its settings are reused)"""
    overwrite: bool = False
    """start over in an --out that already holds a checkpoint"""
    stop_after: int | None = None
    """stop (with a checkpoint) after this many updates; --resume continues"""
    chunk_updates: int | None = None
    """updates per compiled call (progress/checkpoint granularity; results do not depend on it)"""
    eval_every: int | None = None
    """greedy evaluation on every item every this many updates and after the last (0: only the final one)"""
    log_every: int | None = None
    """updates aggregated per metrics row"""
    checkpoint_every: int = 1
    """chunks between checkpoints"""
    checkpoint_seconds: float = 120.0
    """at least this many seconds between two checkpoints before the last (0: every --checkpoint-every chunks)"""
    progress: bool = True
    """show a progress bar"""
    plot: bool = True
    """write learning_curve.png"""
    xla_opt_level: int = DEFAULT_XLA_OPT_LEVEL
    """XLA CPU backend optimization level (-1: XLA's default)"""
    devices: int = 1
    """shard the seeds over this many devices (0: all, every host's; 1: no sharding); docs/scale.md"""
    env_shards: int = 1
    """of those devices, how many split each seed's environments"""
    distributed: bool = False
    """multi-host: call jax.distributed.initialize first (WRL_COORDINATOR, WRL_NUM_PROCESSES, WRL_PROCESS_ID)"""

    def seeds(self) -> list[int]:
        return list(range(self.seed, self.seed + self.num_seeds))


# --------------------------------------------------------------------- parse
@dataclasses.dataclass
class Command:
    """A parsed and validated training command."""

    spec: AlgoSpec
    env: EnvOptions
    run: RunOptions
    config: Any

    @property
    def out_dir(self) -> Path:
        assert self.run.out is not None
        return self.run.out


def parse(algo: str, argv: list[str] | None = None) -> Command:
    """Parse and validate a training command line (raises ``ValueError``; ``--help`` exits)."""
    import tyro

    from wrl_jax.training import checkpoint

    spec = get_spec(algo)
    argv = list(sys.argv[1:] if argv is None else argv)
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--preset", default=None)
    pre.add_argument("--env", default=spec.default_env)
    pre.add_argument("--out", default=None)
    pre.add_argument("--resume", action="store_true")
    known, _ = pre.parse_known_args(argv)

    if known.preset is None:
        known.preset = spec.preset_for(known.env)
    env_defaults = EnvOptions(env=known.env, **spec.env_defaults_for(known.env, known.preset))
    run_defaults = RunOptions(preset=known.preset, num_seeds=spec.default_num_seeds)
    if known.resume:
        if known.out is None:
            raise ValueError("--resume needs --out DIR, the directory of the run to continue")
        saved = checkpoint.read_metadata(known.out)
        if saved.get("algo") != spec.name:
            raise ValueError(f"{known.out} holds a {saved.get('algo')!r} run, not {spec.name!r}")
        config_defaults = config_from_dict(spec.config_cls, saved["config"])
        env_defaults = EnvOptions(env=saved["env"], **saved.get("env_overrides", {}))
        seeds = saved["seeds"]
        run_defaults = dataclasses.replace(
            run_defaults, preset=saved.get("preset", spec.default_preset), num_seeds=len(seeds), seed=seeds[0]
        )
        if "log_every" in saved:
            run_defaults = dataclasses.replace(
                run_defaults, log_every=saved["log_every"], eval_every=saved["eval_every"]
            )
    else:
        if known.preset not in spec.presets:
            raise ValueError(f"unknown {spec.name} preset {known.preset!r}; choose from {sorted(spec.presets)}")
        config_defaults = spec.presets[known.preset]
        run_defaults = dataclasses.replace(run_defaults, preset=known.preset)

    args_cls = dataclasses.make_dataclass(
        f"{spec.name.upper()}Args",
        [("env", EnvOptions), ("run", RunOptions), ("algo", spec.config_cls)],
    )
    defaults = args_cls(env=env_defaults, run=run_defaults, algo=config_defaults)
    parsed = tyro.cli(
        args_cls,
        default=defaults,
        args=argv,
        prog=f"train_{spec.name}.py",
        description=f"Train {spec.name.upper()} on a warehouse environment (wrl_jax). "
        f"Presets: {', '.join(sorted(spec.presets))}.",
        config=(tyro.conf.OmitArgPrefixes,),
    )
    env = parsed.env
    if escape_goes(env.safety_stop, any(arg.split("=")[0] == "--escape-after" for arg in argv)):
        env = dataclasses.replace(env, escape_after=None)
    command = Command(spec=spec, env=env, run=parsed.run, config=parsed.algo)
    validate(command)
    return command


FAMILY_OPTIONS = {
    "num_robots": ("fleet",),
    "block_penalty": ("fleet",),
    "observe_priority": ("fleet",),
    "observe_headings": ("fleet",),
    "view_radius": ("fleet", "procedural"),
    "shaping": ("fleet", "procedural", "continuous"),
    "observe_target": ("continuous",),
    "observe_route": ("continuous",),
    "observe_obstacles": ("continuous",),
    "safety_stop": ("continuous",),
    "safety_margin": ("continuous",),
    "escape_after": ("continuous",),
    "randomize": ("continuous",),
    "collision_penalty": ("continuous",),
    "reward_type": ("rware",),
    "sensor_range": ("rware",),
    "max_inactivity_steps": ("rware",),
    "tie_order": ("rware",),
    "pool_size": ("procedural",),
    "pool_refresh": ("procedural",),
    "observe_last_action": ("procedural", "fleet"),
    "observe_map": ("procedural",),
    "observe_visited": ("procedural",),
    "visit_levels": ("procedural",),
    "observe_rays": ("procedural",),
}
"""Environment flags that only some families take (refused on the others before anything is built)."""

ID_OPTIONS = {"pool_size": ("Continuous-Procedural-Warehouse-v0",)}
"""Flags that single ids of another family take as well (the continuous warehouse's pool of generated layouts)."""


def escape_goes(safety_stop: Any, escape_given: bool) -> bool:
    """Whether a default ``escape_after`` is dropped: the stop's escape goes with the stop when the user turns the
    stop off without asking for an escape (which the environment then refuses by name)."""
    return safety_stop is False and not escape_given


def validate(command: Command) -> None:
    """Raise ``ValueError`` for anything wrong with a command, before anything is compiled."""
    from wrl_jax.core import registry

    run, spec = command.run, command.spec
    if run.preset not in spec.presets and not run.resume:  # resumed, it is the checkpoint's label (maybe retired)
        raise ValueError(f"unknown {spec.name} preset {run.preset!r}; choose from {sorted(spec.presets)}")
    family = registry.entry(command.env.env).family  # unknown environment -> ValueError
    misplaced = [name for name, families in FAMILY_OPTIONS.items()
                 if getattr(command.env, name) is not None and family not in families
                 and command.env.env not in ID_OPTIONS.get(name, ())]
    if misplaced:
        flags = ", ".join("--" + name.replace("_", "-") for name in misplaced)
        kinds = " or ".join(sorted({kind for name in misplaced for kind in FAMILY_OPTIONS[name]}))
        raise ValueError(f"{flags}: {kinds} options, but --env {command.env.env} is a {family!r} environment")
    if run.num_seeds < 1:
        raise ValueError(f"--num-seeds must be at least 1, got {run.num_seeds}")
    if run.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {run.seed}")
    if run.stop_after is not None and run.stop_after < 1:
        raise ValueError(f"--stop-after must be a positive number of updates, got {run.stop_after}")
    if run.resume and run.overwrite:
        raise ValueError("--resume and --overwrite contradict each other")
    if run.devices < 0 or run.env_shards < 1:
        raise ValueError(f"--devices must be >= 0 (0: all) and --env-shards >= 1, got {run.devices}, {run.env_shards}")
    command.config.validate()
    if run.out is None:
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        run.out = Path("runs") / f"{spec.name}-{command.env.env}-{stamp}"
    run.out = Path(run.out)


def build(spec: AlgoSpec, config: Any, env_options: EnvOptions):
    """The algorithm object for a config and environment options."""
    import wrl_jax

    env, env_params = wrl_jax.make(env_options.env, **env_options.overrides())
    return spec.algorithm_cls(config, env, env_params)


