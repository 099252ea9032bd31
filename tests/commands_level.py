"""Tests whose claims are about programs as the commands compile them (LLVM level 1) run at that level.

The session compiles at LLVM level 0 (``tests/conftest.py``): about half the compile time of level 1,
and the suite is mostly compiling. The program XLA builds is the same at every level; only how LLVM
optimizes the machine code changes, so level 0 may round a float otherwise (a multiply and an add
fused here and not there). A few tests claim more than the program's logic:
- that two differently built programs round alike (``make_train`` and the chunked driver, the Gymnasium
  adapter and the jitted transition, a slot of the procedural pool and the plain environment), which
  holds for the programs as the commands compile them, not for any code generation;
- a learning threshold measured at the commands' level (the default preset's), whose run is also
  five times slower at level 0.

:func:`at_commands_level` runs such a test in a pytest process of its own at level 1 (its fixtures
computed there), or in place when the session already runs at level 1 (``WRL_TEST_XLA_LEVEL=1 pytest``).
Importable as ``import commands_level`` from any test (pytest puts ``tests/`` on the path).
"""

from __future__ import annotations

import inspect
import os
import re
import subprocess
import sys
from pathlib import Path

LEVEL_VARIABLE = "WRL_TEST_XLA_LEVEL"
"""The session's LLVM level (``tests/conftest.py`` reads it; 0 unless set)."""

COMMANDS_LEVEL = 1
"""``wrl_jax.cli.machine.DEFAULT_XLA_OPT_LEVEL``, the level ``train_ppo.py`` and the other commands compile at."""

_LEVEL_FLAG = re.compile(r"--xla_backend_optimization_level=(-?\d+)")
ROOT = Path(__file__).resolve().parents[1]


def session_level() -> int | None:
    """The LLVM level this process compiles at, read from ``XLA_FLAGS``; ``None`` where it names none (XLA's default,
    ``WRL_TEST_XLA_LEVEL=-1``)."""
    found = _LEVEL_FLAG.findall(os.environ.get("XLA_FLAGS", ""))
    return int(found[-1]) if found else None


def at_commands_level(test):
    """Decorate a test to run at the commands' level: in place if the session runs there, else in a
    ``pytest`` subprocess that selects this test alone and must report it passed (its output is shown if not).
    For tests without parameters of their own (``run`` takes ``request`` only).

    The returned test requests only ``request``, so no fixture is computed at the session's level for
    nothing; at the commands' level it asks ``request`` for the fixtures ``test`` names.
    """
    names = list(inspect.signature(test).parameters)

    def run(request):
        if session_level() == COMMANDS_LEVEL:
            return test(**{name: request.getfixturevalue(name) for name in names})
        env = {**os.environ, LEVEL_VARIABLE: str(COMMANDS_LEVEL),
               "XLA_FLAGS": _LEVEL_FLAG.sub("", os.environ.get("XLA_FLAGS", "")).strip()}
        done = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:xdist", request.node.nodeid],
            cwd=ROOT, env=env, capture_output=True, text=True, timeout=900,
        )  # fmt: skip
        output = f"{request.node.nodeid} at LLVM level {COMMANDS_LEVEL}:\n{done.stdout[-6000:]}\n{done.stderr[-3000:]}"
        assert done.returncode == 0, output
        # It ran and passed: not skipped, not selected away (pytest's summary line: "1 passed in 3.2s", "1 passed, 2 warnings in ...").
        assert re.search(r"^1 passed[ ,]", done.stdout, re.MULTILINE), output

    for attribute in ("__name__", "__qualname__", "__module__", "__doc__"):
        setattr(run, attribute, getattr(test, attribute))
    run.pytestmark = list(getattr(test, "pytestmark", []))
    return run
