"""Moved to :mod:`wrl_jax.wrappers.gymnasium`; this alias keeps ``import wrl_jax.gym_env`` working."""

import sys

from wrl_jax.wrappers import gymnasium as _moved

sys.modules[__name__] = _moved
