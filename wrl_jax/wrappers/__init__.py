"""Views of our environments for other APIs: Gymnasium (single and vector), gymnax's 5-value step."""

from wrl_jax.wrappers.legacy import LegacyStepAPI

__all__ = ["LegacyStepAPI"]
