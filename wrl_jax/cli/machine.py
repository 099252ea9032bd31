"""What the commands record and set about the machine: XLA's CPU optimization level, CPU facts and load."""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path
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


HOST_DEVICES_FLAG = "--xla_force_host_platform_device_count"
"""XLA's flag that splits the CPU into several XLA devices (each runs its own programs on its own thread)."""


def xla_flags_with_host_devices(flags: str, count: int) -> str:
    """``flags`` with the CPU split into ``count`` XLA devices, unless ``flags`` already says how many.

    Why: on XLA's CPU backend one device runs a program's fused loops on one thread, so the
    elementwise-heavy programs here (the fleet step, PPO updates of small networks) leave the
    other cores mostly idle; with the batch split over several host devices each device's share
    runs on its own thread (docs/scale.md, "Host devices", has the measured speed-ups). Only the CPU
    platform reads this flag; a GPU's devices are unaffected. ``count`` of 1 or less adds nothing.
    """
    if count <= 1 or HOST_DEVICES_FLAG in flags:
        return flags
    return " ".join([flags.strip(), f"{HOST_DEVICES_FLAG}={int(count)}"]).strip()


def apply_xla_opt_level(level: int) -> None:
    """Set XLA's CPU optimization level and :data:`COMPILE_TIME_FLAGS` where ``XLA_FLAGS`` does not set them.

    Effective only before JAX starts its backends: XLA reads ``XLA_FLAGS`` then, and never again.
    """
    os.environ["XLA_FLAGS"] = xla_flags_with_defaults(os.environ.get("XLA_FLAGS", ""), level)


def option_from_argv(argv: list[str], name: str) -> str | None:
    """The first value of option ``name`` in a command line (``name V`` or ``name=V``), else ``None``.

    Read before the command's own parser runs (before JAX starts); the parser reports bad values.
    """
    for index, arg in enumerate(argv):
        if arg == name and index + 1 < len(argv):
            return argv[index + 1]
        if arg.startswith(f"{name}="):
            return arg.split("=", 1)[1]
    return None


def int_option_from_argv(argv: list[str], name: str, default: int) -> int:
    """The integer option ``name`` of a command line, else ``default`` (also for a value that is no integer)."""
    try:
        return int(option_from_argv(argv, name) or default)
    except ValueError:
        return default


def opt_level_from_argv(argv: list[str]) -> int:
    """The ``--xla-opt-level`` of a command line (``--xla-opt-level L`` or ``=L``), else the default."""
    return int_option_from_argv(argv, "--xla-opt-level", DEFAULT_XLA_OPT_LEVEL)


AUTO_DEVICES_ENVS = ("Procedural-Warehouse-v0",)
"""Environments on which ``train_ppo.py`` splits the CPU into host devices when ``--devices`` is not given.

The planning policy's update is elementwise work that one XLA CPU device runs on one thread; split into
as many devices as cores (and seeds) it trained 1.4x faster on 2 cores (docs/procedural.md)."""


def _flag(arg: str) -> str:
    """A command-line word with the flag part's underscores as dashes (tyro takes both spellings)."""
    if not arg.startswith("--"):
        return arg
    name, sep, value = arg.partition("=")
    return name.replace("_", "-") + sep + value


AUTO_DEVICES_ALGOS = ("sac", "td3")
"""Commands that split the CPU into host devices on every environment when ``--devices`` is not given.

SAC's and TD3's updates (small networks, batch 256, a gradient step at a time) leave the second core idle on one
device; split, SAC's default trained 1.5-1.9x faster on 2 cores (docs/continuous.md)."""


def auto_devices(argv: list[str], cpu_count: int | None, environ: dict[str, str] | None = None,
                 algo: str = "ppo") -> list[str]:
    """The flags a training command adds to ``argv`` about devices, where the user chose nothing.

    On :data:`AUTO_DEVICES_ENVS`, and on every environment for an ``algo`` of :data:`AUTO_DEVICES_ALGOS`:
    ``--devices N``, the most devices, at most the CPU's cores, that divide the seeds evenly. ``--resume``: the
    ``--devices`` and ``--env-shards`` the run recorded in its ``config.json`` (a resume on the same devices is
    exact). Nothing where the user chose (``--devices``, ``--env-shards``, ``--distributed`` or
    ``WRL_DISTRIBUTED``, a host device count in ``XLA_FLAGS``), on other environments, or on one core.
    """
    environ = os.environ if environ is None else environ
    argv = [_flag(arg) for arg in argv]
    chosen = ("--devices", "--distributed", "--env-shards")
    user_chose = (any(arg == flag or arg.startswith(f"{flag}=") for arg in argv for flag in chosen)
                  or environ.get("WRL_DISTRIBUTED", "") not in ("", "0")
                  or HOST_DEVICES_FLAG in environ.get("XLA_FLAGS", ""))
    if user_chose:
        return []
    if "--resume" in argv:
        out = option_from_argv(argv, "--out")
        try:
            recorded = json.loads((Path(out) / "config.json").read_text()) if out else {}
        except (OSError, ValueError):
            recorded = {}  # the command's own checks report a missing or broken run
        flags = []
        for name in ("devices", "env_shards"):
            value = recorded.get(name, 1)
            if isinstance(value, int) and value != 1:
                flags += [f"--{name.replace('_', '-')}", str(value)]
        return flags
    every_env = algo in AUTO_DEVICES_ALGOS
    if (not every_env and option_from_argv(argv, "--env") not in AUTO_DEVICES_ENVS) or not cpu_count or cpu_count < 2:
        return []
    seeds = max(1, int_option_from_argv(argv, "--num-seeds", 4))
    count = max(d for d in range(1, min(cpu_count, seeds) + 1) if seeds % d == 0)
    return ["--devices", str(count)] if count > 1 else []


CHOSEN_DEVICES_VARIABLE = "WRL_DEVICES_CHOSEN_BY_COMMAND"
"""Set by :func:`apply_for_command` to the ``--devices`` it chose: the command falls back to one device if
JAX's backend is not the CPU (the split is the CPU's; a GPU machine has its own device count)."""


def apply_for_command(argv: list[str], choose_devices: bool = False, algo: str = "ppo") -> list[str]:
    """A command's first statement: its XLA settings and distributed start-up, before JAX starts.

    ``--xla-opt-level`` (with :data:`COMPILE_TIME_FLAGS`) and, for ``--devices N`` with ``N > 1``, the CPU
    split into ``N`` host devices (:func:`xla_flags_with_host_devices`; ``XLA_FLAGS`` naming its own count
    wins). XLA reads ``XLA_FLAGS`` once, when JAX's backend starts (making an environment starts it), so this
    runs before any environment or algorithm is imported; ``import wrl_jax`` itself starts nothing. Then,
    for ``--distributed`` (or ``WRL_DISTRIBUTED=1``), JAX's distributed runtime
    (:mod:`wrl_jax._distributed`), which must also come before the backend.

    ``choose_devices``: add the flags of :func:`auto_devices` for the command's ``algo``. Returns the command line
    to parse.
    """
    from wrl_jax import _distributed

    asks_help = any(arg in ("-h", "--help") for arg in argv)
    if choose_devices and not asks_help and (flags := auto_devices(argv, os.cpu_count(), algo=algo)):
        argv = [*argv, *flags]
        if "--resume" not in argv:
            count = flags[1]
            os.environ[CHOSEN_DEVICES_VARIABLE] = count
            print(f"the CPU split into {count} host devices for the seeds (--devices {count}; --devices 1 keeps one)")
    apply_xla_opt_level(opt_level_from_argv(argv))
    # ``--devices N`` on a CPU: split it into N XLA devices, so that there are N to shard over.
    os.environ["XLA_FLAGS"] = xla_flags_with_host_devices(os.environ.get("XLA_FLAGS", ""),
                                                          int_option_from_argv(argv, "--devices", 1))
    _distributed.initialize_if_requested()
    return argv


def cpu_info() -> dict[str, Any]:
    info: dict[str, Any] = {"machine": platform.machine(), "cpu_count": os.cpu_count()}
    try:
        info["load_average"] = list(os.getloadavg())
    except OSError:
        pass
    return info


