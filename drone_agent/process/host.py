"""Hosting agents: one process runs one or several drones' agents on one event loop.

Each hosted agent keeps its own vehicle link, its own keys, liveliness token and estimator state,
and hears its siblings as it hears remote agents (its own range, faults and counters; the
process's one consensus hub hands their messages over directly instead of through Zenoh); the
agents of one process share one Zenoh session (issue 4, "Hosting for scale"). Their cores are the
rows of one
:class:`~drone_agent.core.agent_core.BatchAgentCore`: on each pass the agents due at the same tick
(same tick number and vehicle time: one simulator drives them, so their samples of a tick arrive
together) run in one batched call, between each agent's own :meth:`HostedAgent.prepare` (messages,
neighbour wait, plan) and :meth:`HostedAgent.act` (flight phase and setpoint for every agent
of the pass first, then their messages: :meth:`HostedAgent.publish`); their readiness to leave
the ground is updated in one call too. An agent
joins the swarm (declares its transport and token) once its vehicle has answered, since its
position names its spatial cell. In lockstep the process's
:class:`~drone_agent.process.round_gate.RoundBook` publishes, after each pass, the round-done
markers of the rounds its agents finished in it (drone_agent/process/round_gate.py).

Restart (``swarm drill restart``, :meth:`AgentHost.restart`): a drone's agent is killed as a
drop-out kills it (its token goes, it sends nothing more: its vehicle's failsafe takes over) and,
once its vehicle's simulated time has moved on by the gap, a new agent of that drone joins: a new
transport and token, a new flight phase, and its estimator row started afresh
(:meth:`~drone_agent.core.consensus.estimator.BatchConsensus.restart`: a new incarnation, so that
its neighbours start fresh edges with it). The same as starting ``swarm agent`` again for that
drone, without touching the other agents of the process.
"""

from __future__ import annotations

import selectors
import threading
import time
from collections.abc import Callable, Sequence
from contextlib import suppress
from dataclasses import dataclass

import numpy as np

from drone_agent.core.agent_core import AgentConfig, AgentCore, BatchAgentCore
from drone_agent.core.flight_phase import (
    Arrivals,
    BatchFlightPhase,
    BatchReadiness,
    BatchTakeoff,
    FlightPhase,
    Readiness,
    TakeoffClock,
)
from drone_agent.core.inboxes import Inboxes
from drone_agent.process.hosted_agent import DueTick, HostedAgent, RunOptions
from drone_agent.process.round_gate import RoundBook, RoundGate
from drone_agent.process.transport import AgentTransport, Position
from drone_agent.process.transport_link import ConsensusHub
from drone_agent.process.vehicle_link import VehicleLink
from protocols.bus.interface import Bus
from protocols.model.trajectory import DescriptorTrajectory

TransportFactory = Callable[[Bus, int, Position], AgentTransport]
#: Lockstep: with no tick computed for this long (wall s), re-send the newest round markers.
REPEAT_MARKERS_S = 0.2
#: Lockstep: while no vehicle sample, marker or liveliness change comes in, the agents are looked
#: at (heartbeats, timeouts, the gates' grace periods) only this often (wall s).
IDLE_PASS_S = 0.02
#: A restarted drone's new port first greets its vehicle this long (wall s) after the old port
#: closed: longer than the simulator's re-send period (0.25 s), so that it has seen the old port
#: closed (and stopped waiting for it) before a new address speaks for the vehicle.
REGREET_DELAY_S = 0.6
#: The longest (wall s) a pass waits for the rest of a tick's vehicle samples once the first
#: came in (:meth:`AgentHost._gather`): the simulator sends them back to back.
GATHER_S = 0.002


class DroneIdError(ValueError):
    """A --drone-id that is not an index, a range ``A-B`` or a comma-separated list."""


def parse_drone_ids(text: str, max_drones: int = 250) -> list[int]:
    """``"3"``, ``"0-24"``, ``"0,2,5-7"`` -> sorted unique 0-based indices."""
    ids: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        try:
            if "-" in part:
                lo_text, hi_text = part.split("-", 1)
                lo, hi = int(lo_text), int(hi_text)
                if hi < lo:
                    raise DroneIdError(f"drone range {part!r} runs backwards")
                ids.update(range(lo, hi + 1))
            else:
                ids.add(int(part))
        except ValueError as exc:
            if isinstance(exc, DroneIdError):
                raise
            raise DroneIdError(
                f"drone id {part!r} is not an index, a range like 0-24 or a list like 0,3,5"
            ) from None
    bad = [i for i in ids if not 0 <= i < max_drones]
    if bad:
        raise DroneIdError(f"drone index {bad[0]} is outside 0..{max_drones - 1}")
    return sorted(ids)


@dataclass
class _Slot:
    """A drone this process hosts: its vehicle link, and its agent once it has joined."""

    drone: int
    link: VehicleLink
    agent: HostedAgent | None = None
    greeted_at: float = -1e9
    left_reported: bool = False
    #: the newest vehicle time heard (ms)
    newest_ms: int = -1
    #: a restart drill: the vehicle time (ms) at which a new agent starts
    revive_at_ms: int | None = None


class AgentHost:
    """Runs the agents of ``drones`` until :meth:`stop` or until every agent has left."""

    def __init__(
        self,
        drones: Sequence[int],
        links: Sequence[VehicleLink],
        bus: Bus,
        transport_factory: TransportFactory,
        config: AgentConfig,
        fallback_plan: DescriptorTrajectory | None,
        options: RunOptions,
        wall_clock: Callable[[], float] = time.monotonic,
        rounds: RoundBook | None = None,
        roster: Sequence[int] = (),
        hub: ConsensusHub | None = None,
    ) -> None:
        """``rounds`` and ``roster`` (the drones expected from the first tick on, e.g. the
        scenario's) are needed in lockstep (``options.lockstep``). ``hub``: the process's
        consensus hub, if its agents' transports share one; flushed after each pass's ticks,
        before the round-done markers (which must follow the messages they close)."""
        if options.lockstep and rounds is None:
            raise ValueError("lockstep agents need the process's round book")
        self._rounds = rounds
        self._hub = hub
        self._roster = tuple(roster)
        self._slots = [_Slot(d, link) for d, link in zip(drones, links, strict=True)]
        self._slot_of = {slot.drone: slot for slot in self._slots}
        self._core = BatchAgentCore(drones, config)
        #: the agents' readiness to leave the ground, row for row with the core's
        self._readiness = BatchReadiness(len(self._core.agent_ids), config)
        #: and their take-off clocks
        self._takeoff = BatchTakeoff(
            len(self._core.agent_ids), config.consensus.heard_timeout_ticks
        )
        #: and their flight phases
        self._phases = BatchFlightPhase(len(self._core.agent_ids), config.limits)
        self._bus = bus
        self._factory = transport_factory
        self._config = config
        self._plan = fallback_plan
        self._options = options
        self._clock = wall_clock
        self._stop = threading.Event()
        #: the newest vehicle time (ms) the hosted vehicles had together at the last gather
        self._pack_ms = -1
        self._selector = selectors.DefaultSelector()
        for slot in self._slots:
            self._selector.register(slot.link, selectors.EVENT_READ, slot)

    @property
    def drones(self) -> list[int]:
        """The drones this process hosts."""
        return [s.drone for s in self._slots]

    def kill(self, drone: int, reason: str) -> None:
        """Drone ``drone``'s agent dies now (a scenario drop-out): it leaves the swarm at once
        (liveliness token dropped) and never serves its vehicle again, which fails safe."""
        for slot in self._slots:
            if slot.drone == drone:
                if slot.agent is None:  # not joined yet: it never will
                    self._unwatch(slot)
                    slot.link.close()
                    self._slots.remove(slot)
                else:
                    slot.agent.leave(reason)
                return

    def restart(self, drone: int, gap_s: float) -> str | None:
        """The restart drill: kill drone ``drone``'s agent now and start a new one once its
        vehicle's time has moved on by ``gap_s`` s. Returns what was done (for the log), None if
        this process does not run that drone's agent (yet, or any more: a restart already under
        way, or an agent that left on its own)."""
        for slot in self._slots:
            if slot.drone != drone:
                continue
            if slot.agent is None or slot.agent.left or slot.revive_at_ms is not None:
                return None
            slot.agent.leave(f"killed by a restart drill; a new agent starts in {gap_s:g} s")
            slot.left_reported = True  # said by the caller
            # the old port closes (the simulator stops waiting for it at once); the new one
            # greets the vehicle shortly to see its time go on until the new agent starts
            self._unwatch(slot)
            slot.link.reopen()
            self._selector.register(slot.link, selectors.EVENT_READ, slot)
            slot.greeted_at = self._clock() - 1.0 + REGREET_DELAY_S
            slot.revive_at_ms = slot.newest_ms + round(gap_s * 1000)
            t_s = slot.newest_ms / 1000.0
            back_s = t_s + gap_s
            return f"drone {drone}'s agent killed at t={t_s:.2f}s; a new one at t={back_s:.2f}s"
        return None

    @property
    def agents(self) -> list[HostedAgent]:
        """The agents that have joined so far."""
        return [s.agent for s in self._slots if s.agent is not None]

    def stop(self) -> None:
        """Ask :meth:`run` to return (thread-safe)."""
        self._stop.set()

    def run(
        self,
        on_second: Callable[[AgentHost], None] | None = None,
        on_loop: Callable[[], None] | None = None,
        on_leave: Callable[[HostedAgent], None] | None = None,
        on_return: Callable[[int, int], None] | None = None,
    ) -> None:
        """Serve every hosted agent until stopped or all have left the swarm; ``on_second`` runs
        about once a second (wall clock), ``on_loop`` (cheap) in every pass over the agents,
        after the vehicles' samples are read and before any agent's tick (so that it sees the
        ticks now due, :meth:`pending_rounds`), ``on_leave`` once for each agent that leaves the
        swarm on its own, ``on_return(drone, time_boot_ms)`` when a restarted drone's new agent
        starts."""
        last_report = last_tick = last_full = self._clock()
        while not self._stop.is_set():
            fresh = self._read(0.002, on_return)
            if fresh and len(self._slots) > 1:
                self._gather(on_return)
            now = self._clock()
            if self._rounds is not None and not fresh and now - last_full < IDLE_PASS_S:
                # lockstep, waiting: nothing can have become due unless a marker or a
                # liveliness change came in; a pass with nothing new ends here (the time-based
                # checks, ``on_loop``, repeats and reports run at least every IDLE_PASS_S)
                if not self._rounds.poll():
                    continue
            else:
                last_full = now
            if on_loop is not None:
                on_loop()
            if self._hub is not None:
                self._hub.new_pass()
            due: dict[tuple[int, int], list[tuple[HostedAgent, DueTick]]] = {}
            for slot in self._slots:
                if slot.agent is None or slot.revive_at_ms is not None:
                    self._greet(slot)
                    continue
                tick = slot.agent.prepare()
                if tick is not None:
                    when = (tick.tick, tick.sample.time_boot_ms)
                    due.setdefault(when, []).append((slot.agent, tick))
            for group in due.values():
                self._run_cores(group)
            if self._hub is not None:
                self._hub.flush()
            if self._rounds is not None:
                self._rounds.flush()
                if due:
                    last_tick = self._clock()
                elif self._clock() - last_tick > REPEAT_MARKERS_S:
                    self._rounds.repeat()  # in case a marker was lost
                    last_tick = self._clock()
            for slot in self._slots:
                if slot.agent is not None and slot.agent.left and not slot.left_reported:
                    slot.left_reported = True
                    self._let_go(slot)
                    if on_leave is not None:
                        on_leave(slot.agent)
            if self._slots and all(
                s.agent is not None and s.agent.left and s.revive_at_ms is None for s in self._slots
            ):
                break
            now = self._clock()
            if on_second is not None and now - last_report >= 1.0:
                on_second(self)
                last_report = now

    def _read(self, timeout: float, on_return: Callable[[int, int], None] | None) -> bool:
        """Wait up to ``timeout`` s for the vehicles' samples and hand them to their agents
        (joining an agent on its vehicle's first sample); whether any came."""
        fresh = False
        for key, _ in self._selector.select(timeout=timeout):
            slot: _Slot = key.data
            for sample in slot.link.poll():
                fresh = True
                slot.newest_ms = max(slot.newest_ms, sample.time_boot_ms)
                if slot.revive_at_ms is not None and slot.newest_ms >= slot.revive_at_ms:
                    self._revive(slot)
                    if on_return is not None:
                        on_return(slot.drone, slot.newest_ms)
                if slot.agent is None:
                    slot.agent = self._join(slot, sample.position_ned_m)
                slot.agent.on_sample(sample)
        return fresh

    def _gather(self, on_return: Callable[[int, int], None] | None) -> None:
        """A new tick's first samples came in: wait (up to GATHER_S) for the rest of the tick's
        samples of the hosted vehicles that were at the previous tick with the others, so that
        the agents due at one tick run in one batched core call rather than two or three (the
        simulator sends a tick's states back to back, but the first datagram wakes the process
        before the last is in). A vehicle that falls silent (crashed, its agent leaving) lags
        the pack once and is not waited for again."""
        pack_ms = self._pack_ms
        deadline = self._clock() + GATHER_S
        while True:
            newest = max(s.newest_ms for s in self._slots)
            behind = any(
                s.newest_ms < newest and s.newest_ms >= pack_ms and s.agent is not None
                and not s.agent.left and s.revive_at_ms is None
                for s in self._slots
            )  # fmt: skip
            remaining = deadline - self._clock()
            if not behind or remaining <= 0:
                self._pack_ms = newest
                return
            self._read(remaining, on_return)

    def pending_rounds(self) -> dict[int, int]:
        """For each hosted agent with a tick due (its vehicle's newest sample is of a tick it
        has not computed), that tick."""
        out = {}
        period = self._options.control_period_ms
        for slot in self._slots:
            agent = slot.agent
            if agent is None or agent.left or agent.sample is None:
                continue
            tick = round(agent.sample.time_boot_ms / period)
            if tick > agent.last_tick:
                out[slot.drone] = tick
        return out

    def round_of(self, drone: int) -> int:
        """The newest round whose messages drone ``drone``'s agent takes in (-1 before it
        joined): the clock of its link faults."""
        slot = self._slot_of.get(drone)
        return -1 if slot is None or slot.agent is None else slot.agent.round_now

    @property
    def controller_error(self) -> str | None:
        """What the formation controller's last failed call did (None: none failed;
        drone_agent/core/controller.py)."""
        return self._core.controller_error

    def _run_cores(self, group: list[tuple[HostedAgent, DueTick]]) -> None:
        """The cores of the agents due at one tick (same tick, same vehicle time), in one
        batched call, then their readiness to leave the ground in one more; each agent then
        finishes its own tick: all answer their vehicles, their take-off clocks are updated in
        one call, then all publish."""
        ticks = [t for _, t in group]
        first = ticks[0]
        # read once, for the consensus, the separation layer and the readiness (Arrivals)
        inboxes = Inboxes([t.inbox for t in ticks])
        outs = self._core.tick(
            [t.core.row for t in ticks],
            first.tick,
            first.t_s,
            np.array([t.sample.position_ned_m for t in ticks], dtype=float),
            np.array([t.sample.velocity_ned_m_s for t in ticks], dtype=float),
            [t.plan for t in ticks],
            inboxes,
            [t.members for t in ticks],
            [t.climb_to for t in ticks],
            [t.t_s if t.plan_t_s is None else t.plan_t_s for t in ticks],
        )
        rows = [t.core.row for t in ticks]
        arrivals = Arrivals.of_inboxes(rows, inboxes)
        self._readiness.update(
            rows,
            outs[0].message.round,
            [out.disagreement for out in outs],
            [out.ready_to_fly for out in outs],
            arrivals,
            [t.members for t in ticks],
            [agent.phase.committed for agent, _ in group],
            # a vehicle its dialect does not call ready (EKF, GPS, pre-arm, parameters) keeps
            # its agent from agreeing: the swarm waits for it
            [agent.link.dialect.ready for agent, _ in group],
        )
        for (agent, tick), out in zip(group, outs, strict=True):
            agent.act(tick, out)  # every vehicle answered first (HostedAgent.act)
        # the swarm's take-off round, agreed with the neighbours, after this tick's decisions
        self._takeoff.update(
            rows, first.tick, [agent.phase.committed for agent, _ in group], arrivals
        )
        for agent, tick in group:
            agent.publish(tick)

    def _let_go(self, slot: _Slot) -> None:
        """An agent that left for good: close its vehicle link, so that the simulator sees its
        port closed and a lockstep barrier stops waiting for it at once (not after its silence
        timeout); the vehicle fails safe."""
        self._unwatch(slot)
        slot.link.close()

    def _unwatch(self, slot: _Slot) -> None:
        """Stop watching ``slot``'s vehicle link (once; a link let go of is not watched)."""
        with suppress(KeyError, ValueError):  # already let go of (and closed)
            self._selector.unregister(slot.link)

    def _greet(self, slot: _Slot) -> None:
        """Until the vehicle answers: heartbeat it once a second so it learns our address."""
        now = self._clock()
        if now - slot.greeted_at >= 1.0:
            slot.link.send_heartbeat()
            slot.greeted_at = now
        slot.link.service_dialect(now)  # e.g. ask an ArduCopter for its state streams

    def _revive(self, slot: _Slot) -> None:
        """A restarted drone: its next sample starts a new agent (:meth:`_join`) on a fresh
        estimator row."""
        self._core.restart_row(self._core.row_of(slot.drone))
        slot.agent = None
        slot.left_reported = False
        slot.revive_at_ms = None

    def _join(self, slot: _Slot, position: Position) -> HostedAgent:
        transport = self._factory(self._bus, slot.drone, position)
        core = AgentCore(slot.drone, self._config, self._core)
        gate = None
        if self._rounds is not None:
            gate = RoundGate(slot.drone, self._roster, self._rounds)
        options, clock = self._options, self._clock
        readiness = Readiness(self._config, self._readiness, core.row)
        takeoff = TakeoffClock(self._config.consensus.heard_timeout_ticks, self._takeoff, core.row)
        readiness.reset()  # a new life
        takeoff.reset()
        phase = FlightPhase(self._config.limits, self._phases, core.row)  # (afresh)
        return HostedAgent(
            core, slot.link, transport, self._plan, options, clock, gate, readiness, takeoff, phase
        )

    def close(self) -> None:
        """Leave the swarm with every agent and close the vehicle links."""
        for slot in self._slots:
            if slot.agent is not None:
                slot.agent.leave()
            self._unwatch(slot)
            slot.link.close()
        self._selector.close()
        if self._rounds is not None:
            self._rounds.close()
