"""Garments and obstacles from a scene: pattern garments sized, placed and sewn on the character,
mesh garments and obstacles read and checked, and the fit figures of what was simulated. The
pipeline (pipeline.run) calls these; `validate` and the dressing matrix use them too."""
from __future__ import annotations

import dataclasses

import numpy as np

from pipeline.scene import MAX_GARMENT_PARTICLES, Scene
from pipeline.schema import SceneError


def pattern_options(kind: str) -> tuple[str, ...]:
    """The size options a built-in pattern kind accepts (pipeline.scene.KIND_OPTIONS)."""
    from pipeline.scene import KIND_OPTIONS
    return KIND_OPTIONS.get(kind, ())


def check_pattern(scene: Scene, index: int) -> None:
    """A pattern garment's kind exists in the library and its options are the kind's options."""
    from stages.garments.library import KINDS
    g = scene["garments"][index]
    src = scene.path or "<scene>"
    if g["kind"] not in KINDS:
        raise SceneError(f"{src}: garments[{index}].kind: {g['kind']!r} is not in this build's pattern "
                         f"library; available: {', '.join(KINDS)}")
    allowed = pattern_options(g["kind"])
    for key in g["options"]:
        if key not in allowed:
            raise SceneError(f"{src}: garments[{index}].options.{key}: not an option of kind {g['kind']!r}; "
                             f"options: {', '.join(allowed) or 'none'}")


def _item(scene: Scene, section: str, index: int) -> str:
    return f"{section}[{index}] ({scene[section][index]['name']!r})"


def load_scene_meshes(scene: Scene) -> dict:
    """Every mesh file the scene references, read and checked: {(section, index): (x, tri)} (a
    garment's: a GarmentMesh, the file's UVs too). A
    missing, empty, corrupt or degenerate file is a SceneError naming the scene file, the key
    path, the item and the mesh file (what `validate` and `run` check before any stage)."""
    from stages.errors import InputError
    from stages.garments.importer import read_garment_mesh
    from stages.obstacles import load_obstacle_mesh
    from pipeline import where
    src = scene.path or "<scene>"
    out = {}
    for section, load in (("garments", read_garment_mesh), ("obstacles", load_obstacle_mesh)):
        for i, it in enumerate(scene[section]):
            if it["type"] != "mesh":
                continue
            with where.item(f"{_item(scene, section, i)} mesh file {it['path']}"):
                try:
                    more = {"part": it["part"]} if section == "garments" else {}
                    out[(section, i)] = load(it["path"], scale=it["scale"], transform=placement_matrix(it), **more)
                except InputError as err:
                    raise SceneError(f"{src}: {section}[{i}].path: {err.problem}: {err.source} "
                                     f"({section[:-1]} {it['name']!r})") from None
                n = len(out[(section, i)][0])
                if section == "garments" and n > MAX_GARMENT_PARTICLES:
                    raise SceneError(f"{src}: garments[{i}].path: the mesh has {n:,} vertices, more than "
                                     f"{MAX_GARMENT_PARTICLES:,} cloth particles (expected a garment-sized mesh; "
                                     f"decimate it): {it['path']} (garment {it['name']!r})")
    return out


def particle_count(g: dict, meshes: dict, index: int) -> int | None:
    """How many particles a rectangle, tube or mesh garment has (None for a pattern: known once sized)."""
    if g["type"] == "rectangle":
        return g["resolution"][0] * g["resolution"][1]
    if g["type"] == "tube":
        return g["n_around"] * g["n_down"]
    if g["type"] == "mesh" and ("garments", index) in meshes:
        return len(meshes[("garments", index)][0])
    return None


def check_pins(scene: Scene, meshes: dict) -> None:
    """Pinned particle indices inside the garment's particle range."""
    src = scene.path or "<scene>"
    for i, g in enumerate(scene["garments"]):
        pin = g.get("pin")
        n = particle_count(g, meshes, i)
        if not pin or pin["indices"] is None or n is None:
            continue
        for k, idx in enumerate(pin["indices"]):
            if not 0 <= idx < n:
                raise SceneError(f"{src}: garments[{i}].pin.indices[{k}] ({g['name']!r}): particle index {idx} "
                                 f"is out of range: the garment has {n} particles, expected 0 to {n - 1}")


def ignored_joints(g: dict, character) -> tuple[int, ...]:
    """The joint indices of a garment's `ignore_colliders` (names checked by check_references)."""
    names = list(character.joint_names)
    return tuple(names.index(n) for n in g.get("ignore_colliders") or ())


def _garment_where(scene: Scene, index: int, character) -> str:
    g = scene["garments"][index]
    return f"{scene.path or '<scene>'}: garments[{index}] ({g['name']!r}, kind {g['kind']}) on {character.name!r}"


def scene_pattern(scene: Scene, index: int, character, motion, colliders, under=()):
    """The built-in pattern of a pattern garment, sized for the character and the garments worn
    under it (`under`, Garments); a body it cannot be sized for is a SceneError naming the scene
    file and the garment."""
    from stages.checks import ContractError
    from stages.errors import InputError
    from stages.garments.anchors import require_anchors
    from stages.garments.library import library_pattern
    from stages.garments.measurements import garment_measurements
    g = scene["garments"][index]
    check_pattern(scene, index)
    try:
        require_anchors(g["kind"], character, f"garment {g['name']!r}")
    except InputError as err:
        raise SceneError(f"{_garment_where(scene, index, character)}: {err.problem}") from None
    try:
        below = np.concatenate([u.positions for u in under]) if len(under) else None
        pattern = library_pattern(g["kind"], garment_measurements(character, colliders, motion, under=below),
                                  edge_length=g["edge_length"], name=g["name"],
                                  **{k: float(v) for k, v in g["options"].items()})
    except (ContractError, InputError) as err:
        raise SceneError(f"{_garment_where(scene, index, character)}: the pattern cannot be sized for this body: "
                         f"{err}") from None
    check_pattern_size(scene, index, character, pattern)
    return dataclasses.replace(pattern, density=g["density"])


MAX_PATTERN_PARTICLES = 100_000   # ~10x the largest shipped garment; memory and time grow with it


def check_pattern_size(scene: Scene, index: int, character, pattern) -> None:
    """A pattern whose panels would mesh into more than MAX_PATTERN_PARTICLES particles at its edge
    length (a body far larger than a person's, a tiny edge length) is one SceneError saying which
    key to change, before any meshing (a skirt sized for a 9.5 m cylinder: half a million)."""
    from stages.garments.patterns import polygon_area
    area = sum(polygon_area(p.polyline(64)) for p in pattern.panels)
    particles = area / (pattern.edge_length ** 2 * np.sqrt(3.0) / 4.0) / 2.0   # a triangle mesh: ~2 triangles a vertex
    if particles > MAX_PATTERN_PARTICLES:
        height = float(np.ptp(character.vertices[:, 1])) if len(character.vertices) else float("nan")
        raise SceneError(f"{_garment_where(scene, index, character)}: the pattern sized for this body ({height:.2f} m "
                         f"tall) would have about {particles:,.0f} particles at edge_length {pattern.edge_length} m "
                         f"(at most {MAX_PATTERN_PARTICLES:,}); set a larger garments[{index}].edge_length, or "
                         f"character.scale if the body's size is wrong")


def place_scene_pattern(scene: Scene, index: int, character, motion, colliders):
    """Size, triangulate and place a pattern garment without sewing it (what `validate` checks)."""
    from stages.checks import ContractError
    from stages.errors import InputError
    from stages.garments.placement import place_pattern
    from stages.garments.triangulate import triangulate_pattern
    pattern = scene_pattern(scene, index, character, motion, colliders)
    try:
        return place_pattern(pattern, triangulate_pattern(pattern), character, motion, colliders)
    except (ContractError, InputError) as err:
        raise SceneError(f"{_garment_where(scene, index, character)}: cannot place the pattern: {err}") from None


def build_pattern_garment(scene: Scene, index: int, character, motion, colliders, maps, progress=None, under=()):
    """A sewn garment from a built-in pattern: (Garment, SewingLog, GarmentBuild). Seams that do
    not close within the tolerance are a SceneError naming the seam and the gap. under: the
    garments worn under it (its waistband is hugged over them, HUG_GAP + the cloth thickness off)."""
    from stages.garments.hug import HUG_GAP
    from stages.checks import ContractError
    from stages.errors import InputError
    from stages.garments.library import make_garment
    from stages.garments.sewing import SewParams
    g = scene["garments"][index]
    where = _garment_where(scene, index, character)
    pattern = scene_pattern(scene, index, character, motion, colliders, under=under)
    sw = g["sewing"]
    sew = SewParams(tolerance=sw["tolerance"], target=sw["target"],
                    max_iterations=sw["max_iterations"], gravity_scale=sw["gravity_scale"], iterations=sw["iterations"])
    try:
        garment, log, build = make_garment(pattern, character, motion, colliders, maps, sew_params=sew,
                                           progress=progress, under=under,
                                           under_gap=HUG_GAP + scene["simulation"]["cloth_thickness"],
                                           ignore_joints=ignored_joints(g, character))
    except (ContractError, InputError) as err:
        raise SceneError(f"{where}: cannot place and sew the pattern: {err}") from None
    check_sewn(where, index, sw, garment, log, build)
    return garment, log, build


class SewingError(SceneError):
    """A pattern garment's seams did not close. partial: (Garment, SewingLog, GarmentBuild) as the
    sewing left them (what a sweep keeps of a failed job)."""

    def __init__(self, message: str, partial=None):
        super().__init__(message)
        self.partial = partial


def build_garmentcode_garment(scene: Scene, index: int, character, motion, colliders, maps, progress=None,
                              place_only: bool = False):
    """A sewn garment from a GarmentCode pattern file (issue 39): (Garment, SewingLog, GarmentBuild);
    a pattern made for another body warns how far its body is from the character's. place_only:
    graded, meshed and placed but not sewn (what `validate` checks); returns None."""
    import warnings

    from stages.checks import ContractError
    from stages.errors import InputError
    from stages.garments.garmentcode import read_pattern
    from pipeline.assets import assets_dir
    from stages.garments.garmentcode_place import DEFAULT_BODY, body_of, gathered_note, make_gc_garment, place_gc_garment
    from stages.garments.sewing import SewParams
    g = scene["garments"][index]
    where = f"{scene.path or '<scene>'}: garments[{index}] ({g['name']!r}, GarmentCode {g['path']}) on {character.name!r}"
    try:
        gc = read_pattern(g["path"])
        body = body_of(g["path"], assets_dir() / DEFAULT_BODY)
    except InputError as err:
        raise SceneError(f"{scene.path or '<scene>'}: garments[{index}].path: {err}") from None
    from stages.garments.anchors import require_human
    try:
        require_human(character, where)
    except InputError as err:
        raise SceneError(str(err)) from None
    if place_only:
        try:
            place_gc_garment(gc, body, character, motion, colliders, edge_length=g["edge_length"], name=g["name"])
        except (ContractError, InputError) as err:
            raise SceneError(f"{where}: cannot place the pattern: {err}") from None
        return None
    sw = g["sewing"]
    sew = SewParams(tolerance=sw["tolerance"], target=sw["target"],
                    max_iterations=sw["max_iterations"], gravity_scale=sw["gravity_scale"], iterations=sw["iterations"])
    try:
        garment, log, build, warn = make_gc_garment(gc, body, character, motion, colliders, maps,
                                                    edge_length=g["edge_length"], name=g["name"], density=g["density"],
                                                    sew_params=sew, ignore_joints=ignored_joints(g, character),
                                                    progress=progress)
    except (ContractError, InputError) as err:
        raise SceneError(f"{where}: cannot place and sew the pattern: {err}") from None
    if warn:
        warnings.warn(warn, stacklevel=1)
    try:
        check_sewn(where, index, sw, garment, log, build)
    except SewingError as err:
        note = gathered_note(gc, build.worst_seam()[0])
        if not note:
            raise
        raise SewingError(f"{err}; {note}", partial=err.partial) from None
    return garment, log, build


def check_sewn(where: str, index: int, sw: dict, garment, log, build) -> None:
    """SewingError naming the worst open seam when the sewing did not converge (the built garment kept)."""
    if not log.converged:
        seam, gap = build.worst_seam()
        raise SewingError(f"{where}: sewing did not close seam {seam}: {gap * 1000:.1f} mm open after "
                          f"{log.iterations} iterations (garments[{index}].sewing.tolerance {sw['tolerance'] * 1000:.1f} mm, "
                          f"max_iterations {sw['max_iterations']})", partial=(garment, log, build))


def placement_matrix(item: dict) -> np.ndarray:
    """(4, 4) transform of a mesh item's `rotate_deg` (XYZ Euler, degrees) then `translate`."""
    from scipy.spatial.transform import Rotation
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("xyz", item["rotate_deg"], degrees=True).as_matrix()
    m[:3, 3] = item["translate"]
    return m


def build_scene_garments(scene: Scene, character, motion, colliders, maps, meshes: dict | None = None,
                         progress=None):
    """Garments of the scene, placed in the relative frame at frame 0.

    meshes: the files already read by `load_scene_meshes` (read here when not given).
    Returns (garments, builds): builds maps a pattern garment's name to (SewingLog, GarmentBuild).
    progress: optional factory, garment name -> callback(iteration, max_iterations) of its sewing.
    """
    from pipeline import where
    from stages.checks import ContractError
    from stages.errors import InputError
    meshes = load_scene_meshes(scene) if meshes is None else meshes
    out, builds = [None] * len(scene["garments"]), {}
    layers = dressing_layers(scene)
    # inner layers first: a garment's waistband is hugged over the garments worn under it
    for i in sorted(range(len(layers)), key=lambda k: (layers[k], k)):
        g = scene["garments"][i]
        under = [out[k] for k in range(len(layers)) if layers[k] < layers[i]]
        with where.item(f"{_item(scene, 'garments', i)}, type {g['type']}"):
            try:
                garment, built = _build_scene_garment(scene, i, character, motion, colliders, maps, meshes,
                                                      progress(g["name"]) if progress is not None else None,
                                                      under=under)
            except (ContractError, InputError) as err:
                raise _garment_build_error(scene, i, err) from None
        # the fabric's stiffnesses (None: the simulation's); the density is already in the masses
        out[i] = dataclasses.replace(garment, stretch_stiffness=g["stretch_stiffness"],
                                     bend_stiffness=g["bend_stiffness"])
        if built is not None:
            builds[g["name"]] = built
    return out, {g["name"]: builds[g["name"]] for g in scene["garments"] if g["name"] in builds}


def cloth_collision_on(scene: Scene) -> bool:
    """simulation.cloth_collision, or its preset's value when the scene leaves it null."""
    from stages.sim.types import PRESETS, SimParams
    given = scene["simulation"]["cloth_collision"]
    if given is not None:
        return bool(given)
    return bool(PRESETS[scene["simulation"]["preset"]].get("cloth_collision", SimParams.cloth_collision))


def dressing_layers(scene: Scene) -> list[int]:
    """Each garment's cloth layer when the scene's cloth collision is on (its `layer`, else its place
    in the list), else all 0: the garments are then dressed independently."""
    if not cloth_collision_on(scene):
        return [0] * len(scene["garments"])
    return [g["layer"] if g.get("layer") is not None else i for i, g in enumerate(scene["garments"])]


def _garment_build_error(scene: Scene, index: int, err: Exception) -> SceneError:
    """A stage's refusal to build a garment, as a SceneError naming the scene file, the key path
    (`garments[i].pin` for an attachment) and the garment."""
    key = f"garments[{index}]" + (".pin" if getattr(err, "source", None) == "attachment" else "")
    problem = err.problem if hasattr(err, "problem") else str(err)
    return SceneError(f"{scene.path or '<scene>'}: {key} ({scene['garments'][index]['name']!r}): cannot build the "
                      f"garment: {' '.join(str(problem).split())}")


def check_scene_garments(scene: Scene, character, motion, colliders, meshes: dict) -> int:
    """What `validate` does with the garments: builds every garment as a run does, except that a
    pattern garment is sized and placed but not sewn. Returns the number of pattern garments."""
    from pipeline import where
    from stages.checks import ContractError
    from stages.errors import InputError
    patterns = 0
    for i, g in enumerate(scene["garments"]):
        with where.item(f"{_item(scene, 'garments', i)}, type {g['type']}"):
            if g["type"] == "pattern":
                place_scene_pattern(scene, i, character, motion, colliders)
                patterns += 1
                continue
            if g["type"] == "garmentcode":
                build_garmentcode_garment(scene, i, character, motion, colliders, None, place_only=True)
                patterns += 1
                continue
            try:
                _build_scene_garment(scene, i, character, motion, colliders, None, meshes)
            except (ContractError, InputError) as err:
                raise _garment_build_error(scene, i, err) from None
    return patterns


def _build_scene_garment(scene: Scene, i: int, character, motion, colliders, maps, meshes, progress=None,
                         under=()):
    """One garment: (Garment, (SewingLog, GarmentBuild) of a pattern or None). under: the garments
    worn under it (a pattern's waistband is hugged over them)."""
    from stages.garments.simple import rectangle_cloth, tube_skirt
    from stages.garments.types import (COMMON_BONE, attach_indices, attach_near, attach_top_loop, bind_pose,
                                       build_garment)
    g = scene["garments"][i]
    if g["type"] == "pattern":
        garment, log, build = build_pattern_garment(scene, i, character, motion, colliders, maps, progress, under)
        return garment, (log, build)
    if g["type"] == "garmentcode":
        garment, log, build = build_garmentcode_garment(scene, i, character, motion, colliders, maps, progress)
        return garment, (log, build)
    bind = bind_pose(character, motion, colliders)
    if g["type"] == "mesh":
        x, tri = meshes[("garments", i)][:2]
    elif g["type"] == "rectangle":
        nx, ny = g["resolution"]
        axis = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}[g["normal"]]
        x, tri = rectangle_cloth(g["width"], g["height"], nx, ny, center=g["center"], normal=axis)
    else:  # tube
        top = np.asarray(g["center"] if g["center"] is not None else
                         bind.joint_origins[bind.joint_index(g["at_joint"] or character.joint_names[character.root_joint])])
        x, tri = tube_skirt(g["radius_top"], g["radius_bottom"], g["length"], g["n_around"], g["n_down"],
                            center=top + np.asarray(g["offset"]))
    atts = []
    pin = g["pin"]
    if pin is not None:
        if pin["indices"] is not None:
            atts.append(attach_indices(pin["indices"], pin["collider"]))
        elif pin["collider"] is not None and pin["boundary"] is None:
            atts.append(attach_near(pin["collider"], pin["within"]))
        if pin["boundary"] == "top":
            # one bone for the whole loop: a waistband pinned to pelvis and thighs is torn between them
            atts.append(attach_top_loop(pin["collider"] if pin["collider"] is not None else COMMON_BONE))
    return build_garment(g["name"], x, tri, density=g["density"], attachments=atts, bind=bind,
                         ignore_joints=ignored_joints(g, character)), None


def build_scene_obstacles(scene: Scene, duration: float, meshes: dict | None = None):
    """The scene's obstacles (world frame) with their k-DOP trees. meshes: the files already read
    by `load_scene_meshes` (read here when not given)."""
    from pipeline import where
    from stages.checks import ContractError
    from stages.errors import InputError
    meshes = load_scene_meshes(scene) if meshes is None else meshes
    out = []
    for i, o in enumerate(scene["obstacles"]):
        with where.item(f"{_item(scene, 'obstacles', i)}, type {o['type']}"):
            try:
                out.append(_build_scene_obstacle(o, meshes.get(("obstacles", i)), duration))
            except (ContractError, InputError) as err:
                raise SceneError(f"{scene.path or '<scene>'}: {_item(scene, 'obstacles', i)}: cannot build the "
                                 f"obstacle: {' '.join(str(err).split())}") from None
    from stages.obstacles import build_obstacle_set
    with where.item("the obstacle set (k-DOP trees)"):
        return build_obstacle_set(out)


def _build_scene_obstacle(o: dict, file_mesh, duration: float):
    from stages.obstacles import (ObstacleMotion, box_mesh, cylinder_mesh, make_obstacle, plane_mesh,
                                  sphere_mesh, table_mesh)
    t = o["type"]
    if t == "box":
        mesh, pivot = box_mesh(o["center"], o["size"]), o["center"]
    elif t == "table":
        c = np.asarray(o["center"])
        mesh = table_mesh(top_center=c + [0.0, o["height"], 0.0], top_size=tuple(o["top_size"]),
                          top_thickness=o["top_thickness"])
        pivot = c
    elif t == "sphere":
        mesh, pivot = sphere_mesh(o["center"], o["radius"], o["subdivisions"]), o["center"]
    elif t == "plane":
        mesh, pivot = plane_mesh(o["point"], o["normal"], (o["size"], o["size"])), o["point"]
    elif t == "cylinder":
        mesh, pivot = cylinder_mesh(o["center"], o["radius"], o["height"], o["sections"]), o["center"]
    else:  # mesh file
        mesh = file_mesh
        pivot = o["translate"]
    motion = None
    if any(o["velocity"]) or any(o["angular_velocity"]):
        motion = ObstacleMotion.from_velocity(o["velocity"], o["angular_velocity"], pivot=pivot,
                                              duration=max(duration, 1e-3) + 1.0)
    return make_obstacle(o["name"], mesh, thickness=max(o["thickness"], 1e-4), friction=o["friction"],
                         restitution=o["restitution"], motion=motion)


def garment_fits(character, motion, skinned, garments, builds, result, layers=None) -> list:
    """stages.garments.fit.GarmentFit of every simulated garment; the floor is the simulation's
    (SimParams.floor), else the lowest skin point over the frames (world), the fit edges those of the
    pattern garments' builds. layers: each
    garment's cloth layer (dressing_layers) or None: a garment's fit edges are measured to the nearer
    of the skin and the garments of lower layers (a waistband worn over a tucked-in shirt sits on the
    shirt, not on the skin)."""
    from stages.geometry.skin_distance import SkinDistance
    from stages.garments.fit import garment_fit
    from stages.garments.placement import triangle_grid_points
    from pipeline.scene_motion import lowest_skin_point
    floor_y = result.params.floor if result.params.floor is not None else lowest_skin_point(skinned, motion.root_translation)
    nf = len(result.times)
    world = skinned[:nf] + motion.root_translation[:nf, None, :]   # the skin where the garments were, frame by frame
    body = SkinDistance(character)
    layers = [0] * len(garments) if layers is None else list(layers)
    surface = [triangle_grid_points(g.positions, g.triangles) if k < max(layers) else None
               for g, k in zip(garments, layers)]     # of the garments some other one is worn over
    out = []
    for i, (g, track) in enumerate(zip(garments, result.garments)):
        build = builds.get(g.name, (None, None))[1]
        fit_vertices = build.fit_vertices if build is not None else np.zeros(0, np.int64)
        below = [p for p, k in zip(surface, layers) if k < layers[i]]
        out.append(garment_fit(character, skinned[0], g.positions, fit_vertices, track, floor_y, skin_distance=body,
                               under=np.concatenate(below) if below else None, skin_frames=world))
    return out


def garment_fit_report(character, motion, skinned, garments, builds, result, fits=None) -> str:
    """The fit figures of every garment (garment_fits, unless given) as a table; warns about any
    figure out of range and about garments that start inside the body or a collider."""
    import warnings

    from stages.garments.fit import fit_table, start_warnings
    if fits is None:
        fits = garment_fits(character, motion, skinned, garments, builds, result)
    for f, track in zip(fits, result.garments):
        for w in start_warnings(track) + f.warnings():
            warnings.warn(w, stacklevel=1)
    return fit_table(fits, {name: build.worst_seam()[1] for name, (_, build) in builds.items()})
