"""Multi-host start-up that must run before anything touches JAX's backend.

``jax.distributed.initialize`` refuses to run once the XLA backend exists,
and making an environment or an algorithm (their arrays) already creates it. So
the command lines call :func:`initialize_if_requested` first of all
(:func:`wrl_jax.cli.machine.apply_for_command`): when the process was started as a multi-host run (``--distributed`` on a
wrl_jax command line, or ``WRL_DISTRIBUTED=1``), it initializes JAX's
distributed runtime from ``WRL_COORDINATOR``, ``WRL_NUM_PROCESSES`` and
``WRL_PROCESS_ID`` (unset ones are left to JAX's cluster auto-detection).
This module imports nothing of the package.
"""

from __future__ import annotations

import os
import sys


def requested() -> bool:
    return os.environ.get("WRL_DISTRIBUTED") == "1" or "--distributed" in sys.argv[1:]


def initialize(
    coordinator_address: str | None = None, num_processes: int | None = None, process_id: int | None = None
) -> None:
    """``jax.distributed.initialize`` from the arguments or the ``WRL_*`` variables; a no-op if already done."""
    import jax

    if jax.distributed.is_initialized():
        return
    coordinator_address = coordinator_address or os.environ.get("WRL_COORDINATOR")
    if num_processes is None and "WRL_NUM_PROCESSES" in os.environ:
        num_processes = int(os.environ["WRL_NUM_PROCESSES"])
    if process_id is None and "WRL_PROCESS_ID" in os.environ:
        process_id = int(os.environ["WRL_PROCESS_ID"])
    if num_processes is not None and num_processes < 1:
        raise ValueError(f"num_processes must be positive, got {num_processes}")
    if process_id is not None and num_processes is not None and not 0 <= process_id < num_processes:
        raise ValueError(f"process_id must be in 0..{num_processes - 1}, got {process_id}")
    jax.distributed.initialize(
        coordinator_address=coordinator_address, num_processes=num_processes, process_id=process_id
    )


def initialize_if_requested() -> None:
    if requested():
        initialize()
