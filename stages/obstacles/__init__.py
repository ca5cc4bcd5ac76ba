"""Obstacle stage: environment meshes, k-DOP trees, continuous point-triangle contacts (paper B)."""
