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
    # empty since 2026-11-24 late: CesiumMan x long_skirt (hem on the floor, measured from the waist but
    # worn 16 cm lower; measured from there, a side seam pair at a one-edge hip curve stayed open) passes
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
