"""Ground station, operator CLI, in-process reference flight, logs, metrics and plots."""
