"""The SITL simulator: N quadcopters' 6-DOF dynamics, each one's autopilot, and its MAVLink edge.

- ``physics``: parameters, the per-vehicle rules written once (attitude controller, mixer, rotor
  wrench, rigid body, ground contact) and their compiled kernel. Pure.
- ``vehicle``: each vehicle's autopilot (modes, arming, guidance, failsafe, setpoint checks,
  battery, tunables, the ArduCopter flight core) and the world of N vehicles. Pure.
- ``mavlink_edge``: what a vehicle sends and how it answers what it receives, per autopilot
  dialect; streams, map telemetry, channels and sockets (pymavlink as a codec only).
- here: the event loop under either clock (``server``), the lockstep barrier (``lockstep``,
  ``shard_sync``), pacing, shards, and ``swarm sim`` (``sim_config``, ``launch``, ``sim_cli``).
"""
