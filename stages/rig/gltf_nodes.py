"""glTF node tree -> skeleton, and the frame change from the file's world to the model frame.

The glTF spec places a skinned vertex at `sum_k w_k * global(joint_k) @ inverse_bind_k @ x`, where
global() multiplies every ancestor node's transform. The `Character` keeps rigid bone-local frames
(colliders live there), Y up, metres, feet on y = 0; `fold_frames` says how the nodes above the
skeleton, the up-axis rotation, the scale and the floor shift are folded in so that skinning stays
the spec's (module doc of stages.rig.gltf states what is exact).
The character is judged as the pipeline first shows it, the rest pose skinned (skeleton and mesh
together), whatever the file's bind space: `bind_to_rest` finds a turn or scale kept in the
inverse binds only, `detect_up` is the `up_axis: auto` rule (two limbs hanging side by side to
the floor; `Stance` per candidate up), `choose_units` the `scale: null` rule (metres unless
implausible for a biped or animal of that height; cm / mm, or one error naming the scale to set).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse
from scipy.sparse.csgraph import connected_components
from scipy.spatial.transform import Rotation

from stages.errors import InputError
from stages.rig.transforms import trs_to_matrix

# Rotation taking the file's up direction to +Y (the smallest one; +z is the usual Z-up -> Y-up
# export fix (x, y, z) -> (x, z, -y), which also turns Blender's forward -Y into glTF's +Z).
UP_ROTATIONS = {
    "+y": np.eye(3),
    "+z": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
    "-z": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),
    "+x": np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]),
    "-x": np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]]),
    "-y": np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]]),
}
_AXES = {"x": 0, "y": 1, "z": 2}


def up_vector(axis: str) -> np.ndarray:
    """'+z' -> (0, 0, 1) etc."""
    v = np.zeros(3)
    v[_AXES[axis[1]]] = 1.0 if axis[0] == "+" else -1.0
    return v


# --------------------------------------------------------------------------------------------
# Node transforms
# --------------------------------------------------------------------------------------------

def decompose(m: np.ndarray, what: str, path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """TRS (translation, quaternion xyzw, scale) of an affine 4x4 without shear."""
    t = m[:3, 3].copy()
    a = m[:3, :3]
    s = np.linalg.norm(a, axis=0)
    if np.any(s < 1e-12):
        raise InputError(path, f"{what}: singular transform (zero scale)")
    r = a / s
    if np.linalg.det(r) < 0:  # a mirror: put it in the x scale
        s[0] = -s[0]
        r[:, 0] = -r[:, 0]
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-5):
        raise InputError(path, f"{what}: transform has shear, which TRS animation cannot represent")
    return t, Rotation.from_matrix(r).as_quat(), s


def node_trs(node) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The node's TRS if given as TRS (None if it uses a matrix)."""
    if node.matrix is not None and not np.allclose(node.matrix, np.eye(4).ravel()):
        return None
    t = np.array(node.translation if node.translation is not None else [0, 0, 0], np.float64)
    q = np.array(node.rotation if node.rotation is not None else [0, 0, 0, 1], np.float64)
    s = np.array(node.scale if node.scale is not None else [1, 1, 1], np.float64)
    return t, q / np.linalg.norm(q), s


def node_matrix(node) -> np.ndarray:
    trs = node_trs(node)
    if trs is None:
        return np.array(node.matrix, np.float64).reshape(4, 4).T  # column-major in glTF
    return trs_to_matrix(*trs)


def parents_of_nodes(path, doc) -> dict[int, int]:
    """node -> parent node, with the tree checked (existing children, one parent, no cycle)."""
    parent: dict[int, int] = {}
    n_nodes = len(doc.nodes or [])
    for i, node in enumerate(doc.nodes or []):
        for c in node.children or []:
            if not 0 <= c < n_nodes:
                raise InputError(path, f"node {i} has child {c}, which does not exist")
            if c in parent:
                raise InputError(path, f"node {c} has two parents ({parent[c]} and {i})")
            parent[c] = i
    for i in range(n_nodes):  # cycle check
        seen, n = set(), i
        while n in parent:
            if n in seen:
                raise InputError(path, f"the node tree has a cycle through node {n}")
            seen.add(n)
            n = parent[n]
    return parent


def chain(parent: dict[int, int], n: int) -> list[int]:
    """n, its parent, ..., the top node."""
    out = [n]
    while out[-1] in parent:
        out.append(parent[out[-1]])
    return out


def _unique_names(names: list[str]) -> tuple[str, ...]:
    seen: dict[str, int] = {}
    out = []
    for n in names:
        if n in seen:
            seen[n] += 1
            n2 = f"{n}_{seen[n]}"
            while n2 in seen:
                seen[n] += 1
                n2 = f"{n}_{seen[n]}"
            n = n2
        seen.setdefault(n, 0)
        out.append(n)
    return tuple(out)


# --------------------------------------------------------------------------------------------
# Skeleton
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Skeleton:
    """The joints chosen from the node tree.

    order: J node indices, depth-first (parents[j] < j); -1 is the synthetic root '__root__'.
    parents: (J,) int32. names: J unique names.
    above: (4, 4) static transform of the nodes above the root (identity for a synthetic root).
    """

    order: list[int]
    parents: np.ndarray
    names: tuple[str, ...]
    above: np.ndarray

    @property
    def index_of(self) -> dict[int, int]:
        return {n: j for j, n in enumerate(self.order)}


def select_skeleton(nodes, parent: dict[int, int], joint_nodes: list[int], animated: set[int]) -> Skeleton:
    """Skin joints plus every node between them, up to their lowest common ancestor raised to the
    highest animated ancestor; a synthetic root when the joints share no ancestor."""
    chains = [chain(parent, j) for j in joint_nodes]
    common = set(chains[0]).intersection(*map(set, chains[1:]))
    if common:
        top = next(n for n in chains[0] if n in common)
        for n in chain(parent, top)[1:]:
            if n in animated:
                top = n
        synthetic = False
    else:
        top, synthetic = -1, True
    included: set[int] = set()
    for ch in chains:
        for n in ch:
            included.add(n)
            if n == top:
                break
    children = {n: [] for n in included}
    if synthetic:
        children[-1] = list(dict.fromkeys(ch[-1] for ch in chains))
    for n in included:
        for c in nodes[n].children or []:
            if c in included:
                children[n].append(c)
    order: list[int] = []
    stack = [top]
    while stack:  # depth-first pre-order, children in file order
        n = stack.pop()
        order.append(n)
        stack.extend(reversed(children[n]))
    index_of = {n: j for j, n in enumerate(order)}
    parents = np.array([-1] + [index_of[parent[n]] if n in parent and parent[n] in index_of else 0
                               for n in order[1:]], np.int32)
    names = _unique_names(["__root__" if n < 0 else (nodes[n].name or f"node_{n}") for n in order])
    above = np.eye(4)
    if not synthetic:
        for n in chain(parent, top)[1:]:
            above = node_matrix(nodes[n]) @ above
    return Skeleton(order=order, parents=parents, names=names, above=above)


# --------------------------------------------------------------------------------------------
# Bind space vs rest pose
# --------------------------------------------------------------------------------------------

def bind_to_rest(rest_world: np.ndarray, ibm: np.ndarray, joint_weight: np.ndarray,
                 size: float) -> tuple[np.ndarray, float]:
    """The one transform C taking the bind space to the rest pose's world, if the joints holding
    most of the skin weight agree on it: (C (4, 4), share of the skin weight whose joints agree with C).

    rest_world: (J, 4, 4) rest (node TRS) world transforms; ibm: (J, 4, 4) inverse binds (file
    frame); joint_weight: (J,) summed skin weights; size: the bind mesh's extent (file units).
    Joint k maps its bind-space points to the rest world by C_k = rest_world_k @ ibm_k; a file
    whose bind mesh is the rest pose has C_k = I for all. An exporter that turned (or scaled) the
    mesh but not the skeleton stores the turn in every inverse bind: all C_k = C. C is identity
    (bit-exact) when the agreeing C_k are within float32 noise of it, and when no C with a positive
    determinant is shared by half the skin weight (a genuine bind pose, per joint: kept as stored).
    """
    c = rest_world @ ibm
    lin = np.abs(np.linalg.det(c[:, :3, :3])) ** (1.0 / 3.0)
    total = float(joint_weight.sum())
    tol_t = 1e-4 * max(size, 1e-12)

    def agreeing(m: np.ndarray, s: float) -> float:
        close = ((np.abs(c[:, :3, :3] - m[:3, :3]).max(axis=(1, 2)) <= 1e-4 * s)
                 & (np.abs(c[:, :3, 3] - m[:3, 3]).max(axis=1) <= tol_t))
        return float(joint_weight[close].sum()) / total

    best, share = -1, 0.0
    for k in np.flatnonzero(joint_weight > 0):
        if lin[k] > 1e-12:
            w = agreeing(c[k], lin[k])
            if w > share + 1e-12:
                best, share = int(k), w
    if best >= 0 and share >= 0.5 and np.linalg.det(c[best, :3, :3]) > 0:
        m = c[best]
        if np.abs(m[:3, :3] - np.eye(3)).max() > 1e-4 or np.abs(m[:3, 3]).max() > tol_t:
            return m.copy(), share
    # float32 noise of a bind pose that is the rest pose, or no shared change: keep the file's bits
    return np.eye(4), agreeing(np.eye(4), 1.0)


# --------------------------------------------------------------------------------------------
# Stance: which file axis is up and what stands on the floor (`up_axis: auto`)
# --------------------------------------------------------------------------------------------

_CONTACT = 0.02    # share of the size within which a posed vertex (or joint) touches the floor
_STAND = 0.15      # two limbs must hang at least this share of the size for an up to stand
_SAME_LIMB = 0.3   # floor contacts that part less than this share of the best pair's hang: one limb


@dataclass(frozen=True)
class Stance:
    """How the posed character stands with one file direction taken as up (file units).

    axis: '+y', '-z', ...: the file direction taken as up.
    hang: over pairs of floor contacts, the largest min(drop of a, drop of b) from the highest
        joint on the tree path between them down to the floor: how far two limbs hang side by side
        (0 when fewer than two limb ends touch the floor).
    limbs: separate limbs touching the floor (2: a biped, 4: a quadruped; 0 or 1: a prop, a snake,
        a figure lying down).
    height: the posed mesh's extent along the axis.
    """

    axis: str
    hang: float
    limbs: int
    height: float

    @property
    def kind(self) -> str:
        """'biped' (two limbs on the floor), 'animal' (three or more) or 'unknown'."""
        return "biped" if self.limbs == 2 else "animal" if self.limbs > 2 else "unknown"

    def describe(self) -> str:
        """'biped with 2 limbs on the floor', ... for notes and errors."""
        if self.kind == "unknown":
            return "character of unknown kind (no two limbs on the floor)"
        return f"{self.kind} with {self.limbs} limbs on the floor"


def _chains(parents: np.ndarray) -> list[list[int]]:
    """Per joint: itself, its parent, ..., the root."""
    out = []
    for j in range(len(parents)):
        a = [j]
        while parents[a[-1]] >= 0:
            a.append(int(parents[a[-1]]))
        out.append(a)
    return out


def stance_along(axis: str, joint_pos: np.ndarray, parents: np.ndarray, vertices: np.ndarray,
                 vertex_joint: np.ndarray, chains: list | None = None) -> Stance:
    """The Stance of the posed character with file direction `axis` up.

    joint_pos: (J, 3) posed joint origins; parents: (J,), parents[j] < j, one root; vertices:
    (V, 3) the posed (skinned) mesh; vertex_joint: (V,) each vertex's strongest joint.
    Floor contacts: the joints owning a vertex, or placed, within 2 % of the size of the lowest
    vertex. A contact with another contact below it in the tree is no limb's end (the ankle above
    the toes, a long skirt's hip joint above the legs). The drop of an end below its common joint
    with another end is from the highest joint on the path between them, so a leg that is one
    joint at the hip with its mesh down to the foot (chibi rigs, the root on the floor) still hangs.
    Ends parting less than 30 % of the best pair's hang (or 15 % of the size) are one limb.
    """
    u = up_vector(axis)
    chains = chains if chains is not None else _chains(parents)
    hj = joint_pos @ u
    hv = vertices @ u
    floor, size = float(hv.min()), float(np.max(np.ptp(vertices, axis=0)))
    band = floor + _CONTACT * size
    touching = np.zeros(len(parents), bool)
    touching[np.unique(vertex_joint[hv <= band])] = True
    touching |= hj <= band
    end = touching.copy()
    for j in np.flatnonzero(touching):
        end[chains[j][1:]] = False
    ends = np.flatnonzero(end)
    depth = [{n: i for i, n in enumerate(chains[a])} for a in ends]
    top = [np.maximum.accumulate(hj[chains[a]]) for a in ends]  # highest joint from the end up to each ancestor
    drop = np.zeros((ends.size, ends.size))
    for i in range(ends.size):
        for k in range(i + 1, ends.size):
            c = next(n for n in chains[ends[k]] if n in depth[i])  # their lowest common ancestor
            drop[i, k] = drop[k, i] = min(top[i][depth[i][c]], top[k][depth[k][c]]) - floor
    hang = float(drop.max()) if ends.size > 1 else 0.0
    limbs = 0
    if ends.size:
        together = scipy.sparse.csr_matrix(drop < max(_SAME_LIMB * hang, _STAND * size))
        limbs = int(connected_components(together, directed=False)[0])
    return Stance(axis=axis, hang=hang, limbs=limbs, height=float(np.ptp(hv)))


def detect_up(joint_pos: np.ndarray, parents: np.ndarray, vertices: np.ndarray,
              vertex_joint: np.ndarray) -> tuple[str, dict[str, Stance]]:
    """The file's up direction among +-X, +-Y, +-Z (`up_axis: auto`) and every candidate's Stance.

    Skeleton and mesh together, posed as the pipeline first shows the character (the rest pose:
    the nodes' TRS, skinned), so that the bind space of the file does not matter. A standing
    character has (at least) two limbs that reach the floor separately: legs from the hips, a
    quadruped's legs from its hips or chest; a head, a tail or a hand is one limb, toes or fingers
    of one foot or hand part too low to count. The up with the largest `Stance.hang` wins when it
    beats +Y's by 25 % and is at least 15 % of the size; else '+y' (the glTF convention: no two
    such limbs, e.g. a snake, a prop, a single chain). Works for humanoids and quadrupeds alike
    (a quadruped's longest extent is horizontal, so the longest axis would be wrong).
    Assumes the rest pose stands on its legs (not lying, sitting or kneeling as modelled).
    Arguments as for `stance_along`.
    """
    chains = _chains(parents)
    size = float(np.max(np.ptp(vertices, axis=0)))
    stances = {a: stance_along(a, joint_pos, parents, vertices, vertex_joint, chains) for a in UP_ROTATIONS}
    axis = max(UP_ROTATIONS, key=lambda k: stances[k].hang)  # first of equals: +y
    if axis != "+y" and (stances[axis].hang < _STAND * size or stances[axis].hang <= 1.25 * stances["+y"].hang):
        axis = "+y"
    return axis, stances


# --------------------------------------------------------------------------------------------
# Units: metres, unless that makes the character implausibly large or small for its kind
# --------------------------------------------------------------------------------------------

# Plausible posed heights (metres): a biped from a doll-sized chibi to a giant, a four-legged animal
# from a mouse to an elephant. A file beyond them is in other units (or scaled by mistake).
PLAUSIBLE_M = {"biped": (0.25, 4.0), "animal": (0.05, 4.0)}
_UNKNOWN_M = (0.001, 1000.0)   # kind unknown: refused only beyond these (clearly no character) ...
_CHARACTER_M = (0.25, 4.0)     # ... and called unusual for a character beyond these
_TYPICAL_M = {"biped": 1.7, "animal": 0.8, "unknown": 1.7}
_UNIT_GUESSES = ((0.01, "centimetres"), (0.001, "millimetres"))  # tried in this order


@dataclass(frozen=True)
class Units:
    """The length scale taken for a glTF character.

    scale: metres per file unit (glTF world units, after every node transform).
    note: the 'units: ...' note that `inspect` and the run summary print.
    auto: the loader chose a scale other than 1 itself (the caller warns).
    """

    scale: float
    note: str
    auto: bool


def _two_digits(x: float) -> float:
    return float(f"{x:.2g}")


def suggest_scale(height: float, kind: str) -> float:
    """A character.scale for a posed height (m). A biped or animal: the power of ten nearest the
    kind's typical height when it lands in the plausible range (a unit mistake), else the factor
    to the typical height, two digits. Unknown kind: the factor to a human's height, two digits."""
    typical = _TYPICAL_M[kind]
    if kind in PLAUSIBLE_M:
        lo, hi = PLAUSIBLE_M[kind]
        p = 10.0 ** round(np.log10(typical / height))
        if lo <= height * p <= hi:
            return p
    return _two_digits(typical / height)


def choose_units(path, stance: Stance, given: float | None, node_scale: float = 1.0) -> Units:
    """Units of a glTF character from its posed height along the up taken (`Stance.height`, file
    units) and its kind (`Stance.kind`).

    given: the user's character.scale (taken as it is; a note says when the result is unusual) or
    None (auto): metres when plausible for the kind (`PLAUSIBLE_M`); a biped or animal too large
    in metres but plausible in centimetres (else millimetres) gets that scale (auto=True); any
    other implausible size raises InputError naming character.scale and a value for it. Of unknown
    kind (no two limbs on the floor) only beyond 1 mm - 1 km is refused; beyond 0.25 - 4 m the
    note says the size is unusual and which scale would make it human-sized.
    node_scale: the scale the nodes already apply (an FBX export's 0.01 above the skeleton), named.
    """
    kind, what = stance.kind, stance.describe()
    if not stance.height > 0:
        raise InputError(path, "the skinned rest pose has no height (every vertex at one level along the up axis)")
    if given is not None:
        h = stance.height * given
        note = f"units: scale {given:g} (character.scale), {h:.4g} m tall"
        lo, hi = PLAUSIBLE_M.get(kind, _CHARACTER_M)
        if not lo <= h <= hi:
            note += f"; unusual for a {'character' if kind == 'unknown' else kind} ({lo:g}-{hi:g} m)"
        return Units(given, note, False)
    h = stance.height
    nodes = (f", the node transforms scaling the file by {node_scale:.3g} (converted already)"
             if abs(np.log10(node_scale)) > 0.5 else "")
    lo, hi = PLAUSIBLE_M.get(kind, _UNKNOWN_M)
    if lo <= h <= hi:
        if kind == "unknown" and not _CHARACTER_M[0] <= h <= _CHARACTER_M[1]:
            s = suggest_scale(h, kind)
            return Units(1.0, f"units: metres (glTF convention), scale 1{nodes} (auto): {h:.4g} m tall is unusual "
                              f"for a character, kept as its kind is unknown (no two limbs on the floor); "
                              f"character.scale: {s:g} would make it {h * s:.3g} m, human-sized", False)
        return Units(1.0, f"units: metres (glTF convention), scale 1{nodes} (auto: {h:.4g} m tall, plausible for "
                          f"a {what})", False)
    if kind != "unknown" and h > hi:
        for f, name in _UNIT_GUESSES:
            if lo <= h * f <= hi:
                return Units(f, f"units: {name}, scale {f:g} (auto: read as metres it is a {h:.4g} m tall {what}, "
                                f"beyond {lo:g}-{hi:g} m; in {name} {h * f:.4g} m; character.scale overrides)", True)
    s = suggest_scale(h, kind)
    tried = ", nor in centimetres or millimetres" if kind != "unknown" and h > hi else ""
    raise InputError(path, f"character.scale: read as metres this {what} is {h:.4g} m tall, implausible "
                           f"(expected {lo:g}-{hi:g} m{tried}); set character.scale: {s:g} (gives {h * s:.3g} m) "
                           f"or the file's metres per unit")


# --------------------------------------------------------------------------------------------
# Folding the file's frame into the model frame
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Fold:
    """How the glTF world maps to the Character's rigid frames.

    M = U @ above (U: up rotation, scale and floor shift; above: nodes over the skeleton root) is
    split by polar decomposition into A (rigid, (4, 4)) and the stretch K ((3, 3) symmetric,
    = s * I for rotation + uniform scale): M x = A (K x).
    trans: (J, 3, 3) maps each joint's file-frame local translation into the Character's:
        K for the root, else Lb_p^-1 K Lb_p with Lb_p the parent's bind-pose linear part below `above`.
    bind: (J, 3, 3) Lb_j^-1 K Lb_j, pre-multiplied onto each inverse bind.
    For isotropic K both are s * I and the fold is exact for every pose.
    """

    a: np.ndarray
    k: np.ndarray
    trans: np.ndarray
    bind: np.ndarray
    isotropic: bool

    def convert_trs(self, j: int, t: np.ndarray, q: np.ndarray, sc: np.ndarray):
        """File-frame local TRS (N, 3 / 4 / 3) of joint j -> Character-frame TRS."""
        if self.isotropic:
            t = t * self.k[0, 0]
        else:
            t = t @ self.trans[j].T
        if j == 0:
            t = t @ self.a[:3, :3].T + self.a[:3, 3]
            q = (Rotation.from_matrix(self.a[:3, :3]) * Rotation.from_quat(q)).as_quat()
        return t, q, sc

    def convert_matrix(self, j: int, m: np.ndarray) -> np.ndarray:
        """File-frame local matrix of joint j -> Character frame (translation mapped, A on the root)."""
        m = m.copy()
        m[:3, 3] = m[:3, 3] * self.k[0, 0] if self.isotropic else self.trans[j] @ m[:3, 3]
        return self.a @ m if j == 0 else m

    def inverse_bind(self, ibm: np.ndarray, u: np.ndarray) -> np.ndarray:
        """(J, 4, 4) file inverse binds -> model frame -> rigid bone-local: bind_j @ ibm_j @ U^-1."""
        b = np.tile(np.eye(4), (ibm.shape[0], 1, 1))
        b[:, :3, :3] = self.bind
        return b @ ibm @ np.linalg.inv(u)


def fold_frames(path, u: np.ndarray, above: np.ndarray, bind_below: np.ndarray, parents: np.ndarray) -> Fold:
    """The Fold of M = u @ above; bind_below: (J, 4, 4) each joint's bind-pose transform below `above`
    (above^-1 @ inverse_bind^-1), used only when the nodes above the root scale non-uniformly."""
    m = u @ above
    m3 = m[:3, :3]
    det = np.linalg.det(m3)
    if not det > 0:
        raise InputError(path, "the nodes above the skeleton mirror or collapse it (determinant <= 0)")
    s = float(np.cbrt(det))
    r = m3 / s
    nj = len(parents)
    a = np.eye(4)
    a[:3, 3] = m[:3, 3]
    if np.allclose(r.T @ r, np.eye(3), atol=1e-5):
        a[:3, :3] = r
        k = s * np.eye(3)
        iso = np.broadcast_to(k, (nj, 3, 3)).copy()
        return Fold(a=a, k=k, trans=iso, bind=iso.copy(), isotropic=True)
    rot, k = scipy.linalg.polar(m3, side="right")  # m3 = rot @ k
    a[:3, :3] = rot
    lb = bind_below[:, :3, :3]
    try:
        bind = np.linalg.solve(lb, k @ lb)
    except np.linalg.LinAlgError:
        raise InputError(path, "a joint's bind transform is singular (inverse bind matrix with zero scale)") from None
    trans = np.empty((nj, 3, 3))
    trans[0] = k
    trans[1:] = bind[parents[1:]]
    return Fold(a=a, k=k, trans=trans, bind=bind, isotropic=False)
