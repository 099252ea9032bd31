"""Moved to :mod:`wrl_jax.training.checkpoint`;
this alias keeps ``import wrl_jax.checkpoint`` working (the same module object)."""

import sys

from wrl_jax.training import checkpoint as _moved

sys.modules[__name__] = _moved
