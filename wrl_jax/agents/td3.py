"""Twin delayed DDPG, hand-written in JAX and compiled end to end with the environments.

The loop (collection, replay, the learning-starts switch) is
:class:`~wrl_jax.agents.off_policy.OffPolicyActorCritic`'s; this module is TD3's gradient step
(Fujimoto et al. 2018):

1. **Critics**: both towards ``r + gamma * (1 - terminated) * min_j Q'_j(s', a')`` where the target
   actor's action is smoothed, ``a' = clip(mu'(s') + clip(noise, -c, c), -1, 1)``.
2. **Delayed actor**: every ``policy_delay`` gradient steps, the deterministic actor climbs
   ``Q_1(s, mu(s))``, and both target networks take a Polyak step.

Actions are collected as ``clip(mu(s) + N(0, exploration_noise), -1, 1)`` in the unit box. The
delay is keyed on the gradient-step count, which every seed shares, so under ``vmap`` the actor
update stays a real ``lax.cond`` and skipped steps cost nothing.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from wrl_jax.agents.base import AlgoSpec, Metrics
from wrl_jax.agents.off_policy import OffPolicyActorCritic, OffPolicyRunner, mlp
from wrl_jax.agents.off_policy_config import OFF_POLICY_ENV_DEFAULTS, TD3_PRESETS, TD3Config, TD3Hyper


class TD3(OffPolicyActorCritic):
    """TD3 for the shared training driver (one seed; the driver ``vmap``s it)."""

    name = "td3"
    config_cls = TD3Config
    uses_actor_target = True

    @property
    def actor_output_size(self) -> int:
        return self.action_size

    @property
    def averages_actor(self) -> bool:
        return self.config.greedy_target

    def initial_log_alpha(self, hyper: TD3Hyper) -> jax.Array:
        return jnp.zeros((), jnp.float32)

    def deterministic_unit_action(self, actor: Any, obs: jax.Array) -> jax.Array:
        return jnp.tanh(self.actor_forward(actor, obs))

    def exploring_unit_action(self, runner: OffPolicyRunner, noise: jax.Array, obs: jax.Array) -> jax.Array:
        action = self.deterministic_unit_action(runner.actor, obs)
        return jnp.clip(action + runner.hyper.exploration_noise * noise, -1.0, 1.0)

    def gradient_step(self, runner: OffPolicyRunner, key: jax.Array, index: jax.Array) -> tuple[OffPolicyRunner, Metrics]:
        hyper: TD3Hyper = runner.hyper
        learning_rate = self.learning_rate(hyper, index)
        batch_key, noise_key = jax.random.split(key)
        batch, discount = self.sample_batch(runner, batch_key)

        next_action = self.deterministic_unit_action(runner.actor_target, batch.next_obs)
        noise = hyper.policy_noise * jax.random.normal(noise_key, next_action.shape, jnp.float32)
        next_action = jnp.clip(next_action + jnp.clip(noise, -hyper.noise_clip, hyper.noise_clip), -1.0, 1.0)
        next_q = self.critic_values(runner.critic_target, batch.next_obs, next_action).min(axis=0)
        not_terminal = 1.0 - batch.terminated.astype(jnp.float32)
        target = jax.lax.stop_gradient(hyper.reward_scale * batch.reward + discount * not_terminal * next_q)

        def critic_loss(critic):
            q = self.critic_values(critic, batch.obs, batch.action)
            return 0.5 * jnp.square(q - target).mean(axis=-1).sum(), q.mean()

        (q_loss, q_mean), grads = jax.value_and_grad(critic_loss, has_aux=True)(runner.critic)
        critic, critic_opt = self.adam_step(runner.critic, grads, runner.critic_opt, learning_rate)
        runner = runner.replace(critic=critic, critic_opt=critic_opt)

        def actor_update(r: OffPolicyRunner) -> tuple[OffPolicyRunner, jax.Array]:
            def actor_loss(actor):
                before_squash = self.actor_forward(actor, batch.obs)
                first_critic = jax.tree.map(lambda x: x[0], r.critic)
                inputs = jnp.concatenate([batch.obs, jnp.tanh(before_squash)], axis=-1)
                loss = -mlp(first_critic, inputs, self.config.activation)[..., 0].mean()
                if self.config.preactivation_penalty:  # static: without it the program is TD3's own
                    loss = loss + self.config.preactivation_penalty * jnp.square(before_squash).mean()
                return loss

            loss, grads = jax.value_and_grad(actor_loss)(r.actor)
            actor, actor_opt = self.adam_step(r.actor, grads, r.actor_opt, learning_rate)
            return r.replace(actor=actor, actor_opt=actor_opt,
                             actor_target=self.soft_update(r.actor_target, actor, hyper.tau),
                             critic_target=self.soft_update(r.critic_target, r.critic, hyper.tau)), loss

        due = index % self.config.policy_delay == 0
        runner, pi_loss = jax.lax.cond(due, actor_update, lambda r: (r, jnp.zeros((), jnp.float32)), runner)
        # Averaged over a phase's gradient steps, where one in policy_delay computed it.
        metrics = {"critic_loss": q_loss, "actor_loss": pi_loss * self.config.policy_delay, "q_mean": q_mean,
                   "learning_rate": learning_rate}
        return runner, metrics

    def gradient_step_flops(self) -> int:
        """Per sample: the target actor on ``s'`` (1), both target critics (2), both critics forward and
        backward (6), and every ``policy_delay`` steps the actor through the first critic (3 + 3)."""
        actor, critic = self.network_flops()
        delayed = (3 * actor + 3 * critic) // self.config.policy_delay
        return self.config.batch_size * (actor + 8 * critic + delayed)


SPEC = AlgoSpec(
    name="td3",
    config_cls=TD3Config,
    algorithm_cls=TD3,
    presets=TD3_PRESETS,
    default_env="Continuous-Warehouse-12x12-v0",
    default_preset="default",
    default_num_seeds=4,
    env_defaults=OFF_POLICY_ENV_DEFAULTS,
)
