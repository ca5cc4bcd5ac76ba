"""The garment contract: a triangle mesh turned into a mass-spring particle system (paper A §1).

Frames: garment positions are in the *relative frame* at frame 0 (world itself at frame 0; see
stages/rig/types.py). Attached particles store their position in the bone-local frame of the joint
they follow (at frame t: `Motion.joint_world[t, j] @ attach_local`).

`build_garment` makes a Garment from any triangle mesh:
- particles = vertices; stretch/shear springs (kind 0) = unique mesh edges; bend springs (kind 1)
  = the two opposite vertices of each pair of triangles sharing an edge; rest lengths from the
  rest shape, lumped masses from an area density;
- attachment selectors (`attach_indices`, `attach_near`, `attach_top_loop`) resolved at the bind pose;
- attached particles that a collider of another bone passes through during the motion (an arm
  swinging through a waistband) yield to collisions, with a warning (`swept_attachments`).
Degenerate input is repaired with a warning (zero-area / repeated triangles dropped, coincident
vertices welded, unused ones removed) or refused (InputError: non-manifold, empty, non-finite).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from stages.checks import ContractError, check_array, check_index
from stages.errors import InputError
from stages.garments.band import collider_list as _colliders
from stages.garments.band import band_contacts, held_by, resting_limbs, with_pinching_limbs
from stages.garments.band import signed_distance as _signed_distance
from stages.geometry.mesh import boundary_loops

STRETCH = 0  # spring kind: mesh edge (stretch / shear)
COMMON_BONE = "common"   # Attachment.joint: the lowest common ancestor of the nearest bones
TRUNK_BONE = "trunk"     # Attachment.joint: per particle, the bone of the nearest collider not on a limb
BEND = 1     # spring kind: opposite vertices of two adjacent triangles


@dataclass(frozen=True)
class Garment:
    """A garment ready to simulate.

    name: garment name (used in entity paths, e.g. sim/<name>/mesh).
    positions: (N, 3) float64, metres, relative frame at frame 0: the initial particle positions.
    rest_positions: (N, 3) float64, metres, the rest shape the rest lengths come from (may equal
        positions; e.g. a flat pattern placed around the body has its own rest shape).
    triangles: (T, 3) int32, indices into positions (orientation gives the rendered normals).
    springs: (S, 2) int32, particle index pairs, i < j.
    rest_lengths: (S,) float64, metres, > 0.
    kinds: (S,) int8, STRETCH (0) or BEND (1).
    inverse_mass: (N,) float64, 1/kg, >= 0; 0 = pinned (to its bone, or fixed in place when
        attach_joint is -1).
    attach_joint: (N,) int32, -1 = not attached; else the joint whose bone the particle follows: it
        is put on its bone at the start of every step and is pinned for the springs. With inverse mass
        0 it stays there (rigid attachment, paper A §3.2); with a positive one (its lumped mass) it
        yields to the collision response: a collider may push it off its bone for the rest of the
        step (`swept_attachments`).
    attach_local: (N, 3) float64, metres, bone-local position of attached particles (0 for others).
    density: area density used for the masses, kg/m^2. stretch_stiffness, bend_stiffness: share of a
        correction per round at 300/s (SimParams, the garment's fabric), None: the simulation's.
    passing_joints: joints whose colliders never push this garment: limbs it does not wrap that rest
        on its attached band in most frames (stages.garments.band.resting_limbs) or that come against a
        limb it is worn round (stages.garments.band.pinching_limbs); the simulation adds them to its
        ignore_colliders.
    contact_zones: (N,) uint64 or None: a bit per exclusion zone; the cloth x cloth phase does not
        test a pair of features whose particles share a zone (the sewing's seams while they close,
        stages.garments.sewing.seam_zones).
    """

    name: str
    positions: np.ndarray
    rest_positions: np.ndarray
    triangles: np.ndarray
    springs: np.ndarray
    rest_lengths: np.ndarray
    kinds: np.ndarray
    inverse_mass: np.ndarray
    attach_joint: np.ndarray
    attach_local: np.ndarray
    density: float = 0.2
    stretch_stiffness: float | None = None
    bend_stiffness: float | None = None
    passing_joints: tuple = ()
    contact_zones: np.ndarray | None = None

    def __post_init__(self):
        o = f"Garment[{self.name!r}]"
        if any(v is not None and not 0.0 <= v <= 1.0 for v in (self.stretch_stiffness, self.bend_stiffness)):
            raise ContractError(f"{o}: stretch_stiffness / bend_stiffness: expected a share in [0, 1]")
        x = check_array(o, "positions", self.positions, (None, 3), np.float64)
        n = x.shape[0]
        if n == 0:
            raise ContractError(f"{o}.positions: a garment needs at least one particle")
        check_array(o, "rest_positions", self.rest_positions, (n, 3), np.float64)
        check_array(o, "triangles", self.triangles, (None, 3), np.int32)
        check_index(o, "triangles", self.triangles, n)
        s = check_array(o, "springs", self.springs, (None, 2), np.int32)
        check_index(o, "springs", s, n)
        if s.size and np.any(s[:, 0] >= s[:, 1]):
            raise ContractError(f"{o}.springs: expected i < j in every spring")
        nl = s.shape[0]
        r = check_array(o, "rest_lengths", self.rest_lengths, (nl,), np.float64)
        if np.any(r <= 0):
            raise ContractError(f"{o}.rest_lengths: rest lengths must be positive")
        k = check_array(o, "kinds", self.kinds, (nl,), np.int8)
        if np.any((k != STRETCH) & (k != BEND)):
            raise ContractError(f"{o}.kinds: expected 0 (stretch) or 1 (bend)")
        w = check_array(o, "inverse_mass", self.inverse_mass, (n,), np.float64)
        if np.any(w < 0):
            raise ContractError(f"{o}.inverse_mass: must be >= 0")
        aj = check_array(o, "attach_joint", self.attach_joint, (n,), np.int32)
        if np.any(aj < -1):
            raise ContractError(f"{o}.attach_joint: expected -1 or a joint index")
        check_array(o, "attach_local", self.attach_local, (n, 3), np.float64)
        if self.contact_zones is not None:
            check_array(o, "contact_zones", self.contact_zones, (n,), np.uint64)

    @property
    def n_particles(self) -> int:
        return int(self.positions.shape[0])

    @property
    def attached(self) -> np.ndarray:
        """Indices of particles following a bone (rigidly or yielding)."""
        return np.flatnonzero(self.attach_joint >= 0)

    @property
    def yielding(self) -> np.ndarray:
        """Indices of attached particles that yield to the collision response (inverse mass > 0)."""
        return np.flatnonzero((self.attach_joint >= 0) & (self.inverse_mass > 0))


# ---------------------------------------------------------------------------------------------
# attachment selectors

@dataclass(frozen=True)
class Attachment:
    """One attachment selector (paper A §3.2 geometric constraints).

    kind: 'indices' (explicit particle indices), 'near' (particles within `radius` metres of a
        collider or joint in the bind pose) or 'top_loop' (the highest boundary loop, e.g. a
        skirt's waistband).
    indices: particle indices for 'indices' (indices into the positions given to build_garment).
    target: 'near': a collider name, joint name or joint index. The bone followed is the
        collider's bone / that joint.
    joint: joint name or index to follow for 'indices' and 'top_loop'; None = the bone of the
        nearest collider (or nearest joint origin when no colliders are given), per particle;
        COMMON_BONE = one bone for all: the lowest common ancestor of those per-particle bones (a
        run pinned to bones that move apart, a T-shirt's shoulder line on neck, clavicle and upper
        arm, would be torn between them); TRUNK_BONE = per particle, the bone of the nearest collider
        of a joint that is not on a limb (BindPose.limb_joints): a waistband follows the hips and
        spine, never the hand hanging beside it, which would drag it along.
    radius: metres, for 'near'.
    """

    kind: str
    indices: tuple[int, ...] = ()
    target: str | int | None = None
    joint: str | int | None = None
    radius: float = 0.0

    def __post_init__(self):
        if self.kind not in ("indices", "near", "top_loop"):
            raise ContractError(f"Attachment.kind: expected 'indices', 'near' or 'top_loop', got {self.kind!r}")
        if self.kind == "near" and (self.target is None or not self.radius > 0):
            raise ContractError("Attachment 'near' needs a target and a positive radius")


def attach_indices(indices, joint: str | int | None = None) -> Attachment:
    return Attachment("indices", indices=tuple(int(i) for i in np.asarray(indices).ravel()), joint=joint)


def attach_near(target: str | int, radius: float) -> Attachment:
    return Attachment("near", target=target, radius=float(radius))


def attach_top_loop(joint: str | int | None = None) -> Attachment:
    return Attachment("top_loop", joint=joint)


@dataclass(frozen=True)
class BindPose:
    """What attachment selectors need from the character at frame 0 of the motion.

    joint_world: (J, 4, 4) float64, Motion.joint_world[0] (bone-local -> relative frame).
    joint_origins: (J, 3) float64, metres, joint positions at frame 0, relative frame.
    joint_names: J names. colliders: optional ColliderSet (for 'near' a collider).
    poses: optional (F, J, 4, 4) float64, Motion.joint_world at every frame: attachments are checked
        against the colliders of the other bones over these frames (`swept_attachments`).
    parents: optional (J,) int32, the joint hierarchy (-1 = root; for Attachment joint COMMON_BONE).
    collider_frames: optional (F, J + B, 4, 4) float64, ColliderSet.frame_poses over the poses (the
        joints, then the skinned balls); None when the colliders have no balls (= poses).
    limb_joints: the joints of the character's arms and legs (stages.rig.humanoid.limb_joint_sets;
        for Attachment joint TRUNK_BONE); empty when none are found. arm_joints: those of its arms.
    """

    joint_world: np.ndarray
    joint_origins: np.ndarray
    joint_names: tuple[str, ...]
    colliders: object = None
    poses: np.ndarray | None = None
    parents: np.ndarray | None = None
    collider_frames: np.ndarray | None = None
    limb_joints: frozenset = frozenset()
    arm_joints: frozenset = frozenset()

    def frames_of_colliders(self) -> np.ndarray | None:
        """(F, J + B, 4, 4) the transforms colliders are posed by (ColliderSet pose_index), or None."""
        return self.collider_frames if self.collider_frames is not None else self.poses

    def collider_to_local(self, pose_index: int, points: np.ndarray) -> np.ndarray:
        """Relative-frame points (frame 0) in the frame of the collider posed by `pose_index`."""
        if self.collider_frames is None:
            return self.to_local(pose_index, points)
        m = np.linalg.inv(self.collider_frames[0, pose_index])
        return points @ m[:3, :3].T + m[:3, 3]

    def __post_init__(self):
        j = len(self.joint_names)
        if self.parents is not None:
            check_array("BindPose", "parents", self.parents, (j,), np.int32)
        check_array("BindPose", "joint_world", self.joint_world, (j, 4, 4), np.float64)
        check_array("BindPose", "joint_origins", self.joint_origins, (j, 3), np.float64)
        if self.poses is not None:
            check_array("BindPose", "poses", self.poses, (None, j, 4, 4), np.float64)

    def joint_index(self, key) -> int:
        if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
            if 0 <= key < len(self.joint_names):
                return int(key)
        elif key in self.joint_names:
            return self.joint_names.index(key)
        raise InputError("attachment", f"unknown joint {key!r}; joints: {list(self.joint_names)}")

    def to_local(self, joint: int, points: np.ndarray) -> np.ndarray:
        m = np.linalg.inv(self.joint_world[joint])
        return points @ m[:3, :3].T + m[:3, 3]


def bind_pose(character, motion, colliders=None) -> BindPose:
    """The bind pose of attachments: frame 0 of `motion` (relative frame), with all its poses."""
    jw = np.ascontiguousarray(motion.joint_world[0], dtype=np.float64)  # bone-local -> relative frame
    frames = None
    if colliders is not None and getattr(colliders, "balls", None) is not None:
        frames = np.ascontiguousarray(colliders.frame_poses(character.inverse_bind, motion.joint_world))
    return BindPose(jw, np.ascontiguousarray(jw[:, :3, 3]), tuple(character.joint_names), colliders,
                    np.ascontiguousarray(motion.joint_world, dtype=np.float64),
                    np.ascontiguousarray(character.parents, dtype=np.int32), frames, *_limb_joints(character))


def _limb_joints(character) -> tuple[frozenset, frozenset]:
    """The joints of the character's arms and legs, and of its arms, found by name or shape (empty
    when none are)."""
    from stages.rig.humanoid import limb_joint_sets
    parts = limb_joint_sets(character)
    return (frozenset(int(j) for part in parts.values() for j in part),
            frozenset(int(j) for k in ("arm_l", "arm_r") for j in parts[k]))


def _collider_distances(bind: BindPose, points: np.ndarray, joints=None):
    """(C, N) signed distances of points to every collider in the bind pose (`_signed_distance`),
    the (C,) bones they follow and their names; only the colliders of the bones in `joints` if given."""
    cols = _colliders(bind.colliders)
    if joints is not None:
        cols = [c for c in cols if int(c[0]) in joints]
    if not cols:
        return np.zeros((0, points.shape[0])), np.zeros(0, np.int32), []
    d = np.array([_signed_distance(c, bind.collider_to_local(frame, points)) for _, _, c, frame in cols])
    return d, np.array([b for b, _, _, _ in cols], np.int32), [n for _, n, _, _ in cols]


def _nearest_bone(bind: BindPose, points: np.ndarray, skip=frozenset()) -> np.ndarray:
    """Per point, the bone of the nearest collider (or joint origin without colliders), bones in
    `skip` left out unless that leaves none."""
    if bind.colliders is not None and (bind.colliders.hulls or bind.colliders.spheres):
        d, bones, _ = _collider_distances(bind, points)
        keep = np.array([int(b) not in skip for b in bones], bool)
        if keep.any():
            d, bones = d[keep], bones[keep]
        return bones[np.argmin(d, axis=0)]
    d = np.linalg.norm(points[None, :, :] - bind.joint_origins[:, None, :], axis=2)
    keep = np.array([j not in skip for j in range(d.shape[0])], bool)
    if keep.any():
        d[~keep] = np.inf
    return np.argmin(d, axis=0).astype(np.int32)


def _select(att: Attachment, x0: np.ndarray, triangles: np.ndarray, remap: np.ndarray, bind: BindPose):
    """(particle indices, joints followed) of one selector, in welded indexing."""
    if att.kind == "indices":
        idx = np.asarray(att.indices, dtype=np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= remap.size):
            bad = int(idx[(idx < 0) | (idx >= remap.size)][0])
            raise InputError("attachment", f"pinned particle index {bad} out of range [0, {remap.size})")
        idx = remap[idx]
        if np.any(idx < 0):
            raise InputError("attachment", "an attached index refers to a vertex no triangle uses")
        idx = np.unique(idx)
    elif att.kind == "top_loop":
        loops = boundary_loops(triangles)
        if not loops:
            raise InputError("attachment", "'top_loop' on a mesh without boundary")
        idx = np.unique(max(loops, key=lambda lp: (x0[lp, 1].mean(), -int(lp.min()))))
    else:  # near
        t = att.target
        names = []
        if bind.colliders is not None:
            d, bones, names = _collider_distances(bind, x0)
        if isinstance(t, str) and t in names:
            c = names.index(t)
            idx = np.flatnonzero(d[c] <= att.radius)
            joints = np.full(idx.size, bones[c], np.int32)
        else:
            j = bind.joint_index(t)
            idx = np.flatnonzero(np.linalg.norm(x0 - bind.joint_origins[j], axis=1) <= att.radius)
            joints = np.full(idx.size, j, np.int32)
        if idx.size == 0:
            raise InputError("attachment", f"no particle within {att.radius} m of {t!r} in the bind pose")
        return idx, joints
    if att.joint == COMMON_BONE:
        joints = np.full(idx.size, _common_ancestor(bind, _nearest_bone(bind, x0[idx])), np.int32)
    elif att.joint == TRUNK_BONE:
        joints = _nearest_bone(bind, x0[idx], skip=bind.limb_joints)
    elif att.joint is not None:
        joints = np.full(idx.size, bind.joint_index(att.joint), np.int32)
    else:
        joints = _nearest_bone(bind, x0[idx])
    return idx, joints


def _common_ancestor(bind: BindPose, bones: np.ndarray) -> int:
    """The deepest joint that is an ancestor of (or equal to) every one of `bones`."""
    if bind.parents is None:
        raise InputError("attachment", "joint 'common' needs the joint hierarchy (BindPose.parents)")

    def chain(j):
        out = []
        while j >= 0:
            out.append(int(j))
            j = bind.parents[j]
        return out[::-1]      # root first

    chains = [chain(b) for b in np.unique(bones)]
    common = -1
    for level in zip(*chains):
        if len(set(level)) > 1:
            break
        common = level[0]
    if common < 0:
        raise InputError("attachment", "the pinned bones have no common ancestor")
    return common


# ---------------------------------------------------------------------------------------------
# construction

def _repair(name: str, x: np.ndarray, rest: np.ndarray, tri: np.ndarray):
    """Weld coincident vertices, drop degenerate / repeated triangles and unused vertices.

    Returns (x, rest, tri, remap, kept) with remap: original vertex index -> new index (-1 = removed)
    and kept: indices of the input triangles kept, in output order.
    """
    n = x.shape[0]
    scale = max(float(np.ptp(rest, axis=0).max()), 1e-12)
    # weld: vertices whose rest AND initial positions coincide (to 1e-9 of the mesh size)
    q = np.round(np.hstack([rest, x]) / (scale * 1e-9)).astype(np.int64)
    _, first, inv = np.unique(q, axis=0, return_index=True, return_inverse=True)
    inv = inv.ravel()
    weld = first[inv]
    if np.any(weld != np.arange(n)):
        used = np.unique(tri)
        dup = int(np.sum(weld[used] != used))
        if dup:
            warnings.warn(f"garment {name!r}: welded {dup} coincident vertices", stacklevel=3)
    tri = weld[tri]
    a, b, c = rest[tri[:, 0]], rest[tri[:, 1]], rest[tri[:, 2]]
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    bad = (tri[:, 0] == tri[:, 1]) | (tri[:, 1] == tri[:, 2]) | (tri[:, 0] == tri[:, 2]) | (area2 <= 1e-12 * scale * scale)
    kept = np.flatnonzero(~bad)
    if bad.any():
        warnings.warn(f"garment {name!r}: dropped {int(bad.sum())} degenerate (zero-area) triangles", stacklevel=3)
        tri = tri[~bad]
    _, keep = np.unique(np.sort(tri, axis=1), axis=0, return_index=True)
    if keep.size < tri.shape[0]:
        warnings.warn(f"garment {name!r}: dropped {tri.shape[0] - keep.size} repeated triangles", stacklevel=3)
        tri = tri[np.sort(keep)]
        kept = kept[np.sort(keep)]
    if tri.shape[0] == 0:
        raise InputError(f"garment {name!r}", "no non-degenerate triangle")
    used = np.unique(tri)
    unused = np.setdiff1d(np.unique(weld), used)
    if unused.size:
        warnings.warn(f"garment {name!r}: removed {unused.size} vertices no triangle uses", stacklevel=3)
    new = np.full(n, -1, np.int64)
    new[used] = np.arange(used.size)
    remap = new[weld]
    return x[used], rest[used], new[tri].astype(np.int32), remap, kept


def build_garment(name: str, positions, triangles, *, rest_positions=None, density: float = 0.2,
                  attachments=(), bind: BindPose | None = None, triangle_rest=None, extra_springs=None,
                  extra_rest_lengths=None, yield_swept: bool = True, ignore_joints=()) -> Garment:
    """A Garment from a triangle mesh.

    positions: (N, 3) initial positions, metres, relative frame at frame 0.
    triangles: (T, 3) vertex indices.
    rest_positions: (N, 3) rest shape for the rest lengths and masses (default: positions).
    density: area density, kg/m^2 (lumped: each triangle gives a third of its mass to each vertex).
    attachments: Attachment selectors; each chosen particle gets inverse mass 0 and follows its
        bone rigidly. `bind` (see `bind_pose`) is required when there are attachments.
    triangle_rest: optional (T, 3) rest lengths, metres, of each triangle's edges (edge k joins
        vertex k and k+1 mod 3), for meshes whose rest state is not one embedding (a sewn garment:
        each triangle keeps its flat-panel shape). Stretch rest lengths are then the mean over the
        edge's triangles, bend rest lengths the distance of the hinge unfolded flat, masses from the
        triangles' areas (Heron); rest_positions are only used for welding.
    extra_springs: optional (K, 2) vertex index pairs added as stretch springs (e.g. seam springs
        pulling panel edges together while sewing), with extra_rest_lengths (K,) metres > 0.
    yield_swept: the attached particles that a collider of another bone holds deeper than its
        inflation delta at some frame of bind.poses keep their mass and yield to the collision
        response (see Garment.attach_joint), with a warning (`swept_attachments`); the colliders of
        the joints in `ignore_joints` (which the simulation will not let push this garment) do not count.
    """
    where = f"garment {name!r}"
    passing = []          # limbs resting on the band (band.resting_limbs)
    x = np.asarray(positions, dtype=np.float64)
    tri = np.asarray(triangles)
    if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] == 0:
        raise InputError(where, f"positions must be (N, 3), got {x.shape}")
    if tri.ndim != 2 or tri.shape[1] != 3 or tri.shape[0] == 0 or tri.dtype.kind not in "iu":
        raise InputError(where, f"triangles must be a non-empty (T, 3) integer array, got {tri.shape} {tri.dtype}")
    if tri.min() < 0 or tri.max() >= x.shape[0]:
        raise InputError(where, "triangle index out of range")
    rest = x if rest_positions is None else np.asarray(rest_positions, dtype=np.float64)
    if rest.shape != x.shape:
        raise InputError(where, f"rest_positions shape {rest.shape} differs from positions {x.shape}")
    if not (np.isfinite(x).all() and np.isfinite(rest).all()):
        raise InputError(where, "non-finite vertex position")
    if not (np.isfinite(density) and density > 0):
        raise InputError(where, f"density must be positive, got {density}")
    t_in = tri.shape[0]
    x, rest, tri, remap, kept = _repair(name, x, rest, tri.astype(np.int64))
    n = x.shape[0]
    tri_rest = None
    if triangle_rest is not None:
        tri_rest = np.asarray(triangle_rest, dtype=np.float64)
        if tri_rest.shape != (t_in, 3) or not np.isfinite(tri_rest).all() or np.any(tri_rest <= 0):
            raise InputError(where, f"triangle_rest must be ({t_in}, 3) positive lengths, got {tri_rest.shape}")
        tri_rest = tri_rest[kept]

    # stretch/shear: unique edges; count the triangles on each edge for manifoldness
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    opp = np.concatenate([tri[:, 2], tri[:, 0], tri[:, 1]])
    key = np.sort(e, axis=1)
    edges, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    if np.any(cnt > 2):
        bad = edges[np.argmax(cnt > 2)]
        raise InputError(where, f"non-manifold: edge ({bad[0]}, {bad[1]}) is shared by {cnt.max()} triangles")
    # bend: the two opposite vertices of every interior edge
    order = np.argsort(inv, kind="stable")
    si = inv[order]
    pair = np.flatnonzero(si[1:] == si[:-1])
    bend = np.sort(np.stack([opp[order[pair]], opp[order[pair + 1]]], axis=1), axis=1)
    bend = bend[bend[:, 0] != bend[:, 1]]
    bend = np.unique(bend, axis=0)
    # a bend pair that is also an edge (tiny closed meshes) would be a duplicate spring
    if bend.size:
        ecode = edges[:, 0] * n + edges[:, 1]
        bend = bend[~np.isin(bend[:, 0] * n + bend[:, 1], ecode)]
    springs = np.concatenate([edges, bend]).astype(np.int32)
    kinds = np.concatenate([np.full(len(edges), STRETCH, np.int8), np.full(len(bend), BEND, np.int8)])
    if tri_rest is None:
        rest_len = np.linalg.norm(rest[springs[:, 1]] - rest[springs[:, 0]], axis=1)
        a, b, c = rest[tri[:, 0]], rest[tri[:, 1]], rest[tri[:, 2]]
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    else:
        rest_len, area = _rest_from_triangles(tri, tri_rest, edges, bend, n)
    if extra_springs is not None:
        es = np.asarray(extra_springs, dtype=np.int64).reshape(-1, 2)
        el = np.asarray(extra_rest_lengths if extra_rest_lengths is not None else [], dtype=np.float64).ravel()
        if el.shape != (es.shape[0],) or not (np.isfinite(el).all() and np.all(el > 0)):
            raise InputError(where, "extra_rest_lengths must give one positive length per extra spring")
        if es.size and (es.min() < 0 or es.max() >= remap.size):
            raise InputError(where, "extra spring index out of range")
        es = remap[es]
        if np.any(es < 0):
            raise InputError(where, "an extra spring uses a vertex no triangle uses")
        ok = es[:, 0] != es[:, 1]
        es, el = np.sort(es[ok], axis=1), el[ok]
        springs = np.concatenate([springs, es]).astype(np.int32)
        kinds = np.concatenate([kinds, np.full(len(es), STRETCH, np.int8)])
        rest_len = np.concatenate([rest_len, el])
    if np.any(rest_len <= 0):
        raise InputError(where, "a spring has zero rest length (coincident rest vertices)")

    mass = np.bincount(tri.ravel(), weights=np.repeat(area * density / 3.0, 3), minlength=n)
    inv_mass = 1.0 / mass

    attach_joint = np.full(n, -1, np.int32)
    attach_local = np.zeros((n, 3))
    if attachments:
        if bind is None:
            raise InputError(where, "attachments need the bind pose (bind=bind_pose(character, motion, colliders))")
        for att in attachments:
            idx, joints = _select(att, x, tri, remap, bind)
            attach_joint[idx] = joints
        for j in np.unique(attach_joint[attach_joint >= 0]):
            sel = attach_joint == j
            attach_local[sel] = bind.to_local(int(j), x[sel])
        rigid = attach_joint >= 0
        if yield_swept and bind.colliders is not None:
            att = np.flatnonzero(rigid)
            ignore = set(int(j) for j in ignore_joints)
            local, joints, delta = attach_local[att], attach_joint[att], bind.colliders.delta
            contacts = band_contacts(bind, local, joints, delta, ignore)      # once: every frame x collider
            passing = resting_limbs(bind, x, local, joints, delta, contacts=contacts)
            if passing:
                warnings.warn(f"garment {name!r}: the colliders of {', '.join(bind.joint_names[j] for j in passing)} "
                              f"rest on its attached band in most frames and pass through the garment (a limb it "
                              f"does not wrap lying where the band must be; the body audit counts the cloth under "
                              f"it as inside the body)", stacklevel=2)
            passing = with_pinching_limbs(name, bind, x, passing, ignore)
            swept, names = held_by(contacts, att.size, skip=passing)
            if swept.any():
                warnings.warn(f"garment {name!r}: {int(swept.sum())} of {att.size} attached particles yield to "
                              f"collisions: the colliders {', '.join(names)} pass through them during "
                              f"the motion (a limb swinging through the garment: its joint in the garment's "
                              f"ignore_colliders lets it pass through the cloth instead)", stacklevel=2)
                rigid[att[swept]] = False
        inv_mass[rigid] = 0.0
    return Garment(name, np.ascontiguousarray(x), np.ascontiguousarray(rest), np.ascontiguousarray(tri),
                   springs, rest_len, kinds, inv_mass, attach_joint, attach_local, float(density),
                   passing_joints=tuple(passing))


def _rest_from_triangles(tri, tri_rest, edges, bend, n):
    """Rest lengths of stretch and bend springs and triangle areas from per-triangle edge lengths."""
    # edge keys a * n + b in int64: in int32 they wrap above 46,340 particles
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]).astype(np.int64)
    le = np.concatenate([tri_rest[:, 0], tri_rest[:, 1], tri_rest[:, 2]])
    code = np.sort(e, axis=1) @ np.array([n, 1], np.int64)
    ecode = edges[:, 0].astype(np.int64) * n + edges[:, 1]
    idx = np.searchsorted(ecode, code)
    stretch = np.bincount(idx, weights=le, minlength=len(edges)) / np.bincount(idx, minlength=len(edges))
    l0, l1, l2 = tri_rest[:, 0], tri_rest[:, 1], tri_rest[:, 2]
    s = 0.5 * (l0 + l1 + l2)
    area = np.sqrt(np.maximum(s * (s - l0) * (s - l1) * (s - l2), 0.0))
    if not len(bend):
        return stretch, area
    # bend: unfold the two triangles of every interior edge into a plane (shared edge on the x axis)
    t_of = np.concatenate([np.arange(len(tri))] * 3)
    k_of = np.repeat([0, 1, 2], len(tri))
    order = np.argsort(code, kind="stable")
    sc = code[order]
    first = np.flatnonzero(np.r_[True, sc[1:] != sc[:-1]])
    pos = {}
    for f in first:
        if f + 1 < len(sc) and sc[f + 1] == sc[f]:
            o1, o2 = order[f], order[f + 1]
            t1, k1, t2, k2 = t_of[o1], k_of[o1], t_of[o2], k_of[o2]
            c1, c2 = tri[t1, (k1 + 2) % 3], tri[t2, (k2 + 2) % 3]
            base = 0.5 * (tri_rest[t1, k1] + tri_rest[t2, k2])
            # apex of triangle t (edge k = a-b of length base) at distances da (from a), db (from b)
            p1 = _apex(base, tri_rest[t1, (k1 + 2) % 3], tri_rest[t1, (k1 + 1) % 3])
            # triangle t2 walks the shared edge in the other direction: its 'a' is t1's 'b'
            q = _apex(base, tri_rest[t2, (k2 + 2) % 3], tri_rest[t2, (k2 + 1) % 3])
            same = tri[t2, k2] == tri[t1, k1]   # inconsistently oriented neighbours walk it the same way
            if same:
                q = _apex(base, tri_rest[t2, (k2 + 1) % 3], tri_rest[t2, (k2 + 2) % 3])
            p2 = np.array([q[0] if same else base - q[0], -q[1]])
            pos[(min(c1, c2), max(c1, c2))] = float(np.linalg.norm(p1 - p2))
    bl = np.array([pos.get((int(a), int(b)), np.nan) for a, b in bend])
    return np.concatenate([stretch, bl]), area


def _apex(base, da, db):
    """Apex (x, y >= 0) of a triangle with base (0,0)-(base,0) and sides da (from 0), db (from base)."""
    x = (da * da - db * db + base * base) / (2 * base)
    return np.array([x, np.sqrt(max(da * da - x * x, 0.0))])


def edge_strain(garment: Garment, positions: np.ndarray) -> np.ndarray:
    """(S_stretch,) relative length change (L - L0) / L0 of the stretch/shear springs at `positions`."""
    s = garment.springs[garment.kinds == STRETCH]
    l0 = garment.rest_lengths[garment.kinds == STRETCH]
    p = np.asarray(positions, dtype=np.float64)
    return np.linalg.norm(p[s[:, 1]] - p[s[:, 0]], axis=1) / l0 - 1.0
