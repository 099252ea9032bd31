"""Training across devices: the runner state sharded with ``jax.sharding``.

The driver (:mod:`wrl_jax.training`) already trains a batch of seeds (and of
sweep points, :mod:`wrl_jax.sweep`) as one program whose runner-state leaves
have a leading seed axis. :class:`ShardedTrainer` lays that batch out on a 2-D
:class:`~jax.sharding.Mesh` of devices, axes ``("seeds", "envs")``:

- every runner leaf is split along its seed axis over the mesh's ``seeds`` axis
  with ``shard_map`` (independent seeds never talk to each other: no
  communication at all, and each device runs the unsharded program of its seeds);
- the per-seed environment batch (the leaves under ``env_state``, ``obs`` and
  ``episode_stats``, whose second axis is ``num_envs``) is additionally split
  over the ``envs`` axis. Everything else of a seed (network parameters,
  optimizer, replay buffer, key) is replicated along ``envs``; XLA's SPMD
  partitioner inserts the collectives the update needs (the gradient's sum over
  the batch becomes a cross-device all-reduce).

The chunk function is compiled once with these input *and output* shardings,
so the runner state never leaves its devices between chunks; the per-update
metrics and the in-loop evaluation are replicated (a few kilobytes per chunk)
so that every process can read them, which is what makes a multi-host run
work unchanged (:func:`initialize_distributed`).

Results. With the seed axis split, every device runs the unsharded program
of its share of the seeds (``shard_map``), so a batch of ``S`` seeds on ``D``
devices computes what ``D`` single-device batches of ``S / D`` seeds compute:
bit for bit for PPO (tested with 2 CPU devices), and for DQN the same
trajectories with parameters equal to float32 rounding (the per-device program
is compiled as part of a ``D``-device module, and XLA's fusion choices there,
such as forming a fused multiply-add, can differ by an ulp). Compared with one
batch of ``S`` on one device, results agree to float32 rounding: XLA on CPU may
pick a different reduction kernel for a different batch shape (true without
sharding too). Sharding the environment axis splits sums over a seed's batch
(losses, gradients) into per-device partial sums added by an all-reduce, another
order of float additions: again equal to float32 rounding, not bit for bit.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from wrl_jax.agents.base import Algorithm
from wrl_jax.training import driver as training

SEED_AXIS = "seeds"
"""Mesh axis over which seeds (and sweep points) are split."""
ENV_AXIS = "envs"
"""Mesh axis over which each seed's environments are split."""
ENV_FIELDS = ("env_state", "obs", "episode_stats")
"""Runner fields whose second axis is the environment batch (``num_envs``)."""


def make_mesh(devices: int | None = None, env_shards: int = 1, device_list: Sequence[Any] | None = None) -> Mesh:
    """A ``(seeds, envs)`` mesh over ``devices`` devices (``None`` or 0: all of them, every host's).

    ``env_shards`` of them split each seed's environments; the other factor,
    ``devices // env_shards``, splits the seeds.
    """
    available = list(jax.devices() if device_list is None else device_list)
    count = len(available) if devices in (None, 0) else int(devices)
    if count < 1:
        raise ValueError(f"devices must be a positive number (0: all), got {devices}")
    if count > len(available):
        raise ValueError(
            f"devices={count} but only {len(available)} {available[0].platform} device(s) are available "
            "(on CPU, XLA_FLAGS=--xla_force_host_platform_device_count=N makes N; multi-host: see docs/scale.md)"
        )
    if int(env_shards) < 1 or count % int(env_shards):
        raise ValueError(f"env_shards={env_shards} must be a positive divisor of the device count {count}")
    grid = np.array(available[:count], dtype=object).reshape(count // int(env_shards), int(env_shards))
    return Mesh(grid, (SEED_AXIS, ENV_AXIS))


def runner_specs(template: Any, num_envs: int | None) -> Any:
    """The :class:`PartitionSpec` of every runner leaf (``template``: batched shapes, leading seed axis)."""

    def spec(path, leaf) -> P:
        top = path[0]
        name = getattr(top, "name", getattr(top, "key", None))
        if num_envs is not None and name in ENV_FIELDS and len(leaf.shape) >= 2 and leaf.shape[1] == num_envs:
            return P(SEED_AXIS, ENV_AXIS)
        return P(SEED_AXIS)

    return jax.tree_util.tree_map_with_path(spec, template)


def check_layout(num_seeds: int, num_envs: int | None, mesh: Mesh) -> None:
    """Raise ``ValueError`` unless the seed and environment batches split evenly over the mesh."""
    seed_shards, env_shards = mesh.shape[SEED_AXIS], mesh.shape[ENV_AXIS]
    if num_seeds % seed_shards:
        raise ValueError(
            f"{num_seeds} seeds (x sweep points) do not split evenly over {seed_shards} devices on the seed axis: "
            f"use a multiple of {seed_shards} seeds, or fewer devices"
        )
    if env_shards > 1:
        if num_envs is None:
            raise ValueError("this algorithm has no num_envs: its environments cannot be sharded (env_shards=1)")
        if num_envs % env_shards:
            raise ValueError(
                f"num_envs={num_envs} does not split evenly over env_shards={env_shards} devices"
            )


def _to_host(tree: Any) -> Any:
    """Plain NumPy copies of a pytree's leaves (the same global value on every process)."""
    return jax.tree.map(lambda x: None if x is None else np.asarray(jax.device_get(x)), tree)


def _is_placed(tree: Any, shardings: Any) -> bool:
    leaves = jax.tree_util.tree_leaves(tree)
    targets = jax.tree_util.tree_leaves(shardings)
    return len(leaves) == len(targets) and all(
        isinstance(x, jax.Array) and x.sharding == s for x, s in zip(leaves, targets)
    )


class ShardedTrainer(training.Trainer):
    """A :class:`~wrl_jax.training.Trainer` whose batched runner state lives on a device mesh.

    Drop-in: ``training.run(ShardedTrainer(algo, seeds, loop, mesh), ...)``
    behaves like the unsharded trainer (same metrics rows, checkpoints, resume).

    Args:
        algo, seeds, loop: as for :class:`~wrl_jax.training.Trainer`.
        mesh: from :func:`make_mesh` (default: every device on the seed axis).
    """

    def __init__(
        self,
        algo: Algorithm,
        seeds: Sequence[int],
        loop: training.LoopConfig | None = None,
        mesh: Mesh | None = None,
    ):
        super().__init__(algo, seeds, loop)
        self.mesh = make_mesh() if mesh is None else mesh
        self.num_envs = getattr(algo.config, "num_envs", None)
        check_layout(len(self.seeds), self.num_envs, self.mesh)
        template = jax.eval_shape(lambda: training.Trainer.init(self))
        self.specs = runner_specs(template, self.num_envs)
        self.runner_shardings = jax.tree.map(lambda spec: NamedSharding(self.mesh, spec), self.specs)
        self.replicated = NamedSharding(self.mesh, P())
        self._sharded_init_jits: dict[tuple[bool, bool], Any] = {}
        # The seed axis is split *manually* (shard_map): every device runs the program
        # of an unsharded batch of its seeds, so the results are those of
        # len(seeds) / devices-sized batches trained apart (bit for bit for PPO; to
        # an ulp for DQN, see the module docstring). The
        # environment axis stays *automatic*: XLA's SPMD partitioner splits each
        # device's environment batch further and adds the collectives. Inputs and
        # outputs are pinned to the same layout, so the state stays put between
        # chunks and the compiled program is reused for every chunk.
        seeds_spec = P(SEED_AXIS)
        latest_specs = training.LatestEval(update=P(), episodes=seeds_spec)
        chunk = self._per_device(
            self._chunk,
            in_specs=(seeds_spec, P(), latest_specs),
            out_specs=(seeds_spec, P(None, SEED_AXIS), latest_specs),
        )
        self._chunk_jit = jax.jit(
            chunk,
            in_shardings=(self.runner_shardings, self.replicated, self.replicated),
            out_shardings=(self.runner_shardings, self.replicated, self.replicated),
        )
        evaluate = self._per_device(self._evaluate, in_specs=(seeds_spec,), out_specs=seeds_spec)
        self._eval_jit = jax.jit(evaluate, in_shardings=(self.runner_shardings,), out_shardings=self.replicated)

    def _per_device(self, fn, in_specs, out_specs):
        """``fn`` run on each device's slice of the seed axis (other mesh axes left to XLA)."""
        return jax.shard_map(
            fn,
            mesh=self.mesh,
            in_specs=in_specs,
            out_specs=out_specs,
            axis_names=frozenset({SEED_AXIS}),
            check_vma=False,
        )

    # ------------------------------------------------------------ placement
    def init(self, hyper: Any = None, env_params: Any = None) -> Any:
        """Batched runner state created directly in its sharded layout (never whole on one device)."""
        batched = (hyper is not None, env_params is not None)
        if batched not in self._sharded_init_jits:  # one per batching (the driver's own serve the templates)
            in_axes = (0, 0 if batched[0] else None, 0 if batched[1] else None)
            self._sharded_init_jits[batched] = jax.jit(
                jax.vmap(self.algo.init, in_axes=in_axes), in_shardings=self.replicated,
                out_shardings=self.runner_shardings)
        # Host values are the same global value on every process (multi-host safe).
        keys = training.seed_keys(self.seeds)
        return self._sharded_init_jits[batched](_to_host(keys), _to_host(hyper), _to_host(env_params))

    def template(self, hyper: Any = None, env_params: Any = None) -> Any:
        return jax.eval_shape(lambda h, e: training.Trainer.init(self, h, e), hyper, env_params)

    def place(self, runners: Any) -> Any:
        """``runners`` (e.g. loaded from a checkpoint as NumPy) in the trainer's sharded layout."""
        if _is_placed(runners, self.runner_shardings):
            return runners

        def put(x, sharding):
            host = np.asarray(jax.device_get(x))
            return jax.make_array_from_callback(host.shape, sharding, lambda index: host[index])

        return jax.tree.map(put, runners, self.runner_shardings)

    def empty_eval(self, runners: Any) -> training.LatestEval:
        empty = super().empty_eval(runners)
        return jax.tree.map(lambda x: self._replicate(np.asarray(x)), empty)

    def _replicate(self, host: np.ndarray) -> jax.Array:
        return jax.make_array_from_callback(host.shape, self.replicated, lambda index: host[index])

    # ------------------------------------------------------- driver overrides
    def compile(self, runners: Any, latest: training.LatestEval | None = None) -> float:
        return super().compile(self.place(runners), latest)

    def run_chunk(self, runners: Any, start: int, latest: training.LatestEval | None = None):
        return super().run_chunk(self.place(runners), start, latest)

    def evaluate(self, runners: Any):
        return self._eval_jit(self.place(runners))

    def host_state(self, runners: Any) -> Any:
        """The runner state as host arrays on every process (checkpoints); a collective on multi-host."""
        if all(getattr(x, "is_fully_addressable", True) for x in jax.tree_util.tree_leaves(runners)):
            return runners
        from jax.experimental import multihost_utils

        return multihost_utils.process_allgather(runners, tiled=True)


def initialize_distributed(
    coordinator_address: str | None = None, num_processes: int | None = None, process_id: int | None = None
) -> None:
    """``jax.distributed.initialize`` for a multi-host run (a no-op when it already ran).

    Every process runs the same command with its own ``process_id`` (0 ..
    ``num_processes - 1``); process 0's host runs the coordinator at
    ``coordinator_address`` (``host:port``). Unset arguments are read from
    ``WRL_COORDINATOR``, ``WRL_NUM_PROCESSES`` and ``WRL_PROCESS_ID``, then left
    to JAX's cluster auto-detection (SLURM, Open MPI, TPU pods...). It must run
    before anything touches JAX's backend, which making an environment already does:
    the command lines therefore run it when ``wrl_jax`` is imported
    (:mod:`wrl_jax._distributed`; ``--distributed`` or ``WRL_DISTRIBUTED=1``).
    """
    from wrl_jax import _distributed

    _distributed.initialize(coordinator_address, num_processes, process_id)


def describe(mesh: Mesh) -> str:
    """One line naming the mesh, e.g. ``2 cpu devices: seeds x2, envs x1 (1 process)``."""
    devices = mesh.devices.reshape(-1)
    return (
        f"{devices.size} {devices[0].platform} devices: {SEED_AXIS} x{mesh.shape[SEED_AXIS]}, "
        f"{ENV_AXIS} x{mesh.shape[ENV_AXIS]} ({jax.process_count()} process(es))"
    )


__all__ = [
    "ENV_AXIS",
    "SEED_AXIS",
    "ShardedTrainer",
    "check_layout",
    "describe",
    "initialize_distributed",
    "make_mesh",
    "runner_specs",
]
