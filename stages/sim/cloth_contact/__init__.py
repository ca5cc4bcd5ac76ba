"""Cloth x cloth collision (garment-garment and self), a phase of the step loop (stages.sim.step).

Modules: `phase` (ClothPhase: what the simulation builds and the step loop calls; it picks the
method, SimParams.cloth_contact). The swept phase (default): `setup` (its arrays, ClothContact),
`kernels` (its call), `pairs`, `local`, `cull`, `narrow`, `ccd`, `response` (tree search, candidate
lists, filters, exact tests and response), `bench` (a sheet simulation for its tests and
measurements). The offset phase: `offset` (bounds, response, its call), `proximity` (its query).
"""
