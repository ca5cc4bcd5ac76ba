"""Map stage: per-hull OBB, upper/lower planar meshes with point location, map sphere/cylinder."""
