"""The ground-station process (``swarm gcs``): plan server, operator commands and the planner,
drills, MAVLink telemetry in, and what it knows of each drone."""
