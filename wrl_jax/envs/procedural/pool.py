"""Layout pools: pre-generated layouts held in params, so auto-reset never runs a generator.

The environment auto-resets on every step of every environment (a select
between the continued and a fresh episode), so whatever reset costs is paid
on every step. Generating a layout costs a few flood fills; drawing a slot of
a pool costs one random word and a gather. So the environment resets from a
:class:`LayoutPool` of ``pool_size`` layouts in its params, and a learner
refreshes the pool *between updates* with :func:`refresh_pool` (one jitted
call, amortized over a whole rollout). A running episode keeps a copy of its
layout in its state, so a refresh never changes the floor under a robot.

A pool also carries each layout's BFS optimum per item (``optimal``), so the
yardstick of an episode is a gather too.

Held-out layouts come from a key stream disjoint from training by
construction (:func:`stream_keys`: ``fold_in`` of a different tag), and the
disjointness of the *layouts* (two keys could still draw the same small
floor) is checked by hashing: :func:`disjoint_from`.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from wrl_jax.envs.procedural.generators import GeneratorConfig, generate_batch
from wrl_jax.envs.procedural.layout import PaddedLayout, hash_to_int, layout_hash, optimal_route_lengths, stack

STREAMS = {"train": 0, "heldout": 1}
"""Key-stream tags: every training key is ``fold_in(key, 0)``-derived, every held-out one ``fold_in(key, 1)``."""


@struct.dataclass
class LayoutPool:
    """``P`` layouts and their BFS optima.

    Attributes:
        layouts: a :class:`PaddedLayout` whose leaves have a leading ``(P,)`` axis.
        optimal: ``(P, I)`` int32, ``d(start, item) + d(item, goal)`` per item (BFS).
    """

    layouts: PaddedLayout
    optimal: jax.Array

    @property
    def size(self) -> int:
        return int(self.optimal.shape[0])


def pool_of(layouts: PaddedLayout) -> LayoutPool:
    """A pool of a batch of layouts, with their optima computed by the JAX BFS."""
    return LayoutPool(layouts=layouts, optimal=jax.vmap(optimal_route_lengths)(layouts))


def pool_from_layouts(layouts: Sequence[PaddedLayout], pool_size: int | None = None) -> LayoutPool:
    """A pool of given layouts (study maps, MovingAI maps), cycled to ``pool_size`` slots if given."""
    if not layouts:
        raise ValueError("pool_from_layouts needs at least one layout")
    pool_size = len(layouts) if pool_size is None else int(pool_size)
    if pool_size < 1:
        raise ValueError(f"pool_size must be positive, got {pool_size}")
    batch = stack([layouts[index % len(layouts)] for index in range(pool_size)])
    return jax.jit(pool_of)(batch)


def stream_keys(key: jax.Array, stream: str, count: int) -> jax.Array:
    """``count`` layout keys of a stream (``"train"`` or ``"heldout"``); the streams never share a key."""
    if stream not in STREAMS:
        raise ValueError(f"unknown key stream {stream!r}; expected one of {sorted(STREAMS)}")
    return jax.random.split(jax.random.fold_in(key, STREAMS[stream]), count)


def refresh_keys(key: jax.Array, update: jax.Array, count: int) -> jax.Array:
    """``count`` layout keys of the training refresh before update ``update`` (traced is fine).

    The training stream of ``key`` (:func:`stream_keys`'s root) folded with ``update + 1``: a
    refresh never redraws the initial pool's keys (``split`` of the root itself), nor another
    update's, and never the held-out stream's.
    """
    root = jax.random.fold_in(key, STREAMS["train"])
    return jax.random.split(jax.random.fold_in(root, jnp.asarray(update, jnp.uint32) + 1), count)


def refresh_slots(update: jax.Array, count: int, size: int) -> jax.Array:
    """The ``count`` pool slots the refresh before update ``update`` replaces: oldest first (a ring).

    Update ``u`` writes slots ``u * count .. u * count + count - 1`` modulo the pool size, so the
    whole pool is renewed every ``size / count`` updates and every layout stays for as long.
    """
    start = (jnp.asarray(update, jnp.int32) * count) % size
    return (start + jnp.arange(count, dtype=jnp.int32)) % size


@partial(jax.jit, static_argnames=("config",))
def pool_from_keys(keys: jax.Array, config: GeneratorConfig) -> LayoutPool:
    """One generated layout per key, with its optima (one compiled program per config and key count)."""
    return pool_of(generate_batch(keys, config))


def generate_pool(key: jax.Array, pool_size: int, config: GeneratorConfig, stream: str = "train") -> LayoutPool:
    """``pool_size`` fresh layouts from a stream of ``key`` (``"train"``, or ``"heldout"`` for evaluation).

    Check a held-out pool against what training saw with :func:`disjoint_from`.
    """
    return pool_from_keys(stream_keys(key, stream, pool_size), config)


def refresh_pool(key: jax.Array, pool: LayoutPool, config: GeneratorConfig, count: int | None = None) -> LayoutPool:
    """The pool with ``count`` slots (all by default) replaced by fresh layouts drawn from ``key``.

    Call it between updates, with a new key each time (e.g. ``fold_in(key,
    update)``), inside or outside ``jit``; ``count`` (static) smaller than the
    pool changes it gradually: a contiguous run of slots from a random offset,
    cyclically. Episodes in flight are unaffected: their state holds their own layout.
    """
    size = pool.size
    count = size if count is None else int(count)
    if not 1 <= count <= size:
        raise ValueError(f"count must be in 1..{size}, got {count}")
    key_offset, key_layouts = jax.random.split(key)
    fresh = generate_pool(key_layouts, count, config)
    if count == size:
        return fresh
    slots = (jax.random.randint(key_offset, (), 0, size) + jnp.arange(count)) % size
    return jax.tree.map(lambda old, new: old.at[slots].set(new), pool, fresh)


_batch_hash = jax.jit(jax.vmap(layout_hash))


def pool_hashes(pool: LayoutPool | PaddedLayout) -> np.ndarray:
    """``(P,)`` uint64 fingerprints of a pool's layouts, or of a batch of layouts (:func:`layout_hash`)."""
    layouts = pool.layouts if isinstance(pool, LayoutPool) else pool
    return hash_to_int(_batch_hash(layouts))


def disjoint_from(candidates: LayoutPool | PaddedLayout, seen: np.ndarray) -> np.ndarray:
    """``(P,)`` bool: the candidate layouts whose hash is not among ``seen`` (uint64 hashes of training)."""
    return ~np.isin(pool_hashes(candidates), np.asarray(seen, dtype=np.uint64))


def bytes_per_layout(pool: LayoutPool) -> dict[str, int]:
    """Memory of one pool slot by field (bytes), and the ``total``; no distance tables are kept.

    The optimum needs only two BFS fields (from the start and from the goal)
    at pool-building time; the pool keeps the ``I`` resulting numbers, not the
    ``2 H W`` distances, and the environment's shaping is Manhattan (SPEC.md).
    """
    fields = {f"layout.{name}": leaf for name, leaf in vars(pool.layouts).items()}
    fields["optimal"] = pool.optimal
    sizes = {name: int(np.asarray(leaf).nbytes) // pool.size for name, leaf in fields.items()}
    sizes["total"] = sum(sizes.values())
    return sizes
