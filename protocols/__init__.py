"""What the quadswarm processes share: frames and units, the descriptor vector, the trajectory
format, scenario files, and (later) message schemas and MAVLink conventions."""
