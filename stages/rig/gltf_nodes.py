"""glTF node tree -> skeleton, and the frame change from the file's world to the model frame.

The glTF spec places a skinned vertex at `sum_k w_k * global(joint_k) @ inverse_bind_k @ x`, where
global() multiplies every ancestor node's transform. The `Character` keeps rigid bone-local frames
(colliders live there), Y up, metres, feet on y = 0; `fold_frames` says how the nodes above the
skeleton, the up-axis rotation, the scale and the floor shift are folded in so that skinning stays
the spec's (module doc of stages.rig.gltf states what is exact). `detect_up` is the `auto` rule.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
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
# Up axis
# --------------------------------------------------------------------------------------------

def detect_up(joint_pos: np.ndarray, parents: np.ndarray, size: float) -> tuple[str, dict[str, float]]:
    """The file's up direction among +-X, +-Y, +-Z, from the skeleton's bind pose (`auto`).

    A standing character has (at least) two limbs that hang from a common joint down to the floor:
    legs from the hips, or a quadruped's legs from its hips or chest. For each candidate up u, take
    the leaf joints lowest along u (within 10 % of `size` of the lowest leaf); the score of u is,
    over pairs of those leaves, the largest min(drop of a, drop of b) below their lowest common
    ancestor along u: the length of two limbs that reach the floor separately. A head, a tail or a
    hand is one limb; toes or fingers of one foot or hand meet close by, so neither scores.
    Works for humanoids and quadrupeds alike (a quadruped's longest extent is horizontal, so the
    longest axis would be wrong). Returns the up with the best score when it beats +Y's by 25 % and
    is at least 15 % of `size`, else '+y' (the glTF convention: no two such limbs, e.g. a snake, a
    prop, a single chain), and every candidate's score (file units).
    Assumes the bind pose stands on its legs (not lying, sitting or kneeling as modelled), the
    legs end in leaf joints, and the inverse binds are the joints' world bind transforms (as
    exporters write them), so bind mesh and skeleton share the frame a viewer shows.
    joint_pos: (J, 3) bind-pose joint origins in the file's world. parents: (J,), parents[j] < j.
    size: the bind mesh's largest bounding-box extent (file units).
    """
    nj = len(parents)
    has_child = np.zeros(nj, bool)
    has_child[parents[parents >= 0]] = True
    leaves = np.flatnonzero(~has_child)
    ancestors = []
    for j in range(nj):
        a = [j]
        while parents[a[-1]] >= 0:
            a.append(int(parents[a[-1]]))
        ancestors.append(a)
    scores: dict[str, float] = {}
    for axis in UP_ROTATIONS:
        h = joint_pos @ up_vector(axis)
        low = leaves[h[leaves] <= h[leaves].min() + 0.1 * size] if leaves.size else leaves
        best = 0.0
        for i, a in enumerate(low):
            anc_a = set(ancestors[a])
            for b in low[i + 1:]:
                c = next(n for n in ancestors[b] if n in anc_a)
                best = max(best, min(h[c] - h[a], h[c] - h[b]))
        scores[axis] = float(best)
    axis = max(UP_ROTATIONS, key=lambda k: scores[k])  # first of equals: +y
    if axis != "+y" and (scores[axis] < 0.15 * size or scores[axis] <= 1.25 * scores["+y"]):
        axis = "+y"
    return axis, scores


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
