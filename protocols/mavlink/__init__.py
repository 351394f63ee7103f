"""MAVLink as every role speaks it: conventions (states, severities, modes per autopilot
dialect, ports, lockstep handshake), fast framing, signing, the vehicles' clock."""
