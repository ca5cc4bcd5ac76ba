"""The cloth x cloth phase as the simulation's step loop runs it (stages.sim.step, its `cc` argument):
`swept` (stages.sim.cloth_contact.kernels, the default) or `offset` (stages.sim.cloth_contact.offset);
garments that start interpenetrating are sorted by the swept phase's layer rule either way."""
from __future__ import annotations

import numpy as np

from stages.checks import ContractError
from stages.sim.cloth_contact import kernels as CK
from stages.sim.cloth_contact import offset as OF
from stages.sim.cloth_contact.setup import (DEFAULT_MOTION, DEFAULT_ROTATION, KEEP_REACH, SETTLE_FRAMES,
                                            build_cloth_contact, outward_signs)


METHODS = ("swept", "offset")


class ClothPhase:
    """The cloth x cloth phase as the simulation's step loop runs it (stages.sim.step, `cc` argument).

    Built once per simulate() call from the concatenated garments (relative frame at frame 0):
    x (N, 3), triangles (T, 3) global ids, offsets (G + 1,), cinv (N,) inverse masses with attached
    particles 0 (never moved by this phase), layers (G,) 0 = innermost, body_points (V, 3) the skin at
    frame 0 (which way each garment faces), thickness m, every: sub-steps per call,
    layer_depth0 m: the sorting depth of `first`, the tuple simulate() runs SETTLE_FRAMES frames at
    the frame-0 pose with before frame 1 (garments that start interpenetrating, sorted by the
    layers' rule); `rest`: the tuple of every simulated frame, without the layers' rule (every
    pair keeps its side: the settled order is kept). method: 'offset' (`rest` is then the offset
    phase's state, stages.sim.cloth_contact.offset) or 'swept'. exclude: (N,) uint64 exclusion
    zones or None (ClothContact.exclude; the swept phase only).
    """

    def __init__(self, x, triangles, offsets, cinv, layers, body_points, thickness: float, every: int,
                 layer_depth0: float, motion_margin: float | None = None, method: str = "swept", exclude=None):
        if method not in METHODS:
            raise ContractError(f"ClothPhase: method: expected one of {', '.join(METHODS)}, got {method!r}")
        if method != "swept" and exclude is not None and np.any(exclude):
            raise ContractError("ClothPhase: exclusion zones (a garment's contact_zones) need the swept method")
        g = len(offsets) - 1
        tri_garment = (np.searchsorted(np.asarray(offsets), np.asarray(triangles)[:, 0], side="right") - 1)
        outward = (outward_signs(x, triangles, tri_garment, g, body_points) if body_points is not None
                   and body_points.shape[0] else np.ones(g))
        self.cc = build_cloth_contact(x, triangles, offsets, layers=layers, outward=outward, thickness=thickness,
                                      layer_depth=max(layer_depth0, thickness),
                                      motion_margin=DEFAULT_MOTION if motion_margin is None else motion_margin,
                                      rotation=DEFAULT_ROTATION, exclude=exclude)
        topo, tree, work, prm = self.cc.kernel_args()
        self.counters = np.zeros(CK.N_COUNTERS, np.int64)
        self.settled = np.zeros(CK.N_COUNTERS, np.int64)   # the counters after the settling frames
        n = x.shape[0]
        self.x_start = np.zeros((n, 3))
        self.x_before = np.zeros((n, 3))
        self.cinv = np.ascontiguousarray(cinv, np.float64)
        # sorting garments that start interpenetrating: the tree search (candidate lists as deep
        # as layer_depth0 would hold most of the two garments), without the normal-cone culling:
        # the sorting pushes slide parts of one garment over others (its free hem), which a cone
        # test without Volino's contour test misses (settling frames left 2-6 skirt edges through
        # the skirt on the skinned balls, kept ever after by the fail-safe)
        first = (prm[0], prm[1], prm[2], prm[3], False, 0.0, prm[6])
        # culling only with a call every sub-step: the cone test has no contour test, and over sweeps of
        # several sub-steps it missed folds (bvh_walk at 5: 3 + 6 crossing edges left unseen, 0 without it)
        rest = (prm[0], float(thickness), prm[2], prm[3], prm[4] and int(every) == 1, prm[5], prm[6])
        # the layers' rule (a pair ending within the layer depth of the side the layers prescribe is
        # put on that side, stages.sim.cloth_contact.ccd) sorts garments that start interpenetrating:
        # the settling frames only. From frame 1 on every pair keeps the side it starts the step on
        # (`rest` sees one layer), so the order the settling made is kept by the continuous test
        # alone. Forcing a side there pushed single vertices through the other garment wherever part
        # of one had gone round the other's edge (a T-shirt fold over the shorts' waistband, a hand
        # pressing the T-shirt into the trousers), crossings the phase then guarded as if right and
        # its fail-safe fought (2026-11-24: bvh_walk 665 -> 0 particles reverted, 7 -> 0 crossings
        # left; CesiumMan's outfit 20,669 -> 251 and 39 -> 0, 44 -> 0 edges through the other garment)
        one_layer = topo[:8] + (np.zeros_like(topo[8]),) + topo[9:]
        cap = work[2].shape[0]
        self.keep = (np.zeros(n, np.uint8), np.zeros(n, np.uint8), np.zeros(0, np.int8), np.zeros((0, 2), np.int32),
                     np.zeros((cap, 4), np.int32), np.zeros((cap, 4)), np.zeros((cap, 3)), np.zeros(1, np.int64),
                     np.array([KEEP_REACH * thickness]))
        # the settling frames call the phase every sub-step whatever `every` (sorting garments that start
        # through each other takes many calls; CesiumMan's outfit at every 5: 5 edges between them left)
        self.first = (self.x_start, self.x_before, self.cinv, topo, tree, work, first, self.counters, 1, self.keep)
        self.rest = (self.x_start, self.x_before, self.cinv, one_layer, tree, work, rest, self.counters, int(every),
                     self.keep)
        self.settle_frames = SETTLE_FRAMES
        self.method = method
        self.offset = None
        if method == "offset":
            self.offset = OF.offset_state(x, triangles, self.cinv, thickness, int(every))
            self.rest = self.offset
            self.offset_settled = np.zeros(OF.N_OFFSET_COUNTERS, np.int64)

    def mark_settled(self) -> None:
        """The counters so far belong to the settling frames (summary()'s `frames` leaves them out)."""
        self.settled[:] = self.counters
        if self.offset is not None:
            self.offset_settled[:] = self.offset[4]

    @classmethod
    def for_simulation(cls, sysm, layers, params, character, motion) -> "ClothPhase":
        """The phase of simulate()'s particle system `sysm` (stages.sim.simulate._System); layers
        (G,) or None (the garments' order); params: SimParams (cloth_thickness, cloth_contact_every,
        cloth_layer_depth0)."""
        g = len(sysm.names)
        layers = np.arange(g) if layers is None else np.asarray(layers)
        if layers.shape != (g,):
            raise ContractError(f"simulate: layers: expected one per garment ({g}), got {layers.tolist()}")
        body = None
        if character.triangles.shape[0] > 0:
            from stages.rig.skinning import skin
            body = skin(character, motion, frames=[0])[0]
        cinv = np.where(sysm.attach_joint >= 0, 0.0, sysm.inv_mass)
        return cls(sysm.x, sysm.tris, sysm.offsets, cinv, layers, body, params.cloth_thickness,
                   params.contact_steps(), params.cloth_layer_depth0, method=params.cloth_contact,
                   exclude=sysm.contact_zones)

    def settle(self, cloth, cols, m, prm, gravity, wind, fwd0, inv0, substeps, max_speed2, goff, flags,
               floor0=None) -> None:
        """SETTLE_FRAMES frames of the step loop at the frame-0 pose (fwd0 / inv0 (J, 4, 4)) with the
        sorting depth (`first`), not recorded; then xp = x (the sorting moves are not velocity); the
        offset phase's query reruns at the sorted positions. The other arguments are simulate()'s
        run_frames arguments, floor0 the floor's height at that pose (stages.sim.settle.hold_pose)."""
        from stages.sim.settle import hold_pose
        hold_pose(cloth, cols, m, prm, self.settle_frames, gravity, wind, fwd0, inv0, substeps, max_speed2, goff,
                  flags, self.first, floor0)
        if self.offset is not None:
            OF.query(cloth[0], self.offset)
        self.mark_settled()

    def summary(self) -> dict:
        """Counters summed over the run, settling frames included (see stages.sim.cloth_contact.kernels
        N_*); `frames`: the CPU cycles of the recorded frames' calls alone (builds: full list builds and
        in-place updates; detect; respond; failsafe), and their builds."""
        c = self.counters
        f = c - self.settled
        out = {"contacts": int(c[CK.N_CONTACTS]), "corrected": int(c[CK.N_CORRECTED]),
                "unresolved": int(c[CK.N_UNRESOLVED]), "reverted": int(c[CK.N_REVERTED]),
                "left": int(c[CK.N_LEFT]), "rounds": int(c[CK.N_ROUNDS]), "node_pairs": int(c[CK.N_NODE_PAIRS]),
                "tests": int(c[CK.N_TESTS]), "overflow": int(c[CK.N_OVERFLOW]),
                "candidate_builds": int(c[CK.N_BUILDS]), "candidate_overflow": int(c[CK.N_CAND_OVERFLOW]),
                "cycles_build": int(c[CK.N_CYC_BUILD]), "cycles_detect": int(c[CK.N_CYC_DETECT]),
                "cycles_respond": int(c[CK.N_CYC_RESPOND]), "cycles_failsafe": int(c[CK.N_CYC_FAILSAFE]),
                "candidate_updates": int(c[CK.N_LOCAL]),
                "invalid_move": int(c[CK.N_INVALID_MOVE]), "invalid_turn": int(c[CK.N_INVALID_TURN]),
                "frames": {"cycles_build": int(f[CK.N_CYC_BUILD]), "cycles_detect": int(f[CK.N_CYC_DETECT]),
                           "cycles_respond": int(f[CK.N_CYC_RESPOND]), "cycles_failsafe": int(f[CK.N_CYC_FAILSAFE]),
                           "candidate_builds": int(f[CK.N_BUILDS]), "candidate_updates": int(f[CK.N_LOCAL])},
                "layers": [int(v) for v in self.cc.garment_layer],
                "outward": [int(v) for v in self.cc.garment_outward], "method": self.method}
        if self.offset is not None:    # the figures of the offset phase's calls (the swept one sorted only)
            o = self.offset[4]
            fo = o - self.offset_settled
            out["offset"] = OF.offset_summary(o)
            out["frames"] = {"cycles_build": int(fo[OF.O_CYC_QUERY]), "cycles_detect": int(fo[OF.O_CYC_CHECK]),
                             "cycles_respond": int(fo[OF.O_CYC_RESPOND]), "cycles_failsafe": 0,
                             "candidate_builds": int(fo[OF.O_QUERIES]), "candidate_updates": 0}
        return out
