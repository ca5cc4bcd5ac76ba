"""Generalised winding numbers of points w.r.t. a triangle mesh (Barill et al. 2018), brute force and
over a tree of bounding balls refitted per frame: inside the body (>= 0.5) for the simulation's body
audit, garment placement and the collider coverage, open meshes included.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.jit import serial_and_parallel, threaded
from stages.affine import triangle_cross

NUMBA_CACHE_DEPENDS = ("stages.affine",)

@njit(cache=True, forceinline=True)
def _solid_angle(ax, ay, az, bx, by, bz, cx, cy, cz):
    """Signed solid angle of triangle (a, b, c) seen from the origin (Van Oosterom & Strackee)."""
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
    den = la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (bx * cx + by * cy + bz * cz) * la \
        + (cx * ax + cy * ay + cz * az) * lb
    return 2.0 * math.atan2(det, den)


@serial_and_parallel(cache=True)
def winding_numbers_brute(points, vertices, triangles, out):
    """Exact generalised winding number of every point: sum of solid angles / 4 pi. O(N T)."""
    for i in prange(points.shape[0]):
        qx = points[i, 0]
        qy = points[i, 1]
        qz = points[i, 2]
        acc = 0.0
        for t in range(triangles.shape[0]):
            a = triangles[t, 0]
            b = triangles[t, 1]
            c = triangles[t, 2]
            acc += _solid_angle(vertices[a, 0] - qx, vertices[a, 1] - qy, vertices[a, 2] - qz,
                                vertices[b, 0] - qx, vertices[b, 1] - qy, vertices[b, 2] - qz,
                                vertices[c, 0] - qx, vertices[c, 1] - qy, vertices[c, 2] - qz)
        out[i] = acc / (4.0 * math.pi)


@njit(cache=True)
def refit_winding_tree(vertices, triangles, order, node_start, node_end, children, data):
    """Per node (children after parents in index order): data[n] = area-weighted centroid (3),
    area-weighted normal sum (3), radius of a ball around the centroid holding the node's
    triangles (1). Recomputed from the current (skinned) vertices."""
    nn = node_start.size
    for n in range(nn - 1, -1, -1):
        if children[n, 0] < 0:
            ax = 0.0
            cx = 0.0
            cy = 0.0
            cz = 0.0
            sx = 0.0
            sy = 0.0
            sz = 0.0
            for k in range(node_start[n], node_end[n]):
                t = order[k]
                a = triangles[t, 0]
                b = triangles[t, 1]
                c = triangles[t, 2]
                nx, ny, nz = triangle_cross(vertices, a, b, c)
                nx *= 0.5
                ny *= 0.5
                nz *= 0.5
                ar = math.sqrt(nx * nx + ny * ny + nz * nz) + 1e-300
                sx += nx
                sy += ny
                sz += nz
                ax += ar
                cx += ar * (vertices[a, 0] + vertices[b, 0] + vertices[c, 0]) / 3.0
                cy += ar * (vertices[a, 1] + vertices[b, 1] + vertices[c, 1]) / 3.0
                cz += ar * (vertices[a, 2] + vertices[b, 2] + vertices[c, 2]) / 3.0
            cx /= ax
            cy /= ax
            cz /= ax
            r = 0.0
            for k in range(node_start[n], node_end[n]):
                t = order[k]
                for q in range(3):
                    v = triangles[t, q]
                    dx = vertices[v, 0] - cx
                    dy = vertices[v, 1] - cy
                    dz = vertices[v, 2] - cz
                    r = max(r, math.sqrt(dx * dx + dy * dy + dz * dz))
            data[n, 7] = ax
        else:
            l = children[n, 0]
            rr = children[n, 1]
            al = data[l, 7]
            ar = data[rr, 7]
            ax = al + ar
            cx = (al * data[l, 0] + ar * data[rr, 0]) / ax
            cy = (al * data[l, 1] + ar * data[rr, 1]) / ax
            cz = (al * data[l, 2] + ar * data[rr, 2]) / ax
            sx = data[l, 3] + data[rr, 3]
            sy = data[l, 4] + data[rr, 4]
            sz = data[l, 5] + data[rr, 5]
            r = 0.0
            for ch in (l, rr):
                dx = data[ch, 0] - cx
                dy = data[ch, 1] - cy
                dz = data[ch, 2] - cz
                r = max(r, math.sqrt(dx * dx + dy * dy + dz * dz) + data[ch, 6])
            data[n, 7] = ax
        data[n, 0] = cx
        data[n, 1] = cy
        data[n, 2] = cz
        data[n, 3] = sx
        data[n, 4] = sy
        data[n, 5] = sz
        data[n, 6] = r


@serial_and_parallel(cache=True)
def winding_numbers_tree(points, vertices, triangles, order, node_start, node_end, children, data, beta, out):
    """Fast generalised winding number (Barill et al. 2018, first-order dipole far field).

    A node farther than beta * radius from the query contributes (c - q) . N / (4 pi |c - q|^3)
    (its area-weighted normal sum N as a dipole at its centroid c); nearer leaves are summed exactly.
    """
    inv4pi = 1.0 / (4.0 * math.pi)
    for i in prange(points.shape[0]):
        qx = points[i, 0]
        qy = points[i, 1]
        qz = points[i, 2]
        stack = np.empty(64, np.int64)
        top = 0
        stack[0] = 0
        top = 1
        acc = 0.0
        while top > 0:
            top -= 1
            n = stack[top]
            dx = data[n, 0] - qx
            dy = data[n, 1] - qy
            dz = data[n, 2] - qz
            d2 = dx * dx + dy * dy + dz * dz
            r = data[n, 6] * beta
            if d2 > r * r:
                d = math.sqrt(d2)
                acc += (dx * data[n, 3] + dy * data[n, 4] + dz * data[n, 5]) / (d2 * d) * inv4pi
            elif children[n, 0] < 0:
                s = 0.0
                for k in range(node_start[n], node_end[n]):
                    t = order[k]
                    a = triangles[t, 0]
                    b = triangles[t, 1]
                    c = triangles[t, 2]
                    s += _solid_angle(vertices[a, 0] - qx, vertices[a, 1] - qy, vertices[a, 2] - qz,
                                      vertices[b, 0] - qx, vertices[b, 1] - qy, vertices[b, 2] - qz,
                                      vertices[c, 0] - qx, vertices[c, 1] - qy, vertices[c, 2] - qz)
                acc += s * inv4pi
            else:
                stack[top] = children[n, 0]
                stack[top + 1] = children[n, 1]
                top += 2
        out[i] = acc


def build_winding_tree(vertices: np.ndarray, triangles: np.ndarray, leaf_size: int = 8):
    """Topology of the winding-number tree, from the bind pose: median splits of triangle centroids
    along the longest axis. Returns (order, node_start, node_end, children) with node 0 the root
    and children after their parent; refit it per frame with `refit_winding_tree`."""
    cent = vertices[triangles].mean(axis=1)
    order = np.arange(triangles.shape[0])
    starts, ends, kids = [], [], []

    def node(lo, hi):
        idx = len(starts)
        starts.append(lo)
        ends.append(hi)
        kids.append([-1, -1])
        if hi - lo > leaf_size:
            sub = order[lo:hi]
            ax = int(np.argmax(np.ptp(cent[sub], axis=0)))
            order[lo:hi] = sub[np.argsort(cent[sub, ax], kind="stable")]
            mid = (lo + hi) // 2
            kids[idx] = [node(lo, mid), node(mid, hi)]
        return idx

    node(0, triangles.shape[0])
    return (order.astype(np.int64), np.array(starts, np.int64), np.array(ends, np.int64),
            np.array(kids, np.int64))


class WindingTree:
    """The winding-number tree of one mesh whose vertices move (a skinned body): topology built
    once from `vertices`, bounds refitted per frame; inside = winding number >= 0.5."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, beta: float = 2.0):
        self.beta = float(beta)
        self.tree = build_winding_tree(vertices, triangles)
        self.data = np.zeros((self.tree[1].size, 8))
        self.tris = np.ascontiguousarray(triangles, dtype=np.int32)

    def refit(self, vertices: np.ndarray) -> None:
        """Refit the tree to the `vertices` (V, 3) of a frame; queries then use them."""
        order, start, end, kids = self.tree
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        refit_winding_tree(self.vertices, self.tris, order, start, end, kids, self.data)

    def winding_refitted(self, points: np.ndarray) -> np.ndarray:
        """Winding numbers of `points` w.r.t. the vertices of the last `refit`."""
        order, start, end, kids = self.tree
        out = np.empty(points.shape[0])
        threaded(winding_numbers_tree)(np.ascontiguousarray(points, dtype=np.float64), self.vertices, self.tris,
                                       order, start, end, kids, self.data, self.beta, out)
        return out

    def winding(self, vertices: np.ndarray, points: np.ndarray) -> np.ndarray:
        self.refit(vertices)
        return self.winding_refitted(points)

    def inside(self, vertices: np.ndarray, points: np.ndarray) -> np.ndarray:
        return self.winding(vertices, points) >= 0.5


def winding_number(vertices, triangles, points, *, exact: bool = False, beta: float = 2.0) -> np.ndarray:
    """(N,) generalised winding numbers of points w.r.t. a triangle mesh (1 inside a closed
    outward-oriented mesh, 0 outside). exact=True sums every triangle's solid angle (O(N T))."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    t = np.ascontiguousarray(triangles, dtype=np.int32)
    p = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    out = np.empty(p.shape[0])
    if exact:
        threaded(winding_numbers_brute)(p, v, t, out)
        return out
    order, start, end, kids = build_winding_tree(v, t)
    data = np.zeros((start.size, 8))
    refit_winding_tree(v, t, order, start, end, kids, data)
    threaded(winding_numbers_tree)(p, v, t, order, start, end, kids, data, float(beta), out)
    return out
