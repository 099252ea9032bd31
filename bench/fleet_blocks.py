"""Why a learned fleet's robots are blocked: every ``robot_block`` of a saved run, put in a class by its cause.

Why this exists: the aim of issue 15 is fewer than one block per robot per 100 steps, and a block
penalty twice as large did not cut them (docs/fleet_training.md). Which blocks remain says what a
policy would need to avoid them. For the greedy (and the sampled) policy of every seed, on the
planners' shifts (``--episodes``, the final report's), each block of robot ``i`` is classed by the
first reason FLEET_SPEC.md step 3 gives (``wrl_jax.envs.fleet.metrics.block_causes``), in this order:

* ``swap``: some mover ``j`` proposed ``i``'s cell while ``i`` proposed ``j``'s (refused swaps);
* ``into a standing robot``: ``i`` proposed the cell of a robot that did not try to move (it waited,
  or bumped into a shelf or the edge) -- visible in ``i``'s window before it acted;
* ``lost a contested cell``: a mover with a lower index proposed the same free cell;
* ``behind a blocked robot``: ``i`` followed a robot that was itself blocked (a later round).

Run from the repository root::

    .venv/bin/python bench/fleet_blocks.py --run runs/ppo-Fleet-12x12-v0-... --json OUT
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", required=True, type=Path, help="a fleet run directory (checkpoint.msgpack)")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)

    import jax
    import jax.numpy as jnp
    import numpy as np

    from wrl_jax import training
    from wrl_jax.agents import get_spec
    from wrl_jax.agents.base import config_from_dict
    from wrl_jax.cli.options import EnvOptions, build
    from wrl_jax.envs.fleet.conflicts import propose
    from wrl_jax.envs.fleet.evaluation import EVAL_SEED
    from wrl_jax.envs.fleet.metrics import BLOCK_CAUSES as CLASSES
    from wrl_jax.envs.fleet.metrics import block_causes
    from wrl_jax.training import checkpoint

    meta = checkpoint.read_metadata(args.run)
    spec = get_spec(meta["algo"])
    algo = build(spec, config_from_dict(spec.config_cls, meta["config"]),
                 EnvOptions(env=meta["env"], **meta.get("env_overrides", {})))
    env, params = algo.env, algo.env_params
    if getattr(env, "family", None) != "fleet":
        print(f"error: {args.run} is a {env.family!r} run, not a fleet run", file=sys.stderr)
        return 2
    trainer = training.Trainer(algo, meta["seeds"], training.LoopConfig(progress=False))
    runners, _ = checkpoint.load(args.run, trainer.template())
    network_params = jax.vmap(algo.network_params)(runners)
    horizon, robots = int(params.max_steps), env.num_robots

    def causes(pos, action, blocked):
        return block_causes(pos, propose(pos, action, params.shelves)[0], blocked)

    def shift(net, key, sampled):
        reset_key, scan_key = jax.random.split(key)
        obs, state = env.reset_env(reset_key, params)

        def one(carry, keys):
            obs, state, counts = carry
            step_key, policy_key = keys
            action = jnp.where(sampled, algo.sample_action(net, obs, policy_key), algo.greedy_action(net, obs))
            next_obs, next_state, _, _, _, flags = env.transition(step_key, state, action, params)
            counts = counts + causes(state.pos, action, flags["robot_block"]).astype(jnp.int32)
            return (next_obs, next_state, counts), None

        keys = (jax.random.split(scan_key, horizon), jax.random.split(jax.random.fold_in(key, 1), horizon))
        counts = jax.lax.scan(one, (obs, state, jnp.zeros((robots, len(CLASSES)), jnp.int32)), keys)[0][2]
        return counts.sum(axis=0)

    episode_keys = jax.random.split(jax.random.key(EVAL_SEED), args.episodes)
    run_all = jax.jit(jax.vmap(lambda net, sampled: jax.vmap(lambda k: shift(net, k, sampled))(episode_keys),
                               in_axes=(0, None)))
    per_100 = 100.0 / (args.episodes * robots * horizon)
    report = {"run": str(args.run), "env": meta["env"], "num_robots": robots, "episodes": args.episodes,
              "horizon": horizon, "unit": "blocks per robot per 100 steps", "classes": list(CLASSES)}
    for policy in ("greedy", "sampled"):
        counts = np.asarray(run_all(network_params, policy == "sampled")).sum(axis=1) * per_100  # (seeds, 4)
        report[policy] = {"per_seed": {str(seed): dict(zip(CLASSES, map(float, row)))
                                       for seed, row in zip(meta["seeds"], counts)},
                          "mean": dict(zip(CLASSES, map(float, counts.mean(axis=0)))),
                          "total": float(counts.sum(axis=1).mean())}
    print(f"| policy | {' | '.join(CLASSES)} | total |")
    print("|---|" + "---:|" * (len(CLASSES) + 1))
    for policy in ("greedy", "sampled"):
        row = report[policy]
        cells = " | ".join(f"{row['mean'][name]:.2f}" for name in CLASSES)
        print(f"| {policy} | {cells} | {row['total']:.2f} |")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
