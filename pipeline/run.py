"""Stage orchestration: scene settings -> stage inputs, stages in data-flow order, logging, summary.

Stage order: rig (character, motion, skinning, region split) -> hulls (colliders) -> maps ->
garments -> simulation (with obstacles). Each stage's wall time and output sizes go into the
end summary and the recording's `meta/summary`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.dressing import (build_scene_garments, build_scene_obstacles, check_pattern, check_pins, dressing_layers,
                               garment_fit_report, garment_fits, ignored_joints, load_scene_meshes)
from pipeline.scene import Scene
from pipeline.schema import SceneError


@dataclass
class StageReport:
    name: str
    seconds: float
    sizes: dict = field(default_factory=dict)


@dataclass
class RunSummary:
    scene: str
    output: Path | None
    frames: int
    stages: list[StageReport] = field(default_factory=list)
    penetrations: dict = field(default_factory=dict)
    tables: dict = field(default_factory=dict)   # name -> markdown table (fit report, map stats)
    timings: dict = field(default_factory=dict)  # wall-clock seconds besides the stages' (sewing)
    speeds: dict = field(default_factory=dict)   # wall-clock rates, formatted (simulation steps/s)
    exports: list = field(default_factory=list)  # files written by output.export (pipeline.export)

    def text(self) -> str:
        lines = [f"scene {self.scene}: {self.frames} frames"]
        for s in self.stages:
            sizes = ", ".join(f"{k} {v}" for k, v in s.sizes.items())
            lines.append(f"  {s.name:<10} {s.seconds * 1000:9.1f} ms   {sizes}")
        for k, v in self.timings.items():
            lines.append(f"  {k:<10} {v * 1000:9.1f} ms")
        for k, v in self.speeds.items():
            lines.append(f"  {k}: {v}")
        for k, v in self.penetrations.items():
            lines.append(f"  {k}: {v}")
        if "garment fit" in self.tables:
            lines += ["  garment fit:"] + [f"    {row}" for row in self.tables["garment fit"].splitlines()]
        if self.output:
            lines.append(f"recording: {self.output}  (view: rerun {self.output})")
        lines += [f"exported: {p}" for p in self.exports]
        return "\n".join(lines)

    def markdown(self) -> str:
        """The summary without wall-clock times (those are `timings_markdown`): the same run gives
        the same text."""
        out = [f"# {self.scene}", "", f"{self.frames} frames", "", "| stage | sizes |", "| --- | --- |"]
        for s in self.stages:
            out.append(f"| {s.name} | " + ", ".join(f"{k} {v}" for k, v in s.sizes.items()) + " |")
        if self.penetrations:
            out += ["", "## Penetrations", ""] + [f"- {k}: {v}" for k, v in self.penetrations.items()]
        for name, table in self.tables.items():
            out += ["", f"## {name}", "", table]
        return "\n".join(out)

    def timings_markdown(self) -> str:
        out = ["| stage | wall time (ms) |", "| --- | ---: |"]
        out += [f"| {s.name} | {s.seconds * 1000:.1f} |" for s in self.stages]
        out += [f"| {k} | {v * 1000:.1f} |" for k, v in self.timings.items()]
        out += [""] + [f"- {k}: {v}" for k, v in self.speeds.items()] if self.speeds else []
        return "\n".join(out)


class _Timer:
    def __init__(self, summary: RunSummary, name: str):
        self.summary, self.name = summary, name

    def __enter__(self):
        self.t0 = time.perf_counter()
        self.report = StageReport(self.name, 0.0)
        return self.report

    def __exit__(self, *exc):
        self.report.seconds = time.perf_counter() - self.t0
        if exc[0] is None:
            self.summary.stages.append(self.report)
        return False


# simulation keys whose scene default (null) means "the preset's value" (stages.sim.types.PRESETS)
PRESET_KEYS = ("substeps", "iterations", "damping", "tethers", "stretch_stiffness", "bend_stiffness",
               "cloth_collision", "pinch", "entry_side", "cloth_contact_every", "settle_frames")


def sim_params(scene: Scene):
    """The scene's SimParams: its `simulation.preset` with the keys the scene sets on top."""
    from stages.sim import SimParams
    sp = scene["simulation"]
    given = {k: sp[k] for k in PRESET_KEYS if sp[k] is not None}
    return SimParams.preset(sp["preset"], dt=sp["dt"], gravity=tuple(sp["gravity"]), wind=tuple(sp["wind"]),
                            drag=sp["drag"], lift=sp["lift"], aero_interval=sp["aero_interval"], friction=sp["friction"],
                            inertia_scale=sp["inertia_scale"], hull_response=scene["colliders"]["response"],
                            body_audit=sp["body_audit"], cloth_thickness=sp["cloth_thickness"],
                            cloth_contact=sp["cloth_contact"], **given)


# a sub-step moves the skin at most this share of the body's height; a faster clip gets more sub-steps
STEP_TRAVEL = 0.01
MAX_SUBSTEPS = 100


def motion_substeps(scene: Scene, params, skinned: np.ndarray, height: float):
    """params with more sub-steps where the clip moves the skin far in a frame (a run, a kick, a
    jump) and `simulation.substeps` is left to the preset: enough that no sub-step moves the skin's
    fastest 1 % of vertices more than STEP_TRAVEL of the height (relative frame), rounded up to a
    whole number of cloth collision calls, at most MAX_SUBSTEPS. Returns (params, warning or None).
    A CMU walk 3x as fast: 50 sub-steps; p99 strain at the last frame 37 -> 6 %, 32 -> 0
    self-crossing edges."""
    from dataclasses import replace
    if scene["simulation"]["substeps"] is not None or len(skinned) < 2 or not height > 0:
        return params, None
    step = np.percentile(np.linalg.norm(np.diff(skinned, axis=0), axis=2), 99, axis=1)   # (F-1,) m
    f = int(np.argmax(step))
    need = int(np.ceil(step[f] / (STEP_TRAVEL * height)))
    if need <= params.substeps:
        return params, None
    k = params.contact_steps() if params.cloth_collision else 1
    n = min(MAX_SUBSTEPS, -(-need // k) * k)
    return replace(params, substeps=n), (
        f"simulation: {n} sub-steps a frame instead of {params.substeps}: the skin moves up to "
        f"{step[f] * 1000:.0f} mm ({100 * step[f] / height:.0f} % of its height) between frames {f} and {f + 1}"
        + (f"; {MAX_SUBSTEPS} is the most used, {need} would keep each under {100 * STEP_TRAVEL:.0f} %"
           if need > MAX_SUBSTEPS else ""))


def motion_speed_limit(scene: Scene, params, skinned: np.ndarray, root: np.ndarray, times: np.ndarray,
                       height: float):
    """params with `simulation.speed_limit`, or where it is null and the preset is not the paper's, the
    clip's: 3 times the fastest skin speed relative to the root (skinned (F, V, 3), root (F, 3) world
    m) plus twice the speed of a fall from the body's height. Cloth moves with the body or falls;
    much faster is cloth a collider threw (a Kenney chibi's skirt pressed between its arm and leg
    boxes: 117 m/s, diverged). A limit of twice the skin speed plus 1.5 falls (13.6 m/s on CesiumMan)
    capped its T-shirt's hem whipping off the forearm in 33 frames and raised the T-shirt's mean p99
    strain after the blend from 26 to 42 %."""
    from dataclasses import replace
    given = scene["simulation"]["speed_limit"]
    if given is not None:
        return replace(params, speed_limit=float(given))
    if scene["simulation"]["preset"] == "paper" or len(skinned) < 2 or not height > 0:
        return params
    rel = skinned - root[:, None, :]
    dt = np.maximum(np.diff(times), 1e-9)[:, None]
    skin_speed = float((np.linalg.norm(np.diff(rel, axis=0), axis=2) / dt).max())
    return replace(params, speed_limit=3.0 * skin_speed + 2.0 * float(np.sqrt(2.0 * 9.81 * height)))


def speed_limit_note(result) -> str | None:
    """A warning naming the frames where the speed limit acted, or None."""
    hit = np.flatnonzero(result.speed_limited[1:] > 0) + 1
    if hit.size == 0:
        return None
    f = int(hit[np.argmax(result.speed_limited[hit])])
    return (f"simulation: the speed limit ({result.params.speed_limit:.1f} m/s, simulation.speed_limit) capped cloth "
            f"in {hit.size} frame(s), most at frame {f} ({int(result.speed_limited[f])} particles): cloth thrown "
            "by a collider (a limb pressing it onto the body)")


def garment_layers(scene: Scene) -> list[int]:
    """Each garment's cloth collision layer: its `layer`, else its place in the list (earlier = inner)."""
    return [g["layer"] if g.get("layer") is not None else i for i, g in enumerate(scene["garments"])]


def ignored_colliders(scene: Scene, character) -> list[tuple[int, ...]] | None:
    """simulate's ignore_colliders: each garment's `ignore_colliders` as joint indices, or None when
    no garment ignores any."""
    lists = [ignored_joints(g, character) for g in scene["garments"]]
    return lists if any(lists) else None


def strain_source_notes(audit, garments, result, colliders, character, motion) -> tuple[str, ...]:
    """For each garment whose p99 strain goes over the limit: the joints whose colliders its most
    strained edges touch at its worst frame (stages.sim.strain_sources), one line each."""
    from stages.garments.types import STRETCH
    from stages.sim.audit import STRAIN_P99_LIMIT, edge_strains
    from stages.sim.strain_sources import TOP_SHARE, TOUCH, strain_sources
    out = []
    for g, track, ga in zip(garments, result.garments, audit.garments):
        if ga.strain_p99.max(initial=0.0) <= STRAIN_P99_LIMIT:
            continue
        f = int(np.argmax(ga.strain_p99))
        sel = g.kinds == STRETCH
        x = track.positions[f].astype(np.float64) - motion.root_translation[f]     # the colliders' frame
        strain = edge_strains(x[None], g.springs[sel], g.rest_lengths[sel])[0]
        poses = colliders.frame_poses(character.inverse_bind, motion.joint_world[f]) if colliders is not None else None
        shares = strain_sources(x, g.springs[sel], strain, colliders, poses)
        if shares:
            named = ", ".join(f"{character.joint_names[j]} {100 * s:.0f} %" for j, s in list(shares.items())[:4])
            out.append(f"garment {g.name!r}: at frame {f} its {100 * TOP_SHARE:.0f} % most strained edges touch "
                       f"(within {1000 * TOUCH:.0f} mm) the colliders of {named}")
    return tuple(out)


def body_params(settings: dict):
    from stages.rig.procedural import BodyParams
    b = settings["character"]["body"]
    return BodyParams(height=b["height"], chest=b["chest"], waist=b["waist"], hips=b["hips"],
                      arms=b["arms"], legs=b["legs"])


def load_character(scene: Scene):
    """The scene's character from its source (built-in generator, glTF or BVH)."""
    c = scene["character"]
    if c["source"] == "procedural":
        from stages.rig.procedural import procedural_character
        return procedural_character(body_params(scene.settings))
    from stages.errors import InputError
    src = scene.path or "<scene>"
    path = Path(c["path"])
    if not path.is_file():
        raise SceneError(f"{src}: character.path: file not found: {path}")
    try:
        if c["source"] == "gltf":
            from stages.rig.gltf import load_gltf
            return load_gltf(path, scale=c["scale"], up_axis=c["up_axis"],
                             loop=c["loop"])
        from stages.rig.bvh import load_bvh_character
        return load_bvh_character(path, scale=c["scale"], body=body_params(scene.settings),
                                  bind_pose=c["bind_pose"] or "neutral")
    except InputError as err:   # the loader names the file; the scene's key path goes first
        if str(err.source) == str(path):
            raise SceneError(f"{src}: character.path: {' '.join(err.problem.split())}: {path}") from None
        raise SceneError(f"{src}: character ({c['source']} {path}): {' '.join(str(err).split())}") from None


def character_item(scene: Scene) -> str:
    """The character as the last-resort error line names it."""
    c = scene["character"]
    return f"character {c['source']}" + (f" {c['path']}" if c["path"] else "")


def frame_times(scene: Scene, frames: int | None = None) -> np.ndarray:
    """Clip times of the frames to run: start + k * dt."""
    n = frames if frames is not None else scene["frames"]["count"]
    return scene["frames"]["start"] + scene["simulation"]["dt"] * np.arange(n, dtype=np.float64)


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
            if item["type"] == "mesh" and not Path(item["path"]).is_file():
                raise SceneError(f"{src}: {section}[{i}].path: file not found: {item['path']}")
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


def blend_in_seconds(scene: Scene, character, dressed: bool | None = None) -> float:
    """The scene's blend-in: `frames.blend_in` when given, else (auto) sized by stages.rig.blend from
    how far the clip's pose at `frames.start` is from the rest pose, where garments are dressed; 0
    when nothing is dressed (dressed: None = the scene has garments)."""
    from stages.rig.blend import blend_seconds, pose_distance
    from stages.rig.skinning import sample_clip
    given = scene["frames"]["blend_in"]
    if given is not None:
        return float(given)
    clip = scene["character"]["clip"]
    dressed = bool(scene["garments"]) if dressed is None else dressed
    if clip == "rest" or not character.clips or not dressed:
        return 0.0
    first = sample_clip(character, character.clip(clip), np.array([scene["frames"]["start"]]))[0]
    height = float(np.ptp(character.vertices[:, 1])) if len(character.vertices) else 0.0
    return blend_seconds(pose_distance(character, character.rest_local, first), height)


def sample_scene_motion(scene: Scene, character, times: np.ndarray, dressed: bool | None = None):
    """The clip at `times`, after the blend-in (`blend_in_seconds`) from the rest pose."""
    from stages.rig.skinning import rest_motion, sample_motion
    clip = scene["character"]["clip"]
    if clip == "rest" or not character.clips:
        return rest_motion(character, len(times), scene["simulation"]["dt"])
    blend = int(round(blend_in_seconds(scene, character, dressed) / scene["simulation"]["dt"]))
    if blend and len(times) < 2:
        times = frame_times(scene, 2)[:2]
    return sample_motion(character, clip, times, blend_frames=blend)


def collider_poses(scene: Scene, character, motion) -> np.ndarray:
    """(F, J, 4, 4) joint transforms the region split is measured over: every frame the scene plays
    (blend-in included), plus, for `clip: rest`, the built-in range-of-motion sample. Poses the
    scene never plays (the rest of a long clip) would only widen the swept hulls."""
    from stages.rig.motion_range import range_of_motion
    if scene["character"]["clip"] == "rest" or not character.clips:
        return np.concatenate([motion.joint_world, range_of_motion(character)])
    return motion.joint_world


def split_and_fit(scene: Scene, character, motion, progress=None):
    """The region split and the colliders of the scene's `colliders` settings: (split, colliders).
    Swept hulls are fitted over the frames the scene plays (a static scene: its one pose)."""
    from stages.hulls.fit import fit_character
    c = scene["colliders"]
    poses = collider_poses(scene, character, motion) if (c["split"], c["flexible"]) != ("weights", "sphere") else None
    return fit_character(character, poses, split=c["split"], flexible=c["flexible"], delta=c["delta"],
                         motion_tolerance=c["motion_tolerance"], rigid_threshold=c["rigid_threshold"],
                         min_triangles=c["min_triangles"], max_offset=c["max_offset"],
                         sweep_poses=motion.joint_world, progress=progress)


def preflight(scene: Scene, output: Path | None, *, create: bool, output_flag: bool = False) -> dict:
    """Every check that needs no character, before any work: the recording path, the mesh files,
    the pinned indices. Returns the loaded meshes (see `load_scene_meshes`)."""
    from pipeline import where
    from pipeline.recording import check_output_path
    where.stage("checking the scene")
    src = scene.path or "<scene>"
    out = Path(output) if output is not None else scene.output
    key = f"{src}: {'--output' if output_flag else 'output'}"
    check_output_path(out, where=key, create=False)
    meshes = load_scene_meshes(scene)
    check_pins(scene, meshes)
    if create:   # last, so that a scene refused above leaves no new folder behind
        check_output_path(out, where=key, create=True)
    return meshes


def blueprint_of(scene: Scene, character, motion, skinned, colliders, coverage_ran: bool, obstacles, garments,
                 builds, result):
    """The recording's blueprint (pipeline.blueprint) for what this run logged: the cameras frame
    the body over every frame, the simulated garments (down to 25 cm below the floor) and the solid
    obstacles (not a floor plane)."""
    from pipeline import blueprint as bp
    world = skinned + motion.root_translation[:, None, :]
    body = bp.hull_points(world)
    framed = [body]
    if result is not None:
        # cloth that falls off the body and through the (absent) floor is followed only to just below
        # it: framing a fall of metres would shrink the character to a speck
        floor = float(world[..., 1].min()) - 0.25
        framed += [np.maximum(t.positions, [-np.inf, floor, -np.inf]) for t in result.garments]
    names = []
    if obstacles is not None:
        for ob in obstacles.obstacles:
            names.append(ob.name)
            if np.ptp(ob.vertices, axis=0).min() > 1e-6:   # a solid: frame it; a plane (a floor): not
                framed.append(ob.vertices)
    sewing = [np.concatenate([b.flat_positions, b.placed_positions]) for _, b in builds.values()]
    return bp.build(bp.Contents(
        fps=1.0 / scene["simulation"]["dt"], forward=bp.facing(character, motion), scene_box=bp.hull_points(*framed),
        body_box=body, bind_box=bp.hull_points(character.vertices),
        garments=[t.name for t in result.garments] if result is not None else [], sewn=list(builds),
        sewing_box=bp.hull_points(*sewing) if sewing else None, obstacles=names, hulls=[h.name for h in colliders.hulls],
        spheres=[sp.name for sp in colliders.spheres], coverage=coverage_ran))


def background_warmup(scene: Scene, enabled: bool):
    """The BackgroundCompile of the scene's simulation kernels (pipeline.kernel_warmup); it starts
    nothing unless `enabled`, the scene has garments and the kernels are not cached yet."""
    from pipeline.kernel_cache import BACKGROUND_ESTIMATE_S
    from pipeline.kernel_warmup import BackgroundCompile
    if not (enabled and scene["garments"]):
        return BackgroundCompile(None)
    sp = scene["simulation"]
    params = sim_params(scene)
    request = dict(params=params, threads=sp["threads"], cloth_audit=sp["cloth_audit"],
                   coverage=scene["colliders"]["report_every"] > 0 or scene["colliders"]["flexible"] == "balls",
                   vertex_strain=sp["strain_colors"],
                   layers=garment_layers(scene) if params.cloth_collision else None)
    return BackgroundCompile(request, estimate_s=BACKGROUND_ESTIMATE_S)


def run_scene(scene: Scene, *, output: Path | None = None, frames: int | None = None,
              progress: bool = True, on_stage=None, deterministic: bool = False,
              export: tuple | None = None, state: dict | None = None,
              keep_partial: Path | None = None, background_compile: bool = False) -> RunSummary:
    """Check the inputs that need no character (`preflight`), run every stage the scene needs and
    write the recording atomically.

    Wall-clock timings (stage times, sewing time, step times) go to the `timings/` entities only;
    `deterministic` leaves them out, so the same scene and seed give recordings `rerun rrd compare`
    finds equal.

    export: (formats, folder or None) written after the recording (default: the scene's
    output.export, output.export_dir); see pipeline.export.

    state: a dict filled as the run goes (summary, character, motion, skinned, colliders, coverage, garments,
    builds, result, audit, fits, and during the simulation 'sim': {'result': the frames done so far}), so that a caller
    (pipeline.sweep) can measure the run and keep what exists when it fails.
    keep_partial: where a failed run's recording goes (whatever was logged before the failure)
    instead of being deleted.
    background_compile: on a first run (empty numba cache), compile the sewing, simulation and
    cloth audit kernels in a second process while the earlier stages run (pipeline.kernel_warmup).
    """
    from pipeline import logs, style, where
    from pipeline.kernel_cache import compile_note
    from pipeline.progress import Progress
    from pipeline.recording import atomic_recording
    from stages.jit import numba_threads
    from stages.rig.skinning import skin

    out = Path(output) if output is not None else scene.output
    times = frame_times(scene, frames)
    meshes = preflight(scene, output, create=True, output_flag=output is not None)
    formats, export_dir = export if export is not None else (scene.export["formats"], scene.export["dir"])
    if formats:   # an unknown format or a missing extra fails before the run
        from pipeline.export import check_formats
        formats = check_formats(formats, where=f"{scene.path or scene.name}: output.export")
        if not scene["garments"]:
            raise SceneError(f"{scene.path or scene.name}: output.export: the scene has no garments to export "
                             f"(expected at least one entry under 'garments:')")
    summary = RunSummary(scene=scene.name, output=None, frames=len(times))
    announce = on_stage or (lambda name: None)
    state = {} if state is None else state
    state["summary"] = summary

    def say(name: str, *more: str) -> None:
        where.stage(name)
        note = compile_note(name, *more) if progress else None
        announce(f"{name} ({note})" if note else name)

    def bar(label: str, unit: str) -> Progress:   # a stage's progress(done, total) callback
        return Progress(1, label, unit=unit, enabled=progress)

    s = scene.settings
    # every stage's parallel kernels run on simulation.threads threads (1: their serial variants,
    # compiled several times faster: stages.jit)
    warm = background_warmup(scene, background_compile)
    with atomic_recording(out, scene_name=scene.name, scene_text=scene.text, seed=s["seed"],
                          keep_failed=keep_partial) as rec, numba_threads(s["simulation"]["threads"]), warm:
        if warm.started:
            announce(f"simulation kernels (compiling in a second process, first run only: about "
                     f"{warm.estimate_s:.0f} s on 2 cores)")
        say("rig")
        with _Timer(summary, "rig") as r:
            with where.item(character_item(scene)):
                character = load_character(scene)
            check_references(scene, character)
            motion = sample_scene_motion(scene, character, times)
            times = motion.times
            summary.frames = len(times)
            skinned = skin(character, motion)
            state.update(character=character, motion=motion, skinned=skinned)
            r.sizes.update(vertices=character.vertices.shape[0], triangles=character.triangles.shape[0],
                           joints=character.n_joints)
        if character.notes:  # e.g. the up axis a glTF was found to have, its floor shift
            summary.tables["character"] = "\n".join(f"- {n}" for n in character.notes)
            logs.log_text(rec, "rig/notes", summary.tables["character"])

        say("colliders")
        with _Timer(summary, "colliders") as r:
            hull_bar = bar("colliders", "hulls")
            try:
                split, colliders = split_and_fit(scene, character, motion, progress=hull_bar)
            finally:
                hull_bar.close()
            state["colliders"] = colliders
            faces = [h.report.faces_simplified for h in colliders.hulls]
            r.sizes.update(split=split.method, rigid_hulls=len(split.hull_bones),
                           swept_hulls=sum(h.kind == "swept" for h in colliders.hulls),
                           spheres=sum(sp.frame < 0 for sp in colliders.spheres),
                           **({"balls": int(colliders.balls.radius.size)} if colliders.balls is not None else {}),
                           faces=int(np.sum(faces)))
        logs.log_rig(rec, character, split, motion, skinned)
        summary.tables["collider fit"] = logs.log_colliders(rec, character, motion, colliders)
        if s["colliders"]["report_every"] > 0:
            say("collider coverage")
            import warnings

            from stages.coverage import measure_coverage
            from stages.errors import InputError
            with _Timer(summary, "coverage") as r:
                coverage_bar = bar("collider coverage", "frames")
                try:
                    coverage = measure_coverage(character, motion, colliders, every=s["colliders"]["report_every"],
                                                seed=s["seed"], progress=coverage_bar)
                except InputError as err:   # an audit that cannot measure must not stop the run
                    warnings.warn(f"{err}; the run goes on without the coverage report", stacklevel=1)
                    coverage = None
                finally:
                    coverage_bar.close()
            state["coverage"] = coverage
            if coverage is not None:
                t = coverage.totals()
                r.sizes.update(frames=t["frames"], coverage=f"{t['coverage_min'] * 100:.2f} %",
                               excess_p95=f"{t['excess_p95'] * 100:.1f} cm", excess_max=f"{t['excess_max'] * 100:.1f} cm",
                               shell=f"{t['shell_share'] * 100:.0f} %", skin_exposed=f"{t['skin_exposed'] * 100:.2f} %")
                summary.tables["collider coverage"] = logs.log_coverage(rec, motion, coverage,
                                                                        summary.tables["collider fit"])
                for w in coverage.warnings():
                    warnings.warn(w, stacklevel=1)
        if "collider coverage" not in summary.tables:
            logs.log_text(rec, "colliders/report", summary.tables["collider fit"])

        say("maps")
        from stages.maps.build import build_maps
        m = s["colliders"]["map"]
        with _Timer(summary, "maps") as r:
            maps = build_maps(colliders, kind=m["type"], n_theta=m["n_theta"], n_phi=m["n_phi"], n_axial=m["n_axial"])
            r.sizes.update(maps=len(maps.maps))
        summary.tables["map cells"] = logs.log_maps(rec, character, motion, maps)

        coverage_ran = "collider coverage" in summary.tables
        obstacles, garments, builds, result = None, [], {}, None
        if s["obstacles"]:
            say("obstacles")
            with _Timer(summary, "obstacles") as r:
                obstacles = build_scene_obstacles(scene, float(times[-1] - times[0]), meshes)
                r.sizes.update(obstacles=len(obstacles.obstacles), triangles=obstacles.triangles.shape[0],
                               tree_nodes=obstacles.tree.node_min.shape[0])
            logs.log_obstacles(rec, obstacles, times)

        if s["garments"]:
            if not warm.simulation_ready():   # sewing is the first stage to call the simulation's kernels
                where.stage("garments")
                announce(f"garments (waiting for the simulation kernels compiling in a second process: "
                         f"about {warm.seconds_left():.0f} s more)")
                warm.wait_simulation()
            else:
                warm.wait_simulation()
                say("garments")
            with _Timer(summary, "garments") as r:
                sewing_bars = []

                def sewing_bar(name: str) -> Progress:
                    if sewing_bars:
                        sewing_bars[-1].close()
                    sewing_bars.append(bar(f"sewing {name} (stops when the seams close)", "iterations"))
                    return sewing_bars[-1]
                try:
                    garments, builds = build_scene_garments(scene, character, motion, colliders, maps, meshes,
                                                            progress=sewing_bar)
                finally:
                    if sewing_bars:
                        sewing_bars[-1].close()
                state.update(garments=garments, builds=builds)
                r.sizes.update(particles=sum(g.n_particles for g in garments))
                for name, (log, _) in builds.items():
                    r.sizes[f"{name} sewing"] = (f"{log.iterations} it, gap {log.gap_max[-1] * 1000:.1f} mm, "
                                                 f"{'converged' if log.converged else 'NOT converged'}")
                    summary.timings[f"{name} sewing"] = log.seconds
            for name, (log, build) in builds.items():
                i = next(k for k, g in enumerate(garments) if g.name == name)
                logs.log_sewing(rec, name, log, build, garments[i], color=style.fabric(i))
            from stages.sim import simulate
            sp = s["simulation"]
            height = float(np.ptp(character.vertices[:, 1]))
            params, note = motion_substeps(scene, sim_params(scene), skinned, height)
            params = motion_speed_limit(scene, params, skinned, motion.root_translation, motion.times, height)
            if note:
                import warnings
                warnings.warn(note, stacklevel=1)
            say("simulation", *(("cloth collision",) if params.cloth_collision else ()))
            bar = Progress(len(times), "simulation", enabled=progress)
            with _Timer(summary, "simulation") as r:
                try:
                    result = simulate(character, motion, colliders, maps, garments, params, obstacles=obstacles,
                                      layers=garment_layers(scene), ignore_colliders=ignored_colliders(scene, character),
                                      partial=state.setdefault("sim", {}),
                                      progress=lambda done, total: bar.update(done), threads=sp["threads"])
                finally:
                    bar.close()
                state["result"] = result
                r.sizes.update(steps=result.steps)
            note = speed_limit_note(result)
            if note:
                import warnings
                warnings.warn(note, stacklevel=1)
            audit, held = None, ()
            if sp["cloth_audit"]:
                if warm.running():   # its kernels compile in the second process while the run simulates
                    where.stage("cloth audit")
                    announce("cloth audit (waiting for its kernels compiling in a second process)")
                    warm.wait()
                else:
                    warm.wait()
                    say("cloth audit")
                import warnings

                from stages.sim.audit import audit_cloth
                with _Timer(summary, "cloth audit") as r:
                    audit = audit_cloth(result, garments, vertex_strain=sp["strain_colors"])
                    r.sizes.update(exact_pairs=audit.exact_pairs)
                state["audit"] = audit
                held = strain_source_notes(audit, garments, result, colliders, character, motion)
                for w in audit.warnings + held:
                    warnings.warn(w, stacklevel=1)
            summary.penetrations = logs.log_sim(rec, motion, garments, result, audit, held)
            summary.speeds = {k: summary.penetrations.pop(k) for k in list(summary.penetrations) if k.startswith("steps/s")}
            from pipeline.body_report import audit_and_log   # issue 38: body edges through the cloth
            audit_and_log(rec, scene, state, announce=say)
            step_ms = result.step_ms
            state["fits"] = garment_fits(character, motion, skinned, garments, builds, result,
                                         layers=dressing_layers(scene))
            summary.tables["garment fit"] = garment_fit_report(character, motion, skinned, garments, builds, result,
                                                               fits=state["fits"])
            logs.log_text(rec, "sim/fit", summary.tables["garment fit"])
        where.stage("writing the recording")
        logs.log_text(rec, "meta/summary", summary.markdown())
        if not deterministic:   # wall-clock figures: their own entities, left out by --deterministic
            logs.log_text(rec, "timings/stages", summary.timings_markdown())
            if s["garments"]:
                logs.log_scalar_series(rec, "timings/step_ms", step_ms, result.times, name="step (ms)",
                                       color=(60, 160, 90))
        rec.send_blueprint(blueprint_of(scene, character, motion, skinned, colliders, coverage_ran,
                                        obstacles, garments, builds, result), make_active=True, make_default=True)
    summary.output = out
    if formats:
        where.stage("export")
        from pipeline.export import export_run
        summary.exports = export_run(scene, out, motion, skinned, character, result, builds, formats, export_dir)
    return summary
