"""Cloth simulation stage (paper A §1, §3.2-3.3): Verlet mass-spring cloth, position correction,
collisions with the character's spheres and hulls, attachments, relative simulation, body audit."""
from stages.sim.simulate import particles_inside_colliders, simulate
from stages.sim.types import GarmentTrack, SimParams, SimResult, SimulationDiverged

__all__ = ["simulate", "particles_inside_colliders", "SimParams", "SimResult",
           "GarmentTrack", "SimulationDiverged"]
