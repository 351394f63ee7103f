"""The fault timeline of a scenario: what can go wrong, when, and for how long.

Drone indices are 0-based (MAVLink system id = index + 1); times are simulated seconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar


@dataclass(frozen=True)
class Dropout:
    """Drone ``drone``'s agent dies at ``t_s`` (s), e.g. its process is killed."""

    kind: ClassVar[str] = "dropout"
    t_s: float
    drone: int


@dataclass(frozen=True)
class Crash:
    """Drone ``drone``'s motors stop at ``t_s`` (s)."""

    kind: ClassVar[str] = "crash"
    t_s: float
    drone: int


@dataclass(frozen=True)
class LinkCut:
    """The link between ``drones`` (i, j) is cut from ``t_s`` for ``duration_s`` (None: to the
    end); ``one_way``: only messages i -> j are cut."""

    kind: ClassVar[str] = "link_cut"
    t_s: float
    drones: tuple[int, int]
    duration_s: float | None = None
    one_way: bool = False


@dataclass(frozen=True)
class PacketLoss:
    """Messages are lost with ``probability`` from ``t_s`` for ``duration_s`` (None: to the end),
    on the link ``drones`` (i, j) both ways, or on every link when None."""

    kind: ClassVar[str] = "loss"
    t_s: float
    probability: float
    duration_s: float | None = None
    drones: tuple[int, int] | None = None


@dataclass(frozen=True)
class LinkDelay:
    """Messages are delayed by ``delay_ms`` (ms) from ``t_s`` for ``duration_s`` (None: to the
    end), on the link ``drones`` (i, j) both ways, or on every link when None."""

    kind: ClassVar[str] = "delay"
    t_s: float
    delay_ms: float
    duration_s: float | None = None
    drones: tuple[int, int] | None = None


@dataclass(frozen=True)
class Partition:
    """From ``t_s`` for ``duration_s`` (None: to the end) only drones of one group hear each
    other; drones listed in no group form one more group."""

    kind: ClassVar[str] = "partition"
    t_s: float
    groups: tuple[tuple[int, ...], ...]
    duration_s: float | None = None

    def group_ids(self, n_drones: int) -> tuple[int, ...]:
        """The group of each drone 0..n_drones-1 (unlisted drones: ``len(groups)``)."""
        ids = [len(self.groups)] * n_drones
        for g, members in enumerate(self.groups):
            for i in members:
                ids[i] = g
        return tuple(ids)


Fault = Dropout | Crash | LinkCut | PacketLoss | LinkDelay | Partition
