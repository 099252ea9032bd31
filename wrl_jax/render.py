"""Moved to :mod:`wrl_jax.envs.warehouse.render`; this alias keeps ``import wrl_jax.render`` working.

The old module name is bound to the new module itself (not a copy), so private
names, monkeypatching and ``isinstance`` checks behave exactly as before.
"""

import sys

from wrl_jax.envs.warehouse import render as _moved

sys.modules[__name__] = _moved
