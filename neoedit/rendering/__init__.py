"""Ray intervals, samplers, occupancy grid and volume rendering (a flat functional core)."""
