"""Where SAC's (or TD3's) compiled training loop spends its time: the XLA instructions of a trace (issue 34).

The speed aims against SB3 and sbx ask how close the learner runs to the machine's matmul peak. This
builds the learner with its default config on the 12x12 map's default view, starts learning after 512
steps (so that the traced call is mostly gradient steps), runs ``--updates`` updates of 2 seeds in one
program, traces it (``bench/xla_trace.py``) and prints the top instructions by time and the share of the
matrix products (XLA's ``dot`` and its YNNPACK fusions, with their transposes) against everything else.

    python bench/investigations/off_policy_update_trace.py

(about a minute, with the XLA flags the training commands set). Recorded in bench/results/continuous/NOTES.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import jax

import wrl_jax
from wrl_jax import training
from wrl_jax.agents.base import make_train_seeds
from wrl_jax.agents.off_policy_config import OFF_POLICY_ENV_DEFAULTS, SAC_DEFAULT, TD3_DEFAULT
from wrl_jax.agents.sac import SAC
from wrl_jax.agents.td3 import TD3
from wrl_jax.cli.machine import DEFAULT_XLA_OPT_LEVEL, apply_xla_opt_level

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from xla_trace import fusion_shares  # noqa: E402  (bench/ is not a package)

LEARNERS = {"sac": (SAC, SAC_DEFAULT), "td3": (TD3, TD3_DEFAULT)}
MATMUL_OPS = ("dot_general", "transpose")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--algo", choices=sorted(LEARNERS), default="sac")
    parser.add_argument("--env", default="Continuous-Warehouse-12x12-v0")
    parser.add_argument("--updates", type=int, default=400, help="updates per seed in the traced program")
    parser.add_argument("--top", type=int, default=20)
    args = parser.parse_args()
    apply_xla_opt_level(DEFAULT_XLA_OPT_LEVEL)  # before JAX starts its backend, as train_sac.py does
    algo_cls, default = LEARNERS[args.algo]
    env, params = wrl_jax.make(args.env, **OFF_POLICY_ENV_DEFAULTS[args.env])
    config = dataclasses.replace(default, learning_starts=512, total_timesteps=default.num_envs * args.updates)
    algo = algo_cls(config, env, params)
    keys = training.seed_keys([0, 1])
    compiled = jax.jit(make_train_seeds(algo)).lower(keys).compile()
    rows = fusion_shares(compiled, lambda: compiled(keys), calls=2, top=10_000)
    for row in rows[:args.top]:
        print(f"{row['share']:6.1%}  {row['name'][:36]:36s} {row['shape'][:32]:32s} {row['op'][:50]}")
    matmul = sum(row["share"] for row in rows if row["op"] in MATMUL_OPS or row["name"].startswith(("dot", "ynn")))
    print(f"matrix products and their transposes: {matmul:.1%} of the traced time; the rest {1 - matmul:.1%} "
          f"over {len(rows)} instructions")


if __name__ == "__main__":
    main()
