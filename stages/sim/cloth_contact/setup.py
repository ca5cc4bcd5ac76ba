"""Cloth x cloth collision (garment-garment and self) as a self-contained phase of the step loop.

Setup (Python, once per scene) builds a `ClothContact`: topology (edges, feature ownership), one k-DOP
tree per garment over its triangles (paper B; stages.geometry.kdop builds and refits it), work
buffers. The phase itself is one numba call over flat arrays, `collide_cloth` in
stages.sim.cloth_contact.kernels (exact tests in stages.sim.cloth_contact.ccd).

How the step loop uses it (stages.sim.step.run_steps / run_frames; `ClothPhase` below builds the tuples)
--------------------------------------------------------------------
Once per scene, with the simulation's concatenated garments (System.x, System.tris, System.offsets):

    cc = build_cloth_contact(x, tris, offsets, layers=[layer of each garment], thickness=0.003,
                             outward=outward_signs(x, tris, tri_garment, G, body_vertices),
                             motion_margin=DEFAULT_MOTION)   # 0: the tree search every round
    topo, tree, work, prm = cc.kernel_args()      # tuples of arrays + (thickness, layer_depth,
                                                  #  rounds, failsafe_rounds, cull, motion_margin,
                                                  #  rotation): pass them into run_frames next to
                                                  #  `cloth` / `cols`
    x_start = np.empty_like(x); counters = np.zeros(N_COUNTERS, np.int64)

Phase order: forces, Verlet, springs and tethers, body colliders, obstacles, then cloth-cloth LAST,
so the positions a frame records are the ones this phase checked (a later phase could push cloth
back through cloth). Either

- once per sub-step (recommended): `x_start[:] = x` before integrate, `collide_cloth(...)` after the
  obstacles; the correction becomes Verlet velocity like every other position correction; or
- once every k sub-steps (SimParams.cloth_contact_every; stages.sim.step.cloth_phase): `x_start[:] = x`
  at the first; after the k-th `x_before[:] = x; collide_cloth(x_start, x, ..., keep)` then
  `contact_velocity(x_before, x, xp, work[1])` (else the correction would enter the next sub-step as
  a velocity of correction / dt_sub). `keep` holds the pairs the call found within KEEP_REACH
  thicknesses; the sub-steps in between project them again. Without that a layer resting on another
  falls into the gap between calls (5.4 mm in a 1/30 s frame, past a 3-4 mm gap) and every call
  starts from crossings the rounds cannot all undo.

x_start must be free of cloth crossings (the fail-safe reverts to it): true from the first frame on
if the garments start apart; garments that start interpenetrating are sorted by the layer rule up
to `layer_depth` deep (prm[1] may be raised for the first frames only). The simulation applies the
layer rule in those settling frames only (`ClothPhase`): afterwards each pair keeps its side.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stages.checks import ContractError, check_array, check_index, check_positive
from stages.geometry.kdop import DEFAULT_K, KdopTree, build_tree, kdop_directions, merge_forest, triangle_bounds
from stages.sim.cloth_contact import kernels as CK
from stages.sim.cloth_contact import narrow as CN
from stages.sim.cloth_contact.cull import node_borders, patch_nodes

DEFAULT_THICKNESS = 0.003  # m: about two layers of shirt fabric
DEFAULT_MOTION = 0.003     # m: how far particles may move before the candidate lists are rebuilt (0.005 -> 0.003:
                           # fewer candidates per detection for more builds, 5-10 % less CPU per call on the shipped walk)
DEFAULT_ROTATION = 1.2     # rad: the most a normal may turn before they are rebuilt (less where a culled
                           # patch would stop being flat; below arccos(FLAT_COS))
KEEP_REACH = 2.0           # calls every few sub-steps keep the pairs within this many thicknesses (step.cloth_phase)
SETTLE_FRAMES = 3          # frames at the frame-0 pose before frame 1 that sort garments starting interpenetrating


@dataclass(frozen=True)
class ClothContact:
    """Everything `collide_cloth` needs, as flat arrays (world frame, metres).

    N particles (all garments concatenated, garment g = particles garment_offsets[g]..[g+1]),
    T triangles, E edges, G garments, h = k/2 k-DOP directions, n = 2T - G tree nodes (one tree
    per garment with triangles). Bounds are world frame, metres, over the current call's step.

    triangles: (T, 3) int32, global particle ids, each within one garment.
    edges: (E, 2) int32, the unique triangle edges, i < j, sorted.
    tri_edges: (T, 3) int32, edge id of triangle t's edge k = (triangles[t, k], triangles[t, (k+1) % 3]).
    tri_owns: (T,) uint8, bit k (0-2): t owns its corner vertex k; bit 3 + k: t owns its edge k. Each
      vertex and edge has exactly one owner, its lowest-numbered triangle; a triangle pair tests only
      the features it owns, so each feature pair is tested once.
    edge_tris: (E, 2) int32, the (one or two) triangles of an edge, -1 for none.
    particle_garment (N,), tri_garment (T,), edge_garment (E,): int32 garment ids.
    garment_layer: (G,) int32, 0 = innermost; garments of different layers keep their order.
    garment_outward: (G,) float64, +1 if the garment's triangle normals (b-a) x (c-a) point away
      from the body, -1 if they point towards it.
    tree: KdopTree forest, one tree per garment over its triangles (leaf_prim = global triangle id),
      topology from the setup positions; node_min/node_max are refit in place on every call.
    Traversal work arrays:
      node_dirty (n,) uint8: a particle of the node moved since the last detection;
      tri_min / tri_max (T, h) float64: each triangle's k-DOP over the step, inflated;
      pt_min / pt_max (N, h) float64: each particle's swept k-DOP, inflated alike;
      nrm_min / nrm_max (n, h) float64: bounds of the node's unit normals projected on the directions;
      node_patch (n,) uint8: 1 if the node's triangles are one patch of one garment (connected
        through shared vertices); fixed at setup;
      axis_order (h,) int32: the order the directions are tested in;
      stack (S, 2) int32: node pairs still to visit.
    moved, corrected: (N,) uint8 work flags.
    c_kind (C,) int8, c_feat (C, 2) int32, c_idx (C, 4) int32, c_w (C, 4) float64, c_dir (C, 3)
      float64: the contact buffer (capacity C); after a call it holds the last detection's contacts.
    thickness: m > 0, the distance kept between cloth layers (and the proximity band).
    layer_depth: m >= thickness, how deep an outer-layer feature may start inside an inner garment and
      still be pushed out (deeper pairs keep their side: the far side of the body is not "inside").
    rounds: >= 1 response rounds; failsafe_rounds: >= 1 revert rounds.
    cull: normal-cone culling of flat patches in the self test (off: every pair is tested, as the
      brute-force reference does).
    Candidate lists (motion_margin > 0; stages.sim.cloth_contact.kernels.find_contacts): the tree
      search runs once for as many steps as every particle stays within motion_margin (m) of the
      box it spanned at the build and every normal within what keeps the culled patches flat (at
      most `rotation` rad) of its direction then;
      each step tests only the listed pairs. cand_vf (Cv, 2) int32 (particle, triangle), cand_ee
      (Ce, 2) int32 (edge, edge), cand_n (6,) int64 (VF count, EE count, overflowed, valid, detections since the build,
      builds left without culling),
      cand_f (2,) float64 (margin, motion built with), box_lo / box_hi (N, 4) (the boxes, and in
      box_lo[:, 3] how far each particle may move: motion_margin or more when it moves fast), nrm_ref
      (T, 4) (unit normals, cosine of the allowed turn), node_slack (n,) (the culled nodes' turn margins).
    The narrow phase's filter over the lists (stages.sim.cloth_contact.narrow): pbox (N, 8), ebox (E, 8),
      tbox (T, 8) float32 (min x y z, 0, max x y z, 0): each particle's, edge's and
      triangle's swept box, inflated, rounded outwards; p_move (N,) float64: each particle's move;
      feat_moved (E + T,) uint8: the edges' then the triangles' moved flags; pdiag (N, 2 D) float32
      (D = DIAG_LANES: the k-DOP's directions beyond the axes, minima then maxima, padded with 0).
    Lists updated in place when a few particles leave their boxes (stages.sim.cloth_contact.local):
      loc_list (L,) int32 those particles, loc_n (2,) int64 (their count, 1: a full build instead),
      vt_start (N + 1,) int64 / vt_tri (3T,) int32 each particle's triangles, ring (T,) int32 and
      flag (N + T,) uint8 work arrays (flags zero between calls), bld_min / bld_max (N, h) the
      particles' bounds the lists were made with, parent (n,) int32 each node's parent (-1: a root),
      tri_leaf (T,) int32 each triangle's leaf, self_cull (n,) uint8 the nodes the last build culled
      as one flat patch.
    exclude: (N,) uint64 exclusion zones, a bit per zone: a vertex-face or edge-edge pair whose two
      features have particles sharing a bit is not tested (all zero: every pair is). The sewing's
      zones are the cloth either side of a seam, which the seam springs pull together
      (stages.garments.sewing.seam_zones). The swept phase only.
    """

    triangles: np.ndarray
    edges: np.ndarray
    tri_edges: np.ndarray
    tri_owns: np.ndarray
    edge_tris: np.ndarray
    particle_garment: np.ndarray
    tri_garment: np.ndarray
    edge_garment: np.ndarray
    garment_layer: np.ndarray
    garment_outward: np.ndarray
    tree: KdopTree
    node_dirty: np.ndarray
    tri_min: np.ndarray
    tri_max: np.ndarray
    pt_min: np.ndarray
    pt_max: np.ndarray
    nrm_min: np.ndarray
    nrm_max: np.ndarray
    node_patch: np.ndarray
    border_start: np.ndarray
    border_vert: np.ndarray
    axis_order: np.ndarray
    stack: np.ndarray
    moved: np.ndarray
    corrected: np.ndarray
    c_kind: np.ndarray
    c_feat: np.ndarray
    c_idx: np.ndarray
    c_w: np.ndarray
    c_dir: np.ndarray
    cand_vf: np.ndarray
    cand_ee: np.ndarray
    cand_n: np.ndarray
    cand_f: np.ndarray
    box_lo: np.ndarray
    box_hi: np.ndarray
    nrm_ref: np.ndarray
    node_slack: np.ndarray
    pbox: np.ndarray
    ebox: np.ndarray
    tbox: np.ndarray
    p_move: np.ndarray
    feat_moved: np.ndarray
    loc_list: np.ndarray
    loc_n: np.ndarray
    vt_start: np.ndarray
    vt_tri: np.ndarray
    ring: np.ndarray
    flag: np.ndarray
    bld_min: np.ndarray
    bld_max: np.ndarray
    parent: np.ndarray
    tri_leaf: np.ndarray
    self_cull: np.ndarray
    pdiag: np.ndarray
    exclude: np.ndarray
    thickness: float = DEFAULT_THICKNESS
    layer_depth: float = DEFAULT_THICKNESS
    rounds: int = 4
    failsafe_rounds: int = 8
    cull: bool = True
    motion_margin: float = 0.0
    rotation: float = DEFAULT_ROTATION

    def __post_init__(self):
        o = "ClothContact"
        f = check_array(o, "triangles", self.triangles, (None, 3), np.int32)
        e = check_array(o, "edges", self.edges, (None, 2), np.int32)
        t, ne = f.shape[0], e.shape[0]
        n = check_array(o, "particle_garment", self.particle_garment, (None,), np.int32).shape[0]
        g = check_array(o, "garment_layer", self.garment_layer, (None,), np.int32).shape[0]
        check_index(o, "triangles", f, n)
        check_index(o, "edges", e, n)
        if ne and not np.all(e[:, 0] < e[:, 1]):
            raise ContractError(f"{o}.edges: expected i < j in every row")
        check_index(o, "tri_edges", check_array(o, "tri_edges", self.tri_edges, (t, 3), np.int32), ne)
        owns = check_array(o, "tri_owns", self.tri_owns, (t,), np.uint8)
        check_index(o, "edge_tris", check_array(o, "edge_tris", self.edge_tris, (ne, 2), np.int32), t, allow=-1)
        check_index(o, "particle_garment", self.particle_garment, g)
        check_index(o, "tri_garment", check_array(o, "tri_garment", self.tri_garment, (t,), np.int32), g)
        check_index(o, "edge_garment", check_array(o, "edge_garment", self.edge_garment, (ne,), np.int32), g)
        out = check_array(o, "garment_outward", self.garment_outward, (g,), np.float64)
        if not np.all(np.abs(out) == 1.0):
            raise ContractError(f"{o}.garment_outward: expected +1 or -1 per garment")
        # every used vertex and every edge owned exactly once
        vcount = np.zeros(n, np.int64)
        ecount = np.zeros(ne, np.int64)
        for k in range(3):
            np.add.at(vcount, f[:, k], (owns >> k) & 1)
            np.add.at(ecount, self.tri_edges[:, k], (owns >> (3 + k)) & 1)
        used = np.zeros(n, bool)
        used[f.ravel()] = True
        if not (np.all(vcount[used] == 1) and np.all(vcount[~used] == 0) and np.all(ecount == 1)):
            raise ContractError(f"{o}.tri_owns: every vertex and edge needs exactly one owner triangle")
        nn = self.tree.node_min.shape[0]
        h = self.tree.directions.shape[0]
        if sorted(self.tree.leaf_prim[self.tree.leaf_prim >= 0].tolist()) != list(range(t)):
            raise ContractError(f"{o}.tree: expected one leaf per triangle")
        roots = self.tree.tree_offsets[:-1]
        if not all(len(set(self.tri_garment[self._leaves(r)].tolist())) == 1 for r in roots):
            raise ContractError(f"{o}.tree: expected one tree per garment (a forest)")
        check_array(o, "node_dirty", self.node_dirty, (nn,), np.uint8)
        check_array(o, "tri_min", self.tri_min, (t, h), np.float64)
        check_array(o, "tri_max", self.tri_max, (t, h), np.float64)
        check_array(o, "pt_min", self.pt_min, (n, h), np.float64, finite=False)
        check_array(o, "pt_max", self.pt_max, (n, h), np.float64, finite=False)
        check_array(o, "nrm_min", self.nrm_min, (nn, h), np.float64, finite=False)
        check_array(o, "nrm_max", self.nrm_max, (nn, h), np.float64, finite=False)
        check_array(o, "node_patch", self.node_patch, (nn,), np.uint8)
        bs = check_array(o, "border_start", self.border_start, (nn + 1,), np.int64)
        bv = check_array(o, "border_vert", self.border_vert, (None,), np.int32)
        if bs[0] != 0 or bs[-1] != bv.shape[0] or np.any(np.diff(bs) < 0):
            raise ContractError(f"{o}.border_start: expected offsets rising from 0 to {bv.shape[0]}")
        ao = check_array(o, "axis_order", self.axis_order, (h,), np.int32)
        if sorted(ao.tolist()) != list(range(h)):
            raise ContractError(f"{o}.axis_order: expected a permutation of 0..{h - 1}")
        st = check_array(o, "stack", self.stack, (None, 2), np.int32)
        need = 8 * self.tree.max_depth + 32 + self.tree.n_trees ** 2
        if st.shape[0] < need:
            raise ContractError(f"{o}.stack: needs >= 8 * max_depth + 32 + trees^2 = {need} rows, got {st.shape[0]}")
        check_array(o, "moved", self.moved, (n,), np.uint8)
        check_array(o, "corrected", self.corrected, (n,), np.uint8)
        c = check_array(o, "c_kind", self.c_kind, (None,), np.int8).shape[0]
        check_array(o, "c_feat", self.c_feat, (c, 2), np.int32)
        check_array(o, "c_idx", self.c_idx, (c, 4), np.int32)
        check_array(o, "c_w", self.c_w, (c, 4), np.float64, finite=False)
        check_array(o, "c_dir", self.c_dir, (c, 3), np.float64, finite=False)
        cv = check_array(o, "cand_vf", self.cand_vf, (None, 2), np.int32)
        check_array(o, "cand_ee", self.cand_ee, (cv.shape[0], 2), np.int32)
        check_array(o, "cand_n", self.cand_n, (6,), np.int64)
        check_array(o, "cand_f", self.cand_f, (2,), np.float64)
        check_array(o, "box_lo", self.box_lo, (n, 4), np.float64, finite=False)
        check_array(o, "box_hi", self.box_hi, (n, 4), np.float64, finite=False)
        check_array(o, "nrm_ref", self.nrm_ref, (t, 4), np.float64, finite=False)
        check_array(o, "node_slack", self.node_slack, (nn,), np.float64, finite=False)
        check_array(o, "pbox", self.pbox, (n, 8), np.float32, finite=False)
        check_array(o, "ebox", self.ebox, (ne, 8), np.float32, finite=False)
        check_array(o, "tbox", self.tbox, (t, 8), np.float32, finite=False)
        check_array(o, "p_move", self.p_move, (n,), np.float64, finite=False)
        check_array(o, "feat_moved", self.feat_moved, (ne + t,), np.uint8)
        check_array(o, "loc_list", self.loc_list, (None,), np.int32)
        check_array(o, "loc_n", self.loc_n, (2,), np.int64)
        vs = check_array(o, "vt_start", self.vt_start, (n + 1,), np.int64)
        vt = check_array(o, "vt_tri", self.vt_tri, (3 * t,), np.int32)
        if vs[0] != 0 or vs[-1] != 3 * t or np.any(np.diff(vs) < 0):
            raise ContractError(f"{o}.vt_start: expected offsets rising from 0 to {3 * t}")
        check_index(o, "vt_tri", vt, t)
        check_array(o, "ring", self.ring, (t,), np.int32)
        check_array(o, "flag", self.flag, (n + t,), np.uint8)
        check_array(o, "bld_min", self.bld_min, (n, h), np.float64, finite=False)
        check_array(o, "bld_max", self.bld_max, (n, h), np.float64, finite=False)
        check_index(o, "parent", check_array(o, "parent", self.parent, (nn,), np.int32), nn, allow=-1)
        check_index(o, "tri_leaf", check_array(o, "tri_leaf", self.tri_leaf, (t,), np.int32), nn)
        check_array(o, "self_cull", self.self_cull, (nn,), np.uint8)
        if h - 3 > CN.DIAG_LANES:
            raise ContractError(f"{o}: at most {CN.DIAG_LANES + 3} k-DOP directions (pdiag's lanes), got {h}")
        check_array(o, "pdiag", self.pdiag, (n, 2 * CN.DIAG_LANES), np.float32, finite=False)
        check_array(o, "exclude", self.exclude, (n,), np.uint64)
        if not (float(self.motion_margin) >= 0.0 and 0.0 < float(self.rotation) < float(np.arccos(CK.FLAT_COS))):
            raise ContractError(f"{o}: motion_margin must be >= 0 and rotation in (0, {np.arccos(CK.FLAT_COS):.3f}) rad, "
                                f"got {self.motion_margin}, {self.rotation}")
        check_positive(o, "thickness", float(self.thickness))
        if not float(self.layer_depth) >= float(self.thickness):
            raise ContractError(f"{o}.layer_depth: expected >= thickness ({self.thickness}), got {self.layer_depth}")
        if int(self.rounds) < 1 or int(self.failsafe_rounds) < 1:
            raise ContractError(f"{o}: rounds and failsafe_rounds must be >= 1")

    def _unzoned(self, n: int) -> int:
        """The first n contacts of the buffer less the pairs sharing an exclusion zone (kept in order,
        compacted); their new count."""
        if not self.exclude.any():
            return n
        idx = self.c_idx[:n]
        vf = (self.c_kind[:n] == CK.VF_NEAR) | (self.c_kind[:n] == CK.VF_CROSS)   # c_idx: (p, a, b, c) or (a, b, c, d)
        z = self.exclude
        a = np.where(vf, z[idx[:, 0]], z[idx[:, 0]] | z[idx[:, 1]])
        b = np.where(vf, z[idx[:, 1]] | z[idx[:, 2]] | z[idx[:, 3]], z[idx[:, 2]] | z[idx[:, 3]])
        keep = np.flatnonzero((a & b) == 0)
        for arr in (self.c_kind, self.c_feat, self.c_idx, self.c_w, self.c_dir):
            arr[:keep.size] = arr[keep]
        return int(keep.size)

    def _leaves(self, root: int) -> np.ndarray:
        lo = int(root)
        hi = int(self.tree.tree_offsets[np.searchsorted(self.tree.tree_offsets, lo, side="right")])
        lp = self.tree.leaf_prim[lo:hi]
        return lp[lp >= 0]

    @property
    def n_particles(self) -> int:
        return self.particle_garment.shape[0]

    def kernel_args(self) -> tuple:
        """(topo, tree, work, prm): the tuples `collide_cloth` takes after x_prev, x, inv_mass."""
        tr = self.tree
        topo = (self.triangles, self.edges, self.tri_edges, self.tri_owns, self.edge_tris, self.particle_garment,
                self.tri_garment, self.edge_garment, self.garment_layer, self.garment_outward)
        tree = (tr.directions, self.axis_order, tr.tree_offsets, tr.node_min, tr.node_max, tr.children, tr.leaf_prim,
                self.node_dirty, self.tri_min, self.tri_max, self.pt_min, self.pt_max, self.nrm_min, self.nrm_max,
                self.node_patch, self.stack, self.border_start, self.border_vert, self.cand_vf, self.cand_ee,
                self.cand_n, self.cand_f, self.box_lo, self.box_hi, self.nrm_ref, self.node_slack,
                self.pbox, self.ebox, self.tbox, self.p_move, self.feat_moved, self.loc_list, self.loc_n,
                self.vt_start, self.vt_tri, self.ring, self.flag, self.bld_min, self.bld_max, self.parent,
                self.tri_leaf, self.self_cull, self.pdiag, self.exclude)
        work = (self.moved, self.corrected, self.c_kind, self.c_feat, self.c_idx, self.c_w, self.c_dir)
        prm = (float(self.thickness), float(self.layer_depth), int(self.rounds), int(self.failsafe_rounds),
               bool(self.cull), float(self.motion_margin), float(self.rotation))
        return topo, tree, work, prm

    def collide(self, x_prev: np.ndarray, x: np.ndarray, inv_mass: np.ndarray,
                counters: np.ndarray | None = None) -> np.ndarray:
        """Python convenience: one call of `collide_cloth` (x corrected in place). Returns counters."""
        if counters is None:
            counters = np.zeros(CK.N_COUNTERS, np.int64)
        CK.collide_cloth(x_prev, x, inv_mass, *self.kernel_args(), counters)
        return counters

    def contacts(self, x_prev: np.ndarray, x: np.ndarray, only_cross: bool = False,
                 brute_force: bool = False, counters: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Detection only (no response): (kind (m,) int8, feature pair (m, 2) int32: VF (particle,
        triangle), EE (edge, edge) lower id first) of every contact between x_prev and x, sorted; as
        collide_cloth finds them (the tree search, or the candidate lists kept from earlier calls
        with motion_margin > 0; with this object's `cull`) or by brute force over all pairs.
        counters (N_COUNTERS,) int64: accumulated if given."""
        topo, tree, work, prm = self.kernel_args()
        if counters is None:
            counters = np.zeros(CK.N_COUNTERS, np.int64)
        dropped = counters[CK.N_OVERFLOW]
        if brute_force:
            n = CK.brute_force_contacts(x_prev, x, topo, prm[0], prm[1], only_cross, work, counters)
            n = self._unzoned(n)
        else:
            self.moved[:] = 1
            n = CK.find_contacts(x_prev, x, topo, tree, work, prm, only_cross, counters)
        if counters[CK.N_OVERFLOW] != dropped:
            raise ContractError(f"ClothContact.contacts: contact buffer of {self.c_kind.shape[0]} overflowed")
        kind = self.c_kind[:n].copy()
        feat = self.c_feat[:n].copy()
        order = np.lexsort((feat[:, 1], feat[:, 0], kind))
        return kind[order], feat[order]


def mesh_edges(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(edges (E, 2) i < j sorted, tri_edges (T, 3), edge_tris (E, 2) -1 padded) of a triangle mesh."""
    t = triangles.shape[0]
    pairs = np.stack([triangles, np.roll(triangles, -1, axis=1)], axis=2).reshape(-1, 2)
    key = np.sort(pairs, axis=1)
    edges, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    tri_edges = inverse.reshape(t, 3).astype(np.int32)
    edge_tris = np.full((edges.shape[0], 2), -1, np.int32)
    tri_of = np.repeat(np.arange(t, dtype=np.int32), 3)
    order = np.argsort(inverse, kind="stable")
    slot = np.zeros(edges.shape[0], np.int64)
    for r in order:  # first two triangles of each edge (a non-manifold third is not kept)
        e = inverse[r]
        if slot[e] < 2:
            edge_tris[e, slot[e]] = tri_of[r]
        slot[e] += 1
    return edges.astype(np.int32), tri_edges, edge_tris


def feature_owners(triangles: np.ndarray, tri_edges: np.ndarray, n_particles: int,
                   n_edges: int) -> np.ndarray:
    """(T,) uint8 ownership bits: each vertex / edge is owned by its lowest-numbered triangle."""
    t = triangles.shape[0]
    vown = np.full(n_particles, t, np.int64)
    eown = np.full(n_edges, t, np.int64)
    rows = np.arange(t)
    for k in range(3):
        np.minimum.at(vown, triangles[:, k], rows)
        np.minimum.at(eown, tri_edges[:, k], rows)
    owns = np.zeros(t, np.uint8)
    for k in range(3):
        owns |= ((vown[triangles[:, k]] == rows).astype(np.uint8) << k)
    # a triangle could list one vertex twice only if degenerate; the builders drop those
    for k in range(3):
        owns |= ((eown[tri_edges[:, k]] == rows).astype(np.uint8) << (3 + k))
    return owns


def outward_signs(x: np.ndarray, triangles: np.ndarray, tri_garment: np.ndarray, n_garments: int,
                  body_points: np.ndarray) -> np.ndarray:
    """(G,) float64 +-1: whether each garment's normals point away from the body, by an area vote of
    n . (centroid - nearest body point) over its triangles."""
    from scipy.spatial import cKDTree

    v = x[triangles]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    cen = v.mean(axis=1)
    _, idx = cKDTree(body_points).query(cen)
    vote = np.einsum("ij,ij->i", n, cen - body_points[idx])
    s = np.bincount(tri_garment, weights=vote, minlength=n_garments)
    return np.where(s >= 0.0, 1.0, -1.0)


def _parents(children: np.ndarray) -> np.ndarray:
    """(n,) int32 each node's parent, -1 at a root."""
    par = np.full(children.shape[0], -1, np.int32)
    inner = np.nonzero(children[:, 0] >= 0)[0]
    par[children[inner, 0]] = inner
    par[children[inner, 1]] = inner
    return par


def _tri_leaves(leaf_prim: np.ndarray, t: int) -> np.ndarray:
    """(T,) int32 the leaf node of each triangle."""
    leaf = np.zeros(t, np.int32)
    nodes = np.nonzero(leaf_prim >= 0)[0]
    leaf[leaf_prim[nodes]] = nodes
    return leaf


def build_cloth_contact(x: np.ndarray, triangles: np.ndarray, garment_offsets, layers=None, outward=None,
                        thickness: float = DEFAULT_THICKNESS, layer_depth: float | None = None,
                        k: int = DEFAULT_K, rounds: int = 4, failsafe_rounds: int = 8, cull: bool = True,
                        contact_capacity: int | None = None, motion_margin: float = 0.0,
                        rotation: float = DEFAULT_ROTATION, candidate_capacity: int | None = None,
                        exclude=None) -> ClothContact:
    """The cloth contact phase for garments concatenated as in the simulation.

    x: (N, 3) float64 positions (world, m) the tree topology is built from (the setup pose).
    triangles: (T, 3) int global particle ids. garment_offsets: (G + 1,) garment g owns particles
    [off[g], off[g+1]). layers: (G,) int, 0 innermost (default all 0: no layer order). outward: (G,)
    +-1 (default +1, see `outward_signs`). layer_depth: default = thickness (raise it
    for the first frames of a scene whose garments start interpenetrating deeper). exclude: (N,)
    uint64 exclusion zones (ClothContact.exclude; default none).
    """
    x = np.ascontiguousarray(x, np.float64)
    tris = np.ascontiguousarray(triangles, np.int32)
    off = np.asarray(garment_offsets, np.int64)
    g = off.size - 1
    n = x.shape[0]
    if g < 1 or off[0] != 0 or off[-1] != n or np.any(np.diff(off) < 0):
        raise ContractError(f"build_cloth_contact: garment_offsets must rise from 0 to {n}, got {off.tolist()}")
    if tris.shape[0] == 0:
        raise ContractError("build_cloth_contact: needs at least one triangle")
    particle_garment = (np.searchsorted(off, np.arange(n), side="right") - 1).astype(np.int32)
    tri_garment = particle_garment[tris[:, 0]]
    if not (np.all(particle_garment[tris[:, 1]] == tri_garment) and np.all(particle_garment[tris[:, 2]] == tri_garment)):
        raise ContractError("build_cloth_contact: a triangle spans two garments")
    edges, tri_edges, edge_tris = mesh_edges(tris)
    owns = feature_owners(tris, tri_edges, n, edges.shape[0])
    d = kdop_directions(k)
    h = d.shape[0]
    tmin = np.empty((tris.shape[0], h))
    tmax = np.empty_like(tmin)
    margin = 0.5 * max(thickness, layer_depth if layer_depth is not None else thickness)
    triangle_bounds(d, x, x, tris, margin, tmin, tmax)
    # one tree per garment (a forest): a node's triangles then belong to one garment, so a node
    # can be a connected patch (normal-cone culling)
    trees = []
    cen = x[tris].mean(axis=1)
    for gi in range(g):
        rows = np.nonzero(tri_garment == gi)[0]
        if rows.size == 0:
            continue
        tg = build_tree(tmin[rows], tmax[rows], cen[rows], d, margin)
        leaf = np.where(tg.leaf_prim >= 0, rows[np.maximum(tg.leaf_prim, 0)], -1).astype(np.int32)
        trees.append(KdopTree(directions=d, node_min=tg.node_min, node_max=tg.node_max, children=tg.children,
                              leaf_prim=leaf, depth=tg.depth, tree_offsets=tg.tree_offsets, margin=tg.margin))
    tree = merge_forest(trees)
    borders = node_borders(tree.children, tree.leaf_prim, tris, n, int(tree.max_depth))
    cap = contact_capacity if contact_capacity is not None else max(1024, 8 * n)
    ccap = candidate_capacity if candidate_capacity is not None else max(4096, 64 * n)
    layers = np.zeros(g, np.int32) if layers is None else np.asarray(layers, np.int32)
    outward = np.ones(g) if outward is None else np.asarray(outward, np.float64)
    return ClothContact(
        triangles=tris, edges=edges, tri_edges=tri_edges, tri_owns=owns, edge_tris=edge_tris,
        particle_garment=particle_garment, tri_garment=tri_garment.astype(np.int32),
        edge_garment=particle_garment[edges[:, 0]].astype(np.int32), garment_layer=layers,
        garment_outward=outward, tree=tree, node_dirty=np.ones(tree.node_min.shape[0], np.uint8),
        tri_min=tmin, tri_max=tmax, pt_min=np.zeros((n, h)), pt_max=np.zeros((n, h)),
        nrm_min=np.zeros((tree.node_min.shape[0], h)), nrm_max=np.zeros((tree.node_min.shape[0], h)),
        node_patch=patch_nodes(tree.children, tree.leaf_prim, tris, tri_garment.astype(np.int32), n),
        border_start=borders[0], border_vert=borders[1],
        axis_order=np.arange(h, dtype=np.int32),
        stack=np.zeros((8 * tree.max_depth + 32 + tree.n_trees ** 2, 2), np.int32),
        moved=np.ones(n, np.uint8), corrected=np.zeros(n, np.uint8),
        c_kind=np.zeros(cap, np.int8), c_feat=np.zeros((cap, 2), np.int32), c_idx=np.zeros((cap, 4), np.int32),
        c_w=np.zeros((cap, 4)), c_dir=np.zeros((cap, 3)),
        thickness=float(thickness), layer_depth=float(layer_depth if layer_depth is not None else thickness),
        rounds=int(rounds), failsafe_rounds=int(failsafe_rounds), cull=bool(cull),
        cand_vf=np.zeros((ccap, 2), np.int32), cand_ee=np.zeros((ccap, 2), np.int32), cand_n=np.zeros(6, np.int64),
        cand_f=np.zeros(2), box_lo=np.zeros((n, 4)), box_hi=np.zeros((n, 4)), nrm_ref=np.zeros((tris.shape[0], 4)),
        node_slack=np.zeros(tree.node_min.shape[0]),
        pbox=np.zeros((n, 8), np.float32), ebox=np.zeros((edges.shape[0], 8), np.float32),
        tbox=np.zeros((tris.shape[0], 8), np.float32), p_move=np.zeros(n),
        feat_moved=np.zeros(edges.shape[0] + tris.shape[0], np.uint8),
        loc_list=np.zeros(CK.LOCAL_MAX + 1, np.int32), loc_n=np.zeros(2, np.int64),
        vt_start=np.concatenate([[0], np.cumsum(np.bincount(tris.ravel(), minlength=n))]).astype(np.int64),
        vt_tri=np.argsort(tris.ravel(), kind="stable").astype(np.int32) // 3, ring=np.zeros(tris.shape[0], np.int32),
        flag=np.zeros(n + tris.shape[0], np.uint8), bld_min=np.zeros((n, h)), bld_max=np.zeros((n, h)),
        parent=_parents(tree.children), tri_leaf=_tri_leaves(tree.leaf_prim, tris.shape[0]),
        self_cull=np.zeros(tree.node_min.shape[0], np.uint8), pdiag=np.zeros((n, 2 * CN.DIAG_LANES), np.float32),
        exclude=np.zeros(n, np.uint64) if exclude is None else np.ascontiguousarray(exclude, np.uint64),
        motion_margin=float(motion_margin), rotation=float(rotation))
