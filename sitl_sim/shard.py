"""A simulator shard: ``swarm sim --drones LO-HI`` serves drones LO..HI of a swarm only.

Drone ``d`` keeps its identity in every shard: system id ``d + 1`` and UDP port
``vehicle_port(d)`` (so an agent finds its vehicle whichever shard serves it, on that shard's
host), its scenario position, and the scenario's crash faults of the drones in the range. Vehicles
do not touch each other in the simulator (no collision physics), so shards need nothing from each
other under the realtime clock but one clock: each paces to the wall clock from tick 0, which
every shard runs at the same agreed Unix time (``--start-at``; hosts' clocks synchronised, as
NTP keeps them). A shard that falls behind re-bases its pace (sitl_sim/pacing.py) and from then
on lags the others: keep each shard's load within its host's means.

Lockstep across shards (sitl_sim/shard_sync.py, ``--shard-sync HOST:PORT --shard-peers
LIST``): each shard's barrier holds only its own agents, so the shards also agree on every tick
over UDP: a shard steps to k + 1 once every shard holds tick k's setpoints of its live agents.
The agents' consensus then sees the same rounds across shards, as with one simulator.
"""

from __future__ import annotations

from dataclasses import dataclass

from sitl_sim.sim_config import SimConfigError


@dataclass(frozen=True)
class DroneRange:
    """Drones ``first``..``last`` (0-based, inclusive) of a swarm."""

    first: int
    last: int

    @property
    def count(self) -> int:
        return self.last - self.first + 1

    def __contains__(self, drone: object) -> bool:
        return isinstance(drone, int) and self.first <= drone <= self.last


def parse_drones(text: str) -> tuple[int | None, DroneRange | None]:
    """``--drones`` as a count ``N`` (None, no range) or a range ``LO-HI`` (None, range)."""
    text = text.strip()
    if text.isdigit():
        return int(text), None
    lo, sep, hi = text.partition("-")
    if sep and lo.strip().isdigit() and hi.strip().isdigit():
        first, last = int(lo), int(hi)
        if first <= last:
            return None, DroneRange(first, last)
    raise SimConfigError(f"--drones {text!r}: a count N or a range of drone indices LO-HI")
