"""What the commands record and set about the machine: XLA's CPU optimization level, CPU facts and load."""

from __future__ import annotations

import os
import platform
from typing import Any

DEFAULT_XLA_OPT_LEVEL = 1
"""LLVM optimization level for XLA's CPU code (``--xla_backend_optimization_level``).

XLA's default (3) spends about twice the compile time for no measurable speed-up
on these small kernels (docs/training.md has the measurement); on a one-minute
run compile time is a real share. Set ``--xla-opt-level -1`` to keep XLA's default,
or put the flag in ``XLA_FLAGS`` yourself (that wins)."""


def apply_xla_opt_level(level: int) -> None:
    """Set XLA's CPU backend optimization level unless ``XLA_FLAGS`` already sets it.

    Effective only before JAX compiles anything in this process.
    """
    if level < 0:
        return
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_backend_optimization_level" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} --xla_backend_optimization_level={int(level)}".strip()


def cpu_info() -> dict[str, Any]:
    info: dict[str, Any] = {"machine": platform.machine(), "cpu_count": os.cpu_count()}
    try:
        info["load_average"] = list(os.getloadavg())
    except OSError:
        pass
    return info


