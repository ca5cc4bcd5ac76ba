"""Cloth a limb tears lets go of it: an automatic, local and temporary `ignore_colliders`.

A hand or forearm the animation swings into a garment catches the cloth and drags it against the
pinned waist or shoulders, or against the body (docs/decisions.md, "Limbs, strain and the body"):
edges stretch to several times their length. After every frame the edges stretched over `threshold`
(SimParams.limb_release, far past what cloth stretches) are found; their free ends within REACH
of a collider of an arm or leg stop being pushed by that limb's colliders (the collision kernel's
contact entry becomes IGNORED), so the limb passes through the cloth there and the springs pull it
back. An entry is restored once the particle is CLEAR outside every collider of that limb: the
cloth is caught again only from outside. The entries of the limbs a garment ignores are left alone.
"""
from __future__ import annotations

import numpy as np

from stages.garments.types import STRETCH
from stages.sim.collider_query import IGNORED
from stages.sim.strain_sources import collider_distances

REACH = 0.01    # m: an end of a torn edge this near a limb's collider is held by it
CLEAR = 0.01    # m: a released particle this far outside all of a limb's colliders is caught again


class LimbRelease:
    """Per-frame release of cloth torn by limbs (see the module docstring).

    garments: the simulated Garments (their stretch springs and rest lengths); offsets (G + 1,): their
    particles' ranges in the system; inv_mass (N,): 0 for pinned particles (never released); owner
    (C,): the joint of each kernel collider; limbs: the arm and leg joints; contact (N, C): the
    kernel's entries (a garment's IGNORED ones are never released nor restored)."""

    def __init__(self, garments, offsets, inv_mass, colliders, owner, limbs, contact, threshold: float):
        self.colliders, self.owner, self.threshold = colliders, np.asarray(owner), float(threshold)
        self.free = np.asarray(inv_mass) > 0
        self.edges = np.concatenate([g.springs[g.kinds == STRETCH] + o for g, o in zip(garments, offsets)]).astype(np.int64)
        self.rest = np.concatenate([np.maximum(g.rest_lengths[g.kinds == STRETCH], 1e-9) for g in garments])
        self.garment = np.repeat(np.arange(len(garments)), np.diff(offsets))
        self.releasable = np.zeros((len(garments), int(self.owner.max(initial=-1)) + 1), bool)
        for k in range(len(garments)):
            for j in limbs:
                cols = self.owner == j
                if cols.any() and not (contact[offsets[k]:offsets[k + 1]][:, cols] == IGNORED).any():
                    self.releasable[k, j] = True
        self.released = set()                   # (particle, joint) pairs let go of
        self.per_frame = {}                     # frame -> particles released at it

    @property
    def active(self) -> bool:
        return bool(self.releasable.any())

    def after_frame(self, frame: int, x: np.ndarray, contact: np.ndarray, poses: np.ndarray) -> None:
        """Restore, then release, contact entries after `frame` (x (N, 3) relative frame; poses: the
        colliders' poses at the frame, ColliderSet.frame_poses)."""
        if self.released:
            self._restore(x, contact, poses)
        length = np.linalg.norm(x[self.edges[:, 0]] - x[self.edges[:, 1]], axis=1)
        hot = length > (1.0 + self.threshold) * self.rest
        if not hot.any():
            return
        ends = np.unique(self.edges[hot].ravel())
        ends = ends[self.free[ends]]
        if ends.size == 0:
            return
        d, cj = collider_distances(self.colliders, poses, x[ends])
        for j in np.unique(cj):
            if j >= self.releasable.shape[1]:
                continue
            near = self.releasable[self.garment[ends], j] & (d[cj == j].min(axis=0) < REACH)
            cols = self.owner == j
            for i in ends[near]:
                key = (int(i), int(j))
                if key not in self.released:
                    self.released.add(key)
                    contact[i, cols] = IGNORED
                    self.per_frame[frame] = self.per_frame.get(frame, 0) + 1

    def _restore(self, x, contact, poses):
        keys = list(self.released)
        d, cj = collider_distances(self.colliders, poses, x[[i for i, _ in keys]])
        for k, (i, j) in enumerate(keys):
            if d[cj == j, k].min() > CLEAR:
                contact[i, self.owner == j] = -1
                self.released.discard((i, j))

    def counts(self, n_frames: int) -> np.ndarray:
        """(n_frames,) int32: particles released at each frame."""
        out = np.zeros(n_frames, np.int32)
        for f, c in self.per_frame.items():
            if f < n_frames:
                out[f] = c
        return out


def limb_release(sysm, owner, colliders, character, garments, params):
    """The run's LimbRelease (SimParams.limb_release > 0, colliders and limbs present), or None."""
    if not params.limb_release or colliders is None or not (colliders.hulls or colliders.spheres):
        return None
    from stages.rig.humanoid import limb_joint_sets
    limbs = sorted(set().union(*limb_joint_sets(character).values()))
    r = LimbRelease(garments, sysm.offsets, sysm.inv_mass, colliders, owner, limbs, sysm.contact, params.limb_release)
    return r if r.active else None
