"""Shared fixtures (the two registered environments) and the test session's compilation cache.

Many tests compile the same XLA programs in different processes: the two xdist workers, and
every subprocess a CLI test starts (``train_ppo.py``, ``python -m wrl_jax.evaluate``...). JAX's
persistent compilation cache, in a directory made fresh for each session (so a run on a
developer's machine costs what it costs in CI, on a clean checkout), lets the second compile of
a program load the first one's executable. Same executable, same bits: only compile time changes.
The directory is set before JAX is imported, through the environment, so the workers and every
subprocess inherit it; the controlling process removes it at the end.
"""

import os
import shutil
import tempfile

_CACHE_VARIABLE = "JAX_COMPILATION_CACHE_DIR"
_OWNS_CACHE = _CACHE_VARIABLE not in os.environ
if _OWNS_CACHE:
    os.environ[_CACHE_VARIABLE] = tempfile.mkdtemp(prefix="wrl-jax-test-xla-")
    os.environ["WRL_TEST_CACHE_OWNER"] = str(os.getpid())
# Cache every program that took a fifth of a second or more to compile (JAX's default is 1 s).
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.2")
# The commands' XLA settings (wrl_jax.cli.machine: the classic fusion emitter) at LLVM level 0 instead of the
# commands' 1: most test programs run for milliseconds, compiling is most of what the suite does, and level 0
# compiles in about half the time. The CLI subprocesses inherit XLA_FLAGS, so the cache serves both. Tests whose
# claims are about level-1 programs run at level 1 in a process of their own (tests/commands_level.py);
# `WRL_TEST_XLA_LEVEL=1 pytest` runs the whole session at the commands' level.
from wrl_jax.cli import machine  # noqa: E402  (imports no JAX: XLA_FLAGS still count)

os.environ["XLA_FLAGS"] = machine.xla_flags_with_defaults(os.environ.get("XLA_FLAGS", ""),
                                                          int(os.environ.get("WRL_TEST_XLA_LEVEL", "0")))

import pytest  # noqa: E402

import wrl_jax  # noqa: E402

ENV_NAMES = ["Warehouse-8x8-v0", "Warehouse-12x12-v0"]

HEAVY_MODULES = (
    "test_sharding", "test_notebooks", "test_procedural", "test_propagation", "test_fleet_training",
    "test_experiments", "test_ppo", "test_fleet_env", "test_dqn", "test_procedural_refresh", "test_training",
    "test_cli", "test_sweep", "test_bench_tools", "test_gymnax_clients", "test_gymnax_api", "test_install",
    "test_off_policy", "test_gymnasium_continuous", "test_rware_parity", "test_yardstick", "test_continuous_procedural",
    "test_rware_gymnasium", "test_rware_evaluation", "test_rware_conflicts", "test_rware_set_order",
)
"""Test modules by the CPU time their tests took (``pytest -n 2 --durations=0``, summed per module, 2026-12-04), most first.

``make test`` runs ``pytest -n 2 --dist loadscope --no-loadscope-reorder``: a module is one work unit
(its module-scoped fixtures, several of which train a run, are computed once, on one worker), and
the workers take units in collection order, so the long ones start first and the two workers
finish together instead of one of them running a two-minute module alone at the end. (Not
``--dist loadgroup``: with pytest 9.2 xdist 3.8's ``xdist_group`` marks no longer reach the
scheduler, which then splits a group's tests between the workers.)"""


def _module_name(item) -> str:
    return item.module.__name__.rsplit(".", 1)[-1] if getattr(item, "module", None) else ""


def pytest_collection_modifyitems(config, items):
    """Heavy modules first (:data:`HEAVY_MODULES`); tests keep their file order within a module."""
    rank = {name: index for index, name in enumerate(HEAVY_MODULES)}
    items.sort(key=lambda item: rank.get(_module_name(item), len(rank)))


@pytest.fixture(scope="module")
def geodesic_fields_at_the_commands_level():
    """The continuous maps' geodesic fields (the package's Bellman-Ford loop, hundreds of sweeps, run once per layout
    and remembered) compiled at the commands' LLVM level, for the modules that build many maps: the session's level 0
    runs that loop about five times slower (3.6 s of CPU for the 12x12 map, against 0.8 s), and its adds and minimums
    round alike at every level (the three maps' fields compared bit for bit at levels 0, 1 and 2)."""
    import commands_level
    from wrl_jax.envs.continuous import geodesic

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(geodesic, "_relax", commands_level.jit(geodesic._relax.__wrapped__, static_argnums=3))
        yield


@pytest.fixture(params=ENV_NAMES)
def env_name(request):
    return request.param


@pytest.fixture
def env_and_params(env_name):
    return wrl_jax.make(env_name)


def pytest_unconfigure(config):
    """The controlling process removes the session's compilation cache (workers and subprocesses only read it)."""
    if _OWNS_CACHE and os.environ.get("WRL_TEST_CACHE_OWNER") == str(os.getpid()):
        shutil.rmtree(os.environ[_CACHE_VARIABLE], ignore_errors=True)
