"""The stage benchmarks run by `python -m pipeline bench` (pipeline.bench.BENCHES): each module's
`run_benchmark()` returns a dict of figures. They live here, not beside their stages, because a
benchmark builds whole scenes the way `pipeline` does; stages never import `pipeline`."""
