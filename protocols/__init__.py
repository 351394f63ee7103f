"""What every quadswarm role shares, importing nothing else of the project.

- ``model``: frames and rotations, the descriptor vector and descriptors, the trajectory, geodesy.
- ``wire``: the Zenoh payloads and the key expressions of a swarm.
- ``mavlink``: MAVLink conventions, fast framing, signing, the vehicles' clock.
- ``scenario``: scenario files, their schema and the generator.
- ``secrets``: keys, certificates and access rules.
- ``bus``: the message bus (Zenoh and its in-memory twin), Zenoh settings, the rendezvous port.
- ``faults``: the one fault vocabulary of drills and scenarios.
- ``runtime``: numba through one helper, cheap frozen dataclasses, the flight's garbage collector.
"""
