"""Topology of triangle meshes: the edge lists that the cloth and body audits, the collider coverage and
the collider balls' skin samples share."""
from __future__ import annotations

import numpy as np


def mesh_edges(triangles: np.ndarray) -> np.ndarray:
    """(E, 2) int32 unique undirected edges (i < j) of a triangle mesh, sorted."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0).astype(np.int32)


def boundary_loops(triangles: np.ndarray) -> list[np.ndarray]:
    """Closed boundary loops (edges used by one triangle) as ordered vertex index arrays."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    key = np.sort(e, axis=1)
    uniq, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    directed = e[cnt[inv.ravel()] == 1]
    nxt = {}
    for a, b in directed:
        nxt.setdefault(int(a), []).append(int(b))
    loops, seen = [], set()
    for start in sorted(nxt):
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen:
            seen.add(v)
            loop.append(v)
            v = nxt[v][0] if v in nxt else start
        loops.append(np.array(loop, np.int32))
    return loops


def triangles_near_edges(x: np.ndarray, edges: np.ndarray, triangles: np.ndarray) -> list:
    """For each edge (E, 2) of points x, the indices of the triangles (T, 3) it may meet: every one
    whose centre is within half the edge's length plus the largest centre-to-corner distance of the
    edge's midpoint (a superset, from a k-d tree of the centres)."""
    from scipy.spatial import cKDTree
    tb = x[triangles]
    cen = tb.mean(axis=1)
    reach = float(np.linalg.norm(tb - cen[:, None], axis=2).max())     # every triangle within it of its centre
    ends = x[edges]
    return cKDTree(cen).query_ball_point(ends.mean(axis=1), 0.5 * np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1) + reach)
