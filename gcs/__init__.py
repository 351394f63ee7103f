"""The ground side of a swarm, by concern:

- :mod:`gcs.cli` — the ``swarm`` command line: one module per command (``up``, ``gcs``, ``drill``,
  ``scenario``, ``view``, operator commands, ...) and ``swarm up``'s process supervisor;
- :mod:`gcs.station` — the ground-station process: plan server, operator commands and planner,
  drills, MAVLink telemetry, what it knows of each drone;
- :mod:`gcs.reference` — ``swarm simulate``: the whole swarm in one process (the in-process
  reference flight and its radio);
- :mod:`gcs.report` — a flight's report: flight.tlog, events.jsonl, metrics, plots, summaries;
- :mod:`gcs.view` — the 3-D view and flight.rrd in Rerun (optional extra ``quadswarm[view]``).
"""
