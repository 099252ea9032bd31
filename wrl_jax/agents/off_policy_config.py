"""SAC's and TD3's settings: what fixes the program (static config fields), what is traced
(:class:`SACHyper`, :class:`TD3Hyper`, vmappable for a sweep), and the presets a command starts from.

Both learners share every setting of an off-policy loop (:class:`OffPolicyConfig`); each adds
its own. As for PPO and DQN, each field is declared once: a ``Hyper`` field is traced, every
other field is static.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar

import jax
from flax import struct

from wrl_jax.agents.common import (
    check_hidden_sizes,
    check_hyper,
    check_positive_ints,
    hyper_from_config,
    traced_fields,
)
from wrl_jax.agents.networks import ACTIVATIONS


@struct.dataclass
class SACHyper:
    """SAC's traced hyperparameters (float32 scalars, or batched along a sweep axis)."""

    learning_rate: jax.Array
    gamma: jax.Array
    tau: jax.Array
    reward_scale: jax.Array
    initial_alpha: jax.Array


@struct.dataclass
class TD3Hyper:
    """TD3's traced hyperparameters (float32 scalars, or batched along a sweep axis)."""

    learning_rate: jax.Array
    gamma: jax.Array
    tau: jax.Array
    reward_scale: jax.Array
    policy_noise: jax.Array
    noise_clip: jax.Array
    exploration_noise: jax.Array


@dataclasses.dataclass(frozen=True)
class OffPolicyConfig:
    """What every off-policy actor-critic run needs.

    Static (shapes and program structure):
        total_timesteps: environment transitions per seed (all environments together).
        num_envs: environments stepped together in one vector step.
        hidden_sizes: hidden widths of the actor and of each critic.
        activation: ``"relu"`` or ``"tanh"``.
        buffer_size: replay capacity in transitions.
        batch_size: transitions per gradient step.
        train_freq: vector steps collected per update.
        gradient_steps: gradient steps per update (once ``learning_starts`` is passed).
        learning_starts: transitions collected with uniformly random actions before learning.
        noise_correlation: ``rho`` in [0, 1): the exploration noise is ``rho`` times the last
            step's plus fresh noise (0: independent every step).
        n_step: rewards summed per learning target (1: the one-step target; more carries rewards
            back faster, stopping at an episode's end).
        adam_eps: Adam's epsilon.
        anneal_lr: decay the step size linearly towards 0 over the end of the run (every network's and SAC's
            temperature's), as PPO's ``anneal_lr`` does: the last policy then moves less between snapshots.
        anneal_from: the fraction of the run's updates (counted from the first, warm-up included) after which
            the decay starts (0: from the first); needs ``anneal_lr``.

    Traced:
        learning_rate: Adam step size of every network (and of SAC's temperature); the starting one under
            ``anneal_lr``.
        gamma: discount.
        tau: Polyak step of the target networks.
        reward_scale: rewards are multiplied by it before learning.
    """

    hyper_cls: ClassVar[type] = SACHyper
    owner: ClassVar[str] = "OffPolicyConfig"

    total_timesteps: int = 200_000
    num_envs: int = 16
    hidden_sizes: tuple[int, ...] = (256, 256)
    activation: str = "relu"
    buffer_size: int = 200_000
    batch_size: int = 256
    train_freq: int = 1
    gradient_steps: int = 1
    learning_starts: int = 5_000
    n_step: int = 1
    noise_correlation: float = 0.0
    adam_eps: float = 1e-8
    anneal_lr: bool = False
    anneal_from: float = 0.0
    # traced
    learning_rate: float = 3e-4
    gamma: float = 0.99
    tau: float = 0.005
    reward_scale: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden_sizes", tuple(int(w) for w in self.hidden_sizes))

    @property
    def steps_per_update(self) -> int:
        """Transitions one update collects (``train_freq`` vector steps)."""
        return self.num_envs * self.train_freq

    @property
    def num_updates(self) -> int:
        return self.total_timesteps // self.steps_per_update

    def replace(self, **changes: Any):
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    def hyper(self, **overrides: Any):
        """The traced hyperparameters, any of them overridden (a sweep's arrays)."""
        return hyper_from_config(self.hyper_cls, self, self.owner, **overrides)

    def validate(self) -> None:
        """Raise a ``ValueError`` naming the first problem, before anything compiles."""
        owner = self.owner
        check_positive_ints(owner, self, ("total_timesteps", "num_envs", "buffer_size", "batch_size", "train_freq",
                                          "gradient_steps", "n_step", *self.extra_positive_ints()))
        starts = self.learning_starts
        if isinstance(starts, bool) or not isinstance(starts, int) or starts < 0:
            raise ValueError(f"{owner}.learning_starts must be a non-negative integer, got {starts!r}")
        check_hidden_sizes(owner, self.hidden_sizes)
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"{owner}.activation must be one of {sorted(ACTIVATIONS)}, got {self.activation!r}")
        if self.buffer_size < self.steps_per_update:
            raise ValueError(f"{owner}.buffer_size ({self.buffer_size}) must hold one update's transitions "
                             f"(num_envs * train_freq = {self.steps_per_update})")
        if self.total_timesteps < self.steps_per_update:
            raise ValueError(f"{owner}.total_timesteps ({self.total_timesteps}) is less than one update "
                             f"(num_envs * train_freq = {self.steps_per_update} transitions)")
        names = traced_fields(self.hyper_cls)
        for name in (*names, "adam_eps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"{owner}.{name} must be a finite number, got {value!r}")
        check_hyper(f"{owner}", **{name: getattr(self, name) for name in names})
        if self.adam_eps <= 0:
            raise ValueError(f"{owner}.adam_eps must be positive, got {self.adam_eps}")
        start = self.anneal_from
        if isinstance(start, bool) or not isinstance(start, (int, float)) or not 0.0 <= start < 1.0:
            raise ValueError(f"{owner}.anneal_from must be in [0, 1), got {start!r}")
        if not isinstance(self.anneal_lr, bool):
            raise ValueError(f"{owner}.anneal_lr must be True or False, got {self.anneal_lr!r}")
        if start and not self.anneal_lr:
            raise ValueError(f"{owner}.anneal_from={start!r} needs anneal_lr=True (--anneal-lr): without it the step "
                             f"size is constant")
        rho = self.noise_correlation
        if isinstance(rho, bool) or not isinstance(rho, (int, float)) or not 0.0 <= rho < 1.0:
            raise ValueError(f"{owner}.noise_correlation must be in [0, 1), got {rho!r}")

    def extra_positive_ints(self) -> tuple[str, ...]:
        return ()


@dataclasses.dataclass(frozen=True)
class SACConfig(OffPolicyConfig):
    """Soft actor-critic (Haarnoja et al. 2018, the version with a learned temperature).

    Static:
        learn_alpha: learn the temperature towards the target entropy (otherwise it stays ``initial_alpha``).
        target_entropy: the entropy of the environment's actions the temperature steers towards
            (``None``: ``-|A|``, the SAC paper's; the warehouse's presets set -6).
        actor_average: 0 evaluates the actor as trained; above 0 (0.001 in the warehouse's presets), a Polyak
            average of the actor (this rate per gradient step) is kept beside it and is the policy evaluated and
            saved as greedy.
            The average only reads the actor: training is unchanged (up to float rounding).

    Traced:
        initial_alpha: the temperature at the start.
    """

    hyper_cls: ClassVar[type] = SACHyper
    owner: ClassVar[str] = "SACConfig"

    learn_alpha: bool = True
    target_entropy: float | None = None
    initial_alpha: float = 1.0
    actor_average: float = 0.0

    def validate(self) -> None:
        super().validate()
        rate = self.actor_average
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0.0 <= rate <= 1.0:
            raise ValueError(f"{self.owner}.actor_average must be in [0, 1] (0: no average), got {rate!r}")
        value = self.target_entropy
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not math.isfinite(value)):
            raise ValueError(f"{self.owner}.target_entropy must be a finite number or None (-|A|), got {value!r}")


@dataclasses.dataclass(frozen=True)
class TD3Config(OffPolicyConfig):
    """Twin delayed DDPG (Fujimoto et al. 2018).

    Static:
        policy_delay: gradient steps per actor (and target) update.
        preactivation_penalty: weight of the mean square of the actor's output before its tanh, added to the
            actor's loss (0: none, the term left out of the program; the logged ``actor_loss`` includes it).
            Why: an actor pushed deep into the squash gets no gradient through it (1 - tanh^2 is nearly 0) and
            can stay there, commanding the same action in every state.
        greedy_target: the greedy policy (evaluated, and saved as greedy) is the target actor, the Polyak average
            of the actor (``tau`` per actor update) that TD3 keeps for its targets, not the actor as trained.
            Why: one late actor update can leave a snapshot that stops at a shelf; the average moves slowly.
            Training is unchanged. False here, so that runs saved before the field keep their actor;
            :data:`TD3_DEFAULT` sets True.

    Traced:
        policy_noise: standard deviation of the target policy's smoothing noise.
        noise_clip: the smoothing noise is clipped to this magnitude.
        exploration_noise: standard deviation of the Gaussian added to actions while collecting.
    """

    hyper_cls: ClassVar[type] = TD3Hyper
    owner: ClassVar[str] = "TD3Config"

    policy_delay: int = 2
    policy_noise: float = 0.2
    noise_clip: float = 0.5
    exploration_noise: float = 0.1
    preactivation_penalty: float = 0.0
    greedy_target: bool = False

    def extra_positive_ints(self) -> tuple[str, ...]:
        return ("policy_delay",)

    def validate(self) -> None:
        super().validate()
        penalty = self.preactivation_penalty
        if isinstance(penalty, bool) or not isinstance(penalty, (int, float)) or not 0.0 <= penalty < float("inf"):
            raise ValueError(f"{self.owner}.preactivation_penalty must be a finite number >= 0, got {penalty!r}")
        if not isinstance(self.greedy_target, bool):
            raise ValueError(f"{self.owner}.greedy_target must be True or False, got {self.greedy_target!r}")


SB3_SAC = SACConfig(
    # Stable-Baselines3 2.x SAC defaults (what the SB3 comparison runs on the Gymnasium adapter):
    num_envs=1, train_freq=1, gradient_steps=1, batch_size=256, buffer_size=1_000_000, learning_starts=100,
    hidden_sizes=(256, 256), learning_rate=3e-4, gamma=0.99, tau=0.005, initial_alpha=1.0, learn_alpha=True,
    total_timesteps=200_000,
)
"""SB3's SAC defaults: the same hyperparameters on both sides of a speed comparison."""

SAC_DEFAULT = SACConfig(
    num_envs=16, train_freq=1, gradient_steps=2, batch_size=256, hidden_sizes=(128, 128), buffer_size=200_000,
    learning_starts=5_000, learning_rate=1e-3, gamma=0.99, tau=0.005,
    reward_scale=0.1,  # the warehouse's rewards reach 200: Q-values of tens, not thousands
    initial_alpha=0.1, total_timesteps=400_000,  # 12x12 over the stop, 4 seeds on 2 cores: 7-7.5 min with compile
    target_entropy=-6.0,  # -3|A| (the paper: -|A|): the greedy command saturates (96.5 steps per item, not 99)
    actor_average=0.001,  # the greedy policy is a Polyak average of the actor: one grazing step flips a snapshot
)
"""Ours for the continuous warehouse: on 12x12 with :data:`OFF_POLICY_ENV_DEFAULTS` (the route, the safety stop), seeds 0-31,
``train_sac.py``'s split over 2 cores: every item without a contact on 31 of 32 seeds (on one device 32; the route
alone: 29; the paper's target entropy without the average, the route alone: 16 of 24);
bench/results/continuous/NOTES.md."""

TD3_DEFAULT = TD3Config(
    num_envs=16, train_freq=1, gradient_steps=2, batch_size=256, hidden_sizes=(128, 128), buffer_size=200_000,
    learning_starts=5_000, learning_rate=1e-3, gamma=0.99, tau=0.005, reward_scale=0.1,
    total_timesteps=800_000,  # over the safety stop: 24 of 32 seeds solved at 400k (the actor), 32 at 800k
    exploration_noise=0.3,  # 0.1 (the TD3 paper's) left the 8x8 map's far items unfound: 65 % against 97.5 %
    preactivation_penalty=0.001,  # without it 3 seeds of 12 saturate their actor and never deliver
    greedy_target=True,  # the target actor as the greedy policy: 12x12 solved on 32 of 32 seeds, the actor 30
)
"""Ours for the continuous warehouse, the same loop as SAC's default: on 12x12 over the safety stop
(:data:`OFF_POLICY_ENV_DEFAULTS`), seeds 0-31, split over 2 cores: every item without a contact on 32 of 32
seeds (bench/results/continuous/NOTES.md)."""

DYNAMIC_NAME = "Continuous-Warehouse-12x12-Dynamic-v0"
PROCEDURAL_NAME = "Continuous-Procedural-Warehouse-v0"
CONTINUOUS_NAMES = ("Continuous-Warehouse-8x8-v0", "Continuous-Warehouse-12x12-v0", DYNAMIC_NAME, PROCEDURAL_NAME)
"""The continuous warehouse's registered ids (the study's maps and the procedural variant), where PPO trains with
:data:`CONTINUOUS_ENV_DEFAULTS` (:data:`DYNAMIC_ENV_DEFAULTS` with moving obstacles,
:data:`CONTINUOUS_PROCEDURAL_ENV_DEFAULTS` on the procedural variant), SAC and TD3 with
:data:`OFF_POLICY_ENV_DEFAULTS`."""
CONTINUOUS_ENV_DEFAULTS = {"observe_target": True}
"""What a training command gives the continuous warehouse unless its flags say otherwise: the target seen
from the robot after the contract's observation (derived from it; docs/continuous.md has the measurements)."""
ROUTE_ENV_DEFAULTS = {**CONTINUOUS_ENV_DEFAULTS, "shaping": "geodesic", "observe_route": True}
"""The shaping and the observed way around the shelves (with the target alone SAC solved 8x8 but not 12x12 in 600k
steps; with the way, 12x12 on 4 of 4 seeds): under :data:`GUARDED_ENV_DEFAULTS`."""
ROUTE_NAMES = ("Continuous-Warehouse-8x8-v0", "Continuous-Warehouse-12x12-v0")
"""The study's static maps, where SAC and TD3 see the route by default (as every learner does with moving obstacles
and on the procedural variant)."""
GUARDED_ENV_DEFAULTS = {**ROUTE_ENV_DEFAULTS, "observe_obstacles": True, "safety_stop": True}
"""The route, the moving obstacles seen apart from the shelves with whether the last step was blocked, and the safety
stop under the policy with how long it has held the robot: every learner's defaults on the moving obstacles' map
(:data:`DYNAMIC_ENV_DEFAULTS`) and on the procedural variant (:data:`CONTINUOUS_PROCEDURAL_ENV_DEFAULTS`), both with
the stop's escape, and SAC's and TD3's on the study's static maps (:data:`OFF_POLICY_ENV_DEFAULTS`), without it: their
32-seed results were measured before the escape existed."""
CONTINUOUS_PROCEDURAL_ENV_DEFAULTS = {**GUARDED_ENV_DEFAULTS, "escape_after": 10}
"""Every learner's defaults on the procedural variant: the target, the geodesic shaping and the route from every pool
slot's own fields, and the safety stop (which reads the episode's randomized gains and the step's noise) with its held
value in view and its escape from standstills. 4 seeds, of the items of 256 held-out layouts: PPO (2M steps) 100 %
delivered (without the escape 99.6 %; the route without the stop: 99.9 %, 0.82 contact steps per episode; the target
alone 68.2 %), SAC (400k) and TD3 (800k) 99.98 % (without the escape 99.8 % and 99.7 %), no contact; docs/continuous.md."""
DYNAMIC_ENV_DEFAULTS = {**GUARDED_ENV_DEFAULTS, "escape_after": 10}
"""Every learner's defaults on the moving obstacles' map, with the stop's escape from standstills (4 seeds, no contact
in 640 greedy episodes, every seed delivers every one: PPO, 3M steps, 105.3 steps per delivery; SAC, 800k, 105.2;
TD3, 800k, 107.3; without the escape 99.1, 99.7 and 99.4 % delivered; docs/continuous.md)."""
OFF_POLICY_ENV_DEFAULTS = {name: GUARDED_ENV_DEFAULTS if name in ROUTE_NAMES else
                           DYNAMIC_ENV_DEFAULTS if name == DYNAMIC_NAME else
                           CONTINUOUS_PROCEDURAL_ENV_DEFAULTS for name in CONTINUOUS_NAMES}
"""SAC's and TD3's environment defaults per id: the route and the safety stop with its held value on the static maps
too, and on the procedural variant. 12x12, seeds 0-31: SAC 31 of 32 solved (on one device 32, against 29
with the route alone; the held value lets a policy without memory back out of a standstill the stop holds), TD3's
default 32 of 32 (its actor as the greedy policy: 30; the route alone, 400k, no penalty: 4 of 8);
bench/results/continuous/NOTES.md."""

SAC_DYNAMIC = dataclasses.replace(SAC_DEFAULT, total_timesteps=800_000)
"""SAC's default on the moving obstacles' map: twice the static maps' steps (4 seeds, split over 2 cores: 100 %
delivered and no contact with the stop's escape, 16.3 min; before the escape 99.7 % in 19.7 min, one device 99.5 % in
27.6 min; bench/results/continuous/NOTES.md)."""

SAC_PRESETS: dict[str, SACConfig] = {"default": SAC_DEFAULT, "sb3": SB3_SAC, "dynamic": SAC_DYNAMIC}
TD3_PRESETS: dict[str, TD3Config] = {"default": TD3_DEFAULT}
"""One preset for every map: TD3's default already trains the moving obstacles' map's 800k steps."""
