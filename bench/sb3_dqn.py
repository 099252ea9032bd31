"""Our DQN against Stable-Baselines3's DQN, same configuration, measured in the same run.

Both train a preset of ``wrl_jax.agents.dqn`` (``default`` or ``paper``) for the
same number of environment steps per seed:

- **ours**: the whole run compiled (``wrl_jax.training``), all seeds vmapped
  in one program, on the JAX environment; compile time reported apart.
- **SB3**: ``stable_baselines3.DQN`` (PyTorch, CPU) on the NumPy reference
  environment (``wrl_jax.envs.warehouse.reference``, proven equal to the JAX one transition by
  transition), ``DummyVecEnv`` of ``num_envs`` copies, one seed after another.

The configuration maps one to one: network, learning rate (and its linear
annealing, as an SB3 schedule), buffer, batch, ``train_freq``,
``gradient_steps``, ``learning_starts``, ``target_update_interval``, ``tau``,
gamma, the epsilon schedule, Huber loss, gradient clip; SB3 counts
``train_freq`` in vector steps and the target interval in transitions, as we
do. PyTorch runs with one intra-op thread by default (``--torch-threads``):
on this shared 2-core machine its default of 2 threads made one gradient step
of the default preset 264 ms instead of 7 ms (oversubscription), which would
flatter us. Differences that remain: SB3 draws one exploration coin per vector step
for all environments (we draw one per environment), and PyTorch's default
initialization matches ours (uniform +-1/sqrt(fan_in)) only in distribution.

Quality: greedy evaluation on every item after training (and every
``--eval-every-steps`` during it, for the first step at which a seed delivers
every item at the BFS optimum). SB3's evaluation time is excluded from its
training wall time; ours runs inside the compiled loop and is included (it is
small). FLOPs per update are the configuration's (the same for both), so the
achieved GFLOP/s of each side is comparable with the CPU's measured peak.

    python bench/sb3_dqn.py --preset default --seeds 4
    python bench/sb3_dqn.py --preset paper --seeds 1 --total-timesteps 200000

writes ``bench/results/sb3_dqn_<preset>[_<steps>].json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

ENV_NAME = "Warehouse-8x8-v0"


def load_average() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


# ------------------------------------------------------------------- ours
def run_ours(config, seeds: list[int], eval_every_updates: int) -> dict[str, Any]:
    import jax

    from wrl_jax import training
    from wrl_jax.envs.warehouse import evaluation
    from wrl_jax.agents.dqn import make_algorithm

    algo = make_algorithm(config)
    trainer = training.Trainer(
        algo, seeds, training.LoopConfig(eval_every=eval_every_updates, progress=False, chunk_updates=None)
    )
    t0 = time.perf_counter()
    runners = trainer.init()
    jax.block_until_ready(runners)
    init_seconds = time.perf_counter() - t0
    result = training.run(trainer, None, runners=runners)
    episodes = training.final_evaluation(trainer, result)
    summary = evaluation.summarize(episodes, seeds)
    first = result.convergence.first_solved_update(len(seeds))
    steps = trainer.steps_per_update
    updates = result.updates_done * len(seeds)
    return {
        "init_seconds": init_seconds,
        "compile_seconds": result.compile_seconds,
        "train_seconds": result.train_seconds,
        "seconds_per_seed": result.train_seconds / len(seeds),
        "env_steps_per_second": result.updates_done * steps * len(seeds) / result.train_seconds,
        "achieved_gflops": algo.flops_per_update() * updates / result.train_seconds / 1e9,
        "first_optimal_step": [None if u is None else u * steps for u in first],
        "eval": {k: v for k, v in summary.items() if k not in ("rows",)},
    }


# -------------------------------------------------------------------- SB3
def greedy_eval_sb3(model, env_name: str) -> dict[str, Any]:
    """Deterministic episodes of an SB3 policy on every item of the reference environment."""
    import torch

    from wrl_jax.envs.warehouse.layout import optimal_route_lengths
    from wrl_jax.envs.warehouse.reference import make_reference
    from wrl_jax.envs.warehouse.registration import spec

    env = make_reference(env_name)
    optimum = optimal_route_lengths(spec(env_name).layout)
    rows = []
    for item in range(len(optimum)):
        obs, _ = env.reset(options={"item_index": item})
        steps, collisions, ret, delivered = 0, 0, 0.0, False
        while True:
            with torch.no_grad():
                q = model.q_net(torch.as_tensor(obs[None], dtype=torch.float32))
            obs, reward, terminated, truncated, info = env.step(int(q.argmax(dim=1)[0]))
            steps += 1
            ret += float(reward)
            collisions += int(info.get("collision", False))
            if terminated or truncated:
                delivered = bool(terminated)
                break
        rows.append({"item": item, "delivered": delivered, "steps": steps, "optimal_steps": int(optimum[item]),
                     "collisions": collisions, "return": ret})
    delivered = [r for r in rows if r["delivered"]]
    return {
        "success_rate": len(delivered) / len(rows),
        "mean_steps": float(np.mean([r["steps"] for r in delivered])) if delivered else None,
        "optimal_mean_steps": float(np.mean(optimum)),
        "optimal_rate": float(np.mean([r["delivered"] and r["steps"] == r["optimal_steps"] for r in rows])),
        "collision_free_rate": float(np.mean([r["collisions"] == 0 for r in rows])),
        "mean_return": float(np.mean([r["return"] for r in rows])),
        "rows": rows,
    }


def sb3_kwargs(config) -> dict[str, Any]:
    """SB3 ``DQN`` arguments for a :class:`DQNConfig`; raises for what SB3 cannot express."""
    import torch

    if config.double_dqn:
        raise ValueError("SB3's DQN has no Double DQN option")
    if config.loss != "huber" or config.huber_delta != 1.0:
        raise ValueError("SB3's DQN uses smooth L1 (Huber, delta 1) only")
    if config.reward_scale != 1.0:
        raise ValueError("reward_scale != 1 has no SB3 equivalent here")
    lr = config.learning_rate
    learning_rate = (lambda progress_remaining: lr * progress_remaining) if config.anneal_lr else lr
    return dict(
        learning_rate=learning_rate,
        buffer_size=config.buffer_size,
        learning_starts=config.learning_starts,
        batch_size=config.batch_size,
        tau=config.tau,
        gamma=config.gamma,
        train_freq=(config.train_freq, "step"),
        gradient_steps=config.gradient_steps,
        target_update_interval=config.target_update_interval,
        exploration_fraction=config.exploration_fraction,
        exploration_initial_eps=config.exploration_initial_eps,
        exploration_final_eps=config.exploration_final_eps,
        max_grad_norm=config.max_grad_norm,
        policy_kwargs=dict(
            net_arch=list(config.hidden_sizes),
            activation_fn={"relu": torch.nn.ReLU, "tanh": torch.nn.Tanh}[config.activation],
            optimizer_kwargs=dict(eps=config.adam_eps),
        ),
        device="cpu",
    )


def run_sb3(config, seeds: list[int], eval_every_steps: int) -> dict[str, Any]:
    from stable_baselines3 import DQN
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv

    from wrl_jax.envs.warehouse.reference import make_reference

    class Probe(BaseCallback):
        """Greedy evaluation every ``eval_every_steps`` transitions; its time is excluded from training."""

        def __init__(self):
            super().__init__()
            self.eval_seconds = 0.0
            self.first_optimal = None
            self.next_eval = eval_every_steps

        def _on_step(self) -> bool:
            if eval_every_steps and self.num_timesteps >= self.next_eval:
                self.next_eval += eval_every_steps
                t0 = time.perf_counter()
                result = greedy_eval_sb3(self.model, ENV_NAME)
                if self.first_optimal is None and result["optimal_rate"] == 1.0:
                    self.first_optimal = self.num_timesteps
                self.eval_seconds += time.perf_counter() - t0
            return True

    per_seed = []
    for seed in seeds:
        env = DummyVecEnv([lambda: make_reference(ENV_NAME) for _ in range(config.num_envs)])
        model = DQN("MlpPolicy", env, seed=seed, **sb3_kwargs(config))
        probe = Probe()
        t0 = time.perf_counter()
        model.learn(total_timesteps=config.total_timesteps, callback=probe)
        wall = time.perf_counter() - t0 - probe.eval_seconds
        final = greedy_eval_sb3(model, ENV_NAME)
        per_seed.append(
            {
                "seed": seed,
                "train_seconds": wall,
                "env_steps": int(model.num_timesteps),
                "first_optimal_step": probe.first_optimal,
                "eval": {k: v for k, v in final.items() if k != "rows"},
                "rows": final["rows"],
            }
        )
        print(f"  sb3 seed {seed}: {wall:.1f} s, optimal rate {final['optimal_rate']:.2f}, "
              f"first optimal at {probe.first_optimal}", flush=True)
    train_seconds = sum(s["train_seconds"] for s in per_seed)
    evals = [s["eval"] for s in per_seed]
    delivered_steps = [r["steps"] for s in per_seed for r in s["rows"] if r["delivered"]]
    return {
        "train_seconds": train_seconds,
        "seconds_per_seed": train_seconds / len(seeds),
        "env_steps_per_second": sum(s["env_steps"] for s in per_seed) / train_seconds,
        "first_optimal_step": [s["first_optimal_step"] for s in per_seed],
        "eval": {
            "success_rate": float(np.mean([e["success_rate"] for e in evals])),
            "optimal_rate": float(np.mean([e["optimal_rate"] for e in evals])),
            "mean_steps": float(np.mean(delivered_steps)) if delivered_steps else None,
            "collision_free_rate": float(np.mean([e["collision_free_rate"] for e in evals])),
            "mean_return": float(np.mean([e["mean_return"] for e in evals])),
            "all_seeds_optimal": all(e["optimal_rate"] == 1.0 for e in evals),
            "per_seed": [dict(seed=s["seed"], **s["eval"]) for s in per_seed],
        },
    }


# ------------------------------------------------------------------- main
def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="default", choices=["default", "paper"])
    parser.add_argument("--seeds", type=int, default=4, help="seeds 0..N-1 for both")
    parser.add_argument("--total-timesteps", type=int, default=None, help="override the preset's steps per seed")
    parser.add_argument("--eval-every-steps", type=int, default=None,
                        help="periodic greedy evaluation cadence in env steps per seed (default: 1/40 of the run)")
    parser.add_argument("--skip-sb3", action="store_true", help="only ours (e.g. to check the setup)")
    parser.add_argument("--torch-threads", type=int, default=1,
                        help="PyTorch intra-op threads for SB3 (default 1: with 2 threads on a shared 2-core machine "
                        "a gradient step measured 264 ms instead of 7 ms; 0 keeps PyTorch's default)")
    parser.add_argument("--out", default=None, help="JSON path (default bench/results/sb3_dqn_<preset>[_<steps>].json)")
    args = parser.parse_args()

    from wrl_jax.cli.machine import DEFAULT_XLA_OPT_LEVEL, apply_xla_opt_level

    apply_xla_opt_level(DEFAULT_XLA_OPT_LEVEL)  # as train_dqn.py does
    import jax
    import torch

    from wrl_jax.agents.dqn_config import PRESETS
    from wrl_jax.agents.dqn import make_algorithm
    from wrl_jax.agents.networks import measured_matmul_peak_gflops

    config = PRESETS[args.preset]
    if args.total_timesteps is not None:
        config = dataclasses.replace(config, total_timesteps=args.total_timesteps)
    algo = make_algorithm(config)
    seeds = list(range(args.seeds))
    eval_steps = args.eval_every_steps or max(config.steps_per_update, config.total_timesteps // 40)
    eval_updates = max(1, eval_steps // config.steps_per_update)
    eval_steps = eval_updates * config.steps_per_update

    record: dict[str, Any] = {
        "preset": args.preset,
        "env": ENV_NAME,
        "config": json.loads(json.dumps(dataclasses.asdict(config))),
        "seeds": seeds,
        "total_timesteps_per_seed": config.total_timesteps,
        "eval_every_steps": eval_steps,
        "flops_per_update_per_seed": algo.flops_per_update(),
        "gradient_flops_per_update_per_seed": algo.gradient_flops_per_update(),
        "num_updates": algo.num_updates,
        "cpu_peak_gflops": measured_matmul_peak_gflops(),
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(), "load_at_start": load_average()},
        "versions": {"jax": jax.__version__, "torch": torch.__version__},
        "command": "python bench/sb3_dqn.py " + " ".join(sys.argv[1:]),
    }
    print(f"ours: {len(seeds)} seeds x {config.total_timesteps:,} steps ({args.preset})", flush=True)
    record["ours"] = run_ours(config, seeds, eval_updates)
    print(f"  ours: compile {record['ours']['compile_seconds']:.1f} s, train {record['ours']['train_seconds']:.1f} s, "
          f"optimal rate {record['ours']['eval']['optimal_rate']:.2f}", flush=True)
    record["machine"]["load_after_ours"] = load_average()
    if not args.skip_sb3:
        import stable_baselines3

        if args.torch_threads > 0:
            torch.set_num_threads(args.torch_threads)
        record["versions"]["stable_baselines3"] = stable_baselines3.__version__
        record["versions"]["torch_threads"] = torch.get_num_threads()
        print(f"sb3: {len(seeds)} seeds x {config.total_timesteps:,} steps, one after another", flush=True)
        record["sb3"] = run_sb3(config, seeds, eval_steps)
        record["speedup_train_per_seed"] = record["sb3"]["seconds_per_seed"] / record["ours"]["seconds_per_seed"]
        record["speedup_including_compile"] = record["sb3"]["train_seconds"] / (
            record["ours"]["train_seconds"] + record["ours"]["compile_seconds"] + record["ours"]["init_seconds"]
        )
        record["sb3"]["achieved_gflops"] = (
            algo.flops_per_update() * algo.num_updates * len(seeds) / record["sb3"]["train_seconds"] / 1e9
        )
    record["machine"]["load_at_end"] = load_average()

    suffix = "" if args.total_timesteps is None else f"_{config.total_timesteps}"
    out = Path(args.out) if args.out else ROOT / "bench" / "results" / f"sb3_dqn_{args.preset}{suffix}.json"
    write_results(out, record, markdown(record))
    return 0


def write_results(out: Path, record: dict[str, Any], md: str) -> None:
    """The run's JSON at ``out`` and its Markdown table beside it (also printed)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=2))
    out.with_suffix(".md").write_text(md)
    print(md)


def markdown(r: dict[str, Any]) -> str:
    def fmt(x, f="{:.1f}"):
        return "n/a" if x is None else f.format(x)

    lines = [
        f"# DQN: ours vs Stable-Baselines3 ({r['preset']} preset, {r['env']})",
        "",
        f"`{r['command']}`; {len(r['seeds'])} seeds x {r['total_timesteps_per_seed']:,} env steps each; "
        f"load average at start {r['machine']['load_at_start']}, at end {r['machine']['load_at_end']} "
        f"({r['machine']['cpu_count']} CPUs).",
        "",
        "| | ours (JAX, compiled, seeds vmapped) | SB3 (PyTorch, NumPy reference env) |",
        "|---|---|---|",
    ]
    o, s = r["ours"], r.get("sb3")

    def row(name, a, b):
        lines.append(f"| {name} | {a} | {b if s else 'skipped'} |")

    row("train wall time, all seeds", f"{o['train_seconds']:.1f} s (+ compile {o['compile_seconds']:.1f} s)",
        f"{s['train_seconds']:.1f} s" if s else "")
    row("per seed", f"{o['seconds_per_seed']:.2f} s", f"{s['seconds_per_seed']:.1f} s" if s else "")
    row("env steps / s", f"{o['env_steps_per_second']:,.0f}", f"{s['env_steps_per_second']:,.0f}" if s else "")
    row(f"GFLOP/s (peak {r['cpu_peak_gflops']:.0f})", f"{o['achieved_gflops']:.1f}",
        f"{s['achieved_gflops']:.1f}" if s else "")
    row("delivery (all items, all seeds)", f"{100 * o['eval']['success_rate']:.0f}%",
        f"{100 * s['eval']['success_rate']:.0f}%" if s else "")
    row("at the BFS optimum", f"{100 * o['eval']['optimal_rate']:.0f}%",
        f"{100 * s['eval']['optimal_rate']:.0f}%" if s else "")
    row("mean steps (optimum 14.0)", fmt(o["eval"]["mean_steps"], "{:.2f}"),
        fmt(s["eval"]["mean_steps"], "{:.2f}") if s else "")
    row("collision-free", f"{100 * o['eval']['collision_free_rate']:.0f}%",
        f"{100 * s['eval']['collision_free_rate']:.0f}%" if s else "")
    row("first step at the optimum, per seed", str(o["first_optimal_step"]), str(s["first_optimal_step"]) if s else "")
    if s:
        lines += ["", f"Speed-up, training time per seed: **{r['speedup_train_per_seed']:.0f}x**; "
                  f"counting our compile and init too: **{r['speedup_including_compile']:.0f}x**."]
    lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
