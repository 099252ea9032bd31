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

import pytest  # noqa: E402

import wrl_jax  # noqa: E402

ENV_NAMES = ["Warehouse-8x8-v0", "Warehouse-12x12-v0"]


def pytest_sessionfinish(session, exitstatus):
    if _OWNS_CACHE and os.environ.get("WRL_TEST_CACHE_OWNER") == str(os.getpid()):
        shutil.rmtree(os.environ[_CACHE_VARIABLE], ignore_errors=True)


@pytest.fixture(params=ENV_NAMES)
def env_name(request):
    return request.param


@pytest.fixture
def env_and_params(env_name):
    return wrl_jax.make(env_name)
