"""Tests' own programs compiled at XLA's CPU LLVM optimization level 0, for runs where compiling is their time.

Many tests run a program for a few steps (a parity run of 30 to 200 steps, a batch of crowds, a few
evaluation episodes), so compiling is nearly all of their time. The commands' setting (LLVM level 1)
compiles a transition of 19 rware agents in about 2.7 s of CPU; level 0 in about 1 s, and runs it a
few times slower, which such runs do not feel. The level only changes how LLVM optimizes the machine
code, not the program XLA builds. The session itself compiles at level 0 (``tests/conftest.py``), so
these programs differ from the others only when a session runs at the commands' level
(``WRL_TEST_XLA_LEVEL=1``): they stay at 0 there, where level 1 would only be slower.

When it is safe: integer logic and exact float operations (rware's positions, requests and 0/1
rewards; the grid warehouse) give the same results at any level, so exact comparisons still hold.
Float programs may round differently at another level (a fused multiply-add here and not there): a
test of float results at level 0 may compare with a tolerance, or with a reference, but never claims
bit-identity with a program the package compiles at another level (``tests/commands_level.py``).

:func:`jit` is ``jax.jit`` with that compile option, for the tests' own programs; :func:`fast` compiles
a jitted function of the package (``evaluation.team_episodes`` of rware, say) the same way, calling it inside
one such program. Importable as ``import fast_compile`` from any test (pytest puts ``tests/`` on the path).
"""

from __future__ import annotations

import functools

import jax

FAST_COMPILE = {"xla_backend_optimization_level": 0}
"""Per-program XLA options (``jax.jit(..., compiler_options=...)``): LLVM level 0, whatever the session's level."""


def jit_at_level(level: int, fun=None, **kwargs):
    """``jax.jit(fun, **kwargs)`` compiling at LLVM ``level`` whatever the session's; usable as a decorator, bare or
    with arguments."""
    if fun is None:
        return functools.partial(jit_at_level, level, **kwargs)
    return jax.jit(fun, compiler_options={"xla_backend_optimization_level": level}, **kwargs)


def jit(fun=None, **kwargs):
    """``jax.jit(fun, **kwargs)`` compiling at :data:`FAST_COMPILE`; usable as a decorator, bare or with arguments."""
    return jit_at_level(FAST_COMPILE["xla_backend_optimization_level"], fun, **kwargs)


@functools.cache
def fast(jitted, static_argnums=(), static_argnames=()):
    """A jitted package function called from a program of its own compiled at :data:`FAST_COMPILE` (one per function
    and static arguments: ``fast(f, (0,))(env, ...)`` shares its programs like ``f`` itself)."""
    return jit(jitted, static_argnums=static_argnums, static_argnames=static_argnames)
