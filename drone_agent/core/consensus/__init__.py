"""The consensus estimator of the swarm descriptors (ALGORITHM.md §3): params (the rules),
estimator, message packing, compiled kernels, and the per-agent scalar form."""
