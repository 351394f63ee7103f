"""The agent at run time: its vehicle link (one class per autopilot dialect), hosting one or
many agents in a process, the lockstep round gate, the transport over the bus and the link
faults on its receive side (live drills, a scenario's timed faults), ``swarm agent``."""
