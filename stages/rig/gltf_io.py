"""glTF 2.0 file access: the GLB container, buffers and accessors, with bounds checks.

pygltflib parses the JSON; the bytes are read here so that every foreseeable defect (truncated
file, missing buffer, out-of-range accessor) becomes one `InputError` naming the file and the problem.
"""
from __future__ import annotations

import base64
import json
import struct
import urllib.parse
from pathlib import Path
from typing import NoReturn

import numpy as np

from stages.errors import InputError

COMPONENT_DTYPES = {
    5120: np.dtype("<i1"),
    5121: np.dtype("<u1"),
    5122: np.dtype("<i2"),
    5123: np.dtype("<u2"),
    5125: np.dtype("<u4"),
    5126: np.dtype("<f4"),
}
TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


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


def load_document(path: Path):
    import pygltflib

    from stages.input_files import read_bytes
    data = read_bytes(path, "glTF file")   # a FIFO or device is refused unopened
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
    _check_node_transforms(path, doc)
    return doc, bin_chunk


_NODE_SIZES = {"translation": 3, "rotation": 4, "scale": 3, "matrix": 16}


def _check_node_transforms(path: Path, doc) -> None:
    """Node TRS / matrix fields are lists of finite numbers of the spec's length (pygltflib takes
    any JSON there: a 4-number translation reached the matrix code as a broadcast error)."""
    for i, n in enumerate(doc.nodes or []):
        for key, size in _NODE_SIZES.items():
            v = getattr(n, key, None)
            if v is None:
                continue
            ok = isinstance(v, (list, tuple)) and len(v) == size and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) for x in v)
            if not ok:
                raise InputError(path, f"node {i} ({n.name!r}): {key} must be {size} finite numbers, got {str(v)[:60]}")


class Reader:
    """Buffers and accessors of one document, with bounds checks."""

    def __init__(self, path: Path, doc, bin_chunk: bytes | None):
        self.path, self.doc, self.bin_chunk = path, doc, bin_chunk
        self._buffers: dict[int, bytes] = {}

    def fail(self, problem: str) -> NoReturn:
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
            from stages.input_files import MAX_ASSET_BYTES, file_problem
            file = self.path.parent / urllib.parse.unquote(uri)
            problem = file_problem(file, "buffer file", MAX_ASSET_BYTES)
            if problem:
                self.fail(f"buffer {i}: external file {uri!r}: {problem}")
            try:
                with open(file, "rb") as f:   # no more than the buffer's length
                    data = f.read(b.byteLength if b.byteLength is not None else -1)
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
        dtype = COMPONENT_DTYPES.get(a.componentType)
        if dtype is None:
            self.fail(f"{what}: unknown componentType {a.componentType}")
        ncomp = TYPE_SIZES.get(a.type)
        if ncomp is None:
            self.fail(f"{what}: unknown type {a.type!r}")
        count = a.count or 0
        if a.bufferView is None:
            out = np.zeros((count, ncomp), dtype)
        else:
            out = self._read_view(a.bufferView, a.byteOffset, count, dtype, ncomp, what)
        if a.sparse is not None and a.sparse.count:
            sp = a.sparse
            idt = COMPONENT_DTYPES.get(sp.indices.componentType)
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


_MODE_NAMES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP", 4: "TRIANGLES", 5: "TRIANGLE_STRIP", 6: "TRIANGLE_FAN"}


def read_skinned_primitive(rd: Reader, prim, where: str, n_skin_joints: int):
    """One triangle primitive of a skinned mesh, checked.

    Returns positions (V, 3) float64 as stored, triangles (T, 3) int64, joints (V, 4 * sets) int64
    (indices into the skin's joint list) and weights (V, 4 * sets) float64 (>= 0; slots with an
    out-of-range joint must weigh 0 and are zeroed).
    """
    mode = 4 if prim.mode is None else prim.mode
    if mode != 4:
        rd.fail(f"{where}: mode {_MODE_NAMES.get(mode, mode)} is not supported (triangles only)")
    attrs = prim.attributes
    if attrs is None or attrs.POSITION is None:
        rd.fail(f"{where}: no POSITION attribute")
    pos = rd.accessor(attrs.POSITION, f"{where} POSITION")
    if pos.shape[1] != 3 or pos.dtype != np.float64:
        rd.fail(f"{where}: POSITION must be float VEC3")
    nv = pos.shape[0]
    jsets, wsets = [], []
    for k in range(8):
        ja, wa = getattr(attrs, f"JOINTS_{k}", None), getattr(attrs, f"WEIGHTS_{k}", None)
        if ja is None and wa is None:
            break
        if ja is None or wa is None:
            rd.fail(f"{where}: JOINTS_{k} and WEIGHTS_{k} must come together")
        jv = rd.accessor(ja, f"{where} JOINTS_{k}")
        wv = rd.accessor(wa, f"{where} WEIGHTS_{k}")
        if jv.shape != (nv, 4) or wv.shape != (nv, 4) or jv.dtype != np.int64:
            rd.fail(f"{where}: JOINTS_{k} / WEIGHTS_{k} must be {nv} integer / float VEC4")
        jsets.append(jv)
        wsets.append(wv)
    if not jsets:
        rd.fail(f"{where}: skinned mesh without JOINTS_0 / WEIGHTS_0")
    jv = np.concatenate(jsets, axis=1)
    wv = np.concatenate(wsets, axis=1)
    if np.any(wv < -1e-3):
        rd.fail(f"{where}: negative skin weights")
    wv = np.maximum(wv, 0.0)
    bad = (jv < 0) | (jv >= n_skin_joints)
    if np.any(bad & (wv > 0)):
        rd.fail(f"{where}: JOINTS_n index beyond the skin's {n_skin_joints} joints")
    wv[bad] = 0.0  # zero-weight slots may hold anything
    jv = np.clip(jv, 0, n_skin_joints - 1)
    if prim.indices is None:
        if nv % 3:
            rd.fail(f"{where}: {nv} vertices without indices is not a triangle list")
        idx = np.arange(nv, dtype=np.int64)
    else:
        idx = rd.accessor(prim.indices, f"{where} indices")
        if idx.shape[1] != 1 or idx.dtype != np.int64:
            rd.fail(f"{where}: indices must be an integer SCALAR accessor")
        idx = idx[:, 0]
    if idx.size % 3:
        rd.fail(f"{where}: {idx.size} indices is not a multiple of 3")
    if idx.size and (idx.min() < 0 or idx.max() >= nv):
        rd.fail(f"{where}: triangle index {int(idx.max())} out of range ({nv} vertices)")
    return pos, idx.reshape(-1, 3), jv, wv
