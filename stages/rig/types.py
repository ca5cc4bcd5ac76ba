"""Data contracts of the rig stage: the character, its motion and its region split.

Frames
- *model frame*: the frame the bind-pose mesh is given in (Y up, metres, after the scene's
  scale / up-axis override). World = model frame; the character stands on y = 0 at frame 0.
- *bone-local frame of joint j*: `inverse_bind[j] @ x_model`. Hulls and spheres live there.
  At time t a bone-local point maps to the relative frame by `Motion.joint_world[t, j] @ x_local`
  (joint j's global transform); the linear-blend-skinning matrix is `joint_world @ inverse_bind`.
- *relative frame*: world with the root translation of the frame removed (paper A §3.2, relative
  simulation). `Motion.joint_world` is given in it; add `Motion.root_translation` for world.

Joints are topologically ordered: `parents[j] < j`, the root has parent -1. A "bone" is named by
the joint at its origin (bone b spans joint b to its children), so rigid regions and flexible
regions both index joints.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stages.checks import ContractError, check_array, check_index


@dataclass(frozen=True)
class Clip:
    """One animation clip as local joint TRS keyframes.

    times: (K,) float64, seconds, strictly increasing, K >= 1.
    translations: (K, J, 3) float64, metres, each joint's translation in its parent's frame.
    rotations: (K, J, 4) float64, unit quaternions xyzw (scipy order), local rotation.
    scales: (K, J, 3) float64, local scale (1 for rigid rigs).
    interpolation: 'linear' (lerp / slerp between keys) or 'step' (hold the previous key).
    loop: whether sampling past the end wraps around (walk cycles) or clamps.
    """

    name: str
    times: np.ndarray
    translations: np.ndarray
    rotations: np.ndarray
    scales: np.ndarray
    interpolation: str = "linear"
    loop: bool = False

    def __post_init__(self):
        o = f"Clip[{self.name!r}]"
        t = check_array(o, "times", self.times, (None,), np.float64)
        if t.size == 0:
            raise ContractError(f"{o}.times: a clip needs at least one key")
        if t.size > 1 and not np.all(np.diff(t) > 0):
            raise ContractError(f"{o}.times: key times must be strictly increasing")
        k = t.size
        check_array(o, "translations", self.translations, (k, None, 3), np.float64)
        j = self.translations.shape[1]
        check_array(o, "rotations", self.rotations, (k, j, 4), np.float64)
        check_array(o, "scales", self.scales, (k, j, 3), np.float64)
        if not np.allclose(np.linalg.norm(self.rotations, axis=-1), 1.0, atol=1e-6):
            raise ContractError(f"{o}.rotations: quaternions must be unit length")
        if self.interpolation not in ("linear", "step"):
            raise ContractError(f"{o}.interpolation: expected 'linear' or 'step', got {self.interpolation!r}")

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0])


@dataclass(frozen=True)
class Character:
    """A skinned character: bind-pose mesh, skeleton, linear-blend weights and clips.

    vertices: (V, 3) float64, metres, model frame, bind pose.
    triangles: (T, 3) int32, indices into vertices, counter-clockwise seen from outside.
    primitive_ids: (V,) int32, which source primitive / mesh each vertex came from (0 if one).
    joint_names: J unique names.
    parents: (J,) int32, parent joint index, -1 for the root; parents[j] < j.
    rest_local: (J, 4, 4) float64, each joint's rest transform in its parent's frame (the node
        transforms without animation).
    inverse_bind: (J, 4, 4) float64, model frame -> bone-local frame of each joint at bind time.
    skin_joints: (V, K) int32, influencing joints per vertex (K = 4 or 8; unused slots weight 0).
    skin_weights: (V, K) float64, non-negative, each row sums to 1.
    clips: the animation clips (may be empty: rest pose only).
    root_joint: index of the joint whose translation is the character's root translation.
    source: where it came from ('procedural', a file path), for the recording's metadata.
    notes: human-readable notes from loading (e.g. which file axis was taken as up, the floor shift).
    """

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    primitive_ids: np.ndarray
    joint_names: tuple[str, ...]
    parents: np.ndarray
    rest_local: np.ndarray
    inverse_bind: np.ndarray
    skin_joints: np.ndarray
    skin_weights: np.ndarray
    clips: tuple[Clip, ...] = ()
    root_joint: int = 0
    source: str = ""
    notes: tuple[str, ...] = ()

    def __post_init__(self):
        o = f"Character[{self.name!r}]"
        v = check_array(o, "vertices", self.vertices, (None, 3), np.float64)
        nv = v.shape[0]
        check_array(o, "triangles", self.triangles, (None, 3), np.int32)
        check_index(o, "triangles", self.triangles, nv)
        check_array(o, "primitive_ids", self.primitive_ids, (nv,), np.int32)
        nj = len(self.joint_names)
        if nj == 0:
            raise ContractError(f"{o}.joint_names: a character needs at least one joint")
        if len(set(self.joint_names)) != nj:
            raise ContractError(f"{o}.joint_names: names must be unique")
        p = check_array(o, "parents", self.parents, (nj,), np.int32)
        if p[0] != -1 or np.any(p[1:] >= np.arange(1, nj)) or np.any(p[1:] < 0):
            raise ContractError(f"{o}.parents: expected parents[0] == -1 and 0 <= parents[j] < j for j > 0")
        check_array(o, "rest_local", self.rest_local, (nj, 4, 4), np.float64)
        check_array(o, "inverse_bind", self.inverse_bind, (nj, 4, 4), np.float64)
        sj = check_array(o, "skin_joints", self.skin_joints, (nv, None), np.int32)
        check_index(o, "skin_joints", sj, nj)
        w = check_array(o, "skin_weights", self.skin_weights, sj.shape, np.float64)
        if np.any(w < 0):
            raise ContractError(f"{o}.skin_weights: weights must be non-negative")
        sums = w.sum(axis=1)
        if not np.allclose(sums, 1.0, atol=1e-6):
            i = int(np.argmax(np.abs(sums - 1.0)))
            raise ContractError(f"{o}.skin_weights: row {i} sums to {sums[i]:.6g}, expected 1")
        if not 0 <= self.root_joint < nj:
            raise ContractError(f"{o}.root_joint: {self.root_joint} is not a joint index")
        names = [c.name for c in self.clips]
        if len(set(names)) != len(names):
            raise ContractError(f"{o}.clips: clip names must be unique, got {names}")
        for c in self.clips:
            if c.translations.shape[1] != nj:
                raise ContractError(f"{o}.clips[{c.name!r}]: animates {c.translations.shape[1]} joints, character has {nj}")

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    def clip(self, key: str | int) -> Clip:
        """A clip by name or index, with an error listing what exists."""
        if isinstance(key, int) and not isinstance(key, bool):
            if 0 <= key < len(self.clips):
                return self.clips[key]
        else:
            for c in self.clips:
                if c.name == key:
                    return c
        raise KeyError(f"character {self.name!r} has no clip {key!r}; clips: {[c.name for c in self.clips]}")


@dataclass(frozen=True)
class Motion:
    """A clip sampled at the simulation's frame times.

    times: (F,) float64, seconds from the first frame, non-decreasing.
    joint_world: (F, J, 4, 4) float64, each joint's global transform at t in the *relative* frame
        (root translation removed): maps bone-local points to relative-frame points. Skinning
        matrices are `joint_world @ inverse_bind` (see stages.rig.skinning.skinning_matrices).
    root_translation: (F, 3) float64, metres, world translation of the relative frame at each frame
        (root joint's world position minus its position at frame 0); world = relative + this.
    """

    clip_name: str
    times: np.ndarray
    joint_world: np.ndarray
    root_translation: np.ndarray

    def __post_init__(self):
        o = f"Motion[{self.clip_name!r}]"
        t = check_array(o, "times", self.times, (None,), np.float64)
        if t.size == 0:
            raise ContractError(f"{o}.times: a motion needs at least one frame")
        if np.any(np.diff(t) < 0):
            raise ContractError(f"{o}.times: frame times must be non-decreasing")
        check_array(o, "joint_world", self.joint_world, (t.size, None, 4, 4), np.float64)
        check_array(o, "root_translation", self.root_translation, (t.size, 3), np.float64)

    @property
    def n_frames(self) -> int:
        return int(self.times.size)


@dataclass(frozen=True)
class RegionSplit:
    """Skinning-aware split of the mesh (paper A §3.1).

    dominant_joint: (V,) int32, the heaviest influence of each vertex.
    dominant_weight: (V,) float64, its weight.
    rigid: (V,) bool, dominant_weight >= threshold (after merging too-small regions).
    region_joint: (V,) int32. Rigid vertex: the bone (joint) whose hull it belongs to. Flexible
        vertex: the joint between its two heaviest bones (the child bone's origin joint).
    hull_bones: joints that get a hull, ascending. sphere_joints: joints that get a sphere, ascending.
    threshold: the rigid-weight threshold used (1 for the motion split).
    notes: human-readable merges and rejections (regions too small or flat for a hull).
    method: 'weights' (dominant weight >= threshold) or 'motion' (moves with a bone within
        `tolerance` metres over the motion sample).
    deviation: (V,) float64, m, motion split only: the smallest, over the vertex's bones, of its
        largest distance from its bind position in that bone's frame over the sample (None otherwise).
    """

    dominant_joint: np.ndarray
    dominant_weight: np.ndarray
    rigid: np.ndarray
    region_joint: np.ndarray
    hull_bones: tuple[int, ...]
    sphere_joints: tuple[int, ...]
    threshold: float
    notes: tuple[str, ...] = field(default_factory=tuple)
    method: str = "weights"
    tolerance: float = 0.0
    deviation: np.ndarray | None = None

    def __post_init__(self):
        o = "RegionSplit"
        dj = check_array(o, "dominant_joint", self.dominant_joint, (None,), np.int32)
        nv = dj.size
        check_array(o, "dominant_weight", self.dominant_weight, (nv,), np.float64)
        check_array(o, "rigid", self.rigid, (nv,), np.bool_)
        check_array(o, "region_joint", self.region_joint, (nv,), np.int32)
        if not 0.0 < self.threshold <= 1.0:
            raise ContractError(f"{o}.threshold: expected a weight in (0, 1], got {self.threshold}")
        if self.method not in ("weights", "motion"):
            raise ContractError(f"{o}.method: expected 'weights' or 'motion', got {self.method!r}")
        if self.deviation is not None:
            check_array(o, "deviation", self.deviation, (nv,), np.float64)
        hb = set(self.hull_bones)
        if any(b not in hb for b in np.unique(self.region_joint[self.rigid])):
            raise ContractError(f"{o}.hull_bones: a rigid vertex belongs to a bone without a hull")
        sj = set(self.sphere_joints)
        if any(j not in sj for j in np.unique(self.region_joint[~self.rigid])):
            raise ContractError(f"{o}.sphere_joints: a flexible vertex belongs to a joint without a sphere")

    def rigid_vertices(self, bone: int) -> np.ndarray:
        """Indices of the vertices in bone's rigid region."""
        return np.flatnonzero(self.rigid & (self.region_joint == bone))

    def flexible_vertices(self, joint: int) -> np.ndarray:
        """Indices of the vertices in joint's flexible region."""
        return np.flatnonzero(~self.rigid & (self.region_joint == joint))
