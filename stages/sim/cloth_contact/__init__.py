"""Cloth x cloth collision (garment-garment and self), a phase of the step loop (stages.sim.step).

Modules: `phase` (ClothPhase: what the simulation builds and the step loop calls), `setup` (the
swept phase's arrays, ClothContact), `kernels` (the swept phase's call), `pairs`, `local`, `cull`,
`narrow`, `ccd`, `response` (its tree search, candidate lists, filters, exact tests and response),
`bench` (a sheet simulation for its tests and measurements).
"""
