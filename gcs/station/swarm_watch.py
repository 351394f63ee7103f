"""What the ground station knows of each drone, and the ``swarm status`` table. Pure: fed with
decoded agent statuses, liveliness changes, vehicle texts and the vehicles' telemetry state, it
keeps the newest status, who is alive, link quality and failsafe counts, and says which events to
log; the ground station does the I/O.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gcs.station.telemetry import VehicleState
from protocols.mavlink.conventions import MavSeverity
from protocols.model.descriptors import descriptors
from protocols.wire.status import AgentStatus, Health

_CRASH_WORDS = ("crash", "destroyed", "all motors off")
#: Smoothing of the link quality: weight of the newest status (about ten statuses).
_LINK_SMOOTHING = 0.1


def text_kind(severity: int, text: str) -> str:
    """The event kind of a vehicle's STATUSTEXT: ``crash`` (MAV_SEVERITY_EMERGENCY, motors off,
    destroyed), ``failsafe``, ``overload`` (its agent answers too few ticks in time, realtime:
    sitl_sim/vehicle/tick_answers.py) or ``vehicle_text``."""
    lower = text.lower()
    if severity == MavSeverity.EMERGENCY or any(w in lower for w in _CRASH_WORDS):
        return "crash"
    if lower.startswith("agent late"):
        return "overload"
    return "failsafe" if "failsafe" in lower else "vehicle_text"


@dataclass
class SwarmWatch:
    """Per-drone bookkeeping of the ground station (see the module doc)."""

    latest: dict[int, AgentStatus] = field(default_factory=dict)
    alive: set[int] = field(default_factory=set)
    #: drone -> share of the expected consensus messages received (smoothed, 0..1)
    link_quality: dict[int, float] = field(default_factory=dict)
    #: drone -> failsafes its vehicle reported
    failsafes: dict[int, int] = field(default_factory=dict)
    #: the radio's communication range (m); None: expect only the neighbours the agent lists
    range_m: float | None = None
    #: drone -> (simulated time s, why): drones lost to a crash or whose agent went away; they
    #: keep their row in the table with this
    lost: dict[int, tuple[float, str]] = field(default_factory=dict)
    _smoothed_share: dict[int, float] = field(default_factory=dict, repr=False)

    def on_status(
        self, status: AgentStatus, vehicles: Mapping[int, VehicleState] | None = None
    ) -> str | None:
        """Take an agent's status (:meth:`on_statuses` with one)."""
        return self.on_statuses([status], vehicles)[0]

    def on_statuses(
        self, statuses: Sequence[AgentStatus], vehicles: Mapping[int, VehicleState] | None = None
    ) -> list[str | None]:
        """Take agents' statuses, in order; updates each one's link quality: messages received
        since its last status over those the drones in its radio range should have sent, one per
        drone per round (:meth:`senders`, counted for the whole batch at once). Returns, for each,
        the event to log when its separation layer starts or stops changing its command
        (``separation``, ``separation_end``), else None."""
        counts = self._sender_counts([s.drone for s in statuses], vehicles)
        events: list[str | None] = []
        for status in statuses:
            before = self.latest.get(status.drone)
            self.latest[status.drone] = status
            was = before is not None and Health.SEPARATING in before.health
            now = Health.SEPARATING in status.health
            events.append(None if was == now else "separation" if now else "separation_end")
            if before is None or status.round <= before.round:
                continue
            senders = counts.get(status.drone, len(status.neighbours))
            if not senders:
                continue
            expected = (status.round - before.round) * senders
            # clipped only for showing: a message counted just after one status instead of just
            # before makes one share low and the next high, and clipping those would bias it low
            share = max(0.0, (status.counters.rx - before.counters.rx) / expected)
            old = self._smoothed_share.get(status.drone, share)
            new = self._smoothed_share[status.drone] = old + _LINK_SMOOTHING * (share - old)
            self.link_quality[status.drone] = min(1.0, new)
        return events

    def senders(
        self, status: AgentStatus, vehicles: Mapping[int, VehicleState] | None = None
    ) -> int:
        """How many drones should be heard by ``status.drone``: the other alive drones whose
        vehicles are within :attr:`range_m` of its vehicle. Without the range or the positions,
        the neighbours the agent integrated this round (which also fall when messages are lost,
        so the share then hides loss)."""
        counts = self._sender_counts([status.drone], vehicles)
        return counts.get(status.drone, len(status.neighbours))

    def _sender_counts(
        self, drones: Sequence[int], vehicles: Mapping[int, VehicleState] | None
    ) -> dict[int, int]:
        """:meth:`senders` of each of ``drones`` whose vehicle's position is known, all pairs at
        once (one numpy pass for a process's batch of statuses, not a Python loop over every
        vehicle for each status)."""
        if self.range_m is None or vehicles is None:
            return {}
        known = [
            (j, v.position_ned_m)
            for j, v in vehicles.items()
            if v.position_ned_m is not None and (j in self.alive or not self.alive)
        ]
        asked = [(d, vehicles[d].position_ned_m) for d in set(drones) if d in vehicles]
        mine = [(d, p) for d, p in asked if p is not None]
        if not mine:
            return {}
        ids = np.array([j for j, _ in known], dtype=np.int64)
        here = np.array([p for _, p in mine], dtype=np.float64).reshape(-1, 3)
        there = np.array([p for _, p in known], dtype=np.float64).reshape(-1, 3)
        near = np.linalg.norm(here[:, None, :] - there[None, :, :], axis=2) < self.range_m
        near &= ids[None, :] != np.array([d for d, _ in mine], dtype=np.int64)[:, None]
        return dict(zip((d for d, _ in mine), near.sum(axis=1).tolist(), strict=True))

    def on_liveliness(self, drone: int, alive: bool, t_s: float = math.nan) -> str | None:
        """A liveliness change at simulated time ``t_s``; the event to log (``agent_joined``,
        ``dropout_detected``) or None if nothing changed. A drone whose agent goes is marked
        lost (unless it already is, e.g. by its crash); one that comes back is not."""
        if alive and drone not in self.alive:
            self.alive.add(drone)
            self.lost.pop(drone, None)
            return "agent_joined"
        if not alive and drone in self.alive:
            self.alive.discard(drone)
            self.lost.setdefault(drone, (t_s, "its agent left the swarm"))
            return "dropout_detected"
        return None

    def on_vehicle_text(self, drone: int, severity: int, text: str, t_s: float = math.nan) -> str:
        """A vehicle's STATUSTEXT at ``t_s``; its event kind (:func:`text_kind`), failsafes
        counted, a crash marks the drone lost."""
        kind = text_kind(severity, text)
        if kind == "failsafe":
            self.failsafes[drone] = self.failsafes.get(drone, 0) + 1
        if kind == "crash":
            self.lost[drone] = (t_s, f"vehicle crashed: {text}")
        return kind

    def positions(self, vehicles: Mapping[int, VehicleState]) -> np.ndarray | None:
        """Positions (N, 3) NED m of the alive drones' vehicles (every vehicle before any agent
        joined); None with fewer than two."""
        positions = [
            v.position_ned_m
            for i, v in sorted(vehicles.items())
            if v.position_ned_m is not None and (i in self.alive or not self.alive)
        ]
        return np.array(positions, dtype=float) if len(positions) >= 2 else None

    def truth(self, vehicles: Mapping[int, VehicleState]) -> np.ndarray | None:
        """True descriptors (9,) of :meth:`positions`; None with fewer than two positions."""
        positions = self.positions(vehicles)
        return None if positions is None else descriptors(positions)

    def table(self, vehicles: Mapping[int, VehicleState]) -> list[dict[str, Any]]:
        """One row per drone heard: mode, armed, position (NED m), centre estimate error (m), its
        agent's estimate of the descriptors (9, m, rad, m²) and the time of its status (s),
        neighbours, link quality (0..1), failsafes reported by its vehicle, message counters. A
        lost drone keeps its row: mode ``LOST`` and ``lost`` = {t_s, reason}."""
        truth = self.truth(vehicles)
        rows = []
        for i in sorted(set(vehicles) | set(self.latest)):
            v, s = vehicles.get(i), self.latest.get(i)
            err = None
            lost = self.lost.get(i) if i not in self.alive else None
            if s is not None and truth is not None and lost is None:
                err = float(np.linalg.norm(s.estimate[:3] - truth[:3]))
            mode = "LOST" if lost is not None else s.mode.name if s is not None else None
            rows.append(
                {
                    "drone": i,
                    "alive": i in self.alive,
                    "mode": mode,
                    "lost": None if lost is None else {"t_s": lost[0], "reason": lost[1]},
                    "armed": v.armed if v is not None else (s.armed if s else None),
                    "position_ned_m": list(v.position_ned_m) if v and v.position_ned_m else None,
                    "estimate_error_m": err if err is None or math.isfinite(err) else None,
                    "estimate": [float(x) for x in s.estimate] if s is not None else None,
                    "t_s": s.t_s if s is not None else None,
                    "neighbours": list(s.neighbours) if s is not None else [],
                    "link_quality": self.link_quality.get(i),
                    "failsafes": self.failsafes.get(i, 0),
                    "rx": s.counters.rx if s else 0,
                    "tx": s.counters.tx if s else 0,
                    "rx_dropped": (
                        s.counters.rx_dropped_malformed + s.counters.rx_dropped_wrong_swarm
                        if s
                        else 0
                    ),
                    # what the radio's limits dropped on the way (not in rx)
                    "rx_lost_radio": s.counters.rx_lost_radio if s else 0,
                }
            )
        return rows

    def worst_error_m(self, vehicles: Mapping[int, VehicleState]) -> float | None:
        """The largest centre estimate error (m) among alive agents; None if unknown."""
        errors = [r["estimate_error_m"] for r in self.table(vehicles) if r["alive"]]
        finite = [e for e in errors if e is not None]
        return max(finite) if finite else None
