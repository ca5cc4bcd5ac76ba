"""Collider fit audit: coverage of the body by the colliders, and how far they stand off the skin."""
from stages.coverage.measure import ColliderFigures, CoverageReport, measure_coverage

__all__ = ["measure_coverage", "CoverageReport", "ColliderFigures"]
