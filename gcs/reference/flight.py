"""The whole swarm in one process (``swarm simulate``): vehicles, agents and radio, no network.

A composition and nothing else, of the parts every ``swarm up`` flight runs as processes:

- the vehicles are the simulator's pure :class:`~sitl_sim.vehicle.world.World`
(sitl_sim/vehicle/world.py): the
  same dynamics and inner loop, the same autopilots (modes, arming, the offboard-loss failsafe,
  land detection, the crash rules) and the scenario's crashes, stepped once a control tick;
- the agents are the rows of one :class:`~drone_agent.core.agent_core.BatchAgentCore` (one call per
  control tick), each with its flight phase (drone_agent/core/flight_phase.py), reading and
  commanding its vehicle as a ``swarm agent`` does over MAVLink
  (:mod:`gcs.reference.autopilot_link`);
- consensus messages pass through an in-memory radio with the scenario's faults
  (:mod:`gcs.reference.network`).

It is the reference the distributed system is measured against (a lockstep ``swarm up`` flight
is this flight to the last bit: tests/test_lockstep_vs_simulate.py), and a fast tuning tool.
Deterministic for a given seed; no I/O.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drone_agent.core.agent_core import AgentCore, BatchAgentCore, BatchOutputs
from drone_agent.core.config import agent_config
from drone_agent.core.flight_phase import (
    REQUESTS,
    BatchFlightPhase,
    BatchReadiness,
    BatchTakeoff,
)
from drone_agent.process.fault_timeline import TimedAction, timeline
from drone_agent.process.link_faults import LinkFaults, PairRandom, radio_links
from gcs.reference.autopilot_link import AutopilotLink, reported
from gcs.reference.network import InProcessNetwork
from gcs.report.flight_record import FlightRecord, scenario_link_cuts
from protocols.faults import Crash
from protocols.model.plan_timing import flown_plan, flown_time_s, shift_s, tick_time_s
from protocols.model.trajectory import DescriptorTrajectory
from protocols.runtime.collector import flight_collector
from protocols.scenario.scenario_file import Scenario
from protocols.wire.plan import FlightCommand
from protocols.wire.status import MODE_OF, AgentMode
from sitl_sim.physics.attitude_control import euler_from_quat_batch, yaw_from_quat_batch
from sitl_sim.physics.dynamics import POS, QUAT, RATES, VEL, wrench_from_rotor_speeds
from sitl_sim.sim_config import crash_timeline
from sitl_sim.vehicle.autopilot import VehicleEvent
from sitl_sim.vehicle.config import air, attitude_gains, sensors, vehicle_params, vehicle_scales
from sitl_sim.vehicle.tunables import FleetAttitudeGains
from sitl_sim.vehicle.world import World, WorldConfig

AIRBORNE_ALTITUDE_M = 0.1
_FLY = int(FlightCommand.FLY)


def world_of(scenario: Scenario) -> World:
    """The vehicles of ``scenario`` as ``swarm sim --scenario`` builds them for ``swarm up``
    (sitl_sim/launch.py: its rates, vehicle, gains, start, crashes, home, air, the
    vehicles' spread and their sensors; PX4's
    autopilot with its default tunables; no telemetry noise)."""
    crashes = [f for f in scenario.faults if isinstance(f, Crash)]
    config = WorldConfig(
        physics_hz=scenario.rates.physics_hz,
        control_hz=scenario.rates.control_hz,
        crashes=crash_timeline(crashes),
        home=scenario.home,
        air=air(scenario),
        air_seed=scenario.seed,
        vehicle_scales=vehicle_scales(scenario),
        sensors=sensors(scenario),
        sensors_seed=scenario.seed,
    )
    yaw = np.radians([d.yaw_deg for d in scenario.drones])
    gains = FleetAttitudeGains(attitude_gains(scenario), scenario.n_drones)
    rng = np.random.default_rng(scenario.seed)
    return World(vehicle_params(scenario), gains, scenario.positions_ned_m(), yaw, config, rng)


@dataclass(frozen=True)
class FlightEvent:
    """Something that happened at simulated time ``t_s``: ``kind`` and details."""

    t_s: float
    kind: str
    fields: dict[str, Any] = field(default_factory=dict)


class _Recorder:
    """Collects the per-tick samples of a flight into arrays."""

    def __init__(self, n_ticks: int, n: int, links_every: int = 0) -> None:
        self.t = np.zeros(n_ticks)
        self.pos = np.zeros((n_ticks, n, 3))
        self.vel = np.zeros((n_ticks, n, 3))
        self.quat = np.zeros((n_ticks, 4, n))  # turned into Euler angles after the flight
        self.rotor_speed = np.zeros((n_ticks, 4, n))  # into thrust and moments after the flight
        self.rates = np.zeros((n_ticks, n, 3))
        self.desired = np.zeros((n_ticks, 9))
        self.estimate = np.full((n_ticks, n, 9), np.nan)
        self.member = np.zeros((n_ticks, n), dtype=bool)
        self.airborne = np.zeros((n_ticks, n), dtype=bool)
        self.armed = np.zeros((n_ticks, n), dtype=bool)
        self.neighbours = np.zeros((n_ticks, n), dtype=int)
        #: where the state estimates are not the truth: what each vehicle reported (position,
        #: velocity, (roll, pitch, yaw)), (n_ticks, n, 3) each
        self.reported: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        #: every ``links_every`` ticks (0: never), the neighbours each live agent integrated
        self.links_every = links_every
        self.neighbour_ids: dict[int, dict[int, tuple[int, ...]]] = {}


class ReferenceFlight:
    """One flight of a scenario. :meth:`run` flies it and returns the record and the events."""

    def __init__(self, scenario: Scenario, rng: np.random.Generator | None = None) -> None:
        self.scenario = scenario
        self.n = scenario.n_drones
        self.config = agent_config(scenario)
        self.plan = scenario.trajectory()
        self.dt = scenario.rates.dt_control_s
        self.rng = rng if rng is not None else np.random.default_rng(scenario.seed)
        self.world = world_of(scenario)
        self.params = self.world.params
        self.link = AutopilotLink(self.world)
        self.core = BatchAgentCore(range(self.n), self.config)
        self.agents: dict[int, AgentCore] = {
            i: AgentCore(i, self.config, self.core) for i in range(self.n)
        }
        self.readiness = BatchReadiness(self.n, self.config)
        self.phases = BatchFlightPhase(self.n, self.config.limits)
        #: each agent's mode after its last tick (its flight phase's order)
        self.agent_modes = [AgentMode.STARTING] * self.n
        self.takeoff = BatchTakeoff(self.n, self.config.consensus.heard_timeout_ticks)
        self._period_ms = round(self.dt * 1000)
        #: when the swarm left the ground (s; None: not yet): the plan is flown re-timed to it
        self.takeoff_s: float | None = None
        #: the separation layer changes the drone's command (events on each change)
        self.separating = [False] * self.n
        #: the formation controller's last failure, as said in an event (None: none)
        self._controller_error: str | None = None
        delay = max(1, scenario.consensus.delay_ticks)
        # the radio's losses per directed link, seeded by the scenario, as the agents of swarm up
        # draw them: the in-process and distributed flights lose the same messages
        radio_rng = PairRandom(scenario.seed) if rng is None else self.rng
        radio = (
            None if scenario.radio.ideal else radio_links(scenario.radio, self.dt, scenario.seed)
        )
        self.network = InProcessNetwork(self.n, scenario.comms.range_m, radio_rng, delay, radio)
        self.member = np.ones(self.n, dtype=bool)
        self.lost_at: dict[int, float] = {}
        #: vehicle -> the time of the last tick it sent telemetry (a wreck on the ground is silent)
        self.silent_from: dict[int, float] = {}
        self.events: list[FlightEvent] = []
        self._vehicle_events: list[VehicleEvent] = self.world.pending_events
        self.world.pending_events = []
        self._actions: list[TimedAction] = timeline(scenario)
        self.t_s = 0.0
        self._live_cache: tuple[list[int], list[int], frozenset[int]] | None = None
        #: the agents that finished the previous tick (None before the first)
        self._finished: frozenset[int] | None = None

    # -- FaultTarget ---------------------------------------------------------------------------
    @property
    def conditions(self) -> LinkFaults:
        return self.network.conditions

    def kill_agent(self, drone: int) -> None:
        """The agent's process dies: it stops at once; its vehicle will failsafe."""
        self._leave(drone)

    def crash_vehicle(self, drone: int) -> None:
        """The world's own (its scheduled crashes, as the simulator of ``swarm up`` has them):
        the vehicle's motors stopped at the end of the period that reached this time; its agent
        hears of it and leaves at this tick."""

    @property
    def crashed(self) -> np.ndarray:
        """Whether each vehicle has crashed (N,)."""
        return self.world.autopilot.crashed

    def _leave(self, drone: int) -> bool:
        """Drone ``drone``'s agent stops (it sends nothing more); whether it was there."""
        if self.agents.pop(drone, None) is None:
            return False
        if self.member[drone]:
            self.member[drone] = False
            self.lost_at[drone] = self.t_s
        return True

    # -- the loop ------------------------------------------------------------------------------
    def run(
        self, progress: Callable[[float], None] | None = None, links_every: int = 0
    ) -> FlightRecord:
        """Fly the whole scenario; ``progress`` is called with the simulated time every tick.
        With ``links_every`` > 0, the record keeps the ids of the neighbours each agent
        integrated every that many ticks (``FlightRecord.neighbour_ids``)."""
        n_ticks = round(self.scenario.duration_s / self.dt) + 1
        rec = _Recorder(n_ticks, self.n, links_every)
        self._event("run_start", drones=self.n, duration_s=self.scenario.duration_s)
        with flight_collector():
            for k in range(n_ticks):
                self._tick(k, n_ticks, rec, progress)
        self._event("run_end", lost=sorted(self.lost_at))
        # per-tick conversions done once over the whole record (same arithmetic per sample)
        n_ticks_n = rec.quat.shape[0] * self.n
        euler = euler_from_quat_batch(rec.quat.transpose(1, 0, 2).reshape(4, n_ticks_n))
        rotor_speed = rec.rotor_speed.transpose(1, 0, 2).reshape(4, n_ticks_n)
        thrust, moments = wrench_from_rotor_speeds(rotor_speed, self.params)
        return FlightRecord(
            t_s=rec.t,
            position_ned_m=rec.pos,
            velocity_ned_m_s=rec.vel,
            euler_rad=np.ascontiguousarray(euler.reshape(3, -1, self.n).transpose(1, 2, 0)),
            thrust_n=thrust.reshape(-1, self.n),
            moments_nm=np.ascontiguousarray(moments.reshape(3, -1, self.n).transpose(1, 2, 0)),
            desired=rec.desired,
            estimate=rec.estimate,
            member=rec.member,
            airborne=rec.airborne,
            neighbours=rec.neighbours,
            link_faults=scenario_link_cuts(self.scenario),
            lost_at_s=dict(self.lost_at),
            armed=rec.armed,
            body_rates_rad_s=rec.rates,
            neighbour_ids=rec.neighbour_ids,
            reported=rec.reported,
            quat_wxyz=None if rec.reported is None else rec.quat.transpose(0, 2, 1).copy(),
        )

    def run_until_takeoff(self, limit_s: float) -> float | None:
        """Fly until the swarm leaves the ground (at most ``limit_s`` simulated seconds);
        when it did (s), None if it did not by then. Nothing is recorded."""
        n_ticks = round(limit_s / self.dt) + 1
        rec = _Recorder(n_ticks, self.n, 0)
        with flight_collector():
            for k in range(n_ticks):
                self._tick(k, n_ticks, rec, None)
                if self.takeoff_s is not None:
                    return self.takeoff_s
        return None

    def _tick(
        self, k: int, n_ticks: int, rec: _Recorder, progress: Callable[[float], None] | None
    ) -> None:
        """Control tick ``k`` of ``n_ticks`` and the vehicles' period up to the next one: the
        scenario's faults of the tick, what the vehicles reported since the last one (agents
        whose vehicle is lost leave, as a swarm agent does before its tick), the agents' tick."""
        self.t_s = k * self.dt
        self._apply_faults()
        self._vehicles_reported(self._vehicle_events)
        self._control_tick(k, rec)
        if progress is not None:
            progress(self.t_s)
        if k < n_ticks - 1:
            self._vehicle_events = self.world.step()
            silent = self.world.autopilot.silent
            if silent.any():
                for i in np.flatnonzero(silent).tolist():
                    self.silent_from.setdefault(i, self.t_s)

    def _event(self, kind: str, **fields: Any) -> None:
        self.events.append(FlightEvent(round(self.t_s, 6), kind, fields))

    def _apply_faults(self) -> None:
        while self._actions and self._actions[0].t_s <= self.t_s + 1e-9:
            action = self._actions.pop(0)
            action.apply(self)
            self._event(
                "fault" if action.starts else "fault_end",
                fault=action.fault_kind,
                description=action.description,
            )

    def _vehicles_reported(self, events: list[VehicleEvent]) -> None:
        """The vehicles' events (their STATUSTEXTs) as flight events of their kind; then every
        agent whose vehicle is lost leaves the swarm."""
        for e in events:
            self._vehicle_event(e)
        link, phases, modes = self.link, self.phases, self.agent_modes
        ap = self.world.autopilot
        # only a crashed vehicle, or one disarmed and not handed over, can be lost (link.lost's
        # rule): the others are not asked (a call per agent a tick, ~1 % of a flying tick)
        maybe = (ap.crashed | ~(ap.armed | phases.handed_over)).tolist()
        for i in [i for i in self.agents if maybe[i]]:
            reason = link.lost(i, modes[i], bool(phases.handed_over[i]))
            if reason is not None:
                self._leave(i)
                self._event("agent_left", drone=i, reason=reason)

    def _vehicle_event(self, e: VehicleEvent) -> None:
        self._event(e.kind, drone=e.vehicle, severity=int(e.severity), text=e.text)

    def _control_tick(self, k: int, rec: _Recorder) -> None:
        state = self.world.state
        # what each agent reads of its vehicle, as a swarm agent reads it (the telemetry's float32):
        # its autopilot's state estimate (the true state with ideal sensors)
        estimate = self.world.estimate()
        if estimate is None:
            pos, vel = reported(state[POS].T), reported(state[VEL].T)
        else:
            pos, vel = reported(estimate[0].T), reported(estimate[1].T)
        live, rows, now_live = self._live()
        # the membership view of tick k: the agents that finished round k - 1, as the lockstep
        # round gate of every swarm agent has it (drone_agent/process/round_gate.py: an agent that
        # died before its tick k - 1 is known dead only when its round k - 1 does not come)
        members = now_live if self._finished is None else self._finished
        self._finished = now_live
        inboxes = self.network.receive_inboxes(k, live)
        # the tick's time as the agents read it: the vehicle's time_boot_ms
        # (sitl_sim/vehicle/world.py), not k * dt (6.0200000000000005 s at k = 301, where the plan's
        # climb starts)
        t_s = self.world.time_boot_ms(k) / 1000.0
        if not live:
            self._fly_none(k, rec)
            return
        cols = self.core.tick_columns(
            rows,
            k,
            t_s,
            pos[live],
            vel[live],
            [self.plan] * len(live),
            inboxes,
            [members] * len(live),
            plan_t_s=self._plan_times(live, t_s),
        )
        if self.core.controller_error != self._controller_error:  # a user's controller failed
            self._controller_error = self.core.controller_error
            self._event("controller_error", message=self._controller_error)
        rec.estimate[k, live] = cols.estimate
        rec.neighbours[k, live] = [len(ids) for ids in cols.active_neighbours]
        if rec.links_every and k % rec.links_every == 0:
            rec.neighbour_ids[k] = dict(zip(live, cols.active_neighbours, strict=True))
        commands = self._decide(live, cols, members, pos, state, t_s)
        phases = self.phases
        # the swarm's take-off round, agreed over the messages (flight_phase.TakeoffClock)
        takeoffs = self.takeoff.update(
            live, k, phases.committed[live].tolist(), self.network.arrivals
        )
        if self.takeoff_s is None and (said := [t for t in takeoffs if t is not None]):
            self._took_off(min(said))
        messages = cols.outgoing.messages(self.readiness.level[live].tolist(), takeoffs)
        self.link.hand_setpoints(live, commands)
        self.network.send(k, messages, self.network.in_range(pos), pos)
        rec.desired[k] = cols.desired[0]
        self._record_vehicles(k, rec)

    def _decide(
        self,
        live: list[int],
        cols: BatchOutputs,
        members: frozenset[int],
        pos: np.ndarray,
        state: np.ndarray,
        t_s: float,
    ) -> np.ndarray:
        """What each live agent's flight phase decides for its vehicle
        (drone_agent/core/flight_phase.py, the same decision as every ``swarm agent``; the
        scenario's plan always says FLY): the requests go to its autopilot, and the setpoints (roll,
        pitch, yaw, thrust) that answer the tick are returned, one per agent."""
        phases, separating, modes = self.phases, self.separating, self.agent_modes
        committed = phases.committed[live]
        ready_all = self._ready(live, cols, members, committed.tolist())
        estimate = self.world.estimate()  # (the believed yaw; the true one with ideal sensors)
        believed_yaw = yaw_from_quat_batch(state[QUAT]) if estimate is None else estimate[2][2]
        yaw = reported(believed_yaw)[live]
        vehicles = self.link.vehicle_arrays(live, -pos[live, 2])
        orders = phases.decide(
            live,
            [_FLY] * len(live),
            [True] * len(live),
            committed | np.asarray(ready_all, dtype=bool),
            cols.setpoints,
            -cols.desired[:, 2],
            vehicles,
            yaw,
        )
        asks = orders.request.tolist()
        for p, (i, now_separating, mode) in enumerate(
            zip(live, cols.separating, orders.mode.tolist(), strict=True)
        ):
            if now_separating != separating[i]:
                separating[i] = now_separating
                self._event("separation" if now_separating else "separation_end", drone=i)
            modes[i] = MODE_OF[mode]
            if asks[p]:  # (the few that ask their autopilot something this tick)
                view = vehicles.view(p)
                for e in self.link.request(i, REQUESTS[asks[p]], view, t_s):
                    self._vehicle_event(e)
        return orders.setpoint

    def _fly_none(self, k: int, rec: _Recorder) -> None:
        """Control tick ``k`` with no live agent: no message, no setpoint, only the record."""
        rec.desired[k] = self.plan.evaluate(flown_time_s(self.plan, self.t_s, self.takeoff_s))[0]
        self._record_vehicles(k, rec)

    def _plan_times(self, live: list[int], t_s: float) -> list[float]:
        """Each live agent's plan time (protocols/model/plan_timing.py) on its take-off round."""
        times: dict[int | None, float] = {}
        out = []
        for takeoff in self.takeoff.rounds(live):
            t = times.get(takeoff)
            if t is None:
                start = None if takeoff is None else tick_time_s(takeoff, self._period_ms)
                t = times[takeoff] = flown_time_s(self.plan, t_s, start)
            out.append(t)
        return out

    def _took_off(self, takeoff_round: int) -> None:
        """The swarm left the ground at ``takeoff_round``: the plan is flown re-timed to it."""
        self.takeoff_s = tick_time_s(takeoff_round, self._period_ms)
        late = round(shift_s(self.plan, self.takeoff_s), 6)
        self._event("takeoff", takeoff_s=self.takeoff_s, round=takeoff_round, retimed_by_s=late)

    def flown_plan(self) -> DescriptorTrajectory:
        """The plan as flown: re-timed to the take-off (protocols/model/plan_timing.py)."""
        return flown_plan(self.plan, self.t_s if self.takeoff_s is None else self.takeoff_s)

    def _record_vehicles(self, k: int, rec: _Recorder) -> None:
        """The vehicles' samples of control tick ``k`` (armed: after the tick's commands)."""
        state = self.world.state
        rec.t[k] = self.t_s
        rec.pos[k], rec.vel[k] = state[POS].T, state[VEL].T
        rec.quat[k] = state[QUAT]
        rec.rates[k] = state[RATES].T
        rec.rotor_speed[k] = self.world.rotor_speed_rad_s
        estimate = self.world.estimate()
        if estimate is not None:  # what the vehicles' telemetry said, beside the truth
            if rec.reported is None:
                rec.reported = (
                    np.zeros_like(rec.pos),
                    np.zeros_like(rec.vel),
                    np.zeros_like(rec.pos),
                )
            for out, values in zip(rec.reported, estimate, strict=True):
                out[k] = values.T
        rec.member[k] = self.member
        rec.airborne[k] = -state[POS][2] > AIRBORNE_ALTITUDE_M
        rec.armed[k] = self.world.autopilot.armed

    def _ready(
        self,
        live: list[int],
        cols: BatchOutputs,
        members: frozenset[int],
        committed: list[bool],
    ) -> list[bool]:
        """Whether each live agent's swarm is ready to leave the ground (the one rule of
        drone_agent/core/flight_phase.py, :class:`BatchReadiness`: all agents in one call), from the
        tick's outputs and the messages that arrived (the network's arrivals)."""
        ready = self.readiness.update(
            live,
            cols.outgoing.round,
            cols.disagreement,
            cols.ready_to_fly,
            self.network.arrivals,
            members,
            committed,
        )
        return ready.tolist()

    def _live(self) -> tuple[list[int], list[int], frozenset[int]]:
        """The live agents (sorted), their rows in the batched core, and their set; one set
        object while the agents do not change."""
        members = frozenset(self.agents)
        if self._live_cache is None or self._live_cache[2] != members:
            live = sorted(members)
            self._live_cache = (live, [self.agents[i].row for i in live], members)
        return self._live_cache
