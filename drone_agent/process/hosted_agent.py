"""One drone's agent at run time: its vehicle link, its transport and its core, tick by tick.

Each control tick (named by the vehicle's ``time_boot_ms``, protocols/mavlink/conventions.py) the
agent gathers the consensus messages that arrived, runs :class:`AgentCore` (:meth:`prepare`, the
core and the readiness to fly, :meth:`act`, :meth:`publish`; a host runs the cores and the
readiness of its agents due at the same tick in one batched call each), publishes its message,
lets :class:`~drone_agent.core.flight_phase.FlightPhase` decide what to do with the vehicle (fly the
formation, land, hold, stay on the ground), and answers the vehicle with that SET_ATTITUDE_TARGET
echoing the tick (also on the ground, for lockstep). Before a tick it waits for its neighbours'
messages of the previous round: in realtime up to ``neighbour_wait_s`` of wall time, for every
neighbour heard recently (a message its link faults dropped or held back counts as come: it was
lost, not late); in lockstep (``RunOptions.lockstep``, with a
:class:`~drone_agent.process.round_gate.RoundGate`) for every live drone's round-done marker,
however long it takes, so that its inbox, membership view and command timing depend on simulated
time alone and two runs of a scenario repeat exactly.

Safety: it arms only once the plan says fly and every agent's estimate has settled (flight_phase's
Readiness: the swarm leaves the ground together); an airborne vehicle is
never sent less than the minimum thrust (flight_phase's invariant); it leaves the swarm (drops its
liveliness token) when its vehicle falls silent (``vehicle_timeout_s``; a lockstep agent's
(agent_cli) is longer than the simulator's barrier timeout, during which a barrier waiting for
the slowest process legitimately sends nothing) or says
it is lost (an EMERGENCY text, emergency or termination state, or disarmed under it while it flies
the formation); the core checks every setpoint for NaN and limits before it is sent.

Rejoin (issue 14): an agent that starts while its neighbours already fly (a restarted agent, a
late joiner) and whose vehicle is well below them (its failsafe landed it, or is landing it) must
not be counted in the formation from down there: a drone 3 m under a flat formation tilts every
neighbour's estimated plane, which the formation then follows (measured: the plane tilted by
0.3-0.5 rad and took 40 s to level out, the returning drone crawling up with it). So it first
only listens (its estimator row observes: :meth:`BatchConsensus.set_observing`, nobody
integrates with it, while its position still reaches their separation layer) and climbs
straight up to their altitude (``climb_to``:
:func:`~drone_agent.core.agent_core.climb_acceleration`, arming it on the ground if need be); there
it starts a new incarnation as a member and holds its altitude until its estimate has settled, then
flies the formation.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

import numpy as np

from drone_agent.core.agent_core import AgentCore, AgentOutput, Setpoint
from drone_agent.core.consensus.packing import with_level
from drone_agent.core.flight_phase import (
    FlightPhase,
    Order,
    Readiness,
    Request,
    TakeoffClock,
    VehicleView,
)
from drone_agent.process.round_gate import RoundGate
from drone_agent.process.transport import AgentTransport
from drone_agent.process.vehicle_link import VehicleLink, VehicleSample
from protocols.mavlink.conventions import LOST_STATES
from protocols.model.descriptor_vector import CENTRE
from protocols.model.frames import quat_from_zyx
from protocols.model.plan_timing import flown_time_s, tick_time_s
from protocols.model.trajectory import DescriptorTrajectory
from protocols.wire.consensus_message import ConsensusMessage
from protocols.wire.plan import FlightCommand
from protocols.wire.status import AgentMode, AgentStatus, Health

#: Agent modes in which the vehicle flies the agent's setpoints: disarmed under it = lost.
_FLYING_MODES = frozenset({AgentMode.FLYING, AgentMode.HOLDING})
#: The health flags as ints (a status sums them: :meth:`HostedAgent._publish_status`).
_VEHICLE_LINK, _ESTIMATE_FINITE, _CONVERGED, _SEPARATING, _PLAN = (
    int(Health.VEHICLE_LINK), int(Health.ESTIMATE_FINITE), int(Health.CONVERGED),
    int(Health.SEPARATING), int(Health.PLAN),
)  # fmt: skip
#: Neighbours above this altitude (m) fly: an agent that first hears them so is a late joiner.
NEIGHBOURS_AIRBORNE_M = 1.0
#: A late joiner whose vehicle is this far (m) below its flying neighbours climbs first.
CLIMB_BELOW_M = 0.5
#: The climb is over within this (m) of their altitude, moving slower than CLIMB_SLOW_M_S.
CLIMB_DONE_M, CLIMB_SLOW_M_S = 0.15, 0.2
#: Neighbour positions older than this many rounds are not used.
NEIGHBOUR_AGE_TICKS = 25


class Rejoin(Enum):
    """A late joiner's way into the formation (module doc)."""

    NONE = "none"  # a member, flying the formation (or on the ground with the swarm)
    CLIMB = "climb"  # listening only, climbing to the neighbours' altitude
    SETTLE = "settle"  # a member again, holding its altitude until its estimate settles


@dataclass(frozen=True)
class RunOptions:
    """Run-time behaviour of an agent (wall-clock durations in s)."""

    control_period_ms: int = 20
    arm: bool = True
    neighbour_wait_s: float = 0.008
    vehicle_timeout_s: float = 3.0
    heartbeat_period_s: float = 1.0
    #: statuses at 25 Hz (control ticks of 20 ms): the ground station's view and record; the
    #: distributed report holds each estimate on its 25 Hz grid, so a slower rate reads a held
    #: estimate of a moving centre as consensus error (10 Hz: 49 mm instead of < 2.5 mm).
    #: A process's statuses of a pass go in one sample (protocols/wire/status.py), QUEUED
    status_every_ticks: int = 2
    command_retry_s: float = 0.5
    #: lockstep: wait for every live drone's previous round (drone_agent/process/round_gate.py),
    #: retry commands on simulated time
    lockstep: bool = False


@dataclass(frozen=True)
class DueTick:
    """One agent's due tick, between :meth:`HostedAgent.prepare` and :meth:`HostedAgent.act`:
    the core inputs (its vehicle's sample, plan, inbox and membership view) and the command."""

    core: AgentCore
    tick: int
    sample: VehicleSample
    plan: DescriptorTrajectory
    command: FlightCommand
    inbox: list[ConsensusMessage]
    members: frozenset[int]
    climb_to: float | None = None
    #: the plan's own time to fly this tick (protocols/model/plan_timing.py); None: :attr:`t_s`
    plan_t_s: float | None = None

    @property
    def t_s(self) -> float:
        """The vehicle's simulated time of the tick (s)."""
        return self.sample.time_boot_ms / 1000.0


class HostedAgent:
    """Drone ``core.agent_id``'s agent. Feed it vehicle samples; its host calls :meth:`prepare`
    often, runs the core and the readiness of a due tick (batched with its other agents due
    then) and hands the output to :meth:`act`, then calls :meth:`publish`."""

    def __init__(
        self,
        core: AgentCore,
        link: VehicleLink,
        transport: AgentTransport,
        fallback_plan: DescriptorTrajectory | None,
        options: RunOptions,
        wall_clock: Callable[[], float],
        gate: RoundGate | None = None,
        readiness: Readiness | None = None,
        takeoff: TakeoffClock | None = None,
        phase: FlightPhase | None = None,
    ) -> None:
        """``readiness`` and ``takeoff``: its rows of its host's readiness and take-off clocks
        (updated by the host for all its agents at once), ``phase`` its row of the host's flight
        phases; its own if None."""
        if options.lockstep and gate is None:
            raise ValueError("a lockstep agent needs its round gate")
        self.core, self.link, self.transport = core, link, transport
        self.gate = gate if options.lockstep else None
        #: the newest round whose messages are due (tick - 1 while computing a tick): the
        #: link-fault clock of its transport
        self.round_now = -1
        self.fallback_plan = fallback_plan
        self.options = options
        self.clock = wall_clock
        self.mode = AgentMode.STARTING
        self.sample: VehicleSample | None = None
        self.last_tick = -1
        self.last_output: AgentOutput | None = None
        self._inbox: list[ConsensusMessage] = []
        self._last_round_of: dict[int, int] = {}
        self._pending_since: float | None = None
        self._last_sample_wall = wall_clock()
        self._last_heartbeat = -1e9
        self._last_command = -1e9
        self.readiness = readiness if readiness is not None else Readiness(core.config)
        self.phase = phase if phase is not None else FlightPhase(core.config.limits)
        timeout = core.config.consensus.heard_timeout_ticks
        self.takeoff = takeoff if takeoff is not None else TakeoffClock(timeout)
        self.left = False
        self.leave_reason = ""
        self.rejoin = Rejoin.NONE
        #: None until a neighbour's altitude is known; then whether they flew when first heard
        self.late_joiner: bool | None = None
        self._climb_z: float | None = None
        #: each neighbour's newest message (its altitude read when needed: _rejoin_step)
        self._neighbour_msg: dict[int, ConsensusMessage] = {}

    @property
    def drone(self) -> int:
        return self.core.agent_id

    # -- inputs --------------------------------------------------------------------------------
    def on_sample(self, sample: VehicleSample) -> None:
        """A state of the vehicle arrived; the newest one names the tick to compute."""
        if self.sample is None or sample.time_boot_ms > self.sample.time_boot_ms:
            self.sample = sample
        self._last_sample_wall = self.clock()

    def _tick_of(self, sample: VehicleSample) -> int:
        return round(sample.time_boot_ms / self.options.control_period_ms)

    def _collect(self) -> None:
        packets = self.transport.receive()
        last_round = self._last_round_of
        # a message the link faults dropped or held back came as far as time goes: the
        # realtime wait (_neighbours_ready) does not wait for it (it would, the whole
        # neighbour_wait_s, at nearly every tick of a lossy drill)
        for sender, round_ in self.transport.withheld().items():
            if round_ > last_round.get(sender, -1):
                last_round[sender] = round_
        if not packets:
            return
        messages = [packet.message for packet in packets]
        self._inbox += messages
        # the messages come by sender, then round: each sender's last one is its newest
        newest = {m.sender: m for m in messages}
        self._neighbour_msg.update(newest)
        if self.gate is None:  # the realtime wait's record (lockstep waits on its gate)
            for sender, msg in newest.items():
                if msg.round > last_round.get(sender, -1):
                    last_round[sender] = msg.round

    def _neighbours_ready(self, tick: int) -> bool:
        """Every drone heard in the last few rounds has sent its round ``tick - 1``."""
        members = self.transport.members()
        recent = [
            r
            for j, r in self._last_round_of.items()
            if j in members and r >= tick - 1 - self.core.config.consensus.heard_timeout_ticks
        ]
        return all(r >= tick - 1 for r in recent)

    # -- the loop ------------------------------------------------------------------------------
    def prepare(self) -> DueTick | None:
        """Everything before the core: heartbeat, leaving on vehicle loss, collecting messages,
        and whether a tick is due (a newer vehicle sample, and every recent neighbour's message
        of the previous round, or ``neighbour_wait_s`` waited). Returns the core's inputs of the
        due tick, to be run (batched with the other agents due at the same tick) and handed
        to :meth:`act`; None if nothing is due, or if the tick was done without the core (no
        plan yet: the agent stays on the ground)."""
        if self.left:
            return None
        now = self.clock()
        # heartbeats and the dialect's set-up (streams, parameters) on simulated time in
        # lockstep, as commands: an ArduCopter's GCS failsafe counts heartbeats on its own
        # clock, which a lockstep faster than real time runs ahead of the wall
        sample_ms = None if self.gate is None or self.sample is None else self.sample.time_boot_ms
        vehicle_now = now if sample_ms is None else sample_ms / 1000.0
        since = vehicle_now - self._last_heartbeat
        if not 0.0 <= since < self.options.heartbeat_period_s:  # due, or the clock changed
            self.link.send_heartbeat()
            self._last_heartbeat = vehicle_now
        self.link.service_dialect(vehicle_now)
        if (
            self.sample is not None
            and now - self._last_sample_wall > self.options.vehicle_timeout_s
        ):
            self.leave(f"no state from its vehicle for {self.options.vehicle_timeout_s:g} s")
            return None
        lost = self._vehicle_lost()
        if lost is not None:
            self.leave(lost)
            return None
        gate = self.gate
        if gate is None:
            if self.sample is not None:
                self.round_now = max(self.last_tick, self._tick_of(self.sample) - 1)
            self._collect()
        sample = self.sample
        if sample is None or self._tick_of(sample) <= self.last_tick:
            return None
        tick = self._tick_of(sample)
        if gate is not None:
            # lockstep: every live drone's round tick - 1 is in before anything is taken in
            if not gate.ready(tick, now):
                return None
            self.round_now = tick - 1
            self._collect()
            members = gate.members()
        else:
            if self._pending_since is None:
                self._pending_since = now
            waited = now - self._pending_since
            if not self._neighbours_ready(tick) and waited < self.options.neighbour_wait_s:
                return None
            self._pending_since = None
            members = self.transport.members()
        plan, command = self._plan()
        self.last_tick = tick
        if plan is None:  # no plan yet: stay on the ground (an airborne vehicle lands)
            self._carry_out(self._decide(FlightCommand.GROUND, None, 0.0, sample), sample)
            self._after_tick(tick)
            return None
        inbox, self._inbox = self._inbox, []
        climb = self._rejoin_step(tick, sample, command, members)
        takeoff = self.takeoff.round
        period = self.options.control_period_ms
        plan_t = flown_time_s(
            plan,
            sample.time_boot_ms / 1000.0,
            None if takeoff is None else tick_time_s(takeoff, period),
        )
        return DueTick(self.core, tick, sample, plan, command, inbox, members, climb, plan_t)

    def _flying_neighbours_alt(self, tick: int, members: frozenset[int]) -> float | None:
        """The mean altitude (m) of the members heard lately above NEIGHBOURS_AIRBORNE_M."""
        recent = tick - 1 - NEIGHBOUR_AGE_TICKS
        alts = [
            a
            for j, m in self._neighbour_msg.items()
            if j in members
            and m.round >= recent
            and m.position_ned_m is not None  # a version-1 sender's says nothing
            and (a := -float(m.position_ned_m[2])) > NEIGHBOURS_AIRBORNE_M
        ]
        return sum(alts) / len(alts) if alts else None

    def _rejoin_step(
        self, tick: int, sample: VehicleSample, command: FlightCommand, members: frozenset[int]
    ) -> float | None:
        """Advance the late joiner's climb (module doc); the NED z to climb to or hold, None
        to fly the formation."""
        if self.late_joiner is None and self._neighbour_msg:
            self.late_joiner = self._flying_neighbours_alt(tick, members) is not None
        altitude = -float(sample.position_ned_m[2])
        consensus, row = self.core.batch.consensus, self.core.row
        if command != FlightCommand.FLY:
            if self.rejoin == Rejoin.CLIMB:
                consensus.restart(row)  # a member again, on the ground with the others
            self.rejoin, self._climb_z = Rejoin.NONE, None
            return None
        if self.rejoin == Rejoin.NONE:
            if not self.late_joiner or self.phase.committed or self.readiness.ready:
                return None  # (the usual case: the neighbours' altitude is not needed)
            target = self._flying_neighbours_alt(tick, members)
            if target is None or altitude > target - CLIMB_BELOW_M:
                return None
            self.rejoin = Rejoin.CLIMB
            consensus.set_observing(row, True)
        if self.rejoin == Rejoin.CLIMB:
            target = self._flying_neighbours_alt(tick, members)
            if target is not None:
                self._climb_z = -target
            assert self._climb_z is not None
            near = abs(altitude + self._climb_z) < CLIMB_DONE_M
            if near and abs(float(sample.velocity_ned_m_s[2])) < CLIMB_SLOW_M_S:
                self.rejoin = Rejoin.SETTLE  # a member from now: a new incarnation
                consensus.restart(row)
                self.readiness.reset()
        elif self.rejoin == Rejoin.SETTLE and self.readiness.agrees:
            self.rejoin, self._climb_z = Rejoin.NONE, None
        return self._climb_z

    def act(self, due: DueTick, out: AgentOutput) -> None:
        """The vehicle's side of the tick, after the core and its readiness to fly (its host
        updates all its agents' at once: flight_phase.BatchReadiness): decide and send what the
        vehicle does this tick (the setpoint that answers the tick goes last). A host answers all
        its agents' vehicles before any publishes (:meth:`publish`): in lockstep the simulator
        steps once every vehicle has its answer, while the agents' messages are laid out and
        sent."""
        sample = due.sample
        self.last_output = out
        assert out.desired is not None  # the core gives the plan's value of the tick
        commanded_altitude = -float(out.desired[CENTRE][2])
        self._carry_out(self._decide(due.command, out.setpoint, commanded_altitude, sample), sample)

    def publish(self, due: DueTick) -> None:
        """The swarm's side of the tick, after :meth:`act`: the consensus message with this
        agent's settled level, the round done and the status."""
        out = self.last_output
        assert out is not None
        message = with_level(
            out.message, self.readiness.level, takeoff_round=self.takeoff.advertised
        )
        self.transport.publish_consensus(message, due.sample.position_ned_m)
        self._after_tick(due.tick)

    def _after_tick(self, tick: int) -> None:
        if self.gate is not None:
            self.gate.book.finished(self.drone, tick)
        if tick % self.options.status_every_ticks == 0:
            # on the simulated-time grid, so the ground station compares like with like
            self._publish_status()

    def _vehicle_lost(self) -> str | None:
        """Why the vehicle is gone, or None: an EMERGENCY status text (sent the moment its motors
        fail or it hits the ground too hard, long before the 1 Hz heartbeat), in emergency or
        termination state, or disarmed while we fly it (not after we handed it to LAND)."""
        status = self.link.status
        if status.emergency:
            last = status.texts[-1] if status.texts else ""
            return f"its vehicle reported an emergency ({last})" if last else "vehicle emergency"
        if status.system_status in LOST_STATES:
            return f"its vehicle is in state {status.system_status} (emergency or termination)"
        if self.mode in _FLYING_MODES and not status.armed and not self.phase.handed_over:
            return "its vehicle was disarmed in flight"
        return None

    def _plan(self) -> tuple[DescriptorTrajectory | None, FlightCommand]:
        received = self.transport.plan()
        if received is not None:
            return received.trajectory, received.command
        if self.fallback_plan is not None:
            return self.fallback_plan, FlightCommand.FLY
        return None, FlightCommand.GROUND

    def _decide(
        self,
        command: FlightCommand,
        setpoint: Setpoint | None,
        commanded_altitude_m: float,
        sample: VehicleSample,
    ) -> Order:
        modes = self.link.modes()
        vehicle = VehicleView(
            armed=self.link.status.armed,
            in_offboard=modes.in_offboard,
            in_land=modes.in_land,
            in_hold=modes.in_hold,
            altitude_m=-float(sample.position_ned_m[2]),
            on_ground=self.link.status.on_ground,
        )
        return self.phase.decide(
            command,
            self.options.arm,
            self.converged,
            setpoint,
            commanded_altitude_m,
            vehicle,
            float(sample.euler_rad[2]),
        )

    def _carry_out(self, order: Order, sample: VehicleSample) -> None:
        """Send, at most every ``command_retry_s`` (of wall time; of simulated time in
        lockstep), the order's request to the autopilot, then its setpoint echoing the tick. The
        echo goes last: in lockstep it lets the simulator step, which must not happen before the
        tick's commands are in (they would act a tick later, or not, as the datagrams race)."""
        self._request(order.request, sample)
        sp = order.setpoint
        q = quat_from_zyx(sp.yaw_rad, sp.pitch_rad, sp.roll_rad)
        thrust = self.link.dialect.wire_thrust(sp.thrust_normalised, sp.roll_rad, sp.pitch_rad)
        self.link.send_setpoint(sample.time_boot_ms, q, thrust)
        self.mode = order.mode

    def _request(self, request: Request, sample: VehicleSample) -> None:
        if request == Request.NONE:
            return
        # lockstep: retried on simulated time, so the commands reach the vehicle at the same ticks
        now = sample.time_boot_ms / 1000.0 if self.gate is not None else self.clock()
        if now - self._last_command < self.options.command_retry_s:
            return
        self._last_command = now
        status = self.link.status
        if request == Request.ARM_OFFBOARD:
            if not self.link.in_offboard:
                self.link.set_offboard()
            if not status.armed:
                self.link.arm(True)
        elif request == Request.LAND_MODE:
            self.link.set_land()
        elif request == Request.HOLD_MODE:
            self.link.set_hold()

    @property
    def converged(self) -> bool:
        """Its estimate and the whole swarm's have settled (:class:`Readiness`); latched once the
        agent has decided to fly (the neighbours' take-off must not send it back to the ground
        half-armed)."""
        return self.phase.committed or self.readiness.ready or self.rejoin != Rejoin.NONE

    def _publish_status(self) -> None:
        out = self.last_output
        # the flags summed as ints, made a Health once (an IntFlag's | costs ~10 us a call: a
        # 50-agent process spent 1 % of its time there)
        health = 0
        if self.clock() - self._last_sample_wall <= self.options.vehicle_timeout_s:
            health += _VEHICLE_LINK
        if out is not None and all(map(math.isfinite, out.estimate.tolist())):
            health += _ESTIMATE_FINITE
        if self.converged:
            health += _CONVERGED
        if out is not None and out.separating:
            health += _SEPARATING
        received = self.transport.plan()
        if received is not None or self.fallback_plan is not None:
            health += _PLAN
        estimate = out.estimate if out is not None else np.full(9, np.nan)
        self.transport.publish_status(
            AgentStatus(
                drone=self.drone,
                round=max(self.last_tick, 0),
                t_s=max(self.last_tick, 0) * self.options.control_period_ms / 1000.0,
                mode=self.mode,
                armed=self.link.status.armed,
                health=Health(health),
                estimate=estimate,
                neighbours=out.active_neighbours if out is not None else (),
                counters=self.transport.counters().status(self.core.rejected_setpoints),
                plan_seq=None if received is None else received.seq,
                takeoff_round=self.takeoff.round,
            )
        )

    def leave(self, reason: str = "stopped") -> None:
        """Leave the swarm: drop the liveliness token so every peer removes this drone;
        ``leave_reason`` says why."""
        if not self.left:
            self.left = True
            self.leave_reason = reason
            self.mode = AgentMode.LEAVING
            self.transport.close()
