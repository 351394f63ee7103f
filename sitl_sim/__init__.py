"""The SITL simulator: vectorised 6-DOF quadcopter dynamics and each vehicle's inner loop.

Pure core (numpy, no I/O, no clock):
``vehicle_params``, ``dynamics``, ``attitude_control``, ``mixer``, ``inner_loop``, ``failsafe``
(the flight core); ``setpoint`` (offboard setpoint validation), ``autopilot`` (modes, arming,
failsafe and crash state machines of N vehicles), ``guidance`` (what each autopilot asks of its
inner loop per physics step), ``world`` (N vehicles stepped at the physics rate), ``tunables``
(the parameter table), ``streams`` (message-interval bookkeeping), ``lockstep`` (the barrier),
``pacing`` (wall-clock pacing and the real-time factor), ``copter`` (the ArduCopter dialect's
autopilot and guidance).

MAVLink edge (pymavlink as a codec only): ``messages`` (what a vehicle sends), ``commands``
(COMMAND_LONG/INT and SET_MODE), ``dispatch`` (inbound routing, checks, counters), ``dialect``
(PX4 or ArduCopter on the wire, chosen once; ``copter_messages``), ``channel``
(UDP endpoints, batching, signing), ``network`` (the sockets), ``server`` (the event loop under
either clock). ``swarm sim``: ``sim_config``, ``launch`` and ``sim_cli``.
"""
