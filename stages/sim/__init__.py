"""Simulation stage: Verlet mass-spring cloth, position correction, collisions, attachments."""
