"""glTF loading: a hand-made file against an independent evaluator, and the real CesiumMan /
RiggedSimple assets against a per-vertex LBS computed straight from pygltflib accessors."""
from __future__ import annotations

import base64
import json
import struct
from dataclasses import replace

import numpy as np
import pygltflib
import pytest
from scipy.spatial.transform import Rotation, Slerp

from stages.errors import InputError
from stages.rig.gltf import load_gltf, sample_gltf_channel
from stages.rig.skinning import rest_motion, sample_motion, skin

# --------------------------------------------------------------------------------------------
# A tiny glTF writer (json + bytes), independent of the loader.
# --------------------------------------------------------------------------------------------

_CT = {np.int8: 5120, np.uint8: 5121, np.int16: 5122, np.uint16: 5123, np.uint32: 5125, np.float32: 5126}
_TYPE = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4", 16: "MAT4"}


class Builder:
    def __init__(self):
        self.blob = bytearray()
        self.views, self.accessors = [], []
        self.doc = {"asset": {"version": "2.0"}}

    def accessor(self, arr, dtype, normalized=False) -> int:
        arr = np.asarray(arr)
        ncomp = 1 if arr.ndim == 1 else arr.shape[1]
        raw = np.ascontiguousarray(arr, dtype=dtype).tobytes()
        while len(self.blob) % 4:
            self.blob.append(0)
        self.views.append({"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(raw)})
        self.blob += raw
        acc = {"bufferView": len(self.views) - 1, "componentType": _CT[dtype], "count": int(arr.shape[0]),
               "type": _TYPE[ncomp]}
        if normalized:
            acc["normalized"] = True
        if dtype is np.float32 and ncomp == 3:
            acc["min"] = arr.min(axis=0).tolist()
            acc["max"] = arr.max(axis=0).tolist()
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def document(self, uri=None) -> dict:
        while len(self.blob) % 4:
            self.blob.append(0)
        d = dict(self.doc)
        d["bufferViews"] = self.views
        d["accessors"] = self.accessors
        buf = {"byteLength": len(self.blob)}
        if uri is not None:
            buf["uri"] = uri
        d["buffers"] = [buf]
        return d

    def write_glb(self, path):
        js = json.dumps(self.document()).encode()
        js += b" " * (-len(js) % 4)
        body = struct.pack("<I4s", len(js), b"JSON") + js + struct.pack("<I4s", len(self.blob), b"BIN\x00") + bytes(self.blob)
        path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body)

    def write_gltf(self, path, external: bool):
        if external:
            (path.parent / (path.stem + ".bin")).write_bytes(bytes(self.blob))
            doc = self.document(uri=path.stem + ".bin")
        else:
            doc = self.document(uri="data:application/octet-stream;base64," + base64.b64encode(bytes(self.blob)).decode())
        path.write_text(json.dumps(doc))


def quat(axis, angle):
    return Rotation.from_rotvec(np.asarray(axis, float) / np.linalg.norm(axis) * angle).as_quat()


# Node layout of the hand-made character (indices into "nodes"):
#   0 'above' (translation + rotation + uniform scale 2, above the skeleton) -> [1, 7]
#   1 'hip' joint (animated: LINEAR translation, CUBICSPLINE rotation) -> [2]
#   2 'mid' joint given as a matrix -> [3]
#   3 'arm' joint (STEP rotation) -> [4]
#   4 'helper' non-joint node between joints -> [5]
#   5 'hand' joint (LINEAR scale) -> [6]
#   6 'tip' joint (CUBICSPLINE translation)
#   7 'body' mesh node (its own transform must be ignored: skinned)
MID_MATRIX = np.eye(4)
MID_MATRIX[:3, :3] = Rotation.from_euler("xyz", [0.3, -0.2, 0.5]).as_matrix()
MID_MATRIX[:3, 3] = [0.0, 0.6, 0.1]
KEY_T = np.array([0.0, 0.4, 1.0])
SKIN_ORDER = [5, 1, 6, 2, 3]  # scrambled on purpose: the loader must re-order topologically


def node_trs():
    """Static TRS of every node (the rest pose)."""
    return {
        0: ([1.0, 0.5, -0.3], quat([0, 1, 0], 0.7), [2.0, 2.0, 2.0]),
        1: ([0.0, 0.2, 0.0], quat([1, 0, 0], 0.1), [1, 1, 1]),
        3: ([0.0, 0.5, 0.0], quat([0, 0, 1], -0.4), [1, 1, 1]),
        4: ([0.1, 0.3, 0.0], quat([0, 1, 0], 0.25), [1, 1, 1]),
        5: ([0.0, 0.4, 0.05], quat([1, 1, 0], 0.3), [1, 1, 1]),
        6: ([0.0, 0.3, 0.0], [0, 0, 0, 1.0], [1, 1, 1]),
        7: ([100.0, 0, 0], [0, 0, 0, 1.0], [1, 1, 1]),
    }


def channels(variant=None):
    """(node, path, interpolation, times, values) with values as glTF stores them."""
    rng = np.random.default_rng(7)
    hip_t = np.array([[0, 0.2, 0], [0.1, 0.25, 0.05], [0.3, 0.2, -0.1]])
    hip_r_vals = np.stack([quat([0, 1, 0], a) for a in (0.0, 0.6, -0.3)])
    hip_r = np.concatenate([np.stack([rng.normal(0, 0.3, 4), v, rng.normal(0, 0.3, 4)]) for v in hip_r_vals])
    arm_r = np.stack([quat([0, 0, 1], a) for a in (-0.4, 0.5, 1.2)])
    hand_s = np.array([[1, 1, 1], [1.2, 0.9, 1.1], [1, 1, 1]])
    tip_vals = np.array([[0, 0.3, 0], [0.05, 0.35, 0], [0, 0.3, 0.1]])
    tip_t = np.concatenate([np.stack([rng.normal(0, 0.2, 3), v, rng.normal(0, 0.2, 3)]) for v in tip_vals])
    return [
        (1, "translation", "LINEAR", KEY_T, hip_t),
        (1, "rotation", "CUBICSPLINE", KEY_T, hip_r),
        (3, "rotation", "STEP", KEY_T, arm_r),
        (5, "scale", "LINEAR", np.array([0.0, 0.5, 0.8]), hand_s),
        (6, "translation", "CUBICSPLINE", KEY_T, tip_t),
    ] + ([(0, "rotation", "LINEAR", np.array([0.0, 1.0]), np.stack([quat([0, 1, 0], 0.7), quat([1, 0, 0], 0.5)]))]
         if variant == "animated_above" else [])


def mesh_data():
    """Two primitives: (positions, triangles, joints (V, 8 or 4) as skin slots, weights)."""
    rng = np.random.default_rng(3)
    p0 = rng.uniform(-0.3, 0.3, (12, 3)) + [0, 0.8, 0]
    t0 = rng.integers(0, 12, (10, 3))
    j0 = np.stack([rng.permutation(5) for _ in range(12)])
    j0 = np.concatenate([j0, j0[:, :3]], axis=1)  # 8 slots, a few repeated joints
    w0 = rng.uniform(0, 1, (12, 8))
    w0[:, 6:] = 0.0
    w0 /= w0.sum(axis=1, keepdims=True)
    p1 = rng.uniform(-0.2, 0.2, (6, 3)) + [0, 1.4, 0]
    t1 = np.array([[0, 1, 2], [3, 4, 5]])
    j1 = rng.integers(0, 5, (6, 4))
    w1 = rng.integers(1, 256, (6, 4)).astype(np.uint8)  # unorm; rows need not sum to 255
    return (p0, t0, j0, w0), (p1, t1, j1, w1)


def build_test_gltf(skin=True, mode=4, variant=None) -> Builder:
    b = Builder()
    trs = node_trs()
    nodes = []
    for i in range(8):
        n = {"name": ["above", "hip", "mid", "arm", "helper", "hand", "tip", "body"][i]}
        if i != 2:
            t, r, s = trs[i]
            n.update(translation=list(map(float, t)), rotation=list(map(float, r)), scale=list(map(float, s)))
        else:
            n["matrix"] = MID_MATRIX.T.ravel().tolist()
        nodes.append(n)
    for parent, kids in {0: [1, 7], 1: [2], 2: [3], 3: [4], 4: [5], 5: [6]}.items():
        nodes[parent]["children"] = kids
    if variant == "two_trees":  # 'tip' becomes a scene root: the joints share no ancestor
        del nodes[5]["children"]
    (p0, t0, j0, w0), (p1, t1, j1, w1) = mesh_data()
    prim0 = {"attributes": {"POSITION": b.accessor(p0, np.float32),
                            "JOINTS_0": b.accessor(j0[:, :4], np.uint16), "WEIGHTS_0": b.accessor(w0[:, :4], np.float32),
                            "JOINTS_1": b.accessor(j0[:, 4:], np.uint16), "WEIGHTS_1": b.accessor(w0[:, 4:], np.float32)},
             "indices": b.accessor(t0.ravel(), np.uint8), "mode": mode}
    prim1 = {"attributes": {"POSITION": b.accessor(p1, np.float32),
                            "JOINTS_0": b.accessor(j1, np.uint8), "WEIGHTS_0": b.accessor(w1, np.uint8, normalized=True)},
             "indices": b.accessor(t1.ravel(), np.uint32)}
    b.doc["meshes"] = [{"name": "body", "primitives": [prim0, prim1]}]
    if skin:
        ibm = np.stack([np.linalg.inv(m) for m in bind_worlds()])
        b.doc["skins"] = [{"joints": SKIN_ORDER, "inverseBindMatrices": b.accessor(ibm.transpose(0, 2, 1).reshape(-1, 16), np.float32)}]
        nodes[7]["skin"] = 0
    nodes[7]["mesh"] = 0
    b.doc["nodes"] = nodes
    b.doc["scenes"] = [{"nodes": [0, 6] if variant == "two_trees" else [0]}]
    b.doc["scene"] = 0
    samplers, chans = [], []
    for node, pth, interp, times, vals in channels(variant):
        samplers.append({"input": b.accessor(times, np.float32), "output": b.accessor(vals, np.float32),
                         "interpolation": interp})
        chans.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": pth}})
    b.doc["animations"] = [{"name": "wave", "samplers": samplers, "channels": chans}]
    return b


def bind_worlds():
    """A bind pose that is NOT the rest pose: arbitrary rigid frames per skin joint (SKIN_ORDER),
    below the 'above' node (so the joints' world frames carry its scale 2, as an exporter writes)."""
    rng = np.random.default_rng(11)
    t, r, s = node_trs()[0]
    above = np.eye(4)
    above[:3, :3] = Rotation.from_quat(r).as_matrix() * s
    above[:3, 3] = t
    out = []
    for _ in SKIN_ORDER:
        m = np.eye(4)
        m[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.5, 3)).as_matrix()
        m[:3, 3] = rng.normal(0, 0.5, 3)
        out.append(above @ m)
    return out


# Independent evaluator of the hand-made file (from the arrays above, never from the loader).
def ref_sample(interp, pth, times, vals, t):
    times = times.astype(np.float32).astype(np.float64)  # the file stores float32
    vals = vals.astype(np.float32).astype(np.float64)
    if t <= times[0]:
        k, u = 0, 0.0
    elif t >= times[-1]:
        k, u = len(times) - 2, 1.0
    else:
        k = int(np.flatnonzero(times <= t)[-1])
        u = (t - times[k]) / (times[k + 1] - times[k])
    if interp == "STEP":
        return vals[int(np.flatnonzero(times <= t)[-1]) if t >= times[0] else 0]
    if interp == "CUBICSPLINE":
        a, v, b = vals[0::3], vals[1::3], vals[2::3]
        d = times[k + 1] - times[k]
        out = ((2 * u**3 - 3 * u**2 + 1) * v[k] + (u**3 - 2 * u**2 + u) * d * b[k]
               + (-2 * u**3 + 3 * u**2) * v[k + 1] + (u**3 - u**2) * d * a[k + 1])
        return out / np.linalg.norm(out) if pth == "rotation" else out
    if pth == "rotation":
        return Slerp([0, 1], Rotation.from_quat(vals[k:k + 2]))([u]).as_quat()[0]
    return (1 - u) * vals[k] + u * vals[k + 1]


def ref_world_vertices(t, scale=1.0, up_axis="y", variant=None):
    trs = {i: [np.array(x, float) for x in v] for i, v in node_trs().items()}
    for node, pth, interp, times, vals in channels(variant):
        trs[node][{"translation": 0, "rotation": 1, "scale": 2}[pth]] = ref_sample(interp, pth, times, vals, t)

    def local(i):
        if i == 2:
            return MID_MATRIX
        tt, r, s = trs[i]
        m = np.eye(4)
        m[:3, :3] = Rotation.from_quat(r).as_matrix() @ np.diag(s)
        m[:3, 3] = tt
        return m

    world = {0: local(0)}
    for i, p in [(1, 0), (2, 1), (3, 2), (4, 3), (5, 4), (6, 5)]:
        world[i] = world[p] @ local(i)
    if variant == "two_trees":
        world[6] = local(6)
    ibm = [np.linalg.inv(m) for m in bind_worlds()]
    out = []
    for p, _, j, w in mesh_data():
        w = w.astype(np.float64)
        w = w / w.sum(axis=1, keepdims=True)
        for v in range(p.shape[0]):
            x = np.append(p[v].astype(np.float32).astype(np.float64), 1.0)
            acc = np.zeros(4)
            for k in range(j.shape[1]):
                acc += w[v, k] * (world[SKIN_ORDER[j[v, k]]] @ ibm[j[v, k]] @ x)
            out.append(acc[:3])
    # the loader turns the file Y up and lifts the lowest bind-mesh vertex (file positions) to y = 0
    bind = np.concatenate([p.astype(np.float32).astype(np.float64) for p, _, _, _ in mesh_data()]) * scale
    out = np.array(out) * scale
    if up_axis == "z":
        out = np.stack([out[:, 0], out[:, 2], -out[:, 1]], axis=1)
        bind = np.stack([bind[:, 0], bind[:, 2], -bind[:, 1]], axis=1)
    return out - [0.0, bind[:, 1].min(), 0.0]


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    d = tmp_path_factory.mktemp("gltf")
    b = build_test_gltf()
    b.write_glb(d / "made.glb")
    b.write_gltf(d / "made_embedded.gltf", external=False)
    b.write_gltf(d / "made_external.gltf", external=True)
    return d


def test_made_structure(made):
    c = load_gltf(made / "made.glb")
    # the 5 skin joints plus the non-joint 'helper' between arm and hand; 'above' folds away
    assert c.joint_names == ("hip", "mid", "arm", "helper", "hand", "tip")
    assert c.parents.tolist() == [-1, 0, 1, 2, 3, 4]
    assert c.vertices.shape == (18, 3) and c.triangles.shape == (12, 3)
    assert c.primitive_ids.tolist() == [0] * 12 + [1] * 6
    assert c.skin_joints.shape[1] == 8  # JOINTS_1 present
    assert c.triangles[10:].min() >= 12  # the second primitive's indices are offset
    assert not np.any(c.skin_joints == 3) or np.all(c.skin_weights[c.skin_joints == 3] == 0)  # helper unweighted
    (clip,) = c.clips
    # its last pose is not its first: played once and held (loop auto), said in the notes
    assert clip.name == "wave" and clip.interpolation == "linear" and not clip.loop
    assert any("played once" in n and "wave" in n for n in c.notes)
    assert load_gltf(made / "made.glb", loop=True).clips[0].loop
    assert clip.times[0] == 0.0 and abs(clip.duration - 1.0) < 1e-6
    # STEP keys at 0.4 and 1.0 get a hold key 1 us before them; CUBICSPLINE adds dense samples
    assert np.any(np.abs(clip.times - (float(np.float32(0.4)) - 1e-6)) < 1e-12)
    assert clip.times.size > 60


@pytest.mark.parametrize("name", ["made.glb", "made_embedded.gltf", "made_external.gltf"])
def test_made_skinning_matches_independent_evaluator(made, name):
    c = load_gltf(made / name, loop=True)
    # the STEP key 0.4 is stored as float32; within 1 us before it the baked clip ramps (module doc)
    times = np.array([0.0, 0.1, 0.25, 0.39, float(np.float32(0.4)), 0.55, 0.7, 0.85, 0.999, 1.0, 1.3])  # 1.3: loop wraps
    m = sample_motion(c, "wave", times)
    world = skin(c, m) + m.root_translation[:, None, :]
    for f, t in enumerate(times):
        ref = ref_world_vertices(t % 1.0)  # a looping clip wraps at its duration
        # the cubic bake tolerance is 1e-4 in values; lever arms here are < 3 m (scale 2)
        np.testing.assert_allclose(world[f], ref, atol=2e-3, err_msg=f"t = {t}")
    assert np.all(m.root_translation[0] == 0)


def test_made_scale_and_up_axis(made):
    c = load_gltf(made / "made.glb", scale=0.5, up_axis="z")
    m = sample_motion(c, 0, [0.0, 0.55])
    world = skin(c, m) + m.root_translation[:, None, :]
    np.testing.assert_allclose(world[1], ref_world_vertices(0.55, scale=0.5, up_axis="z"), atol=2e-3)
    # bone-local frames stay metric: every inverse bind has an orthonormal rotation part
    r = c.inverse_bind[:, :3, :3]
    np.testing.assert_allclose(r @ r.transpose(0, 2, 1), np.broadcast_to(np.eye(3), r.shape), atol=1e-5)


def test_made_step_channel_is_held(made):
    c = load_gltf(made / "made.glb")
    clip = c.clips[0]
    arm = c.joint_names.index("arm")
    from stages.rig.skinning import sample_clip
    loc = sample_clip(c, clip, np.array([0.2, 0.3999, float(np.float32(0.4)), 0.7]))
    want = [Rotation.from_quat(quat([0, 0, 1], a)).as_matrix() for a in (-0.4, -0.4, 0.5, 0.5)]
    for f in range(4):
        np.testing.assert_allclose(loc[f, arm, :3, :3], want[f], atol=1e-5)


def test_sample_gltf_channel_exact():
    kt = np.array([0.0, 1.0, 3.0])
    v = np.array([[0.0, 0, 0], [1, 2, 3], [1, 0, 3]])
    np.testing.assert_allclose(sample_gltf_channel(kt, v, "LINEAR", "translation", [0.5, 2.0, -1, 9]),
                               [[0.5, 1, 1.5], [1, 1, 3], [0, 0, 0], [1, 0, 3]])
    np.testing.assert_allclose(sample_gltf_channel(kt, v, "STEP", "translation", [0.999, 1.0, 2.9, 3.0]),
                               [v[0], v[1], v[1], v[2]])
    # CUBICSPLINE: passes through the values, with derivative = out-tangent at each key
    rng = np.random.default_rng(0)
    cub = np.concatenate([np.stack([rng.normal(size=3), v[k], rng.normal(size=3)]) for k in range(3)])
    np.testing.assert_allclose(sample_gltf_channel(kt, cub, "CUBICSPLINE", "translation", kt), v, atol=1e-12)
    h = 1e-6
    for k in range(2):
        d = (sample_gltf_channel(kt, cub, "CUBICSPLINE", "translation", [kt[k] + h])[0] - v[k]) / h
        np.testing.assert_allclose(d, cub[3 * k + 2], atol=1e-4)
        d_in = (v[k + 1] - sample_gltf_channel(kt, cub, "CUBICSPLINE", "translation", [kt[k + 1] - h])[0]) / h
        np.testing.assert_allclose(d_in, cub[3 * (k + 1)], atol=1e-4)
    # LINEAR rotation is slerp: constant angular speed
    q = np.stack([quat([0, 0, 1], 0.0), quat([0, 0, 1], 1.0)])
    r = sample_gltf_channel(np.array([0.0, 1.0]), q, "LINEAR", "rotation", [0.25])
    np.testing.assert_allclose(Rotation.from_quat(r).magnitude(), [0.25], atol=1e-12)


# --------------------------------------------------------------------------------------------
# Errors
# --------------------------------------------------------------------------------------------

def test_no_skin_is_an_input_error(tmp_path):
    build_test_gltf(skin=False).write_glb(tmp_path / "noskin.glb")
    with pytest.raises(InputError, match="noskin.glb: no skinned mesh"):
        load_gltf(tmp_path / "noskin.glb")


def test_non_triangle_mode_is_an_input_error(tmp_path):
    build_test_gltf(mode=1).write_glb(tmp_path / "lines.glb")
    with pytest.raises(InputError, match="mode LINES is not supported"):
        load_gltf(tmp_path / "lines.glb")


def test_missing_external_buffer(tmp_path):
    build_test_gltf().write_gltf(tmp_path / "ext.gltf", external=True)
    (tmp_path / "ext.bin").unlink()
    with pytest.raises(InputError, match="ext.gltf: buffer 0: external file 'ext.bin': buffer file not found"):
        load_gltf(tmp_path / "ext.gltf")


def test_missing_accessor(tmp_path):
    b = build_test_gltf()
    b.doc["meshes"][0]["primitives"][1]["attributes"]["POSITION"] = 999
    b.write_glb(tmp_path / "acc.glb")
    with pytest.raises(InputError, match="accessor 999 does not exist"):
        load_gltf(tmp_path / "acc.glb")


@pytest.mark.parametrize("cut", [0, 10, 19, 100, 2000, -1000, -1])
def test_truncated_glb(made, tmp_path, cut):
    data = (made / "made.glb").read_bytes()
    (tmp_path / "cut.glb").write_bytes(data[:cut])
    with pytest.raises(InputError, match="cut.glb: "):
        load_gltf(tmp_path / "cut.glb")


def test_garbage_and_missing_files(tmp_path):
    (tmp_path / "junk.gltf").write_bytes(bytes(range(256)))
    with pytest.raises(InputError, match="junk.gltf"):
        load_gltf(tmp_path / "junk.gltf")
    (tmp_path / "notgltf.gltf").write_text('{"nodes": []}')
    with pytest.raises(InputError, match="not a glTF document"):
        load_gltf(tmp_path / "notgltf.gltf")
    with pytest.raises(InputError, match="glTF file not found"):
        load_gltf(tmp_path / "absent.glb")


# --------------------------------------------------------------------------------------------
# Real assets
# --------------------------------------------------------------------------------------------

def _raw_accessor(g: pygltflib.GLTF2, blob: bytes, i: int) -> np.ndarray:
    a = g.accessors[i]
    v = g.bufferViews[a.bufferView]
    dt = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}[a.componentType]
    n = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[a.type]
    assert v.byteStride in (None, n * np.dtype(dt).itemsize)
    start = (v.byteOffset or 0) + (a.byteOffset or 0)
    return np.frombuffer(blob, dtype=dt, count=a.count * n, offset=start).reshape(a.count, n)


def _reference_world(path, t):
    """Per-vertex LBS at time t straight from pygltflib's accessors and the node tree."""
    g = pygltflib.GLTF2().load(str(path))
    blob = g.binary_blob()
    trs = {}
    for i, n in enumerate(g.nodes):
        trs[i] = [np.array(n.translation or [0, 0, 0], float), np.array(n.rotation or [0, 0, 0, 1], float),
                  np.array(n.scale or [1, 1, 1], float)]
    for anim in g.animations[:1]:
        for ch in anim.channels:
            s = anim.samplers[ch.sampler]
            kt = _raw_accessor(g, blob, s.input)[:, 0].astype(float)
            kv = _raw_accessor(g, blob, s.output).astype(float)
            slot = {"translation": 0, "rotation": 1, "scale": 2}[ch.target.path]
            if s.interpolation == "STEP" or kt.size == 1:
                val = kv[max(0, np.searchsorted(kt, t, side="right") - 1)]
            elif ch.target.path == "rotation":
                val = Slerp(kt, Rotation.from_quat(kv))([np.clip(t, kt[0], kt[-1])]).as_quat()[0]
            else:
                val = np.array([np.interp(t, kt, kv[:, c]) for c in range(kv.shape[1])])
            trs[ch.target.node][slot] = val

    def local(i):
        tt, r, s = trs[i]
        m = np.eye(4)
        m[:3, :3] = Rotation.from_quat(r).as_matrix() * s
        m[:3, 3] = tt
        return m

    world = {}

    def visit(i, pm):
        world[i] = pm @ local(i)
        for c in g.nodes[i].children or []:
            visit(c, world[i])

    for root in g.scenes[g.scene or 0].nodes:
        visit(root, np.eye(4))
    mesh_node = next(n for n in g.nodes if n.skin is not None)
    sk = g.skins[mesh_node.skin]
    ibm = _raw_accessor(g, blob, sk.inverseBindMatrices).astype(float).reshape(-1, 4, 4).transpose(0, 2, 1)
    out = []
    lift = -min(_raw_accessor(g, blob, p.attributes.POSITION)[:, 1].min() for p in g.meshes[mesh_node.mesh].primitives)
    for prim in g.meshes[mesh_node.mesh].primitives:
        pos = _raw_accessor(g, blob, prim.attributes.POSITION).astype(float)
        jts = _raw_accessor(g, blob, prim.attributes.JOINTS_0).astype(int)
        wts = _raw_accessor(g, blob, prim.attributes.WEIGHTS_0).astype(float)
        for v in range(pos.shape[0]):
            acc = np.zeros(4)
            for k in range(4):
                j = jts[v, k]
                acc += wts[v, k] / wts[v].sum() * (world[sk.joints[j]] @ ibm[j] @ np.append(pos[v], 1.0))
            out.append(acc[:3])
    return np.array(out) + [0.0, lift, 0.0]  # the loader puts the lowest bind-mesh vertex on y = 0


def _raw_bind_mesh(path) -> np.ndarray:
    """The skinned mesh's POSITION accessors as stored, every primitive in order."""
    g = pygltflib.GLTF2().load(str(path))
    mesh_node = next(n for n in g.nodes if n.skin is not None)
    return np.concatenate([_raw_accessor(g, g.binary_blob(), p.attributes.POSITION).astype(float)
                           for p in g.meshes[mesh_node.mesh].primitives])


@pytest.mark.parametrize("name", ["CesiumMan.glb", "RiggedSimple.glb"])
def test_y_up_assets_load_as_stored_plus_floor_lift(assets_dir, name):
    """Files that are Y up already: `auto` keeps the axes, vertices are the file's to 1e-9 but
    for the vertical lift that puts the lowest one on y = 0 (the only change from the loader
    before `auto`: CesiumMan rises 7.7e-8 m, RiggedSimple 0.033 m)."""
    raw = _raw_bind_mesh(assets_dir / name)
    for up_axis in ("auto", "y"):
        c = load_gltf(assets_dir / name, up_axis=up_axis)
        np.testing.assert_allclose(c.vertices, raw + [0.0, -raw[:, 1].min(), 0.0], rtol=0, atol=1e-9)
        assert c.vertices[:, 1].min() == 0.0
        assert c.notes[0].startswith("up axis: file +Y")


@pytest.fixture(scope="module")
def cesium(assets_dir):
    return load_gltf(assets_dir / "CesiumMan.glb")


def test_cesium_man_structure(cesium):
    c = cesium
    assert c.n_joints == 19
    assert c.vertices.shape == (3273, 3) and c.triangles.shape == (4672, 3)
    assert c.skin_joints.shape == (3273, 4)
    (clip,) = c.clips
    assert clip.duration == pytest.approx(2.0, abs=1e-6) and clip.loop
    assert c.joint_names[c.root_joint] == "Skeleton_torso_joint_1"
    # upright, Y up, feet at y ~ 0, about 1.5 m tall
    lo, hi = c.vertices.min(axis=0), c.vertices.max(axis=0)
    assert abs(lo[1]) < 0.01 and 1.45 < hi[1] < 1.55
    assert np.argmax(hi - lo) == 1 or (hi - lo)[1] > 1.3


def test_cesium_man_skin_matches_raw_accessors(cesium, assets_dir):
    m = sample_motion(cesium, 0, [0.0, 0.5])
    world = skin(cesium, m) + m.root_translation[:, None, :]
    ref = _reference_world(assets_dir / "CesiumMan.glb", 0.5)
    np.testing.assert_allclose(world[1], ref, atol=2e-5)
    ref0 = _reference_world(assets_dir / "CesiumMan.glb", 0.0)
    np.testing.assert_allclose(world[0], ref0, atol=2e-5)
    # the walk keeps the feet near the ground
    assert -0.03 < world[1][:, 1].min() < 0.05


def test_cesium_man_rest_pose_reproduces_bind_mesh(cesium):
    v = skin(cesium, rest_motion(cesium, 2, 1 / 30))
    np.testing.assert_allclose(v[0], cesium.vertices, atol=1e-5)
    np.testing.assert_allclose(v[1], cesium.vertices, atol=1e-5)


def test_rigged_simple(assets_dir):
    c = load_gltf(assets_dir / "RiggedSimple.glb")
    assert c.n_joints == 4 and c.parents.tolist() == [-1, 0, 1, 2]
    (clip,) = c.clips
    assert clip.duration == pytest.approx(6.6667, abs=1e-3)
    m = sample_motion(c, 0, [0.0, 2.0])
    world = skin(c, m) + m.root_translation[:, None, :]
    np.testing.assert_allclose(world[1], _reference_world(assets_dir / "RiggedSimple.glb", 2.0), atol=2e-5)
    np.testing.assert_allclose(skin(c, rest_motion(c, 1, 0.1))[0], c.vertices, atol=1e-5)


def test_sparse_accessor_positions(made, tmp_path):
    b = build_test_gltf()
    prim = b.doc["meshes"][0]["primitives"][1]
    dense = b.accessors[prim["attributes"]["POSITION"]]
    (_, _, _, _), (p1, _, _, _) = mesh_data()
    idx = b.accessor(np.array([1, 4], np.uint32), np.uint32)
    val = b.accessor(p1[[1, 4]] + 10.0, np.float32)
    sparse = dict(dense)
    sparse["sparse"] = {"count": 2, "indices": {"bufferView": b.accessors[idx]["bufferView"], "componentType": 5125},
                        "values": {"bufferView": b.accessors[val]["bufferView"]}}
    b.accessors.append(sparse)
    prim["attributes"]["POSITION"] = len(b.accessors) - 1
    b.write_glb(tmp_path / "sparse.glb")
    got = load_gltf(tmp_path / "sparse.glb").vertices
    base = load_gltf(made / "made.glb").vertices
    moved = np.zeros(18, bool)
    moved[[12 + 1, 12 + 4]] = True
    np.testing.assert_allclose(got[~moved], base[~moved], atol=1e-6)
    assert np.all(np.linalg.norm(got[moved] - base[moved], axis=1) > 10.0)  # moved by 10 * (2 * R) scale


@pytest.mark.parametrize("variant, names", [
    ("animated_above", ("above", "hip", "mid", "arm", "helper", "hand", "tip")),
    ("two_trees", ("__root__", "above", "hip", "mid", "arm", "helper", "hand", "tip")),
])
def test_skeleton_root_variants(tmp_path, variant, names):
    """An animated node above the joints joins the skeleton; joints in two trees get a synthetic root."""
    build_test_gltf(variant=variant).write_glb(tmp_path / "v.glb")
    c = load_gltf(tmp_path / "v.glb")
    assert c.joint_names == names
    assert c.joint_names[c.root_joint] == "hip"
    times = np.array([0.0, 0.25, 0.55, 0.85])
    m = sample_motion(c, 0, times)
    world = skin(c, m) + m.root_translation[:, None, :]
    for f, t in enumerate(times):
        np.testing.assert_allclose(world[f], ref_world_vertices(t, variant=variant), atol=2e-3, err_msg=f"t = {t}")


@pytest.mark.assets
def test_a_clip_loops_when_its_last_pose_meets_its_first(assets_dir):
    # Kenney's 'die' ends lying down (72 % of the height from its first pose): looped, it jumped
    # back up every third of a second and threw the cloth off; its walk and CesiumMan's are cycles
    from stages.rig.gltf import cycles
    k = load_gltf(assets_dir / "kenney_mini_male_a.glb")
    loops = {c.name: c.loop for c in k.clips}
    assert loops["walk"] and loops["idle"] and loops["sprint"] and not loops["die"]
    assert load_gltf(assets_dir / "CesiumMan.glb").clips[0].loop
    die = next(c for c in k.clips if c.name == "die")
    assert cycles(k.parents, replace(die, translations=die.translations[:1].repeat(die.times.size, 0),
                                     rotations=die.rotations[:1].repeat(die.times.size, 0),
                                     scales=die.scales[:1].repeat(die.times.size, 0)), 0.67)   # a held pose loops
