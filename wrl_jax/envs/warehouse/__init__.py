"""The study's single robot (SPEC.md): env, types, layouts, maps, routes, NumPy reference, render."""
