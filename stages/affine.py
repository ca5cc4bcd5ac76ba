"""Inline numba helpers over points given as three floats: (4, 4) affine matrices applied to one
point, and a triangle's edge cross product.

Shared by the simulation, obstacle and hull kernels; returning tuples keeps hot loops allocation-free.
"""
from __future__ import annotations

from numba import njit


@njit(cache=True, _nrt=False, forceinline=True)
def apply_affine(m, x, y, z):
    """m @ (x, y, z, 1), first three components."""
    return (m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3],
            m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3],
            m[2, 0] * x + m[2, 1] * y + m[2, 2] * z + m[2, 3])


@njit(cache=True, _nrt=False, forceinline=True)
def apply_rigid_inverse(m, x, y, z):
    """R^T ((x, y, z) - t) for a rigid m = [R t]: the inverse without inverting."""
    x -= m[0, 3]
    y -= m[1, 3]
    z -= m[2, 3]
    return (m[0, 0] * x + m[1, 0] * y + m[2, 0] * z,
            m[0, 1] * x + m[1, 1] * y + m[2, 1] * z,
            m[0, 2] * x + m[1, 2] * y + m[2, 2] * z)


@njit(cache=True, _nrt=False, forceinline=True)
def triangle_cross(v, a, b, c):
    """(v[b] - v[a]) x (v[c] - v[a]) for rows a, b, c of v (N, 3): the normal, |.| = twice the area."""
    e1x = v[b, 0] - v[a, 0]
    e1y = v[b, 1] - v[a, 1]
    e1z = v[b, 2] - v[a, 2]
    e2x = v[c, 0] - v[a, 0]
    e2y = v[c, 1] - v[a, 1]
    e2z = v[c, 2] - v[a, 2]
    return e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
