"""gymnax, imported in one place.

``import gymnax`` imports every gymnax environment, so a missing dependency of one we never
use (six, for its MNIST bandit) fails it; this says so, and how to fix it, instead of a
traceback from inside gymnax. :mod:`wrl_jax.core.environment` and the registry import gymnax
from here.
"""

try:
    import gymnax
    from gymnax.environments import environment as gymnax_environment
    from gymnax.environments import spaces
except ImportError as error:
    raise ImportError(
        f"wrl_jax's environments are gymnax environments, and `import gymnax` failed: {error}. "
        "gymnax imports all of its own environments on import, so any of their dependencies is needed. "
        "Install the locked set (`make install`, or `pip install --require-hashes --no-deps -r "
        f"requirements/core.txt`), or the missing package: `pip install {error.name or '<package>'}`."
    ) from error

__all__ = ["gymnax", "gymnax_environment", "spaces"]
