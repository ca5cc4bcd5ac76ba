"""Colours of the recording: one place, so the logging, the blueprint and the tests agree.

The scene view shows the body in a neutral skin tone and every garment in its own fabric colour;
region colours (one per bone, `pipeline.logs.palette`) appear only in the rig and colliders tabs,
where they explain the region split and which collider belongs to which bone.
"""
from __future__ import annotations

SKIN = (214, 182, 156, 255)           # neutral, light, unsaturated: reads as a body, not a garment
# fabric colours, in garment order: contrast with the skin and with each other
FABRICS = (
    (52, 96, 168, 255),               # denim blue
    (178, 58, 58, 255),               # brick red
    (72, 140, 92, 255),               # bottle green
    (222, 168, 48, 255),              # mustard
    (122, 78, 150, 255),              # plum
    (40, 150, 160, 255),              # teal
)
PIN_RIGID = (30, 30, 30, 255)         # attached particles: near black
PIN_YIELDING = (255, 170, 0, 255)     # attached but pushed by another bone's collider: amber
OBSTACLE = (150, 150, 158, 255)       # obstacles: light grey
FLOOR = (44, 46, 52, 255)             # the simulation's floor: a shade over the viewer's background, so the
                                      # body and cloth on it stand out (a light floor outshone them)
PIN_RADIUS = 0.007


def fabric(i: int) -> tuple:
    """The i-th garment's fabric colour (RGBA uint8)."""
    return FABRICS[i % len(FABRICS)]
