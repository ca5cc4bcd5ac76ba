"""k-DOP (fixed-direction hull, FDH) bounding volumes and binary trees of them (paper B §2-3).

Direction sets (h = k/2 unit directions; a k-DOP stores [min, max] of projections on each):
  k = 6  : the 3 coordinate axes (an AABB);
  k = 14 : + the 4 cube diagonals (1, +-1, +-1);
  k = 18 : + the 6 edge diagonals (1, +-1, 0), (1, 0, +-1), (0, 1, +-1);
  k = 26 : all 13 of the above.
Default k = 18: Klosowski et al. (IEEE TVCG 1998, "Efficient collision detection using bounding
volume hierarchies of k-DOPs") found 18-DOPs the best cost / tightness trade-off in their
benchmarks, and for cloth over a table the 6 edge diagonals tighten exactly the slanted sheets
that fold over axis-aligned edges, at 9 intervals per test versus 13 for k = 26.
`pipeline.benches.obstacles.run_benchmark` measures all four on the table scene.

Trees are built top-down as in the paper: the split axis is the direction of the set along which
the node is longest; the split point is the median of the primitives' centre projections on it;
recursion ends at single primitives. Node ids are assigned breadth-first, so children always have
larger ids than their parent and a reverse sweep is a bottom-up refit.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from stages.checks import ContractError, check_array, check_index


@dataclass(frozen=True)
class KdopTree:
    """A binary k-DOP (fixed-direction hull) tree, or a forest of them, as flat arrays for numba.

    directions: (h, 3) float64, unit vectors, h = k / 2; a k-DOP is [min_i, max_i] of the
      projections on directions[i].
    node_min, node_max: (n, h) float64, metres, world frame; each node bounds its subtree's
      primitives inflated by `margin` of its tree.
    children: (n, 2) int32, child node ids, (-1, -1) for leaves. Children ids are always greater
      than their parent's, so iterating node ids in reverse is a valid bottom-up (refit) order.
    leaf_prim: (n,) int32, the primitive id of a leaf (triangle id into the owner's triangle
      array, or particle id for the cloth tree), -1 for inner nodes.
    depth: (n,) int32, 0 at a root.
    tree_offsets: (r + 1,) int32; tree i owns nodes [tree_offsets[i], tree_offsets[i+1]) and its
      root is node tree_offsets[i]. A single tree has tree_offsets = [0, n].
    margin: (r,) float64, metres >= 0, inflation of each tree's bounds (obstacle thickness; 0 for
      the cloth tree, whose leaves bound a particle's swept segment over the step).
    """

    directions: np.ndarray
    node_min: np.ndarray
    node_max: np.ndarray
    children: np.ndarray
    leaf_prim: np.ndarray
    depth: np.ndarray
    tree_offsets: np.ndarray
    margin: np.ndarray

    def __post_init__(self):
        o = "KdopTree"
        d = check_array(o, "directions", self.directions, (None, 3), np.float64)
        h = d.shape[0]
        if h not in (3, 7, 9, 13):
            raise ContractError(f"{o}.directions: expected 3, 7, 9 or 13 directions (k = 6/14/18/26), got {h}")
        if not np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12):
            raise ContractError(f"{o}.directions: directions must be unit vectors")
        mn = check_array(o, "node_min", self.node_min, (None, h), np.float64)
        n = mn.shape[0]
        mx = check_array(o, "node_max", self.node_max, (n, h), np.float64)
        if n and not np.all(mn <= mx):
            raise ContractError(f"{o}: node_min > node_max somewhere")
        ch = check_array(o, "children", self.children, (n, 2), np.int32)
        check_index(o, "children", ch, n, allow=-1)
        lp = check_array(o, "leaf_prim", self.leaf_prim, (n,), np.int32)
        if not np.array_equal(lp >= 0, ch[:, 0] < 0):
            raise ContractError(f"{o}: a node must be a leaf (children -1, leaf_prim >= 0) or inner (both children, leaf_prim -1)")
        inner = ch[:, 0] >= 0
        if not np.all(ch[inner] > np.nonzero(inner)[0][:, None]):
            raise ContractError(f"{o}.children: child ids must be greater than their parent's")
        check_array(o, "depth", self.depth, (n,), np.int32)
        off = check_array(o, "tree_offsets", self.tree_offsets, (None,), np.int32)
        if off.size < 2 or off[0] != 0 or off[-1] != n or not np.all(np.diff(off) > 0):
            raise ContractError(f"{o}.tree_offsets: expected increasing offsets from 0 to {n}")
        m = check_array(o, "margin", self.margin, (off.size - 1,), np.float64)
        if np.any(m < 0):
            raise ContractError(f"{o}.margin: must be >= 0")

    @property
    def k(self) -> int:
        return 2 * self.directions.shape[0]

    @property
    def n_trees(self) -> int:
        return self.tree_offsets.size - 1

    @property
    def max_depth(self) -> int:
        return int(self.depth.max()) if self.depth.size else 0


_AXES = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
_CORNERS = [(1, 1, 1), (1, 1, -1), (1, -1, 1), (-1, 1, 1)]
_EDGES = [(1, 1, 0), (1, 0, 1), (0, 1, 1), (1, -1, 0), (1, 0, -1), (0, 1, -1)]
DEFAULT_K = 18


def kdop_directions(k: int = DEFAULT_K) -> np.ndarray:
    """(k/2, 3) float64 unit directions of the standard k-DOP, k in {6, 14, 18, 26}."""
    sets = {6: _AXES, 14: _AXES + _CORNERS, 18: _AXES + _EDGES, 26: _AXES + _CORNERS + _EDGES}
    if k not in sets:
        raise ContractError(f"kdop_directions: k must be 6, 14, 18 or 26, got {k}")
    d = np.array(sets[k], dtype=np.float64)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


# ---------------------------------------------------------------------------------------------
# numba kernels: primitive bounds, build, refit

@njit(cache=True)
def triangle_bounds(directions, verts_a, verts_b, triangles, margin, out_min, out_max):
    """Per-triangle k-DOP over its 3 vertices in two poses (verts_a, verts_b: (V, 3)), inflated
    by `margin`. Writes out_min/out_max (T, h). Pass the same array twice for a static pose."""
    h = directions.shape[0]
    for t in range(triangles.shape[0]):
        for i in range(h):
            lo = np.inf
            hi = -np.inf
            for c in range(3):
                v = triangles[t, c]
                for verts in (verts_a, verts_b):
                    p = (verts[v, 0] * directions[i, 0] + verts[v, 1] * directions[i, 1]
                         + verts[v, 2] * directions[i, 2])
                    lo = min(lo, p)
                    hi = max(hi, p)
            out_min[t, i] = lo - margin
            out_max[t, i] = hi + margin


@njit(cache=True)
def segment_bounds(directions, x0, x1, out_min, out_max):
    """Per-particle k-DOP of its swept segment x0[p] -> x1[p] over the step. (N, h) outputs."""
    h = directions.shape[0]
    for p in range(x0.shape[0]):
        for i in range(h):
            a = x0[p, 0] * directions[i, 0] + x0[p, 1] * directions[i, 1] + x0[p, 2] * directions[i, 2]
            b = x1[p, 0] * directions[i, 0] + x1[p, 1] * directions[i, 1] + x1[p, 2] * directions[i, 2]
            out_min[p, i] = min(a, b)
            out_max[p, i] = max(a, b)


@njit(cache=True)
def build_topology(prim_min, prim_max, centre_proj):
    """Top-down median split of P primitives (paper B §2).

    prim_min, prim_max: (P, h) per-primitive k-DOPs; centre_proj: (P, h) projections of each
    primitive's centre on the directions. Returns node_min, node_max (2P-1, h), children
    (2P-1, 2) int32, leaf_prim (2P-1,) int32, depth (2P-1,) int32.
    """
    n_prim, h = prim_min.shape
    n = 2 * n_prim - 1
    node_min = np.empty((n, h))
    node_max = np.empty((n, h))
    children = np.full((n, 2), -1, dtype=np.int32)
    leaf_prim = np.full(n, -1, dtype=np.int32)
    depth = np.zeros(n, dtype=np.int32)
    start = np.zeros(n, dtype=np.int64)
    end = np.zeros(n, dtype=np.int64)
    order = np.arange(n_prim)
    end[0] = n_prim
    next_id = 1
    for node in range(n):  # breadth-first: a node is created by its parent before it is visited
        s = start[node]
        e = end[node]
        for i in range(h):
            lo = np.inf
            hi = -np.inf
            for j in range(s, e):
                lo = min(lo, prim_min[order[j], i])
                hi = max(hi, prim_max[order[j], i])
            node_min[node, i] = lo
            node_max[node, i] = hi
        if e - s == 1:
            leaf_prim[node] = order[s]
            continue
        axis = 0
        longest = -1.0
        for i in range(h):
            ext = node_max[node, i] - node_min[node, i]
            if ext > longest:
                longest = ext
                axis = i
        keys = np.empty(e - s)
        for j in range(s, e):
            keys[j - s] = centre_proj[order[j], axis]
        perm = np.argsort(keys, kind="mergesort")  # stable: ties keep the previous order
        seg = order[s:e].copy()
        for j in range(e - s):
            order[s + j] = seg[perm[j]]
        mid = s + (e - s) // 2
        a = next_id
        b = next_id + 1
        next_id += 2
        children[node, 0] = a
        children[node, 1] = b
        start[a] = s
        end[a] = mid
        start[b] = mid
        end[b] = e
        depth[a] = depth[node] + 1
        depth[b] = depth[node] + 1
    return node_min, node_max, children, leaf_prim, depth


@njit(cache=True, inline="always")
def _merge_children(node_min, node_max, children, node):
    """An inner node's bounds: the union of its two children's."""
    a = children[node, 0]
    b = children[node, 1]
    for i in range(node_min.shape[1]):
        node_min[node, i] = min(node_min[a, i], node_min[b, i])
        node_max[node, i] = max(node_max[a, i], node_max[b, i])


@njit(cache=True)
def refit_range(node_min, node_max, children, leaf_prim, prim_min, prim_max, lo, hi):
    """Bottom-up refit of nodes [lo, hi) from per-primitive bounds (leaf_prim indexes prim_*)."""
    h = node_min.shape[1]
    for node in range(hi - 1, lo - 1, -1):
        p = leaf_prim[node]
        if p >= 0:
            for i in range(h):
                node_min[node, i] = prim_min[p, i]
                node_max[node, i] = prim_max[p, i]
        else:
            _merge_children(node_min, node_max, children, node)


@njit(cache=True)
def refit_particle_tree(node_min, node_max, children, leaf_prim, directions, x0, x1):
    """Refit the cloth tree (every step): leaves bound each particle's segment x0 -> x1."""
    h = directions.shape[0]
    for node in range(node_min.shape[0] - 1, -1, -1):
        p = leaf_prim[node]
        if p >= 0:
            for i in range(h):
                a = x0[p, 0] * directions[i, 0] + x0[p, 1] * directions[i, 1] + x0[p, 2] * directions[i, 2]
                b = x1[p, 0] * directions[i, 0] + x1[p, 1] * directions[i, 1] + x1[p, 2] * directions[i, 2]
                node_min[node, i] = min(a, b)
                node_max[node, i] = max(a, b)
        else:
            _merge_children(node_min, node_max, children, node)


# ---------------------------------------------------------------------------------------------
# builders (Python, once per scene)

def build_tree(prim_min: np.ndarray, prim_max: np.ndarray, centres: np.ndarray,
               directions: np.ndarray, margin: float = 0.0) -> KdopTree:
    """One k-DOP tree over P >= 1 primitives with bounds (P, h) (already inflated) and centres (P, 3)."""
    if prim_min.shape[0] == 0:
        raise ContractError("build_tree: needs at least one primitive")
    proj = np.ascontiguousarray(centres @ directions.T)
    nmin, nmax, ch, lp, dep = build_topology(np.ascontiguousarray(prim_min), np.ascontiguousarray(prim_max), proj)
    return KdopTree(directions=directions, node_min=nmin, node_max=nmax, children=ch, leaf_prim=lp,
                    depth=dep, tree_offsets=np.array([0, nmin.shape[0]], dtype=np.int32),
                    margin=np.array([margin], dtype=np.float64))


def build_triangle_tree(vertices: np.ndarray, triangles: np.ndarray, k: int = DEFAULT_K,
                        margin: float = 0.0) -> KdopTree:
    """k-DOP tree over triangles (leaf_prim = row of `triangles`), bounds inflated by `margin`."""
    d = kdop_directions(k)
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(triangles, dtype=np.int32)
    mn = np.empty((f.shape[0], d.shape[0]))
    mx = np.empty_like(mn)
    triangle_bounds(d, v, v, f, float(margin), mn, mx)
    return build_tree(mn, mx, v[f].mean(axis=1), d, margin)


def build_particle_tree(x0: np.ndarray, x1: np.ndarray | None = None, k: int = DEFAULT_K) -> KdopTree:
    """The cloth tree: one leaf per particle (its swept segment x0 -> x1; x1 = x0 if None).

    Topology is fixed from these positions; refit it every step with `refit_particle_tree`.
    """
    d = kdop_directions(k)
    x0 = np.ascontiguousarray(x0, dtype=np.float64)
    x1 = x0 if x1 is None else np.ascontiguousarray(x1, dtype=np.float64)
    mn = np.empty((x0.shape[0], d.shape[0]))
    mx = np.empty_like(mn)
    segment_bounds(d, x0, x1, mn, mx)
    return build_tree(mn, mx, 0.5 * (x0 + x1), d, 0.0)


def merge_forest(trees: list[KdopTree]) -> KdopTree:
    """Concatenate single trees (same directions) into one forest; leaf_prim is kept as given."""
    d = trees[0].directions
    if any(not np.array_equal(t.directions, d) for t in trees):
        raise ContractError("merge_forest: all trees must share one direction set")
    offsets = np.zeros(len(trees) + 1, dtype=np.int32)
    offsets[1:] = np.cumsum([t.node_min.shape[0] for t in trees])
    children = np.concatenate([np.where(t.children >= 0, t.children + o, -1)
                               for t, o in zip(trees, offsets[:-1])]).astype(np.int32)
    return KdopTree(directions=d,
                    node_min=np.concatenate([t.node_min for t in trees]),
                    node_max=np.concatenate([t.node_max for t in trees]),
                    children=children,
                    leaf_prim=np.concatenate([t.leaf_prim for t in trees]).astype(np.int32),
                    depth=np.concatenate([t.depth for t in trees]).astype(np.int32),
                    tree_offsets=offsets,
                    margin=np.concatenate([t.margin for t in trees]))


# ---------------------------------------------------------------------------------------------
# logging helpers (the lead logs these)

def kdop_nodes_at_depth(tree: KdopTree, depth: int, node_min: np.ndarray | None = None,
                        node_max: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(mins, maxs), each (m, h): the nodes at `depth` plus the leaves shallower than it, so the
    set covers every primitive. Pass node_min/node_max to read current (refit) bounds instead of
    the tree's build-time ones."""
    mn = tree.node_min if node_min is None else node_min
    mx = tree.node_max if node_max is None else node_max
    sel = (tree.depth == depth) | ((tree.depth < depth) & (tree.leaf_prim >= 0))
    return mn[sel].copy(), mx[sel].copy()


def kdop_box(mins: np.ndarray, maxs: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centres, half_sizes), each (m, 3): the axis-aligned part of k-DOPs (exact for k = 6)."""
    axes = [int(np.argmax(np.abs(directions @ e))) for e in np.eye(3)]
    lo = mins[:, axes]
    hi = maxs[:, axes]
    return 0.5 * (lo + hi), 0.5 * (hi - lo)


def kdop_wireframe(mins: np.ndarray, maxs: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """(s, 2, 3) float64 edge segments of one k-DOP (the intersection of its 2h half-spaces).

    Flat or degenerate k-DOPs (a leaf over a resting particle) are widened by 1e-6 m so the
    polytope has an interior; the result is then the wireframe of that slightly larger polytope.
    """
    from scipy.optimize import linprog
    from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError

    mins = np.asarray(mins, np.float64) - 1e-6
    maxs = np.asarray(maxs, np.float64) + 1e-6
    # half-spaces A x + b <= 0:  d.x - max <= 0  and  -d.x + min <= 0
    a = np.vstack([directions, -directions])
    b = np.concatenate([-maxs, mins])
    hs = np.column_stack([a, b])
    # Chebyshev centre: the interior point HalfspaceIntersection needs
    norm = np.linalg.norm(a, axis=1)
    res = linprog(c=[0, 0, 0, -1], A_ub=np.column_stack([a, norm]), b_ub=-b,
                  bounds=[(None, None)] * 3 + [(0, None)], method="highs")
    if not res.success or res.x[3] <= 0:
        raise ContractError("kdop_wireframe: the k-DOP's half-spaces have no interior (min > max?)")
    try:
        pts = HalfspaceIntersection(hs, res.x[:3]).intersections
        hull = ConvexHull(pts)
    except QhullError as exc:  # pragma: no cover - guarded by the widening above
        raise ContractError(f"kdop_wireframe: could not intersect the half-spaces ({exc})") from None
    # keep hull triangle edges whose two faces are not coplanar (drop the triangulation diagonals)
    normals = hull.equations[:, :3]
    segs = set()
    for f, simplex in enumerate(hull.simplices):
        for e in range(3):
            nb = hull.neighbors[f, e]  # neighbour opposite vertex e, sharing the other two
            if normals[f] @ normals[nb] > 1.0 - 1e-9:
                continue
            i, j = sorted((simplex[(e + 1) % 3], simplex[(e + 2) % 3]))
            segs.add((i, j))
    segs = sorted(segs)
    return np.array([[pts[i], pts[j]] for i, j in segs], dtype=np.float64).reshape(-1, 2, 3)
