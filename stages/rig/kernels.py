"""Numba kernels of the rig stage (linear blend skinning)."""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps, plain slice errors: see stages/jit.py)


@njit(cache=True)
def lbs_kernel(matrices: np.ndarray, vertices: np.ndarray, joints: np.ndarray, weights: np.ndarray,
               out: np.ndarray) -> None:
    """Linear blend skinning of many frames (serial: ~30 us per 3k-vertex frame, not worth threads).

    matrices: (F, J, 4, 4) float64 skinning matrices; vertices: (V, 3) float64 bind pose;
    joints: (V, K) int32; weights: (V, K) float64; out: (F, V, 3) float64, written in place:
    out[f, v] = sum_k weights[v, k] * (matrices[f, joints[v, k]] @ [vertices[v], 1])[:3].
    """
    n_frames = matrices.shape[0]
    n_verts = vertices.shape[0]
    n_slots = joints.shape[1]
    for fv in range(n_frames * n_verts):
        f = fv // n_verts
        v = fv - f * n_verts
        x = vertices[v, 0]
        y = vertices[v, 1]
        z = vertices[v, 2]
        ax = 0.0
        ay = 0.0
        az = 0.0
        for k in range(n_slots):
            w = weights[v, k]
            if w == 0.0:
                continue
            m = matrices[f, joints[v, k]]
            ax += w * (m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3])
            ay += w * (m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3])
            az += w * (m[2, 0] * x + m[2, 1] * y + m[2, 2] * z + m[2, 3])
        out[f, v, 0] = ax
        out[f, v, 1] = ay
        out[f, v, 2] = az
