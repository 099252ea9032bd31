"""PPO's actor and critic: two MLPs kept as one flat parameter vector, their inputs, their FLOPs, and the
memory the planning policy keeps across the steps of an evaluation.

:class:`ActorCritic` is a mixin of :class:`~wrl_jax.agents.ppo.PPO` (rejax's shape: the update in
the algorithm, the networks beside it). It reads the algorithm's ``config`` and ``env``; the
inputs are the observation as it is, one-hot coordinates (``obs_encoding="onehot"``, a gather
in the first layer), or the propagation encoder's values around the robot
(``encoder="propagation"``), and with a centralized critic the fleet's global state.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp

from wrl_jax.agents import propagation
from wrl_jax.agents.encoding import agent_observation_size, encoded_size, onehot_coordinates, onehot_rows
from wrl_jax.agents.initializers import init_mlp_params
from wrl_jax.agents.networks import ACTIVATIONS, mlp_forward_flops
from wrl_jax.agents.ppo_config import PPOConfig
from wrl_jax.core.environment import Environment
from wrl_jax.core.evaluation import PolicyMemory


class ActorCritic:
    """The network methods of :class:`~wrl_jax.agents.ppo.PPO` (``config``, ``env``, ``num_agents`` and
    ``centralized`` are the algorithm's)."""

    def setup_networks(self, config: PPOConfig, env: Environment) -> None:
        """The networks' static layout: inputs (encoding, propagation features, global state), shapes."""
        self.activation = ACTIVATIONS[config.activation]
        # A box of actions: a diagonal Gaussian (the actor gives the mean, a learned state-independent
        # log standard deviation the spread); otherwise a categorical over env.num_actions.
        self.policy_outputs = env.num_actions
        self.global_size = int(env.global_state_size()) if config.critic == "centralized" else 0
        self.coordinates = onehot_coordinates(env, config.obs_encoding)
        self.map_layout = None  # (offset, H, W) of the map the propagation encoder plans over
        if config.encoder == "propagation":
            layout = env.map_observation() if hasattr(env, "map_observation") else None
            self.map_layout = propagation.check_map_layout(layout, env.name, agent_observation_size(env))
        # The runner keeps actor and critic parameters as one flat vector, so the
        # optimizer and the gradient clip are a few fused kernels instead of a
        # few per weight array: a third fewer kernels for XLA to compile.
        self.num_features = encoded_size(env, config.obs_encoding)
        if self.map_layout is not None:  # the map is replaced by the values around the robot
            self.num_features += propagation.NUM_FEATURES - 3 * self.map_layout[1] * self.map_layout[2]
        template = jax.eval_shape(self._init_networks, jax.random.PRNGKey(0))
        leaves, self._params_treedef = jax.tree_util.tree_flatten(template)
        self._param_shapes = [leaf.shape for leaf in leaves]
        self.num_params = sum(math.prod(shape) for shape in self._param_shapes)

    def _init_networks(self, key: jax.Array) -> dict[str, Any]:
        sizes = tuple(self.config.hidden_sizes)
        critic_inputs = self.num_features + self.global_size
        actor, critic = init_mlp_params(
            key, [(self.num_features, sizes, self.policy_outputs, 0.01), (critic_inputs, sizes, 1, 1.0)]
        )
        if self.continuous:
            actor["log_std"] = jnp.zeros((self.policy_outputs,), jnp.float32)
        if self.map_layout is not None:  # one propagation, the actor's, read by both
            actor["propagation"] = propagation.init_propagation()
        return {"actor": actor, "critic": critic}

    def network_inputs(self, actor: dict[str, Any], obs: jax.Array, by_run: bool = False) -> jax.Array:
        """What the MLPs read: ``obs`` itself, or with ``encoder="propagation"`` the observation
        with its map replaced by the values around the robot, propagated with the actor's
        learned costs (:func:`wrl_jax.agents.propagation.map_features`). The critic reads
        the same: one propagation per observation, and the value loss teaches the costs too.
        ``by_run``: a ``(N, obs)`` minibatch whose consecutive rows often share a leg (one
        propagation per run of them, the same values: :func:`~wrl_jax.agents.propagation.map_features_by_run`)."""
        if self.map_layout is None:
            return obs
        rounds, walls = self.config.propagation_rounds, self.config.propagation_walls
        if by_run and rounds == 0 and obs.ndim == 2:
            return propagation.map_features_by_run(actor["propagation"], obs, self.map_layout, walls=walls)
        return propagation.map_features(actor["propagation"], obs, self.map_layout, rounds, walls)

    def rollout_inputs(self, actor: dict[str, Any], obs: jax.Array, cache: Any = None) -> tuple[jax.Array, Any]:
        """``(inputs, cache)``: :meth:`network_inputs` of a batch of environments' observations, propagating
        only those whose leg (map and target) changed since ``cache`` (``None``: all of them)."""
        if self.config.propagation_rounds:  # a fixed number of rounds: no cache (the old programs)
            return self.network_inputs(actor, obs), cache
        if cache is None:
            cache = propagation.init_leg_cache(obs, self.map_layout)
        return propagation.map_features_cached(actor["propagation"], obs, self.map_layout, cache,
                                               walls=self.config.propagation_walls)

    def policy_memory(self) -> PolicyMemory | None:
        """With ``encoder="propagation"`` (converged): each episode's values, propagated once per leg."""
        if self.map_layout is None or self.config.propagation_rounds:
            return None

        def init(network_params, obs):
            return propagation.init_leg_cache(obs, self.map_layout)

        def logits(network_params, memory, obs):
            inputs, memory = propagation.map_features_cached(network_params["propagation"], obs, self.map_layout,
                                                             memory, walls=self.config.propagation_walls)
            return self.forward(network_params, obs, inputs=inputs), memory

        def greedy(network_params, memory, obs):
            out, memory = logits(network_params, memory, obs)
            return jnp.argmax(out, axis=-1).astype(jnp.int32), memory

        def sample(network_params, memory, obs, keys):
            out, memory = logits(network_params, memory, obs)
            draw = jax.vmap(lambda key, row: jax.random.categorical(key, row, axis=-1).astype(jnp.int32))
            return draw(keys, out), memory

        return PolicyMemory(init, greedy, sample)

    def forward(
        self,
        network: dict[str, Any],
        obs: jax.Array,
        global_state: jax.Array | None = None,
        *,
        inputs: jax.Array | None = None,
    ) -> jax.Array:
        """One network (actor logits or critic value) on observations ``(..., obs_size)``.

        With ``obs_encoding="raw"`` this is exactly ``networks.MLP.apply``. With
        ``"onehot"`` the first layer multiplies a one-hot vector, so it is computed
        as what that product is, a sum of a few kernel rows (a gather: 6 for the
        warehouse), not as a dense matmul over the mostly-zero inputs.

        ``global_state`` ``(..., G)`` (the centralized critic only) is the rest of
        the first layer's input, shared by the ``K`` agents of ``obs`` ``(..., K, obs_size)``:
        its product with the kernel is computed once per environment and broadcast.

        ``inputs``: :meth:`network_inputs` of ``obs``, when the caller computed them
        already (with ``encoder="propagation"`` the critic has no propagation of its own
        and needs them). The actor then adds its learned multiple of the action features
        to its logits: a policy that follows the propagated values from the start.
        """
        if inputs is None:
            if self.map_layout is not None and "propagation" not in network:
                raise ValueError("with encoder='propagation' the critic reads the actor's propagation: "
                                 "pass inputs=network_inputs(actor, obs)")
            inputs = self.network_inputs(network, obs)
        obs = inputs
        layers = [network["params"][f"Dense_{i}"] for i in range(len(network["params"]))]
        first = layers[0]
        kernel = first["kernel"] if global_state is None else first["kernel"][: self.num_features]
        if self.config.obs_encoding == "raw":
            x = obs @ kernel + first["bias"]
        else:
            count, values = self.coordinates[0], self.coordinates[1]
            rows = onehot_rows(obs, self.coordinates)  # (..., count) row indices into the kernel
            extra = obs[..., count:]  # what follows the coordinates (the carrying flag, a window)
            x = kernel[rows].sum(axis=-2) + extra @ kernel[count * values :] + first["bias"]
        if global_state is not None:
            x = x + (global_state @ first["kernel"][self.num_features :])[..., None, :]
        for layer in layers[1:]:
            x = self.activation(x) @ layer["kernel"] + layer["bias"]
        if self.map_layout is not None and "propagation" in network:
            x = x + network["propagation"]["prior"] * propagation.action_features(obs)
        return x

    def flatten(self, networks: dict[str, Any]) -> jax.Array:
        """``{"actor": ..., "critic": ...}`` flax parameter trees -> the runner's flat vector."""
        return jnp.concatenate([leaf.reshape(-1) for leaf in jax.tree_util.tree_leaves(networks)])

    def unflatten(self, flat: jax.Array) -> dict[str, Any]:
        """The runner's flat vector -> ``{"actor": ..., "critic": ...}`` flax parameter trees."""
        leaves, offset = [], 0
        for shape in self._param_shapes:
            size = math.prod(shape)
            leaves.append(flat[offset : offset + size].reshape(shape))
            offset += size
        return jax.tree_util.tree_unflatten(self._params_treedef, leaves)

    def flops_per_update(self) -> int:
        cfg = self.config
        # The one-hot first layer is a gather-sum, about the cost of a dense layer on the raw values.
        obs, hidden, actions = agent_observation_size(self.env), tuple(cfg.hidden_sizes), self.policy_outputs
        if self.map_layout is not None:  # the MLPs see the features, not the map; the actor's propagation
            _, height, width = self.map_layout  # is counted with the actor, the critic shares it
            obs = self.num_features
            # Converged, the propagation runs once per leg of an episode for as many rounds as the leg's
            # longest route: data-dependent, so not counted (the count is then the MLPs', a lower bound).
            rounds = cfg.propagation_rounds
            plan = propagation.propagation_forward_flops(height, width, rounds) if rounds else 0
        else:
            plan = 0
        actor = mlp_forward_flops(obs, hidden, actions) + plan
        critic = mlp_forward_flops(obs, hidden, 1)
        # Network rows: one per agent; the centralized critic's global part once per environment step.
        n = cfg.steps_per_update * (self.num_agents or 1)
        if self.centralized:
            critic += 2 * self.global_size * hidden[0] // (self.num_agents or 1)
        rollout = n * actor
        values = 2 * n * critic
        train = cfg.update_epochs * n * 3 * (actor + critic)  # forward + backward ~ 3 forwards
        return rollout + values + train
