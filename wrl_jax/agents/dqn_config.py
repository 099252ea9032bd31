"""DQN's settings: what fixes the program (static :class:`DQNConfig` fields), what is traced
(:class:`DQNHyper`, vmappable for a sweep), and the presets a command starts from.

Each field is declared once: a :class:`DQNHyper` field is traced, every other field is static.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

import jax
from flax import struct

from wrl_jax.agents.common import (
    check_hidden_sizes,
    check_hyper,
    check_positive_ints,
    hyper_from_config,
    traced_fields,
)

LossName = Literal["huber", "mse"]


@struct.dataclass
class DQNHyper:
    """The traced hyperparameters of one run (float32 scalars, or batched for a sweep).

    These fields are the one declaration of what is traced; every other
    :class:`DQNConfig` field is static.
    """

    learning_rate: jax.Array
    gamma: jax.Array
    tau: jax.Array
    exploration_initial_eps: jax.Array
    exploration_final_eps: jax.Array
    exploration_fraction: jax.Array
    max_grad_norm: jax.Array
    huber_delta: jax.Array
    reward_scale: jax.Array


# ---------------------------------------------------------------------- config
@dataclasses.dataclass(frozen=True)
class DQNConfig:
    """Everything one DQN run needs.

    Static fields fix shapes and program structure; fields marked *traced*
    become :class:`DQNHyper` arrays in the runner state and can be swept with
    ``vmap`` without recompiling.

    Attributes:
        total_timesteps: environment transitions per seed (all environments together).
        num_envs: environments stepped together in one vector step.
        hidden_sizes: widths of the Q-network's hidden layers.
        activation: ``"relu"`` or ``"tanh"``.
        buffer_size: replay capacity in transitions.
        batch_size: transitions per gradient step.
        train_freq: vector steps collected between two training phases.
        gradient_steps: gradient steps per training phase.
        learning_starts: transitions collected before the first gradient step
            (before that, actions are uniformly random, as in SB3).
        target_update_interval: transitions between two target updates.
        double_dqn: choose the bootstrap action with the online network.
        loss: ``"huber"`` (SB3's smooth L1, delta ``huber_delta``) or ``"mse"``.
        adam_eps: Adam's epsilon (PyTorch's default 1e-8, what SB3's DQN uses).
        anneal_lr: decay the learning rate linearly to 0 over the run (SB3's
            constant rate when False).
        learning_rate: *traced*, Adam step size.
        gamma: *traced*, discount.
        tau: *traced*, target update ``target <- tau * online + (1 - tau) * target``;
            1.0 is a hard copy.
        exploration_initial_eps / exploration_final_eps: *traced*, epsilon goes
            linearly from the first to the second ...
        exploration_fraction: *traced*, ... over this fraction of ``total_timesteps``.
        max_grad_norm: *traced*, global gradient-norm clip.
        huber_delta: *traced*, where the Huber loss turns linear.
        reward_scale: *traced*, rewards are multiplied by it before learning (Q-values
            are in scaled units; the greedy policy is unchanged by a positive scale).
    """

    total_timesteps: int = 500_000
    num_envs: int = 1
    hidden_sizes: tuple[int, ...] = (256, 256)
    activation: str = "relu"
    buffer_size: int = 100_000
    batch_size: int = 128
    train_freq: int = 4
    gradient_steps: int = 1
    learning_starts: int = 100
    target_update_interval: int = 10_000
    double_dqn: bool = False
    loss: LossName = "huber"
    adam_eps: float = 1e-8
    anneal_lr: bool = False
    # traced
    learning_rate: float = 1e-3
    gamma: float = 0.99
    tau: float = 1.0
    exploration_initial_eps: float = 1.0
    exploration_final_eps: float = 0.02
    exploration_fraction: float = 0.1
    max_grad_norm: float = 10.0
    huber_delta: float = 1.0
    reward_scale: float = 1.0


    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden_sizes", tuple(int(w) for w in self.hidden_sizes))

    # -------------------------------------------------------------- derived
    @property
    def steps_per_update(self) -> int:
        """Transitions one update collects (``train_freq`` vector steps)."""
        return self.num_envs * self.train_freq

    @property
    def num_updates(self) -> int:
        return self.total_timesteps // self.steps_per_update

    def replace(self, **changes: Any) -> "DQNConfig":
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    def hyper(self, **overrides: Any) -> DQNHyper:
        """The traced hyperparameters (:class:`DQNHyper`), any of them overridden (a sweep's arrays)."""
        return hyper_from_config(DQNHyper, self, "DQN", **overrides)

    def validate(self) -> None:
        """Raise a ``ValueError`` naming the first problem, before anything compiles."""
        positive_ints = (
            "total_timesteps",
            "num_envs",
            "buffer_size",
            "batch_size",
            "train_freq",
            "gradient_steps",
            "target_update_interval",
        )
        check_positive_ints("DQNConfig", self, positive_ints)
        starts = self.learning_starts
        if isinstance(starts, bool) or not isinstance(starts, int) or starts < 0:
            raise ValueError(f"DQNConfig.learning_starts must be a non-negative integer, got {self.learning_starts!r}")
        check_hidden_sizes("DQNConfig", self.hidden_sizes)
        if self.activation not in ("relu", "tanh"):
            raise ValueError(f"DQNConfig.activation must be 'relu' or 'tanh', got {self.activation!r}")
        if self.loss not in ("huber", "mse"):
            raise ValueError(f"DQNConfig.loss must be 'huber' or 'mse', got {self.loss!r}")
        if self.buffer_size < self.num_envs:
            raise ValueError(
                f"DQNConfig.buffer_size ({self.buffer_size}) must hold at least one vector step "
                f"(num_envs={self.num_envs})"
            )
        if self.total_timesteps < self.steps_per_update:
            raise ValueError(
                f"DQNConfig.total_timesteps ({self.total_timesteps}) is less than one update "
                f"(num_envs * train_freq = {self.steps_per_update} transitions)"
            )
        for name in traced_fields(DQNHyper) + ("adam_eps",):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"DQNConfig.{name} must be a finite number, got {value!r}")
        check_hyper("DQN hyperparameter", **{name: getattr(self, name) for name in traced_fields(DQNHyper)})
        if self.adam_eps <= 0:
            raise ValueError(f"DQNConfig.adam_eps must be positive, got {self.adam_eps}")


PAPER = DQNConfig(
    # The study's Table 2 for DQN on 8x8, exactly:
    learning_rate=1e-3,
    hidden_sizes=(256, 256),
    gamma=0.99,
    buffer_size=100_000,
    batch_size=128,
    exploration_initial_eps=1.0,
    exploration_final_eps=0.02,
    num_envs=1,
    total_timesteps=500_000,
    # What the table omits, as Stable-Baselines3 2.x's DQN defaults would have it:
    train_freq=4,
    gradient_steps=1,
    learning_starts=100,
    target_update_interval=10_000,
    tau=1.0,  # hard copy
    exploration_fraction=0.1,
    loss="huber",  # SB3's smooth L1 loss
    huber_delta=1.0,
    max_grad_norm=10.0,
    adam_eps=1e-8,  # PyTorch Adam's default
    activation="relu",  # SB3's QNetwork activation
    double_dqn=False,
    anneal_lr=False,
    reward_scale=1.0,
)
"""The study's exact setting (Table 2), completed with SB3 2.x DQN defaults."""

DEFAULT = DQNConfig(
    num_envs=32,  # many environments per vector step: diverse data at no extra gradient cost
    train_freq=1,  # one gradient step per vector step (32 transitions)
    gradient_steps=1,
    batch_size=128,
    hidden_sizes=(128, 128),
    buffer_size=100_000,
    learning_starts=1_000,
    target_update_interval=32,  # every update (32 transitions) ...
    tau=0.02,  # ... a Polyak step
    gamma=0.8,
    learning_rate=1e-2,
    anneal_lr=True,
    exploration_initial_eps=1.0,
    exploration_final_eps=0.5,
    exploration_fraction=0.2,
    loss="huber",
    huber_delta=1.0,
    max_grad_norm=10.0,
    total_timesteps=160_000,  # 5,000 updates
)
"""Ours, tuned for Warehouse-8x8-v0 on a 2-core CPU (docs/dqn.md has the measurements)."""

PRESETS: dict[str, DQNConfig] = {"default": DEFAULT, "paper": PAPER}

STUDY_TABLE3 = {
    "Task Completion Rate": "100% (all 10 locations)",
    "Mean Steps to Complete": "14.7 steps (converged)",
    "Mean Episode Reward": "+356 (fully converged)",
    "Convergence Timestep": "~180,000 steps",
    "Obstacle Avoidance": "100% in all eval runs",
    "Stage Switching": "100% correct behavioural switching",
}
"""The study's Table 3 column for DQN on 8x8, printed beside ours."""
