"""Inline numba helpers for (4, 4) affine matrices applied to one point given as three floats.

Shared by the simulation and obstacle kernels; returning tuples keeps hot loops allocation-free.
"""
from __future__ import annotations

from numba import njit


@njit(cache=True, inline="always")
def apply_affine(m, x, y, z):
    """m @ (x, y, z, 1), first three components."""
    return (m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3],
            m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3],
            m[2, 0] * x + m[2, 1] * y + m[2, 2] * z + m[2, 3])


@njit(cache=True, inline="always")
def apply_rigid_inverse(m, x, y, z):
    """R^T ((x, y, z) - t) for a rigid m = [R t]: the inverse without inverting."""
    x -= m[0, 3]
    y -= m[1, 3]
    z -= m[2, 3]
    return (m[0, 0] * x + m[1, 0] * y + m[2, 0] * z,
            m[0, 1] * x + m[1, 1] * y + m[2, 1] * z,
            m[0, 2] * x + m[1, 2] * y + m[2, 2] * z)
