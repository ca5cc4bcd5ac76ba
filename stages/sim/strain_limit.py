"""Strain limiting (Provot 1995, "inverse dynamics"; Bridson, Fedkiw & Anderson 2002): after a step's
spring rounds and collisions, every mesh edge longer than (1 + limit) times its rest length is
shortened back to that bound, shared by inverse mass, in a few Gauss-Seidel passes.

Why: the springs' few rounds cannot undo what the collisions do within a step. Cloth hooked or
pinched round a limb is pushed out of the colliders on both sides of it every step and stays
stretched across it (issue 38: crossed triangles 2-2.5 times their rest size on the worst frames,
the skin poking through their flat middle). The limit comes after the collisions, so a hook cannot
hold the cloth stretched: the limit pulls it into the limb and the next step's collisions push it
out on whichever side is nearer (a release through the limb, in one frame). With the collisions
after the limit instead (a second collision pass), the colliders won again and the strain stayed
(cesium_skirt worst p99 after the blend-in 127 -> 106 %; after them: 46 %).

Layout: `limits` = (si, sj, max_len, wi) as built by `strain_limits`: (E,) int32 ends, (E,) float64
(1 + limit) * rest, (E,) float64 share of the correction the first end takes (w_i / (w_i + w_j),
inverse masses with attached particles 0; the second end takes 1 - wi). Empty arrays: off.
"""
from __future__ import annotations

import numpy as np
from numba import njit

PASSES = 4      # Gauss-Seidel passes per step (edges still over the bound after them wait for the next step)


def strain_limits(si, sj, rest, w, limit: float) -> tuple:
    """The `limits` tuple of the edges (si, sj) with rest lengths `rest`, particles' inverse masses w
    (attached: 0); edges with both ends fixed left out. limit <= 0: empty (off)."""
    si = np.asarray(si, np.int64)
    sj = np.asarray(sj, np.int64)
    w = np.asarray(w, np.float64)
    wsum = w[si] + w[sj] if si.size else np.zeros(0)
    keep = wsum > 0 if limit > 0 else np.zeros(si.size, bool)
    return (np.ascontiguousarray(si[keep], np.int32), np.ascontiguousarray(sj[keep], np.int32),
            np.ascontiguousarray((1.0 + float(limit)) * np.asarray(rest, np.float64)[keep]),
            np.ascontiguousarray(w[si[keep]] / wsum[keep]))


@njit(cache=True, _nrt=False)
def limit_strain(x, limits, passes):
    """Shorten every edge of `limits` longer than its bound to the bound, `passes` Gauss-Seidel passes
    in edge order (serial: the result does not depend on the thread count). Returns the number of
    edges shortened in the first pass (0: none was over its bound)."""
    si, sj, max_len, wi = limits
    first = 0
    for p in range(passes):
        n = 0
        for k in range(si.size):
            i = si[k]
            j = sj[k]
            dx = x[j, 0] - x[i, 0]
            dy = x[j, 1] - x[i, 1]
            dz = x[j, 2] - x[i, 2]
            d2 = dx * dx + dy * dy + dz * dz
            b = max_len[k]
            if d2 <= b * b:
                continue
            c = 1.0 - b / np.sqrt(d2)       # the fraction of the edge to remove
            a = wi[k] * c
            e = (1.0 - wi[k]) * c
            x[i, 0] += a * dx
            x[i, 1] += a * dy
            x[i, 2] += a * dz
            x[j, 0] -= e * dx
            x[j, 1] -= e * dy
            x[j, 2] -= e * dz
            n += 1
        if p == 0:
            first = n
        if n == 0:
            break
    return first
