"""The floor under worn garments (SimParams.floor): a horizontal half-space the cloth stays above.

The simulation runs in the relative frame (world = x + T(t), stages/sim/simulate.py), so a world floor
at height f is the moving plane y >= f - T_y(t) there: `floor_heights` gives its height at every step
boundary of a chunk of frames (the root translation interpolated between frames as the colliders'
poses are), and `collide_floor`, a phase of the step loop (stages.sim.step.run_steps, after the
collisions with the character), puts a free particle under it back on it.
"""
from __future__ import annotations

import numpy as np
from numba import njit


def floor_heights(root_y: np.ndarray, f0: int, f1: int, substeps: int, level: float) -> np.ndarray:
    """(K + 1,) float64, K = (f1 - f0) * substeps: the floor's height in the relative frame at the step
    boundaries of frames f0..f1-1 (frame f steps from f - 1 to f), `level` its world height; root_y
    (F,) the root translation's height per frame, lerped between frames."""
    u = np.arange(substeps) / substeps
    a, b = root_y[f0 - 1:f1 - 1], root_y[f0:f1]
    t = np.append((a[:, None] + (b - a)[:, None] * u[None, :]).ravel(), root_y[f1 - 1])
    return np.ascontiguousarray(level - t, dtype=np.float64)


@njit(cache=True, _nrt=False)
def collide_floor(x, xp, inv_mass, attach_joint, floor, k, d_next, friction):
    """Step k's floor response: a free particle (not attached, inverse mass > 0) under floor[k + 1]
    (the plane's height at the end of the step, relative frame) is put on it. As a body collider's
    response (stages.sim.body_collide._push): relative to the plane (at floor[k] at the step's start,
    and moving by -d_next along it: the ground, which does not move in world, seen from the root
    with the inertia scale's share of its travel, so that the ground's pull matches the cloth's
    inertia), Coulomb friction takes up to `friction` times the depth off the tangential travel, and a
    push-out beyond where the particle started the step (the plane rising into it: the root going
    down) is not turned into an upward Verlet velocity (xp moved by it: fully inelastic). floor (K + 1,)
    (see floor_heights); d_next (3,) this step's scaled root travel (run_steps' d_next[k])."""
    f0 = floor[k]
    f1 = floor[k + 1]
    gx = -d_next[0]
    gz = -d_next[2]
    for i in range(x.shape[0]):
        y = x[i, 1]
        if y >= f1 or inv_mass[i] == 0.0 or attach_joint[i] >= 0:
            continue
        depth = f1 - y
        x[i, 1] = f1
        if friction > 0.0:
            tx = x[i, 0] - xp[i, 0] - gx
            tz = x[i, 2] - xp[i, 2] - gz
            tl = np.sqrt(tx * tx + tz * tz)
            if tl > 0.0:
                c = min(1.0, friction * depth / tl)
                x[i, 0] -= c * tx
                x[i, 2] -= c * tz
        vn = f0 - xp[i, 1]      # (end height over the plane, 0) - (start height over it)
        if vn > 0.0:
            xp[i, 1] += vn
