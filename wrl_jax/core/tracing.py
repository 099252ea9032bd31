"""A function traced once, used twice: as a ``lax.cond`` branch and for the shapes of the other branch.

``lax.cond`` needs both branches to return the same shapes. When one branch does the work (an update,
an evaluation) and the other stands in for it (zeros, NaNs), the stand-in needs the worker's output
shapes. ``jax.eval_shape`` would trace the worker once for them and the cond would trace it again;
:func:`traced_once` keeps the first trace's jaxpr and replays it, which gives the same program (the same
StableHLO, checked in the tests) for half the tracing.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.extend


def traced_once(fn: Callable[..., Any], *args: Any) -> tuple[Callable[..., Any], Any]:
    """``(replay, shapes)``: ``replay(*args)`` computes ``fn(*args)`` from one trace of ``fn`` at ``args``'
    shapes (call it with arguments of those shapes only); ``shapes`` are its outputs' ``ShapeDtypeStruct``s."""
    jaxpr, shapes = jax.make_jaxpr(fn, return_shape=True)(*args)
    run = jax.extend.core.jaxpr_as_fun(jaxpr)
    in_tree, out_tree = jax.tree.structure(args), jax.tree.structure(shapes)

    def replay(*call_args: Any) -> Any:
        leaves, tree = jax.tree.flatten(call_args)
        if tree != in_tree:
            raise TypeError(f"traced_once: called with {tree}, traced with {in_tree}")
        return jax.tree.unflatten(out_tree, run(*leaves))

    return replay, shapes
