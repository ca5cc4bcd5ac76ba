"""Scene files: the YAML schema, loading with line/column marks, and path resolution.

`load_scene(path)` returns a `Scene`: the validated, default-filled settings plus where they came
from. Relative paths inside the file resolve against the scene file's folder.
"""
from __future__ import annotations

import difflib
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from pipeline.fabric import check_material, resolve_fabrics
from pipeline.schema import REQUIRED, Field, SceneError, plausible, validate

# bounds of positions, speeds and angles: far past any scene, short of sizes that overflow the kernels
POS = Field("float", lo=-1e4, hi=1e4)          # m
SPEED = Field("float", lo=-1e3, hi=1e3)        # m/s (rad/s)
ANGLE = Field("float", lo=-3600.0, hi=3600.0)  # degrees
V3 = Field("vec3", [0.0, 0.0, 0.0], "centre, m", item=POS)


def _pin_fields():
    return {
        "indices": Field("list", None, "particle indices to pin", item=Field("int", lo=0, hi=10_000_000)),
        "collider": Field("str", None, "joint name: pin particles near this joint's collider (bind pose)"),
        "within": Field("float", 0.03, "distance (m) to the collider surface / joint for `collider`", lo=0.0, hi=1.0),
        "boundary": Field("str", None, "pin the whole top boundary loop, to one bone: the collider's, else the common ancestor of the nearest colliders' bones", choices=("top",)),
    }


def _check_pin(p):
    if p is None:
        return None
    if p["indices"] is None and p["collider"] is None and p["boundary"] is None:
        return "expected at least one of 'indices', 'collider' or 'boundary'"
    return None


PIN = Field("section", None, "particles with inverse mass 0, attached to a bone", fields=_pin_fields(), check=_check_pin)

_GARMENT_COMMON = {
    "name": Field("str", None, "garment name (entity path sim/<name>); default: the pattern's kind, else the file's "
                  "name, else the type, numbered from _2 when repeated"),
    "density": Field("float", None, "area density, kg/m^2 (default: the material's, else 0.2)", lo=0.0, lo_open=True,
                     hi=100.0, warn=plausible(0.02, 2.0, "cloth weighs 0.05-0.6 kg/m^2")),
    "material": Field("any", None, "fabric: cotton, denim, jersey, silk, wool or leather, or {file: a GarmentCode "
                      "simulator settings file}; sets density, stretch_stiffness and bend_stiffness unless the "
                      "garment gives them", check=check_material),
    "stretch_stiffness": Field("float", None, "this garment's share of a stretch correction per round at 300 "
                               "rounds/s (default: the material's, else simulation.stretch_stiffness)",
                               lo=0.0, lo_open=True, hi=1.0),
    "bend_stiffness": Field("float", None, "this garment's share of a bend correction per round at 300 rounds/s "
                            "(default: the material's, else simulation.bend_stiffness)", lo=0.0, hi=1.0),
    "pin": PIN,
    "layer": Field("int", None, "cloth collision layer, 0 = innermost; default: the garment's place in the "
                   "list (earlier = inner); garments of a higher layer are kept outside lower ones", lo=0, hi=1000),
    "ignore_colliders": Field("list", [], "joint names whose colliders never push this garment: limbs the animation "
                              "swings through it (a hand brushing the hips); the cloth then passes through them "
                              "(counted by the body audit)", item=Field("str")),
}

GARMENT = Field("union", REQUIRED, "a garment", check=lambda g: _check_garment(g), variants={
    "rectangle": {
        **_GARMENT_COMMON,
        "width": Field("float", 1.0, "size along the cloth's first axis, m", lo=0.0, lo_open=True, hi=100.0),
        "height": Field("float", 1.0, "size along the cloth's second axis, m", lo=0.0, lo_open=True, hi=100.0),
        "resolution": Field("list", [50, 50], "particles along each axis [nx, ny]", item=Field("int", lo=2, hi=1000), length=2),
        "center": Field("vec3", [0.0, 1.0, 0.0], "centre, m, relative frame at frame 0", item=POS),
        "normal": Field("str", "y", "axis the cloth faces", choices=("x", "y", "z")),
    },
    "tube": {
        **_GARMENT_COMMON,
        "radius_top": Field("float", 0.18, "m", lo=0.0, lo_open=True, hi=10.0),
        "radius_bottom": Field("float", 0.30, "m", lo=0.0, lo_open=True, hi=10.0),
        "length": Field("float", 0.45, "m", lo=0.0, lo_open=True, hi=10.0),
        "n_around": Field("int", 48, "particles around", lo=6, hi=2000),
        "n_down": Field("int", 24, "particle rings top to bottom", lo=2, hi=2000),
        "at_joint": Field("str", None, "centre the tube top at this joint (bind pose)"),
        "center": Field("vec3", None, "top centre, m (instead of at_joint)", item=POS),
        "offset": Field("vec3", [0.0, 0.0, 0.0], "added to the top centre, m", item=POS),
    },
})

_PATTERN_KINDS = ("tshirt", "short_skirt", "long_skirt", "shorts", "trousers", "cape", "square")
GARMENT.tag_hints.update({k: f"{k!r} is a pattern kind: write type: pattern, kind: {k}" for k in _PATTERN_KINDS})

# the size options of the built-in patterns (stages/garments/library.py: each generator's keyword
# arguments; tests/test_scene_ranges.py holds the two in step), one range for each name whatever the kind
PATTERN_OPTIONS = {
    "ease": Field("float", None, "girth added to the body's (or its colliders'), m", lo=0.0, hi=0.5),
    "hip_ease": Field("float", None, "girth added at the hips, m", lo=0.0, hi=0.5),
    "length": Field("float", None, "skirt or cape length, m", lo=0.0, lo_open=True, hi=3.0),
    "flare": Field("float", None, "hem width over hip width (1: straight)", lo=1.0, hi=5.0),
    "length_below_waist": Field("float", None, "tshirt hem below the waist, m (negative: above it)", lo=-0.5, hi=1.5),
    "sleeve_length": Field("float", None, "tshirt sleeve length, m", lo=0.0, lo_open=True, hi=1.0),
    "leg_length": Field("float", None, "shorts / trousers leg length below the crotch, m", lo=0.0, lo_open=True,
                        hi=1.5),
    "leg_ease": Field("float", None, "radius added to the thigh (shorts) or shin (trousers) at the hem, m",
                      lo=0.0, hi=0.3),
    "crotch_drop": Field("float", None, "crotch below the body's, m", lo=0.0, hi=0.3),
    "size": Field("float", None, "square edge length, m", lo=0.0, lo_open=True, hi=5.0),
    "height_above": Field("float", None, "square height above the head, m", lo=0.0, hi=2.0),
}
KIND_OPTIONS = {
    "tshirt": ("ease", "length_below_waist", "sleeve_length"),
    "short_skirt": ("length", "flare", "ease", "hip_ease"),
    "long_skirt": ("length", "flare", "ease", "hip_ease"),
    "shorts": ("leg_length", "ease", "hip_ease", "leg_ease", "crotch_drop"),
    "trousers": ("leg_length", "ease", "hip_ease", "leg_ease", "crotch_drop"),
    "cape": ("length",),
    "square": ("size", "height_above"),
}
MAX_GARMENT_PARTICLES = 100_000   # ~10x the largest shipped garment: memory and time grow with it


def _check_garment(g):
    """Options of a pattern garment's kind; a rectangle's or tube's particle count (the schema's per-axis
    bounds allow 4 million)."""
    if g["type"] == "pattern":
        allowed = KIND_OPTIONS.get(g["kind"], ())
        for key in g["options"]:
            if key not in allowed:
                near = difflib.get_close_matches(key, allowed, n=1, cutoff=0.5)
                hint = f" (did you mean {near[0]!r}?)" if near else ""
                return (f"options.{key}", f"not an option of kind {g['kind']!r}{hint}; options: "
                                          f"{', '.join(allowed) or 'none'}")
    n = (g["resolution"][0] * g["resolution"][1] if g["type"] == "rectangle" else
         g["n_around"] * g["n_down"] if g["type"] == "tube" else 0)
    if n > MAX_GARMENT_PARTICLES:
        keys = "resolution" if g["type"] == "rectangle" else "n_around x n_down"
        return f"{keys} make {n:,} particles, more than {MAX_GARMENT_PARTICLES:,} (expected a garment-sized mesh)"
    return None


_FABRIC = ("density", "material", "stretch_stiffness", "bend_stiffness")
GARMENT.variants["pattern"] = {
    **{k: _GARMENT_COMMON[k] for k in ("name", *_FABRIC, "layer", "ignore_colliders")},
    "kind": Field("str", REQUIRED, "a built-in sewing pattern, sized from the character's measurements",
                  choices=_PATTERN_KINDS),
    "edge_length": Field("float", 0.025, "target mean edge length of the flat panels, m", lo=0.005, hi=0.2),
    "options": Field("section", {}, "size options of the kind (a key left out: sized from the body); "
                     + "; ".join(f"{k}: {', '.join(v)}" for k, v in KIND_OPTIONS.items()),
                     fields=PATTERN_OPTIONS, sparse=True),
    "sewing": Field("section", {}, "sewing under micro-gravity", fields={
        "tolerance": Field("float", 0.004, "largest seam gap accepted, m", lo=0.0, lo_open=True),
        "target": Field("float", 0.002, "within the tolerance, the sewing goes on while the largest gap still falls, "
                        "down to this, m (at most the tolerance)", lo=0.0, lo_open=True),
        "max_iterations": Field("int", 40, "sewing simulation rounds at most (the sewing runs at least 2)", lo=2, hi=10000),
        "gravity_scale": Field("float", 0.005, "share of gravity while sewing", lo=0.0, hi=1.0),
        "iterations": Field("int", 16, "spring correction rounds while sewing", lo=1, hi=1000),
    }),
}
GARMENT.variants["garmentcode"] = {   # issue 39: a GarmentCode sewing pattern
    **{k: _GARMENT_COMMON[k] for k in ("name", *_FABRIC, "layer", "ignore_colliders")},
    "path": Field("path", REQUIRED, "GarmentCode *_specification.json, relative to the scene file; the body it was "
                  "made for: body_measurements.yaml beside it, else GarmentCode's default body (mean_all)"),
    "edge_length": Field("float", 0.025, "target mean edge length of the flat panels, m", lo=0.005, hi=0.2),
    "sewing": Field("section", {}, "sewing under micro-gravity", fields={
        **GARMENT.variants["pattern"]["sewing"].fields,
        # gathered seams of unequal sides need more rounds than the built-in patterns' (16: 5-12 mm left open,
        # 64: 4.7 mm on the circle skirt sampled for mean_all, on the built-in character)
        "iterations": Field("int", 128, "spring correction rounds while sewing", lo=1, hi=1000),
        # where four panels meet (a waistband's side seam on a skirt's) the corners stay 3.4-4.7 mm
        # apart at any number of rounds; they are merged into one vertex after sewing
        "tolerance": Field("float", 0.005, "largest seam gap accepted, m", lo=0.0, lo_open=True),
    }),
}
GARMENT.variants["mesh"] = {
    **_GARMENT_COMMON,
    "path": Field("path", REQUIRED, "OBJ / PLY / GLB garment mesh, relative to the scene file"),
    "part": Field("any", None, "a glTF / GLB holding several meshes: the one to use (its name or index; one garment "
                  "item each), or 'all' to simulate them as one cloth; null: the file must hold one",
                  check=lambda v: None if v is None or (isinstance(v, (str, int)) and not isinstance(v, bool))
                  else f"expected a mesh name, an index or 'all', got {v!r}"),
    "scale": Field("float", 1.0, "metres per file unit", lo=0.0, lo_open=True, hi=1e6,
                   warn=plausible(1e-3, 100.0, "a garment mesh in m, cm or mm needs 1, 0.01 or 0.001")),
    "translate": Field("vec3", [0.0, 0.0, 0.0], "m, relative frame at frame 0", item=POS),
    "rotate_deg": Field("vec3", [0.0, 0.0, 0.0], "XYZ Euler angles, degrees", item=ANGLE),
}

def _nonzero(v):
    return None if any(abs(c) > 1e-9 for c in v) else f"expected a non-zero direction, got {v!r}"


_OBSTACLE_COMMON = {
    "name": Field("str", None, "obstacle name (entity path obstacles/<name>); default: the file's name, else the "
                  "type, numbered from _2 when repeated"),
    "thickness": Field("float", 0.005, "contact thickness, m", lo=0.0, hi=1.0,
                       warn=plausible(None, 0.05, "cloth is held this far off the surface")),
    "friction": Field("float", 0.3, "tangential friction coefficient", lo=0.0, hi=1.0),
    "restitution": Field("float", 0.0, "normal restitution", lo=0.0, hi=1.0),
    "velocity": Field("vec3", [0.0, 0.0, 0.0], "rigid linear velocity, m/s", item=SPEED),
    "angular_velocity": Field("vec3", [0.0, 0.0, 0.0], "rigid angular velocity about the centre, rad/s", item=SPEED),
}

OBSTACLE = Field("union", REQUIRED, "an obstacle", variants={
    "box": {**_OBSTACLE_COMMON, "center": V3,
            "size": Field("vec3", REQUIRED, "edge lengths, m", item=Field("float", lo=0.0, lo_open=True, hi=1e3))},
    "table": {**_OBSTACLE_COMMON, "center": Field("vec3", [0.0, 0.0, 0.0], "floor point under the table centre", item=POS),
              "top_size": Field("list", [1.0, 0.6], "table top [x, z] size, m",
                                item=Field("float", lo=0.0, lo_open=True, hi=100.0), length=2),
              "height": Field("float", 0.75, "m", lo=0.0, lo_open=True, hi=100.0),
              "top_thickness": Field("float", 0.03, "m", lo=0.0, lo_open=True, hi=10.0)},
    "sphere": {**_OBSTACLE_COMMON, "center": V3, "radius": Field("float", REQUIRED, "m", lo=0.0, lo_open=True, hi=1e3),
               "subdivisions": Field("int", 3, "icosphere subdivisions", lo=0, hi=6)},
    "plane": {**_OBSTACLE_COMMON, "point": Field("vec3", [0.0, 0.0, 0.0], "a point on the plane, m", item=POS),
              "normal": Field("vec3", [0.0, 1.0, 0.0], "the side the cloth stays on (any length but 0)",
                              item=Field("float", lo=-1e3, hi=1e3), check=_nonzero),
              "size": Field("float", 10.0, "finite extent, m", lo=0.0, lo_open=True, hi=1e5)},
    "cylinder": {**_OBSTACLE_COMMON, "center": V3, "radius": Field("float", REQUIRED, "m", lo=0.0, lo_open=True, hi=1e3),
                 "height": Field("float", REQUIRED, "m", lo=0.0, lo_open=True, hi=1e3),
                 "sections": Field("int", 32, "facets around", lo=3, hi=512)},
    "mesh": {**_OBSTACLE_COMMON, "path": Field("path", REQUIRED, "OBJ / PLY / STL / GLB file"),
             "scale": Field("float", 1.0, "metres per file unit", lo=0.0, lo_open=True, hi=1e6,
                            warn=plausible(1e-3, 1e3, "a mesh in m, cm or mm needs 1, 0.01 or 0.001")),
             "translate": Field("vec3", [0.0, 0.0, 0.0], "m", item=POS),
             "rotate_deg": Field("vec3", [0.0, 0.0, 0.0], "XYZ Euler angles, degrees", item=ANGLE)},
})


def _check_character(c):
    if c["scale"] is None and c["source"] != "gltf":
        c["scale"] = 1.0  # auto units are the glTF loader's; a BVH or the built-in body is taken in metres
    if c["source"] in ("gltf", "bvh") and not c["path"]:
        return f"source {c['source']!r} needs a 'path'"
    if c["source"] == "procedural" and c["path"]:
        return "source 'procedural' takes no 'path' (did you mean source: gltf or bvh?)"
    if c["bind_pose"] is not None and c["source"] != "bvh":
        return f"bind_pose applies to source 'bvh' only (source is {c['source']!r})"
    return None


def _check_floor(v):
    if v in ("auto", "none"):
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not abs(v) <= 1e3:
        return f"expected auto, none or a height in m (a number in [-1000, 1000]), got {v!r}"
    return None


SCENE_SPEC = {
    "name": Field("str", None, "scene name; default: the file name without .yaml"),
    "seed": Field("int", 0, "seed for every random choice", lo=0, hi=2**32 - 1),
    "character": Field("section", {}, "the skinned character", check=_check_character, fields={
        "source": Field("str", "procedural", "procedural | gltf | bvh", choices=("procedural", "gltf", "bvh")),
        "path": Field("path", None, ".glb/.gltf or .bvh file, relative to the scene file"),
        "clip": Field("any", 0, "clip name or index ('rest' = no motion)"),
        "scale": Field("float", None, "length scale applied to the asset (metres per file unit); default "
                       "(null): glTF auto (metres, or cm / mm when metres make a biped or animal implausibly "
                       "tall, else an error naming the scale to set), BVH 1; a number is taken as it is",
                       lo=0.0, lo_open=True, hi=1e6, nullable=True,
                       warn=plausible(1e-4, 100.0, "metres per file unit: 1 for m, 0.01 for cm, 0.001 for mm")),
        "up_axis": Field("str", "auto", "up axis of a glTF asset: auto (where two limbs of the skinned rest "
                         "pose hang down to the floor), y or z", choices=("auto", "y", "z")),
        "loop": Field("bool", None, "glTF clips past their end: on (loop), off (hold the last pose), or null "
                      "(default: loop when the clip's last pose meets its first, else hold)", nullable=True),
        "bind_pose": Field("str", None, "bvh: pose the skin is built and bound in (default neutral)",
                           choices=("neutral", "frame0", "rest")),
        "body": Field("section", {}, "built-in character / generated BVH skin sizes", fields={
            "height": Field("float", 1.75, "m", lo=0.5, hi=2.5),
            "chest": Field("float", 1.0, "girth scale", lo=0.5, hi=2.0),
            "waist": Field("float", 1.0, "girth scale", lo=0.5, hi=2.0),
            "hips": Field("float", 1.0, "girth scale", lo=0.5, hi=2.0),
            "arms": Field("float", 1.0, "girth scale", lo=0.5, hi=2.0),
            "legs": Field("float", 1.0, "girth scale", lo=0.5, hi=2.0),
        }),
    }),
    "frames": Field("section", {}, "which part of the clip to run", fields={
        "start": Field("float", 0.0, "clip time of the first frame, s", lo=0.0, hi=1e6),
        "count": Field("int", 60, "number of frames", lo=1, hi=100000),
        "blend_in": Field("float", None, "seconds of extra frames first, carrying the character from its rest "
                          "pose (where garments are dressed) into the running clip; default (null): sized from how "
                          "far the clip's first pose is from the rest pose (0 when it is the rest pose or the scene "
                          "has no garments); 0: garments dressed on the clip's first pose", lo=0.0, hi=60.0,
                          nullable=True),
    }),
    "colliders": Field("section", {}, "collider fitting (paper A §2)", fields={
        "delta": Field("float", 0.01, "inflation thickness, m", lo=0.0, lo_open=True, hi=0.5,
                       warn=plausible(0.001, 0.1, "the colliders stand this far off the skin")),
        "split": Field("str", "motion", "motion: a vertex is rigid for the bone it moves with over the clip (within "
                       "motion_tolerance) | weights: dominant skin weight >= rigid_threshold (paper)",
                       choices=("motion", "weights")),
        "motion_tolerance": Field("float", 0.5, "split: motion: how far (as a fraction of delta) a rigid vertex may "
                                  "move in its bone's frame", lo=0.0, hi=10.0),
        "rigid_threshold": Field("float", 0.9, "split: weights: dominant skin weight that makes a vertex rigid", lo=0.0, lo_open=True, hi=1.0),
        "flexible": Field("str", "balls", "balls: spheres whose centres are skinned with the flexible skin (stages/hulls/balls.py) "
                          "| swept: hulls of the flexible vertices over the motion, in the frame of the bone each moves "
                          "least with | sphere: one sphere per joint (paper)", choices=("balls", "swept", "sphere")),
        "min_triangles": Field("int", 40, "simplification stops at this many hull faces", lo=4, hi=100_000),
        "max_offset": Field("float", 0.005, "simplified hull stays within this distance (m) of the inflated one; null = unbounded (paper)", lo=0.0, lo_open=True,
                            nullable=True),
        "report_every": Field("int", 10, "measure coverage and excess every this many frames (and the last); 0 = off", lo=0, hi=100_000),
        "map": Field("section", {}, "map volume per hull", fields={
            "type": Field("str", "auto", "auto | sphere | cylinder", choices=("auto", "sphere", "cylinder")),
            "n_theta": Field("int", 12, "cells around", lo=3, hi=720),
            "n_phi": Field("int", 6, "map sphere: cells from pole to pole", lo=2, hi=360),
            "n_axial": Field("int", 8, "map cylinder: cells along the axis", lo=1, hi=1000),
        }),
        "response": Field("str", "ray", "ray (paper's query path) | brute_ray (same response, every face tested) | nearest_plane (baseline)",
                          choices=("ray", "brute_ray", "nearest_plane")),
    }),
    "garments": Field("list", [], "garments to simulate", item=GARMENT),
    "obstacles": Field("list", [], "environment obstacles (paper B)", item=OBSTACLE),
    "simulation": Field("section", {}, "cloth simulation", fields={
        "preset": Field("str", "default", "default (small steps: 20 sub-steps x 2 rounds, tethers) | paper (paper A: "
                        "1 step x 3 rounds per frame, no tethers); the keys marked 'preset' below override it",
                        choices=("default", "paper")),
        "dt": Field("float", 1.0 / 30.0, "frame time, s", lo=1e-4, hi=1.0,
                    warn=plausible(None, 0.1, "frames far apart let the cloth overshoot (1/30 s is usual)")),
        "substeps": Field("int", None, "steps per frame (preset)", lo=1, hi=1000),
        "iterations": Field("int", None, "rounds of spring position correction per step (preset)", lo=1, hi=1000),
        "gravity": Field("vec3", [0.0, -9.81, 0.0], "m/s^2", item=Field("float", lo=-1e3, hi=1e3),
                         warn=plausible(None, 30.0, "the Earth's is 9.81 m/s^2", norm=True)),
        "damping": Field("float", None, "fraction of the velocity lost per 1/30 s (preset)", lo=0.0, hi=1.0),
        "wind": Field("vec3", [0.0, 0.0, 0.0], "air velocity, m/s", item=Field("float", lo=-200.0, hi=200.0),
                      warn=plausible(None, 40.0, "a storm's wind is 25 m/s", norm=True)),
        "drag": Field("float", 0.5, "aerodynamic drag coefficient", lo=0.0, hi=100.0),
        "lift": Field("float", 0.1, "aerodynamic lift coefficient", lo=0.0, hi=100.0),
        "aero_interval": Field("float", 1.0 / 30.0, "s: the aerodynamic forces are computed once per this span of "
                               "sub-steps and held over it (0: every sub-step)", lo=0.0, hi=10.0),
        "friction": Field("float", 0.5, "Coulomb friction with colliders: sliding reduced by up to friction x push depth", lo=0.0, hi=10.0),
        "tethers": Field("bool", None, "(preset) long-range attachments: free particles stay within their rest distance along the mesh of the nearest pinned one (Kim et al. 2012; not in the paper)"),
        "inertia_scale": Field("float", 0.0, "0 = relative simulation (paper), 1 = world space", lo=0.0, hi=1.0),
        "stretch_stiffness": Field("float", None, "share of a stretch correction applied per round at 300 rounds/s "
                                   "(frequency-scaled: the same cloth at any sub-step count; preset)", lo=0.0, lo_open=True, hi=1.0),
        "bend_stiffness": Field("float", None, "share of a bend correction applied per round at 300 rounds/s (preset: "
                                "0.2; paper 1: as stiff as the stretch springs, it stretches cloth the body curves)",
                                lo=0.0, hi=1.0),
        "cloth_collision": Field("bool", None, "on | off (preset: on in default, off in paper) "
                                 "garment-garment and self collision (cloth x cloth, last phase of every "
                                 "step); garments keep their `layer` order"),
        "pinch": Field("str", None, "midpoint | limb | escape (preset: midpoint; paper: escape): cloth pressed between the "
                       "colliders of two joints (an arm lowered onto the torso, a hand on the hip) stays in the middle "
                       "of their overlap; limb: the deeper limb's collider acts and the body's yields, the cloth held "
                       "midway between them at once (less strain, more cloth inside the body); escape: it leaves "
                       "their union",
                       choices=("midpoint", "limb", "escape")),
        "entry_side": Field("bool", None, "on | off (preset: off): cloth a limb pushes past its middle in one "
                            "step leaves the limb by the side it came in, not the far side (the paper's map "
                            "response would wrap it round the limb)"),
        "face_contact": Field("bool", None, "on | off (preset: off): the colliders also push the cloth's triangles "
                              "(their centres and edge midpoints), not only its particles: a limb thinner than the "
                              "cloth's triangles, or cloth stretched across one, cannot pass between the particles "
                              "(collisions take 2.5-5 times as long)"),
        "strain_limit": Field("float", None, "share over the rest length (preset: 0, off): after every sub-step's "
                              "collisions a cloth edge longer than (1 + strain_limit) times its rest length is "
                              "shortened back to it: cloth hooked on a limb is let through it instead of staying "
                              "stretched round it (less strain, more cloth inside the body)", lo=0.0, hi=10.0),
        "limb_release": Field("float", None, "share over the rest length (preset: off; left unset, a run whose cloth a "
                              "limb tears past 500 % is simulated again with 2, except in the paper preset): after every frame "
                              "the cloth edges stretched more than this where they touch an arm's or leg's collider "
                              "stop being pushed by that limb until they are outside it again: cloth a limb tears "
                              "lets go of it (the limb passes through it there) instead of staying torn; 0: off",
                              lo=0.0, hi=100.0),
        "cloth_thickness": Field("float", 0.003, "distance kept between cloth layers, m", lo=0.0, lo_open=True, hi=0.1),
        "cloth_contact": Field("str", "swept", "swept | offset: how cloth collision keeps cloth from passing through "
                               "cloth. swept: continuous collision tests of every call's motion; offset: one proximity "
                               "query reused while every particle stays within a bound from its distance to the "
                               "nearest cloth feature it is not part of (after Offset Geometric Contact; no crossing "
                               "by construction, slower on the shipped scenes)", choices=("swept", "offset")),
        "cloth_contact_every": Field("int", None, "sub-steps per cloth collision call (the largest divisor of substeps "
                                     "up to it); the sub-steps between calls hold the pairs the last call found within "
                                     "two thicknesses (preset: 5). 1: a call every sub-step", lo=1, hi=1000),
        "settle_frames": Field("int", None, "frames the garments hang, damped, at the first frame's pose before "
                               "frame 0 is recorded (preset: 10; paper 0)", lo=0, hi=300),
        "speed_limit": Field("float", None, "m/s: the cloth's speed (relative to the character's root) is capped "
                             "at this at every sub-step, so that cloth a collider throws cannot fly off; null: "
                             "from the clip (3 times its fastest skin speed plus twice the speed of a fall "
                             "from the body's height; paper preset: none); 0: none", lo=0.0, hi=1e6),
        "floor": Field("any", "auto", "auto | none | a height in m: a floor the cloth rests on (world y = the "
                       "height). auto: under the character's feet, at the soles of their colliders (colliders.delta under "
                       "y = 0, or under the lowest point its skin reaches over the clip when that is lower), for scenes without obstacles (with them, their own `plane` is the "
                       "floor) and not in the paper preset (paper A had none); none: no floor",
                       check=lambda v: _check_floor(v)),
        "body_audit": Field("bool", True, "count particles inside the true skinned mesh per frame"),
        "cloth_audit": Field("bool", True, "per frame edge strain and cloth edges crossing cloth triangles (sim/<garment>/strain, sim/intersections/...)"),
        "strain_colors": Field("bool", False, "colour the cloth meshes by per-vertex edge strain (blue 0 -> red 10 %)"),
        "threads": Field("int", 1, "worker threads for the simulation kernels; results are identical for any "
                         "count; 2 pays on an idle 2-core machine, 1 is safer on a loaded one", lo=1, hi=256),
    }),
    "output": Field("path", None, "recording path; default recordings/<name>.rrd in the working folder; or a "
                    "mapping {path, export, export_dir} (see OUTPUT_FIELDS)"),
}

# `output:` as a mapping: the recording path plus the files exported after the run (pipeline.export)
OUTPUT_FIELDS = {
    "path": Field("path", None, "recording path; default recordings/<name>.rrd in the working folder"),
    "export": Field("list", [], "formats written after the run: npz, pc2 (+ obj rest mesh), obj, glb, usd (extra 'usd')",
                    item=Field("str", choices=("npz", "pc2", "obj", "glb", "usd"))),
    "export_dir": Field("path", None, "folder for the exports; default <recording folder>/<recording stem>_export"),
}


@dataclass(frozen=True)
class Scene:
    """A validated scene: `settings` is the default-filled dict tree of SCENE_SPEC."""

    path: Path | None
    name: str
    text: str
    settings: dict
    # output.export / output.export_dir: {'formats': [...], 'dir': path or None} (pipeline.export)
    export: dict = field(default_factory=lambda: {"formats": [], "dir": None})
    # legal but implausible values (schema `warn`), shown by `warn_notes` once every check passed
    notes: tuple = ()

    def __getitem__(self, key):
        return self.settings[key]

    @property
    def output(self) -> Path:
        out = self.settings["output"]
        return Path(out) if out else Path("recordings") / f"{self.name}.rrd"


def _marks(node, path: str, out: dict):
    """Record (line, column), 1-based, of every key path in a composed YAML node tree."""
    out[path] = (node.start_mark.line + 1, node.start_mark.column + 1)
    if isinstance(node, yaml.MappingNode):
        for k, v in node.value:
            key = k.value if isinstance(k, yaml.ScalarNode) else str(k.value)
            sub = f"{path}.{key}" if path else key
            out["@" + sub] = (k.start_mark.line + 1, k.start_mark.column + 1)  # the key itself
            _marks(v, sub, out)
    elif isinstance(node, yaml.SequenceNode):
        for i, v in enumerate(node.value):
            _marks(v, f"{path}[{i}]", out)


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys (YAML silently keeps the last one). Merge keys
    (`<<: *anchor`) work as in YAML 1.1: the mapping's own keys override the merged ones."""

    def construct_mapping(self, node, deep=False):
        seen = set()
        for k, _ in node.value:
            if k.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(k, deep=deep)
            if key in seen:
                raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", k.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def parse_scene_text(text: str, *, source: str = "<scene>", base_dir: Path | None = None,
                     default_name: str = "scene") -> Scene:
    """Parse and validate scene YAML text."""
    try:
        from stages.safe_yaml import load_checked
        data, node = load_checked(text, source, SceneError, loader=_UniqueKeyLoader)
    except yaml.MarkedYAMLError as e:
        m = e.problem_mark or e.context_mark
        at = f"{source}:{m.line + 1}:{m.column + 1}" if m else source
        raise SceneError(f"{at}: YAML syntax error: {e.problem or e}") from None
    except yaml.YAMLError as e:
        raise SceneError(f"{source}: YAML error: {e}") from None
    marks: dict = {}
    if node is not None:
        _marks(node, "", marks)
    if data is None:   # nothing but blanks and comments: running the defaults would be a surprise
        raise SceneError(f"{source}: the scene file is empty (expected a mapping such as 'character:', "
                         f"'garments:'; write '{{}}' to run every default)")
    if isinstance(data, dict) and "base" in data and ("grid" in data or "cases" in data):
        # a sweep file run as a scene: 'unknown key base' would send the user looking for a typo
        at = f"{source}:{marks['@base'][0]}:{marks['@base'][1]}" if "@base" in marks else source
        raise SceneError(f"{at}: base: this is a sweep file (base, grid / cases), not a scene: run it with "
                         f"`python -m pipeline sweep {source}`")
    return scene_from_data(data, text=text, source=source, base_dir=base_dir, default_name=default_name, marks=marks)


def scene_from_data(data, *, text: str, source: str = "<scene>", base_dir: Path | None = None,
                    default_name: str = "scene", marks: dict | None = None) -> Scene:
    """Validate an already parsed scene mapping (`text` is what the recording stores as the scene).
    Without `marks` the messages name the key path but no line and column (a sweep's generated
    scenes: pipeline.sweep)."""
    marks = {} if marks is None else marks
    notes: list = []
    export = {"path": None, "export": [], "export_dir": None}
    if isinstance(data, dict) and isinstance(data.get("output"), dict):   # output: {path, export, export_dir}
        export = validate({"output": Field("section", {}, fields=OUTPUT_FIELDS)}, {"output": data["output"]},
                          source=source, marks=marks, base_dir=base_dir, notes=notes)["output"]
        data = {**data, "output": export["path"]}
    settings = validate(SCENE_SPEC, data, source=source, marks=marks, base_dir=base_dir, notes=notes)
    for section in ("garments", "obstacles"):   # names are entity paths: sim/<name>, obstacles/<name>
        _default_names(settings[section])
        first: dict = {}
        for i, item in enumerate(settings[section]):
            j = first.setdefault(item["name"], i)
            if j != i:
                mark = marks.get(f"{section}[{i}].name")
                at = f"{source}:{mark[0]}:{mark[1]}" if mark else source
                raise SceneError(f"{at}: {section}[{i}].name: {item['name']!r} is already the name of "
                                 f"{section}[{j}]; names must be unique")
    _check_frames(settings, source, marks)
    resolve_fabrics(settings, source, base_dir)
    name = settings["name"] or default_name
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
        raise SceneError(f"{source}: name: {name!r} must use only letters, digits, '_', '-' and '.'")
    return Scene(path=None, name=name, text=text, settings=settings,
                 export={"formats": list(export["export"]), "dir": export["export_dir"]}, notes=tuple(notes))


def _default_names(items: list) -> None:
    """In place: a name for every item that has none, from what it is (a pattern's kind, a file's
    stem without GarmentCode's '_specification', else the type), numbered from _2 where it repeats a
    name already taken (a name the scene gives wins)."""
    taken = {it["name"] for it in items if it["name"]}
    for it in items:
        if it["name"]:
            continue
        if it.get("kind"):
            base = it["kind"]
        elif it.get("path"):
            base = re.sub(r"_specification$", "", Path(it["path"]).stem)
        else:
            base = it["type"]
        base = re.sub(r"[^A-Za-z0-9_.-]+", "_", base).strip("_") or it["type"]
        name, k = base, 2
        while name in taken:
            name, k = f"{base}_{k}", k + 1
        it["name"] = name
        taken.add(name)


def warn_notes(scene: Scene) -> None:
    """The scene's implausible-value lines as warnings (`validate` and `run` call it once their
    checks before the stages passed)."""
    import warnings
    for note in scene.notes:
        warnings.warn(note, stacklevel=2)


MAX_FRAMES = 100_000   # frames run, blend-in included: the recording and memory grow with them


def _check_frames(settings: dict, source: str, marks: dict) -> None:
    """The blend-in's frames (frames.blend_in / simulation.dt) and the clip's together at most MAX_FRAMES."""
    fr, dt = settings["frames"], settings["simulation"]["dt"]
    blend = int(round((fr["blend_in"] or 0.0) / dt))
    if fr["count"] + blend > MAX_FRAMES:
        key = "frames.blend_in" if blend else "frames.count"
        mark = marks.get(key) or marks.get("simulation.dt")
        at = f"{source}:{mark[0]}:{mark[1]}" if mark else source
        raise SceneError(f"{at}: {key}: {fr['count']:,} frames plus {blend:,} blend-in frames "
                         f"({fr['blend_in'] or 0:g} s at simulation.dt {dt:g} s) are more than {MAX_FRAMES:,}; "
                         f"expected fewer frames or a longer dt")


def load_scene(path: str | os.PathLike) -> Scene:
    """Read, parse and validate a scene file; every problem is a `SceneError` naming the file."""
    from stages.input_files import read_text_file
    p = Path(path)
    # a regular file of bounded size, checked by stat before it is opened (a FIFO would block, /dev/zero never end)
    text = read_text_file(p, "scene file", SceneError)
    scene = parse_scene_text(text, source=str(p), base_dir=p.resolve().parent, default_name=p.stem)
    return Scene(path=p, name=scene.name, text=text, settings=scene.settings, export=scene.export, notes=scene.notes)
