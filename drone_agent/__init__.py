"""The per-drone agent: consensus estimator of the swarm descriptors and cooperative controller."""
