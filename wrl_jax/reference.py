"""Moved to :mod:`wrl_jax.envs.warehouse.reference`; this alias keeps ``import wrl_jax.reference`` working.

The old module name is bound to the new module itself (not a copy), so private
names, monkeypatching and ``isinstance`` checks behave exactly as before.
"""

import sys

from wrl_jax.envs.warehouse import reference as _moved

sys.modules[__name__] = _moved
