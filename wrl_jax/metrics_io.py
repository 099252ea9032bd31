"""Moved to :mod:`wrl_jax.training.metrics_io`;
this alias keeps ``import wrl_jax.metrics_io`` working (the same module object)."""

import sys

from wrl_jax.training import metrics_io as _moved

sys.modules[__name__] = _moved
