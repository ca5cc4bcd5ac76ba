"""Reading a mesh file through trimesh without trimesh guessing text encodings.

trimesh decodes text (an OBJ, an ASCII STL, a binary STL's 80-byte header) as UTF-8 and, when that
fails, imports `charset_normalizer` to guess the encoding: a package it does not install. A valid
OBJ with one Latin-1 byte in a comment, or any garbage STL, then failed with "No module named
'charset_normalizer'". Here the bytes are read first and made valid UTF-8 before trimesh sees them
(text: UTF-8, else Latin-1, which decodes any byte; a binary STL's header: blanked, it is free text),
so no guess is needed and no optional dependency is involved.
"""
from __future__ import annotations

import io
import os
import struct
from pathlib import Path

import numpy as np

from stages.errors import InputError

TEXT_FORMATS = ("obj", "off", "xyz")


def _utf8(data: bytes) -> bytes:
    try:
        data.decode("utf-8")
        return data
    except UnicodeDecodeError:
        return data.decode("latin-1").encode("utf-8")


def _stl(data: bytes) -> bytes:
    if len(data) >= 84:
        (n,) = struct.unpack("<I", data[80:84])
        if len(data) == 84 + 50 * n:          # binary: the header is free text, blank it
            return b" " * 80 + data[80:]
    return _utf8(data)                        # ASCII STL (or garbage, which the parser refuses)


def _checked_resolver():
    import trimesh

    class CheckedResolver(trimesh.resolvers.FilePathResolver):
        """Files an OBJ names (`mtllib`, textures) read only when they are regular files of bounded
        size: a FIFO there blocked the reader forever."""

        def get(self, name):
            from stages.input_files import MAX_ASSET_BYTES, file_problem
            target = os.path.join(self.parent, name.strip())
            problem = file_problem(Path(target), "file the mesh names", MAX_ASSET_BYTES)
            if problem:
                raise InputError(target, problem)
            return super().get(name)
    return CheckedResolver


def _pick_part(p: Path, scene, part):
    """One mesh of a glTF scene of several: `part` its name (or node name) or index; 'all': merged."""
    import trimesh
    meshes = [m for m in scene.dump(concatenate=False) if isinstance(m, trimesh.Trimesh)]
    names = [str(m.metadata.get("name") or m.metadata.get("node") or i) for i, m in enumerate(meshes)]
    if part == "all" or (part is None and len(meshes) == 1):
        return trimesh.util.concatenate(meshes) if meshes else scene.to_mesh()
    listed = ", ".join(f"{i}: {n!r}" for i, n in enumerate(names))
    if part is None:
        raise InputError(p, f"holds {len(meshes)} meshes ({listed}); expected one: choose it with "
                            f"'part: <name or index>', or 'part: all' to simulate them as one cloth")
    for i, m in enumerate(meshes):
        if part == i or part in (names[i], m.metadata.get("node")):
            return m
    raise InputError(p, f"part {part!r} is not one of its meshes ({listed})")


def read_mesh_file(path, *, what: str = "mesh", part="all"):
    """The file at `path` as one trimesh.Trimesh (process=False, node transforms applied), or an
    InputError naming the file: missing, a folder, empty, unreadable or not a triangle mesh.
    part: of a glTF / GLB holding several meshes, the one to read (name or index), 'all' (merged)
    or None (a file of several is an InputError listing them); other formats are read whole."""
    import trimesh

    from stages.input_files import read_bytes
    p = Path(path)
    if not p.exists():
        raise InputError(p, "file not found")
    if p.is_dir():
        raise InputError(p, "is a folder, expected a mesh file")
    data = read_bytes(p, f"{what} file")   # a FIFO or device is refused unopened
    if not data.strip():
        raise InputError(p, f"the {what} file is empty")
    kind = p.suffix.lower().lstrip(".")
    if kind in TEXT_FORMATS:
        data = _utf8(data)
    elif kind == "stl":
        data = _stl(data)
    try:
        resolver = _checked_resolver()(str(p))
        if kind in ("glb", "gltf") and part != "all":
            scene = trimesh.load(io.BytesIO(data), file_type=kind, force="scene", process=False, resolver=resolver)
        else:
            loaded = trimesh.load(io.BytesIO(data), file_type=kind, force="mesh", process=False, resolver=resolver)
    except Exception as exc:  # trimesh raises many kinds for corrupt files; report one line
        msg = " ".join(str(exc).split())[:160]
        raise InputError(p, f"cannot read the {what} ({type(exc).__name__}: {msg or 'no detail'})") from None
    if kind in ("glb", "gltf") and part != "all":
        loaded = _pick_part(p, scene, part)
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise InputError(p, f"no triangle faces in the {what} file")
    v, f = np.asarray(loaded.vertices), np.asarray(loaded.faces)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise InputError(p, f"vertices are not 3D points (array of shape {v.shape})")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise InputError(p, f"faces are not triangles of vertex indices (array of shape {f.shape})")
    if f.min() < 0 or f.max() >= len(v):
        raise InputError(p, f"a face refers to vertex {int(f.max()) + 1 if f.max() >= len(v) else int(f.min()) + 1} "
                            f"of {len(v)}")
    return loaded
