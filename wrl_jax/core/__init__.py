"""What every environment family shares: the gymnax base, the registry, grid mechanics, and the
evaluation contract a family gives the training driver (:mod:`~wrl_jax.core.evaluation`)."""
