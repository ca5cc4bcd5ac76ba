"""The fit figures a user checks (stages.garments.fit): the waistband / collar's distance to the skin,
or to a garment worn under it; the hem above the floor; the share inside the body."""
from types import SimpleNamespace

import numpy as np
import pytest

from stages.garments.fit import FIT_GAP_MAX, garment_fit


@pytest.fixture(scope="module")
def body():
    from stages.rig.procedural import BodyParams, procedural_character
    from stages.rig.skinning import vertex_normals
    c = procedural_character(BodyParams())
    v = np.asarray(c.vertices, np.float64)
    return c, v, vertex_normals(v, c.triangles)


def _track(positions, inside_body):
    return SimpleNamespace(name="band", positions=positions[None].astype(np.float32),
                           penetrations_body=np.array([inside_body]))


def test_fit_gap_is_the_signed_distance_to_the_skin(body):
    """Points 1.5 cm out along the skin's normals at the torso measure 1.5 cm (a smooth skin: the
    nearest skin point is the one they left); 1 cm in, -1 cm; the floor clearance is the lowest point."""
    c, v, n = body
    rng = np.random.default_rng(3)
    torso = np.flatnonzero((v[:, 1] > 1.0) & (v[:, 1] < 1.2) & (np.abs(v[:, 0]) < 0.1) & (n[:, 2] > 0.9))
    k = rng.choice(torso, 40, replace=False)
    out = v[k] + 0.015 * n[k]
    f = garment_fit(c, v, out, np.arange(40), _track(out, 0), floor_y=0.0)
    assert f.fit_gap.shape == (40,) and abs(f.fit_gap_median - 0.015) < 0.002
    assert np.isclose(f.floor_clearance[0], out[:, 1].min(), atol=1e-6) and f.body_share[0] == 0
    inner = v[k] - 0.01 * n[k]
    g = garment_fit(c, v, inner, np.arange(40), _track(inner, 40), floor_y=0.0)
    assert abs(g.fit_gap_median + 0.01) < 0.002 and g.body_share[0] == 1.0
    assert any("inside the body" in w for w in g.warnings(after_frame=0))


def test_a_band_over_another_garment_is_measured_to_it(body):
    """A band 4 cm off the skin worn over a shirt 3.5 cm off it: 4 cm to the skin (a warning), 5 mm
    to what it is worn over; points under the band's surface that are farther do not count."""
    c, v, n = body
    torso = np.flatnonzero((v[:, 1] > 1.0) & (v[:, 1] < 1.2) & (np.abs(v[:, 0]) < 0.1) & (n[:, 2] > 0.9))[:30]
    band = v[torso] + 0.04 * n[torso]
    shirt = np.concatenate([v[torso] + 0.035 * n[torso], v[torso] + 0.2 * n[torso]])
    alone = garment_fit(c, v, band, np.arange(len(band)), _track(band, 0), floor_y=0.0)
    over = garment_fit(c, v, band, np.arange(len(band)), _track(band, 0), floor_y=0.0, under=shirt)
    assert alone.fit_gap_median > FIT_GAP_MAX and any("from the skin" in w for w in alone.warnings())
    assert np.allclose(over.fit_gap, 0.005, atol=1e-6) and not over.warnings()
