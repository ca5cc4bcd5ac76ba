"""What each stage puts in the recording. Stages stay unaware of Rerun; these functions read
their output dataclasses and log them.

Conventions: timelines `frame` (sequence) and `sim_time` (duration, s); static data static;
per-frame meshes send only positions and normals as columns against static triangles and colours.
Everything is shown in the world frame: relative-frame data gets `Motion.root_translation` added.
"""
from __future__ import annotations

import numpy as np
import rerun as rr

from pipeline import style
from stages.rig.skinning import vertex_normals
from stages.rig.types import Character, Motion, RegionSplit


def palette(n: int, seed: int = 7) -> np.ndarray:
    """(n, 4) uint8 distinct, deterministic colours (golden-ratio hues)."""
    h = (np.arange(n) * 0.618033988749895 + seed * 0.1) % 1.0
    s, v = 0.65, 0.92
    i = np.floor(h * 6).astype(int) % 6
    f = h * 6 - np.floor(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    r = np.choose(i, [v, q, p, p, t, v])
    g = np.choose(i, [t, v, v, q, p, p])
    b = np.choose(i, [p, p, t, v, v, q])
    rgb = (np.stack([r, g, b], 1) * 255).astype(np.uint8)
    return np.column_stack([rgb, np.full(n, 255, np.uint8)])


def time_columns(times: np.ndarray, first_frame: int = 0) -> list:
    return [rr.TimeColumn("frame", sequence=np.arange(first_frame, first_frame + len(times))),
            rr.TimeColumn("sim_time", duration=np.asarray(times, dtype=np.float64))]


def log_mesh_series(rec: rr.RecordingStream, entity: str, triangles: np.ndarray, positions: np.ndarray,
                    times: np.ndarray, *, colors: np.ndarray | None = None,
                    albedo: tuple | None = None, frame_colors: np.ndarray | None = None) -> None:
    """Static triangles (+ colours), then per-frame positions and normals in one columnar send.

    positions: (F, V, 3) world metres; times: (F,) s; frame_colors: optional (F, V, 4) uint8 RGBA
    per frame (instead of the static colours).
    """
    static = {"triangle_indices": triangles.astype(np.uint32)}
    if colors is not None:
        static["vertex_colors"] = colors
    if albedo is not None:
        static["albedo_factor"] = albedo
    rec.log(entity, rr.Mesh3D.from_fields(**static), static=True)
    f, v = positions.shape[:2]
    normals = vertex_normals(positions.astype(np.float64), triangles)
    per_frame = {} if frame_colors is None else {"vertex_colors": frame_colors.reshape(-1, 4).astype(np.uint8)}
    rec.send_columns(entity, indexes=time_columns(times), columns=rr.Mesh3D.columns(
        vertex_positions=positions.reshape(-1, 3).astype(np.float32),
        vertex_normals=normals.reshape(-1, 3).astype(np.float32), **per_frame,
    ).partition(np.full(f, v)))


def log_transform_series(rec: rr.RecordingStream, entity: str, matrices: np.ndarray, times: np.ndarray) -> None:
    """Per-frame (F, 4, 4) transforms (rotation part must be orthonormal for the viewer)."""
    rec.send_columns(entity, indexes=time_columns(times), columns=rr.Transform3D.columns(
        translation=matrices[:, :3, 3].astype(np.float32),
        mat3x3=matrices[:, :3, :3].astype(np.float32),
    ))


def log_scalar_series(rec: rr.RecordingStream, entity: str, values: np.ndarray, times: np.ndarray,
                      *, name: str, color=(230, 80, 60)) -> None:
    rec.log(entity, rr.SeriesLines(names=name, colors=[color]), static=True)
    rec.send_columns(entity, indexes=time_columns(times),
                     columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)))


def world_joint_matrices(character: Character, motion: Motion) -> np.ndarray:
    """(F, J, 4, 4) world transforms of the bone-local frames (joint globals + root translation)."""
    m = motion.joint_world.copy()
    m[:, :, :3, 3] += motion.root_translation[:, None, :]
    return m


def log_rig(rec: rr.RecordingStream, character: Character, split: RegionSplit, motion: Motion,
            skinned: np.ndarray) -> None:
    """rig/mesh (per frame, neutral skin tone), rig/regions (bind pose, static, coloured by region,
    rig/regions/labels: each rigid region's bone name at its centre), rig/skeleton, rig/joints."""
    n_j = character.n_joints
    colors = palette(n_j)
    region_color = colors[split.region_joint].copy()
    # flexible regions: the joint colour washed towards white, so joints read as bands
    region_color[~split.rigid, :3] = (0.45 * region_color[~split.rigid, :3] + 0.55 * 255).astype(np.uint8)
    world = skinned + motion.root_translation[:, None, :]
    log_mesh_series(rec, "rig/mesh", character.triangles, world, motion.times, albedo=style.SKIN)
    rec.log("rig/regions", rr.Mesh3D(
        vertex_positions=character.vertices.astype(np.float32),
        vertex_normals=vertex_normals(character.vertices, character.triangles).astype(np.float32),
        triangle_indices=character.triangles.astype(np.uint32), vertex_colors=region_color), static=True)
    bones = [j for j in range(n_j) if (split.rigid & (split.region_joint == j)).any()]
    if bones:   # the legend: a label per rigid region, at the region's centre
        centres = np.array([character.vertices[split.rigid & (split.region_joint == j)].mean(0) for j in bones])
        rec.log("rig/regions/labels", rr.Points3D(centres.astype(np.float32), colors=colors[bones], radii=0.01,
                                                  labels=[character.joint_names[j] for j in bones],
                                                  show_labels=True), static=True)
    # skeleton: one segment per parent-child pair; a joint's position is its global transform's origin
    joints = world_joint_matrices(character, motion)[:, :, :3, 3]
    kids = np.flatnonzero(character.parents >= 0)
    segs = np.stack([joints[:, character.parents[kids]], joints[:, kids]], axis=2)  # (F, S, 2, 3)
    f, s = segs.shape[:2]
    rec.log("rig/skeleton", rr.LineStrips3D.from_fields(colors=[(250, 210, 60, 255)], radii=[0.006]), static=True)
    rec.send_columns("rig/skeleton", indexes=time_columns(motion.times),
                     columns=rr.LineStrips3D.columns(strips=list(segs.reshape(-1, 2, 3).astype(np.float32))).partition(np.full(f, s)))
    rec.log("rig/joints", rr.Points3D.from_fields(colors=colors, radii=[0.012], labels=list(character.joint_names),
                                                  show_labels=False), static=True)
    rec.send_columns("rig/joints", indexes=time_columns(motion.times),
                     columns=rr.Points3D.columns(positions=joints.reshape(-1, 3).astype(np.float32)).partition(np.full(f, n_j)))


def log_text(rec: rr.RecordingStream, entity: str, markdown: str) -> None:
    rec.log(entity, rr.TextDocument(markdown, media_type="text/markdown"), static=True)


def _convex_mesh(rec, entity: str, mesh, color) -> None:
    rec.log(entity, rr.Mesh3D(vertex_positions=mesh.vertices.astype(np.float32),
                              vertex_normals=vertex_normals(mesh.vertices, mesh.faces).astype(np.float32),
                              triangle_indices=mesh.faces.astype(np.uint32), albedo_factor=color), static=True)


def _log_balls(rec: rr.RecordingStream, character: Character, motion: Motion, colliders, colors) -> None:
    """The skinned balls as one ellipsoid batch per frame (their centres move with the skin), in the
    relative frame like the body."""
    b = colliders.balls
    centers = b.centers(character.inverse_bind, motion.joint_world) + motion.root_translation[:, None, :]  # (F, B, 3) world
    half = np.repeat(b.radius[:, None], 3, axis=1).astype(np.float32)
    col = np.array([(*(int(x) for x in colors[j][:3]), 120) for j in b.joint], np.uint8)
    rec.log("colliders/balls", rr.Ellipsoids3D.from_fields(half_sizes=half, colors=col, fill_mode="solid"), static=True)
    nf, nb = centers.shape[:2]
    rec.send_columns("colliders/balls", indexes=time_columns(motion.times), columns=rr.Ellipsoids3D.columns(
        centers=centers.reshape(-1, 3).astype(np.float32)).partition(np.full(nf, nb)))


def log_colliders(rec: rr.RecordingStream, character: Character, motion: Motion, colliders) -> str:
    """Hulls (raw / inflated / simplified) and spheres in bone frames under per-frame transforms.

    Returns the fit report as a markdown table (the caller logs it at colliders/report, with the
    coverage table when there is one).
    """
    world = world_joint_matrices(character, motion)
    colors = palette(character.n_joints)
    rows = ["| collider | faces raw / inflated / simplified | volume raw (cm³) | excess (cm³) | Hausdorff (mm) | contains | worst violation (mm) |",
            "| --- | --- | ---: | ---: | ---: | --- | ---: |"]
    for h in colliders.hulls:
        base = f"colliders/hulls/{h.name}"
        log_transform_series(rec, base, world[:, h.bone], motion.times)
        c = tuple(int(x) for x in colors[h.bone][:3])
        _convex_mesh(rec, f"{base}/raw", h.raw, (*c, 90))
        _convex_mesh(rec, f"{base}/inflated", h.inflated, (*c, 60))
        _convex_mesh(rec, f"{base}/simplified", h.simplified, (*c, 200))
        if h.kind != "swept":   # rigid hulls carry their bone's name (swept ones share its colour)
            rec.log(f"{base}/label", rr.Points3D([h.simplified.vertices.mean(0).astype(np.float32)], radii=0.004,
                                                 colors=[(*c, 255)], labels=[h.name], show_labels=True), static=True)
        # the region's vertices in the bind pose (region_points add the bone's core and, for a
        # swept hull, every pose)
        ib = character.inverse_bind[h.bone]
        pts = character.vertices[h.region_vertices] @ ib[:3, :3].T + ib[:3, 3]
        rec.log(f"{base}/region", rr.Points3D(pts.astype(np.float32), radii=0.003,
                                              colors=[(40, 40, 40, 255)]), static=True)
        r = h.report
        rows.append(f"| {h.name}{' (swept)' if h.kind == 'swept' else ''} | {r.faces_raw} / {r.faces_inflated} / {r.faces_simplified} | "
                    f"{r.volume_raw * 1e6:.1f} | {r.excess_volume * 1e6:.1f} | {r.hausdorff * 1e3:.2f} | "
                    f"{'yes' if r.contains_region else 'NO'} | {r.worst_violation * 1e3:.3f} |")
    if colliders.balls is not None and colliders.balls.radius.size:
        _log_balls(rec, character, motion, colliders, colors)
    for sp in (s for s in colliders.spheres if s.frame < 0):
        base = f"colliders/spheres/{sp.name}"
        log_transform_series(rec, base, world[:, sp.joint], motion.times)
        c = tuple(int(x) for x in colors[sp.joint][:3])
        rec.log(base + "/sphere", rr.Ellipsoids3D(centers=[sp.center], half_sizes=[[sp.radius] * 3],
                                                  colors=[(*c, 120)], fill_mode="solid"), static=True)
        rec.log(base + "/region", rr.Points3D(sp.region_points.astype(np.float32), radii=0.003,
                                              colors=[(90, 90, 90, 255)]), static=True)
    reps = [h.report for h in colliders.hulls]
    if reps:
        rows.append(f"| **total ({len(reps)} hulls, {len(colliders.spheres)} spheres)** | "
                    f"{sum(r.faces_raw for r in reps)} / {sum(r.faces_inflated for r in reps)} / "
                    f"{sum(r.faces_simplified for r in reps)} | {sum(r.volume_raw for r in reps) * 1e6:.1f} | "
                    f"{sum(r.excess_volume for r in reps) * 1e6:.1f} | {max(r.hausdorff for r in reps) * 1e3:.2f} | "
                    f"{'yes' if all(r.contains_region for r in reps) else 'NO'} | "
                    f"{max(r.worst_violation for r in reps) * 1e3:.3f} |")
    table = "\n".join(rows)
    if colliders.notes:
        table += "\n\n" + "\n".join(f"- {n}" for n in colliders.notes)
    return table


def coverage_table(coverage) -> str:
    """Markdown: per sampled frame and per collider, coverage / excess / shell (stages.coverage)."""
    t = coverage.totals()
    rows = [f"worst of {t['frames']} sampled frames: coverage {t['coverage_min'] * 100:.2f} %, excess p50 "
            f"{t['excess_p50'] * 100:.1f} / p95 {t['excess_p95'] * 100:.1f} / max {t['excess_max'] * 100:.1f} cm, "
            f"shell {t['shell_share'] * 100:.0f} % of the body volume, skin out of every collider "
            f"{t['skin_exposed'] * 100:.2f} % of its points ({t['interior_samples_min']}+ body samples per "
            f"frame, grid cell {coverage.cell * 1000:.1f} mm, {coverage.surface_samples} collider-surface samples)", "",
            "| frame | coverage (%) | excess p50 / p95 / max (cm) | shell (% of body) | skin exposed (%) |",
            "| ---: | ---: | --- | ---: | ---: |"]
    for k, f in enumerate(coverage.frames):
        rows.append(f"| {int(f)} | {coverage.coverage[k] * 100:.2f} | {coverage.excess_p50[k] * 100:.1f} / "
                    f"{coverage.excess_p95[k] * 100:.1f} / {coverage.excess_max[k] * 100:.1f} | {coverage.shell_share[k] * 100:.0f} | "
                    f"{coverage.skin_exposed[k] * 100:.2f} |")
    rows += ["", "| collider | kind | coverage near it (%) | excess p50 / p95 / max (cm) | shell (% of body) |",
             "| --- | --- | ---: | --- | ---: |"]
    for c in coverage.colliders:
        cov = "–" if np.isnan(c.coverage) else f"{c.coverage * 100:.2f}"
        rows.append(f"| {c.name} | {c.kind} | {cov} | {c.excess_p50 * 100:.1f} / {c.excess_p95 * 100:.1f} / "
                    f"{c.excess_max * 100:.1f} | {c.shell_share * 100:.1f} |")
    return "\n".join(rows)


def log_coverage(rec: rr.RecordingStream, motion: Motion, coverage, fit_table: str) -> str:
    """colliders/report (fit table + coverage table) and colliders/fit/* series at the sampled frames."""
    table = coverage_table(coverage)
    log_text(rec, "colliders/report", "## Coverage and excess\n\n" + table + "\n\n## Hull fit\n\n" + fit_table)
    index = [rr.TimeColumn("frame", sequence=coverage.frames),
             rr.TimeColumn("sim_time", duration=motion.times[coverage.frames])]
    for key, name, values, color in (
            ("coverage", "coverage (%)", coverage.coverage * 100, (60, 160, 90)),
            ("excess_p95", "excess p95 (cm)", coverage.excess_p95 * 100, (230, 140, 40)),
            ("excess_max", "excess max (cm)", coverage.excess_max * 100, (220, 70, 50)),
            ("shell", "shell (% of body volume)", coverage.shell_share * 100, (90, 110, 200)),
            ("skin_exposed", "skin out of every collider (% of its points)", coverage.skin_exposed * 100, (200, 60, 160))):
        rec.log(f"colliders/fit/{key}", rr.SeriesLines(names=name, colors=[color]), static=True)
        rec.send_columns(f"colliders/fit/{key}", indexes=index, columns=rr.Scalars.columns(scalars=values))
    return table


def ramp(values: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """(N, 4) uint8 colours from blue (lo, default the smallest value) through green to red (hi,
    default the largest; values beyond are clipped)."""
    v = np.asarray(values, dtype=np.float64)
    lo = (v.min() if v.size else 0.0) if lo is None else lo
    hi = (v.max() if v.size else 1.0) if hi is None else hi
    t = np.clip((v - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    r = np.clip(2 * t - 0.5, 0, 1)
    g = np.clip(1.5 - np.abs(2 * t - 1) * 1.5, 0, 1)
    b = np.clip(1.2 - 2 * t, 0, 1)
    return np.column_stack([(np.stack([r, g, b], 1) * 255).astype(np.uint8), np.full(v.size, 255, np.uint8)])


def map_cell_outlines(hm, samples: int = 6) -> list[np.ndarray]:
    """One closed polyline per map cell (bone-local), drawn on a surface just outside the hull."""
    radius = 1.15 * float(np.linalg.norm(hm.half_extents))
    th = np.linspace(0, 2 * np.pi, hm.n_theta + 1)
    sec = np.linspace(hm.second_lo, hm.second_hi, hm.n_second + 1)
    u = np.linspace(0, 1, samples)
    strips = []
    for i in range(hm.n_theta):
        for k in range(hm.n_second):
            t = np.concatenate([th[i] + (th[i + 1] - th[i]) * u, np.full(samples, th[i + 1]),
                                th[i + 1] - (th[i + 1] - th[i]) * u, np.full(samples, th[i])])
            s = np.concatenate([np.full(samples, sec[k]), sec[k] + (sec[k + 1] - sec[k]) * u,
                                np.full(samples, sec[k + 1]), sec[k + 1] - (sec[k + 1] - sec[k]) * u])
            if hm.kind == "cylinder":
                r = 1.15 * float(np.linalg.norm(hm.half_extents[1:]))
                q = np.column_stack([s, r * np.cos(t), r * np.sin(t)])
            else:  # sphere: s is phi from +axis 0
                q = radius * np.column_stack([np.cos(s), np.sin(s) * np.cos(t), np.sin(s) * np.sin(t)])
            strips.append(hm.center + q @ hm.axes)
    return strips


def log_maps(rec: rr.RecordingStream, character: Character, motion: Motion, maps) -> str:
    """OBBs, upper / lower planar meshes and map cells per hull, in bone frames. Returns the
    cell-statistics table (also logged at maps/report)."""
    from scipy.spatial.transform import Rotation
    world = world_joint_matrices(character, motion)
    rows = ["| hull | map | faces | cells | longest list | mean list |", "| --- | --- | ---: | ---: | ---: | ---: |"]
    for hm, bone, name in zip(maps.maps, maps.bones, maps.names):
        base = f"maps/{name}"
        log_transform_series(rec, base, world[:, bone], motion.times)
        quat = Rotation.from_matrix(hm.axes.T).as_quat()  # columns = box axes in bone-local coords
        rec.log(f"{base}/obb", rr.Boxes3D(centers=[hm.center], half_sizes=[hm.half_extents], quaternions=[quat],
                                          colors=[(255, 200, 0, 255)]), static=True)
        for side, faces, color in (("upper", hm.upper_faces, (220, 90, 60, 160)), ("lower", hm.lower_faces, (60, 120, 220, 160))):
            flat = hm.center + np.column_stack([np.zeros(len(hm.planar_vertices)), hm.planar_vertices]) @ hm.axes
            normal = np.broadcast_to(hm.axes[0] * (1 if side == "upper" else -1), flat.shape)
            rec.log(f"{base}/{side}", rr.Mesh3D(vertex_positions=flat.astype(np.float32),
                                                 vertex_normals=normal.astype(np.float32),
                                                 triangle_indices=faces.astype(np.uint32), albedo_factor=color), static=True)
        lengths = hm.cell_lengths
        rec.log(f"{base}/cells", rr.LineStrips3D([s.astype(np.float32) for s in map_cell_outlines(hm)],
                                                  colors=ramp(lengths), radii=0.0015,
                                                  labels=[str(int(n)) for n in lengths], show_labels=False), static=True)
        st = hm.cell_stats
        rows.append(f"| {name} | {hm.kind} {hm.n_theta}×{hm.n_second} | {hm.mesh.faces.shape[0]} | {st['cells']} | "
                    f"{int(lengths.max())} | {lengths.mean():.2f} |")
    table = "\n".join(rows)
    log_text(rec, "maps/report", table)
    return table


STRAIN_RAMP_MAX = 0.10      # per-vertex strain colouring: this strain and above is the top of the ramp


def log_sim(rec: rr.RecordingStream, motion: Motion, garments, result, audit=None, strain_notes=()) -> dict:
    """Cloth meshes (each garment its fabric colour), penetration counts, step time and the
    parameters; with `audit` (a stages.sim.audit.ClothAudit) the strain and crossing series and, when
    it has per-vertex strain, the meshes coloured by it; strain_notes: lines on what holds the
    strained edges (pipeline.cloth_checks.strain_source_notes), into the report. Returns the summary figures."""
    for i, (track, g) in enumerate(zip(result.garments, garments)):
        vs = audit.garments[i].vertex_strain if audit is not None else None
        frame_colors = None
        if vs is not None:
            frame_colors = ramp(vs.ravel(), 0.0, STRAIN_RAMP_MAX).reshape(*vs.shape, 4)
        log_mesh_series(rec, f"sim/{track.name}/mesh", track.triangles, track.positions, result.times,
                        albedo=None if vs is not None else style.fabric(i), frame_colors=frame_colors)
        a = g.attached
        if a.size:   # attached particles: rigid ones dark, yielding ones (see Garment.attach_joint) amber
            path = f"sim/{track.name}/attached"
            rgba = np.where((g.inverse_mass[a] > 0)[:, None], [style.PIN_YIELDING], [style.PIN_RIGID]).astype(np.uint8)
            rec.log(path, rr.Points3D.from_fields(colors=rgba, radii=[style.PIN_RADIUS]), static=True)
            rec.send_columns(path, indexes=time_columns(result.times),
                             columns=rr.Points3D.columns(positions=track.positions[:, a].reshape(-1, 3)).partition(
                                 np.full(len(result.times), a.size)))
    log_scalar_series(rec, "sim/penetrations/colliders", result.penetrations_colliders, result.times,
                      name="inside a collider", color=(230, 80, 60))
    if result.params.pinch != "escape":
        log_scalar_series(rec, "sim/penetrations/pinched", result.pinched, result.times,
                          name="held between two joints' colliders", color=(240, 170, 40))
    if result.params.limb_release and result.released is not None:
        log_scalar_series(rec, "sim/penetrations/released", result.released, result.times,
                          name="let go of a limb that tore the cloth", color=(60, 170, 220))
    audited = bool(result.params.body_audit)
    if audited:
        log_scalar_series(rec, "sim/penetrations/body", result.penetrations_body, result.times,
                          name="inside the body mesh", color=(150, 60, 200))
        log_scalar_series(rec, "sim/penetrations/body_overlap", result.penetrations_body_overlap, result.times,
                          name="inside the body where it meets itself (counted apart)", color=(190, 150, 220))
    # the step time (wall clock) is logged by run_scene under timings/, outside sim/
    log_scalar_series(rec, "sim/contacts/colliders", result.corrected, result.times,
                      name="particles moved by a collider", color=(90, 90, 90))
    if result.contacts_obstacles.any():
        log_scalar_series(rec, "sim/contacts/obstacles", result.contacts_obstacles, result.times,
                          name="obstacle contacts (per frame)", color=(200, 140, 40))
        pts = result.contact_points
        rec.log("sim/contacts/obstacles/points", rr.Points3D.from_fields(colors=[(255, 140, 0, 255)], radii=[0.004]),
                static=True)
        rec.send_columns("sim/contacts/obstacles/points", indexes=time_columns(result.times),
                         columns=rr.Points3D.columns(positions=np.concatenate(pts).reshape(-1, 3)).partition(
                             np.array([len(p) for p in pts])))
    if audit is not None:
        for ga in audit.garments:
            values = np.stack([ga.strain_mean, ga.strain_p99, ga.strain_max], axis=1) * 100.0
            rec.log(f"sim/{ga.name}/strain", rr.SeriesLines(names=[f"{ga.name} {k} (%)" for k in ("mean", "p99", "max")],
                                                             colors=[(60, 120, 220), (230, 150, 40), (220, 60, 60)]),
                    static=True)
            rec.send_columns(f"sim/{ga.name}/strain", indexes=time_columns(result.times),
                             columns=rr.Scalars.columns(scalars=values.ravel()).partition(np.full(len(values), 3)))
            log_scalar_series(rec, f"sim/intersections/{ga.name}", ga.crossings_self, result.times,
                              name=f"{ga.name}: edges through its own triangles", color=(200, 60, 60))
        if len(audit.garments) > 1:
            log_scalar_series(rec, "sim/intersections/between", audit.crossings_between, result.times,
                              name="edges through another garment", color=(160, 40, 160))
    p = result.params
    log_text(rec, "sim/params", "| parameter | value |\n| --- | --- |\n" + "\n".join(
        f"| {k} | {v} |" for k, v in p.__dict__.items()))
    n = sum(t.positions.shape[1] for t in result.garments)
    body = result.penetrations_body
    worst = int(np.argmax(body))
    steps_s = result.steps / max(float(result.step_ms.sum()) * result.params.substeps / 1000, 1e-9)
    out = {
        "particles": n,
        "inside colliders (max / mean per frame, frame 0 excluded)":
            f"{int(result.penetrations_colliders[1:].max(initial=0))} / {float(result.penetrations_colliders[1:].mean()) if len(body) > 1 else 0:.2f}",
        "pinched between two joints' colliders, held in their overlap (max / mean per frame, frame 0 excluded)":
            f"{int(result.pinched[1:].max(initial=0))} / {float(result.pinched[1:].mean()) if len(body) > 1 else 0:.2f}"
            if p.pinch != "escape" else "off (simulation.pinch: escape)",
        "let go of a limb that tore them (particles, sum over the frames / frames)":
            f"{int(result.released.sum())} / {int((result.released > 0).sum())}"
            if p.limb_release and result.released is not None else "off (simulation.limb_release: 0)",
        "inside body (max / mean per frame)": (f"{int(body.max())} / {float(body.mean()):.2f} "
                                               f"({100 * int(body.max()) / max(n, 1):.2f} % of particles, worst frame {worst})")
                                              if audited else "not audited (simulation.body_audit: false)",
        "inside the body where it meets itself, counted apart (max per frame)":
            f"{int(result.penetrations_body_overlap.max(initial=0))}" if audited else "not audited",
        "steps/s (simulation only)": f"{steps_s:.0f}",
    }
    if result.notes:
        out["notes"] = "; ".join(result.notes)
    if strain_notes:
        out["what holds the most strained edges"] = "; ".join(strain_notes)
    cc = result.cloth_contact
    if cc:
        layers = ", ".join(f"{t.name} {l}" for t, l in zip(result.garments, cc.get("layers", ())))
        out["cloth collision (layers; contacts / corrected / reverted / left over the run)"] = (
            f"on, thickness {1000 * p.cloth_thickness:.1f} mm (layers: {layers}); {cc['contacts']} / "
            f"{cc['corrected']} / {cc['reverted']} / {cc['left']}")
        if "offset" in cc:    # the offset phase (the counts above: the layers' sorting before frame 1)
            o = cc["offset"]
            out["cloth collision (layers; contacts / corrected / reverted / left over the run)"] += (
                f"; offset phase: {o['queries']} queries, {o['pairs']} pairs listed, {o['pushed']} pushed, "
                f"{o['held']} particles held back")
    else:
        out["cloth collision (layers; contacts / corrected / reverted / left over the run)"] = "off"
    if audit is not None:
        out.update(audit.summary())
    # wall-clock figures stay out of sim/report so identical runs log identical data there
    log_text(rec, "sim/report", "\n".join(f"- {k}: {v}" for k, v in out.items() if not k.startswith("steps/s")))
    return out


FLOOR_MARGIN = 0.5     # m the floor's square reaches past what stands and hangs over it


def log_floor(rec: rr.RecordingStream, height: float, points: np.ndarray) -> None:
    """floor/mesh: the simulation's floor (SimParams.floor, world height m) as a static square under
    `points` (..., 3) world (the body over every frame and the cloth), FLOOR_MARGIN past them."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    lo, hi = p[:, [0, 2]].min(axis=0) - FLOOR_MARGIN, p[:, [0, 2]].max(axis=0) + FLOOR_MARGIN
    v = np.array([[lo[0], height, lo[1]], [hi[0], height, lo[1]], [hi[0], height, hi[1]], [lo[0], height, hi[1]]],
                 np.float32)
    rec.log("floor/mesh", rr.Mesh3D(vertex_positions=v, vertex_normals=np.tile(np.float32([0, 1, 0]), (4, 1)),
                                    triangle_indices=np.array([[0, 2, 1], [0, 3, 2]], np.uint32),
                                    albedo_factor=style.FLOOR), static=True)


def log_obstacles(rec: rr.RecordingStream, obstacles, times: np.ndarray, *, kdop_depth: int = 3) -> None:
    """obstacles/<name>/mesh static in the body frame (under a per-frame transform when moving),
    and the k-DOP nodes at `kdop_depth` of each static obstacle's tree (boxes for k = 6, wireframes
    otherwise), at obstacles/<name>/kdop."""
    from stages.geometry.kdop import kdop_box, kdop_wireframe
    tree = obstacles.tree
    for i, ob in enumerate(obstacles.obstacles):
        base = f"obstacles/{ob.name}"
        c = style.OBSTACLE[:3]
        rec.log(f"{base}/mesh", rr.Mesh3D(vertex_positions=ob.vertices.astype(np.float32),
                                          vertex_normals=vertex_normals(ob.vertices, ob.triangles).astype(np.float32),
                                          triangle_indices=ob.triangles.astype(np.uint32), albedo_factor=(*c, 255)),
                static=True)
        if not ob.is_static:
            log_transform_series(rec, base, np.stack([ob.pose_at(float(t)) for t in times]), times)
            continue
        lo, hi = tree.tree_offsets[i], tree.tree_offsets[i + 1]
        sub_depth = tree.depth[lo:hi]
        sel = np.arange(lo, hi)[(sub_depth == kdop_depth) | ((sub_depth < kdop_depth) & (tree.leaf_prim[lo:hi] >= 0))]
        mins, maxs = tree.node_min[sel], tree.node_max[sel]
        if tree.directions.shape[0] == 3:
            centres, half = kdop_box(mins, maxs, tree.directions)
            rec.log(f"{base}/kdop", rr.Boxes3D(centers=centres, half_sizes=half, colors=[(*c, 255)]), static=True)
        else:
            segs = [kdop_wireframe(a, b, tree.directions) for a, b in zip(mins, maxs)]
            rec.log(f"{base}/kdop", rr.LineStrips3D([s.astype(np.float32) for g in segs for s in g],
                                                    colors=[(*c, 255)], radii=0.001), static=True)


def log_uvs(rec: rr.RecordingStream, uvs: dict) -> None:
    """sim/<name>/uv: a garment's texture coordinates per corner (pipeline.export.run_uvs), so that
    `export` of the recording writes them as a run's own export does."""
    for name, (uv, uvf) in uvs.items():
        rec.log(f"sim/{name}/uv", rr.AnyValues(texcoords=np.asarray(uv, np.float32).reshape(-1),
                                              texcoord_faces=np.asarray(uvf, np.int32).reshape(-1)), static=True)


def log_sewing(rec: rr.RecordingStream, name: str, log, build, garment, color=style.FABRICS[0]) -> None:
    """garments/<name>/{flat, placed, sewing, sewn}: the pattern's flat panels, the panels wrapped
    around the body, the sewing progress on the `sewing_iteration` timeline, and the sewn mesh."""
    base = f"garments/{name}"
    tri = build.unsewn_triangles
    for part, pos, color in (("flat", build.flat_positions, (240, 200, 120, 255)),
                             ("placed", build.placed_positions, (120, 200, 240, 255))):
        rec.log(f"{base}/{part}", rr.Mesh3D(vertex_positions=pos.astype(np.float32),
                                            vertex_normals=vertex_normals(pos, tri).astype(np.float32),
                                            triangle_indices=tri.astype(np.uint32), albedo_factor=color), static=True)
    rec.log(f"{base}/sewn", rr.Mesh3D(vertex_positions=garment.positions.astype(np.float32),
                                      vertex_normals=vertex_normals(garment.positions, garment.triangles).astype(np.float32),
                                      triangle_indices=garment.triangles.astype(np.uint32),
                                      albedo_factor=color), static=True)
    k = len(log.logged)
    if k:
        it = [rr.TimeColumn("sewing_iteration", sequence=np.asarray(log.logged, np.int64))]
        rec.log(f"{base}/sewing", rr.Mesh3D.from_fields(triangle_indices=log.triangles.astype(np.uint32),
                                                        albedo_factor=color), static=True)
        n = log.positions.shape[1]
        rec.send_columns(f"{base}/sewing", indexes=it, columns=rr.Mesh3D.columns(
            vertex_positions=log.positions.reshape(-1, 3).astype(np.float32),
            vertex_normals=vertex_normals(log.positions.astype(np.float64), log.triangles).reshape(-1, 3).astype(np.float32),
        ).partition(np.full(k, n)))
    steps = [rr.TimeColumn("sewing_iteration", sequence=np.arange(log.gap_max.size, dtype=np.int64))]
    for key, values, color in (("gap_max", log.gap_max, (230, 80, 60)), ("gap_mean", log.gap_mean, (60, 120, 220))):
        rec.log(f"{base}/sewing/{key}", rr.SeriesLines(names=f"seam {key.replace('_', ' ')} (m)", colors=[color]), static=True)
        rec.send_columns(f"{base}/sewing/{key}", indexes=steps, columns=rr.Scalars.columns(scalars=np.asarray(values, np.float64)))
    log_text(rec, f"{base}/report", f"- iterations: {log.iterations}\n- converged: {log.converged}\n"
             f"- final seam gap max / mean: {log.gap_max[-1] * 1000:.2f} / {log.gap_mean[-1] * 1000:.2f} mm\n"
             f"- particles inside a collider after sewing: {log.penetrations}\n"
             + "".join(f"- {n}\n" for n in log.notes))
