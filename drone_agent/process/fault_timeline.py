"""A scenario's fault timeline as timed actions on the in-process swarm.

A scenario fault is a drill command with a start time (:mod:`protocols.faults`): at ``t_s`` it
starts, as the operator's drill would (:meth:`~drone_agent.process.link_faults.LinkFaults.apply` for
a link fault, the same method drone_agent/process/fault_drills.py calls), and when it has a
``duration_s`` it ends that much later (:meth:`~drone_agent.process.link_faults.LinkFaults.end`).
Actions act on a small interface (:class:`FaultTarget`) so the same timeline drives the in-process
reference flight (gcs/reference/flight.py), the ground station (crashes) and each agent process
(drop-outs, link faults): it lives beside the agent so every one of them imports it without
reaching up.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from drone_agent.process.link_faults import LinkFaults, delay_ticks
from protocols.faults import Crash, Delay, Dropout, Fault, LinkCut, Loss, Pair, Partition
from protocols.scenario.scenario_file import Scenario


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


def _where(link: Pair | None) -> str:
    return "all links" if link is None else f"link {link[0]}-{link[1]}"


def describe(fault: Fault, dt_s: float) -> str:
    """What ``fault`` does, for the events (``end of`` it when it ends)."""
    if isinstance(fault, Dropout):
        return f"drone {fault.drone} agent dropped out"
    if isinstance(fault, Crash):
        return f"drone {fault.drone} vehicle crashed"
    if isinstance(fault, LinkCut):
        way = "one-way " if fault.one_way else ""
        return f"{way}link cut {fault.i}-{fault.j}"
    if isinstance(fault, Loss):
        return f"{fault.probability:.0%} loss on {_where(fault.link)}"
    if isinstance(fault, Delay):
        ticks = delay_ticks(fault.delay_ms, dt_s)
        return f"{fault.delay_ms:g} ms delay ({ticks} ticks) on {_where(fault.link)}"
    return f"partition {list(map(list, fault.groups))}"


def _start(fault: Fault, dt_s: float) -> Callable[[FaultTarget], None]:
    def start(t: FaultTarget) -> None:
        if isinstance(fault, Dropout):
            t.kill_agent(fault.drone)
        elif isinstance(fault, Crash):
            t.crash_vehicle(fault.drone)
        else:
            t.conditions.apply(fault, dt_s)

    return start


def _end(fault: LinkCut | Loss | Delay | Partition) -> Callable[[FaultTarget], None]:
    def end(t: FaultTarget) -> None:
        t.conditions.end(fault)

    return end


def actions(fault: Fault, dt_s: float) -> list[TimedAction]:
    """The start of ``fault`` at its ``t_s`` and, when it has a duration, its end."""
    text = describe(fault, dt_s)
    out = [TimedAction(fault.t_s, text, fault.kind, True, _start(fault, dt_s))]
    if not isinstance(fault, Dropout | Crash) and fault.duration_s is not None:
        end_s = fault.t_s + fault.duration_s
        out.append(TimedAction(end_s, f"end of {text}", fault.kind, False, _end(fault)))
    return out


def timeline(scenario: Scenario) -> list[TimedAction]:
    """Every fault's actions, in time order (stable for equal times)."""
    dt = scenario.rates.dt_control_s
    return sorted((a for f in scenario.faults for a in actions(f, dt)), key=lambda a: a.t_s)
