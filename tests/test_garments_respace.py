"""hug.respace: a pinned band's vertices spaced along their hugged polyline as on the pattern."""
import numpy as np
from hypothesis import given, settings, strategies as st

from stages.garments.hug import respace


def _on_polyline(q, p):
    """Distance of each point of q to the polyline p."""
    a, b = p[:-1], p[1:]
    ab = b - a
    out = []
    for x in q:
        t = np.clip(np.einsum("ij,ij->i", x - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0, 1)
        out.append(np.min(np.linalg.norm(a + t[:, None] * ab - x, axis=1)))
    return np.array(out)


@settings(max_examples=60, deadline=None)
@given(st.integers(3, 25), st.integers(0, 2 ** 16))
def test_respace_keeps_the_polyline_and_follows_the_pattern_spacing(k, seed):
    rng = np.random.default_rng(seed)
    p = np.cumsum(rng.uniform(0.002, 0.04, (k, 3)) * rng.choice([-1, 1], (k, 3)), axis=0)
    uv = np.c_[np.cumsum(np.r_[0.0, rng.uniform(0.005, 0.03, k - 1)]), np.zeros(k)]
    q = respace(p, uv)
    np.testing.assert_allclose(q[[0, -1]], p[[0, -1]], atol=1e-12)         # the ends stay
    assert _on_polyline(q, p).max() < 1e-9                                   # on the hugged line
    # arc length along the polyline at each new vertex: proportional to the pattern's
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    f = uv[:, 0] / uv[-1, 0]
    arc = []
    for x in q:
        best = None   # the arc length at x (the first segment holding it)
        for i in range(k - 1):
            d = _on_polyline(x[None], p[i:i + 2])[0]
            if d < 1e-9:
                t = np.linalg.norm(x - p[i])
                best = s[i] + t if best is None else min(best, s[i] + t)
        arc.append(best)
    np.testing.assert_allclose(np.array(arc) / s[-1], f, atol=1e-9)


def test_respace_on_a_straight_line_is_the_pattern_spacing_scaled():
    p = np.c_[np.array([0.0, 0.1, 0.15, 0.5, 0.6]), np.zeros(5), np.zeros(5)]
    uv = np.c_[np.array([0.0, 1.0, 2.0, 3.0, 4.0]), np.zeros(5)]
    np.testing.assert_allclose(respace(p, uv)[:, 0], [0.0, 0.15, 0.3, 0.45, 0.6])
