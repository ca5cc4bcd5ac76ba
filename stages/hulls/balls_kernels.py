"""Numba kernels of the skinned-ball fit (stages/hulls/balls.py)."""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps, plain slice errors: see stages/jit.py)


@njit(cache=True)
def pairs_in_reach(centers: np.ndarray, targets: np.ndarray, reach: np.ndarray, cell: float):
    """Every (centre, target) pair within reach at every pose, found through a uniform grid of the
    targets at the first pose: (indptr (C + 1,) int64, cols (N,) int64, far (N,) float64), CSR rows
    by centre, cols ascending in a row, far = the pair's largest distance over the poses (m).

    centers (S, C, 3), targets (S, T, 3) float64, m; reach (C,) float64, m; cell: grid cell edge, m."""
    n_poses, n_c, n_t = centers.shape[0], centers.shape[1], targets.shape[1]
    lo = np.empty(3)
    dims = np.empty(3, np.int64)
    for a in range(3):
        lo[a] = targets[0, :, a].min() if n_t else 0.0
        hi = targets[0, :, a].max() if n_t else 0.0
        dims[a] = int((hi - lo[a]) / cell) + 1
    key = np.empty(n_t, np.int64)
    for t in range(n_t):
        ix = int((targets[0, t, 0] - lo[0]) / cell)
        iy = int((targets[0, t, 1] - lo[1]) / cell)
        iz = int((targets[0, t, 2] - lo[2]) / cell)
        key[t] = (ix * dims[1] + iy) * dims[2] + iz
    order = np.argsort(key, kind="mergesort")          # stable: targets ascending within a cell
    start = np.zeros(dims[0] * dims[1] * dims[2] + 1, np.int64)
    for t in range(n_t):
        start[key[t] + 1] += 1
    for k in range(1, start.size):
        start[k] += start[k - 1]
    indptr = np.zeros(n_c + 1, np.int64)
    cols = np.empty(max(16, 64 * n_c), np.int64)
    far = np.empty(cols.size)
    row = np.empty(n_t, np.int64)      # one centre's pairs, sorted before they are kept
    row_far = np.empty(n_t)
    n = 0
    for c in range(n_c):
        r = reach[c]
        r2 = r * r
        m = 0
        cx, cy, cz = centers[0, c, 0], centers[0, c, 1], centers[0, c, 2]
        x0, x1 = max(int((cx - r - lo[0]) / cell), 0), min(int((cx + r - lo[0]) / cell), dims[0] - 1)
        y0, y1 = max(int((cy - r - lo[1]) / cell), 0), min(int((cy + r - lo[1]) / cell), dims[1] - 1)
        z0, z1 = max(int((cz - r - lo[2]) / cell), 0), min(int((cz + r - lo[2]) / cell), dims[2] - 1)
        for ix in range(x0, x1 + 1):
            for iy in range(y0, y1 + 1):
                for iz in range(z0, z1 + 1):
                    k = (ix * dims[1] + iy) * dims[2] + iz
                    for j in range(start[k], start[k + 1]):
                        t = order[j]
                        worst = 0.0
                        for s in range(n_poses):
                            dx = centers[s, c, 0] - targets[s, t, 0]
                            dy = centers[s, c, 1] - targets[s, t, 1]
                            dz = centers[s, c, 2] - targets[s, t, 2]
                            d2 = dx * dx + dy * dy + dz * dz
                            if d2 > worst:
                                worst = d2
                                if worst > r2:
                                    break
                        if worst <= r2:
                            row[m] = t
                            row_far[m] = np.sqrt(worst)
                            m += 1
        if n + m > cols.size:
            grown = max(2 * cols.size, n + m)
            cols2 = np.empty(grown, np.int64)
            far2 = np.empty(grown)
            cols2[:n] = cols[:n]
            far2[:n] = far[:n]
            cols, far = cols2, far2
        idx = np.argsort(row[:m])
        for i in range(m):
            cols[n + i] = row[idx[i]]
            far[n + i] = row_far[idx[i]]
        n += m
        indptr[c + 1] = n
    return indptr, cols[:n].copy(), far[:n].copy()
