"""What the learners share, written once: hyperparameter rules, traced hyperparameters, schedules, clipping.

Each algorithm declares its *traced* hyperparameters once, as the fields of
its ``Hyper`` struct (:func:`traced_fields`); every other config field is
static (it fixes shapes or program structure). :func:`hyper_from_config`
turns a config (plus sweep overrides, scalars or arrays of sweep points) into
that struct of float32 arrays after :func:`check_hyper` has range-checked
every value against :data:`HYPER_RULES`, so a bad value is a ``ValueError``
naming it before anything compiles.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

HyperT = TypeVar("HyperT")

HYPER_RULES: dict[str, tuple[str, Callable[[np.ndarray], np.ndarray]]] = {
    "learning_rate": ("> 0", lambda x: x > 0),
    "gamma": ("in [0, 1]", lambda x: (x >= 0) & (x <= 1)),
    "gae_lambda": ("in [0, 1]", lambda x: (x >= 0) & (x <= 1)),
    "clip_eps": ("> 0", lambda x: x > 0),
    "ent_coef": (">= 0", lambda x: x >= 0),
    "vf_coef": (">= 0", lambda x: x >= 0),
    "max_grad_norm": ("> 0", lambda x: x > 0),
    "reward_scale": ("> 0", lambda x: x > 0),
    "tau": ("in (0, 1]", lambda x: (x > 0) & (x <= 1)),
    "exploration_initial_eps": ("in [0, 1]", lambda x: (x >= 0) & (x <= 1)),
    "exploration_final_eps": ("in [0, 1]", lambda x: (x >= 0) & (x <= 1)),
    "exploration_fraction": ("in (0, 1]", lambda x: (x > 0) & (x <= 1)),
    "huber_delta": ("> 0", lambda x: x > 0),
    "initial_alpha": ("> 0", lambda x: x > 0),
    "policy_noise": (">= 0", lambda x: x >= 0),
    "noise_clip": (">= 0", lambda x: x >= 0),
    "exploration_noise": (">= 0", lambda x: x >= 0),
}
"""Valid range of every traced hyperparameter of every algorithm: name -> (rule in words, check)."""


def traced_fields(hyper_cls: type) -> tuple[str, ...]:
    """The traced hyperparameters of an algorithm: the fields of its ``Hyper`` struct."""
    return tuple(f.name for f in dataclasses.fields(hyper_cls))


def check_hyper(owner: str, **values: Any) -> None:
    """Raise ``ValueError`` for a traced value that is not finite or out of its range (scalars or arrays)."""
    for name, value in values.items():
        array = np.asarray(value, dtype=np.float64)
        if not np.all(np.isfinite(array)):
            raise ValueError(f"{owner} {name} must be finite, got {value!r}")
        if name in HYPER_RULES:
            rule, ok = HYPER_RULES[name]
            if not np.all(ok(array)):
                raise ValueError(f"{owner} {name} must be {rule}, got {value!r}")


def hyper_from_config(hyper_cls: type[HyperT], config: Any, owner: str, **overrides: Any) -> HyperT:
    """The config's traced values as ``hyper_cls`` (float32), any of them overridden (a sweep's arrays)."""
    names = traced_fields(hyper_cls)
    unknown = sorted(set(overrides) - set(names))
    if unknown:
        raise ValueError(f"unknown {owner} hyperparameter(s) {unknown}; traced ones: {list(names)}")
    values = {name: overrides.get(name, getattr(config, name)) for name in names}
    check_hyper(owner, **values)
    return hyper_cls(**{name: jnp.asarray(value, jnp.float32) for name, value in values.items()})


def check_positive_ints(owner: str, config: Any, names: tuple[str, ...]) -> None:
    """Each named config field is an ``int`` >= 1 (``bool`` refused)."""
    for name in names:
        value = getattr(config, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{owner} {name} must be a positive integer, got {value!r}")


def check_hidden_sizes(owner: str, hidden_sizes: tuple[int, ...]) -> None:
    if not hidden_sizes or any(int(width) < 1 for width in hidden_sizes):
        raise ValueError(f"{owner} hidden_sizes must be positive widths, e.g. (64, 64), got {hidden_sizes!r}")


def linear_decay(value: jax.Array, progress: jax.Array) -> jax.Array:
    """``value * max(1 - progress, 0)``: a linear schedule from ``value`` at progress 0 to 0 at progress 1."""
    return value * jnp.maximum(1.0 - progress, 0.0)


def clip_by_global_norm(grads: Any, max_norm: jax.Array) -> tuple[Any, jax.Array]:
    """``optax.clip_by_global_norm`` with a traced threshold (a sweep may vary it); also returns the norm.

    ``grads`` is an array or a pytree of arrays; the norm is over all of them.
    """
    leaves = jax.tree_util.tree_leaves(grads)
    norm = jnp.sqrt(functools.reduce(jnp.add, [jnp.sum(jnp.square(leaf)) for leaf in leaves]))
    scale = jnp.where(norm > max_norm, max_norm / norm, 1.0)
    return jax.tree.map(lambda g: g * scale, grads), norm


def count_events(env: Any, info: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """A batched step's counts of the info flags the environment names (``env.event_metrics``),
    as float32 scalars under their metric names: what every learner logs beside its losses."""
    return {metric: info[flag].sum().astype(jnp.float32) for flag, metric in env.event_metrics.items()}


def polyak_update(target: Any, online: Any, tau: jax.Array) -> Any:
    """A target network moved towards the online one: ``tau * online + (1 - tau) * target`` per leaf.

    ``tau = 1`` copies (DQN's hard update); a small ``tau`` is the soft update of DQN's default,
    SAC and TD3. ``tau`` may be traced (a sweep varies it).
    """
    return jax.tree.map(lambda t, o: tau * o + (1.0 - tau) * t, target, online)
