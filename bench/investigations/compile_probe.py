"""Compile time of four representative programs under this process's ``XLA_FLAGS`` (one JSON line).

Does an XLA flag make the test suite's compiles cheaper? Each setting runs in a fresh process, so every
program is compiled from scratch (no compilation cache); the checksums show whether the results moved:

    for f in "" --xla_llvm_disable_expensive_passes=true --xla_cpu_copy_insertion_use_region_analysis=false; do
      XLA_FLAGS="--xla_backend_optimization_level=1 --xla_cpu_use_fusion_emitters=false $f" \
        python bench/investigations/compile_probe.py
    done

The programs: PPO training on Warehouse-8x8-v0, SAC on Continuous-Warehouse-8x8-v0, a batched random rware
rollout (tiny-4ag) and PPO on Procedural-Warehouse-v0, each tiny; per program the seconds to trace and lower,
to compile, and to run once more after a first call. Results: bench/results/test_suite/NOTES.md.
"""

from __future__ import annotations

import json
import os
import time

import jax
import numpy as np

import wrl_jax
from wrl_jax import training
from wrl_jax.agents.base import make_train_seeds
from wrl_jax.agents.off_policy_config import SACConfig
from wrl_jax.agents.ppo import PPO
from wrl_jax.agents.ppo_config import PPOConfig
from wrl_jax.agents.sac import SAC


def probe(fn, *args) -> dict:
    t0 = time.perf_counter()
    lowered = jax.jit(fn).lower(*args)
    t1 = time.perf_counter()
    compiled = lowered.compile()
    t2 = time.perf_counter()
    jax.block_until_ready(compiled(*args))
    t3 = time.perf_counter()
    result = jax.block_until_ready(compiled(*args))
    t4 = time.perf_counter()
    leaves = [np.asarray(x) for x in jax.tree_util.tree_leaves(result)
              if not jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)]
    checksum = float(sum(np.abs(leaf.astype(np.float64)).sum() for leaf in leaves))
    return {"lower": round(t1 - t0, 2), "compile": round(t2 - t1, 2), "run": round(t4 - t3, 3), "checksum": checksum}


def rware_rollout(env, params):
    def rollout(key):
        def one(key):
            _, state = env.reset(key, params)

            def body(state, key):
                action = jax.random.randint(key, (env.num_agents,), 0, 5)
                _, state, reward, *_ = env.step(key, state, action, params)
                return state, reward.sum()

            return jax.lax.scan(body, state, jax.random.split(key, 200))[1].sum()

        return jax.vmap(one)(jax.random.split(key, 64))

    return rollout


def main() -> None:
    out = {"xla_flags": os.environ.get("XLA_FLAGS", "")}
    env, params = wrl_jax.make("Warehouse-8x8-v0")
    ppo = PPO(PPOConfig(num_envs=16, num_steps=32, num_minibatches=4, update_epochs=2, hidden_sizes=(64, 64),
                        total_timesteps=16 * 32 * 20), env, params)
    out["ppo_8x8"] = probe(make_train_seeds(ppo), training.seed_keys([0, 1]))
    env, params = wrl_jax.make("Continuous-Warehouse-8x8-v0")
    sac = SAC(SACConfig(num_envs=8, total_timesteps=8 * 200, learning_starts=400, batch_size=64,
                        hidden_sizes=(64, 64), buffer_size=4000), env, params)
    out["sac_8x8"] = probe(make_train_seeds(sac), training.seed_keys([0, 1]))
    env, params = wrl_jax.make("rware-tiny-4ag-v2")
    out["rware_tiny_4ag"] = probe(rware_rollout(env, params), jax.random.key(0))
    env, params = wrl_jax.make("Procedural-Warehouse-v0", pool_size=64)
    ppo = PPO(PPOConfig(num_envs=16, num_steps=16, num_minibatches=2, update_epochs=1, hidden_sizes=(32,),
                        total_timesteps=16 * 16 * 5, obs_encoding="raw"), env, params)
    out["ppo_procedural"] = probe(make_train_seeds(ppo), training.seed_keys([0]))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
