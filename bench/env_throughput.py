"""Environment throughput: random-action steps per second, JAX against the NumPy reference.

Measures, in one process and interleaved round by round (so that every
configuration sees the same load on a shared machine):

* the JAX environment as a learner runs it: ``jax.jit`` of a ``lax.scan`` over
  time of ``jax.vmap(env.step)`` over a batch of environments, with automatic
  reset, at several batch sizes, for each registered layout;
* the NumPy reference :class:`wrl_jax.envs.warehouse.reference.WarehouseReferenceEnv`: one
  environment, a Python loop, ``reset()`` when an episode ends;
* Gymnasium's ``SyncVectorEnv`` of reference environments (same-step autoreset,
  the JAX environment's semantics).

What one JAX "step" includes (per environment; everything inside the one jitted call):

1. a uniform random action: 2-bit fields of ``jax.random.bits`` words, 16
   actions per 32-bit word, the words of the whole call drawn before the scan
   (``--actions randint``: ``jax.random.randint``);
2. its own key for the automatic reset: the scan carries a key, splits it once
   per step, and ``jax.random.split(step_key, batch)`` gives each environment
   one (what PureJaxRL-style learners and this repository's PPO do;
   ``--env-keys fold_in`` folds the environment index in instead;
   ``--env-keys batched`` gives no key per environment: the step's key draws
   one word per environment with ``wrl_jax.envs.warehouse.env.draw_items`` and the batch is
   stepped with ``env.step_to_item``, as this repository's DQN does);
3. ``env.step``: the transition, reward, termination and truncation, the
   reset item drawn from that key (``wrl_jax.envs.warehouse.env.draw_item``: one word), the
   auto-reset select, the observation and ``info["final_obs"]``;
4. consuming everything a learner reads from the step: ``obs``,
   ``info["final_obs"]``, ``reward``, ``terminated`` and ``truncated`` are
   summed into a float32 checksum carried by the scan, so XLA cannot drop any
   of that work (the info flags ``collision``, ``wall_bump``, ... are not read).

``params`` is an argument of the jitted function, not a constant folded into
it, as in this repository's learners.

Compile time (``lower`` + ``compile``) is reported apart; then one warm-up
call, then ``--repeats`` timed calls, each ``block_until_ready``-ed, median
reported. The environment state is carried from call to call, as in training.

``--gymnax`` measures instead, in one process and interleaved: our ``env.step``
against the generic gymnax-style step (``wrl_jax.core.environment.Environment.step``:
split key + ``reset_env`` every step) at a large batch in the loop above, and
the loop a gymnax user writes (``jax.random.split(key, 3)``, ``randint``
actions, ``jax.random.split(key, n)``, ``jax.vmap(env.step)`` in ``lax.scan``)
at 4,096 environments, part by part (its random numbers alone, the step
alone), with the ``while`` loops and fusions of each compiled program
(:func:`main_gymnax`; docs/throughput.md, "The gymnax pattern").

Run from the repository root::

    .venv/bin/python bench/env_throughput.py            # full run, writes bench/results/
    .venv/bin/python bench/env_throughput.py --quick    # a smoke run (about a minute)
    .venv/bin/python bench/env_throughput.py --gymnax --envs Warehouse-12x12-v0 --repeats 9
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run as a script from a checkout without `pip install -e .`
    sys.path.insert(0, str(ROOT))

import gymnasium as gym  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import wrl_jax  # noqa: E402
from wrl_jax.core.environment import Environment  # noqa: E402
from wrl_jax.envs.warehouse import registration  # noqa: E402
from wrl_jax.envs.warehouse.env import Warehouse, draw_item, draw_items, item_from_word  # noqa: E402
from wrl_jax.envs.warehouse.reference import make_reference  # noqa: E402
from wrl_jax.envs.warehouse.types import EnvParams, EnvState  # noqa: E402

DEFAULT_ENVS = ("Warehouse-8x8-v0", "Warehouse-12x12-v0")
DEFAULT_BATCHES = (1, 4, 16, 64, 256, 1024, 4096, 16384, 65536)
QUICK_BATCHES = (1, 256, 65536)
DEFAULT_KEY_IMPLS = ("threefry2x32", "philox4x32")
RESULTS = ROOT / "bench" / "results"
MEASURED_FILES = ("wrl_jax/envs/warehouse/env.py", "wrl_jax/envs/warehouse/types.py",
                  "wrl_jax/envs/warehouse/layout.py", "wrl_jax/envs/warehouse/maps.py",
                  "wrl_jax/envs/warehouse/registration.py", "wrl_jax/envs/warehouse/reference.py",
                  "wrl_jax/core/environment.py", "bench/env_throughput.py")
"""The files whose code the benchmark times; uncommitted changes to them are recorded with the result."""


# --------------------------------------------------------------------- JAX side
def draw_action_source(key: jax.Array, horizon: int, batch: int, how: str) -> jax.Array:
    """The random actions of a whole call, drawn in one go before the scan.

    ``packed`` (default): ``(horizon, ceil(batch / 16))`` uint32 words; every
    2-bit field of a uniform word is uniform on {0, 1, 2, 3} and independent
    of the others, so a word holds 16 actions (one random block per 16
    environments), unpacked in the step by :func:`actions_at`. The words are
    materialized as the scan's input on purpose: if the generator were fused
    into the unpacking, XLA would recompute each word once per action (it
    does so with unrolled generators such as philox).
    ``randint``: ``jax.random.randint(key, (horizon, batch), 0, 4)``, the obvious call.
    """
    if how == "randint":
        return jax.random.randint(key, (horizon, batch), 0, 4, dtype=jnp.int32)
    return jax.random.bits(key, (horizon, -(-batch // 16)), jnp.uint32)


def actions_at(source: jax.Array, batch: int, how: str) -> jax.Array:
    """The ``batch`` actions of one step from its row of :func:`draw_action_source`."""
    if how == "randint":
        return source
    fields = (source[:, None] >> (2 * jnp.arange(16, dtype=jnp.uint32))) & 3
    return fields.reshape(-1)[:batch].astype(jnp.int32)


PARTS = {
    "step": "the full step, as in the table",
    "rng_only": "only the random numbers of a step: actions, per-env keys, and the reset item drawn from each",
    "shared_key": "env.step with ONE reset key shared by the batch: the per-env keys and draws removed",
}
"""The cost breakdown (``--breakdown``): what a step costs, part by part, at one batch size."""


def per_env_keys(key: jax.Array, batch: int, how: str) -> jax.Array:
    """``batch`` keys for the automatic resets: ``jax.random.split`` or ``fold_in`` of the env index."""
    if how == "fold_in":
        return jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, jnp.arange(batch, dtype=jnp.uint32))
    return jax.random.split(key, batch)


def make_rollout(env: Warehouse, batch: int, horizon: int, actions: str, part: str = "step",
                 env_keys: str = "split") -> Callable:
    """``(params, state, key, checksum) -> (state, key, checksum)`` after ``horizon`` steps of ``batch`` envs.

    ``params`` is an argument, not a constant baked into the program, as in
    this repository's learners (one compiled program serves every layout of a size).
    """
    vstep = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    vstep_to_item = jax.vmap(env.step_to_item, in_axes=(0, 0, 0, None))
    shared_key_step = jax.vmap(env.step, in_axes=(None, 0, 0, None))
    draw = jax.vmap(draw_item, in_axes=(0, None))

    def rollout(params: EnvParams, state: EnvState, key: jax.Array, checksum: jax.Array):
        key, action_key = jax.random.split(key)
        action_source = draw_action_source(action_key, horizon, batch, actions)

        def one_step(carry, source):
            state, key, checksum = carry
            key, env_key = jax.random.split(key)
            action = actions_at(source, batch, actions)
            if part == "rng_only" and env_keys == "batched":
                items = draw_items(env_key, batch, params)
                checksum = checksum + jnp.sum(items.astype(jnp.float32)) + jnp.sum(action.astype(jnp.float32))
                return (state, key, checksum), None
            if part == "rng_only":
                items = draw(per_env_keys(env_key, batch, env_keys), params)
                checksum = checksum + jnp.sum(items.astype(jnp.float32)) + jnp.sum(action.astype(jnp.float32))
                return (state, key, checksum), None
            if part == "shared_key":
                obs, state, reward, terminated, truncated, info = shared_key_step(env_key, state, action, params)
            elif env_keys == "batched":
                items = draw_items(env_key, batch, params)
                obs, state, reward, terminated, truncated, info = vstep_to_item(state, action, items, params)
            else:
                keys = per_env_keys(env_key, batch, env_keys)
                obs, state, reward, terminated, truncated, info = vstep(keys, state, action, params)
            checksum = (
                checksum
                + jnp.sum(obs)
                + jnp.sum(info["final_obs"])
                + jnp.sum(reward)
                + jnp.sum(terminated.astype(jnp.float32))
                + jnp.sum(truncated.astype(jnp.float32)) * 2.0
            )
            return (state, key, checksum), None

        return jax.lax.scan(one_step, (state, key, checksum), action_source)[0]

    return rollout


@dataclass
class JaxCase:
    env_name: str
    key_impl: str
    batch: int
    horizon: int
    part: str = "step"
    compile_s: float = 0.0
    times_s: list[float] = field(default_factory=list)
    cpu_s: list[float] = field(default_factory=list)
    checksum: float = 0.0
    # not serialized
    _fn: Callable | None = None
    _params: EnvParams | None = None
    _carry: tuple | None = None

    @property
    def label(self) -> str:
        part = "" if self.part == "step" else f" [{self.part}]"
        return f"{self.env_name} {self.key_impl} batch={self.batch}{part}"

    def steps_per_call(self) -> int:
        return self.batch * self.horizon

    def prepare(self, actions: str, env_keys: str, seed: int) -> None:
        env, params = wrl_jax.make(self.env_name)
        key = jax.random.key(seed, impl=self.key_impl)
        reset_key, run_key = jax.random.split(key)
        _, state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(jax.random.split(reset_key, self.batch), params)
        carry = (state, run_key, jnp.float32(0.0))
        rollout = make_rollout(env, self.batch, self.horizon, actions, self.part, env_keys)
        start = time.perf_counter()
        compiled = jax.jit(rollout).lower(params, *carry).compile()
        self.compile_s = time.perf_counter() - start
        carry = jax.block_until_ready(compiled(params, *carry))  # warm-up call, not timed
        self._fn, self._params, self._carry = compiled, params, carry

    def time_once(self) -> None:
        start, cpu_start = time.perf_counter(), time.process_time()
        carry = jax.block_until_ready(self._fn(self._params, *self._carry))
        self.times_s.append(time.perf_counter() - start)
        self.cpu_s.append(time.process_time() - cpu_start)
        self._carry = carry
        self.checksum = float(carry[2])

    def summary(self) -> dict:
        median = statistics.median(self.times_s)
        return {"env_name": self.env_name, "key_impl": self.key_impl, "batch": self.batch, "part": self.part,
                "horizon": self.horizon, "steps_per_call": self.steps_per_call(), "compile_s": self.compile_s,
                "times_s": self.times_s, "median_s": median, "steps_per_s": self.steps_per_call() / median,
                "cpu_s": self.cpu_s, "steps_per_cpu_s": self.steps_per_call() / statistics.median(self.cpu_s),
                "checksum": self.checksum}


# --------------------------------------------------------------- reference side
@dataclass
class ReferenceCase:
    """The NumPy reference, one env (``num_envs == 0``) or a SyncVectorEnv of ``num_envs``."""

    env_name: str
    num_envs: int
    steps: int
    times_s: list[float] = field(default_factory=list)
    _env: object = None
    _rng: np.random.Generator | None = None
    reward_sum: float = 0.0

    @property
    def kind(self) -> str:
        return "numpy reference, 1 env" if self.num_envs == 0 else f"gymnasium SyncVectorEnv x{self.num_envs}"

    def prepare(self, seed: int) -> None:
        self._rng = np.random.default_rng(seed)
        if self.num_envs == 0:
            self._env = make_reference(self.env_name)
            self._env.reset(seed=seed)
        else:
            self._env = gym.vector.SyncVectorEnv(
                [lambda: make_reference(self.env_name) for _ in range(self.num_envs)],
                autoreset_mode=gym.vector.AutoresetMode.SAME_STEP,
            )
            self._env.reset(seed=seed)
        self.time_once(record=False)  # warm-up

    def time_once(self, record: bool = True) -> None:
        start = time.perf_counter()
        if self.num_envs == 0:
            self._run_single()
        else:
            self._run_vector()
        if record:
            self.times_s.append(time.perf_counter() - start)

    def _run_single(self) -> None:
        env, total = self._env, 0.0
        # Actions drawn in blocks (as the JAX side draws them for a whole batch).
        for block in range(0, self.steps, 4096):
            for action in self._rng.integers(0, 4, size=min(4096, self.steps - block)).tolist():
                _, reward, terminated, truncated, _ = env.step(action)
                total += reward
                if terminated or truncated:
                    env.reset()
        self.reward_sum = float(total)

    def _run_vector(self) -> None:
        venv, total = self._env, 0.0
        for _ in range(self.steps // self.num_envs):
            _, reward, _, _, _ = venv.step(self._rng.integers(0, 4, size=self.num_envs))
            total += float(reward.sum())
        self.reward_sum = float(total)

    def transitions(self) -> int:
        return self.steps if self.num_envs == 0 else (self.steps // self.num_envs) * self.num_envs

    def summary(self) -> dict:
        median = statistics.median(self.times_s)
        return {"env_name": self.env_name, "kind": self.kind, "num_envs": max(self.num_envs, 1),
                "steps_per_call": self.transitions(), "times_s": self.times_s, "median_s": median,
                "steps_per_s": self.transitions() / median, "reward_sum": self.reward_sum}


# ------------------------------------------------------------------- reporting
def machine_info() -> dict:
    cpu = platform.processor()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", *MEASURED_FILES],
                               cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
        changed = [path for path in dirty if path in MEASURED_FILES]
        if changed:
            commit += f" (uncommitted changes to {', '.join(changed)})"
    except (OSError, subprocess.CalledProcessError):
        commit = None
    return {
        "cpu": cpu,
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jaxlib": importlib.metadata.version("jaxlib"),
        "numpy": np.__version__,
        "gymnasium": gym.__version__,
        "jax_devices": [str(d) for d in jax.devices()],
        "threefry_partitionable": bool(jax.config.jax_threefry_partitionable),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "git_commit": commit,
        "date_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }


def load_average() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def markdown_table(jax_rows: list[dict], ref_rows: list[dict], env_keys: str = "split") -> str:
    reference = {row["env_name"]: row["steps_per_s"] for row in ref_rows if row["kind"].startswith("numpy")}
    lines = [
        "| environment | implementation | batch | steps/s | x reference | compile s |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for row in ref_rows:
        ratio = row["steps_per_s"] / reference[row["env_name"]]
        lines.append(f"| {row['env_name']} | {row['kind']} | {row['num_envs']} | "
                     f"{row['steps_per_s']:,.0f} | {ratio:.2f} | - |")
    for row in jax_rows:
        ratio = row["steps_per_s"] / reference[row["env_name"]]
        impl = f"JAX env.step, {row['key_impl']} keys"
        if env_keys == "batched":
            impl = f"JAX env.step_to_item + draw_items (one key per batch step), {row['key_impl']} keys"
        elif env_keys == "fold_in":
            impl += " (fold_in per env)"
        impl += " (JAX default)" if row["key_impl"] == "threefry2x32" else " (caller's choice)"
        shown = f"{ratio:,.0f}" if ratio >= 10 else f"{ratio:.1f}"
        lines.append(f"| {row['env_name']} | {impl} | {row['batch']:,} | {row['steps_per_s']:,.0f} | "
                     f"{shown} | {row['compile_s']:.2f} |")
    return "\n".join(lines)


def breakdown_table(jax_rows: list[dict]) -> str:
    """Each part of a step at the largest batch: steps/s, nanoseconds per env step, share of the full step."""
    largest = max(row["batch"] for row in jax_rows)
    rows = [row for row in jax_rows if row["batch"] == largest]
    full = {(row["env_name"], row["key_impl"]): row for row in rows if row["part"] == "step"}
    lines = [
        f"Cost breakdown at batch {largest:,} (same run, interleaved; ns = wall-clock nanoseconds per env step "
        f"on the whole machine):",
        "",
        "| environment | keys | part | steps/s | ns per env step | share of the full step |",
        "|---|---|---|---:|---:|---:|",
    ]
    for row in sorted(rows, key=lambda r: (r["env_name"], r["key_impl"], list(PARTS).index(r["part"]))):
        ns = 1e9 / row["steps_per_s"]
        share = (1e9 / full[(row["env_name"], row["key_impl"])]["steps_per_s"])
        lines.append(f"| {row['env_name']} | {row['key_impl']} | {row['part']}: {PARTS[row['part']]} | "
                     f"{row['steps_per_s']:,.0f} | {ns:.1f} | {ns / share:.0%} |")
    return "\n".join(lines)



# ------------------------------------------------------------ gymnax mode
GYMNAX_PARTS = {
    "ours": "env.step (our step: the whole key goes to the reset draw, unrolled threefry)",
    "ours_bits_loop": "env.step as before this change: the reset word from jax.random.bits (JAX's looped threefry)",
    "generic": "the generic gymnax step, wrl_jax.core.environment.Environment.step: split key + reset_env every step",
    "rng_only": "the user's random numbers alone: split(key, 3), randint actions, split(key, n) per-env keys",
    "step_only": "vmap(env.step) alone: the call's keys and actions drawn once, outside the timed program",
}
"""The rows of ``--gymnax``: what a gymnax user's loop costs, and which part of it is ours."""


def step_function(env: Warehouse, part: str) -> Callable:
    """The per-environment ``step(key, state, action, params)`` a gymnax-mode row times."""
    if part == "generic":
        return lambda key, state, action, params: Environment.step(env, key, state, action, params)
    if part == "ours_bits_loop":
        def looped(key, state, action, params):
            word = jax.random.bits(key, (), jnp.uint32)
            return env.step_to_item(state, action, item_from_word(word, params.num_items), params)
        return looped
    return env.step


def make_user_loop(env: Warehouse, batch: int, horizon: int, part: str) -> Callable:
    """``(params, state, key, checksum) -> (state, key, checksum)``: the loop a gymnax user writes.

    Each step: ``key, k_act, k_step = jax.random.split(key, 3)``; actions from
    ``jax.random.randint(k_act, (n,), 0, num_actions)``; one key per
    environment from ``jax.random.split(k_step, n)``; ``jax.vmap(env.step)``;
    inside ``lax.scan``. The reward, observation and done flags are summed
    into the carried checksum so that nothing is dropped.
    """
    vstep = jax.vmap(step_function(env, part if part != "step_only" else "ours"), in_axes=(0, 0, 0, None))

    def checksum_of(obs, reward, terminated, truncated):
        return jnp.sum(obs) + jnp.sum(reward) + jnp.sum((terminated | truncated).astype(jnp.float32))

    def loop(params: EnvParams, state: EnvState, key: jax.Array, checksum: jax.Array, inputs=None):
        if part == "step_only":
            # ``inputs``: (actions, keys) of the whole call, drawn once outside the timed program.
            def step_only(carry, inputs):
                state, key, checksum = carry
                obs, state, reward, terminated, truncated, _ = vstep(inputs[1], state, inputs[0], params)
                return (state, key, checksum + checksum_of(obs, reward, terminated, truncated)), None

            return jax.lax.scan(step_only, (state, key, checksum), inputs)[0]

        def one_step(carry, _):
            state, key, checksum = carry
            key, action_key, step_key = jax.random.split(key, 3)
            actions = jax.random.randint(action_key, (batch,), 0, env.num_actions)
            keys = jax.random.split(step_key, batch)
            if part == "rng_only":
                words = jax.random.key_data(keys)[:, 0] >> 16
                return (state, key, checksum + jnp.sum(actions + words.astype(jnp.int32)).astype(jnp.float32)), None
            obs, state, reward, terminated, truncated, _ = vstep(keys, state, actions, params)
            return (state, key, checksum + checksum_of(obs, reward, terminated, truncated)), None

        return jax.lax.scan(one_step, (state, key, checksum), None, horizon)[0]

    return loop


def program_counts(compiled) -> dict:
    """Per-step work XLA was left with: ``while`` loops and fusions in the optimized program (whole call)."""
    text = compiled.as_text()
    return {"while_loops": len(re.findall(r"\bwhile\(", text)), "fusions": len(re.findall(r"=[^=]*\bfusion\(", text))}


@dataclass
class GymnaxCase(JaxCase):
    """A ``--gymnax`` row; ``pattern``: ``"user"`` (:func:`make_user_loop`) or ``"harness"`` (:func:`make_rollout`)."""

    pattern: str = "user"
    counts: dict = field(default_factory=dict)
    _extra: tuple = ()

    @property
    def label(self) -> str:
        return f"{self.env_name} {self.pattern} batch={self.batch} [{self.part}]"

    def prepare(self, actions: str, env_keys: str, seed: int) -> None:
        env, params = wrl_jax.make(self.env_name)
        key = jax.random.key(seed, impl=self.key_impl)
        reset_key, run_key = jax.random.split(key)
        _, state = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))(jax.random.split(reset_key, self.batch), params)
        carry = (state, run_key, jnp.float32(0.0))
        if self.pattern == "user":
            function = make_user_loop(env, self.batch, self.horizon, self.part)
        else:
            function = make_harness_variant(env, self.batch, self.horizon, actions, self.part)
        extra = ()
        if self.part == "step_only":
            action_key, keys_key = jax.random.split(jax.random.fold_in(key, 1))
            extra = (jax.block_until_ready((
                jax.random.randint(action_key, (self.horizon, self.batch), 0, env.num_actions),
                jax.random.split(keys_key, (self.horizon, self.batch)))),)
        start = time.perf_counter()
        compiled = jax.jit(function).lower(params, *carry, *extra).compile()
        self.compile_s = time.perf_counter() - start
        self.counts = program_counts(compiled)
        self._extra = extra
        carry = jax.block_until_ready(compiled(params, *carry, *extra))
        self._fn, self._params, self._carry = compiled, params, carry

    def time_once(self) -> None:
        start, cpu_start = time.perf_counter(), time.process_time()
        carry = jax.block_until_ready(self._fn(self._params, *self._carry, *self._extra))
        self.times_s.append(time.perf_counter() - start)
        self.cpu_s.append(time.process_time() - cpu_start)
        self._carry = carry
        self.checksum = float(carry[2])

    def summary(self) -> dict:
        return {**super().summary(), "pattern": self.pattern, **self.counts}


def make_harness_variant(env: Warehouse, batch: int, horizon: int, actions: str, part: str) -> Callable:
    """:func:`make_rollout` (the table's loop: packed actions, a split key per environment) with ``part``'s step."""
    # make_rollout vmaps env.step: give it this part's step on a shallow copy of the environment.
    variant = object.__new__(type(env))
    variant.__dict__.update(env.__dict__)
    variant.step = step_function(env, part)
    return make_rollout(variant, batch, horizon, actions)


def gymnax_cases(args: argparse.Namespace) -> list[GymnaxCase]:
    impl = args.key_impls[0]
    cases = []
    for name in args.envs:
        large = args.gymnax_large_batch
        for part in ("ours", "ours_bits_loop", "generic"):
            cases.append(GymnaxCase(name, impl, large, horizon_for(large, args), part, pattern="harness"))
        user = args.gymnax_user_batch
        for part in GYMNAX_PARTS:
            cases.append(GymnaxCase(name, impl, user, horizon_for(user, args), part, pattern="user"))
    return cases


def gymnax_table(rows: list[dict]) -> str:
    """Each gymnax-mode row: steps/s (median and best call), cost per batch step, ratios to ``ours``.

    On a shared machine other processes stretch some calls several-fold, so
    the ratios are given twice: by the best call of each row (the least
    disturbed) and by the median process CPU time (the work, whatever the wait).
    """
    def best(row):
        return row["steps_per_call"] / min(row["times_s"])

    ours = {(row["env_name"], row["pattern"], row["batch"]): row for row in rows if row["part"] == "ours"}
    lines = [
        ("| environment | loop | batch | step | steps/s (median) | steps/s (best) | us per batch step (best) "
         "| x ours (best) | x ours (CPU time) | while loops | fusions | compile s |"),
        "|---|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        base = ours[(row["env_name"], row["pattern"], row["batch"])]
        loop = "gymnax user's loop" if row["pattern"] == "user" else "table's loop (packed actions)"
        lines.append(f"| {row['env_name']} | {loop} | {row['batch']:,} | {row['part']}: {GYMNAX_PARTS[row['part']]} | "
                     f"{row['steps_per_s']:,.0f} | {best(row):,.0f} | {1e6 * row['batch'] / best(row):,.1f} | "
                     f"{best(row) / best(base):.2f} | {row['steps_per_cpu_s'] / base['steps_per_cpu_s']:.2f} | "
                     f"{row['while_loops']} | {row['fusions']} | {row['compile_s']:.2f} |")
    return "\n".join(lines)


def main_gymnax(args: argparse.Namespace, command: str) -> dict:
    """``--gymnax``: our step against the generic gymnax step, and a gymnax user's loop part by part."""
    load_before = load_average()
    cases = gymnax_cases(args)
    for case in cases:
        case.prepare(args.actions, args.env_keys, args.seed)
        print(f"compiled {case.label:56s} horizon {case.horizon:5d}  {case.compile_s:5.2f} s  {case.counts}",
              flush=True)
    for round_index in range(args.repeats):
        for case in cases:
            case.time_once()
        print(f"round {round_index + 1}/{args.repeats} done, load average {load_average()}", flush=True)
    rows = [case.summary() for case in cases]
    table = gymnax_table(rows)
    settings = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    result = {"command": command, "settings": settings,
              "parts": GYMNAX_PARTS, "machine": machine_info(), "load_average_before": load_before,
              "load_average_after": load_average(), "jax": rows, "table_markdown": table}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    args.out.with_suffix(".md").write_text(
        f"Command: `{command}`\n\nMachine: {result['machine']['cpu']} ({result['machine']['cpu_count']} CPUs), "
        f"jax {jax.__version__}, {args.key_impls[0]} keys, load average before/after {load_before} / "
        f"{result['load_average_after']}; interleaved rounds, median of {args.repeats}\n\n{table}\n")
    print()
    print(table)
    print(f"\nwrote {args.out} and {args.out.with_suffix('.md')}")
    return result


# ------------------------------------------------------------------------ main
def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", nargs="+", default=list(DEFAULT_ENVS), help="registered environment names")
    parser.add_argument("--batch-sizes", nargs="+", type=int, default=None,
                        help=f"JAX batch sizes (default {' '.join(map(str, DEFAULT_BATCHES))})")
    parser.add_argument("--key-impls", nargs="+", default=list(DEFAULT_KEY_IMPLS),
                        help="jax.random key implementations the caller passes (threefry2x32 is JAX's default)")
    parser.add_argument("--horizon", type=int, default=None,
                        help="scan length of one timed call (default: steps-per-call / batch, within [16, 4096])")
    parser.add_argument("--steps-per-call", type=int, default=None,
                        help="target env steps per timed call when --horizon is not given (default 2**21)")
    parser.add_argument("--repeats", type=int, default=None, help="timed calls per configuration (default 7)")
    parser.add_argument("--actions", choices=("packed", "randint"), default="packed",
                        help="how random actions are drawn (see draw_action_source)")
    parser.add_argument("--env-keys", choices=("split", "fold_in", "batched"), default="split",
                        help="how the per-env reset keys are made from the step's key (see per_env_keys); "
                             "batched: no per-env keys, items from env.draw_items and env.step_to_item")
    parser.add_argument("--reference-steps", type=int, default=None,
                        help="transitions per timed call of the NumPy reference (default 20000)")
    parser.add_argument("--vector-sizes", nargs="*", type=int, default=None,
                        help="SyncVectorEnv sizes (default 16 256; none to skip)")
    parser.add_argument("--breakdown", action=argparse.BooleanOptionalAction, default=None,
                        help="also time the parts of a step at the largest batch (default: on, off with --quick)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--gymnax", action="store_true",
                        help="instead of the table: our step against the generic gymnax step, and a gymnax user's "
                             "loop (split + randint + vmap(env.step) in lax.scan) part by part; writes "
                             "bench/results/env_throughput_gymnax.{json,md}")
    parser.add_argument("--gymnax-large-batch", type=int, default=65536, help="--gymnax: the large batch")
    parser.add_argument("--gymnax-user-batch", type=int, default=4096, help="--gymnax: the user loop's batch")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: batches 1 256 65536, 3 repeats, fewer steps")
    parser.add_argument("--out", type=Path, default=None,
                        help="JSON output (default bench/results/env_throughput.json; the .md table beside it)")
    args = parser.parse_args(argv)
    quick = args.quick
    defaults = {
        "batch_sizes": list(QUICK_BATCHES if quick else DEFAULT_BATCHES),
        "steps_per_call": 2**18 if quick else 2**21,
        "repeats": 3 if quick else 7,
        "reference_steps": 3000 if quick else 20000,
    }
    for name, value in defaults.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    args.vector_sizes = args.vector_sizes if args.vector_sizes is not None else ([16] if quick else [16, 256])
    args.breakdown = (not quick) if args.breakdown is None else args.breakdown
    if args.out is None and args.gymnax:
        args.out = RESULTS / ("env_throughput_gymnax_quick.json" if quick else "env_throughput_gymnax.json")
    if args.out is None:
        args.out = RESULTS / ("env_throughput_quick.json" if quick else "env_throughput.json")
    if args.out.is_dir() or args.out.suffix != ".json":
        parser.error(f"--out must be a .json file path (the .md table is written beside it), got {args.out}")
    for name in args.envs:
        registration.spec(name)  # a clear error for an unknown name, before any work
    for impl in args.key_impls:
        try:
            jax.random.key(0, impl=impl)
        except (ValueError, TypeError) as error:
            parser.error(f"unknown --key-impls entry {impl!r}: {error}")
    positive = {"--batch-sizes": min(args.batch_sizes), "--repeats": args.repeats,
                "--steps-per-call": args.steps_per_call, "--reference-steps": args.reference_steps,
                "--horizon": 1 if args.horizon is None else args.horizon}
    for flag, value in positive.items():
        if value < 1:
            parser.error(f"{flag} must be positive, got {value}")
    if any(n < 1 for n in args.vector_sizes):
        parser.error(f"--vector-sizes must be positive, got {args.vector_sizes}")
    return args


def horizon_for(batch: int, args: argparse.Namespace) -> int:
    if args.horizon is not None:
        return args.horizon
    return int(min(4096, max(16, args.steps_per_call // batch)))


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    command = " ".join([Path(sys.executable).name, *sys.argv]) if argv is None else "main(" + repr(argv) + ")"
    print(f"# env throughput: {command}", flush=True)
    if args.gymnax:
        return main_gymnax(args, command)
    load_before = load_average()

    jax_cases = [JaxCase(name, impl, batch, horizon_for(batch, args))
                 for name in args.envs for impl in args.key_impls for batch in args.batch_sizes]
    if args.breakdown:
        largest = max(args.batch_sizes)
        jax_cases += [JaxCase(name, impl, largest, horizon_for(largest, args), part)
                      for name in args.envs for impl in args.key_impls for part in PARTS if part != "step"]
    ref_cases = [ReferenceCase(name, n, args.reference_steps)
                 for name in args.envs for n in [0, *args.vector_sizes]]
    for case in jax_cases:
        case.prepare(args.actions, args.env_keys, args.seed)
        print(f"compiled {case.label:48s} horizon {case.horizon:5d}  {case.compile_s:5.2f} s", flush=True)
    for case in ref_cases:
        case.prepare(args.seed)

    # Interleaved rounds: every configuration is timed once per round.
    for round_index in range(args.repeats):
        for case in ref_cases:
            case.time_once()
        for case in jax_cases:
            case.time_once()
        print(f"round {round_index + 1}/{args.repeats} done, load average {load_average()}", flush=True)

    jax_rows = [case.summary() for case in jax_cases]
    ref_rows = [case.summary() for case in ref_cases]
    reference = {row["env_name"]: row["steps_per_s"] for row in ref_rows if row["num_envs"] == 1
                 and row["kind"].startswith("numpy")}
    for row in jax_rows + ref_rows:
        row["ratio_vs_reference"] = row["steps_per_s"] / reference[row["env_name"]]
    table = markdown_table([row for row in jax_rows if row["part"] == "step"], ref_rows, args.env_keys)
    if args.breakdown:
        table += "\n\n" + breakdown_table(jax_rows)
    result = {
        "command": command,
        "what_one_step_includes": __doc__.split("What one JAX \"step\" includes")[1].split("Compile time")[0].strip(),
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "machine": machine_info(),
        "load_average_before": load_before,
        "load_average_after": load_average(),
        "jax": jax_rows,
        "reference": ref_rows,
        "table_markdown": table,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    args.out.with_suffix(".md").write_text(
        f"Command: `{command}`\n\nMachine: {result['machine']['cpu']} ({result['machine']['cpu_count']} CPUs), "
        f"jax {jax.__version__}, load average before/after {load_before} / {result['load_average_after']}\n\n"
        f"{table}\n"
    )
    print()
    print(table)
    print(f"\nwrote {args.out} and {args.out.with_suffix('.md')}")
    return result


if __name__ == "__main__":
    main()
