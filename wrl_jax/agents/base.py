"""The contract between an RL algorithm and the shared training driver.

An :class:`Algorithm` describes *one seed* of training as two pure functions,
``init`` and ``update``. The driver (``wrl_jax.training``) ``vmap``s them over
seeds (and sweep points), ``lax.scan``s ``update`` over a chunk of updates in
one compiled program, and between chunks reports progress, writes metrics and
checkpoints. Because all of an algorithm's mutable state is one pytree (its
runner state), a checkpoint is that pytree, and resuming is exact.

Hyperparameters that a sweep may vary (learning rate, entropy coefficient,
epsilon schedule, the environment's reward constants...) are *traced*: they
live in the runner state (``runner.hyper`` and ``runner.env_params``), never as
Python constants inside ``update``. Only what fixes array shapes (network
width, number of environments, rollout length) is static, on the config.
"""

from __future__ import annotations

import abc
import dataclasses
import json
import typing
from collections.abc import Callable, Mapping
from typing import Any, ClassVar, Generic, TypeVar

import jax
import jax.numpy as jnp
from flax import struct

from wrl_jax.core.environment import Environment
from wrl_jax.core.gymnax_base import spaces

RunnerT = TypeVar("RunnerT")


def observation_size(env: Environment) -> int:
    """Width of one flat observation, from the environment's gymnax observation space."""
    shape = env.observation_space().shape
    size = 1
    for dim in shape:
        size *= int(dim)
    return size

Metrics = dict[str, jax.Array]


class Algorithm(abc.ABC, Generic[RunnerT]):
    """One seed of an RL algorithm, as pure functions the driver composes.

    Subclasses set ``name`` and take ``(config, env, env_params)``.
    """

    name: ClassVar[str]

    action_kind: str = "discrete"
    """The actions it emits: ``"discrete"`` (an index per agent) or ``"continuous"`` (a vector in a box)."""

    def __init__(self, config: Any, env: Environment, env_params: Any):
        config.validate()  # every algorithm, the same way: a ValueError naming the field, before anything compiles
        continuous = isinstance(env.action_space(env_params), spaces.Box)
        if continuous != (self.action_kind == "continuous"):
            raise ValueError(f"{type(self).__name__} acts in a {self.action_kind} action space; {env.name} takes "
                             f"{'continuous' if continuous else 'discrete'} actions")
        self.config = config
        self.env = env
        self.env_params = env_params

    @property
    @abc.abstractmethod
    def num_updates(self) -> int:
        """Updates in a full training run (``total_timesteps // steps_per_update``)."""

    @property
    @abc.abstractmethod
    def steps_per_update(self) -> int:
        """Environment transitions one update collects, for one seed."""

    @abc.abstractmethod
    def init(self, key: jax.Array, hyper: Any | None = None, env_params: Any | None = None) -> RunnerT:
        """The runner state of one seed before training.

        ``hyper`` (the algorithm's traced hyperparameters) and ``env_params``
        default to the config's and the constructor's; a sweep passes batched
        ones under ``vmap``.
        """

    @abc.abstractmethod
    def update(self, runner: RunnerT, update_index: jax.Array) -> tuple[RunnerT, Metrics]:
        """One update of one seed: collect ``steps_per_update`` transitions and learn.

        ``update_index`` is the same for every seed (the driver does not batch
        it), so schedules keyed on it stay cheap under ``vmap``. Metrics are
        float32 scalars; episode counts come as sums (see :class:`EpisodeSums`)
        so chunks aggregate exactly.
        """

    @abc.abstractmethod
    def network_params(self, runner: RunnerT) -> Any:
        """The parameters the greedy policy needs (what evaluation loads)."""

    @abc.abstractmethod
    def greedy_action(self, network_params: Any, obs: jax.Array) -> jax.Array:
        """The deterministic action for one observation (argmax Q, or the policy's mode)."""

    has_stochastic_policy: ClassVar[bool] = False
    """Whether :meth:`sample_action` is defined (a policy-gradient method's sampled policy)."""

    def sample_action(self, network_params: Any, obs: jax.Array, key: jax.Array) -> jax.Array:
        """An action drawn from the learned policy for ``obs`` (only where :attr:`has_stochastic_policy`)."""
        raise NotImplementedError(f"{self.name} has no stochastic policy to sample")

    def policy_memory(self) -> Any:
        """A :class:`~wrl_jax.core.evaluation.PolicyMemory` where the policy is cheaper with memory across
        steps (evaluations then run it on the whole batch), else ``None`` (the default)."""
        return None

    def flops_per_update(self) -> int | None:
        """Floating-point operations one update of one seed costs (network passes), if known.

        Optional: the CLI divides it by the measured time to report achieved
        GFLOP/s against ``networks.measured_matmul_peak_gflops()``.
        """
        return None


@dataclasses.dataclass(frozen=True)
class AlgoSpec:
    """How the shared CLI (``wrl_jax.cli``) and ``python -m wrl_jax.evaluate`` find an algorithm.

    Each algorithm module defines one as ``SPEC``; ``wrl_jax.agents.ALGORITHM_MODULES``
    maps the algorithm's name to that module.

    Attributes:
        name: ``"ppo"``, ``"dqn"``: also the checkpoint's ``algo`` field.
        config_cls: the config dataclass; every field becomes a CLI flag. It must
            provide ``validate()`` (raising ``ValueError``) and a
            ``total_timesteps`` field.
        algorithm_cls: ``algorithm_cls(config, env, env_params)``.
        presets: preset name -> config instance (``--preset``).
        default_env: environment the command trains on by default.
        default_preset: preset used without ``--preset``.
        default_num_seeds: seeds trained at once by default.
        study: the study's Table 3 column for this algorithm (metric -> text), shown beside ours.
        env_presets: environment name -> the preset used for it without ``--preset``
            (an environment family with its own default, e.g. the procedural warehouse).
        family_presets: environment family -> the preset of its environments that ``env_presets``
            does not name (every ``rware-*`` id: ``"rware"``).
        env_defaults: environment name -> environment overrides a training command
            applies unless its flags say otherwise (the fleet trains with a larger
            block penalty than FLEET_SPEC.md's default); recorded in the run's
            ``env_overrides`` like any flag.
        preset_env_defaults: preset name -> environment name -> overrides that preset needs there, applied
            over ``env_defaults`` (the procedural planning preset reads the map, its MLP sibling does not).
    """

    name: str
    config_cls: type
    algorithm_cls: type[Algorithm]
    presets: Mapping[str, Any]
    default_env: str
    default_preset: str = "default"
    default_num_seeds: int = 4
    study: Mapping[str, str] | None = None
    env_presets: Mapping[str, str] = dataclasses.field(default_factory=dict)
    family_presets: Mapping[str, str] = dataclasses.field(default_factory=dict)
    env_defaults: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict)
    preset_env_defaults: Mapping[str, Mapping[str, Mapping[str, Any]]] = dataclasses.field(default_factory=dict)

    def preset_for(self, env_name: str) -> str:
        """The preset a command uses on ``env_name`` when ``--preset`` is not given."""
        from wrl_jax.core import registry

        name = env_name.removeprefix(registry.GYMNAX_PREFIX)
        if name in self.env_presets:
            return self.env_presets[name]
        try:
            family = registry.entry(name).family
        except (KeyError, ValueError):
            return self.default_preset  # an unknown name: the command's own check reports it
        return self.family_presets.get(family, self.default_preset)

    def env_defaults_for(self, env_name: str, preset: str | None = None) -> dict[str, Any]:
        """The environment overrides a command applies on ``env_name`` with ``preset`` (default: the
        environment's own preset) unless its flags change them."""
        from wrl_jax.core import registry

        preset = self.preset_for(env_name) if preset is None else preset
        name = env_name.removeprefix(registry.GYMNAX_PREFIX)
        return {**self.env_defaults.get(name, {}), **self.preset_env_defaults.get(preset, {}).get(name, {})}


@struct.dataclass
class EpisodeStats:
    """Running return and length of each environment's current episode."""

    episode_return: jax.Array  # (num_envs,) float32
    episode_length: jax.Array  # (num_envs,) int32

    @classmethod
    def zeros(cls, num_envs: int) -> "EpisodeStats":
        return cls(jnp.zeros((num_envs,), jnp.float32), jnp.zeros((num_envs,), jnp.int32))


@struct.dataclass
class EpisodeSums:
    """Sums over the episodes that ended within some transitions.

    ``mean return = return_sum / episodes``; ``terminated`` counts the episodes that ended by
    termination (the task done) rather than truncation: a family's
    :class:`~wrl_jax.core.evaluation.TrainRate` turns it into a rate (the warehouse's delivery rate).
    """

    episodes: jax.Array
    terminated: jax.Array
    return_sum: jax.Array
    length_sum: jax.Array

    def as_metrics(self) -> Metrics:
        return {
            "episodes": self.episodes,
            "terminated": self.terminated,
            "return_sum": self.return_sum,
            "length_sum": self.length_sum,
        }


def track_episodes(
    stats: EpisodeStats, reward: jax.Array, terminated: jax.Array, truncated: jax.Array
) -> tuple[EpisodeStats, EpisodeSums]:
    """Advance the running episode statistics by one batched transition.

    Returns the new running stats (zeroed where an episode ended) and the sums
    over the episodes that ended on this transition.
    """
    episode_return = stats.episode_return + reward
    episode_length = stats.episode_length + 1
    done = terminated | truncated
    sums = EpisodeSums(
        episodes=done.sum().astype(jnp.float32),
        terminated=terminated.sum().astype(jnp.float32),
        return_sum=jnp.where(done, episode_return, 0.0).sum(),
        length_sum=jnp.where(done, episode_length, 0).sum().astype(jnp.float32),
    )
    new_stats = EpisodeStats(
        episode_return=jnp.where(done, 0.0, episode_return),
        episode_length=jnp.where(done, 0, episode_length),
    )
    return new_stats, sums


def sum_episode_sums(sums: EpisodeSums) -> EpisodeSums:
    """Collapse a leading (time) axis of stacked :class:`EpisodeSums`."""
    return jax.tree.map(lambda x: x.sum(axis=0), sums)


# ------------------------------------------------------------ PureJaxRL shape
def make_train(algo: Algorithm, num_updates: int | None = None) -> Callable[..., tuple[Any, dict]]:
    """``train(key, hyper=None, env_params=None) -> (runner, metrics)`` for one seed.

    ``init`` then ``lax.scan`` of ``update`` over ``num_updates`` updates (the
    algorithm's full run by default). ``metrics`` leaves have a leading update
    axis. Pure: ``jax.jit`` it, or ``jax.vmap`` it over keys (:func:`make_train_seeds`)
    and over traced hyperparameters for a sweep.

    The initial runner passes through an optimization barrier: without it XLA
    fuses the initialisation arithmetic into the first update, and on CPUs
    with FMA/AVX-512 the contracted multiply-adds round differently from the
    chunked driver (which initialises in its own program), so the two would
    differ in the last bits. With it, PPO's one program equals the driver bit
    for bit (``tests/training/test_training.py``); the off-policy learners' two
    programs still fuse differently and agree to float rounding (about 1e-7).
    """
    num_updates = algo.num_updates if num_updates is None else int(num_updates)

    def train(key: jax.Array, hyper: Any = None, env_params: Any = None):
        runner = jax.lax.optimization_barrier(algo.init(key, hyper, env_params))
        return jax.lax.scan(algo.update, runner, jnp.arange(num_updates, dtype=jnp.int32))

    return train


def make_train_seeds(algo: Algorithm, num_updates: int | None = None) -> Callable[[jax.Array], tuple[Any, dict]]:
    """:func:`make_train` ``vmap``-ped over a batch of keys (one per seed); the update index stays unbatched."""
    return jax.vmap(make_train(algo, num_updates))


# ------------------------------------------------------ configs as JSON data
def config_to_dict(config: Any) -> dict[str, Any]:
    """A config dataclass as JSON-able data (tuples become lists)."""
    return json.loads(json.dumps(dataclasses.asdict(config)))


def config_from_dict(cls: type, data: dict[str, Any]) -> Any:
    """Rebuild a config dataclass from :func:`config_to_dict`'s output (lists back to tuples)."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ValueError(f"{cls.__name__} has no field(s) {unknown}")
    values = {}
    for name, value in data.items():
        if isinstance(value, list) and typing.get_origin(hints[name]) is tuple:
            value = tuple(value)
        values[name] = value
    return cls(**values)
