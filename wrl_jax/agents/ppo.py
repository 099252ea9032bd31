"""Proximal Policy Optimization, hand-written in JAX, compiled end to end.

One update of one seed (:meth:`PPO.update`):

1. Rollout: ``num_steps`` steps of ``num_envs`` vmapped environments in a
   ``lax.scan``; actions sampled from the actor's categorical policy.
2. Values: the critic on every observation *and* on every ``info["final_obs"]``
   (the observation a transition reached, before an auto-reset), as one batched
   forward pass after the rollout.
3. GAE: ``delta_t = r_t + gamma (1 - terminated_t) V(final_obs_t) - V(obs_t)``,
   the trace cut at every episode end. Truncation is not termination: a
   time-limit step still bootstraps from the value of the state it reached,
   only a delivery zeroes the future.
4. ``update_epochs`` passes over the batch in ``num_minibatches`` shuffled
   minibatches (with ``encoder="propagation"``: shuffled environments, each with its
   steps in order, so a leg's rows are propagated once): clipped surrogate,
   squared-error value loss, entropy bonus, one global-norm gradient clip over actor
   and critic together, Adam.

Reward scale. Rewards span -10.5 to +250 (and returns about 270). Left as they
are, the value loss is ~10^4 times the policy loss, dominates the global-norm
clip, and the policy gradient is scaled to almost nothing. We multiply rewards
by ``reward_scale`` (a traced hyperparameter; default 0.01, so returns are ~2.7)
before GAE. It is a fixed constant, not a running statistic, so it is exact,
stateless and identical across seeds. The ``paper`` preset keeps 1.0, because
Stable-Baselines3 with default settings (no ``VecNormalize``) does not scale.

Static fields of :class:`PPOConfig` fix shapes or program structure; the traced
ones (:class:`PPOHyper`) live in the runner state, so a sweep can ``vmap`` them.

The settings and presets are :mod:`wrl_jax.agents.ppo_config`, the networks (inputs, forward
pass, flat parameters, FLOPs) :mod:`wrl_jax.agents.ppo_networks`;
what PPO shares with DQN lives in :mod:`wrl_jax.agents.common`.
"""

from __future__ import annotations

import math

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from wrl_jax.agents import base
from wrl_jax.agents.base import (
    Algorithm,
    AlgoSpec,
    EpisodeStats,
    sum_episode_sums,
    track_episodes,
)
from wrl_jax.agents.common import clip_by_global_norm, count_events, linear_decay
from wrl_jax.agents.off_policy_config import (
    CONTINUOUS_ENV_DEFAULTS,
    CONTINUOUS_NAMES,
    DYNAMIC_ENV_DEFAULTS,
    DYNAMIC_NAME,
    CONTINUOUS_PROCEDURAL_ENV_DEFAULTS,
    PROCEDURAL_NAME,
)
from wrl_jax.agents.ppo_config import (
    FLEET_ENV_DEFAULTS,
    PRESETS,
    PRESET_ENV_DEFAULTS,
    PROCEDURAL_ENV_DEFAULTS,
    STUDY_TABLE3,
    PPOConfig,
    PPOHyper,
)
from wrl_jax.agents.ppo_networks import ActorCritic
from wrl_jax.core.environment import Environment
from wrl_jax.core.gymnax_base import spaces


@struct.dataclass
class PPORunner:
    """Everything one seed of PPO carries from update to update."""

    params: jax.Array  # flat float32 vector of actor and critic parameters (see PPO.unflatten)
    opt_state: Any
    env_state: Any  # the env family's state, batched over num_envs
    obs: jax.Array  # (num_envs, obs_size), or (num_envs, K, obs_size) for K agents
    episode_stats: EpisodeStats
    key: jax.Array
    hyper: PPOHyper
    env_params: Any


class Transition(struct.PyTreeNode):
    obs: jax.Array
    action: jax.Array
    log_prob: jax.Array
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    final_obs: jax.Array
    global_state: Any = None  # (num_envs, G) with a centralized critic, else None
    final_global_state: Any = None
    events: Any = None  # {metric: scalar}: the step's counts of the info flags in ``env.event_metrics``
    inputs: Any = None  # with encoder="propagation": the networks' inputs of obs and of final_obs
    final_inputs: Any = None


_ADAM_EPS = 1e-5  # as in Stable-Baselines3 and CleanRL


class PPO(ActorCritic, Algorithm[PPORunner]):
    """PPO for one seed; see the module docstring. ``PPO(config, env, env_params)``."""

    name = "ppo"

    def __init__(self, config: PPOConfig, env: Environment, env_params: Any):
        observation_type = getattr(env, "observation_type", "flattened")
        if observation_type != "flattened":
            raise ValueError(f"PPO's networks read a flat observation vector; {env.name} has observation_type="
                             f"{observation_type!r}: train on observation_type='flattened' (rware's default)")
        space = env.action_space(env_params)
        self.continuous = isinstance(space, spaces.Box)
        self.action_kind = "continuous" if self.continuous else "discrete"
        if self.continuous:
            if config.obs_encoding != "raw" or config.encoder != "mlp":
                raise ValueError(f"PPO on {env.name} (continuous actions) takes obs_encoding='raw' and encoder='mlp'")
            self.action_low = jnp.asarray(np.broadcast_to(np.asarray(space.low, np.float32), space.shape))
            self.action_high = jnp.asarray(np.broadcast_to(np.asarray(space.high, np.float32), space.shape))
        super().__init__(config, env, env_params)
        self.adam = optax.scale_by_adam(eps=_ADAM_EPS)
        self.num_agents = getattr(env, "num_agents", None)  # None: single agent, no agent axis
        if config.critic == "centralized" and (self.num_agents is None or not hasattr(env, "global_state")):
            raise ValueError(
                f"PPO critic='centralized' needs a multi-agent environment with a global state (the fleet, rware); "
                f"{env.name} is a single-agent {getattr(env, 'family', '?')!r} environment: use critic='local'"
            )
        self.centralized = config.critic == "centralized"
        self.setup_networks(config, env)

    @property
    def num_updates(self) -> int:
        return self.config.num_updates

    @property
    def steps_per_update(self) -> int:
        return self.config.steps_per_update

    # ------------------------------------------------------------------ init
    def init(self, key: jax.Array, hyper: PPOHyper | None = None, env_params: Any | None = None) -> PPORunner:
        hyper = self.config.hyper() if hyper is None else hyper
        env_params = self.env_params if env_params is None else env_params
        key, k_params, k_env = jax.random.split(key, 3)
        params = self.flatten(self._init_networks(k_params))
        obs, env_state = jax.vmap(self.env.reset, in_axes=(0, None))(
            jax.random.split(k_env, self.config.num_envs), env_params)
        return PPORunner(
            params=params,
            opt_state=self.adam.init(params),
            env_state=env_state,
            obs=obs,
            episode_stats=EpisodeStats.zeros(self.config.num_envs),  # per environment (a fleet's team return)
            key=key,
            hyper=hyper,
            env_params=env_params,
        )

    # ---------------------------------------------------------------- update
    def update(self, runner: PPORunner, update_index: jax.Array) -> tuple[PPORunner, dict[str, jax.Array]]:
        if self.env.refreshes_params:  # e.g. the procedural warehouse renews part of its layout pool
            runner = runner.replace(env_params=self.env.params_for_update(runner.env_params, update_index))
        cfg, hyper = self.config, runner.hyper
        networks = self.unflatten(runner.params)
        # Every random number of the update comes from four draws made here, not
        # from draws inside the scans: each threefry call site costs compile time.
        key, k_env, k_act, k_order = jax.random.split(runner.key, 4)
        # A key per step and environment, for vmap(env.step): PPO's stream since its first results (see
        # docs/architecture.md, "Stepping"), kept so that every published PPO number stays reproducible.
        env_keys = jax.random.split(k_env, cfg.num_steps * cfg.num_envs).reshape(cfg.num_steps, cfg.num_envs, -1)
        agents = () if self.num_agents is None else (self.num_agents,)
        # Categorical: Gumbel noise, one per action (Gumbel-max); Gaussian: one standard normal per dimension.
        draw = jax.random.normal if self.continuous else jax.random.gumbel
        gumbel = draw(k_act, (cfg.num_steps, cfg.num_envs, *agents, self.env.num_actions))
        global_states = jax.vmap(self.env.global_state, in_axes=(0, None)) if self.centralized else None

        # 1. rollout (with encoder="propagation", the values are propagated once per leg of an episode:
        # a cache of each environment's values travels with the scan, and the networks' inputs are kept)
        planning = self.map_layout is not None

        def env_step(carry, step_inputs):
            env_state, obs, stats, plan = carry
            step_keys, step_gumbel = step_inputs
            inputs = plan[0] if planning else None
            logits = self.forward(networks["actor"], obs, inputs=inputs)
            if self.continuous:  # the sample is learned from; the box receives it clipped
                action = logits + jnp.exp(networks["actor"]["log_std"]) * step_gumbel
                log_prob = self.gaussian_log_prob(networks["actor"], logits, action)
                env_action = jnp.clip(action, self.action_low, self.action_high)
            else:
                log_probs = jax.nn.log_softmax(logits)
                action = jnp.argmax(log_probs + step_gumbel, axis=-1)  # Gumbel-max: a sample of softmax(logits)
                log_prob = jnp.take_along_axis(log_probs, action[..., None], axis=-1)[..., 0]
                env_action = action
            next_obs, next_state, reward, terminated, truncated, info = jax.vmap(
                self.env.step, in_axes=(0, 0, 0, None)
            )(step_keys, env_state, env_action, runner.env_params)
            extras = {}
            if self.num_agents is not None:
                team_reward = reward.sum(axis=-1)  # an episode's return: the fleet's, summed over robots
            else:
                team_reward = reward
            if self.env.event_metrics:  # the info flags the environment asks to count
                extras["events"] = count_events(self.env, info)
            if self.centralized:
                extras["global_state"] = global_states(env_state, runner.env_params)
                extras["final_global_state"] = info["final_global_state"]
            if planning:  # the state reached first (its leg is usually the step's own), then the next one
                extras["inputs"], cache = inputs, plan[1]
                extras["final_inputs"], cache = self.rollout_inputs(networks["actor"], info["final_obs"], cache)
                plan = self.rollout_inputs(networks["actor"], next_obs, cache)
            stats, sums = track_episodes(stats, team_reward, terminated, truncated)
            transition = Transition(obs, action, log_prob, reward, terminated, truncated, info["final_obs"], **extras)
            return (next_state, next_obs, stats, plan), (transition, sums)

        plan = self.rollout_inputs(networks["actor"], runner.obs) if planning else None
        (env_state, obs, stats, _), (traj, sums) = jax.lax.scan(
            env_step, (runner.env_state, runner.obs, runner.episode_stats, plan), (env_keys, gumbel)
        )

        # 2. values of the observations and of the states the transitions reached
        both = jnp.concatenate([traj.obs, traj.final_obs], axis=0)  # (2T, E, [K,] obs)
        both_global = (
            jnp.concatenate([traj.global_state, traj.final_global_state], axis=0) if self.centralized else None
        )
        if planning:
            both_inputs = jnp.concatenate([traj.inputs, traj.final_inputs], axis=0)
        else:
            both_inputs = self.network_inputs(networks["actor"], both)
        both_values = self.forward(networks["critic"], both, both_global, inputs=both_inputs)[..., 0]
        values, next_values = both_values[: cfg.num_steps], both_values[cfg.num_steps :]

        # 3. GAE, truncation bootstrapped, the trace cut at every episode end (a fleet's
        # episode ends for all its robots at once: the flags are broadcast over robots)
        terminated, done = traj.terminated, traj.terminated | traj.truncated
        if self.num_agents is not None:
            terminated, done = (jnp.broadcast_to(x[..., None], traj.reward.shape) for x in (terminated, done))
        advantages = gae(
            traj.reward * hyper.reward_scale,
            values,
            next_values,
            terminated if cfg.bootstrap_truncated else done,
            done,
            hyper.gamma,
            hyper.gae_lambda,
        )
        returns = advantages + values

        # 4. minibatch epochs
        batch = {
            "obs": traj.obs,
            "action": traj.action,
            "log_prob": traj.log_prob,
            "advantage": advantages,
            "return": returns,
        }
        if self.centralized:
            batch["global_state"] = traj.global_state
        if planning:  # minibatches of whole environments, so that a leg's rows are neighbours (propagated once)
            batch = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), batch)
        batch = jax.tree.map(lambda x: x.reshape((cfg.steps_per_update,) + x.shape[2:]), batch)
        progress = update_index.astype(jnp.float32) / cfg.num_updates  # 0 at the first update
        learning_rate = linear_decay(hyper.learning_rate, progress) if cfg.anneal_lr else hyper.learning_rate
        ent_coef = linear_decay(hyper.ent_coef, progress) if cfg.anneal_ent else hyper.ent_coef
        hyper = hyper.replace(ent_coef=ent_coef)

        # A random permutation of the batch per epoch: argsort of random bits (of the environments with
        # encoder="propagation", each keeping its steps in order).
        if planning:
            envs = jnp.argsort(jax.random.bits(k_order, (cfg.update_epochs, cfg.num_envs)), axis=-1)
            orders = (envs[..., None] * cfg.num_steps + jnp.arange(cfg.num_steps)).reshape(cfg.update_epochs, -1)
        else:
            orders = jnp.argsort(jax.random.bits(k_order, (cfg.update_epochs, cfg.steps_per_update)), axis=-1)

        def epoch(carry, order):
            params, opt_state = carry
            minibatches = jax.tree.map(
                lambda x: x[order].reshape((cfg.num_minibatches, cfg.minibatch_size) + x.shape[1:]), batch
            )

            def minibatch_step(carry, mb):
                params, opt_state = carry
                grads, stats = jax.grad(self._loss, has_aux=True)(params, mb, hyper)
                grads, grad_norm = clip_by_global_norm(grads, hyper.max_grad_norm)
                updates, opt_state = self.adam.update(grads, opt_state, params)
                params = params - learning_rate * updates
                return (params, opt_state), {**stats, "grad_norm": grad_norm}

            return jax.lax.scan(minibatch_step, (params, opt_state), minibatches)

        (params, opt_state), loss_stats = jax.lax.scan(epoch, (runner.params, runner.opt_state), orders)

        explained = 1.0 - jnp.var(returns - values) / (jnp.var(returns) + 1e-8)
        events = {} if traj.events is None else jax.tree.map(jnp.sum, traj.events)
        metrics = {
            **sum_episode_sums(sums).as_metrics(),
            **events,
            **jax.tree.map(jnp.mean, loss_stats),
            "learning_rate": learning_rate,
            "ent_coef": ent_coef,
            "explained_variance": explained,
        }
        metrics = jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), metrics)
        new_runner = runner.replace(
            params=params, opt_state=opt_state, env_state=env_state, obs=obs, episode_stats=stats, key=key
        )
        return new_runner, metrics

    def _loss(self, params: jax.Array, mb: dict[str, jax.Array], hyper: PPOHyper):
        networks = self.unflatten(params)
        inputs = self.network_inputs(networks["actor"], mb["obs"], by_run=True)  # once for both networks
        logits = self.forward(networks["actor"], mb["obs"], inputs=inputs)
        if self.continuous:
            log_prob = self.gaussian_log_prob(networks["actor"], logits, mb["action"])
            # A diagonal Gaussian's entropy: the same for every state (its spread is state-independent).
            entropy = (networks["actor"]["log_std"] + 0.5 * math.log(2 * math.pi * math.e)).sum()
        else:
            log_probs = jax.nn.log_softmax(logits)
            log_prob = jnp.take_along_axis(log_probs, mb["action"][..., None], axis=-1)[..., 0]
            entropy = -(jnp.exp(log_probs) * log_probs).sum(-1).mean()
        log_ratio = log_prob - mb["log_prob"]
        ratio = jnp.exp(log_ratio)
        advantage = mb["advantage"]
        if self.config.normalize_advantages:
            advantage = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
        clipped = jnp.clip(ratio, 1.0 - hyper.clip_eps, 1.0 + hyper.clip_eps)
        policy_loss = -jnp.minimum(ratio * advantage, clipped * advantage).mean()
        value = self.forward(networks["critic"], mb["obs"], mb.get("global_state"), inputs=inputs)[..., 0]
        value_loss = jnp.square(mb["return"] - value).mean()
        loss = policy_loss - hyper.ent_coef * entropy + hyper.vf_coef * value_loss
        stats = {
            "loss": loss,
            "policy_loss": policy_loss,
            "value_loss": value_loss,
            "entropy": entropy,
            "approx_kl": ((ratio - 1.0) - log_ratio).mean(),
            "clip_fraction": (jnp.abs(ratio - 1.0) > hyper.clip_eps).astype(jnp.float32).mean(),
        }
        return loss, stats

    # ------------------------------------------------------------ inference
    def network_params(self, runner: PPORunner) -> Any:
        return self.unflatten(runner.params)["actor"]

    def greedy_action(self, network_params: Any, obs: jax.Array) -> jax.Array:
        """The policy's mode: the most likely action, or the Gaussian's mean clipped to the box."""
        out = self.forward(network_params, obs)
        if self.continuous:
            return jnp.clip(out, self.action_low, self.action_high)
        return jnp.argmax(out, axis=-1).astype(jnp.int32)

    has_stochastic_policy = True

    def sample_action(self, network_params: Any, obs: jax.Array, key: jax.Array) -> jax.Array:
        """A draw from the policy (``obs`` may carry batch axes), clipped to the box if continuous."""
        out = self.forward(network_params, obs)
        if self.continuous:
            noise = jax.random.normal(key, out.shape, jnp.float32)
            return jnp.clip(out + jnp.exp(network_params["log_std"]) * noise, self.action_low, self.action_high)
        return jax.random.categorical(key, out, axis=-1).astype(jnp.int32)

    @staticmethod
    def gaussian_log_prob(actor: Any, mean: jax.Array, action: jax.Array) -> jax.Array:
        """Log-density of ``action`` under the diagonal Gaussian of ``mean`` and the actor's log std."""
        log_std = actor["log_std"]
        z = (action - mean) * jnp.exp(-log_std)
        return (-0.5 * jnp.square(z) - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)

def gae(
    reward: jax.Array,
    value: jax.Array,
    next_value: jax.Array,
    terminated: jax.Array,
    done: jax.Array,
    gamma: jax.Array,
    gae_lambda: jax.Array,
) -> jax.Array:
    """Generalized advantage estimates over a ``(T, ...)`` rollout.

    ``next_value[t]`` is the value of the state transition ``t`` reached (before
    any auto-reset). ``terminated`` zeroes it (a delivery has no future);
    ``done`` (terminated or truncated) cuts the lambda trace, because the next
    row of the rollout belongs to a new episode. A truncated step therefore
    still bootstraps: ``A = r + gamma V(s_T) - V(s)``.
    """
    not_terminated = 1.0 - terminated.astype(jnp.float32)
    not_done = 1.0 - done.astype(jnp.float32)
    delta = reward + gamma * not_terminated * next_value - value

    def backward(carry, x):
        delta_t, not_done_t = x
        advantage = delta_t + gamma * gae_lambda * not_done_t * carry
        return advantage, advantage

    _, advantages = jax.lax.scan(backward, jnp.zeros_like(delta[0]), (delta, not_done), reverse=True)
    return advantages


SPEC = AlgoSpec(
    name="ppo",
    config_cls=PPOConfig,
    algorithm_cls=PPO,
    presets=PRESETS,
    default_env="Warehouse-12x12-v0",
    default_preset="default",
    default_num_seeds=4,
    study=STUDY_TABLE3,
    env_presets={"Procedural-Warehouse-v0": "procedural", "Fleet-12x12-v0": "fleet", "Fleet-32x32-v0": "fleet",
                 **{f"Continuous-{name}": "continuous" for name in (
                     "Warehouse-8x8-v0", "Warehouse-12x12-v0", "Procedural-Warehouse-v0")},
                 DYNAMIC_NAME: "continuous_dynamic"},
    family_presets={"rware": "rware"},
    env_defaults={"Fleet-12x12-v0": FLEET_ENV_DEFAULTS, "Fleet-32x32-v0": FLEET_ENV_DEFAULTS,
                  "Procedural-Warehouse-v0": PROCEDURAL_ENV_DEFAULTS,
                  **{name: CONTINUOUS_ENV_DEFAULTS for name in CONTINUOUS_NAMES}, DYNAMIC_NAME: DYNAMIC_ENV_DEFAULTS,
                  PROCEDURAL_NAME: CONTINUOUS_PROCEDURAL_ENV_DEFAULTS},
    preset_env_defaults=PRESET_ENV_DEFAULTS,
)


def make_train(config: PPOConfig, env: Environment | None = None, env_params: Any | None = None):
    """``train(key) -> (runner, metrics)``: a whole PPO run of one seed as one pure, jittable function.

    The environment defaults to ``Warehouse-12x12-v0``. ``jax.vmap`` it over keys
    for many seeds (:func:`~wrl_jax.agents.base.make_train_seeds` does).
    """
    from wrl_jax.core.registry import make

    if env is None:
        env, env_params = make("Warehouse-12x12-v0")
    elif env_params is None:
        raise ValueError("pass env_params together with env")
    return base.make_train(PPO(config, env, env_params))
