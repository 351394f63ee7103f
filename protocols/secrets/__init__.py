"""A swarm's secrets: keys, certificates and access rules of ``swarm keys init``."""
