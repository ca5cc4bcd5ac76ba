"""Named fabrics (issue 39, part 4): the cloth figures of a garment's `material`.

A fabric states five figures. Two are physical and used as they are: the area density (kg/m^2,
the particles' lumped masses: it matters against the air, the drag and lift of SimParams, and
between garments) and the thickness (m). Two are this simulator's stiffnesses: the share of a
stretch or bend spring correction applied per round at REFERENCE_RATE (300) rounds per second
(stages/sim/types.py, SimParams), which are not material constants: a position-based spring has no
modulus, its stiffness is how much of the error one round removes. They are mapped from the fabric's
measured bending rigidity and in-plane extensibility by rank, as below. Friction is the Coulomb
coefficient against skin.

How the figures were set (representative values of the fabric class, not of one cloth):
- density: area weight of typical cloths of the class, as sold: silk charmeuse/crepe de chine
  60-80 g/m^2, cotton shirting and poplin 110-150, single jersey 150-200, wool suiting 230-300,
  denim 12-14 oz/yd^2 = 400-475, garment leather (0.8-1.2 mm) 600-1000.
- thickness: KES-FB3 thickness at 0.5 gf/cm^2 of the same classes (Kawabata, The Standardization
  and Analysis of Hand Evaluation, 1980): silk ~0.1-0.2 mm, shirting ~0.3, jersey ~0.5-0.6, wool
  suiting ~0.5-0.7, denim ~0.8-1.0 mm; leather as its nominal thickness.
- bend_stiffness: ordered by KES-FB2 bending rigidity B (gf.cm^2/cm): silk ~0.01-0.03, jersey
  ~0.02-0.05, cotton shirting ~0.05-0.15, wool suiting ~0.08-0.2, denim ~0.5-1.5, leather several.
  The scale: 0.2 (the simulator's default, calibrated so a sewn tube on the body curves without
  stretching, SimParams) stands for cotton shirting; the others are set on a log scale of B about
  it, k = 0.2 (B / B_cotton)^0.5 clipped to [0.02, 1]; 0.02 is GarmentCode's "very soft" fabric
  mapped the same way (fabric_from_sim_props).
- stretch_stiffness: woven cloth and leather barely extend under their own weight (KES-FB1 EMT at
  500 gf/cm: a few %, Kawabata 1980; Penava et al. 2014 measure woven cotton's Young's modulus at
  hundreds of MPa along the yarns), so they keep the simulator's fully stiff 1.0. A single jersey
  knit extends several times more at the same load (Wang et al. 2011, "Data-driven elastic models
  for cloth", measured knits far softer in stretch than wovens), so it is 0.5: a strand of hanging
  cloth lengthens under gravity where a woven one does not.
- friction: fabric against skin, kinetic coefficient of the order 0.2-0.6 (Derler and Gerhardt
  2012, "Tribology of skin", review of textile-skin measurements): silk at the low end, wool and
  leather at the high end; 0.5 is also GarmentCode's fabric_friction and body_friction.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from stages.errors import InputError


@dataclass(frozen=True)
class Fabric:
    """A cloth's figures. density: kg/m^2. stretch_stiffness, bend_stiffness: this simulator's share of
    a correction per round at 300 rounds/s, (0, 1] and [0, 1]. friction: Coulomb coefficient against
    skin. thickness: m. source: where the figures come from (one line)."""

    name: str
    density: float
    stretch_stiffness: float
    bend_stiffness: float
    friction: float
    thickness: float
    source: str


FABRICS = {f.name: f for f in (
    Fabric("silk", 0.07, 1.0, 0.02, 0.25, 0.00015, "silk charmeuse: 60-80 g/m^2, KES B ~0.01-0.03 gf.cm^2/cm"),
    Fabric("jersey", 0.18, 0.5, 0.05, 0.4, 0.0006, "cotton single jersey: 150-200 g/m^2, B ~0.02-0.05, knit: "
                                                   "extensible (Wang et al. 2011)"),
    Fabric("cotton", 0.13, 1.0, 0.2, 0.4, 0.0003, "cotton shirting: 110-150 g/m^2, B ~0.05-0.15 (the simulator's "
                                                 "default bend)"),
    Fabric("wool", 0.27, 1.0, 0.3, 0.5, 0.0006, "wool suiting: 230-300 g/m^2, B ~0.08-0.2"),
    Fabric("denim", 0.43, 1.0, 0.6, 0.5, 0.0009, "12-14 oz denim: 400-475 g/m^2, B ~0.5-1.5"),
    Fabric("leather", 0.8, 1.0, 1.0, 0.6, 0.001, "garment leather 0.8-1.2 mm: 600-1000 g/m^2, bend rigidity "
                                                "above any woven (clipped to the simulator's stiffest)"),
)}

# GarmentCode's warp simulator (pygarment/meshgen): garment_edge_ke is the bending stiffness (its
# settings call 1 "very soft", 100 "mid-softness", 500 minimal bending), garment_tri_ke the in-plane
# one (10000 in every settings file it ships). Mapped on the same log scale as the named fabrics:
# edge_ke 100 (mid) -> 0.2 (cotton, this simulator's default), 1 -> 0.02, 500 -> 0.45.
GC_MID_EDGE_KE = 100.0
GC_TRI_KE = 10000.0


def fabric_from_sim_props(material: dict, where: str) -> Fabric:
    """A Fabric from the `material` mapping of a GarmentCode simulator settings file (sim.config.material).

    bend_stiffness = 0.2 sqrt(garment_edge_ke / 100), clipped to [0, 1]; stretch_stiffness =
    garment_tri_ke / 10000 clipped to (0, 1] (its files all give 10000: fully stiff); friction =
    fabric_friction; thickness = fabric_thickness, in the body's unit, cm (GarmentCode's bodies are
    in cm), to m. fabric_density is not read: GarmentCode's simulator states it in its own scaled
    units (1.0 in every file), not kg/m^2, so the density is the garment's own (or its default).
    Missing keys take GarmentCode's default_sim_props values. where: names the file in errors."""
    def number(key: str, default: float, lo: float) -> float:
        v = material.get(key, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < lo:
            raise InputError(where, f"material.{key}: expected a number >= {lo}, got {v!r}")
        return float(v)

    if not isinstance(material, dict):
        raise InputError(where, f"material: expected a mapping of GarmentCode material settings, got {material!r}")
    edge_ke = number("garment_edge_ke", 1.0, 0.0)
    tri_ke = number("garment_tri_ke", GC_TRI_KE, 0.0)
    if tri_ke <= 0:
        raise InputError(where, "material.garment_tri_ke: expected a positive number, got 0")
    return Fabric(name="garmentcode", density=float("nan"),
                  stretch_stiffness=min(1.0, tri_ke / GC_TRI_KE),
                  bend_stiffness=min(1.0, 0.2 * math.sqrt(edge_ke / GC_MID_EDGE_KE)),
                  friction=number("fabric_friction", 0.5, 0.0),
                  thickness=number("fabric_thickness", 0.1, 0.0) / 100.0,
                  source=f"GarmentCode simulator settings {where}")
