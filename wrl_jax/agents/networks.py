"""The networks of both algorithms: a plain MLP, and its FLOP count.

PPO uses two of them (actor and critic), DQN one (the Q-network). Orthogonal
initialization with per-layer scales follows common PPO practice; a small
output scale makes a fresh policy near-uniform.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import flax.linen as nn
import jax

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


CPU_MATMUL_PEAK_GFLOPS = 180.0
"""Measured float32 matmul throughput of the 2-core development CPU (JAX 0.10.2,
a 2048x2048 and an 8192x256x256 matmul both reach about 180 GFLOP/s). The
yardstick for "how close is training to what this CPU can do"."""
