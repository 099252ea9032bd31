"""Our SAC against Stable-Baselines3's SAC and sbx's: wall time to 99 % delivery, same hyperparameters.

Every side trains SAC with the hyperparameters of ``wrl_jax.agents.off_policy_config.SAC_DEFAULT``
(what ``python train_sac.py`` runs) on the same view of the continuous warehouse (the target and the route
seen, geodesic shaping: SAC's default on the static maps less its safety stop, which would act inside the
environment on every side alike; the comparison was measured without it), seeds ``0..N-1``, in one run:

- **ours**: the whole loop compiled (``wrl_jax.training``), the seeds ``vmap``ped, split over host devices as
  ``train_sac.py`` splits them (``--devices``, default one per core that divides the seeds: 2 here, both
  cores); compile time reported apart and counted in the wall.
- **SB3**: ``stable_baselines3.SAC`` (PyTorch, CPU) on the Gymnasium adapter
  (``wrl_jax.wrappers.gymnasium_continuous.ContinuousGymEnv``), a ``DummyVecEnv`` of ``num_envs``
  copies per seed; the seeds split over ``--library-processes`` processes (default 2, one PyTorch thread
  each: both cores, as ours uses them; two threads in one process oversubscribe a shared 2-core machine,
  see ``bench/sb3_dqn.py``).
- **sbx** (``--libraries sbx``): SB3's loop with its networks and updates in JAX (``sbx.SAC``), the same
  adapter and vector environment, its seeds one after another in a process of its own started with the
  ``XLA_FLAGS`` this command was given (XLA's defaults unless you set some: not our optimization level, not
  our split of the CPU into host devices, which would slow its programs; XLA spreads its work over the
  cores; it compiles our environment behind the adapter at that level too, a few seconds of its setup). It is not
  in the test extras; its venv reuses this
  project's packages (it asks for nothing they conflict with)::

      python3 -m venv /tmp/sbx-venv
      echo "$PWD/.venv/lib/python3.11/site-packages" > /tmp/sbx-venv/lib/python3.11/site-packages/wrl.pth
      /tmp/sbx-venv/bin/pip install sbx-rl==0.28.0
      /tmp/sbx-venv/bin/python bench/sb3_sac.py --libraries sb3 sbx

The settings map one to one (``library_kwargs``; tested for SB3): 16 environments, ``train_freq`` 1
vector step, 2 gradient steps per vector step, batch 256, buffer 200k, 5,000 random steps first, two
hidden layers of 128 (ReLU), learning rate 1e-3 for the actor, the critics and the temperature, Adam's
epsilon, gamma 0.99, tau 0.005, the temperature learned from 0.1 towards the target entropy (-6, or
``--target-entropy``), time-limit cut-offs bootstrapped, the actor as trained evaluated (our default evaluates an
average of it, which changes no training step; here every side evaluates the actor). Our ``reward_scale`` 0.1 is
a ``TransformReward`` on the libraries' side. What differs: the initial weights (ours orthogonal, the actor's last layer scaled by 0.01; SB3
PyTorch's uniform default, sbx flax's default), and the order of the temperature step (SB3 before the
critics, with the old value used in that gradient step as ours does; sbx and ours after the actor).

Every side is evaluated the same way every ``--eval-every-steps`` transitions per seed: the
deterministic policy on every item of the warehouse, with the family's evaluation and per-seed summary
(``wrl_jax.envs.continuous.evaluation``; the libraries' actor weights are read into a JAX function that
acts as their ``predict(obs, deterministic=True)``, tested for SB3), and a seed stops at its first
evaluation with at least ``--target`` of the items delivered. The libraries' evaluation time is excluded
from their wall; ours runs inside the compiled loop, is included, and all our seeds train until the
slowest has reached the target: both choices favour the libraries.

    python bench/sb3_sac.py --seeds 4
    python bench/sb3_sac.py --env Continuous-Warehouse-8x8-v0 --seeds 2

writes ``bench/results/continuous/<libraries>_sac_<env tag>.json`` and ``.md``.
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

from bench.sb3_dqn import load_average, write_results  # noqa: E402


def env_view(env_name: str) -> dict[str, Any]:
    """SAC's default overrides for ``env_name`` (``python train_sac.py --env ENV``), less the safety stop and the
    held value on the static maps: the route alone there, the view the committed comparison measured."""
    from wrl_jax.agents.off_policy_config import OFF_POLICY_ENV_DEFAULTS, ROUTE_ENV_DEFAULTS, ROUTE_NAMES

    return dict(ROUTE_ENV_DEFAULTS if env_name in ROUTE_NAMES else OFF_POLICY_ENV_DEFAULTS.get(env_name, {}))


def flops_per_env_step(config, env_name: str) -> float:
    """The configuration's FLOPs per collected transition (acting and its share of gradient steps): the same
    for both sides, so each side's achieved GFLOP/s compares with the machine's matmul peak."""
    import wrl_jax
    from wrl_jax.agents.sac import SAC

    env, params = wrl_jax.make(env_name, **env_view(env_name))
    return SAC(config, env, params).flops_per_update() / config.steps_per_update


# ------------------------------------------------------------------- ours
def run_ours(config, env_name: str, seeds: list[int], eval_every_updates: int, target: float,
             devices: int = 1) -> dict[str, Any]:
    import jax

    import wrl_jax
    from wrl_jax import training
    from wrl_jax.agents.sac import SAC

    env, params = wrl_jax.make(env_name, **env_view(env_name))
    algo = SAC(config, env, params)
    loop = training.LoopConfig(eval_every=eval_every_updates, chunk_updates=eval_every_updates, progress=False)
    if devices > 1:
        from wrl_jax.training import sharding

        trainer = sharding.ShardedTrainer(algo, seeds, loop, sharding.make_mesh(devices, 1))
    else:
        trainer = training.Trainer(algo, seeds, loop)
    t0 = time.perf_counter()
    runners = trainer.init()
    latest = trainer.empty_eval(runners)
    jax.block_until_ready(runners)
    init_seconds = time.perf_counter() - t0
    compile_seconds = trainer.compile(runners, latest)
    first: list[int | None] = [None] * len(seeds)
    history: list[dict[str, Any]] = []
    train_seconds, done = 0.0, 0
    while done < trainer.num_updates and any(f is None for f in first):
        t0 = time.perf_counter()
        runners, metrics, latest = trainer.run_chunk(runners, done, latest)
        train_seconds += time.perf_counter() - t0
        done += next(iter(metrics.values())).shape[0]
        rates = metrics["eval_success_rate"][-1]
        solved = metrics["eval_solved"][-1]
        steps = done * trainer.steps_per_update
        history.append({"env_steps": steps, "seconds": train_seconds, "delivered": [float(r) for r in rates],
                        "solved": [bool(s == 1.0) for s in solved]})
        for s, rate in enumerate(rates):
            if first[s] is None and rate >= target:
                first[s] = steps
        print(f"  ours {steps:>7,} steps {train_seconds:6.1f} s: delivered "
              + " ".join(f"{100 * r:3.0f}%" for r in rates), flush=True)
    env_steps = done * trainer.steps_per_update * len(seeds)
    return {
        "init_seconds": init_seconds,
        "compile_seconds": compile_seconds,
        "train_seconds": train_seconds,
        "wall_seconds": init_seconds + compile_seconds + train_seconds,
        "env_steps_per_second": env_steps / train_seconds,
        "env_steps": env_steps,
        "achieved_gflops": algo.flops_per_update() * done * len(seeds) / train_seconds / 1e9,
        "first_target_step": first,
        "reached": all(f is not None for f in first),
        "history": history,
    }


# -------------------------------------------------------------------- SB3
def sb3_actor_params(model) -> list[tuple[np.ndarray, np.ndarray]]:
    """SB3's actor (``latent_pi`` then ``mu``) as ``(W, b)`` pairs with ``W`` of shape (in, out)."""
    import torch

    layers = [m for m in model.actor.latent_pi if isinstance(m, torch.nn.Linear)] + [model.actor.mu]
    return [(m.weight.detach().numpy().T.copy(), m.bias.detach().numpy().copy()) for m in layers]


def sb3_deterministic_action(weights, obs):
    """SB3's deterministic SAC action ``tanh(mu(latent_pi(obs)))`` in JAX (ReLU layers); the action box is
    [-1, 1], so SB3's unscaling is the identity."""
    import jax
    import jax.numpy as jnp

    h = obs
    for w, b in weights[:-1]:
        h = jax.nn.relu(h @ w + b)
    w, b = weights[-1]
    return jnp.tanh(h @ w + b)


def make_evaluator(env_name: str, action):
    """``policy params -> (delivered fraction, solved)``: ``action(params, obs)`` on the family's episodes,
    scored by the family's own per-seed summary (what our training loop reports)."""
    import jax

    import wrl_jax
    from wrl_jax.envs.continuous.evaluation import evaluate_episodes, seed_summary

    env, params = wrl_jax.make(env_name, **env_view(env_name))

    @jax.jit
    def delivered(policy):
        summary = seed_summary(evaluate_episodes(lambda obs, state: action(policy, obs), env, params))
        return summary["eval_success_rate"], summary["eval_solved"] == 1.0

    return lambda policy: tuple(float(x) for x in delivered(policy))


def library_kwargs(config, library: str) -> dict[str, Any]:
    """``SAC`` arguments of SB3 or sbx for a :class:`SACConfig`; raises for what this comparison does not map."""
    if config.n_step != 1 or config.noise_correlation != 0.0:
        raise ValueError(f"{library}'s SAC has no n-step targets or correlated exploration noise here")
    if not config.learn_alpha:
        raise ValueError("this comparison maps the learned temperature only")
    if config.actor_average:
        raise ValueError(f"{library}'s SAC evaluates its actor as trained: compare with actor_average=0")
    if config.activation != "relu":
        raise ValueError("this comparison maps ReLU networks only (the evaluation reads the actor as ReLU layers)")
    if library == "sb3":
        import torch

        activation = torch.nn.ReLU
    else:
        import flax.linen as nn

        activation = nn.relu
    return dict(
        learning_rate=config.learning_rate,
        buffer_size=config.buffer_size,
        learning_starts=config.learning_starts,
        batch_size=config.batch_size,
        tau=config.tau,
        gamma=config.gamma,
        train_freq=(config.train_freq, "step"),
        gradient_steps=config.gradient_steps,
        ent_coef=f"auto_{config.initial_alpha}",
        target_entropy="auto" if config.target_entropy is None else float(config.target_entropy),
        policy_kwargs=dict(net_arch=list(config.hidden_sizes), activation_fn=activation,
                           optimizer_kwargs=dict(eps=config.adam_eps)),
        device="cpu",
    )


def library_policy(model, library: str):
    """``(params, action)``: the trained actor's parameters and a JAX ``action(params, obs)`` that acts as the
    library's ``predict(obs, deterministic=True)``."""
    if library == "sb3":
        return sb3_actor_params(model), sb3_deterministic_action
    state = model.policy.actor_state  # sbx: a flax TrainState; the deterministic action is the mode

    def action(params, obs):  # sbx's actor flattens all but a leading batch axis: give it one
        rows = obs.reshape(-1, obs.shape[-1])
        return state.apply_fn(params, rows).mode().reshape(*obs.shape[:-1], -1)

    return state.params, action


def train_library_seeds(config, env_name: str, seeds: list[int], eval_every_steps: int, target: float,
                        library: str, torch_threads: int) -> list[dict[str, Any]]:
    """SB3's SAC (``library="sb3"``) or sbx's (its JAX port) on ``seeds``, one after another, on the
    Gymnasium adapter; runs in a process of its own (sbx always, SB3 when seeds are split over processes)."""
    import gymnasium as gym
    import torch
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv

    from wrl_jax.cli.machine import DEFAULT_XLA_OPT_LEVEL, apply_xla_opt_level
    from wrl_jax.wrappers.gymnasium_continuous import ContinuousGymEnv

    if library == "sb3":  # SB3's spawned processes evaluate with JAX; sbx's keeps XLA as its user has it
        apply_xla_opt_level(DEFAULT_XLA_OPT_LEVEL)
    if torch_threads > 0:
        torch.set_num_threads(torch_threads)
    if library == "sb3":
        from stable_baselines3 import SAC as LibrarySAC
    else:
        from sbx import SAC as LibrarySAC
    scale = float(config.reward_scale)
    parent = os.getppid()

    def make_env():
        return gym.wrappers.TransformReward(ContinuousGymEnv(env_name, **env_view(env_name)), lambda r: scale * r)

    class Probe(BaseCallback):
        """The family's evaluation every ``eval_every_steps`` transitions; stops at ``target``; time excluded."""

        def __init__(self, evaluate):
            super().__init__()
            self.evaluate = evaluate
            self.eval_seconds, self.first, self.history = 0.0, None, []
            self.next_eval = eval_every_steps
            self.t0 = time.perf_counter()

        def _on_step(self) -> bool:
            if os.getppid() != parent:  # the bench was stopped: a spawned worker does not train on alone
                raise SystemExit(f"{library}: the bench that started this process has ended")
            if self.num_timesteps < self.next_eval:
                return True
            self.next_eval += eval_every_steps
            t0 = time.perf_counter()
            rate, solved = self.evaluate(library_policy(self.model, library)[0])
            self.eval_seconds += time.perf_counter() - t0
            seconds = time.perf_counter() - self.t0 - self.eval_seconds
            self.history.append({"env_steps": int(self.num_timesteps), "seconds": seconds, "delivered": rate,
                                 "solved": bool(solved)})
            print(f"  {library} seed {seed} {self.num_timesteps:>7,} steps {seconds:6.1f} s: delivered "
                  f"{100 * rate:3.0f}%", flush=True)
            if rate >= target:
                self.first = int(self.num_timesteps)
                return False
            return True

    if library == "sbx":
        import jax

        print(f"  sbx's process: {jax.device_count()} XLA device(s), XLA_FLAGS={os.environ.get('XLA_FLAGS', '')!r}",
              flush=True)
    per_seed = []
    for seed in seeds:
        venv = DummyVecEnv([make_env for _ in range(config.num_envs)])
        t0 = time.perf_counter()
        model = LibrarySAC("MlpPolicy", venv, seed=seed, **library_kwargs(config, library))
        setup = time.perf_counter() - t0
        probe = Probe(make_evaluator(env_name, library_policy(model, library)[1]))
        model.learn(total_timesteps=config.total_timesteps, callback=probe)
        wall = time.perf_counter() - probe.t0 - probe.eval_seconds
        per_seed.append({"seed": seed, "setup_seconds": setup, "train_seconds": wall,
                         "env_steps": int(model.num_timesteps), "first_target_step": probe.first,
                         "history": probe.history})
    return per_seed


def run_library(config, env_name: str, seeds: list[int], eval_every_steps: int, target: float, library: str,
                processes: int, torch_threads: int, user_xla_flags: str) -> dict[str, Any]:
    """The library's seeds split over ``processes`` processes (seed ``i`` to process ``i mod processes``), one
    PyTorch thread each by default: with 2 on this 2-core machine it uses both cores, as ours does. sbx runs in a
    spawned process even alone, with ``user_xla_flags`` (this process's XLA was set for ours). Its wall is the
    slowest process's time in setup and training (evaluations excluded)."""
    groups = [seeds[i::processes] for i in range(processes) if seeds[i::processes]]
    args = (config, env_name)
    tail = (eval_every_steps, target, library, torch_threads)
    if len(groups) == 1 and library == "sb3":
        results = [train_library_seeds(*args, groups[0], *tail)]
    else:
        import concurrent.futures
        import multiprocessing

        ours = os.environ.get("XLA_FLAGS", "")
        if library == "sbx":  # a spawned process copies the environment as it starts
            os.environ["XLA_FLAGS"] = user_xla_flags
        try:
            with concurrent.futures.ProcessPoolExecutor(len(groups),
                                                        mp_context=multiprocessing.get_context("spawn")) as pool:
                results = list(pool.map(train_library_seeds, *zip(*[(*args, g, *tail) for g in groups])))
        finally:
            os.environ["XLA_FLAGS"] = ours
    per_seed = sorted((s for group in results for s in group), key=lambda s: s["seed"])
    wall = max(sum(s["setup_seconds"] + s["train_seconds"] for s in group) for group in results)
    return {
        "processes": len(groups),
        "wall_seconds": wall,
        "train_seconds": wall,
        "env_steps_per_second": sum(s["env_steps"] for s in per_seed) / wall,
        "first_target_step": [s["first_target_step"] for s in per_seed],
        "reached": all(s["first_target_step"] is not None for s in per_seed),
        "per_seed": per_seed,
    }


# ------------------------------------------------------------------- main
LIBRARIES = {"sb3": "SB3 (PyTorch, Gymnasium adapter)", "sbx": "sbx (JAX, Gymnasium adapter)"}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="Continuous-Warehouse-12x12-v0")
    parser.add_argument("--seeds", type=int, default=4, help="seeds 0..N-1 for every side")
    parser.add_argument("--total-timesteps", type=int, default=None,
                        help="the most env steps per seed (default: the preset's, 400k)")
    parser.add_argument("--target", type=float, default=0.99, help="delivered fraction a seed stops at")
    parser.add_argument("--target-entropy", type=float, default=None,
                        help="SAC's target entropy on every side (default: SAC_DEFAULT's, -6; -2 is the paper's -|A|)")
    parser.add_argument("--eval-every-steps", type=int, default=8000, help="env steps per seed between evaluations")
    parser.add_argument("--libraries", nargs="*", default=["sb3"], choices=sorted(LIBRARIES),
                        help="the other side(s): sb3 (the test extras have it), sbx (its own venv, see the docstring)")
    parser.add_argument("--skip-ours", action="store_true", help="only the libraries")
    parser.add_argument("--library-processes", type=int, default=2,
                        help="processes SB3's seeds are split over (default 2: both cores; sbx uses one process of "
                             "its own, XLA threads)")
    parser.add_argument("--torch-threads", type=int, default=1,
                        help="PyTorch intra-op threads per process for SB3 (0 keeps PyTorch's default)")
    parser.add_argument("--devices", type=int, default=None,
                        help="host devices our seeds are split over (default: train_sac.py's, one per core that "
                             "divides the seeds; 1: one program on one device)")
    parser.add_argument("--out", default=None,
                        help="JSON path (default bench/results/continuous/<libraries>_sac_<env>.json)")
    args = parser.parse_args()

    from wrl_jax.cli.machine import (DEFAULT_XLA_OPT_LEVEL, apply_xla_opt_level, auto_devices,
                                     xla_flags_with_host_devices)

    user_xla_flags = os.environ.get("XLA_FLAGS", "")  # sbx's process gets these, not ours
    apply_xla_opt_level(DEFAULT_XLA_OPT_LEVEL)  # as train_sac.py does, and its split of the CPU
    devices = 1 if args.skip_ours else args.devices  # --skip-ours: the libraries alone, on the CPU as it is
    if devices is None:
        chosen = auto_devices(["--num-seeds", str(args.seeds)], os.cpu_count(), algo="sac")
        devices = int(chosen[1]) if chosen else 1
    os.environ["XLA_FLAGS"] = xla_flags_with_host_devices(os.environ.get("XLA_FLAGS", ""), devices)
    import jax

    from wrl_jax.agents.networks import measured_matmul_peak_gflops
    from wrl_jax.agents.off_policy_config import SAC_DEFAULT

    # The libraries evaluate the actor as trained; ours does the same here (the average changes no training step).
    config = dataclasses.replace(SAC_DEFAULT, actor_average=0.0)
    if args.target_entropy is not None:
        config = dataclasses.replace(config, target_entropy=args.target_entropy)
    if args.total_timesteps is not None:
        config = dataclasses.replace(config, total_timesteps=args.total_timesteps)
    seeds = list(range(args.seeds))
    eval_updates = max(1, args.eval_every_steps // config.steps_per_update)
    eval_steps = eval_updates * config.steps_per_update
    record: dict[str, Any] = {
        "env": args.env,
        "env_overrides": env_view(args.env),
        "config": json.loads(json.dumps(dataclasses.asdict(config))),
        "seeds": seeds,
        "target_delivered": args.target,
        "max_env_steps_per_seed": config.total_timesteps,
        "eval_every_steps": eval_steps,
        "flops_per_env_step": flops_per_env_step(config, args.env),
        "cpu_peak_gflops": measured_matmul_peak_gflops(),
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(), "load_at_start": load_average()},
        "versions": {"jax": jax.__version__},
        "command": "python bench/sb3_sac.py " + " ".join(sys.argv[1:]),
    }
    if not args.skip_ours:
        print(f"ours: {len(seeds)} seeds vmapped over {devices} device(s), up to {config.total_timesteps:,} steps "
              f"each", flush=True)
        record["ours"] = {**run_ours(config, args.env, seeds, eval_updates, args.target, devices), "devices": devices}
        record["machine"]["load_after_ours"] = load_average()
    for library in args.libraries:
        import stable_baselines3

        record["versions"]["stable_baselines3"] = stable_baselines3.__version__
        if library == "sb3":
            import torch

            record["versions"].update(torch=torch.__version__, torch_threads_per_process=args.torch_threads)
        else:
            import sbx

            record["versions"]["sbx"] = sbx.__version__
        processes = args.library_processes if library == "sb3" else 1
        print(f"{library}: {len(seeds)} seeds over {processes} process(es), up to "
              f"{config.total_timesteps:,} steps each", flush=True)
        side = record[library] = run_library(config, args.env, seeds, eval_steps, args.target, library,
                                             processes, args.torch_threads, user_xla_flags)
        if library == "sbx":
            side["xla_flags"] = user_xla_flags
        side["achieved_gflops"] = record["flops_per_env_step"] * sum(
            s["env_steps"] for s in side["per_seed"]) / side["train_seconds"] / 1e9
        if "ours" in record:
            side["wall_ratio"] = side["wall_seconds"] / record["ours"]["wall_seconds"]
            side["throughput_ratio"] = record["ours"]["env_steps_per_second"] / side["env_steps_per_second"]
    record["machine"]["load_at_end"] = load_average()

    tag = args.env.removeprefix("Continuous-Warehouse-").removesuffix("-v0").lower()
    name = "_".join(args.libraries) or "ours"
    out = Path(args.out) if args.out else ROOT / "bench" / "results" / "continuous" / f"{name}_sac_{tag}.json"
    write_results(out, record, markdown(record))
    return 0


def markdown(r: dict[str, Any]) -> str:
    sides = [("ours", "ours (JAX, compiled, seeds vmapped)")] + [(k, v) for k, v in LIBRARIES.items() if k in r]
    lines = [
        f"# SAC: ours and {', '.join(k for k, _ in sides[1:]) or 'nothing'} on {r['env']} "
        f"(to {100 * r['target_delivered']:.0f} % delivered)",
        "",
        f"`{r['command']}`; seeds {r['seeds']}, at most {r['max_env_steps_per_seed']:,} env steps each, evaluated "
        f"every {r['eval_every_steps']:,}; load average at start {r['machine']['load_at_start']}, at end "
        f"{r['machine']['load_at_end']} ({r['machine']['cpu_count']} CPUs; processes per library: "
        f"{ {k: r[k].get('processes', 1) for k, _ in sides[1:]} }; matmul peak {r['cpu_peak_gflops']:.0f} "
        f"GFLOP/s; {r['flops_per_env_step'] / 1e6:.1f} MFLOP per env step on every side).",
        "",
        "| | " + " | ".join(label for _, label in sides) + " |",
        "|---|" + "---|" * len(sides),
    ]

    def row(name, text):
        cells = [text(r[key]) if key in r else "skipped" for key, _ in sides]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")

    row("wall, every seed to the target", lambda x: f"{x['wall_seconds']:.1f} s" + (
        f" (compile {x['compile_seconds']:.1f} s)" if "compile_seconds" in x else ""))
    row("env steps / s, all seeds", lambda x: f"{x['env_steps_per_second']:,.0f}")
    row("first step at the target, per seed", lambda x: str(x["first_target_step"]))
    row("GFLOP/s", lambda x: f"{x['achieved_gflops']:.1f}")
    row("wall over ours (env steps / s: ours over it)",
        lambda x: f"{x['wall_ratio']:.1f}x ({x['throughput_ratio']:.1f}x)" if "wall_ratio" in x else "")
    if not all(r[key]["reached"] for key, _ in sides if key in r):
        lines += ["", "Not every seed reached the target: a wall is then the whole budget's."]
    lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
