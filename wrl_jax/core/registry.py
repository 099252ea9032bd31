"""Environment names -> factories, for ``wrl_jax.make`` and ``gymnax.make`` alike.

A family registers each of its named environments once, with a factory
``factory(**overrides) -> (env, params)`` given as a ``"module:function"``
path, so nothing is imported until a name is made. Every name is also
registered with gymnax's own registry as ``"wrl_jax/<name>"``, once gymnax
is loaded: ``import gymnax`` imports every gymnax environment and starts JAX's
backend, which ``import wrl_jax`` must not do (a broken corner of gymnax would
take the whole package down, and XLA's flags could no longer be set), and
wrl_jax's environments load only gymnax's base modules. So ``import wrl_jax``
registers with gymnax if it is loaded, else installs an import hook that does
it when gymnax is imported (:func:`register_with_gymnax_when_imported`), in
whichever order the two come; gymnax refuses an id twice, so it checks first.

The one place that lists the built-in names is :mod:`wrl_jax.envs`.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import importlib.abc
import importlib.util
import sys
from collections.abc import Callable
from typing import Any

GYMNAX_PREFIX = "wrl_jax/"


@dataclasses.dataclass(frozen=True)
class EnvEntry:
    """A registered environment name.

    Attributes:
        name: e.g. ``"Warehouse-12x12-v0"``.
        factory: ``"package.module:function"``; the function takes keyword
            overrides and returns ``(env, params)`` with ``env.default_params is params``.
        family: the family folder (``"warehouse"``, ``"fleet"``, ...), for docs and listings.
        kwargs: fixed keyword arguments passed to the factory before the user's overrides.
    """

    name: str
    factory: str
    family: str
    kwargs: tuple[tuple[str, Any], ...] = ()

    def load(self) -> Callable[..., tuple[Any, Any]]:
        module_name, function_name = self.factory.split(":")
        return getattr(importlib.import_module(module_name), function_name)


_REGISTRY: dict[str, EnvEntry] = {}


def register(name: str, factory: str, *, family: str, **kwargs: Any) -> None:
    """Register ``name`` (idempotent for an identical entry; a different one is an error)."""
    entry = EnvEntry(name=name, factory=factory, family=family, kwargs=tuple(sorted(kwargs.items())))
    existing = _REGISTRY.get(name)
    if existing is not None and existing != entry:
        raise ValueError(f"environment {name!r} is already registered as {existing}")
    _REGISTRY[name] = entry
    if _GYMNAX_REGISTERED:
        register_with_gymnax()


def registered_names(family: str | None = None) -> list[str]:
    return sorted(name for name, entry in _REGISTRY.items() if family is None or entry.family == family)


def entry(name: str) -> EnvEntry:
    if name.startswith(GYMNAX_PREFIX):
        name = name[len(GYMNAX_PREFIX):]
    if name not in _REGISTRY:
        raise ValueError(f"unknown environment {name!r}; registered: {', '.join(registered_names())}")
    return _REGISTRY[name]


def make(name: str, **overrides: Any) -> tuple[Any, Any]:
    """Build a registered environment: ``(env, params)``; ``env.default_params`` are those params.

    ``name`` may carry gymnax's ``"wrl_jax/"`` prefix. Overrides are the
    family's (reward constants, ``max_steps``, ``num_robots``, ...); an
    unknown one is a ``ValueError`` from the family's factory.
    """
    found = entry(name)
    return found.load()(**{**dict(found.kwargs), **overrides})


_EVALUATIONS: dict[str, str] = {}


def register_evaluation(family: str, target: str) -> None:
    """Register a family's evaluation hook (``"module:attribute"``, a
    :class:`wrl_jax.core.evaluation.FamilyEvaluation`), loaded on first use."""
    existing = _EVALUATIONS.get(family)
    if existing is not None and existing != target:
        raise ValueError(f"family {family!r} already has the evaluation {existing}")
    _EVALUATIONS[family] = target


def evaluation(family: str) -> Any:
    """The evaluation hook of an environment family."""
    if family not in _EVALUATIONS:
        raise ValueError(
            f"environment family {family!r} has no evaluation registered (known: {sorted(_EVALUATIONS)}); "
            f"register one in wrl_jax/envs/__init__.py"
        )
    module_name, attribute = _EVALUATIONS[family].split(":")
    return getattr(importlib.import_module(module_name), attribute)


_GYMNAX_REGISTERED = False


def register_with_gymnax() -> list[str]:
    """Register every name with gymnax as ``"wrl_jax/<name>"`` (idempotent); returns the gymnax ids.

    Imports gymnax. Names registered later are added as they come.
    """
    global _GYMNAX_REGISTERED
    from wrl_jax.core.gymnax_base import import_gymnax

    gymnax = import_gymnax()
    for name in _REGISTRY:
        if GYMNAX_PREFIX + name not in gymnax.registered_envs:
            gymnax.register(GYMNAX_PREFIX + name, functools.partial(_make_env_only, name))
    _GYMNAX_REGISTERED = True
    return [GYMNAX_PREFIX + name for name in _REGISTRY]


def register_with_gymnax_when_imported() -> None:
    """Register with gymnax now if it is loaded, else as soon as anyone imports it.

    ``import wrl_jax`` must not import gymnax (it starts JAX), and wrl_jax's environments load
    only gymnax's base modules (:mod:`wrl_jax.core.gymnax_base`). So the names reach gymnax's
    registry through an import hook: the first ``import gymnax`` runs gymnax's package as
    usual, then :func:`_finish_gymnax`.
    """
    if "gymnax" in sys.modules:
        _finish_gymnax()
    elif not any(isinstance(finder, _GymnaxImportHook) for finder in sys.meta_path):
        sys.meta_path.insert(0, _GymnaxImportHook())


def _finish_gymnax() -> None:
    """gymnax's package is loaded: bind the base modules wrl_jax loaded on its own as the attributes they
    would have been (``gymnax.environments.spaces``), and register our names."""
    environments = sys.modules.get("gymnax.environments")
    for name in ("environment", "spaces"):
        module = sys.modules.get(f"gymnax.environments.{name}")
        if environments is not None and module is not None and not hasattr(environments, name):
            setattr(environments, name, module)
    register_with_gymnax()


class _GymnaxImportHook(importlib.abc.MetaPathFinder):
    """Finds gymnax with the finders after it, so that :func:`_finish_gymnax` runs once gymnax's package has run.

    It stays installed: a lookup alone (``importlib.util.find_spec("gymnax")``) or a failed import must not use it
    up, and once gymnax is in ``sys.modules`` no import asks it again.
    """

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname != "gymnax":
            return None
        others = [finder for finder in sys.meta_path if finder is not self and hasattr(finder, "find_spec")]
        for finder in others:
            spec = finder.find_spec(fullname, path, target)
            if spec is not None:
                if spec.loader is not None:
                    spec.loader = _ThenFinishGymnax(spec.loader)
                return spec
        return None


class _ThenFinishGymnax(importlib.abc.Loader):
    """gymnax's own loader, with :func:`_finish_gymnax` after the package's code has run."""

    def __init__(self, loader: Any):
        self._loader = loader

    def create_module(self, spec: Any) -> Any:
        return self._loader.create_module(spec)

    def exec_module(self, module: Any) -> None:
        self._loader.exec_module(module)
        _finish_gymnax()

    def __getattr__(self, name: str) -> Any:  # get_resource_reader, is_package...: gymnax's loader's own
        return getattr(self._loader, name)


def _make_env_only(name: str, **overrides: Any) -> Any:
    """gymnax's factories return the environment alone; gymnax pairs it with ``default_params``."""
    return make(name, **overrides)[0]
