"""PPO's settings: what fixes the program (static :class:`PPOConfig` fields), what is traced
(:class:`PPOHyper`, vmappable for a sweep), and the presets a command starts from.

Each field is declared once: a :class:`PPOHyper` field is traced, every other field is static.
"""

from __future__ import annotations

import dataclasses
from typing import Any

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

OBS_ENCODINGS = ("raw", "onehot")
ENCODERS = ("mlp", "propagation")
CRITICS = ("local", "centralized")

@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO settings. Defaults are the tuned ``default`` preset (see :data:`PRESETS`).

    Static (shapes and program structure):
        num_envs: environments stepped in parallel per seed.
        num_steps: rollout length per environment per update.
        num_minibatches: minibatches per epoch (must divide ``num_envs * num_steps``).
        update_epochs: passes over each rollout.
        hidden_sizes: hidden widths of both the actor and the critic MLP (separate networks).
        activation: ``"tanh"`` or ``"relu"``.
        total_timesteps: environment steps per seed; ``num_updates = total // (num_envs * num_steps)``.
        obs_encoding: what the networks see. ``"raw"``: the 7 observation values
            (the study's MLP). ``"onehot"``: each coordinate of the observation
            decoded back to its cell index and one-hot encoded (N + 1 values
            per coordinate, the extra one for "picked up"), plus the carrying
            flag: the same information, in a form an MLP separates linearly.
        anneal_lr: decay the learning rate linearly to 0 over the updates.
        anneal_ent: decay the entropy coefficient linearly to 0 over the updates
            (explore early, sharpen the policy whose argmax is evaluated late).
        normalize_advantages: standardize advantages within each minibatch.
        bootstrap_truncated: bootstrap a time-limit truncation from the value of
            the state it reached (correct); ``False`` treats it as termination
            (the common bug, kept to show the difference).
        critic: multi-agent environments only (the fleet, rware). ``"local"``: IPPO, the
            critic sees each robot's own observation; ``"centralized"``: MAPPO,
            the critic sees the robot's observation and the environment's
            global state (``env.global_state``), the actor still only its own.
        encoder: ``"mlp"``: the observation straight into the MLPs. ``"propagation"``:
            environments whose observation holds a map (``env.map_observation()``,
            e.g. ``Procedural-Warehouse-v0`` with ``observe_map=True``): values are first
            propagated from the target over the map with learned costs (the actor's
            parameters, :mod:`wrl_jax.agents.propagation`), and both MLPs see the rest
            of the observation and the values around the robot instead of the map.
        propagation_rounds: ``0`` (the default): propagate until the values stop changing, so they
            reach every cell whatever the route's length; ``k > 0``: ``k`` rounds, paths of at most
            ``k`` moves (cells farther away read as unreachable).
        propagation_walls: shelves are walls to that propagation (the default); ``False`` learns their
            cost like a floor cell's (it then stays only as dear as the training floors' detours need).

    Traced (vmappable, :class:`PPOHyper`):
        learning_rate, gamma, gae_lambda, clip_eps, ent_coef, vf_coef, max_grad_norm, reward_scale.
    """

    num_envs: int = 64
    num_steps: int = 32
    num_minibatches: int = 4
    update_epochs: int = 4
    hidden_sizes: tuple[int, ...] = (64, 64)
    activation: str = "tanh"
    obs_encoding: str = "onehot"
    total_timesteps: int = 600_000  # 292 updates; 300,000 left 3-4 seeds in 32 one item 2 steps long (docs/ppo.md)
    anneal_lr: bool = True
    anneal_ent: bool = True
    normalize_advantages: bool = True
    bootstrap_truncated: bool = True
    critic: str = "local"
    encoder: str = "mlp"
    propagation_rounds: int = 0
    propagation_walls: bool = True
    learning_rate: float = 0.01
    gamma: float = 0.95
    gae_lambda: float = 0.6
    clip_eps: float = 0.2
    ent_coef: float = 0.2
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    reward_scale: float = 0.01

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden_sizes", tuple(int(w) for w in self.hidden_sizes))

    @property
    def steps_per_update(self) -> int:
        return self.num_envs * self.num_steps

    @property
    def num_updates(self) -> int:
        return self.total_timesteps // self.steps_per_update

    @property
    def minibatch_size(self) -> int:
        return self.steps_per_update // self.num_minibatches

    def hyper(self, **overrides: Any) -> "PPOHyper":
        """The traced hyperparameters (:class:`PPOHyper`), any of them overridden (a sweep's arrays)."""
        return hyper_from_config(PPOHyper, self, "PPO", **overrides)

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first problem; called before anything is compiled."""
        positive = ("num_envs", "num_steps", "num_minibatches", "update_epochs", "total_timesteps")
        check_positive_ints("PPO", self, positive)
        check_hidden_sizes("PPO", self.hidden_sizes)
        if not isinstance(self.propagation_rounds, int) or self.propagation_rounds < 0:
            raise ValueError(f"PPO propagation_rounds must be an int >= 0 (0: until the values converge), "
                             f"got {self.propagation_rounds!r}")
        if self.obs_encoding not in OBS_ENCODINGS:
            raise ValueError(f"PPO obs_encoding must be one of {OBS_ENCODINGS}, got {self.obs_encoding!r}")
        if self.encoder not in ENCODERS:
            raise ValueError(f"PPO encoder must be one of {ENCODERS}, got {self.encoder!r}")
        if self.encoder == "propagation" and self.obs_encoding != "raw":
            raise ValueError("PPO encoder='propagation' needs obs_encoding='raw' (it reads the map from the raw values)")
        if self.encoder == "propagation" and self.critic != "local":
            raise ValueError("PPO encoder='propagation' is for single-robot environments: use critic='local'")
        if self.critic not in CRITICS:
            raise ValueError(f"PPO critic must be one of {CRITICS}, got {self.critic!r}")
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"PPO activation must be one of {sorted(ACTIVATIONS)}, got {self.activation!r}")
        if self.steps_per_update % self.num_minibatches:
            raise ValueError(
                f"PPO batch of num_envs * num_steps = {self.num_envs} * {self.num_steps} = {self.steps_per_update} "
                f"is not divisible into num_minibatches={self.num_minibatches}"
            )
        if self.total_timesteps < self.steps_per_update:
            raise ValueError(
                f"PPO total_timesteps={self.total_timesteps} is less than one update "
                f"(num_envs * num_steps = {self.steps_per_update})"
            )
        check_hyper("PPO", **{name: getattr(self, name) for name in traced_fields(PPOHyper)})


@struct.dataclass
class PPOHyper:
    """The traced hyperparameters (float32 scalars, or batched along a sweep axis).

    These fields are the one declaration of what is traced; every other
    :class:`PPOConfig` field is static.
    """

    learning_rate: jax.Array
    gamma: jax.Array
    gae_lambda: jax.Array
    clip_eps: jax.Array
    ent_coef: jax.Array
    vf_coef: jax.Array
    max_grad_norm: jax.Array
    reward_scale: jax.Array


# -------------------------------------------------------------------- presets
PAPER = PPOConfig(
    # The study's Table 2 for PPO on 12x12:
    learning_rate=3e-4,
    hidden_sizes=(256, 256),
    gamma=0.99,
    num_envs=8,
    num_steps=1024,
    update_epochs=10,
    ent_coef=0.02,
    clip_eps=0.2,
    total_timesteps=600_000,
    # What the table omits, as Stable-Baselines3's PPO defaults would have it:
    gae_lambda=0.95,
    num_minibatches=128,  # SB3 batch_size=64 -> 8192 / 64
    vf_coef=0.5,
    max_grad_norm=0.5,
    activation="tanh",  # SB3 MlpPolicy's activation_fn
    obs_encoding="raw",  # the 7 observation values straight into the MLP
    anneal_lr=False,  # SB3's constant learning rate
    anneal_ent=False,  # and constant entropy coefficient
    normalize_advantages=True,  # SB3 normalizes per minibatch
    reward_scale=1.0,  # SB3 without VecNormalize sees the raw rewards
)
"""The study's exact setting (Table 2), completed with SB3 2.x PPO defaults."""

DEFAULT = PPOConfig()
"""Ours, for Warehouse-12x12-v0 on a 2-core CPU; chosen on seeds 2000-2031, validated on 1000-1031 (docs/ppo.md)."""

PROCEDURAL_MLP = dataclasses.replace(
    DEFAULT,
    obs_encoding="raw",  # the egocentric window and positions: the one-hot encoding is the study maps' coordinates
    hidden_sizes=(128, 128),
    learning_rate=3e-3,
    gamma=0.97,
    gae_lambda=0.9,
    ent_coef=0.0,  # no entropy bonus: a sharper policy trains closer to the greedy one that is evaluated
    total_timesteps=2_500_000,  # 1,220 updates
)
"""``--preset procedural_mlp``: the MLP on the robot's window and memory, no map (docs/procedural.md).

It searches where the planning preset plans: 99.3 % of held-out episodes delivered with 8.2 % excess
over the BFS optimum (seeds 0-3), and on floors unlike its training ones much less."""

PROCEDURAL = dataclasses.replace(PROCEDURAL_MLP, encoder="propagation", total_timesteps=500_000)
"""The default for ``Procedural-Warehouse-v0``: the policy that plans (docs/procedural.md).

The MLP of :data:`PROCEDURAL_MLP` reads the window, the memory and, instead of the map, the values
propagated over the whole map with learned costs until they converge (:mod:`wrl_jax.agents.propagation`);
the environment observes its map (:data:`PRESET_ENV_DEFAULTS`)."""

PRESET_ENV_DEFAULTS = {"procedural": {"Procedural-Warehouse-v0": {"observe_map": True}},
                       "procedural_mlp": {"Procedural-Warehouse-v0": {"observe_map": False}}}
"""What a preset needs of an environment, over the environment's own defaults (the planning preset reads
the map; the MLP would take it as 768 more inputs, and did worse with them). Other environments: nothing."""

PROCEDURAL_ENV_DEFAULTS = {"observe_last_action": True, "observe_visited": True, "visit_levels": 3}
"""What ``python train_ppo.py --env Procedural-Warehouse-v0`` changes in the environment unless told otherwise.

Memory of the robot's own moves, appended to the robot observation: its previous action, one-hot, and a
window channel counting its visits to each cell (up to 3) since its current target was set. A memoryless
greedy policy with a 5x5 window meets the same observation at both cells of a dead end whose far wall it
sees from one of them only, and went back and forth there on 22 % of held-out episodes; with a yes/no
trail a loop looks the same on every lap once it is marked, and 2.3 % of episodes still looped; counts
make every lap look different (docs/procedural.md). Not planner features: the robot's own trail.
``--observe-last-action False --observe-visited False --visit-levels 1`` trains on the plain observation."""

FLEET = dataclasses.replace(
    DEFAULT,
    num_envs=32,  # x K robots: every robot's observation is a row of the batch (IPPO)
    num_steps=64,
    obs_encoding="onehot",  # own and target row and col one-hot, then the carrying flag and the window
    update_epochs=2,  # half the gradient work of an update: more, cheaper updates in the same wall time
    total_timesteps=2_621_440,  # 1,280 updates
)
"""IPPO for ``Fleet-12x12-v0`` (the default there, with the block penalty of :data:`FLEET_ENV_DEFAULTS`);
docs/fleet_training.md has what it reaches against PIBT (with the observation of :data:`FLEET_ENV_DEFAULTS`,
8 of 8 seeds above it at K = 4 and at 95 % of it or more at K = 8)."""

FLEET_ENV_DEFAULTS = {"block_penalty": -60.0, "observe_last_action": True, "observe_headings": True}
"""What ``python train_ppo.py --env Fleet-12x12-v0`` changes in the environment unless told otherwise.

FLEET_SPEC.md's -1 makes pushing into an occupied cell worth it whenever the robot ahead
moves away at least a third of the time (a push gains the +2 shaping, a block costs 1 more
than waiting), and the greedy policy then blocks about 5-15 times per robot per 100 steps;
at -5 a push pays only when the robot ahead almost surely leaves. Evaluation counts blocks
whatever the penalty. -60 since the headings below: once a robot can see a contested cell
coming, a dearer block teaches it to yield (at K = 4, 0.88 blocks per robot per 100 steps at
-5, 0.71 at -10, 0.25 at -40, 0.22 at -60; at K = 8, 3.30, 2.76, 0.85, 0.40, for 107 % of
PIBT's throughput at -10, 102 % at -40 and 101 % at -60, the first penalty with every seed of
eight under 1 block; with the contract's observation -10 changed nothing).
``observe_last_action`` gives each robot its previous action and whether
it was blocked (a one-step memory): two robots meeting head-on otherwise see the same window
step after step and the argmax repeats the refused swap; with it the greedy fleet at K = 8
went from 88 to 95 % of PIBT. ``observe_headings`` shows where the other robots' previous
actions aimed, so a meeting or a contested cell is seen before it happens: with both, the
K = 4 fleet blocks 0.9 times per robot per 100 steps instead of 2.5 at -5 (docs/fleet_training.md)."""

CONTINUOUS = dataclasses.replace(
    DEFAULT,
    obs_encoding="raw",  # positions, heading, lidar: nothing to one-hot encode
    num_envs=64,
    num_steps=64,
    num_minibatches=8,
    update_epochs=4,
    hidden_sizes=(128, 128),
    learning_rate=1e-3,
    gamma=0.99,
    gae_lambda=0.95,
    ent_coef=0.0,
    reward_scale=0.1,  # deliveries pay 200: the same scale the off-policy learners use
    total_timesteps=2_000_000,
)
"""PPO with a Gaussian policy for the continuous warehouse (first setting; docs/continuous.md)."""

RWARE = dataclasses.replace(
    DEFAULT,
    obs_encoding="onehot",  # the own cell one-hot (rware's raw x, y are integers up to the grid size)
    num_envs=32,  # x N agents: every agent's observation is a row of the batch
    num_steps=64,
    num_minibatches=4,
    update_epochs=4,
    hidden_sizes=(128, 128),
    learning_rate=1e-3,
    anneal_ent=False,
    gamma=0.99,  # a delivery pays once, tens of steps after the pick-up that earned it
    gae_lambda=0.95,
    normalize_advantages=False,  # standardized, the advantages of a team that never delivered are noise at scale 1
    ent_coef=0.003,  # with raw advantages: 0.01 outweighs the first deliveries, 0.001 ends teams too sharp
    reward_scale=1.0,  # rware pays 1 per delivery
    total_timesteps=4_000_000,  # a tenth of the 40M EPyMARL trained its on-policy learners for
    critic="local",  # IPPO: at this entropy its mean is at or above MAPPO's on every task, in 4/5 of the time
)
"""IPPO for RWARE, the default on every ``rware-*`` id (``--critic centralized``: MAPPO, whose critic reads every
agent's observation); docs/rware.md has what each reaches. One-hot cells and small, frequent updates: with
rware's raw coordinates, or 4x larger updates at half the step size, 4M steps gave about half the return or none.
Raw advantages: before the first delivery every reward is 0, and standardizing the critic's noise steered some
seeds' teams into standing still for good. Entropy 0.003: at 0.001 the policies' entropy ends lower (0.025-0.08
against 0.04-0.2), and IPPO's returns are lower on every task, with more seeds in which an agent delivers nothing
in some episode (bench/results/rware/NOTES.md)."""

CONTINUOUS_DYNAMIC = dataclasses.replace(CONTINUOUS, total_timesteps=3_000_000)
"""The ``continuous`` preset for the moving obstacles' map, with the 3M steps its measurements used
(docs/continuous.md)."""

PRESETS = {"default": DEFAULT, "paper": PAPER, "procedural": PROCEDURAL, "procedural_mlp": PROCEDURAL_MLP,
           "fleet": FLEET, "continuous": CONTINUOUS, "continuous_dynamic": CONTINUOUS_DYNAMIC, "rware": RWARE}

STUDY_TABLE3 = {
    "Task Completion Rate": "Stable across 20 locations",
    "Mean Steps to Complete": "~25-60 steps (est.)",
    "Mean Episode Reward": ">+150 target",
    "Convergence Timestep": "~400,000 steps (est.)",
    "Obstacle Avoidance": "~95%+ in evaluation",
    "Stage Switching": "not reported",
}
