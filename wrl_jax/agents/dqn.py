"""Deep Q-learning, hand-written in JAX and compiled end to end.

One *update* of one seed (the unit the shared training driver ``lax.scan``s):

1. ``train_freq`` vector steps of ``num_envs`` environments with
   epsilon-greedy actions from the online Q-network; every transition goes
   into the replay buffer with ``next_obs`` taken *before* the automatic reset
   (``info["final_obs"]``) and only ``terminated`` stopping the bootstrap, so
   a time-limit truncation is bootstrapped like any other step;
2. once ``learning_starts`` transitions have been collected,
   ``gradient_steps`` gradient steps, each on a uniform batch from the buffer,
   towards ``r + gamma * (1 - terminated) * Q_target(s', a*)`` with
   ``a* = argmax Q_target(s')`` (or ``argmax Q_online(s')``, Double DQN),
   Huber or squared loss, global-norm gradient clipping and Adam;
3. the target network is moved towards the online one (``tau = 1``: a hard
   copy) every ``target_update_interval`` transitions.

The schedules follow Stable-Baselines3's ``DQN`` so that the ``paper`` preset
means what the study ran: ``train_freq``, ``learning_starts`` and the
exploration schedule are counted in environment transitions, the target
interval too. Decisions keyed on the step count (learning has started, the
target is due) use ``lax.cond`` on the driver's unbatched ``update_index``, so
under ``vmap`` over seeds they stay real branches and skipped work costs
nothing.

Everything a sweep may vary (learning rate, discount, epsilon schedule, tau,
gradient clip, Huber delta, reward scale) is a traced :class:`DQNHyper` in the
runner state; what fixes array shapes or the program's structure (network,
environments, buffer, batch, frequencies, loss, Double DQN, learning-rate
annealing) is static on :class:`DQNConfig`.

Compile time is part of every short run's wall time, so the update draws all
randomness of a vector step in one call (each ``jax.random`` call site
compiles a threefry kernel: tenths of a second each on this CPU) and the
Q-network is initialized without QR decompositions (see :meth:`DQN.init_network`).

Why one module of this length: config, presets (the study's Table 2 and our
measured defaults), runner state, acting, learning and the FLOP count are one
algorithm, readable top to bottom; what DQN shares with PPO lives in
:mod:`wrl_jax.agents.common`, the replay buffer in :mod:`wrl_jax.agents.replay`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from wrl_jax.agents import base
from wrl_jax.agents.base import (
    Algorithm,
    AlgoSpec,
    EpisodeStats,
    EpisodeSums,
    Metrics,
    observation_size,
    sum_episode_sums,
    track_episodes,
)
from wrl_jax.agents.common import (
    clip_by_global_norm,
    count_events,
    linear_decay,
    polyak_update,
)
from wrl_jax.agents.dqn_config import PRESETS, STUDY_TABLE3, DQNConfig, DQNHyper
from wrl_jax.agents.networks import MLP, mlp_forward_flops
from wrl_jax.agents.replay import ReplayBuffer, Transition
from wrl_jax.core.environment import Environment


# ---------------------------------------------------------------------- state
@struct.dataclass
class DQNRunner:
    """All mutable state of one seed: a checkpoint of it resumes training exactly."""

    params: Any  # online Q-network
    target_params: Any
    opt_state: Any
    buffer: ReplayBuffer
    env_state: Any  # the env family's state, batched over num_envs
    obs: jax.Array  # (num_envs, obs_size)
    episode_stats: EpisodeStats
    key: jax.Array
    hyper: DQNHyper
    env_params: Any


# ------------------------------------------------------------------ algorithm
class DQN(Algorithm[DQNRunner]):
    """DQN for the shared training driver (one seed; the driver ``vmap``s it).

    Args:
        config: a validated :class:`DQNConfig`.
        env: the environment (static shapes).
        env_params: its params (the default ``init`` uses them).
    """

    name = "dqn"

    def __init__(self, config: DQNConfig, env: Environment, env_params: Any):
        if not isinstance(config, DQNConfig):
            raise TypeError(f"DQN needs a DQNConfig, got {type(config).__name__}")
        if getattr(env, "num_agents", None) is not None:
            raise ValueError(f"DQN is single-agent; {env.name} is a {env.num_agents}-robot fleet: train it with "
                             f"PPO (python train_ppo.py --env {env.name})")
        super().__init__(config, env, env_params)
        self.network = MLP(hidden_sizes=config.hidden_sizes, output_size=env.num_actions, activation=config.activation)
        # Adam without its step size: the (traced) learning rate is applied by hand.
        self.optimizer = optax.scale_by_adam(eps=config.adam_eps)

    # ----------------------------------------------------------- contract
    @property
    def num_updates(self) -> int:
        return self.config.num_updates

    @property
    def steps_per_update(self) -> int:
        return self.config.steps_per_update

    def network_params(self, runner: DQNRunner) -> Any:
        return runner.params

    def greedy_action(self, network_params: Any, obs: jax.Array) -> jax.Array:
        return jnp.argmax(self.network.apply(network_params, obs), axis=-1).astype(jnp.int32)

    def init_network(self, key: jax.Array) -> Any:
        """Fresh Q-network parameters, initialized as PyTorch's ``nn.Linear`` (what SB3 uses).

        Every kernel and bias is uniform in ``+-1/sqrt(fan_in)``. The shared
        MLP's own initializer is orthogonal, which needs a QR decomposition per
        layer: compiling that under ``vmap`` costs seconds on this CPU, more
        than a whole short training run. The parameter tree is the MLP's, so
        ``network.apply`` is unchanged.
        """
        shapes = jax.eval_shape(self.network.init, key, jnp.zeros((observation_size(self.env),), jnp.float32))["params"]
        names = sorted(shapes, key=lambda name: int(name.split("_")[-1]))  # Dense_0, Dense_1, ...
        sizes = [shapes[name][part].size for name in names for part in ("kernel", "bias")]
        # One draw for all parameters: every random call costs compile time.
        unit = jax.random.uniform(key, (sum(sizes),), jnp.float32, -1.0, 1.0)
        params, offset = {}, 0
        for name in names:
            bound = 1.0 / math.sqrt(shapes[name]["kernel"].shape[0])
            params[name] = {}
            for part in ("kernel", "bias"):
                shape = shapes[name][part].shape
                size = math.prod(shape)
                params[name][part] = bound * unit[offset : offset + size].reshape(shape)
                offset += size
        return {"params": params}

    def q_values(self, network_params: Any, obs: jax.Array) -> jax.Array:
        """Q-values of every action, ``(..., num_actions)``."""
        return self.network.apply(network_params, obs)

    def init(self, key: jax.Array, hyper: DQNHyper | None = None, env_params: Any | None = None) -> DQNRunner:
        config = self.config
        hyper = config.hyper() if hyper is None else hyper
        env_params = self.env_params if env_params is None else env_params
        key, net_key, reset_key = jax.random.split(key, 3)
        obs, env_state = self.env.batch_reset(reset_key, config.num_envs, env_params)
        params = self.init_network(net_key)
        return DQNRunner(
            params=params,
            # A copy, not the same buffers: the target must not alias the online net.
            target_params=jax.tree.map(jnp.copy, params),
            opt_state=self.optimizer.init(params),
            buffer=ReplayBuffer.empty(config.buffer_size, observation_size(self.env)),
            env_state=env_state,
            obs=obs,
            episode_stats=EpisodeStats.zeros(config.num_envs),
            key=key,
            hyper=hyper,
            env_params=env_params,
        )

    # ------------------------------------------------------------- update
    def epsilon(self, hyper: DQNHyper, timestep: jax.Array) -> jax.Array:
        """Exploration rate after ``timestep`` transitions (SB3's linear schedule)."""
        duration = hyper.exploration_fraction * self.config.total_timesteps
        progress = jnp.minimum(timestep.astype(jnp.float32) / duration, 1.0)
        eps = hyper.exploration_initial_eps + progress * (hyper.exploration_final_eps - hyper.exploration_initial_eps)
        # Before learning starts, actions are uniformly random (as in SB3).
        return jnp.where(timestep < self.config.learning_starts, 1.0, eps)

    def _env_step(self, runner: DQNRunner, timestep: jax.Array) -> tuple[DQNRunner, tuple[EpisodeSums, dict[str, jax.Array]]]:
        """One vector step: act epsilon-greedily, step, store the transitions."""
        config = self.config
        # All randomness of a vector step comes from one split and one draw:
        # every random call site costs compile time (threefry is a large kernel).
        key, draw_key, env_key = jax.random.split(runner.key, 3)
        bits = jax.random.bits(draw_key, (2, config.num_envs), jnp.uint32)
        explore = _unit_float(bits[0]) < self.epsilon(runner.hyper, timestep)
        random_action = (bits[1] % self.env.num_actions).astype(jnp.int32)
        action = jnp.where(explore, random_action, self.greedy_action(runner.params, runner.obs))
        obs, env_state, reward, terminated, truncated, info = self.env.batch_step(
            env_key, runner.env_state, action, runner.env_params
        )
        buffer = runner.buffer.add(
            Transition(
                obs=runner.obs,
                action=action,
                reward=reward,
                next_obs=info["final_obs"],  # the state reached, before the auto-reset
                terminated=terminated,  # truncation still bootstraps
            )
        )
        stats, sums = track_episodes(runner.episode_stats, reward, terminated, truncated)
        runner = runner.replace(key=key, buffer=buffer, env_state=env_state, obs=obs, episode_stats=stats)
        return runner, (sums, count_events(self.env, info))

    def loss_fn(
        self, params: Any, target_params: Any, hyper: DQNHyper, batch: Transition
    ) -> tuple[jax.Array, jax.Array]:
        """Mean TD loss of a batch, and the mean Q of the actions taken."""
        q_next_target = self.network.apply(target_params, batch.next_obs)
        if self.config.double_dqn:
            next_action = jnp.argmax(self.network.apply(params, batch.next_obs), axis=-1)
        else:
            next_action = jnp.argmax(q_next_target, axis=-1)
        next_value = jnp.take_along_axis(q_next_target, next_action[:, None], axis=-1)[:, 0]
        not_terminal = 1.0 - batch.terminated.astype(jnp.float32)
        target = jax.lax.stop_gradient(hyper.reward_scale * batch.reward + hyper.gamma * not_terminal * next_value)
        q = jnp.take_along_axis(self.network.apply(params, batch.obs), batch.action[:, None], axis=-1)[:, 0]
        error = q - target
        if self.config.loss == "huber":
            loss = optax.losses.huber_loss(error, delta=hyper.huber_delta)
        else:
            loss = 0.5 * jnp.square(error)
        return loss.mean(), q.mean()

    def _gradient_step(
        self, runner: DQNRunner, key: jax.Array, learning_rate: jax.Array
    ) -> tuple[DQNRunner, tuple[jax.Array, jax.Array]]:
        hyper = runner.hyper
        batch = runner.buffer.sample(key, self.config.batch_size)
        (loss, q_mean), grads = jax.value_and_grad(self.loss_fn, has_aux=True)(
            runner.params, runner.target_params, hyper, batch
        )
        grads, _ = clip_by_global_norm(grads, hyper.max_grad_norm)
        updates, opt_state = self.optimizer.update(grads, runner.opt_state, runner.params)
        params = jax.tree.map(lambda p, u: p - learning_rate * u, runner.params, updates)
        return runner.replace(params=params, opt_state=opt_state), (loss, q_mean)

    def learning_rate(self, hyper: DQNHyper, timestep: jax.Array) -> jax.Array:
        """Step size after ``timestep`` transitions (constant, or linearly annealed to 0)."""
        if not self.config.anneal_lr:
            return hyper.learning_rate
        return linear_decay(hyper.learning_rate, timestep.astype(jnp.float32) / self.config.total_timesteps)

    def _train(self, runner: DQNRunner, timestep: jax.Array) -> tuple[DQNRunner, tuple[jax.Array, jax.Array]]:
        """``gradient_steps`` gradient steps; mean loss and mean Q over them."""
        keys = jax.random.split(runner.key, self.config.gradient_steps + 1)
        learning_rate = self.learning_rate(runner.hyper, timestep)
        runner, (loss, q_mean) = jax.lax.scan(
            lambda r, k: self._gradient_step(r, k, learning_rate), runner.replace(key=keys[0]), keys[1:]
        )
        return runner, (loss.mean(), q_mean.mean())

    def update(self, runner: DQNRunner, update_index: jax.Array) -> tuple[DQNRunner, Metrics]:
        config = self.config
        update_index = jnp.asarray(update_index, jnp.int32)
        if self.env.refreshes_params:  # e.g. the procedural warehouse renews part of its layout pool
            runner = runner.replace(env_params=self.env.params_for_update(runner.env_params, update_index))
        first_step = update_index * config.steps_per_update
        timesteps = first_step + config.num_envs * jnp.arange(config.train_freq, dtype=jnp.int32)
        runner, (sums, events) = jax.lax.scan(self._env_step, runner, timesteps)
        done = first_step + config.steps_per_update  # transitions collected after this update

        # SB3 trains once more than learning_starts transitions were collected.
        learning = done > config.learning_starts
        no_training = (jnp.zeros((), jnp.float32), jnp.zeros((), jnp.float32))
        runner, (loss, q_mean) = jax.lax.cond(
            learning, self._train, lambda r, t: (r, no_training), runner, first_step
        )

        # Target update every target_update_interval transitions (when a multiple is crossed).
        interval = config.target_update_interval
        due = (done // interval) > (first_step // interval)
        runner = jax.lax.cond(due, self._update_target, lambda r: r, runner)

        metrics = {
            **sum_episode_sums(sums).as_metrics(),
            **jax.tree.map(jnp.sum, events),  # the environment's event counts (sums: log groups add them)
            "loss": loss,
            "q_mean": q_mean,
            "epsilon": self.epsilon(runner.hyper, done - 1),
            "learning_rate": jnp.where(learning, self.learning_rate(runner.hyper, first_step), 0.0),
        }
        metrics = jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), metrics)
        return runner, metrics

    def _update_target(self, runner: DQNRunner) -> DQNRunner:
        return runner.replace(target_params=polyak_update(runner.target_params, runner.params, runner.hyper.tau))

    # --------------------------------------------------------------- cost
    def gradient_flops_per_update(self) -> int:
        """FLOPs of the gradient steps of one update, one seed (2 per multiply-add).

        Per sampled transition: the online network's forward and backward pass
        on ``obs`` (about 3 forward passes) and the target network's forward
        pass on ``next_obs`` (1; Double DQN adds an online forward on
        ``next_obs``). The study's replay ratio (batch 128 every 4 steps,
        [256, 256]) is 52.5 MFLOP of forward+backward plus 17.5 of target
        forward: 70 MFLOP per update.
        """
        forward = mlp_forward_flops(observation_size(self.env), self.config.hidden_sizes, self.env.num_actions)
        passes = 5 if self.config.double_dqn else 4
        return passes * forward * self.config.batch_size * self.config.gradient_steps

    def flops_per_update(self) -> int:
        """Gradient steps plus the epsilon-greedy forward pass of every collected transition."""
        forward = mlp_forward_flops(observation_size(self.env), self.config.hidden_sizes, self.env.num_actions)
        return self.gradient_flops_per_update() + self.config.steps_per_update * forward


SPEC = AlgoSpec(
    name="dqn",
    config_cls=DQNConfig,
    algorithm_cls=DQN,
    presets=PRESETS,
    default_env="Warehouse-8x8-v0",
    default_preset="default",
    default_num_seeds=4,
    study=STUDY_TABLE3,
)


# ------------------------------------------------------------- one program
DEFAULT_ENV = "Warehouse-8x8-v0"
"""The study's DQN environment; what ``train_dqn.py`` trains on by default."""


def make_algorithm(config: DQNConfig, env: Environment | None = None, env_params: Any | None = None) -> DQN:
    """The :class:`DQN` of ``config`` on ``env`` (default: :data:`DEFAULT_ENV`)."""
    if env is None:
        if env_params is not None:
            raise ValueError("pass env together with env_params")
        from wrl_jax.core.registry import make

        env, env_params = make(DEFAULT_ENV)
    elif env_params is None:
        raise ValueError("pass env_params together with env")
    return DQN(config, env, env_params)


def make_train(
    config: DQNConfig, env: Environment | None = None, env_params: Any | None = None
) -> Callable[..., tuple[DQNRunner, Metrics]]:
    """``train(key) -> (runner, metrics)``: a whole run of one seed as one jittable function.

    ``init`` then one ``lax.scan`` of ``update`` over every update; ``metrics``
    has one row per update. Train many seeds in one program with
    ``jax.jit(jax.vmap(make_train(config)))(keys)``: the update index stays
    unbatched, so the learning-starts and target-update branches remain real
    ``lax.cond``s under ``vmap``. ``train(key, hyper, env_params)`` also takes
    a :class:`DQNHyper` (e.g. batched for a sweep) and environment params.
    """
    return base.make_train(make_algorithm(config, env, env_params))


def _unit_float(bits: jax.Array) -> jax.Array:
    """Uniform float32 in [0, 1) from uint32 words (their top 24 bits)."""
    return (bits >> 8).astype(jnp.float32) * jnp.float32(2.0**-24)
