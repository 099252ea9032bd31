"""Domain randomization on the continuous warehouse: does a policy trained with it hold when the test ranges widen?

Issue 34's measurement: train a learner (``--algo``: ``train_ppo.py``'s, ``train_sac.py``'s or ``train_td3.py``'s
command with its defaults for the map, over the safety stop where that is the default) on a study map twice, with
``--randomize True`` and without, then evaluate every seed's greedy policy under three conditions:

* ``nominal``: the contract's robot, no noise (``randomize=False``);
* ``1x``: the contract's randomization ranges (gains in [0.8, 1.2], actuation noise 0.05, lidar noise 0.02 m,
  dropout 0.02, start within 0.2 m, heading uniform);
* ``1.5x``: every range 1.5 times as wide: gains in [0.7, 1.3], actuation noise 0.075, lidar noise 0.03 m,
  dropout 0.03. The start jitter stays 0.2 m: at 0.3 m a robot of radius 0.3 could start inside a shelf
  (the environment refuses more than ``0.5 - robot_radius``), and the heading is uniform in both.

Every item, ``--rounds`` episodes per item (fixed draws, the same for every policy). The aim: the randomized
policy loses at most 2 points of delivery from ``1x`` to ``1.5x``. On ``Continuous-Procedural-Warehouse-v0``
(randomized by default) the episodes are the final report's held-out layouts instead (256, every item, the
report's rounds), with the pursuit controller on the same episodes under each condition.

Usage: ``python bench/continuous_randomization.py [--algo ppo] [--env Continuous-Warehouse-8x8-v0]
[--total-timesteps 1000000] [--num-seeds 4] [--devices N] [--rounds 16] [--out runs/randomization]
[--json bench/results/continuous/randomization.json]`` (``--total-timesteps 0``: the learner's default).
The two runs go to ``--out``/randomized and ``--out``/plain; a finished run there with the same settings is
evaluated again, not retrained (other settings: refused).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax import training
from wrl_jax.agents import get_spec
from wrl_jax.agents.base import config_from_dict
from wrl_jax.cli.options import EnvOptions, build, parse
from wrl_jax.envs.continuous.evaluation import evaluate_episodes
from wrl_jax.envs.continuous.procedural import NAME as PROCEDURAL_NAME
from wrl_jax.envs.continuous.procedural_evaluation import HELDOUT_LAYOUTS, evaluate_layout_sets
from wrl_jax.envs.procedural.layout_sets import heldout_set
from wrl_jax.training import checkpoint

ROOT = Path(__file__).resolve().parents[1]
"""The repository root, where the training scripts are."""

WIDER = 1.5
"""How much wider the test ranges are than the training ranges."""


def conditions(params) -> dict:
    """The three test conditions as params of the trained environment."""
    half = (params.gain_high - params.gain_low) / 2
    centre = (params.gain_high + params.gain_low) / 2
    on = jnp.asarray(True)
    return {
        "nominal": params.replace(randomize=jnp.asarray(False)),
        "1x": params.replace(randomize=on),
        f"{WIDER:g}x": params.replace(randomize=on, gain_low=centre - WIDER * half, gain_high=centre + WIDER * half,
                                      actuation_noise=WIDER * params.actuation_noise,
                                      lidar_noise=WIDER * params.lidar_noise,
                                      lidar_dropout=WIDER * params.lidar_dropout),
    }


def train(algo: str, env_name: str, out: Path, total_timesteps: int, num_seeds: int, randomize: bool,
          devices: int | None) -> float:
    """``python train_<algo>.py`` (the user's command, in a process of its own: the script chooses XLA's host
    devices before JAX starts); returns the run's wall seconds (from its summary).

    A finished run in ``out`` is reused only if it is this one: learner, environment, seeds, steps (when given) and
    every environment option the command gives today (randomization, and defaults such as the stop's escape).
    """
    argv = ["--env", env_name, "--num-seeds", str(num_seeds), "--randomize", str(randomize), "--out", str(out),
            "--no-progress", "--no-plot", "--overwrite"]
    if total_timesteps:
        argv += ["--total-timesteps", str(total_timesteps)]
    if (out / "summary.json").exists():
        meta = json.loads((out / "config.json").read_text())
        found = (meta["algo"], meta["env"], meta["env_overrides"], len(meta["seeds"]))
        wanted = (algo, env_name, parse(algo, argv).env.overrides(), num_seeds)
        if total_timesteps:
            found, wanted = (*found, meta["config"]["total_timesteps"]), (*wanted, total_timesteps)
        if found != wanted:
            raise SystemExit(f"{out} holds another run ((algo, env, env options, seeds[, steps]) = {found}, wanted "
                             f"{wanted}): choose another --out")
        return float(json.loads((out / "summary.json").read_text())["wall_seconds"])
    if devices:
        argv += ["--devices", str(devices)]
    command = [sys.executable, str(ROOT / f"train_{algo}.py"), *argv]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"training failed ({done.returncode}): {' '.join(command)}\n{done.stderr[-2000:]}")
    return float(json.loads((out / "summary.json").read_text())["wall_seconds"])


def evaluate(run_dir: Path, rounds: int) -> dict:
    """Every seed of a finished run under every condition: delivered share and collisions per episode."""
    meta = checkpoint.read_metadata(run_dir)
    spec = get_spec(meta["algo"])
    algo = build(spec, config_from_dict(spec.config_cls, meta["config"]),
                 EnvOptions(env=meta["env"], **meta.get("env_overrides", {})))
    trainer = training.Trainer(algo, meta["seeds"], training.LoopConfig(progress=False))
    runners, _ = checkpoint.load(run_dir, trainer.template())
    networks = jax.vmap(algo.network_params)(runners)
    env = algo.env  # a run with the safety stop keeps it: the stop reads each condition's gains and noise
    if meta["env"] == PROCEDURAL_NAME:
        return evaluate_heldout(algo, networks, jax.tree.map(lambda x: x[0], runners.env_params), meta["seeds"])

    @jax.jit
    def episodes(networks, params):
        def one(network):
            result = evaluate_episodes(lambda obs, state: algo.greedy_action(network, obs), env, params, rounds)
            valid = result.valid.astype(jnp.float32)
            return ((result.delivered * valid).sum() / valid.sum(),
                    (result.collisions * valid).sum() / valid.sum())
        return jax.vmap(one)(networks)

    out = {}
    for name, params in conditions(algo.env_params).items():
        delivered, collisions = jax.device_get(episodes(networks, params))
        out[name] = {"delivered_per_seed": [round(float(x), 4) for x in delivered],
                     "delivered": round(float(np.mean(delivered)), 4),
                     "collisions_per_episode": round(float(np.mean(collisions)), 3)}
    return out


def evaluate_heldout(algo, networks, params, seeds: list[int]) -> dict:
    """The procedural variant: every seed on the held-out layouts under every condition, pursuit beside."""
    heldout, _ = heldout_set(algo.env.generator, algo.env.training_layout_hashes(params), HELDOUT_LAYOUTS)
    out = {}
    for name, condition in conditions(params).items():
        row = evaluate_layout_sets(algo.greedy_action, networks, algo.env, condition, [heldout], seeds)["heldout"]
        out[name] = {"delivered_per_seed": [round(entry["success_rate"], 4) for entry in row["per_seed"]],
                     "delivered": round(row["success_rate"], 4),
                     "collisions_per_episode": round(row["collisions_per_episode"], 4),
                     "mean_steps": round(row["mean_steps"], 2), "episodes_per_seed": row["episodes_per_seed"],
                     "pursuit": row["pursuit"]}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", choices=("ppo", "sac", "td3"), default="ppo")
    parser.add_argument("--env", default="Continuous-Warehouse-8x8-v0")
    parser.add_argument("--total-timesteps", type=int, default=1_000_000, help="0: the learner's default")
    parser.add_argument("--num-seeds", type=int, default=4)
    parser.add_argument("--devices", type=int, default=None, help="passed to the training command (default: its own)")
    parser.add_argument("--rounds", type=int, default=16, help="episodes per item and condition")
    parser.add_argument("--out", type=Path, default=Path("runs/randomization"))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.rounds < 1 or args.num_seeds < 1 or args.total_timesteps < 0:
        parser.error("--rounds and --num-seeds must be positive, --total-timesteps at least 0")
    report = {"algo": args.algo, "env": args.env, "total_timesteps": args.total_timesteps, "num_seeds": args.num_seeds,
              "rounds": args.rounds, "wider": WIDER, "arms": {}}
    for randomize in (True, False):
        arm = "randomized" if randomize else "plain"
        wall = train(args.algo, args.env, args.out / arm, args.total_timesteps, args.num_seeds, randomize,
                     args.devices)
        devices = json.loads((args.out / arm / "config.json").read_text())["devices"]
        report["arms"][arm] = {"train_wall_s": round(wall, 1), "devices": devices,
                               **evaluate(args.out / arm, args.rounds)}
    steps = f"{args.total_timesteps:,} steps" if args.total_timesteps else "its default steps"
    episodes = (f"{HELDOUT_LAYOUTS} held-out layouts" if args.env == PROCEDURAL_NAME
                else f"{args.rounds} rounds per item")
    print(f"{args.env}, {args.algo.upper()} {steps} x {args.num_seeds} seeds, {episodes}")
    print("| trained | nominal | 1x | 1.5x | loss 1x -> 1.5x (points) | collisions / ep. at 1.5x |")
    print("|---|---|---|---|---|---|")
    for arm, res in report["arms"].items():
        wide = res[f"{WIDER:g}x"]
        loss = 100 * (res["1x"]["delivered"] - wide["delivered"])
        pursuit = (f" (pursuit {100 * wide['pursuit']['success_rate']:.1f} %, "
                   f"{wide['pursuit']['collisions_per_episode']:.3f})" if "pursuit" in wide else "")
        print(f"| {arm} | {100 * res['nominal']['delivered']:.1f} % | {100 * res['1x']['delivered']:.1f} % | "
              f"{100 * wide['delivered']:.1f} %{pursuit} | {loss:+.1f} | {wide['collisions_per_episode']:.3f} |")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
