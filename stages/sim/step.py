"""The cloth step as a short loop over named phases (run_steps), and whole chunks of frames (run_frames).

Layout: all garments concatenated into one particle system; flat float64 / int32 arrays.
x (N, 3) current positions, xp (N, 3) previous positions (Verlet), both in the relative frame.
Poses: fwd (J, 4, 4) bone-local -> relative frame at the END of the step, inv (J, 4, 4) its inverse,
inv0 (J, 4, 4) the inverse at the START of the step (for friction relative to a moving collider).

Phases, one module each: stages.sim.forces (aerodynamic forces), stages.sim.integrate (Verlet,
gravity, attachments), stages.sim.springs (spring corrections and tethers), stages.sim.collider_grid
(collider frames, broad phase), stages.sim.body_collide (colliders; then stages.sim.face_collide,
the colliders against the cloth's triangles, SimParams.face_contact; then stages.sim.strain_limit,
SimParams.strain_limit; then stages.sim.floor, SimParams.floor), stages.sim.cloth_contact.kernels
(cloth x cloth: garment-garment and self collision, last, so a recorded frame is what it checked).

Speed (issue 6): a whole chunk of frames runs in one call (`run_frames`): nothing is allocated and
no Python runs between steps. The per-step phases are parallel loops (prange) over disjoint
particles / triangles / spring blocks, so the result is the same for any thread count (OpenMP
regions cost ~1 us each; the caller picks the threads, 1 by default). Hot kernels are compiled with
`_nrt=False`: numba otherwise increments / decrements (atomically) the reference count of every
array argument of each helper inlined into the loop, which cost more than the hull query itself.

Cloth-side argument tuples (built once by simulate.py, unpacked for free inside njit):
    cloth = (x, xp, inv_mass, attach_joint, attach_local, ij, sp, group_start, ti, ta, tl, tris,
             tri_mass, tri_force, vt_table, x4, vertex_force, vt_eye)
    cols  = (col_joint, col_kind, col_index, col_bcenter, col_bradius, sph_center, sph_radius,
             tq, tq0, fq, cw, grid_start, grid_items, grid_runs, grid_box, grid_dims, face_edges, src_range, cws,
             family)
            cws (C, 5): the swept spheres of a frame's broad phase (collider_grid.swept_spheres)
            family (C, 3): joint, its parent, its depth (collider_grid.collider_family; the 'limb' pinch rule)
    prm   = (h, damping, s, k_drag, k_lift, friction, use_aero, iterations, passes, method, aero_every, pinch,
             speed_h, entry, faces, limits)
            entry: SimParams.entry_side (body_collide.collide's `entry`); pinch: body_collide.PINCH_* code.
            faces: SimParams.face_contact (face_collide.collide_faces after the particles' collisions).
            speed_h: the speed limit times h (m per step; 0: no limit, see integrate.limit_speed).
            limits: stages.sim.strain_limit's edges (empty arrays: SimParams.strain_limit off).
            aero_every: steps per aerodynamic force computation (SimParams.aero_steps): the forces of
            step k with k % aero_every == 0 are held over the next aero_every steps, summed per vertex
            into vertex_force (N + 1, 4) once (integrate then reads it through vt_eye, (N, 1)).
    flags = (corrected, inside, speed2, contact)
    cc    = None (no cloth-cloth phase: its kernels are then neither typed nor compiled: numba prunes
            the `cc is not None` branches for a None argument), the offset phase's 5-tuple
            (stages.sim.cloth_contact.offset.offset_state; numba prunes on the tuple's length too) or, built by simulate.py from
            stages.sim.cloth_contact.setup.ClothContact.kernel_args():
            (x_start, x_before, cinv, topo, tree, work, cprm, counters, every, keep)
            x_start / x_before (N, 3) work arrays; cinv (N,) inverse masses with attached particles 0;
            every: sub-steps per cloth-contact call (1: every sub-step; k: one call swept over k
            sub-steps, its correction not turned into velocity, see contact_velocity); keep: the
            contacts the last call found, projected in every step (stages.sim.cloth_contact.response.keep_contacts).
"""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.jit import opt_level, with_parallel_calls
from stages.sim.body_collide import PINCHED, collide
from stages.sim.cloth_contact.kernels import PUSH_OVER, SWEEPS, collide_cloth, contact_velocity, respond
from stages.sim.cloth_contact.offset import offset_call
from stages.maps.kernels import METHOD_NEAREST_PLANE
from stages.sim.face_collide import collide_faces
from stages.sim.floor import collide_floor
from stages.sim.collider_grid import build_grid, collider_frames, swept_spheres
from stages.sim.forces import aero_forces
from stages.sim.integrate import LIMITED, gather_forces, integrate, limit_speed
from stages.sim.simd import cycles
from stages.sim.springs import correct_springs
from stages.sim.strain_limit import PASSES as LIMIT_PASSES, limit_strain

# the phases are compiled into the step loop: an edit of any of them must invalidate its cache
NUMBA_CACHE_DEPENDS = ("stages.sim.body_collide", "stages.sim.face_collide", "stages.sim.floor", "stages.sim.body_escape", "stages.sim.collider_query",
                       "stages.sim.collider_grid", "stages.sim.forces", "stages.sim.strain_limit",
                       "stages.sim.integrate", "stages.sim.simd", "stages.sim.springs", "stages.maps.kernels",
                       "stages.maps.types", "stages.affine", "stages.fastmath", "stages.sim.cloth_contact.kernels",
                       "stages.sim.cloth_contact.ccd", "stages.sim.cloth_contact.cull",
                       "stages.sim.cloth_contact.narrow", "stages.sim.cloth_contact.local", "stages.sim.cloth_contact.pairs", "stages.sim.cloth_contact.response",
                       "stages.sim.cloth_contact.offset", "stages.sim.cloth_contact.proximity", "stages.geometry.kdop")

# Broad phase once per frame (the spheres swept through its steps, no query-frame boxes) from this
# many colliders on; fewer, once per step (with the boxes). Measured one frame from the same state,
# per-frame minimum over 25 rounds, alternating (2026-11-24, load 3.5-3.9): the bench walk (162
# colliders) collisions 88.9 -> 69.5 us a step with the swept grid; the bench drape (one hull)
# 49.7 -> 55.1 us (its cells lose the OBB cut, building its grid costs ~2 us). Same positions.
SWEPT_GRID_MIN = 8

# timer slots (CPU cycles; simulate.py converts to seconds)
T_INTEGRATE = 0
T_CONSTRAINTS = 1
T_COLLISIONS = 2
T_CLOTH = 3
N_TIMERS = 4


# -- steps and frames ------------------------------------------------------------------------------
@njit(cache=True, _nrt=False)
def run_steps(cloth, cols, m, prm, gravity, wind, fwd, inv, inv0, d_prev, d_next, floor, k0, k1, flags, timers, cc):
    """Steps k0..k1-1 in the paper's order: forces, Verlet (+ attachments), spring corrections,
    collisions (the floor last), then cloth x cloth (cc, or None: off). Per step k: fwd[k] / inv[k]
    (J, 4, 4) the pose at its end, inv0[k] at its start; d_prev[k] / d_next[k] (3,) the root
    translation over the previous / this step; floor[k] / floor[k + 1] the floor's height at its start
    / end (stages.sim.floor.floor_heights; empty: no floor). timers (N_TIMERS,) int64 accumulate
    cycles of integrate / constraints / collisions / cloth contact."""
    (x, xp, inv_mass, attach_joint, attach_local, ij, sp, group_start, ti, ta, tl, tris, tri_mass,
     tri_force, vt_table, x4, vertex_force, vt_eye) = cloth
    (col_joint, col_kind, col_index, col_bcenter, col_bradius, sph_center, sph_radius,
     tq, tq0, fq, cw, grid_start, grid_items, grid_runs, grid_box, grid_dims, face_edges, src_range, cws,
     family) = cols
    (h, damping, s, k_drag, k_lift, friction, use_aero, iterations, passes, method, aero_every, pinch, speed_h, entry,
     faces, limits) = prm
    corrected, inside, speed2, contact = flags
    for k in range(k0, k1):
        if cc is not None and len(cc) == 10:     # the swept phase (a 5-tuple: the offset phase)
            if k % cc[8] == 0:
                copy_rows(cc[0], x)     # x_start: the start of the swept interval (free of crossings)
        t0 = cycles()
        if aero_every == 1:
            if use_aero:
                aero_forces(x, xp, tri_mass, tris, h, s, d_prev[k], wind, k_drag, k_lift, tri_force)
            integrate(x, xp, inv_mass, attach_joint, attach_local, fwd[k], h, gravity, damping, s,
                      d_prev[k], d_next[k], use_aero, tri_force, vt_table)
        else:
            if use_aero and k % aero_every == 0:
                aero_forces(x, xp, tri_mass, tris, h, s, d_prev[k], wind, k_drag, k_lift, tri_force, aero_every)
                gather_forces(tri_force, vt_table, vertex_force)
            integrate(x, xp, inv_mass, attach_joint, attach_local, fwd[k], h, gravity, damping, s,
                      d_prev[k], d_next[k], use_aero, vertex_force, vt_eye)
        t1 = cycles()
        correct_springs(x, x4, ij, sp, group_start, ti, ta, tl, iterations)
        t2 = cycles()
        collider_frames(fwd[k], inv[k], inv0[k], m, col_joint, col_kind, col_index, col_bcenter, col_bradius,
                        sph_center, tq, tq0, fq, cw)
        if k1 - k0 == 1 or col_joint.size < SWEPT_GRID_MIN:    # its own broad phase (one step: the obstacle loop)
            build_grid(m, method, col_kind, col_index, sph_radius, tq, fq, cw, grid_start, grid_items, grid_runs,
                       grid_box, grid_dims)
        elif k == k0:       # a frame's steps: one broad phase over the spheres swept through them
            swept_spheres(fwd, k0, k1, col_joint, col_bcenter, col_bradius, cws)
            build_grid(m, METHOD_NEAREST_PLANE, col_kind, col_index, sph_radius, tq, fq, cws, grid_start, grid_items,
                       grid_runs, grid_box, grid_dims)
        collide(x, xp, inv_mass, m, method, col_kind, col_index, sph_radius, tq, tq0, fq, cw,
                grid_start, grid_items, grid_box, grid_dims, face_edges, src_range, friction, passes, corrected, inside,
                speed2, contact, h, col_joint, pinch, entry, family)
        if faces:
            collide_faces(x, xp, inv_mass, tris, m, method, col_kind, col_index, sph_radius, tq, tq0, fq, cw,
                          grid_start, grid_items, grid_box, grid_dims, contact, corrected)
        if limits[0].size:      # strain limiting after the collisions (SimParams.strain_limit)
            limit_strain(x, limits, LIMIT_PASSES)
        if floor.size:
            collide_floor(x, xp, inv_mass, attach_joint, floor, k, d_next[k], friction)
        t3 = cycles()
        if cc is not None:
            cloth_phase(x, xp, k, cc)
            timers[T_CLOTH] += cycles() - t3
        if speed_h > 0.0:
            limit_speed(x, xp, inv_mass, speed_h, speed2, h, corrected)
        timers[T_INTEGRATE] += t1 - t0
        timers[T_CONSTRAINTS] += t2 - t1
        timers[T_COLLISIONS] += t3 - t2


@njit(cache=True, _nrt=False)
def copy_rows(dst, src):
    """dst[:] = src for (N, 3) arrays, without numba's runtime (a slice copy needs it)."""
    for i in range(src.shape[0]):
        dst[i, 0] = src[i, 0]
        dst[i, 1] = src[i, 1]
        dst[i, 2] = src[i, 2]


@njit(cache=True, _nrt=False)
def cloth_phase(x, xp, k, cc):
    """The cloth x cloth phase after step k. The offset phase (cc a 5-tuple,
    stages.sim.cloth_contact.offset): one offset_call every `every` steps. The swept phase: every `every` steps, one collide_cloth over the
    interval since x_start; when that interval is longer than one step, the correction is not
    turned into Verlet velocity (contact_velocity: only the approach along it is dropped), and every
    step first projects the contacts the last call found (kept: a layer resting on another is held
    in the steps between calls instead of falling through the gap and being caught by the next),
    no particle farther than its contact's depth (respond's `bound` 1: a stale held contact whose
    only movable particle had a small weight diverged against a collider pushing it back)."""
    if len(cc) == 5:    # the offset phase (stages.sim.cloth_contact.offset)
        if (k + 1) % cc[3][3] == 0:
            offset_call(x, xp, cc)
        return
    x_start, x_before, cinv, topo, tree, work, cprm, counters, every, keep = cc
    if every > 1 and keep[7][0] > 0:
        target = PUSH_OVER * cprm[0]
        for _ in range(SWEEPS):
            respond(x, cinv, keep[:7], keep[7][0], target, 1.0)
    if (k + 1) % every != 0:
        return
    if every == 1:
        collide_cloth(x_start, x, cinv, topo, tree, work, cprm, counters)
    else:
        copy_rows(x_before, x)
        collide_cloth(x_start, x, cinv, topo, tree, work, cprm, counters, keep)
        contact_velocity(x_before, x, xp, work[1])


N_COUNTS = 4    # record_frame's counts per frame: corrected particles, max speed^2, pinched, speed-limited particles


@njit(cache=True, _nrt=False)
def record_frame(x, flags, max_speed2, goff, pos, pen, counts):
    """Store one frame: pos (N, 3) float32 <- x; pen (G,) particles inside a collider per garment
    (garment g = goff[g]..goff[g+1]); counts = (particles a collider pushed, max speed^2, pinched
    particles, particles whose speed was limited in the frame).
    Returns False (storing nothing) if a particle is non-finite or faster than sqrt(max_speed2)."""
    corrected, inside, speed2, _ = flags
    vmax = 0.0
    for i in range(x.shape[0]):
        v = speed2[i]
        if not (v <= max_speed2) or not (np.isfinite(x[i, 0]) and np.isfinite(x[i, 1]) and np.isfinite(x[i, 2])):
            return False
        vmax = max(vmax, v)
    nc = 0
    n_pinched = 0
    n_limited = 0
    for g in range(goff.size - 1):
        n_in = 0
        for i in range(goff[g], goff[g + 1]):
            pos[i, 0] = x[i, 0]
            pos[i, 1] = x[i, 1]
            pos[i, 2] = x[i, 2]
            n_in += inside[i] == 1
            n_pinched += inside[i] == PINCHED
            nc += corrected[i] & 1
            n_limited += (corrected[i] & LIMITED) != 0
        pen[g] = n_in
    counts[0] = nc
    counts[1] = vmax
    counts[2] = n_pinched
    counts[3] = n_limited
    return True


@njit(cache=True, _nrt=False)
def run_frames(cloth, cols, m, prm, gravity, wind, fwd, inv, inv0, d_prev, d_next, floor, substeps, max_speed2,
               goff, pos, pen, counts, step_cycles, flags, timers, cc):
    """Frames 0..F-1 of a chunk (F = pos.shape[0]), `substeps` steps each (pose arrays: F * substeps,
    floor F * substeps + 1 or empty),
    each recorded with record_frame into pos[f], pen[f], counts[f]; step_cycles[f] the frame's
    stepping cycles (recording excluded). Returns the number of frames done: F, or the index of the
    first frame that diverged (not recorded; the state is left as it diverged)."""
    corrected = flags[0]
    for f in range(pos.shape[0]):
        corrected[:] = 0
        c0 = cycles()
        run_steps(cloth, cols, m, prm, gravity, wind, fwd, inv, inv0, d_prev, d_next, floor,
                  f * substeps, (f + 1) * substeps, flags, timers, cc)
        step_cycles[f] = cycles() - c0
        if not record_frame(cloth[0], flags, max_speed2, goff, pos[f], pen[f], counts[f]):
            return f
    return pos.shape[0]


# threads > 1: the same loops over the phases' parallel variants (stages.jit: the serial ones
# compile several times faster; simulate picks with stages.jit.for_threads)
# The loops' own code is small: LLVM level 1 for their modules, which only link the phases'
# (optimised at the default level when they are compiled) -- 2 x 3.5 s of compile less.
run_steps = opt_level(1)(run_steps)
run_frames = opt_level(1)(run_frames)
run_steps_parallel = with_parallel_calls(run_steps)
run_frames_parallel = with_parallel_calls(run_frames)
