"""Hull stage: convex hulls per rigid region, inflation, constrained QEM simplification, joint spheres."""
from stages.hulls.fit import fit_colliders, fit_hull, fit_report_totals, hausdorff_to_hull, joint_sphere
from stages.hulls.hull import convex_hull, inflate_hull, mesh_volume
from stages.hulls.simplify import simplify_hull

__all__ = ["convex_hull", "inflate_hull", "simplify_hull", "joint_sphere", "fit_colliders", "fit_hull",
           "fit_report_totals", "hausdorff_to_hull", "mesh_volume"]
