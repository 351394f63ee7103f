"""What goes over Zenoh: the versioned binary payloads (consensus, batch, status, plan, fault,
round-done) and the key expressions of one swarm."""
