"""A scenario's fault timeline as timed actions on the in-process swarm.

Each fault becomes a start action and, when it has a duration, an end action. Actions act on a
small interface (:class:`FaultTarget`) so the same timeline drives the in-process reference flight
(gcs/reference/flight.py), the ground station (crashes) and each agent process (drop-outs, link
faults): it lives beside the agent so every one of them imports it without reaching up.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from drone_agent.link_faults import LinkFaults
from protocols.scenario import (
    Crash,
    Dropout,
    Fault,
    LinkCut,
    LinkDelay,
    PacketLoss,
    Partition,
    Scenario,
)


class FaultTarget(Protocol):
    """What a fault can act on."""

    @property
    def conditions(self) -> LinkFaults: ...

    def kill_agent(self, drone: int) -> None: ...

    def crash_vehicle(self, drone: int) -> None: ...


@dataclass(frozen=True)
class TimedAction:
    """``apply`` runs once simulated time reaches ``t_s``; ``description`` goes to the events."""

    t_s: float
    description: str
    fault_kind: str
    starts: bool
    apply: Callable[[FaultTarget], None]


def _pairs(drones: tuple[int, int] | None, one_way: bool = False) -> list[tuple[int, int]]:
    if drones is None:
        return []
    i, j = drones
    return [(i, j)] if one_way else [(i, j), (j, i)]


def _window(
    fault: Fault,
    duration_s: float | None,
    start: Callable[[FaultTarget], None],
    end: Callable[[FaultTarget], None],
    text: str,
) -> list[TimedAction]:
    actions = [TimedAction(fault.t_s, text, fault.kind, True, start)]
    if duration_s is not None:
        actions.append(
            TimedAction(fault.t_s + duration_s, f"end of {text}", fault.kind, False, end)
        )
    return actions


def _killer(drone: int) -> Callable[[FaultTarget], None]:
    def apply(t: FaultTarget) -> None:
        t.kill_agent(drone)

    return apply


def _crasher(drone: int) -> Callable[[FaultTarget], None]:
    def apply(t: FaultTarget) -> None:
        t.crash_vehicle(drone)

    return apply


def _link_cut(f: LinkCut) -> list[TimedAction]:
    pairs = _pairs(f.drones, f.one_way)
    way = "one-way " if f.one_way else ""
    text = f"{way}link cut {f.drones[0]}-{f.drones[1]}"

    def start(t: FaultTarget) -> None:
        t.conditions.cut.update(pairs)

    def end(t: FaultTarget) -> None:
        t.conditions.cut.difference_update(pairs)

    return _window(f, f.duration_s, start, end, text)


def _loss(f: PacketLoss) -> list[TimedAction]:
    pairs = _pairs(f.drones)
    where = "all links" if f.drones is None else f"link {f.drones[0]}-{f.drones[1]}"

    def start(t: FaultTarget) -> None:
        if pairs:
            t.conditions.link_loss.update({p: f.probability for p in pairs})
        else:
            t.conditions.loss = f.probability

    def end(t: FaultTarget) -> None:
        if pairs:
            for p in pairs:
                t.conditions.link_loss.pop(p, None)
        else:
            t.conditions.loss = 0.0

    return _window(f, f.duration_s, start, end, f"{f.probability:.0%} loss on {where}")


def _delay(f: LinkDelay, dt_s: float) -> list[TimedAction]:
    pairs = _pairs(f.drones)
    ticks = round(f.delay_ms / 1000.0 / dt_s)
    where = "all links" if f.drones is None else f"link {f.drones[0]}-{f.drones[1]}"

    def start(t: FaultTarget) -> None:
        if pairs:
            t.conditions.link_delay_ticks.update({p: ticks for p in pairs})
        else:
            t.conditions.extra_delay_ticks = ticks

    def end(t: FaultTarget) -> None:
        if pairs:
            for p in pairs:
                t.conditions.link_delay_ticks.pop(p, None)
        else:
            t.conditions.extra_delay_ticks = 0

    text = f"{f.delay_ms:g} ms delay ({ticks} ticks) on {where}"
    return _window(f, f.duration_s, start, end, text)


def _partition(f: Partition, n: int) -> list[TimedAction]:
    groups = dict(enumerate(f.group_ids(n)))

    def start(t: FaultTarget) -> None:
        t.conditions.partition = groups

    def end(t: FaultTarget) -> None:
        t.conditions.partition = None

    return _window(f, f.duration_s, start, end, f"partition {list(map(list, f.groups))}")


def timeline(scenario: Scenario) -> list[TimedAction]:
    """Every fault's actions, in time order (stable for equal times)."""
    actions: list[TimedAction] = []
    dt = scenario.rates.dt_control_s
    for f in scenario.faults:
        if isinstance(f, Dropout):
            text = f"drone {f.drone} agent dropped out"
            actions.append(TimedAction(f.t_s, text, f.kind, True, _killer(f.drone)))
        elif isinstance(f, Crash):
            text = f"drone {f.drone} vehicle crashed"
            actions.append(TimedAction(f.t_s, text, f.kind, True, _crasher(f.drone)))
        elif isinstance(f, LinkCut):
            actions += _link_cut(f)
        elif isinstance(f, PacketLoss):
            actions += _loss(f)
        elif isinstance(f, LinkDelay):
            actions += _delay(f, dt)
        elif isinstance(f, Partition):
            actions += _partition(f, scenario.n_drones)
    return sorted(actions, key=lambda a: a.t_s)
