"""Geometry queries that several stages share: the bottom layer of `stages`.

- kdop: k-DOP bounding volumes and trees of them (obstacle contact, cloth contact; paper B)
- winding: generalised winding numbers of points w.r.t. a mesh, a tree refitted per frame (inside the body)
- mesh: a triangle mesh's unique edges
- skin_distance: exact distance to a skinned mesh over that tree (collider fit, coverage, garment fit)

It imports no stage package (only stages.checks, stages.jit, stages.affine and the like), so any
stage may import it. Import the modules by name; the package re-exports nothing.
"""
