"""Settling before frame 0: the step loop at the first frame's pose, heavily damped, so that a sewn
garment hangs under full gravity before the motion starts (stages.sim.simulate calls it)."""
from __future__ import annotations

import numpy as np

from stages.sim import step
from stages.sim.types import REFERENCE_STEP, SETTLE_DAMPING


def settle(cloth, cols, m, prm, params, gravity, wind, fwd0, inv0, max_speed2, goff, flags, cc) -> bool:
    """params.settle_frames frames of the step loop at the frame-0 pose (fwd0 / inv0 (J, 4, 4)) with
    the velocity damped by SETTLE_DAMPING per 1/30 s, not recorded; then xp = x (the garment starts
    at rest). cc: the cloth phase's state (ClothPhase.rest) or None. The other arguments are
    run_frames'. False when the cloth diverged (the state left as it diverged)."""
    ss, f = params.substeps, params.settle_frames
    damped = (prm[0], 1.0 - (1.0 - SETTLE_DAMPING) ** (params.step / REFERENCE_STEP)) + tuple(prm[2:])
    k = f * ss
    fwd = np.ascontiguousarray(np.repeat(fwd0[None], k, axis=0))
    inv = np.ascontiguousarray(np.repeat(inv0[None], k, axis=0))
    z = np.zeros((k, 3))
    n, g = cloth[0].shape[0], goff.size - 1
    done = step.run_frames(cloth, cols, m, damped, gravity, wind, fwd, inv, inv, z, z, ss, max_speed2, goff,
                           np.zeros((f, n, 3), np.float32), np.zeros((f, g), np.int32), np.zeros((f, step.N_COUNTS)),
                           np.zeros(f, np.int64), flags, np.zeros(step.N_TIMERS, np.int64), cc)
    if done < f:
        return False
    cloth[1][:] = cloth[0]
    return True
