"""A character's measurements as a GarmentCode body file (`body_measurements.yaml`, the keys of
GarmentCode's assets/bodies/mean_all.yaml; cm and degrees), so that a pattern can be made to
measure for it with GarmentCode and brought back (`python -m pipeline measure`).

Measured on the character (stages.garments.measurements.garment_measurements, bind pose):
height, head_l, waist_line, hips_line, bust_line (levels: the shoulder top, waist, hips and chest
tapes), bust, waist, hips (girths), shoulder_w (between the upper-arm joints), arm_length,
arm_pose_angle, neck_w, leg_circ (thigh). They invert garmentcode_place.read_body's levels exactly:
read back, the body's waist, hips, bust and shoulder levels are the character's.
Estimated: the other keys of the default body, scaled from it (widths and girths by the mean of the
measured girth ratios, lengths by the height ratio, angles kept); listed in the file's `estimated`.
"""
from __future__ import annotations

import math

import numpy as np

MEASURED = ("height", "head_l", "waist_line", "hips_line", "bust_line", "bust", "waist", "hips", "shoulder_w",
            "arm_length", "arm_pose_angle", "neck_w", "leg_circ")
ANGLES = ("hip_inclination", "shoulder_incl")
LENGTHS = ("armscye_depth", "crotch_hip_diff", "vert_bust_line", "waist_over_bust_line")


def gc_body(meas: dict, default: dict, clearance: float = 0.008) -> tuple[dict, list]:
    """({key: value cm / deg}, estimated keys) of a character measured in `meas` (metres, radians;
    garment_measurements without colliders, whose clearance is `clearance`), `default` the
    GarmentCode default body's values (cm, deg)."""
    floor = meas.get("floor_y", 0.0)
    top = floor + meas["height"]
    sh = meas.get("shoulder_top", meas["shoulder_y"] + 0.03 * meas["height"])   # as body_map reads it
    cm = lambda m: round(float(m) * 100.0, 4)
    out = {
        "height": cm(meas["height"]),
        "head_l": cm(top - sh),
        "waist_line": cm(sh - meas["waist_y"]),
        "hips_line": cm(meas["waist_y"] - meas["hips_y"]),
        "bust_line": cm(sh - meas["chest_y"]),
        "bust": cm(meas["chest"]), "waist": cm(meas["waist"]), "hips": cm(meas["hips"]),
        "shoulder_w": cm(2 * meas["shoulder_half"]),
    }
    if np.isfinite(meas.get("arm_length", np.nan)):
        out["arm_length"] = cm(meas["arm_length"])
    if "arm_angle" in meas:
        out["arm_pose_angle"] = round(math.degrees(meas["arm_angle"]), 4)
    if "neck_half" in meas:
        out["neck_w"] = cm(2 * (meas["neck_half"] - clearance))
    if "thigh_radius" in meas:
        out["leg_circ"] = cm(2 * math.pi * (meas["thigh_radius"] - clearance))
    girth = float(np.mean([out[k] / default[k] for k in ("bust", "waist", "hips")]))
    height = out["height"] / default["height"]
    estimated = []
    for k, v in default.items():
        if k in out:
            continue
        out[k] = round(v if k in ANGLES else v * (height if k in LENGTHS else girth), 4)
        estimated.append(k)
    return {k: out[k] for k in sorted(out)}, sorted(estimated)


def body_yaml(values: dict, estimated: list, character: str) -> str:
    """The body file's text: `body:` with the values, and comments naming the character and what
    was estimated."""
    import yaml
    head = (f"# GarmentCode body measurements (cm, degrees) of {character}, written by `python -m pipeline "
            f"measure`.\n# Estimated from GarmentCode's default body (mean_all), not measured: "
            f"{', '.join(estimated) or 'none'}.\n")
    return head + yaml.safe_dump({"body": values}, sort_keys=True)
