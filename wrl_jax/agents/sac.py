"""Soft actor-critic, hand-written in JAX and compiled end to end with the environments.

The loop (collection, replay, the learning-starts switch) is
:class:`~wrl_jax.agents.off_policy.OffPolicyActorCritic`'s; this module is SAC's gradient step:

1. **Critics**: both towards ``r + gamma * (1 - terminated) * (min_j Q'_j(s', a') - alpha log pi(a'|s'))``
   (with ``n_step``: the discounted sum of up to ``n`` rewards and ``gamma ** steps``)
   with ``a' ~ pi(.|s')`` and the target critics ``Q'`` (Polyak copies), squared error.
2. **Actor**: minimize ``alpha log pi(a|s) - min_j Q_j(s, a)`` with ``a ~ pi(.|s)`` reparameterized,
   through the critics just updated.
3. **Temperature**: ``log alpha`` moves so that the policy's entropy tracks the target (``-|A|`` unless
   ``target_entropy`` says otherwise).
4. Target critics: ``Q' <- tau Q + (1 - tau) Q'``.

The policy is a tanh-squashed Gaussian. Its log-density counts every change of variables from
the Gaussian to the environment's action: the tanh (``log(1 - tanh(u)^2)``, computed stably) and
the affine map onto the box (``log`` of its half-widths), so the entropy the temperature
controls is the entropy of the actions the environment receives, whatever its bounds.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp

from wrl_jax.agents.base import AlgoSpec, Metrics
from wrl_jax.agents.off_policy import OffPolicyActorCritic, OffPolicyRunner
from wrl_jax.agents.off_policy_config import DYNAMIC_NAME, OFF_POLICY_ENV_DEFAULTS, SAC_PRESETS, SACConfig, SACHyper

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0
"""The actor's log standard deviation is clipped to this range (as SB3 and the SAC paper's code)."""


class SAC(OffPolicyActorCritic):
    """SAC for the shared training driver (one seed; the driver ``vmap``s it)."""

    name = "sac"
    config_cls = SACConfig
    has_stochastic_policy = True

    def __init__(self, config: SACConfig, env: Any, env_params: Any):
        super().__init__(config, env, env_params)
        # No distribution on the box has more entropy than the uniform one, log(volume): a target at or above
        # it would make the temperature grow without end.
        most = self.log_action_scale + self.action_size * math.log(2.0)
        if self.target_entropy >= most:
            raise ValueError(f"SACConfig.target_entropy ({self.target_entropy}) must be below the largest entropy of "
                             f"an action on {env.name}'s box, log(volume) = {most:.3f}")

    @property
    def actor_output_size(self) -> int:
        return 2 * self.action_size  # mean and log standard deviation

    @property
    def target_entropy(self) -> float:
        target = self.config.target_entropy
        return -float(self.action_size) if target is None else float(target)

    def initial_log_alpha(self, hyper: SACHyper) -> jax.Array:
        return jnp.log(jnp.asarray(hyper.initial_alpha, jnp.float32))

    # ------------------------------------------------------------- policy
    def gaussian(self, actor: Any, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        out = self.actor_forward(actor, obs)
        mean, log_std = out[..., : self.action_size], out[..., self.action_size :]
        return mean, jnp.clip(log_std, LOG_STD_MIN, LOG_STD_MAX)

    def sample_unit(self, actor: Any, obs: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        """A reparameterized sample in the unit box and the log-density of its environment action."""
        mean, log_std = self.gaussian(actor, obs)
        return self.squash(mean, log_std, jax.random.normal(key, mean.shape, jnp.float32))

    def squash(self, mean: jax.Array, log_std: jax.Array, noise: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``tanh(mean + std * noise)`` and the log-density of its environment action."""
        u = mean + jnp.exp(log_std) * noise
        gaussian_log_prob = -0.5 * jnp.square(noise) - log_std - 0.5 * math.log(2 * math.pi)
        # log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u)), exact and stable for large |u|.
        log_det_tanh = 2.0 * (math.log(2.0) - u - jax.nn.softplus(-2.0 * u))
        log_prob = (gaussian_log_prob - log_det_tanh).sum(axis=-1) - self.log_action_scale
        return jnp.tanh(u), log_prob

    def deterministic_unit_action(self, actor: Any, obs: jax.Array) -> jax.Array:
        return jnp.tanh(self.gaussian(actor, obs)[0])

    def exploring_unit_action(self, runner: OffPolicyRunner, noise: jax.Array, obs: jax.Array) -> jax.Array:
        return self.squash(*self.gaussian(runner.actor, obs), noise)[0]

    def sample_action(self, network_params: Any, obs: jax.Array, key: jax.Array) -> jax.Array:
        return self.to_env(self.sample_unit(network_params, obs, key)[0])

    # ----------------------------------------------------------- learning
    @property
    def averages_actor(self) -> bool:
        return self.config.actor_average > 0

    def gradient_step(self, runner: OffPolicyRunner, key: jax.Array, index: jax.Array) -> tuple[OffPolicyRunner, Metrics]:
        hyper: SACHyper = runner.hyper
        learning_rate = self.learning_rate(hyper, index)
        batch_key, next_key, actor_key = jax.random.split(key, 3)
        batch, discount = self.sample_batch(runner, batch_key)
        alpha = jnp.exp(runner.log_alpha)

        next_action, next_log_prob = self.sample_unit(runner.actor, batch.next_obs, next_key)
        next_q = self.critic_values(runner.critic_target, batch.next_obs, next_action).min(axis=0)
        not_terminal = 1.0 - batch.terminated.astype(jnp.float32)
        target = jax.lax.stop_gradient(
            hyper.reward_scale * batch.reward + discount * not_terminal * (next_q - alpha * next_log_prob))

        def critic_loss(critic):
            q = self.critic_values(critic, batch.obs, batch.action)
            return 0.5 * jnp.square(q - target).mean(axis=-1).sum(), q.mean()

        (q_loss, q_mean), grads = jax.value_and_grad(critic_loss, has_aux=True)(runner.critic)
        critic, critic_opt = self.adam_step(runner.critic, grads, runner.critic_opt, learning_rate)

        def actor_loss(actor):
            action, log_prob = self.sample_unit(actor, batch.obs, actor_key)
            q = self.critic_values(critic, batch.obs, action).min(axis=0)
            return (alpha * log_prob - q).mean(), log_prob

        (pi_loss, log_prob), grads = jax.value_and_grad(actor_loss, has_aux=True)(runner.actor)
        actor, actor_opt = self.adam_step(runner.actor, grads, runner.actor_opt, learning_rate)

        log_alpha, alpha_opt = runner.log_alpha, runner.alpha_opt
        if self.config.learn_alpha:
            entropy_gap = jax.lax.stop_gradient(log_prob + self.target_entropy).mean()
            log_alpha, alpha_opt = self.adam_step(log_alpha, -entropy_gap, alpha_opt, learning_rate)

        if self.averages_actor:
            runner = runner.replace(actor_target=self.soft_update(runner.actor_target, actor, self.config.actor_average))
        runner = runner.replace(
            actor=actor, actor_opt=actor_opt, critic=critic, critic_opt=critic_opt, log_alpha=log_alpha,
            alpha_opt=alpha_opt, critic_target=self.soft_update(runner.critic_target, critic, hyper.tau))
        metrics = {"critic_loss": q_loss, "actor_loss": pi_loss, "q_mean": q_mean, "alpha": alpha,
                   "entropy": -log_prob.mean(), "learning_rate": learning_rate}
        return runner, metrics

    def gradient_step_flops(self) -> int:
        """Per sample: the actor on ``s'`` (1 forward) and on ``s`` (forward and backward: 3), both target
        critics on ``s'`` (2), both critics on ``s`` (6) and on the actor's action for the actor loss (6)."""
        actor, critic = self.network_flops()
        return self.config.batch_size * (4 * actor + 14 * critic)


SPEC = AlgoSpec(
    name="sac",
    config_cls=SACConfig,
    algorithm_cls=SAC,
    presets=SAC_PRESETS,
    default_env="Continuous-Warehouse-12x12-v0",
    default_preset="default",
    default_num_seeds=4,
    env_presets={DYNAMIC_NAME: "dynamic"},
    env_defaults=OFF_POLICY_ENV_DEFAULTS,
)
