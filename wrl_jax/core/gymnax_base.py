"""gymnax's base class and spaces, loaded without the rest of gymnax.

wrl_jax's environments subclass ``gymnax.environments.environment.Environment`` and use
``gymnax.environments.spaces``. Those two modules import only JAX, flax, NumPy and
Gymnasium, but ``import gymnax`` also imports all twenty of gymnax's own environments (Pong
imports seaborn, hence SciPy and pandas; Catch imports matplotlib): about 1.3 s, more than a
third of a training command's start-up. So, unless gymnax is loaded already, the two files
are loaded here under their own names (``sys.modules["gymnax.environments.environment"]``),
without running gymnax's package ``__init__`` files. When gymnax itself is imported later,
its package finds them loaded and uses them: one ``Environment`` class, whichever came first.
:func:`wrl_jax.core.registry.register_with_gymnax_when_imported` then binds them as its
attributes and registers our names. (The first load is not locked against another thread importing gymnax at
the same moment: make the first environment before starting threads that import gymnax.)

A missing dependency of one of gymnax's own environments (six, for its MNIST bandit) no
longer stops wrl_jax either; :func:`import_gymnax` says what to install when gymnax itself is needed.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

BASE_MODULES = ("gymnax.environments.spaces", "gymnax.environments.environment")
"""The gymnax modules wrl_jax needs, in an order that loads each one's imports first (neither imports gymnax)."""


def import_gymnax() -> ModuleType:
    """``import gymnax``, with an error that names the missing package and the command that installs it."""
    try:
        import gymnax
    except ImportError as error:
        raise ImportError(
            f"wrl_jax registers its environments with gymnax, and `import gymnax` failed: {error}. "
            "gymnax imports all of its own environments on import, so any of their dependencies is needed. "
            "Install the locked set (`make install`, or `pip install --require-hashes --no-deps -r "
            f"requirements/core.txt`), or the missing package: `pip install {(error.name or '<package>').split('.')[0]}`."
        ) from error
    return gymnax


def _load_by_file(name: str, package_dir: str) -> ModuleType:
    """Load one module of gymnax under its own name, without importing its parent packages."""
    if name in sys.modules:
        return sys.modules[name]
    path = Path(package_dir, *name.split(".")[1:]).with_suffix(".py")
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def _base_modules() -> tuple[ModuleType, ModuleType]:
    """(spaces, environment): loaded by file when gymnax is not loaded yet and sits on ``sys.path``."""
    if "gymnax" not in sys.modules:
        package = importlib.machinery.PathFinder.find_spec("gymnax")  # on sys.path, past wrl_jax's import hook
        if package is not None and package.submodule_search_locations:
            package_dir = list(package.submodule_search_locations)[0]
            return tuple(_load_by_file(name, package_dir) for name in BASE_MODULES)
    import_gymnax()  # loaded already, or installed where only the import system finds it (or missing: the error)
    from gymnax.environments import environment, spaces
    return spaces, environment


spaces, gymnax_environment = _base_modules()

__all__ = ["gymnax_environment", "import_gymnax", "spaces"]
