"""What SAC and TD3 share: the runner, the networks, the collection loop and the update's skeleton.

Both are off-policy actor-critics on a box of actions (rejax's shape: this base writes the loop,
:mod:`wrl_jax.agents.sac` and :mod:`wrl_jax.agents.td3` write their losses). One update of one seed:

1. ``train_freq`` vector steps of ``num_envs`` environments; actions are uniform in the box until
   ``learning_starts`` transitions were collected, then the learner's exploring policy. With
   ``noise_correlation`` ``rho > 0`` the exploration noise is an AR(1) process, Gaussian at every
   step but correlated in time (the "colored noise" of Eberhard et al. 2023): a robot that steers
   with (v, w) travels instead of jittering in place. Every
   transition goes into the replay buffer with ``next_obs`` taken before the automatic reset
   (``info["final_obs"]``) and only ``terminated`` stopping the bootstrap: a time-limit
   truncation is bootstrapped like any other step.
2. Once learning has started, ``gradient_steps`` gradient steps (:meth:`gradient_step`), each
   on a uniform batch from the buffer; with ``n_step > 1`` each sampled transition is extended to
   the discounted rewards of up to ``n`` steps of its environment (stopping at its episode's end),
   bootstrapped with ``gamma ** steps`` (:func:`~wrl_jax.agents.replay.n_step_sample`).

Networks work in the unit box ``[-1, 1]^A`` (a tanh output); :meth:`to_env` maps it affinely onto
the environment's box, and the buffer stores unit actions. The twin critics are one parameter
tree with a leading axis of 2, evaluated with ``vmap``. Parameters are initialized without
QR decompositions (:func:`~wrl_jax.agents.initializers.init_mlp_params`): compile time is part
of every short run.
"""

from __future__ import annotations

import abc
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from wrl_jax.agents.base import (
    Algorithm,
    EpisodeStats,
    EpisodeSums,
    Metrics,
    observation_size,
    sum_episode_sums,
    track_episodes,
)
from wrl_jax.agents.common import count_events, linear_decay, polyak_update
from wrl_jax.agents.initializers import init_mlp_params
from wrl_jax.agents.networks import ACTIVATIONS, mlp_forward_flops
from wrl_jax.agents.off_policy_config import OffPolicyConfig
from wrl_jax.agents.replay import ReplayBuffer, Transition, n_step_sample
from wrl_jax.core.environment import Environment
from wrl_jax.core.tracing import traced_once


@struct.dataclass
class OffPolicyRunner:
    """All mutable state of one seed: a checkpoint of it resumes training exactly.

    ``actor_target`` is TD3's target actor, or SAC's average of its actor with ``actor_average`` (else an
    empty dict); ``log_alpha`` and
    ``alpha_opt`` are SAC's temperature and its optimizer (TD3: zero and empty).
    """

    actor: Any
    critic: Any  # twin critics: every leaf has a leading axis of 2
    actor_target: Any
    critic_target: Any
    actor_opt: Any
    critic_opt: Any
    log_alpha: jax.Array
    alpha_opt: Any
    buffer: ReplayBuffer
    env_state: Any  # the env family's state, batched over num_envs
    obs: jax.Array  # (num_envs, obs_size)
    exploration: jax.Array  # (num_envs, A): the standard-normal noise of the last step (correlated exploration)
    episode_stats: EpisodeStats
    key: jax.Array
    hyper: Any
    env_params: Any


def mlp(params: dict[str, Any], x: jax.Array, activation: str) -> jax.Array:
    """An :class:`~wrl_jax.agents.networks.MLP`'s forward pass on its parameter tree, as plain matmuls."""
    act = ACTIVATIONS[activation]
    layers = params["params"]
    for i in range(len(layers)):
        if i:
            x = act(x)
        x = x @ layers[f"Dense_{i}"]["kernel"] + layers[f"Dense_{i}"]["bias"]
    return x


class OffPolicyActorCritic(Algorithm[OffPolicyRunner]):
    """The shared loop of SAC and TD3 for the training driver (one seed; the driver ``vmap``s it)."""

    action_kind = "continuous"
    config_cls: type = OffPolicyConfig
    uses_actor_target: bool = False

    @property
    def averages_actor(self) -> bool:
        """Whether the greedy policy is ``actor_target``, an average of the actor (SAC's ``actor_average``, TD3's
        ``greedy_target``), instead of the actor as trained."""
        return False

    def __init__(self, config: OffPolicyConfig, env: Environment, env_params: Any):
        if not isinstance(config, self.config_cls):
            raise TypeError(f"{type(self).__name__} needs a {self.config_cls.__name__}, got {type(config).__name__}")
        if getattr(env, "num_agents", None) is not None:
            raise ValueError(f"{type(self).__name__} is single-agent; {env.name} has {env.num_agents} agents")
        super().__init__(config, env, env_params)
        space = env.action_space(env_params)
        if len(space.shape) != 1:
            raise ValueError(f"{type(self).__name__} needs a flat action box; {env.name}'s has shape {space.shape}")
        low = np.broadcast_to(np.asarray(space.low, np.float32), space.shape)
        high = np.broadcast_to(np.asarray(space.high, np.float32), space.shape)
        if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(high > low)):
            raise ValueError(f"{env.name}'s action box must be finite with high > low, got [{low}, {high}]")
        self.action_size = int(space.shape[0])
        self.action_scale = (high - low) / 2
        self.action_centre = (high + low) / 2
        self.log_action_scale = float(np.log(self.action_scale).sum())  # log|det| of the map onto the box
        self.obs_size = observation_size(env)
        # Adam without its step size: the (traced) learning rate is applied by hand.
        self.optimizer = optax.scale_by_adam(eps=config.adam_eps)

    # ----------------------------------------------------------- contract
    @property
    def num_updates(self) -> int:
        return self.config.num_updates

    @property
    def steps_per_update(self) -> int:
        return self.config.steps_per_update

    def network_params(self, runner: OffPolicyRunner) -> Any:
        """The greedy policy's parameters: the actor, or its average (:attr:`averages_actor`)."""
        return runner.actor_target if self.averages_actor else runner.actor

    def greedy_action(self, network_params: Any, obs: jax.Array) -> jax.Array:
        return self.to_env(self.deterministic_unit_action(network_params, obs))

    # ------------------------------------------------------- the learner's
    @property
    @abc.abstractmethod
    def actor_output_size(self) -> int:
        """Width of the actor's output layer."""

    @abc.abstractmethod
    def deterministic_unit_action(self, actor: Any, obs: jax.Array) -> jax.Array:
        """The policy's deterministic action in the unit box, ``(..., A)``."""

    @abc.abstractmethod
    def exploring_unit_action(self, runner: OffPolicyRunner, noise: jax.Array, obs: jax.Array) -> jax.Array:
        """The action collected once learning has started, in the unit box, ``(num_envs, A)``, from
        standard-normal ``noise`` ``(num_envs, A)`` (independent per step, or correlated in time)."""

    @abc.abstractmethod
    def gradient_step(self, runner: OffPolicyRunner, key: jax.Array, index: jax.Array) -> tuple[OffPolicyRunner, Metrics]:
        """One gradient step of every network on a batch; ``index`` counts gradient steps (unbatched)."""

    @abc.abstractmethod
    def initial_log_alpha(self, hyper: Any) -> jax.Array:
        """The runner's ``log_alpha`` at the start (TD3: 0, unused)."""

    # ------------------------------------------------------------ networks
    def to_env(self, unit: jax.Array) -> jax.Array:
        """Unit-box actions -> the environment's box."""
        return unit * self.action_scale + self.action_centre

    def actor_forward(self, actor: Any, obs: jax.Array) -> jax.Array:
        return mlp(actor, obs, self.config.activation)

    def critic_values(self, critic: Any, obs: jax.Array, unit_action: jax.Array) -> jax.Array:
        """Both critics' Q-values of ``(obs, unit_action)``: ``(2, ...)``."""
        inputs = jnp.concatenate([obs, unit_action], axis=-1)
        return jax.vmap(lambda p: mlp(p, inputs, self.config.activation)[..., 0])(critic)

    def init_networks(self, key: jax.Array) -> tuple[Any, Any]:
        """Actor and twin critics: orthogonal kernels, a small actor output (a near-zero, wide first policy)."""
        hidden = tuple(self.config.hidden_sizes)
        critic_spec = (self.obs_size + self.action_size, hidden, 1, 1.0)
        actor, *critics = init_mlp_params(key, [(self.obs_size, hidden, self.actor_output_size, 0.01),
                                                critic_spec, critic_spec])
        return actor, jax.tree.map(lambda a, b: jnp.stack([a, b]), *critics)

    def sample_batch(self, runner: OffPolicyRunner, key: jax.Array) -> tuple[Transition, jax.Array]:
        """A batch of (n-step) transitions and each one's bootstrap discount (``gamma ** steps``)."""
        config = self.config
        if config.n_step == 1:
            return runner.buffer.sample(key, config.batch_size), runner.hyper.gamma
        return n_step_sample(runner.buffer, key, config.batch_size, config.n_step, config.num_envs, runner.hyper.gamma)

    def learning_rate(self, hyper: Any, index: jax.Array) -> jax.Array:
        """The step size of gradient step ``index`` (``update * gradient_steps + i``, warm-up updates included):
        constant, or under ``anneal_lr`` constant until ``anneal_from`` of the run, then falling linearly to
        ``learning_rate / (steps in the decay)`` at the last step (PPO's :func:`linear_decay`)."""
        config = self.config
        if not config.anneal_lr:
            return hyper.learning_rate
        total = config.num_updates * config.gradient_steps
        start = config.anneal_from * total
        progress = (index.astype(jnp.float32) - start) / (total - start)
        return jnp.minimum(linear_decay(hyper.learning_rate, progress), hyper.learning_rate)

    def adam_step(self, params: Any, grads: Any, opt_state: Any, learning_rate: jax.Array) -> tuple[Any, Any]:
        updates, opt_state = self.optimizer.update(grads, opt_state, params)
        return jax.tree.map(lambda p, u: p - learning_rate * u, params, updates), opt_state

    def init(self, key: jax.Array, hyper: Any | None = None, env_params: Any | None = None) -> OffPolicyRunner:
        config = self.config
        hyper = config.hyper() if hyper is None else hyper
        env_params = self.env_params if env_params is None else env_params
        key, net_key, reset_key = jax.random.split(key, 3)
        obs, env_state = self.env.batch_reset(reset_key, config.num_envs, env_params)
        actor, critic = self.init_networks(net_key)
        log_alpha = self.initial_log_alpha(hyper)
        return OffPolicyRunner(
            actor=actor,
            critic=critic,
            actor_target=jax.tree.map(jnp.copy, actor) if self.uses_actor_target or self.averages_actor else {},
            critic_target=jax.tree.map(jnp.copy, critic),
            actor_opt=self.optimizer.init(actor),
            critic_opt=self.optimizer.init(critic),
            log_alpha=log_alpha,
            alpha_opt=self.optimizer.init(log_alpha) if not self.uses_actor_target else {},
            buffer=ReplayBuffer.empty(config.buffer_size, self.obs_size, self.action_size,
                                      truncation=config.n_step > 1),
            env_state=env_state,
            obs=obs,
            exploration=jnp.zeros((config.num_envs, self.action_size), jnp.float32),
            episode_stats=EpisodeStats.zeros(config.num_envs),
            key=key,
            hyper=hyper,
            env_params=env_params,
        )

    # -------------------------------------------------------------- update
    def _env_step(self, runner: OffPolicyRunner, timestep: jax.Array) -> tuple[OffPolicyRunner, tuple[EpisodeSums, Metrics]]:
        """One vector step: act (uniformly before learning starts), step, store the transitions."""
        config = self.config
        key, random_key, policy_key, env_key = jax.random.split(runner.key, 4)
        shape = (config.num_envs, self.action_size)
        rho = config.noise_correlation
        if rho == 0.0:  # independent noise every step
            uniform = jax.random.uniform(random_key, shape, jnp.float32, -1.0, 1.0)
            noise = jax.random.normal(policy_key, shape, jnp.float32)
        else:  # an AR(1) process: still N(0, 1) at every step, but it keeps its direction for ~1/(1-rho) steps
            noise = rho * runner.exploration + math.sqrt(1.0 - rho * rho) * jax.random.normal(policy_key, shape)
            uniform = 2.0 * jax.scipy.stats.norm.cdf(noise) - 1.0  # uniform in (-1, 1) at every step, correlated
        unit = jax.lax.cond(timestep < config.learning_starts, lambda: uniform,
                            lambda: self.exploring_unit_action(runner, noise, runner.obs))
        obs, env_state, reward, terminated, truncated, info = self.env.batch_step(
            env_key, runner.env_state, self.to_env(unit), runner.env_params)
        buffer = runner.buffer.add(Transition(obs=runner.obs, action=unit, reward=reward, next_obs=info["final_obs"],
                                              terminated=terminated,
                                              truncated=truncated if config.n_step > 1 else None))
        stats, sums = track_episodes(runner.episode_stats, reward, terminated, truncated)
        runner = runner.replace(key=key, buffer=buffer, env_state=env_state, obs=obs, episode_stats=stats,
                                exploration=noise)
        return runner, (sums, count_events(self.env, info))

    def _train(self, runner: OffPolicyRunner, first_index: jax.Array) -> tuple[OffPolicyRunner, Metrics]:
        """``gradient_steps`` gradient steps; each metric averaged over them."""
        steps = self.config.gradient_steps
        keys = jax.random.split(runner.key, steps + 1)
        indices = first_index + jnp.arange(steps, dtype=jnp.int32)
        runner, metrics = jax.lax.scan(lambda r, xs: self.gradient_step(r, *xs), runner.replace(key=keys[0]),
                                       (keys[1:], indices))
        return runner, jax.tree.map(lambda x: x.mean(), metrics)

    def update(self, runner: OffPolicyRunner, update_index: jax.Array) -> tuple[OffPolicyRunner, Metrics]:
        config = self.config
        update_index = jnp.asarray(update_index, jnp.int32)
        if self.env.refreshes_params:
            runner = runner.replace(env_params=self.env.params_for_update(runner.env_params, update_index))
        first_step = update_index * config.steps_per_update
        timesteps = first_step + config.num_envs * jnp.arange(config.train_freq, dtype=jnp.int32)
        runner, (sums, events) = jax.lax.scan(self._env_step, runner, timesteps)
        learning = first_step + config.steps_per_update > config.learning_starts
        first_index = update_index * config.gradient_steps
        train, shapes = traced_once(self._train, runner, first_index)  # one trace: the branch and its shapes
        idle = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes[1])
        runner, losses = jax.lax.cond(learning, train, lambda r, i: (r, idle), runner, first_index)
        metrics = {**sum_episode_sums(sums).as_metrics(), **jax.tree.map(jnp.sum, events), **losses}
        return runner, jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), metrics)

    def soft_update(self, target: Any, online: Any, tau: jax.Array) -> Any:
        return polyak_update(target, online, tau)

    # --------------------------------------------------------------- cost
    def network_flops(self) -> tuple[int, int]:
        """Forward FLOPs of the actor and of one critic, per sample."""
        hidden = self.config.hidden_sizes
        return (mlp_forward_flops(self.obs_size, hidden, self.actor_output_size),
                mlp_forward_flops(self.obs_size + self.action_size, hidden, 1))

    def flops_per_update(self) -> int:
        """Gradient steps (see :meth:`gradient_step_flops`) plus the acting pass of every collected transition."""
        actor, _ = self.network_flops()
        steps = self.config.gradient_steps * self.gradient_step_flops()
        return steps + self.config.steps_per_update * actor

    @abc.abstractmethod
    def gradient_step_flops(self) -> int:
        """FLOPs of one gradient step on a batch (2 per multiply-add; a backward pass ~ 2 forward)."""
