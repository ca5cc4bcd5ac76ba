"""TEST HARNESS ONLY: a minimal square Verlet cloth to exercise the obstacle collider in tests and
the benchmark while the real cloth stage (stages/sim) is written. Not the project's simulator.

Grid cloth in the XZ plane, structural + shear + bend distance constraints (paper A's position
corrections, Gauss-Seidel, deterministic order), Verlet with a little damping, then one
`ObstacleCollider.collide` per step.
"""
from __future__ import annotations

import numpy as np
from numba import njit


def square_cloth(n: int = 50, size: float = 1.6, center=(0.0, 1.0, 0.0)):
    """n x n particles spanning size x size metres, flat at height center.y.

    Returns x (n*n, 3) float64, springs (s, 2) int32, rest (s,) float64 (metres).
    """
    u = np.linspace(-size / 2, size / 2, n)
    gx, gz = np.meshgrid(u, u, indexing="ij")
    x = np.column_stack([gx.ravel() + center[0], np.full(n * n, float(center[1])), gz.ravel() + center[2]])
    idx = np.arange(n * n).reshape(n, n)
    s = [np.column_stack([idx[:-1, :].ravel(), idx[1:, :].ravel()]),      # structural
         np.column_stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()]),
         np.column_stack([idx[:-1, :-1].ravel(), idx[1:, 1:].ravel()]),   # shear
         np.column_stack([idx[1:, :-1].ravel(), idx[:-1, 1:].ravel()]),
         np.column_stack([idx[:-2, :].ravel(), idx[2:, :].ravel()]),      # bend
         np.column_stack([idx[:, :-2].ravel(), idx[:, 2:].ravel()])]
    springs = np.concatenate(s).astype(np.int32)
    rest = np.linalg.norm(x[springs[:, 0]] - x[springs[:, 1]], axis=1)
    return x, springs, rest


@njit(cache=True)
def verlet_integrate(x_prev, x, inv_mass, gx, gy, gz, dt, damping):
    """Verlet integrate (x_prev, x) -> (x, x_new) in place."""
    n = x.shape[0]
    for p in range(n):
        if inv_mass[p] == 0.0:
            x_prev[p, 0] = x[p, 0]
            x_prev[p, 1] = x[p, 1]
            x_prev[p, 2] = x[p, 2]
            continue
        for j, g in ((0, gx), (1, gy), (2, gz)):
            cur = x[p, j]
            x[p, j] = cur + (1.0 - damping) * (cur - x_prev[p, j]) + g * dt * dt
            x_prev[p, j] = cur


@njit(cache=True)
def project_springs(x, inv_mass, springs, rest, iterations):
    """`iterations` rounds of distance corrections shared by inverse mass (paper A)."""
    for _ in range(iterations):
        for s in range(springs.shape[0]):
            i = springs[s, 0]
            k = springs[s, 1]
            wi = inv_mass[i]
            wk = inv_mass[k]
            if wi + wk == 0.0:
                continue
            dx = x[k, 0] - x[i, 0]
            dy = x[k, 1] - x[i, 1]
            dz = x[k, 2] - x[i, 2]
            ln = np.sqrt(dx * dx + dy * dy + dz * dz)
            if ln == 0.0:
                continue
            c = (ln - rest[s]) / (ln * (wi + wk))
            x[i, 0] += wi * c * dx
            x[i, 1] += wi * c * dy
            x[i, 2] += wi * c * dz
            x[k, 0] -= wk * c * dx
            x[k, 1] -= wk * c * dy
            x[k, 2] -= wk * c * dz


def drop_cloth(collider, x0, springs, rest, steps: int, dt: float = 1.0 / 30.0, damping: float = 0.02,
               iterations: int = 3, gravity=(0.0, -9.81, 0.0), inv_mass=None, on_step=None,
               rounds: int = 1):
    """Drop a cloth from rest at x0 for `steps` steps against `collider` (an ObstacleCollider).

    Each step: Verlet, then `rounds` x (`iterations` spring corrections + one collision call), so
    with rounds > 1 the obstacle carries the hanging weight inside the constraint loop.

    Returns (x_prev, x) at the end. on_step(step, x_prev, x, n_contacts) is called after each step.
    """
    x = np.ascontiguousarray(x0, dtype=np.float64).copy()
    x_prev = x.copy()
    w = np.ones(x.shape[0]) if inv_mass is None else np.asarray(inv_mass, np.float64)
    g = [float(c) for c in gravity]
    for s in range(steps):
        verlet_integrate(x_prev, x, w, g[0], g[1], g[2], dt, damping)
        for _ in range(rounds):
            project_springs(x, w, springs, rest, iterations)
            n = collider.collide(x_prev, x, w, s * dt, (s + 1) * dt)
        if on_step is not None:
            on_step(s, x_prev, x, n)
    return x_prev, x
