"""The continuous warehouse of docs/CONTINUOUS_SPEC.md: a disc robot with lidar, moving obstacles, domain randomization."""
