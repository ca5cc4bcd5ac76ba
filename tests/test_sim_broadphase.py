"""Collision broad phase (stages.sim.collider_grid.build_grid): the cell lists are conservative, and collide gives the
same answer with them as with every collider as candidate."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from stages.hulls.types import ColliderSet, SphereCollider
from stages.maps.build import build_maps
from stages.maps.kernels import METHOD_NEAREST_PLANE, METHOD_PAPER, collide_points
from stages.sim.body_collide import PINCHED, SCREEN_MAX, collide
from stages.sim.collider_grid import build_grid, GRID_CELLS, swept_spheres
from stages.sim.scenes import convex_mesh, fibonacci_points, hull_set
from tests.test_sim_kernels import _collider_arrays


def _scene(seed, disjoint=False):
    """Four hulls (one elongated, limb-like) and four spheres, each on its own posed bone (rotated,
    moved, one scaled); returns (colliders, maps, fwd (8, 4, 4)). Overlapping, or disjoint: their
    world bounding spheres 1 cm apart along x (no collider can push a particle into another)."""
    rng = np.random.default_rng(seed)
    hulls = []
    for b, ext in enumerate(((0.4, 0.08, 0.07), (0.2, 0.15, 0.1), (0.06, 0.05, 0.04), (0.25, 0.2, 0.2))):
        mesh = convex_mesh(fibonacci_points(40, ext) + rng.normal(0, 0.005, (40, 3)) + rng.uniform(-0.05, 0.05, 3))
        hulls.append(hull_set(mesh, bone=b, name=f"h{b}").hulls[0])
    spheres = tuple(SphereCollider(j, f"s{j}", rng.uniform(-0.2, 0.2, 3), float(rng.uniform(0.04, 0.2)),
                                   np.zeros((0, 3))) for j in range(4, 8))
    cs = ColliderSet(hulls=tuple(hulls), spheres=spheres, delta=0.0, min_triangles=4)
    fwd = np.tile(np.eye(4), (8, 1, 1))
    for j in range(8):
        fwd[j, :3, :3] = Rotation.from_rotvec(rng.normal(0, 1.0, 3)).as_matrix() * (1.3 if j == 3 else 1.0)
        fwd[j, :3, 3] = rng.uniform(-0.15, 0.15, 3)
    if disjoint:
        cursor = 0.0
        for j, (c, r) in enumerate([(h.simplified.vertices.mean(axis=0), h.simplified.vertices) for h in hulls]
                                   + [(q.center, None) for q in spheres]):
            r = np.linalg.norm(r - c, axis=1).max() if r is not None else spheres[j - 4].radius
            r *= 1.3 if j == 3 else 1.0
            w = fwd[j, :3, :3] @ c
            fwd[j, :3, 3] = [cursor + r - w[0], rng.uniform(-0.03, 0.03) - w[1], -w[2]]
            cursor += 2 * r + 0.01
    return cs, build_maps(cs), fwd


def _build(col, method):
    build_grid(col.m, method, col.kind, col.index, col.sph_radius, col.tq, col.fq, col.cw, col.grid_start,
                 col.grid_items, col.grid_runs, col.grid_box, col.grid_dims)


def _cell_of(col, p):
    """Reference lookup: the cell (i, j, k) -> (i n1 + j) n2 + k of int((p - low) / size), -1 off the grid."""
    u = (p - col.grid_box[:3]) * col.grid_box[3]
    n = col.grid_dims
    if not ((u >= 0) & (u < n)).all():
        return -1
    i, j, k = u.astype(np.int64)
    return int((i * n[1] + j) * n[2] + k)


def _inside_matrix(cs, maps, fwd, pts, method):
    """(P, C) bool: point p inside collider c, from the maps stage's query (hulls, bone-local) and
    |p - centre| < r (spheres), collider order hulls then spheres."""
    cols = []
    for h, hull in enumerate(cs.hulls):
        inv = np.linalg.inv(fwd[hull.bone])
        cols.append(collide_points(maps, pts @ inv[:3, :3].T + inv[:3, 3], h, method)[0])
    for s in cs.spheres:
        inv = np.linalg.inv(fwd[s.joint])
        cols.append(np.linalg.norm(pts @ inv[:3, :3].T + inv[:3, 3] - s.center, axis=1) < s.radius)
    return np.stack(cols, axis=1)


def _points(cs, fwd, rng, n):
    """Uniform points around the colliders plus points within 1e-7 of hull vertices and sphere
    surfaces (the cells' borders cut the colliders there), in world."""
    pts = [rng.uniform(-0.8, 0.8, (n, 3))]
    for hull in cs.hulls:
        v = hull.simplified.vertices
        c = v.mean(axis=0)
        for f in (1 - 1e-7, 1 - 1e-3, 0.5):
            loc = c + (v - c) * f
            pts.append(loc @ fwd[hull.bone, :3, :3].T + fwd[hull.bone, :3, 3])
    for s in cs.spheres:
        d = rng.normal(size=(50, 3))
        loc = s.center + d / np.linalg.norm(d, axis=1, keepdims=True) * s.radius * rng.uniform(0.5, 1 - 1e-7, (50, 1))
        pts.append(loc @ fwd[s.joint, :3, :3].T + fwd[s.joint, :3, 3])
    return np.concatenate(pts)


@pytest.mark.parametrize("method", [METHOD_PAPER, METHOD_NEAREST_PLANE])
@pytest.mark.parametrize("seed", range(4))
def test_grid_lists_every_collider_that_holds_a_point(seed, method):
    cs, maps, fwd = _scene(seed)
    col = _collider_arrays(cs, maps, fwd)
    _build(col, method)
    nc = col.joint.size
    n_cells = int(np.prod(col.grid_dims))
    assert 1 <= n_cells <= GRID_CELLS
    start, items = col.grid_start, col.grid_items
    for b in range(n_cells):       # ascending lists, each collider at most once
        assert (np.diff(items[start[b]:start[b + 1]]) > 0).all()
    pts = _points(cs, fwd, np.random.default_rng(100 + seed), 4000)
    inside = _inside_matrix(cs, maps, fwd, pts, method)
    assert inside.any(axis=0).all()          # every collider holds some of the points
    listed = np.zeros_like(inside)
    for p, x in enumerate(pts):
        b = _cell_of(col, x)
        if b >= 0:
            listed[p, items[start[b]:start[b + 1]]] = True
    missed = inside & ~listed
    assert not missed.any(), f"{missed.sum()} point-collider pairs not listed"
    # the lists do prune: a point's cell lists far fewer than all colliders
    assert listed.sum(axis=1).mean() < 0.5 * nc


def _collide_with(col, grid, x, xp, contact, method, passes, friction=0.5, pinch=True):
    out, xp = x.copy(), xp.copy()
    n = x.shape[0]
    corr, ins, sp = np.zeros(n, np.uint8), np.zeros(n, np.uint8), np.zeros(n)
    collide(out, xp, np.ones(n), col.m, method, col.kind, col.index, col.sph_radius, col.tq, col.tq0, col.fq,
              col.cw, *grid, col.face_edges, col.src_range, friction, passes, corr, ins, sp, contact, 1 / 30,
              col.joint, int(pinch), False, col.family)
    return out, xp, corr, ins


def _every_collider(nc):
    """Grid arrays of one cell over all space listing every collider (the brute-force candidates)."""
    return (np.array([0, nc], np.int64), np.arange(nc, dtype=np.int32), np.array([-1e3, -1e3, -1e3, 1 / 2e3]),
            np.ones(3, np.int64))


def _posed(cs, maps, fwd, method):
    inv0 = np.linalg.inv(fwd)
    inv0[:, :3, 3] += 0.01         # the bones moved over the step: friction acts relative to them
    col = _collider_arrays(cs, maps, fwd, inv0)
    _build(col, method)
    return col, (col.grid_start, col.grid_items, col.grid_box, col.grid_dims)


@pytest.mark.parametrize("method", [METHOD_PAPER, METHOD_NEAREST_PLANE])
@pytest.mark.parametrize("seed", range(3))
def test_collide_with_the_grid_equals_every_collider_as_candidate(seed, method):
    """Disjoint colliders sharing cells: the same positions, previous positions, flags and face
    cache (bit for bit) as with every collider listed, twice (the second call with the face cache
    of the first)."""
    cs, maps, fwd = _scene(seed, disjoint=True)
    col, grid = _posed(cs, maps, fwd, method)
    nc = col.joint.size
    assert (np.diff(col.grid_start[:int(np.prod(col.grid_dims)) + 1]) > 1).any()   # cells shared by colliders
    rng = np.random.default_rng(200 + seed)
    x = _points(cs, fwd, rng, 3000)
    xp = x + rng.normal(0, 0.01, x.shape)
    ca = np.full((x.shape[0], nc), -1, np.int32)
    cb = ca.copy()
    for _ in range(2):
        a = _collide_with(col, grid, x, xp, ca, method, passes=4)
        b = _collide_with(col, _every_collider(nc), x, xp, cb, method, passes=4)
        for u, v in zip(a, b):
            assert np.array_equal(u, v)
        assert np.array_equal(ca, cb)
        assert a[2].sum() > 100 and not a[3].any()      # many particles were pushed, none left inside


@pytest.mark.parametrize("seed", range(3))
def test_collide_with_the_grid_leaves_overlapping_colliders(seed):
    """Overlapping colliders: with the grid as with every collider listed, every particle ends
    outside all of them, or (pinch) pinched between two joints' colliders and then inside at least
    one (the visiting budget counts visits, so pinched particles may take other escapes: positions
    are not compared)."""
    cs, maps, fwd = _scene(seed)
    col, grid = _posed(cs, maps, fwd, METHOD_PAPER)
    nc = col.joint.size
    rng = np.random.default_rng(300 + seed)
    x = _points(cs, fwd, rng, 3000)
    for pinch in (False, True):
        for g in (grid, _every_collider(nc)):
            out, _, corr, ins = _collide_with(col, g, x, x, np.full((x.shape[0], nc), -1, np.int32), METHOD_PAPER, 4,
                                              pinch=pinch)
            inside = _inside_matrix(cs, maps, fwd, out, METHOD_PAPER).any(axis=1)
            pinched = ins == PINCHED
            assert corr.sum() > 100 and not (ins == 1).any() and (pinch or not pinched.any())
            assert not inside[~pinched].any() and inside[pinched].all()


@pytest.mark.parametrize("seed", range(3))
def test_a_frames_swept_grid_lists_every_collider_that_holds_a_point_at_any_of_its_steps(seed):
    """The step loop builds one broad phase per frame (stages.sim.step.run_steps): build_grid over the
    spheres swept through the frame's steps (swept_spheres, no query-frame boxes). Its cell lists
    hold every collider that holds a point at any step's pose; each swept sphere holds every step's."""
    cs, maps, fwd0 = _scene(seed)
    rng = np.random.default_rng(300 + seed)
    steps = 5
    fwd = np.empty((steps,) + fwd0.shape)
    for k in range(steps):      # each bone turns and moves a little more at every step
        for j in range(fwd0.shape[0]):
            turn = Rotation.from_rotvec(0.05 * (k + 1) * rng.normal(0, 1.0, 3)).as_matrix()
            fwd[k, j] = fwd0[j]
            fwd[k, j, :3, :3] = turn @ fwd0[j, :3, :3]
            fwd[k, j, :3, 3] = fwd0[j, :3, 3] + 0.02 * (k + 1) * rng.normal(0, 1.0, 3)
    fwd = np.ascontiguousarray(fwd)
    cols = [_collider_arrays(cs, maps, fwd[k]) for k in range(steps)]
    col = cols[0]
    cws = np.zeros_like(col.cw)
    swept_spheres(fwd, 0, steps, col.joint, col.bcenter, col.bradius, cws)
    for c_k in cols:
        assert (np.linalg.norm(c_k.cw[:, :3] - cws[:, :3], axis=1) + c_k.cw[:, 3] <= cws[:, 3]).all()
    build_grid(col.m, METHOD_NEAREST_PLANE, col.kind, col.index, col.sph_radius, col.tq, col.fq, cws, col.grid_start,
               col.grid_items, col.grid_runs, col.grid_box, col.grid_dims)
    start, items = col.grid_start, col.grid_items
    for k in range(steps):
        pts = _points(cs, fwd[k], rng, 1500)
        inside = _inside_matrix(cs, maps, fwd[k], pts, METHOD_PAPER)
        assert inside.any()
        listed = np.zeros_like(inside)
        for p, x in enumerate(pts):
            b = _cell_of(col, x)
            if b >= 0:
                listed[p, items[start[b]:start[b + 1]]] = True
        assert not (inside & ~listed).any()


@pytest.mark.parametrize("method", [METHOD_PAPER, METHOD_NEAREST_PLANE])
@pytest.mark.parametrize("seed", range(3))
def test_screened_collide_equals_the_visiting_loop(seed, method):
    """With at most SCREEN_MAX colliders, collide first screens every particle (_may_hit) and visits
    only those that may be inside one; with one far collider more (no screening) every particle is
    visited. Disjoint colliders (the visiting budget, passes x colliders, is not spent): the same
    positions, previous positions, flags, speeds and face cache, bit for bit, over three calls, each
    from the last one's positions moved a little and with its face cache (remembered exit faces,
    separating faces and the planes of outline rejections)."""
    cs, _, fwd = _scene(seed, disjoint=True)
    few = ColliderSet(hulls=cs.hulls[:2], spheres=cs.spheres[:2], delta=0.0, min_triangles=4)
    far = SphereCollider(7, "far", np.array([100.0, 0.0, 0.0]), 0.1, np.zeros((0, 3)))
    more = ColliderSet(hulls=few.hulls, spheres=few.spheres + (far,), delta=0.0, min_triangles=4)
    maps = build_maps(few)
    (ca, grid_a), (cb, grid_b) = (_posed(s, maps, fwd, method) for s in (few, more))
    nc = ca.joint.size
    assert nc == SCREEN_MAX and cb.joint.size == nc + 1
    rng = np.random.default_rng(400 + seed)
    x = _points(few, fwd, rng, 3000)
    xp = x + rng.normal(0, 0.01, x.shape)
    face_a = np.full((x.shape[0], nc), -1, np.int32)
    face_b = np.full((x.shape[0], nc + 1), -1, np.int32)
    for _ in range(3):
        out = []
        for col, grid, face in ((ca, grid_a, face_a), (cb, grid_b, face_b)):
            o, p = x.copy(), xp.copy()
            corr, ins, speed2 = np.zeros(len(x), np.uint8), np.zeros(len(x), np.uint8), np.zeros(len(x))
            collide(o, p, np.ones(len(x)), col.m, method, col.kind, col.index, col.sph_radius, col.tq, col.tq0, col.fq,
                    col.cw, *grid, col.face_edges, col.src_range, 0.5, 4, corr, ins, speed2, face, 1 / 30,
                    col.joint, 1, False, col.family)
            out.append((o, p, corr, ins, speed2))
        for u, v in zip(*out):
            assert np.array_equal(u, v)
        assert np.array_equal(face_a, face_b[:, :nc]) and (face_b[:, nc] == -1).all()
        assert out[0][2].sum() > 50 and (out[0][2] == 0).sum() > 1000     # pushed and untouched particles
        x, xp = out[0][0] + rng.normal(0, 0.003, x.shape), out[0][0]
    if method == METHOD_PAPER:
        assert (face_a >= 0).any() and (face_a <= -2).any()
