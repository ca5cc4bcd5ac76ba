"""check_blown_up: cloth that blew up by strain or distance (with the speed limit on it cannot go
fast) is labelled diverged, on a synthetic track against a brute-force reading of the bounds."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from pipeline.cloth_checks import FAR_MIN, MAX_STRAIN, ClothBlewUp, check_blown_up
from stages.sim import SimulationDiverged

SHEET = np.array([[0.0, 1.0, 0.0], [0.1, 1.0, 0.0], [0.0, 1.0, 0.1], [0.1, 1.0, 0.1]])
TRI = np.array([[0, 1, 2], [1, 3, 2]])
BODY = np.zeros((4, 5, 3)) + np.array([[0.0, 0.0, 0.0], [0.3, 1.7, 0.2], [0.1, 0.5, 0.1], [-0.3, 0.2, -0.2],
                                       [0.0, 1.0, 0.0]])


def _result(frames):
    track = SimpleNamespace(name="sheet", positions=np.stack(frames), triangles=TRI)
    return SimpleNamespace(garments=[track])


def test_a_quiet_sheet_passes():
    assert check_blown_up(_result([SHEET] * 4), BODY, 1.7) is None


def test_an_edge_stretched_past_the_bound_is_diverged_at_its_first_frame():
    stretched = SHEET.copy()
    stretched[3] += [0.1 * (MAX_STRAIN + 1.5), 0.0, 0.0]      # edge 1-3 (0.1 m) becomes ~0.66 m long
    err = check_blown_up(_result([SHEET, SHEET, stretched, stretched]), BODY, 1.7)
    assert isinstance(err, ClothBlewUp) and isinstance(err, SimulationDiverged)
    assert err.frame == 2 and err.garment_names == ("sheet",)
    assert "stretched" in str(err) and "frame 2" in str(err) and "'sheet'" in str(err)
    barely = SHEET.copy()
    barely[3] += [0.1 * (MAX_STRAIN - 0.5) * 0.5, 0.0, 0.0]   # well under the bound
    assert check_blown_up(_result([SHEET, barely, barely, barely]), BODY, 1.7) is None


def test_a_particle_far_from_the_body_is_diverged():
    fallen = SHEET.copy()
    fallen[:, 1] -= 78.0            # the dt: 1 run: 78 m below the floor, at modest strain
    err = check_blown_up(_result([SHEET, SHEET, SHEET, fallen]), BODY, 1.7)
    assert err is not None and err.frame == 3 and "m from the body" in str(err)
    near = SHEET.copy()
    near[:, 1] -= FAR_MIN * 0.5     # under the bound (max(5 m, 5 heights))
    assert check_blown_up(_result([SHEET, near, near, near]), BODY, 1.7) is None
