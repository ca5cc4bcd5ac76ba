"""Export a run's animation (garments + body) to files other tools read: npz, PC2 + OBJ, glb, USD.

Stages: `from_recording(path) -> ExportData` (positions read back from the `.rrd`), `from_run(...)`
(the in-memory result of `pipeline.run.run_scene`, with UVs from the flat pattern panels), and
`write(data, formats, out_dir) -> [paths]`. Every file is written to a temporary name and renamed,
so a failure never leaves a half-written file. Bad input raises `ExportError` (one line naming the
file and what was expected; the CLI prints it and exits 2).

Conventions, in every format: world metres, Y up (right-handed), frame i at time times[i] s;
vertex order = the garment's particles (the sewn, merged seam vertices) or the body's skinned
mesh vertices; faces once. UVs of a pattern (or GarmentCode) garment come from its flat panels laid out
side by side, scaled uniformly into [0, 1] (a fabric texture maps as the panels were cut), a mesh
garment's from its file; a sewn seam has two UVs for one particle, so UVs are per
corner: `uv` (U, 2) with `uv_faces` (T, 3) indices into it (npz, OBJ `f v/vt`, USD faceVarying
`st`); glTF only has per-vertex attributes, so the glb appends a duplicate vertex for each seam
corner after the N particles (`extras.particle_of_vertex` maps every vertex to its particle).
"""
from __future__ import annotations

import json
import os
import struct
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

FORMATS = ("npz", "pc2", "obj", "glb", "usd")
EXTRAS = {"usd": ("pxr", "usd")}   # format -> (module, pip extra)


from pipeline.schema import SceneError


class ExportError(SceneError):
    """A bad export input: one line naming the file and what was expected (a user error: exit 2)."""


@dataclass
class AnimatedMesh:
    """One animated triangle mesh.

    name: the garment's name, or 'body'. kind: 'garment' | 'body'.
    vertices_seq: (F, N, 3) float32, world metres, Y up; N = the garment's particles (body: the
        skinned mesh's vertices, root translation included).
    faces: (T, 3) int32 indices into N.
    uv: (U, 2) float32 in [0, 1] or None; uv_faces: (T, 3) int32 indices into uv (per corner).
    """

    name: str
    kind: str
    vertices_seq: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None
    uv_faces: np.ndarray | None = None


@dataclass
class ExportData:
    """Everything exported. times: (F,) float64 s; frames: (F,) int64 frame numbers; fps: frames
    per second (1 / dt); source: the recording or scene it came from (for messages, metadata)."""

    meshes: list
    times: np.ndarray
    frames: np.ndarray
    fps: float
    source: str
    scene_name: str = "scene"


# ---------------------------------------------------------------- sources

def _rows(store, entity: str):
    """(frames (F,), times_ns (F,) or None, positions (F, N, 3) float32, triangles (T, 3) or None)."""
    frames, times, pos, tri = [], [], [], None
    for chunk in store.stream().filter(content=entity).to_chunks():
        b = chunk.to_record_batch()
        names = b.schema.names
        if "Mesh3D:triangle_indices" in names and "frame" not in names:
            col = b.column("Mesh3D:triangle_indices")
            for i in range(b.num_rows):
                if col[i].is_valid:
                    tri = np.asarray(col[i].values.flatten().to_numpy(zero_copy_only=False)).reshape(-1, 3)
        if "Mesh3D:vertex_positions" in names and "frame" in names:
            col = b.column("Mesh3D:vertex_positions")
            fr = b.column("frame").to_numpy()
            tn = b.column("sim_time").cast("int64").to_numpy() if "sim_time" in names else None
            for i in range(b.num_rows):
                if not col[i].is_valid:
                    continue
                frames.append(int(fr[i]))
                times.append(None if tn is None else int(tn[i]))
                pos.append(np.asarray(col[i].values.flatten().to_numpy(zero_copy_only=False),
                                      np.float32).reshape(-1, 3))
    order = np.argsort(frames, kind="stable")
    return (np.asarray(frames, np.int64)[order], None if None in times else np.asarray(times, np.int64)[order],
            [pos[i] for i in order], tri)


def _recorded_uv(store, entity: str, faces: np.ndarray):
    """(uv, uv_faces) a run stored at sim/<name>/uv (logs.log_uvs), when they fit `faces`."""
    for chunk in store.stream().filter(content=entity).to_chunks():
        b = chunk.to_record_batch()
        if "texcoords" in b.schema.names and "texcoord_faces" in b.schema.names:
            uv = np.asarray(b.column("texcoords")[0].values.to_numpy(zero_copy_only=False), np.float32).reshape(-1, 2)
            uvf = np.asarray(b.column("texcoord_faces")[0].values.to_numpy(zero_copy_only=False), np.int64)
            uvf = uvf.reshape(-1, 3).astype(np.int32)
            if uvf.shape == faces.shape and len(uv) and 0 <= uvf.min() and uvf.max() < len(uv):
                return uv, uvf
    return None, None


def from_recording(path: str | os.PathLike) -> ExportData:
    """Read the garments (`sim/<name>/mesh`) and the body (`rig/mesh`) back from a recording.

    The `frame` timeline orders the rows; times come from `sim_time` read as integer nanoseconds
    (its `to_pylist()` raises when dt is not a whole number of microseconds).
    """
    p = Path(path)
    if not p.exists():
        raise ExportError(f"{p}: recording not found (expected a .rrd written by `python -m pipeline run`)")
    try:
        from rerun.chunk import RrdReader
        store = RrdReader(p).store()
        entities = list(store.schema().entity_paths())
    except Exception as e:   # not an rrd, truncated, ...
        raise ExportError(f"{p}: cannot read as a Rerun recording ({type(e).__name__}: {e})") from None
    garments = sorted(e.split("/")[2] for e in entities
                      if e.startswith("/sim/") and e.endswith("/mesh") and e.count("/") == 3)
    if not garments:
        raise ExportError(f"{p}: the recording has no garments (expected sim/<garment>/mesh entities; "
                          f"was the scene run with garments?)")
    meshes, ref = [], None
    for kind, name, entity in ([("garment", g, f"/sim/{g}/mesh") for g in garments]
                               + ([("body", "body", "/rig/mesh")] if "/rig/mesh" in entities else [])):
        frames, tns, pos, tri = _rows(store, entity)
        if tri is None or not pos:
            raise ExportError(f"{p}: {entity.lstrip('/')} has no triangles or no per-frame positions")
        if ref is None:
            ref = (frames, tns)
        elif not np.array_equal(frames, ref[0]):
            raise ExportError(f"{p}: {entity.lstrip('/')} has other frames than sim/{garments[0]}/mesh")
        if len({q.shape for q in pos}) != 1:
            raise ExportError(f"{p}: {entity.lstrip('/')}: the vertex count changes between frames")
        m = AnimatedMesh(name, kind, np.stack(pos).astype(np.float32), tri.astype(np.int32))
        if kind == "garment" and f"/sim/{name}/uv" in entities:
            m.uv, m.uv_faces = _recorded_uv(store, f"/sim/{name}/uv", m.faces)
        meshes.append(m)
    frames, tns = ref
    times = tns / 1e9 if tns is not None else frames.astype(np.float64) / 30.0
    fps = 1.0 / float(np.median(np.diff(times))) if len(times) > 1 else 30.0
    return ExportData(meshes, times, frames, fps, str(p), scene_name=p.stem)


def pattern_uv(build) -> tuple[np.ndarray, np.ndarray]:
    """(uv (U, 2) float32 in [0, 1], uv_faces (T, 3) int32) from a GarmentBuild's flat panels (laid
    out side by side, z = 0), scaled uniformly (aspect kept) into the unit square."""
    flat = np.asarray(build.flat_positions, np.float64)[:, :2]
    lo = flat.min(0)
    span = float((flat.max(0) - lo).max()) or 1.0
    return ((flat - lo) / span).astype(np.float32), np.asarray(build.unsewn_triangles, np.int32)


def garment_uv(name: str, faces: np.ndarray, builds: dict, mesh_uv=None):
    """(uv, uv_faces) of a garment with `faces` (T, 3): a pattern's (GarmentCode's) flat panels when it
    was sewn from one (`builds`), else a mesh garment's file UVs (`mesh_uv`: (uv, uv_faces)), or
    (None, None). Only when the UV corners match the faces one to one (the sewn triangles are the merged
    flat ones; a mesh garment's are the file's)."""
    faces = np.asarray(faces)
    if name in builds:
        from stages.garments.sewing import merge_pairs
        build = builds[name][1]
        uv, uvf = pattern_uv(build)
        remap = merge_pairs(uv.shape[0], np.asarray(build.seam_pairs))
        if uvf.shape == faces.shape and np.array_equal(remap[uvf], faces):
            return uv, uvf
    elif mesh_uv is not None and mesh_uv[0] is not None and mesh_uv[1].shape == faces.shape:
        return mesh_uv
    return None, None


def mesh_uvs(scene, meshes: dict | None) -> dict:
    """name -> (uv, uv_faces) of the scene's mesh garments whose files have UVs (load_scene_meshes)."""
    out = {}
    for i, g in enumerate(scene["garments"]):
        m = (meshes or {}).get(("garments", i))
        if g["type"] == "mesh" and m is not None and len(m) == 4 and m[2] is not None:
            out[g["name"]] = (m[2], m[3])
    return out


def run_uvs(scene, result, builds, meshes: dict | None = None) -> dict:
    """name -> (uv, uv_faces) of every simulated garment that has UVs (`garment_uv`); what the
    recording stores (sim/<name>/uv) and the exports write."""
    files = mesh_uvs(scene, meshes)
    out = {}
    for track in result.garments:
        uv, uvf = garment_uv(track.name, track.triangles, builds, files.get(track.name))
        if uv is not None:
            out[track.name] = (uv, uvf)
    return out


def from_run(scene, motion, skinned, character, result, builds, source: str, meshes: dict | None = None) -> ExportData:
    """The in-memory run: garment tracks (world), the skinned body + root translation, UVs
    (`run_uvs`: pattern panels, mesh garments' files; `meshes` from load_scene_meshes)."""
    uvs = run_uvs(scene, result, builds, meshes)
    out = []
    for track in result.garments:
        m = AnimatedMesh(track.name, "garment", np.asarray(track.positions, np.float32),
                         np.asarray(track.triangles, np.int32))
        m.uv, m.uv_faces = uvs.get(track.name, (None, None))
        out.append(m)
    body = (np.asarray(skinned) + motion.root_translation[:, None, :]).astype(np.float32)
    out.append(AnimatedMesh("body", "body", body, np.asarray(character.triangles, np.int32)))
    times = np.asarray(result.times, np.float64)
    fps = 1.0 / float(scene["simulation"]["dt"])
    return ExportData(out, times, np.arange(len(times), dtype=np.int64), fps, source, scene_name=scene.name)


# ---------------------------------------------------------------- writers

@contextmanager
def _atomic(path: Path, mode: str = "wb"):
    """Yield a temporary path next to `path` (pipeline.disk.temporary_path); rename it to `path` on
    success, remove it on failure. A write error (a full disk) is one ExportError naming the file."""
    from pipeline.disk import remove_stale_temporaries, temporary_path
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(path)   # what a killed run left
    tmp = temporary_path(path)
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as e:
        raise ExportError(f"{path}: cannot write the export ({e.strerror or e}); an earlier file there is kept") from None
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def _meta(data: ExportData, m: AnimatedMesh) -> dict:
    return {"up_axis": "Y", "units": "metres", "handedness": "right", "fps": data.fps,
            "frame_start": int(data.frames[0]), "frame_end": int(data.frames[-1]), "frames": int(len(data.frames)),
            "mesh": m.name, "kind": m.kind, "source": data.source, "vertex_order": (
                "the garment's particles" if m.kind == "garment" else "the skinned body mesh's vertices")}


def write_npz(data: ExportData, m: AnimatedMesh, path: Path) -> Path:
    """Named arrays: vertices_seq (F, N, 3) float32, faces (T, 3) int32, uv (U, 2) float32 and
    uv_faces (T, 3) int32 (empty when there are no UVs), fps, times (F,) s, frames (F,), meta (JSON)."""
    with _atomic(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, vertices_seq=m.vertices_seq.astype(np.float32), faces=m.faces.astype(np.int32),
                     uv=m.uv if m.uv is not None else np.zeros((0, 2), np.float32),
                     uv_faces=m.uv_faces if m.uv_faces is not None else np.zeros((0, 3), np.int32),
                     fps=np.float64(data.fps), times=data.times.astype(np.float64),
                     frames=data.frames.astype(np.int64), meta=np.array(json.dumps(_meta(data, m))))
    return path


PC2_HEADER = struct.Struct("<12siiffi")   # signature, version, points, start frame, sample rate, samples


def write_pc2(data: ExportData, m: AnimatedMesh, path: Path) -> Path:
    """Blender / 3ds Max point cache: 'POINTCACHE2\\0', version 1, num points, start frame, sample
    rate (frames between samples: 1), num samples, then F x N x 3 little-endian float32."""
    f_, n = m.vertices_seq.shape[:2]
    with _atomic(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(PC2_HEADER.pack(b"POINTCACHE2\0", 1, n, float(data.frames[0]), 1.0, f_))
            f.write(np.ascontiguousarray(m.vertices_seq, dtype="<f4").tobytes())
    return path


def read_pc2(path: Path) -> tuple[np.ndarray, float, float]:
    """(positions (F, N, 3) float32, start frame, sample rate) of a PC2 file."""
    raw = Path(path).read_bytes()
    sig, version, n, start, rate, f_ = PC2_HEADER.unpack_from(raw)
    if sig != b"POINTCACHE2\0" or version != 1:
        raise ExportError(f"{path}: not a PC2 file (signature {sig!r}, version {version})")
    pos = np.frombuffer(raw, "<f4", count=f_ * n * 3, offset=PC2_HEADER.size)
    return pos.reshape(f_, n, 3), start, rate


def write_obj(data: ExportData, m: AnimatedMesh, path: Path, frame: int = 0) -> Path:
    """The rest mesh (frame `frame`, default the first) for the PC2: `v` in particle order, `vt`
    and per-corner `f v/vt` when there are UVs. Metadata in comments."""
    lines = [f"# {k}: {v}" for k, v in _meta(data, m).items()] + [f"# positions of frame index {frame}", f"o {m.name}"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in m.vertices_seq[frame].astype(np.float64)]
    if m.uv is not None:
        lines += [f"vt {u:.9g} {v:.9g}" for u, v in m.uv.astype(np.float64)]
        lines += [f"f {a + 1}/{ta + 1} {b + 1}/{tb + 1} {c + 1}/{tc + 1}"
                  for (a, b, c), (ta, tb, tc) in zip(m.faces, m.uv_faces)]
    else:
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in m.faces]
    with _atomic(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    return path


def split_for_uv(m: AnimatedMesh) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Per-vertex UVs for formats without per-corner ones: (particle_of_vertex (V,) int64 with the
    first N = 0..N-1, uv (V, 2) or None, faces (T, 3) into V). A corner whose UV differs from its
    particle's first UV gets a duplicate vertex appended after the N particles."""
    n = m.vertices_seq.shape[1]
    if m.uv is None:
        return np.arange(n), None, m.faces
    corner_uv = m.uv[m.uv_faces].reshape(-1, 2)
    corners = m.faces.reshape(-1)
    uv = np.zeros((n, 2), np.float32)
    seen = np.full(n, -1, np.int64)   # uv index first seen per particle
    extra: dict = {}
    particle = list(range(n))
    uvs = [None] * n
    out = corners.copy()
    for k, (p, t) in enumerate(zip(corners, m.uv_faces.reshape(-1))):
        if seen[p] < 0:
            seen[p] = t
            uv[p] = m.uv[t]
        elif seen[p] != t and not np.array_equal(m.uv[seen[p]], m.uv[t]):
            key = (int(p), int(t))
            if key not in extra:
                extra[key] = len(particle)
                particle.append(int(p))
                uvs.append(m.uv[t])
            out[k] = extra[key]
    uv_all = np.concatenate([uv, np.asarray([u for u in uvs[n:]], np.float32).reshape(-1, 2)])
    del corner_uv
    return np.asarray(particle, np.int64), uv_all, out.reshape(-1, 3).astype(np.int32)


def write_glb(data: ExportData, path: Path) -> Path:
    """One binary glTF with every mesh: each a node with one mesh whose morph targets are the
    frames (target f = positions(f) - positions(0)), and one animation whose STEP-interpolated
    weights show exactly one target per frame. Morph targets rather than a mesh per frame: faces,
    UVs and the vertex order are stored once, and Blender imports them as shape keys with animated
    values on one object (per-frame meshes would be F objects whose visibility has to be faked with
    scale keys). glTF is Y up, metres, right-handed, which the pipeline already is."""
    import pygltflib as g
    blob = bytearray()
    views, accessors = [], []

    def add(arr: np.ndarray, target=None, minmax=False) -> int:
        arr = np.ascontiguousarray(arr)
        while len(blob) % 4:
            blob.append(0)
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=arr.nbytes, target=target))
        blob.extend(arr.tobytes())
        ctype = {np.dtype(np.float32): g.FLOAT, np.dtype(np.uint32): g.UNSIGNED_INT}[arr.dtype]
        typ = {1: g.SCALAR, 2: g.VEC2, 3: g.VEC3}[1 if arr.ndim == 1 else arr.shape[1]]
        acc = g.Accessor(bufferView=len(views) - 1, componentType=ctype, count=arr.shape[0], type=typ)
        if minmax:
            acc.min = arr.min(0).tolist() if arr.ndim > 1 else [float(arr.min())]
            acc.max = arr.max(0).tolist() if arr.ndim > 1 else [float(arr.max())]
        accessors.append(acc)
        return len(accessors) - 1

    nodes, meshes, anims = [], [], []
    f_ = len(data.times)
    t_in = add((data.times - data.times[0]).astype(np.float32), minmax=True)
    w_out = add(np.eye(f_, dtype=np.float32).reshape(-1))   # frame k: weight 1 on target k (shared)
    for m in data.meshes:
        particle, uv, faces = split_for_uv(m)
        seq = m.vertices_seq[:, particle].astype(np.float32)
        attrs = g.Attributes(POSITION=add(seq[0], g.ARRAY_BUFFER, minmax=True))
        if uv is not None:
            attrs.TEXCOORD_0 = add(uv.astype(np.float32), g.ARRAY_BUFFER)
        targets = [g.Attributes(POSITION=add(seq[k] - seq[0], g.ARRAY_BUFFER, minmax=True)) for k in range(f_)]
        prim = g.Primitive(attributes=attrs, indices=add(faces.reshape(-1).astype(np.uint32), g.ELEMENT_ARRAY_BUFFER),
                           targets=targets, mode=g.TRIANGLES)
        meshes.append(g.Mesh(name=m.name, primitives=[prim], weights=[1.0] + [0.0] * (f_ - 1),
                             extras={**_meta(data, m), "particles": int(m.vertices_seq.shape[1]),
                                     "particle_of_vertex": particle.tolist() if len(particle) > m.vertices_seq.shape[1] else None,
                                     "morph_targets": "one per frame; positions = POSITION + target"}))
        nodes.append(g.Node(name=m.name, mesh=len(meshes) - 1))
        anims.append(len(nodes) - 1)
    animation = g.Animation(name="frames", samplers=[g.AnimationSampler(input=t_in, output=w_out, interpolation="STEP")
                                                     for _ in anims],
                            channels=[g.AnimationChannel(sampler=i, target=g.AnimationChannelTarget(node=n, path="weights"))
                                      for i, n in enumerate(anims)])
    gltf = g.GLTF2(asset=g.Asset(version="2.0", generator="garment-colliders pipeline.export",
                                 extras={"up_axis": "Y", "units": "metres", "fps": data.fps,
                                         "frame_start": int(data.frames[0]), "frames": f_, "source": data.source}),
                   scene=0, scenes=[g.Scene(nodes=list(range(len(nodes))))], nodes=nodes, meshes=meshes,
                   accessors=accessors, bufferViews=views, buffers=[g.Buffer(byteLength=len(blob))],
                   animations=[animation])
    gltf.set_binary_blob(bytes(blob))
    with _atomic(path) as tmp:
        gltf.save_binary(str(tmp))
    return path


def write_usd(data: ExportData, path: Path) -> Path:
    """One USD stage (.usdc): /Root/<mesh> UsdGeom.Mesh with time-sampled points at frame numbers,
    faceVarying `st` UVs, upAxis Y, metersPerUnit 1, timeCodesPerSecond = framesPerSecond = fps."""
    with _atomic(path) as tmp:
        usd_tmp = tmp.with_suffix(".usdc")   # USD picks the file format from the suffix
        try:
            _usd_stage(data, usd_tmp)
            os.replace(usd_tmp, tmp)
        finally:
            if usd_tmp.exists():
                usd_tmp.unlink()
    return path


def _usd_stage(data: ExportData, usd_tmp: Path) -> None:
    from pxr import Sdf, Usd, UsdGeom, Vt
    stage = Usd.Stage.CreateNew(str(usd_tmp))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(data.fps)
    stage.SetFramesPerSecond(data.fps)
    stage.SetStartTimeCode(float(data.frames[0]))
    stage.SetEndTimeCode(float(data.frames[-1]))
    root = UsdGeom.Xform.Define(stage, "/Root")
    stage.SetDefaultPrim(root.GetPrim())
    stage.GetRootLayer().customLayerData = {"source": data.source, "up_axis": "Y", "units": "metres"}
    for m in data.meshes:
        name = "".join(c if c.isalnum() or c == "_" else "_" for c in m.name)
        name = name if name[:1].isalpha() or name[:1] == "_" else "_" + name   # a valid prim name
        mesh = UsdGeom.Mesh.Define(stage, f"/Root/{name}")
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(m.faces)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(m.faces.reshape(-1).tolist()))
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        mesh.GetPrim().SetCustomDataByKey("kind", m.kind)
        pts = mesh.CreatePointsAttr()
        for k, fr in enumerate(data.frames):
            pts.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(m.vertices_seq[k], np.float32)), float(fr))
        if m.uv is not None:
            st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                         UsdGeom.Tokens.faceVarying)
            st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(m.uv, np.float32)))
            st.SetIndices(Vt.IntArray(m.uv_faces.reshape(-1).tolist()))
    stage.GetRootLayer().Save()


def check_formats(formats, where: str = "--format") -> list[str]:
    """Validated, de-duplicated formats; ExportError naming a bad one or a missing extra."""
    out = []
    for f in formats:
        f = str(f).lower().lstrip(".")
        if f in ("abc", "alembic"):
            raise ExportError(f"{where}: alembic is not supported (no maintained Alembic binding installs from "
                              f"PyPI); use usd or pc2")
        if f not in FORMATS:
            raise ExportError(f"{where}: unknown format {f!r} (expected one of {', '.join(FORMATS)})")
        if f not in out:
            out.append(f)
    for f in out:
        if f in EXTRAS:
            mod, extra = EXTRAS[f]
            try:
                __import__(mod)
            except ImportError:
                raise ExportError(f"{where}: {f} export needs the '{extra}' extra: pip install -e \".[{extra}]\"") from None
    return out


def write(data: ExportData, formats, out_dir: str | os.PathLike) -> list[Path]:
    """Write every format into out_dir; returns the paths. npz, pc2 and obj: one file per mesh
    (<scene>.<mesh>.<ext>); glb and usd: one file with every mesh (<scene>.<ext>)."""
    formats = check_formats(formats)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ExportError(f"{out}: is a file, expected an output folder")
    base = data.scene_name
    paths = []
    for f in formats:
        if f in ("npz", "pc2", "obj"):
            for m in data.meshes:
                target = out / f"{base}.{m.name}.{f}"
                paths.append({"npz": write_npz, "pc2": write_pc2, "obj": write_obj}[f](data, m, target))
                if f == "pc2" and "obj" not in formats:   # the rest mesh the cache deforms
                    paths.append(write_obj(data, m, out / f"{base}.{m.name}.obj"))
        elif f == "glb":
            paths.append(write_glb(data, out / f"{base}.glb"))
        elif f == "usd":
            paths.append(write_usd(data, out / f"{base}.usdc"))
    return paths


def check_export_dir(out_dir: str | os.PathLike, where: str) -> None:
    """Before the run: the exports' folder is a folder (or can be made: its nearest existing
    ancestor is a writable folder), so a run is never lost to a bad export path at its end."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ExportError(f"{where}: {out}: is a file, expected a folder for the exports")
    existing = out
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise ExportError(f"{where}: {out}: cannot create the folder: {existing} is a file")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ExportError(f"{where}: {out}: folder {existing} is not writable")


def default_dir(recording: str | os.PathLike) -> Path:
    """Where exports go unless told: next to the recording, `<recording stem>_export/`."""
    r = Path(recording)
    return r.with_name(f"{r.stem}_export")


def export_run(scene, recording: Path, motion, skinned, character, result, builds, formats, out_dir=None,
               meshes: dict | None = None) -> list[Path]:
    """After a run: write `formats` of the in-memory result (UVs included) into out_dir."""
    src = str(scene.path or scene.name)
    if result is None or not result.garments:
        raise ExportError(f"{src}: output.export: the scene has no garments to export (expected at least one "
                          f"entry under 'garments:')")
    data = from_run(scene, motion, skinned, character, result, builds, source=src, meshes=meshes)
    return write(data, formats, out_dir if out_dir is not None else default_dir(recording))
