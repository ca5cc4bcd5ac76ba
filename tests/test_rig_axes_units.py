"""glTF characters as they come: up axis and units from the skinned rest pose, skeleton and mesh
together. A humanoid and a quadruped, written as .glb files with pygltflib, stored every way up
(the turn in the node transforms, in the inverse bind matrices, or both), in metres,
centimetres, millimetres or centimetres under an FBX-style node scale 0.01; each must load
standing on its feet at its true height. Implausible sizes are scaled with a note or refused in
one line naming character.scale; an explicit scale is taken as it is; the real assets load as before."""
from __future__ import annotations

import functools
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from scipy.spatial.transform import Rotation

from stages.errors import InputError
from stages.rig.gltf import load_gltf
from stages.rig.skinning import forward_kinematics, rest_motion, sample_motion, skin

REPO = Path(__file__).resolve().parent.parent

# --------------------------------------------------------------------------------------------
# Two figures: joints (name, parent, position), Y up, metres, facing +Z, feet on y = 0.
# --------------------------------------------------------------------------------------------

HUMANOID = [
    ("hips", None, (0, 0.95, 0)), ("spine", "hips", (0, 1.15, 0)), ("chest", "spine", (0, 1.35, 0)),
    ("neck", "chest", (0, 1.5, 0)), ("head", "neck", (0, 1.58, 0.02)), ("head_top", "head", (0, 1.76, 0.02)),
    ("upperarm_l", "chest", (0.18, 1.42, 0)), ("forearm_l", "upperarm_l", (0.42, 1.3, 0)),
    ("hand_l", "forearm_l", (0.62, 1.18, 0.02)), ("hand_end_l", "hand_l", (0.72, 1.12, 0.03)),
    ("upperarm_r", "chest", (-0.18, 1.42, 0)), ("forearm_r", "upperarm_r", (-0.42, 1.3, 0)),
    ("hand_r", "forearm_r", (-0.62, 1.18, 0.02)), ("hand_end_r", "hand_r", (-0.72, 1.12, 0.03)),
    ("thigh_l", "hips", (0.1, 0.9, 0)), ("shin_l", "thigh_l", (0.1, 0.5, 0.02)), ("foot_l", "shin_l", (0.1, 0.08, 0)),
    ("toe_l", "foot_l", (0.1, 0.03, 0.16)),
    ("thigh_r", "hips", (-0.1, 0.9, 0)), ("shin_r", "thigh_r", (-0.1, 0.5, 0.02)), ("foot_r", "shin_r", (-0.1, 0.08, 0)),
    ("toe_r", "foot_r", (-0.1, 0.03, 0.16)),
]
QUADRUPED = [  # 2.3 m nose to tail, 1.15 m tall: the longest extent is horizontal
    ("hips", None, (0, 0.75, -0.55)), ("spine", "hips", (0, 0.78, -0.1)), ("chest", "spine", (0, 0.78, 0.35)),
    ("neck", "chest", (0, 0.95, 0.6)), ("head", "neck", (0, 1.05, 0.8)), ("nose", "head", (0, 1.0, 1.05)),
    ("tail_1", "hips", (0, 0.8, -0.8)), ("tail_2", "tail_1", (0, 0.7, -1.05)), ("tail_3", "tail_2", (0, 0.5, -1.2)),
] + [(f"{part}_{leg}", base if part == "upper" else f"{prev}_{leg}", (x, y, z))
     for leg, base, x, z in (("fl", "chest", 0.15, 0.35), ("fr", "chest", -0.15, 0.35),
                             ("hl", "hips", 0.15, -0.55), ("hr", "hips", -0.15, -0.55))
     for part, prev, y in (("upper", None, 0.62), ("lower", "upper", 0.32), ("paw", "lower", 0.05))]
FIGURES = {"humanoid": HUMANOID, "quadruped": QUADRUPED}

# A rotation standing the figure's +Y along each storage axis, after a turn about its own vertical.
_STAND = {"+y": Rotation.identity(), "-y": Rotation.from_euler("x", 180, degrees=True),
          "+z": Rotation.from_euler("x", 90, degrees=True), "-z": Rotation.from_euler("x", -90, degrees=True),
          "+x": Rotation.from_euler("z", -90, degrees=True), "-x": Rotation.from_euler("z", 90, degrees=True)}
_HEADING = {"+y": 20, "-y": 30, "+z": -15, "-z": 40, "+x": 10, "-x": -25}
STORE = {k: r * Rotation.from_euler("y", _HEADING[k], degrees=True) for k, r in _STAND.items()}
UNITS = {"m": 1.0, "cm": 100.0, "mm": 1000.0, "node_0.01": 100.0, "node_0.01_m": 100.0}  # file units per metre


def figure_mesh(figure):
    """A box around every bone (parent -> child), 3 cm from the bone axis.

    Returns positions (V, 3) in metres (rest pose = bind pose), triangles (T, 3), joints (V, 2)
    and weights (V, 2): the ring at the parent is the parent's, the ring at the child blends
    70 / 30 into the child when the child is a joint with a bone of its own."""
    names = [n for n, _, _ in figure]
    pos = {n: np.array(p, float) for n, _, p in figure}
    has_child = {p for _, p, _ in figure if p is not None}
    verts, tris, joints, weights = [], [], [], []
    for name, parent, _ in figure:
        if parent is None:
            continue
        a, b = pos[parent], pos[name]
        axis = (b - a) / np.linalg.norm(b - a)
        side = np.cross(axis, [0.3, 0.5, 0.8])
        side /= np.linalg.norm(side)
        up = np.cross(axis, side)
        base = len(verts)
        for end, (j, w) in ((a, ((names.index(parent), names.index(parent)), (1.0, 0.0))),
                            (b, ((names.index(parent), names.index(name)), (0.7, 0.3) if name in has_child else (1.0, 0.0)))):
            for u, v in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                verts.append(end + 0.03 * (u * side + v * up))
                joints.append(j)
                weights.append(w)
        for c in range(4):
            i, k = base + c, base + (c + 1) % 4
            tris += [[i, k, k + 4], [i, k + 4, i + 4]]
        tris += [[base, base + 2, base + 1], [base, base + 3, base + 2], [base + 4, base + 5, base + 6],
                 [base + 4, base + 6, base + 7]]
    return np.array(verts), np.array(tris), np.array(joints), np.array(weights)


def trs(t=(0, 0, 0), r: Rotation | None = None, s=1.0) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = (r.as_matrix() if r is not None else np.eye(3)) * s
    m[:3, 3] = t
    return m


# --------------------------------------------------------------------------------------------
# A glTF writer on pygltflib
# --------------------------------------------------------------------------------------------

class Glb:
    """Accessors into one binary blob, saved as a .glb by pygltflib."""

    def __init__(self):
        self.blob = bytearray()
        self.gltf = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0"))

    def accessor(self, arr, dtype, kind: str) -> int:
        arr = np.ascontiguousarray(arr, dtype=dtype)
        while len(self.blob) % 4:
            self.blob.append(0)
        self.gltf.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=arr.nbytes))
        self.blob += arr.tobytes()
        ctype = {np.float32: pygltflib.FLOAT, np.uint16: pygltflib.UNSIGNED_SHORT, np.uint8: pygltflib.UNSIGNED_BYTE}[dtype]
        acc = pygltflib.Accessor(bufferView=len(self.gltf.bufferViews) - 1, componentType=ctype,
                                 count=int(arr.shape[0]), type=kind)
        if kind == "VEC3" and dtype is np.float32:
            acc.min, acc.max = arr.min(axis=0).tolist(), arr.max(axis=0).tolist()
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1

    def save(self, path: Path) -> Path:
        while len(self.blob) % 4:
            self.blob.append(0)
        self.gltf.buffers = [pygltflib.Buffer(byteLength=len(self.blob))]
        self.gltf.set_binary_blob(bytes(self.blob))
        self.gltf.save_binary(str(path))
        return path


def quat(r: Rotation) -> list:
    return [float(x) for x in r.as_quat()]


def write_figure(path: Path, figure, *, node_up="+y", mesh_up="+y", units="m", arms_down=0.0,
                 clip=False) -> dict:
    """The figure as a skinned .glb, and what the file means by the glTF spec.

    node_up: the skeleton stored with its up along this file axis, through the root joint's rest
      rotation (no fixing node). mesh_up: the bind mesh stored with its up along this axis; the
      inverse binds hold the turn from there to the skeleton's frame (so node transforms and bind
      mesh disagree about up unless the two are equal).
    units: 'm', 'cm', 'mm' (every length in those units), or 'node_0.01' (centimetres below an
      'Armature' node with scale 0.01 and the Z-up -> Y-up turn: an FBX export, metres already;
      the bind mesh in the armature's centimetres, the inverse binds holding the 0.01), or
      'node_0.01_m' (the same nodes, the bind mesh in the world's metres).
    arms_down: radians the rest pose (node TRS) turns the upper arms down from the bind pose
      (the bind space is then not the rest pose, per joint).
    clip: a LINEAR clip 'walk' (hips translation, thigh / shin rotations).
    Returns {"rest": (V, 3) the rest pose skinned by the spec in the file's world, "world_up":
    the unit vector that is the figure's up there, "metres": metres per world unit, "glb": path,
    "ibm": (J, 4, 4) and "mesh" (V, 3) as stored (float32), "joints" / "weights" (V, 2), "locals":
    (J, 4, 4) rest local matrices, "parents", "above": (4, 4), "rest_world": (J, 4, 4),
    "true": (V, 3) the figure in metres, Y up}.
    """
    names = [n for n, _, _ in figure]
    parents = np.array([-1 if p is None else names.index(p) for _, p, _ in figure])
    pos = np.array([p for _, _, p in figure], float)
    f = UNITS[units]
    r_node, r_mesh = STORE[node_up], STORE[mesh_up]
    above = np.eye(4)
    if units.startswith("node_0.01"):  # Blender's FBX look: the armature turns Z up to Y up and scales cm to m
        above = trs(r=Rotation.from_euler("x", -90, degrees=True), s=0.01)
        r_node = Rotation.from_euler("x", 90, degrees=True) * r_node
    arm_turn = {"upperarm_l": Rotation.from_rotvec([0, 0, -arms_down]), "upperarm_r": Rotation.from_rotvec([0, 0, arms_down])}

    # Rest pose (node TRS) and bind pose (what the inverse binds invert), below `above`.
    locals_rest, locals_bind = [], []
    for j, (name, parent, p) in enumerate(figure):
        t = f * (pos[j] - (pos[parents[j]] if parents[j] >= 0 else 0))
        r = r_node if parents[j] < 0 else Rotation.identity()
        if parents[j] < 0:
            t = r_node.apply(t)
        locals_bind.append(trs(t, r))
        locals_rest.append(trs(t, r * arm_turn[name] if name in arm_turn else r))
    rest_world = forward_kinematics(parents, np.array(locals_rest), above)
    bind_world = forward_kinematics(parents, np.array(locals_bind), above)

    verts, tris, vj, vw = figure_mesh(figure)
    stored = r_mesh.apply(f * verts)
    # bind space -> the skeleton's bind world: above, then the skeleton's turn, from the mesh's turn
    to_world = above @ trs(r=r_node * r_mesh.inv())
    if units == "node_0.01_m":  # the bind mesh as the world shows it, in metres
        stored = r_mesh.apply(verts)
        to_world = trs(r=STORE[node_up] * r_mesh.inv())
    ibm = np.linalg.inv(bind_world) @ to_world

    g = Glb()
    nodes = []
    for j, (name, _, _) in enumerate(figure):
        t, q = locals_rest[j][:3, 3], Rotation.from_matrix(locals_rest[j][:3, :3])
        nodes.append(pygltflib.Node(name=name, translation=[float(x) for x in t], rotation=quat(q),
                                    children=[int(k) for k in np.flatnonzero(parents == j)]))
    root_nodes = [0]
    if units.startswith("node_0.01"):
        nodes.append(pygltflib.Node(name="Armature", rotation=quat(Rotation.from_matrix(above[:3, :3] / 0.01)),
                                    scale=[0.01, 0.01, 0.01], children=[0]))
        root_nodes = [len(nodes) - 1]
    prim = pygltflib.Primitive(
        attributes=pygltflib.Attributes(
            POSITION=g.accessor(stored, np.float32, "VEC3"),
            JOINTS_0=g.accessor(np.concatenate([vj, np.zeros_like(vj)], axis=1), np.uint8, "VEC4"),
            WEIGHTS_0=g.accessor(np.concatenate([vw, np.zeros_like(vw)], axis=1), np.float32, "VEC4")),
        indices=g.accessor(tris.ravel(), np.uint16, "SCALAR"))
    nodes.append(pygltflib.Node(name="body", mesh=0, skin=0))
    root_nodes.append(len(nodes) - 1)
    g.gltf.nodes = nodes
    g.gltf.meshes = [pygltflib.Mesh(name="body", primitives=[prim])]
    g.gltf.skins = [pygltflib.Skin(joints=list(range(len(figure))),
                                   inverseBindMatrices=g.accessor(ibm.transpose(0, 2, 1).reshape(-1, 16), np.float32, "MAT4"))]
    if clip:
        g.gltf.animations = [walk_clip(g, figure, locals_rest)]
    g.gltf.scenes = [pygltflib.Scene(nodes=root_nodes)]
    g.gltf.scene = 0
    g.save(path)

    stored32 = stored.astype(np.float32).astype(np.float64)
    ibm32 = ibm.astype(np.float32).astype(np.float64)
    return {"rest": spec_skin(rest_world, ibm32, stored32, vj, vw), "mesh": stored32, "ibm": ibm32,
            "world_up": (above[:3, :3] @ r_node.apply([0, 1, 0])) / np.linalg.norm(above[:3, :3] @ r_node.apply([0, 1, 0])),
            "metres": 1.0 / (f * (0.01 if units.startswith("node_0.01") else 1.0)), "glb": path, "joints": vj, "weights": vw,
            "locals": np.array(locals_rest), "parents": parents, "above": above, "rest_world": rest_world,
            "true": verts}


WALK_T = np.array([0.0, 0.5, 1.0])


def walk_clip(g: Glb, figure, locals_rest):
    """Hips sway forward (in its parent's frame), the left thigh and shin swing, LINEAR."""
    names = [n for n, _, _ in figure]
    hips_t = locals_rest[0][:3, 3]
    hips_r = Rotation.from_matrix(locals_rest[0][:3, :3])
    sway = np.stack([hips_t, hips_t + hips_r.apply([0, 0, 0.1 * np.linalg.norm(hips_t)]), hips_t])
    swing = [Rotation.from_rotvec([a, 0, 0]) for a in (0.0, -0.6, 0.3)]
    samplers, channels = [], []
    time_acc = g.accessor(WALK_T, np.float32, "SCALAR")
    for node, path, vals in ((0, "translation", sway),
                             (names.index("thigh_l"), "rotation", np.stack([r.as_quat() for r in swing])),
                             (names.index("shin_l"), "rotation", np.stack([(r.inv()).as_quat() for r in swing]))):
        out = g.accessor(vals, np.float32, "VEC3" if vals.shape[1] == 3 else "VEC4")
        samplers.append(pygltflib.AnimationSampler(input=time_acc, output=out,
                                                   interpolation="LINEAR"))
        channels.append(pygltflib.AnimationChannel(sampler=len(samplers) - 1,
                                                   target=pygltflib.AnimationChannelTarget(node=node, path=path)))
    return pygltflib.Animation(name="walk", samplers=samplers, channels=channels)


def spec_skin(world, ibm, mesh, vj, vw) -> np.ndarray:
    """Linear-blend skinning exactly as the glTF spec states it, per vertex."""
    m = world @ ibm
    out = np.zeros_like(mesh)
    for k in range(vj.shape[1]):
        mk = m[vj[:, k]]
        out += vw[:, k, None] * (np.einsum("vij,vj->vi", mk[:, :3, :3], mesh) + mk[:, :3, 3])
    return out


def posed_rest(c) -> np.ndarray:
    return skin(c, rest_motion(c, 1, 1 / 30))[0]


def assert_stands(c, ref: dict, figure, rel=1e-4):
    """The loaded character, skinned in its rest pose, is the figure's rest pose as the spec places
    it in the file, stood up and in metres: heights above the floor and distances to a vertex
    both match (so feet on y = 0, head up, true height), up to a turn about the vertical."""
    posed = posed_rest(c)
    truth = ref["rest"] * ref["metres"]
    h_true = truth @ ref["world_up"]
    h_true -= h_true.min()
    height = np.ptp(h_true)
    np.testing.assert_allclose(posed[:, 1], h_true, atol=rel * height + 1e-9)
    np.testing.assert_allclose(np.linalg.norm(posed - posed[0], axis=1), np.linalg.norm(truth - truth[0], axis=1),
                               atol=rel * height + 1e-9)
    assert np.ptp(posed[:, 1]) == pytest.approx(np.ptp(ref["true"][:, 1]), rel=0.02)
    names = [n for n, _, _ in figure]
    top = names.index("head_top" if "head_top" in names else "head")
    g = forward_kinematics(c.parents, c.rest_local)
    joints_y = g[:, 1, 3]
    assert joints_y[c.joint_names.index(names[top])] > 0.8 * np.ptp(posed[:, 1])  # the head is up
    feet = [c.joint_names.index(n) for n in names if n.startswith(("foot", "toe", "paw"))]
    assert feet and np.all(joints_y[feet] < 0.1 * np.ptp(posed[:, 1]))  # on its feet (two or four)
    # the bind mesh stands with the rest pose (the loader took the bind space into the rest frame)
    assert c.vertices[:, 1].min() == pytest.approx(0.0, abs=1e-9)


def load_quiet(path, **kw):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        c = load_gltf(path, **kw)
    return c, [str(w.message) for w in caught]


# --------------------------------------------------------------------------------------------
# Every way up: the turn in the node transforms, in the inverse binds, or both
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("figure", list(FIGURES))
@pytest.mark.parametrize("node_up", list(STORE))
@pytest.mark.parametrize("mesh_up", list(STORE))
def test_stands_whichever_way_skeleton_and_mesh_are_stored(tmp_path, figure, node_up, mesh_up):
    fig = FIGURES[figure]
    ref = write_figure(tmp_path / "fig.glb", fig, node_up=node_up, mesh_up=mesh_up)
    c, warned = load_quiet(ref["glb"])
    assert c.notes[0].startswith(f"up axis: file {node_up.upper()} (auto")  # the skeleton's (posed) up
    limbs = 2 if figure == "humanoid" else 4
    assert f"{limbs} limbs reach the floor" in c.notes[0]
    assert any(n.startswith("units: metres (glTF convention), scale 1 (auto") for n in c.notes) and not warned
    assert_stands(c, ref, fig)
    if mesh_up != node_up:  # the inverse binds hold a turn: the bind mesh was taken into the rest frame
        assert any(n.startswith("bind space: the inverse binds hold a") and "deg turn that the nodes do not" in n
                   for n in c.notes)
    else:
        assert not any(n.startswith(("bind space", "bind pose")) for n in c.notes)


def test_robot_z_up_mesh_turn_in_inverse_binds_stands_and_walks(tmp_path):
    """The reported robot: a Y-up skeleton, its mesh stored Z up, the 90 degree turn only in the
    inverse bind matrices. `auto` and `y` both stand it (it lay flat), and it walks as the spec says."""
    ref = write_figure(tmp_path / "robot.glb", HUMANOID, node_up="+y", mesh_up="+z", clip=True)
    for up in ("auto", "y"):
        c, _ = load_quiet(ref["glb"], up_axis=up)
        assert_stands(c, ref, HUMANOID)
        times = np.array([0.0, 0.25, 0.5, 0.8])
        m = sample_motion(c, "walk", times)
        world = skin(c, m) + m.root_translation[:, None, :]
        for fi, t in enumerate(times):
            local = ref["locals"].copy()
            u = t / 0.5 if t <= 0.5 else (t - 0.5) / 0.5
            k = 0 if t <= 0.5 else 1
            hips_t = local[0][:3, 3]
            hips_r = Rotation.from_matrix(local[0][:3, :3])
            sway = [hips_t, hips_t + hips_r.apply([0, 0, 0.1 * np.linalg.norm(hips_t)]), hips_t]
            local[0][:3, 3] = (1 - u) * sway[k] + u * sway[k + 1]
            angles = (0.0, -0.6, 0.3)
            a = (1 - u) * angles[k] + u * angles[k + 1]
            names = [n for n, _, _ in HUMANOID]
            local[names.index("thigh_l")][:3, :3] = Rotation.from_rotvec([a, 0, 0]).as_matrix()
            local[names.index("shin_l")][:3, :3] = Rotation.from_rotvec([-a, 0, 0]).as_matrix()
            spec = spec_skin(forward_kinematics(ref["parents"], local, ref["above"]), ref["ibm"], ref["mesh"],
                             ref["joints"], ref["weights"])
            # Y up already: the model frame is the file's world lifted to the floor
            np.testing.assert_allclose(world[fi], spec - [0, ref["rest"][:, 1].min(), 0], atol=1e-5, err_msg=f"t = {t}")


def test_bind_pose_not_the_rest_pose_per_joint(tmp_path):
    """Bound with the arms out (bind space), rested with them 40 degrees lower (node TRS): the rest
    pose is what skins and stands; the bind mesh stays as stored (exact skinning)."""
    ref = write_figure(tmp_path / "apose.glb", HUMANOID, arms_down=np.radians(40))
    c, _ = load_quiet(ref["glb"])
    posed = posed_rest(c)
    np.testing.assert_allclose(posed, ref["rest"] - [0, ref["rest"][:, 1].min(), 0], atol=1e-5)
    assert np.abs(c.vertices - (ref["mesh"] - [0, ref["mesh"][:, 1].min(), 0])).max() < 1e-9  # bind mesh kept
    assert any(n.startswith("bind pose: differs from the rest pose") for n in c.notes)


def test_bind_pose_per_joint_and_a_turn_in_the_inverse_binds(tmp_path):
    """Both at once: the mesh stored Z up with the turn in the inverse binds, the arms bound out
    and rested down. The joints holding most of the skin agree on the turn: the mesh is turned
    into the rest frame and stands; the rest pose skins to the spec's."""
    ref = write_figure(tmp_path / "both.glb", HUMANOID, mesh_up="-x", arms_down=np.radians(40))
    c, _ = load_quiet(ref["glb"])
    assert c.notes[0].startswith("up axis: file +Y (auto")
    assert_stands(c, ref, HUMANOID)


# --------------------------------------------------------------------------------------------
# Units: metres, centimetres, millimetres, an FBX node scale 0.01
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("figure", list(FIGURES))
@pytest.mark.parametrize("units", list(UNITS))
@pytest.mark.parametrize("node_up, mesh_up", [("+y", "+y"), ("+z", "+y"), ("+y", "+z"), ("-x", "-y")])
def test_units_found_from_the_size_and_kind(tmp_path, figure, units, node_up, mesh_up):
    fig = FIGURES[figure]
    ref = write_figure(tmp_path / "fig.glb", fig, node_up=node_up, mesh_up=mesh_up, units=units)
    c, warned = load_quiet(ref["glb"])
    assert_stands(c, ref, fig)
    note = next(n for n in c.notes if n.startswith("units:"))
    kind = "biped" if figure == "humanoid" else "animal"
    if units in ("cm", "mm"):
        name = {"cm": "centimetres", "mm": "millimetres"}[units]
        assert note.startswith(f"units: {name}, scale {1 / UNITS[units]:g} (auto: read as metres it is a ")
        assert f"m tall {kind} with" in note
        assert len(warned) == 1 and note[len("units: "):] in warned[0] and str(ref["glb"]) in warned[0]
    else:
        assert note.startswith("units: metres (glTF convention), scale 1") and f"plausible for a {kind}" in note
        assert not warned
        if units.startswith("node_0.01"):
            assert "node transforms scaling the file by 0.01" in note


def test_cm_quadruped_reported_79_m_is_scaled(tmp_path):
    """The report: a quadruped authored in centimetres was '79 m, units: metres' without a doubt."""
    ref = write_figure(tmp_path / "dog.glb", QUADRUPED, units="cm")
    c, warned = load_quiet(ref["glb"])
    note = next(n for n in c.notes if n.startswith("units:"))
    assert "it is a 103.9 m tall animal with 4 limbs on the floor" in note and "in centimetres 1.039 m" in note
    assert "character.scale overrides" in note
    assert np.ptp(posed_rest(c)[:, 1]) == pytest.approx(1.039, rel=0.02)


@pytest.mark.parametrize("figure, f, want", [
    ("humanoid", 0.005, "set character.scale: 100 (gives 0.884 m)"),    # 8.8 mm: too small
    ("humanoid", 12.0, "set character.scale: 0.1 (gives 2.12 m)"),      # 21 m: neither cm nor mm fit
    ("quadruped", 0.02, "set character.scale: 100 (gives 2.08 m)"),     # 2.1 cm
])
def test_implausible_size_is_one_line_naming_the_scale(tmp_path, monkeypatch, figure, f, want):
    monkeypatch.setitem(UNITS, "odd", f)
    ref = write_figure(tmp_path / "odd.glb", FIGURES[figure], node_up="+z", units="odd")
    with pytest.raises(InputError) as e:
        load_gltf(ref["glb"])
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{ref['glb']}: character.scale: read as metres this")
    assert "implausible (expected" in msg and want in msg, msg
    # the scale it names makes it load; an explicit scale is taken as it is (no auto, a note only)
    s = float(want.split("character.scale: ")[1].split()[0])
    c, warned = load_quiet(ref["glb"], scale=s)
    assert not warned and next(n for n in c.notes if n.startswith("units:")).startswith(f"units: scale {s:g} (character.scale)")
    c, warned = load_quiet(ref["glb"], scale=1.0)
    assert not warned and "unusual for a" in next(n for n in c.notes if n.startswith("units:"))


def test_explicit_scale_disables_auto_units(tmp_path):
    ref = write_figure(tmp_path / "cm.glb", HUMANOID, units="cm", node_up="-z")
    c, warned = load_quiet(ref["glb"], scale=0.01)
    assert not warned and any(n.startswith("units: scale 0.01 (character.scale), 1.767 m tall") for n in c.notes)
    assert_stands(c, ref, HUMANOID)
    c, warned = load_quiet(ref["glb"], scale=1.0)  # taken as given: 180 m, said unusual, not refused
    assert not warned and np.ptp(posed_rest(c)[:, 1]) == pytest.approx(176.7, rel=0.02)
    assert "unusual for a biped (0.25-4 m)" in next(n for n in c.notes if n.startswith("units:"))


def test_unknown_kind_is_kept_with_a_note(tmp_path, monkeypatch):
    """A chain (no two limbs on the floor) is not scaled: 12 m is unusual, the note says which
    scale gives a human-sized one; only beyond 1 mm - 1 km is it refused."""
    chain = [("a", None, (0, 0, 0)), ("b", "a", (0, 4, 0)), ("c", "b", (0, 8, 0)), ("d", "c", (0, 12, 0))]
    ref = write_figure(tmp_path / "pole.glb", chain)
    c, warned = load_quiet(ref["glb"])
    note = next(n for n in c.notes if n.startswith("units:"))
    assert not warned and "unusual for a character" in note and "character.scale: 0.14 would make it 1.68 m" in note
    monkeypatch.setitem(UNITS, "huge", 1000.0)
    ref = write_figure(tmp_path / "pole_km.glb", chain, units="huge")
    with pytest.raises(InputError, match=r"unknown kind \(no two limbs on the floor\) is 1\.2e\+04 m tall, implausible"):
        load_gltf(ref["glb"])


# --------------------------------------------------------------------------------------------
# Scene schema, the run's loader, inspect
# --------------------------------------------------------------------------------------------

def test_scene_scale_defaults_to_auto_for_gltf_only():
    from pipeline.scene import parse_scene_text
    assert parse_scene_text("character: {source: gltf, path: a.glb}")["character"]["scale"] is None
    assert parse_scene_text("character: {source: gltf, path: a.glb, scale: null}")["character"]["scale"] is None
    assert parse_scene_text("character: {source: gltf, path: a.glb, scale: 0.01}")["character"]["scale"] == 0.01
    assert parse_scene_text("character: {source: bvh, path: w.bvh}")["character"]["scale"] == 1.0
    assert parse_scene_text("name: x")["character"]["scale"] == 1.0


def test_run_loader_error_is_one_line(tmp_path, monkeypatch):
    from pipeline.run import load_character
    from pipeline.scene import SceneError, load_scene
    monkeypatch.setitem(UNITS, "tiny", 0.005)
    write_figure(tmp_path / "tiny.glb", HUMANOID, units="tiny")
    (tmp_path / "s.yaml").write_text("character: {source: gltf, path: tiny.glb}\n")
    with pytest.raises(SceneError) as e:
        load_character(load_scene(tmp_path / "s.yaml"))
    msg = str(e.value)
    assert "\n" not in msg and "character.path" in msg and "set character.scale: 100" in msg and "tiny.glb" in msg
    (tmp_path / "s.yaml").write_text("character: {source: gltf, path: tiny.glb, scale: 100}\n")
    c = load_character(load_scene(tmp_path / "s.yaml"))
    assert np.ptp(posed_rest(c)[:, 1]) == pytest.approx(0.884, rel=0.02)


def test_inspect_prints_the_units_note(tmp_path):
    write_figure(tmp_path / "dog.glb", QUADRUPED, units="cm", node_up="+z")
    r = subprocess.run([sys.executable, "-m", "pipeline", "inspect", str(tmp_path / "dog.glb")], cwd=REPO,
                       env=dict(os.environ), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[1].endswith("height 1.039 m")
    assert lines[2].startswith("units: centimetres, scale 0.01 (auto: read as metres it is a 103.9 m tall animal with 4 limbs")
    assert "up axis: file +Z (auto; skinned rest pose: 4 limbs reach the floor" in lines[2]


# --------------------------------------------------------------------------------------------
# The real assets: as before
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name, height", [("CesiumMan.glb", 1.507), ("kenney_mini_male_a.glb", 0.671),
                                          ("kenney_mini_female_b.glb", 0.723)])
def test_real_humanoids_as_before(assets_dir, name, height):
    if not (assets_dir / name).is_file():
        pytest.skip(f"{name} not in {assets_dir}")
    c, warned = load_quiet(assets_dir / name)
    assert not warned
    assert c.notes[0].startswith("up axis: file +Y (auto; skinned rest pose: 2 limbs reach the floor")
    assert c.notes[1].startswith("units: metres (glTF convention), scale 1 (auto:") and "plausible for a biped" in c.notes[1]
    assert np.ptp(c.vertices[:, 1]) == pytest.approx(height, abs=1e-3)
    assert np.ptp(posed_rest(c)[:, 1]) == pytest.approx(height, abs=1e-3)
    assert not any(n.startswith(("bind space", "bind pose")) for n in c.notes)


def test_rigged_simple_is_kept_and_called_unusual(assets_dir):
    c, warned = load_quiet(assets_dir / "RiggedSimple.glb")
    assert not warned and c.notes[0].startswith("up axis: file +Y (auto")
    note = c.notes[1]
    assert note.startswith("units: metres (glTF convention), scale 1 (auto): 9.551 m tall is unusual for a character")
    assert "character.scale: 0.18 would make it 1.72 m, human-sized" in note
    assert np.ptp(c.vertices[:, 1]) == pytest.approx(9.551, abs=1e-3)


def restored_copy(src: Path, dst: Path, turn: Rotation, where: str) -> None:
    """`src` re-stored turned by `turn` (float32 as stored). where='nodes': the scene's root nodes
    turned, the bind meshes and inverse binds with them (an exporter's other up axis: the viewer
    shows it turned); where='inverse_binds': only the bind meshes turned, the inverse binds
    turning them back (the viewer shows it as before; the bind mesh alone lies turned)."""
    g = pygltflib.GLTF2().load(str(src))
    blob = bytearray(g.binary_blob())
    t4 = np.eye(4)
    t4[:3, :3] = turn.as_matrix()
    done = set()

    def rewrite(i, fn, n):
        if i in done:
            return
        done.add(i)
        a, v = g.accessors[i], g.bufferViews[g.accessors[i].bufferView]
        stride = v.byteStride or 4 * n
        off = (v.byteOffset or 0) + (a.byteOffset or 0)
        raw = np.frombuffer(bytes(blob), np.uint8, count=(a.count - 1) * stride + 4 * n, offset=off)
        x = np.lib.stride_tricks.as_strided(raw.view(np.uint8), (a.count, 4 * n), (stride, 1)).copy().view(np.float32)
        y = fn(x.astype(np.float64)).astype(np.float32)
        for r in range(a.count):
            blob[off + r * stride:off + r * stride + 4 * n] = y[r].tobytes()
        if a.min is not None:
            a.min, a.max = y.min(axis=0).tolist(), y.max(axis=0).tolist()

    for node in g.nodes:
        if node.skin is not None:
            for prim in g.meshes[node.mesh].primitives:
                rewrite(prim.attributes.POSITION, turn.apply, 3)
            rewrite(g.skins[node.skin].inverseBindMatrices,
                    lambda m: (m.reshape(-1, 4, 4).transpose(0, 2, 1) @ np.linalg.inv(t4)).transpose(0, 2, 1).reshape(-1, 16), 16)
    if where == "nodes":
        root = pygltflib.Node(name="turned", rotation=quat(turn), children=list(g.scenes[g.scene or 0].nodes))
        g.nodes.append(root)
        g.scenes[g.scene or 0].nodes = [len(g.nodes) - 1]
    g.set_binary_blob(bytes(blob))
    g.save_binary(str(dst))


@functools.lru_cache(maxsize=2)
def _original(path: str):
    return load_gltf(path)


@pytest.mark.parametrize("name", ["CesiumMan.glb", "kenney_mini_male_a.glb"])
@pytest.mark.parametrize("stored_up", ["-y", "+z", "-z", "+x", "-x"])
@pytest.mark.parametrize("where", ["nodes", "inverse_binds"])
def test_real_assets_restored_any_way_stand_as_the_original(assets_dir, tmp_path, name, stored_up, where):
    if not (assets_dir / name).is_file():
        pytest.skip(f"{name} not in {assets_dir}")
    restored_copy(assets_dir / name, tmp_path / name, _STAND[stored_up], where)
    orig = _original(str(assets_dir / name))
    c, warned = load_quiet(tmp_path / name)
    want = stored_up if where == "nodes" else "+y"
    assert not warned and c.notes[0].startswith(f"up axis: file {want.upper()} (auto; skinned rest pose: 2 limbs")
    np.testing.assert_allclose(posed_rest(c), posed_rest(orig), atol=2e-5)
    np.testing.assert_allclose(c.vertices, orig.vertices, atol=2e-5)
    times = np.array([0.1, 0.7])
    m0, m1 = sample_motion(orig, 0, times), sample_motion(c, 0, times)
    np.testing.assert_allclose(skin(c, m1) + m1.root_translation[:, None], skin(orig, m0) + m0.root_translation[:, None],
                               atol=5e-5)
