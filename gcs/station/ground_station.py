"""``swarm gcs``: the ground-station process.

Publishes the scenario's trajectory as the plan (seq 0, FLY) with :class:`PlanServer`, records the
simulator's GCS telemetry stream into ``flight.tlog`` (:class:`TelemetryReceiver`), follows every
agent's status (also logged into ``flight.tlog``) and liveliness on Zenoh (:class:`SwarmWatch`),
answers operator commands and drills on ``swarm/<sid>/command`` (:mod:`gcs.station.commands`,
:mod:`gcs.station.drills`), logs events to ``events.jsonl``, and at the end writes the report from
those two files (:mod:`gcs.report.from_logs`). All times are simulated seconds (the vehicles'
``time_boot_ms``).

Session (``swarm up --drones N``, ``session``): the first plan is the scenario's with GROUND, so
the vehicles wait on the ground for ``swarm takeoff``, and the run has no end time. Shutdown
(``swarm shutdown``, or :meth:`request_shutdown`: a session's SIGINT): a flying swarm gets the
``land`` plan; once every vehicle still heard is disarmed on the ground, or after
``shutdown_timeout_s`` wall seconds, the run ends and the report is written.

Restart (the gcs-restart drill, under ``swarm up``): the station ends without a report and
``swarm up`` starts it again with ``resume``: it appends to both logs, its clock starts at the
last logged event and it adopts the plan the agents fly (asking them for up to 10 s while they
reconnect), so the final report covers the whole flight.

One thread does everything: Zenoh callbacks only append to deques, the command queryable is a
FIFO channel drained by the loop. Use as a context manager; :meth:`stop` is signal-safe.
"""

from __future__ import annotations

import json
import math
import select
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import zenoh

from drone_agent.core.flight_phase import AIRBORNE_ALTITUDE_M
from drone_agent.process.fault_timeline import TimedAction, timeline
from drone_agent.process.transport_link import PlanServer
from gcs.report.agent_timing import timing_metrics
from gcs.report.events import EventLog, read_events
from gcs.report.from_logs import write_report
from gcs.report.log_record import build_record
from gcs.report.tlog import read_tlog
from gcs.report.trajectory_file import write_trajectory
from gcs.station.commands import (
    CommandError,
    Reply,
    Request,
    encode_reply,
    parse_request,
    plan_arrival,
    plan_command,
)
from gcs.station.drills import GcsDrills
from gcs.station.planner import Envelope, PlanRefused
from gcs.station.swarm_watch import SwarmWatch
from gcs.station.telemetry import TelemetryReceiver
from protocols.bus.zenoh_bus import ZenohBus, ZenohSettings
from protocols.model.plan_timing import (
    departure_s,
    flown_plan,
    shift_s,
    takeoff_metrics,
    tick_time_s,
)
from protocols.model.trajectory import DescriptorTrajectory
from protocols.scenario.scenario_file import Scenario
from protocols.wire.format import WireError
from protocols.wire.keys import SwarmKeys
from protocols.wire.plan import FlightCommand, PlanMessage, decode_plan
from protocols.wire.status import decode_statuses
from sitl_sim.vehicle.config import vehicle_params

_POLL_S = 0.02
#: Shortest time between two passes of the main loop (s).
_MIN_PASS_S = 0.005
#: How long a restarted ground station asks the swarm for its current plan (s).
RESUME_PLAN_WAIT_S = 10.0
#: A vehicle silent this long (simulated s) is not waited for at shutdown (crashed, gone).
SILENT_VEHICLE_S = 3.0


@dataclass(frozen=True)
class GcsOptions:
    """How to run the ground station. ``duration_s``: stop at this simulated time (s);
    ``telemetry_hz``: sampling rate of the report's record; ``plan_query_s``: how long (s) to ask
    the swarm for its current plan at start; ``on_line``: gets the status line; ``run_file``: the
    agents' process ids written by ``swarm up`` (enables the dropout and gcs-restart drills);
    ``resume``: a restart: append to flight.tlog and events.jsonl instead of starting them;
    ``signing_key``: sign the MAVLink commands sent to the vehicles (crash drills); ``session``:
    an operator session: the first plan says GROUND and there is no end time;
    ``shutdown_timeout_s``: how long (wall s) a shutdown waits for the swarm to land;
    ``on_recording``: called once the telemetry port is bound (what the simulator sends from then
    on reaches flight.tlog), before Zenoh opens."""

    scenario: Scenario
    report_dir: Path
    zenoh: ZenohSettings
    swarm_id: str = "swarm"
    gcs_host: str = "127.0.0.1"
    gcs_port: int = 14550
    duration_s: float | None = None
    envelope: Envelope = field(default_factory=Envelope)
    telemetry_hz: float = 10.0
    plan_query_s: float = 1.0
    plots: bool = True
    recording: bool = True  # flight.rrd with the report
    on_line: Callable[[str], None] | None = None
    run_file: Path | None = None
    resume: bool = False
    signing_key: bytes | None = None
    session: bool = False
    shutdown_timeout_s: float = 120.0
    on_recording: Callable[[], None] | None = None
    #: vehicles that each count from their own boot: the swarm clock's epoch (Unix s;
    #: protocols/mavlink/swarm_clock.py), None when one simulator's time is the swarm's
    swarm_epoch_s: float | None = None
    #: at the end time, land the swarm (the ``land`` plan) and end the run once it is down, as
    #: a shutdown does (vehicles that outlive the run: another project's SITL, hardware)
    land_at_end: bool = False


class GroundStation:
    """The ground station of one swarm (see the module doc)."""

    def __init__(self, options: GcsOptions) -> None:
        self._o = options
        self._keys = SwarmKeys(options.swarm_id, 1.0)
        self._stop = False
        self.restart_requested = False
        self._shutdown_asked = False
        #: wall clock (monotonic s) the shutdown began, None before
        self._shutdown_since: float | None = None
        #: a restarted station's clock starts where its events log ended, not at 0
        self._t_floor_s = (
            _last_event_time(options.report_dir / "events.jsonl") if options.resume else 0.0
        )
        self._statuses: deque[bytes] = deque(maxlen=10_000)
        #: the newest simulated time of an agent status (kept as they come: not a loop over all
        #: drones each time the time is asked, several times a pass)
        self._t_status_s = 0.0
        #: each agent's newest word of the swarm's take-off round (flight_phase.TakeoffClock)
        self._takeoff_of: dict[int, int | None] = {}
        # a restarted station carries on with the take-off its predecessor logged
        self._takeoff_round = (
            _last_takeoff(options.report_dir / "events.jsonl") if options.resume else None
        )
        self._period_ms = round(options.scenario.rates.dt_control_s * 1000)
        self._liveliness: deque[tuple[str, bool]] = deque()
        self.watch = SwarmWatch(range_m=options.scenario.comms.range_m)
        options.report_dir.mkdir(parents=True, exist_ok=True)
        self._closers: list[Callable[[], None]] = []
        try:
            self.events = EventLog(options.report_dir / "events.jsonl")
            self.events.open()
            self._closers.append(self.events.close)
            self.telemetry = TelemetryReceiver(
                options.gcs_host,
                options.gcs_port,
                options.report_dir / "flight.tlog",
                append=options.resume,
                signing_key=options.signing_key,
                # a restarted station's clock: what comes before any timed telemetry (a
                # STATUSTEXT, a HEARTBEAT) is stamped there, not at 0, in the tlog and the events
                sim_time_s=self._t_floor_s,
                origin=options.scenario.home,
                epoch_s=options.swarm_epoch_s,
            )
            self._closers.append(self.telemetry.close)
            if options.on_recording is not None:
                options.on_recording()
            self.bus = ZenohBus.open(options.zenoh)
            self._closers.append(self.bus.close)
            for sub in (
                self.bus.subscribe_callback(self._keys.status_all(), self._on_status),
                self.bus.watch_liveliness(self._keys.alive_all(), self._on_alive),
            ):
                self._closers.append(sub.close)
            self._faults: list[TimedAction] | None = None
            self.drills = GcsDrills(self.bus, options.swarm_id, self.events, self.telemetry)
            self._closers.append(self.drills.close)
            handler: zenoh.handlers.FifoChannel[zenoh.Query] = zenoh.handlers.FifoChannel(64)
            self._commands = self.bus.session.declare_queryable(self._keys.command, handler)
            self._closers.append(self._commands.undeclare)
            held = self._current_plan()  # before our own plan queryable exists
            self.plans = PlanServer(self.bus, options.swarm_id)
            self._closers.append(self.plans.close)
            if held is None and options.session:
                first = PlanMessage(options.scenario.trajectory(), FlightCommand.GROUND)
                self._publish(first, "session: on the ground until swarm takeoff")
            elif held is None:
                self._publish(PlanMessage(options.scenario.trajectory()), "scenario")
            else:
                self._publish(held, "restart: adopted the swarm's current plan")
        except BaseException:
            self.close()
            raise

    def _current_plan(self) -> PlanMessage | None:
        """The newest plan the swarm already flies (agents answer plan queries), if any: a
        restarted ground station carries on from it instead of going back to the scenario's."""
        newest: PlanMessage | None = None
        # a restart waits for the agents to reconnect (they retry within a second)
        deadline = time.monotonic() + (RESUME_PLAN_WAIT_S if self._o.resume else 0.0)
        while True:
            replies = self.bus.session.get(self._keys.plan, timeout=self._o.plan_query_s)
            for reply in replies:  # ends when every queryable answered or at the timeout
                if reply.ok is None:
                    continue
                try:
                    plan = decode_plan(reply.ok.payload.to_bytes(), self._o.swarm_id)
                except WireError:
                    continue
                if newest is None or plan.seq > newest.seq:
                    newest = plan
            if newest is not None or time.monotonic() >= deadline:
                return newest
            # the telemetry meanwhile (a restarted station: the swarm flies on)
            for text in self.telemetry.poll():
                self._vehicle_text(text.t_s, text.drone, text.severity, text.text)
            time.sleep(0.2)

    def __enter__(self) -> GroundStation:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Undeclare everything, close the session, the socket and the logs (idempotent)."""
        while self._closers:
            self._closers.pop()()

    def stop(self) -> None:
        """Ask :meth:`run` to finish (safe from a signal handler)."""
        self._stop = True

    def request_shutdown(self) -> None:
        """Ask :meth:`run` to land the swarm if it flies, then finish (safe from a signal
        handler; the loop carries it out)."""
        self._shutdown_asked = True

    @property
    def now_s(self) -> float:
        """The newest simulated time (s) heard from a vehicle or an agent."""
        return max(self.telemetry.sim_time_s, self._t_status_s, self._t_floor_s)

    @property
    def takeoff_s(self) -> float | None:
        """When the swarm left the ground (s), as its agents agreed it; None: not yet."""
        t = self._takeoff_round
        return None if t is None else tick_time_s(t, self._period_ms)

    def flown(self, now_s: float | None = None) -> DescriptorTrajectory:
        """The plan in force as the swarm flies it (protocols/model/plan_timing.py): re-timed to the
        take-off; before it, held until ``now_s`` (default: now)."""
        takeoff = self.takeoff_s
        when = takeoff if takeoff is not None else (self.now_s if now_s is None else now_s)
        return flown_plan(self.plan.trajectory, when)

    def _flown_plan(self, now_s: float) -> PlanMessage:
        """The plan in force as flown, as the plan message the planner continues from."""
        return replace(self.plan, trajectory=self.flown(now_s))

    def _track_takeoff(self) -> None:
        """The swarm's take-off round: the least the live agents report. A new one is an event
        ("takeoff", with how late the plan is flown) and rewrites trajectory.json as flown."""
        alive = self.watch.alive
        said = [t for d, t in self._takeoff_of.items() if t is not None and d in alive]
        takeoff = min(said) if said else None
        if takeoff is None or takeoff == self._takeoff_round:
            return
        self._takeoff_round = takeoff
        t_s = self.takeoff_s
        late = shift_s(self.plan.trajectory, t_s)
        self.events.record(
            self.now_s,
            "takeoff",
            takeoff_s=t_s,
            round=takeoff,
            retimed_by_s=round(late, 6),
            plan_seq=self.plan.seq,
        )
        write_trajectory(self.flown(), self._o.report_dir / "trajectory.json")

    def _on_status(self, _key: str, payload: bytes) -> None:  # Zenoh thread: enqueue only
        self._statuses.append(payload)

    def _on_alive(self, key: str, alive: bool) -> None:  # Zenoh thread: enqueue only
        self._liveliness.append((key, alive))

    def _publish(self, plan: PlanMessage, why: str) -> None:
        self.plans.publish(plan)
        self.plan = plan
        # the plan in force, as flown, for a live view of the report folder (swarm view)
        write_trajectory(self.flown(), self._o.report_dir / "trajectory.json")
        self.events.record(
            self.now_s, "plan_published", seq=plan.seq, command=plan.command.name, reason=why
        )

    def _scenario_faults(self) -> None:
        """Record each fault of the scenario's timeline as its time passes ("fault" and
        "fault_end" events, as ``swarm simulate`` records them). The agents and the simulator
        carry them out; a restarted station records only those still to come."""
        if self._faults is None:
            now = self.now_s
            self._faults = [a for a in timeline(self._o.scenario) if a.t_s > now or not now]
        while self._faults and self._faults[0].t_s <= self.now_s + 1e-9:
            action = self._faults.pop(0)
            self.events.record(
                action.t_s,
                "fault" if action.starts else "fault_end",
                fault=action.fault_kind,
                description=action.description,
            )

    def run(self) -> list[Path]:
        """Run until :meth:`stop` or the end time; then write and return the report files."""
        end_s = None if self._o.session else self._o.duration_s or self._o.scenario.duration_s
        # wall clock of the run's start: a restarted station's report covers the whole flight
        started = _run_started(self._o.report_dir / "events.jsonl") if self._o.resume else None
        wall0 = time.time() if started is None else started
        self.events.record(
            self.now_s,
            "gcs_restarted" if self._o.resume else "run_start",
            scenario=self._o.scenario.name,
            end_s=end_s,
            wall_clock_s=round(time.time(), 3),
        )
        next_line = time.monotonic() + 1.0
        # the simulator's last report
        last_sample_s = math.inf if end_s is None else end_s - 1.0 / self._o.telemetry_hz
        last_pass = time.monotonic()
        while not self._stop and (self.now_s < last_sample_s or self._landing_at_end(end_s)):
            select.select([self.telemetry], [], [], _POLL_S)
            # at most one pass every _MIN_PASS_S: what came meanwhile waits in the socket and the
            # queues, and is taken in one pass (not one pass per datagram)
            pause = last_pass + _MIN_PASS_S - time.monotonic()
            if pause > 0:
                time.sleep(pause)
            last_pass = time.monotonic()
            for text in self.telemetry.poll():
                self._vehicle_text(text.t_s, text.drone, text.severity, text.text)
            self._drain_zenoh()
            self.drills.drain(self.now_s)
            self._scenario_faults()
            self._answer_commands()
            if self._shutdown_asked and self._shutdown_since is None:
                self._begin_shutdown(self.now_s, "interrupt")
            if self._shutdown_since is not None and self._shutdown_over():
                break
            if time.monotonic() >= next_line:
                next_line += 1.0
                if self._o.on_line is not None:
                    self._o.on_line(self.status_line())
        if self.restart_requested:
            self.events.record(self.now_s, "gcs_stopped", reason="restart", plan_seq=self.plan.seq)
            return []
        if end_s is None or self._o.land_at_end:  # a session, or a landing after the end
            end_s = max(self.now_s, end_s or 0.0)
        # report_end_s: where the report's record ends (gcs.api.load_report rebuilds it)
        self.events.record(self.now_s, "run_end", plan_seq=self.plan.seq, report_end_s=end_s)
        self.telemetry.close()
        n = self._o.scenario.n_drones
        report = self._o.report_dir
        track = read_tlog(report / "flight.tlog")
        flown = self.flown()
        record = build_record(
            report / "flight.tlog",
            report / "events.jsonl",
            flown,
            n,
            self._o.telemetry_hz,
            end_s,
            self._o.scenario,
            track=track,
        )
        wall = time.time() - wall0
        extra = {
            "scenario": self._o.scenario.name,
            "mode": "distributed (swarm gcs)",
            "plan_seq": self.plan.seq,
            "settle_s": self._o.scenario.settle_s,
            "takeoff": takeoff_metrics(self.takeoff_s, self.plan.trajectory),
            "layout": _run_layout(self._o.run_file),
            "wall_time_s": round(wall, 3),
            "real_time_factor": round(self.now_s / wall, 3) if wall > 0 else None,
            "agent_timing": timing_metrics(track, read_events(report / "events.jsonl")),
        }
        return write_report(
            self._o.report_dir,
            record,
            flown,
            self._o.scenario.settle_s,
            extra,
            self._o.plots,
            vehicle_params(self._o.scenario).max_thrust_n,
            self._o.recording,
            track,
        )

    def _vehicle_text(self, t_s: float, drone: int, severity: int, text: str) -> None:
        """Log a vehicle's STATUSTEXT as a crash, a failsafe or a plain text."""
        kind = self.watch.on_vehicle_text(drone, severity, text, t_s)
        self.events.record(t_s, kind, drone=drone, severity=severity, text=text)

    def _drain_zenoh(self) -> None:
        while self._statuses:
            try:  # one status, or a process's batch of them
                statuses = decode_statuses(self._statuses.popleft(), self._o.swarm_id)
            except WireError:
                continue
            kinds = self.watch.on_statuses(statuses, self.telemetry.vehicles)
            for status, kind in zip(statuses, kinds, strict=True):
                self._t_status_s = max(self._t_status_s, status.t_s)
                if kind:
                    self.events.record(status.t_s, kind, drone=status.drone)
                self._takeoff_of[status.drone] = status.takeoff_round
            self.telemetry.log_agent_statuses(statuses)
        self._track_takeoff()
        while self._liveliness:
            key, alive = self._liveliness.popleft()
            drone = self._keys.drone_of(key)
            if drone is not None and (kind := self.watch.on_liveliness(drone, alive, self.now_s)):
                self.events.record(self.now_s, kind, drone=drone)

    def _answer_commands(self) -> None:
        while (query := self._commands.try_recv()) is not None:
            payload = query.payload.to_bytes() if query.payload is not None else None
            reply = replace(self.execute(payload), t_s=self.now_s)
            query.reply(self._keys.command, encode_reply(reply))
            query.drop()

    def execute(self, payload: bytes | None) -> Reply:
        """Validate and carry out one command request; never raises for a bad request."""
        now = self.now_s
        try:
            request = parse_request(payload)
        except CommandError as exc:
            self.events.record(now, "command", command=None, accepted=False, reason=str(exc))
            return Reply(False, str(exc), self.plan.seq)
        if request.name == "status":
            table = tuple(self.status_table())
            return Reply(True, f"t = {now:.2f} s", self.plan.seq, table, plan=self.plan_summary())
        n = self._o.scenario.n_drones
        if request.name == "crash":  # drills, recorded by GcsDrills
            return replace(self.drills.crash(request.args["drone"], n, now), seq=self.plan.seq)
        if request.name == "dropout":
            reply = self.drills.dropout(
                request.args["drone"], n, now, self._o.run_file, self.watch.alive
            )
            return replace(reply, seq=self.plan.seq)
        if request.name == "gcs-restart":
            return self._restart(now)
        if request.name == "shutdown":
            reply = self._begin_shutdown(now, "swarm shutdown")
        elif self._shutdown_since is not None:
            reply = Reply(False, "the swarm is shutting down", self.plan.seq)
        else:
            reply = self._plan_command(request, now)
        self.events.record(
            now,
            "command",
            command=request.name,
            args=request.args,
            accepted=reply.accepted,
            reason=reply.reason,
            seq=reply.seq,
        )
        return reply

    def _plan_command(self, request: Request, now_s: float) -> Reply:
        """A plan-changing command: publish the next plan, or say why not."""
        try:
            positions = self.watch.positions(self.telemetry.vehicles)
            plan, when, arrives_s = plan_arrival(
                request, self._flown_plan(now_s), now_s, self._o.envelope, positions
            )
        except PlanRefused as exc:
            return Reply(False, str(exc), self.plan.seq)
        self._publish(plan, request.name)
        return Reply(True, f"plan {plan.seq}: {when}", plan.seq, arrives_s=arrives_s)

    def plan_summary(self) -> dict[str, Any]:
        """The plan in force, for ``status``: its ``seq``, ``command`` (FLY, GROUND, LAND) and
        ``late_s``, how many seconds late the swarm flies it (protocols/model/plan_timing.py); None
        while a plan that leaves the ground still waits there for the swarm's take-off."""
        takeoff, trajectory = self.takeoff_s, self.plan.trajectory
        waiting = (
            takeoff is None
            and self.plan.command == FlightCommand.FLY
            and departure_s(trajectory, self.now_s) is not None
        )
        late = None if waiting else shift_s(trajectory, takeoff)
        return {"seq": self.plan.seq, "command": self.plan.command.name, "late_s": late}

    def _landing_at_end(self, end_s: float | None) -> bool:
        """With ``land_at_end``, past the end time: land first (once), True until the swarm is
        down (:meth:`_shutdown_over`, checked in the loop)."""
        if not self._o.land_at_end or end_s is None:
            return False
        if self._shutdown_since is None:
            self._begin_shutdown(self.now_s, "the scenario ended")
        return True

    def _begin_shutdown(self, now_s: float, why: str) -> Reply:
        """Land the swarm if it flies (the ``land`` plan), then end the run once it is down
        (:meth:`_shutdown_over`)."""
        if self._shutdown_since is not None:
            return Reply(False, "already shutting down", self.plan.seq)
        self._shutdown_since = time.monotonic()
        airborne = self.airborne_drones()
        if self.plan.command == FlightCommand.FLY:
            positions = self.watch.positions(self.telemetry.vehicles)
            landing, when = plan_command(
                Request("land", {}), self._flown_plan(now_s), now_s, self._o.envelope, positions
            )
            self._publish(landing, f"shutdown ({why}): land first")
            what = f"landing ({when}), then the run ends and the report is written"
        elif airborne:
            what = "the swarm is landing; then the run ends and the report is written"
        else:
            what = "the swarm is on the ground: the run ends and the report is written"
        self.events.record(now_s, "shutdown", reason=why, airborne=airborne)
        return Reply(True, what, self.plan.seq)

    def airborne_drones(self) -> list[int]:
        """Drones whose vehicle is armed or off the ground, among those still heard (a vehicle
        silent for SILENT_VEHICLE_S, e.g. crashed, is not waited for; one whose agent left is:
        its own failsafe lands it)."""
        now = self.now_s
        return [
            i
            for i, v in sorted(self.telemetry.vehicles.items())
            if now - v.t_s < SILENT_VEHICLE_S
            and (
                v.armed
                or (v.position_ned_m is not None and -v.position_ned_m[2] > AIRBORNE_ALTITUDE_M)
            )
        ]

    def _shutdown_over(self) -> bool:
        """The shutdown's landing is over: every vehicle heard is down, or the time is up."""
        assert self._shutdown_since is not None
        airborne = self.airborne_drones()
        if not airborne:
            self.events.record(self.now_s, "shutdown_landed")
            return True
        if time.monotonic() - self._shutdown_since > self._o.shutdown_timeout_s:
            self.events.record(self.now_s, "shutdown_timeout", airborne=airborne)
            return True
        return False

    def _restart(self, now_s: float) -> Reply:
        """The gcs-restart drill: end the run without a report, exit code RESTART_EXIT_CODE, and
        ``swarm up`` starts the ground station again (with ``--resume``)."""
        if self._o.run_file is None:
            reply = Reply(
                False,
                "only a ground station started by swarm up can be restarted (swarm up starts it "
                "again); stop and start this one yourself",
                self.plan.seq,
            )
        else:
            reply = Reply(True, "the ground station restarts now", self.plan.seq)
            self.restart_requested = True
            self._stop = True
        self.events.record(
            now_s, "drill", drill="gcs_restart", accepted=reply.accepted, reason=reply.reason
        )
        return reply

    def status_table(self) -> list[dict[str, Any]]:
        """The ``swarm status`` table (:meth:`SwarmWatch.table`)."""
        return self.watch.table(self.telemetry.vehicles)

    def status_line(self) -> str:
        """One line: sim time, vehicles heard, agents alive, worst centre estimate error."""
        worst = self.watch.worst_error_m(self.telemetry.vehicles)
        return (
            f"gcs t={self.now_s:7.2f}s  vehicles {len(self.telemetry.vehicles)}  "
            f"agents alive {len(self.watch.alive)}  plan {self.plan.seq}  "
            f"worst estimate error {'-' if worst is None else f'{worst:.3f} m'}"
        )


def _last_event_time(path: Path) -> float:
    """The time (s) of the last event in ``path``; 0 if there is none."""
    try:
        events = read_events(path)
    except (OSError, ValueError):
        return 0.0
    return max((float(e.get("t_s", 0.0)) for e in events), default=0.0)


def _run_layout(run_file: Path | None) -> str | None:
    """How ``swarm up`` laid the agents out, and why (its run file); None if not said."""
    if run_file is None:
        return None
    try:
        layout = json.loads(run_file.read_text()).get("layout")
    except (OSError, ValueError, AttributeError):
        return None
    return layout if isinstance(layout, str) and layout else None


def _last_takeoff(path: Path) -> int | None:
    """The take-off round the events log ``path`` last recorded; None if none."""
    try:
        events = read_events(path)
    except (OSError, ValueError):
        return None
    rounds = [e.get("round") for e in events if e.get("kind") == "takeoff"]
    return rounds[-1] if rounds and isinstance(rounds[-1], int) else None


def _run_started(path: Path) -> float | None:
    """The wall clock (Unix time, s) the run of the events log ``path`` started; None if the
    log does not say."""
    try:
        events = read_events(path)
    except (OSError, ValueError):
        return None
    starts = [e.get("wall_clock_s") for e in events if e.get("kind") == "run_start"]
    return float(starts[0]) if starts and isinstance(starts[0], int | float) else None
