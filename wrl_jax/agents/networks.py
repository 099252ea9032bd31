"""The networks of both algorithms: a plain MLP, its FLOP count, and the machine's matmul peak.

PPO uses two of them (actor and critic), DQN one (the Q-network). Orthogonal
initialization with per-layer scales follows common PPO practice; a small
output scale makes a fresh policy near-uniform.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

ACTIVATIONS: dict[str, Callable[[jax.Array], jax.Array]] = {"relu": nn.relu, "tanh": nn.tanh}


class MLP(nn.Module):
    """Dense layers with an activation between them; no activation on the output.

    Attributes:
        hidden_sizes: widths of the hidden layers, e.g. ``(256, 256)``.
        output_size: width of the output layer (actions, or 1 for a value).
        activation: ``"relu"`` or ``"tanh"``.
        output_init_scale: orthogonal-init gain of the output layer.
    """

    hidden_sizes: Sequence[int]
    output_size: int
    activation: str = "relu"
    output_init_scale: float = 1.0

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"unknown activation {self.activation!r}; choose from {sorted(ACTIVATIONS)}")
        act = ACTIVATIONS[self.activation]
        for width in self.hidden_sizes:
            x = nn.Dense(width, kernel_init=nn.initializers.orthogonal(math.sqrt(2.0)))(x)
            x = act(x)
        return nn.Dense(self.output_size, kernel_init=nn.initializers.orthogonal(self.output_init_scale))(x)


def mlp_forward_flops(input_size: int, hidden_sizes: Sequence[int], output_size: int) -> int:
    """Floating-point operations of one forward pass for one sample (2 per multiply-add).

    A backward pass costs about twice this, so a gradient step on a batch of
    ``B`` samples costs about ``3 * B * mlp_forward_flops(...)``.
    """
    widths = [input_size, *hidden_sizes, output_size]
    return sum(2 * a * b for a, b in zip(widths[:-1], widths[1:]))


@functools.cache
def measured_matmul_peak_gflops(size: int | None = None, repeats: int = 5) -> float:
    """Float32 matmul throughput of JAX's default device, measured now (best of ``repeats``).

    The yardstick for "how close does training come to what this machine can
    do": a large square matmul is the fastest this machine runs the networks'
    arithmetic. Measured, not a constant, because the same code runs on CPUs
    whose peaks differ several times (about 180 GFLOP/s on the project's first
    2-core development CPU, about 475 on its AVX-512 successor), and measured
    in the same process as the run it is compared with, under the same load.
    ``size`` defaults to 1024 on a CPU (on the 2-core CPU measured, 221 GFLOP/s
    against 211 at 2048, for an eighth of the work: about 0.2 s) and 4096 on an accelerator
    (where a small matmul measures launch overhead, not the peak). Cached per process.
    """
    if size is None:
        size = 1024 if jax.default_backend() == "cpu" else 4096
    a = jnp.ones((size, size), jnp.float32)
    matmul = jax.jit(jnp.matmul)
    matmul(a, a).block_until_ready()
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        matmul(a, a).block_until_ready()
        best = min(best, time.perf_counter() - start)
    return 2 * size**3 / best / 1e9
