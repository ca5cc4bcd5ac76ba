"""Blending from the rest (bind) pose into a running clip, and how long that blend should be.

Garments are dressed and sewn on the character's rest pose, where the limbs are apart and nothing
presses on the cloth; a scene that starts anywhere in a clip then gets frames that carry the
character from that pose into the clip. Two things make that blend smooth:

- the weight of the clip pose goes 0 -> 1 along smootherstep (C2: no jump in velocity or
  acceleration at either end);
- the clip is running while it blends in: its time accelerates from standing to full speed along
  the same curve, so that the last blend frame reaches `start` moving at the clip's own speed. A
  blend towards the *frozen* pose at `start` arrives at rest and then jumps to the clip's speed:
  the jolt every blend-in had at its last frame.
"""
from __future__ import annotations

import numpy as np

# the blend takes this many seconds per body height that the farthest skin point travels (a hand
# moving at half a body height a second: CesiumMan's T-pose to its walk ~1 s, the BVH's A-pose ~0.5 s)
SECONDS_PER_HEIGHT = 2.0
BLEND_MIN_S = 0.3          # a shorter blend snaps the cloth along (the dressing frames' own speed)
BLEND_MAX_S = 2.0          # beyond this the blend is no slower, only longer to watch
BLEND_NONE = 0.005         # poses closer than this share of the height need no blend


def smootherstep(u: np.ndarray) -> np.ndarray:
    """6u^5 - 15u^4 + 10u^3 on [0, 1]: 0 -> 1 with zero first and second derivatives at both ends."""
    u = np.clip(np.asarray(u, np.float64), 0.0, 1.0)
    return u * u * u * (u * (6.0 * u - 15.0) + 10.0)


def smootherstep_tail(u: np.ndarray) -> np.ndarray:
    """Integral of smootherstep from u to 1 (0.5 at u = 0, 0 at u = 1)."""
    u = np.clip(np.asarray(u, np.float64), 0.0, 1.0)
    return 0.5 - u ** 4 * (u * (u - 3.0) + 2.5)


def blend_schedule(n_frames: int, dt: float, start: float) -> tuple[np.ndarray, np.ndarray]:
    """For `n_frames` blend frames before clip time `start`: (weights (B,), clip times (B,)).

    Frame k has u = k / B; its pose is the rest pose blended with the clip at `times[k]` by
    `weights[k]`. The clip time runs at smootherstep(u) of its speed, so it reaches `start` at
    u = 1 at full speed, having played B * dt / 2 seconds of the clip before `start`.
    """
    u = np.arange(n_frames, dtype=np.float64) / max(n_frames, 1)
    return smootherstep(u), start - n_frames * dt * smootherstep_tail(u)


def blend_seconds(distance: float, height: float) -> float:
    """Blend length (s) for a farthest skin displacement `distance` (m) on a body `height` m tall:
    0 below BLEND_NONE of the height, else SECONDS_PER_HEIGHT per height travelled, clamped to
    [BLEND_MIN_S, BLEND_MAX_S]."""
    if not np.isfinite(distance) or height <= 0 or distance <= BLEND_NONE * height:
        return 0.0
    return float(np.clip(SECONDS_PER_HEIGHT * distance / height, BLEND_MIN_S, BLEND_MAX_S))
