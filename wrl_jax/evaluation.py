"""Moved to :mod:`wrl_jax.envs.warehouse.evaluation`;
this alias keeps ``import wrl_jax.evaluation`` working (the same module object)."""

import sys

from wrl_jax.envs.warehouse import evaluation as _moved

sys.modules[__name__] = _moved
