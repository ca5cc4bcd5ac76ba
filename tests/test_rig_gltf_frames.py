"""glTF frames: a skinned box under a rotated / scaled / translated parent node against a plain
per-vertex evaluation of the spec (node tree, 4x4 products, inverse binds, weights), and `auto`
standing characters stored with any axis up (humanoid, quadruped) on their feet."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation, Slerp

from stages.errors import InputError
from stages.rig.gltf import load_gltf
from stages.rig.skinning import rest_motion, sample_motion, skin
from tests.test_rig_gltf import Builder, quat

# --------------------------------------------------------------------------------------------
# The skinned box: parent (any TRS or matrix) -> root -> mid -> tip joints, and a mesh node.
# --------------------------------------------------------------------------------------------

F32 = lambda a: np.asarray(a, np.float64).astype(np.float32).astype(np.float64)  # noqa: E731
KEYS = np.array([0.0, 0.5, 1.0])
ROOT_REST = ([0.1, 0.05, 0.2], quat([0, 1, 0], 0.3))
CHILD_T = {"mid": [0.0, 0.6, 0.0], "tip": [0.0, 0.5, 0.0]}


def trs_matrix(t, q, s=(1, 1, 1)) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(q).as_matrix() @ np.diag(s)
    m[:3, 3] = t
    return m


def box_channels(axis):
    """LINEAR channels (node, path, times, values): root translation, mid / tip rotation about axis."""
    return [
        (1, "translation", KEYS, np.array([ROOT_REST[0], [0.4, 0.1, -0.3], [-0.2, 0.3, 0.5]])),
        (2, "rotation", KEYS, np.stack([quat(axis, a) for a in (0.0, 0.9, -0.6)])),
        (3, "rotation", KEYS, np.stack([quat(axis, a) for a in (0.2, -0.7, 1.1)])),
    ]


def box_mesh():
    """A 0.3 x 1.4 x 0.2 box along the joint chain (skeleton frame), weights by height, two
    joints blended around each joint. Returns positions (V, 3), triangles, joints (V, 4), weights."""
    ys = np.linspace(0.0, 1.4, 8)
    corners = [(-0.15, -0.1), (0.15, -0.1), (0.15, 0.1), (-0.15, 0.1)]
    p = np.array([[x + 0.1, y, z + 0.2] for y in ys for x, z in corners])
    tris = []
    for r in range(7):
        for c in range(4):
            a, b = 4 * r + c, 4 * r + (c + 1) % 4
            tris += [[a, b, b + 4], [a, b + 4, a + 4]]
    tris += [[0, 2, 1], [0, 3, 2], [28, 29, 30], [28, 30, 31]]
    h = p[:, 1]
    w_mid = np.clip((h - 0.45) / 0.3, 0, 1) * (h < 1.0) + (h >= 1.0) * np.clip((1.3 - h) / 0.3, 0, 1)
    w_tip = np.clip((h - 1.0) / 0.3, 0, 1)
    w_root = 1.0 - w_mid - w_tip
    joints = np.tile([0, 1, 2, 0], (p.shape[0], 1))
    weights = np.stack([w_root, w_mid, w_tip, np.zeros_like(h)], axis=1)
    return p, np.array(tris), joints, weights


def rest_below_parent(root_q=ROOT_REST[1]):
    """Rest (= bind) world transforms of root, mid, tip below the parent node."""
    root = trs_matrix(ROOT_REST[0], root_q)
    mid = root @ trs_matrix(CHILD_T["mid"], [0, 0, 0, 1])
    return [root, mid, mid @ trs_matrix(CHILD_T["tip"], [0, 0, 0, 1])]


def build_box(parent: np.ndarray, parent_trs=None, axis=(0, 0, 1), root_q=ROOT_REST[1]) -> Builder:
    """The box glTF. parent: its 4x4; parent_trs: (t, q, s) to store it as TRS, else as a matrix;
    root_q: the root joint's rest rotation (the box runs along the root's y axis).
    Inverse binds include the parent (as exporters write them); positions are the bind mesh in
    the file's world. The mesh node has a transform of its own, which skinning must ignore."""
    b = Builder()
    nodes = [{"name": "parent", "children": [1, 4]},
             {"name": "root", "translation": ROOT_REST[0], "rotation": list(root_q), "children": [2]},
             {"name": "mid", "translation": CHILD_T["mid"], "children": [3]},
             {"name": "tip", "translation": CHILD_T["tip"]},
             {"name": "mesh", "mesh": 0, "skin": 0, "translation": [5.0, -3.0, 2.0], "rotation": list(quat([1, 2, 3], 1.0))}]
    if parent_trs is None:
        nodes[0]["matrix"] = parent.T.ravel().tolist()
    else:
        t, q, s = parent_trs
        nodes[0].update(translation=list(map(float, t)), rotation=list(map(float, q)), scale=list(map(float, s)))
    p, tris, joints, weights = box_mesh()
    turn = Rotation.from_quat(root_q) * Rotation.from_quat(ROOT_REST[1]).inv()  # the box follows the root
    p = turn.apply(p - ROOT_REST[0]) + ROOT_REST[0]
    world = p @ parent[:3, :3].T + parent[:3, 3]
    ibm = np.stack([np.linalg.inv(parent @ m) for m in rest_below_parent(root_q)])
    prim = {"attributes": {"POSITION": b.accessor(world, np.float32), "JOINTS_0": b.accessor(joints, np.uint8),
                           "WEIGHTS_0": b.accessor(weights, np.float32)},
            "indices": b.accessor(tris.ravel(), np.uint16)}
    b.doc.update(nodes=nodes, meshes=[{"primitives": [prim]}], scenes=[{"nodes": [0]}], scene=0,
                 skins=[{"joints": [1, 2, 3], "inverseBindMatrices": b.accessor(ibm.transpose(0, 2, 1).reshape(-1, 16), np.float32)}])
    samplers, chans = [], []
    for node, pth, times, vals in box_channels(axis):
        samplers.append({"input": b.accessor(times, np.float32), "output": b.accessor(vals, np.float32)})
        chans.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": pth}})
    b.doc["animations"] = [{"name": "bend", "samplers": samplers, "channels": chans}]
    return b


def read_accessor(b: Builder, i: int, n: int) -> np.ndarray:
    """Accessor i of what the Builder wrote (uint8 or float32, n components) as float64 (count, n)."""
    a = b.accessors[i]
    dtype = np.uint8 if a["componentType"] == 5121 else np.float32
    return np.frombuffer(bytes(b.blob), dtype, offset=b.views[a["bufferView"]]["byteOffset"],
                         count=a["count"] * n).reshape(-1, n).astype(np.float64)


def spec_box(b: Builder, t: float) -> np.ndarray:
    """Skinned positions (V, 3) at time t as the glTF spec composes them, read back from the
    document the test wrote: walk the node tree multiplying 4x4s, then sum w * world @ ibm @ x."""
    doc = b.document()
    acc = lambda i, n: read_accessor(b, i, n)  # noqa: E731
    trs = {}
    for i, n in enumerate(doc["nodes"]):
        trs[i] = [np.array(n.get("translation", [0, 0, 0]), float), np.array(n.get("rotation", [0, 0, 0, 1]), float),
                  np.array(n.get("scale", [1, 1, 1]), float)]
    anim = doc["animations"][0]
    for ch in anim["channels"]:
        smp = anim["samplers"][ch["sampler"]]
        kt = acc(smp["input"], 1)[:, 0]
        slot = {"translation": 0, "rotation": 1, "scale": 2}[ch["target"]["path"]]
        kv = acc(smp["output"], 4 if slot == 1 else 3)
        if slot == 1:
            trs[ch["target"]["node"]][1] = Slerp(kt, Rotation.from_quat(kv))([t]).as_quat()[0]
        else:
            trs[ch["target"]["node"]][slot] = np.array([np.interp(t, kt, kv[:, c]) for c in range(3)])

    def local(i):
        n = doc["nodes"][i]
        if "matrix" in n:
            return np.array(n["matrix"], float).reshape(4, 4).T
        return trs_matrix(*trs[i])

    world = {}

    def visit(i, above):
        world[i] = above @ local(i)
        for c in doc["nodes"][i].get("children", []):
            visit(c, world[i])

    visit(0, np.eye(4))
    prim = doc["meshes"][0]["primitives"][0]["attributes"]
    pos, jts, wts = acc(prim["POSITION"], 3), acc(prim["JOINTS_0"], 4).astype(int), acc(prim["WEIGHTS_0"], 4)
    ibm = acc(doc["skins"][0]["inverseBindMatrices"], 16).reshape(-1, 4, 4).transpose(0, 2, 1)
    joints = doc["skins"][0]["joints"]
    out = np.zeros((pos.shape[0], 3))
    for v in range(pos.shape[0]):
        x = np.append(pos[v], 1.0)
        for k in range(4):
            out[v] += wts[v, k] / wts[v].sum() * (world[joints[jts[v, k]]] @ ibm[jts[v, k]] @ x)[:3]
    return out


def expected(b: Builder, t: float, scale: float = 1.0) -> np.ndarray:
    """spec_box in the model frame of an up_axis 'y' load: scaled, lowest bind vertex lifted to 0."""
    pos = spec_box_bind(b)
    return spec_box(b, t) * scale - [0.0, pos[:, 1].min() * scale, 0.0]


def spec_box_bind(b: Builder) -> np.ndarray:
    """The bind mesh as stored (file frame)."""
    return read_accessor(b, b.doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"], 3)


def loaded_world(path, times, **kw):
    c = load_gltf(path, loop=False, **kw)  # t = 1.0 is the last key, not the wrap to 0
    m = sample_motion(c, 0, np.asarray(times, float))
    return c, skin(c, m) + m.root_translation[:, None, :]


TIMES = [0.0, 0.2, 0.5, 0.65, 1.0]


# --------------------------------------------------------------------------------------------
# Rotation + translation + uniform scale above the skeleton: exact in every pose
# --------------------------------------------------------------------------------------------

Z_UP_ROOT = (Rotation.from_euler("x", 90, degrees=True) * Rotation.from_quat(ROOT_REST[1])).as_quat()


@pytest.mark.parametrize("parent_trs, root_q", [
    (([0.0, 0.0, 0.0], quat([1, 0, 0], -np.pi / 2), [1.0, 1.0, 1.0]), Z_UP_ROOT),      # Z-up skeleton + the fix
    (([0.3, -1.0, 2.0], quat([1, 0, 0], -np.pi / 2), [0.01, 0.01, 0.01]), Z_UP_ROOT),  # ... with cm -> m
    (([1.5, 0.2, -0.7], quat([0.3, -1, 0.6], 2.1), [2.5, 2.5, 2.5]), ROOT_REST[1]),    # an arbitrary rotation
])
@pytest.mark.parametrize("as_matrix", [False, True])
def test_box_under_rigid_scaled_parent_is_exact(tmp_path, parent_trs, root_q, as_matrix):
    parent = trs_matrix(*parent_trs)
    b = build_box(parent, None if as_matrix else parent_trs, root_q=root_q)
    b.write_glb(tmp_path / "box.glb")
    c, world = loaded_world(tmp_path / "box.glb", TIMES, up_axis="y", scale=1.7)
    for f, t in enumerate(TIMES):
        want = expected(b, t, 1.7)
        np.testing.assert_allclose(world[f], want, rtol=0, atol=1e-9 * (1 + np.abs(want).max()), err_msg=f"t = {t}")
    assert c.vertices[:, 1].min() == 0.0
    if root_q is Z_UP_ROOT:  # the fixing node stands the Z-up box: 1.4 tall, times the scales
        assert np.ptp(c.vertices[:, 1]) == pytest.approx(1.4 * 1.7 * parent_trs[2][0], rel=1e-6)
    r = c.inverse_bind[:, :3, :3]  # bone-local frames rigid
    np.testing.assert_allclose(r @ r.transpose(0, 2, 1), np.broadcast_to(np.eye(3), r.shape), atol=1e-6)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-6)


@settings(max_examples=25, deadline=None)
@given(q=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1),
       log_s=st.floats(-2, 2), t=st.lists(st.floats(-5, 5), min_size=3, max_size=3), time=st.floats(0, 1))
def test_box_random_rigid_parent_property(tmp_path_factory, q, log_s, t, time):
    """Random parent rotation, uniform scale 0.01..100 and translation: every skinned vertex (so
    every height) equals the spec's, with `auto` (a single chain keeps the file's +Y)."""
    s = 10.0 ** log_s
    parent_trs = (t, np.array(q) / np.linalg.norm(q), [s, s, s])
    b = build_box(trs_matrix(*parent_trs), parent_trs)
    path = tmp_path_factory.mktemp("prop") / "box.glb"
    b.write_glb(path)
    c, world = loaded_world(path, [time])
    want = expected(b, time)
    np.testing.assert_allclose(world[0], want, rtol=0, atol=1e-9 * (1 + np.abs(want).max()))
    assert c.notes[0].startswith("up axis: file +Y")


# --------------------------------------------------------------------------------------------
# Non-uniform scale / shear above the skeleton: exact where the module doc says, bounded elsewhere
# --------------------------------------------------------------------------------------------

NONUNIFORM = ([0.4, 1.0, -0.5], quat([0.2, 1, -0.4], 0.8), [1.6, 0.7, 1.6])


def test_box_nonuniform_parent_bind_pose_and_commuting_motion_exact(tmp_path):
    """Scale (1.6, 0.7, 1.6): the bind mesh, the root's trajectory and bends about the parent's
    y axis (which commute with the stretch) are exact; bone-local frames stay rigid."""
    parent = trs_matrix(*NONUNIFORM)
    b = build_box(parent, NONUNIFORM, axis=(0, 1, 0))
    b.write_glb(tmp_path / "box.glb")
    c, world = loaded_world(tmp_path / "box.glb", TIMES, up_axis="y")
    bind = spec_box_bind(b)
    np.testing.assert_allclose(c.vertices, bind - [0, bind[:, 1].min(), 0], atol=1e-12)
    np.testing.assert_allclose(skin(c, rest_motion(c, 1, 0.1))[0], c.vertices, atol=1e-6)  # rest = bind here
    for f, t in enumerate(TIMES):
        np.testing.assert_allclose(world[f], expected(b, t), atol=1e-6, err_msg=f"t = {t}")
    r = c.inverse_bind[:, :3, :3]
    np.testing.assert_allclose(r @ r.transpose(0, 2, 1), np.broadcast_to(np.eye(3), r.shape), atol=1e-6)
    assert any("non-uniformly" in n for n in c.notes)


@pytest.mark.parametrize("shear", [False, True])
def test_box_nonuniform_parent_general_motion_within_documented_bound(tmp_path, shear):
    """Bends about x inside a (1.6, 0.7, 1.2)-stretched (or sheared) parent: a rigid bone cannot
    follow the shear; each vertex is within (largest - smallest principal stretch) x (its distance
    from its joints + the bone lengths from the root) of the spec, and exact in the bind pose."""
    parent = trs_matrix(NONUNIFORM[0], NONUNIFORM[1], [1.6, 0.7, 1.2])
    if shear:
        parent[:3, :3] = parent[:3, :3] @ np.array([[1, 0.3, 0], [0, 1, 0], [0.2, 0, 1]])
    b = build_box(parent, None, axis=(1, 0, 0))
    b.write_glb(tmp_path / "box.glb")
    c, world = loaded_world(tmp_path / "box.glb", TIMES, up_axis="y")
    sv = np.linalg.svd(parent[:3, :3], compute_uv=False)
    p, _, joints, weights = box_mesh()
    below = rest_below_parent()
    reach = np.zeros(p.shape[0])
    path_len = np.cumsum([0.0, np.linalg.norm(CHILD_T["mid"]), np.linalg.norm(CHILD_T["tip"])])
    for k in range(3):
        local = (p - below[k][:3, 3]) @ below[k][:3, :3]  # vertex in joint k's frame
        reach = np.maximum(reach, np.where(weights[:, k] > 0, np.linalg.norm(local, axis=1) + path_len[k], 0.0))
    worst = 0.0
    for f, t in enumerate(TIMES):
        err = np.linalg.norm(world[f] - expected(b, t), axis=1)
        assert np.all(err <= (sv.max() - sv.min()) * reach + 1e-6), f"t = {t}"
        worst = max(worst, err.max())
    assert worst > 1e-3  # the limitation is real (else this test would check nothing)
    bind = spec_box_bind(b)  # the rest pose is the bind pose: exact
    np.testing.assert_allclose(c.vertices, bind - [0, bind[:, 1].min(), 0], atol=1e-12)
    np.testing.assert_allclose(skin(c, rest_motion(c, 1, 0.1))[0], c.vertices, atol=1e-6)


def test_mirroring_parent_is_an_input_error(tmp_path):
    parent = trs_matrix([0, 0, 0], [0, 0, 0, 1], [-1.0, 1.0, 1.0])
    build_box(parent).write_glb(tmp_path / "mirror.glb")
    with pytest.raises(InputError, match="mirror.glb: the nodes above the skeleton mirror"):
        load_gltf(tmp_path / "mirror.glb")


def test_unknown_up_axis_is_an_input_error(tmp_path):
    build_box(np.eye(4)).write_glb(tmp_path / "box.glb")
    with pytest.raises(InputError, match="up_axis must be one of auto, y, z, got 'w'"):
        load_gltf(tmp_path / "box.glb", up_axis="w")


# --------------------------------------------------------------------------------------------
# up_axis 'auto': characters stored with any axis up, no correcting node
# --------------------------------------------------------------------------------------------

# Joints (name, parent, position) of two standing figures, Y up, forward +Z, feet on y = 0.
HUMANOID = [
    ("hips", None, (0, 0.95, 0)), ("spine", "hips", (0, 1.15, 0)), ("chest", "spine", (0, 1.35, 0)),
    ("neck", "chest", (0, 1.5, 0)), ("head", "neck", (0, 1.6, 0.02)), ("head_end", "head", (0, 1.75, 0.02)),
    ("shoulder_l", "chest", (0.18, 1.42, 0)), ("elbow_l", "shoulder_l", (0.45, 1.42, 0)),
    ("hand_l", "elbow_l", (0.7, 1.42, 0)), ("finger_l", "hand_l", (0.82, 1.42, 0.0)),
    ("thumb_l", "hand_l", (0.76, 1.42, 0.06)),
    ("shoulder_r", "chest", (-0.18, 1.42, 0)), ("elbow_r", "shoulder_r", (-0.45, 1.42, 0)),
    ("hand_r", "elbow_r", (-0.7, 1.42, 0)), ("finger_r", "hand_r", (-0.82, 1.42, 0.0)),
    ("thumb_r", "hand_r", (-0.76, 1.42, 0.06)),
    ("thigh_l", "hips", (0.1, 0.9, 0)), ("knee_l", "thigh_l", (0.1, 0.5, 0.02)), ("ankle_l", "knee_l", (0.1, 0.1, 0)),
    ("toe_l", "ankle_l", (0.1, 0.03, 0.15)), ("heel_l", "ankle_l", (0.1, 0.03, -0.05)),
    ("thigh_r", "hips", (-0.1, 0.9, 0)), ("knee_r", "thigh_r", (-0.1, 0.5, 0.02)), ("ankle_r", "knee_r", (-0.1, 0.1, 0)),
    ("toe_r", "ankle_r", (-0.1, 0.03, 0.15)), ("heel_r", "ankle_r", (-0.1, 0.03, -0.05)),
]
QUADRUPED = [  # longer (2.2 m nose to tail) than tall (1.1 m): the longest extent is horizontal
    ("hips", None, (0, 0.75, -0.55)), ("tail_1", "hips", (0, 0.8, -0.8)), ("tail_2", "tail_1", (0, 0.8, -1.2)),
    ("spine", "hips", (0, 0.78, -0.1)), ("chest", "spine", (0, 0.78, 0.35)), ("neck", "chest", (0, 0.95, 0.6)),
    ("head", "neck", (0, 1.05, 0.8)), ("nose", "head", (0, 1.0, 1.0)),
    ("ear_l", "head", (0.06, 1.12, 0.75)), ("ear_r", "head", (-0.06, 1.12, 0.75)),
] + [(f"{part}_{leg}", base if part == "upper" else f"{prev}_{leg}", (x, y, z))
     for leg, base, x, z in (("fl", "chest", 0.15, 0.35), ("fr", "chest", -0.15, 0.35),
                             ("hl", "hips", 0.15, -0.55), ("hr", "hips", -0.15, -0.55))
     for part, prev, y in (("upper", None, 0.6), ("lower", "upper", 0.3), ("paw", "lower", 0.04))]

# A rotation that stands the figure's +Y along each storage axis (and turns it a little about Y).
STORE = {"+y": Rotation.identity(), "-y": Rotation.from_euler("x", 180, degrees=True),
         "+z": Rotation.from_euler("x", 90, degrees=True), "-z": Rotation.from_euler("x", -90, degrees=True),
         "+x": Rotation.from_euler("z", -90, degrees=True), "-x": Rotation.from_euler("z", 90, degrees=True)}


def figure_mesh(figure):
    """A thin box around every bone, skinned to the bone's parent joint; (V, 3), tris, joint index per vertex."""
    names = [n for n, _, _ in figure]
    pos = {n: np.array(p, float) for n, _, p in figure}
    verts, tris, owner = [], [], []
    for name, parent, _ in figure:
        if parent is None:
            continue
        a, b = pos[parent], pos[name]
        axis = (b - a) / np.linalg.norm(b - a)
        side = np.cross(axis, [0.3, 0.5, 0.8])
        side /= np.linalg.norm(side)
        up = np.cross(axis, side)
        base = len(verts)
        for end in (a, b):
            for u, v in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                verts.append(end + 0.03 * (u * side + v * up))
                owner.append(names.index(parent))
        for c in range(4):
            i, j = base + c, base + (c + 1) % 4
            tris += [[i, j, j + 4], [i, j + 4, i + 4]]
        tris += [[base, base + 2, base + 1], [base, base + 3, base + 2], [base + 4, base + 5, base + 6], [base + 4, base + 6, base + 7]]
    return np.array(verts), np.array(tris), np.array(owner)


def build_figure(figure, store: Rotation) -> Builder:
    """The figure stored rotated by `store`, through the root joint's rotation (no fixing node)."""
    names = [n for n, _, _ in figure]
    pos = {n: np.array(p, float) for n, _, p in figure}
    nodes = []
    for name, parent, p in figure:
        n = {"name": name, "children": [names.index(c) for c, pa, _ in figure if pa == name]}
        if parent is None:
            n.update(translation=list(store.apply(p)), rotation=list(store.as_quat()))
        else:
            n["translation"] = list(np.array(p) - pos[parent])
        nodes.append(n)
    rot = np.eye(4)
    rot[:3, :3] = store.as_matrix()
    worlds = []
    for name, _, p in figure:
        m = np.eye(4)
        m[:3, 3] = p
        worlds.append(rot @ m)
    verts, tris, owner = figure_mesh(figure)
    b = Builder()
    joints = np.stack([owner, np.zeros_like(owner), np.zeros_like(owner), np.zeros_like(owner)], axis=1)
    weights = np.zeros((len(owner), 4))
    weights[:, 0] = 1.0
    ibm = np.stack([np.linalg.inv(w) for w in worlds])
    prim = {"attributes": {"POSITION": b.accessor(store.apply(verts), np.float32), "JOINTS_0": b.accessor(joints, np.uint8),
                           "WEIGHTS_0": b.accessor(weights, np.float32)},
            "indices": b.accessor(tris.ravel(), np.uint16)}
    nodes.append({"name": "body", "mesh": 0, "skin": 0})
    b.doc.update(nodes=nodes, meshes=[{"primitives": [prim]}], scenes=[{"nodes": [0, len(nodes) - 1]}], scene=0,
                 skins=[{"joints": list(range(len(figure))),
                         "inverseBindMatrices": b.accessor(ibm.transpose(0, 2, 1).reshape(-1, 16), np.float32)}])
    return b


@pytest.mark.parametrize("figure", ["humanoid", "quadruped"])
@pytest.mark.parametrize("stored_up", list(STORE))
def test_auto_stands_any_storage_upright(tmp_path, figure, stored_up):
    fig = HUMANOID if figure == "humanoid" else QUADRUPED
    verts = figure_mesh(fig)[0]
    b = build_figure(fig, STORE[stored_up])
    b.write_glb(tmp_path / "fig.glb")
    c = load_gltf(tmp_path / "fig.glb")  # auto is the default
    assert c.notes[0].startswith(f"up axis: file {stored_up.upper()} (auto")
    # upright: every vertex at its height above the figure's lowest point (any turn about Y allowed)
    np.testing.assert_allclose(c.vertices[:, 1], verts[:, 1] - verts[:, 1].min(), atol=1e-6)
    # rigid: distances kept
    np.testing.assert_allclose(np.linalg.norm(c.vertices - c.vertices[0], axis=1),
                               np.linalg.norm(verts - verts[0], axis=1), atol=1e-6)
    # 'y' keeps the old behaviour: the file's axes as stored, only lifted to the floor
    stored = F32(STORE[stored_up].apply(verts))
    old = load_gltf(tmp_path / "fig.glb", up_axis="y")
    np.testing.assert_allclose(old.vertices, stored - [0, stored[:, 1].min(), 0], atol=1e-9)
    # the skeleton stands too: the rest pose skins to the bind mesh, the feet are the lowest joints
    np.testing.assert_allclose(skin(c, rest_motion(c, 1, 0.1))[0], c.vertices, atol=1e-6)


def test_z_up_humanoid_gets_body_measurements(tmp_path):
    """The reported failure: a Z-up robot lying down broke every pattern garment in
    body_measurements (QhullError). Stood up by `auto`, it measures like the figure."""
    from stages.rig.procedural import body_measurements

    build_figure(HUMANOID, STORE["+z"]).write_glb(tmp_path / "robot.glb")
    m = body_measurements(load_gltf(tmp_path / "robot.glb"))
    verts = figure_mesh(HUMANOID)[0]
    assert m["height"] == pytest.approx(np.ptp(verts[:, 1]), abs=1e-6)
    for key in ("chest", "waist", "hips"):
        assert np.isfinite(m[key]) and 0.1 < m[key] < 2.0, (key, m[key])


def z_up_copy(src, dst):
    """`src` re-stored Z up as a Z-up exporter without the fixing node would write it: the scene root
    turned +90 deg about X, the bind mesh and inverse binds turned with it (float32 as stored)."""
    import pygltflib

    g = pygltflib.GLTF2().load(str(src))
    blob = bytearray(g.binary_blob())
    turn = Rotation.from_euler("x", 90, degrees=True)
    t4 = np.eye(4)
    t4[:3, :3] = turn.as_matrix()
    mesh_node = next(n for n in g.nodes if n.skin is not None)

    def rewrite(i, fn, n):
        a, v = g.accessors[i], g.bufferViews[g.accessors[i].bufferView]
        off = (v.byteOffset or 0) + (a.byteOffset or 0)
        x = np.frombuffer(bytes(blob), np.float32, count=a.count * n, offset=off).reshape(a.count, n).astype(np.float64)
        y = fn(x).astype(np.float32)
        blob[off:off + y.nbytes] = y.tobytes()
        if a.min is not None:
            a.min, a.max = y.min(axis=0).tolist(), y.max(axis=0).tolist()

    for prim in g.meshes[mesh_node.mesh].primitives:
        rewrite(prim.attributes.POSITION, turn.apply, 3)
    rewrite(g.skins[mesh_node.skin].inverseBindMatrices,
            lambda m: (m.reshape(-1, 4, 4).transpose(0, 2, 1) @ np.linalg.inv(t4)).transpose(0, 2, 1).reshape(-1, 16), 16)
    top = g.scenes[g.scene or 0].nodes[0]
    assert g.nodes[top].rotation is None and g.nodes[top].matrix is None
    g.nodes[top].rotation = turn.as_quat().tolist()
    g.set_binary_blob(bytes(blob))
    g.save_binary(str(dst))


def test_cesium_man_stored_z_up_stands_as_the_original(assets_dir, tmp_path):
    """The real asset re-stored Z up: `auto` finds +Z and stands it exactly as the Y-up file
    (same bind mesh, same walk, per vertex); 'y' leaves it lying as stored; body measurements work."""
    from stages.rig.procedural import body_measurements

    z_up_copy(assets_dir / "CesiumMan.glb", tmp_path / "cesium_z.glb")
    orig, w0 = loaded_world(assets_dir / "CesiumMan.glb", [0.0, 0.5, 1.3])
    c, w1 = loaded_world(tmp_path / "cesium_z.glb", [0.0, 0.5, 1.3])
    assert c.notes[0].startswith("up axis: file +Z (auto")
    np.testing.assert_allclose(c.vertices, orig.vertices, atol=1e-6)
    np.testing.assert_allclose(w1, w0, atol=1e-5)
    lying = load_gltf(tmp_path / "cesium_z.glb", up_axis="y")
    assert np.ptp(lying.vertices[:, 2]) > 1.4 and np.ptp(lying.vertices[:, 1]) < 0.4
    m, m0 = body_measurements(c), body_measurements(orig)
    for key in ("height", "chest", "waist", "hips"):
        assert m[key] == pytest.approx(m0[key], abs=1e-5)
