"""The warehouse pick-and-place environment in JAX (SPEC.md).

Functional and explicit, in the gymnax style: the environment object holds
only static shapes; state and params are pytrees passed in and out, so every
method is pure and can be ``jit``-ed, ``vmap``-ped over thousands of
environments and ``lax.scan``-ned over time.

``step`` auto-resets: when a transition ends the episode (``terminated`` or
``truncated``) it returns the first observation of a fresh episode, and keeps
the observation the transition actually reached in ``info["final_obs"]`` (and
gymnax 1.0's ``info["final_observation"]``), so a learner can bootstrap a
truncated episode from the right state. ``transition`` is the same transition
without the reset.

:class:`Warehouse` is a gymnax 1.0 environment (:mod:`wrl_jax.core.environment`):
``default_params``, ``action_space()``/``observation_space()``, ``name``,
``num_actions``; it overrides the base's generic ``step`` with a cheaper one that
splits no key (the next item is drawn from the step key itself, see
:func:`draw_item`).

Why one module of this length: the whole MDP of SPEC.md (reset, transition,
observation, the reset draws and the params with their checks) is what the
NumPy reference is checked against bit for bit; it reads best in one place.
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.core.environment import Environment
from wrl_jax.core.gymnax_base import spaces
from wrl_jax.core.random import random_word, threefry2x32
from wrl_jax.envs.warehouse.layout import MOVES, Layout
from wrl_jax.envs.warehouse.types import REWARD_DEFAULTS, EnvParams, EnvState

NUM_ACTIONS = 4
MAX_ITEMS = 2**16 - 1
"""Item capacity bound of :func:`draw_item`'s 32-bit arithmetic (layouts allow 62 anyway)."""
ACTION_NAMES = ("up", "down", "left", "right")

StepResult = tuple[jax.Array, EnvState, jax.Array, jax.Array, jax.Array, dict[str, jax.Array]]


class Warehouse(Environment[EnvState, EnvParams]):
    """The pick-and-place MDP for one grid size.

    Args:
        size: grid side ``N`` (static: it fixes array shapes).
        max_items: item capacity ``K_max`` of the params' ``items`` array.
        observe_carrying: include the carrying flag as observation index 6.
            ``False`` gives the 6-value observation of the study's
            "task-stage ignorance" failure mode; keep it ``True`` otherwise.
        default_params: what ``params=None`` means (gymnax's ``default_params``);
            :func:`wrl_jax.make` sets the registered layout's. Environments
            compare equal when their static configuration *and* their default
            params are equal; any params of the same shapes run on any of them.
        name: the registered name, if any (``"Warehouse-8x8-v0"``).
    """

    family = "warehouse"
    event_metrics = MappingProxyType({"collision": "collisions_sum"})  # training moves into shelves

    def __init__(
        self,
        size: int,
        max_items: int,
        observe_carrying: bool = True,
        default_params: EnvParams | None = None,
        name: str | None = None,
    ):
        super().__init__(default_params)
        if size < 2:
            raise ValueError(f"grid size must be at least 2, got {size}")
        if not 1 <= max_items <= MAX_ITEMS:
            raise ValueError(f"max_items must be in 1..{MAX_ITEMS}, got {max_items}")
        self.size = int(size)
        self.max_items = int(max_items)
        self.observe_carrying = bool(observe_carrying)
        # Entry i + 1 is float32(i) / float32(N - 1) for i in -1..N-1, rounded once, as SPEC.md says.
        self._coordinate_table = np.arange(-1, self.size, dtype=np.float32) / np.float32(self.size - 1)
        self._name = name or f"Warehouse-{self.size}x{self.size}"

    @property
    def obs_size(self) -> int:
        return 7 if self.observe_carrying else 6

    def onehot_coordinates(self) -> tuple[int, int, int, int]:
        """Six coordinates (robot, item, goal), each ``i / (N - 1)`` for ``i`` in ``-1..N-1``: ``N + 1`` values."""
        return (6, self.size + 1, 1, self.size - 1)

    def __repr__(self) -> str:
        return (
            f"Warehouse(size={self.size}, max_items={self.max_items}, "
            f"observe_carrying={self.observe_carrying})"
        )

    def static_config(self) -> tuple:
        return (self.size, self.max_items, self.observe_carrying)

    # ------------------------------------------------------------ gymnax API
    @property
    def name(self) -> str:
        return self._name

    @property
    def num_actions(self) -> int:
        return NUM_ACTIONS

    def action_space(self, params: EnvParams | None = None) -> spaces.Discrete:
        """``Discrete(4)``, int32: 0 up, 1 down, 2 left, 3 right."""
        return spaces.Discrete(NUM_ACTIONS)

    def observation_space(self, params: EnvParams | None = None) -> spaces.Box:
        """``Box((7,) or (6,), float32)``: coordinates in ``[0, 1]``, a carried item's at ``-1/(N-1)``."""
        low = float(self._coordinate_table[0])
        return spaces.Box(low, 1.0, (self.obs_size,), jnp.float32)

    # ------------------------------------------------------------------ reset
    def reset(self, key: jax.Array, params: EnvParams | None = None) -> tuple[jax.Array, EnvState]:
        """Start an episode with the item drawn uniformly from the layout's items."""
        return self.reset_env(key, self.default_params if params is None else params)

    def reset_env(self, key: jax.Array, params: EnvParams) -> tuple[jax.Array, EnvState]:
        return self.reset_to_item(draw_item(key, params), params)

    def reset_to_item(self, item_index: jax.Array | int, params: EnvParams | None = None) -> tuple[jax.Array, EnvState]:
        """Start an episode with a chosen item (deterministic evaluation)."""
        params = self.default_params if params is None else params
        if not isinstance(item_index, jax.core.Tracer) and not isinstance(params.num_items, jax.core.Tracer):
            _check_item_index(item_index, params)
        state = _initial_state(jnp.asarray(item_index, dtype=jnp.int32), params)
        return self.get_obs(state, params), state

    # ------------------------------------------------------------------- step
    def step(
        self, key: jax.Array, state: EnvState, action: jax.Array | int, params: EnvParams | None = None
    ) -> StepResult:
        """One transition, then an automatic reset if the episode ended.

        Returns ``(obs, state, reward, terminated, truncated, info)``. When the
        episode ended, ``obs`` and ``state`` begin the next episode (its item
        drawn from ``key`` by :func:`draw_item`) and ``info["final_obs"]`` is
        the observation the transition reached; otherwise ``info["final_obs"]``
        equals ``obs``. Same results as the base's generic ``step`` would give
        with a key split, at less cost: the transition needs no randomness, so
        the whole key goes to the reset draw.
        """
        params = self.default_params if params is None else params
        return self.step_to_item(state, action, draw_item(key, params), params)

    def batch_reset(self, key: jax.Array, num_envs: int, params: EnvParams) -> tuple[jax.Array, EnvState]:
        """``num_envs`` fresh episodes whose items come from one draw (:func:`draw_items`), no key per env."""
        items = draw_items(key, num_envs, params)
        return jax.vmap(self.reset_to_item, in_axes=(0, None))(items, params)

    def batch_step(self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams) -> StepResult:
        """A batch's :meth:`step` with every reset item from one draw (:func:`draw_items`).

        The same distribution as ``vmap(step)`` over split keys, at less cost:
        one ``jax.random.bits`` call for the batch instead of a threefry block
        per environment (docs/throughput.md).
        """
        items = draw_items(key, action.shape[0], params)
        return jax.vmap(self.step_to_item, in_axes=(0, 0, 0, None))(state, action, items, params)

    def step_to_item(
        self, state: EnvState, action: jax.Array | int, next_item: jax.Array | int, params: EnvParams
    ) -> StepResult:
        """:meth:`step` with the next episode's item given instead of drawn.

        For learners that draw the items of many environments at once from one
        key (cheaper than a key per environment) and for tests that pin resets.
        """
        obs, next_state, reward, terminated, truncated, info = self.transition(None, state, action, params)
        reset_state = _initial_state(jnp.asarray(next_item, dtype=jnp.int32), params)
        done = terminated | truncated
        next_state = jax.tree.map(lambda fresh, cont: jnp.where(done, fresh, cont), reset_state, next_state)
        info = {**info, "final_obs": obs, "final_observation": obs}
        # A select between the reached and the reset observation, rather than
        # observing the returned state: learners read ``final_obs`` too, so the
        # reached observation is computed anyway, and the reset one costs only
        # the drawn item's lookups (robot at start and goal are the same for all).
        reset_obs = self.get_obs(reset_state, params)
        return jnp.where(done, reset_obs, obs), next_state, reward, terminated, truncated, info

    def transition(
        self, key: jax.Array | None, state: EnvState, action: jax.Array | int, params: EnvParams
    ) -> StepResult:
        """One transition of SPEC.md, without a reset (for tests and analysis).

        ``key`` is unused (the single robot's transition draws nothing; pass
        ``None``); it is there for the base class's family hook.

        ``info`` holds bool flags of this transition: ``collision`` (a move
        into a shelf), ``wall_bump`` (a move off the grid), ``picked_up`` and
        ``delivered``.
        """
        if not isinstance(action, jax.core.Tracer):
            check_action(action)
        action = jnp.asarray(action, dtype=jnp.int32)
        pos = state.pos
        proposed = pos + jnp.asarray(MOVES)[action]
        on_grid = jnp.all((proposed >= 0) & (proposed < self.size))
        wall_bump = ~on_grid
        # Off the grid, the clipped cell is the robot's own cell (one coordinate moved by one).
        clipped = jnp.clip(proposed, 0, self.size - 1)
        collision = on_grid & params.shelves[clipped[0], clipped[1]]
        # The study's bug writes the position before the check; the fix checks first.
        blocked = collision & ~params.collision_bug
        next_pos = jnp.where(blocked, pos, clipped)

        reward, picked_up, delivered = spec_reward(
            params, pos, next_pos, state.carrying, state.item_pos, params.goal, collision, wall_bump
        )

        time = state.time + 1
        terminated = delivered
        truncated = (time >= params.max_steps) & ~terminated
        next_state = EnvState(
            pos=next_pos,
            item_index=state.item_index,
            item_pos=state.item_pos,
            carrying=state.carrying | picked_up,
            time=time,
        )
        info = {"collision": collision, "wall_bump": wall_bump, "picked_up": picked_up, "delivered": delivered}
        return self.get_obs(next_state, params), next_state, reward, terminated, truncated, info

    # ------------------------------------------------------------ observation
    def get_obs(self, state: EnvState, params: EnvParams | None = None, key: jax.Array | None = None) -> jax.Array:
        """The float32 observation of SPEC.md (7 values, or 6 without the carrying flag).

        gymnax 1.0's legacy observation hook (its ``observe`` calls it); ``key`` is unused.
        """
        params = self.default_params if params is None else params
        # Coordinates are read from an exact table of float32(i) / float32(N-1):
        # XLA on CPU compiles float division into a reciprocal multiply, which can
        # differ from SPEC.md's true float32 quotient in the last bit.
        table = jnp.asarray(self._coordinate_table)
        robot = table[state.pos + 1]
        goal = table[params.goal + 1]
        item = table[jnp.where(state.carrying, 0, state.item_pos + 1)]
        parts = [robot, goal, item]
        if self.observe_carrying:
            parts.append(state.carrying.astype(jnp.float32)[None])
        return jnp.concatenate(parts)


def spec_reward(
    params: Any,
    pos: jax.Array,
    next_pos: jax.Array,
    carrying: jax.Array,
    item_pos: jax.Array,
    goal: jax.Array,
    collision: jax.Array,
    wall_bump: jax.Array,
    distance_change: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """SPEC.md's pickup, delivery and float32 reward of one move: ``(reward, picked_up, delivered)``.

    Shared by every single-robot family (the study's maps, the procedural
    warehouses); ``params`` holds the six reward constants. Terms are added in
    SPEC.md's order, as the NumPy reference adds them, so the bits agree.
    ``distance_change``: ``d(pos) - d(pos')`` int32 of another distance than SPEC.md's
    Manhattan one (the procedural warehouse's BFS shaping); ``None``: Manhattan.
    """
    target = jnp.where(carrying, goal, item_pos)
    if distance_change is None:
        distance_change = jnp.sum(jnp.abs(pos - target)) - jnp.sum(jnp.abs(next_pos - target))
    picked_up = ~carrying & jnp.all(next_pos == item_pos)
    delivered = carrying & jnp.all(next_pos == goal)
    zero = jnp.float32(0.0)
    reward = jnp.where(delivered, zero, params.step_penalty)
    reward = reward + jnp.where(collision, params.obstacle_penalty, zero)
    reward = reward + jnp.where(wall_bump, params.wall_penalty, zero)
    reward = reward + params.shaping_coef * distance_change.astype(jnp.float32)
    reward = reward + jnp.where(picked_up, params.pickup_reward, zero)
    reward = reward + jnp.where(delivered, params.delivery_reward, zero)
    return reward, picked_up, delivered


def draw_item(key: jax.Array, params: EnvParams) -> jax.Array:
    """The item index of a new episode, uniform over the layout's items, drawn from ``key``.

    One 32-bit random word mapped to an item by :func:`item_from_word`.
    ``jax.random.randint`` draws two words and a key split for a bias below
    ``2**-64``; for the automatic reset, which every environment pays on every
    step, that made it the largest cost of :meth:`Warehouse.step` (about x1.6
    slower at large batch, see docs/throughput.md).

    For JAX's default keys the word is computed by :func:`threefry_word`, the
    same bits as ``jax.random.bits(key, (), jnp.uint32)`` without the loop
    JAX's CPU lowering runs (see there); other keys use ``jax.random.bits``.
    """
    return item_from_word(random_word(key), params.num_items)


def threefry_word(key_data: jax.Array) -> jax.Array:
    """The xor of Threefry-2x32's two output words for counter ``(0, 0)`` under ``key_data[..., :2]``."""
    x0, x1 = threefry2x32(key_data[..., 0], key_data[..., 1], np.uint32(0), np.uint32(0))
    return x0 ^ x1


def draw_items(key: jax.Array, num_envs: int, params: EnvParams) -> jax.Array:
    """Items of ``num_envs`` new episodes from ONE key: ``(num_envs,)`` int32.

    For a learner stepping a batch with :meth:`Warehouse.step_to_item`: one
    ``jax.random.bits`` call gives every environment an independent uniform
    word, so the batch needs no key per environment (a threefry block each,
    about a quarter of the cost of a default step at large batch).
    """
    return item_from_word(jax.random.bits(key, (num_envs,), jnp.uint32), params.num_items)


def item_from_word(word: jax.Array, num_items: jax.Array) -> jax.Array:
    """``floor(word * num_items / 2**32)`` for uniform uint32 words: an item index in ``0..num_items-1``.

    Lemire's multiply-shift, done in 16-bit halves so it needs no 64-bit
    integers. Each item's probability is within ``2**-32`` of ``1/num_items``.
    """
    count = num_items.astype(jnp.uint32)  # < 2**16, checked by Warehouse
    high = (word >> 16) * count  # < 2**32
    low = ((word & 0xFFFF) * count) >> 16  # < 2**16, and high + low < 2**32
    return ((high + low) >> 16).astype(jnp.int32)


def _initial_state(item_index: jax.Array, params: EnvParams) -> EnvState:
    """The first state of an episode whose item is ``params.items[item_index]``."""
    return EnvState(
        pos=params.start,
        item_index=item_index,
        item_pos=params.items[item_index],
        carrying=jnp.zeros((), dtype=bool),
        time=jnp.zeros((), dtype=jnp.int32),
    )


# ---------------------------------------------------------------------- params
def make_params(
    layout: Layout,
    *,
    max_steps: int,
    max_items: int | None = None,
    collision_bug: bool = False,
    **rewards: float,
) -> EnvParams:
    """Params of ``layout`` with SPEC.md's reward constants, any of them overridden.

    Args:
        layout: a validated layout.
        max_steps: truncation length (positive).
        max_items: pad ``items`` to this capacity so layouts with different
            item counts share one compiled program; defaults to the layout's count.
        collision_bug: the study's collision-bug switch (see :class:`EnvParams`).
        **rewards: overrides of ``step_penalty``, ``obstacle_penalty``,
            ``wall_penalty``, ``shaping_coef``, ``pickup_reward``, ``delivery_reward``.
    """
    unknown = sorted(set(rewards) - set(REWARD_DEFAULTS))
    if unknown:
        raise ValueError(f"unknown reward parameter(s) {unknown}; known: {sorted(REWARD_DEFAULTS)}")
    if int(max_steps) < 1:
        raise ValueError(f"max_steps must be a positive integer, got {max_steps}")
    max_items = layout.num_items if max_items is None else int(max_items)
    if max_items < layout.num_items:
        raise ValueError(f"max_items={max_items} is smaller than the layout's {layout.num_items} items")
    items = np.zeros((max_items, 2), dtype=np.int32)
    items[: layout.num_items] = layout.items
    items[layout.num_items :] = layout.items[0]  # padding: a valid cell, never drawn
    values = {**REWARD_DEFAULTS, **rewards}
    for name, value in values.items():
        # Checked in float32, the type the reward is computed in. A nonzero constant
        # below 1e-30 in magnitude could make a float32 subnormal, which XLA on CPU
        # flushes to zero (IEEE float32, and the NumPy reference, keep it); from 1e-30
        # (> 2**-100) up, every partial sum of the reward is a multiple of 2**-123, so
        # no subnormal can arise and the flush never changes a result.
        with np.errstate(over="ignore"):
            value32 = np.float32(value)
        if not np.isfinite(value32):
            raise ValueError(f"reward parameter {name} must be finite in float32, got {value}")
        if value32 != 0 and abs(value32) < 1e-30:
            raise ValueError(
                f"reward parameter {name}={value} is too small: use 0 or a magnitude of at least 1e-30 "
                f"(XLA on CPU flushes float32 subnormals to zero)"
            )
    return EnvParams(
        shelves=jnp.asarray(layout.shelves, dtype=bool),
        start=jnp.asarray(layout.start, dtype=jnp.int32),
        goal=jnp.asarray(layout.goal, dtype=jnp.int32),
        items=jnp.asarray(items),
        num_items=jnp.asarray(layout.num_items, dtype=jnp.int32),
        max_steps=jnp.asarray(int(max_steps), dtype=jnp.int32),
        collision_bug=jnp.asarray(bool(collision_bug)),
        **{name: jnp.asarray(value, dtype=jnp.float32) for name, value in values.items()},
    )


def check_action(action: Any) -> None:
    """Raise a clear ``ValueError`` for an action outside ``{0, 1, 2, 3}``."""
    array = np.asarray(action)
    # Floats are refused even when integral (2.0), as in the reference and the
    # Gymnasium adapters: a float action is almost always a policy-output bug.
    if array.dtype.kind not in "iu":
        raise ValueError(f"action must be an integer in 0..3 (up, down, left, right), got {action!r}")
    if np.any((array < 0) | (array >= NUM_ACTIONS)):
        raise ValueError(f"action {action!r} is out of range: expected 0 up, 1 down, 2 left or 3 right")


def _check_item_index(item_index: Any, params: EnvParams) -> None:
    array = np.asarray(item_index)
    num_items = np.asarray(params.num_items)
    if array.dtype.kind not in "iu":
        raise ValueError(f"item_index must be an integer, got {item_index!r}")
    if np.any((array < 0) | (array >= num_items)):
        raise ValueError(f"item_index {item_index!r} is out of range: the layout has {num_items} items")
