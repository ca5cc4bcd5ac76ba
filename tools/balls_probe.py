"""Measure skinned balls (stages/hulls/balls.py) for the flexible regions beside the rigid hulls, as
`python -m pipeline bench coverage` measures collider sets: 60-frame walk, delta 1 cm, every 10th
frame and the last; coverage of a jittered 1.2 cm grid inside the body, excess of union-surface
samples outside the body, shell share. The simulation does not use balls yet (branch work).

    python tools/balls_probe.py CHARACTER [SLACK_M]   # CHARACTER: built-in | CesiumMan | "CMU 131_01 (BVH skin)"
"""
import sys, time, numpy as np
from stages.coverage.bench import characters, MODES
from stages.coverage.measure import SkinDistance, collider_arrays, inside_matrix, surface_samples, ColliderArrays
from stages.coverage import kernels as K
from stages.hulls.fit import fit_character
from stages.hulls.types import ColliderSet
from stages.hulls.balls import fit_balls
from stages.rig.skinning import sample_motion, skin_poses
name = sys.argv[1]; slack = float(sys.argv[2]) if len(sys.argv) > 2 else 0.0075; DELTA = 0.01
ch, clip, start = characters()[name]()
motion = sample_motion(ch, clip, start + np.arange(60) / 30.0)
poses = motion.joint_world; F, J = poses.shape[:2]
regions, cs = fit_character(ch, poses, delta=DELTA, **MODES["default"])
rigid = ColliderSet(hulls=tuple(h for h in cs.hulls if h.kind == "rigid"), spheres=(), delta=cs.delta, min_triangles=cs.min_triangles, flexible=cs.flexible, notes=())
skinned = skin_poses(ch, poses); body = SkinDistance(ch)
t0 = time.time()
balls = fit_balls(ch, regions, poses, skinned, body, delta=DELTA, slack=slack)
print(f"fit {time.time()-t0:.1f} s, balls {balls.radius.size}, unheld {balls.unheld.size}")
cf = balls.centers(ch.inverse_bind, poses)
ra = collider_arrays(rigid); nb = balls.radius.size; R = balls.radius
rng = np.random.default_rng(0); hull_pts, _ = surface_samples(rigid, 0.01, rng); res = []
for f in list(range(0, F, 10)) + [F - 1]:
    arr = ColliderArrays(joint=np.concatenate([ra.joint, J + np.arange(nb)]).astype(np.int32), kind=np.concatenate([ra.kind, np.full(nb, K.KIND_SPHERE)]).astype(np.int32),
        bcenter=np.concatenate([ra.bcenter, np.zeros((nb, 3))]), bradius=np.concatenate([ra.bradius, R * (1 + 1e-9) + 1e-9]),
        plane_start=np.concatenate([ra.plane_start, np.full(nb, ra.plane_start[-1])]), planes=ra.planes,
        sph_center=np.concatenate([ra.sph_center, np.zeros((nb, 3))]), sph_radius=np.concatenate([ra.sph_radius, R]), names=(), kinds=())
    pose = np.concatenate([poses[f], np.repeat(np.eye(4)[None], nb, 0)]); pose[J:, :3, 3] = cf[f]
    V = skinned[f]; body.refit(V); h = 0.012
    grid = np.stack(np.meshgrid(*[np.arange(a, b, h) for a, b in zip(V.min(0) - .03, V.max(0) + .03)], indexing="ij"), -1).reshape(-1, 3)
    grid = grid + (rng.random(grid.shape) - 0.5) * h
    inb = body.inside(grid); incol = inside_matrix(grid, arr, pose).any(1)
    surf = [(p @ pose[arr.joint[i]][:3, :3].T + pose[arr.joint[i]][:3, 3], i) for i, p in enumerate(hull_pts)]
    for i in range(nb):
        n = int(np.clip(4 * np.pi * R[i] ** 2 / 1e-4, 64, 6000)); d = rng.normal(size=(n, 3)); d /= np.linalg.norm(d, axis=1, keepdims=True)
        surf.append((cf[f, i] + R[i] * d, len(hull_pts) + i))
    P = np.concatenate([s for s, _ in surf]); owner = np.concatenate([np.full(len(s), i) for s, i in surf])
    im = inside_matrix(P, arr, pose).astype(bool); im[np.arange(P.shape[0]), owner] = False
    out = ~im.any(1) & ~body.inside(P); dist = body.distance(P[out])
    res.append((incol[inb].mean(), np.percentile(dist, 95), dist.max(), (incol & ~inb).sum() / inb.sum()))
a = np.array(res)
print(f"{name} slack {slack}: balls {nb} + rigid {len(rigid.hulls)}; coverage min {a[:,0].min()*100:.2f} %, p95 {a[:,1].max()*100:.2f}, max {a[:,2].max()*100:.2f} cm, shell {a[:,3].mean()*100:.1f} %")
