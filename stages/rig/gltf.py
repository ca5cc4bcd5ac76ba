"""glTF 2.0 skinned characters -> `Character` (bind mesh, skeleton, weights, baked clips).

pygltflib parses the JSON; the GLB container, buffers and accessors are read here so that every
foreseeable defect (truncated file, missing buffer, out-of-range accessor) becomes one
`InputError` naming the file and the problem.

Conventions (glTF spec):
- A skinned mesh node's own transform is ignored; vertices are in the skin's bind space and
  `x_world = sum_k w_k * world(joint_k) @ inverse_bind_k @ x`.
- The skeleton = the skin joints plus every node on the path from a joint up to the joints'
  lowest common ancestor (and up to the highest animated ancestor of it, if any), so non-joint
  nodes between joints become unweighted joints and the FK stays exact. Joints are re-ordered
  depth-first (parents[j] < j). If the joints share no ancestor, a synthetic root `__root__` is added.
- The static transform P of the nodes above that root, the `up_axis` rotation and the `scale`
  factor are folded in as follows (P must be a rotation + translation + uniform scale):
  U = up_rotation * scale, U @ P = A * s with A rigid and s = scale * scale(P). Then
  every joint translation is multiplied by s, the root's local transform is pre-multiplied by A,
  inverse_bind' = diag(s) @ inverse_bind @ U^-1 and vertices' = U @ vertices. Skinned positions
  are exactly U applied to the glTF world positions, and bone-local frames stay metric (rigid).

Animation baking (the `Clip` contract has one interpolation mode per clip):
- all channels STEP -> a 'step' clip at the union of key times (exact);
- otherwise a 'linear' clip at the union of the LINEAR / STEP key times, plus, for every STEP
  key t_k (k > 0), a key at t_k - 1e-6 s holding the previous value (so linear playback reproduces
  the step except within 1 us of it), plus, for CUBICSPLINE channels, dense samples: each key
  segment is cut into ceil(duration * cubic_rate) pieces, doubled until lerp / slerp between the
  samples is within `cubic_tol` of the exact Hermite curve at the piece midpoints.
Every baked key is the exact sampler value (`sample_gltf_channel`). Joints without a channel keep
their rest TRS. Channels on nodes outside the skeleton and 'weights' (morph) channels are ignored.
Clip times keep the file's times (usually starting at 0); `loop` sets every clip's loop flag.
"""
from __future__ import annotations

import base64
import json
import struct
import urllib.parse
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from stages.errors import InputError
from stages.rig.transforms import slerp, trs_to_matrix
from stages.rig.types import Character, Clip

_COMPONENT_DTYPES = {
    5120: np.dtype("<i1"),
    5121: np.dtype("<u1"),
    5122: np.dtype("<i2"),
    5123: np.dtype("<u2"),
    5125: np.dtype("<u4"),
    5126: np.dtype("<f4"),
}
_TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_MODE_NAMES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP", 4: "TRIANGLES", 5: "TRIANGLE_STRIP", 6: "TRIANGLE_FAN"}
_PATH_SIZES = {"translation": 3, "rotation": 4, "scale": 3}
_STEP_EPS = 1e-6  # seconds before a STEP key where the baked linear clip still holds the old value


# --------------------------------------------------------------------------------------------
# File, buffers, accessors
# --------------------------------------------------------------------------------------------

def _parse_glb(path: Path, data: bytes) -> tuple[str, bytes | None]:
    """Split a GLB container into its JSON text and its BIN chunk (None if absent)."""
    if len(data) < 20:
        raise InputError(path, f"truncated GLB: {len(data)} bytes, shorter than the 20-byte header")
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF":
        raise InputError(path, "not a GLB file (bad magic)")
    if version != 2:
        raise InputError(path, f"GLB version {version} is not supported (need 2)")
    if length > len(data):
        raise InputError(path, f"truncated GLB: header says {length} bytes, file has {len(data)}")
    pos, json_text, bin_chunk = 12, None, None
    while pos + 8 <= length:
        chunk_len, chunk_type = struct.unpack_from("<I4s", data, pos)
        start, end = pos + 8, pos + 8 + chunk_len
        if end > length:
            raise InputError(path, f"truncated GLB: chunk {chunk_type!r} runs past the end of the file")
        if chunk_type == b"JSON" and json_text is None:
            try:
                json_text = data[start:end].decode("utf-8")
            except UnicodeDecodeError:
                raise InputError(path, "GLB JSON chunk is not valid UTF-8") from None
        elif chunk_type == b"BIN\x00" and bin_chunk is None:
            bin_chunk = data[start:end]
        pos = end + (-chunk_len % 4)
    if json_text is None:
        raise InputError(path, "GLB has no JSON chunk")
    return json_text, bin_chunk


def _load_document(path: Path):
    import pygltflib

    try:
        data = path.read_bytes()
    except OSError as e:
        raise InputError(path, f"cannot read file: {e.strerror or e}") from None
    if data[:4] == b"glTF":
        json_text, bin_chunk = _parse_glb(path, data)
    else:
        bin_chunk = None
        try:
            json_text = data.decode("utf-8-sig")
        except UnicodeDecodeError:
            raise InputError(path, "neither a GLB file nor UTF-8 glTF JSON") from None
    try:
        as_dict = json.loads(json_text)
    except json.JSONDecodeError as e:
        raise InputError(path, f"corrupt glTF JSON: {e.msg} at line {e.lineno} column {e.colno}") from None
    if not isinstance(as_dict, dict) or "asset" not in as_dict:
        raise InputError(path, "not a glTF document (no 'asset' object)")
    try:
        doc = pygltflib.GLTF2.from_json(json_text)
    except Exception as e:  # pygltflib / dataclasses_json raise assorted types on malformed fields
        raise InputError(path, f"malformed glTF JSON ({type(e).__name__}: {e})") from None
    return doc, bin_chunk


class _Reader:
    """Buffers and accessors of one document, with bounds checks."""

    def __init__(self, path: Path, doc, bin_chunk: bytes | None):
        self.path, self.doc, self.bin_chunk = path, doc, bin_chunk
        self._buffers: dict[int, bytes] = {}

    def fail(self, problem: str):
        raise InputError(self.path, problem)

    def buffer(self, i: int) -> bytes:
        if i in self._buffers:
            return self._buffers[i]
        if not 0 <= i < len(self.doc.buffers):
            self.fail(f"buffer {i} does not exist ({len(self.doc.buffers)} buffers)")
        b = self.doc.buffers[i]
        uri = b.uri
        if uri is None:
            if i != 0 or self.bin_chunk is None:
                self.fail(f"buffer {i} has no uri and there is no GLB BIN chunk")
            data = self.bin_chunk
        elif uri.startswith("data:"):
            head, _, payload = uri.partition(",")
            if not head.endswith(";base64"):
                self.fail(f"buffer {i}: only base64 data URIs are supported")
            try:
                data = base64.b64decode(payload, validate=True)
            except ValueError:
                self.fail(f"buffer {i}: corrupt base64 data URI")
        else:
            file = self.path.parent / urllib.parse.unquote(uri)
            try:
                data = file.read_bytes()
            except OSError:
                self.fail(f"buffer {i}: external file {uri!r} is missing or unreadable")
        if b.byteLength is not None and len(data) < b.byteLength:
            self.fail(f"buffer {i} is truncated: {len(data)} bytes, byteLength says {b.byteLength}")
        self._buffers[i] = data
        return data

    def _view_bytes(self, view_index: int) -> tuple[bytes, int, int, int | None]:
        views = self.doc.bufferViews
        if view_index is None or not 0 <= view_index < len(views):
            self.fail(f"bufferView {view_index} does not exist ({len(views)} bufferViews)")
        v = views[view_index]
        data = self.buffer(v.buffer if v.buffer is not None else -1)
        off = v.byteOffset or 0
        if v.byteLength is None or off + v.byteLength > len(data):
            self.fail(f"bufferView {view_index} lies outside buffer {v.buffer} ({len(data)} bytes)")
        return data, off, v.byteLength, v.byteStride

    def _read_view(self, view_index, byte_offset, count, dtype, ncomp, what) -> np.ndarray:
        data, view_off, view_len, stride = self._view_bytes(view_index)
        elem = dtype.itemsize * ncomp
        stride = stride or elem
        start = view_off + (byte_offset or 0)
        need = (byte_offset or 0) + (count - 1) * stride + elem if count else 0
        if need > view_len:
            self.fail(f"{what} reads {need} bytes past the start of bufferView {view_index} ({view_len} bytes)")
        if count == 0:
            return np.zeros((0, ncomp), dtype)
        arr = np.ndarray((count, ncomp), dtype=dtype, buffer=data, offset=start, strides=(stride, dtype.itemsize))
        return np.array(arr)  # own, aligned copy

    def accessor(self, index, what: str = "accessor") -> np.ndarray:
        """Accessor `index` as a (count, ncomp) array: float64 for floats / normalized, else int64."""
        acc_list = self.doc.accessors
        if index is None or not 0 <= index < len(acc_list):
            self.fail(f"{what}: accessor {index} does not exist ({len(acc_list)} accessors)")
        a = acc_list[index]
        what = f"{what} (accessor {index})"
        dtype = _COMPONENT_DTYPES.get(a.componentType)
        if dtype is None:
            self.fail(f"{what}: unknown componentType {a.componentType}")
        ncomp = _TYPE_SIZES.get(a.type)
        if ncomp is None:
            self.fail(f"{what}: unknown type {a.type!r}")
        count = a.count or 0
        if a.bufferView is None:
            out = np.zeros((count, ncomp), dtype)
        else:
            out = self._read_view(a.bufferView, a.byteOffset, count, dtype, ncomp, what)
        if a.sparse is not None and a.sparse.count:
            sp = a.sparse
            idt = _COMPONENT_DTYPES.get(sp.indices.componentType)
            if idt is None or idt.kind != "u":
                self.fail(f"{what}: bad sparse index componentType {sp.indices.componentType}")
            idx = self._read_view(sp.indices.bufferView, sp.indices.byteOffset, sp.count, idt, 1, what)[:, 0]
            vals = self._read_view(sp.values.bufferView, sp.values.byteOffset, sp.count, dtype, ncomp, what)
            if np.any(idx >= count):
                self.fail(f"{what}: sparse index out of range")
            out = out.copy()
            out[idx.astype(np.int64)] = vals
        if dtype.kind == "f":
            out = out.astype(np.float64)
        elif a.normalized:
            info = np.iinfo(dtype)
            out = np.maximum(out.astype(np.float64) / info.max, -1.0)
        else:
            out = out.astype(np.int64)
        if out.dtype == np.float64 and not np.all(np.isfinite(out)):
            self.fail(f"{what}: contains NaN or infinite values")
        return out


# --------------------------------------------------------------------------------------------
# Transforms
# --------------------------------------------------------------------------------------------

def _decompose(m: np.ndarray, what: str, path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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


def _node_trs(node) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The node's TRS if given as TRS (None if it uses a matrix)."""
    if node.matrix is not None and not np.allclose(node.matrix, np.eye(4).ravel()):
        return None
    t = np.array(node.translation if node.translation is not None else [0, 0, 0], np.float64)
    q = np.array(node.rotation if node.rotation is not None else [0, 0, 0, 1], np.float64)
    s = np.array(node.scale if node.scale is not None else [1, 1, 1], np.float64)
    return t, q / np.linalg.norm(q), s


def _node_matrix(node) -> np.ndarray:
    trs = _node_trs(node)
    if trs is None:
        return np.array(node.matrix, np.float64).reshape(4, 4).T  # column-major in glTF
    return trs_to_matrix(*trs)


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
# Skeleton
# --------------------------------------------------------------------------------------------

def _parents_of_nodes(path, doc) -> dict[int, int]:
    parent: dict[int, int] = {}
    n_nodes = len(doc.nodes)
    for i, node in enumerate(doc.nodes):
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


def _chain(parent: dict[int, int], n: int) -> list[int]:
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


def load_gltf(path, *, scale: float = 1.0, up_axis: str = "y", loop: bool = True,
              cubic_rate: float = 60.0, cubic_tol: float = 1e-4) -> Character:
    """Load a skinned glTF 2.0 (.glb, or .gltf with external .bin / data URIs) as a Character.

    scale: multiplies every length (vertices, joint translations, inverse binds).
    up_axis: 'y' (glTF) or 'z' (rotate a Z-up asset to Y up: (x, y, z) -> (x, z, -y)).
    loop: the loop flag of every clip. cubic_rate (Hz) / cubic_tol: CUBICSPLINE baking (module doc).
    Every skinned mesh node (mesh + skin) contributes its triangle primitives; `primitive_ids`
    numbers them in file order. Skin weights keep the 8 strongest influences (K = 8 when any
    primitive has JOINTS_1, else K = 4), renormalised.
    Raises InputError (naming the file) for unreadable / corrupt / unsupported content.
    """
    path = Path(path)
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(path, f"scale must be a positive number, got {scale}")
    if up_axis not in ("y", "z"):
        raise InputError(path, f"up_axis must be 'y' or 'z', got {up_axis!r}")
    doc, bin_chunk = _load_document(path)
    rd = _Reader(path, doc, bin_chunk)
    nodes = doc.nodes or []
    parent = _parents_of_nodes(path, doc)

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

    # Skeleton root: lowest common ancestor of the joints, raised to the highest animated ancestor.
    chains = [_chain(parent, j) for j in skin_joint_nodes]
    common = set(chains[0]).intersection(*map(set, chains[1:]))
    if common:
        lca = next(n for n in chains[0] if n in common)
        top = lca
        for n in _chain(parent, lca)[1:]:
            if n in animated:
                top = n
        synthetic = False
    else:
        top, synthetic = -1, True  # no common ancestor: add '__root__' above the tree tops
    included: set[int] = set()
    for ch in chains:
        for n in ch:
            included.add(n)
            if n == top:
                break
    if synthetic:
        children = {n: [] for n in included}
        tops = [ch[-1] for ch in chains]
        children[-1] = list(dict.fromkeys(tops))
    else:
        children = {n: [] for n in included}
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
    nj = len(order)
    parents = np.array([-1] + [index_of[parent[n]] if n in parent and parent[n] in index_of else 0
                               for n in order[1:]], np.int32)
    names = _unique_names(["__root__" if n < 0 else (nodes[n].name or f"node_{n}") for n in order])

    # Rest TRS of every joint (in the file's units) and the static transform above the root.
    rest_trs = []
    for n in order:
        if n < 0:
            rest_trs.append((np.zeros(3), np.array([0.0, 0, 0, 1]), np.ones(3)))
            continue
        trs = _node_trs(nodes[n])
        if trs is None:
            trs = _decompose(_node_matrix(nodes[n]), f"node {n} ({names[index_of[n]]}) matrix", path)
        rest_trs.append(trs)
    above = np.eye(4)
    if not synthetic:
        for n in _chain(parent, top)[1:]:
            above = _node_matrix(nodes[n]) @ above
    up = np.eye(4)
    if up_axis == "z":
        up[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]
    u4 = up @ np.diag([scale, scale, scale, 1.0])
    q = u4 @ above
    det = np.linalg.det(q[:3, :3])
    if det <= 0:
        raise InputError(path, "the nodes above the skeleton mirror or collapse it (determinant <= 0)")
    s_len = float(np.cbrt(det))
    r_top = q[:3, :3] / s_len
    if not np.allclose(r_top.T @ r_top, np.eye(3), atol=1e-5):
        raise InputError(path, "the nodes above the skeleton have non-uniform scale or shear (unsupported)")
    a_top = np.eye(4)
    a_top[:3, :3] = r_top
    a_top[:3, 3] = q[:3, 3]
    q_top = Rotation.from_matrix(r_top).as_quat()

    def convert_trs(j, t, qr, sc):
        """File-frame local TRS of joint j -> Character-frame TRS (length scale; A on the root)."""
        t = t * s_len
        if j == 0:
            t = t @ r_top.T + a_top[:3, 3]
            qr = (Rotation.from_quat(q_top) * Rotation.from_quat(qr)).as_quat()
        return t, qr, sc

    rest_conv = [convert_trs(j, t[None], qr[None], sc[None]) for j, (t, qr, sc) in enumerate(rest_trs)]
    rest_t = np.concatenate([c[0] for c in rest_conv])
    rest_q = np.concatenate([c[1] for c in rest_conv])
    rest_s = np.concatenate([c[2] for c in rest_conv])
    rest_local = trs_to_matrix(rest_t, rest_q, rest_s)
    # Matrix nodes whose TRS decomposition is exact except for float noise: keep matrices exact.
    for j, n in enumerate(order):
        if n >= 0 and _node_trs(nodes[n]) is None:
            m = _node_matrix(nodes[n]).copy()
            m[:3, 3] *= s_len
            rest_local[j] = a_top @ m if j == 0 else m

    # Inverse binds (file frame); several skins must agree up to one bind-space change per skin.
    ibm_file: dict[int, np.ndarray] = {}
    bind_change: dict[int, np.ndarray] = {}
    for s in used_skins:
        sk = skins[s]
        if sk.inverseBindMatrices is None:
            ibms = np.tile(np.eye(4), (len(sk.joints), 1, 1))
        else:
            raw = rd.accessor(sk.inverseBindMatrices, f"skin {s} inverseBindMatrices")
            if raw.shape != (len(sk.joints), 16):
                raise InputError(path, f"skin {s}: inverseBindMatrices has {raw.shape[0]} matrices of "
                                       f"{raw.shape[1]} values, expected {len(sk.joints)} MAT4")
            ibms = raw.reshape(-1, 4, 4).transpose(0, 2, 1)
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
    # Unweighted joints (inserted nodes, synthetic root): inverse of their rest world transform.
    rest_world_file = np.empty((nj, 4, 4))
    for j, n in enumerate(order):
        local = np.eye(4) if n < 0 else _node_matrix(nodes[n])
        rest_world_file[j] = (above if j == 0 else rest_world_file[parents[j]]) @ local
    inv_u4 = np.linalg.inv(u4)
    s4 = np.diag([s_len, s_len, s_len, 1.0])
    inverse_bind = np.empty((nj, 4, 4))
    for j, n in enumerate(order):
        ibm = ibm_file[n] if n in ibm_file else np.linalg.inv(rest_world_file[j])
        inverse_bind[j] = s4 @ ibm @ inv_u4

    # Meshes.
    verts, tris, prim_ids, joints_l, weights_l = [], [], [], [], []
    n_prims = 0
    offset = 0
    for ni in skinned:
        node = nodes[ni]
        sk_index = node.skin
        joint_map = np.array([index_of[jn] for jn in skins[sk_index].joints], np.int64)
        to_model = u4 @ bind_change[sk_index]
        mesh = doc.meshes[node.mesh]
        for pi, prim in enumerate(mesh.primitives or []):
            where = f"mesh {node.mesh} ({mesh.name or 'unnamed'}) primitive {pi}"
            mode = 4 if prim.mode is None else prim.mode
            if mode != 4:
                raise InputError(path, f"{where}: mode {_MODE_NAMES.get(mode, mode)} is not supported (triangles only)")
            attrs = prim.attributes
            if attrs is None or attrs.POSITION is None:
                raise InputError(path, f"{where}: no POSITION attribute")
            pos = rd.accessor(attrs.POSITION, f"{where} POSITION")
            if pos.shape[1] != 3 or pos.dtype != np.float64:
                raise InputError(path, f"{where}: POSITION must be float VEC3")
            nv = pos.shape[0]
            jsets, wsets = [], []
            for k in range(8):
                ja, wa = getattr(attrs, f"JOINTS_{k}", None), getattr(attrs, f"WEIGHTS_{k}", None)
                if ja is None and wa is None:
                    break
                if ja is None or wa is None:
                    raise InputError(path, f"{where}: JOINTS_{k} and WEIGHTS_{k} must come together")
                jv = rd.accessor(ja, f"{where} JOINTS_{k}")
                wv = rd.accessor(wa, f"{where} WEIGHTS_{k}")
                if jv.shape != (nv, 4) or wv.shape != (nv, 4) or jv.dtype != np.int64:
                    raise InputError(path, f"{where}: JOINTS_{k} / WEIGHTS_{k} must be {nv} integer / float VEC4")
                jsets.append(jv)
                wsets.append(wv)
            if not jsets:
                raise InputError(path, f"{where}: skinned mesh without JOINTS_0 / WEIGHTS_0")
            jv = np.concatenate(jsets, axis=1)
            wv = np.concatenate(wsets, axis=1)
            if np.any(wv < -1e-3):
                raise InputError(path, f"{where}: negative skin weights")
            wv = np.maximum(wv, 0.0)
            bad = (jv < 0) | (jv >= joint_map.size)
            if np.any(bad & (wv > 0)):
                raise InputError(path, f"{where}: JOINTS_n index beyond the skin's {joint_map.size} joints")
            wv[bad] = 0.0  # zero-weight slots may hold anything
            jv = np.clip(jv, 0, joint_map.size - 1)
            if prim.indices is None:
                if nv % 3:
                    raise InputError(path, f"{where}: {nv} vertices without indices is not a triangle list")
                idx = np.arange(nv, dtype=np.int64)
            else:
                idx = rd.accessor(prim.indices, f"{where} indices")
                if idx.shape[1] != 1 or idx.dtype != np.int64:
                    raise InputError(path, f"{where}: indices must be an integer SCALAR accessor")
                idx = idx[:, 0]
            if idx.size % 3:
                raise InputError(path, f"{where}: {idx.size} indices is not a multiple of 3")
            if idx.size and (idx.min() < 0 or idx.max() >= nv):
                raise InputError(path, f"{where}: triangle index {int(idx.max())} out of range ({nv} vertices)")
            verts.append(pos @ to_model[:3, :3].T + to_model[:3, 3])
            tris.append(idx.reshape(-1, 3) + offset)
            prim_ids.append(np.full(nv, n_prims, np.int32))
            joints_l.append(joint_map[jv])
            weights_l.append(wv)
            offset += nv
            n_prims += 1
    if not verts:
        raise InputError(path, "the skinned meshes have no primitives")
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
        raise InputError(path, f"{int(np.sum(sums <= 0))} vertices have all skin weights zero")
    sw /= sums[:, None]

    root_joint = min(index_of[n] for n in skin_joint_nodes)
    try:
        clips = _bake_clips(path, doc, rd, order, index_of, rest_trs, convert_trs, loop, cubic_rate, cubic_tol)
        return Character(
            name=path.stem,
            vertices=np.concatenate(verts),
            triangles=np.concatenate(tris).astype(np.int32),
            primitive_ids=np.concatenate(prim_ids),
            joint_names=names,
            parents=parents,
            rest_local=rest_local,
            inverse_bind=inverse_bind,
            skin_joints=sj,
            skin_weights=sw,
            clips=tuple(clips),
            root_joint=root_joint,
            source=str(path),
        )
    except ValueError as e:  # a ContractError here means the file holds something we mis-read
        raise InputError(path, f"inconsistent content: {e}") from None


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
