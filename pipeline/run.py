"""Stage orchestration: scene settings -> stage inputs, stages in data-flow order, logging, summary.

Stage order: rig (character, motion, skinning, region split) -> hulls (colliders) -> maps ->
garments -> simulation (with obstacles). Each stage's wall time and output sizes go into the
end summary and the recording's `meta/summary`.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from pipeline.cloth_checks import check_blown_up, release_note, speed_limit_note, strain_source_notes, torn_by
from pipeline.dressing import (build_scene_garments, build_scene_obstacles, dressing_layers, garment_fit_report,
                               garment_fits, ignored_joints)
from pipeline.preflight import check_memory, check_references, preflight
from pipeline.scene import Scene, warn_notes
from pipeline.scene_motion import (collider_poses, frame_times, motion_floor, motion_speed_limit, motion_substeps,
                                   sample_scene_motion)
from pipeline.schema import SceneError
from pipeline.summary import RunSummary, StageTimer


# simulation keys whose scene default (null) means "the preset's value" (stages.sim.types.PRESETS)
PRESET_KEYS = ("substeps", "iterations", "damping", "tethers", "stretch_stiffness", "bend_stiffness",
               "cloth_collision", "pinch", "entry_side", "face_contact", "strain_limit", "limb_release", "cloth_contact_every", "settle_frames")


TORN_RELEASE = 2.0   # simulation.limb_release of the second run of a scene whose cloth a limb tore


def torn_release(scene: Scene, params) -> bool:
    """Whether a run whose cloth tore (pipeline.cloth_checks.check_blown_up) is simulated again with
    cloth let go of the limbs that tear it (SimParams.limb_release = TORN_RELEASE): when the scene leaves
    `limb_release` to the default preset. Off in the paper preset, and when the scene sets it (0 keeps
    the first run and its stop)."""
    sp = scene["simulation"]
    return sp["limb_release"] is None and sp["preset"] != "paper" and not params.limb_release


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


def garment_layers(scene: Scene) -> list[int]:
    """Each garment's cloth collision layer: its `layer`, else its place in the list (earlier = inner)."""
    return [g["layer"] if g.get("layer") is not None else i for i, g in enumerate(scene["garments"])]


def ignored_colliders(scene: Scene, character) -> list[tuple[int, ...]] | None:
    """simulate's ignore_colliders: each garment's `ignore_colliders` as joint indices, or None when
    no garment ignores any."""
    lists = [ignored_joints(g, character) for g in scene["garments"]]
    return lists if any(lists) else None


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
    from stages.input_files import MAX_ASSET_BYTES, file_problem
    problem = file_problem(path, "character file", MAX_ASSET_BYTES)   # stat only: a FIFO is never opened
    if problem:
        raise SceneError(f"{src}: character.path: {problem}: {path}")
    try:
        if c["source"] == "gltf":
            from stages.rig.gltf import load_gltf
            return load_gltf(path, scale=c["scale"], up_axis=c["up_axis"],
                             loop=c["loop"])
        from stages.rig.bvh_character import load_bvh_character
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
        spheres=[sp.name for sp in colliders.spheres], coverage=coverage_ran,
        floor=result is not None and result.params.floor is not None))


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
              keep_partial: Path | None = None, keep_diverged: Path | None = None,
              background_compile: bool = False) -> RunSummary:
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
    keep_diverged: where the recording of a run whose cloth diverged goes (every stage logged, the
    simulation up to the end when the cloth blew up by strain or distance, the blueprint; the message
    names the file); other failures leave no file.
    background_compile: on a first run (empty numba cache), compile the sewing, simulation and
    cloth audit kernels in a second process while the earlier stages run (pipeline.kernel_warmup).
    """
    from pipeline import where
    from pipeline.kernel_cache import compile_note
    from pipeline.progress import Progress

    out = Path(output) if output is not None else scene.output
    times = frame_times(scene, frames)
    meshes = preflight(scene, output, create=True, output_flag=output is not None, export=export)
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

    ran: list[str] = []   # the stages announced: their kernels are compiled once the run ends (mark_ran)

    def say(name: str, *more: str) -> None:
        ran.extend((name, *more))
        where.stage(name)
        note = compile_note(name, *more) if progress else None
        announce(f"{name} ({note})" if note else name)

    def bar(label: str, unit: str) -> Progress:   # a stage's progress(done, total) callback
        return Progress(1, label, unit=unit, enabled=progress)

    warm = background_warmup(scene, background_compile)
    from stages.sim import SimulationDiverged
    keep, keep_on = (keep_partial, (BaseException,)) if keep_partial is not None else (keep_diverged, (SimulationDiverged,))
    try:
        return _run_stages(scene, out, times, meshes, formats, export_dir, summary, announce, state, ran, say, bar,
                           warm, keep, keep_on, progress, deterministic)
    except SimulationDiverged as exc:
        if keep is not None and keep_partial is None and Path(keep).is_file():
            exc.args = (f"{exc.args[0] if exc.args else exc}; the recording of what was simulated: {keep}",)
        raise


def _run_stages(scene, out, times, meshes, formats, export_dir, summary, announce, state, ran, say, bar, warm, keep,
                keep_on, progress, deterministic):
    """run_scene's stages inside the recording (see run_scene)."""
    from pipeline import logs, style, where
    from pipeline.kernel_cache import mark_ran
    from pipeline.progress import Progress
    from pipeline.recording import atomic_recording
    from stages.jit import numba_threads
    from stages.rig.skinning import skin
    s = scene.settings
    blown = None
    # every stage's parallel kernels run on simulation.threads threads (1: their serial variants,
    # compiled several times faster: stages.jit)
    with atomic_recording(out, scene_name=scene.name, scene_text=scene.text, seed=s["seed"],
                          keep_failed=keep, keep_on=keep_on) as rec, numba_threads(s["simulation"]["threads"]), warm:
        if warm.started:
            announce(f"simulation kernels (compiling in a second process, first run only: about "
                     f"{warm.estimate_s:.0f} s on 2 cores)")
        say("rig")
        with StageTimer(summary, "rig") as r:
            with where.item(character_item(scene)):
                character = load_character(scene)
            check_references(scene, character)
            motion = sample_scene_motion(scene, character, times)
            check_memory(scene, len(motion.times), character.vertices.shape[0], 0)   # before the body is skinned
            warn_notes(scene)   # implausible values: once the checks before the stages passed
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
        with StageTimer(summary, "colliders") as r:
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
            with StageTimer(summary, "coverage") as r:
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
        with StageTimer(summary, "maps") as r:
            maps = build_maps(colliders, kind=m["type"], n_theta=m["n_theta"], n_phi=m["n_phi"], n_axial=m["n_axial"])
            r.sizes.update(maps=len(maps.maps))
        summary.tables["map cells"] = logs.log_maps(rec, character, motion, maps)

        coverage_ran = "collider coverage" in summary.tables
        obstacles, garments, builds, result = None, [], {}, None
        if s["obstacles"]:
            say("obstacles")
            with StageTimer(summary, "obstacles") as r:
                obstacles = build_scene_obstacles(scene, float(times[-1] - times[0]), meshes)
                r.sizes.update(obstacles=len(obstacles.obstacles), triangles=obstacles.triangles.shape[0],
                               tree_nodes=obstacles.tree.node_min.shape[0])
            logs.log_obstacles(rec, obstacles, times)

        if s["garments"]:
            if not warm.simulation_ready():   # sewing is the first stage to call the simulation's kernels
                where.stage("garments")
                ran.append("garments")
                announce(f"garments (waiting for the simulation kernels compiling in a second process: "
                         f"about {warm.seconds_left():.0f} s more)")
                warm.wait_simulation()
            else:
                warm.wait_simulation()
                say("garments")
            with StageTimer(summary, "garments") as r:
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
            params = motion_floor(scene, params, skinned, motion.root_translation)
            if note:
                import warnings
                warnings.warn(note, stacklevel=1)
            check_memory(scene, len(times), character.vertices.shape[0], sum(g.n_particles for g in garments))
            say("simulation", *(("cloth collision",) if params.cloth_collision else ()))

            def simulated(params, label):
                bar = Progress(len(times), label, enabled=progress)
                try:
                    return simulate(character, motion, colliders, maps, garments, params, obstacles=obstacles,
                                    layers=garment_layers(scene), ignore_colliders=ignored_colliders(scene, character),
                                    partial=state.setdefault("sim", {}),
                                    progress=lambda done, total: bar.update(done), threads=sp["threads"])
                finally:
                    bar.close()
            with StageTimer(summary, "simulation") as r:
                result = state["result"] = simulated(params, "simulation")
                # strain and distance: a fast particle is caught in the step
                blown = check_blown_up(result, skinned + motion.root_translation[:, None, :], height, garments)
                if blown is not None and torn_release(scene, params):   # torn by a limb: again, letting go
                    import warnings
                    warnings.warn(f"{blown.args[0].replace('simulation diverged', 'cloth torn', 1)}: simulated again, "
                                  f"cloth a limb stretches over {TORN_RELEASE * 100:.0f} % let go of it "
                                  "(simulation.limb_release)", stacklevel=1)
                    params = dataclasses.replace(params, limb_release=TORN_RELEASE)
                    result = state["result"] = simulated(params, "simulation (again, letting go of torn cloth)")
                    blown = check_blown_up(result, skinned + motion.root_translation[:, None, :], height, garments)
                    if blown is not None:    # the stop says the second run did not help either
                        blown.args = (f"{blown.args[0]} (in a second run too, cloth a limb stretched over "
                                      f"{TORN_RELEASE * 100:.0f} % let go of it)",)
                r.sizes.update(steps=result.steps)
            if blown is not None:   # logged to the end (what tore it is in the recording), then raised
                cause = torn_by(blown, garments, result, colliders, character, motion,
                                ignored=ignored_colliders(scene, character))
                if cause:
                    blown.args = (f"{blown.args[0]}; {cause}",)
                logs.log_text(rec, "meta/diverged", str(blown))
            for note in (speed_limit_note(result), release_note(result)):
                if note:
                    import warnings
                    warnings.warn(note, stacklevel=1)
            audit, held = None, ()
            if sp["cloth_audit"]:
                if warm.running():   # its kernels compile in the second process while the run simulates
                    where.stage("cloth audit")
                    ran.append("cloth audit")
                    announce("cloth audit (waiting for its kernels compiling in a second process)")
                    warm.wait()
                else:
                    warm.wait()
                    say("cloth audit")
                import warnings

                from stages.sim.audit import audit_cloth
                with StageTimer(summary, "cloth audit") as r:
                    audit = audit_cloth(result, garments, vertex_strain=sp["strain_colors"])
                    r.sizes.update(exact_pairs=audit.exact_pairs)
                state["audit"] = audit
                held = strain_source_notes(audit, garments, result, colliders, character, motion)
                for w in audit.warnings + held:
                    warnings.warn(w, stacklevel=1)
            summary.penetrations = logs.log_sim(rec, motion, garments, result, audit, held)
            if params.floor is not None:   # under the body over every frame and the cloth
                body = (skinned + motion.root_translation[:, None, :]).reshape(-1, 3)
                logs.log_floor(rec, params.floor, np.concatenate([body] + [t.positions.reshape(-1, 3) for t in result.garments]))
            from pipeline.export import run_uvs
            logs.log_uvs(rec, run_uvs(scene, result, builds, meshes))
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
        if blown is not None:
            where.stage("simulation")
            raise blown
    summary.output = out
    mark_ran(*ran)
    if formats:
        where.stage("export")
        from pipeline.export import export_run
        summary.exports = export_run(scene, out, motion, skinned, character, result, builds, formats, export_dir,
                                     meshes=meshes)
    return summary
