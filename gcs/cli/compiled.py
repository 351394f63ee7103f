"""Loading the compiled loops (numba) before a command flies, and saying so when it compiled."""

from __future__ import annotations

import sys
import time
from pathlib import Path


def warm_compiled(
    command: str, sim: bool, agents: bool, scenario: Path, *, links: bool = False
) -> None:
    """Load the compiled loops of what ``command`` runs here (the simulator's physics, the
    agents' core for ``scenario``, with ``links`` the simulator's telemetry framing), or, on the
    first run after an install or an edit, compile them (numba, cached beside the sources): once,
    before the flight or its processes start, and not silently (a first compile takes ~15 s)."""
    started = time.monotonic()
    if sim:
        from sitl_sim.physics import jit as physics_jit

        physics_jit.ready()
    if links:  # the simulator's MAVLink links (its telemetry framing)
        from sitl_sim.mavlink_edge import telemetry_out

        telemetry_out.warm()
    if agents:
        from drone_agent.core.agent_core import warm_up
        from drone_agent.core.config import agent_config
        from protocols.scenario.scenario_file import load_scenario

        try:
            config = agent_config(load_scenario(scenario))
        except (OSError, ValueError):  # the agents will say what is wrong with it
            config = None
        if config is not None:
            warm_up(config)
    took = time.monotonic() - started
    if took > 2.0:
        print(f"{command}: compiled the simulator's and agents' maths ({took:.0f} s, once)",
              file=sys.stderr)  # fmt: skip
