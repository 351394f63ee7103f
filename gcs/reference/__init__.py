"""``swarm simulate``: the whole swarm in one process, with the same agent core as the distributed
system, its in-memory radio and its report."""
