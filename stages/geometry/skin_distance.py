"""Exact distance from points to a triangle mesh that moves (a skinned body), and inside tests, over
the winding-number tree of stages/geometry/winding.py refitted per frame: a ball per node holds the
node's triangles, so max(0, |p - c| - r) is a lower bound of any of its triangles' distance (branch
and bound). The collider fit (hulls), its coverage and the garments' fit ask it.

- `distance_to_mesh_tree`: the tree's exact distance; `distance_to_mesh_brute`: every triangle tried
  (the reference of the tree in tests); the tree's also says which triangle is nearest.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from stages.geometry.winding import WindingTree
from stages.jit import serial_and_parallel, threaded


@njit(cache=True, forceinline=True)
def point_triangle_distance2(px, py, pz, vertices, a, b, c):
    """Squared distance from p to triangle (v[a], v[b], v[c]): closest point by Voronoi regions
    (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ax, ay, az = vertices[a, 0], vertices[a, 1], vertices[a, 2]
    abx, aby, abz = vertices[b, 0] - ax, vertices[b, 1] - ay, vertices[b, 2] - az
    acx, acy, acz = vertices[c, 0] - ax, vertices[c, 1] - ay, vertices[c, 2] - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return apx * apx + apy * apy + apz * apz
    bpx, bpy, bpz = px - vertices[b, 0], py - vertices[b, 1], pz - vertices[b, 2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bpx * bpx + bpy * bpy + bpz * bpz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        qx, qy, qz = apx - v * abx, apy - v * aby, apz - v * abz
        return qx * qx + qy * qy + qz * qz
    cpx, cpy, cpz = px - vertices[c, 0], py - vertices[c, 1], pz - vertices[c, 2]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cpx * cpx + cpy * cpy + cpz * cpz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        qx, qy, qz = apx - w * acx, apy - w * acy, apz - w * acz
        return qx * qx + qy * qy + qz * qz
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        qx = bpx - w * (vertices[c, 0] - vertices[b, 0])
        qy = bpy - w * (vertices[c, 1] - vertices[b, 1])
        qz = bpz - w * (vertices[c, 2] - vertices[b, 2])
        return qx * qx + qy * qy + qz * qz
    den = 1.0 / (va + vb + vc)
    v = vb * den
    w = vc * den
    qx = apx - abx * v - acx * w
    qy = apy - aby * v - acy * w
    qz = apz - abz * v - acz * w
    return qx * qx + qy * qy + qz * qz


@serial_and_parallel(cache=True)
def distance_to_mesh_brute(points, vertices, triangles, out):
    """out[i] = distance from points[i] to the nearest triangle, every triangle tried. O(N T)."""
    for i in prange(points.shape[0]):
        best = np.inf
        for t in range(triangles.shape[0]):
            d2 = point_triangle_distance2(points[i, 0], points[i, 1], points[i, 2], vertices,
                                          triangles[t, 0], triangles[t, 1], triangles[t, 2])
            best = min(best, d2)
        out[i] = math.sqrt(best)


@njit(cache=True, forceinline=True)
def _nearest_in_tree(px, py, pz, vertices, triangles, order, node_start, node_end, children, data, stack):
    """(squared distance, triangle) of the triangle nearest p over the refitted winding-number tree:
    nodes whose ball is farther than the best so far are skipped, the nearer child is opened first."""
    stack[0] = 0
    top = 1
    best = np.inf
    arg = -1
    while top > 0:
        top -= 1
        n = stack[top]
        dx = data[n, 0] - px
        dy = data[n, 1] - py
        dz = data[n, 2] - pz
        low = math.sqrt(dx * dx + dy * dy + dz * dz) - data[n, 6]
        if low > 0.0 and low * low >= best:
            continue
        if children[n, 0] < 0:
            for k in range(node_start[n], node_end[n]):
                t = order[k]
                d2 = point_triangle_distance2(px, py, pz, vertices, triangles[t, 0], triangles[t, 1],
                                              triangles[t, 2])
                if d2 < best:
                    best = d2
                    arg = t
        else:
            l = children[n, 0]
            r = children[n, 1]
            dl = (data[l, 0] - px) ** 2 + (data[l, 1] - py) ** 2 + (data[l, 2] - pz) ** 2
            dr = (data[r, 0] - px) ** 2 + (data[r, 1] - py) ** 2 + (data[r, 2] - pz) ** 2
            if dl < dr:  # push the far child first so the near one pops first
                l, r = r, l
            stack[top] = l
            stack[top + 1] = r
            top += 2
    return best, arg


@serial_and_parallel(cache=True)
def distance_to_mesh_tree(points, vertices, triangles, order, node_start, node_end, children, data, out, nearest):
    """out[i] = distance from points[i] to the nearest triangle (exact), nearest[i] = that triangle
    (ties: the first found), over the refitted winding-number tree (_nearest_in_tree)."""
    for i in prange(points.shape[0]):
        stack = np.empty(128, np.int64)
        d2, t = _nearest_in_tree(points[i, 0], points[i, 1], points[i, 2], vertices, triangles, order, node_start,
                                 node_end, children, data, stack)
        out[i] = math.sqrt(d2)
        nearest[i] = t


class SkinDistance:
    """Inside tests and exact distances to a skinned mesh, over one winding tree refitted per frame.

    character: anything with the bind-pose `vertices` (V, 3) and `triangles` (T, 3) of the skin (a
    stages.rig.types.Character); `refit` it to a frame's skinned vertices before asking."""

    def __init__(self, character):
        self.winding = WindingTree(character.vertices, character.triangles)

    def refit(self, vertices: np.ndarray) -> None:
        self.winding.refit(vertices)

    def inside(self, points: np.ndarray) -> np.ndarray:
        return self.winding.winding_refitted(points) >= 0.5

    def distance(self, points: np.ndarray) -> np.ndarray:
        return nearest_on_mesh(self.winding, points)[0]

    def nearest_triangle(self, points: np.ndarray) -> np.ndarray:
        """(N,) int64: the skin triangle nearest each point (at the last refit)."""
        return nearest_on_mesh(self.winding, points)[1]


def nearest_on_mesh(tree: WindingTree, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((N,) float64 distance, (N,) int64 triangle) from each point to the nearest triangle of
    `tree`'s mesh, as last refitted."""
    order, start, end, kids = tree.tree
    out = np.zeros(points.shape[0])
    nearest = np.zeros(points.shape[0], np.int64)
    threaded(distance_to_mesh_tree)(np.ascontiguousarray(points, np.float64), tree.vertices, tree.tris, order, start,
                                    end, kids, tree.data, out, nearest)
    return out, nearest
