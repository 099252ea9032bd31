"""Where the suite's time goes: JAX's tracing, lowering and XLA compile time per test (a pytest plugin).

    python -m pytest -n 2 --dist loadscope -p tests.compile_profile --compile-profile DIR ...
    python bench/suite_compile_profile.py DIR

Each test process (the controller and every xdist worker) writes ``DIR/<worker>.json``: one
``[test id, kind, function name, seconds]`` per event JAX reports through ``jax.monitoring``
(kind ``trace``, ``lower``, ``compile``, or ``cache_hit`` for a program the persistent cache served; JAX
reports a compile event for those too). The folder's earlier ``.json`` files are removed at the start.
Subprocesses a test starts (CLI runs, notebook kernels) are not seen: their time counts as the test's.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "compile",
}
_events: list[tuple[str, str, str, float]] = []
_current = ["<collection>"]


def pytest_addoption(parser):
    parser.addoption("--compile-profile", metavar="DIR", default=None,
                     help="write JAX's trace, lowering and compile time per test to DIR (tests/compile_profile.py)")


def _listener(event: str, duration: float, **kwargs) -> None:
    kind = EVENTS.get(event, "cache_hit" if "cache_retrieval" in event else None)
    if kind is not None:
        _events.append((_current[0], kind, str(kwargs.get("fun_name", "")), float(duration)))


def pytest_configure(config):
    folder = config.getoption("--compile-profile")
    if folder:
        if "PYTEST_XDIST_WORKER" not in os.environ:  # the controller, before any worker: no earlier run's files
            for old in Path(folder).glob("*.json"):
                old.unlink()
        import jax.monitoring

        jax.monitoring.register_event_duration_secs_listener(_listener)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    _current[0] = item.nodeid
    yield


def pytest_unconfigure(config):
    folder = config.getoption("--compile-profile")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        name = os.environ.get("PYTEST_XDIST_WORKER", "controller")
        (Path(folder) / f"{name}.json").write_text(json.dumps(_events))
