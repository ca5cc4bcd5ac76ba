"""Check that Blender imports the exported files (issue 18): vertex counts, animation length and
positions.

Run with Blender's own Python (not the venv); --python-exit-code 1 makes a failing script (an
importer that raises) exit 1 instead of 0:

    blender -b --factory-startup --python-exit-code 1 --python tools/blender_check.py -- EXPORT_DIR [--frames F]

EXPORT_DIR holds what `python -m pipeline export ... --format pc2,glb,usd -o EXPORT_DIR` wrote.
For each file it prints one line `ok|FAIL|SKIP <file>: <what was found>` and exits 1 on any failure:
  - <scene>.<mesh>.obj + .pc2: the OBJ imported (Y up: the importer puts the turn to Blender's Z up
    on the object), a Mesh Cache modifier (PC2, its default axes) added; the object's vertex count
    must equal the PC2's point count, the cache's sample count F, and the evaluated vertices at the
    first, middle and last frame the positions turned to Z up (within 1e-5 m) of the npz export
    beside it (the pipeline's own arrays; without it, of the PC2 itself);
  - <scene>.glb: glTF importer, with the scene's frame rate set to the file's (asset.extras.fps;
    at Blender's default 24 fps a 30 fps file's 120 frames land on 96); every mesh's shape keys
    (morph targets) = F, its action spans frames 0..F-1, at frame k the key shown is target_k, and
    the shape keys of 3 frames hold the npz's positions (else the glb's) turned to Z up (within 1e-5 m);
  - <scene>.usdc: USD importer; every mesh has time-sampled points (a Mesh Sequence Cache) over
    frames 0..F-1, and at 3 frames the npz's positions turned to Z up (within 1e-5 m). A Blender
    built without USD (Debian's package) prints SKIP for it.
The counts expected come from the files themselves (PC2 header, glTF accessors, USD stage), and
--frames checks F as well when given.
"""
import json
import struct
import sys
from pathlib import Path

import bpy  # noqa: F401  (Blender only)

try:
    import numpy as np
    if "bool" not in np.__dict__:   # Debian 12's Blender 3.4.1 glTF importer calls np.bool (gone in NumPy 1.24)
        np.bool = bool
except ImportError:   # pragma: no cover - Blender's glTF importer needs numpy too: apt-get install python3-numpy
    sys.exit("FAIL numpy is not importable in Blender's Python (Debian: apt-get install python3-numpy)")

argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
folder = Path(argv[0]) if argv else Path("exports")
want_frames = int(argv[argv.index("--frames") + 1]) if "--frames" in argv else None
failures = 0
TOL = 1e-5   # m


def report(ok, name: str, text: str) -> None:
    global failures
    failures += ok is False
    print(f"{'ok' if ok else 'SKIP' if ok is None else 'FAIL'} {name}: {text}", flush=True)


def fresh() -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)


def new_objects(before):
    return [o for o in bpy.data.objects if o.name not in before]


def z_up(p: np.ndarray) -> np.ndarray:
    """Y-up (x, y, z) as Blender's Z-up world (x, -z, y)."""
    return np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)


def world_vertices(obj) -> np.ndarray:
    ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    co = np.empty(len(ev.data.vertices) * 3)
    ev.data.vertices.foreach_get("co", co)
    m = np.array(obj.matrix_world)
    co = co.reshape(-1, 3)
    return co @ m[:3, :3].T + m[:3, 3]


def probe_frames(n: int) -> list:
    return sorted({0, n // 2, n - 1})


def npz_reference(folder: Path, scene: str, mesh: str):
    """The pipeline's own positions (F, N, 3) from `<scene>.<mesh>.npz` beside the file (export it with
    npz too), the independent reference; None without it (then the file is checked against itself)."""
    f = folder / f"{scene}.{mesh}.npz"
    return np.load(f)["vertices_seq"] if f.is_file() else None


for pc2 in sorted(folder.glob("*.pc2")):
    fresh()
    raw = pc2.read_bytes()
    _, version, points, start, rate, samples = struct.unpack("<12siiffi", raw[:32])
    cache = np.frombuffer(raw[32:32 + samples * points * 12], np.float32).reshape(samples, points, 3)
    scene_name, mesh_name = pc2.stem.rsplit(".", 1) if "." in pc2.stem else (pc2.stem, "")
    ref = npz_reference(folder, scene_name, mesh_name)
    against = "the npz" if ref is not None else "the PC2"
    ref = ref if ref is not None else cache
    before = set(bpy.data.objects.keys())
    obj_path = pc2.with_suffix(".obj")
    if "obj_import" in dir(bpy.ops.wm):   # Blender >= 3.3
        bpy.ops.wm.obj_import(filepath=str(obj_path), forward_axis="NEGATIVE_Z", up_axis="Y")
    else:
        bpy.ops.import_scene.obj(filepath=str(obj_path), split_mode="OFF", axis_forward="-Z", axis_up="Y")
    obj = new_objects(before)[0]
    mod = obj.modifiers.new("cache", "MESH_CACHE")
    mod.cache_format, mod.filepath = "PC2", str(pc2)   # default axes: the OBJ's turn is on the object
    errors = []
    for k in probe_frames(samples):
        bpy.context.scene.frame_set(int(start) + k)
        got = world_vertices(obj)
        if got.shape != (points, 3):
            errors.append(f"frame {k}: {got.shape[0]} vertices")
            continue
        if k >= len(ref) or ref.shape[1] != points:
            errors.append(f"frame {k}: {against} has shape {ref.shape}")
            continue
        err = float(np.abs(got - z_up(ref[k])).max())
        if err > TOL:
            errors.append(f"frame {k}: {err:.3g} m off {against}")
    n = len(obj.data.vertices)
    ok = n == points and not errors and (want_frames is None or samples == want_frames)
    report(ok, pc2.name, f"{n} vertices (PC2 {points}), {samples} samples from frame {start:g}, positions at frames "
                         f"{probe_frames(samples)} " + (f"as in {against}" if not errors else "; ".join(errors)))


def glb_positions(path: Path):
    """{mesh name: (F, V, 3) float32 positions per frame} and the asset extras, read from the .glb."""
    b = path.read_bytes()
    n = struct.unpack("<I", b[12:16])[0]
    doc = json.loads(b[20:20 + n])
    blob = b[20 + n + 8:]

    def acc(i):
        a = doc["accessors"][i]
        v = doc["bufferViews"][a["bufferView"]]
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[a["type"]]
        return np.frombuffer(blob, np.float32, a["count"] * width, v.get("byteOffset", 0) + a.get("byteOffset", 0)).reshape(a["count"], width)

    out = {}
    for mesh in doc["meshes"]:
        prim = mesh["primitives"][0]
        base = acc(prim["attributes"]["POSITION"])
        seq = np.stack([base + acc(t["POSITION"]) for t in prim["targets"]])
        ref = npz_reference(path.parent, path.stem, mesh["name"])
        if ref is not None:   # the glb's vertices are particles (plus a copy per seam corner)
            pv = (mesh.get("extras") or {}).get("particle_of_vertex")
            ref = ref[:, np.asarray(pv)] if pv is not None else ref
            out[mesh["name"]] = (ref, "the npz")
        else:
            out[mesh["name"]] = (seq, "the glb")
    return out, doc["asset"].get("extras", {})


for glb in sorted(folder.glob("*.glb")):
    fresh()
    positions, extras = glb_positions(glb)
    fps = float(extras.get("fps", 24.0))
    bpy.context.scene.render.fps = max(1, round(fps))
    bpy.context.scene.render.fps_base = bpy.context.scene.render.fps / fps
    bpy.ops.import_scene.gltf(filepath=str(glb))
    for obj in [o for o in bpy.data.objects if o.type == "MESH"]:
        keys = obj.data.shape_keys
        n_keys = len(keys.key_blocks) - 1 if keys else 0   # minus the basis
        action = keys.animation_data.action if keys and keys.animation_data else None
        lo, hi = (int(round(x)) for x in action.frame_range) if action else (0, -1)
        errors = []
        seq, against = positions.get(obj.data.name, positions.get(obj.name, (None, "the glb")))
        for k in probe_frames(n_keys):
            bpy.context.scene.frame_set(k)
            shown = [kb.name for kb in keys.key_blocks[1:] if kb.value > 0.5]
            if shown != [keys.key_blocks[k + 1].name]:
                errors.append(f"frame {k} shows {shown}")
            co = np.empty(len(obj.data.vertices) * 3)
            keys.key_blocks[k + 1].data.foreach_get("co", co)
            m = np.array(obj.matrix_world)
            world = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
            if seq is None or seq.shape[1] != world.shape[0]:
                errors.append(f"no mesh of {world.shape[0]} vertices named {obj.data.name!r} in {against}")
                break
            err = float(np.abs(world - z_up(seq[k])).max())
            if err > TOL:
                errors.append(f"frame {k}: {err:.3g} m off {against}")
        ok = (n_keys > 0 and (lo, hi) == (0, n_keys - 1) and not errors
              and (want_frames is None or n_keys == want_frames))
        report(ok, f"{glb.name}:{obj.name}", f"{len(obj.data.vertices)} vertices, {n_keys} shape keys, action over frames "
                                            f"{lo}..{hi} at {fps:g} fps, " + (f"target_k at frame k, positions as in {against}"
                                                                            if not errors else "; ".join(errors)))

for usd in sorted(folder.glob("*.usd*")):
    if "usd_import" not in dir(bpy.ops.wm):
        report(None, usd.name, f"this Blender ({bpy.app.version_string}) has no USD importer (built without USD, "
                               f"as Debian's package is)")
        continue
    fresh()
    bpy.ops.wm.usd_import(filepath=str(usd), set_frame_range=True)
    sc = bpy.context.scene
    frames = sc.frame_end - sc.frame_start + 1
    for obj in [o for o in bpy.data.objects if o.type == "MESH"]:
        cached = any(m.type == "MESH_SEQUENCE_CACHE" for m in obj.modifiers)
        ref = npz_reference(folder, usd.stem, obj.name)
        errors = []
        if ref is not None:
            for k in probe_frames(frames):
                sc.frame_set(sc.frame_start + k)
                got = world_vertices(obj)
                if got.shape != ref.shape[1:]:
                    errors.append(f"frame {k}: {got.shape[0]} vertices, the npz {ref.shape[1]}")
                    break
                err = float(np.abs(got - z_up(ref[k])).max())
                if err > TOL:
                    errors.append(f"frame {k}: {err:.3g} m off the npz")
        ok = cached and not errors and (want_frames is None or frames == want_frames)
        report(ok, f"{usd.name}:{obj.name}", f"{len(obj.data.vertices)} vertices, animated={cached}, frames "
                                            f"{sc.frame_start}..{sc.frame_end} at {sc.render.fps / sc.render.fps_base:g} fps"
                                            + ("" if ref is None else f", positions at frames {probe_frames(frames)} "
                                               + ("as in the npz" if not errors else "; ".join(errors))))

if not any(folder.glob("*")):
    report(False, str(folder), "no exported files")
sys.exit(1 if failures else 0)
