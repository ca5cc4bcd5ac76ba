"""Check that Blender imports the exported files (issue 18): vertex counts and animation length.

Run with Blender's own Python (not the venv):

    blender -b --factory-startup --python tools/blender_check.py -- EXPORT_DIR [--frames F]

EXPORT_DIR holds what `python -m pipeline export ... --format pc2,glb,usd -o EXPORT_DIR` wrote.
For each file it prints one line `ok|FAIL <file>: <what was found>` and exits 1 on any failure:
  - <scene>.<mesh>.obj + .pc2: the OBJ imported (vertex order kept), a Mesh Cache modifier (PC2, Y up)
    added; the object's vertex count must equal the PC2's point count, and the cache's sample count F;
  - <scene>.glb: glTF importer; every mesh's shape keys (morph targets) = F, its action spans F frames;
  - <scene>.usdc: USD importer; every mesh has time-sampled points over frames 0..F-1.
The counts expected come from the files themselves (PC2 header, glTF extras, USD stage), and --frames
checks F as well when given.
"""
import struct
import sys
from pathlib import Path

import bpy  # noqa: F401  (Blender only)

argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
folder = Path(argv[0]) if argv else Path("exports")
want_frames = int(argv[argv.index("--frames") + 1]) if "--frames" in argv else None
failures = 0


def report(ok: bool, name: str, text: str) -> None:
    global failures
    failures += not ok
    print(f"{'ok' if ok else 'FAIL'} {name}: {text}", flush=True)


def fresh() -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)


def new_objects(before):
    return [o for o in bpy.data.objects if o.name not in before]


for pc2 in sorted(folder.glob("*.pc2")):
    fresh()
    _, version, points, start, rate, samples = struct.unpack("<12siiffi", pc2.read_bytes()[:32])
    before = set(bpy.data.objects.keys())
    obj_path = pc2.with_suffix(".obj")
    if hasattr(bpy.ops.wm, "obj_import"):   # Blender >= 3.3
        bpy.ops.wm.obj_import(filepath=str(obj_path), forward_axis="NEGATIVE_Z", up_axis="Y")
    else:
        bpy.ops.import_scene.obj(filepath=str(obj_path), split_mode="OFF", axis_forward="-Z", axis_up="Y")
    obj = new_objects(before)[0]
    mod = obj.modifiers.new("cache", "MESH_CACHE")
    mod.cache_format, mod.filepath = "PC2", str(pc2)
    mod.forward_axis, mod.up_axis = "NEG_Z", "POS_Y"
    bpy.context.scene.frame_set(int(start) + samples - 1)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    n = len(obj.evaluated_get(depsgraph).data.vertices)
    ok = n == points and (want_frames is None or samples == want_frames)
    report(ok, pc2.name, f"{n} vertices (PC2 {points}), {samples} samples from frame {start}")

for glb in sorted(folder.glob("*.glb")):
    fresh()
    bpy.ops.import_scene.gltf(filepath=str(glb))
    for obj in [o for o in bpy.data.objects if o.type == "MESH"]:
        keys = obj.data.shape_keys
        n_keys = len(keys.key_blocks) - 1 if keys else 0   # minus the basis
        action = keys.animation_data.action if keys and keys.animation_data else None
        span = int(action.frame_range[1] - action.frame_range[0]) + 1 if action else 0
        ok = n_keys > 0 and span >= n_keys - 1 and (want_frames is None or n_keys == want_frames)
        report(ok, f"{glb.name}:{obj.name}", f"{len(obj.data.vertices)} vertices, {n_keys} shape keys, "
                                            f"action over {span} frames")

for usd in sorted(folder.glob("*.usd*")):
    fresh()
    bpy.ops.wm.usd_import(filepath=str(usd), set_frame_range=True)
    sc = bpy.context.scene
    frames = sc.frame_end - sc.frame_start + 1
    for obj in [o for o in bpy.data.objects if o.type == "MESH"]:
        cached = any(m.type == "MESH_SEQUENCE_CACHE" for m in obj.modifiers)
        ok = cached and (want_frames is None or frames == want_frames)
        report(ok, f"{usd.name}:{obj.name}", f"{len(obj.data.vertices)} vertices, animated={cached}, "
                                            f"frames {sc.frame_start}..{sc.frame_end}")

if not any(folder.glob("*")):
    report(False, str(folder), "no exported files")
sys.exit(1 if failures else 0)
