"""Settling before frame 0: frames of the step loop held at the first frame's pose, not recorded, so
that sewn garments hang (and layered ones are sorted) before the motion starts. stages.sim.simulate
calls `settle`; the cloth phase's layer sorting (ClothPhase.settle) runs `hold_pose` too."""
from __future__ import annotations

import numpy as np

from stages.sim import step
from stages.sim.types import REFERENCE_STEP, SETTLE_DAMPING


def hold_pose(cloth, cols, m, prm, frames, gravity, wind, fwd0, inv0, substeps, max_speed2, goff, flags, cc,
              floor0=None) -> bool:
    """`frames` frames of the step loop at the pose fwd0 / inv0 (J, 4, 4), not recorded; then xp = x
    (the cloth starts them at rest). cc: the cloth phase's state or None; floor0: the floor's height
    in the relative frame at that pose (None: no floor); the other arguments are run_frames'. False
    when the cloth diverged (the state left as it diverged)."""
    k = frames * substeps
    fwd = np.ascontiguousarray(np.repeat(fwd0[None], k, axis=0))
    inv = np.ascontiguousarray(np.repeat(inv0[None], k, axis=0))
    z = np.zeros((k, 3))
    floor = np.full(k + 1, float(floor0)) if floor0 is not None else np.zeros(0)
    n, g = cloth[0].shape[0], goff.size - 1
    done = step.run_frames(cloth, cols, m, prm, gravity, wind, fwd, inv, inv, z, z, floor, substeps, max_speed2, goff,
                           np.zeros((frames, n, 3), np.float32), np.zeros((frames, g), np.int32),
                           np.zeros((frames, step.N_COUNTS)), np.zeros(frames, np.int64), flags,
                           np.zeros(step.N_TIMERS, np.int64), cc)
    if done < frames:
        return False
    cloth[1][:] = cloth[0]
    return True


def settle(cloth, cols, m, prm, params, gravity, wind, fwd0, inv0, max_speed2, goff, flags, cc, floor0=None) -> bool:
    """params.settle_frames frames held at the frame-0 pose with the velocity damped by SETTLE_DAMPING
    per 1/30 s (`hold_pose`): the garments hang under full gravity, then start at rest."""
    damped = (prm[0], 1.0 - (1.0 - SETTLE_DAMPING) ** (params.step / REFERENCE_STEP)) + tuple(prm[2:])
    return hold_pose(cloth, cols, m, damped, params.settle_frames, gravity, wind, fwd0, inv0, params.substeps,
                     max_speed2, goff, flags, cc, floor0)
