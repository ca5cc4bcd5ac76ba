"""The simulation stage end to end on small scenes with exact predictions."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stages.garments.simple import rectangle_cloth, tube_skirt
from stages.garments.types import attach_indices, attach_top_loop, bind_pose, build_garment, edge_strain
from stages.maps.build import build_maps
from stages.sim import SimParams, SimulationDiverged, simulate
from stages.sim.scenes import convex_mesh, fibonacci_points, hull_set, sphere_set, toy_character, toy_motion

TRI = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]], np.int32)
TET = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]) * 0.01 - 5.0  # a far-away body (audit)


def _char():
    return toy_character(TET, TRI)


def _cloth(n=12, center=(0, 0.5, 0), size=0.6):
    x, tri = rectangle_cloth(size, size, n, n, center=center)
    return x, tri


@pytest.mark.parametrize("tethers", [False, True])
def test_pinned_cloth_hangs_and_converges(tethers):
    x, tri = rectangle_cloth(0.5, 0.5, 10, 10, center=(0, 1, 0), normal=(0, 0, 1))
    top = np.flatnonzero(np.isclose(x[:, 1], x[:, 1].max()))
    ch, mo = _char(), toy_motion(150)
    g = build_garment("flag", x, tri, attachments=[attach_indices(top, "root")], bind=bind_pose(ch, mo))
    r = simulate(ch, mo, None, None, [g], SimParams(body_audit=False, damping=0.05, tethers=tethers))
    p = r.garments[0].positions
    assert r.max_speed[-1] < 0.05 and np.abs(p[-1] - p[-2]).max() < 2e-3
    assert np.allclose(p[:, top], x[top], atol=1e-6)               # pinned row never moves
    assert p[-1, :, 1].min() < x[:, 1].min() + 0.05                  # it hangs down
    strain = np.abs(edge_strain(g, p[-1].astype(np.float64)))
    if tethers:   # long-range attachments: nothing hangs lower than its rest distance from the top row
        assert strain.max() < 0.05 and p[-1, :, 1].min() >= x[:, 1].min() - 1e-4
    else:         # 3 rounds alone: stretchy, bounded
        assert strain.max() < 0.4 and strain.mean() < 0.12


def test_tethers_reach_every_free_particle_with_its_rest_path_length():
    from stages.sim.simulate import tethers
    x, tri = rectangle_cloth(0.4, 0.3, 5, 4, center=(0, 1, 0), normal=(0, 0, 1))
    top = np.flatnonzero(np.isclose(x[:, 1], x[:, 1].max()))
    ch, mo = _char(), toy_motion(2)
    g = build_garment("flag", x, tri, attachments=[attach_indices(top, "root")], bind=bind_pose(ch, mo))
    ti, ta, tl = tethers([g], np.array([0, g.n_particles]), g.inverse_mass)
    free = np.flatnonzero(g.inverse_mass > 0)
    assert np.array_equal(np.sort(ti), free) and np.isin(ta, top).all()
    # a 5 x 4 grid 0.1 x 0.1 apart with diagonals: the straight column up is the shortest path
    want = x[top, 1].max() - x[ti, 1]
    np.testing.assert_allclose(tl, want, atol=1e-9)
    np.testing.assert_allclose(x[ta, 0], x[ti, 0], atol=1e-9)


def test_cloth_falls_on_sphere_without_penetration():
    ch, mo = _char(), toy_motion(60)
    x, tri = _cloth(14, (0.02, 0.45, 0.01), 0.8)
    g = build_garment("cloth", x, tri)
    cs = sphere_set(radius=0.3)
    r = simulate(ch, mo, cs, None, [g], SimParams(body_audit=False, friction=1.0))
    assert r.corrected.max() > 0
    assert (r.penetrations_colliders == 0).all()
    d = np.linalg.norm(r.garments[0].positions.astype(np.float64), axis=2)
    assert d.min() > 0.3 - 1e-5
    assert r.garments[0].positions[-1, :, 1].max() > 0.25          # friction keeps it on top


def test_hull_collider_and_body_audit_agree_at_rest():
    mesh = convex_mesh(fibonacci_points(40, (0.25, 0.3, 0.2)))
    ch = toy_character(mesh.vertices, mesh.faces)
    cs = hull_set(mesh)
    x, tri = _cloth(12, (0.0, 0.4, 0.0), 0.7)
    r = simulate(ch, toy_motion(40), cs, build_maps(cs), [build_garment("c", x, tri)], SimParams(friction=1.0))
    assert r.corrected.max() > 0
    assert (r.penetrations_colliders == 0).all() and (r.penetrations_body == 0).all()


def test_attachments_follow_their_bone_exactly():
    n = 20
    rots = Rotation.from_euler("y", np.linspace(0, 1.5, n)[:, None]).as_matrix()
    ch, mo = _char(), toy_motion(n, rotations=rots, root_translation=np.linspace(0, 1, n)[:, None] * [1, 0, 0.5])
    x, tri = tube_skirt(0.2, 0.3, 0.4, 12, 5, center=(0.05, 1.0, 0.0))
    g = build_garment("skirt", x, tri, attachments=[attach_top_loop("root")], bind=bind_pose(ch, mo))
    r = simulate(ch, mo, None, None, [g], SimParams(body_audit=False, substeps=2))
    a = g.attached
    want = np.einsum("fij,nj->fni", mo.joint_world[:, 0, :3, :3], g.attach_local[a]) + mo.joint_world[:, 0, None, :3, 3]
    want += mo.root_translation[:, None, :]
    np.testing.assert_allclose(r.garments[0].positions[:, a], want, atol=2e-6)


def test_inertia_scale_zero_vs_one_under_translating_root():
    n = 30
    t = np.arange(n) / 30.0
    root = np.stack([2.0 * t ** 2, 0.3 * np.sin(4 * t), np.zeros(n)], axis=1)   # accelerating root
    ch = _char()
    x, tri = _cloth(8, (0, 1, 0), 0.4)
    g = build_garment("c", x, tri)
    # no damping / air: then a world-space free fall is exactly predictable
    p = SimParams(body_audit=False, drag=0.0, lift=0.0, damping=0.0)
    static = simulate(ch, toy_motion(n), None, None, [g], p).garments[0].positions.astype(np.float64)
    moving = toy_motion(n, root_translation=root)
    rel = simulate(ch, moving, None, None, [g], p).garments[0].positions.astype(np.float64)
    p1 = SimParams(body_audit=False, drag=0.0, lift=0.0, damping=0.0, inertia_scale=1.0)
    world = simulate(ch, moving, None, None, [g], p1).garments[0].positions.astype(np.float64)
    # s = 0: the cloth is carried rigidly by the root translation (paper's relative simulation)
    np.testing.assert_allclose(rel, static + root[:, None, :], atol=1e-5)
    # s = 1: plain world-space simulation: a free cloth ignores how the character moves, except
    # that it starts moving with the root (d_prev = d_next at the first step)
    v0 = root[1] - root[0]
    np.testing.assert_allclose(world, static + v0 * np.arange(n)[:, None, None], atol=1e-4)
    assert np.abs(world - rel).max() > 0.05


def test_divergence_is_detected_and_named():
    ch, mo = _char(), toy_motion(30)
    x, tri = _cloth(6)
    g = build_garment("cloth", x, tri)
    with pytest.raises(SimulationDiverged) as err:
        simulate(ch, mo, None, None, [g], SimParams(body_audit=False, max_speed=1.0, drag=0.0, lift=0.0))
    e = err.value
    assert e.frame == 4 and "frame 4" in str(e) and "cloth#" in str(e)   # 9.81 * 4/30 > 1 m/s
    assert e.partial is not None and e.partial.n_frames == 4
    assert np.isfinite(e.partial.garments[0].positions).all()


def test_two_runs_are_identical():
    mesh = convex_mesh(fibonacci_points(40, (0.25, 0.3, 0.2)))
    ch = toy_character(mesh.vertices, mesh.faces)
    cs = hull_set(mesh)
    maps = build_maps(cs)
    x, tri = _cloth(16, (0.03, 0.4, 0.0), 0.8)
    g = build_garment("c", x, tri)
    p = SimParams(friction=0.8, wind=(1.0, 0.0, 0.5))
    a = simulate(ch, toy_motion(30), cs, maps, [g], p)
    b = simulate(ch, toy_motion(30), cs, maps, [g], p, threads=2)   # parallel loops: same result
    np.testing.assert_array_equal(a.garments[0].positions, b.garments[0].positions)
    np.testing.assert_array_equal(a.penetrations_body, b.penetrations_body)
    np.testing.assert_array_equal(a.corrected, b.corrected)


def test_world_obstacle_catches_the_cloth():
    """Paper B obstacles (world frame) are collided after every step: a cloth falls on a box."""
    from stages.obstacles.primitives import box_mesh, make_obstacle
    from stages.obstacles.stage import build_obstacle_set
    box = make_obstacle("box", box_mesh((0, 0.2, 0), (0.6, 0.4, 0.6)), thickness=0.005, friction=0.5)
    obstacles = build_obstacle_set([box])
    x, tri = _cloth(10, (0.0, 0.55, 0.0), 0.5)
    g = build_garment("c", x, tri)
    r = simulate(_char(), toy_motion(30), None, None, [g], SimParams(body_audit=False, substeps=2),
                 obstacles=obstacles)
    p = r.garments[0].positions
    assert np.isfinite(p).all() and p[-1, :, 1].min() > 0.4 - 1e-3       # resting on the top face
    assert any("obstacles" in n for n in r.notes)


def test_stiffness_and_damping_mean_the_same_at_any_substep_count():
    """Frequency scaling: what is left of a violation after one second of rounds, and of the velocity
    after 1/30 s of steps, does not depend on substeps / iterations; the paper preset is unscaled."""
    left, kept = [], []
    for substeps, iterations in ((1, 3), (10, 1), (20, 1), (7, 4)):
        p = SimParams(substeps=substeps, iterations=iterations, stretch_stiffness=0.6, damping=0.02)
        rounds_per_s = iterations * substeps / p.dt
        left.append((1 - p.round_stiffness(0.6)) ** rounds_per_s)
        kept.append((1 - p.step_damping()) ** substeps)
    np.testing.assert_allclose(left, left[0], rtol=1e-9)
    np.testing.assert_allclose(kept, 0.98, rtol=1e-12)
    paper = SimParams.preset("paper")
    assert paper.round_stiffness(1.0) == 1.0 and paper.step_damping() == paper.damping
    assert SimParams().round_stiffness(1.0) == 1.0 and SimParams().round_stiffness(0.0) == 0.0


def test_chunk_poses_of_translation_only_frames_equal_the_general_path():
    """Skinned balls' frames (translation only, after the joints) take a shortcut in chunk_poses
    (lerp, negated translation): the same matrices, bit for bit, as interpolating and inverting
    every frame the general way, for one and for many sub-steps."""
    import importlib
    from types import SimpleNamespace
    S = importlib.import_module("stages.sim.poses")
    rng = np.random.default_rng(5)
    from scipy.spatial.transform import Rotation
    f, j, b = 6, 3, 5
    jw = np.zeros((f, j + b, 4, 4))
    jw[..., 3, 3] = 1.0
    jw[:, :j, :3, :3] = Rotation.random(f * j, random_state=2).as_matrix().reshape(f, j, 3, 3)
    jw[:, j:, :3, :3] = np.eye(3)
    jw[..., :3, 3] = rng.normal(size=(f, j + b, 3))
    motion = SimpleNamespace(joint_world=jw, root_translation=np.zeros((f, 3)))
    assert S.shift_tail(jw) == j
    for substeps in (1, 4):
        fwd, inv, inv0, *_ = S.chunk_poses(motion, 2, 6, substeps, 1.0, None)
        parts = [S.frame_poses(jw, k, substeps) for k in range(2, 6)]
        for got, want in zip((fwd, inv, inv0), (np.concatenate([p[i] for p in parts]) for i in range(3))):
            assert np.array_equal(got, want)


def test_aero_forces_held_over_a_time_span():
    """SimParams.aero_interval: the aerodynamic forces computed once per span of steps (a divisor of
    substeps, stated in time) and held; a cloth blown by wind moves nearly as with forces every step."""
    assert SimParams(aero_interval=0.0).aero_steps() == 1
    assert SimParams(aero_interval=1 / 150).aero_steps() == 4              # 20 sub-steps of 1/600 s
    assert SimParams(substeps=15, aero_interval=1 / 150).aero_steps() == 3
    assert SimParams(substeps=7, aero_interval=1 / 30).aero_steps() == 7
    assert SimParams.preset("paper").aero_steps() == 1
    assert SimParams.preset("paper", aero_interval=1 / 150).aero_steps() == 1   # one step is longer
    x, tri = rectangle_cloth(0.5, 0.5, 10, 10, center=(0, 1, 0), normal=(0, 0, 1))
    top = np.flatnonzero(np.isclose(x[:, 1], x[:, 1].max()))
    ch, mo = _char(), toy_motion(20)
    g = build_garment("flag", x, tri, attachments=[attach_indices(top, "root")], bind=bind_pose(ch, mo))
    base = dict(body_audit=False, wind=(2.0, 0.0, 3.0), drag=1.0, lift=0.3)
    every, held, again, still = (simulate(ch, mo, None, None, [g], SimParams(**{**base, **kw})) for kw in (
        {"aero_interval": 0.0}, {"aero_interval": 1 / 150}, {"aero_interval": 1 / 150},
        {"aero_interval": 0.0, "wind": (0.0, 0.0, 0.0)}))
    a, b, c = (r.garments[0].positions[-1] for r in (every, held, still))
    np.testing.assert_array_equal(b, again.garments[0].positions[-1])       # deterministic
    blown = np.abs(a - c).max()
    assert blown > 0.02                                                     # the wind moves the cloth
    assert np.abs(a - b).max() < 0.05 * blown


def test_worn_garment_settles_before_frame_0_and_a_blow_up_there_names_its_particles():
    """settle_frames: an attached sheet hangs (damped, then at rest) before frame 0 is recorded; a
    free one is recorded where it was put. Cloth that blows up while settling is a divergence at
    frame 0 naming the particles (not an internal error)."""
    from dataclasses import replace as dc_replace
    from stages.garments.simple import rectangle_cloth
    from stages.garments.types import attach_indices, bind_pose, build_garment
    from stages.sim import SimParams, SimulationDiverged, simulate
    from stages.sim.scenes import toy_character, toy_motion
    x, t = rectangle_cloth(0.2, 0.2, 6, 6, center=(0.0, 1.0, 0.0), normal=(0.0, 1.0, 0.0))   # flat
    ch = toy_character(np.zeros((0, 3)), np.zeros((0, 3), np.int32))
    motion = toy_motion(3)
    top = list(np.flatnonzero(x[:, 0] < x[:, 0].min() + 1e-9))     # held along one edge: it swings down
    worn = build_garment("worn", x, t, attachments=[attach_indices(top)], bind=bind_pose(ch, motion))
    free = build_garment("free", x, t)
    p = SimParams(body_audit=False, substeps=4, settle_frames=5)
    r = simulate(ch, motion, None, None, [worn], p)
    r0 = simulate(ch, motion, None, None, [worn], dc_replace(p, settle_frames=0))
    hang0, hang1 = r.garments[0].positions[0], r0.garments[0].positions[0]
    assert hang0[:, 1].min() < hang1[:, 1].min() - 0.02        # it had swung down before frame 0
    np.testing.assert_allclose(simulate(ch, motion, None, None, [free], p).garments[0].positions[0], x, atol=1e-6)
    with pytest.raises(SimulationDiverged) as err:
        simulate(ch, motion, None, None, [worn], dc_replace(p, max_speed=1e-3))
    assert err.value.frame == 0 and err.value.particles.size > 0 and err.value.partial is None
