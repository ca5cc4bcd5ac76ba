"""The warning a GarmentCode pattern made for another body gets: its shoulders for a top, and the
slide off narrow shoulders (garmentcode_place.mismatch_warning)."""
from __future__ import annotations

import math

from stages.garments.garmentcode_grade import Grade
from stages.garments.garmentcode_place import SLIP_WIDTH, GCBody, mismatch_warning

# GarmentCode's mean_all, as read_body gives it (m)
BODY = GCBody(height=1.72, waist_y=1.07, hips_y=0.86, bust_y=1.20, shoulder_y=1.457, waist=0.84, hips=1.03,
              bust=1.00, shoulder_half=0.1823, arm_angle=math.radians(40), values={}, source="mean_all.yaml")


def character(shoulder_half: float) -> dict:
    """Measurements of a character like BODY but for the shoulders (garment_measurements' keys)."""
    return {"height": BODY.height, "chest": BODY.bust, "waist": BODY.waist, "hips": BODY.hips,
            "shoulder_half": shoulder_half}


def test_a_top_on_narrow_shoulders_is_told_it_slides_off():
    meas = character(0.091)        # CesiumMan: upper-arm joints 18 cm apart
    line = mismatch_warning(BODY, meas, "shirt", Grade.uniform(0.956, 1.0), top=True)
    assert "shoulders 18 cm vs 36 cm (-50 %)" in line
    assert "its shoulders come out 35 cm wide on the character's 18 cm" in line and "pipeline measure" in line
    assert "height" not in line and "bust" not in line          # only what differs


def test_shoulders_within_the_slip_width_are_listed_without_the_hint():
    meas = character(BODY.shoulder_half * 0.9)     # the CMU walk: 34 cm against 36.5
    line = mismatch_warning(BODY, meas, "tee", Grade.uniform(0.87, 1.0), top=True)
    assert "shoulders 33 cm vs 36 cm (-10 %)" in line and "slide off" not in line
    # graded just under the bound: no hint; at it: the hint
    k = SLIP_WIDTH * 0.9
    assert "slide off" not in mismatch_warning(BODY, meas, "tee", Grade.uniform(k - 1e-3, 1.0), top=True)
    assert "slide off" in mismatch_warning(BODY, meas, "tee", Grade.uniform(k + 1e-3, 1.0), top=True)


def test_skirts_and_matching_bodies_say_nothing_of_shoulders():
    narrow = character(0.091)
    assert mismatch_warning(BODY, narrow, "skirt", Grade.uniform(1.0, 1.0)) is None     # not a top
    assert mismatch_warning(BODY, character(BODY.shoulder_half), "shirt", top=True) is None
    assert mismatch_warning(BODY, {k: v for k, v in narrow.items() if k != "shoulder_half"}, "shirt",
                            top=True) is None          # no shoulders measured: nothing said
