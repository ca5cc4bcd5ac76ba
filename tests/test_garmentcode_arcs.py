"""A GarmentCode arc graded onto another body (stages.garments.garmentcode.map_panel_points): the
circle through its mapped ends and midpoint, or, on the grading's second try, the cubic fitted to the
mapped arc."""
from __future__ import annotations

import numpy as np

from stages.garments.garmentcode import edge_points, parse_pattern
from tests.test_garmentcode import _panel, _spec


def test_a_graded_arc_is_the_mapped_arc():
    """With exact_arcs (the grading's second try, when a panel's graded circles cross its other edges),
    graded by a similarity an arc stays a circle; graded x1.42 across and x0.39 up (a chibi) it is
    a cubic through its mapped ends within 1 % of its chord of the mapped arc everywhere (the circle
    through the mapped ends and midpoint is 2.8 % of the chord off it here; on the male chibi it took
    a hoodie's back panel across its own other edges)."""
    from stages.garments.garmentcode import map_panel_points
    gc = parse_pattern(_spec({"p": _panel([[0, 0], [40, 0], [40, -60], [0, -60]], {"type": "circle", "params": [25, 0, 1]})}))
    p = gc.panels[0]
    e = p.edges[0]
    t = np.linspace(0, 1, 201)
    for kx, ky, kind in ((0.8, 0.8, "circle"), (1.42, 0.39, "cubic")):
        def f(x):
            return x * np.array([kx, ky, kx])
        q = map_panel_points(p, f, exact_arcs=True)
        assert q.edges[0].kind == kind
        assert map_panel_points(p, f).edges[0].kind == "circle"
        want = (p.to_3d(edge_points(p, e, t)) * [kx, ky, kx] - f(np.asarray(p.translation)[None])[0]) @ q.rotation
        got = edge_points(q, q.edges[0], t)
        chord = np.linalg.norm(want[-1, :2] - want[0, :2])
        assert np.abs(got - want[:, :2]).max() < 0.01 * chord
        assert np.abs(want[:, 2]).max() < 1e-12      # an upright panel keeps its plane
