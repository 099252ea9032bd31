"""``python -m wrl_jax.sweep``: moved to :mod:`wrl_jax.training.sweep`.

Run as a module, it is the sweep command; imported, it is an alias of the
moved module (the same module object), so ``import wrl_jax.sweep`` keeps working.
"""

import sys

from wrl_jax.training import sweep as _moved

if __name__ == "__main__":
    sys.exit(_moved.main())
else:
    sys.modules[__name__] = _moved
