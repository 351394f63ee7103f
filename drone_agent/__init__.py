"""The per-drone agent: consensus estimator of the swarm descriptors and cooperative controller.

- ``core``: pure and batched (consensus, moments, controller, separation, flight phases).
- ``process``: the agent at run time (vehicle link per dialect, host, round gate, transport, the
  link faults on its receive side, ``swarm agent``).
"""
