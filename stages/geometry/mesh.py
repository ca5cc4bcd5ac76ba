"""Topology of triangle meshes: the edge lists that the cloth and body audits, the collider coverage and
the collider balls' skin samples share."""
from __future__ import annotations

import numpy as np


def mesh_edges(triangles: np.ndarray) -> np.ndarray:
    """(E, 2) int32 unique undirected edges (i < j) of a triangle mesh, sorted."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0).astype(np.int32)
