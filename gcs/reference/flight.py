"""The whole swarm in one process (``swarm simulate``): vehicles, agents and radio, no network.

Every drone runs the same agent core as the distributed agents (all of them as the rows of one
:class:`~drone_agent.agent_core.BatchAgentCore`, one call per control tick),
the vehicles run the same dynamics and inner loop as the SITL simulator, and consensus messages
pass through an in-memory radio with the scenario's faults. It is the reference the distributed
system is measured against, and a fast tuning tool. Deterministic for a given seed; no I/O.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drone_agent.agent_core import AgentCore, BatchAgentCore, BatchOutputs, Setpoint
from drone_agent.config import agent_config
from drone_agent.consensus_batch import frozen_factory
from drone_agent.fault_timeline import TimedAction, timeline
from drone_agent.flight_phase import (
    BatchReadiness,
    BatchTakeoff,
    FlightPhase,
    Request,
    VehicleView,
)
from drone_agent.link_faults import LinkFaults, PairRandom
from gcs.reference.network import InProcessNetwork
from gcs.report.flight_record import FlightRecord, scenario_link_cuts
from protocols.collector import flight_collector
from protocols.frames import FloatArray, quat_from_zyx
from protocols.plan_timing import flown_plan, flown_time_s, shift_s, tick_time_s
from protocols.scenario import Scenario
from protocols.trajectory import DescriptorTrajectory
from protocols.wire_plan import FlightCommand
from sitl_sim.attitude_control import euler_from_quat_batch, yaw_from_quat_batch
from sitl_sim.config import attitude_gains, vehicle_params
from sitl_sim.dynamics import (
    POS,
    QUAT,
    RATES,
    VEL,
    initial_state,
    wrench_from_rotor_speeds,
)
from sitl_sim.failsafe import FailsafeConfig, failsafe_command
from sitl_sim.physics_kernel import PhysicsKernel
from sitl_sim.setpoint import validate_attitude_targets

AIRBORNE_ALTITUDE_M = 0.1
HARD_LANDING_M_S = 2.0
#: An agent leaves the swarm this long after its vehicle crashes: the next control tick, as the
#: distributed agent does on its vehicle's EMERGENCY STATUSTEXT (drone_agent/hosted_agent.py).
CRASH_NOTICE_S = 0.0
_new_vehicle_view = frozen_factory(VehicleView)


def reported(values: FloatArray) -> FloatArray:
    """``values`` as a vehicle reports them to its agent: LOCAL_POSITION_NED and ATTITUDE carry
    float32 (drone_agent/vehicle_link.py reads them back as float64). The in-process agents read
    their vehicles through this, as every ``swarm agent`` does, so the two runners compute on the
    same inputs: a square grid's orientation estimate is ill-conditioned (equal spreads: its axes
    are any), and the rounding alone turned one agent's estimated heading by 0.13 rad at the
    take-off of the 25-drone grid, which the formation then flew (up to 14 mm apart at N = 25,
    12 cm at N = 100)."""
    return np.asarray(values, dtype=np.float64).astype(np.float32).astype(np.float64)


def received(
    drones: list[int], commands: list[tuple[float, float, float, float]]
) -> tuple[list[int], FloatArray, FloatArray]:
    """The setpoints ``commands`` (roll, pitch, yaw rad, normalised thrust) of ``drones`` as their
    vehicles take them from a swarm agent: the agent's quaternion (drone_agent/hosted_agent.py:
    ``quat_from_zyx``, the same values over an array as one by one), SET_ATTITUDE_TARGET's
    float32, the simulator's validation (sitl_sim/setpoint.py: normalised, back to ZYX angles).
    Returns the drones whose setpoint was valid (the others keep their last one, as the
    simulator's vehicles do), their attitudes (3, K) and thrusts (K,). A square grid's take-off
    turned on the last bit of a command: 1e-13 m of one vehicle's position flipped its agent's
    estimated heading by 90 degrees at N = 100. The simulator's checks run over all the drones
    at once (:func:`~sitl_sim.setpoint.validate_attitude_targets`: the same rule, compiled)."""
    values = np.array(commands).T
    quats = quat_from_zyx(values[2], values[1], values[0]).astype(np.float32).T
    thrusts = values[3].astype(np.float32)
    codes, _, euler = validate_attitude_targets(quats, thrusts)  # float32's values as float64
    ok = codes == 0
    taken = np.asarray(drones, dtype=np.intp)[ok].tolist()
    return taken, euler[ok].T, thrusts[ok].astype(np.float64)


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
        #: every ``links_every`` ticks (0: never), the neighbours each live agent integrated
        self.links_every = links_every
        self.neighbour_ids: dict[int, dict[int, tuple[int, ...]]] = {}


class ReferenceFlight:
    """One flight of a scenario. :meth:`run` flies it and returns the record and the events."""

    def __init__(self, scenario: Scenario, rng: np.random.Generator | None = None) -> None:
        self.scenario = scenario
        self.n = scenario.n_drones
        self.params = vehicle_params(scenario)
        self.att_gains = attitude_gains(scenario)
        self.config = agent_config(scenario)
        self.plan = scenario.trajectory()
        self.dt = scenario.rates.dt_control_s
        self.substeps = scenario.rates.physics_steps_per_control
        self.rng = rng if rng is not None else np.random.default_rng(scenario.seed)
        yaw0 = np.radians([d.yaw_deg for d in scenario.drones])
        self.state = initial_state(scenario.positions_ned_m(), yaw0)
        self.core = BatchAgentCore(range(self.n), self.config)
        self.agents: dict[int, AgentCore] = {
            i: AgentCore(i, self.config, self.core) for i in range(self.n)
        }
        self.readiness = BatchReadiness(self.n, self.config)
        self.phases = [FlightPhase(self.config.limits) for _ in range(self.n)]
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
        self.network = InProcessNetwork(self.n, scenario.comms.range_m, radio_rng, delay)
        self.failsafe = FailsafeConfig()
        self.armed = np.zeros(self.n, dtype=bool)
        self.crashed = np.zeros(self.n, dtype=bool)
        self.member = np.ones(self.n, dtype=bool)
        self.attitude_sp = np.zeros((3, self.n))
        self.attitude_sp[2] = yaw0
        self.thrust_sp = np.zeros(self.n)
        self.last_setpoint_s = np.full(self.n, -np.inf)
        self.in_failsafe = np.zeros(self.n, dtype=bool)
        self.rotor_speed = np.zeros((4, self.n))
        self.leave_at: dict[int, float] = {}
        self.lost_at: dict[int, float] = {}
        self.events: list[FlightEvent] = []
        self._actions: list[TimedAction] = timeline(scenario)
        self.t_s = 0.0
        self._kernel = PhysicsKernel(self.params, self.n, self.dt / self.substeps, self.att_gains)
        self._oldest_setpoint_s: float | None = None
        self._any_failsafe = False  # whether a vehicle in failsafe may still be armed
        self._live_cache: tuple[list[int], list[int], frozenset[int]] | None = None
        #: the agents that finished the previous tick (None before the first)
        self._finished: frozenset[int] | None = None

    # -- FaultTarget ---------------------------------------------------------------------------
    @property
    def conditions(self) -> LinkFaults:
        return self.network.conditions

    def kill_agent(self, drone: int) -> None:
        """The agent's process dies: it stops at once; its vehicle will failsafe."""
        self.agents.pop(drone, None)
        self._lose(drone)

    def crash_vehicle(self, drone: int) -> None:
        """Motors off: the vehicle falls. Its agent hears the crash and leaves at the next tick."""
        self.crashed[drone] = True
        self.armed[drone] = False
        self.leave_at[drone] = self.t_s + CRASH_NOTICE_S
        self._lose(drone)

    def _lose(self, drone: int) -> None:
        if self.member[drone]:
            self.member[drone] = False
            self.lost_at[drone] = self.t_s

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
        """Control tick ``k`` of ``n_ticks`` and the physics up to the next one."""
        self.t_s = k * self.dt
        self._apply_faults()
        self._control_tick(k, rec)
        if progress is not None:
            progress(self.t_s)
        if k < n_ticks - 1:
            armed = self.last_setpoint_s[self.armed]
            self._oldest_setpoint_s = float(armed.min()) if armed.shape[0] else None
            if not self._physics_steps():
                for sub in range(self.substeps):
                    self._physics_step(self.t_s + sub * self.dt / self.substeps)

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
        for drone, t_leave in list(self.leave_at.items()):
            if self.t_s >= t_leave:
                del self.leave_at[drone]
                if self.agents.pop(drone, None) is not None:
                    self._event("agent_left", drone=drone, reason="vehicle crashed")

    def _control_tick(self, k: int, rec: _Recorder) -> None:
        true_pos = self.state[POS].T
        # what each agent reads of its vehicle, as a swarm agent reads it (the telemetry's float32)
        pos, vel = reported(true_pos), reported(self.state[VEL].T)
        live, rows, now_live = self._live()
        # the membership view of tick k: the agents that finished round k - 1, as the lockstep
        # round gate of every swarm agent has it (drone_agent/round_gate.py: an agent that died
        # before its tick k - 1 is known dead only when its round k - 1 does not come)
        members = now_live if self._finished is None else self._finished
        self._finished = now_live
        inboxes = self.network.receive_inboxes(k, live)
        # the tick's time as the agents read it: the vehicle's time_boot_ms (sitl_sim/world.py),
        # not k * dt (6.0200000000000005 s at k = 301, where the plan's climb starts)
        t_s = round(k * 1000 / self.scenario.rates.control_hz) / 1000.0
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
        yaw = reported(yaw_from_quat_batch(self.state[QUAT])).tolist()
        altitude = (-pos[:, 2]).tolist()
        flying: list[int] = []
        commands: list[tuple[float, float, float, float]] = []
        separating, crashed = self.separating, self.crashed.tolist()
        phases = self.phases
        committed = [phases[i].committed for i in live]
        ready_all = self._ready(live, cols, members, committed)
        armed_now, failsafe_now = self.armed.tolist(), self.in_failsafe.tolist()
        commanded_altitude = (-cols.desired[:, 2]).tolist()
        for i, now_separating, setpoint, up_m, ready, flies in zip(
            live,
            cols.separating,
            cols.setpoints,
            commanded_altitude,
            ready_all,
            committed,
            strict=True,
        ):
            if now_separating != separating[i]:
                separating[i] = now_separating
                self._event("separation" if now_separating else "separation_end", drone=i)
            if crashed[i]:
                continue
            sp = self._decide(
                i, setpoint, up_m, flies or ready, altitude[i], yaw[i], armed_now[i],
                failsafe_now[i],
            )  # fmt: skip
            if sp is not None:
                flying.append(i)
                commands.append(sp)
        # the swarm's take-off round, agreed over the messages (flight_phase.TakeoffClock)
        takeoffs = self.takeoff.update(
            live, k, [phases[i].committed for i in live], self.network.arrivals
        )
        if self.takeoff_s is None and (said := [t for t in takeoffs if t is not None]):
            self._took_off(min(said))
        messages = cols.outgoing.messages(self.readiness.level[live].tolist(), takeoffs)
        if flying:
            flown, attitude, thrust = received(flying, commands)
            self.attitude_sp[:, flown] = attitude
            self.thrust_sp[flown] = thrust
            self.last_setpoint_s[flown] = self.t_s
        self.network.send(k, messages, self.network.in_range(pos))
        rec.desired[k] = cols.desired[0]
        self._record_vehicles(k, rec)

    def _fly_none(self, k: int, rec: _Recorder) -> None:
        """Control tick ``k`` with no live agent: no message, no setpoint, only the record."""
        rec.desired[k] = self.plan.evaluate(flown_time_s(self.plan, self.t_s, self.takeoff_s))[0]
        self._record_vehicles(k, rec)

    def _plan_times(self, live: list[int], t_s: float) -> list[float]:
        """Each live agent's plan time (protocols/plan_timing.py) on its take-off round."""
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
        """The plan as flown: re-timed to the take-off (protocols/plan_timing.py)."""
        return flown_plan(self.plan, self.t_s if self.takeoff_s is None else self.takeoff_s)

    def _record_vehicles(self, k: int, rec: _Recorder) -> None:
        """The vehicles' samples of control tick ``k``."""
        rec.t[k] = self.t_s
        rec.pos[k], rec.vel[k] = self.state[POS].T, self.state[VEL].T
        rec.quat[k] = self.state[QUAT]
        rec.rates[k] = self.state[RATES].T
        rec.rotor_speed[k] = self.rotor_speed
        rec.member[k] = self.member
        rec.airborne[k] = -self.state[POS][2] > AIRBORNE_ALTITUDE_M
        rec.armed[k] = self.armed

    def _ready(
        self,
        live: list[int],
        cols: BatchOutputs,
        members: frozenset[int],
        committed: list[bool],
    ) -> list[bool]:
        """Whether each live agent's swarm is ready to leave the ground (the one rule of
        drone_agent/flight_phase.py, :class:`BatchReadiness`: all agents in one call), from the
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

    def _decide(
        self,
        i: int,
        setpoint: Setpoint | None,
        commanded_altitude_m: float,
        ready: bool,
        altitude_m: float,
        yaw_rad: float,
        armed: bool,
        in_failsafe: bool,
    ) -> tuple[float, float, float, float] | None:
        """What the agent's flight phase decides for its vehicle (drone_agent/flight_phase.py,
        the same decision as every ``swarm agent``): arms it when asked, and returns the
        setpoint (roll, pitch, yaw, thrust) of an armed vehicle, None for a disarmed one. The
        scenario's plan always says FLY. The vehicle here has no flight modes: arming takes the
        offboard setpoints at once, and a hold (no valid setpoint in the air) flies the order's
        level hover setpoint. ``setpoint``: the agent's checked setpoint (None: none);
        ``commanded_altitude_m``: the plan's centre altitude (m, up); ``armed``,
        ``in_failsafe``: the vehicle's state at the tick."""
        arming = not armed and not in_failsafe
        # VehicleView(armed, in_offboard, in_land, in_hold, altitude_m)
        vehicle = _new_vehicle_view(armed, armed, in_failsafe, False, altitude_m)
        order = self.phases[i].decide(
            FlightCommand.FLY, True, ready, setpoint, commanded_altitude_m, vehicle, yaw_rad
        )
        if order.request == Request.ARM_OFFBOARD and arming:
            self.armed[i] = armed = True
            self._event("armed", drone=i)
        if not armed:
            return None
        sp = order.setpoint
        return (sp.roll_rad, sp.pitch_rad, sp.yaw_rad, sp.thrust_normalised)

    def _live(self) -> tuple[list[int], list[int], frozenset[int]]:
        """The live agents (sorted), their rows in the batched core, and their set; one set
        object while the agents do not change."""
        members = frozenset(self.agents)
        if self._live_cache is None or self._live_cache[2] != members:
            live = sorted(members)
            self._live_cache = (live, [self.agents[i].row for i in live], members)
        return self._live_cache

    def _physics_steps(self) -> bool:
        """The tick's sub-steps in one kernel call (the same numbers as one
        :meth:`_physics_step` each) when nothing can change between them: no vehicle in
        failsafe and none that can go stale before the last sub-step (its time is the latest;
        staleness is monotonic in time). Whether it did."""
        if self._any_failsafe:
            return False
        oldest = self._oldest_setpoint_s
        last_s = self.t_s + (self.substeps - 1) * self.dt / self.substeps
        if oldest is not None and last_s - oldest > self.failsafe.offboard_timeout_s:
            return False
        self.state, self.rotor_speed, impacts = self._kernel.substeps(
            self.state, self.attitude_sp, self.thrust_sp, self.armed, self.substeps
        )
        for impact in impacts:
            for i in np.flatnonzero(impact > HARD_LANDING_M_S):
                self._event("hard_landing", drone=int(i), impact_m_s=round(float(impact[i]), 2))
        return True

    def _physics_step(self, t_s: float) -> None:
        attitude, thrust = self.attitude_sp, self.thrust_sp
        timeout = self.failsafe.offboard_timeout_s
        # no vehicle can be stale while the oldest armed one's last setpoint is recent enough
        # (t - last is monotonic in last; the armed set only shrinks between control ticks)
        oldest = self._oldest_setpoint_s
        stale = None
        if oldest is not None and t_s - oldest > timeout:
            stale = self.armed & (t_s - self.last_setpoint_s > timeout)
        if stale is not None and stale.any():
            attitude, thrust = attitude.copy(), thrust.copy()
            for i in np.flatnonzero(stale & ~self.in_failsafe):
                self.in_failsafe[i] = True
                self._any_failsafe = True
                self._event(
                    "failsafe",
                    drone=int(i),
                    reason="no setpoint for "
                    f"{self.failsafe.offboard_timeout_s:g} s: level, descend, disarm",
                )
            since = t_s - self.last_setpoint_s[stale] - self.failsafe.offboard_timeout_s
            yaw = yaw_from_quat_batch(self.state[QUAT][:, stale])
            att, thr = failsafe_command(
                self.state[5, stale],
                yaw,
                since,
                self.params.hover_thrust_n / self.params.max_thrust_n,
                self.failsafe,
            )
            attitude[:, stale], thrust[stale] = att, thr
        # inner_loop + step_with_contact, fused (same arithmetic: sitl_sim.physics_kernel)
        self.state, self.rotor_speed, impact = self._kernel.substep(
            self.state, attitude, thrust, self.armed
        )
        if impact is not None:
            for i in np.flatnonzero(impact > HARD_LANDING_M_S):
                self._event("hard_landing", drone=int(i), impact_m_s=round(float(impact[i]), 2))
        if not self._any_failsafe:
            return
        landed = self.in_failsafe & self.armed & (self.state[2] >= -1e-6)
        for i in np.flatnonzero(landed):
            self.armed[i] = False
            self._event("disarmed", drone=int(i), reason="failsafe landing complete")
        # a vehicle in failsafe is never armed again: once all are disarmed, nothing to check
        self._any_failsafe = bool((self.in_failsafe & self.armed).any())
