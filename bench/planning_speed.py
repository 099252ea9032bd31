"""Training speed of PPO's planning policy on the procedural warehouse, before and after propagating once per leg.

Why this exists: the propagation encoder (wrl_jax/agents/propagation.py) used to propagate its values
over the map for every observation: at every rollout step, for both values of GAE, and for every row of
every minibatch (with a fixed 48 rounds). Now it propagates until the values converge, but once per leg
of an episode (a map and a target): the rollout keeps each environment's values until its leg changes,
and the update propagates once per run of consecutive rows of one leg (minibatches of whole
environments). This measures, in one process, one seed's PPO updates per second of three programs on
the same environment (the procedural preset's, with the map), compile time apart (two warm-up updates,
then ``--updates`` timed ones, ``block_until_ready``-ed):

* ``mlp``: ``--preset procedural_mlp`` (no map, no propagation), the speed to aim for;
* ``every_observation``: the propagation encoder as it was (48 rounds, every observation);
* ``once_per_leg``: the default ``procedural`` preset (converged, once per leg).

    XLA_FLAGS="--xla_backend_optimization_level=1 --xla_cpu_use_fusion_emitters=false" \\
        .venv/bin/python bench/planning_speed.py --json bench/results/procedural_ppo/planning_speed.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from wrl_jax.agents import ppo, ppo_config  # noqa: E402
from wrl_jax.cli.machine import cpu_info  # noqa: E402
from wrl_jax.core.registry import make  # noqa: E402

PROGRAMS = {
    "mlp": (ppo_config.PROCEDURAL_MLP, False),
    "every_observation": (dataclasses.replace(ppo_config.PROCEDURAL, propagation_rounds=48), True),
    "once_per_leg": (ppo_config.PROCEDURAL, True),
}


def measure(config: ppo_config.PPOConfig, observe_map: bool, updates: int, seed: int) -> dict:
    env, params = make("Procedural-Warehouse-v0", **ppo_config.PROCEDURAL_ENV_DEFAULTS, observe_map=observe_map)
    algo = ppo.PPO(config, env, params)
    update = jax.jit(algo.update)
    runner = algo.init(jax.random.key(seed))
    tic = time.perf_counter()
    for index in range(2):
        runner, metrics = update(runner, jnp.int32(index))
    jax.block_until_ready(runner)
    warm = time.perf_counter() - tic
    tic = time.perf_counter()
    for index in range(2, 2 + updates):
        runner, metrics = update(runner, jnp.int32(index))
    jax.block_until_ready(runner)
    seconds = time.perf_counter() - tic
    return {"env_steps_per_s": updates * config.steps_per_update / seconds, "seconds": seconds,
            "warm_up_s": warm, "updates": updates, "steps_per_update": config.steps_per_update,
            "episodes_last_update": float(metrics["episodes"])}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--updates", type=int, default=20, help="timed updates per program")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    results = {name: measure(config, observe_map, args.updates, args.seed)
               for name, (config, observe_map) in PROGRAMS.items()}
    base = results["every_observation"]["env_steps_per_s"]
    for name, row in results.items():
        row["vs_every_observation"] = row["env_steps_per_s"] / base
        print(f"{name:18s} {row['env_steps_per_s']:9.0f} env steps/s  ({row['vs_every_observation']:.2f}x "
              f"the old propagation; warm-up {row['warm_up_s']:.1f} s)")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"results": results, "machine": cpu_info(), "argv": sys.argv[1:]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
