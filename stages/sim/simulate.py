"""The simulation stage: Verlet mass-spring cloth against the character's colliders (paper A).

One step, in the paper's order (stages.sim.step.run_steps):
1. character pose without the root translation (Motion.joint_world is in the relative frame);
   colliders and attached particles follow their bones (poses interpolated between frames at
   sub-steps: slerp of the rotation, lerp of the translation; stages.sim.poses);
2. forces: gravity, aerodynamic drag and lift per triangle (velocities from Verlet positions);
3. Verlet integration, damping;
4. `iterations` rounds of spring position correction (stretch and compression, shared by inverse
   mass, per-kind stiffness), each followed by the tethers (long-range attachments to the attached
   particles, SimParams.tethers);
5. collisions in each collider's bone-local frame (spheres: paper eq. 5-6; hulls: the map stage's
   inside test and response), Coulomb friction, counts of corrected / still-inside particles;
6. the root translation re-applied for the output (positions are stored in world).
After every frame, cloth a limb tore lets go of it (SimParams.limb_release, stages.sim.release).

Inertia scale s in [0, 1]. World positions are y = x + T(t) (x: relative frame, T: root translation).
A plain world-space Verlet step y' = y + (1 - k)(y - y_prev) + a h^2 rewritten in the relative frame is
    x' = x + (1 - k)(x - x_prev + d_prev) - d_next + a h^2,
with d_prev = T(t) - T(t - h) and d_next = T(t + h) - T(t): the cloth feels the root's
acceleration (d_next - d_prev ~ T'' h^2) and the damping acts on its world velocity. We scale both
root terms by s:
    x' = x + (1 - k)(x - x_prev + s d_prev) - s d_next + a h^2,
so s = 0 is the paper's relative simulation (no inertial effect of the root motion) and s = 1 is
exactly a world-space simulation (to rounding). The aerodynamic air velocity uses the same scaled
world velocity, (x - x_prev + s d_prev) / h. At the first step d_prev := d_next: the cloth starts
at rest in the relative frame (moving with the character). Friction and collisions are relative to
the colliders, so they do not depend on s.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from stages.checks import ContractError
from stages.jit import for_threads
from stages.garments.types import BEND, STRETCH, Garment
from stages.maps.kernels import METHOD_BRUTE, METHOD_NEAREST_PLANE, METHOD_PAPER
from stages.maps.types import KIND_CYLINDER, MapArrays
from stages.sim import body_collide, collider_grid, forces, integrate, simd, step
from stages.sim.collider_grid import collider_family
from stages.sim.cloth_contact.phase import ClothPhase
from stages.sim.floor import floor_heights
from stages.sim.poses import chunk_poses
from stages.sim.release import limb_release
from stages.sim.settle import settle
from stages.sim.springs import pack_springs, partition_springs
from stages.sim.strain_limit import strain_limits
from stages.sim.types import PINCH_RULES, GarmentTrack, SimParams, SimResult, SimulationDiverged

_CYCLES_PER_S = None
FRAME_CHUNK = 32     # frames per kernel call (bounds the pose arrays; progress is reported per chunk)


def cycles_per_second() -> float:
    """Calibrate the kernels' cycle counter against perf_counter once per process."""
    global _CYCLES_PER_S
    if _CYCLES_PER_S is None:
        simd.read_cycles()
        t0, c0 = time.perf_counter(), simd.read_cycles()
        while time.perf_counter() - t0 < 0.02:
            pass
        t1, c1 = time.perf_counter(), simd.read_cycles()
        _CYCLES_PER_S = max((c1 - c0) / (t1 - t0), 1.0)
    return _CYCLES_PER_S


def empty_map_arrays() -> MapArrays:
    """A MapArrays with no hull (the kernels need the argument even without hulls)."""
    f, i = np.zeros(0), np.zeros(0, np.int32)
    return MapArrays(center=np.zeros((0, 3)), axes=np.zeros((0, 3, 3)), half=np.zeros((0, 3)), kind=i,
                     n_theta=i, n_second=i, second_lo=f, second_hi=f, face_start=np.zeros(1, np.int32),
                     planes=np.zeros((0, 4)), cell_base=np.zeros(1, np.int32), cell_start=np.zeros(1, np.int32),
                     cell_tris=i, loc_base=np.zeros(1, np.int32), loc_x=f, loc_start=np.zeros(1, np.int32),
                     loc_y=np.zeros((0, 4)), loc_face=i)


# -- setup ------------------------------------------------------------------------------------------
def tethers(garments, offsets, inv_mass):
    """Long-range attachments: (particle, anchor, length) arrays (int32, int32, float64), global
    indices. Per garment with fixed particles (inverse mass 0: attached or pinned), every free particle
    connected to one gets the nearest fixed particle along the rest mesh edges (multi-source Dijkstra)
    and that edge-path length (>= the geodesic distance, so the tether never pulls at rest)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    ti, ta, tl = [], [], []
    for g, o in zip(garments, offsets[:-1]):
        w = inv_mass[o:o + g.n_particles]
        fixed = np.flatnonzero(w == 0)
        if fixed.size == 0 or fixed.size == w.size:
            continue
        e = g.springs[g.kinds == STRETCH]
        r = g.rest_lengths[g.kinds == STRETCH]
        graph = coo_matrix((np.concatenate([r, r]), (np.concatenate([e[:, 0], e[:, 1]]),
                                                      np.concatenate([e[:, 1], e[:, 0]]))),
                           shape=(g.n_particles, g.n_particles)).tocsr()
        dist, _, src = dijkstra(graph, indices=fixed, min_only=True, return_predecessors=True)
        free = np.flatnonzero((w > 0) & np.isfinite(dist))
        ti.append(free + o)
        ta.append(src[free] + o)
        tl.append(dist[free])
    if not ti:
        return np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros(0)
    return (np.concatenate(ti).astype(np.int32), np.concatenate(ta).astype(np.int32),
            np.ascontiguousarray(np.concatenate(tl), dtype=np.float64))


# -- system ----------------------------------------------------------------------------------------
class _System:
    """All garments concatenated into one particle system (flat arrays for the kernels)."""

    def __init__(self, garments, joint_world0: np.ndarray, params: SimParams):
        self.names = [g.name for g in garments]
        self.offsets = np.cumsum([0] + [g.n_particles for g in garments])
        n = int(self.offsets[-1])
        self.particle_garment = np.repeat(np.arange(len(garments)), np.diff(self.offsets))
        self.x = np.ascontiguousarray(np.concatenate([g.positions for g in garments]))
        self.inv_mass = np.ascontiguousarray(np.concatenate([g.inverse_mass for g in garments]))
        self.attach_joint = np.ascontiguousarray(np.concatenate([g.attach_joint for g in garments]))
        self.attach_local = np.ascontiguousarray(np.concatenate([g.attach_local for g in garments]))
        self.contact_zones = np.concatenate([np.zeros(g.n_particles, np.uint64) if g.contact_zones is None
                                             else g.contact_zones for g in garments])
        nj = joint_world0.shape[0]
        if np.any(self.attach_joint >= nj):
            raise ContractError(f"simulate: a garment is attached to joint {int(self.attach_joint.max())}, "
                                f"the motion has {nj} joints")
        att = self.attach_joint >= 0
        if att.any():  # exact bind: the attached particles start where their bone puts them
            m = joint_world0[self.attach_joint[att]]
            self.x[att] = np.einsum("nij,nj->ni", m[:, :3, :3], self.attach_local[att]) + m[:, :3, 3]
        self.xp = self.x.copy()
        springs = np.concatenate([g.springs + o for g, o in zip(garments, self.offsets)])
        rest = np.concatenate([g.rest_lengths for g in garments])
        kinds = np.concatenate([g.kinds for g in garments])
        # each garment's fabric may set its own stiffness (None: the simulation's)
        k_stretch = np.concatenate([np.full(len(g.kinds), params.round_stiffness(
            params.stretch_stiffness if g.stretch_stiffness is None else g.stretch_stiffness)) for g in garments])
        k_bend = np.concatenate([np.full(len(g.kinds), params.round_stiffness(
            params.bend_stiffness if g.bend_stiffness is None else g.bend_stiffness)) for g in garments])
        # springs, tethers and the aerodynamic force see every attached particle as pinned (yielding
        # ones too: they yield to the collision response only, see Garment.attach_joint)
        w = np.where(self.attach_joint >= 0, 0.0, self.inv_mass)
        wsum = w[springs[:, 0]] + w[springs[:, 1]]
        live = wsum > 0
        springs, rest, kinds, wsum = springs[live], rest[live], kinds[live], wsum[live]
        stretch = kinds == STRETCH      # the mesh edges (seams included): what the strain audit measures
        self.limits = strain_limits(springs[stretch, 0], springs[stretch, 1], rest[stretch], w, params.strain_limit)
        stiff = np.where(kinds == BEND, k_bend[live], k_stretch[live])
        order, part_start = partition_springs(self.x, springs, n_parts=2)
        springs, rest, stiff, wsum = springs[order], rest[order], stiff[order], wsum[order]
        self.si = np.ascontiguousarray(springs[:, 0], dtype=np.int32)
        self.sj = np.ascontiguousarray(springs[:, 1], dtype=np.int32)
        self.rest = np.ascontiguousarray(rest)
        self.wi = np.ascontiguousarray(stiff * w[self.si] / wsum)
        self.wj = np.ascontiguousarray(stiff * w[self.sj] / wsum)
        self.ij, self.sp, self.group_start = pack_springs(self.si, self.sj, self.rest, self.wi, self.wj,
                                                            part_start, n)
        self.x4 = simd.padded_rows(n)
        self.tris = np.ascontiguousarray(np.concatenate([g.triangles + o for g, o in zip(garments, self.offsets)]),
                                         dtype=np.int32)
        # mass of each triangle's free vertices (a third of each lumped mass; aerodynamic force cap)
        third = np.where(w > 0, 1.0 / (3.0 * np.where(w > 0, w, 1.0)), 0.0)
        self.tri_mass = np.ascontiguousarray(third[self.tris].sum(axis=1))
        # per triangle (x, y, z, 0) aerodynamic force, row T zero (the padding of vt_table)
        self.tri_force = simd.padded_rows(self.tris.shape[0])
        self.vt_table = forces.vertex_triangles(self.tris, n)
        self.vertex_force = simd.padded_rows(n)     # per vertex sums of held forces (SimParams.aero_steps)
        self.vt_eye = integrate.identity_table(n)
        self.corrected = np.zeros(n, np.uint8)
        self.inside = np.zeros(n, np.uint8)
        self.speed2 = np.zeros(n)
        self.contact = np.zeros((n, 0), np.int32)   # per particle and collider: last face, or IGNORED (see set_colliders)
        self.goff = np.ascontiguousarray(self.offsets, dtype=np.int64)
        self.ti, self.ta, self.tl = tethers(garments, self.offsets, w) if params.tethers else (
            np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros(0))

    def cloth(self) -> tuple:
        """The kernels' `cloth` tuple (see stages/sim/step.py)."""
        return (self.x, self.xp, self.inv_mass, self.attach_joint, self.attach_local, self.ij, self.sp,
                self.group_start, self.ti, self.ta, self.tl, self.tris, self.tri_mass, self.tri_force,
                self.vt_table, self.x4, self.vertex_force, self.vt_eye)

    def set_colliders(self, n_colliders: int):
        """The collision kernel's per particle and collider face cache, all unknown (-1); entries
        of colliders a garment ignores become body_collide.IGNORED (`ignore_colliders`)."""
        self.contact = np.full((self.x.shape[0], n_colliders), -1, np.int32)

    def ignore_colliders(self, joints, owner: np.ndarray, n_joints: int):
        """Garment g's particles are never pushed by the colliders of the joints joints[g] (owner (C,):
        each collider's joint): their contact entries become body_collide.IGNORED."""
        if len(joints) != len(self.names):
            raise ContractError(f"simulate: ignore_colliders has {len(joints)} entries, expected one per garment "
                                f"({len(self.names)})")
        for g, js in enumerate(joints):
            js = np.asarray(list(js), np.int64)
            if js.size and (js.min() < 0 or js.max() >= n_joints):
                raise ContractError(f"simulate: ignore_colliders[{g}] ({self.names[g]!r}): joint indices must be in "
                                    f"0..{n_joints - 1}, got {js.tolist()}")
            cols = np.flatnonzero(np.isin(owner, js))
            if cols.size:
                self.contact[self.offsets[g]:self.offsets[g + 1], cols] = body_collide.IGNORED

    def flags(self) -> tuple:
        return (self.corrected, self.inside, self.speed2, self.contact)

    def split(self, a: np.ndarray) -> list:
        return [a[self.offsets[i]:self.offsets[i + 1]] for i in range(len(self.names))]


def exit_face_data(hull_maps, m) -> tuple[np.ndarray, np.ndarray]:
    """Per-face and per-hull data of the collision kernel's exit-face cache (body_collide._cached_face).

    face_edges (F, 12) float64: per face (global id, OBB-local frame of its hull) its three edge
    planes (m, o), m the unit in-plane normal pointing into the triangle: inside iff m.r >= o.
    src_range (H, 2) float64: the map ray's source is known strictly inside hull h when its axial
    coordinate s0 satisfies lo < s0 < hi (map sphere: the OBB centre, s0 = 0; map cylinder: the
    axis point s0 = q0). An empty range (lo >= hi) turns the cache off for that hull.
    """
    face_edges = np.zeros((m.planes.shape[0], 12))
    src_range = np.zeros((len(hull_maps), 2))
    for h, hm in enumerate(hull_maps):
        f0, f1 = int(m.face_start[h]), int(m.face_start[h + 1])
        v = (hm.mesh.vertices - m.center[h]) @ m.axes[h].T             # OBB-local
        tri = v[hm.mesh.faces]                                          # (F, 3, 3)
        n = m.planes[f0:f1, :3]
        for k in range(3):
            a, b = tri[:, k], tri[:, (k + 1) % 3]
            e = np.cross(n, b - a)
            e /= np.linalg.norm(e, axis=1, keepdims=True)
            face_edges[f0:f1, 4 * k:4 * k + 3] = e
            face_edges[f0:f1, 4 * k + 3] = np.einsum("ij,ij->i", e, a)
        # the source s = (s0, 0, 0) is inside iff n0 s0 < off - margin for every face
        n0, off = m.planes[f0:f1, 0], m.planes[f0:f1, 3] - 1e-9 * float(m.half[h].max())
        if int(m.kind[h]) == KIND_CYLINDER:
            lo = np.max(off[n0 < 0] / n0[n0 < 0], initial=-np.inf)
            hi = np.min(off[n0 > 0] / n0[n0 > 0], initial=np.inf)
            if np.any(off[n0 == 0] <= 0):
                lo, hi = np.inf, -np.inf
        else:
            lo, hi = (-np.inf, np.inf) if np.all(off > 0) else (np.inf, -np.inf)
        src_range[h] = lo, hi
    return face_edges, src_range


class _Colliders:
    """Colliders as flat arrays: unified index c (hulls first, then spheres)."""

    def __init__(self, colliders, maps, parents=None):
        hulls = tuple(colliders.hulls) if colliders is not None else ()
        spheres = tuple(colliders.spheres) if colliders is not None else ()
        self.notes = []
        if hulls:
            if maps is None:
                from stages.maps import build_maps
                maps = build_maps(colliders)
                self.notes.append("maps built with default settings (none given)")
            if len(maps.maps) != len(hulls) or np.any(np.asarray(maps.bones) != [h.bone for h in hulls]):
                raise ContractError("simulate: the MapSet does not match the ColliderSet's hulls (order / bones)")
            self.m = maps.arrays
        else:
            self.m = empty_map_arrays()
        self.face_edges, self.src_range = exit_face_data(maps.maps if hulls else (), self.m)
        joint, kind, index, bc, br = [], [], [], [], []
        # the joint each collider belongs to (a ball's: its region's joint; `joint` is its pose index)
        self.owner = np.array([hull.bone for hull in hulls] + [s.joint for s in spheres], np.int32)
        for h, hull in enumerate(hulls):
            v = hull.simplified.vertices
            c = v.mean(axis=0)
            joint.append(hull.bone)
            kind.append(collider_grid.KIND_HULL)
            index.append(h)
            bc.append(c)
            br.append(np.linalg.norm(v - c, axis=1).max() * (1 + 1e-9) + 1e-9)
        for k, s in enumerate(spheres):
            joint.append(s.pose_index)
            kind.append(collider_grid.KIND_SPHERE)
            index.append(k)
            bc.append(s.center)
            br.append(s.radius * (1 + 1e-9) + 1e-9)
        nc = len(joint)
        self.joint = np.array(joint, np.int32)
        self.kind = np.array(kind, np.int32)
        self.index = np.array(index, np.int32)
        self.bcenter = np.array(bc, np.float64).reshape(nc, 3)
        self.bradius = np.array(br, np.float64)
        self.sph_center = np.array([s.center for s in spheres], np.float64).reshape(len(spheres), 3)
        self.sph_radius = np.array([s.radius for s in spheres], np.float64)
        self.tq = np.zeros((nc, 12))
        self.tq0 = np.zeros((nc, 12))
        self.fq = np.zeros((nc, 12))
        self.cw = np.zeros((nc, 5))
        self.cws = np.zeros((nc, 5))      # a frame's swept spheres (collider_grid.swept_spheres)
        self.grid_start = np.zeros(collider_grid.GRID_CELLS + 1, np.int64)
        self.grid_items = np.zeros(max(nc * collider_grid.GRID_CELLS, 1), np.int32)
        self.grid_runs = np.zeros((max(nc * collider_grid.GRID_CELLS, 1), 3), np.int32)
        self.grid_box = np.zeros(4)
        self.grid_dims = np.zeros(3, np.int64)
        self.family = collider_family(self.owner, parents)

    def cols(self) -> tuple:
        """The kernels' `cols` tuple (see stages/sim/step.py)."""
        return (self.joint, self.kind, self.index, self.bcenter, self.bradius, self.sph_center, self.sph_radius,
                self.tq, self.tq0, self.fq, self.cw, self.grid_start, self.grid_items, self.grid_runs,
                self.grid_box, self.grid_dims,
                self.face_edges, self.src_range, self.cws, self.family)


def particles_inside_colliders(points, colliders, maps, pose, method: int = METHOD_PAPER) -> np.ndarray:
    """(N,) bool: which points (relative frame) are inside a collider of `colliders` posed by
    `pose` (J, 4, 4) joint transforms (e.g. motion.joint_world[f]); maps None: built with defaults."""
    col = _Colliders(colliders, maps)
    fwd = np.ascontiguousarray(pose, dtype=np.float64)
    inv = np.ascontiguousarray(np.linalg.inv(fwd))
    collider_grid.collider_frames(fwd, inv, inv, col.m, col.joint, col.kind, col.index, col.bcenter, col.bradius,
                      col.sph_center, col.tq, col.tq0, col.fq, col.cw)
    p = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    out = np.zeros(p.shape[0], np.uint8)
    none_ignored = np.full((p.shape[0], col.joint.size), -1, np.int32)
    body_collide.count_inside(p, np.ones(p.shape[0]), col.m, method, col.kind, col.index, col.sph_radius, col.tq, col.cw,
                              none_ignored, out)
    return out.astype(bool)


# -- the stage ----------------------------------------------------------------------------------------
def simulate(character, motion, colliders, maps, garments, params: SimParams, *, obstacles=None,
             progress=None, threads: int | None = 1, layers=None, partial: dict | None = None,
             ignore_colliders=None) -> SimResult:
    """See `_simulate`. threads: numba threads for the parallel kernels during the call (None = the
    current numba setting). Results do not depend on it (every parallel loop writes disjoint
    particles). Default 1: on the shared 2-core machine a second thread pays only when a core is
    idle (see pipeline/benches/sim.py). layers: (G,) cloth collision layer per garment, 0 = innermost
    (default: the garments' order); used when params.cloth_collision. partial: optional dict the
    simulation keeps 'result' in (a function of no argument: the SimResult of the frames done so
    far), for a caller that stops the run from outside (a sweep's timeout) and keeps what was done.
    ignore_colliders: optional, per garment a collection of joint indices whose colliders (hulls,
    spheres, balls) never push that garment (a limb the animation swings through it: the cloth then
    passes through the limb, which the body audit counts)."""
    if threads is None:
        return _simulate(character, motion, colliders, maps, garments, params, obstacles, progress, layers, partial,
                         ignore_colliders)
    import numba
    old = numba.get_num_threads()
    numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    try:
        return _simulate(character, motion, colliders, maps, garments, params, obstacles, progress, layers, partial,
                         ignore_colliders)
    finally:
        numba.set_num_threads(old)


def _simulate(character, motion, colliders, maps, garments, params, obstacles, progress, layers, partial,
              ignore_colliders=None) -> SimResult:
    """Simulate `garments` on `character` playing `motion` (see the module docstring).

    character: stages.rig.types.Character; motion: Motion sampled every params.dt seconds;
    colliders: ColliderSet (or None: no colliders); maps: MapSet of colliders.hulls (None: built
    with defaults); garments: sequence of Garment (relative frame at frame 0);
    obstacles: optional ObstacleSet (paper B environment, world frame) collided after the colliders;
    progress: optional callable(frames_done, n_frames).
    Raises SimulationDiverged (with the partial result) when the cloth blows up.
    """
    t_start = time.perf_counter()
    garments = tuple(garments)
    if not garments:
        raise ContractError("simulate: no garment to simulate")
    if not all(isinstance(g, Garment) for g in garments):
        raise ContractError("simulate: garments must be stages.garments.types.Garment")
    names = [g.name for g in garments]
    if len(set(names)) != len(names):
        raise ContractError(f"simulate: garment names must be unique, got {names}")
    nf = motion.n_frames
    if motion.joint_world.shape[1] != character.n_joints:
        raise ContractError(f"simulate: motion has {motion.joint_world.shape[1]} joints, character {character.n_joints}")
    if nf > 1:
        dts = np.diff(motion.times)
        if not np.allclose(dts, params.dt, rtol=1e-6, atol=1e-9):
            raise ContractError(f"simulate: motion frames are {dts.min():.6g}..{dts.max():.6g} s apart, "
                                f"SimParams.dt is {params.dt:.6g} s")
    body_motion = motion           # the skin (audits); `motion` below also poses the colliders
    if colliders is not None and colliders.balls is not None:
        # the skinned balls' frames follow the joints (collider index = pose index; attachments use joints only)
        from dataclasses import replace
        motion = replace(motion, joint_world=np.ascontiguousarray(
            colliders.frame_poses(character.inverse_bind, motion.joint_world)))
    sysm = _System(garments, motion.joint_world[0], params)
    col = _Colliders(colliders, maps, character.parents)
    sysm.set_colliders(col.joint.size)
    notes = list(col.notes)
    if any(g.passing_joints for g in garments):    # limbs resting on a band (stages.garments.band)
        ignore_colliders = [tuple(sorted(set(ignore_colliders[k] if ignore_colliders is not None else ())
                                         | set(g.passing_joints))) for k, g in enumerate(garments)]
    if ignore_colliders is not None:
        sysm.ignore_colliders(ignore_colliders, col.owner, character.n_joints)
        notes += [f"{g.name}: not pushed by the colliders of {', '.join(character.joint_names[j] for j in js)}"
                  for g, js in zip(garments, ignore_colliders) if len(js)]
    method = {"ray": METHOD_PAPER, "brute_ray": METHOD_BRUTE, "nearest_plane": METHOD_NEAREST_PLANE}[params.hull_response]
    s = float(params.inertia_scale)
    h = params.step
    ss = params.substeps
    n = sysm.x.shape[0]
    gravity = np.asarray(params.gravity, np.float64)
    wind = np.asarray(params.wind, np.float64)
    k_drag = 0.5 * params.air_density * params.drag
    k_lift = 0.5 * params.air_density * params.lift
    use_aero = bool(k_drag > 0 or k_lift > 0)
    timers = np.zeros(step.N_TIMERS, np.int64)
    timings = {"poses": 0.0, "integrate": 0.0, "constraints": 0.0, "collisions": 0.0, "obstacles": 0.0,
               "audit": 0.0}
    cphase = ClothPhase.for_simulation(sysm, layers, params, character, body_motion) if params.cloth_collision else None

    root = motion.root_translation
    # the floor (world height SimParams.floor): the cloth's mid-surface rests half its thickness above it
    level = None if params.floor is None else float(params.floor) + 0.5 * float(params.cloth_thickness)
    floor0 = None if level is None else level - float(root[0, 1])    # relative frame, at frame 0
    no_floor = np.zeros(0)
    ocol = None
    if obstacles is not None:
        from stages.obstacles.stage import ObstacleCollider
        oset = getattr(obstacles, "obstacle_set", obstacles)
        ocol = ObstacleCollider(oset, sysm.x + root[0])
        notes.append(f"obstacles: {len(oset.obstacles)} (k-DOP trees, world frame)")

    audit = None
    if params.body_audit and character.triangles.shape[0] > 0:
        from stages.rig.skinning import skin
        from stages.sim.body_audit import InsideBody
        audit = InsideBody(character)

    release = limb_release(sysm, col.owner, colliders, character, garments, params)
    rel = np.zeros((nf, n, 3), np.float32)       # relative frame; root translation added at the end
    pen_col = np.zeros((nf, len(garments)), np.int32)
    pen_body = np.full((nf, len(garments)), -1, np.int32)
    pen_overlap = np.zeros((nf, len(garments)), np.int32)     # of the particles inside: where the body meets itself
    counts = np.zeros((nf, step.N_COUNTS))        # see step.record_frame
    step_cycles = np.zeros(nf, np.int64)
    n_obst = np.zeros(nf, np.int32)                                # obstacle contacts per frame
    obst_points = [np.zeros((0, 3), np.float32) for _ in range(nf)]
    prm = (h, params.step_damping(), s, k_drag, k_lift, float(params.friction), use_aero, int(params.iterations),
           int(params.collision_passes), method, int(params.aero_steps()), PINCH_RULES.index(params.pinch),
           float(params.speed_limit) * h, bool(params.entry_side), bool(params.face_contact), sysm.limits)
    cloth, cols, flags = sysm.cloth(), col.cols(), sysm.flags()
    # one thread: the serial kernels (compiled several times faster than the parallel ones)
    import numba
    threads = numba.get_num_threads()
    run_frames, run_steps = (for_threads(k, threads) for k in (step.run_frames, step.run_steps))
    max2 = float(params.max_speed) ** 2

    def audit_frames(f0, f1):
        if audit is None or f1 <= f0:
            return
        t0 = time.perf_counter()
        verts = skin(character, body_motion, frames=list(range(f0, f1)))
        for k, f in enumerate(range(f0, f1)):
            ins, held = audit.classify(verts[k], rel[f])
            pen_body[f] = [int(a.sum()) for a in sysm.split(ins & ~held)]
            pen_overlap[f] = [int(a.sum()) for a in sysm.split(held)]
        timings["audit"] += time.perf_counter() - t0

    def result(f_end):
        pos = [rel[:f_end, o0:o1] + root[:f_end, None, :].astype(np.float32)
               for o0, o1 in zip(sysm.offsets[:-1], sysm.offsets[1:])]
        step_ms = step_cycles[:f_end] / cycles_per_second() * 1e3 / ss
        res = _result(garments, pos, pen_col, pen_body, pen_overlap, counts[:, 0].astype(np.int32),
                      np.sqrt(counts[:, 1]), step_ms, motion.times, timings, timers, max(f_end - 1, 0) * ss,
                      params, notes, f_end)
        return dataclasses.replace(res, pinched=counts[:f_end, 2].astype(np.int32),
                                   speed_limited=counts[:f_end, 3].astype(np.int32),
                                   released=release.counts(f_end) if release is not None else np.zeros(f_end, np.int32),
                                   contacts_obstacles=n_obst[:f_end].copy(), contact_points=tuple(obst_points[:f_end]),
                                   cloth_contact=cphase.summary() if cphase is not None else {})

    def diverged(f):
        sp2 = sysm.speed2
        bad = ~(np.isfinite(sp2) & (sp2 <= max2)) | ~np.isfinite(sysm.x).all(axis=1)
        idx = np.flatnonzero(bad)
        gname = [names[int(sysm.particle_garment[i])] for i in idx]
        local = idx - sysm.offsets[sysm.particle_garment[idx]]
        fin = sp2[np.isfinite(sp2)]
        audit_frames(0, f)
        return SimulationDiverged(f, local, gname, float(np.sqrt(fin.max())) if fin.size else float("nan"),
                                  partial=result(f) if f > 0 else None)

    timings["setup"] = time.perf_counter() - t_start
    # frame 0: the initial state; count particles starting inside a collider (no response)
    fwd0 = np.ascontiguousarray(motion.joint_world[0])
    inv_0 = np.ascontiguousarray(np.linalg.inv(fwd0))
    # worn garments (every one attached to the body) are sorted by their layers and hang under full
    # gravity at the frame-0 pose before frame 0; a free cloth (a sheet dropped on the character or on
    # obstacles, which the step loop below meets only frame by frame) is recorded where the scene puts
    # it, and sorted after frame 0
    worn = obstacles is None and all((g.attach_joint >= 0).any() or (g.inverse_mass == 0).any() for g in garments)
    if cphase is not None and worn:   # garments that start interpenetrating: sorted by their layers
        cphase.settle(cloth, cols, col.m, prm, gravity, wind, fwd0, inv_0, ss, max2, sysm.goff, flags, floor0)
    if params.settle_frames and worn:
        if not settle(cloth, cols, col.m, prm, params, gravity, wind, fwd0, inv_0, max2, sysm.goff, flags,
                      cphase.rest if cphase is not None else None, floor0):
            raise diverged(0)
        if cphase is not None:
            cphase.mark_settled()
    collider_grid.collider_frames(fwd0, inv_0, inv_0, col.m, col.joint, col.kind, col.index, col.bcenter, col.bradius,
                      col.sph_center, col.tq, col.tq0, col.fq, col.cw)
    body_collide.count_inside(sysm.x, sysm.inv_mass, col.m, method, col.kind, col.index, col.sph_radius, col.tq, col.cw,
                              sysm.contact, sysm.inside)
    sysm.corrected[:] = 0
    sysm.speed2[:] = 0.0
    step.record_frame(sysm.x, flags, np.inf, sysm.goff, rel[0], pen_col[0], counts[0])
    audit_frames(0, 1)
    if cphase is not None and not worn:
        cphase.settle(cloth, cols, col.m, prm, gravity, wind, fwd0, inv_0, ss, max2, sysm.goff, flags, floor0)
    if progress is not None:
        progress(1, nf)

    if partial is not None:
        frames_done = [1]
        partial["result"] = lambda: result(frames_done[0])
    d_last = None
    f0 = 1
    while f0 < nf:
        f1 = min(nf, f0 + (1 if ocol is not None or release is not None else FRAME_CHUNK))
        cc = cphase.rest if cphase is not None else None
        t0 = time.perf_counter()
        fwd, inv, inv0, d_prev, d_next, tr, d_last = chunk_poses(motion, f0, f1, ss, s, d_last)
        floor = no_floor if level is None else floor_heights(root[:, 1], f0, f1, ss, level)
        timings["poses"] += time.perf_counter() - t0
        if ocol is None:
            done = run_frames(cloth, cols, col.m, prm, gravity, wind, fwd, inv, inv0, d_prev, d_next, floor, ss, max2,
                                sysm.goff, rel[f0:f1], pen_col[f0:f1], counts[f0:f1], step_cycles[f0:f1], flags,
                                timers, cc)
            if done < f1 - f0:
                raise diverged(f0 + done)
        else:   # paper B obstacles live in world: hand over world positions after every step
            f = f0
            sysm.corrected[:] = 0
            c0 = simd.read_cycles()
            for k in range(ss):
                if cc is not None and len(cc) == 10 and k % cc[8] == 0:   # the swept phase's x_start: the start of the phase's sweep (as run_steps)
                    cc[0][:] = sysm.x
                run_steps(cloth, cols, col.m, prm, gravity, wind, fwd, inv, inv0, d_prev, d_next, floor, k, k + 1,
                          flags, timers, None)
                to = time.perf_counter()
                ta = motion.times[f - 1] + k * h
                xpw, xw = sysm.xp + tr[k], sysm.x + tr[k + 1]
                ocol.collide(xpw, xw, sysm.inv_mass, ta, ta + h)
                sysm.xp[:] = xpw - tr[k]
                sysm.x[:] = xw - tr[k + 1]
                n_obst[f] += ocol.n_contacts
                timings["obstacles"] += time.perf_counter() - to
                if cc is not None:   # cloth x cloth last, after the obstacles
                    tc = simd.read_cycles()
                    step.cloth_phase(sysm.x, sysm.xp, k, cc)
                    timers[step.T_CLOTH] += simd.read_cycles() - tc
            obst_points[f] = ocol.contacts()["point"].astype(np.float32)
            step_cycles[f] = simd.read_cycles() - c0
            if not step.record_frame(sysm.x, flags, max2, sysm.goff, rel[f], pen_col[f], counts[f]):
                raise diverged(f)
        if release is not None:      # after the frame: its positions and the colliders' poses
            release.after_frame(f0, sysm.x, sysm.contact, motion.joint_world[f0])
        audit_frames(f0, f1)
        if partial is not None:
            frames_done[0] = f1
        if progress is not None:
            progress(f1, nf)
        f0 = f1
    timings["total"] = time.perf_counter() - t_start
    return result(nf)


def _result(garments, pos, pen_col, pen_body, pen_overlap, corrected, max_speed, step_ms, times, timings, timers,
            steps, params, notes, nf) -> SimResult:
    cps = cycles_per_second()
    tm = dict(timings)
    tm["integrate"] = float(timers[step.T_INTEGRATE] / cps)
    tm["constraints"] = float(timers[step.T_CONSTRAINTS] / cps)
    tm["collisions"] = float(timers[step.T_COLLISIONS] / cps)
    tm["cloth"] = float(timers[step.T_CLOTH] / cps)
    audit_on = bool((pen_body[:nf] >= 0).all())
    tracks = tuple(GarmentTrack(g.name, g.triangles, pos[i][:nf], np.ascontiguousarray(pen_col[:nf, i]),
                                np.ascontiguousarray(pen_body[:nf, i]), np.ascontiguousarray(pen_overlap[:nf, i]))
                   for i, g in enumerate(garments))
    body = pen_body[:nf].sum(axis=1).astype(np.int32) if audit_on else np.full(nf, -1, np.int32)
    return SimResult(garments=tracks, times=np.asarray(times[:nf], np.float64),
                     penetrations_colliders=pen_col[:nf].sum(axis=1).astype(np.int32), penetrations_body=body,
                     penetrations_body_overlap=pen_overlap[:nf].sum(axis=1).astype(np.int32),
                     corrected=corrected[:nf].copy(), max_speed=max_speed[:nf].copy(), step_ms=step_ms[:nf].copy(),
                     timings=tm, steps=int(steps), params=params, notes=tuple(notes))
