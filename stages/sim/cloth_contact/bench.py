"""A small Verlet mass-spring cloth that calls the cloth contact phase every step, for the tests and
the benchmark (not the production step loop, which is stages.sim.step).

    python -m stages.sim.cloth_contact.bench            # time collide_cloth on two layered 40 x 40 sheets
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np
from numba import njit

from stages.sim.cloth_contact import kernels as CK
from stages.sim.cloth_contact.setup import ClothContact, build_cloth_contact, mesh_edges


def grid_sheet(nx: int, nz: int, size_x: float, size_z: float, origin=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """A flat sheet in the x-z plane: positions (nx*nz, 3) float64 m, triangles (2(nx-1)(nz-1), 3) int32
    with normals (b-a) x (c-a) along +y (up)."""
    u, v = np.meshgrid(np.linspace(0.0, size_x, nx), np.linspace(0.0, size_z, nz), indexing="ij")
    x = np.stack([u.ravel(), np.zeros(u.size), v.ravel()], axis=1) + np.asarray(origin, np.float64)
    idx = np.arange(nx * nz).reshape(nx, nz)
    a = idx[:-1, :-1].ravel()
    b = idx[1:, :-1].ravel()
    c = idx[1:, 1:].ravel()
    d = idx[:-1, 1:].ravel()
    # alternate the diagonal so the sheet has no preferred shear direction
    flip = ((np.arange(nx - 1)[:, None] + np.arange(nz - 1)[None, :]) % 2).ravel().astype(bool)
    t1 = np.where(flip[:, None], np.stack([a, c, b], 1), np.stack([a, d, b], 1))
    t2 = np.where(flip[:, None], np.stack([a, d, c], 1), np.stack([b, d, c], 1))
    return x, np.concatenate([t1, t2]).astype(np.int32)


def cloth_springs(x: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stretch springs on every edge plus bending springs across each interior edge (paper A):
    (springs (S, 2) int32, rest lengths (S,) float64 from x)."""
    edges, _, edge_tris = mesh_edges(triangles)
    bend = []
    for e in np.nonzero(edge_tris[:, 1] >= 0)[0]:
        t0, t1 = triangles[edge_tris[e, 0]], triangles[edge_tris[e, 1]]
        o0 = [v for v in t0 if v not in edges[e]][0]
        o1 = [v for v in t1 if v not in edges[e]][0]
        bend.append((min(o0, o1), max(o0, o1)))
    s = np.concatenate([edges, np.array(bend, np.int32).reshape(-1, 2)]).astype(np.int32)
    return s, np.linalg.norm(x[s[:, 0]] - x[s[:, 1]], axis=1)


@njit(cache=True)
def _verlet(x, xp, inv_mass, dt, gravity_y, damping):
    for i in range(x.shape[0]):
        if inv_mass[i] == 0.0:
            continue
        for k in range(3):
            v = x[i, k] - xp[i, k]
            xp[i, k] = x[i, k]
            x[i, k] += damping * v + (gravity_y * dt * dt if k == 1 else 0.0)


@njit(cache=True)
def _springs(x, inv_mass, springs, rest, iterations):
    for _ in range(iterations):
        for s in range(springs.shape[0]):
            i = springs[s, 0]
            j = springs[s, 1]
            w = inv_mass[i] + inv_mass[j]
            if w == 0.0:
                continue
            dx = x[j, 0] - x[i, 0]
            dy = x[j, 1] - x[i, 1]
            dz = x[j, 2] - x[i, 2]
            ln = np.sqrt(dx * dx + dy * dy + dz * dz)
            if ln == 0.0:
                continue
            c = (ln - rest[s]) / (ln * w)
            for k, d in ((0, dx), (1, dy), (2, dz)):
                x[i, k] += inv_mass[i] * c * d
                x[j, k] -= inv_mass[j] * c * d


@njit(cache=True)
def _obstacles(x, xp, sphere_c, sphere_r, ground_y, friction):
    """Push particles out of a sphere (radius <= 0: none) and above the ground plane; friction
    scales the tangential step."""
    for i in range(x.shape[0]):
        if sphere_r > 0.0:
            dx = x[i, 0] - sphere_c[0]
            dy = x[i, 1] - sphere_c[1]
            dz = x[i, 2] - sphere_c[2]
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            if 0.0 < d < sphere_r:
                for k, v in ((0, dx), (1, dy), (2, dz)):
                    x[i, k] = sphere_c[k] + v * sphere_r / d
                    xp[i, k] = x[i, k] - (1.0 - friction) * (x[i, k] - xp[i, k])
        if x[i, 1] < ground_y:
            x[i, 1] = ground_y
            xp[i, 0] = x[i, 0] - (1.0 - friction) * (x[i, 0] - xp[i, 0])
            xp[i, 2] = x[i, 2] - (1.0 - friction) * (x[i, 2] - xp[i, 2])


class SheetSim:
    """Verlet mass-spring cloth (unit masses) with a sphere, a ground plane and the cloth contact
    phase last in every step, so the step's end state is what the contact phase checked."""

    def __init__(self, x: np.ndarray, triangles: np.ndarray, garment_offsets, layers=None, dt: float = 1 / 300,
                 thickness: float = 0.004, sphere=None, ground_y: float = -1e9, contact: bool = True,
                 iterations: int = 8, **contact_kw):
        self.x = np.ascontiguousarray(x, np.float64).copy()
        self.xp = self.x.copy()
        self.x_start = self.x.copy()
        self.inv_mass = np.ones(self.x.shape[0])
        self.triangles = np.ascontiguousarray(triangles, np.int32)
        self.springs, self.rest = cloth_springs(self.x, self.triangles)
        self.dt = dt
        self.iterations = iterations
        self.sphere_c = np.zeros(3) if sphere is None else np.asarray(sphere[0], np.float64)
        self.sphere_r = -1.0 if sphere is None else float(sphere[1])
        self.ground_y = ground_y
        self.cc: ClothContact | None = None
        if contact:
            self.cc = build_cloth_contact(self.x, self.triangles, garment_offsets, layers, thickness=thickness,
                                          **contact_kw)
            self.args = self.cc.kernel_args()
        self.counters = np.zeros(CK.N_COUNTERS, np.int64)
        self.contact_seconds = 0.0
        self.contact_calls = 0

    def step(self):
        self.x_start[:] = self.x
        _verlet(self.x, self.xp, self.inv_mass, self.dt, -9.81, 0.99)
        _springs(self.x, self.inv_mass, self.springs, self.rest, self.iterations)
        _obstacles(self.x, self.xp, self.sphere_c, self.sphere_r, self.ground_y, 0.5)
        if self.cc is not None:
            t0 = time.process_time()  # CPU time: the machine is shared
            CK.collide_cloth(self.x_start, self.x, self.inv_mass, *self.args, self.counters)
            self.contact_seconds += time.process_time() - t0
            self.contact_calls += 1


def layered_sheets(n: int = 40, size: float = 1.0, gap: float = 0.01, height: float = 0.5):
    """Two n x n sheets, the upper (layer 1) `gap` above the lower (layer 0), centred over the origin."""
    xa, ta = grid_sheet(n, n, size, size, (-size / 2, height, -size / 2))
    xb, tb = grid_sheet(n, n, size * 0.999, size * 0.999, (-size / 2, height + gap, -size / 2))
    x = np.concatenate([xa, xb])
    t = np.concatenate([ta, tb + xa.shape[0]])
    return x, t, [0, xa.shape[0], x.shape[0]]


def run_benchmark(n: int = 40, steps: int = 300, substeps: int = 10, warm: int = 150) -> dict:
    """Two layered n x n sheets (2 n^2 particles) dropped on a sphere: the time of one collide_cloth
    call once per sub-step (dt = 1/300 s) and once per frame (swept over `substeps` sub-steps).
    Times are CPU seconds of this process (the machine is shared). Returns and prints calls/s, with
    the load average."""
    x, t, off = layered_sheets(n)
    sim = SheetSim(x, t, off, layers=[0, 1], sphere=((0.0, 0.0, 0.0), 0.3), thickness=0.004)
    for _ in range(warm):  # settle into contact (the sheets fall onto the sphere), compile
        sim.step()
    sim.counters[:] = 0
    sim.contact_seconds = 0.0
    sim.contact_calls = 0
    for _ in range(steps):
        sim.step()
    per_step = sim.contact_seconds / sim.contact_calls
    c_step = sim.counters.copy()
    # once per frame: sub-steps without contact, then one swept call from the frame's start
    sim_f = SheetSim(sim.x, t, off, layers=[0, 1], sphere=((0.0, 0.0, 0.0), 0.3), thickness=0.004)
    sim_f.xp[:] = sim.xp
    frame_s = 0.0
    frames = steps // substeps
    counters = np.zeros(CK.N_COUNTERS, np.int64)
    for _ in range(frames):
        x0 = sim_f.x.copy()
        cc, sim_f.cc = sim_f.cc, None
        for _ in range(substeps):
            sim_f.step()
        sim_f.cc = cc
        x_before = sim_f.x.copy()
        t0 = time.process_time()
        CK.collide_cloth(x0, sim_f.x, sim_f.inv_mass, *sim_f.args, counters)
        frame_s += time.process_time() - t0
        CK.contact_velocity(x_before, sim_f.x, sim_f.xp, sim_f.cc.corrected)
    res = {"particles": x.shape[0], "triangles": t.shape[0], "per_substep_ms": 1e3 * per_step,
           "per_substep_calls_s": 1.0 / per_step, "per_frame_ms": 1e3 * frame_s / frames,
           "per_frame_calls_s": frames / frame_s, "load": os.getloadavg()[0],
           "contacts_per_substep": c_step[CK.N_CONTACTS] / steps,
           "rounds_per_substep": c_step[CK.N_ROUNDS] / steps,
           "reverted_per_substep": c_step[CK.N_REVERTED] / steps,
           "contacts_per_frame": counters[CK.N_CONTACTS] / frames,
           "reverted_per_frame": counters[CK.N_REVERTED] / frames,
           "node_pairs_per_substep": c_step[CK.N_NODE_PAIRS] / steps, "tests_per_substep": c_step[CK.N_TESTS] / steps,
           "node_pairs_per_frame": counters[CK.N_NODE_PAIRS] / frames, "tests_per_frame": counters[CK.N_TESTS] / frames}
    print(f"cloth contact, {res['particles']} particles / {res['triangles']} triangles (two layered {n} x {n} "
          f"sheets on a sphere), load average {res['load']:.2f} on {os.cpu_count()} cores")
    print(f"  once per sub-step : {res['per_substep_ms']:.3f} ms/call (CPU) = {res['per_substep_calls_s']:.0f} calls/s; "
          f"per call {res['contacts_per_substep']:.0f} contacts, {res['rounds_per_substep']:.2f} rounds, "
          f"{res['node_pairs_per_substep']:.0f} node pairs, {res['tests_per_substep']:.0f} exact tests, "
          f"{res['reverted_per_substep']:.2f} reverted")
    print(f"  once per frame    : {res['per_frame_ms']:.3f} ms/call (CPU) = {res['per_frame_calls_s']:.0f} calls/s; "
          f"per call {res['contacts_per_frame']:.0f} contacts, {res['node_pairs_per_frame']:.0f} node pairs, "
          f"{res['tests_per_frame']:.0f} exact tests, {res['reverted_per_frame']:.2f} reverted")
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40, help="sheet resolution (particles per side)")
    ap.add_argument("--steps", type=int, default=300)
    a = ap.parse_args(argv)
    run_benchmark(a.n, a.steps)


if __name__ == "__main__":
    main()
