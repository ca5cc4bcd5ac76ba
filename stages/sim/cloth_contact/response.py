"""Cloth x cloth collision: the response to a detection's contacts (stages.sim.cloth_contact.kernels
finds them), when a round needs none (`settled`), the fail-safe's revert, and the Verlet velocity
after a call swept over several sub-steps.

Every contact is the constraint C = dir . sum_k w_k x_k - h >= 0 over its 4 particles (the contact
buffer `work` of stages.sim.cloth_contact.setup.ClothContact.kernel_args), projected by inverse mass (PBD);
pinned particles (inv_mass 0) never move.
"""
from __future__ import annotations

from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.sim.cloth_contact.ccd import EE_CROSS, VF_CROSS

NUMBA_CACHE_DEPENDS = ("stages.affine", "stages.sim.cloth_contact.ccd")

SETTLED = 0.25       # a round that finds no crossing and no pair closer than (1 - SETTLED) h ends the call


@njit(cache=True, _nrt=False)
def respond(x, inv_mass, work, n, target, bound=3.0):
    """Project contacts 0..n-1 in buffer order (Gauss-Seidel): C = dir . sum_k w_k x_k - target;
    if C < 0 each particle moves by -C w_k inv_mass_k / sum_j w_j^2 inv_mass_j along dir.

    bound: no particle moves farther than `bound` times -C, the contact's depth. Where a contact's
    only movable particle has a small weight (a triangle corner beside pinned ones) the projection
    would move it by depth / weight: a held contact (projected every sub-step between calls with the
    last call's direction and weights, stages.sim.step.cloth_phase, bound 1) against a collider
    pushing the particle back (CesiumMan's hand folding the skirt at the hip) moved a corner 100
    depths a sub-step until the run diverged; in a call, a Kenney chibi's skirt pressed by its arm
    boxes threw corners tens of metres (a call's fail-safe only reverts what still crosses). Where
    every particle of a contact moves, none moves farther than 3 depths (its largest weight is at
    least 1/2, and the move is depth w_k / sum w_j^2): the calls' bound 3 changes nothing there."""
    moved, corrected, c_kind, c_feat, c_idx, c_w, c_dir = work
    for k in range(n):
        dx = c_dir[k, 0]
        dy = c_dir[k, 1]
        dz = c_dir[k, 2]
        cval = -target
        den = 0.0
        for j in range(4):
            i = c_idx[k, j]
            w = c_w[k, j]
            cval += w * (dx * x[i, 0] + dy * x[i, 1] + dz * x[i, 2])
            den += w * w * inv_mass[i]
        if cval >= 0.0 or den == 0.0:
            continue
        lam = -cval / den
        for j in range(4):
            i = c_idx[k, j]
            sc = lam * c_w[k, j] * inv_mass[i]
            if sc == 0.0:
                continue
            sc = min(max(sc, bound * cval), -bound * cval)
            x[i, 0] += sc * dx
            x[i, 1] += sc * dy
            x[i, 2] += sc * dz
            moved[i] = 1
            corrected[i] = 1


@njit(cache=True, _nrt=False)
def keep_contacts(work, n, keep):
    """Append contacts 0..n-1 of the buffer `work` to the kept buffer `keep`: work's 7 arrays in its
    layout, so `respond` projects it (its moved / corrected flags are respond's scratch, its kind and
    feature arrays empty: respond reads neither), then k_n (1,) i8 its count, then the reach (1,) f8
    collide_cloth detects them within. Contacts past its capacity are not kept; a pair found in
    several rounds is kept once per round (projecting it twice is harmless)."""
    k_n = keep[7]
    c_idx = work[4]
    c_w = work[5]
    c_dir = work[6]
    k_idx = keep[4]
    k_w = keep[5]
    k_dir = keep[6]
    m = k_n[0]
    for k in range(n):
        if m >= k_idx.shape[0]:
            break
        for j in range(4):
            k_idx[m, j] = c_idx[k, j]
            k_w[m, j] = c_w[k, j]
        for j in range(3):
            k_dir[m, j] = c_dir[k, j]
        m += 1
    k_n[0] = m


@njit(cache=True, _nrt=False)
def settled(x, inv_mass, work, n, h):
    """Contacts 0..n-1 need no response: none is a crossing (VF_CROSS / EE_CROSS) and every pair
    with a particle the response can move is at least (1 - SETTLED) h apart on its side
    (C = dir . sum_k w_k x_k >= (1 - SETTLED) h). Such a state is left as it is (the next step's
    detection finds those pairs again): responding to them would move particles only to find the
    pairs their moves bring within h, round after round (the layers' resting contact and
    neighbours in a fold do not converge in a few rounds), and a pair of pinned particles only
    would be found again every round."""
    moved, corrected, c_kind, c_feat, c_idx, c_w, c_dir = work
    floor = (1.0 - SETTLED) * h
    for k in range(n):
        if c_kind[k] == VF_CROSS or c_kind[k] == EE_CROSS:
            return False
        c = 0.0
        den = 0.0
        for j in range(4):
            i = c_idx[k, j]
            c += c_w[k, j] * (c_dir[k, 0] * x[i, 0] + c_dir[k, 1] * x[i, 1] + c_dir[k, 2] * x[i, 2])
            den += c_w[k, j] * c_w[k, j] * inv_mass[i]
        if c < floor and den > 0.0:
            return False
    return True


@njit(cache=True, _nrt=False)
def revert(x_prev, x, inv_mass, work, n):
    """Fail-safe: every movable particle of contacts 0..n-1 goes back to x_prev. Returns how many
    particles changed."""
    moved, corrected, c_kind, c_feat, c_idx, c_w, c_dir = work
    changed = 0
    for k in range(n):
        for j in range(4):
            i = c_idx[k, j]
            if inv_mass[i] == 0.0:
                continue
            if x[i, 0] != x_prev[i, 0] or x[i, 1] != x_prev[i, 1] or x[i, 2] != x_prev[i, 2]:
                x[i, 0] = x_prev[i, 0]
                x[i, 1] = x_prev[i, 1]
                x[i, 2] = x_prev[i, 2]
                moved[i] = 1
                corrected[i] = 1
                changed += 1
    return changed


@njit(cache=True, _nrt=False)
def contact_velocity(x_before, x, xp, corrected):
    """Verlet velocity after a `collide_cloth` called once per frame (or whenever the correction should
    not become velocity): for each corrected particle, with d = x - x_before its correction and
    v = x_before - xp its velocity (times dt) before it, drop the part of v that approaches along d
    (inelastic along the contact normal, tangential kept) and set xp = x - v. Uncorrected particles
    keep xp. corrected: work[1] of the call."""
    for i in range(x.shape[0]):
        if not corrected[i]:
            continue
        dx = x[i, 0] - x_before[i, 0]
        dy = x[i, 1] - x_before[i, 1]
        dz = x[i, 2] - x_before[i, 2]
        vx = x_before[i, 0] - xp[i, 0]
        vy = x_before[i, 1] - xp[i, 1]
        vz = x_before[i, 2] - xp[i, 2]
        dd = dx * dx + dy * dy + dz * dz
        if dd > 0.0:
            vn = (vx * dx + vy * dy + vz * dz) / dd
            if vn < 0.0:
                vx -= vn * dx
                vy -= vn * dy
                vz -= vn * dz
        xp[i, 0] = x[i, 0] - vx
        xp[i, 1] = x[i, 1] - vy
        xp[i, 2] = x[i, 2] - vz
