"""Commands run as a user runs them, each in a process of its own, forked from one interpreter that has not started JAX.

A fresh interpreter spends more than a second of CPU importing what every command loads before JAX (NumPy,
ml_dtypes, ``wrl_jax``, which imports no JAX). Run as a script, this module loads those once and forks a child per
command; each child still starts JAX itself, with its own ``XLA_FLAGS``. The tests call :func:`launch` (a command
line: script or source, output files, environment) and :func:`in_child` (a function, its JSON result back through
a pipe) from the programs they run this way.
"""

from __future__ import annotations

import json
import os
import runpy
import signal
import socket
import subprocess
import sys
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def start(run: dict) -> int:
    """Fork a child for one command and return its pid. ``run``: ``argv`` (a script and its arguments) or ``source``
    (Python text); ``out`` and ``err`` files (the same path: one log); ``env``, when given, replaces the environment
    before the command starts JAX."""
    pid = os.fork()
    if pid:
        return pid
    out = os.open(run["out"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    os.dup2(out, 1)
    os.dup2(out if run["err"] == run["out"] else os.open(run["err"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC), 2)
    if "env" in run:
        os.environ.clear()
        os.environ.update(run["env"])
    code = 0
    try:
        if "source" in run:
            exec(compile(run["source"], "<forked source>", "exec"), {"__name__": "__main__"})
        else:
            sys.argv, sys.path[0] = run["argv"], os.path.dirname(os.path.abspath(run["argv"][0]))
            runpy.run_path(run["argv"][0], run_name="__main__")
    except SystemExit as exit:
        code = exit.code if isinstance(exit.code, int) else int(exit.code is not None)
    except BaseException:
        traceback.print_exc()
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def in_child(body, *args):
    """``body(*args)`` (JSON in and out) in a forked child, so that what it imports or patches stays there; an
    exception comes back as ``{"error": repr}`` (the other children still run)."""
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(read)
        try:
            result = body(*args)
        except BaseException as error:
            result = {"error": repr(error)}
        with os.fdopen(write, "w") as pipe:
            pipe.write(json.dumps(result))
        os._exit(0)
    os.close(write)
    with os.fdopen(read) as pipe:
        text = pipe.read()
    os.waitpid(pid, 0)
    return json.loads(text)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def run_stage(stage: list[dict]) -> list[int]:
    """A stage's commands at once (``{port}`` in their environments: one port free as the stage starts); exit codes."""
    port = str(free_port())
    runs = [{**run, "env": {k: v.replace("{port}", port) for k, v in run["env"].items()}} if "env" in run else run
            for run in stage]
    return [os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]) for pid in [start(run) for run in runs]]


def launch(stages: list[list[dict]], timeout: float = 900) -> list[list[int]]:
    """Run ``stages`` (lists of :func:`start`'s commands), one stage after the other, from a fresh launcher
    process; the exit codes, stage by stage. On a timeout the launcher and every command it forked are killed."""
    proc = subprocess.Popen([sys.executable, __file__, json.dumps(stages)], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        raise
    assert proc.returncode == 0, err[-4000:]
    return json.loads(out.strip().splitlines()[-1])


if __name__ == "__main__":
    sys.path[0] = str(ROOT)  # wrl_jax from this checkout, as the commands import it
    import ml_dtypes  # noqa: F401
    import numpy  # noqa: F401

    import wrl_jax  # noqa: F401

    assert "jax" not in sys.modules, "importing wrl_jax imported JAX"
    print(json.dumps([run_stage(stage) for stage in json.loads(sys.argv[1])]))
