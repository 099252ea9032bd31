"""What PPO's propagation encoder costs, and what its two speed choices buy (wrl_jax/agents/propagation.py).

Why this exists: docs/procedural.md ("A policy that plans") claims that the hand-written backward pass
is many times cheaper than JAX's autodiff through the rounds, and that the rounds written as
concatenations on a bordered grid beat pads and slices under the XLA flags the training commands set.
This measures both, in one process, on the same inputs (compile time apart: one warm-up call each,
then the median of ``--repeats`` calls, every one ``block_until_ready``-ed):

* ``forward``: :func:`propagate` (concatenations) against the same rounds written with a pad and four
  slices per round, on ``--batch`` 16x16 maps;
* ``gradient``: the gradient in the costs of a weighted sum of the values, by :func:`propagate`'s custom
  backward pass against autodiff of the pad-and-slice loop (a scan that stores every round), on
  ``--grad-batch`` maps.

Run it twice to see both XLA settings (the commands' flags are not set here; pass them yourself)::

    XLA_FLAGS="--xla_backend_optimization_level=1 --xla_cpu_use_fusion_emitters=false" \\
        .venv/bin/python bench/propagation_speed.py --json bench/results/propagation_speed_commands.json
    .venv/bin/python bench/propagation_speed.py --json bench/results/propagation_speed_default.json
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from wrl_jax.agents import propagation  # noqa: E402


def pad_and_slice_rounds(cost: jax.Array, target: jax.Array, rounds: int) -> jax.Array:
    """The rounds written plainly: a pad and four slices per round (differentiable by autodiff)."""
    values = jnp.where(target > 0.5, 0.0, -propagation.BIG)

    def one_round(_, values):
        padded = jnp.pad(values, ((0, 0), (1, 1), (1, 1)), constant_values=-propagation.BIG)
        best = jnp.maximum(jnp.maximum(padded[:, :-2, 1:-1], padded[:, 2:, 1:-1]),
                           jnp.maximum(padded[:, 1:-1, :-2], padded[:, 1:-1, 2:]))
        return jnp.maximum(values, best - cost)

    return jax.lax.fori_loop(0, rounds, one_round, values)


def median_seconds(fn, *args, repeats: int) -> float:
    jax.block_until_ready(fn(*args))  # warm-up: compile
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--grad-batch", type=int, default=1024)
    parser.add_argument("--rounds", type=int, default=48)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    size = 16
    blocked = rng.random((args.batch, size, size)) < 0.25
    target = np.zeros((args.batch, size, size), np.float32)
    target[np.arange(args.batch), rng.integers(0, size, args.batch), rng.integers(0, size, args.batch)] = 1.0
    cost = jnp.asarray(rng.uniform(0.5, 2.0, blocked.shape) + 5.0 * blocked, jnp.float32)
    target = jnp.asarray(target)
    weights = jnp.asarray(rng.normal(size=blocked.shape), jnp.float32)
    rounds, g = args.rounds, args.grad_batch

    ours = jax.jit(lambda c, t: propagation.propagate(c, t, rounds))
    plain = jax.jit(lambda c, t: pad_and_slice_rounds(c, t, rounds))
    grad_ours = jax.jit(jax.grad(lambda c, t, w: (propagation.propagate(c, t, rounds) * w).sum()))
    grad_plain = jax.jit(jax.grad(lambda c, t, w: (pad_and_slice_rounds(c, t, rounds) * w).sum()))
    same = bool(jnp.array_equal(ours(cost, target), plain(cost, target)))
    grad_gap = float(jnp.abs(grad_ours(cost[:g], target[:g], weights[:g])
                             - grad_plain(cost[:g], target[:g], weights[:g])).max())

    result = {
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "batch": args.batch, "grad_batch": g, "rounds": rounds, "repeats": args.repeats,
        "forward_concat_s": median_seconds(ours, cost, target, repeats=args.repeats),
        "forward_pad_slice_s": median_seconds(plain, cost, target, repeats=args.repeats),
        "gradient_custom_s": median_seconds(grad_ours, cost[:g], target[:g], weights[:g], repeats=args.repeats),
        "gradient_autodiff_s": median_seconds(grad_plain, cost[:g], target[:g], weights[:g], repeats=args.repeats),
        "values_equal": same,
        "max_gradient_difference": grad_gap,
    }
    result["forward_pad_slice_over_concat"] = result["forward_pad_slice_s"] / result["forward_concat_s"]
    result["gradient_autodiff_over_custom"] = result["gradient_autodiff_s"] / result["gradient_custom_s"]
    print(json.dumps(result, indent=2))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
