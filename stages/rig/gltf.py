"""glTF 2.0 skinned characters -> `Character` (bind mesh, skeleton, weights, baked clips).

File access (GLB, buffers, accessors, primitives) is in `gltf_io`, the node tree and the frame
change in `gltf_nodes`; every defect becomes one `InputError` naming the file and the problem.

Frames (glTF spec): a skinned vertex x (the mesh node's own transform is ignored) lands at
`x_world = sum_k w_k * global(joint_k) @ inverse_bind_k @ x`, global() multiplying every ancestor
node (also the non-joint nodes above the skeleton, with any rotation, translation and scale).
- The skeleton = the skin joints plus every node on the path from a joint up to the joints'
  lowest common ancestor (and up to the highest animated ancestor of it, if any), so non-joint
  nodes between joints become unweighted joints and the FK stays exact. Joints are re-ordered
  depth-first (parents[j] < j). If the joints share no ancestor, a synthetic root `__root__` is added.
- Bind space: joint k takes its bind-space points to the rest pose's world by C_k = rest_world_k @
  inverse_bind_k (I when the bind mesh is the rest pose). When the joints holding at least half
  the skin weight share one C (an exporter that turned the mesh Z-up -> Y-up, or scaled it, in
  the inverse binds but not in the nodes), the bind mesh becomes C @ mesh and the inverse binds
  inverse_bind_k @ C^-1: skinning is unchanged in every pose, and the bind mesh stands as the
  skeleton does (`gltf_nodes.bind_to_rest`). Otherwise the file's bind pose is kept as stored.
- The model frame is U applied to the glTF world: U = floor shift @ up rotation @ scale. The up
  rotation takes the file's up (`up_axis`; 'auto': `gltf_nodes.detect_up`, from the skinned rest
  pose, skeleton and mesh together) to +Y; the scale is `scale`, or with None the units found
  from the rest pose's height and kind (`gltf_nodes.choose_units`: metres; cm / mm when metres
  make a biped or animal implausibly tall; refused when nothing makes it plausible); the floor
  shift (vertical only) puts the lowest bind-mesh vertex on y = 0.
- The static transform P of the nodes above the root is folded in (`gltf_nodes.fold_frames`):
  U @ P = A @ K, A rigid, K the stretch (polar decomposition). Joint translations are mapped by
  K (root) or Lb_p^-1 K Lb_p (Lb_p: parent's bind-pose linear part below P), the root's local
  transform is pre-multiplied by A, inverse_bind' = (Lb^-1 K Lb) @ inverse_bind @ U^-1 and
  vertices' = U @ vertices; bone-local frames stay rigid (when the file's bind transforms are).
- Rotation + translation + uniform scale above the root (K = s * I to 1e-5, the common case:
  Z-up fixes, cm -> m): skinned positions are exactly U applied to the glTF world positions, in
  every pose.
- Non-uniform scale or shear above the root: a rigid bone cannot follow the shear a glTF viewer
  shows when a bone turns inside a stretched frame. Exact: the bind pose (skinning it gives the
  bind mesh), the root's trajectory (root translation keys map by K), and every pose in which each
  joint keeps its bind-pose orientation relative to P up to rotations that commute with K (e.g.
  about the axis of a (a, b, a) scale). Otherwise a vertex is off by at most (largest - smallest
  principal stretch of K) x (its distance from its joints' origins + the bone lengths from the
  root to them, both measured below P), for joints without scale of their own.
- `Character.notes` says which up axis was taken (and why, for 'auto'), the units (and why), a bind
  space that is not the rest pose, and the floor shift.

Animation baking (the `Clip` contract has one interpolation mode per clip):
- all channels STEP -> a 'step' clip at the union of key times (exact);
- otherwise a 'linear' clip at the union of the LINEAR / STEP key times, plus, for every STEP
  key t_k (k > 0), a key at t_k - 1e-6 s holding the previous value (so linear playback reproduces
  the step except within 1 us of it), plus, for CUBICSPLINE channels, dense samples: each key
  segment is cut into ceil(duration * cubic_rate) pieces, doubled until lerp / slerp between the
  samples is within `cubic_tol` of the exact Hermite curve at the piece midpoints.
Every baked key is the exact sampler value (`sample_gltf_channel`). Joints without a channel keep
their rest TRS. Channels on nodes outside the skeleton and 'weights' (morph) channels are ignored.
Clip times keep the file's times (usually starting at 0); `loop` sets every clip's loop flag, or
None (auto, `cycles`): a clip loops when its last pose meets its first (a walk cycle), else it is
played once and its last pose held (a fall, a 'die': looped, it jumped back up every third of a
second and threw the cloth off).
"""
from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from stages.errors import InputError
from stages.rig.gltf_io import Reader, load_document, read_skinned_primitive
from stages.rig.gltf_nodes import (UP_ROTATIONS, bind_to_rest, choose_units, decompose, detect_up, fold_frames,
                                   node_matrix, node_trs, parents_of_nodes, select_skeleton)
from stages.rig.transforms import slerp, trs_to_matrix
from stages.rig.types import Character, Clip

_PATH_SIZES = {"translation": 3, "rotation": 4, "scale": 3}
_STEP_EPS = 1e-6  # seconds before a STEP key where the baked linear clip still holds the old value
UP_AXES = ("auto", "y", "z")


# --------------------------------------------------------------------------------------------
# Animation samplers
# --------------------------------------------------------------------------------------------

def sample_gltf_channel(key_times: np.ndarray, values: np.ndarray, interpolation: str, path: str,
                        t: np.ndarray) -> np.ndarray:
    """Evaluate a glTF animation sampler exactly at times `t`.

    key_times: (K,) seconds, non-decreasing. values: (K, C) for LINEAR / STEP, (3K, C) for
    CUBICSPLINE (in-tangent, value, out-tangent per key). path: 'translation' | 'rotation' |
    'scale' (rotation: slerp for LINEAR, re-normalised Hermite for CUBICSPLINE).
    t: (N,) seconds; clamps outside [key_times[0], key_times[-1]]. Returns (N, C) float64.
    """
    key_times = np.asarray(key_times, np.float64).ravel()
    values = np.asarray(values, np.float64)
    t = np.atleast_1d(np.asarray(t, np.float64))
    k = key_times.size
    cubic = interpolation == "CUBICSPLINE"
    if cubic:
        v = values.reshape(k, 3, -1)
        in_tan, val, out_tan = v[:, 0], v[:, 1], v[:, 2]
    else:
        val = values
    if k == 1:
        out = np.repeat(val[:1], t.size, axis=0)
    elif interpolation == "STEP":
        i = np.clip(np.searchsorted(key_times, t, side="right") - 1, 0, k - 1)
        out = val[i]
    else:
        tc = np.clip(t, key_times[0], key_times[-1])
        i = np.clip(np.searchsorted(key_times, tc, side="right") - 1, 0, k - 2)
        dt = key_times[i + 1] - key_times[i]
        safe = np.where(dt > 0, dt, 1.0)
        u = np.where(dt > 0, (tc - key_times[i]) / safe, 1.0)
        if cubic:
            u2, u3 = u * u, u * u * u
            h00 = 2 * u3 - 3 * u2 + 1
            h10 = u3 - 2 * u2 + u
            h01 = -2 * u3 + 3 * u2
            h11 = u3 - u2
            out = (h00[:, None] * val[i] + (h10 * dt)[:, None] * out_tan[i]
                   + h01[:, None] * val[i + 1] + (h11 * dt)[:, None] * in_tan[i + 1])
        elif path == "rotation":
            out = slerp(val[i], val[i + 1], u)
        else:
            out = (1 - u)[:, None] * val[i] + u[:, None] * val[i + 1]
    out = np.array(out, np.float64)
    if path == "rotation":
        out /= np.linalg.norm(out, axis=1, keepdims=True)
    return out


def _lerp_keys(times: np.ndarray, vals: np.ndarray, path: str, t: np.ndarray) -> np.ndarray:
    """Linear (slerp for rotations) playback of already-sampled keys, for the bake error check."""
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, times.size - 2)
    u = (t - times[i]) / (times[i + 1] - times[i])
    if path == "rotation":
        return slerp(vals[i], vals[i + 1], u)
    return (1 - u)[:, None] * vals[i] + u[:, None] * vals[i + 1]


def _cubic_bake_times(key_times, values, path, rate: float, tol: float) -> np.ndarray:
    """Sample times, per key segment, at which lerp / slerp matches the Hermite curve within tol."""
    out = [key_times]
    for a, b in zip(key_times[:-1], key_times[1:]):
        if b <= a:
            continue
        n = max(1, int(np.ceil((b - a) * rate)))
        while True:
            ts = np.linspace(a, b, n + 1)
            vs = sample_gltf_channel(key_times, values, "CUBICSPLINE", path, ts)
            mids = 0.5 * (ts[:-1] + ts[1:])
            quarter = np.concatenate([mids, 0.5 * (ts[:-1] + mids)])
            exact = sample_gltf_channel(key_times, values, "CUBICSPLINE", path, quarter)
            err = np.abs(_lerp_keys(ts, vs, path, quarter) - exact)
            if path == "rotation":  # q and -q are the same rotation
                err = np.minimum(err, np.abs(_lerp_keys(ts, vs, path, quarter) + exact))
            if err.max() <= tol or n >= 4096:
                break
            n *= 2
        out.append(ts[1:-1])
    return np.concatenate(out)




# --------------------------------------------------------------------------------------------
# Loader
# --------------------------------------------------------------------------------------------

def _inverse_binds(path, doc, rd, used_skins, order, rest_world):
    """File-frame inverse bind of every joint (J, 4, 4) and each skin's bind-space change (4, 4).

    Several skins must agree up to one bind-space change per skin (mapping its mesh into the
    first skin's bind space). Unweighted joints get the inverse of their rest world transform.
    """
    ibm_file: dict[int, np.ndarray] = {}
    bind_change: dict[int, np.ndarray] = {}
    for s in used_skins:
        sk = doc.skins[s]
        if sk.inverseBindMatrices is None:
            ibms = np.tile(np.eye(4), (len(sk.joints), 1, 1))
        else:
            raw = rd.accessor(sk.inverseBindMatrices, f"skin {s} inverseBindMatrices")
            if raw.shape != (len(sk.joints), 16):
                raise InputError(path, f"skin {s}: inverseBindMatrices has {raw.shape[0]} matrices of "
                                       f"{raw.shape[1]} values, expected {len(sk.joints)} MAT4")
            ibms = raw.reshape(-1, 4, 4).transpose(0, 2, 1)
            # the whole matrix: a corrupted bottom row leaves the 3 x 3 part invertible but not it
            dets = np.abs(np.linalg.det(ibms[:, :3, :3])) * np.abs(np.linalg.det(ibms))
            if not np.all(np.isfinite(dets) & (dets > 1e-300)):
                raise InputError(path, f"skin {s}: inverse bind matrix {int(np.argmin(np.nan_to_num(dets)))} is singular "
                                       f"or not finite")
        shared = [(k, jn) for k, jn in enumerate(sk.joints) if jn in ibm_file]
        change = np.eye(4)
        if shared:
            k0, jn0 = shared[0]
            change = np.linalg.inv(ibm_file[jn0]) @ ibms[k0]
            for k, jn in shared:
                if not np.allclose(ibm_file[jn] @ change, ibms[k], atol=1e-4):
                    raise InputError(path, f"skin {s} disagrees with an earlier skin on the bind pose of joint node {jn}")
        inv_change = np.linalg.inv(change)
        for k, jn in enumerate(sk.joints):
            ibm_file.setdefault(jn, ibms[k] @ inv_change)
        bind_change[s] = change
    ibm = np.stack([ibm_file[n] if n in ibm_file else np.linalg.inv(rest_world[j]) for j, n in enumerate(order)])
    return ibm, bind_change


def _read_meshes(doc, rd, skinned, index_of, bind_change):
    """Every skinned mesh node's primitives in the first skin's bind space (file frame).

    Returns vertices (V, 3), triangles (T, 3) int32, primitive ids (V,) int32, skin joints (V, K)
    int32 (skeleton indices, K = 8 if any primitive has JOINTS_1 else 4, strongest first) and
    weights (V, K) renormalised.
    """
    verts, tris, prim_ids, joints_l, weights_l = [], [], [], [], []
    offset = 0
    for ni in skinned:
        node = doc.nodes[ni]
        joint_map = np.array([index_of[jn] for jn in doc.skins[node.skin].joints], np.int64)
        change = bind_change[node.skin]
        mesh = doc.meshes[node.mesh]
        for pi, prim in enumerate(mesh.primitives or []):
            where = f"mesh {node.mesh} ({mesh.name or 'unnamed'}) primitive {pi}"
            pos, tri, jv, wv = read_skinned_primitive(rd, prim, where, joint_map.size)
            verts.append(pos @ change[:3, :3].T + change[:3, 3])
            tris.append(tri + offset)
            prim_ids.append(np.full(pos.shape[0], len(prim_ids), np.int32))
            joints_l.append(joint_map[jv])
            weights_l.append(wv)
            offset += pos.shape[0]
    if not verts:
        rd.fail("the skinned meshes have no primitives")
    k_slots = 8 if any(j.shape[1] > 4 for j in joints_l) else 4
    sj = np.zeros((offset, k_slots), np.int32)
    sw = np.zeros((offset, k_slots), np.float64)
    row = 0
    for jv, wv in zip(joints_l, weights_l):
        order_k = np.argsort(-wv, axis=1, kind="stable")[:, :k_slots]
        take = min(k_slots, jv.shape[1])
        n = jv.shape[0]
        sj[row:row + n, :take] = np.take_along_axis(jv, order_k, axis=1)[:, :take]
        sw[row:row + n, :take] = np.take_along_axis(wv, order_k, axis=1)[:, :take]
        row += n
    sums = sw.sum(axis=1)
    if np.any(sums <= 0):
        rd.fail(f"{int(np.sum(sums <= 0))} vertices have all skin weights zero")
    sw /= sums[:, None]
    return np.concatenate(verts), np.concatenate(tris).astype(np.int32), np.concatenate(prim_ids), sj, sw


def _skin_rest(skin_m: np.ndarray, verts: np.ndarray, sj: np.ndarray, sw: np.ndarray) -> np.ndarray:
    """Linear-blend skinning of verts (V, 3) by per-joint matrices skin_m (J, 4, 4): (V, 3).
    One influence slot at a time, so memory stays (V, 4, 4) whatever K."""
    out = np.zeros_like(verts)
    for k in range(sj.shape[1]):
        m = skin_m[sj[:, k]]
        out += sw[:, k, None] * (np.einsum("vij,vj->vi", m[:, :3, :3], verts) + m[:, :3, 3])
    return out


def load_gltf(path, *, scale: float | None = None, up_axis: str = "auto", loop: bool | None = None,
              cubic_rate: float = 60.0, cubic_tol: float = 1e-4) -> Character:
    """Load a skinned glTF 2.0 (.glb, or .gltf with external .bin / data URIs) as a Character.

    The character stands as a glTF viewer shows it (every node transform composed, module doc),
    turned Y up and lifted so that its lowest bind-mesh vertex is on y = 0 (no horizontal shift).
    A bind space the nodes do not explain (a turn or scale kept in the inverse binds only) is
    taken into the rest pose's frame first (`gltf_nodes.bind_to_rest`), so the bind mesh stands
    as the skinned rest pose does.
    scale: metres per file unit, multiplying every length (vertices, joint translations, inverse
    binds); None (auto, `gltf_nodes.choose_units`): metres (the glTF convention) unless the posed
    character is implausibly large for a biped or animal and centimetres or millimetres fix it
    (then that scale, a note and a warning), or implausible anyway (InputError naming
    character.scale and a value for it).
    up_axis: which file axis is up: 'auto' (`gltf_nodes.detect_up`: the direction along which two
    limbs of the skinned rest pose hang side by side to the floor; +Y when no such pair), 'y' (the
    glTF convention, no rotation) or 'z' ((x, y, z) -> (x, z, -y)).
    loop: the loop flag of every clip; None: each clip's from `cycles`. cubic_rate (Hz) / cubic_tol: CUBICSPLINE baking (module doc).
    Every skinned mesh node (mesh + skin) contributes its triangle primitives; `primitive_ids`
    numbers them in file order. Skin weights keep the 8 strongest influences (K = 8 when any
    primitive has JOINTS_1, else K = 4), renormalised. `notes`: the up axis (first), the units
    ('units: ...'), the bind space when it is not the rest pose, the floor shift.
    Raises InputError (naming the file) for unreadable / corrupt / unsupported content.
    """
    path = Path(path)
    number = isinstance(scale, (int, float, np.integer, np.floating)) and not isinstance(scale, bool)
    if scale is not None and not (number and np.isfinite(scale) and scale > 0):
        raise InputError(path, f"character.scale must be a positive number or null (auto), got {scale!r}")
    if up_axis not in UP_AXES:
        raise InputError(path, f"up_axis must be one of {', '.join(UP_AXES)}, got {up_axis!r}")
    doc, bin_chunk = load_document(path)
    rd = Reader(path, doc, bin_chunk)
    nodes = doc.nodes or []
    parent = parents_of_nodes(path, doc)

    skinned = [i for i, n in enumerate(nodes) if n.mesh is not None and n.skin is not None]
    if not skinned:
        raise InputError(path, "no skinned mesh (no node has both a mesh and a skin)")
    skins = doc.skins or []
    for i in skinned:
        if not 0 <= nodes[i].skin < len(skins):
            raise InputError(path, f"node {i} uses skin {nodes[i].skin}, which does not exist")
        if not 0 <= nodes[i].mesh < len(doc.meshes or []):
            raise InputError(path, f"node {i} uses mesh {nodes[i].mesh}, which does not exist")
    used_skins = list(dict.fromkeys(nodes[i].skin for i in skinned))
    skin_joint_nodes: list[int] = []
    for s in used_skins:
        js = skins[s].joints or []
        if not js:
            raise InputError(path, f"skin {s} has no joints")
        for j in js:
            if not 0 <= j < len(nodes):
                raise InputError(path, f"skin {s} names joint node {j}, which does not exist")
        skin_joint_nodes.extend(js)
    skin_joint_nodes = list(dict.fromkeys(skin_joint_nodes))

    # Which nodes are animated (TRS channels), to extend the skeleton over animated ancestors.
    animated: set[int] = set()
    for a in doc.animations or []:
        for c in a.channels or []:
            if c.target is not None and c.target.node is not None and c.target.path in _PATH_SIZES:
                animated.add(c.target.node)
    skel = select_skeleton(nodes, parent, skin_joint_nodes, animated)
    order, parents, names, above = skel.order, skel.parents, skel.names, skel.above
    index_of = skel.index_of
    nj = len(order)

    # Rest TRS (file frame) and rest world transforms of every joint.
    rest_trs = []
    rest_world = np.empty((nj, 4, 4))
    for j, n in enumerate(order):
        if n < 0:
            rest_trs.append((np.zeros(3), np.array([0.0, 0, 0, 1]), np.ones(3)))
        else:
            trs = node_trs(nodes[n])
            rest_trs.append(trs if trs is not None else decompose(node_matrix(nodes[n]), f"node {n} ({names[j]}) matrix", path))
        local = np.eye(4) if n < 0 else node_matrix(nodes[n])
        rest_world[j] = (above if j == 0 else rest_world[parents[j]]) @ local
    ibm, bind_change = _inverse_binds(path, doc, rd, used_skins, order, rest_world)
    verts, tris, prim_ids, sj, sw = _read_meshes(doc, rd, skinned, index_of, bind_change)

    # Bind space -> the rest pose's world, when one transform does it (a turn or scale kept in the
    # inverse binds only): the mesh is taken there, so that it stands as the skeleton does.
    size = float(np.max(np.ptp(verts, axis=0)))
    joint_weight = np.bincount(sj.ravel(), weights=sw.ravel(), minlength=nj)
    change, agree = bind_to_rest(rest_world, ibm, joint_weight, size)
    notes_bind = []
    if not np.array_equal(change, np.eye(4)):
        verts = verts @ change[:3, :3].T + change[:3, 3]
        in_skin = np.isin(order, skin_joint_nodes)
        ibm = np.where(in_skin[:, None, None], ibm @ np.linalg.inv(change), np.linalg.inv(rest_world))
        s_change = float(np.cbrt(np.linalg.det(change[:3, :3])))
        turn = float(np.degrees(Rotation.from_matrix(change[:3, :3] / s_change).magnitude()))
        held = [f"a {turn:.3g} deg turn"] * (turn > 0.01) + [f"scale {s_change:.4g}"] * (abs(s_change - 1) > 1e-5)
        notes_bind.append(f"bind space: the inverse binds hold {' and '.join(held) or 'a shift'} that the nodes do "
                          f"not; the bind mesh is taken into the rest pose's frame (skinning unchanged)")
    elif agree < 1.0 - 1e-9:  # e.g. bound in a T-pose, rested in an A-pose: exact as stored
        notes_bind.append(f"bind pose: differs from the rest pose (the nodes' TRS) for joints holding "
                          f"{100 * (1 - agree):.3g} % of the skin weight; kept as stored (skinning exact)")

    # The posed character (the rest pose, skinned) decides the up axis and the size: that is what
    # the pipeline shows first, whatever the bind space.
    with np.errstate(over="ignore", invalid="ignore"):
        posed = _skin_rest(rest_world @ ibm, verts, sj, sw)
    if not np.all(np.isfinite(posed)):
        raise InputError(path, "the skinned rest pose is not finite (node transforms or inverse binds overflow)")
    axes, stances = detect_up(rest_world[:, :3, 3], parents, posed, sj[:, 0])
    axis = axes if up_axis == "auto" else "+" + up_axis
    node_scale = float(np.cbrt(abs(np.linalg.det(rest_world[0, :3, :3]))))
    units = choose_units(path, stances[axis], scale, node_scale if node_scale > 0 else 1.0)
    scale = units.scale
    if units.auto:
        warnings.warn(f"{path}: {units.note}", stacklevel=2)
    if up_axis == "auto":
        why = ", ".join(f"{k} {v.hang * scale:.3g}" for k, v in stances.items() if v.hang > 0) or "none"
        limbs = stances[axis].limbs
        said = f"{limbs} limbs reach the floor" if limbs > 1 else "no two limbs reach the floor, the glTF +Y kept"
        notes = [f"up axis: file {axis.upper()} (auto; skinned rest pose: {said}; metres two limbs hang side by "
                 f"side by candidate up: {why})"]
    else:
        notes = [f"up axis: file {axis.upper()} (up_axis: {up_axis})"]
    notes += [units.note] + notes_bind

    # U maps the glTF world to the model frame: up rotation and scale, then the floor shift.
    u = np.eye(4)
    u[:3, :3] = UP_ROTATIONS[axis] * scale
    lift = -float(np.min(verts @ u[1, :3]))
    u[1, 3] = lift
    notes.append(f"floor: lifted {lift:+.4g} m so that the lowest bind-mesh vertex is at y = 0")
    bind_world = np.linalg.inv(ibm)  # each joint's bind-pose global transform, file frame
    fold = fold_frames(path, u, above, np.linalg.inv(above) @ bind_world, parents)
    if not fold.isotropic:
        sv = np.linalg.eigvalsh(fold.k) / scale
        notes.append(f"the nodes above the skeleton stretch it non-uniformly (principal scales "
                     f"{', '.join(f'{x:.4g}' for x in sv)}): exact in the bind pose, see stages.rig.gltf")

    rest_local = np.empty((nj, 4, 4))
    for j, n in enumerate(order):
        if n >= 0 and node_trs(nodes[n]) is None:  # matrix nodes: keep the matrix exact
            rest_local[j] = fold.convert_matrix(j, node_matrix(nodes[n]))
        else:
            t, q, sc = fold.convert_trs(j, *(x[None] for x in rest_trs[j]))
            rest_local[j] = trs_to_matrix(t[0], q[0], sc[0])

    root_joint = min(index_of[n] for n in skin_joint_nodes)
    try:
        clips = _bake_clips(path, doc, rd, order, index_of, rest_trs, fold.convert_trs, bool(loop), cubic_rate,
                            cubic_tol)
        if loop is None:
            height = float(np.ptp(verts @ u[1, :3] + u[1, 3]))
            clips = [replace(c, loop=cycles(parents, c, height)) for c in clips]
            held = [c.name for c in clips if not c.loop]
            if held:
                notes.append(f"clips played once, their last pose held (it does not meet the first): {', '.join(held)}")
        return Character(
            name=path.stem,
            vertices=verts @ u[:3, :3].T + u[:3, 3],
            triangles=tris,
            primitive_ids=prim_ids,
            joint_names=names,
            parents=parents,
            rest_local=rest_local,
            inverse_bind=fold.inverse_bind(ibm, u),
            skin_joints=sj,
            skin_weights=sw,
            clips=tuple(clips),
            root_joint=root_joint,
            source=str(path),
            notes=tuple(notes),
        )
    except ValueError as e:  # a ContractError here means the file holds something we mis-read
        raise InputError(path, f"inconsistent content: {e}") from None


# a clip is a cycle when its last pose is this close to its first (joint positions relative to the
# root), as a share of the height or of the clip's largest step between keys, whichever is larger:
# CesiumMan's walk ends 1.3 % of its height from its start (largest step 5.8 %); Kenney's 'die' 72 %
# (21 %), its wheelchair look 3.9 % (0.8 %: a turn of the head that stays)
CYCLE_GAP = 0.01
CYCLE_STEPS = 1.5


def cycles(parents, clip, height: float) -> bool:
    """Whether the clip's last pose meets its first (a cycle that loops without a jump); height: the
    character's, metres (the clip's units)."""
    from stages.rig.transforms import forward_kinematics
    if clip.times.size < 2 or not height > 0:
        return True
    keys = np.concatenate([np.arange(clip.times.size), [0]])
    local = trs_to_matrix(clip.translations[keys], clip.rotations[keys], clip.scales[keys])
    pos = np.stack([forward_kinematics(parents, m)[:, :3, 3] for m in local])
    root = int(np.flatnonzero(np.asarray(parents) < 0)[0])
    rel = pos - pos[:, root:root + 1]
    steps = np.linalg.norm(np.diff(rel, axis=0), axis=2).max(axis=1)     # key to key, the last: back to the first
    return bool(steps[-1] <= max(CYCLE_GAP * height, CYCLE_STEPS * steps[:-1].max(initial=0.0)))


def _bake_clips(path, doc, rd, order, index_of, rest_trs, convert_trs, loop, cubic_rate, cubic_tol):
    clips = []
    names_seen: set[str] = set()
    for ai, anim in enumerate(doc.animations or []):
        chans = []
        for ci, ch in enumerate(anim.channels or []):
            tgt = ch.target
            if tgt is None or tgt.node not in index_of or tgt.path not in _PATH_SIZES:
                continue
            if ch.sampler is None or not 0 <= ch.sampler < len(anim.samplers or []):
                raise InputError(path, f"animation {ai} channel {ci}: sampler {ch.sampler} does not exist")
            smp = anim.samplers[ch.sampler]
            interp = smp.interpolation or "LINEAR"
            if interp not in ("LINEAR", "STEP", "CUBICSPLINE"):
                raise InputError(path, f"animation {ai} sampler {ch.sampler}: unknown interpolation {interp!r}")
            where = f"animation {ai} sampler {ch.sampler}"
            kt = rd.accessor(smp.input, f"{where} input")
            if kt.shape[1] != 1 or kt.shape[0] == 0:
                raise InputError(path, f"{where}: input must be a non-empty SCALAR accessor")
            kt = kt[:, 0]
            if np.any(np.diff(kt) < 0):
                raise InputError(path, f"{where}: key times decrease")
            vals = rd.accessor(smp.output, f"{where} output")
            c = _PATH_SIZES[tgt.path]
            want = kt.size * (3 if interp == "CUBICSPLINE" else 1)
            if vals.shape != (want, c):
                raise InputError(path, f"{where}: output has shape {vals.shape}, expected ({want}, {c}) for {tgt.path}")
            if tgt.path == "rotation" and interp != "CUBICSPLINE":
                norms = np.linalg.norm(vals, axis=1, keepdims=True)
                if np.any(norms < 1e-9):
                    raise InputError(path, f"{where}: zero-length rotation quaternion")
                vals = vals / norms
            chans.append((index_of[tgt.node], tgt.path, interp, kt, vals))
        if not chans:
            continue
        all_step = all(c[2] == "STEP" for c in chans)
        keys = [c[3] for c in chans]
        dense = []
        if not all_step:
            for j, p, interp, kt, vals in chans:
                if interp == "STEP" and kt.size > 1:
                    gaps = np.diff(kt)
                    eps = np.minimum(_STEP_EPS, 0.5 * np.where(gaps > 0, gaps, np.inf))
                    keys.append((kt[1:] - eps)[gaps > 0])
                elif interp == "CUBICSPLINE" and kt.size > 1:
                    dense.append(_cubic_bake_times(kt, vals, p, cubic_rate, cubic_tol))
        times = np.unique(np.concatenate(keys))
        if dense:  # dense samples within 0.1 us of a key add nothing but near-duplicate keys
            extra = np.unique(np.concatenate(dense))
            i = np.clip(np.searchsorted(times, extra), 1, times.size - 1) if times.size > 1 else np.zeros(extra.size, int)
            near = np.minimum(np.abs(extra - times[i]), np.abs(extra - times[np.maximum(i - 1, 0)]))
            times = np.union1d(times, extra[near > 1e-7])
        nk, nj = times.size, len(order)
        tr = np.empty((nk, nj, 3))
        rot = np.empty((nk, nj, 4))
        sc = np.empty((nk, nj, 3))
        for j, (t0, q0, s0) in enumerate(rest_trs):
            tr[:, j], rot[:, j], sc[:, j] = t0, q0, s0
        for j, p, interp, kt, vals in chans:
            v = sample_gltf_channel(kt, vals, interp, p, times)
            {"translation": tr, "rotation": rot, "scale": sc}[p][:, j] = v
        for j in range(nj):
            tr[:, j], rot[:, j], sc[:, j] = convert_trs(j, tr[:, j], rot[:, j], sc[:, j])
        rot /= np.linalg.norm(rot, axis=-1, keepdims=True)
        name = anim.name or f"animation_{ai}"
        base, k = name, 1
        while name in names_seen:
            k += 1
            name = f"{base}_{k}"
        names_seen.add(name)
        clips.append(Clip(name=name, times=times, translations=tr, rotations=rot, scales=sc,
                          interpolation="step" if all_step else "linear", loop=loop))
    return clips

