"""Checks before any stage: the recording and export paths, the mesh files and pinned indices
(`preflight`, no character needed), and the names only the character can confirm
(`check_references`: clip, joints, a GarmentCode garment's files). `validate`, `run` and a sweep's
job check run these."""
from __future__ import annotations

from pathlib import Path

from pipeline.dressing import check_pattern, check_pins, load_scene_meshes
from pipeline.scene import Scene
from pipeline.schema import SceneError
from stages.input_files import file_problem


def preflight(scene: Scene, output: Path | None, *, create: bool, output_flag: bool = False,
              export: tuple | None = None) -> dict:
    """Every check that needs no character, before any work: the recording path, the exports'
    folder, the mesh files, the pinned indices. Returns the loaded meshes (see `load_scene_meshes`).
    export: (formats, folder or None) instead of the scene's output.export (the `export` command's)."""
    from pipeline import where
    from pipeline.export import check_export_dir, default_dir
    from pipeline.recording import check_output_path
    where.stage("checking the scene")
    src = scene.path or "<scene>"
    out = Path(output) if output is not None else scene.output
    key = f"{src}: {'--output' if output_flag else 'output'}"
    check_output_path(out, where=key, create=False)
    formats, folder = export if export is not None else (scene.export["formats"], scene.export["dir"])
    if formats:
        check_export_dir(folder or default_dir(out), where=f"{src}: " + (
            "--output" if export is not None else "output.export_dir" if folder else "output.export"))
    meshes = load_scene_meshes(scene)
    check_pins(scene, meshes)
    if create:   # last, so that a scene refused above leaves no new folder behind
        check_output_path(out, where=key, create=True)
    return meshes


def check_references(scene: Scene, character) -> None:
    """Names the scene uses that only the character can confirm (clip, joints)."""
    src = scene.path or "<scene>"
    clip = scene["character"]["clip"]
    if not (clip == "rest" or isinstance(clip, (int, str)) and not isinstance(clip, bool)):
        raise SceneError(f"{src}: character.clip: expected a clip name, an index or 'rest', got {clip!r}")
    if clip != "rest":
        try:
            character.clip(clip)
        except KeyError:
            raise SceneError(f"{src}: character.clip: {clip!r} is not a clip of {character.name!r}; "
                             f"clips: {[c.name for c in character.clips] or 'none'} (or 'rest')") from None
    for section in ("garments", "obstacles"):
        for i, item in enumerate(scene[section]):
            problem = file_problem(Path(item["path"]), "mesh file") if item["type"] == "mesh" else None
            if problem:
                raise SceneError(f"{src}: {section}[{i}].path: {problem}: {item['path']}")
    names = set(character.joint_names)
    for i, g in enumerate(scene["garments"]):
        if g["type"] == "pattern":
            check_pattern(scene, i)
        if g["type"] == "garmentcode":      # read now: a bad pattern file stops the run before the colliders
            from stages.errors import InputError
            from stages.garments.garmentcode import read_pattern
            from pipeline.assets import assets_dir
            from stages.garments.garmentcode_place import DEFAULT_BODY, body_of
            try:
                read_pattern(g["path"])
                body_of(g["path"], assets_dir() / DEFAULT_BODY)
            except InputError as err:
                raise SceneError(f"{src}: garments[{i}].path: {err}") from None
        refs = [("at_joint", g.get("at_joint"))]
        if g.get("pin") is not None:
            refs.append(("pin.collider", g["pin"]["collider"]))
        refs += [(f"ignore_colliders[{k}]", name) for k, name in enumerate(g.get("ignore_colliders") or ())]
        for key, name in refs:
            if name is not None and name not in names:
                import difflib
                near = difflib.get_close_matches(name, sorted(names), n=1)
                hint = f" (did you mean {near[0]!r}?)" if near else f"; joints: {', '.join(character.joint_names)}"
                raise SceneError(f"{src}: garments[{i}].{key}: {name!r} is not a joint of {character.name!r}{hint}")


def available_memory() -> int | None:
    """Bytes the kernel says a new allocation can have without swapping (MemAvailable), or None."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


# bytes per frame per body vertex and per cloth particle the run keeps (the skinned body in float64, its
# normals, the recording's copies; the cloth's positions, audits, rows). Body: the built-in walk without
# garments, 200 -> 2,000 frames: peak RSS +1.47 GB (380 B a vertex a frame, 2026-11-29). Cloth: an upper
# bound: scenes/default.yaml (2,202 vertices, 1,054 particles) grew 0.46 MB a frame from 30 to 300 frames
BODY_BYTES, CLOTH_BYTES = 380, 200


def check_memory(scene: Scene, frames: int, body_vertices: int, particles: int) -> None:
    """A run that would need more memory than the machine has available is one SceneError saying how
    much and what to change, before it allocates (it was killed by the kernel with no message)."""
    free = available_memory()
    need = frames * (body_vertices * BODY_BYTES + particles * CLOTH_BYTES)
    if free is not None and need > free:
        gb = 1024 ** 3
        raise SceneError(f"{scene.path or '<scene>'}: frames.count: {frames:,} frames of a {body_vertices:,}-vertex "
                         f"body" + (f" and {particles:,} cloth particles" if particles else "")
                         + f" need about {need / gb:.1f} GB of memory, more than the {free / gb:.1f} GB available; "
                         f"expected fewer frames" + (" or a coarser garment" if particles else ""))
