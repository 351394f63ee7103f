"""The simulator's MAVLink edge (pymavlink as a codec only): messages out, commands and
dispatch in, dialects on the wire, streams, map telemetry, channels and sockets."""
