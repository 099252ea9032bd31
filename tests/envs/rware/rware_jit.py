"""How the rware tests compile their own programs: XLA's CPU backend at LLVM optimization level 0.

The rware tests run each program for a few steps (a parity run of 30 to 200 steps, a batch of
crowds, a few evaluation episodes), so compiling is nearly all of their time. The session's
setting (``tests/conftest.py``: LLVM level 1) compiles a transition of 19 agents in about 2.7 s of
CPU; level 0 in about 1 s, and runs it a few times slower, which these runs do not feel. The level
only changes how LLVM optimizes the machine code, not the program XLA builds. rware's programs are
integer logic (positions, directions, requests) and float operations that are exact (sums of 0/1
rewards, coordinates divided by the grid size), so their results do not depend on it: the parity
tests still compare with rware exactly. (Float programs may round differently at another level;
the other families' tests keep the session's.)

:func:`jit` is ``jax.jit`` with that compile option, for the tests' own programs; :func:`fast` compiles
a jitted function of the package (``scripted.team_episodes``, say) the same way, calling it inside
one such program.
"""

from __future__ import annotations

import functools

import jax

FAST_COMPILE = {"xla_backend_optimization_level": 0}
"""Per-program XLA options (``jax.jit(..., compiler_options=...)``): LLVM level 0 instead of the session's 1."""


def jit(fun=None, **kwargs):
    """``jax.jit(fun, **kwargs)`` compiling at :data:`FAST_COMPILE`; usable as a decorator, bare or with arguments."""
    if fun is None:
        return functools.partial(jit, **kwargs)
    return jax.jit(fun, compiler_options=FAST_COMPILE, **kwargs)


@functools.cache
def fast(jitted, static_argnums=(), static_argnames=()):
    """A jitted package function called from a program of its own compiled at :data:`FAST_COMPILE` (one per function
    and static arguments: ``fast(f, (0,))(env, ...)`` shares its programs like ``f`` itself)."""
    return jit(jitted, static_argnums=static_argnums, static_argnames=static_argnames)
