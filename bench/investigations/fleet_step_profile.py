"""Where a fleet step's time goes, part by part, and how two implementations compare back to back.

Why this exists: issue 14 asks for 20 M robot-steps/s on a 2-core CPU and for what bounds the step;
the only way to know which part to make cheaper is to time each part alone, in one process, under the
same (noisy, shared) load. Every case is ``jax.jit`` of a ``lax.scan`` over time of ``jax.vmap`` over
envs of Fleet-12x12-v0. Inputs are drawn in bulk before timing (one ``jax.random.randint`` for the
``(T, B, K)`` actions, one ``jax.random.split`` for the ``(T, B)`` keys) and scanned over, so the
timed program is the step alone; every output is summed into a checksum so nothing is dead code.

Parts (``--parts``):

* ``step``: ``env.step`` (transition, observation, auto-reset, ``final_obs``, every flag);
* ``read``: ``env.step`` read as ``bench/fleet_throughput.py`` reads it (``obs``, ``final_obs``, reward,
  truncation, each summed over the whole batch, the observation not carried to the next step), so XLA
  drops the rest (the flags, ``final_global_state``) and fuses the sums as in that bench (per-fleet sums
  inside ``vmap``, or an observation carried in the loop, fuse differently);
* ``transition``: ``env.transition`` (the core plus the observation of the reached state, no reset);
* ``core``: ``fleet_transition`` with its task draw (no observation, no reset);
* ``obs``: ``fleet_observation`` alone, of a state moved cheaply every step (all robots shifted alike);
* ``conflicts``: ``propose`` and ``resolve_conflicts`` alone (positions carried);
* ``draw``: the step's key split and both task draws (transition and auto-reset);
* ``reset``: ``reset_env`` and the select of state and observation against a carried observation.

``--trace`` then runs each case under ``jax.profiler`` and prints its top fusions by share of the
traced time (``bench/xla_trace.py``): where the time goes inside the fused program.

Compile time (``lower`` + ``compile``) is reported apart; then ``--repeats`` rounds, each timing every
case once, interleaved, median reported. ``--baseline FILE`` adds the same cases for an older copy of
``wrl_jax/envs/fleet/env.py`` (with ``--baseline-obs FILE``, an older ``wrl_jax/core/observation.py``
for it to import), so a before/after ratio is measured in one process. Run from the repository root::

    .venv/bin/python bench/investigations/fleet_step_profile.py --robots 8 --batch 8192 --parts step core obs
    .venv/bin/python bench/investigations/fleet_step_profile.py --robots 8 --batch 8192 --devices 8 --parts step obs \
        --baseline /tmp/env_before.py --baseline-obs /tmp/obs_before.py   # files from `git show COMMIT:PATH`
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import statistics
import sys
import time
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
if str(ROOT / "bench") not in sys.path:
    sys.path.insert(0, str(ROOT / "bench"))  # host_split

if __name__ == "__main__":
    # --devices N splits the CPU into N XLA host devices, which XLA reads once, when JAX starts.
    from host_split import split_cpu_from_argv

    split_cpu_from_argv(sys.argv[1:], "--devices", 1)

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import Mesh, NamedSharding  # noqa: E402
from jax.sharding import PartitionSpec as P  # noqa: E402

import wrl_jax.envs  # noqa: E402, F401  (registers the names)
from wrl_jax.core.registry import make  # noqa: E402
from wrl_jax.envs.fleet import conflicts, dynamics, observation  # noqa: E402
from wrl_jax.envs.fleet.env import Fleet  # noqa: E402

# The current code as one namespace, shaped like the older single-module env.py files it is compared with.
current_module = types.SimpleNamespace(**{**vars(conflicts), **vars(observation), **vars(dynamics), "Fleet": Fleet})

PARTS = ("step", "read", "transition", "core", "obs", "conflicts", "draw", "reset")


def load_baseline(env_file: str, obs_file: str | None) -> types.ModuleType:
    """An older ``env.py`` as a module; with ``obs_file``, importing its observation functions from that file.

    Functions the file does not define (the current ``env.py`` keeps only the class: the MDP is in
    ``dynamics.py``, ``observation.py`` and ``conflicts.py``) come from the current code."""
    source = Path(env_file).read_text()
    if obs_file:
        spec = importlib.util.spec_from_file_location("fleet_profile_baseline_observation", obs_file)
        obs_module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(obs_module)
        sys.modules[spec.name] = obs_module
        source = source.replace("from wrl_jax.core.observation import", f"from {spec.name} import")
    module = types.ModuleType("fleet_profile_baseline_env")
    exec(compile(source, env_file, "exec"), module.__dict__)  # noqa: S102 (a local file the user names)
    for name, value in vars(current_module).items():
        module.__dict__.setdefault(name, value)
    return module


def checksum(tree) -> jax.Array:
    """Sum of every leaf as float32 (bools and ints included), so every output is consumed."""
    return sum(jnp.sum(leaf.astype(jnp.float32)) for leaf in jax.tree.leaves(tree))


def one_env(module, env, part: str):
    """``(state, obs, key, action, params) -> (state, obs, value)``: one env's part of a step."""

    def fn(state, obs, key, action, params):
        if part == "step":
            obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)
            return state, obs, checksum((obs, reward, terminated, truncated, info))
        if part == "read":  # as bench/fleet_throughput.py reads the step: summed over the batch, obs not carried
            seen, state, reward, terminated, truncated, info = env.step(key, state, action, params)
            return state, obs, (seen, info["final_obs"], reward, truncated)
        if part == "transition":
            obs, state, reward, terminated, truncated, info = env.transition(key, state, action, params)
            return state, obs, checksum((obs, reward, terminated, truncated, info))
        if part == "core":
            tasks = module.draw_tasks(key, params, env.num_robots)
            state, reward, truncated, flags = module.fleet_transition(state, action, tasks, params)
            return state, obs, checksum((reward, truncated, flags))
        if part == "obs":
            size = params.shelves.shape[0]
            state = state.replace(pos=(state.pos + 1) % size, carrying=~state.carrying, time=state.time + 1)
            seen = module.fleet_observation(state, params, env.view_radius)
            return state, obs, checksum(seen)
        if part == "conflicts":
            proposal, wall_bump, shelf_hit = module.propose(state.pos, action, params.shelves)
            pos, robot_block = module.resolve_conflicts(state.pos, proposal)
            return state.replace(pos=pos), obs, checksum((robot_block, wall_bump, shelf_hit))
        if part == "draw":
            key_step, key_reset = module.step_keys(key)
            drawn = (module.draw_tasks(key_step, params, env.num_robots),
                     module.draw_tasks(key_reset, params, env.num_robots))
            return state, obs, checksum(drawn)
        if part == "reset":
            reset_obs, reset_state = env.reset_env(key, params)
            done = (state.time + 1) >= params.max_steps
            state = jax.tree.map(lambda f, c: jnp.where(done, f, c), reset_state, state.replace(time=state.time + 1))
            obs = jnp.where(done, reset_obs, obs)
            return state, obs, checksum(obs)
        raise ValueError(part)

    return fn


def build(module, env, params, part: str, batch: int, horizon: int, seed: int, devices: int = 1):
    """Compile one case; returns ``(compiled, args, compile_s)``; the carry of ``args`` is updated per call.

    With ``devices > 1`` the batch is split over the first ``devices`` XLA devices (``shard_map``, each
    device the one-device program on its share, nothing communicated), as bench/fleet_throughput.py does.
    """
    step = jax.vmap(one_env(module, env, part), in_axes=(0, 0, 0, 0, None))

    def run(params, state, obs, keys, actions):
        def body(carry, xs):
            state, obs, total = carry
            state, obs, value = step(state, obs, xs[0], xs[1], params)
            return (state, obs, total + checksum(value)), None

        (state, obs, total), _ = jax.lax.scan(body, (state, obs, jnp.float32(0.0)), (keys, actions))
        return state, obs, total

    key_reset, key_keys, key_actions = jax.random.split(jax.random.key(seed), 3)
    obs, state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(jax.random.split(key_reset, batch), params)
    # Start mid-shift so that every timed call of ``horizon`` steps crosses one auto-reset or more.
    state = state.replace(time=state.time + (int(params.max_steps) - horizon // 2) % int(params.max_steps))
    keys = jax.random.split(key_keys, horizon * batch).reshape(horizon, batch)
    actions = jax.random.randint(key_actions, (horizon, batch, env.num_robots), 0, 5, dtype=jnp.int32)
    program = run
    if devices > 1:
        if batch % devices:
            raise ValueError(f"batch {batch} does not split over {devices} devices")
        mesh = Mesh(np.array(jax.devices()[:devices]), ("envs",))

        def per_device(params, state, obs, keys, actions):
            state, obs, total = run(params, state, obs, keys, actions)
            return state, obs, total[None]

        sharded = jax.shard_map(per_device, mesh=mesh, in_specs=(P(), P("envs"), P("envs"), P(None, "envs"),
                                                                 P(None, "envs")),
                                out_specs=(P("envs"), P("envs"), P("envs")), check_vma=False)

        def program(params, state, obs, keys, actions):
            state, obs, totals = sharded(params, state, obs, keys, actions)
            return state, obs, jnp.sum(totals)

        state, obs = jax.device_put((state, obs), NamedSharding(mesh, P("envs")))
        keys, actions = jax.device_put((keys, actions), NamedSharding(mesh, P(None, "envs")))
    start = time.perf_counter()
    compiled = jax.jit(program, donate_argnums=(1, 2)).lower(params, state, obs, keys, actions).compile()
    return compiled, [params, state, obs, keys, actions], time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", type=int, nargs="+", default=[8])
    parser.add_argument("--batch", type=int, nargs="+", default=[8192])
    parser.add_argument("--horizon", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--parts", nargs="+", default=list(PARTS), choices=PARTS)
    parser.add_argument("--baseline", default=None, help="an older copy of wrl_jax/envs/fleet/env.py")
    parser.add_argument("--baseline-obs", default=None, help="the observation.py that baseline imports")
    parser.add_argument("--no-current", action="store_true", help="time the baseline only")
    parser.add_argument("--devices", type=int, default=1,
                        help="split the CPU into this many XLA host devices and each batch over them")
    parser.add_argument("--trace", action="store_true", help="print each case's top fusions (jax.profiler)")
    args = parser.parse_args(argv)

    impls = {} if args.no_current else {"current": current_module}
    if args.baseline:
        impls["baseline"] = load_baseline(args.baseline, args.baseline_obs)
    cases = {}
    for num_robots in args.robots:
        env, params = make("Fleet-12x12-v0", num_robots=num_robots)
        for batch in args.batch:
            for name, module in impls.items():
                impl_env = env if module is current_module else module.Fleet(params, env.view_radius, env.name)
                for part in args.parts:
                    label = (name, num_robots, batch, part)
                    cases[label] = build(module, impl_env, params, part, batch, args.horizon, seed=0,
                                         devices=args.devices)
                    compiled, call_args, _ = cases[label]
                    call_args[1:3] = jax.block_until_ready(compiled(*call_args))[:2]  # warm-up
                    print(f"compiled {label} in {cases[label][2]:.1f} s", file=sys.stderr, flush=True)
    times = {label: [] for label in cases}
    sums = {}
    for _ in range(args.repeats):
        for label, (compiled, call_args, _) in cases.items():
            start = time.perf_counter()
            state, obs, total = jax.block_until_ready(compiled(*call_args))
            times[label].append(time.perf_counter() - start)
            call_args[1:3] = state, obs
            sums[label] = float(total)
    rows = []
    for (name, num_robots, batch, part), spent in times.items():
        median = statistics.median(spent)
        rows.append({"impl": name, "robots": num_robots, "batch": batch, "part": part,
                     "compile_s": round(cases[(name, num_robots, batch, part)][2], 2),
                     "median_s": median, "env_steps_per_s": batch * args.horizon / median,
                     "robot_steps_per_s": batch * args.horizon * num_robots / median,
                     "checksum": sums[(name, num_robots, batch, part)]})
        print(f"{name:9s} K={num_robots} B={batch:6d} {part:10s} {rows[-1]['robot_steps_per_s'] / 1e6:8.2f} "
              f"M robot-steps/s  ({rows[-1]['env_steps_per_s'] / 1e3:9.1f} k env-steps/s, "
              f"compile {rows[-1]['compile_s']:.1f} s)")
    if "baseline" in impls and "current" in impls:
        for row in rows:
            if row["impl"] == "current":
                base = next(r for r in rows if r["impl"] == "baseline" and all(
                    r[k] == row[k] for k in ("robots", "batch", "part")))
                print(f"ratio current/baseline K={row['robots']} B={row['batch']:6d} {row['part']:10s} "
                      f"x{base['median_s'] / row['median_s']:.2f}")
    traces = {}
    if args.trace:
        from xla_trace import fusion_shares

        for label, (compiled, call_args, _) in cases.items():
            def call(compiled=compiled, call_args=call_args):  # state and obs are donated: carry them on
                out = compiled(*call_args)
                call_args[1:3] = out[:2]
                return out

            traces[" ".join(map(str, label))] = shares = fusion_shares(compiled, call)
            print(f"top fusions of {' '.join(map(str, label))} (share of traced time):")
            for row in shares:
                print(f"  {100 * row['share']:5.1f} %  {row['shape']:22s} {row['op']:28s} {row['name']}")
    print(json.dumps({"horizon": args.horizon, "repeats": args.repeats, "devices": args.devices, "rows": rows,
                      **({"top_fusions": traces} if traces else {})}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
