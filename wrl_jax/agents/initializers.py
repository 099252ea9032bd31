"""Network initialisation without per-layer random calls or LAPACK: orthogonal kernels by Gram-Schmidt."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp


def init_mlp_params(key: jax.Array, networks: list[tuple[int, tuple[int, ...], int, float]]) -> list[dict]:
    """Parameters of several :class:`~wrl_jax.agents.networks.MLP` s, as ``MLP.init`` lays them out.

    Each network is ``(input_size, hidden_sizes, output_size, output_init_scale)``.
    Kernels are orthogonal (gain sqrt(2) on hidden layers, the given scale on the
    output), biases zero: the distribution of ``MLP.init``. Two differences, both
    for the 2-core CPU:

    - all the Gaussian draws come from one ``jax.random.normal`` call; one call
      per layer (as ``MLP.init`` does) makes XLA compile a copy of the threefry
      hash per layer, seconds of compile time;
    - the orthogonalization is Gram-Schmidt in plain XLA ops, not LAPACK's QR:
      under ``vmap`` over seeds, jaxlib 0.10.2 runs batched QR kernels on the
      intra-op thread pool, and two of them running at once (two layers) can
      deadlock a 2-thread pool for good.
    """
    shapes = []
    for input_size, hidden, output_size, output_scale in networks:
        widths = [input_size, *hidden, output_size]
        gains = [math.sqrt(2.0)] * len(hidden) + [output_scale]
        shapes.append([(a, b, g) for a, b, g in zip(widths[:-1], widths[1:], gains)])
    sizes = [a * b for layers in shapes for a, b, _ in layers]
    noise = jax.random.normal(key, (sum(sizes),), jnp.float32)
    out, offset = [], 0
    for layers in shapes:
        params = {}
        for layer, (a, b, gain) in enumerate(layers):
            gaussian = noise[offset : offset + a * b].reshape(max(a, b), min(a, b))
            offset += a * b
            q = orthonormal_columns(gaussian)
            kernel = q if a >= b else q.T
            params[f"Dense_{layer}"] = {"kernel": gain * kernel, "bias": jnp.zeros((b,), jnp.float32)}
        out.append({"params": params})
    return out


def orthonormal_columns(a: jax.Array) -> jax.Array:
    """The Q of ``a = QR`` with R's diagonal positive (``a``: rows >= cols), by Gram-Schmidt.

    Classical Gram-Schmidt applied twice per column ("CGS2"), which is as
    accurate as Householder QR for the well-conditioned Gaussian matrices of an
    initializer. For a Gaussian ``a``, Q is Haar-distributed (uniform over
    matrices with orthonormal columns), exactly what ``orthogonal`` initializers draw.
    """
    rows, cols = a.shape
    if rows < cols:
        raise ValueError(f"orthonormal_columns needs rows >= cols, got {a.shape}")
    column_index = jnp.arange(cols)

    def add_column(j, q):
        v = jax.lax.dynamic_index_in_dim(a, j, axis=1, keepdims=False)
        previous = q * (column_index < j)  # the columns already done
        for _ in range(2):
            v = v - previous @ (previous.T @ v)
        v = v / jnp.sqrt(jnp.sum(v * v))
        return jax.lax.dynamic_update_index_in_dim(q, v, j, axis=1)

    return jax.lax.fori_loop(0, cols, add_column, jnp.zeros_like(a))
