"""Pattern garments once on a real rig (CesiumMan): a short skirt sized to its colliders sews,
clear of the body."""
import numpy as np
import pytest

from stages.garments.library import library_pattern, make_garment
from stages.garments.measurements import garment_measurements
from stages.geometry.mesh import boundary_loops


def test_short_skirt_sews_on_cesium_man(assets_dir):
    from stages.hulls import fit_colliders
    from stages.maps.build import build_maps
    from stages.rig.gltf import load_gltf
    from stages.rig.regions import split_regions
    from stages.rig.skinning import rest_motion, skin
    from stages.geometry.winding import winding_number
    c = load_gltf(assets_dir / "CesiumMan.glb")
    m = rest_motion(c, 2, 1.0 / 30.0)
    cols = fit_colliders(c, split_regions(c, threshold=0.55), delta=0.01, min_triangles=40, max_offset=0.02)
    meas = garment_measurements(c, cols, m)
    p = library_pattern("short_skirt", meas, edge_length=0.03)
    g, log, build = make_garment(p, c, m, cols, build_maps(cols))
    assert log.converged and log.gap_max[-1] <= 0.004
    body = skin(c, m, frames=[0])[0]
    assert np.all(winding_number(body, c.triangles, g.positions) < 0.5)
    assert len(boundary_loops(g.triangles)) == 2 and g.attached.size > 0
    # the skirt's hip girth covers the body's hips plus what the colliders need
    front = p.panel("front")
    hip = 4 * front.edges[front.edge_index("side_l_lo")].points[0][0]
    assert hip >= max(meas["hips"], meas["clear_skirt"]) - 1e-9
