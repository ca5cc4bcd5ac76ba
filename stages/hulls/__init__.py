"""Hull stage: convex hulls per rigid region, inflation, constrained QEM simplification, joint spheres."""
