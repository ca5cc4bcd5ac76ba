"""Obstacle stage: environment meshes, k-DOP trees, continuous point-triangle contacts (paper B).

Public API
- types: Obstacle, ObstacleMotion, ObstacleSet (their k-DOP trees: stages.geometry.kdop)
- primitives: box_mesh, table_mesh, sphere_mesh, plane_mesh, cylinder_mesh, load_obstacle_mesh,
  make_obstacle
- stage: build_obstacle_set (once per scene), ObstacleCollider (per-step state, `.collide`)
- kernels: collide_obstacles (the numba per-step kernel; contract in its module docstring)
"""
from stages.obstacles.types import Obstacle, ObstacleMotion, ObstacleSet
from stages.obstacles.primitives import (box_mesh, cylinder_mesh, load_obstacle_mesh, make_obstacle,
                                         plane_mesh, sphere_mesh, table_mesh)
from stages.obstacles.stage import ObstacleCollider, build_obstacle_set

__all__ = [
    "Obstacle", "ObstacleMotion", "ObstacleSet",
    "box_mesh", "cylinder_mesh", "load_obstacle_mesh", "make_obstacle", "plane_mesh", "sphere_mesh", "table_mesh",
    "ObstacleCollider", "build_obstacle_set",
]
