"""The skin generated around any skeleton (the built-in character's, a BVH's): tapered elliptic
capsules per bone, their smooth union meshed with marching cubes, and linear-blend weights.

Skin: each bone is a tapered capsule with an elliptic cross-section (semi-axes per joint, linearly
interpolated along the bone); the body is the polynomial smooth union of those capsules, meshed with
marching cubes on a grid whose spacing is chosen from the estimated surface area so the triangle
count lands near `target_triangles` (no decimator is installed), then projected back onto the exact
implicit surface and relaxed tangentially to even out marching-cubes slivers.

Weights: every vertex belongs (softly, over ~1 cm) to the capsules nearest it in field value; within
a capsule the weight is rigid (1 to the capsule's bone) except in a band of a few cm across each end
joint, where a smoothstep over the signed distance to the joint's bisector plane blends the parent
and child bones. Radii are guessed from the skeleton's shape when none are given (`guess_radii`).
Conventions as stages.rig.procedural (Y up, metres).
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from stages.checks import ContractError, check_array
from stages.rig.body_params import INFLUENCES, BodyParams
# ---------------------------------------------------------------------------------------------
# Implicit body: tapered elliptic capsules, smooth union


@dataclass(frozen=True)
class _Capsules:
    """Flat arrays describing S capsules (internal).

    start, end: (S,3) axis endpoints (world); axis: (S,3) unit; length: (S,);
    width_axis, depth_axis: (S,3) unit, perpendicular to axis;
    r0, r1: (S,2) (width, depth) semi-axes at start / end;
    bone: (S,) joint owning the capsule; child: (S,) joint at the end, -1 for a tip.
    """

    start: np.ndarray
    end: np.ndarray
    axis: np.ndarray
    length: np.ndarray
    width_axis: np.ndarray
    depth_axis: np.ndarray
    r0: np.ndarray
    r1: np.ndarray
    bone: np.ndarray
    child: np.ndarray


def _cross_section_axes(axis: np.ndarray):
    """Width axis: world X projected off the bone, or world Z for bones running along X (arms,
    so hands are wide front-to-back with palms facing the body); depth = axis x width."""
    x = np.array([1.0, 0.0, 0.0])
    z = np.array([0.0, 0.0, 1.0])
    ref = z if abs(axis[0]) > abs(axis[2]) + 0.2 else x
    w = ref - np.dot(ref, axis) * axis
    n = np.linalg.norm(w)
    if n < 1e-6:  # only if the bone runs exactly along ref
        w = np.array([0.0, 1.0, 0.0]) - axis[1] * axis
        n = np.linalg.norm(w)
    w = w / n
    return w, np.cross(axis, w)


_END_SITE = re.compile(r"(?i:(^|[_\s.])(end(\s*site)?|nub|tip))\d*$|[a-z0-9](End|Nub|Tip)\d*$")


def _build_capsules(parents, positions, radii, ends, min_length, end_leaf=None):
    """end_leaf: (J,) bool, leaves that ARE end sites (BVH 'Head_end'): the bone into them stops
    at them (cap pulled back) without a blend band, and they get no capsule of their own."""
    if end_leaf is None:
        end_leaf = np.zeros(len(parents), bool)
    rows = []
    children = [[] for _ in parents]
    for j, p in enumerate(parents):
        if p >= 0:
            children[p].append(j)
    for b in range(len(parents)):
        main = _main_child(b, parents, positions, children)
        # side branches (pelvis -> thighs, chest -> clavicles) keep the child's size throughout,
        # so the torso's wide section does not spread sideways along them
        targets = []
        for c in children[b]:
            if end_leaf[c]:
                d = positions[c] - positions[b]
                n = np.linalg.norm(d)
                cap = 0.5 * (radii[c][0] + radii[c][1])
                if n > cap:
                    targets.append((-1, positions[b] + d / n * (n - cap), radii[c]))
                else:
                    targets.append((-1, positions[b].copy(), radii[c]))
            else:
                targets.append((c, positions[c], radii[c]))
        if end_leaf[b]:
            pass
        elif not children[b]:
            tip = ends.get(b)
            if tip is None:
                tip = _guess_tip(b, parents, positions, radii)
            r_tip = 0.8 * radii[b]
            d = tip - positions[b]
            n = np.linalg.norm(d)
            # pull the capsule's end back by the cap's axial radius so the surface reaches the tip
            cap = 0.5 * (r_tip[0] + r_tip[1])
            end = positions[b] + d / n * max(n - cap, 0.0) if n > 1e-9 else positions[b].copy()
            targets.append((-1, end, r_tip))
        for c, e, r_end in targets:
            d = e - positions[b]
            n = float(np.linalg.norm(d))
            if n < min_length and c >= 0:
                continue  # zero-length bone (BVH 'HipJoint', 'lowerneck'): no capsule of its own
            axis = d / n if n >= 1e-9 else np.array([0.0, 1.0, 0.0])
            w, dp = _cross_section_axes(axis)
            r0 = radii[b] if (c < 0 or c == main) else np.minimum(radii[b], r_end)
            rows.append((positions[b], e, axis, n, w, dp, r0, r_end, b, c))
    if not rows or max(r[3] for r in rows) < min_length:
        raise ContractError("skin_skeleton: the skeleton has no bone of positive length")
    cols = list(zip(*rows))
    f = lambda i: np.array(cols[i], dtype=np.float64)  # noqa: E731
    return _Capsules(f(0), f(1), f(2), f(3), f(4), f(5), f(6), f(7),
                     np.array(cols[8], dtype=np.int32), np.array(cols[9], dtype=np.int32))


def _main_child(b, parents, positions, children):
    """The child continuing the incoming direction (or +Y at the root), -1 if none."""
    if not children[b]:
        return -1
    p = parents[b]
    incoming = positions[b] - positions[p] if p >= 0 else np.zeros(3)
    if np.linalg.norm(incoming) < 1e-9:
        incoming = np.array([0.0, 1.0, 0.0])
    best, score = children[b][0], -np.inf
    for c in children[b]:
        d = positions[c] - positions[b]
        n = np.linalg.norm(d)
        sc = np.dot(d, incoming) / (n * np.linalg.norm(incoming)) if n > 1e-9 else -2.0
        if sc > score:
            best, score = c, sc
    return best


def _guess_tip(b, parents, positions, radii):
    """A leaf without an end site: extend along the parent bone by max(half its length, 2 radii)."""
    p = parents[b]
    r = float(np.mean(radii[b]))
    if p < 0:
        return positions[b] + np.array([0.0, 2.0 * r, 0.0])
    d = positions[b] - positions[p]
    n = np.linalg.norm(d)
    q = p
    while n < 1e-9 and parents[q] >= 0:  # zero-length parent bone: look further up
        q = parents[q]
        d = positions[b] - positions[q]
        n = np.linalg.norm(d)
    if n < 1e-9:
        return positions[b] + np.array([0.0, 2.0 * r, 0.0])
    return positions[b] + d / n * max(0.5 * n, 2.0 * r)


def _capsule_fields(caps: _Capsules, points: np.ndarray) -> np.ndarray:
    """(N, S) distance-like field of each capsule: negative inside, ~metres near the surface."""
    v = points[:, None, :] - caps.start[None, :, :]
    s = np.einsum("nsk,sk->ns", v, caps.axis)
    length = np.maximum(caps.length, 1e-12)
    t = np.clip(s / length, 0.0, 1.0)
    q = v - (t * caps.length)[..., None] * caps.axis[None]
    rw = caps.r0[:, 0] + t * (caps.r1[:, 0] - caps.r0[:, 0])
    rd = caps.r0[:, 1] + t * (caps.r1[:, 1] - caps.r0[:, 1])
    ra = 0.5 * (rw + rd)
    qw = np.einsum("nsk,sk->ns", q, caps.width_axis)
    qd = np.einsum("nsk,sk->ns", q, caps.depth_axis)
    qa = np.einsum("nsk,sk->ns", q, caps.axis)
    rho = np.sqrt((qw / rw) ** 2 + (qd / rd) ** 2 + (qa / ra) ** 2)
    return (rho - 1.0) * np.minimum(rw, rd)


def _smooth_union(fields: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum over axis 1, folded in capsule order (deterministic)."""
    f = fields[:, 0].copy()
    if k <= 0:
        return fields.min(axis=1)
    for s in range(1, fields.shape[1]):
        g = fields[:, s]
        hh = np.maximum(k - np.abs(f - g), 0.0) / k
        f = np.minimum(f, g) - hh * hh * k * 0.25
    return f


def _field(caps, k, points):
    return _smooth_union(_capsule_fields(caps, points), k)


def _field_gradient(caps, k, points, eps):
    g = np.empty_like(points)
    for a in range(3):
        d = np.zeros(3)
        d[a] = eps
        g[:, a] = (_field(caps, k, points + d) - _field(caps, k, points - d)) / (2 * eps)
    return g


# ---------------------------------------------------------------------------------------------
# Meshing


def _marching_cubes(caps, k, spacing):
    from skimage.measure import marching_cubes

    rmax = np.maximum(caps.r0.max(axis=1), caps.r1.max(axis=1))[:, None]
    lo = np.minimum(caps.start - rmax, caps.end - rmax).min(axis=0) - 2 * spacing
    hi = np.maximum(caps.start + rmax, caps.end + rmax).max(axis=0) + 2 * spacing
    n = np.ceil((hi - lo) / spacing).astype(int) + 1
    axes = [lo[a] + spacing * np.arange(n[a]) for a in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    vol = _field(caps, k, grid).reshape(tuple(n))
    # keep samples off the iso level exactly, which makes zero-area triangles
    vol = np.where(np.abs(vol) < 1e-9, 1e-9, vol)
    verts, faces, _, _ = marching_cubes(vol, 0.0, spacing=(spacing,) * 3, allow_degenerate=False)
    return verts.astype(np.float64) + lo, faces.astype(np.int64)


def _largest_component(verts, faces):
    nv = len(verts)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]]])
    adj = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(nv, nv))
    ncomp, label = connected_components(adj, directed=False)
    if ncomp == 1:
        return verts, faces, 1
    used = np.zeros(nv, bool)
    used[faces.ravel()] = True
    counts = np.bincount(label[used], minlength=ncomp)
    keep_label = int(np.argmax(counts))
    keep_v = label == keep_label
    remap = -np.ones(nv, np.int64)
    remap[keep_v] = np.arange(keep_v.sum())
    keep_f = keep_v[faces[:, 0]]
    return verts[keep_v], remap[faces[keep_f]], ncomp


def _relax(verts, faces, caps, k, spacing, iterations=4):
    """Project onto the implicit surface, then alternate tangential Laplacian smoothing with
    re-projection: evens out marching-cubes slivers without changing topology."""
    eps = 1e-4 * spacing / 0.01
    nv = len(verts)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1]])
    adj = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(nv, nv)).tocsr()
    adj.data[:] = 1.0  # duplicate edges summed: back to 0/1
    deg = np.asarray(adj.sum(axis=1)).ravel()

    def project(x, steps=3):
        for _ in range(steps):
            f = _field(caps, k, x)
            g = _field_gradient(caps, k, x, eps)
            gg = np.maximum(np.einsum("ij,ij->i", g, g), 1e-12)
            step = (f / gg)[:, None] * g
            # limit each step to a fraction of the grid so a bad gradient cannot fling a vertex
            n = np.linalg.norm(step, axis=1, keepdims=True)
            x = x - step * np.minimum(1.0, 0.5 * spacing / np.maximum(n, 1e-12))
        return x

    x = project(verts)
    x0 = x.copy()
    for _ in range(iterations):
        g = _field_gradient(caps, k, x, eps)
        nrm = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
        lap = adj @ x / deg[:, None] - x
        lap -= np.einsum("ij,ij->i", lap, nrm)[:, None] * nrm
        x = project(x + 0.5 * lap, steps=2)
    # where smoothing folded a face against the surface normal (thin hands), undo it locally
    for _ in range(3):
        bad = _flipped_faces(x, faces, caps, k, eps)
        if not bad.any():
            break
        v = np.unique(faces[bad])
        x[v] = x0[v]
    return x


def _flipped_faces(x, faces, caps, k, eps):
    """Faces whose normal points against the field gradient at their centroid."""
    tri = x[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    g = _field_gradient(caps, k, tri.mean(axis=1), eps)
    sign = np.sign(np.einsum("ij,ij->i", n, g).sum())  # orientation of the whole mesh
    return np.einsum("ij,ij->i", n, g) * sign <= 0


# ---------------------------------------------------------------------------------------------
# Skin weights


def _smoothstep(lo, hi, x):
    u = np.clip((x - lo) / np.maximum(hi - lo, 1e-12), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _joint_bands(parents, positions, caps: _Capsules, band_scale):
    """Per joint: blend plane normal (bisector of the parent bone and the joint's own bone) and
    half-width of the blend band (half the joint's mean radius, at most a quarter of the shorter
    adjacent bone, so short bones keep a rigid middle)."""
    nj = len(parents)
    normal = np.zeros((nj, 3))
    half = np.zeros(nj)
    own_len = np.full(nj, np.inf)
    own_dir = np.zeros((nj, 3))
    for s in range(len(caps.bone)):
        b = caps.bone[s]
        if caps.length[s] > 1e-9 and caps.length[s] < own_len[b]:
            own_len[b] = caps.length[s]
        if caps.length[s] > 1e-9 and not own_dir[b].any():
            own_dir[b] = caps.axis[s]
    for j in range(nj):
        p = parents[j]
        if p < 0:
            continue
        into = positions[j] - positions[p]
        n_into = np.linalg.norm(into)
        d = own_dir[j].copy()
        if n_into > 1e-9:
            d = d + into / n_into
        if np.linalg.norm(d) < 1e-9:
            d = into / n_into if n_into > 1e-9 else np.array([0.0, 1.0, 0.0])
        normal[j] = d / np.linalg.norm(d)
        limit = min([x for x in (n_into, own_len[j]) if 1e-9 < x < np.inf], default=0.02)
        half[j] = max(min(band_scale * 0.5 * float(np.mean(caps_radius_at(caps, j))), 0.25 * limit), 0.004)
    return normal, half


def caps_radius_at(caps: _Capsules, j):
    s = np.flatnonzero(caps.bone == j)
    if s.size:
        return caps.r0[s[0]]
    s = np.flatnonzero(caps.child == j)
    if s.size:
        return caps.r1[s[0]]
    return np.array([0.02, 0.02])


def _skin_weights(verts, parents, positions, caps: _Capsules, softness, band_scale=1.0):
    nv, nj = len(verts), len(parents)
    fields = _capsule_fields(caps, verts)  # (N, S)
    excess = fields - fields.min(axis=1, keepdims=True)
    member = np.exp(-excess / softness) * (excess < 6 * softness)
    member /= member.sum(axis=1, keepdims=True)
    normal, half = _joint_bands(parents, positions, caps, band_scale)
    w = np.zeros((nv, nj))
    rows = np.arange(nv)
    for s in range(len(caps.bone)):
        a = member[:, s]
        live = a > 0
        if not live.any():
            continue
        b = int(caps.bone[s])
        c = int(caps.child[s])
        x = verts[live]
        rest = np.ones(len(x))
        if c >= 0:
            v = _smoothstep(-half[c], half[c], (x - positions[c]) @ normal[c])
            w[rows[live], c] += a[live] * v
            rest = 1.0 - v
        p = parents[b]
        if p >= 0:
            u = _smoothstep(-half[b], half[b], (x - positions[b]) @ normal[b])
            w[rows[live], b] += a[live] * rest * u
            w[rows[live], p] += a[live] * rest * (1.0 - u)
        else:
            w[rows[live], b] += a[live] * rest
    if nj < INFLUENCES:  # fewer joints than slots: zero-weight padding columns
        w = np.concatenate([w, np.zeros((nv, INFLUENCES - nj))], axis=1)
    order = np.argsort(-w, axis=1, kind="stable")[:, :INFLUENCES]
    top = np.take_along_axis(w, order, axis=1)
    top /= top.sum(axis=1, keepdims=True)
    # unused slots: weight 0, index of the dominant joint (a valid index)
    order = np.where(top > 0, order, order[:, :1])
    return order.astype(np.int32), top


# ---------------------------------------------------------------------------------------------
# Radii guessed from an arbitrary skeleton


def guess_radii(parents, positions, joint_names=None) -> np.ndarray:
    """(J, 2) (width, depth) semi-axes guessed from the skeleton's shape, metres.

    Humanoid-looking skeletons (a spine chain from the root to the highest joint with at least
    two limbs hanging below the root and two more branching off above it) get a body template:
    torso sizes by height fraction, limb sizes by normalised arc length along each limb. Anything
    else gets round capsules of 15 % of the adjacent bone length.
    """
    parents = np.asarray(parents)
    positions = np.asarray(positions, dtype=np.float64)
    nj = len(parents)
    children = [[] for _ in range(nj)]
    for j, p in enumerate(parents):
        if p >= 0:
            children[p].append(j)
    bone_len = np.zeros(nj)
    for j, p in enumerate(parents):
        if p >= 0:
            d = np.linalg.norm(positions[j] - positions[p])
            bone_len[p] = max(bone_len[p], d)
            bone_len[j] = max(bone_len[j], d) if bone_len[j] == 0 else bone_len[j]
    fallback = np.repeat(np.maximum(0.15 * bone_len, 1e-3)[:, None], 2, axis=1)
    if fallback.max() <= 1e-3:
        fallback[:] = 0.05

    ylo, yhi = positions[:, 1].min(), positions[:, 1].max()
    extent = yhi - ylo
    if nj < 8 or extent <= 1e-6:
        return fallback
    # spine: root to the highest joint
    top = int(np.argmax(positions[:, 1]))
    spine = []
    j = top
    while j >= 0:
        spine.append(j)
        j = parents[j]
    spine = spine[::-1]
    on_spine = np.zeros(nj, bool)
    on_spine[spine] = True
    limbs = []  # (first joint, kind)
    root_y = positions[spine[0], 1]
    for s in spine:
        for c in children[s]:
            if on_spine[c]:
                continue
            sub = _subtree(c, children)
            low = positions[sub, 1].min()
            if len(sub) < 2:
                continue
            kind = "leg" if low < root_y - 0.25 * extent else "arm"
            limbs.append((c, kind, sub))
    if sum(k == "leg" for _, k, _ in limbs) < 2 or sum(k == "arm" for _, k, _ in limbs) < 2:
        return fallback
    # joints span ankle (~0.04 H) to the head joint (~0.9 H), or floor to head top when the
    # highest joint is an end site (BVH 'Head_end')
    if joint_names is not None and _END_SITE.search(str(joint_names[top])):
        h = extent / 0.98
        ground = ylo - 0.01 * h
    else:
        h = extent / 0.88
        ground = ylo - 0.04 * h
    radii = fallback.copy()
    torso_y = np.array([0.40, 0.47, 0.53, 0.62, 0.72, 0.78, 0.82, 0.85, 0.90, 1.0])
    torso_w = np.array([0.070, 0.090, 0.094, 0.080, 0.092, 0.085, 0.034, 0.032, 0.047, 0.040])
    torso_d = np.array([0.060, 0.068, 0.068, 0.058, 0.064, 0.060, 0.034, 0.034, 0.055, 0.048])
    for s in spine:
        f = (positions[s, 1] - ground) / h
        radii[s] = [np.interp(f, torso_y, torso_w) * h, np.interp(f, torso_y, torso_d) * h]
    for first, kind, sub in limbs:
        arc = {first: 0.0}
        for j in sub:  # sub is in topological order
            if j != first:
                arc[j] = arc[parents[j]] + np.linalg.norm(positions[j] - positions[parents[j]])
        total = max(arc.values()) or 1.0
        for j in sub:
            u = arc[j] / total
            if kind == "leg":
                r = np.interp(u, [0.0, 0.15, 0.55, 0.85, 1.0], [0.055, 0.052, 0.031, 0.022, 0.020])
                radii[j] = [r * h, r * h]
            else:
                r = np.interp(u, [0.0, 0.25, 0.6, 0.85, 1.0], [0.034, 0.033, 0.025, 0.020, 0.015])
                radii[j] = [r * h, r * h * (0.65 if u > 0.85 else 1.0)]
    # joints off the spine and off any limb (rare): fallback
    return radii


def _subtree(root, children):
    out = [root]
    i = 0
    while i < len(out):
        out.extend(children[out[i]])
        i += 1
    return sorted(out)


# ---------------------------------------------------------------------------------------------
# Public skin generator


def skin_skeleton(joint_names, parents, joint_positions, params: BodyParams = BodyParams(), *,
                  radii=None, end_sites=None):
    """A closed, manifold, outward-oriented skin around a skeleton, with linear-blend weights.

    joint_names: J names (only used in messages). parents: (J,) ints, parents[j] < j, -1 root.
    joint_positions: (J, 3) float, bind-pose world positions, metres, Y up.
    params: `target_triangles` and `blend_radius` are used.
    radii: optional (J,) or (J, 2) cross-section semi-axes (width, depth) at each joint, metres;
        the width axis is world X projected off the bone, or world Z for bones running mostly
        along X. Guessed by `guess_radii` when None.
    end_sites: optional {joint index: (3,) world position} where a leaf bone ends (BVH End Site);
        leaves without one extend along their parent bone, except leaves named like end sites
        ('Head_end', 'LeftToe_End2', 'HandNub', 'finger_tip'): those ARE the end of their parent
        bone, which then stops there, and they carry no weight.

    Returns (vertices (V,3) float64 world, triangles (T,3) int32 CCW from outside,
    skin_joints (V,4) int32, skin_weights (V,4) float64 rows summing to 1).
    Raises ContractError for a malformed skeleton (bad parents, NaN, no positive-length bone).
    """
    o = "skin_skeleton"
    nj = len(joint_names)
    parents = np.asarray(parents)
    if parents.shape != (nj,) or nj == 0:
        raise ContractError(f"{o}: parents must have one entry per joint ({nj}), got shape {parents.shape}")
    parents = parents.astype(np.int32)
    if parents[0] != -1 or np.any(parents[1:] >= np.arange(1, nj)) or np.any(parents[1:] < -1):
        raise ContractError(f"{o}: expected parents[0] == -1 and parents[j] < j")
    positions = check_array(o, "joint_positions", np.ascontiguousarray(joint_positions, dtype=np.float64),
                            (nj, 3), np.float64)
    if radii is None:
        radii = guess_radii(parents, positions, joint_names)
    radii = np.asarray(radii, dtype=np.float64)
    if radii.shape == (nj,):
        radii = np.repeat(radii[:, None], 2, axis=1)
    check_array(o, "radii", radii, (nj, 2), np.float64)
    if np.any(radii <= 0):
        raise ContractError(f"{o}: radii must be positive")
    ends = {}
    for j, e in (end_sites or {}).items():
        if not 0 <= int(j) < nj:
            raise ContractError(f"{o}: end site for joint {j}, which does not exist")
        ends[int(j)] = check_array(o, f"end_sites[{j}]", np.asarray(e, dtype=np.float64), (3,), np.float64)

    scale = float(np.median(radii))
    children = np.zeros(nj, bool)
    children[parents[parents >= 0]] = True
    end_leaf = np.array([not children[j] and parents[j] >= 0 and j not in ends
                         and bool(_END_SITE.search(str(joint_names[j]))) for j in range(nj)])
    caps = _build_capsules(parents, positions, radii, ends, min_length=1e-3 * max(scale, 1e-3) * 10,
                           end_leaf=end_leaf)
    span = positions[:, 1].max() - positions[:, 1].min()
    k = params.blend_radius * max(span / 0.88, 10 * scale)

    # triangle count ~ c * area / spacing^2 for marching cubes; calibrate c by one trial run
    area = float(np.sum(np.pi * (caps.r0.mean(1) + caps.r1.mean(1)) * caps.length)
                 + 4 * np.pi * np.sum(caps.r1.mean(1) ** 2 * (caps.child < 0)))
    spacing = np.sqrt(2.6 * area / params.target_triangles)
    for attempt in range(4):
        verts, faces = _marching_cubes(caps, k, spacing)
        ratio = len(faces) / params.target_triangles
        if 0.9 <= ratio <= 1.1 or attempt == 3:
            break
        spacing *= np.sqrt(ratio)
    # a limb thinner than the grid can pinch off; keep the body, drop the crumbs
    verts, faces, _ = _largest_component(verts, faces)
    verts = _relax(verts, faces, caps, k, spacing)
    # outward orientation: signed volume must be positive
    vol = np.einsum("ij,ij->i", verts[faces[:, 0]], np.cross(verts[faces[:, 1]], verts[faces[:, 2]])).sum()
    if vol < 0:
        faces = faces[:, ::-1]
    joints, weights = _skin_weights(verts, parents, positions, caps, softness=0.004 * max(span / 1.5, 0.2))
    return verts, np.ascontiguousarray(faces, dtype=np.int32), joints, weights
