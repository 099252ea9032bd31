"""What every environment family shares: the gymnax base, the registry, grid mechanics."""
