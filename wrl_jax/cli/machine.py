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

COMPILE_TIME_FLAGS = ("--xla_cpu_use_fusion_emitters=false",)
"""XLA CPU flags the commands add beside the optimization level, for compile time.

``--xla_cpu_use_fusion_emitters=false`` emits fused loops with XLA's classic
elemental emitter instead of the newer MLIR fusion pipeline: a third less compile
time for these programs at the same speed per update (``bench/xla_compile_flags.py``,
docs/training.md). Each is applied only when ``XLA_FLAGS`` does not name it already,
and none is applied with ``--xla-opt-level -1`` (XLA's defaults throughout)."""


def xla_flags_with_defaults(flags: str, level: int) -> str:
    """``flags`` (an ``XLA_FLAGS`` value) with the commands' settings added where it does not set them."""
    if level < 0:
        return flags
    added = [] if "xla_backend_optimization_level" in flags else [f"--xla_backend_optimization_level={int(level)}"]
    added += [flag for flag in COMPILE_TIME_FLAGS if flag.split("=")[0] not in flags]
    return " ".join([flags.strip(), *added]).strip()


def apply_xla_opt_level(level: int) -> None:
    """Set XLA's CPU optimization level and :data:`COMPILE_TIME_FLAGS` where ``XLA_FLAGS`` does not set them.

    Effective only before JAX compiles anything in this process.
    """
    os.environ["XLA_FLAGS"] = xla_flags_with_defaults(os.environ.get("XLA_FLAGS", ""), level)


def cpu_info() -> dict[str, Any]:
    info: dict[str, Any] = {"machine": platform.machine(), "cpu_count": os.cpu_count()}
    try:
        info["load_average"] = list(os.getloadavg())
    except OSError:
        pass
    return info


