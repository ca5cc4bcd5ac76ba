"""Geometry queries that several stages share: the bottom layer of `stages`.

- kdop: k-DOP bounding volumes and trees of them (obstacle contact, cloth contact; paper B)

It imports no stage package (only stages.checks, stages.jit, stages.affine and the like), so any
stage may import it. Import the modules by name; the package re-exports nothing.
"""
