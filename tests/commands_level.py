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
:func:`jit` compiles a test's own program at level 1 in place: for long learning runs, which level 1 runs
faster, not for claims about the package's programs (those are compiled inside the package).
Importable as ``import commands_level`` from any test (pytest puts ``tests/`` on the path).
"""

from __future__ import annotations

import functools
import inspect
import os
import re
import subprocess
import sys
from pathlib import Path

import fast_compile

LEVEL_VARIABLE = "WRL_TEST_XLA_LEVEL"
"""The session's LLVM level (``tests/conftest.py`` reads it; 0 unless set)."""

COMMANDS_LEVEL = 1
"""``wrl_jax.cli.machine.DEFAULT_XLA_OPT_LEVEL``, the level ``train_ppo.py`` and the other commands compile at."""

_LEVEL_FLAG = re.compile(r"--xla_backend_optimization_level=(-?\d+)")
ROOT = Path(__file__).resolve().parents[1]


jit = functools.partial(fast_compile.jit_at_level, COMMANDS_LEVEL)
"""``jax.jit`` compiling at the commands' level, for a test's own long-running program (a learning run measured at
level 1): level 1 compiles it more slowly but runs it up to five times faster than level 0. Usable as a decorator,
bare or with arguments."""


def xla_flags_at(level: int, flags: str) -> str:
    """``flags`` (an ``XLA_FLAGS`` value) with LLVM ``level`` in place of any level it names."""
    return f"{_LEVEL_FLAG.sub('', flags).strip()} --xla_backend_optimization_level={level}".strip()


def session_level() -> int | None:
    """The LLVM level this process compiles at, read from ``XLA_FLAGS``; ``None`` where it names none (XLA's default,
    ``WRL_TEST_XLA_LEVEL=-1``)."""
    found = _LEVEL_FLAG.findall(os.environ.get("XLA_FLAGS", ""))
    return int(found[-1]) if found else None


def at_commands_level(test):
    """Decorate a test to run at the commands' level: in place if the session runs there, else in a ``pytest``
    process at that level that must report it passed (its output is shown if not). One such process runs all the
    decorated tests of a module this session selected (:func:`_module_outcomes`): one start-up, one set of fixtures.
    For tests without parameters of their own (``run`` takes ``request`` only).

    The returned test requests only ``request``, so no fixture is computed at the session's level for
    nothing; at the commands' level it asks ``request`` for the fixtures ``test`` names.
    """
    names = list(inspect.signature(test).parameters)

    def run(request):
        if session_level() == COMMANDS_LEVEL:
            return test(**{name: request.getfixturevalue(name) for name in names})
        outcomes = _module_outcomes(request)
        assert request.node.nodeid in outcomes["passed"], (
            f"{request.node.nodeid} at LLVM level {COMMANDS_LEVEL}:\n{outcomes['output']}")

    for attribute in ("__name__", "__qualname__", "__module__", "__doc__"):
        setattr(run, attribute, getattr(test, attribute))
    run.pytestmark = list(getattr(test, "pytestmark", []))
    run.at_commands_level = True
    return run


def _module_outcomes(request) -> dict:
    """``{"passed": node ids, "output": ...}`` of the decorated tests of ``request``'s module that this session
    selected, run in one ``pytest`` process at the commands' level by the first of them to run (kept in the module)."""
    outcomes = request.module.__dict__.setdefault("_commands_level_outcomes", {})
    if not outcomes:
        nodeids = [item.nodeid for item in request.session.items
                   if item.module is request.module and getattr(item.obj, "at_commands_level", False)]
        env = {**os.environ, LEVEL_VARIABLE: str(COMMANDS_LEVEL),
               "XLA_FLAGS": xla_flags_at(COMMANDS_LEVEL, os.environ.get("XLA_FLAGS", ""))}
        outcomes.update(passed=set(), output="")
        try:
            done = subprocess.run(
                [sys.executable, "-m", "pytest", "-q", "-rA", "--color=no", "-p", "no:cacheprovider", "-p", "no:xdist",
                 *nodeids],
                cwd=ROOT, env=env, capture_output=True, text=True, timeout=900,
            )  # fmt: skip
        except subprocess.TimeoutExpired as error:  # kept, so the module's other decorated tests do not start another
            outcomes["output"] = f"the level-{COMMANDS_LEVEL} process timed out: {error}"
            return outcomes
        # Passed, not skipped or selected away: the short summary's "PASSED <node id>" lines, less any test that also
        # has an "ERROR <node id>" line (a fixture's teardown that failed after it).
        summary = {kind: set(re.findall(rf"^{kind} (\S+)", done.stdout, re.MULTILINE)) for kind in ("PASSED", "ERROR")}
        outcomes["passed"] = summary["PASSED"] - summary["ERROR"]
        outcomes["output"] = f"exit {done.returncode}\n{done.stdout[-6000:]}\n{done.stderr[-3000:]}"
    return outcomes
