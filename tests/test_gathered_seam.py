"""Gathered seams: a side longer than the other is gathered onto it (gather.gathered_rest), so the
seam closes without the cloth passing through itself."""
import numpy as np
import pytest

from stages.garments.patterns import Edge, Panel, Pattern, Placement, Seam, SeamSide
from stages.garments.gather import GATHER_BAND, gathered_rest
from stages.garments.sewing import SewParams, sew
from stages.garments.triangulate import triangulate_pattern
from tests.test_garments_sewing import scene  # noqa: F401  (the built-in character, module scope)


def rect(name, w, h):
    return Panel(name, (Edge("bottom", "line", ((w, 0.0),)), Edge("right", "line", ((w, h),)),
                        Edge("top", "line", ((0.0, h),)), Edge("left", "line", ((0.0, 0.0),))), Placement("plane"))

def crossings(x, t):
    from stages.sim.audit import crossing_flags
    e = np.unique(np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1), axis=0)
    own, _, _ = crossing_flags(x, e, np.zeros(len(e), np.int32), t, np.zeros(len(t), np.int32))
    return int(own.sum())

def sew_panels(scene, gather: bool, tolerance: float = 0.002):
    """A 40 cm edge sewn to a 25 cm edge (1.6x: the sampled tee's armholes are 1.69x) on two flat
    panels held upright in front of the built-in character: (SewingLog, cloth edges through cloth)."""
    c, m, cols, maps, body = scene
    pat = Pattern("g", (rect("long", 0.40, 0.20), rect("short", 0.25, 0.20)),
                  (Seam(SeamSide("long", "top"), SeamSide("short", "bottom"), reverse=True),), 0.025)
    flat = triangulate_pattern(pat)
    uv, tri = flat.uv, flat.triangles
    rest = np.linalg.norm(uv[tri[:, [1, 2, 0]]] - uv[tri], axis=2)
    if gather:
        rest, ratios = gathered_rest(tri, uv, flat.seam_pairs, flat.seam_index, flat.panel_of_vertex)
        assert abs(ratios[0] - 1.6) < 0.01
    pv = flat.panel_of_vertex
    # upright in front of the body (z = 0.8 m), the short panel above the long, centred, a 6 cm gap
    x = np.c_[uv[:, 0] - np.where(pv == 0, 0.20, 0.125), 0.9 + uv[:, 1] + np.where(pv == 1, 0.26, 0.0), np.full(len(uv), 0.8)]
    sewn, log = sew("g", x, tri, rest, flat.seam_pairs, c, m, cols, maps, SewParams(tolerance=tolerance))
    return log, crossings(sewn, tri)


def test_a_gathered_seam_closes_without_crossings(scene):
    # held flat in the air, the gathered band cannot curve as on a body: 3.7 mm open at most
    log, crossed = sew_panels(scene, gather=True, tolerance=SewParams().tolerance)
    assert log.converged and log.gap_max[-1] <= SewParams().tolerance
    assert crossed == 0


def test_without_easing_the_same_seam_stays_open(scene):
    # the reference: seam springs alone stall against the longer panel's own springs (24.8 mm with
    # stiff bend springs; 4.5 mm once the stalled sewing softens them, still open)
    log, _ = sew_panels(scene, gather=False)
    assert not log.converged and log.gap_max[-1] > 2 * 0.002


def test_gathering_keeps_the_far_side_as_it_was():
    pat = Pattern("g", (rect("long", 0.40, 0.20), rect("short", 0.25, 0.20)),
                  (Seam(SeamSide("long", "top"), SeamSide("short", "bottom"), reverse=True),), 0.025)
    flat = triangulate_pattern(pat)
    uv, tri, pairs = flat.uv, flat.triangles, flat.seam_pairs
    before = np.linalg.norm(uv[tri[:, [1, 2, 0]]] - uv[tri], axis=2)
    rest, ratios = gathered_rest(tri, uv, pairs, flat.seam_index, flat.panel_of_vertex)
    # the eased edge is as long as the other side, segment for segment within a few per cent
    long_side = np.linalg.norm(np.diff(uv[pairs[:, 0]], axis=0), axis=1)
    short_side = np.linalg.norm(np.diff(uv[pairs[:, 1]], axis=0), axis=1)
    assert long_side.sum() == pytest.approx(1.6 * short_side.sum(), rel=0.01)
    e = {tuple(sorted(k)): r for t, rr in zip(tri, rest) for k, r in zip(((t[0], t[1]), (t[1], t[2]), (t[2], t[0])), rr)}
    eased = sum(e[tuple(sorted((int(a), int(b))))] for a, b in zip(pairs[:-1, 0], pairs[1:, 0]))
    assert eased == pytest.approx(short_side.sum(), rel=0.02)
    # every triangle still a triangle, the short panel and the cloth farther than the band from the
    # edge unchanged
    l0, l1, l2 = rest.T
    assert np.all(l0 + l1 > l2) and np.all(l1 + l2 > l0) and np.all(l2 + l0 > l1)
    far = (flat.panel_of_triangle == 1) | (uv[tri][:, :, 1].max(axis=1) < 0.20 - GATHER_BAND - 1e-9)
    assert far.sum() > 0
    assert np.allclose(rest[far], before[far])
    # equal sides: nothing eased
    same = Pattern("g", (rect("a", 0.30, 0.20), rect("b", 0.30, 0.20)),
                   (Seam(SeamSide("a", "top"), SeamSide("b", "bottom"), reverse=True),), 0.025)
    f2 = triangulate_pattern(same)
    r2, ratios2 = gathered_rest(f2.triangles, f2.uv, f2.seam_pairs, f2.seam_index, f2.panel_of_vertex)
    assert ratios2 == {} and np.allclose(r2, np.linalg.norm(f2.uv[f2.triangles[:, [1, 2, 0]]] - f2.uv[f2.triangles], axis=2))
