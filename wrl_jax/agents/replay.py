"""A replay buffer written in JAX: fixed-size circular arrays in the training carry.

DQN, SAC and TD3 learn from transitions they stored earlier. Here the store is a pytree of
preallocated arrays (``capacity`` rows each) plus a write position and a fill
count, so it lives inside the compiled training loop like any other state:
``add`` writes a batch of transitions (one per environment, per vector step)
at the write position, wrapping around and overwriting the oldest rows once
full; ``sample`` draws row indices uniformly, with replacement, from the
filled part. Both are pure functions, ``jit``/``vmap``/``scan`` friendly, and
a checkpoint of the runner state holds the buffer, so resuming is exact.

``next_obs`` of a transition that ended its episode must be the observation
the transition reached (the environment's ``info["final_obs"]``), not the
first observation of the next episode: a truncated episode is bootstrapped
from it, and only ``terminated`` stops the bootstrap.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class Transition:
    """A batch of transitions (leading axis: the batch).

    Attributes:
        obs: ``(B, obs_size)`` float32, the observation the action was taken in.
        action: ``(B,)`` int32 (a discrete action) or ``(B, A)`` float32 (a point of a box).
        reward: ``(B,)`` float32.
        next_obs: ``(B, obs_size)`` float32, the observation the transition reached
            (before any automatic reset).
        terminated: ``(B,)`` bool, True where the episode ended in a terminal state
            (no bootstrap). A truncation is *not* a termination.
        truncated: ``(B,)`` bool where the episode was cut off, or ``None`` (not stored): what
            n-step returns need to stop at an episode's end (:func:`n_step_sample`).
    """

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    next_obs: jax.Array
    terminated: jax.Array
    truncated: jax.Array | None = None


@struct.dataclass
class ReplayBuffer:
    """Circular storage of ``capacity`` transitions.

    Attributes:
        data: a :class:`Transition` whose arrays have ``capacity`` rows.
        position: int32, the row the next transition is written to.
        size: int32, how many rows hold transitions (grows to ``capacity``).
    """

    data: Transition
    position: jax.Array
    size: jax.Array

    @property
    def capacity(self) -> int:
        """Rows of storage (static: an array shape)."""
        return self.data.reward.shape[-1]

    @classmethod
    def empty(cls, capacity: int, obs_size: int, action_size: int | None = None,
              truncation: bool = False) -> "ReplayBuffer":
        """A buffer of ``capacity`` zeroed rows, none of them filled.

        ``action_size=None`` stores discrete actions (int32 indices); an integer
        stores continuous ones (float32 vectors of that length). ``truncation``
        also stores the ``truncated`` flags (for n-step returns).
        """
        if int(capacity) < 1:
            raise ValueError(f"replay buffer capacity must be a positive integer, got {capacity}")
        if int(obs_size) < 1:
            raise ValueError(f"observation size must be a positive integer, got {obs_size}")
        capacity, obs_size = int(capacity), int(obs_size)
        if action_size is None:
            action = jnp.zeros((capacity,), jnp.int32)
        elif int(action_size) < 1:
            raise ValueError(f"action size must be a positive integer, got {action_size}")
        else:
            action = jnp.zeros((capacity, int(action_size)), jnp.float32)
        data = Transition(
            obs=jnp.zeros((capacity, obs_size), jnp.float32),
            action=action,
            reward=jnp.zeros((capacity,), jnp.float32),
            next_obs=jnp.zeros((capacity, obs_size), jnp.float32),
            terminated=jnp.zeros((capacity,), bool),
            truncated=jnp.zeros((capacity,), bool) if truncation else None,
        )
        return cls(data=data, position=jnp.zeros((), jnp.int32), size=jnp.zeros((), jnp.int32))

    def add(self, batch: Transition) -> "ReplayBuffer":
        """Write a batch of ``n`` transitions, oldest rows overwritten once full.

        Row ``i`` of the batch goes to ``(position + i) % capacity``. The batch
        must not be larger than the buffer (it would overwrite itself).
        """
        n = batch.reward.shape[0]
        capacity = self.capacity
        if n > capacity:
            raise ValueError(f"cannot add {n} transitions at once to a replay buffer of capacity {capacity}")
        # A scatter to explicit rows handles every batch size and any write
        # position; under vmap a slice write with a per-seed position would
        # become a scatter anyway.
        rows = (self.position + jnp.arange(n, dtype=jnp.int32)) % capacity
        data = jax.tree.map(lambda store, new: store.at[rows].set(new.astype(store.dtype)), self.data, batch)
        return ReplayBuffer(
            data=data,
            position=(self.position + n) % capacity,
            size=jnp.minimum(self.size + n, capacity),
        )

    def sample(self, key: jax.Array, batch_size: int) -> Transition:
        """``batch_size`` transitions drawn uniformly, with replacement, from the filled rows.

        Rows are random 32-bit words modulo the fill count: for buffers far
        smaller than 2**32 the bias is below ``size / 2**32`` (2e-5 for 100,000
        rows), and one draw compiles much faster than ``jax.random.randint``.
        The buffer must hold at least one transition; an empty one yields row 0.
        """
        bits = jax.random.bits(key, (batch_size,), jnp.uint32)
        rows = (bits % jnp.maximum(self.size, 1).astype(jnp.uint32)).astype(jnp.int32)
        return jax.tree.map(lambda store: store[rows], self.data)


def n_step_sample(buffer: ReplayBuffer, key: jax.Array, batch_size: int, n: int, stride: int,
                  gamma: jax.Array) -> tuple[Transition, jax.Array]:
    """Uniform rows, each extended to an n-step transition: ``(batch, discount)``.

    Rows are written ``stride`` (the number of environments) at a time, so row ``r + k stride`` is
    the same environment's ``k``-th next transition. From a sampled row the rewards of up to ``n``
    transitions are summed, discounted, stopping after the first that ended its episode
    (terminated or truncated) and before any row not yet written; ``next_obs`` and ``terminated``
    are the last one's, and ``discount`` is ``gamma ** steps`` for the bootstrap. With ``n = 1``
    this is :meth:`ReplayBuffer.sample` with ``discount = gamma``. The buffer must store
    ``truncated`` (``ReplayBuffer.empty(..., truncation=True)``).
    """
    if buffer.data.truncated is None:
        raise ValueError("n-step returns need a buffer that stores truncations: ReplayBuffer.empty(..., truncation=True)")
    capacity = buffer.capacity
    bits = jax.random.bits(key, (batch_size,), jnp.uint32)
    rows = (bits % jnp.maximum(buffer.size, 1).astype(jnp.uint32)).astype(jnp.int32)
    newer = (buffer.position - 1 - rows) % capacity  # rows written after each sampled row
    data = buffer.data
    first = jax.tree.map(lambda store: store[rows], data)
    ended = first.terminated | first.truncated
    total, discount, last = first.reward, jnp.full((batch_size,), 1.0, jnp.float32) * gamma, first
    for k in range(1, n):
        later = (rows + k * stride) % capacity
        take = ~ended & (k * stride <= newer)
        step = jax.tree.map(lambda store: store[later], data)
        total = total + jnp.where(take, discount * step.reward, 0.0)
        discount = jnp.where(take, discount * gamma, discount)
        last = jax.tree.map(lambda new, old: jnp.where(take.reshape(-1, *([1] * (new.ndim - 1))), new, old), step, last)
        ended = ended | (take & (step.terminated | step.truncated))
    batch = Transition(obs=first.obs, action=first.action, reward=total, next_obs=last.next_obs,
                       terminated=last.terminated, truncated=last.truncated)
    return batch, discount
