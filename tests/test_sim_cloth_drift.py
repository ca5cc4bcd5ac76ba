"""The offset phase's drift test (stages.sim.cloth_contact.drift): equal to its plain-Python reference,
and sound: whenever it passes, no pair the query left unlisted (features at least the radius apart)
has two vertices whose displacements differ by as much as the pair's distance (property test)."""
from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings, strategies as st

from stages.sim.cloth_contact import drift as DR
from stages.sim.cloth_contact import proximity as PX
from stages.sim.cloth_contact.bench import grid_sheet
from stages.sim.cloth_contact.setup import mesh_edges


def _drift(x, xq, t, radius):
    dr = DR.drift_state(x.shape[0])
    DR.drift_build(xq, t, radius, dr)
    return DR.ratio(x, xq, dr)


def _sheet(seed, n=5, bend=0.3):
    """A small sheet, bent and jittered (a few vertices far from flat)."""
    rng = np.random.default_rng(seed)
    x, t = grid_sheet(n, n, 0.08, 0.08)
    x = np.asarray(x, np.float64)
    x[:, 1] += bend * np.sin(6.0 * x[:, 0]) * 0.05 + rng.normal(0.0, 0.003, x.shape[0])
    return x, np.ascontiguousarray(t, np.int32)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), scale=st.floats(1e-4, 0.02), turn=st.floats(0.0, 0.5))
def test_drift_matches_reference_and_is_sound(seed, scale, turn):
    xq, t = _sheet(seed)
    rng = np.random.default_rng(seed + 1)
    c, s = np.cos(turn), np.sin(turn)
    rot = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    # a motion of the whole (turned and carried) plus a random deformation of `scale`
    x = xq @ rot.T + rng.normal(0.0, 1.0, 3) + rng.normal(0.0, scale, xq.shape)
    radius = 0.006
    got = _drift(x, xq, t, radius)
    assert np.isclose(got, DR.reference_ratio(x, xq, t, radius), rtol=1e-12, atol=0.0)
    if got >= 1.0:
        return
    edges, _, _ = mesh_edges(t)
    listed = PX.brute_force_pairs(xq, t, edges, radius)
    d = x - xq
    for v in range(xq.shape[0]):        # every unlisted vertex-facet pair
        for tri in t:
            a, b, c_ = (int(i) for i in tri)
            if v in (a, b, c_) or (PX.KIND_VF, (v, a, b, c_)) in listed:
                continue
            dist = PX._ref_point_triangle(xq[v], xq[a], xq[b], xq[c_])
            assert max(np.linalg.norm(d[v] - d[k]) for k in (a, b, c_)) < dist


def test_rigid_motion_passes_and_tearing_fails():
    xq, t = _sheet(3)
    dr = DR.drift_state(xq.shape[0])
    DR.drift_build(xq, t, 0.006, dr)
    c, s = np.cos(0.3), np.sin(0.3)
    moved = xq @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T + [0.5, -2.0, 1.0]
    assert DR.ratio(xq + 0.3, xq, dr) < 1e-9         # carried: no drift (rounding only)
    assert DR.ratio(moved, xq, dr) > 0.0             # turned: drift grows with the distance apart
    torn = xq.copy()
    torn[0] += [0.0, 0.01, 0.0]                      # one vertex 1 cm off its neighbours (radius 6 mm)
    assert DR.ratio(torn, xq, dr) > 1.0
