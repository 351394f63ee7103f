"""Live link-fault drills: fault commands from ``swarm/<sid>/fault`` applied to an agent process's
:class:`~drone_agent.process.link_faults.LinkFaults`.

The bus callback only queues the raw payload (it runs on the bus's thread); :meth:`FaultDrills.
poll`, called from the agents' loop thread, decodes them and starts each as a scenario starts its
faults (:meth:`LinkFaults.apply <drone_agent.process.link_faults.LinkFaults.apply>`), and ends timed
ones (``duration_s``, :meth:`LinkFaults.end <drone_agent.process.link_faults.LinkFaults.end>`) once
the simulated time (control round x period) has passed their end. Malformed payloads are counted
and ignored.
"""

from __future__ import annotations

import heapq
import itertools
import sys
import threading
from collections import deque
from collections.abc import Callable

from drone_agent.process.link_faults import LinkFaults
from protocols.bus.interface import Bus, Closeable
from protocols.faults import (
    Clear,
    Delay,
    Dropout,
    FaultCommand,
    LinkCut,
    LinkFault,
    LinkRestore,
    Loss,
    Partition,
    Restart,
)
from protocols.wire.fault import decode_fault
from protocols.wire.format import WireError
from protocols.wire.keys import SwarmKeys

#: Most payloads kept between two polls; older ones are dropped (and counted as malformed).
MAX_QUEUED = 256


def _stderr(line: str) -> None:
    print(f"agents: {line}", file=sys.stderr, flush=True)


def describe(command: FaultCommand) -> str:
    """One line saying what ``command`` does, for logs."""
    if isinstance(command, LinkCut):
        arrow = "->" if command.one_way else "<->"
        until = f" for {command.duration_s:g} s" if command.duration_s else ""
        return f"link_cut {command.i}{arrow}{command.j}{until}"
    if isinstance(command, LinkRestore):
        return f"link_restore {command.i}<->{command.j}"
    if isinstance(command, Loss):
        where = f" on {command.link[0]}<->{command.link[1]}" if command.link else ""
        until = f" for {command.duration_s:g} s" if command.duration_s else ""
        return f"loss {command.probability:g}{where}{until}"
    if isinstance(command, Delay):
        where = f" on {command.link[0]}<->{command.link[1]}" if command.link else ""
        until = f" for {command.duration_s:g} s" if command.duration_s else ""
        return f"delay {command.delay_ms:g} ms{where}{until}"
    if isinstance(command, Restart):
        return f"restart drone {command.drone} after {command.gap_s:g} s"
    if isinstance(command, Dropout):
        return f"dropout of drone {command.drone}'s agent"
    if isinstance(command, Partition):
        if command.heals:
            return "partition healed"
        until = f" for {command.duration_s:g} s" if command.duration_s else ""
        return "partition " + "/".join(",".join(map(str, g)) for g in command.groups) + until
    return "clear"


class FaultDrills:
    """Applies the fault commands of swarm ``swarm_id`` to ``faults``; ``period_s`` is the control
    period (s) and ``round_clock()`` the current control round, so simulated time is their
    product. ``log(line)`` (default: stderr) reports each command applied or rejected;
    ``restart(drone, gap_s)`` carries out a restart drill and ``kill(drone)`` a dropout drill of
    a hosted agent (the process's agent host; a drone it does not host is left alone)."""

    def __init__(
        self,
        bus: Bus,
        swarm_id: str,
        faults: LinkFaults,
        period_s: float,
        round_clock: Callable[[], int],
        log: Callable[[str], None] | None = None,
        restart: Callable[[int, float], None] | None = None,
        kill: Callable[[int], None] | None = None,
    ) -> None:
        self._faults, self._period_s, self._clock = faults, period_s, round_clock
        self._restart = restart
        self._kill = kill
        self._log = log or _stderr
        self._swarm_id = swarm_id
        self._queue: deque[bytes] = deque()
        self._lock = threading.Lock()
        #: timed faults to end: (end time s, arrival order, command)
        self._undo: list[tuple[float, int, LinkFault]] = []
        self._order = itertools.count()
        self.applied = 0
        self.malformed = 0
        self._overflow = 0
        key = SwarmKeys(swarm_id, 1.0).fault
        self._sub: Closeable = bus.subscribe_callback(key, self._on_sample)

    def _on_sample(self, _key: str, payload: bytes) -> None:
        with self._lock:
            if len(self._queue) >= MAX_QUEUED:
                self._overflow += 1
                return
            self._queue.append(bytes(payload))

    def poll(self) -> None:
        """Decode and apply the queued commands; undo the timed faults that have ended."""
        t_s = self._clock() * self._period_s
        while self._undo and self._undo[0][0] <= t_s:
            self._faults.end(heapq.heappop(self._undo)[2])
        if not self._queue:  # the usual case: nothing to do, no lock taken
            return
        with self._lock:
            payloads, overflow = list(self._queue), self._overflow
            self._queue.clear()
            self._overflow = 0
        self.malformed += overflow
        for payload in payloads:
            try:
                command = decode_fault(payload, self._swarm_id)
            except WireError as exc:
                self.malformed += 1
                self._log(f"fault drill ignored ({exc}); {self.malformed} malformed so far")
                continue
            self.applied += 1
            self._log(f"fault drill at t={t_s:.2f}s: {describe(command)}")
            self._apply(command, t_s)

    def _apply(self, command: FaultCommand, t_s: float) -> None:
        if isinstance(command, Restart):
            if self._restart is not None:
                self._restart(command.drone, command.gap_s)
        elif isinstance(command, Dropout):
            if self._kill is not None:
                self._kill(command.drone)
        else:
            self._faults.apply(command, self._period_s)
            if isinstance(command, Clear):
                self._undo.clear()
            elif not isinstance(command, LinkRestore) and command.duration_s is not None:
                heapq.heappush(self._undo, (t_s + command.duration_s, next(self._order), command))

    def close(self) -> None:
        """Stop listening for fault commands."""
        self._sub.close()
