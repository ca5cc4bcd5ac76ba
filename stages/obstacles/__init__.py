"""Obstacle stage: environment meshes, k-DOP trees, continuous point-triangle contacts (paper B).

Public API
- types: Obstacle, ObstacleMotion, KdopTree, ObstacleSet
- primitives: box_mesh, table_mesh, sphere_mesh, plane_mesh, cylinder_mesh, load_obstacle_mesh,
  make_obstacle
- kdop: kdop_directions, build_triangle_tree, build_particle_tree, kdop_nodes_at_depth,
  kdop_wireframe, kdop_box
- stage: build_obstacle_set (once per scene), ObstacleCollider (per-step state, `.collide`)
- kernels: collide_obstacles (the numba per-step kernel; contract in its module docstring)
"""
from stages.obstacles.types import KdopTree, Obstacle, ObstacleMotion, ObstacleSet
from stages.obstacles.primitives import (box_mesh, cylinder_mesh, load_obstacle_mesh, make_obstacle,
                                         plane_mesh, sphere_mesh, table_mesh)
from stages.obstacles.kdop import (DEFAULT_K, build_particle_tree, build_triangle_tree, kdop_box,
                                   kdop_directions, kdop_nodes_at_depth, kdop_wireframe)
from stages.obstacles.stage import ObstacleCollider, build_obstacle_set

__all__ = [
    "KdopTree", "Obstacle", "ObstacleMotion", "ObstacleSet",
    "box_mesh", "cylinder_mesh", "load_obstacle_mesh", "make_obstacle", "plane_mesh", "sphere_mesh", "table_mesh",
    "DEFAULT_K", "build_particle_tree", "build_triangle_tree", "kdop_box", "kdop_directions",
    "kdop_nodes_at_depth", "kdop_wireframe",
    "ObstacleCollider", "build_obstacle_set",
]
