"""Moved: names are registered in :mod:`wrl_jax.envs` and made by :mod:`wrl_jax.core.registry`.

This alias keeps ``import wrl_jax.registry`` (``make``, ``make_from_layout``,
``registered_names``, ``spec``, ``REGISTRY``) working; it is the warehouse
family's registration module.
"""

import sys

from wrl_jax.envs.warehouse import registration as _moved

sys.modules[__name__] = _moved
