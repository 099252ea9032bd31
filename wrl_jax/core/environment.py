"""The base of every wrl_jax environment family, on gymnax 1.0.

A family subclasses :class:`Environment` and writes three things:

- ``reset_env(key, params) -> (obs, state)``: a fresh episode. It runs on every
  step under auto-reset (for every environment of a batch), so it must be cheap:
  no generator, no BFS; draw from arrays already in ``params``.
- ``transition(key, state, action, params)
  -> (obs, state, reward, terminated, truncated, info)``: one transition without
  reset. ``terminated`` and ``truncated`` are kept apart (the SPEC.md and
  FLEET_SPEC.md semantics: a delivery is not a time-out).
- ``observation_space(params=None)`` and ``action_space(params=None)`` (gymnax
  ``spaces``), ``num_actions``, ``name`` and ``default_params``.

The base then provides gymnax 1.0's interface exactly: ``step`` (transition +
auto-reset, six values, the reached observation in ``info["final_obs"]`` and
``info["final_observation"]``), ``reset``, the 5-value ``step_env`` hook,
``is_truncated``. Unlike gymnax's generic ``step``, ``step`` is not jitted
here: callers jit (concrete inputs outside ``jit`` are validated with clear
errors), and a family may override ``step`` with a cheaper equivalent (the
single-robot warehouse does: it draws the next item from the step key itself).

Environment objects are ``jit`` static arguments: they hold only static
configuration (shapes, switches) and a fingerprint of their default params,
and compare and hash by those (see :meth:`Environment.static_key`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, Generic, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from wrl_jax.core.gymnax_base import gymnax_environment

StateT = TypeVar("StateT")
ParamsT = TypeVar("ParamsT")

StepResult = tuple[Any, Any, jax.Array, jax.Array, jax.Array, dict[str, Any]]


def params_fingerprint(params: Any) -> str:
    """A short hash of a params pytree's structure, shapes, dtypes and values.

    Part of an environment's identity: two environments whose default params
    differ (another layout of the same size) must not share a ``jit`` cache
    entry, since ``params=None`` bakes the defaults into the trace.
    """
    if params is None:
        return ""
    digest = hashlib.sha1(str(jax.tree_util.tree_structure(params)).encode())
    for leaf in jax.tree_util.tree_leaves(params):
        array = np.asarray(leaf)
        digest.update(f"{array.dtype}{array.shape}".encode())
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()[:16]


class Environment(gymnax_environment.Environment, Generic[StateT, ParamsT]):
    """A gymnax 1.0 environment with wrl_jax's conventions (see the module docstring).

    Subclasses call ``super().__init__(default_params)`` and implement
    :meth:`static_config`, :meth:`reset_env`, :meth:`transition` and the spaces.
    """

    family: str = ""
    """The family folder under :mod:`wrl_jax.envs` (``"warehouse"``, ``"fleet"``...): which
    evaluation hook the training driver uses (:mod:`wrl_jax.core.evaluation`)."""

    num_agents: int | None = None
    """Agents acting in one step. ``None``: a single-agent family (no agent axis). A multi-agent family
    (the fleet) sets it to ``K``: its observations, actions and rewards carry a leading agent axis of
    that length, while ``terminated`` and ``truncated`` stay per environment (one shared episode)."""

    event_metrics: Mapping[str, str] = MappingProxyType({})
    """Info flags the training loop counts, by the metric name it logs their sum under per update
    (the fleet: ``{"delivered": "deliveries_sum", ...}``); a family's
    :class:`~wrl_jax.core.evaluation.TrainRate` s can divide them."""

    def __init__(self, default_params: ParamsT | None = None):
        self._default_params = default_params
        self._fingerprint = params_fingerprint(default_params)

    # ------------------------------------------------------------ identity
    def static_config(self) -> tuple:
        """The static configuration that fixes this environment's programs (shapes, switches)."""
        raise NotImplementedError

    def static_key(self) -> tuple:
        return (type(self).__name__, *self.static_config(), self._fingerprint)

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and other.static_key() == self.static_key()

    def __hash__(self) -> int:
        return hash(self.static_key())

    # ------------------------------------------------------------ gymnax API
    @property
    def default_params(self) -> ParamsT:
        if self._default_params is None:
            raise ValueError(
                f"{self!r} was built without default params (no layout): pass params explicitly, "
                f"or build it with wrl_jax.make(name) / make_from_layout(...)"
            )
        return self._default_params

    def with_default_params(self, params: ParamsT):
        """A copy of this environment whose ``default_params`` are ``params``."""
        clone = self.without_default_params()
        clone._default_params = params
        clone._fingerprint = params_fingerprint(params)
        return clone

    def without_default_params(self):
        """This environment with no default params: equal for every layout of the same static configuration.

        The ``jit`` static argument of code that always passes params
        explicitly, so that one compiled program serves every layout.
        """
        clone = object.__new__(type(self))
        clone.__dict__.update(self.__dict__)
        clone._default_params = None
        clone._fingerprint = ""
        return clone

    def reset(self, key: jax.Array, params: ParamsT | None = None) -> tuple[Any, StateT]:
        """A fresh episode: ``(obs, state)``."""
        return self.reset_env(key, self.default_params if params is None else params)

    def step(self, key: jax.Array, state: StateT, action: Any, params: ParamsT | None = None) -> StepResult:
        """One transition, then an automatic reset if the episode ended.

        Returns ``(obs, state, reward, terminated, truncated, info)``. When the
        episode ended, ``obs`` and ``state`` begin the next one and
        ``info["final_obs"]`` (also ``info["final_observation"]``, gymnax 1.0's
        name) is the observation the transition reached; otherwise it equals ``obs``.
        """
        params = self.default_params if params is None else params
        key_step, key_reset = jax.random.split(key)
        obs, next_state, reward, terminated, truncated, info = self.transition(key_step, state, action, params)
        reset_obs, reset_state = self.reset_env(key_reset, params)
        done = _episode_done(terminated, truncated)
        next_state = jax.tree.map(lambda fresh, cont: _select(done, fresh, cont), reset_state, next_state)
        next_obs = jax.tree.map(lambda fresh, cont: _select(done, fresh, cont), reset_obs, obs)
        info = {**info, "final_obs": obs, "final_observation": obs}
        return next_obs, next_state, reward, terminated, truncated, info

    def step_env(self, key: jax.Array, state: StateT, action: Any, params: ParamsT):
        """gymnax 1.0's 5-value hook ``(obs, state, reward, terminated, info)``; ``info["truncated"]`` too."""
        obs, state, reward, terminated, truncated, info = self.transition(key, state, action, params)
        return obs, state, reward, terminated, {**info, "truncated": truncated}

    def is_truncated(self, state: StateT, params: ParamsT) -> jax.Array:
        return state.time >= params.max_steps_in_episode

    def is_terminated(self, state: StateT, params: ParamsT) -> jax.Array:
        return jnp.zeros((), dtype=bool)

    # ------------------------------------------------------------ batches
    def batch_reset(self, key: jax.Array, num_envs: int, params: ParamsT) -> tuple[Any, StateT]:
        """``num_envs`` fresh episodes from one key (leaves with a leading axis ``num_envs``).

        Generic: a key per environment and ``vmap(reset_env)``. A family may
        override it with a cheaper equivalent (one draw for the whole batch).
        """
        keys = jax.random.split(key, num_envs)
        return jax.vmap(self.reset_env, in_axes=(0, None))(keys, params)

    def batch_step(self, key: jax.Array, state: StateT, action: Any, params: ParamsT) -> StepResult:
        """:meth:`step` for a batch of environments from one key (what learners call).

        Generic: a key per environment and ``vmap(step)``; a family may
        override it with a cheaper equivalent, as the warehouse does.
        """
        num_envs = jax.tree_util.tree_leaves(state)[0].shape[0]
        keys = jax.random.split(key, num_envs)
        return jax.vmap(self.step, in_axes=(0, 0, 0, None))(keys, state, action, params)

    # ------------------------------------------------------------ family hooks
    def onehot_coordinates(self) -> tuple[int, int, int, int] | None:
        """Where an observation holds grid cells, for networks that one-hot encode them (or ``None``).

        ``(count, values, offset, scale)``: the first ``count`` observation values are
        cells, value ``x`` is cell index ``round(x * scale) + offset`` in ``0..values-1``.
        PPO's ``obs_encoding="onehot"`` reads it; a family without it only offers ``"raw"``.
        """
        return None

    refreshes_params: bool = False
    """Whether :meth:`params_for_update` changes the params (a learner then calls it before every update)."""

    def params_for_update(self, params: ParamsT, update_index: jax.Array) -> ParamsT:
        """The params an update collects its experience with, from the previous update's (traced, in ``jit``).

        Identity by default. A family whose params hold something a learner should
        renew while it trains (the procedural warehouse's layout pool) overrides it
        with a deterministic function of ``update_index``, so a run repeats bit for bit
        and a resumed run continues exactly. It runs once per update, not per step:
        generation belongs here, never in ``reset_env``.
        """
        return params

    def reset_env(self, key: jax.Array, params: ParamsT) -> tuple[Any, StateT]:
        raise NotImplementedError

    def transition(self, key: jax.Array, state: StateT, action: Any, params: ParamsT) -> StepResult:
        raise NotImplementedError

    def action_space(self, params: ParamsT | None = None):
        raise NotImplementedError

    def observation_space(self, params: ParamsT | None = None):
        raise NotImplementedError


def _episode_done(terminated: jax.Array, truncated: jax.Array) -> jax.Array:
    return jnp.logical_or(terminated, truncated)


def _select(done: jax.Array, fresh: jax.Array, cont: jax.Array) -> jax.Array:
    # ``done`` may be a scalar (one episode for the whole state, as in the
    # fleet) or match the leaf's leading axes; broadcast from the left.
    done = jnp.reshape(done, done.shape + (1,) * (cont.ndim - done.ndim))
    return jnp.where(done, fresh, cont)


def only_where(pred: jax.Array, compute, operand: jax.Array, otherwise):
    """``compute(operand)`` where ``pred``, else ``otherwise`` (same pytree); computed only when needed.

    A ``lax.while_loop`` that runs at most once: a family's cheaper auto-reset. Under ``vmap``, ``jnp.where``
    and ``lax.cond`` both evaluate ``compute`` for every environment on every step; a batched while runs its
    body only while some environment of the batch needs it (then selects per environment), so a batch whose
    episodes start and end together (a fleet's shift, rware's 500 steps) pays for the reset on one step in
    ``max_steps``. ``operand`` (an unsigned integer array, e.g. key data) rides in the loop carry and is
    changed by the body, so XLA cannot hoist ``compute`` out of the loop as loop-invariant.
    """
    def body(carry):
        _, data, _ = carry
        return jnp.zeros((), dtype=bool), data + np.asarray(1, dtype=data.dtype), compute(data)

    return jax.lax.while_loop(lambda carry: carry[0], body, (jnp.asarray(pred), operand, otherwise))[2]


def materialise(value: jax.Array) -> jax.Array:
    """``value`` (int or bool), computed once into its own buffer: a max with the dtype's least value.

    Why: XLA's CPU fusion copies a cheap producer into every consumer (and into every element of one
    that broadcasts it or gathers with it), so a long chain read by many operations is rebuilt many
    times per step. A reduction is not copied into consumers that reuse it; ``optimization_barrier``
    is dropped on CPU.
    """
    if value.dtype != jnp.bool_ and not jnp.issubdtype(value.dtype, jnp.integer):
        raise TypeError(f"materialise takes an integer or bool array, got {value.dtype}")
    least = False if value.dtype == jnp.bool_ else jnp.iinfo(value.dtype).min
    return jnp.max(jnp.stack([value, jnp.full_like(value, least)]), axis=0)
