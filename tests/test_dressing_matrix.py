"""The dressing matrix (`python -m pipeline matrix`): every garment kind on every character, each pair
dressed, sewn and simulated as `run` does, and checked against the pass criteria of
pipeline.matrix (seams closed, nothing inside the colliders after frame 0, <= 0.5 % inside the
body, waistband / collar within 2 cm of the skin, above the floor).

Marked `matrix` (about 2-3 minutes): `python -m pytest -m "not matrix"` skips it. Pairs known to fail
today are xfails with the measured reason (`-rxX` lists them; a fixed one shows as XPASS).
"""
from __future__ import annotations

import pytest

from pipeline import matrix

pytestmark = pytest.mark.matrix

# (character, kind) -> what fails today (python -m pipeline matrix, 30 frames, 2026-11-24, skinned
# balls as the flexible colliders)
KNOWN: dict = {
    # since bend_stiffness 0.2 (2026-11-24 night): the skirt is 80 % of waist-to-floor long, measured from
    # the waist, but sits at skirt_top, 16 cm lower on CesiumMan: its hem lies on the floor from frame 0
    # (-1.8 cm), and the softer cloth hangs 0.8 cm below it at frame 11 (just above it at bend 1).
    # Measured from skirt_top the pattern is 0.6228 m long and a side seam pair at the left hip, placed
    # 2.1 mm apart, opens to 5.2 mm while sewing (0.60 / 0.6224 / 0.63 / 0.66 m close, 10-12 cm above the
    # floor): not fixed yet.
    ("CesiumMan", "long_skirt"): "hem 0.8 cm below the floor at frame 11 (length measured from the waist, "
                                 "worn 16 cm lower)",
}

_prepared: dict = {}


def _pair_scene(character: str, kind: str, frames: int = 30):
    from pipeline.scene import parse_scene_text
    base = matrix.characters()[character] % frames + "colliders: {report_every: 0}\n"
    return base, parse_scene_text(base + f"garments: [{{type: pattern, name: {kind}, kind: {kind}}}]\n",
                                  source=f"matrix:{character}:{kind}")


def _params():
    out = []
    for character in matrix.characters():
        for kind in matrix.KINDS:
            marks = [pytest.mark.xfail(reason=KNOWN[(character, kind)], strict=False)] \
                if (character, kind) in KNOWN else []
            out.append(pytest.param(character, kind, marks=marks, id=f"{character}-{kind}"))
    return out


@pytest.mark.parametrize("character,kind", _params())
def test_garment_dresses_the_character(character, kind, request):
    from pipeline.scene import parse_scene_text
    if matrix.needed_asset(matrix.characters()[character]) is not None:
        request.getfixturevalue("assets_dir")    # skips (or fails under GARMENT_REQUIRE_ASSETS=1) without
    base, scene = _pair_scene(character, kind)
    if character not in _prepared:
        _prepared[character] = matrix.Prepared(parse_scene_text(base, source=f"matrix:{character}"))
    r = matrix.run_pair(_prepared[character], scene)
    assert r["status"] == "ok", f"{character} x {kind}: {r['status']} ({matrix.row_figures(r)})"
