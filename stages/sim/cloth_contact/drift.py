"""How far the cloth has deformed since the offset phase's query (stages.sim.cloth_contact.offset):
the proof that the pairs the query did not list (features at least the radius r apart at x_q) still
cannot touch, from the relative displacements D_a - D_b of nearby vertices only, so that a cloth
moving or turning as a whole keeps its query (one margin for all, |D_i - c| < r / 2 with one common
c, sent the query again at nearly every call of a falling or walking garment).

Why it is enough: an unlisted pair (A, B) is at least r apart at x_q, and any vertex a of A and b of
B with |x_a - x_b| = s are at least s - 2 e apart as features (e: the longest edge at x_q, each
feature's diameter). Level k (of LEVELS) bins the vertices at x_q into cubes of side
h_k = 2 e + 2 r 4^k: two vertices within h_k of each other lie in the same or adjacent cubes, so the
displacement box of those two cubes bounds |D_a - D_b|; its diagonal must stay below
limit_k = max(r, h_(k-1) - 2 e) (r at level 0), the least feature distance of pairs that level is the
first to hold. Vertices farther apart than the last level's side: the box of every displacement
against the last limit. Straight paths x_q -> x scale every D alike, so the bound holds all along.

`ratio(x, xq, dr)`: the largest diagonal / limit over the levels (< SAFE: proven).

State (drift_state): (size (L,), limit (L + 1,), cell_of (L, N) i4, n_cells (L,) i4, cell_ijk (L, N, 3)
i8, keys (L, H) i8, vals (L, H) i4, pairs (L, 14 N, 2) i4, n_pairs (L,) i4, box (L, N, 6))
"""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)

LEVELS = 4
_BITS = 21
_MASK = (1 << _BITS) - 1
_EMPTY = -1


def drift_state(n: int) -> tuple:
    """Work arrays for a cloth of n vertices (filled by drift_build at each query)."""
    n = max(int(n), 1)
    h = 1 << int(np.ceil(np.log2(2 * n + 2)))
    return (np.zeros(LEVELS), np.zeros(LEVELS + 1), np.zeros((LEVELS, n), np.int32), np.zeros(LEVELS, np.int32),
            np.zeros((LEVELS, n, 3), np.int64), np.full((LEVELS, h), _EMPTY, np.int64),
            np.zeros((LEVELS, h), np.int32), np.zeros((LEVELS, 14 * n, 2), np.int32), np.zeros(LEVELS, np.int32),
            np.zeros((LEVELS, n, 6)))


@njit(cache=True, _nrt=False, inline="always")
def _key(i, j, k):
    """One int64 per cube (coordinates wrapped to _BITS bits: cubes that share a key are one cube,
    a larger box: still a bound)."""
    return ((i & _MASK) << (2 * _BITS)) | ((j & _MASK) << _BITS) | (k & _MASK)


@njit(cache=True, _nrt=False, inline="always")
def _slot(key, bits):
    return np.int64((np.uint64(key) * np.uint64(11400714819323198485)) >> np.uint64(64 - bits))


@njit(cache=True, _nrt=False)
def _find(keys, vals, key, bits):
    """The cube id of key at one level, -1 when absent."""
    mask = keys.shape[0] - 1
    s = _slot(key, bits)
    while keys[s] != _EMPTY:
        if keys[s] == key:
            return vals[s]
        s = (s + 1) & mask
    return -1


@njit(cache=True, _nrt=False)
def drift_build(xq, tris, radius, dr):
    """Bin the vertices at x_q into each level's cubes and list the pairs of adjacent occupied cubes."""
    size, limit, cell_of, n_cells, ijk, keys, vals, pairs, n_pairs, _ = dr
    e2 = 0.0
    for t in range(tris.shape[0]):
        for k in range(3):
            a, b = tris[t, k], tris[t, (k + 1) % 3]
            dx, dy, dz = xq[a, 0] - xq[b, 0], xq[a, 1] - xq[b, 1], xq[a, 2] - xq[b, 2]
            e2 = max(e2, dx * dx + dy * dy + dz * dz)
    e = np.sqrt(e2)
    for lv in range(LEVELS):
        size[lv] = 2.0 * e + 2.0 * radius * 4.0 ** lv
        limit[lv] = radius if lv == 0 else max(radius, size[lv - 1] - 2.0 * e)
    limit[LEVELS] = max(radius, size[LEVELS - 1] - 2.0 * e)
    hsize = keys.shape[1]
    bits = 0
    while (1 << bits) < hsize:
        bits += 1
    n = xq.shape[0]
    for lv in range(LEVELS):
        for s in range(hsize):
            keys[lv, s] = _EMPTY
        inv = 1.0 / size[lv]
        nc = 0
        for v in range(n):
            i = np.int64(np.floor(xq[v, 0] * inv))
            j = np.int64(np.floor(xq[v, 1] * inv))
            k = np.int64(np.floor(xq[v, 2] * inv))
            key = _key(i, j, k)
            s = _slot(key, bits)
            while keys[lv, s] != _EMPTY and keys[lv, s] != key:
                s = (s + 1) & (hsize - 1)
            if keys[lv, s] == _EMPTY:
                keys[lv, s] = key
                vals[lv, s] = nc
                ijk[lv, nc, 0], ijk[lv, nc, 1], ijk[lv, nc, 2] = i, j, k
                nc += 1
            cell_of[lv, v] = vals[lv, s]
        n_cells[lv] = nc
        npair = 0
        for c in range(nc):
            for dx in range(-1, 2):
                for dy in range(-1, 2):
                    for dz in range(-1, 2):
                        # each unordered pair of adjacent cubes once: the offsets after (0, 0, 0)
                        if dx < 0 or (dx == 0 and (dy < 0 or (dy == 0 and dz <= 0))):
                            continue
                        o = _find(keys[lv], vals[lv], _key(ijk[lv, c, 0] + dx, ijk[lv, c, 1] + dy, ijk[lv, c, 2] + dz),
                                  bits)
                        if o >= 0 and o != c:
                            pairs[lv, npair, 0] = c
                            pairs[lv, npair, 1] = o
                            npair += 1
        n_pairs[lv] = npair


@njit(cache=True, _nrt=False, inline="always")
def _diag2(box, a, b):
    s = 0.0
    for k in range(3):
        d = max(box[a, 3 + k], box[b, 3 + k]) - min(box[a, k], box[b, k])
        s += d * d
    return s


@njit(cache=True, _nrt=False)
def ratio(x, xq, dr):
    """The largest diagonal of a displacement box over its limit (module docstring), over every level
    and the whole cloth."""
    size, limit, cell_of, n_cells, ijk, keys, vals, pairs, n_pairs, box = dr
    n = x.shape[0]
    worst = 0.0
    lo0 = lo1 = lo2 = np.inf
    hi0 = hi1 = hi2 = -np.inf
    for v in range(n):
        d0, d1, d2 = x[v, 0] - xq[v, 0], x[v, 1] - xq[v, 1], x[v, 2] - xq[v, 2]
        lo0, hi0 = min(lo0, d0), max(hi0, d0)
        lo1, hi1 = min(lo1, d1), max(hi1, d1)
        lo2, hi2 = min(lo2, d2), max(hi2, d2)
    if n > 0:
        worst = np.sqrt((hi0 - lo0) ** 2 + (hi1 - lo1) ** 2 + (hi2 - lo2) ** 2) / limit[LEVELS]
    for lv in range(LEVELS):
        bx = box[lv]
        for c in range(n_cells[lv]):
            for k in range(3):
                bx[c, k] = np.inf
                bx[c, 3 + k] = -np.inf
        for v in range(n):
            c = cell_of[lv, v]
            for k in range(3):
                d = x[v, k] - xq[v, k]
                bx[c, k] = min(bx[c, k], d)
                bx[c, 3 + k] = max(bx[c, 3 + k], d)
        w2 = 0.0
        for c in range(n_cells[lv]):
            w2 = max(w2, _diag2(bx, c, c))
        for p in range(n_pairs[lv]):
            w2 = max(w2, _diag2(bx, pairs[lv, p, 0], pairs[lv, p, 1]))
        worst = max(worst, np.sqrt(w2) / limit[lv])
    return worst


def reference_ratio(x: np.ndarray, xq: np.ndarray, tris: np.ndarray, radius: float) -> float:
    """Plain-Python reference of drift_build + ratio (dicts of cubes, no wrapped keys)."""
    d = x - xq
    e = max((float(np.linalg.norm(xq[a] - xq[b])) for t in tris for a, b in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))),
            default=0.0)
    sizes = [2 * e + 2 * radius * 4.0 ** lv for lv in range(LEVELS)]
    limits = [radius] + [max(radius, sizes[lv - 1] - 2 * e) for lv in range(1, LEVELS + 1)]
    worst = float(np.linalg.norm(d.max(0) - d.min(0))) / limits[LEVELS] if len(d) else 0.0
    for lv in range(LEVELS):
        cubes: dict = {}
        for v in range(len(x)):
            cubes.setdefault(tuple(int(c) for c in np.floor(xq[v] / sizes[lv])), []).append(v)
        for c, members in cubes.items():
            for o in np.ndindex(3, 3, 3):
                other = cubes.get(tuple(c[k] + o[k] - 1 for k in range(3)))
                if other is None:
                    continue
                dd = d[members + other]
                worst = max(worst, float(np.linalg.norm(dd.max(0) - dd.min(0))) / limits[lv])
    return worst
