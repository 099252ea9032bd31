"""Split the CPU into XLA host devices from a bench's command line, before JAX starts (no JAX imported here).

XLA reads ``XLA_FLAGS`` once, when JAX starts, so a bench that splits its batch over host devices must
set the device count before its first ``import jax``. The rule itself is ``wrl_jax/cli/machine.py``'s,
loaded by its path: importing it through the package would start JAX too early.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def load_machine_module():
    """``wrl_jax/cli/machine.py`` as a module of its own, without importing the package."""
    spec = importlib.util.spec_from_file_location("_wrl_jax_machine", ROOT / "wrl_jax" / "cli" / "machine.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def split_cpu_from_argv(argv: list[str], option: str, default: int) -> None:
    """Set ``XLA_FLAGS`` to split the CPU into the count of ``option`` in ``argv`` (else ``default``) host devices."""
    machine = load_machine_module()
    os.environ["XLA_FLAGS"] = machine.xla_flags_with_host_devices(
        os.environ.get("XLA_FLAGS", ""), machine.int_option_from_argv(argv, option, default))
