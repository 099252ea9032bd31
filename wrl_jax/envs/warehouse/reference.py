"""A plain NumPy reference of the warehouse MDP, written from SPEC.md alone.

This is the yardstick the JAX environment is checked against, bit for bit
(``tests/envs/warehouse/test_parity.py``). It is deliberately written in the style of the
study: one environment, mutable attributes, Python ``if`` statements and
NumPy scalars, so that it reads like the specification and shares no
transition code with ``wrl_jax.envs.warehouse.env``. The only code it shares is the layout
parser (``wrl_jax.envs.warehouse.layout``), which SPEC.md allows, and the registry's table of
maps and episode limits (data, not logic) for :func:`make_reference`.

Float arithmetic follows SPEC.md literally: the reward is the float32 sum of
six float32 terms, added left to right in the order SPEC.md lists them, an
inactive term contributing ``float32(0.0)``; an observation coordinate is the
IEEE float32 quotient ``float32(value) / float32(N - 1)``. NumPy scalar
arithmetic on ``np.float32`` is exactly that (no fused multiply-add, no
reciprocal multiply, no reassociation).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from wrl_jax.envs.warehouse.layout import ITEM_MARKERS, Layout, parse

# Written out from SPEC.md (not imported from the JAX side), so that a drift
# of either side's defaults is caught by the tests that compare them.
DEFAULT_REWARDS: dict[str, float] = {
    "step_penalty": -0.5,
    "obstacle_penalty": -10.0,
    "wall_penalty": 0.0,
    "shaping_coef": 2.0,
    "pickup_reward": 50.0,
    "delivery_reward": 200.0,
}
"""The six reward constants of SPEC.md, in the order their terms are added."""

# (row, col) change of each action, SPEC.md: 0 up, 1 down, 2 left, 3 right.
ACTION_DELTAS: tuple[tuple[int, int], ...] = ((-1, 0), (1, 0), (0, -1), (0, 1))
ACTION_NAMES: tuple[str, ...] = ("up", "down", "left", "right")


class WarehouseReferenceEnv(gym.Env):
    """One warehouse robot, pick-and-place, exactly as SPEC.md defines it.

    Args:
        layout: a :class:`~wrl_jax.envs.warehouse.layout.Layout` or an ASCII map (parsed and
            validated; a bad map raises ``ValueError`` naming the problem).
        max_steps: the step count at which an episode is truncated.
        step_penalty, obstacle_penalty, wall_penalty, shaping_coef,
        pickup_reward, delivery_reward: the reward constants of SPEC.md,
            stored as float32 (the reward is computed in float32).
        observe_carrying: include the carrying flag as observation index 6.
            ``False`` reproduces the study's "task-stage ignorance" failure
            mode (a 6-value observation that cannot tell the two stages apart).
        collision_bug: reproduce the study's "collision state corruption":
            on a move into a shelf the robot's position is written into the
            shelf cell before the collision is noticed, so the robot ends up
            *on* the shelf; the obstacle penalty still applies and the shaping
            sees the shelf cell as the new position. Off by default.
        render_mode: ``None`` or ``"ansi"`` (``render()`` returns a text grid).

    The episode API is Gymnasium's: ``reset(seed=..., options={"item_index": i})``
    and ``step(action) -> (obs, reward, terminated, truncated, info)``, without
    automatic reset; stepping a finished episode raises ``RuntimeError``.
    ``info`` holds Python bools ``collision``, ``wall_bump``, ``picked_up``
    and ``delivered`` describing the transition.
    """

    metadata = {"render_modes": ["ansi"], "render_fps": 4}

    def __init__(
        self,
        layout: Layout | str,
        max_steps: int,
        *,
        step_penalty: float = DEFAULT_REWARDS["step_penalty"],
        obstacle_penalty: float = DEFAULT_REWARDS["obstacle_penalty"],
        wall_penalty: float = DEFAULT_REWARDS["wall_penalty"],
        shaping_coef: float = DEFAULT_REWARDS["shaping_coef"],
        pickup_reward: float = DEFAULT_REWARDS["pickup_reward"],
        delivery_reward: float = DEFAULT_REWARDS["delivery_reward"],
        observe_carrying: bool = True,
        collision_bug: bool = False,
        render_mode: str | None = None,
    ):
        super().__init__()
        if isinstance(layout, str):
            layout = parse(layout)
        if not isinstance(layout, Layout):
            raise TypeError(f"layout must be a wrl_jax.envs.warehouse.layout.Layout or an ASCII map string, got {type(layout)}")
        if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
            raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")

        self.layout = layout
        self.size = layout.size
        self.shelves = np.array(layout.shelves, dtype=bool)
        self.start = (int(layout.start[0]), int(layout.start[1]))
        self.goal = (int(layout.goal[0]), int(layout.goal[1]))
        self.items = [(int(row), int(col)) for row, col in layout.items]
        self.max_steps = int(max_steps)
        self.observe_carrying = bool(observe_carrying)
        self.collision_bug = bool(collision_bug)
        self.render_mode = render_mode

        given = {
            "step_penalty": step_penalty,
            "obstacle_penalty": obstacle_penalty,
            "wall_penalty": wall_penalty,
            "shaping_coef": shaping_coef,
            "pickup_reward": pickup_reward,
            "delivery_reward": delivery_reward,
        }
        for name, value in given.items():
            _check_reward_constant(name, value)
        self.step_penalty = np.float32(step_penalty)
        self.obstacle_penalty = np.float32(obstacle_penalty)
        self.wall_penalty = np.float32(wall_penalty)
        self.shaping_coef = np.float32(shaping_coef)
        self.pickup_reward = np.float32(pickup_reward)
        self.delivery_reward = np.float32(delivery_reward)

        # Observations lie in [-1/(N-1), 1]: -1/(N-1) is the "item picked up" marker.
        low = np.float32(-1.0) / np.float32(self.size - 1)
        obs_size = 7 if self.observe_carrying else 6
        self.observation_space = spaces.Box(low=low, high=np.float32(1.0), shape=(obs_size,), dtype=np.float32)
        self.action_space = spaces.Discrete(len(ACTION_DELTAS))

        # Episode state, as the study keeps it; None until the first reset.
        self.robot_pos: tuple[int, int] | None = None
        self.item_index: int | None = None
        self.item_pos: tuple[int, int] | None = None
        self.carrying = False
        self.steps = 0
        self.done = True

    # ------------------------------------------------------------------ reset
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start an episode: the item is ``options["item_index"]`` or drawn uniformly."""
        super().reset(seed=seed)
        options = {} if options is None else dict(options)
        unknown = sorted(set(options) - {"item_index"})
        if unknown:
            raise ValueError(f"unknown reset option(s) {unknown}; the only option is 'item_index'")
        item_index = options.get("item_index")
        if item_index is None:
            item_index = int(self.np_random.integers(len(self.items)))
        else:
            item_index = self._checked_item_index(item_index)

        self.robot_pos = self.start
        self.item_index = item_index
        self.item_pos = self.items[item_index]
        self.carrying = False
        self.steps = 0
        self.done = False
        return self._observation(), {}

    # ------------------------------------------------------------------- step
    def step(self, action):
        """One transition (s, a, s') of SPEC.md; no automatic reset."""
        action = self._checked_action(action)
        if self.robot_pos is None:
            raise RuntimeError("call reset() before step()")
        if self.done:
            raise RuntimeError("the episode is over (terminated or truncated); call reset() before step()")

        # The target is taken in s, before the move: the item, or the goal once carrying.
        target = self.goal if self.carrying else self.item_pos
        old_pos = self.robot_pos
        d_row, d_col = ACTION_DELTAS[action]
        next_row, next_col = old_pos[0] + d_row, old_pos[1] + d_col

        wall_bump = False
        collision = False
        if not (0 <= next_row < self.size and 0 <= next_col < self.size):
            wall_bump = True  # boundary reflection: stay put, not a collision
            new_pos = old_pos
        elif self.shelves[next_row, next_col]:
            collision = True
            if self.collision_bug:
                new_pos = (next_row, next_col)  # the study's bug: written before the check
            else:
                new_pos = old_pos
        else:
            new_pos = (next_row, next_col)

        picked_up = False
        delivered = False
        if not self.carrying and new_pos == self.item_pos:
            picked_up = True
        elif self.carrying and new_pos == self.goal:
            delivered = True

        d_old = abs(old_pos[0] - target[0]) + abs(old_pos[1] - target[1])
        d_new = abs(new_pos[0] - target[0]) + abs(new_pos[1] - target[1])

        zero = np.float32(0.0)
        terms = [
            zero if delivered else self.step_penalty,
            self.obstacle_penalty if collision else zero,
            self.wall_penalty if wall_bump else zero,
            self.shaping_coef * np.float32(d_old - d_new),
            self.pickup_reward if picked_up else zero,
            self.delivery_reward if delivered else zero,
        ]
        reward = terms[0]
        with np.errstate(over="ignore"):  # float32 overflow to +-inf is IEEE, as in XLA
            for term in terms[1:]:
                reward = np.float32(reward + term)

        self.robot_pos = new_pos
        if picked_up:
            self.carrying = True
        self.steps += 1
        terminated = delivered
        truncated = self.steps >= self.max_steps and not terminated
        self.done = terminated or truncated

        info = {"collision": collision, "wall_bump": wall_bump, "picked_up": picked_up, "delivered": delivered}
        return self._observation(), reward, terminated, truncated, info

    # ------------------------------------------------------------ observation
    def _observation(self) -> np.ndarray:
        scale = np.float32(self.size - 1)
        if self.carrying:
            item = (-1, -1)
        else:
            item = self.item_pos
        values = [*self.robot_pos, *self.goal, *item]
        obs = [np.float32(value) / scale for value in values]
        if self.observe_carrying:
            obs.append(np.float32(1.0) if self.carrying else np.float32(0.0))
        return np.array(obs, dtype=np.float32)

    # ------------------------------------------------------------- rendering
    def render(self) -> str | None:
        """A text grid: ``R`` robot (``r`` when carrying), ``G`` goal, ``#`` shelf, item marker."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='ansi'")
            return None
        rows = [["#" if shelf else "." for shelf in row] for row in self.shelves]
        rows[self.goal[0]][self.goal[1]] = "G"
        if self.robot_pos is not None:
            if not self.carrying:
                rows[self.item_pos[0]][self.item_pos[1]] = ITEM_MARKERS[self.item_index]
            robot = "r" if self.carrying else "R"
            rows[self.robot_pos[0]][self.robot_pos[1]] = robot
        status = "" if self.robot_pos is None else (
            f"step {self.steps}/{self.max_steps}, {'carrying' if self.carrying else 'not carrying'} "
            f"item {self.item_index}\n"
        )
        return status + "\n".join(" ".join(row) for row in rows) + "\n"

    # ------------------------------------------------------------- checking
    @staticmethod
    def _checked_action(action: Any) -> int:
        """The action as an int; ``ValueError`` for anything but an integer in 0..3."""
        array = np.asarray(action)
        if array.shape != () or array.dtype.kind not in "iu":
            raise ValueError(
                f"action must be a single integer in 0..3 (0 up, 1 down, 2 left, 3 right), got {action!r}"
            )
        value = int(array)
        if not 0 <= value < len(ACTION_DELTAS):
            raise ValueError(f"action {value} is out of range: expected 0 up, 1 down, 2 left or 3 right")
        return value

    def _checked_item_index(self, item_index: Any) -> int:
        array = np.asarray(item_index)
        if array.shape != () or array.dtype.kind not in "iu":
            raise ValueError(f"item_index must be a single integer, got {item_index!r}")
        value = int(array)
        if not 0 <= value < len(self.items):
            raise ValueError(
                f"item_index {value} is out of range: the layout has {len(self.items)} items (0..{len(self.items) - 1})"
            )
        return value


MIN_REWARD_MAGNITUDE = 1e-30
"""Smallest magnitude of a nonzero reward constant.

A float32 subnormal behaves differently in the two implementations: IEEE
arithmetic (NumPy, this reference) keeps it, XLA on CPU flushes it to zero. If
every nonzero constant is at least ``1e-30 > 2**-100`` in magnitude, each is a
multiple of ``2**-123`` and so is every partial sum of the reward, so no
subnormal can ever arise and both implementations compute the same floats.
"""


def _check_reward_constant(name: str, value: Any) -> None:
    """``ValueError`` unless ``value`` is 0 or a finite float32 of magnitude >= 1e-30."""
    with np.errstate(over="ignore"):
        value32 = np.float32(value)
    if not np.isfinite(value32):
        raise ValueError(f"reward parameter {name} must be finite in float32, got {value!r}")
    if value32 != 0 and abs(value32) < MIN_REWARD_MAGNITUDE:
        raise ValueError(
            f"reward parameter {name}={value!r} is too small: use 0 or a magnitude of at least "
            f"{MIN_REWARD_MAGNITUDE} (float32 subnormals are flushed to zero by XLA on CPU)"
        )


def make_reference(name: str, **overrides: Any) -> WarehouseReferenceEnv:
    """The reference twin of ``wrl_jax.make(name, **overrides)``.

    Same names, same overrides (every reward constant, ``max_steps``,
    ``observe_carrying``, ``collision_bug``), same defaults. ``max_items`` is
    accepted for symmetry with ``wrl_jax.make`` (it pads the JAX params and
    changes nothing here) and checked the same way; ``render_mode`` is passed on.
    """
    from wrl_jax.envs.warehouse.registration import spec  # the table of maps and episode limits only

    entry = spec(name)
    layout = entry.layout
    max_items = overrides.pop("max_items", None)
    if max_items is not None and int(max_items) < layout.num_items:
        raise ValueError(f"max_items={max_items} is smaller than the layout's {layout.num_items} items")
    known = set(DEFAULT_REWARDS) | {"max_steps", "observe_carrying", "collision_bug", "render_mode"}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise ValueError(f"unknown override(s) {unknown}; known: {sorted(known | {'max_items'})}")
    overrides.setdefault("max_steps", entry.max_steps)
    return WarehouseReferenceEnv(layout, **overrides)
