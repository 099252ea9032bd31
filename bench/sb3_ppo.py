"""Our PPO against Stable-Baselines3's PPO, same configuration, measured in the same run.

    python bench/sb3_ppo.py --preset default --seeds 4
    python bench/sb3_ppo.py --preset paper --seeds 2

For a preset of ``wrl_jax.agents.ppo`` this trains

- ours: ``train_ppo.py``'s code path (``wrl_jax.cli``), all seeds in one compiled
  program, on the JAX environment;
- SB3: ``stable_baselines3.PPO`` on the NumPy reference environment
  (``wrl_jax.envs.warehouse.reference``, bit-identical transitions), one seed after another,
  8 or 64 Python environments in a ``DummyVecEnv``, configured to match:
  ``n_steps``, ``batch_size`` (= our minibatch), ``n_epochs``, learning rate
  (linear schedule if annealed), ``gamma``, ``gae_lambda``, ``clip_range``,
  ``ent_coef`` (annealed by a callback if ours is), ``vf_coef``,
  ``max_grad_norm``, separate actor and critic MLPs of the same widths and
  activation, orthogonal init, advantage normalization, Adam eps 1e-5. Our
  one-hot observation encoding and reward scale are applied with Gymnasium
  wrappers, so SB3 learns from the same inputs and rewards. SB3 also
  bootstraps time-limit truncations (``TimeLimit.truncated``), as we do.

Both get exactly the same number of environment steps per seed, and both are
evaluated the same way: the greedy (deterministic) policy on every item index,
steps against the BFS optimum. Wall times include everything each side needs
from a cold start (ours: compile; SB3: its setup). The JSON result goes to
``bench/results/sb3_ppo_<preset>.json`` with a Markdown table beside it.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def _git_commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "wrl_jax", "bench"], cwd=ROOT, capture_output=True,
                               text=True).stdout.strip()
        return out.stdout.strip() + (" (uncommitted changes)" if dirty else "")
    except OSError:
        return "unknown"


# ------------------------------------------------------------------------ ours
def run_ours(preset: str, env_name: str, seeds: int, total_timesteps: int | None) -> dict:
    from wrl_jax.cli import options as cli_options
    from wrl_jax.cli import train as cli_train

    out = Path(tempfile.mkdtemp(prefix=f"bench-ppo-{preset}-"))
    argv = ["--preset", preset, "--env", env_name, "--num-seeds", str(seeds), "--out", str(out), "--no-progress"]
    if total_timesteps:
        argv += ["--total-timesteps", str(total_timesteps)]
    t0 = time.perf_counter()
    command = cli_options.parse("ppo", argv)
    summary = cli_train.train(command)
    wall = time.perf_counter() - t0
    ev = summary["eval"]
    return {
        "wall_seconds": wall,
        "compile_seconds": summary["compile_seconds"] + summary["init_seconds"],
        "train_seconds": summary["train_seconds"],
        "env_steps_per_seed": summary["env_steps_per_seed"],
        "seeds": summary["seeds"],
        "success_rate": ev["success_rate"],
        "optimal_rate": ev["optimal_rate"],
        "mean_steps": ev["mean_steps"],
        "optimal_mean_steps": ev["optimal_mean_steps"],
        "collision_free_rate": ev["collision_free_rate"],
        "per_seed": ev["per_seed"],
        "first_optimal_step": summary["convergence"]["first_optimal_step"],
        "achieved_gflops": summary["achieved_gflops"],
        "out": str(out),
    }


# ------------------------------------------------------------------------- SB3
def _onehot_wrapper(gym, env, size: int):
    from gymnasium import spaces

    class OneHot(gym.ObservationWrapper):
        """The one-hot coordinate encoding of ``wrl_jax.agents.encoding.encode_observation``, in NumPy."""

        def __init__(self, inner):
            super().__init__(inner)
            width = 6 * (size + 1) + (inner.observation_space.shape[0] - 6)
            self.observation_space = spaces.Box(0.0, 1.0, (width,), np.float32)

        def observation(self, obs):
            out = np.zeros(self.observation_space.shape, np.float32)
            cells = np.rint(obs[:6] * (size - 1)).astype(np.int64) + 1
            out[np.arange(6) * (size + 1) + cells] = 1.0
            out[6 * (size + 1) :] = obs[6:]
            return out

    return OneHot(env)


def run_sb3(config, env_name: str, seed: int, total_steps: int, torch_threads: int = 1) -> dict:
    import gymnasium as gym
    import torch

    torch.set_num_threads(torch_threads)
    from stable_baselines3 import PPO as SB3PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv

    from wrl_jax.envs.warehouse.layout import optimal_route_lengths
    from wrl_jax.envs.warehouse.reference import make_reference

    def make_one():
        env = make_reference(env_name)
        size = env.size
        if config.obs_encoding == "onehot":
            env = _onehot_wrapper(gym, env, size)
        if config.reward_scale != 1.0:
            env = gym.wrappers.TransformReward(env, lambda r: np.float32(r * config.reward_scale))
        return env

    t0 = time.perf_counter()
    vec = DummyVecEnv([make_one for _ in range(config.num_envs)])
    lr = config.learning_rate
    schedule = (lambda remaining: lr * remaining) if config.anneal_lr else lr
    activation = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}[config.activation]
    model = SB3PPO(
        "MlpPolicy",
        vec,
        learning_rate=schedule,
        n_steps=config.num_steps,
        batch_size=config.minibatch_size,
        n_epochs=config.update_epochs,
        gamma=config.gamma,
        gae_lambda=config.gae_lambda,
        clip_range=config.clip_eps,
        normalize_advantage=config.normalize_advantages,
        ent_coef=config.ent_coef,
        vf_coef=config.vf_coef,
        max_grad_norm=config.max_grad_norm,
        policy_kwargs={
            "net_arch": {"pi": list(config.hidden_sizes), "vf": list(config.hidden_sizes)},
            "activation_fn": activation,
        },
        seed=seed,
        device="cpu",
        verbose=0,
    )

    class AnnealEntropy(BaseCallback):
        def _on_rollout_end(self) -> None:
            self.model.ent_coef = config.ent_coef * self.model._current_progress_remaining

        def _on_step(self) -> bool:
            return True

    callback = AnnealEntropy() if config.anneal_ent else None
    setup = time.perf_counter() - t0
    t1 = time.perf_counter()
    model.learn(total_timesteps=total_steps, callback=callback)
    train = time.perf_counter() - t1

    # Greedy evaluation on every item, as wrl_jax.envs.warehouse.evaluation does it.
    env = make_one()
    base = env.unwrapped
    optimum = optimal_route_lengths(base.layout) if hasattr(base, "layout") else None
    rows = []
    for item in range(len(base.items)):
        obs, _ = env.reset(options={"item_index": item})
        steps, ret, collisions, done, delivered = 0, 0.0, 0, False, False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, terminated, truncated, info = env.step(int(action))
            steps += 1
            ret += float(reward) / config.reward_scale
            collisions += int(info["collision"])
            done, delivered = terminated or truncated, terminated
        rows.append({"item": item, "delivered": delivered, "steps": steps, "return": ret, "collisions": collisions})
    if optimum is None:
        optimum = [None] * len(rows)
    delivered = [r for r in rows if r["delivered"]]
    return {
        "seed": seed,
        "setup_seconds": setup,
        "train_seconds": train,
        "wall_seconds": setup + train,
        "env_steps": int(model.num_timesteps),
        "success_rate": len(delivered) / len(rows),
        "optimal_rate": sum(1 for r, o in zip(rows, optimum) if r["delivered"] and r["steps"] == o) / len(rows),
        "mean_steps": float(np.mean([r["steps"] for r in delivered])) if delivered else None,
        "collision_free_rate": sum(1 for r in rows if r["collisions"] == 0) / len(rows),
        "rows": rows,
        "torch_threads": torch.get_num_threads(),
    }


# ------------------------------------------------------------------------ main
def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="default", choices=["default", "paper"])
    parser.add_argument("--env", default="Warehouse-12x12-v0")
    parser.add_argument("--seeds", type=int, default=2, help="seeds for each side")
    parser.add_argument("--total-timesteps", type=int, default=None, help="override the preset's budget")
    parser.add_argument("--out", default=None)
    parser.add_argument("--torch-threads", type=int, default=1,
                        help="torch intra-op threads for SB3 (1 is fastest for these small networks on 2 cores)")
    args = parser.parse_args()

    from wrl_jax.agents.ppo_config import PRESETS

    config = PRESETS[args.preset]
    if args.total_timesteps:
        config = dataclasses.replace(config, total_timesteps=args.total_timesteps)
    load_before = list(os.getloadavg())
    ours = run_ours(args.preset, args.env, args.seeds, args.total_timesteps)
    steps = ours["env_steps_per_seed"]
    print(f"ours: {args.seeds} seeds in {ours['wall_seconds']:.1f} s (compile {ours['compile_seconds']:.1f} s), "
          f"success {ours['success_rate']:.2f}, optimal {ours['optimal_rate']:.2f}", flush=True)
    sb3 = []
    for seed in range(args.seeds):
        result = run_sb3(config, args.env, seed, steps, args.torch_threads)
        sb3.append(result)
        print(f"sb3 seed {seed}: {result['wall_seconds']:.1f} s, success {result['success_rate']:.2f}, "
              f"optimal {result['optimal_rate']:.2f}, mean steps {result['mean_steps']}", flush=True)
    load_after = list(os.getloadavg())
    sb3_wall = sum(r["wall_seconds"] for r in sb3)
    import jax
    import stable_baselines3
    import torch

    result = {
        "command": "python bench/sb3_ppo.py " + " ".join(sys.argv[1:]),
        "preset": args.preset,
        "env": args.env,
        "config": dataclasses.asdict(config),
        "seeds_each_side": args.seeds,
        "env_steps_per_seed": steps,
        "ours": ours,
        "sb3": sb3,
        "ratio": {
            "wall_sb3_over_ours": sb3_wall / ours["wall_seconds"],
            "train_sb3_over_ours": sum(r["train_seconds"] for r in sb3) / ours["train_seconds"],
            "definition": "SB3 total wall time for all its seeds (one after another) over ours for the same seeds "
            "(in one program, compile included); train_ excludes our compile and SB3's setup",
        },
        "quality": {
            "ours_success_rate": ours["success_rate"],
            "ours_optimal_rate": ours["optimal_rate"],
            "sb3_success_rate": float(np.mean([r["success_rate"] for r in sb3])),
            "sb3_optimal_rate": float(np.mean([r["optimal_rate"] for r in sb3])),
        },
        "machine": {
            "cpu_count": os.cpu_count(),
            "platform": platform.platform(),
            "load_average_before": load_before,
            "load_average_after": load_after,
            "versions": {"jax": jax.__version__, "torch": torch.__version__, "sb3": stable_baselines3.__version__},
            "git_commit": _git_commit(),
        },
    }
    out = Path(args.out) if args.out else ROOT / "bench" / "results" / f"sb3_ppo_{args.preset}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2))
    md = [
        f"Command: `{result['command']}` (load average before/after {load_before[0]:.1f} / {load_after[0]:.1f}, "
        f"{os.cpu_count()} CPUs)",
        "",
        f"PPO `{args.preset}` preset on {args.env}, {steps:,} env steps per seed, {args.seeds} seeds each side.",
        "",
        "| | wall s (all seeds) | of which compile/setup s | items delivered | items at BFS optimum | mean steps |",
        "|---|---:|---:|---:|---:|---:|",
        f"| wrl_jax (one program, JAX env) | {ours['wall_seconds']:.1f} | {ours['compile_seconds']:.1f} | "
        f"{100 * ours['success_rate']:.0f}% | {100 * ours['optimal_rate']:.0f}% | {ours['mean_steps']} |",
        f"| SB3 + NumPy reference (seeds in turn) | {sb3_wall:.1f} | "
        f"{sum(r['setup_seconds'] for r in sb3):.1f} | {100 * result['quality']['sb3_success_rate']:.0f}% | "
        f"{100 * result['quality']['sb3_optimal_rate']:.0f}% | "
        f"{np.mean([r['mean_steps'] for r in sb3 if r['mean_steps'] is not None]) if any(r['mean_steps'] for r in sb3) else 'n/a'} |",
        "",
        f"SB3 / wrl_jax wall time: **{result['ratio']['wall_sb3_over_ours']:.1f}x** "
        f"(training only: {result['ratio']['train_sb3_over_ours']:.1f}x).",
    ]
    out.with_suffix(".md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
