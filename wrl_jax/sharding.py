"""Moved to :mod:`wrl_jax.training.sharding`;
this alias keeps ``import wrl_jax.sharding`` working (the same module object)."""

import sys

from wrl_jax.training import sharding as _moved

sys.modules[__name__] = _moved
