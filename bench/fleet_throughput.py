"""Fleet throughput: robot-steps per second of the JAX fleet, with random and PIBT actions, against NumPy and POGEMA.

Measured in one process, interleaved round by round (every case sees the
same load on a shared machine), on ``Fleet-12x12-v0`` (FLEET_SPEC.md):

* ``jax random``: ``jax.jit`` of a ``lax.scan`` over time of ``jax.vmap(env.step)``
  (the full step: transition, observation, auto-reset, ``info["final_obs"]``)
  with uniform random actions in ``0..4`` (a random word per robot modulo 5) and one key per env
  per step, drawn for the whole call at its start inside the timed program (see ``jax_program``),
  everything a learner reads (``obs``, ``final_obs``,
  reward, truncation) summed into a checksum so nothing is dropped;
* ``jax core``: the transition alone (:func:`wrl_jax.envs.fleet.dynamics.fleet_transition`
  with its task draw; no observation, no reset), to show what the observation costs;
* ``jax pibt``: the same full step with PIBT actions
  (:func:`wrl_jax.envs.fleet.planners.plan`) and the priorities carried and
  reset on truncation, compiled with the planners' XLA options
  (:func:`wrl_jax.envs.fleet.planners.compiler_options`: the classic CPU fusion
  emitter, faster for PIBT; the random-action cases keep XLA's defaults, which are
  faster for them);
* ``numpy reference``: :class:`wrl_jax.envs.fleet.reference.FleetReference`,
  one env in a Python loop, random actions, and with NumPy PIBT actions;
* planner alone: the jitted, vmapped JAX PIBT on a batch of recorded fleet
  states (with the planners' XLA options, and again with XLA's defaults) against the NumPy PIBT of ``tests/envs/fleet/test_fleet_planners.py`` (the
  recursive one the tests check the JAX PIBT against, move for move) on the same states;
* POGEMA (``pogema`` 1.4.0, lifelong mode ``on_target="restart"``) on the same
  12x12 map (shelves as obstacles; POGEMA places robots and targets itself),
  same robot count, view radius 2, random actions, in a subprocess of this run
  with its own virtual environment, since POGEMA pins numpy<2 and
  gymnasium 0.28. Made with::

      python3 -m venv /tmp/pogema-venv && /tmp/pogema-venv/bin/pip install pogema

  (``--pogema-python`` points elsewhere; without that interpreter the POGEMA
  row records why it is missing).

Compile time (``lower`` + ``compile``) is reported apart; a warm-up call, then
``--repeats`` timed calls per case, median reported; robot-steps = envs x
steps x robots. Run from the repository root::

    .venv/bin/python bench/fleet_throughput.py            # writes bench/results/fleet_throughput.json
    .venv/bin/python bench/fleet_throughput.py --quick    # smoke run
    .venv/bin/python bench/fleet_throughput.py --robots 8 --batches 8192 --trace   # + the split steps' top fusions
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

DEFAULT_HOST_DEVICES = 16
"""XLA CPU devices the bench splits the machine into (``--host-devices``) for its sharded cases.

16 on this 2-core machine: three interleaved pairs of K = 8 runs, 16 against 8 devices, ran the
split random step at 24.9 / 30.3 / 31.0 M against 24.6 / 24.8 / 25.7 M robot-steps/s (and the
split PIBT step 12.1-14.8 M against 11.5-11.9 M); 32 devices ran slower than 16
(docs/fleet_planners.md "Speed")."""


if __name__ == "__main__":
    # XLA reads XLA_FLAGS once, when JAX starts: split the CPU into --host-devices XLA devices now, so the
    # sharded cases run beside the one-device ones (a one-device program uses the first device only).
    from host_split import split_cpu_from_argv

    split_cpu_from_argv(sys.argv[1:], "--host-devices", DEFAULT_HOST_DEVICES)

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import Mesh, NamedSharding  # noqa: E402
from jax.sharding import PartitionSpec as P  # noqa: E402

from wrl_jax.core.observation import observation_size  # noqa: E402
from wrl_jax.core.random import random_words, split_keys  # noqa: E402
from wrl_jax.core.registry import make  # noqa: E402
from wrl_jax.envs.fleet import metrics, planners  # noqa: E402
from wrl_jax.envs.fleet.dynamics import draw_tasks, fleet_transition  # noqa: E402
from wrl_jax.envs.fleet.reference import FleetReference  # noqa: E402

ENV = "Fleet-12x12-v0"
RESULTS = ROOT / "bench" / "results"
POGEMA_PYTHON = "/tmp/pogema-venv/bin/python"


def numpy_planners():
    """The NumPy PIBT and greedy of the tests (imported from the file, which is not a package)."""
    spec = importlib.util.spec_from_file_location("fleet_planner_tests", ROOT / "tests" / "envs" / "fleet" / "test_fleet_planners.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# ------------------------------------------------------------------ JAX cases
def jax_program(env: Any, batch: int, horizon: int, mode: str) -> Callable:
    """``(params, carry) -> carry`` after ``horizon`` steps of ``batch`` fleets; carry = (state, prio, key, sum)."""
    num_robots = env.num_robots
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    core = jax.vmap(fleet_transition, in_axes=(0, 0, 0, None))
    draw = jax.vmap(draw_tasks, in_axes=(0, None, None))
    plan = jax.vmap(planners.plan, in_axes=(None, 0, 0, None))
    update = jax.vmap(planners.next_priorities)

    def run(params, carry):
        state, prio, key, checksum = carry
        # The call's random draws up front, from the unrolled threefry of wrl_jax.core.random (jax.random's bits;
        # jax.random runs threefry as a CPU loop, which cost a quarter of the step), scanned over: drawn inside the
        # step, XLA fuses the hash into every fusion that reads an action or a key, and recomputes it there.
        key, action_key, env_key = split_keys(key, 3)
        keys = split_keys(env_key, horizon * batch).reshape(horizon, batch)
        actions = (random_words(action_key, horizon * batch * num_robots) % 5).astype(jnp.int32)
        actions = actions.reshape(horizon, batch, num_robots)

        def one_step(carry, inputs):
            state, prio, checksum = carry
            keys, action = inputs
            if mode == "pibt":
                action = plan("pibt", prio, state, params)
            if mode == "core":
                state, reward, truncated, _ = core(state, action, draw(keys, params, num_robots), params)
                return (state, prio, checksum + jnp.sum(reward)), None
            obs, state, reward, _, truncated, info = step(keys, state, action, params)
            if mode == "pibt":
                prio = update(prio, info, truncated)
            checksum = checksum + jnp.sum(obs) + jnp.sum(info["final_obs"]) + jnp.sum(reward) + jnp.sum(truncated)
            return (state, prio, checksum), None

        state, prio, checksum = jax.lax.scan(one_step, (state, prio, checksum), (keys, actions))[0]
        return state, prio, key, checksum

    return run


def over_devices(env: Any, batch: int, horizon: int, mode: str, devices: int) -> Callable:
    """:func:`jax_program` with the batch split over the first ``devices`` XLA devices (``shard_map``).

    Each device runs the one-device program on its ``batch / devices`` fleets with its own key; the
    carry's key and checksum get a leading device axis. Nothing is communicated between devices.
    """
    mesh = Mesh(np.array(jax.devices()[:devices]), ("envs",))
    local = jax_program(env, batch // devices, horizon, mode)

    def per_device(params, state, prio, key, checksum):
        state, prio, key, checksum = local(params, (state, prio, key[0], checksum[0]))
        return state, prio, key[None], checksum[None]

    sharded = jax.shard_map(per_device, mesh=mesh, in_specs=(P(), P("envs"), P("envs"), P("envs"), P("envs")),
                            out_specs=P("envs"), check_vma=False)
    return lambda params, carry: sharded(params, *carry)


class JaxCase:
    def __init__(self, num_robots: int, batch: int, horizon: int, mode: str, seed: int, devices: int = 1):
        self.num_robots, self.batch, self.horizon, self.mode, self.devices = num_robots, batch, horizon, mode, devices
        if batch % devices:
            raise ValueError(f"batch {batch} does not split over {devices} devices")
        env, self.params = make(ENV, num_robots=num_robots)
        reset_key, run_key = jax.random.split(jax.random.key(seed))
        _, state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(jax.random.split(reset_key, batch), self.params)
        prio = jax.vmap(lambda _: planners.pibt_init(num_robots))(jnp.arange(batch))
        self.carry = (state, prio, run_key, jnp.float32(0.0))
        if devices > 1:
            mesh = Mesh(np.array(jax.devices()[:devices]), ("envs",))
            self.carry = jax.device_put((state, prio, jax.random.split(run_key, devices), jnp.zeros(devices)),
                                        NamedSharding(mesh, P("envs")))
        start = time.perf_counter()
        # PIBT's program with the planners' XLA options (the classic CPU fusion emitter: faster with PIBT,
        # slower for the random step, which keeps XLA's defaults).
        self.options = planners.compiler_options() if mode == "pibt" else {}
        program = jax_program(env, batch, horizon, mode) if devices == 1 else over_devices(
            env, batch, horizon, mode, devices)
        self.fn = jax.jit(program, compiler_options=self.options).lower(self.params, self.carry).compile()
        self.compile_s = time.perf_counter() - start
        self.carry = jax.block_until_ready(self.fn(self.params, self.carry))  # warm-up
        self.times_s: list[float] = []

    @property
    def impl(self) -> str:
        return f"jax {self.mode}" + (f", {self.devices} devices" if self.devices > 1 else "")

    @property
    def label(self) -> str:
        return f"{self.impl} K={self.num_robots} batch={self.batch}"

    def call(self) -> Any:
        """One call of the compiled program, the carry carried on."""
        self.carry = self.fn(self.params, self.carry)
        return self.carry

    def time_once(self) -> None:
        start = time.perf_counter()
        jax.block_until_ready(self.call())
        self.times_s.append(time.perf_counter() - start)

    def summary(self) -> dict:
        robot_steps = self.batch * self.horizon * self.num_robots
        median = statistics.median(self.times_s)
        return {"impl": self.impl, "num_robots": self.num_robots, "batch": self.batch, "devices": self.devices,
                "horizon": self.horizon, "compile_s": self.compile_s, "times_s": self.times_s,
                "compiler_options": self.options,
                "robot_steps_per_s": robot_steps / median, "checksum": float(jnp.sum(self.carry[3]))}


# ------------------------------------------------------------------ NumPy cases
class ReferenceCase:
    """The NumPy reference env, one fleet, random or NumPy-PIBT actions, ``steps`` transitions per timed call."""

    def __init__(self, num_robots: int, steps: int, mode: str, seed: int, tests_module):
        _, params = make(ENV, num_robots=num_robots)
        self.ref = FleetReference.from_params(params)
        self.num_robots, self.steps, self.mode, self.pibt = num_robots, steps, mode, tests_module.numpy_pibt
        self.num_items, self.num_stations = int(params.num_items), int(params.num_stations)
        self.rng = np.random.default_rng(seed)
        _, self.state = self.ref.reset(*self.tasks())
        self.age = np.zeros(num_robots, dtype=np.int64)
        self.times_s: list[float] = []
        self.deliveries = 0

    def tasks(self):
        k = self.num_robots
        return self.rng.integers(0, self.num_items, k), self.rng.integers(0, self.num_stations, k)

    def actions(self) -> np.ndarray:
        if self.mode == "random":
            return self.rng.integers(0, 5, self.num_robots)
        s, ref = self.state, self.ref
        fields = [ref.station_dist[s.station[i]] if s.carrying[i] else ref.item_dist[s.item[i]]
                  for i in range(self.num_robots)]
        return self.pibt(s.pos, ref.shelves, fields, [(self.age[i], -i) for i in range(self.num_robots)])

    def time_once(self) -> None:
        start = time.perf_counter()
        for _ in range(self.steps):
            _, self.state, _, _, truncated, info = self.ref.step(self.state, self.actions(), self.tasks(), self.tasks())
            reached = info["picked_up"] | info["delivered"]
            self.age = np.where(reached | truncated, 0, self.age + 1)
            self.deliveries += int(info["delivered"].sum())
        self.times_s.append(time.perf_counter() - start)

    def summary(self) -> dict:
        return {"impl": f"numpy reference {self.mode}", "num_robots": self.num_robots, "batch": 1,
                "steps_per_call": self.steps, "times_s": self.times_s,
                "robot_steps_per_s": self.steps * self.num_robots / statistics.median(self.times_s)}


class PlannerCase:
    """PIBT alone on recorded fleet states: JAX vmapped over ``batch`` states, or the NumPy one state at a time.

    ``impl``: ``"jax"`` (compiled with :func:`planners.compiler_options`, as the library compiles its
    planner programs), ``"jax, xla defaults"`` (the same program with XLA's own options), ``"numpy"``.
    """

    def __init__(self, num_robots: int, batch: int, impl: str, states: dict, tests_module, devices: int = 1):
        self.num_robots, self.batch, self.devices = num_robots, batch, devices
        self.impl = impl + (f", {devices} devices" if devices > 1 else "")
        self.options = planners.compiler_options() if impl == "jax" else {}
        _, self.params = make(ENV, num_robots=num_robots)
        self.states = {name: jax.tree.map(lambda x: x[:batch], value) for name, value in states.items()}
        self.times_s: list[float] = []
        self.compile_s = 0.0
        if impl.startswith("jax"):
            state = jax.tree.map(jnp.asarray, self.states["state"])
            prio = jax.tree.map(jnp.asarray, self.states["prio"])
            self.args = (prio, state, self.params)
            batched = jax.vmap(planners.plan, in_axes=(None, 0, 0, None))
            plan = lambda p, s, params: batched("pibt", p, s, params)  # noqa: E731
            if devices > 1:  # the states split over the first ``devices`` devices, as in :func:`over_devices`
                mesh = Mesh(np.array(jax.devices()[:devices]), ("envs",))
                self.args = jax.device_put(self.args[:2], NamedSharding(mesh, P("envs"))) + (self.params,)
                plan = jax.shard_map(plan, mesh=mesh, in_specs=(P("envs"), P("envs"), P()), out_specs=P("envs"),
                                     check_vma=False)
            start = time.perf_counter()
            program = jax.jit(plan, compiler_options=self.options)
            self.fn = program.lower(*self.args).compile()
            self.compile_s = time.perf_counter() - start
            self.fn(*self.args).block_until_ready()
        else:
            ref = FleetReference.from_params(self.params)
            self.pibt, self.shelves = tests_module.numpy_pibt, ref.shelves
            self.item_dist, self.station_dist = ref.item_dist, ref.station_dist

    def time_once(self) -> None:
        start = time.perf_counter()
        if self.impl.startswith("jax"):
            jax.block_until_ready(self.fn(*self.args))
        else:
            s, prio = self.states["state"], self.states["prio"]
            k = self.num_robots
            for b in range(self.batch):
                fields = [self.station_dist[s.station[b, i]] if s.carrying[b, i] else self.item_dist[s.item[b, i]]
                          for i in range(k)]
                priority = prio.age[b] * k + prio.tiebreak[b]
                self.pibt(s.pos[b], self.shelves, fields, priority)
        self.times_s.append(time.perf_counter() - start)

    def summary(self) -> dict:
        return {"impl": f"{self.impl} pibt planner", "num_robots": self.num_robots, "batch": self.batch,
                "devices": self.devices,
                "compile_s": self.compile_s, "times_s": self.times_s, "compiler_options": self.options,
                "robot_decisions_per_s": self.batch * self.num_robots / statistics.median(self.times_s)}


def recorded_states(num_robots: int, count: int, seed: int) -> dict:
    """``count`` fleet states from PIBT shifts, with random ages (NumPy arrays), for the planner-alone cases."""
    env, params = make(ENV, num_robots=num_robots)
    horizon = int(params.max_steps)
    episodes = -(-count // horizon)
    run = jax.jit(jax.vmap(metrics.rollout, in_axes=(None, None, None, 0, None)), static_argnums=(0, 2, 4))
    _, steps = run(env, params, "pibt", jax.random.split(jax.random.key(seed), episodes), horizon)
    state = jax.tree.map(lambda x: np.asarray(x).reshape(-1, *x.shape[2:])[:count], steps.state)
    rng = np.random.default_rng(seed)
    prio = planners.PibtState(age=rng.integers(0, 40, (count, num_robots)).astype(np.int32),
                              tiebreak=np.tile(np.arange(num_robots - 1, -1, -1, dtype=np.int32), (count, 1)))
    return {"state": state, "prio": prio}


# ------------------------------------------------------------------ POGEMA
POGEMA_SCRIPT = r"""
import json, sys, time
import numpy as np
import pogema
from pogema import GridConfig, pogema_v0
args = json.loads(sys.argv[1])
cfg = GridConfig(map=args["map"], num_agents=args["num_robots"], obs_radius=args["view_radius"],
                 on_target="restart", max_episode_steps=args["max_steps"], seed=args["seed"])
env = pogema_v0(grid_config=cfg)
env.reset(seed=args["seed"])
rng = np.random.default_rng(args["seed"])
k = args["num_robots"]
def run(steps):
    start = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(rng.integers(0, 5, k).tolist())
        if all(terminated) or all(truncated):
            env.reset()
    return time.perf_counter() - start
run(200)
times = [run(args["steps"]) for _ in range(args["repeats"])]
obs, _ = env.reset()
print(json.dumps({"times_s": times, "pogema": pogema.__version__, "numpy": np.__version__,
                  "env_class": type(env.unwrapped).__name__, "obs_shape": list(np.asarray(obs[0]).shape),
                  "obs_dtype": str(np.asarray(obs[0]).dtype)}))
"""


def pogema_case(python: str, num_robots: int, steps: int, repeats: int, seed: int) -> dict:
    """POGEMA's robot-steps/s in a subprocess, or why it could not run."""
    _, params = make(ENV, num_robots=num_robots)
    shelves = np.asarray(params.shelves)
    grid = "\n".join("".join("#" if cell else "." for cell in row) for row in shelves)
    row = {"impl": "pogema lifelong random", "num_robots": num_robots, "batch": 1, "steps_per_call": steps}
    if not Path(python).exists():
        return {**row, "error": f"no interpreter at {python}; install with: python3 -m venv /tmp/pogema-venv && "
                                f"/tmp/pogema-venv/bin/pip install pogema"}
    payload = json.dumps({"map": grid, "num_robots": num_robots, "view_radius": 2, "max_steps": int(params.max_steps),
                          "seed": seed, "steps": steps, "repeats": repeats})
    done = subprocess.run([python, "-c", POGEMA_SCRIPT, payload], capture_output=True, text=True, timeout=900)
    if done.returncode != 0:
        return {**row, "error": done.stderr.strip()[-2000:]}
    out = json.loads(done.stdout.strip().splitlines()[-1])
    return {**row, **out, "robot_steps_per_s": steps * num_robots / statistics.median(out["times_s"])}


# ------------------------------------------------------------------ main
def bytes_per_robot_step(view_radius: int = 2) -> dict:
    """What one robot-step of the full JAX step writes at least: its observation row, twice (obs and final_obs)."""
    obs = 4 * observation_size(view_radius)
    return {"observation_row_bytes": obs, "obs_plus_final_obs_bytes": 2 * obs,
            "state_bytes": 4 * 2 + 4 + 4 + 1, "action_bytes": 4, "reward_bytes": 4}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", type=int, nargs="+", default=[4, 8])
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 64, 1024, 8192])
    parser.add_argument("--horizon", type=int, default=64, help="scan length of one timed call")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--reference-steps", type=int, default=300)
    parser.add_argument("--planner-batch", type=int, default=4096, help="states for the planner-alone cases")
    parser.add_argument("--numpy-planner-states", type=int, default=1000)
    parser.add_argument("--pogema-python", default=POGEMA_PYTHON)
    parser.add_argument("--pogema-steps", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--host-devices", type=int, default=DEFAULT_HOST_DEVICES,
                        help="XLA CPU devices (set before JAX starts) the sharded cases split their batch over; "
                             "1: no sharded cases")
    parser.add_argument("--quick", action="store_true", help="smoke run: K=4, batches 1 and 256, 2 repeats")
    parser.add_argument("--trace", action="store_true",
                        help="after timing, trace the split step cases and record their top fusions (bench/xla_trace.py)")
    parser.add_argument("--out", type=Path, default=RESULTS / "fleet_throughput.json")
    args = parser.parse_args(argv)
    if args.quick:
        args.robots, args.batches, args.repeats, args.horizon = [4], [1, 256], 2, 16
        args.reference_steps, args.planner_batch, args.numpy_planner_states, args.pogema_steps = 50, 256, 100, 300
    tests_module = numpy_planners()
    devices = min(args.host_devices, len(jax.devices()))

    cases: list[Any] = []
    for k in args.robots:
        for batch in args.batches:
            for mode in ("random", "pibt") + (("core",) if batch == max(args.batches) else ()):
                cases.append(JaxCase(k, batch, args.horizon, mode, args.seed))
                print(f"compiled {cases[-1].label}: {cases[-1].compile_s:.1f} s", flush=True)
        if devices > 1:  # the largest batch again, split over the host devices
            for mode in ("random", "pibt"):
                cases.append(JaxCase(k, max(args.batches), args.horizon, mode, args.seed, devices))
                print(f"compiled {cases[-1].label}: {cases[-1].compile_s:.1f} s", flush=True)
        states = recorded_states(k, args.planner_batch, args.seed)
        cases.append(PlannerCase(k, args.planner_batch, "jax", states, tests_module))
        if devices > 1:
            cases.append(PlannerCase(k, args.planner_batch, "jax", states, tests_module, devices))
        cases.append(PlannerCase(k, args.planner_batch, "jax, xla defaults", states, tests_module))
        cases.append(PlannerCase(k, args.numpy_planner_states, "numpy", states, tests_module))
        for mode in ("random", "pibt"):
            cases.append(ReferenceCase(k, args.reference_steps, mode, args.seed, tests_module))
    pogema_rows = {k: [] for k in args.robots}
    loads = []
    for round_ in range(args.repeats):  # interleaved: every case once per round
        for case in cases:
            case.time_once()
        for k in args.robots:
            pogema_rows[k].append(pogema_case(args.pogema_python, k, args.pogema_steps, 1, args.seed + round_))
        loads.append(list(os.getloadavg()))
        print(f"round {round_ + 1}/{args.repeats} done, load {loads[-1][0]:.1f}", flush=True)

    rows = [case.summary() for case in cases]
    if args.trace:  # where the split steps spend their time, fusion by fusion
        from xla_trace import fusion_shares

        for case, row in zip(cases, rows):
            if isinstance(case, JaxCase) and case.devices > 1:
                row["top_fusions"] = fusion_shares(case.fn, case.call)
                print(f"top fusions of {case.label} (share of traced time):")
                for fusion in row["top_fusions"]:
                    print(f"  {100 * fusion['share']:5.1f} %  {fusion['shape']:22s} {fusion['op']:28s} {fusion['name']}")
    for k, runs in pogema_rows.items():
        ok = [r for r in runs if "error" not in r]
        if ok:
            times = [r["times_s"][0] for r in ok]
            rows.append({**ok[0], "times_s": times,
                         "robot_steps_per_s": args.pogema_steps * k / statistics.median(times)})
        else:
            rows.append(runs[0])
    result = {"env": ENV, "rows": rows, "ratios": ratios(rows), "bytes_per_robot_step": bytes_per_robot_step(),
              "command": " ".join([".venv/bin/python", "bench/fleet_throughput.py", *(argv or sys.argv[1:])]),
              "load_average_per_round": loads, "machine": machine()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    for row in rows:
        rate = row.get("robot_steps_per_s", row.get("robot_decisions_per_s"))
        shown = f"{rate:,.0f}" if rate is not None else row.get("error", "")[:200]
        print(f"{row['impl']:28s} K={row['num_robots']} batch={row['batch']:>6}  {shown}")
    print(json.dumps(result["ratios"], indent=2))
    print(f"wrote {args.out}")
    return 0


def ratios(rows: list[dict]) -> dict:
    """Speed-ups at the largest batch, per robot count, against the baselines of the same run."""
    out = {}
    for k in sorted({row["num_robots"] for row in rows}):
        of = {(row["impl"], row["batch"]): row for row in rows if row["num_robots"] == k}
        best = lambda impl: max((r for (i, _), r in of.items() if i == impl), key=lambda r: r["batch"])  # noqa: E731
        rate = lambda impl: best(impl).get("robot_steps_per_s", best(impl).get("robot_decisions_per_s"))  # noqa: E731
        entry = {
            "jax_random_vs_numpy_reference_random": rate("jax random") / rate("numpy reference random"),
            "jax_pibt_vs_numpy_reference_pibt": rate("jax pibt") / rate("numpy reference pibt"),
            "jax_pibt_planner_vs_numpy_pibt_planner": rate("jax pibt planner") / rate("numpy pibt planner"),
            "jax_pibt_planner_xla_defaults_vs_numpy_pibt_planner":
                rate("jax, xla defaults pibt planner") / rate("numpy pibt planner"),
            "jax_core_vs_jax_random": rate("jax core") / rate("jax random"),
        }
        # the sharded cases' impl without its ", D devices": "jax random", "jax pibt", "jax pibt planner"
        sharded = {i.replace(f", {r['devices']} devices", ""): i for (i, _), r in of.items() if r.get("devices", 1) > 1}
        if sharded:
            entry["jax_random_sharded_vs_jax_random"] = rate(sharded["jax random"]) / rate("jax random")
            entry["jax_pibt_sharded_vs_jax_pibt"] = rate(sharded["jax pibt"]) / rate("jax pibt")
            entry["jax_pibt_planner_sharded_vs_jax_pibt_planner"] = (
                rate(sharded["jax pibt planner"]) / rate("jax pibt planner"))
            entry["jax_pibt_planner_sharded_vs_numpy_pibt_planner"] = (
                rate(sharded["jax pibt planner"]) / rate("numpy pibt planner"))
        pogema = [r for (i, _), r in of.items() if i.startswith("pogema") and "robot_steps_per_s" in r]
        if pogema:
            entry["jax_random_vs_pogema_random"] = rate("jax random") / pogema[0]["robot_steps_per_s"]
            if sharded:
                entry["jax_random_sharded_vs_pogema_random"] = (
                    rate(sharded["jax random"]) / pogema[0]["robot_steps_per_s"])
        out[f"K={k}"] = entry
    return out


def machine() -> dict:
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                                check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = None
    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.processor())
    return {"cpu": cpu, "cpu_count": os.cpu_count(), "python": platform.python_version(), "jax": jax.__version__,
            "numpy": np.__version__, "xla_flags": os.environ.get("XLA_FLAGS", ""), "git_commit": commit,
            "date_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}


if __name__ == "__main__":
    sys.exit(main())
