"""Self-collision culling of the cloth tree (Volino & Magnenat-Thalmann 1994, "Efficient self-collision
detection on smoothly discretized surface animations using geometrical shape regularity").

A connected patch of a garment whose unit normals all lie strictly on one side of a plane through
the origin (a normal cone under 90 degrees) cannot fold onto itself, so it needs no self test. This
holds for one tree node (its triangles one patch) and, the case that matters on a curved garment,
for two neighbouring nodes: their k-DOPs always overlap along their shared border, down to the leaves,
yet their union is a flat patch a few levels down. Two nodes are neighbours when they share a vertex;
each node keeps its border vertices (those with a triangle outside the node), sorted, so the test
is a merge of two short lists. (Volino's contour test, that the patch's outline does not overlap
itself in projection, is left out: median-split nodes of a cloth mesh are compact, and the cone is
kept well under 90 degrees (FLAT_COS), so a patch whose sides face each other is not culled.)

Setup (`patch_nodes`, `node_borders`) runs once per scene; the tests run inside the traversal.
"""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)

FLAT_COS = 0.3       # a patch is flat when its unit normals project beyond this on one direction (within
                     # 72.5 degrees of it). There is no contour test: at 0.05 (87 degrees) a patch whose
                     # sides face each other (a trouser leg's C closing) was culled while it closed through
                     # itself (CesiumMan's outfit, a call every 5 sub-steps: 4 edges, 0 at 0.3;
                     # long_skirt 10-15 % and drape ~9 % more cloth time, the walks the same)
UNION_COS = 0.5      # two neighbouring nodes together: a narrower cone (under 60 degrees), so a
                     # fold made of two triangle strips turning 90 degrees each is still tested


def flat_cos_for(rotation: float) -> float:
    """The threshold that keeps a patch flat at FLAT_COS after each normal turns by up to
    `rotation` radians (culling decided once for a candidate list's lifetime)."""
    return float(np.cos(np.arccos(FLAT_COS) - rotation))


@njit(cache=True)
def flat_patch(nrm_min, nrm_max, node_patch, a, flat_cos):
    """Node a is one connected patch whose normal cone is under 90 degrees (nrm_min / nrm_max:
    bounds of its unit normals' projections on the k-DOP directions, beyond flat_cos on one)."""
    if not node_patch[a]:
        return False
    for i in range(nrm_min.shape[1]):
        if nrm_min[a, i] > flat_cos or nrm_max[a, i] < -flat_cos:
            return True
    return False


@njit(cache=True)
def flat_union(nrm_min, nrm_max, node_patch, border_start, border_vert, a, b, flat_cos):
    """Nodes a and b (disjoint triangles) together form one flat patch: each is a patch, they share
    a vertex, and their normals together lie on one side of a plane."""
    if not (node_patch[a] and node_patch[b]):
        return False
    flat = False
    for i in range(nrm_min.shape[1]):
        if min(nrm_min[a, i], nrm_min[b, i]) > flat_cos or max(nrm_max[a, i], nrm_max[b, i]) < -flat_cos:
            flat = True
            break
    if not flat:
        return False
    # neighbours: a shared vertex is a border vertex of both (its triangles lie in both nodes)
    i = border_start[a]
    i1 = border_start[a + 1]
    j = border_start[b]
    j1 = border_start[b + 1]
    while i < i1 and j < j1:
        va = border_vert[i]
        vb = border_vert[j]
        if va == vb:
            return True
        if va < vb:
            i += 1
        else:
            j += 1
    return False


# ---------------------------------------------------------------------------------------------
# setup

@njit(cache=True)
def _find(parent, v):
    while parent[v] != v:
        parent[v] = parent[parent[v]]
        v = parent[v]
    return v


@njit(cache=True)
def patch_nodes(children, leaf_prim, triangles, tri_garment, n_particles):
    """(n,) uint8: 1 where a node's triangles form one connected patch (through shared vertices) of
    one garment. Setup only."""
    n = children.shape[0]
    out = np.zeros(n, dtype=np.uint8)
    parent = np.arange(n_particles)
    tris = np.empty(triangles.shape[0], dtype=np.int64)
    stack = np.empty(n, dtype=np.int64)
    for node in range(n):
        m = 0
        stack[0] = node
        top = 1
        while top > 0:
            top -= 1
            q = stack[top]
            if leaf_prim[q] >= 0:
                tris[m] = leaf_prim[q]
                m += 1
            else:
                stack[top] = children[q, 0]
                stack[top + 1] = children[q, 1]
                top += 2
        ok = True
        for j in range(m):
            t = tris[j]
            if tri_garment[t] != tri_garment[tris[0]]:
                ok = False
            for k in range(1, 3):
                ra = _find(parent, triangles[t, 0])
                rb = _find(parent, triangles[t, k])
                if ra != rb:
                    parent[max(ra, rb)] = min(ra, rb)
        root = _find(parent, triangles[tris[0], 0])
        for j in range(m):
            if _find(parent, triangles[tris[j], 0]) != root:
                ok = False
        out[node] = 1 if ok else 0
        for j in range(m):  # reset the touched vertices
            for k in range(3):
                parent[triangles[tris[j], k]] = triangles[tris[j], k]
    return out


@njit(cache=True)
def node_borders(children, leaf_prim, triangles, n_particles, max_depth):
    """(border_start (n + 1,) int64, border_vert (M,) int32): node q's border vertices, sorted, are
    border_vert[border_start[q]:border_start[q + 1]]; a border vertex has a triangle outside q.
    Bottom-up: a node's vertices with their triangle counts in it are the merge of its children's
    border lists (a child's interior vertex has all its triangles in that child). Setup only."""
    n = children.shape[0]
    valence = np.zeros(n_particles, dtype=np.int64)
    for t in range(triangles.shape[0]):
        for k in range(3):
            valence[triangles[t, k]] += 1
    # every node's list is at most 3 per triangle under it, and the nodes of one depth share triangles
    cap = 3 * triangles.shape[0] * (max_depth + 1) + 3
    buf_v = np.empty(cap, dtype=np.int32)
    buf_c = np.empty(cap, dtype=np.int64)
    start = np.zeros(n, dtype=np.int64)
    count = np.zeros(n, dtype=np.int64)
    top = 0
    for q in range(n - 1, -1, -1):   # children have larger ids than their parent
        start[q] = top
        t = leaf_prim[q]
        if t >= 0:
            a = np.int64(triangles[t, 0])
            b = np.int64(triangles[t, 1])
            c = np.int64(triangles[t, 2])
            lo = min(a, min(b, c))
            hi = max(a, max(b, c))
            mid = a + b + c - lo - hi
            for k in range(3):
                v = lo if k == 0 else (mid if k == 1 else hi)
                if valence[v] > 1:
                    buf_v[top] = v
                    buf_c[top] = 1
                    top += 1
        else:
            l = children[q, 0]
            r = children[q, 1]
            i = start[l]
            i1 = start[l] + count[l]
            j = start[r]
            j1 = start[r] + count[r]
            while i < i1 or j < j1:
                if j >= j1 or (i < i1 and buf_v[i] < buf_v[j]):
                    v = buf_v[i]
                    c = buf_c[i]
                    i += 1
                elif i >= i1 or buf_v[j] < buf_v[i]:
                    v = buf_v[j]
                    c = buf_c[j]
                    j += 1
                else:
                    v = buf_v[i]
                    c = buf_c[i] + buf_c[j]
                    i += 1
                    j += 1
                if c < valence[v]:
                    buf_v[top] = v
                    buf_c[top] = c
                    top += 1
        count[q] = top - start[q]
    border_start = np.zeros(n + 1, dtype=np.int64)
    for q in range(n):
        border_start[q + 1] = border_start[q] + count[q]
    border_vert = np.empty(border_start[n], dtype=np.int32)
    for q in range(n):
        for k in range(count[q]):
            border_vert[border_start[q] + k] = buf_v[start[q] + k]
    return border_start, border_vert
