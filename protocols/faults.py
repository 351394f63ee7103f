"""The one fault vocabulary: what an operator's drill sends and what a scenario schedules.

A scenario fault is a drill command with a start time: each class below is a command, and its
``t_s`` (simulated s from the scenario's start) says when a scenario applies it. A drill sent live
applies when it arrives: its ``t_s`` stays 0 and does not travel (``protocols.wire.fault``
encodes and decodes these same classes). Each class's ``kind`` is its name in a scenario file,
in the drill logs and, upper-cased, of its wire op.

Drone indices are 0-based (MAVLink system id = index + 1). A link ``(i, j)`` is two drone
indices; link faults act on it both ways unless a cut is ``one_way`` (i -> j only). A
``duration_s`` of None lasts until changed; a timed fault undoes itself ``duration_s`` s after
it started (``drone_agent.process.link_faults.LinkFaults.apply`` and ``end``: the one rule by which
the scenario timeline and the operator's drills act on the radio).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

Pair = tuple[int, int]


@dataclass(frozen=True)
class Clear:
    """No link faults any more."""

    kind: ClassVar[str] = "clear"
    t_s: float = 0.0


@dataclass(frozen=True)
class LinkCut:
    """Cut the link i-j (only i -> j when ``one_way``) for ``duration_s`` s (None: until
    restored)."""

    kind: ClassVar[str] = "link_cut"
    i: int
    j: int
    one_way: bool = False
    duration_s: float | None = None
    t_s: float = 0.0

    @property
    def link(self) -> Pair:
        """The link ``(i, j)``."""
        return self.i, self.j


@dataclass(frozen=True)
class LinkRestore:
    """Restore the link i-j, both ways."""

    kind: ClassVar[str] = "link_restore"
    i: int
    j: int
    t_s: float = 0.0

    @property
    def link(self) -> Pair:
        """The link ``(i, j)``."""
        return self.i, self.j


@dataclass(frozen=True)
class Loss:
    """Packet loss ``probability`` (0..1) on ``link`` (both ways) or on every link (None), for
    ``duration_s`` s (None: until changed). When it ends, the link loses at the every-link rate
    again (the every-link loss ends at 0)."""

    kind: ClassVar[str] = "loss"
    probability: float
    link: Pair | None = None
    duration_s: float | None = None
    t_s: float = 0.0


@dataclass(frozen=True)
class Delay:
    """Added delay ``delay_ms`` (ms >= 0, flown as whole control ticks) on ``link`` (both ways)
    or on every link (None), for ``duration_s`` s (None: until changed). When it ends, the link
    is delayed as every link again (the every-link delay ends at 0)."""

    kind: ClassVar[str] = "delay"
    delay_ms: float
    link: Pair | None = None
    duration_s: float | None = None
    t_s: float = 0.0


@dataclass(frozen=True, init=False)
class Partition:
    """Split the swarm into ``groups`` of drone ids for ``duration_s`` s (None: until healed):
    only drones of one group hear each other, and drones listed in no group form one more
    group. No groups (``Partition(None)`` or ``Partition(())``) heals the partition."""

    kind: ClassVar[str] = "partition"
    groups: tuple[tuple[int, ...], ...]
    duration_s: float | None = None
    t_s: float = 0.0

    def __init__(
        self,
        groups: tuple[tuple[int, ...], ...] | None,
        duration_s: float | None = None,
        t_s: float = 0.0,
    ) -> None:
        object.__setattr__(self, "groups", groups or ())
        object.__setattr__(self, "duration_s", duration_s)
        object.__setattr__(self, "t_s", t_s)

    @property
    def heals(self) -> bool:
        """Whether this heals the partition (no groups)."""
        return not self.groups

    def group_ids(self, n_drones: int) -> tuple[int, ...]:
        """The group of each drone 0..n_drones-1 (unlisted drones: ``len(groups)``)."""
        ids = [len(self.groups)] * n_drones
        for g, members in enumerate(self.groups):
            for i in members:
                ids[i] = g
        return tuple(ids)


@dataclass(frozen=True)
class Restart:
    """Kill drone ``drone``'s agent and start a new one ``gap_s`` simulated s later."""

    kind: ClassVar[str] = "restart"
    drone: int
    gap_s: float
    t_s: float = 0.0


@dataclass(frozen=True)
class Dropout:
    """Kill drone ``drone``'s agent, for good (e.g. its process dies)."""

    kind: ClassVar[str] = "dropout"
    drone: int
    t_s: float = 0.0


@dataclass(frozen=True)
class Crash:
    """Stop drone ``drone``'s motors. A vehicle fault: the simulator (a scenario) or the ground
    station (its crash drill, MAV_CMD_INJECT_FAILURE) carries it out; it is not sent to the
    agents."""

    kind: ClassVar[str] = "crash"
    drone: int
    t_s: float = 0.0


LinkFault = Clear | LinkCut | LinkRestore | Loss | Delay | Partition
"""What acts on the radio (``drone_agent.process.link_faults.LinkFaults.apply``)."""

FaultCommand = LinkFault | Restart | Dropout
"""What the agents' fault topic carries (``protocols.wire.fault``)."""

Fault = Dropout | Crash | LinkCut | Loss | Delay | Partition
"""What a scenario schedules (``[[faults]] kind``)."""
