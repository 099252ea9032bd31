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

    Effective only before JAX starts its backends: XLA reads ``XLA_FLAGS`` then, and never again.
    """
    os.environ["XLA_FLAGS"] = xla_flags_with_defaults(os.environ.get("XLA_FLAGS", ""), level)


def opt_level_from_argv(argv: list[str]) -> int:
    """The ``--xla-opt-level`` of a command line (``--xla-opt-level L`` or ``=L``), else the default."""
    for index, arg in enumerate(argv):
        if arg == "--xla-opt-level" and index + 1 < len(argv):
            value = argv[index + 1]
        elif arg.startswith("--xla-opt-level="):
            value = arg.split("=", 1)[1]
        else:
            continue
        try:
            return int(value)
        except ValueError:
            return DEFAULT_XLA_OPT_LEVEL  # the command's own parser reports the bad value
    return DEFAULT_XLA_OPT_LEVEL


def apply_for_command(argv: list[str]) -> None:
    """The training scripts' first statement: the command line's XLA settings, before JAX starts.

    Importing wrl_jax starts JAX (gymnax creates arrays at import), so the scripts call this before their
    first import; ``python -m wrl_jax.<command>`` imports the package before any of its code runs, so
    there only ``XLA_FLAGS`` itself is effective.
    """
    apply_xla_opt_level(opt_level_from_argv(argv))


def cpu_info() -> dict[str, Any]:
    info: dict[str, Any] = {"machine": platform.machine(), "cpu_count": os.cpu_count()}
    try:
        info["load_average"] = list(os.getloadavg())
    except OSError:
        pass
    return info


