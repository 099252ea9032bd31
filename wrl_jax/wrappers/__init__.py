"""Views of our environments for other APIs: Gymnasium (single and vector), PettingZoo, gymnax's 5-value step.

Each module imports its own API; this package imports nothing, so ``import wrl_jax`` stays light.
"""
