"""Split the CPU into XLA host devices from a bench's command line, before JAX starts (no JAX imported here).

XLA reads ``XLA_FLAGS`` once, when JAX starts, so a bench that splits its batch over host devices must
set the device count before its first ``import jax``. The rule itself is :mod:`wrl_jax.cli.machine`'s
(``import wrl_jax`` starts no JAX).
"""

from __future__ import annotations

import os

from wrl_jax.cli import machine


def split_cpu_from_argv(argv: list[str], option: str, default: int) -> None:
    """Set ``XLA_FLAGS`` to split the CPU into the count of ``option`` in ``argv`` (else ``default``) host devices."""
    os.environ["XLA_FLAGS"] = machine.xla_flags_with_host_devices(
        os.environ.get("XLA_FLAGS", ""), machine.int_option_from_argv(argv, option, default))
